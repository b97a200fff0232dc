#include "visloc/map_building/map_builder.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <exception>
#include <fstream>
#include <optional>
#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <string_view>
#include <numeric>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <thread>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/map/map.h"
#include "visloc/map_building/segment_builder.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/sfm/colmap_database_writer.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/parallel_for.h"
#include "visloc/util/timer.h"
#include "visloc/util/random.h"

namespace visloc {
namespace fs = std::filesystem;

void MapBuildOptions::validate() const {
  if (images_dir.empty()) throw_error(ErrorCode::kInvalidArgument, "map build: --images is required");
  if (!fs::is_directory(images_dir))
    throw_error(ErrorCode::kIo, images_dir.string(), ": no such image directory");
  if (!gps_csv.empty() && !fs::is_regular_file(gps_csv))
    throw_error(ErrorCode::kIo, gps_csv.string(), ": no such GPS file");
  if (poses == PoseSource::kKnown && known_poses.empty())
    throw_error(ErrorCode::kInvalidArgument, "map build: --poses known needs --known-poses MODEL_DIR");
  if (jobs < 0) throw_error(ErrorCode::kInvalidArgument, "map build: jobs must be >= 0, got ", jobs);
  segment_file.validate();
  if (!(fallback_focal_factor > 0))
    throw_error(ErrorCode::kInvalidArgument, "map build: fallback_focal_factor must be positive");
  if (!(pair_max_distance > 0) || !(pair_max_angle_deg > 0 && pair_max_angle_deg <= 180))
    throw_error(ErrorCode::kInvalidArgument, "map build: pair_max_distance must be > 0 and pair_max_angle_deg in (0, 180]");
  if (pq_training_images < 1)
    throw_error(ErrorCode::kInvalidArgument, "map build: pq_training_images must be >= 1");
  if (pq_training_descriptors < 256 * 4)
    throw_error(ErrorCode::kInvalidArgument, "map build: pq_training_descriptors must be >= 1024");
  if (matcher == PairMatcher::kGuided && poses != PoseSource::kKnown)
    throw_error(ErrorCode::kInvalidArgument, "map build: --matcher guided needs known poses (--poses known)");
  if (executor == BuildExecutor::kSlurm && slurm_task_command.empty())
    throw_error(ErrorCode::kInvalidArgument, "map build: the Slurm executor needs the task command");
  plan.validate();
  sift.validate();
  colmap.validate();
  guided.validate();
  pair_verification.validate();
  slurm.validate();
  itq.validate();
  if (pq_code_bytes && !valid_pq_subvectors(*pq_code_bytes))
    throw_error(ErrorCode::kInvalidArgument, "map build: --pq-bytes must be 16 or 32, got ", *pq_code_bytes);
  if (pq_residual_splits && !valid_residual_splits(*pq_residual_splits))
    throw_error(ErrorCode::kInvalidArgument, "map build: --pq-residual-splits must be 1, 2 or 4, got ",
                *pq_residual_splits);
  if (pq_residual_beam && (*pq_residual_beam < 1 || *pq_residual_beam > kResidualMaxBeam))
    throw_error(ErrorCode::kInvalidArgument, "map build: --pq-residual-beam must be in [1, ", kResidualMaxBeam,
                "], got ", *pq_residual_beam);
  pq.validate();
  registration.validate();
  embedding.validate();
  image_index.validate();
}

PairMatcher MapBuildOptions::effective_matcher() const {
  if (matcher != PairMatcher::kDefault) return matcher;
  return poses == PoseSource::kKnown ? PairMatcher::kGuided : PairMatcher::kColmap;
}

std::string_view to_string(PairMatcher matcher) {
  switch (matcher) {
    case PairMatcher::kDefault:
      return "auto";
    case PairMatcher::kGuided:
      return "guided";
    case PairMatcher::kColmap:
      return "colmap";
    case PairMatcher::kTwoView:
      return "twoview";
  }
  return "auto";
}

size_t MapBuildResult::failed() const {
  return static_cast<size_t>(std::count_if(segments.begin(), segments.end(), [](const auto& s) { return !s.ok; }));
}

namespace {

std::string segment_stem(int id) {
  std::ostringstream s;
  s << std::setw(4) << std::setfill('0') << id;
  return s.str();
}

nlohmann::json to_json(const SegmentBuildResult& r) {
  return {{"id", r.id},
          {"ok", r.ok},
          {"error", r.error},
          {"images", r.images},
          {"registered_images", r.registered_images},
          {"points", r.points},
          {"bytes_per_point", r.bytes_per_point},
          {"registration_rms_m", r.registration_rms_m},
          {"registration_median_m", r.registration_median_m},
          {"registration_max_m", r.registration_max_m},
          {"registration_inliers", r.registration_inliers},
          {"seconds", r.seconds},
          {"seconds_features", r.seconds_features},
          {"seconds_database", r.seconds_database},
          {"seconds_matching", r.seconds_matching},
          {"seconds_triangulation", r.seconds_triangulation},
          {"seconds_compression", r.seconds_compression},
          {"matcher", r.matcher},
          {"pairs", r.pairs},
          {"matched_pairs", r.matched_pairs},
          {"matches", r.matches},
          {"points_track3", r.points_track3},
          {"mean_track_length", r.mean_track_length},
          {"mean_reprojection_error", r.mean_reprojection_error},
          {"file_bytes", r.file_bytes},
          {"file_crc32c", r.file_crc32c}};
}

SegmentBuildResult segment_result_from_json(const nlohmann::json& j) {
  SegmentBuildResult r;
  r.id = j.at("id");
  r.ok = j.at("ok");
  r.error = j.value("error", "");
  r.images = j.value("images", size_t{0});
  r.registered_images = j.value("registered_images", size_t{0});
  r.points = j.value("points", size_t{0});
  r.bytes_per_point = j.value("bytes_per_point", 0.0);
  r.registration_rms_m = j.value("registration_rms_m", 0.0);
  r.registration_median_m = j.value("registration_median_m", 0.0);
  r.registration_max_m = j.value("registration_max_m", 0.0);
  r.registration_inliers = j.value("registration_inliers", 0);
  r.seconds = j.value("seconds", 0.0);
  r.seconds_features = j.value("seconds_features", 0.0);
  r.seconds_database = j.value("seconds_database", 0.0);
  r.seconds_matching = j.value("seconds_matching", 0.0);
  r.seconds_triangulation = j.value("seconds_triangulation", 0.0);
  r.seconds_compression = j.value("seconds_compression", 0.0);
  r.matcher = j.value("matcher", "");
  r.pairs = j.value("pairs", size_t{0});
  r.matched_pairs = j.value("matched_pairs", size_t{0});
  r.matches = j.value("matches", size_t{0});
  r.points_track3 = j.value("points_track3", size_t{0});
  r.mean_track_length = j.value("mean_track_length", 0.0);
  r.mean_reprojection_error = j.value("mean_reprojection_error", 0.0);
  r.file_bytes = j.value("file_bytes", uint64_t{0});
  r.file_crc32c = j.value("file_crc32c", uint32_t{0});
  return r;
}

nlohmann::json similarity_json(const Similarity3d& s) {
  nlohmann::json r = nlohmann::json::array();
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) r.push_back(s.rotation(i, k));
  return {{"scale", s.scale}, {"rotation_row_major", r}, {"translation", {s.translation.x(), s.translation.y(), s.translation.z()}}};
}

// The camera's "up" (image −y) in world coordinates. Street-level cameras are
// upright on average, so the sum over a segment's cameras gives the world's up.
Eigen::Vector3d camera_up(const CameraPose& pose) {
  return pose.rotation.conjugate() * Eigen::Vector3d(0, -1, 0);
}

PinholeCamera camera_of(const ColmapCamera& c) {
  try {
    return PinholeCamera::from_colmap(colmap_camera_model_name(c.model_id), static_cast<int>(c.width),
                                      static_cast<int>(c.height), c.params);
  } catch (const Error& e) {
    throw_error(ErrorCode::kInvalidArgument, "known poses: camera ", c.camera_id, ": ", e.what());
  }
}

// Known poses as a COLMAP model: read from a model directory, or made from a
// pose list and an intrinsics list (one COLMAP camera per image).
ColmapModel load_known_poses(const MapBuildOptions& opt) {
  if (fs::is_directory(opt.known_poses)) return read_colmap_model(opt.known_poses);
  if (opt.known_intrinsics.empty())
    throw_error(ErrorCode::kInvalidArgument, "map build: ", opt.known_poses.string(),
                " is a pose list; it needs --known-intrinsics (lines 'name MODEL w h params', '*' for all images)");
  const std::vector<NamedPose> poses = read_pose_list(opt.known_poses);
  const CamerasByName cams = read_intrinsics_by_name(opt.known_intrinsics);
  ColmapModel model;
  uint32_t id = 0;
  for (const NamedPose& p : poses) {
    const PinholeCamera* listed = find_listed_camera(cams, p.name);
    if (!listed)
      throw_error(ErrorCode::kNotFound, opt.known_intrinsics.string(), ": no intrinsics for image '", p.name,
                  "' (and no '*' line)");
    const PinholeCamera& k = *listed;
    ++id;
    ColmapCamera cam;
    cam.camera_id = id;
    auto [model_name, params] = k.colmap_model();
    // SIMPLE_RADIAL rather than SIMPLE_PINHOLE for square pixels, as before.
    if (model_name == "SIMPLE_PINHOLE") model_name = "SIMPLE_RADIAL", params.push_back(0.0);
    cam.model_id = colmap_camera_model_id(model_name);
    cam.width = static_cast<uint64_t>(k.width);
    cam.height = static_cast<uint64_t>(k.height);
    cam.params = params;
    model.cameras.push_back(cam);
    ColmapImage im;
    im.image_id = id;
    im.name = p.name;
    im.camera_id = id;
    const Eigen::Quaterniond& q = p.cam_from_world.rotation;
    im.cam_from_world_q_wxyz = {q.w(), q.x(), q.y(), q.z()};
    const Eigen::Vector3d& t = p.cam_from_world.translation;
    im.cam_from_world_t = {t.x(), t.y(), t.z()};
    model.images.push_back(std::move(im));
  }
  return model;
}

// One build of a map directory at a time: an exclusive lock (flock) on
// MAP/work/build.lock, released when the process ends, however it ends.
class BuildLock {
 public:
  explicit BuildLock(const fs::path& path) {
    fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd_ < 0) throw_error(ErrorCode::kIo, path.string(), ": cannot open the build lock: ", std::strerror(errno));
    if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
      ::close(fd_);
      throw_error(ErrorCode::kInvalidArgument, "map build: another build of ", path.parent_path().parent_path().string(),
                  " is running (", path.string(), " is locked)");
    }
  }
  ~BuildLock() { ::close(fd_); }
  BuildLock(const BuildLock&) = delete;
  BuildLock& operator=(const BuildLock&) = delete;

 private:
  int fd_ = -1;
};

