// visloc bench segments: the paper's segment design study (eval/segment_study.h).
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <thread>

#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/eval/segment_study.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

namespace {

std::vector<int> parse_int_list(const char* option, const std::string& text) {
  std::vector<int> out;
  for (double v : parse_numbers(text, option)) {
    if (v != std::floor(v) || std::abs(v) > 1e6)
      throw_error(ErrorCode::kInvalidArgument, option, ": ", v, " is not an integer");
    out.push_back(static_cast<int>(v));
  }
  if (out.empty()) throw_error(ErrorCode::kInvalidArgument, option, ": empty list");
  return out;
}

}  // namespace

void add_bench_segments(CLI::App& bench) {
  struct Args {
    SegmentStudyOptions options;
    std::string out, city, kitti, placemarks = "4,6,8,10,14", overlaps = "0,1,2,3", setting = "3+";
    int jobs = 0;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "segments",
      "The paper's segment design study: build the same map with P placemarks per segment and O shared with "
      "neighbours, for every P and O (O < P), localize the same queries on each; report registration, median "
      "error, wrong poses, map bytes and build time as report.md and plots in --out (every configuration measured "
      "there so far). Resumes per configuration");
  cmd->add_option("--out", a->out, "Study directory (DATASET/pP_oO/result.json, report.md, plots)")->required();
  cmd->add_option("--city", a->city,
                  "A 'visloc bench city' directory: its map images, positives and negatives (run that first)");
  cmd->add_option("--kitti", a->kitti, "KITTI directory (map = even frames with known poses, queries = odd frames)");
  cmd->add_option("--placemarks", a->placemarks, "Placemarks per segment, comma-separated")->capture_default_str();
  cmd->add_option("--overlaps", a->overlaps, "Placemarks shared by neighbours, comma-separated")
      ->capture_default_str();
  cmd->add_option("--jobs", a->jobs, "Segments built at once (0: cores)")->capture_default_str();
  cmd->add_option("--max-queries", a->options.max_queries,
                  "Localize at most this many queries per data set, evenly spread (0: all)")
      ->capture_default_str();
  cmd->add_flag("--keep-maps", a->options.keep_maps, "Keep every configuration's map (default: only its result)");
  add_localizer_options(cmd, a->options.localizer, a->setting);
  cmd->callback([a] {
    SegmentStudyOptions& o = a->options;
    if (a->city.empty() && a->kitti.empty())
      throw_error(ErrorCode::kInvalidArgument, "bench segments: give --city, --kitti or both");
    o.localizer.setting = parse_paper_setting(a->setting);
    o.placemarks = parse_int_list("--placemarks", a->placemarks);
    o.overlaps = parse_int_list("--overlaps", a->overlaps);
    o.map.jobs = a->jobs > 0 ? a->jobs : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    o.validate();
    const fs::path out = a->out;
    fs::create_directories(out);
    std::vector<StudyDataset> sets;
    if (!a->city.empty()) sets.push_back(city_study_dataset(a->city));
    if (!a->kitti.empty()) sets.push_back(kitti_study_dataset(a->kitti, out / "kitti"));
    const bool tty = ::isatty(STDERR_FILENO);
    auto progress = [tty](const SegmentStudyProgress& p) {
      if (p.stage == "features" && p.done != p.total && p.done % 50 != 0) return;
      std::cerr << (tty ? "\r" : "") << "bench segments: " << p.dataset;
      if (p.placemarks) std::cerr << " P=" << p.placemarks << " O=" << p.overlap;
      std::cerr << " " << p.stage;
      if (p.total > 1) std::cerr << " " << p.done << "/" << p.total;
      std::cerr << (tty && p.stage != "done" ? "     " : "\n") << std::flush;
    };
    std::vector<std::pair<std::string, nlohmann::json>> rows;
    for (const auto& d : sets) {
      run_segment_study(out, d, o, progress);
      rows.emplace_back(d.name, collect_segment_study_rows(out, d.name));  // earlier runs' configurations too
    }
    write_segment_study_report(out, rows);
    std::cout << read_file(out / "report.md");
  });
}

}  // namespace visloc::cli
