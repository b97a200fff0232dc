// visloc map build / visloc map update: segments reconstructed by COLMAP,
// compressed and geo-registered (map/map_builder.h).
#include <unistd.h>

#include <iomanip>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/map/map_builder.h"
#include "visloc/util/error.h"

namespace visloc::cli {
namespace {

struct MapBuildArgs {
  std::string images, gps, out, poses = "sfm", known_poses, colmap = "colmap";
  int jobs = 0;
  int segment = -1;
  MapBuildOptions options;
};

void bind_build_options(CLI::App* cmd, MapBuildArgs& a, bool update) {
  cmd->add_option("--images", a.images, "Directory of the map's images")->required();
  cmd->add_option("--gps", a.gps, "GPS CSV (image,lat,lon,alt[,placemark]) or 'exif'")->default_str("exif");
  cmd->add_option("--poses", a.poses, "Where poses come from: 'sfm' (COLMAP mapper) or 'known' (triangulate)")
      ->check(CLI::IsMember({"sfm", "known"}))
      ->capture_default_str();
  cmd->add_option("--known-poses", a.known_poses,
                  "With --poses known: a COLMAP model directory (text or binary) with the images' exact poses, "
                  "or a pose list 'name qw qx qy qz tx ty tz' (world-to-camera; needs --known-intrinsics)");
  cmd->add_option("--known-intrinsics", a.options.known_intrinsics,
                  "With a pose list: intrinsics 'name MODEL width height params...' per line ('*' for every image)");
  cmd->add_option("--jobs", a.jobs, "Segments built in parallel (0: number of cores)")->capture_default_str();
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
  add_sift_options(cmd, a.options.sift);
  if (update) cmd->add_option("--segment", a.segment, "The segment to rebuild")->required();
}

void run_build(const std::string& map_dir, MapBuildArgs& a) {
  MapBuildOptions& o = a.options;
  o.images_dir = a.images;
  if (a.gps != "exif") o.gps_csv = a.gps;
  o.poses = a.poses == "known" ? PoseSource::kKnown : PoseSource::kSfm;
  o.known_poses = a.known_poses;
  o.jobs = a.jobs;
  o.colmap.binary = a.colmap;
  if (a.segment >= 0) o.only_segments = {a.segment};
  const bool tty = ::isatty(STDERR_FILENO);
  auto progress = [tty](const MapBuildProgress& p) {
    // On a terminal the line is redrawn; in a log, one line per 10% of a stage.
    if (!tty && p.done != p.total && p.done != 0 && (p.done * 10 / p.total) == ((p.done - 1) * 10 / p.total)) return;
    const double rate = p.elapsed_s > 0 ? p.done / p.elapsed_s : 0;
    std::cerr << (tty ? "\r" : "") << "map build: " << p.stage << " " << p.done << "/" << p.total << ", "
              << std::fixed << std::setprecision(0) << p.elapsed_s << " s";
    if (p.stage == "segments" && p.done < p.total && rate > 0)
      std::cerr << ", ETA " << (p.total - p.done) / rate << " s";
    std::cerr << (tty && p.done < p.total ? "   " : "\n") << std::flush;
  };
  MapBuildResult r = build_map(map_dir, o, progress);
  std::cout << std::left << std::setw(8) << "segment" << std::right << std::setw(8) << "images" << std::setw(11)
            << "registered" << std::setw(9) << "points" << std::setw(10) << "B/point" << std::setw(12) << "GPS rms m"
            << std::setw(12) << "GPS max m" << std::setw(10) << "seconds" << "  status\n";
  for (const auto& s : r.segments) {
    std::cout << std::left << std::setw(8) << s.id << std::right << std::setw(8) << s.images << std::setw(11)
              << s.registered_images << std::setw(9) << s.points << std::fixed << std::setprecision(1)
              << std::setw(10) << s.bytes_per_point << std::setprecision(2) << std::setw(12) << s.registration_rms_m
              << std::setw(12) << s.registration_max_m << std::setprecision(1) << std::setw(10) << s.seconds << "  "
              << (s.ok ? (s.reused ? "reused" : "ok") : "FAILED: " + s.error) << "\n";
  }
  std::cout << r.images << " images, " << r.placemarks << " placemarks, " << r.segments.size() << " segments ("
            << r.failed() << " failed); features " << std::setprecision(1) << r.seconds_features << " s, segments "
            << r.seconds_segments << " s, total " << r.seconds_total << " s\n";
  if (r.failed() == r.segments.size())
    throw_error(ErrorCode::kExternalTool, "no segment could be built (see the logs under ", map_dir, "/work)");
}

}  // namespace

void add_map_build_commands(CLI::App& map) {
  auto build = std::make_shared<MapBuildArgs>();
  auto build_out = std::make_shared<std::string>();
  CLI::App* b = map.add_subcommand("build", "Build a map from geotagged images: segments reconstructed by COLMAP, "
                                            "compressed, geo-registered (resumable)");
  b->add_option("--out", *build_out, "Map directory (created; an interrupted build there resumes)")->required();
  bind_build_options(b, *build, false);
  b->callback([build, build_out] { run_build(*build_out, *build); });

  auto update = std::make_shared<MapBuildArgs>();
  auto update_map = std::make_shared<std::string>();
  CLI::App* u = map.add_subcommand("update", "Rebuild one segment of a map built by 'map build' (same inputs)");
  u->add_option("map", *update_map, "Map directory")->required();
  bind_build_options(u, *update, true);
  u->callback([update, update_map] { run_build(*update_map, *update); });
}

}  // namespace visloc::cli
