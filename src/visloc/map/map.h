// A map directory (DESIGN.md "map/"):
//   MAP/manifest.json          format version, ENU origin if known, parameters,
//                              segments (file, counts, bytes, CRC32C of the file),
//                              PQ codebook, source, held-out images
//   MAP/segments/NNNN.vlseg    segment files (segment_file.h)
//   MAP/pq_codebook.vlpq       the PQ codebook shared by every segment
//   MAP/hash_rotation.vlitq    the ITQ hash rotation shared by the segments
//                              that have none of their own (optional)
//   MAP/descriptors/NNNN.vldesc  mean SIFT per point (uint8), kind "PDSC":
//                              not used on the device; kept for rebuilding
//                              segments and for the raw-SIFT baselines
//   MAP/holdout.txt            held-out images' reference poses
//                              (name qw qx qy qz tx ty tz, world-to-camera)
// Every file is written atomically; manifest.json last.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/pq_codebook.h"

namespace visloc {

inline constexpr int kMapFormatVersion = 1;
inline constexpr uint32_t kPointDescriptorFileVersion = 1;

struct MapSegmentEntry {
  uint32_t id = 0;
  std::string file;              // relative to the map directory
  std::string descriptors_file;  // relative; empty when not kept
  size_t points = 0;
  size_t images = 0;
  uint64_t file_bytes = 0;
  uint32_t file_crc32c = 0;
};

// The cascade search's hash-code blend weight fitted on the map's own data
// (CascadeSearchOptions::hash_blend_weight; `visloc map fit-blend --store`,
// or map build / map import --fit-blend), with the segment files it was
// fitted on: a weight whose segments have since changed is not used.
struct MapHashBlend {
  double weight = 0;                              // in [0, 1]
  std::vector<uint32_t> segment_crc32c;           // the segments' file_crc32c at the fit, in manifest order
  nlohmann::json fit = nlohmann::json::object();  // what the fit saw (views, matches, grid), as reported
};

struct MapManifest {
  int format_version = kMapFormatVersion;
  std::optional<std::array<double, 3>> enu_origin_lat_lon_alt;
  nlohmann::json parameters = nlohmann::json::object();
  std::string pq_codebook_file = "pq_codebook.vlpq";
  std::string hash_rotation_file;  // relative; empty: every segment has its own
  std::vector<MapSegmentEntry> segments;
  nlohmann::json source = nlohmann::json::object();   // e.g. {"colmap": ..., "database": ...}
  std::vector<std::string> holdout_images;
  std::string holdout_file;                            // relative; empty when none
  std::optional<MapHashBlend> hash_blend;              // "hash_blend"; absent when never fitted

  // The stored blend weight when it was fitted on these segments (the same
  // files, by their checksums, in the same order); nullopt otherwise.
  std::optional<double> fitted_hash_blend() const;
  nlohmann::json to_json() const;
  static MapManifest from_json(const nlohmann::json& j, const std::string& what);
};

void write_manifest(const std::filesystem::path& map_dir, const MapManifest& manifest);
// Throws Error naming the file for a missing, unparsable or newer-version manifest.
MapManifest read_manifest(const std::filesystem::path& map_dir);

// Mean descriptors of a segment's points (uint8, N × 128) and track sizes.
void write_point_descriptor_file(const std::filesystem::path& path, const DescriptorMatrix& descriptors,
                                 const std::vector<uint32_t>& track_size);
DescriptorMatrix read_point_descriptor_file(const std::filesystem::path& path);

// An opened map: manifest, shared codebook, segments mapped on demand.
class Map {
 public:
  static Map open(const std::filesystem::path& dir);
  const MapManifest& manifest() const { return manifest_; }
  const PqCodebook& codebook() const { return codebook_; }
  // The map's hash rotation, or null when every segment has its own.
  const std::shared_ptr<const BinaryHasher>& hasher() const { return hasher_; }
  const std::filesystem::path& dir() const { return dir_; }
  // Maps segment `index` (position in manifest().segments) and checks that
  // its size matches the manifest.
  std::unique_ptr<Segment> open_segment(size_t index) const;

 private:
  std::filesystem::path dir_;
  MapManifest manifest_;
  PqCodebook codebook_;
  std::shared_ptr<const BinaryHasher> hasher_;
};

// What `visloc map info` prints.
struct MapSegmentInfo {
  uint32_t id = 0;
  size_t points = 0, images = 0;
  uint32_t format_version = 0;
  SegmentBytes bytes;
  std::optional<XyzQuantization> xyz_quantization;  // version 3: coordinates in uint16
  std::optional<double> metres_per_unit;            // enu_from_segment's scale, when georegistered
  bool point_uncertainty = false;                   // section PTUNC (map build --point-uncertainty)
  // The worst per-axis rounding error of the coordinates (0 for float32), in
  // segment units and, with a known scale, in metres.
  double xyz_rounding_error() const { return xyz_quantization ? xyz_quantization->max_rounding_error() : 0.0; }
};
struct MapInfo {
  MapManifest manifest;
  std::vector<MapSegmentInfo> segments;
  uint64_t codebook_bytes = 0;
  int pq_code_bytes = kPqCodeBytes;  // bytes per PQ code (the codebook's): 16 or 32
  PqQuantizer pq_quantizer = PqQuantizer::kProduct;  // the codebook's
  int pq_residual_splits = 0;                        // a residual codebook's parts; 0 for the PQ
  int pq_residual_beam = 0;                          // a residual codebook's encoder beam; 0 for the PQ
  uint64_t hash_rotation_bytes = 0;
  size_t total_points = 0;
  uint64_t total_per_point_bytes = 0;  // Σ per-point sections
  uint64_t total_bytes = 0;            // Σ segment files + codebook + shared hash rotation
  nlohmann::json to_json() const;
  // The segment table and totals `visloc map info` prints for the map named `map_name`.
  std::string summary(const std::string& map_name) const;
};
MapInfo map_info(const std::filesystem::path& dir);

}  // namespace visloc
