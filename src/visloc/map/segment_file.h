// Segment files (.vlseg): one 3D sub-model with compressed descriptors only,
// the unit the localizer maps into memory (DESIGN.md "map/"; Tran et al.
// section III-B). A SectionFile of kind "SEGM", kind version 2 (version 1 is
// still read); every section 64-byte aligned and CRC32C-checked
// (util/section_file.h):
//
//   META    JSON: segment id, point and image counts, hash/PQ parameters,
//           "hash_rotation": "segment" (ITQ sections present) or "map" (the
//           map's hash_rotation.vlitq), optional enu_from_segment similarity
//   XYZ     N × 3 float32 point positions (segment frame)
//   CODE    N × 16 bytes ITQ hash codes (HashCode: 2 × uint64 little-endian)
//   PQ      N × 16 bytes PQ codes (codebook shared by the map: pq_codebook.vlpq)
//   ITQMEAN 128 float32 mean subtracted before hashing   } only with a
//   ITQW    128 × 128 float32 projection, row-major       } segment rotation
//   IMAGES  JSON array of the segment's images: name, camera {model, width,
//           height, params}, cam_from_world {q_wxyz, t}
//
// Bytes per point on disk: XYZ 12 + CODE 16 + PQ 16 = 44, plus META and
// IMAGES (and 64.5 KiB of ITQ with a segment rotation). The lookup tables of
// the cascade are a function of the codes: Segment::open builds them in
// memory (CascadeLookup: ~8 × (2 B id + bucket) per point + 96 KiB).
// Version 1 also stored them (LUTOFF 8 × 65537 uint32, LUTIDS 8 × N uint32)
// and always an ITQ rotation; its tables are ignored and rebuilt.
// Segment::open maps the file and points into it (no copy of the arrays).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <vector>

#include "visloc/geo/similarity_transform.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/util/json_fields.h"
#include "visloc/util/section_file.h"

namespace visloc {

inline constexpr uint32_t kSegmentFileVersion = 2;
inline constexpr uint32_t kOldestSegmentFileVersion = 1;

struct SegmentImage {
  std::string name;
  int camera_model_id = 1;  // COLMAP model id
  uint64_t width = 0, height = 0;
  std::vector<double> camera_params;
  std::array<double, 4> cam_from_world_q_wxyz{1, 0, 0, 0};
  std::array<double, 3> cam_from_world_t{0, 0, 0};
};
nlohmann::json to_json(const SegmentImage& image);
// Reads and checks an image record: a valid COLMAP camera (model, parameter
// count, finite, focal > 0, principal point inside the image) and a pose with
// a unit quaternion and a finite translation. Error(kFormat) names the field.
SegmentImage segment_image_from_json(const JsonField& j);
SegmentImage segment_image_from_json(const nlohmann::json& j);
// A similarity stored as {"scale", "rotation_row_major", "translation"}:
// scale > 0, an orthonormal rotation with determinant +1, finite values.
std::optional<Similarity3d> similarity_from_json(const JsonField& j);

// Everything a segment file holds, owned (the writer's input).
struct SegmentData {
  uint32_t segment_id = 0;
  std::vector<float> xyz;  // N × 3
  BinaryHasher hasher;            // empty: the codes use the map's hash rotation
  std::vector<HashCode> codes;
  std::vector<uint8_t> pq_codes;  // N × 16
  std::vector<SegmentImage> images;
  nlohmann::json extra_meta = nlohmann::json::object();  // merged into META (e.g. enu_from_segment)
  size_t num_points() const { return xyz.size() / 3; }
};

void write_segment_file(const std::filesystem::path& path, const SegmentData& segment);

// Measured sizes of one segment file.
struct SegmentBytes {
  uint64_t file = 0;        // whole file
  uint64_t per_point = 0;   // XYZ + CODE + PQ sections
  uint64_t lookup_tables = 0; // version 1 only: LUTOFF + LUTIDS sections (ignored, rebuilt)
  uint64_t hasher = 0;      // ITQMEAN + ITQW (0 with the map's rotation)
  uint64_t other = 0;       // META, IMAGES, header, table, padding
  uint64_t lookup_memory = 0;  // resident bytes of the lookup tables built at open
  double per_point_bytes_per_point(size_t n) const { return n ? double(per_point) / double(n) : 0; }
  double file_bytes_per_point(size_t n) const { return n ? double(file) / double(n) : 0; }
};

// A read-only segment mapped from its file. Opening verifies the container
// (magic, kind, version, size, every CRC) and the index structure, and
// rejects a file with a clear message naming it.
class Segment {
 public:
  // `map_hasher`: the map's hash rotation, required when the segment has none.
  static std::unique_ptr<Segment> open(const std::filesystem::path& path,
                                       std::shared_ptr<const BinaryHasher> map_hasher = nullptr);
  uint32_t format_version() const { return reader_.kind_version(); }
  // index() points into the segment itself (its lookup tables): not copyable or movable.
  Segment(const Segment&) = delete;
  Segment& operator=(const Segment&) = delete;
  bool uses_map_hasher() const { return map_hasher_ != nullptr; }

  uint32_t id() const { return id_; }
  size_t num_points() const { return num_points_; }
  std::span<const float> xyz() const { return xyz_; }
  const CascadeIndexView& index() const { return index_; }
  const std::vector<SegmentImage>& images() const { return images_; }
  const nlohmann::json& meta() const { return meta_; }
  // META's enu_from_segment (checked at open), absent when not georegistered.
  const std::optional<Similarity3d>& enu_from_segment() const { return enu_from_segment_; }
  const SegmentBytes& bytes() const { return bytes_; }
  const std::filesystem::path& path() const { return reader_.path(); }

 private:
  explicit Segment(const std::filesystem::path& path);
  SectionFileReader reader_;
  uint32_t id_ = 0;
  size_t num_points_ = 0;
  std::span<const float> xyz_;
  CascadeIndexView index_;
  CascadeLookup lookup_;
  std::shared_ptr<const BinaryHasher> map_hasher_;
  std::vector<SegmentImage> images_;
  nlohmann::json meta_;
  std::optional<Similarity3d> enu_from_segment_;
  SegmentBytes bytes_;
};

}  // namespace visloc
