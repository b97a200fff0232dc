// visloc map build / visloc map update: segments reconstructed by COLMAP,
// compressed and geo-registered (map_building/map_builder.h).
#include <unistd.h>

#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc::cli {
namespace {

namespace fs = std::filesystem;

struct MapBuildArgs {
  std::string images, gps, out, poses = "sfm", known_poses, colmap = "colmap";
  std::string matcher = "auto", executor = "local";
  int jobs = 0;
  bool gps_subset = false;
  int segment = -1;
  MapBuildOptions options;
};

void bind_build_options(CLI::App* cmd, MapBuildArgs& a, bool update) {
  cmd->add_option("--images", a.images, "Directory of the map's images")->required();
  cmd->add_option("--gps", a.gps, "GPS CSV (image,lat,lon,alt[,placemark]) or 'exif'")->default_str("exif");
  cmd->add_flag("--gps-subset", a.gps_subset,
                "The GPS CSV lists a subset of --images: build from those only (default: every image in the folder "
                "must have a line)");
  cmd->add_option("--poses", a.poses, "Where poses come from: 'sfm' (COLMAP mapper) or 'known' (triangulate)")
      ->check(CLI::IsMember({"sfm", "known"}))
      ->capture_default_str();
  cmd->add_option("--known-poses", a.known_poses,
                  "With --poses known: a COLMAP model directory (text or binary) with the images' exact poses, "
                  "or a pose list 'name qw qx qy qz tx ty tz' (world-to-camera; needs --known-intrinsics)");
  cmd->add_option("--known-intrinsics", a.options.known_intrinsics,
                  "With a pose list: intrinsics 'name MODEL width height params...' per line ('*' for every image)");
  cmd->add_option("--matcher", a.matcher,
                  "Pair matching: 'guided' (known poses: features near the epipolar line, RootSIFT ratio test; "
                  "fast), 'colmap' (COLMAP's matcher and verification), 'auto' (guided with known poses)")
      ->check(CLI::IsMember({"auto", "guided", "colmap"}))
      ->capture_default_str();
  cmd->add_option("--sampson", a.options.guided.max_sampson_px, "Guided matching: epipolar band, Sampson distance (px)")
      ->capture_default_str();
  cmd->add_option("--executor", a.executor,
                  "Where segments are built: 'local' (threads, see --jobs) or 'slurm' (one job array; every task "
                  "runs 'visloc map build-segment MAP N' on a node that sees the map directory)")
      ->check(CLI::IsMember({"local", "slurm"}))
      ->capture_default_str();
  cmd->add_option("--slurm-partition", a.options.slurm.partition, "Slurm partition (default: the cluster's)");
  cmd->add_option("--slurm-cpus", a.options.slurm.cpus_per_task,
                  "CPUs per Slurm task (give --colmap-threads the same to use them in COLMAP)")
      ->capture_default_str();
  cmd->add_option("--slurm-args", a.options.slurm.extra_args,
                  "More sbatch options for the array, e.g. \"--mem=8G --time=2:00:00\"");
  cmd->add_option("--jobs", a.jobs, "Local executor: segments built in parallel (0: number of cores)")
      ->capture_default_str();
  cmd->add_option("--colmap", a.colmap, "COLMAP executable")->capture_default_str();
  cmd->add_option("--colmap-threads", a.options.colmap.threads, "Threads per COLMAP call")->capture_default_str();
  cmd->add_option("--exhaustive-max", a.options.exhaustive_max_images,
                  "COLMAP exhaustive matching for segments up to this many images, spatial matching above")
      ->capture_default_str();
  cmd->add_option("--spatial-neighbors", a.options.colmap.spatial_max_neighbors,
                  "Spatial matching: nearest images matched to each image")
      ->capture_default_str();
  cmd->add_option("--min-placemarks", a.options.plan.min_placemarks, "Placemarks per segment, at least")
      ->capture_default_str();
  cmd->add_option("--max-placemarks", a.options.plan.max_placemarks, "Placemarks per segment, at most")
      ->capture_default_str();
  cmd->add_option("--overlap", a.options.plan.overlap, "Placemarks shared by consecutive segments")
      ->capture_default_str();
  cmd->add_option("--placemark-radius", a.options.plan.placemark_radius,
                  "Metres: consecutive images this close form a placemark (without a placemark column)")
      ->capture_default_str();
  cmd->add_flag("--chain-order", [&a](int64_t) { a.options.plan.order = PlacemarkOrder::kChain; },
                "Order placemarks by nearest-neighbour chaining (unordered collections) instead of capture order");
  cmd->add_option("--registration-threshold", a.options.registration.inlier_threshold,
                  "Metres: GPS inlier threshold of the geo-registration")
      ->capture_default_str();
  cmd->add_option("--retrieval-dims", a.options.embedding.output_dims,
                  "Retrieval embedding dimensions after PCA-whitening (0: full 4096)")
      ->capture_default_str();
  cmd->add_flag("!--no-retrieval", a.options.build_retrieval, "Do not build the retrieval index");
  cmd->add_option("--pq-training-images", a.options.pq_training_images,
                  "The PQ codebook trains on at most this many images, spread over the map (with --executor slurm "
                  "only their features are extracted before the array; each task extracts its segment's)")
      ->capture_default_str();
  cmd->add_option_function<std::string>(
         "--hash-rotation",
         [&a](const std::string& v) { a.options.hash_rotation = parse_hash_rotation_scope(v); },
         "ITQ hash rotation: 'segment' (one per segment, in its file) or 'map' (one for the map, "
         "MAP/hash_rotation.vlitq: 64 KiB less per segment, a query hashed once) [segment]")
      ->check(CLI::IsMember({"segment", "map"}));
  add_sift_options(cmd, a.options.sift);
  if (update) cmd->add_option("--segment", a.segment, "The segment to rebuild")->required();
}

// The options of `map build` as given, recorded in MAP/work/build.json so
// that `map build-segment` (a Slurm task) builds with exactly the same.
std::vector<std::string> given_arguments(const CLI::App* cmd) {
  std::vector<std::string> args;
  for (const CLI::Option* o : cmd->get_options()) {
    if (o->count() == 0 || o->get_name() == "--help" || o->get_name() == "--segment" || o->get_positional()) continue;
    const std::string name = o->get_name();
    if (o->get_expected_min() == 0) {  // a flag
      for (size_t k = 0; k < o->count(); ++k) args.push_back(name);
      continue;
    }
    for (const std::string& v : o->results()) {
      args.push_back(name);
      args.push_back(v);
    }
  }
  return args;
}


// Progress on stderr: on a terminal a live block (the map's line and one line
// per running segment, redrawn in place); in a log, one line per stage change.
class BuildProgressPrinter {
 public:
  BuildProgressPrinter() : tty_(::isatty(STDERR_FILENO)) {}
  void operator()(const MapBuildProgress& p) {
    if (tty_) draw(p);
    else log(p);
  }

