// Segment files (.vlseg): one 3D sub-model with compressed descriptors only,
// the unit the localizer maps into memory (DESIGN.md "map/"; Tran et al.
// section III-B). A SectionFile of kind "SEGM", kind version 4, 3 or 2
// (version 1 is still read); every section 64-byte aligned and CRC32C-checked
// (util/section_file.h). Version 3 differs from 2 only in the points'
// coordinates: XYZ16 instead of XYZ (the writer writes version 3 only then,
// so files with float32 coordinates stay readable by version-2 readers).
// Version 4 has 32-byte PQ codes (META "pq": {"subvectors": 32}), with the
// coordinates in XYZ16 when META has xyz_quantization, else in XYZ; the
// writer writes it only for 32-byte codes, so 16-byte maps stay readable by
// version-3 readers, and those reject a 32-byte map by its version:
//
//   META    JSON: segment id, point and image counts, hash/PQ parameters,
//           "hash_rotation": "segment" (ITQ sections present) or "map" (the
//           map's hash_rotation.vlitq), optional enu_from_segment similarity;
//           version 3: "xyz_quantization": {"origin": [3], "step": [3]}
//   XYZ     versions 1-2: N × 3 float32 point positions (segment frame)
//   XYZ16   version 3: N × 3 uint16 q, position = float(origin + step × q)
//           per axis, computed in double (the segment's bounding box in
//           65,536 steps: rounding error ≤ step / 2 per axis)
//   CODE    N × 16 bytes ITQ hash codes (HashCode: 2 × uint64 little-endian)
//   PQ      N × M bytes PQ codes, M = 16 (versions 1-3) or META's pq.subvectors,
//           16 or 32 (version 4); the codebook is the map's: pq_codebook.vlpq
//   ITQMEAN 128 float32 mean subtracted before hashing   } only with a
//   ITQW    128 × 128 float32 projection, row-major       } segment rotation
//   IMAGES  JSON array of the segment's images: name, camera {model, width,
//           height, params}, cam_from_world {q_wxyz, t}
//   PTUNC   optional, any version: N × 4 bytes, each point's triangulation
//           covariance (geometry/point_uncertainty.h); META "point_uncertainty":
//           {"keypoint_noise_px": σ_m}. Readers before it ignore the section.
//
// Bytes per point on disk: XYZ 12 (XYZ16 6) + CODE 16 + PQ 16 = 44 (38), or
// 60 (54) with 32-byte PQ codes, + 4 with PTUNC, plus META and
// IMAGES (and 64.5 KiB of ITQ with a segment rotation). The lookup tables of
// the cascade are a function of the codes: Segment::open builds them in
// memory (CascadeLookup: ~8 × (2 B id + bucket) per point + 96 KiB, and 1 MiB of
// radius-1 neighbourhood sizes).
// Version 1 also stored them (LUTOFF 8 × 65537 uint32, LUTIDS 8 × N uint32)
// and always an ITQ rotation; its tables are ignored and rebuilt.
// Segment::open maps the file and points into it (no copy of the arrays),
// except for XYZ16, decoded into floats the segment owns (12 B per point,
// counted in SegmentBytes::xyz_memory).
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
#include "visloc/geometry/point_uncertainty.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/util/json_fields.h"
#include "visloc/util/section_file.h"

namespace visloc {

inline constexpr uint32_t kSegmentFileVersion = 4;          // newest version read and written (32-byte PQ)
inline constexpr uint32_t kInt16XyzSegmentFileVersion = 3;  // written for 16-byte PQ with int16 coordinates
inline constexpr uint32_t kFloatXyzSegmentFileVersion = 2;  // written for 16-byte PQ with float32 coordinates
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
  std::vector<uint8_t> pq_codes;      // N × pq_subvectors
  int pq_subvectors = kPqSubvectors;  // bytes per PQ code: 16 or 32 (version 4 file)
  std::vector<SegmentImage> images;
  // Empty, or one code per point (section PTUNC) with the keypoint noise it
  // assumed (META point_uncertainty.keypoint_noise_px).
  std::vector<PointUncertaintyCode> point_uncertainty;
  double keypoint_noise_px = 0;
  nlohmann::json extra_meta = nlohmann::json::object();  // merged into META (e.g. enu_from_segment)
  size_t num_points() const { return xyz.size() / 3; }
};

