// MapBuilder: `visloc map build` (paper section III-A). A city's geotagged
// images are cut into segments of 8-10 consecutive placemarks (2 shared with
// the next segment); each segment is reconstructed on its own by COLMAP
// (a process), compressed into a segment file (mean SIFT → ITQ codes of the segment's
// or the map's rotation, PQ codes with the map's shared codebook) and geo-registered to local ENU
// by a robust similarity transform from its camera centres to their GPS
// (upright: the cameras' mean up axis is aligned with ENU up, leaving yaw,
// scale and translation, which stay well-posed along a straight street).
//
// Work layout inside the map directory:
//   MAP/work/features/NAME.vlfeat   our SIFT per image (shared by segments)
//   MAP/work/segNNNN/               database.db, sparse/, log.txt, result.json
//   MAP/segments/NNNN.vlseg         finished segments
//   MAP/manifest.json               rewritten (atomically) after every segment
// A segment is finished when its result.json records success and its
// segment file exists; a build started again redoes only the others. One
// failing segment is reported and the rest of the map stays usable.
#pragma once

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

#include "visloc/features/sift_extractor.h"
#include "visloc/geo/similarity_transform.h"
#include "visloc/map/segment_file.h"
#include "visloc/map_building/hash_blend_fit.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/retrieval/image_index.h"
#include "visloc/retrieval/triangulation_embedding.h"
#include "visloc/sfm/colmap_runner.h"
#include "visloc/sfm/guided_matcher.h"
#include "visloc/sfm/segment_plan.h"
#include "visloc/sfm/slurm.h"
#include "visloc/twoview/image_pair.h"
#include "visloc/util/timer.h"

