#include "visloc/map/segment_file.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "visloc/colmap/colmap_model.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/util/error.h"
#include "visloc/util/json_fields.h"

namespace visloc {

nlohmann::json to_json(const SegmentImage& im) {
  return {{"name", im.name},
          {"camera",
           {{"model_id", im.camera_model_id}, {"width", im.width}, {"height", im.height}, {"params", im.camera_params}}},
          {"cam_from_world", {{"q_wxyz", im.cam_from_world_q_wxyz}, {"t", im.cam_from_world_t}}}};
}

SegmentImage segment_image_from_json(const nlohmann::json& j) {
  return segment_image_from_json(JsonField(j, "segment image"));
}

SegmentImage segment_image_from_json(const JsonField& j) {
  SegmentImage im;
  im.name = j.at("name").string();
  if (im.name.empty()) j.at("name").fail("is empty");
  const JsonField c = j.at("camera");
  im.camera_model_id = static_cast<int>(c.at("model_id").integer(0, 100));
  im.width = c.at("width").unsigned_integer(kColmapMaxImageSide);
  im.height = c.at("height").unsigned_integer(kColmapMaxImageSide);
  im.camera_params = c.at("params").numbers();
  ColmapCamera cam;
  cam.model_id = im.camera_model_id, cam.width = im.width, cam.height = im.height, cam.params = im.camera_params;
  try {
    validate_colmap_camera(cam, j.file());
  } catch (const Error& e) {
    c.fail("is not a valid camera (", e.what(), ")");
  }
  const JsonField pose = j.at("cam_from_world");
  const auto q = pose.at("q_wxyz").numbers(4);
  const auto t = pose.at("t").numbers(3);
  const double qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (!(std::abs(qn - 1.0) <= 1e-3)) pose.at("q_wxyz").fail("must be a unit quaternion, its norm is ", qn);
  std::copy(q.begin(), q.end(), im.cam_from_world_q_wxyz.begin());
  std::copy(t.begin(), t.end(), im.cam_from_world_t.begin());
  return im;
}

std::optional<Similarity3d> similarity_from_json(const JsonField& j) {
  Similarity3d s;
  s.scale = j.at("scale").number();
  if (!(s.scale > 1e-9 && s.scale < 1e9)) j.at("scale").fail("must be a positive scale, found ", s.scale);
  const auto r = j.at("rotation_row_major").numbers(9);
  const auto t = j.at("translation").numbers(3);
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) s.rotation(i, k) = r[3 * i + k];
  const double off = (s.rotation.transpose() * s.rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (!(off <= 1e-6) || !(s.rotation.determinant() > 0))
    j.at("rotation_row_major").fail("must be a rotation (orthonormal, determinant +1); |RᵀR − I| is ", off,
                                    ", det ", s.rotation.determinant());
  s.translation = {t[0], t[1], t[2]};
  return s;
}

XyzQuantization XyzQuantization::fit(std::span<const float> xyz) {
  XyzQuantization q;
  for (int axis = 0; axis < 3; ++axis) {
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (size_t i = axis; i < xyz.size(); i += 3) lo = std::min(lo, double(xyz[i])), hi = std::max(hi, double(xyz[i]));
    if (!(lo <= hi)) lo = hi = 0;  // no points
    q.origin[axis] = lo;
    q.step[axis] = (hi > lo ? hi - lo : 1.0) / kMaxLevel;
  }
  return q;
}

double XyzQuantization::max_rounding_error() const { return 0.5 * std::max({step[0], step[1], step[2]}); }

std::vector<uint16_t> XyzQuantization::encode(std::span<const float> xyz) const {
  std::vector<uint16_t> q(xyz.size());
  for (size_t i = 0; i < xyz.size(); ++i) {
    const double level = std::round((double(xyz[i]) - origin[i % 3]) / step[i % 3]);
    q[i] = static_cast<uint16_t>(std::clamp(level, 0.0, kMaxLevel));
  }
  return q;
}

std::vector<float> XyzQuantization::decode(std::span<const uint16_t> q) const {
  std::vector<float> xyz(q.size());
  for (size_t i = 0; i < q.size(); ++i) xyz[i] = static_cast<float>(origin[i % 3] + step[i % 3] * double(q[i]));
  return xyz;
}

void XyzQuantization::validate(const std::string& what, ErrorCode code) const {
  const double float_max = std::numeric_limits<float>::max();
  for (int axis = 0; axis < 3; ++axis) {
    if (!std::isfinite(origin[axis]) || !(std::isfinite(step[axis]) && step[axis] > 0))
      throw_error(code, what, ": xyz_quantization axis ", axis, " has origin ", origin[axis], " and step ", step[axis],
                  " (finite values and a step > 0 expected)");
    // Decoding is monotonic in q: both ends within float's range bound every position.
    const double end = origin[axis] + step[axis] * kMaxLevel;
    if (!(std::abs(origin[axis]) <= float_max && std::abs(end) <= float_max))
      throw_error(code, what, ": xyz_quantization axis ", axis, " decodes to [", origin[axis], ", ", end,
                  "], outside float32's range");
  }
}

nlohmann::json XyzQuantization::to_json() const { return {{"origin", origin}, {"step", step}}; }

XyzQuantization XyzQuantization::from_json(const JsonField& j) {
  XyzQuantization q;
  const auto origin = j.at("origin").numbers(3);
  const auto step = j.at("step").numbers(3);
  std::copy(origin.begin(), origin.end(), q.origin.begin());
  std::copy(step.begin(), step.end(), q.step.begin());
  q.validate(j.file(), ErrorCode::kFormat);
  return q;
}

void SegmentWriteOptions::validate() const {
  if (!(std::isfinite(max_quantization_error_m) && max_quantization_error_m > 0))
    throw_error(ErrorCode::kInvalidArgument,
                "SegmentWriteOptions.max_quantization_error_m must be a positive number "
                "of metres, found ",
                max_quantization_error_m);
}

namespace {

// enu_from_segment's scale (metres per segment unit) when extra_meta holds a
// usable one; the reader validates the similarity itself.
std::optional<double> metres_per_segment_unit(const nlohmann::json& extra_meta) {
  if (!extra_meta.is_object() || !extra_meta.contains("enu_from_segment")) return std::nullopt;
  const nlohmann::json& e = extra_meta["enu_from_segment"];
  if (!e.is_object() || !e.contains("scale") || !e["scale"].is_number()) return std::nullopt;
  const double scale = e["scale"].get<double>();
  if (!(std::isfinite(scale) && scale > 0)) return std::nullopt;
  return scale;
}

}  // namespace

std::optional<XyzQuantization> choose_xyz_quantization(const SegmentData& s, const SegmentWriteOptions& options) {
  options.validate();
  if (options.coordinates == PointCoordinates::kFloat32) return std::nullopt;
  const bool finite = std::all_of(s.xyz.begin(), s.xyz.end(), [](float v) { return std::isfinite(v); });
  if (!finite) {
    // Float32 keeps the bad value for the reader to reject; quantizing would hide it.
    if (options.coordinates == PointCoordinates::kAuto) return std::nullopt;
    throw_error(ErrorCode::kInvalidArgument, "segment ", s.segment_id,
                ": int16 point coordinates need finite coordinates");
  }
  const XyzQuantization q = XyzQuantization::fit(s.xyz);
  q.validate("segment " + std::to_string(s.segment_id), ErrorCode::kInvalidArgument);
  if (options.coordinates == PointCoordinates::kInt16) return q;
  const std::optional<double> scale = metres_per_segment_unit(s.extra_meta);
  if (!scale || !(*scale * q.max_rounding_error() <= options.max_quantization_error_m)) return std::nullopt;
  return q;
}

void write_segment_file(const std::filesystem::path& path, const SegmentData& s, const SegmentWriteOptions& options) {
  const size_t n = s.num_points();
  VISLOC_CHECK(s.xyz.size() == 3 * n);
  VISLOC_CHECK(s.codes.size() == n, "codes");
  if (!valid_pq_subvectors(s.pq_subvectors))
    throw_error(ErrorCode::kInvalidArgument, "segment ", s.segment_id, ": PQ codes of ", s.pq_subvectors,
                " bytes (16 or 32)");
  VISLOC_CHECK(s.pq_codes.size() == n * size_t(s.pq_subvectors), "pq codes");
  VISLOC_CHECK(s.point_uncertainty.empty() || s.point_uncertainty.size() == n, "one point uncertainty per point");
  const bool own_hasher = !s.hasher.mean.empty();
  if (own_hasher)
    VISLOC_CHECK(s.hasher.mean.size() == kDescriptorDim && s.hasher.projection.size() == kHashBits * kDescriptorDim);
  nlohmann::json meta = s.extra_meta;
  meta["segment_id"] = s.segment_id;
  meta["points"] = n;
  meta["images"] = s.images.size();
  meta["hash"] = {{"bits", kHashBits}, {"tables", kHashTables}, {"table_bits", kHashTableBits}, {"method", "itq"}};
  meta["hash_rotation"] = own_hasher ? "segment" : "map";
  meta["pq"] = {{"subvectors", s.pq_subvectors}, {"bits", 8}};
  meta.erase("point_uncertainty");
  const bool with_uncertainty = options.point_uncertainty && !s.point_uncertainty.empty();
  if (with_uncertainty) meta["point_uncertainty"] = {{"keypoint_noise_px", s.keypoint_noise_px}};
  const std::optional<XyzQuantization> quantization = choose_xyz_quantization(s, options);
  meta.erase("xyz_quantization");
  if (quantization) meta["xyz_quantization"] = quantization->to_json();
  nlohmann::json images = nlohmann::json::array();
  for (const auto& im : s.images) images.push_back(to_json(im));
  const uint32_t version = s.pq_subvectors != kPqSubvectors ? kSegmentFileVersion
                           : quantization                   ? kInt16XyzSegmentFileVersion
                                                            : kFloatXyzSegmentFileVersion;
  SectionFileWriter w(path, "SEGM", version);
  w.add_text("META", meta.dump());
  if (quantization)
    w.add_array<uint16_t>("XYZ16", quantization->encode(s.xyz));
  else
    w.add_array<float>("XYZ", s.xyz);
  w.add_array<HashCode>("CODE", s.codes);
  w.add_array<uint8_t>("PQ", s.pq_codes);
  if (with_uncertainty) w.add_array<PointUncertaintyCode>("PTUNC", s.point_uncertainty);
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
  {
    s->meta_ = parse_json(r.text("META"), name, "section META");
    const JsonField meta(s->meta_, name + " (META)");
    if (!s->meta_.is_object()) meta.fail("must be a JSON object");
    s->id_ = static_cast<uint32_t>(meta.at("segment_id").unsigned_integer(std::numeric_limits<uint32_t>::max()));
    s->num_points_ = meta.at("points").unsigned_integer(CascadeLookup::kMaxPoints);
    const uint64_t image_count = meta.has("images") ? meta.at("images").unsigned_integer() : 0;
    const nlohmann::json images = parse_json(r.text("IMAGES"), name, "section IMAGES");
    const JsonField list(images, name + " (IMAGES)");
    for (size_t i = 0; i < list.size(); ++i) s->images_.push_back(segment_image_from_json(list.at(i)));
    if (meta.has("images") && image_count != s->images_.size())
      meta.at("images").fail("says ", image_count, " images, section IMAGES holds ", s->images_.size());
    scope = meta.string_or("hash_rotation", "segment");
    if (scope != "segment" && scope != "map") meta.at("hash_rotation").fail("must be \"segment\" or \"map\", found \"", scope, "\"");
    has_crc = meta.has("hash_rotation_crc32c");
    if (has_crc)
      expected_crc = static_cast<uint32_t>(meta.at("hash_rotation_crc32c").unsigned_integer(std::numeric_limits<uint32_t>::max()));
    if (meta.has("enu_from_segment")) s->enu_from_segment_ = similarity_from_json(meta.at("enu_from_segment"));
    if (r.kind_version() < 4 && meta.has("xyz_quantization") != (r.kind_version() >= 3))
      throw_error(ErrorCode::kFormat, name, ": META ", r.kind_version() >= 3 ? "lacks" : "has",
                  " xyz_quantization in a version ", r.kind_version(), " segment file");
    if (r.kind_version() >= 4) {
      const int64_t m = meta.at("pq").at("subvectors").integer(kPqSubvectors, kPqFineSubvectors);
      if (!valid_pq_subvectors(int(m)))
        meta.at("pq").at("subvectors").fail("must be 16 or 32 (bytes per PQ code), found ", m);
      s->index_.pq_subvectors = int(m);
    }
    if (meta.has("xyz_quantization")) s->xyz_quantization_ = XyzQuantization::from_json(meta.at("xyz_quantization"));
  }
  if (s->num_points_ > CascadeLookup::kMaxPoints)
    throw_error(ErrorCode::kFormat, name, ": ", s->num_points_, " points, at most ", CascadeLookup::kMaxPoints);
  const int64_t n = static_cast<int64_t>(s->num_points_);
  const char* const xyz_tag = s->xyz_quantization_ ? "XYZ16" : "XYZ";
  const char* const other_xyz_tag = s->xyz_quantization_ ? "XYZ" : "XYZ16";
  if (r.has(other_xyz_tag))
    throw_error(ErrorCode::kFormat, name, ": a version ", r.kind_version(), " segment file has no section '",
                other_xyz_tag, "' (its coordinates are in '", xyz_tag, "')");
  if (s->xyz_quantization_) {
    s->decoded_xyz_ = s->xyz_quantization_->decode(r.array<uint16_t>("XYZ16", 3 * n));
    s->xyz_ = s->decoded_xyz_;
  } else {
    s->xyz_ = r.array<float>("XYZ", 3 * n);
  }
  for (size_t i = 0; i < s->xyz_.size(); ++i)
    if (!std::isfinite(s->xyz_[i]))
      throw_error(ErrorCode::kFormat, name, ": section '", xyz_tag, "': point ", i / 3, " has a non-finite coordinate");
  CascadeIndexView& v = s->index_;
  v.num_points = s->num_points_;
  auto codes = r.array<HashCode>("CODE", n);
  v.codes = codes.data();
  v.pq_codes = r.array<uint8_t>("PQ", n * v.pq_subvectors).data();
  SegmentBytes& b = s->bytes_;
  if (r.has("PTUNC")) s->point_uncertainty_ = r.array<PointUncertaintyCode>("PTUNC", n);
  const bool own_rotation = r.has("ITQMEAN") || r.has("ITQW");
  if (own_rotation != (scope == "segment"))
    throw_error(ErrorCode::kFormat, name, ": META says hash_rotation '", scope, "' but the file ",
                own_rotation ? "has" : "has no", " ITQ sections");
  if (own_rotation) {
    v.hasher.mean = r.array<float>("ITQMEAN", kDescriptorDim).data();
    v.hasher.projection = r.array<float>("ITQW", kHashBits * kDescriptorDim).data();
    b.hasher = r.bytes("ITQMEAN").size() + r.bytes("ITQW").size();
    check_hash_rotation(v.hasher, name);
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
  b.per_point = r.bytes(xyz_tag).size() + r.bytes("CODE").size() + r.bytes("PQ").size() +
                (r.has("PTUNC") ? r.bytes("PTUNC").size() : 0);
  b.xyz_memory = s->decoded_xyz_.capacity() * sizeof(float);
  for (const char* t : {"LUTOFF", "LUTIDS"})
    if (r.has(t)) b.lookup_tables += r.bytes(t).size();
  b.other = b.file - b.per_point - b.lookup_tables - b.hasher;
  b.lookup_memory = s->lookup_.memory_bytes();
  return s;
}

}  // namespace visloc