// Everything a segment's build needs, the same in build_map and in a Slurm
// task (build_planned_segment): inputs, ENU frame, plan, known poses, codebook.
struct BuildContext {
  fs::path map_dir;
  const MapBuildOptions* options = nullptr;
  std::vector<GpsRecord> records;
  std::vector<Eigen::Vector3d> enu;  // per record
  GeoPosition origin;
  SegmentPlan plan;
  std::optional<ColmapModel> known;
  Similarity3d enu_from_known;  // kKnown: the known frame → ENU (one transform for the map)
  PqCodebook codebook;
  std::shared_ptr<const BinaryHasher> map_hasher;  // kMap: the map's rotation
};

fs::path feature_path(const BuildContext& ctx, const std::string& image) {
  return ctx.map_dir / "work" / "features" / (image + ".vlfeat");
}
fs::path segment_progress_file(const fs::path& map_dir, int id) { return segment_work_dir(map_dir, id) / "progress.json"; }
fs::path segment_result_file(const fs::path& map_dir, int id) { return segment_work_dir(map_dir, id) / "result.json"; }
fs::path segment_file(const fs::path& map_dir, int id) { return map_dir / "segments" / (segment_stem(id) + ".vlseg"); }

// Inputs (GPS from the CSV or EXIF), the ENU origin (kept from an earlier run
// of the same build, else the first image), the segment plan, known poses.
BuildContext prepare_context(const fs::path& map_dir, const MapBuildOptions& opt) {
  BuildContext ctx;
  ctx.map_dir = map_dir;
  ctx.options = &opt;
  if (!opt.gps_csv.empty()) {
    ctx.records = read_gps_csv(opt.gps_csv);
    std::vector<std::string> missing;
    for (const auto& r : ctx.records)
      if (!fs::is_regular_file(opt.images_dir / r.image)) missing.push_back(r.image);
    if (!missing.empty())
      throw_error(ErrorCode::kNotFound, opt.gps_csv.string(), ": ", missing.size(), " listed images are not in ",
                  opt.images_dir.string(), " (first: ", missing.front(), ")");
    if (!opt.gps_lists_subset) {
      std::set<std::string> listed;
      for (const auto& r : ctx.records) listed.insert(r.image);
      std::vector<std::string> unlisted;
      for (const auto& e : fs::directory_iterator(opt.images_dir))
        if (e.is_regular_file() && is_image_file(e.path()) && !listed.count(e.path().filename().string()))
          unlisted.push_back(e.path().filename().string());
      std::sort(unlisted.begin(), unlisted.end());
      if (!unlisted.empty())
        throw_error(ErrorCode::kInvalidArgument, opt.gps_csv.string(), " lists ", ctx.records.size(), " images but ",
                    unlisted.size(), " more in ", opt.images_dir.string(), " have no line (first: ", unlisted.front(),
                    "); add them, or pass --gps-subset to build from the listed images only");
    }
  } else {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(opt.images_dir))
      if (e.is_regular_file() && is_image_file(e.path())) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    std::vector<std::string> no_gps;
    for (const auto& f : files) {
      ImageMetadata m = read_image_metadata(f, opt.sift.image);
      if (!m.gps) {
        no_gps.push_back(f.filename().string());
        continue;
      }
      ctx.records.push_back({f.filename().string(), *m.gps, std::nullopt});
    }
    if (!no_gps.empty())
      throw_error(ErrorCode::kInvalidArgument, no_gps.size(), " images in ", opt.images_dir.string(),
                  " have no GPS in EXIF (first: ", no_gps.front(), "); give --gps FILE.csv");
  }
  if (ctx.records.size() < 2)
    throw_error(ErrorCode::kInvalidArgument, "map build: need at least 2 geotagged images, got ", ctx.records.size());

  ctx.origin = ctx.records.front().position;
  if (fs::exists(map_dir / "manifest.json")) {
    const MapManifest previous = read_manifest(map_dir);
    if (previous.enu_origin_lat_lon_alt) {
      const auto& o = *previous.enu_origin_lat_lon_alt;
      ctx.origin = {o[0], o[1], o[2]};
    }
  }
  const EnuFrame frame(ctx.origin);
  for (const auto& r : ctx.records) ctx.enu.push_back(frame.to_enu(r.position));
  ctx.plan = plan_segments(ctx.records, frame, opt.plan);

  // Known poses: one similarity from the poses' frame to ENU for the whole map.
  if (opt.poses == PoseSource::kKnown) {
    ctx.known = load_known_poses(opt);
    std::vector<Eigen::Vector3d> src, dst;
    Eigen::Vector3d up = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < ctx.records.size(); ++i) {
      const int64_t k = ctx.known->image_index_by_name(ctx.records[i].image);
      if (k < 0)
        throw_error(ErrorCode::kNotFound, opt.known_poses.string(), ": no pose for image '", ctx.records[i].image, "'");
      // Known intrinsics must be for the image as it is on disk (its header).
      const auto& im = ctx.known->images[k];
      const PinholeCamera cam = camera_of(ctx.known->cameras[ctx.known->camera_index(im.camera_id)]);
      const ImageMetadata meta = read_image_metadata(opt.images_dir / im.name, opt.sift.image);
      if (cam.width != meta.width || cam.height != meta.height)
        throw_error(ErrorCode::kInvalidArgument, "map build: the known intrinsics of image '", im.name, "' are for ",
                    cam.width, "x", cam.height, " pixels, but ", (opt.images_dir / im.name).string(), " is ",
                    meta.width, "x", meta.height);
      const CameraPose pose = colmap_image_pose(im);
      src.push_back(pose.center());
      up += camera_up(pose);
      dst.push_back(ctx.enu[i]);
    }
    ctx.enu_from_known = estimate_street_similarity_ransac(src, dst, up, opt.registration).transform;
  }
  return ctx;
}

using SegmentProgressFn = std::function<void(const SegmentProgress&)>;

// The images of every segment, in order: what the coordinator planned, which
// a Slurm task checks against its own plan before building.
std::vector<std::string> segment_images(const BuildContext& ctx, int id) {
  std::vector<std::string> names;
  for (int pm : ctx.plan.segments[id])
    for (size_t i : ctx.plan.placemarks[pm].images) names.push_back(ctx.records[i].image);
  return names;
}
nlohmann::json plan_json(const BuildContext& ctx) {
  nlohmann::json segments = nlohmann::json::array();
  for (size_t s = 0; s < ctx.plan.segments.size(); ++s) segments.push_back(segment_images(ctx, static_cast<int>(s)));
  return {{"version", 1}, {"segments", segments}};
}

// Our SIFT features of the given records, extracted where the feature file
// is missing or unreadable (written atomically, so segments that share images
// and run at once at worst extract one twice). `done(k)` reports progress;
// errors are collected and thrown together.
void ensure_features(const BuildContext& ctx, const std::vector<size_t>& records, int jobs, bool validate,
                     const std::function<void(size_t)>& done) {
  const MapBuildOptions& opt = *ctx.options;
  std::atomic<size_t> count{0};
  std::mutex m;
  std::vector<std::string> errors;
  std::optional<SiftExtractor> sift;  // made when a feature file is missing
  parallel_for(records.size(), jobs, [&](size_t k) {
    const size_t i = records[k];
    const fs::path out = feature_path(ctx, ctx.records[i].image);
    bool have = false;
    if (fs::exists(out)) {
      have = true;
      if (validate) {
        try {
          read_feature_file(out);
        } catch (const Error&) {
          have = false;
        }
      }
    }
    if (!have) {
      try {
        {
          std::lock_guard lock(m);
          if (!sift) sift.emplace(opt.sift);
        }
        fs::create_directories(out.parent_path());
        write_feature_file(out, sift->extract_file(opt.images_dir / ctx.records[i].image));
      } catch (const std::exception& e) {
        std::lock_guard lock(m);
        errors.push_back(opt.images_dir.string() + "/" + ctx.records[i].image + ": " + e.what());
      }
    }
    const size_t d = ++count;
    if (done) {
      std::lock_guard lock(m);
      done(d);
    }
  });
  if (!errors.empty()) throw_error(ErrorCode::kIo, errors.size(), " images could not be read: ", errors.front());
}

// The images whose descriptors train the PQ codebook: all of them, or at
// most pq_training_images spread evenly along the map's order.
std::vector<size_t> pq_training_records(const BuildContext& ctx) {
  const size_t n = ctx.records.size(), k = std::min(n, ctx.options->pq_training_images);
  std::vector<size_t> out;
  for (size_t j = 0; j < k; ++j) out.push_back(j * n / k);
  return out;
}