namespace visloc {

// How a segment's image pairs are matched.
enum class PairMatcher {
  kDefault,  // guided with known poses, COLMAP's with SfM
  kGuided,   // known poses only: epipolar-guided RootSIFT matching (sfm/guided_matcher.h)
  kColmap,   // COLMAP's matcher (matches_importer / exhaustive / spatial) and its geometric verification
  // Our exact matching with a 1-1 and a 1-M set, verified by two-view RANSAC
  // (twoview/image_pair.h: 1m-sprt by default, the paper's one-many RANSAC
  // on image pairs): E with known, undistorted cameras, else F.
  kTwoView,
};
// "auto", "guided", "colmap", "twoview" (the option's choices).
std::string_view to_string(PairMatcher matcher);

// Where segments are built: threads of this process, or one Slurm job array
// whose tasks run `visloc map build-segment MAP N` on a shared map directory.
enum class BuildExecutor { kLocal, kSlurm };

enum class PoseSource {
  kSfm,    // COLMAP's mapper estimates the poses
  kKnown,  // exact poses are given (street-view captures); COLMAP triangulates
};

struct MapBuildOptions {
  std::filesystem::path images_dir;
  std::filesystem::path gps_csv;         // empty: read GPS from each image's EXIF
  // With gps_csv: false (default) every image in images_dir must be listed,
  // as with EXIF every image must carry GPS; true: the CSV chooses a subset
  // of the folder and the other images are left out of the map.
  bool gps_lists_subset = false;
  PoseSource poses = PoseSource::kSfm;
  // kKnown: a COLMAP model directory (text or binary) whose image names
  // match, or a pose list file ('name qw qx qy qz tx ty tz', world-to-camera)
  // with known_intrinsics giving the cameras.
  std::filesystem::path known_poses;
  // With a pose list: intrinsics 'name MODEL width height params...' per image;
  // a line named '*' applies to every image without a line of its own.
  std::filesystem::path known_intrinsics;
  SegmentPlanOptions plan;
  SiftOptions sift;
  ColmapRunnerOptions colmap;
  PairMatcher matcher = PairMatcher::kDefault;
  GuidedMatchOptions guided;
  PairVerificationOptions pair_verification;  // --matcher twoview
  BuildExecutor executor = BuildExecutor::kLocal;
  SlurmOptions slurm;
  // kSlurm: the command each task runs, without the segment index that Slurm
  // appends (e.g. {"/usr/bin/visloc", "map", "build-segment", "/abs/MAP"}).
  std::vector<std::string> slurm_task_command;
  // Written to MAP/work/build.json once the build holds the map (the CLI
  // records its options there for `map build-segment`); empty: not written.
  std::string build_record;
  size_t exhaustive_max_images = 20;        // COLMAP exhaustive matching up to this many images, else:
  double pair_max_distance = 30;            //   known poses: pairs of views at most this far apart (m)
  double pair_max_angle_deg = 60;           //   and looking within this angle of each other;
                                            //   SfM: COLMAP's spatial matcher on the GPS priors
  ItqOptions itq;
  // kMap: one ITQ rotation for the map (MAP/hash_rotation.vlitq), learned on
  // the PQ codebook's training sample, so that hash codes compare across
  // segments (the localizer's point votes need it); kSegment: one per
  // segment, learned on its points' descriptors. Empty (default): the
  // existing map's (resolve_hash_rotation), kMap for a new map.
  std::optional<HashRotationScope> hash_rotation;
  SegmentWriteOptions segment_file;  // point coordinates: float32, int16 or auto
  // Bytes per PQ code (--pq-bytes): 16 or 32. Empty (default): the existing
  // map's (its codebook's), else pq.subvectors for a new map
  // (resolve_pq_code_bytes); given and unlike the existing map's: refused
  // before anything is written.
  std::optional<int> pq_code_bytes;
  // The PQ codes' quantizer (--pq-quantizer): as pq_code_bytes, the existing
  // map's when empty, else pq.quantizer for a new map (resolve_pq_quantizer).
  std::optional<PqQuantizer> pq_quantizer;
  // Residual codes' parts (--pq-residual-splits) and beam
  // (--pq-residual-beam): likewise an existing residual map's when empty, else
  // pq.residual_splits / pq.residual_beam (resolve_pq_residual).
  std::optional<int> pq_residual_splits, pq_residual_beam;
  PqTrainingOptions pq;
  size_t pq_training_descriptors = 100000;  // sampled across the training images:
  size_t pq_training_images = 1000;         // at most this many images, spread evenly over the map
                                            // (their features are extracted before any segment;
                                            // on Slurm, each task extracts the rest of its own)
  SimilarityRansacOptions registration;     // GPS → ENU registration (threshold in metres)
  double fallback_focal_factor = 1.2;       // focal = factor × max(w, h) when EXIF has none
  int jobs = 0;                             // local: segments built in parallel (0: number of cores)
  std::vector<int> only_segments;           // rebuild just these (map update); empty: all
  bool build_retrieval = true;              // train and write MAP/retrieval (T-embedding + IVF-PQ)
  // Last, fit the cascade search's hash-blend weight on the built map and
  // store it in its manifest (fit_map_hash_blend, store_map_hash_blend):
  // localize and eval then use it by default. Unset (the default): fit, and
  // when the fit fails keep the map without a weight and say why
  // (MapBuildResult::hash_blend_error); true: a failed fit fails the build;
  // false: no fit (a weight stored earlier is kept, for the segments it was
  // fitted on).
  std::optional<bool> fit_hash_blend;
  MapBlendFitOptions hash_blend;
  // Retrieval: global descriptor, PCA-whitened to 512-D by default (8.4 MB of
  // parameters instead of 67 MB for full 4096-D whitening; under IVF-PQ at
  // 100K images it kept more recall and was 3× faster: see issue #7's notes).
  TriangulationEmbeddingOptions embedding = [] {
    TriangulationEmbeddingOptions o;
    o.output_dims = 512;
    return o;
  }();
  ImageIndexOptions image_index;  // retrieval: IVF-PQ index
  void validate() const;
  PairMatcher effective_matcher() const;  // kDefault resolved: guided with known poses, else COLMAP's
};

class OptionTable;
// The options as `visloc map build`'s command-line options: --images, --gps, --gps-subset, --poses,
// --known-poses, --known-intrinsics, --matcher, --sampson, --executor, --slurm-*, --jobs, --colmap,
// --colmap-threads, --exhaustive-max, --spatial-neighbors, the placemark plan's, --chain-order,
// --registration-threshold, --retrieval-dims, --no-retrieval, --pq-training-images, --hash-rotation,
// --point-coordinates, --pq-bytes, SIFT's.
void add_options(OptionTable& table, MapBuildOptions& options);
// --fit-blend (true) and --no-fit-blend (false), of map build, map import and bench city.
void add_fit_blend_options(OptionTable& table, std::optional<bool>& fit);
// --pq-bytes 16|32 into options.subvectors (map build, map import, bench segments).
void add_pq_bytes_option(OptionTable& table, PqTrainingOptions& options);

struct SegmentBuildResult {
  int id = 0;
  bool ok = false;
  bool reused = false;              // finished in an earlier run
  std::string error;
  size_t images = 0;                // images given to COLMAP
  size_t registered_images = 0;     // images with a pose in the model
  size_t points = 0;
  double bytes_per_point = 0;       // whole segment file / points
  double registration_rms_m = 0;    // GPS residual over inliers
  double registration_median_m = 0;
  double registration_max_m = 0;
  int registration_inliers = 0;
  double seconds = 0;
  // Seconds per stage: COLMAP database with our features, matching (guided
  // or COLMAP's, with verification), triangulation + bundle adjustment
  // (COLMAP), compression + geo-registration + files.
  double seconds_features = 0;  // features this segment had to extract (a Slurm task; 0 when all were there)
  double seconds_database = 0, seconds_matching = 0, seconds_triangulation = 0, seconds_compression = 0;
  std::string matcher;              // "guided", "colmap" or "twoview"
  size_t pairs = 0;                 // candidate pairs given to the matcher (0: COLMAP chose)
  size_t matched_pairs = 0;         // guided: pairs with at least min_matches matches; twoview: verified pairs
  size_t matches = 0;               // guided: matches written; twoview: inliers written
  size_t points_track3 = 0;         // points seen in at least 3 images
  double mean_track_length = 0;
  double mean_reprojection_error = 0;  // pixels, COLMAP's per-point error averaged
  uint64_t file_bytes = 0;          // segment file size and checksum (for the manifest)
  uint32_t file_crc32c = 0;
};

struct MapBuildResult {
  std::vector<SegmentBuildResult> segments;
  size_t images = 0, placemarks = 0;
  double seconds_features = 0, seconds_segments = 0, seconds_retrieval = 0, seconds_total = 0;
  std::optional<double> hash_blend_weight;  // fitted and stored (MapBuildOptions::fit_hash_blend)
  std::string hash_blend_error;             // why the default fit failed (the map has no weight then)
  double seconds_hash_blend = 0;
  size_t failed() const;
};

// What a running segment is doing: stage "queued", "database", "matching"
// (done/total pairs), "triangulating", "bundle adjustment", "compressing".
struct SegmentProgress {
  int segment = 0;
  std::string stage;
  size_t done = 0, total = 0;
};

struct MapBuildProgress {
  std::string stage;  // "features", "segments", "retrieval"
  size_t done = 0, total = 0;
  double elapsed_s = 0;
  std::vector<SegmentProgress> running;  // stage "segments": the segments in progress
  double eta_s = -1;                     // stage "segments": whole map, once it can be estimated
};

// Builds one segment of a map whose build was started by build_map (its
// features and PQ codebook exist and its manifest records the ENU origin),
// with the same options: what a Slurm task runs. Writes the segment's files
// and MAP/work/segNNNN/result.json and returns the result (ok = false with
// the error when it failed; throws only for bad arguments or internal errors).
SegmentBuildResult build_planned_segment(const std::filesystem::path& map_dir, const MapBuildOptions& options,
                                         int segment);

// MAP/work/segNNNN: segment `segment`'s working folder (its COLMAP database,
// model under sparse/, logs), always kept: a resumed build, `map update` and
// `map fit-blend` read it.
std::filesystem::path segment_work_dir(const std::filesystem::path& map_dir, int segment);

// The hash rotation a build of `map_dir` uses: `given`, else the existing
// map's (MAP/hash_rotation.vlitq present: kMap; a manifest without it: a
// map built with a rotation per segment, kSegment), else kMap for a new map.
HashRotationScope resolve_hash_rotation(const std::filesystem::path& map_dir,
                                        const std::optional<HashRotationScope>& given);
// The PQ code size a build of `map_dir` uses: the existing map's codebook's,
// else options.pq_code_bytes, else options.pq.subvectors. An explicit
// pq_code_bytes unlike the existing map's throws Error(kInvalidArgument)
// naming --pq-bytes; an unreadable codebook throws the reader's error.
int resolve_pq_code_bytes(const std::filesystem::path& map_dir, const MapBuildOptions& options);
// The same for the quantizer: the existing codebook's, else
// options.pq_quantizer, else options.pq.quantizer; an explicit one unlike the
// existing map's throws Error(kInvalidArgument).
PqQuantizer resolve_pq_quantizer(const std::filesystem::path& map_dir, const MapBuildOptions& options);
// The residual parts and beam of a build of `map_dir`, into `pq`: an existing
// residual codebook's, else options.pq_residual_splits / pq_residual_beam,
// else options.pq's. Either given and unlike an existing residual codebook's
// throws Error(kInvalidArgument); a map with PQ codes ignores both.
void resolve_pq_residual(const std::filesystem::path& map_dir, const MapBuildOptions& options, PqTrainingOptions& pq);

MapBuildResult build_map(const std::filesystem::path& map_dir, const MapBuildOptions& options,
                         const std::function<void(const MapBuildProgress&)>& progress = {});

// The build of a map directory in named stages (as COLMAP's controllers):
// build_map is MapBuilder(map_dir, options, progress).run(). Each segment is
// built in stages of its own (map_builder.cc: SegmentBuilder): features,
// database (+ guided matching), COLMAP matching, reconstruction, geo-
// registration, compression.
class MapBuilder {
 public:
  using ProgressFn = std::function<void(const MapBuildProgress&)>;
  MapBuilder(std::filesystem::path map_dir, const MapBuildOptions& options, ProgressFn progress = {});
  ~MapBuilder();
  MapBuilder(const MapBuilder&) = delete;
  MapBuilder& operator=(const MapBuilder&) = delete;

