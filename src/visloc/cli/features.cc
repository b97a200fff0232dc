// visloc features IMAGE... [--out DIR]: SIFT features of images, written as
// .vlfeat files (docs/formats.md), with count and time per image.
#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc::cli {

void add_features_command(CLI::App& app) {
  struct Args {
    std::vector<std::string> images;
    std::string out;
    SiftOptions sift;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("features", "Extract SIFT features (COLMAP-compatible uint8 descriptors)");
  OptionTable t;
  t.add("images", args->images, "Image files (JPEG or PNG)").require();
  t.add("--out", args->out, "Write IMAGE.vlfeat files into this directory");
  add_options(t, args->sift);
  bind_options(cmd, t);
  cmd->callback([args] {
    namespace fs = std::filesystem;
    if (!args->out.empty()) {
      std::error_code ec;
      fs::create_directories(args->out, ec);
      if (ec) throw_error(ErrorCode::kIo, "cannot create output directory ", args->out, ": ", ec.message());
    }
    SiftExtractor sift(args->sift);
    int failed = 0;
    for (const auto& image : args->images) {
      try {
        Timer t;
        ImageMetadata meta;
        FeatureSet f = sift.extract_file(image, &meta);
        const double ms = t.elapsed_ms();
        std::cout << image << ": " << f.size() << " features, " << meta.width << "x" << meta.height << ", "
                  << std::fixed << std::setprecision(1) << ms << " ms";
        if (!args->out.empty()) {
          fs::path out = fs::path(args->out) / (fs::path(image).filename().string() + ".vlfeat");
          write_feature_file(out, f);
          std::cout << " -> " << out.string();
        }
        std::cout << std::endl;
      } catch (const Error& e) {
        if (e.code() == ErrorCode::kInternal) throw;
        std::cerr << "visloc: error: " << e.what() << "\n";
        ++failed;
      }
    }
    if (failed > 0)
      throw_error(ErrorCode::kIo, failed, " of ", args->images.size(), " images failed");
  });
}

}  // namespace visloc::cli