 private:
  static std::string segment_line(const SegmentProgress& s) {
    std::ostringstream l;
    l << "  segment " << s.segment << ": " << s.stage;
    if (s.total > 0) l << " " << s.done << "/" << s.total << (s.stage == "matching" ? " pairs" : "");
    return l.str();
  }
  static std::string map_line(const MapBuildProgress& p) {
    std::ostringstream l;
    l << "map build: " << p.stage << " " << p.done << "/" << p.total << ", " << std::fixed << std::setprecision(0)
      << p.elapsed_s << " s";
    if (p.eta_s >= 0 && p.done < p.total) l << ", ETA " << p.eta_s << " s";
    return l.str();
  }
  void draw(const MapBuildProgress& p) {
    const bool final_update = p.done == p.total && p.running.empty();
    if (!final_update && p.stage == last_stage_ && redraw_.elapsed_ms() < 200) return;
    redraw_ = Timer();
    std::string out;
    if (lines_ > 0) out += "\033[" + std::to_string(lines_) + "F";  // back to the block's first line
    out += map_line(p) + "\033[K\n";
    for (const auto& s : p.running) out += segment_line(s) + "\033[K\n";
    out += "\033[J";
    lines_ = 1 + static_cast<int>(p.running.size());
    if (final_update) lines_ = 0;  // the next stage starts below
    last_stage_ = p.stage;
    std::cerr << out << std::flush;
  }
  void log(const MapBuildProgress& p) {
    if (p.stage != "segments") {
      // One line per 10% of a stage.
      if (p.done != p.total && p.done != 0 && (p.done * 10 / p.total) == ((p.done - 1) * 10 / p.total)) return;
      std::cerr << map_line(p) << "\n" << std::flush;
      return;
    }
    std::map<int, std::string> now;
    for (const auto& s : p.running) {
      now[s.segment] = s.stage;
      auto it = stages_.find(s.segment);
      if (it == stages_.end() || it->second != s.stage) std::cerr << "map build:" << segment_line(s).substr(1) << "\n";
    }
    if (p.done != segments_done_) std::cerr << map_line(p) << "\n";
    segments_done_ = p.done;
    stages_ = std::move(now);
    std::cerr << std::flush;
  }

