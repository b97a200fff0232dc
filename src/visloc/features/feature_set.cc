#include "visloc/features/feature_set.h"

#include <nlohmann/json.hpp>

#include "visloc/util/error.h"
#include "visloc/util/section_file.h"

namespace visloc {

void FeatureSet::check_consistent() const {
  VISLOC_CHECK(keypoints.size() == descriptors.rows(), "keypoints and descriptors differ in count");
}

void write_feature_file(const std::filesystem::path& path, const FeatureSet& f) {
  f.check_consistent();
  nlohmann::json meta = {{"image", f.image},
                         {"width", f.image_width},
                         {"height", f.image_height},
                         {"count", f.size()},
                         {"extractor", f.extractor.empty() ? nlohmann::json(nullptr)
                                                           : nlohmann::json::parse(f.extractor)}};
  SectionFileWriter w(path, "FEAT", kFeatureFileVersion);
  w.add_text("META", meta.dump());
  w.add_array<Keypoint>("KPTS", f.keypoints);
  w.add("DESC", f.descriptors.data(), f.descriptors.size_bytes());
  w.commit();
}

FeatureSet read_feature_file(const std::filesystem::path& path) {
  SectionFileReader r(path, "FEAT", 1, kFeatureFileVersion);
  FeatureSet f;
  nlohmann::json meta;
  int64_t count = -1;
  try {
    meta = nlohmann::json::parse(r.text("META"));
    f.image = meta.at("image").get<std::string>();
    f.image_width = meta.at("width").get<int>();
    f.image_height = meta.at("height").get<int>();
    if (!meta.at("extractor").is_null()) f.extractor = meta.at("extractor").dump();
    if (meta.contains("count")) count = meta.at("count").get<int64_t>();
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, path.string(), ": bad META section: ", e.what());
  }
  if (f.image_width <= 0 || f.image_height <= 0 || count < -1 || count > (int64_t{1} << 32))
    throw_error(ErrorCode::kFormat, path.string(), ": bad META section: image size ", f.image_width, "x",
                f.image_height, ", count ", count);
  auto kpts = r.array<Keypoint>("KPTS", count);
  auto desc = r.array<uint8_t>("DESC", count * kDescriptorDim);
  f.keypoints.assign(kpts.begin(), kpts.end());
  f.descriptors = DescriptorMatrix(desc.data(), kpts.size());
  return f;
}

}  // namespace visloc
