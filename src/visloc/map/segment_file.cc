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
  const bool own_hasher = !s.hasher.mean.empty();
  if (own_hasher)
    VISLOC_CHECK(s.hasher.mean.size() == kDescriptorDim && s.hasher.projection.size() == kHashBits * kDescriptorDim);
  nlohmann::json meta = s.extra_meta;
  meta["segment_id"] = s.segment_id;
  meta["points"] = n;
  meta["images"] = s.images.size();
  meta["hash"] = {{"bits", kHashBits}, {"tables", kHashTables}, {"table_bits", kHashTableBits}, {"method", "itq"}};
  meta["hash_rotation"] = own_hasher ? "segment" : "map";
  meta["pq"] = {{"subvectors", kPqSubvectors}, {"bits", 8}};
  nlohmann::json images = nlohmann::json::array();
  for (const auto& im : s.images) images.push_back(to_json(im));
  SectionFileWriter w(path, "SEGM", kSegmentFileVersion);
  w.add_text("META", meta.dump());
  w.add_array<float>("XYZ", s.xyz);
  w.add_array<HashCode>("CODE", s.codes);
  w.add_array<uint8_t>("PQ", s.pq_codes);
  if (own_hasher) {
    w.add_array<float>("ITQMEAN", s.hasher.mean);
    w.add_array<float>("ITQW", s.hasher.projection);
  }
  w.add_text("IMAGES", images.dump());
  w.commit();
}

Segment::Segment(const std::filesystem::path& path)
    : reader_(path, "SEGM", kOldestSegmentFileVersion, kSegmentFileVersion) {}

std::unique_ptr<Segment> Segment::open(const std::filesystem::path& path,
                                       std::shared_ptr<const BinaryHasher> map_hasher) {
  std::unique_ptr<Segment> s(new Segment(path));
  const SectionFileReader& r = s->reader_;
  const std::string name = path.string();
  std::string scope;
  bool has_crc = false;
  uint32_t expected_crc = 0;
  try {
    s->meta_ = nlohmann::json::parse(r.text("META"));
    s->id_ = s->meta_.at("segment_id").get<uint32_t>();
    s->num_points_ = s->meta_.at("points").get<size_t>();
    for (const auto& j : nlohmann::json::parse(r.text("IMAGES"))) s->images_.push_back(segment_image_from_json(j));
    scope = s->meta_.value("hash_rotation", "segment");
    has_crc = s->meta_.contains("hash_rotation_crc32c");
    if (has_crc) expected_crc = s->meta_.at("hash_rotation_crc32c").get<uint32_t>();
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, name, ": bad segment metadata: ", e.what());
  }
  if (s->num_points_ > CascadeLookup::kMaxPoints)
    throw_error(ErrorCode::kFormat, name, ": ", s->num_points_, " points, at most ", CascadeLookup::kMaxPoints);
  const int64_t n = static_cast<int64_t>(s->num_points_);
  s->xyz_ = r.array<float>("XYZ", 3 * n);
  CascadeIndexView& v = s->index_;
  v.num_points = s->num_points_;
  auto codes = r.array<HashCode>("CODE", n);
  v.codes = codes.data();
  v.pq_codes = r.array<uint8_t>("PQ", n * kPqCodeBytes).data();
  SegmentBytes& b = s->bytes_;
  const bool own_rotation = r.has("ITQMEAN") || r.has("ITQW");
  if (own_rotation != (scope == "segment"))
    throw_error(ErrorCode::kFormat, name, ": META says hash_rotation '", scope, "' but the file ",
                own_rotation ? "has" : "has no", " ITQ sections");
  if (own_rotation) {
    v.hasher.mean = r.array<float>("ITQMEAN", kDescriptorDim).data();
    v.hasher.projection = r.array<float>("ITQW", kHashBits * kDescriptorDim).data();
    b.hasher = r.bytes("ITQMEAN").size() + r.bytes("ITQW").size();
  } else {
    if (!map_hasher)
      throw_error(ErrorCode::kFormat, name,
                  ": the segment's codes use its map's hash rotation (MAP/hash_rotation.vlitq), and none was given "
                  "(is hash_rotation_file missing from the map's manifest.json?)");
    const uint32_t given = hash_rotation_fingerprint(*map_hasher);
    if (has_crc && expected_crc != given)
      throw_error(ErrorCode::kFormat, name, ": the segment's codes were made with another hash rotation (CRC32C ",
                  expected_crc, ") than its map's (", given, "); rebuild the segment");
    s->map_hasher_ = std::move(map_hasher);
    v.hasher = s->map_hasher_->view();
  }
  s->lookup_ = CascadeLookup(codes);
  v.lookup = &s->lookup_;
  v.validate(name);
  b.file = r.file_size();
  for (const char* t : {"XYZ", "CODE", "PQ"}) b.per_point += r.bytes(t).size();
  for (const char* t : {"LUTOFF", "LUTIDS"})
    if (r.has(t)) b.lookup_tables += r.bytes(t).size();
  b.other = b.file - b.per_point - b.lookup_tables - b.hasher;
  b.lookup_memory = s->lookup_.memory_bytes();
  return s;
}

}  // namespace visloc