  // Validates the options, takes the map directory's build lock, then runs
  // the stages below in order; one run per MapBuilder.
  MapBuildResult run();

 private:
  struct State;
  struct SlurmRun;
  // Stages, in the order run() calls them.
  void check_earlier_slurm_arrays();  // an interrupted run's arrays must have ended
  void plan_segments();               // inputs, ENU frame, plan; forgets segments of another plan
  void extract_features();            // our SIFT per image (on Slurm: the PQ training images only)
  void train_codebook();              // PQ codebook (and the map's hash rotation), once per map
  void select_segments();             // finished earlier (reused) or to build; the first manifest
  void build_segments_local();        // threads of this process
  void build_segments_slurm();        // job arrays, results collected from the shared directory
  void build_retrieval();             // T-embedding + IVF-PQ over the built segments' images
  void fit_hash_blend();              // last, unless MapBuildOptions::fit_hash_blend is false
  // Shared by the stages.
  void write_current_manifest();
  void report_segments();                                  // with the state mutex held
  void segment_finished(const SegmentBuildResult& result);  // with the state mutex held
  void submit_slurm_arrays(SlurmRun& run);
  void collect_slurm_results(SlurmRun& run);
  void wait_for_slurm_arrays(SlurmRun& run);
  void settle_slurm_tasks(SlurmRun& run);

