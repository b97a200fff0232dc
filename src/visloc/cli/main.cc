#include <iostream>

#include "visloc/cli/commands.h"
#include "visloc/util/error.h"

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
  } catch (const std::bad_alloc&) {
    std::cerr << "visloc: error: out of memory\n";
    return cli::kExitUserError;
  } catch (const std::exception& e) {
    std::cerr << "visloc: internal error: " << e.what() << "\n";
    return cli::kExitInternal;
  }
  return cli::kExitOk;
}