// Point coordinates in 3 × uint16 over the segment's bounding box (META
// "xyz_quantization", section XYZ16).
struct XyzQuantization {
  static constexpr double kMaxLevel = 65535;
  std::array<double, 3> origin{0, 0, 0};  // per axis, the box's minimum
  std::array<double, 3> step{1, 1, 1};    // per axis, > 0
  // The bounding box of N × 3 finite coordinates in 65,535 steps per axis
  // (an axis without extent gets step 1 / 65535: every point decodes exactly).
  static XyzQuantization fit(std::span<const float> xyz);
  // The worst per-axis rounding error, max(step) / 2, in segment units.
  double max_rounding_error() const;
  std::vector<uint16_t> encode(std::span<const float> xyz) const;
  std::vector<float> decode(std::span<const uint16_t> q) const;
  // Steps finite and > 0, every decodable position a finite float; else
  // Error(code) naming `what`.
  void validate(const std::string& what, ErrorCode code) const;
  nlohmann::json to_json() const;
  static XyzQuantization from_json(const JsonField& j);  // and validate(kFormat)
};

enum class PointCoordinates {
  kAuto,     // int16 when the worst rounding error is within max_quantization_error_m, else float32
  kFloat32,  // always float32 (version 2 file)
  kInt16,    // always quantized (version 3 file)
};

struct SegmentWriteOptions {
  PointCoordinates coordinates = PointCoordinates::kAuto;
  // kAuto's bound on the worst per-axis rounding error, in metres (the
  // segment frame's unit times enu_from_segment's scale; a segment without
  // that scale keeps float32). Why 2 mm: a point then moves by at most
  // 3.5 mm (RMS about 1 mm); seen from 3 m with a 1000 px focal that is at
  // most 1.2 px (typically 0.3 px), well inside RANSAC's 4 px threshold and
  // below SIFT's keypoint noise, and it is independent from point to point,
  // so over the hundreds of inliers of a pose it stays far below the
  // localizer's ~1 cm median error. Points triangulated from real photos
  // are rarely known better than a few millimetres anyway.
  double max_quantization_error_m = 0.002;
  // Write the points' uncertainty (section PTUNC, 4 bytes per point) when the
  // segment has it: the reported pose σ then includes the map's own error.
  // Opt-in (map build / import --point-uncertainty): see point_uncertainty.h
  // for what it changes and why it is not the default.
  bool point_uncertainty = false;
  void validate() const;
};

// The coordinates' quantization the writer uses for `segment` under
// `options`, or nullopt for float32. kInt16 with coordinates that cannot be
// quantized (not finite) throws Error(kInvalidArgument).
std::optional<XyzQuantization> choose_xyz_quantization(const SegmentData& segment, const SegmentWriteOptions& options);

void write_segment_file(const std::filesystem::path& path, const SegmentData& segment,
                        const SegmentWriteOptions& options = {});

// Measured sizes of one segment file.
struct SegmentBytes {
  uint64_t file = 0;        // whole file
  uint64_t per_point = 0;   // XYZ + CODE + PQ (+ PTUNC) sections
  uint64_t lookup_tables = 0; // version 1 only: LUTOFF + LUTIDS sections (ignored, rebuilt)
  uint64_t hasher = 0;      // ITQMEAN + ITQW (0 with the map's rotation)
  uint64_t other = 0;       // META, IMAGES, header, table, padding
  uint64_t lookup_memory = 0;  // resident bytes of the lookup tables built at open
  uint64_t xyz_memory = 0;     // resident bytes of coordinates decoded at open (version 3; else 0)
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
  // Present when the file stores quantized coordinates (version 3).
  const std::optional<XyzQuantization>& xyz_quantization() const { return xyz_quantization_; }
  const CascadeIndexView& index() const { return index_; }
  const std::vector<SegmentImage>& images() const { return images_; }
  // One code per point (section PTUNC), empty when the file has none.
  std::span<const PointUncertaintyCode> point_uncertainty() const { return point_uncertainty_; }
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
  std::span<const float> xyz_;      // into the file, or into decoded_xyz_
  std::vector<float> decoded_xyz_;  // version 3: XYZ16 decoded
  std::optional<XyzQuantization> xyz_quantization_;
  CascadeIndexView index_;
  CascadeLookup lookup_;
  std::shared_ptr<const BinaryHasher> map_hasher_;
  std::vector<SegmentImage> images_;
  std::span<const PointUncertaintyCode> point_uncertainty_;
  nlohmann::json meta_;
  std::optional<Similarity3d> enu_from_segment_;
  SegmentBytes bytes_;
};

}  // namespace visloc
