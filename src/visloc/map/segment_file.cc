#include "visloc/map/segment_file.h"

#include "visloc/matching/pq_codebook.h"
#include "visloc/util/error.h"

namespace visloc {

nlohmann::json to_json(const SegmentImage& im) {
  return {{"name", im.name},
          {"camera",
           {{"model_id", im.camera_model_id}, {"width", im.width}, {"height", im.height}, {"params", im.camera_params}}},
          {"cam_from_world", {{"q_wxyz", im.cam_from_world_q_wxyz}, {"t", im.cam_from_world_t}}}};
}

SegmentImage segment_image_from_json(const nlohmann::json& j) {
  SegmentImage im;
  im.name = j.at("name").get<std::string>();
  const auto& c = j.at("camera");
  im.camera_model_id = c.at("model_id").get<int>();
  im.width = c.at("width").get<uint64_t>();
  im.height = c.at("height").get<uint64_t>();
  im.camera_params = c.at("params").get<std::vector<double>>();
  im.cam_from_world_q_wxyz = j.at("cam_from_world").at("q_wxyz").get<std::array<double, 4>>();
  im.cam_from_world_t = j.at("cam_from_world").at("t").get<std::array<double, 3>>();
  return im;
}

void write_segment_file(const std::filesystem::path& path, const SegmentData& s) {
  const size_t n = s.num_points();
  VISLOC_CHECK(s.xyz.size() == 3 * n);
  VISLOC_CHECK(s.codes.size() == n, "codes");
  VISLOC_CHECK(s.pq_codes.size() == n * kPqCodeBytes, "pq codes");
  VISLOC_CHECK(s.tables.offsets.size() == kHashTables * kLutOffsetsPerTable, "lut offsets");
  VISLOC_CHECK(s.tables.ids.size() == kHashTables * n, "lut ids");
  VISLOC_CHECK(s.hasher.mean.size() == kDescriptorDim && s.hasher.projection.size() == kHashBits * kDescriptorDim);
  nlohmann::json meta = s.extra_meta;
  meta["segment_id"] = s.segment_id;
  meta["points"] = n;
  meta["images"] = s.images.size();
  meta["hash"] = {{"bits", kHashBits}, {"tables", kHashTables}, {"table_bits", kHashTableBits}, {"method", "itq"}};
  meta["pq"] = {{"subvectors", kPqSubvectors}, {"bits", 8}};
  nlohmann::json images = nlohmann::json::array();
  for (const auto& im : s.images) images.push_back(to_json(im));
  SectionFileWriter w(path, "SEGM", kSegmentFileVersion);
  w.add_text("META", meta.dump());
  w.add_array<float>("XYZ", s.xyz);
  w.add_array<HashCode>("CODE", s.codes);
  w.add_array<uint8_t>("PQ", s.pq_codes);
  w.add_array<float>("ITQMEAN", s.hasher.mean);
  w.add_array<float>("ITQW", s.hasher.projection);
  w.add_array<uint32_t>("LUTOFF", s.tables.offsets);
  w.add_array<uint32_t>("LUTIDS", s.tables.ids);
  w.add_text("IMAGES", images.dump());
  w.commit();
}

Segment::Segment(const std::filesystem::path& path)
    : reader_(path, "SEGM", kSegmentFileVersion, kSegmentFileVersion) {}

std::unique_ptr<Segment> Segment::open(const std::filesystem::path& path) {
  std::unique_ptr<Segment> s(new Segment(path));
  const SectionFileReader& r = s->reader_;
  const std::string name = path.string();
  try {
    s->meta_ = nlohmann::json::parse(r.text("META"));
    s->id_ = s->meta_.at("segment_id").get<uint32_t>();
    s->num_points_ = s->meta_.at("points").get<size_t>();
    for (const auto& j : nlohmann::json::parse(r.text("IMAGES"))) s->images_.push_back(segment_image_from_json(j));
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, name, ": bad segment metadata: ", e.what());
  }
  const int64_t n = static_cast<int64_t>(s->num_points_);
  s->xyz_ = r.array<float>("XYZ", 3 * n);
  CascadeIndexView& v = s->index_;
  v.num_points = s->num_points_;
  v.codes = r.array<HashCode>("CODE", n).data();
  v.pq_codes = r.array<uint8_t>("PQ", n * kPqCodeBytes).data();
  v.hasher.mean = r.array<float>("ITQMEAN", kDescriptorDim).data();
  v.hasher.projection = r.array<float>("ITQW", kHashBits * kDescriptorDim).data();
  v.lut_offsets = r.array<uint32_t>("LUTOFF", int64_t(kHashTables) * int64_t(kLutOffsetsPerTable)).data();
  v.lut_ids = r.array<uint32_t>("LUTIDS", int64_t(kHashTables) * n).data();
  v.validate(name);
  SegmentBytes& b = s->bytes_;
  b.file = r.file_size();
  for (const char* t : {"XYZ", "CODE", "PQ", "LUTIDS"}) b.per_point += r.bytes(t).size();
  b.lut_offsets = r.bytes("LUTOFF").size();
  b.hasher = r.bytes("ITQMEAN").size() + r.bytes("ITQW").size();
  b.other = b.file - b.per_point - b.lut_offsets - b.hasher;
  return s;
}

}  // namespace visloc