// Watches a COLMAP log while point_triangulator runs and reports "bundle
// adjustment" once COLMAP has started it (it prints a bundle adjustment header).
class ColmapStageWatcher {
 public:
  ColmapStageWatcher(fs::path log, int segment, const SegmentProgressFn& report)
      : log_(std::move(log)), segment_(segment), report_(report), start_(file_size(log_)) {
    if (report_) thread_ = std::thread([this] { run(); });
  }
  ~ColmapStageWatcher() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }

 private:
  static uintmax_t file_size(const fs::path& p) {
    std::error_code ec;
    const auto n = fs::file_size(p, ec);
    return ec ? 0 : n;
  }
  void run() {
    // Reads only what COLMAP appended since the last look (keeping a tail as
    // long as the pattern, which may straddle two reads).
    static constexpr std::string_view kPattern = "Bundle adjustment";
    uintmax_t offset = start_;
    std::string carry;
    try {
      while (!stop_) {
        for (int i = 0; i < 10 && !stop_; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
        if (stop_) break;
        std::ifstream in(log_);
        in.seekg(static_cast<std::streamoff>(offset));
        std::string text = carry + std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        offset += text.size() - carry.size();
        if (text.find(kPattern) != std::string::npos) {
          report_({segment_, "bundle adjustment", 0, 0});
          break;
        }
        carry = text.size() > kPattern.size() ? text.substr(text.size() - kPattern.size()) : text;
      }
    } catch (const std::exception&) {  // progress is best effort; never end the process for it
    }
  }
  fs::path log_;
  int segment_;
  SegmentProgressFn report_;
  uintmax_t start_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// One segment's build in stages: features → database (with guided matching,
// its matches too) → COLMAP's matching → reconstruction → geo-registration →
// compression and files. run() calls them in order; any stage may throw.
class SegmentBuilder {
 public:
  SegmentBuilder(const BuildContext& ctx, int id, const SegmentProgressFn& report)
      : ctx_(ctx), opt_(*ctx.options), id_(id), report_(report), matcher_(opt_.effective_matcher()) {}
  SegmentBuildResult run() {
    prepare_work_dir();
    extract_missing_features();
    fill_database();
    match_with_colmap();
    reconstruct();
    read_model();
    geo_register();
    compress_and_write();
    res_.ok = true;
    res_.seconds = timer_.elapsed_ms() / 1000.0;
    return res_;
  }

 private:
  void stage(const char* name, size_t done = 0, size_t total = 0) const {
    if (report_) report_({id_, name, done, total});
  }
  void prepare_work_dir();
  void extract_missing_features();
  void fill_database();
  void add_images(ColmapDatabaseWriter& db);
  std::vector<std::pair<size_t, size_t>> candidate_pairs() const;
  void match_guided(ColmapDatabaseWriter& db);
  void match_twoview(ColmapDatabaseWriter& db);
  void match_with_colmap();
  void reconstruct();
  void read_model();
  void geo_register();
  void compress_and_write();
  std::vector<CameraPose> known_poses() const {
    std::vector<CameraPose> poses;
    for (const auto& im : text_images_) poses.push_back(im.cam_from_world);
    return poses;
  }

  const BuildContext& ctx_;
  const MapBuildOptions& opt_;
  const int id_;
  const SegmentProgressFn& report_;
  const PairMatcher matcher_;  // kGuided, kColmap or kTwoView
  Timer timer_, t_stage_;
  SegmentBuildResult res_;
  fs::path work_, log_, db_path_, model_dir_;
  std::vector<size_t> images_;  // records of the segment's placemarks, in route order
  std::vector<ColmapTextCamera> text_cameras_;  // known poses: COLMAP's text model
  std::vector<ColmapTextImage> text_images_;
  std::vector<FeatureSet> features_;  // guided or twoview matching: per image
  std::vector<PinholeCamera> cameras_;
  std::vector<int64_t> db_image_ids_;  // per image: its id in the database
  std::optional<ColmapRunner> colmap_;
  ColmapModel model_;
  Similarity3d enu_from_segment_;
  size_t registration_images_ = 0;  // model images with GPS
};

void SegmentBuilder::prepare_work_dir() {
  res_.id = id_;
  res_.matcher = to_string(matcher_);
  work_ = segment_work_dir(ctx_.map_dir, id_);
  fs::remove_all(work_);
  fs::create_directories(work_);
  log_ = work_ / "log.txt";
  db_path_ = work_ / "database.db";
  for (int pm : ctx_.plan.segments[id_])
    for (size_t i : ctx_.plan.placemarks[pm].images) images_.push_back(i);
  res_.images = images_.size();
}

// Features of the segment's images that are not there yet (a Slurm task
// extracts its own; locally they were extracted for the whole map).
void SegmentBuilder::extract_missing_features() {
  Timer t_features;
  std::vector<size_t> missing;
  for (size_t i : images_)
    if (!fs::exists(feature_path(ctx_, ctx_.records[i].image))) missing.push_back(i);
  if (!missing.empty())
    ensure_features(ctx_, missing, 1, false, [&](size_t k) {
      if (k % 8 == 0 || k == missing.size()) stage("features", k, missing.size());
    });
  res_.seconds_features = t_features.elapsed_ms() / 1000;
}

// Our features into a fresh COLMAP database; with guided or twoview
// matching, the matches and their two-view geometries too, in the same
// transaction.
void SegmentBuilder::fill_database() {
  stage("database");
  t_stage_ = Timer();
  ColmapDatabaseWriter db(db_path_);
  add_images(db);
  res_.seconds_database = t_stage_.elapsed_ms() / 1000;
  if (matcher_ == PairMatcher::kGuided) match_guided(db);
  if (matcher_ == PairMatcher::kTwoView) match_twoview(db);
  db.commit();
  if (matcher_ != PairMatcher::kColmap) res_.seconds_matching = t_stage_.elapsed_ms() / 1000;
  // The features were only for our matching: free them before COLMAP
  // reconstructs (segments build concurrently, each would hold its images').
  std::vector<FeatureSet>().swap(features_);
  std::vector<PinholeCamera>().swap(cameras_);
}

void SegmentBuilder::add_images(ColmapDatabaseWriter& db) {
  std::map<std::tuple<int, int, double, bool>, int64_t> camera_ids;
  for (size_t i : images_) {
    const std::string& name = ctx_.records[i].image;
    FeatureSet f = read_feature_file(feature_path(ctx_, name));
    PinholeCamera cam;
    if (ctx_.known) {
      const auto& im = ctx_.known->images[ctx_.known->image_index_by_name(name)];
      cam = camera_of(ctx_.known->cameras[ctx_.known->camera_index(im.camera_id)]);
    } else {
      ImageMetadata meta = read_image_metadata(opt_.images_dir / name, opt_.sift.image);
      cam = PinholeCamera::centered(meta.width, meta.height, meta.focal_px());
    }
    const double fallback = opt_.fallback_focal_factor * std::max(cam.width, cam.height);
    const auto key = std::make_tuple(cam.width, cam.height, cam.has_focal ? cam.focal : 0.0, cam.has_focal);
    auto it = camera_ids.find(key);
    if (it == camera_ids.end() || ctx_.known) {
      const int64_t cid = db.add_camera(cam, fallback);
      it = camera_ids.insert_or_assign(key, cid).first;
      if (ctx_.known) text_cameras_.push_back({cid, cam});
    }
    const int64_t iid = db.add_image(name, it->second, ctx_.enu[i]);
    db_image_ids_.push_back(iid);
    db.add_features(iid, f);
    if (ctx_.known) {
      const auto& im = ctx_.known->images[ctx_.known->image_index_by_name(name)];
      text_images_.push_back({iid, it->second, name, colmap_image_pose(im)});
    }
    if (matcher_ != PairMatcher::kColmap) {
      features_.push_back(std::move(f));
      cameras_.push_back(cam);
    }
  }
}

// The pairs our matchers match. Small segments: every pair (as COLMAP's
// exhaustive matching). Else, known poses: pairs that can overlap (near and
// looking alike; distances in metres, the known frame's scale); SfM: pairs
// whose GPS positions are at most pair_max_distance apart.
std::vector<std::pair<size_t, size_t>> SegmentBuilder::candidate_pairs() const {
  std::vector<std::pair<size_t, size_t>> pairs;
  const size_t n = images_.size();
  if (ctx_.known) {
    pairs = n <= opt_.exhaustive_max_images
                ? overlapping_pairs(known_poses(), std::numeric_limits<double>::infinity(), 180)
                : overlapping_pairs(known_poses(), opt_.pair_max_distance / ctx_.enu_from_known.scale,
                                    opt_.pair_max_angle_deg);
  } else {
    for (size_t a = 0; a < n; ++a)
      for (size_t b = a + 1; b < n; ++b)
        if (n <= opt_.exhaustive_max_images ||
            (ctx_.enu[images_[a]] - ctx_.enu[images_[b]]).norm() <= opt_.pair_max_distance)
          pairs.emplace_back(a, b);
  }
  if (pairs.empty()) throw_error(ErrorCode::kInvalidArgument, "segment ", id_, ": no overlapping image pairs");
  return pairs;
}

// Known poses: epipolar-guided matching of the pairs that can overlap.
void SegmentBuilder::match_guided(ColmapDatabaseWriter& db) {
  t_stage_ = Timer();
  const std::vector<CameraPose> poses = known_poses();
  const auto pairs = candidate_pairs();
  res_.pairs = pairs.size();
  std::vector<CenteredKeypoints> centered(features_.size());
  for (size_t k = 0; k < features_.size(); ++k) centered[k].assign(features_[k], cameras_[k]);
  GuidedMatcher matcher(opt_.guided);
  const size_t report_every = std::max<size_t>(1, pairs.size() / 100);
  for (size_t p = 0; p < pairs.size(); ++p) {
    const auto [a, b] = pairs[p];
    const TwoViewGeometry g = two_view_geometry(cameras_[a], poses[a], cameras_[b], poses[b]);
    const auto& m = matcher.match(features_[a], centered[a], features_[b], centered[b], g);
    if (!m.empty()) {
      db.add_calibrated_pair(text_images_[a].image_id, text_images_[b].image_id, m, g.F, g.E, g.b_from_a_rotation,
                             g.b_from_a_direction);
      ++res_.matched_pairs;
      res_.matches += m.size();
    }
    if (p % report_every == 0) stage("matching", p, pairs.size());
  }
  stage("matching", pairs.size(), pairs.size());
  std::ostringstream summary;
  summary << "guided matching: " << pairs.size() << " pairs, " << res_.matched_pairs << " with >= "
          << opt_.guided.min_matches << " matches, " << res_.matches << " matches\n";
  std::ofstream(log_, std::ios::app) << summary.str();
}

// Our exact matching (1-1 and 1-M sets) verified by two-view RANSAC,
// 1m-sprt by default: the paper's one-many RANSAC on a segment's pairs. E
// when both cameras are known and undistorted (known poses), else F.
void SegmentBuilder::match_twoview(ColmapDatabaseWriter& db) {
  t_stage_ = Timer();
  const auto pairs = candidate_pairs();
  res_.pairs = pairs.size();
  auto calibration = [](const PinholeCamera& c) -> std::optional<Eigen::Matrix3d> {
    if (!c.has_focal || c.k1 != 0) return std::nullopt;
    Eigen::Matrix3d K;
    K << c.focal, 0, c.cx, 0, c.focal_y(), c.cy, 0, 0, 1;
    return K;
  };
  size_t extra_inliers = 0;
  const size_t report_every = std::max<size_t>(1, pairs.size() / 100);
  for (size_t p = 0; p < pairs.size(); ++p) {
    const auto [a, b] = pairs[p];
    PairVerificationOptions o = opt_.pair_verification;
    o.estimation.calibration1 = ctx_.known ? calibration(cameras_[a]) : std::nullopt;
    o.estimation.calibration2 = ctx_.known ? calibration(cameras_[b]) : std::nullopt;
    const bool essential = o.estimation.calibration1 && o.estimation.calibration2;
    o.estimation.model = essential ? TwoViewModel::kEssential : TwoViewModel::kFundamental;
    const VerifiedPair v = verify_image_pair(features_[a], features_[b], o);
    if (v.verified) {
      db.add_verified_pair(db_image_ids_[a], db_image_ids_[b], v.matches, v.inliers, v.estimate.fundamental,
                           essential ? std::optional<Eigen::Matrix3d>(v.estimate.matrix) : std::nullopt);
      ++res_.matched_pairs;
      res_.matches += v.inliers.size();
      extra_inliers += v.estimate.extra_inliers;
    }
    if (p % report_every == 0) stage("matching", p, pairs.size());
  }
  stage("matching", pairs.size(), pairs.size());
  std::ostringstream summary;
  summary << "twoview matching (" << to_string(opt_.pair_verification.estimation.variant) << "): " << pairs.size()
          << " pairs, " << res_.matched_pairs << " verified (>= " << opt_.pair_verification.min_inliers
          << " inliers, 1-1 inlier ratio >= " << opt_.pair_verification.min_inlier_ratio << "), " << res_.matches
          << " inliers written, one per feature of each image (1-M verification found " << extra_inliers
          << " inliers beyond the 1-1 ones)\n";
  std::ofstream(log_, std::ios::app) << summary.str();
}

// COLMAP's matching and verification (unless our matching did it).
void SegmentBuilder::match_with_colmap() {
  colmap_.emplace(opt_.colmap);
  if (matcher_ != PairMatcher::kColmap) return;
  t_stage_ = Timer();
  stage("matching");
  if (ctx_.known && images_.size() > opt_.exhaustive_max_images) {
    // Known poses: match only views that can overlap (near, looking alike).
    const auto pairs =
        overlapping_pairs(known_poses(), opt_.pair_max_distance / ctx_.enu_from_known.scale, opt_.pair_max_angle_deg);
    if (pairs.empty()) throw_error(ErrorCode::kInvalidArgument, "segment ", id_, ": no overlapping image pairs");
    std::ostringstream list;
    for (const auto& [a, b] : pairs) list << text_images_[a].name << ' ' << text_images_[b].name << '\n';
    res_.pairs = pairs.size();
    write_file_atomic(work_ / "pairs.txt", list.str());
    colmap_->match_pairs(db_path_, work_ / "pairs.txt", log_);
  } else {
    colmap_->match(db_path_, choose_match_strategy(images_.size(), true, opt_.exhaustive_max_images), log_);
  }
  res_.seconds_matching = t_stage_.elapsed_ms() / 1000;
}

// COLMAP: mapper, or with known poses point_triangulator (triangulation, then bundle adjustment).
void SegmentBuilder::reconstruct() {
  t_stage_ = Timer();
  stage(ctx_.known ? "triangulating" : "reconstructing (COLMAP mapper)");
  {
    ColmapStageWatcher watcher(log_, id_, ctx_.known ? report_ : SegmentProgressFn{});
    if (ctx_.known) {
      write_colmap_text_model(work_ / "known", text_cameras_, text_images_);
      model_dir_ = work_ / "sparse" / "0";
      colmap_->triangulate(db_path_, opt_.images_dir, work_ / "known", model_dir_, log_);
    } else {
      model_dir_ = colmap_->map(db_path_, opt_.images_dir, work_ / "sparse", log_);
    }
  }
  res_.seconds_triangulation = t_stage_.elapsed_ms() / 1000;
}

// The model COLMAP wrote and its statistics (tracks, reprojection errors).
void SegmentBuilder::read_model() {
  t_stage_ = Timer();
  stage("compressing");
  model_ = read_colmap_model(model_dir_);
  res_.registered_images = model_.images.size();
  if (model_.points.size() < 20)
    throw_error(ErrorCode::kExternalTool, "segment ", id_, ": COLMAP reconstructed only ", model_.points.size(),
                " points from ", images_.size(), " images (log: ", log_.string(), ")");
  double track_sum = 0, error_sum = 0;
  for (const auto& p : model_.points) {
    track_sum += static_cast<double>(p.track.size());
    error_sum += p.error;
    if (p.track.size() >= 3) ++res_.points_track3;
  }
  res_.mean_track_length = track_sum / static_cast<double>(model_.points.size());
  res_.mean_reprojection_error = error_sum / static_cast<double>(model_.points.size());
}

// Geo-registration: segment frame → ENU (known poses: the map's transform, residuals measured).
void SegmentBuilder::geo_register() {
  std::vector<Eigen::Vector3d> src, dst;
  std::map<std::string, size_t> record_of;
  for (size_t i : images_) record_of[ctx_.records[i].image] = i;
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  for (const auto& im : model_.images) {
    auto it = record_of.find(im.name);
    if (it == record_of.end()) continue;
    const CameraPose pose = colmap_image_pose(im);
    src.push_back(pose.center());
    up += camera_up(pose);
    dst.push_back(ctx_.enu[it->second]);
  }
  registration_images_ = src.size();
  if (ctx_.known) {
    enu_from_segment_ = ctx_.enu_from_known;
    res_.registration_inliers = static_cast<int>(src.size());
    std::vector<double> r;
    double sum2 = 0;
    for (size_t k = 0; k < src.size(); ++k) {
      r.push_back((enu_from_segment_.apply(src[k]) - dst[k]).norm());
      sum2 += r.back() * r.back();
    }
    std::sort(r.begin(), r.end());
    res_.registration_rms_m = r.empty() ? 0 : std::sqrt(sum2 / r.size());
    res_.registration_median_m = r.empty() ? 0 : r[r.size() / 2];
    res_.registration_max_m = r.empty() ? 0 : r.back();
  } else {
    const SimilarityEstimate e = estimate_street_similarity_ransac(src, dst, up, opt_.registration);
    enu_from_segment_ = e.transform;
    res_.registration_inliers = e.inlier_count;
    res_.registration_rms_m = e.rms_residual;
    res_.registration_median_m = e.median_residual;
    res_.registration_max_m = e.max_residual;
  }
}

// Compression: mean SIFT per point, ITQ codes (the segment's rotation or the
// map's), PQ with the map's codebook; the segment and descriptor files.
void SegmentBuilder::compress_and_write() {
  Timer t_part;
  ColmapDatabase db(db_path_);
  PointDescriptors desc = compute_point_descriptors(model_, db);
  const double ms_descriptors = t_part.elapsed_ms();
  SegmentBuildStats compression_stats;
  SegmentData data = make_segment_data(model_, desc, ctx_.codebook, opt_.itq, static_cast<uint32_t>(id_),
                                       &compression_stats, ctx_.map_hasher.get());
  if (opt_.segment_file.point_uncertainty)
    point_uncertainty_of_model(model_, &data.point_uncertainty, &data.keypoint_noise_px);
  std::vector<int> placemark_ids;
  for (int pm : ctx_.plan.segments[id_]) placemark_ids.push_back(ctx_.plan.placemarks[pm].id);
  data.extra_meta["enu_from_segment"] = similarity_json(enu_from_segment_);
  data.extra_meta["placemarks"] = placemark_ids;
  data.extra_meta["registration"] = {{"rms_m", res_.registration_rms_m},
                                     {"median_m", res_.registration_median_m},
                                     {"max_m", res_.registration_max_m},
                                     {"inliers", res_.registration_inliers},
                                     {"images", registration_images_}};
  fs::create_directories(ctx_.map_dir / "segments");
  fs::create_directories(ctx_.map_dir / "descriptors");
  const fs::path seg_path = segment_file(ctx_.map_dir, id_);
  write_segment_file(seg_path, data, opt_.segment_file);
  write_point_descriptor_file(ctx_.map_dir / "descriptors" / (segment_stem(id_) + ".vldesc"),
                              round_descriptors(desc.mean), desc.track_size);
  res_.points = data.num_points();
  {
    const std::string contents = read_file(seg_path);
    res_.file_bytes = contents.size();
    res_.file_crc32c = crc32c(contents.data(), contents.size());
  }
  res_.bytes_per_point = double(res_.file_bytes) / std::max<size_t>(1, res_.points);
  std::ostringstream line;
  line << std::fixed << std::setprecision(2) << "compression: point descriptors " << ms_descriptors / 1000
       << " s, ITQ " << compression_stats.ms_itq / 1000 << " s, encoding " << compression_stats.ms_encode / 1000
       << " s, total with files " << t_stage_.elapsed_ms() / 1000 << " s\n";
  std::ofstream(log_, std::ios::app) << line.str();
  res_.seconds_compression = t_stage_.elapsed_ms() / 1000;
}

// A segment's build (SegmentBuilder) with failures turned into a result (ok = false, error) and
// the result recorded in the segment's result.json.
SegmentBuildResult build_and_record_segment(const BuildContext& ctx, int id, const SegmentProgressFn& report) {
  SegmentBuildResult r;
  try {
    r = SegmentBuilder(ctx, id, report).run();
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kInternal) throw;
    r = SegmentBuildResult{};
    r.id = id;
    r.error = e.what();
  } catch (const std::filesystem::filesystem_error& e) {  // e.g. disk full, permissions
    r = SegmentBuildResult{};
    r.id = id;
    r.error = e.what();
  }
  fs::create_directories(segment_work_dir(ctx.map_dir, id));
  write_file_atomic(segment_result_file(ctx.map_dir, id), to_json(r).dump(2));
  return r;
}