  std::unique_ptr<State> state_;
};

// Segment table and totals as `visloc map build` prints them.
std::string build_summary(const MapBuildResult& result);
// One line on a segment as `visloc map build-segment` prints it.
std::string segment_summary(const SegmentBuildResult& result);

// What `map build` recorded in MAP/work/build.json for `map build-segment`:
// its arguments and the directory it ran in (their relative paths' base).
struct BuildRecord {
  std::filesystem::path file;  // MAP/work/build.json
  std::vector<std::string> args;
  std::string cwd;
};
BuildRecord read_build_record(const std::filesystem::path& map_dir);

// Records a `map build`'s arguments (`build_args`, relative paths taken from
// the current directory) in options.build_record for `map build-segment`,
// and with the Slurm executor sets the command each task runs (this program).
void record_build_for_tasks(MapBuildOptions& options, const std::filesystem::path& map_dir,
                            const std::vector<std::string>& build_args);

// Prints a build's progress as `visloc map build` does. Live (a terminal): a
// block of the map's line and one line per running segment, redrawn in
// place; otherwise (a log): one line per stage change and per 10% of a stage.
class MapBuildProgressPrinter {
 public:
  MapBuildProgressPrinter(std::ostream& out, bool live);
  void operator()(const MapBuildProgress& progress);

 private:
  void draw(const MapBuildProgress& p);
  void log(const MapBuildProgress& p);

  std::ostream& out_;
  bool live_;
  int lines_ = 0;  // lines of the live block drawn last
  std::string last_stage_;
  Timer redraw_;
  std::map<int, std::string> stages_;  // log: each running segment's stage last printed
  size_t segments_done_ = 0;
};

// The segment id on line `line` (from 0) of a Slurm array's task list.
int task_list_segment(const std::filesystem::path& task_list, int line);

// The build's statistics as a JSON object (Python's visloc.build_map returns
// it): each segment as in its MAP/work/segNNNN/result.json, plus "reused".
nlohmann::json to_json(const MapBuildResult& r);

}  // namespace visloc
