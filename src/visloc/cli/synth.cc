// visloc synth city --out DIR [options]: renders a synthetic street-view city
// with exact ground truth (src/visloc/synth/city_writer.h documents the
// output layout), with a progress line on stderr and a summary on stdout.
// --measure-pairs N then measures SIFT matching between adjacent placemarks
// under the true geometry (view_pair_check.h).
#include <unistd.h>

#include <functional>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/synth/city_writer.h"
#include "visloc/synth/view_pair_check.h"
#include "visloc/util/option_table.h"

namespace visloc::cli {

namespace {

void add_synth_city_command(CLI::App* synth) {
  struct Args {
    synth::CityOptions city;
    std::string out;
    std::vector<std::string> markers;  // x,y,z each
    int measure_pairs = 0;
    SiftOptions sift;
    bool quiet = false;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = synth->add_subcommand(
      "city", "Render a synthetic street-view city: placemarks of rectilinear views, queries, exact poses");
  OptionTable t;
  t.add("--out", a->out, "Output directory (layout: see docs/formats.md)").require();
  add_options(t, a->city);
  t.add("--marker", a->markers, "Red sphere at x,y,z (ENU metres); repeatable (calibration, tests)");
  t.flag("--quiet", a->quiet, "No progress line");
  t.add("--measure-pairs", a->measure_pairs,
        "Then measure SIFT matches between N pairs of adjacent placemarks under the true geometry")
      .non_negative();
  add_options(t, a->sift);
  bind_options(cmd, t);
  cmd->callback([a] {
    synth::CityOptions& o = a->city;
    for (const std::string& m : a->markers) o.markers.push_back(synth::parse_marker_position(m, "--marker"));
    synth::CityProgressPrinter progress(std::cerr, ::isatty(STDERR_FILENO) != 0);
    const synth::CityStats stats =
        synth::write_city(o, a->out, a->quiet ? synth::CityProgressCallback() : std::ref(progress));
    std::cout << synth::city_summary(o, stats, a->out);
    if (a->measure_pairs > 0)
      std::cout << synth::adjacent_pair_summary(
          synth::measure_adjacent_placemarks(o, a->out, a->measure_pairs, a->sift));
    std::cout.flush();
  });
}

}  // namespace

void add_synth_command(CLI::App& app) {
  CLI::App* synth = app.add_subcommand("synth", "Generate synthetic data with exact ground truth");
  synth->require_subcommand(1);
  add_synth_city_command(synth);
}

}  // namespace visloc::cli