// A finished segment from an earlier run (or another process): its
// result.json records success and its segment file exists.
// A segment finished by an earlier run, reused only if its codes were made
// with the rotation this build uses (`map_hasher`, or its own when null), and,
// with `want_point_uncertainty`, if it has the points' uncertainty (a build
// resumed with --point-uncertainty rebuilds the segments made without it).
std::optional<SegmentBuildResult> finished_segment(const fs::path& map_dir, int id,
                                                   const std::shared_ptr<const BinaryHasher>& map_hasher,
                                                   int pq_code_bytes, bool want_point_uncertainty) {
  const fs::path result_file = segment_result_file(map_dir, id);
  if (!fs::exists(result_file) || !fs::exists(segment_file(map_dir, id))) return std::nullopt;
  try {
    SegmentBuildResult r = segment_result_from_json(nlohmann::json::parse(read_file(result_file)));
    if (!r.ok || r.id != id) return std::nullopt;
    auto seg = Segment::open(segment_file(map_dir, id), map_hasher);  // rejects another map rotation
    if (seg->uses_map_hasher() != (map_hasher != nullptr)) return std::nullopt;  // the other scope: rebuild
    if (seg->index().pq_subvectors != pq_code_bytes) return std::nullopt;        // another codebook's codes: rebuild
    if (want_point_uncertainty && seg->point_uncertainty().empty()) return std::nullopt;
    return r;
  } catch (const std::exception&) {
  }
  return std::nullopt;
}

// The result of a segment that a task ran, or why there is none.
SegmentBuildResult recorded_segment(const fs::path& map_dir, int id) {
  const fs::path result_file = segment_result_file(map_dir, id);
  if (fs::exists(result_file)) {
    try {
      SegmentBuildResult r = segment_result_from_json(nlohmann::json::parse(read_file(result_file)));
      if (r.id == id && (!r.ok || fs::exists(segment_file(map_dir, id)))) return r;
    } catch (const std::exception&) {
    }
  }
  SegmentBuildResult r;
  r.id = id;
  r.error = "the task left no result";
  return r;
}

