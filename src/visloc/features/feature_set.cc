#include "visloc/features/feature_set.h"

#include <limits>

#include <nlohmann/json.hpp>

#include "visloc/util/error.h"
#include "visloc/util/json_fields.h"
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
    // Integers only, range-checked (json_fields.h): a 1e73 is refused, not converted.
    const JsonField m(meta, path.string(), "META");
    f.image = meta.at("image").get<std::string>();
    f.image_width = static_cast<int>(m.at("width").integer(1, std::numeric_limits<int>::max()));
    f.image_height = static_cast<int>(m.at("height").integer(1, std::numeric_limits<int>::max()));
    if (!meta.at("extractor").is_null()) f.extractor = meta.at("extractor").dump();
    if (meta.contains("count")) count = m.at("count").integer(0, int64_t{1} << 32);
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, path.string(), ": bad META section: ", e.what());
  }
  if (f.image_width <= 0 || f.image_height <= 0 || count < -1 || count > (int64_t{1} << 32))
    throw_error(ErrorCode::kFormat, path.string(), ": bad META section: image size ", f.image_width, "x",
                f.image_height, ", count ", count);
  auto kpts = r.array<Keypoint>("KPTS", count);
  auto desc = r.array<uint8_t>("DESC", count < 0 ? -1 : count * kDescriptorDim);
  // Without a count in META, the sections must still agree (found by fuzzing:
  // a short DESC was read past its end).
  if (desc.size() != kpts.size() * static_cast<size_t>(kDescriptorDim))
    throw_error(ErrorCode::kFormat, path.string(), ": DESC holds ", desc.size(), " bytes for ", kpts.size(),
                " keypoints (", kDescriptorDim, " bytes each)");
  f.keypoints.assign(kpts.begin(), kpts.end());
  f.descriptors = DescriptorMatrix(desc.data(), kpts.size());
  return f;
}

}  // namespace visloc
