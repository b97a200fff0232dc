// visloc bench city: the city benchmark (eval/city_benchmark.h).
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <cerrno>
#include <cstring>
#include <thread>

#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/eval/city_benchmark.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

namespace {

// Runs this very command again with "--stage localize" appended (--stage
// takes the last value), in a fresh process that inherits stdout and stderr.
void run_localize_stage_in_new_process() {
  std::ifstream in("/proc/self/cmdline", std::ios::binary);
  const std::string cmdline((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<std::string> args;
  for (size_t start = 0; start < cmdline.size();) {
    const size_t end = cmdline.find('\0', start);
    args.push_back(cmdline.substr(start, end == std::string::npos ? std::string::npos : end - start));
    if (end == std::string::npos) break;
    start = end + 1;
  }
  if (args.empty()) throw_error(ErrorCode::kInternal, "bench city: cannot read this process's command line");
  args.push_back("--stage");
  args.push_back("localize");
  std::vector<char*> argv;
  for (auto& x : args) argv.push_back(x.data());
  argv.push_back(nullptr);
  std::cout.flush();
  std::cerr << "bench city: localizing in a fresh process (its peak memory goes into the report)\n";
  pid_t pid = 0;
  if (const int err = ::posix_spawn(&pid, "/proc/self/exe", nullptr, nullptr, argv.data(), environ))
    throw_error(ErrorCode::kInternal, "bench city: cannot start the localization process: ", std::strerror(err));
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0)
    if (errno != EINTR) throw_error(ErrorCode::kInternal, "bench city: waitpid: ", std::strerror(errno));
  // It printed its own error; pass its exit status on.
  if (WIFEXITED(status) && WEXITSTATUS(status) != 0) std::exit(WEXITSTATUS(status));
  if (!WIFEXITED(status))
    throw_error(ErrorCode::kInternal, "bench city: the localization process died from signal ", WTERMSIG(status));
}

struct CityArgs {
  CityBenchmarkOptions options;
  std::string out, layout = "grid", elevations = "10", size = "640x640", executor = "local", setting = "3+";
  std::string stage = "auto";
  double cache_mib = 512;
  std::string shared_data = VISLOC_DEFAULT_SHARED_DATA;
  int jobs = 0;
};

// The city: its streets, its views and its queries.
void add_city_options(CLI::App* cmd, CityArgs& a) {
  CityBenchmarkOptions& o = a.options;
  cmd->add_option("--layout", a.layout, "Street network: line, grid or random")->capture_default_str();
  cmd->add_option("--road-length", o.city.layout.road_length_m, "line: street length; random: each road's (m)")
      ->capture_default_str();
  cmd->add_option("--grid-blocks-x", o.city.layout.grid_blocks_x, "grid: blocks east-west")->capture_default_str();
  cmd->add_option("--grid-blocks-y", o.city.layout.grid_blocks_y, "grid: blocks north-south")->capture_default_str();
  cmd->add_option("--block-size", o.city.layout.block_size_m, "grid: distance between parallel streets (m)")
      ->capture_default_str();
  cmd->add_option("--random-roads", o.city.layout.random_roads, "random: number of roads")->capture_default_str();
  cmd->add_option("--headings", o.city.views.headings, "Views around each placemark")->capture_default_str();
  cmd->add_option("--elevations", a.elevations, "View elevations in degrees, comma-separated")->capture_default_str();
  cmd->add_option("--size", a.size, "Map image size WIDTHxHEIGHT")->capture_default_str();
  cmd->add_option("--queries", o.city.queries.count, "Query views rendered (positives and negatives)")
      ->capture_default_str();
}

// What is mapped, and which queries are positives and negatives.
void add_split_options(CLI::App* cmd, CityArgs& a) {
  CityBenchmarkOptions& o = a.options;
  cmd->add_option("--leave-out-roads", o.leave_out_roads, "The last roads of the layout are left out of the map")
      ->capture_default_str();
  cmd->add_option("--positive-distance", o.positive_max_distance_m,
                  "A query within this distance (m, in plan) of a mapped placemark is a positive")
      ->capture_default_str();
  cmd->add_option("--negative-distance", o.negative_min_distance_m,
                  "A query farther than this (m) from every mapped placemark is a negative")
      ->capture_default_str();
  cmd->add_option("--negatives", o.foreign_photos, "Foreign photos from --shared-data (negatives)")
      ->capture_default_str();
  cmd->add_option("--shared-data", a.shared_data, "Real photos for foreign negatives ('' for none)")
      ->capture_default_str();
}

// The map build and the stages of the run.
void add_run_options(CLI::App* cmd, CityArgs& a) {
  CityBenchmarkOptions& o = a.options;
  cmd->add_option("--min-placemarks", o.map.plan.min_placemarks, "Map: placemarks per segment, at least")
      ->capture_default_str();
  cmd->add_option("--max-placemarks", o.map.plan.max_placemarks, "Map: placemarks per segment, at most")
      ->capture_default_str();
  cmd->add_option("--overlap", o.map.plan.overlap, "Map: placemarks shared by consecutive segments")
      ->capture_default_str();
  cmd->add_option("--jobs", a.jobs, "Render threads and segments built at once (0: cores)")->capture_default_str();
  cmd->add_option("--executor", a.executor, "Map build: local or slurm (see 'map build --help')")
      ->check(CLI::IsMember({"local", "slurm"}))
      ->capture_default_str();
  cmd->add_option("--seed", o.city.layout.seed, "Seed of the city")->capture_default_str();
  cmd->add_option("--stage", a.stage,
                  "auto: render and build here, then localize in a fresh process (so that the report's peak memory "
                  "is the localizer's); all: everything in this process; prepare: render and build only; localize: "
                  "localize and report only (after prepare, same options)")
      ->check(CLI::IsMember({"auto", "all", "prepare", "localize"}))
      ->take_last()  // the fresh process appends "--stage localize"
      ->capture_default_str();
}

// Slurm tasks run `map build-segment`, which reads the options of an equivalent `map build`.
void record_slurm_build(const std::string& out_dir, MapBuildOptions& map) {
  const fs::path out = fs::absolute(out_dir);
  const std::vector<std::string> args = {"--images", (out / "city" / "images").string(), "--gps",
                                         (out / "map_gps.csv").string(), "--gps-subset", "--poses", "known", "--known-poses",
                                         (out / "city" / "sparse").string(), "--out", (out / "map").string(),
                                         "--min-placemarks", std::to_string(map.plan.min_placemarks),
                                         "--max-placemarks", std::to_string(map.plan.max_placemarks),
                                         "--overlap", std::to_string(map.plan.overlap)};
  map.executor = BuildExecutor::kSlurm;
  record_build_for_tasks(map, out / "map", args);
}

void run_bench_city(CityArgs& a) {
  a.options.localizer.cache_bytes = static_cast<uint64_t>(a.cache_mib * 1024 * 1024);
  CityBenchmarkOptions& o = a.options;
  o.localizer.setting = parse_paper_setting(a.setting);
  o.city.layout.layout = synth::parse_road_layout(a.layout);
  o.city.views.elevations_deg = parse_numbers(a.elevations, "--elevations");
  if (std::sscanf(a.size.c_str(), "%dx%d", &o.city.views.width, &o.city.views.height) != 2)
    throw_error(ErrorCode::kInvalidArgument, "--size: '", a.size, "' is not WIDTHxHEIGHT");
  const int jobs = a.jobs > 0 ? a.jobs : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  o.city.jobs = jobs;
  o.map.jobs = jobs;
  if (!a.shared_data.empty() && fs::is_directory(a.shared_data)) o.shared_data = a.shared_data;
  else if (!a.shared_data.empty())
    std::cerr << "bench city: " << a.shared_data << " is absent: no foreign photos\n";
  if (a.executor == "slurm") record_slurm_build(a.out, o.map);
  const bool tty = ::isatty(STDERR_FILENO);
  std::string last_stage;
  auto progress = [&](const CityBenchmarkProgress& p) {
    if (!tty && p.stage == last_stage && p.done != p.total && p.done % (p.stage == "render" ? 100 : 20) != 0)
      return;
    last_stage = p.stage;
    std::cerr << (tty ? "\r" : "") << "bench city: " << p.stage << " " << p.done << "/" << p.total
              << (tty && p.done != p.total ? "   " : "\n") << std::flush;
  };
  auto map_progress = [&](const MapBuildProgress& p) {
    if (p.stage != "segments" || (p.done != p.total && !tty)) return;
    std::cerr << (tty ? "\r" : "") << "bench city: map segments " << p.done << "/" << p.total
              << (tty && p.done != p.total ? "   " : "\n") << std::flush;
  };
  o.map.plan.validate();  // before hours of rendering
  if (a.stage == "auto") {
    o.stage = CityBenchmarkStage::kPrepare;
    run_city_benchmark(a.out, o, progress, map_progress);
    run_localize_stage_in_new_process();  // it prints the report
    return;
  }
  o.stage = a.stage == "all"       ? CityBenchmarkStage::kAll
            : a.stage == "prepare" ? CityBenchmarkStage::kPrepare
                                   : CityBenchmarkStage::kLocalize;
  run_city_benchmark(a.out, o, progress, map_progress);
  if (o.stage == CityBenchmarkStage::kPrepare) return;
  std::cout << read_file(fs::path(a.out) / "report.md");
}

}  // namespace

void add_bench_city(CLI::App& bench) {
  auto a = std::make_shared<CityArgs>();
  CityBenchmarkOptions& o = a->options;
  o.city.views.headings = 8;
  o.city.layout.grid_blocks_x = o.city.layout.grid_blocks_y = 2;
  o.city.queries.count = 540;  // about 350 positives and 60 negatives on the default grid
  CLI::App* cmd = bench.add_subcommand(
      "city",
      "The city benchmark: render a synthetic city, map all its streets but a few, localize queries near mapped "
      "streets (positives), on the unmapped streets and foreign photos (negatives); count wrong poses apart from "
      "misses, score retrieval. Resumes at every stage; writes report.json and report.md in --out");
  cmd->add_option("--out", a->out, "Benchmark directory (city/, map/, report.json, report.md)")->required();
  add_city_options(cmd, *a);
  add_split_options(cmd, *a);
  add_run_options(cmd, *a);
  add_localizer_options(cmd, o.localizer, a->setting);
  cmd->add_option("--cache-mib", a->cache_mib, "Localizer: segment cache budget (MiB)")
      ->check(positive_finite_number())
      ->capture_default_str();
  cmd->callback([a] { run_bench_city(*a); });
}

}  // namespace visloc::cli
