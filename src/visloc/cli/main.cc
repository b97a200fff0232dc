#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>

#include "visloc/cli/commands.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/util/error.h"

namespace {

// Every floating-point option of every command refuses NaN and ±infinity
// (CLI11 parses them, and range checks let NaN through); ranges are checked
// by the options' own validators and the library's validate().
void require_finite_numbers(CLI::App& app) {
  const CLI::Validator finite(
      [](std::string& text) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (end == text.c_str()) return {};  // not a number at all: CLI11's own conversion reports it
        if (std::isnan(v) || std::isinf(v)) return "'" + text + "' is not a finite number";
        return {};
      },
      "", "FINITE");
  for (CLI::Option* o : app.get_options())
    if (o->get_type_name().find("FLOAT") != std::string::npos) o->check(finite);
  for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) require_finite_numbers(*sub);
}

}  // namespace

int main(int argc, char** argv) {
  using namespace visloc;
  CLI::App app{
      "visloc: on-device image-based localization in a city from one photo.\n"
      "Retrieval picks small 3D sub-models of a street-view map; cascade hashing +\n"
      "product quantization finds 2D-3D matches; one-many RANSAC with SPRT gives the pose."};
  app.set_version_flag("--version", "visloc 0.1.0");
  app.require_subcommand(1);
  cli::add_features_command(app);
  cli::add_map_command(app);
  cli::add_localize_command(app);
  cli::add_eval_command(app);
  cli::add_bench_command(app);
  cli::add_synth_command(app);
  cli::add_retrieval_command(app);
  cli::add_view_command(app);
  cli::add_match_command(app);
  require_finite_numbers(app);
  // OpenCV's thread pool (SIFT) is process-wide and the program's to set:
  // one thread unless a command's --threads says otherwise.
  set_opencv_threads(1);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? cli::kExitOk : cli::kExitUsage;
  } catch (const Error& e) {
    std::cout.flush();
    std::cerr << "visloc: error: " << e.what() << "\n";
    switch (e.code()) {
      case ErrorCode::kNotImplemented: return cli::kExitNotImplemented;
      case ErrorCode::kInternal: return cli::kExitInternal;
      default: return cli::kExitUserError;
    }
  } catch (const std::filesystem::filesystem_error& e) {
    std::cout.flush();
    std::cerr << "visloc: error: " << e.what() << "\n";
    return cli::kExitUserError;
  } catch (const std::bad_alloc&) {
    std::cerr << "visloc: error: out of memory\n";
    return cli::kExitUserError;
  } catch (const std::exception& e) {
    std::cerr << "visloc: internal error: " << e.what() << "\n";
    return cli::kExitInternal;
  }
  return cli::kExitOk;
}