// Share of a segment's work done at a stage (for the map's ETA).
double stage_fraction(const SegmentProgress& p) {
  if (p.stage == "features") return p.total ? 0.02 * double(p.done) / double(p.total) : 0;
  if (p.stage == "database") return 0.02;
  if (p.stage == "matching") return p.total ? 0.05 + 0.45 * double(p.done) / double(p.total) : 0.05;
  if (p.stage == "triangulating") return 0.5;
  if (p.stage == "bundle adjustment") return 0.7;
  if (p.stage == "compressing") return 0.9;
  return 0;
}

}  // namespace

fs::path segment_work_dir(const fs::path& map_dir, int id) { return map_dir / "work" / ("seg" + segment_stem(id)); }

HashRotationScope resolve_hash_rotation(const fs::path& map_dir, const std::optional<HashRotationScope>& given) {
  if (given) return *given;
  if (fs::exists(map_dir / kHashRotationFileName)) return HashRotationScope::kMap;
  if (fs::exists(map_dir / "manifest.json")) return HashRotationScope::kSegment;
  return HashRotationScope::kMap;
}

PqQuantizer resolve_pq_quantizer(const fs::path& map_dir, const MapBuildOptions& options) {
  const fs::path codebook_path = map_dir / "pq_codebook.vlpq";
  if (!fs::exists(codebook_path)) return options.pq_quantizer.value_or(options.pq.quantizer);
  const PqQuantizer existing = PqCodebook::read(codebook_path).quantizer();
  if (options.pq_quantizer && *options.pq_quantizer != existing)
    throw_error(ErrorCode::kInvalidArgument, map_dir.string(), ": the map's PQ codes are of the ", to_string(existing),
                " quantizer (", codebook_path.string(), "); build it without --pq-quantizer (or with --pq-quantizer ",
                to_string(existing), "), or build ", to_string(*options.pq_quantizer), " codes into a new directory");
  return existing;
}

void resolve_pq_residual(const fs::path& map_dir, const MapBuildOptions& options, PqTrainingOptions& pq) {
  const fs::path codebook_path = map_dir / "pq_codebook.vlpq";
  if (!fs::exists(codebook_path)) {
    pq.residual_splits = options.pq_residual_splits.value_or(options.pq.residual_splits);
    pq.residual_beam = options.pq_residual_beam.value_or(options.pq.residual_beam);
    return;
  }
  const PqCodebook existing = PqCodebook::read(codebook_path);
  if (!existing.is_residual()) return;
  auto refuse_unlike = [&](const std::optional<int>& given, int has, const char* flag, const std::string& what) {
    if (given && *given != has)
      throw_error(ErrorCode::kInvalidArgument, map_dir.string(), ": the map's residual codes ", what, " (",
                  codebook_path.string(), "); build it without ", flag, " (or with ", flag, " ", has,
                  "), or build codes with ", flag, " ", *given, " into a new directory");
  };
  refuse_unlike(options.pq_residual_splits, existing.residual_splits(), "--pq-residual-splits",
                "are over " + std::to_string(existing.residual_splits()) + " part(s)");
  refuse_unlike(options.pq_residual_beam, existing.residual_beam(), "--pq-residual-beam",
                "have a beam of " + std::to_string(existing.residual_beam()));
  pq.residual_splits = existing.residual_splits();
  pq.residual_beam = existing.residual_beam();
}

int resolve_pq_code_bytes(const fs::path& map_dir, const MapBuildOptions& options) {
  const fs::path codebook_path = map_dir / "pq_codebook.vlpq";
  if (!fs::exists(codebook_path)) return options.pq_code_bytes.value_or(options.pq.subvectors);
  const int existing = PqCodebook::read(codebook_path).code_bytes();
  if (options.pq_code_bytes && *options.pq_code_bytes != existing)
    throw_error(ErrorCode::kInvalidArgument, map_dir.string(), ": the map has ", existing, "-byte PQ codes (",
                codebook_path.string(), "); build it without --pq-bytes (or with --pq-bytes ", existing, "), or build ",
                *options.pq_code_bytes, "-byte codes into a new directory");
  return existing;
}

SegmentBuildResult build_planned_segment(const fs::path& map_dir, const MapBuildOptions& options, int segment) {
  MapBuildOptions opt = options;
  opt.hash_rotation = resolve_hash_rotation(map_dir, options.hash_rotation);
  opt.validate();
  opt.pq.subvectors = resolve_pq_code_bytes(map_dir, opt);  // refuses an explicit size unlike the map's
  opt.pq.quantizer = resolve_pq_quantizer(map_dir, opt);    // and a quantizer unlike its
  resolve_pq_residual(map_dir, opt, opt.pq);                // and residual parts or beam unlike its
  opt.pq.validate();                                        // e.g. residual with 32-byte codes
  const fs::path codebook_path = map_dir / "pq_codebook.vlpq";
  if (!fs::exists(map_dir / "manifest.json") || !fs::exists(codebook_path))
    throw_error(ErrorCode::kNotFound, map_dir.string(),
                ": not a planned map (no manifest.json or pq_codebook.vlpq); start it with 'visloc map build'");
  BuildContext ctx = prepare_context(map_dir, opt);
  if (segment < 0 || segment >= static_cast<int>(ctx.plan.segments.size()))
    throw_error(ErrorCode::kInvalidArgument, "segment ", segment, " does not exist (the map has ",
                ctx.plan.segments.size(), ")");
  {
    // The inputs must still give the plan the build started from.
    const fs::path plan_file = map_dir / "work" / "plan.json";
    std::vector<std::string> planned;
    try {
      planned = nlohmann::json::parse(read_file(plan_file)).at("segments").at(segment).get<std::vector<std::string>>();
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      throw_error(ErrorCode::kFormat, plan_file.string(), ": no plan for segment ", segment, ": ", e.what());
    }
    if (planned != segment_images(ctx, segment))
      throw_error(ErrorCode::kInvalidArgument, "segment ", segment, ": the images and GPS now give another plan than ",
                  plan_file.string(), " (inputs changed since 'map build' started?); run 'map build' again");
  }
  ctx.codebook = PqCodebook::read(codebook_path);
  if (opt.hash_rotation == HashRotationScope::kMap) {
    const fs::path rotation_path = map_dir / kHashRotationFileName;
    if (!fs::exists(rotation_path))
      throw_error(ErrorCode::kNotFound, rotation_path.string(), ": the map's hash rotation is missing; run 'map build'");
    ctx.map_hasher = std::make_shared<const BinaryHasher>(read_hash_rotation_file(rotation_path));
  }
  // Progress for the coordinator, which polls it: a file rewritten on every stage change.
  std::string last_stage;
  Timer since_write;
  auto report = [&](const SegmentProgress& p) {
    if (p.stage == last_stage && since_write.elapsed_ms() < 1000 && p.done != p.total) return;
    last_stage = p.stage;
    since_write = Timer();
    try {
      write_file_atomic(segment_progress_file(map_dir, segment),
                        nlohmann::json{{"stage", p.stage}, {"done", p.done}, {"total", p.total}}.dump());
    } catch (const std::exception&) {  // progress is best effort
    }
  };
  SegmentBuildResult r = build_and_record_segment(ctx, segment, report);
  std::error_code ec;
  fs::remove(segment_progress_file(map_dir, segment), ec);
  return r;
}

namespace {

// A result is looked for by listing its directory, which makes a shared
// filesystem revalidate what it cached about that directory.
bool has_result(const fs::path& map_dir, int id) {
  std::error_code ec;
  for (fs::directory_iterator it(segment_work_dir(map_dir, id), ec), end; !ec && it != end; it.increment(ec))
    if (it->path().filename() == "result.json") return true;
  return false;
}

}  // namespace

// What the stages of a map's build share.
struct MapBuilder::State {
  fs::path map_dir;
  MapBuildOptions opt;
  ProgressFn progress;
  Timer total;
  int jobs = 1;
  fs::path slurm_dir, active_file;       // MAP/work/slurm, and the arrays that may be running there
  fs::path codebook_path, rotation_path;  // the map's PQ codebook and hash rotation
  BuildContext ctx;
  MapBuildResult result;
  // Segments: which, and the live state of the running ones (for progress and the ETA).
  Timer t_segments;
  size_t n_segments = 0;
  std::set<int> only;
  std::vector<int> to_build;
  size_t segments_done = 0;
  std::mutex state_mutex;
  std::map<int, SegmentProgress> running;
  size_t to_build_total = 0;
  size_t built = 0;
  double seconds_built = 0;
  size_t concurrency = 1;  // segments built at once: the local threads, or on Slurm as many as run (at least 1)
};

// Slurm: arrays of at most max_array_size tasks; task k of an array builds
// the k-th segment of its task list.
struct MapBuilder::SlurmRun {
  struct Submitted {
    SlurmArray array;
    std::vector<int> segments;
    SlurmArray::State state = SlurmArray::State::kRunning;
  };
  std::vector<Submitted> arrays;
  std::map<int, std::pair<size_t, int>> task_of;  // segment → (array, task index)
  std::string active;                              // job ids, one a line (as in active_file)
  std::set<int> pending;                           // segments without a result yet
  std::string task_name(int id) const {
    const auto [a, k] = task_of.at(id);
    return arrays[a].array.job_id() + "_" + std::to_string(k);
  }
  std::string task_log(int id) const {
    const auto [a, k] = task_of.at(id);
    return arrays[a].array.task_log(k).string();
  }
};

MapBuilder::MapBuilder(fs::path map_dir, const MapBuildOptions& options, ProgressFn progress)
    : state_(std::make_unique<State>()) {
  state_->map_dir = std::move(map_dir);
  state_->opt = options;
  state_->progress = std::move(progress);
}

MapBuilder::~MapBuilder() = default;

