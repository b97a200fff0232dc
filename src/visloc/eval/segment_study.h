// The paper's "GSV model design" study (`visloc bench segments`, issue #13):
// the same map images are cut into segments of P placemarks sharing O with
// their neighbours, for every P in `placemarks` and O in `overlaps` (O < P);
// each map is built and the same queries are localized against it. Reported
// per configuration: registration, median error, wrong poses, map bytes and
// points, build time, milliseconds per query.
//
// Two data sets: a `visloc bench city` directory (its rendered city, its map
// images, its scored positives and negatives) and KITTI (the even frames are
// the map, with known poses; the odd frames are the queries).
//
// Every configuration shares the SIFT features and the PQ codebook of the
// first one (hard links), so build times are those of the segments and the
// retrieval index. Query features are extracted once. Each configuration's
// result is kept in DIR/DATASET/pP_oO/result.json: a rerun resumes.
#pragma once

#include <filesystem>
#include <functional>
#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/pipeline/localizer.h"

namespace visloc {

struct StudyQuery {
  std::filesystem::path image;
  PinholeCamera camera;
  std::optional<CameraPose> truth;  // none: a negative (any registration is a wrong pose)
  std::string kind;                 // "positive" or "negative"
};

// A data set: the map images with known poses, and queries.
struct StudyDataset {
  std::string name;
  std::filesystem::path images_dir, gps_csv, known_poses, known_intrinsics;  // MapBuildOptions fields
  std::vector<StudyQuery> queries;
};

// From a `visloc bench city` directory with a report (its positives and
// negatives; its map images, GPS and poses).
StudyDataset city_study_dataset(const std::filesystem::path& bench_city_dir);
// KITTI (../shared/data/kitti07): map = even frames, queries = odd frames
// (queries.txt); writes the map's GPS list and intrinsics into work_dir.
StudyDataset kitti_study_dataset(const std::filesystem::path& kitti_dir, const std::filesystem::path& work_dir);

struct SegmentStudyOptions {
  std::vector<int> placemarks = {4, 6, 8, 10, 14};  // the paper's values
  std::vector<int> overlaps = {0, 1, 2, 3};
  MapBuildOptions map;          // images, GPS, poses and segment sizes are set per configuration
  LocalizerOptions localizer;
  double wrong_position_m = 5, wrong_rotation_deg = 10;
  bool keep_maps = false;       // keep each configuration's map (else only its result)
  size_t max_queries = 0;       // 0: every query; else this many, evenly spread (the same in every configuration)
  void validate() const;
};

class OptionTable;
// The study's options: --placemarks, --overlaps (comma-separated lists),
// --jobs, --max-queries, --keep-maps and the localizer's.
void add_options(OptionTable& table, SegmentStudyOptions& options);

struct SegmentStudyProgress {
  std::string dataset;
  int placemarks = 0, overlap = 0;
  std::string stage;  // "features", "build", "localize", "done"
  size_t done = 0, total = 0;
};

// Runs (or resumes) the study of one data set in out_dir/DATASET; writes
// result.json per configuration and returns the rows (one per configuration).
nlohmann::json run_segment_study(const std::filesystem::path& out_dir, const StudyDataset& dataset,
                                 const SegmentStudyOptions& options,
                                 const std::function<void(const SegmentStudyProgress&)>& progress = {});

// Every configuration measured so far in out_dir/DATASET (result.json files,
// those of earlier runs with other P and O lists included), by P then O.
nlohmann::json collect_segment_study_rows(const std::filesystem::path& out_dir, const std::string& dataset);

// report.md (tables) and one plot per data set (registration and map size
// against placemarks per segment, a line per overlap) from the rows of
// run_segment_study, keyed by data set name.
void write_segment_study_report(const std::filesystem::path& out_dir,
                                const std::vector<std::pair<std::string, nlohmann::json>>& rows_by_dataset);

// `visloc bench segments`: the study of a `visloc bench city` directory and
// of KITTI (either path may be empty, not both) in out_dir, then the report
// over every configuration measured there; returns report.md. Progress lines
// go to `log` (one line rewritten in place when `tty`).
std::string run_segment_studies(const std::filesystem::path& out_dir, const std::filesystem::path& city_dir,
                                const std::filesystem::path& kitti_dir, const SegmentStudyOptions& options,
                                std::ostream& log, bool tty);

}  // namespace visloc
