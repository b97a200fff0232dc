// Evaluation protocols beyond "a query list against a map":
//   * query features from the benchmark's own feature store (the COLMAP
//     database an imported map came from) instead of our SIFT on the images
//     (`--query-features database`): the difference is the cost of mixing
//     extractors;
//   * leave-one-out on an imported COLMAP model: every image in turn is
//     removed from the model (the Dubrovnik holdout of colmap_model.h), the
//     map is rebuilt without it and the image is localized against it;
//   * the peer: COLMAP 3.8's image_registrator registers the same queries
//     into the same model (features imported, matched against the model's
//     images), timed in the same run.
#pragma once

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "visloc/colmap/colmap_model.h"
#include "visloc/eval/evaluation.h"
#include "visloc/features/feature_set.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/sfm/colmap_runner.h"

namespace visloc {

enum class QueryFeatureSource { kImages, kDatabase };
QueryFeatureSource parse_query_feature_source(const std::string& name);  // "images", "database"
std::string to_string(QueryFeatureSource source);

// The features a map's source model ships for its images (manifest
// "source"): the COLMAP database of a COLMAP import (features and the
// database's intrinsics), or the Lowe key files of a Bundler import (features
// converted as the import did; the camera is the image's size from
// `images_dir` with the focal length from EXIF when present, else unknown —
// Bundler datasets ship no query intrinsics). Throws Error(kInvalidArgument)
// naming the map when it has none (maps built from images: use our SIFT).
class SourceFeatureStore {
 public:
  explicit SourceFeatureStore(const std::filesystem::path& map_dir, const std::filesystem::path& images_dir = {});
  ~SourceFeatureStore();
  FeatureSet features(const std::string& image) const;  // Error(kNotFound) naming the store and the image
  PinholeCamera camera(const std::string& image) const;  // the source's intrinsics for that image
  bool is_colmap() const;  // model_dir() and database() are set only for COLMAP imports
  const std::filesystem::path& model_dir() const { return model_dir_; }
  const std::filesystem::path& database() const { return database_; }

 private:
  struct Impl;
  std::filesystem::path model_dir_, database_, images_dir_;
  std::unique_ptr<Impl> impl_;
};

// A query as the protocols hand it to a localizer: its features and camera.
struct PreparedQuery {
  std::string name;
  FeatureSet features;
  PinholeCamera camera;
  double features_ms = 0;  // extraction (images) or reading (database)
  std::string error;       // a bad image: the reason (features empty)
};

// Features and camera of one query: from the image file (our SIFT;
// `intrinsics`, else EXIF focal, else unknown focal) or from the store (the
// store's intrinsics unless `intrinsics` is given).
PreparedQuery prepare_query(const std::string& name, QueryFeatureSource source, const std::filesystem::path& image_dir,
                            const SiftOptions& sift, const SourceFeatureStore* store,
                            const std::optional<PinholeCamera>& intrinsics, bool use_exif_focal = true);

// Localizes a prepared query (a bad image gives an unregistered result with
// its error).
LocalizationResult localize_prepared(const Localizer& localizer, const PreparedQuery& query);

struct LeaveOneOutOptions {
  LocalizerOptions localizer;
  ColmapImportOptions import;               // holdout_images and overwrite are set per image
  QueryFeatureSource features = QueryFeatureSource::kImages;
  std::filesystem::path images_dir;          // with kImages
  std::vector<std::string> images;           // the images to leave out; empty: every image of the model
  CamerasByName intrinsics;                  // per image, or '*' for all; else the model's camera (known intrinsics)
  std::filesystem::path work_dir;            // scratch maps (removed at the end)
  bool compare_colmap = false;               // also register each image with COLMAP
  ColmapRunnerOptions colmap;
  std::function<void(size_t done, size_t total)> progress;
  void validate() const;
};

struct ColmapRegistrationResult {
  std::vector<LocalizationResult> results;  // in query order; times.total = the query's share
  double seconds_matching = 0, seconds_registration = 0;
};

struct LeaveOneOutResult {
  std::vector<LocalizationResult> results;
  std::map<std::string, QueryTruth> truth;   // the images' poses in the model
  std::optional<ColmapRegistrationResult> colmap;
  double seconds_import = 0;                 // rebuilding the maps (not a per-query cost)
};

// Leave-one-out on a COLMAP model + database.
LeaveOneOutResult run_leave_one_out(const std::filesystem::path& model_dir, const std::filesystem::path& database,
                                    const LeaveOneOutOptions& options);

// The peer: registers `queries` (features + cameras) into `model` (which
// must not contain them) with COLMAP's image_registrator. A copy of
// `database` (the model's images and features) gets the queries' features;
// each query is matched against every model image (matches_importer with an
// explicit pair list), then image_registrator runs. Nothing is written
// outside work_dir. Times are wall-clock, divided evenly over the queries.
ColmapRegistrationResult register_with_colmap(const ColmapModel& model, const std::filesystem::path& database,
                                              const std::vector<PreparedQuery>& queries,
                                              const ColmapRunnerOptions& colmap,
                                              const std::filesystem::path& work_dir);

}  // namespace visloc