MapBuildResult MapBuilder::run() {
  State& s = *state_;
  s.opt.validate();
  s.total = Timer();
  s.jobs = s.opt.jobs > 0 ? s.opt.jobs : std::max(1u, std::thread::hardware_concurrency());
  s.opt.hash_rotation = resolve_hash_rotation(s.map_dir, s.opt.hash_rotation);
  s.opt.pq.subvectors = resolve_pq_code_bytes(s.map_dir, s.opt);  // before anything is written
  s.opt.pq.quantizer = resolve_pq_quantizer(s.map_dir, s.opt);
  resolve_pq_residual(s.map_dir, s.opt, s.opt.pq);
  s.opt.pq.validate();  // e.g. residual with 32-byte codes, before anything is written
  fs::create_directories(s.map_dir / "work" / "features");
  const BuildLock lock(s.map_dir / "work" / "build.lock");
  check_earlier_slurm_arrays();
  if (!s.opt.build_record.empty()) write_file_atomic(s.map_dir / "work" / "build.json", s.opt.build_record);
  plan_segments();
  extract_features();
  train_codebook();
  select_segments();
  if (s.opt.executor == BuildExecutor::kLocal) build_segments_local();
  else if (!s.to_build.empty()) build_segments_slurm();
  s.result.seconds_segments = s.t_segments.elapsed_ms() / 1000;
  build_retrieval();
  fit_hash_blend();
  s.result.seconds_total = s.total.elapsed_ms() / 1000;
  return std::move(s.result);
}

// An array of an interrupted Slurm run may still be building segments of this map.
void MapBuilder::check_earlier_slurm_arrays() {
  State& s = *state_;
  s.slurm_dir = s.map_dir / "work" / "slurm";
  s.active_file = s.slurm_dir / "active_job";
  if (!fs::exists(s.active_file)) return;
  std::istringstream jobs_listed(read_file(s.active_file));
  for (std::string earlier; jobs_listed >> earlier;)
    if (SlurmArray::attach(s.opt.slurm, earlier, s.slurm_dir).poll() != SlurmArray::State::kDone)
      throw_error(ErrorCode::kInvalidArgument, "map build: Slurm array ", earlier, " of an earlier run may still be ",
                  "building segments of ", s.map_dir.string(), "; wait for it to end or cancel it (scancel ", earlier,
                  "), then run this again (or, if no task can run any more, delete ", s.active_file.string(), ")");
  std::error_code ec;
  fs::remove(s.active_file, ec);
}

void MapBuilder::plan_segments() {
  State& s = *state_;
  s.ctx = prepare_context(s.map_dir, s.opt);
  // A segment finished under another plan (other segment sizes, other
  // inputs) is built again: its result is forgotten when its images differ.
  const fs::path plan_path = s.map_dir / "work" / "plan.json";
  const nlohmann::json plan = plan_json(s.ctx);
  if (fs::exists(plan_path)) {
    nlohmann::json earlier = nlohmann::json::parse(read_file(plan_path), nullptr, false);
    const bool usable = !earlier.is_discarded() && earlier.is_object() && earlier.contains("segments") &&
                        earlier["segments"].is_array();
    const size_t n_new = plan["segments"].size();
    const size_t n_old = usable ? earlier["segments"].size() : 0;
    std::error_code ec;
    for (size_t id = 0; id < std::max(n_new, n_old); ++id) {
      const bool same = usable && id < n_old && id < n_new && earlier["segments"][id] == plan["segments"][id];
      if (!same) fs::remove(segment_result_file(s.map_dir, static_cast<int>(id)), ec);
    }
  }
  write_file_atomic(plan_path, plan.dump());
  s.result.images = s.ctx.records.size();
  s.result.placemarks = s.ctx.plan.placemarks.size();
}

// Features, once per image (segments overlap), in parallel; cached. On
// Slurm only those that train the PQ codebook: the tasks extract the rest.
void MapBuilder::extract_features() {
  State& s = *state_;
  Timer t_features;
  std::vector<size_t> records;
  if (s.opt.executor == BuildExecutor::kSlurm) {
    records = pq_training_records(s.ctx);
  } else {
    records.resize(s.ctx.records.size());
    std::iota(records.begin(), records.end(), size_t{0});
  }
  ensure_features(s.ctx, records, s.jobs, true, [&](size_t d) {
    if (s.progress) s.progress({"features", d, records.size(), s.total.elapsed_ms() / 1000, {}, -1});
  });
  s.result.seconds_features = t_features.elapsed_ms() / 1000;
}

// The PQ codebook (and, with a map rotation, the ITQ rotation): trained
// once per map on descriptors sampled across all images.
void MapBuilder::train_codebook() {
  State& s = *state_;
  const MapBuildOptions& opt = s.opt;
  BuildContext& ctx = s.ctx;
  s.codebook_path = s.map_dir / "pq_codebook.vlpq";
  s.rotation_path = s.map_dir / kHashRotationFileName;
  const bool map_rotation = opt.hash_rotation == HashRotationScope::kMap;
  if (fs::exists(s.codebook_path)) {
    ctx.codebook = PqCodebook::read(s.codebook_path);
    VISLOC_CHECK(ctx.codebook.code_bytes() == opt.pq.subvectors, "(resolve_pq_code_bytes ran before)");
    VISLOC_CHECK(ctx.codebook.quantizer() == opt.pq.quantizer, "(resolve_pq_quantizer ran before)");
  }
  if (map_rotation && fs::exists(s.rotation_path))
    ctx.map_hasher = std::make_shared<const BinaryHasher>(read_hash_rotation_file(s.rotation_path));
  if (!ctx.codebook.empty() && (!map_rotation || ctx.map_hasher)) return;
  const std::vector<size_t> training = pq_training_records(ctx);
  const size_t per_image = (opt.pq_training_descriptors + training.size() - 1) / training.size();
  std::vector<float> sample;
  RandomGenerator rng(opt.pq.seed);
  for (size_t i : training) {
    FeatureSet f = read_feature_file(feature_path(ctx, ctx.records[i].image));
    std::vector<size_t> rows(f.size());
    for (size_t k = 0; k < rows.size(); ++k) rows[k] = k;
    shuffle(rows.begin(), rows.end(), rng);
    rows.resize(std::min(rows.size(), per_image));
    for (size_t k : rows)
      for (int d = 0; d < kDescriptorDim; ++d) sample.push_back(f.descriptors.row(k)[d]);
  }
  const size_t training_count = sample.size() / kDescriptorDim;
  if (ctx.codebook.empty()) {
    ctx.codebook = PqCodebook::train(sample.data(), training_count, opt.pq);
    nlohmann::json pq_meta = {{"dimension", kDescriptorDim},
                              {"subvectors", ctx.codebook.subvectors()},
                              {"bits", 8},
                              {"training_descriptors", opt.pq.training_rows(training_count)},
                              {"training_source", "image descriptors sampled across the map"},
                              {"seed", opt.pq.seed}};
    pq_meta.update(nlohmann::json::parse(ctx.codebook.quantizer_json()));
    ctx.codebook.write(s.codebook_path, pq_meta.dump());
  }
  if (map_rotation && !ctx.map_hasher) {
    ItqResult itq = train_itq(sample.data(), training_count, opt.itq);
    write_hash_rotation_file(s.rotation_path, itq.hasher,
                             nlohmann::json{{"training_descriptors", training_count},
                                            {"training_source", "image descriptors sampled across the map"},
                                            {"itq_iterations", opt.itq.iterations},
                                            {"seed", opt.itq.seed}}
                                 .dump());
    ctx.map_hasher = std::make_shared<const BinaryHasher>(std::move(itq.hasher));
  }
}

// Which segments to build: not finished earlier (or asked for by update).
// Each one's outcome is recorded as soon as it ends; the first manifest
// holds the ENU origin and plan before any task reads them.
void MapBuilder::select_segments() {
  State& s = *state_;
  s.t_segments = Timer();
  s.n_segments = s.ctx.plan.segments.size();
  s.result.segments.resize(s.n_segments);
  for (size_t k = 0; k < s.n_segments; ++k) {
    s.result.segments[k].id = static_cast<int>(k);
    s.result.segments[k].error = "not built";
  }
  s.only = std::set<int>(s.opt.only_segments.begin(), s.opt.only_segments.end());
  for (int id : s.only)
    if (id < 0 || id >= static_cast<int>(s.n_segments))
      throw_error(ErrorCode::kInvalidArgument, "segment ", id, " does not exist (the map has ", s.n_segments, ")");
  for (size_t k = 0; k < s.n_segments; ++k) {
    const int id = static_cast<int>(k);
    if (!s.only.count(id)) {
      // An update (only some segments) keeps the others with or without the
      // points' uncertainty: the localizer takes each segment as it is.
      const bool want_point_uncertainty = s.opt.segment_file.point_uncertainty && s.only.empty();
      if (auto r =
              finished_segment(s.map_dir, id, s.ctx.map_hasher, s.ctx.codebook.code_bytes(), want_point_uncertainty)) {
        s.result.segments[k] = *r;
        s.result.segments[k].reused = true;
        ++s.segments_done;
        continue;
      }
      // An update keeps the other segments as they are: one that cannot be
      // kept (another hash rotation or code size) would drop out of the map.
      if (!s.only.empty() && fs::exists(segment_file(s.map_dir, id)))
        throw_error(ErrorCode::kInvalidArgument, "segment ", id, " of ", s.map_dir.string(),
                    " was built with another hash rotation than --hash-rotation ", to_string(*s.opt.hash_rotation),
                    " gives, or with PQ codes of another size than the map's ", s.ctx.codebook.code_bytes(),
                    " bytes (or is damaged); update with the same options, or rebuild the map with 'map build'");
    }
    if (s.only.empty() || s.only.count(id)) s.to_build.push_back(id);
  }
  write_current_manifest();
  s.to_build_total = s.to_build.size();
  s.concurrency = static_cast<size_t>(s.jobs);
}

