// visloc localize --map MAP IMAGE... : one JSON line per image (DESIGN.md).
#include <unistd.h>

#include <fstream>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {

void add_localize_command(CLI::App& app) {
  struct Args {
    std::string map, out, setting = "3+", intrinsics, poses;
    std::vector<std::string> images;
    double focal = 0;
    double cache_mib = 512;
    LocalizerOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("localize", "Localize query images against a map (one JSON line per image)");
  cmd->add_option("--map", args->map, "Map directory")->required();
  cmd->add_option("images", args->images, "Query images")->required();
  cmd->add_option("--out", args->out, "Write the JSON lines to this file (default: standard output)");
  cmd->add_option("--poses", args->poses,
                  "Also write the registered images' poses as 'name qw qx qy qz tx ty tz' (world-to-camera in the "
                  "segment's frame; the visuallocalization.net format)");
  cmd->add_option("--focal", args->focal, "Focal length in pixels for every image (default: EXIF, else estimated)")
      ->check(positive_finite_number());
  cmd->add_option("--intrinsics", args->intrinsics,
                  "Per-image intrinsics: 'name MODEL width height params...' (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL)")
      ->excludes("--focal");
  add_localizer_options(cmd, args->options, args->setting);
  cmd->add_option("--cache-mib", args->cache_mib, "Segment cache budget (MiB)")
      ->check(positive_finite_number())
      ->capture_default_str();
  cmd->callback([args] {
    args->options.setting = parse_paper_setting(args->setting);
    args->options.cache_bytes = static_cast<uint64_t>(args->cache_mib * 1024 * 1024);
    Localizer localizer(args->map, args->options);
    std::map<std::string, PinholeCamera> cameras;
    if (!args->intrinsics.empty())
      for (auto& c : read_intrinsics_list(args->intrinsics)) cameras[c.name] = c.camera;
    std::ostringstream lines;
    const bool tty = ::isatty(STDERR_FILENO);
    size_t registered = 0, failed = 0;
    std::vector<NamedPose> poses;
    for (size_t i = 0; i < args->images.size(); ++i) {
      std::optional<PinholeCamera> intrinsics;
      if (!cameras.empty()) {
        auto it = cameras.find(std::filesystem::path(args->images[i]).filename().string());
        if (it != cameras.end()) intrinsics = it->second;
      } else if (args->focal > 0) {
        PinholeCamera c;
        c.focal = args->focal;
        c.has_focal = true;
        intrinsics = c;  // width/height/principal point from the image
      }
      LocalizationResult r = localizer.localize_file(args->images[i], intrinsics);
      registered += r.registered;
      if (r.registered) poses.push_back({r.image, r.cam_from_segment});
      failed += !r.error.empty();
      const std::string line = to_json(r).dump();
      if (args->out.empty()) std::cout << line << std::endl;
      else lines << line << '\n';
      if (tty && args->images.size() > 1)
        std::cerr << "\rlocalize: " << i + 1 << "/" << args->images.size() << ", " << registered << " registered"
                  << (i + 1 == args->images.size() ? "\n" : "") << std::flush;
    }
    if (!args->out.empty()) write_file_atomic(args->out, lines.str());
    if (!args->poses.empty()) write_pose_list(args->poses, poses);
    if (failed == args->images.size())
      throw_error(ErrorCode::kIo, "no image could be read (see the error fields)");
  });
}

}  // namespace visloc::cli
