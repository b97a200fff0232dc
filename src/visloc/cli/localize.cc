// visloc localize --map MAP IMAGE... : one JSON line per image (DESIGN.md).
#include <unistd.h>

#include <fstream>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {

void add_localize_command(CLI::App& app) {
  struct Args {
    std::string map, out, intrinsics, poses;
    std::vector<std::string> images;
    double focal = 0;
    LocalizerOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("localize", "Localize query images against a map (one JSON line per image)");
  OptionTable t;
  t.add("--map", args->map, "Map directory").require();
  t.add("images", args->images, "Query images").require();
  t.add("--out", args->out, "Write the JSON lines to this file (default: standard output)");
  t.add("--poses", args->poses,
        "Also write the registered images' poses as 'name qw qx qy qz tx ty tz' (world-to-camera in the "
        "segment's frame; the visuallocalization.net format)");
  t.add("--focal", args->focal, "Focal length in pixels for every image (default: EXIF, else estimated)")
      .positive()
      .no_default();
  t.add("--intrinsics", args->intrinsics,
        "Per-image intrinsics: 'name MODEL width height params...' (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, "
        "RADIAL with k2 = 0, OPENCV with k2 = p1 = p2 = 0; "
        "by file name, '*' for every image without a line)");
  add_options(t, args->options);
  bind_options(cmd, t);
  cmd->get_option("--intrinsics")->excludes("--focal");
  cmd->callback([args] {
    Localizer localizer(args->map, args->options);
    CamerasByName cameras;
    if (!args->intrinsics.empty()) {
      cameras = read_intrinsics_by_name(args->intrinsics);
      std::vector<std::string> names;
      for (const auto& image : args->images) names.push_back(std::filesystem::path(image).filename().string());
      if (const std::string w = unlisted_cameras_warning(cameras, args->intrinsics, names, "images"); !w.empty())
        std::cerr << "localize: " << w << "\n";
    }
    std::ostringstream lines;
    const bool tty = ::isatty(STDERR_FILENO);
    size_t registered = 0, failed = 0;
    std::vector<NamedPose> poses;
    for (size_t i = 0; i < args->images.size(); ++i) {
      std::optional<PinholeCamera> intrinsics;
      if (!cameras.empty()) {
        const PinholeCamera* listed =
            find_listed_camera(cameras, std::filesystem::path(args->images[i]).filename().string());
        if (listed) intrinsics = *listed;
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