void MapBuilder::write_current_manifest() {
  const State& s = *state_;
  const MapBuildOptions& opt = s.opt;
  MapManifest man;
  man.enu_origin_lat_lon_alt = std::array<double, 3>{s.ctx.origin.lat, s.ctx.origin.lon, s.ctx.origin.alt};
  nlohmann::json plan_json = nlohmann::json::array();
  for (size_t k = 0; k < s.n_segments; ++k) {
    nlohmann::json pms = nlohmann::json::array();
    for (int pm : s.ctx.plan.segments[k]) pms.push_back(s.ctx.plan.placemarks[pm].id);
    plan_json.push_back(pms);
  }
  nlohmann::json failed = nlohmann::json::array();
  for (const auto& r : s.result.segments)
    if (!r.ok && !r.error.empty() && r.error != "not built") failed.push_back({{"id", r.id}, {"error", r.error}});
  // Listed whenever present: a segment of an earlier run may need it.
  if (fs::exists(s.rotation_path)) man.hash_rotation_file = kHashRotationFileName;
  nlohmann::json pq_parameters = {{"subvectors", s.ctx.codebook.subvectors()}, {"bits", 8}, {"seed", opt.pq.seed}};
  pq_parameters.update(nlohmann::json::parse(s.ctx.codebook.quantizer_json()));
  man.parameters = {{"hash",
                     {{"method", "itq"},
                      {"bits", kHashBits},
                      {"tables", kHashTables},
                      {"table_bits", kHashTableBits},
                      {"itq_iterations", opt.itq.iterations},
                      {"seed", opt.itq.seed},
                      {"rotation", to_string(opt.hash_rotation.value_or(HashRotationScope::kMap))}}},
                    {"pq", pq_parameters},
                    {"point_descriptor", "mean of track"},
                    {"sift", nlohmann::json::parse(opt.sift.to_json())},
                    {"segments",
                     {{"min_placemarks", opt.plan.min_placemarks},
                      {"max_placemarks", opt.plan.max_placemarks},
                      {"overlap", opt.plan.overlap}}},
                    {"matcher", std::string(to_string(opt.effective_matcher()))}};
  if (opt.effective_matcher() == PairMatcher::kTwoView)
    man.parameters["pair_verification"] = {
        {"ransac", std::string(to_string(opt.pair_verification.estimation.variant))},
        {"threshold_px", opt.pair_verification.estimation.threshold_px},
        {"min_inliers", opt.pair_verification.min_inliers},
        {"min_inlier_ratio", opt.pair_verification.min_inlier_ratio}};
  man.source = {{"type", "build"},
                {"images", fs::absolute(opt.images_dir).string()},
                {"gps", opt.gps_csv.empty() ? std::string("exif") : fs::absolute(opt.gps_csv).string()},
                {"poses", opt.poses == PoseSource::kKnown ? "known" : "sfm"},
                {"segment_placemarks", plan_json},
                {"failed_segments", failed}};
  // A weight fitted earlier is kept: it counts only while the segments it was
  // fitted on are the map's (MapManifest::fitted_hash_blend), and
  // fit_hash_blend() replaces it at the end of a run that asks for it.
  std::error_code exists_error;
  if (fs::exists(s.map_dir / "manifest.json", exists_error)) {
    try {
      man.hash_blend = read_manifest(s.map_dir).hash_blend;
    } catch (const Error&) {
      // An unreadable old manifest is replaced whole, without it.
    }
  }
  for (const auto& r : s.result.segments) {
    if (!r.ok) continue;
    const std::string file = "segments/" + segment_stem(r.id) + ".vlseg";
    man.segments.push_back({static_cast<uint32_t>(r.id), file, "descriptors/" + segment_stem(r.id) + ".vldesc",
                            r.points, r.registered_images, r.file_bytes, r.file_crc32c});
  }
  visloc::write_manifest(s.map_dir, man);
}

void MapBuilder::report_segments() {
  State& s = *state_;
  if (!s.progress) return;
  MapBuildProgress p{"segments", s.segments_done, s.n_segments, s.total.elapsed_ms() / 1000, {}, -1};
  double partial = 0;
  for (const auto& [id, sp] : s.running) {
    p.running.push_back(sp);
    partial += stage_fraction(sp);
  }
  const double work_done = static_cast<double>(s.built) + partial;
  const double remaining = static_cast<double>(s.to_build_total) - work_done;
  const double elapsed = s.t_segments.elapsed_ms() / 1000;
  if (s.built > 0) {
    // Measured: seconds per segment of those finished in this run, spread
    // over the segments built at once.
    const double parallel = std::max<double>(1.0, std::min<double>(static_cast<double>(s.concurrency),
                                                                   static_cast<double>(s.to_build_total)));
    p.eta_s = s.seconds_built / static_cast<double>(s.built) * remaining / parallel;
  } else if (work_done > 0.25 && elapsed > 1) {
    p.eta_s = elapsed / work_done * remaining;  // from the stages of the running segments
  }
  s.progress(p);
}

void MapBuilder::segment_finished(const SegmentBuildResult& r) {
  State& s = *state_;
  s.result.segments[r.id] = r;
  s.running.erase(r.id);
  ++s.built;
  s.seconds_built += r.seconds;
  ++s.segments_done;
  write_current_manifest();
  report_segments();
}

void MapBuilder::build_segments_local() {
  State& s = *state_;
  parallel_for(s.to_build.size(), s.jobs, [&](size_t k) {
    const int id = s.to_build[k];
    auto report = [&](const SegmentProgress& p) {
      std::lock_guard lock(s.state_mutex);
      s.running[id] = p;
      report_segments();
    };
    SegmentBuildResult r = build_and_record_segment(s.ctx, id, report);
    std::lock_guard lock(s.state_mutex);
    segment_finished(r);
  });
}

// Tasks write result.json (and progress.json while they run); the arrays are
// watched until they end, then results still on their way are waited for.
void MapBuilder::build_segments_slurm() {
  State& s = *state_;
  for (int id : s.to_build) {
    std::error_code ec;
    fs::remove(segment_result_file(s.map_dir, id), ec);
    fs::remove(segment_progress_file(s.map_dir, id), ec);
  }
  SlurmRun run;
  submit_slurm_arrays(run);
  run.pending = std::set<int>(s.to_build.begin(), s.to_build.end());
  s.concurrency = 1;
  wait_for_slurm_arrays(run);
  settle_slurm_tasks(run);
  std::error_code ec;
  fs::remove(s.active_file, ec);
}

void MapBuilder::submit_slurm_arrays(SlurmRun& run) {
  const State& s = *state_;
  const std::string stamp = std::to_string(std::chrono::duration_cast<std::chrono::milliseconds>(
                                               std::chrono::system_clock::now().time_since_epoch())
                                               .count());
  const std::vector<int>& to_build = s.to_build;
  for (size_t first = 0; first < to_build.size(); first += s.opt.slurm.max_array_size) {
    const std::vector<int> chunk(
        to_build.begin() + static_cast<std::ptrdiff_t>(first),
        to_build.begin() + static_cast<std::ptrdiff_t>(std::min(to_build.size(), first + s.opt.slurm.max_array_size)));
    const fs::path list = s.slurm_dir / ("tasks-" + stamp + "-" + std::to_string(run.arrays.size()) + ".txt");
    std::string text;
    for (int id : chunk) text += std::to_string(id) + "\n";
    fs::create_directories(s.slurm_dir);
    write_file_atomic(list, text);
    std::vector<int> indices(chunk.size());
    std::iota(indices.begin(), indices.end(), 0);
    std::vector<std::string> command = s.opt.slurm_task_command;
    command.insert(command.end(), {"--task-list", fs::absolute(list).string()});
    run.arrays.push_back({SlurmArray::submit(s.opt.slurm, indices, command, s.slurm_dir), chunk});
    for (size_t k = 0; k < chunk.size(); ++k) run.task_of[chunk[k]] = {run.arrays.size() - 1, static_cast<int>(k)};
    run.active += run.arrays.back().array.job_id() + "\n";
    write_file_atomic(s.active_file, run.active);
  }
}

// Results that appeared, and progress of the rest.
void MapBuilder::collect_slurm_results(SlurmRun& run) {
  State& s = *state_;
  std::vector<int> ended;
  std::lock_guard lock(s.state_mutex);
  for (int id : run.pending) {
    if (has_result(s.map_dir, id)) {
      SegmentBuildResult r = recorded_segment(s.map_dir, id);
      if (!r.ok) r.error += " (Slurm task " + run.task_name(id) + ", log: " + run.task_log(id) + ")";
      segment_finished(r);
      ended.push_back(id);
      continue;
    }
    try {
      const auto j = nlohmann::json::parse(read_file(segment_progress_file(s.map_dir, id)));
      s.running[id] = {id, j.at("stage").get<std::string>(), j.at("done").get<size_t>(), j.at("total").get<size_t>()};
    } catch (const std::exception&) {  // not started yet, or mid-rename
    }
  }
  for (int id : ended) run.pending.erase(id);
  s.concurrency = std::max<size_t>(s.concurrency, std::max<size_t>(1, s.running.size()));
  report_segments();
}

// Until every result is in or no array runs any more.
void MapBuilder::wait_for_slurm_arrays(SlurmRun& run) {
  const SlurmOptions& slurm = state_->opt.slurm;
  Timer since_poll, unreachable;
  bool any_running = true;
  while (!run.pending.empty() && any_running) {
    std::this_thread::sleep_for(std::chrono::seconds(1));
    collect_slurm_results(run);
    if (since_poll.elapsed_ms() < slurm.poll_seconds * 1000) continue;
    since_poll = Timer();
    any_running = false;
    bool any_unknown = false;
    for (auto& a : run.arrays) {
      if (a.state != SlurmArray::State::kDone) a.state = a.array.poll();
      any_running |= a.state != SlurmArray::State::kDone;
      any_unknown |= a.state == SlurmArray::State::kUnknown;
    }
    if (!any_unknown) unreachable = Timer();
    if (unreachable.elapsed_ms() > slurm.unreachable_seconds * 1000)
      throw_error(ErrorCode::kExternalTool, "map build: squeue has failed for ", slurm.unreachable_seconds,
                  " s; the arrays (", run.active.substr(0, run.active.size() - 1),
                  ") are left running; run the same command again once Slurm answers");
  }
}

// The arrays are gone: results may still be on their way through a shared
// filesystem. Tasks that Slurm reports as failed are not waited for.
void MapBuilder::settle_slurm_tasks(SlurmRun& run) {
  State& s = *state_;
  Timer grace;
  while (!run.pending.empty()) {
    collect_slurm_results(run);
    if (run.pending.empty()) break;
    std::map<size_t, std::map<int, SlurmTaskState>> states;
    for (size_t a = 0; a < run.arrays.size(); ++a) states[a] = run.arrays[a].array.task_states();
    bool wait = false;
    for (int id : run.pending) {
      const auto [a, k] = run.task_of.at(id);
      const auto st = states[a].find(k);
      const bool known_failure = st != states[a].end() && !st->second.state.empty() && st->second.state != "COMPLETED";
      if (!known_failure && grace.elapsed_ms() < s.opt.slurm.result_grace_seconds * 1000) wait = true;
    }
    if (wait) {
      std::this_thread::sleep_for(std::chrono::seconds(2));
      continue;
    }
    std::lock_guard lock(s.state_mutex);
    for (int id : run.pending) {
      const auto [a, k] = run.task_of.at(id);
      std::ostringstream why;
      why << "Slurm task " << run.task_name(id) << " left no result";
      const auto st = states[a].find(k);
      if (st != states[a].end())
        why << " (" << st->second.state << ", exit " << st->second.exit_code << ":" << st->second.signal << ")";
      why << "; log: " << run.task_log(id);
      SegmentBuildResult r;
      r.id = id;
      r.error = why.str();
      segment_finished(r);
    }
    run.pending.clear();
  }
}

