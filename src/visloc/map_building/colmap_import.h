// `visloc map import --colmap` / `--bundler`: a COLMAP model + database, or a
// Bundler reconstruction (bundle.out + list + Lowe key files, converted by
// colmap/bundler.h), become a map of one segment (issue 6 splits city-scale
// maps into many):
//   1. read the model (binary or text) and, with a holdout list, remove those
//      images the way the Dubrovnik protocol does (colmap_model.h
//      remove_images): their poses are kept as the queries' reference poses;
//   2. mean SIFT per 3D point from its track (colmap/point_descriptors.h),
//      the descriptors taken from the database or from the key files;
//   3. PQ codebook (16 × 8 bits), trained once per map on a sample across
//      the whole map's point descriptors, or on another database's image
//      descriptors (an independent set, as the paper trains its codebook);
//   4. ITQ learned on the segment's descriptors (stored in the segment or,
//      with --hash-rotation map, in MAP/hash_rotation.vlitq); codes, PQ codes;
//   5. segment file, descriptor file, codebook, holdout poses, manifest.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "visloc/colmap/bundler.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/geometry/pose_list.h"  // read_name_list
#include "visloc/map/segment_file.h"
#include "visloc/map_building/hash_blend_fit.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"

namespace visloc {

struct ColmapImportOptions {
  std::vector<std::string> holdout_images;      // image names removed from the model
  std::filesystem::path pq_training_database;   // empty: train on the map's own point descriptors
  std::vector<std::string> pq_training_images;  // names in that database; empty: all its images
  ItqOptions itq;
  HashRotationScope hash_rotation = HashRotationScope::kSegment;  // kMap: MAP/hash_rotation.vlitq
  SegmentWriteOptions segment_file;  // point coordinates (auto: float32 here, an import has no metric scale)
  PqTrainingOptions pq;
  bool keep_descriptors = true;  // write descriptors/NNNN.vldesc
  bool overwrite = false;        // replace an existing map in the output directory
  // Fit the cascade search's hash-blend weight on the new map and store it in
  // its manifest before the map replaces any previous one (fit_map_hash_blend,
  // store_map_hash_blend). Unset (the default): for COLMAP imports that keep
  // their descriptors, and a failed fit leaves the map without a weight
  // (ColmapImportResult::hash_blend_error); true: a COLMAP import with
  // descriptors, whose failed fit fails the import; false: never.
  std::optional<bool> fit_hash_blend;
  MapBlendFitOptions hash_blend;
  void validate() const;
};

class OptionTable;
// The options as `visloc map import`'s command-line options: --pq-train-database, --itq-iterations,
// --hash-rotation, --point-coordinates, --seed (ITQ's; the CLI seeds PQ training with it too), --no-descriptors,
// --overwrite.
void add_options(OptionTable& table, ColmapImportOptions& options);

struct ColmapImportResult {
  size_t images = 0, points = 0, observations = 0;
  ColmapHoldoutStats holdout;
  size_t pq_training_descriptors = 0;
  std::string pq_training_source;
  double itq_final_error = 0;
  std::optional<double> hash_blend_weight;  // fitted and stored (fit_hash_blend)
  std::string hash_blend_error;             // why the default fit failed (the map has no weight then)
  double ms_read = 0, ms_descriptors = 0, ms_pq = 0, ms_itq = 0, ms_encode = 0, ms_write = 0, ms_hash_blend = 0;
};

// The statistics as `visloc map import --json` prints them (and Python returns).
nlohmann::json to_json(const ColmapImportResult& r);

ColmapImportResult import_colmap_map(const std::filesystem::path& model_dir, const std::filesystem::path& database,
                                     const std::filesystem::path& out_dir, const ColmapImportOptions& options = {});

// Bundler import: read_bundler_model (bundler options: key folder, image
// folder, RootSIFT or raw descriptors), then the same steps as the COLMAP
// import with the key files as the descriptor source. Holdout names are the
// list's image names as written.
struct BundlerImportResult {
  ColmapImportResult map;             // ms_read covers the conversion
  BundlerConversionStats conversion;
};
BundlerImportResult import_bundler_map(const std::filesystem::path& bundle_file,
                                       const std::filesystem::path& list_file, const std::filesystem::path& out_dir,
                                       const BundlerConversionOptions& bundler = {},
                                       const ColmapImportOptions& options = {});

// What `visloc map import` is given: a COLMAP model and its database, or a
// Bundler reconstruction; the holdout and PQ training images as name lists.
struct MapImportSources {
  std::filesystem::path colmap_model, database;     // COLMAP
  std::filesystem::path bundle_file, bundler_list;  // Bundler
  BundlerConversionOptions bundler;                 // key and image folders, RootSIFT or Lowe's
  std::filesystem::path holdout_list;               // images held out as queries (empty: none)
  std::filesystem::path pq_training_list;           // images of the PQ training database (empty: all)
  bool is_bundler() const;  // a Bundler file or list is named
  // Exactly one complete source (naming the command line's options) and an output directory.
  void validate(const std::filesystem::path& out_dir) const;
};
// The sources as `visloc map import`'s command-line options: --colmap, --database, --bundler, --list, --keys,
// --images, --raw-sift, --holdout, --pq-train-images.
void add_options(OptionTable& table, MapImportSources& sources);

struct MapImportResult {
  ColmapImportResult map;
  std::optional<BundlerConversionStats> bundler;  // a Bundler import's conversion
  bool root_sift = true;                          // Bundler: descriptors converted to RootSIFT
};

// import_colmap_map or import_bundler_map, with the lists read into `options`.
MapImportResult import_map(const MapImportSources& sources, const std::filesystem::path& out_dir,
                           ColmapImportOptions options);
// The statistics as `visloc map import --json` prints them (without "map").
nlohmann::json to_json(const MapImportResult& r);
// The statistics as `visloc map import` prints them.
std::string import_summary(const MapImportResult& r, const MapImportSources& sources,
                           const std::filesystem::path& out_dir);

}  // namespace visloc
