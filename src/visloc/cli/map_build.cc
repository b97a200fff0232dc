// visloc map build / update / build-segment: segments reconstructed by COLMAP,
// compressed and geo-registered (map_building/map_builder.h; the options:
// map_building/option_tables.cc).
#include <unistd.h>

#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/util/error.h"

namespace visloc::cli {
namespace {

namespace fs = std::filesystem;

// The options of `map build` as given, recorded in MAP/work/build.json so
// that `map build-segment` (a Slurm task) builds with exactly the same.
std::vector<std::string> given_arguments(const CLI::App* cmd) {
  std::vector<std::string> args;
  for (const CLI::Option* o : cmd->get_options()) {
    if (o->count() == 0 || o->get_name() == "--help" || o->get_name() == "--segment" || o->get_positional()) continue;
    const std::string name = o->get_name();
    if (o->get_expected_min() == 0) {  // a flag
      args.insert(args.end(), o->count(), name);
      continue;
    }
    for (const std::string& v : o->results()) {
      args.push_back(name);
      args.push_back(v);
    }
  }
  return args;
}

// The options `map build` recorded, parsed as it parsed them.
MapBuildOptions recorded_options(const BuildRecord& record) {
  MapBuildOptions options;
  OptionTable table;
  table.text("--out", "", [](const std::string&) {}, "Map directory (the task is given it)");
  add_options(table, options);
  CLI::App parser;
  bind_options(&parser, table);
  try {
    parser.parse(std::vector<std::string>(record.args.rbegin(), record.args.rend()));  // CLI11 pops from the back
  } catch (const CLI::ParseError& e) {
    throw_error(ErrorCode::kFormat, record.file.string(), ": recorded options do not parse: ", e.what());
  }
  return options;
}

// `segment` >= 0: rebuild only that segment (map update).
void run_build(const std::string& map_dir, MapBuildOptions& o, int segment, const CLI::App* cmd) {
  record_build_for_tasks(o, map_dir, given_arguments(cmd));
  if (segment >= 0) o.only_segments = {segment};
  MapBuildProgressPrinter printer(std::cerr, ::isatty(STDERR_FILENO));
  const MapBuildResult r = build_map(map_dir, o, [&printer](const MapBuildProgress& p) { printer(p); });
  std::cout << build_summary(r);
  if (r.failed() == r.segments.size())
    throw_error(ErrorCode::kExternalTool, "no segment could be built (see the logs under ", map_dir, "/work)");
}

}  // namespace

void add_map_build_commands(CLI::App& map) {
  auto build = std::make_shared<MapBuildOptions>();
  auto build_out = std::make_shared<std::string>();
  CLI::App* b = map.add_subcommand("build", "Build a map from geotagged images: segments reconstructed by COLMAP, "
                                            "compressed, geo-registered (resumable)");
  OptionTable bt;
  bt.add("--out", *build_out, "Map directory (created; an interrupted build there resumes)").require();
  add_options(bt, *build);
  bind_options(b, bt);
  b->callback([build, build_out, b] { run_build(*build_out, *build, -1, b); });

  auto update = std::make_shared<MapBuildOptions>();
  auto update_map = std::make_shared<std::string>();
  auto update_segment = std::make_shared<int>(-1);
  CLI::App* u = map.add_subcommand("update", "Rebuild one segment of a map built by 'map build' (same inputs)");
  OptionTable ut;
  ut.add("map", *update_map, "Map directory").require();
  add_options(ut, *update);
  ut.add("--segment", *update_segment, "The segment to rebuild").require();
  bind_options(u, ut);
  u->callback([update, update_map, update_segment, u] { run_build(*update_map, *update, *update_segment, u); });

  auto task_map = std::make_shared<std::string>();
  auto task_segment = std::make_shared<int>(-1);
  auto task_list = std::make_shared<std::string>();
  CLI::App* t = map.add_subcommand(
      "build-segment",
      "Build one segment of a map started by 'map build' with the options recorded in MAP/work/build.json "
      "(what each Slurm task runs; also for rebuilding one segment by hand)");
  OptionTable tt;
  tt.add("map", *task_map, "Map directory").require();
  tt.add("segment", *task_segment, "Segment index (with --task-list: the line of the list)").require().non_negative();
  tt.add("--task-list", *task_list, "File of segment ids, one per line (a Slurm array's task list)");
  bind_options(t, tt);
  t->callback([task_map, task_segment, task_list] {
    if (!task_list->empty()) *task_segment = task_list_segment(*task_list, *task_segment);
    const fs::path map_dir = fs::absolute(*task_map);
    const BuildRecord record = read_build_record(map_dir);
    MapBuildOptions options = recorded_options(record);
    std::error_code ec;
    fs::current_path(record.cwd, ec);  // relative paths in the record are relative to where the build started
    if (ec)
      throw_error(ErrorCode::kIo, record.file.string(), ": cannot change to the build's directory ", record.cwd, ": ",
                  ec.message());
    options.executor = BuildExecutor::kLocal;  // this task builds its segment here
    const SegmentBuildResult r = build_planned_segment(map_dir, options, *task_segment);
    if (!r.ok) throw_error(ErrorCode::kExternalTool, "segment ", r.id, ": ", r.error);
    std::cout << segment_summary(r);
  });
}

}  // namespace visloc::cli