// Retrieval over the images of the segments that were built.
void MapBuilder::fit_hash_blend() {
  State& s = *state_;
  if (!s.opt.fit_hash_blend.value_or(true) || s.result.failed() >= s.n_segments) return;
  Timer t;
  if (s.progress) s.progress({"hash blend", 0, 1, s.total.elapsed_ms() / 1000, {}, -1});
  MapBlendFit fit;
  try {
    fit = fit_map_hash_blend(s.map_dir, s.opt.hash_blend);
  } catch (const std::exception& e) {
    if (!s.opt.fit_hash_blend.has_value()) {  // the default: the map is whole without it
      s.result.hash_blend_error = e.what();
      if (s.progress) s.progress({"hash blend", 1, 1, s.total.elapsed_ms() / 1000, {}, -1});
      return;
    }
    const auto* error = dynamic_cast<const Error*>(&e);
    if (!error) throw;
    throw_error(error->code(), s.map_dir.string(), ": map build: the segments are built, but fitting the hash blend ",
                "(--fit-blend) failed (the map works without it; 'visloc map fit-blend' fits it alone): ", e.what());
  }
  store_map_hash_blend(s.map_dir, fit, /*lock_build=*/false);  // this build holds the lock
  s.result.hash_blend_weight = fit.fit.weight;
  s.result.seconds_hash_blend = t.elapsed_ms() / 1000;
  if (s.progress) s.progress({"hash blend", 1, 1, s.total.elapsed_ms() / 1000, {}, -1});
}

void MapBuilder::build_retrieval() {
  State& s = *state_;
  if (!s.opt.build_retrieval || s.result.failed() >= s.n_segments) return;
  Timer t_retrieval;
  if (s.progress) s.progress({"retrieval", 0, 1, s.total.elapsed_ms() / 1000, {}, -1});
  std::vector<std::vector<int32_t>> segments_of_record(s.ctx.records.size());
  for (const auto& r : s.result.segments) {
    if (!r.ok) continue;
    for (int pm : s.ctx.plan.segments[r.id])
      for (size_t i : s.ctx.plan.placemarks[pm].images) segments_of_record[i].push_back(r.id);
  }
  std::vector<std::string> names;
  std::vector<DescriptorMatrix> descriptors;
  std::vector<std::vector<int32_t>> segments_of_image;
  for (size_t i = 0; i < s.ctx.records.size(); ++i) {
    if (segments_of_record[i].empty()) continue;
    names.push_back(s.ctx.records[i].image);
    descriptors.push_back(read_feature_file(feature_path(s.ctx, s.ctx.records[i].image)).descriptors);
    segments_of_image.push_back(segments_of_record[i]);
  }
  std::vector<const DescriptorMatrix*> pointers;
  for (const auto& d : descriptors) pointers.push_back(&d);
  RetrievalMap::build(pointers, names, SegmentTable(segments_of_image), s.opt.embedding, s.opt.image_index)
      .save(s.map_dir / "retrieval");
  s.result.seconds_retrieval = t_retrieval.elapsed_ms() / 1000;
  if (s.progress) s.progress({"retrieval", 1, 1, s.total.elapsed_ms() / 1000, {}, -1});
}

MapBuildResult build_map(const fs::path& map_dir, const MapBuildOptions& opt,
                         const std::function<void(const MapBuildProgress&)>& progress) {
  return MapBuilder(map_dir, opt, progress).run();
}

nlohmann::json to_json(const MapBuildResult& r) {
  nlohmann::json segments = nlohmann::json::array();
  for (const auto& s : r.segments) {
    nlohmann::json j = to_json(s);  // as in MAP/work/segNNNN/result.json
    j["reused"] = s.reused;
    segments.push_back(std::move(j));
  }
  return {{"images", r.images},
          {"placemarks", r.placemarks},
          {"failed", r.failed()},
          {"segments", segments},
          {"seconds",
           {{"features", r.seconds_features},
            {"segments", r.seconds_segments},
            {"retrieval", r.seconds_retrieval},
            {"hash_blend", r.seconds_hash_blend},
            {"total", r.seconds_total}}},
          {"hash_blend_weight", r.hash_blend_weight ? nlohmann::json(*r.hash_blend_weight) : nlohmann::json()},
          {"hash_blend_error", r.hash_blend_error}};
}

std::string build_summary(const MapBuildResult& r) {
  std::ostringstream out;
  out << std::left << std::setw(8) << "segment" << std::right << std::setw(8) << "images" << std::setw(11)
      << "registered" << std::setw(9) << "points" << std::setw(10) << "B/point" << std::setw(12) << "GPS rms m"
      << std::setw(12) << "GPS max m" << std::setw(10) << "seconds" << std::setw(9) << "match s" << std::setw(9)
      << "triang s" << "  status\n";
  for (const auto& s : r.segments) {
    out << std::left << std::setw(8) << s.id << std::right << std::setw(8) << s.images << std::setw(11)
        << s.registered_images << std::setw(9) << s.points << std::fixed << std::setprecision(1) << std::setw(10)
        << s.bytes_per_point << std::setprecision(2) << std::setw(12) << s.registration_rms_m << std::setw(12)
        << s.registration_max_m << std::setprecision(1) << std::setw(10) << s.seconds << std::setw(9)
        << s.seconds_matching << std::setw(9) << s.seconds_triangulation << "  "
        << (s.ok ? (s.reused ? "reused" : "ok") : "FAILED: " + s.error) << "\n";
  }
  out << r.images << " images, " << r.placemarks << " placemarks, " << r.segments.size() << " segments ("
      << r.failed() << " failed); features " << std::setprecision(1) << r.seconds_features << " s, segments "
      << r.seconds_segments << " s, total " << r.seconds_total << " s\n";
  if (r.hash_blend_weight)
    out << std::setprecision(2) << "hash blend weight " << *r.hash_blend_weight
        << " fitted on the map and stored (localize and eval use it by default)\n";
  if (!r.hash_blend_error.empty())
    out << "warning: the hash blend was not fitted (the search ranks by the PQ distance alone on this map): "
        << r.hash_blend_error << "\n";
  return out.str();
}

std::string segment_summary(const SegmentBuildResult& r) {
  std::ostringstream out;
  out << "segment " << r.id << ": " << r.images << " images, " << r.points << " points, " << std::fixed
      << std::setprecision(1) << r.seconds << " s (matching " << r.seconds_matching << " s, triangulation "
      << r.seconds_triangulation << " s)\n";
  return out.str();
}

BuildRecord read_build_record(const fs::path& map_dir) {
  const fs::path record = map_dir / "work" / "build.json";
  if (!fs::exists(record))
    throw_error(ErrorCode::kNotFound, record.string(), ": no recorded build; start the map with 'visloc map build'");
  BuildRecord r;
  r.file = record;
  try {
    const auto j = nlohmann::json::parse(read_file(record));
    if (j.at("version").get<int>() != 1) throw std::runtime_error("unknown version");
    r.args = j.at("args").get<std::vector<std::string>>();
    r.cwd = j.at("cwd").get<std::string>();
  } catch (const std::exception& e) {
    throw_error(ErrorCode::kFormat, record.string(), ": bad build record: ", e.what());
  }
  return r;
}

int task_list_segment(const fs::path& task_list, int line) {
  std::istringstream list(read_file(task_list));
  std::vector<int> ids;
  try {
    for (std::string text; std::getline(list, text);)
      if (!text.empty()) ids.push_back(std::stoi(text));
  } catch (const std::exception&) {
    throw_error(ErrorCode::kFormat, task_list.string(), ": not a list of segment ids");
  }
  if (line >= static_cast<int>(ids.size()))
    throw_error(ErrorCode::kInvalidArgument, task_list.string(), ": no line ", line, " (", ids.size(), " segments)");
  return ids[static_cast<size_t>(line)];
}

void record_build_for_tasks(MapBuildOptions& options, const fs::path& map_dir,
                            const std::vector<std::string>& build_args) {
  options.build_record =
      nlohmann::json{{"version", 1}, {"cwd", fs::current_path().string()}, {"args", build_args}}.dump(2);
  if (options.executor != BuildExecutor::kSlurm) return;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec) throw_error(ErrorCode::kIo, "cannot find this program's path for the Slurm tasks: ", ec.message());
  options.slurm_task_command = {self.string(), "map", "build-segment", fs::absolute(map_dir).string()};
}

namespace {

std::string segment_progress_line(const SegmentProgress& s) {
  std::ostringstream l;
  l << "  segment " << s.segment << ": " << s.stage;
  if (s.total > 0) l << " " << s.done << "/" << s.total << (s.stage == "matching" ? " pairs" : "");
  return l.str();
}

std::string map_progress_line(const MapBuildProgress& p) {
  std::ostringstream l;
  l << "map build: " << p.stage << " " << p.done << "/" << p.total << ", " << std::fixed << std::setprecision(0)
    << p.elapsed_s << " s";
  if (p.eta_s >= 0 && p.done < p.total) l << ", ETA " << p.eta_s << " s";
  return l.str();
}

}  // namespace

MapBuildProgressPrinter::MapBuildProgressPrinter(std::ostream& out, bool live) : out_(out), live_(live) {}

void MapBuildProgressPrinter::operator()(const MapBuildProgress& progress) {
  if (live_) draw(progress);
  else log(progress);
}

void MapBuildProgressPrinter::draw(const MapBuildProgress& p) {
  const bool final_update = p.done == p.total && p.running.empty();
  if (!final_update && p.stage == last_stage_ && redraw_.elapsed_ms() < 200) return;
  redraw_ = Timer();
  std::string text;
  if (lines_ > 0) text += "\033[" + std::to_string(lines_) + "F";  // back to the block's first line
  text += map_progress_line(p) + "\033[K\n";
  for (const auto& s : p.running) text += segment_progress_line(s) + "\033[K\n";
  text += "\033[J";
  lines_ = 1 + static_cast<int>(p.running.size());
  if (final_update) lines_ = 0;  // the next stage starts below
  last_stage_ = p.stage;
  out_ << text << std::flush;
}

void MapBuildProgressPrinter::log(const MapBuildProgress& p) {
  if (p.stage != "segments") {
    // One line per 10% of a stage.
    if (p.done != p.total && p.done != 0 && (p.done * 10 / p.total) == ((p.done - 1) * 10 / p.total)) return;
    out_ << map_progress_line(p) << "\n" << std::flush;
    return;
  }
  std::map<int, std::string> now;
  for (const auto& s : p.running) {
    now[s.segment] = s.stage;
    auto it = stages_.find(s.segment);
    if (it == stages_.end() || it->second != s.stage)
      out_ << "map build:" << segment_progress_line(s).substr(1) << "\n";
  }
  if (p.done != segments_done_) out_ << map_progress_line(p) << "\n";
  segments_done_ = p.done;
  stages_ = std::move(now);
  out_ << std::flush;
}

}  // namespace visloc