  bool tty_;
  int lines_ = 0;
  std::string last_stage_;
  Timer redraw_;
  std::map<int, std::string> stages_;
  size_t segments_done_ = 0;
};

void apply_arguments(MapBuildArgs& a) {
  MapBuildOptions& o = a.options;
  o.images_dir = a.images;
  if (a.gps != "exif") o.gps_csv = a.gps;
  o.gps_lists_subset = a.gps_subset;
  o.poses = a.poses == "known" ? PoseSource::kKnown : PoseSource::kSfm;
  o.known_poses = a.known_poses;
  o.jobs = a.jobs;
  o.colmap.binary = a.colmap;
  o.matcher = a.matcher == "guided" ? PairMatcher::kGuided
              : a.matcher == "colmap" ? PairMatcher::kColmap
                                      : PairMatcher::kDefault;
  o.executor = a.executor == "slurm" ? BuildExecutor::kSlurm : BuildExecutor::kLocal;
}

void run_build(const std::string& map_dir, MapBuildArgs& a, const CLI::App* cmd) {
  MapBuildOptions& o = a.options;
  apply_arguments(a);
  record_build_for_tasks(o, map_dir, given_arguments(cmd));
  if (a.segment >= 0) o.only_segments = {a.segment};
  BuildProgressPrinter printer;
  MapBuildResult r = build_map(map_dir, o, [&printer](const MapBuildProgress& p) { printer(p); });
  std::cout << build_summary(r);
  if (r.failed() == r.segments.size())
    throw_error(ErrorCode::kExternalTool, "no segment could be built (see the logs under ", map_dir, "/work)");
}

}  // namespace

void record_build_for_tasks(MapBuildOptions& o, const std::filesystem::path& map_dir,
                            const std::vector<std::string>& build_args) {
  o.build_record =
      nlohmann::json{{"version", 1}, {"cwd", fs::current_path().string()}, {"args", build_args}}.dump(2);
  if (o.executor != BuildExecutor::kSlurm) return;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec) throw_error(ErrorCode::kIo, "cannot find this program's path for the Slurm tasks: ", ec.message());
  o.slurm_task_command = {self.string(), "map", "build-segment", fs::absolute(map_dir).string()};
}

void add_map_build_commands(CLI::App& map) {
  auto build = std::make_shared<MapBuildArgs>();
  auto build_out = std::make_shared<std::string>();
  CLI::App* b = map.add_subcommand("build", "Build a map from geotagged images: segments reconstructed by COLMAP, "
                                            "compressed, geo-registered (resumable)");
  b->add_option("--out", *build_out, "Map directory (created; an interrupted build there resumes)")->required();
  bind_build_options(b, *build, false);
  b->callback([build, build_out, b] { run_build(*build_out, *build, b); });

  auto update = std::make_shared<MapBuildArgs>();
  auto update_map = std::make_shared<std::string>();
  CLI::App* u = map.add_subcommand("update", "Rebuild one segment of a map built by 'map build' (same inputs)");
  u->add_option("map", *update_map, "Map directory")->required();
  bind_build_options(u, *update, true);
  u->callback([update, update_map, u] { run_build(*update_map, *update, u); });

  auto task_map = std::make_shared<std::string>();
  auto task_segment = std::make_shared<int>(-1);
  CLI::App* t = map.add_subcommand(
      "build-segment",
      "Build one segment of a map started by 'map build' with the options recorded in MAP/work/build.json "
      "(what each Slurm task runs; also for rebuilding one segment by hand)");
  t->add_option("map", *task_map, "Map directory")->required();
  t->add_option("segment", *task_segment, "Segment index (with --task-list: the line of the list)")
      ->required()
      ->check(CLI::NonNegativeNumber);
  auto task_list = std::make_shared<std::string>();
  t->add_option("--task-list", *task_list, "File of segment ids, one per line (a Slurm array's task list)");
  t->callback([task_map, task_segment, task_list] {
    if (!task_list->empty()) *task_segment = task_list_segment(*task_list, *task_segment);
    const fs::path map_dir = fs::absolute(*task_map);
    const BuildRecord record = read_build_record(map_dir);
    // Parse the recorded options exactly as 'map build' did.
    MapBuildArgs a;
    std::string out;
    CLI::App parser;
    parser.add_option("--out", out);
    bind_build_options(&parser, a, false);
    std::vector<std::string> reversed(record.args.rbegin(), record.args.rend());
    try {
      parser.parse(reversed);
    } catch (const CLI::ParseError& e) {
      throw_error(ErrorCode::kFormat, record.file.string(), ": recorded options do not parse: ", e.what());
    }
    std::error_code ec;
    fs::current_path(record.cwd, ec);  // relative paths in the record are relative to where the build started
    if (ec)
      throw_error(ErrorCode::kIo, record.file.string(), ": cannot change to the build's directory ", record.cwd, ": ",
                  ec.message());
    apply_arguments(a);
    a.options.executor = BuildExecutor::kLocal;  // this task builds its segment here
    const SegmentBuildResult r = build_planned_segment(map_dir, a.options, *task_segment);
    if (!r.ok) throw_error(ErrorCode::kExternalTool, "segment ", r.id, ": ", r.error);
    std::cout << segment_summary(r);
  });
}

}  // namespace visloc::cli
