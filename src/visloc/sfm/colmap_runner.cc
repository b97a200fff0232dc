#include "visloc/sfm/colmap_runner.h"

#include <vector>

#include "visloc/sfm/process.h"
#include "visloc/util/error.h"

namespace visloc {

void ColmapRunnerOptions::validate() const {
  if (binary.empty()) throw_error(ErrorCode::kInvalidArgument, "COLMAP binary must be named");
  if (threads < 1) throw_error(ErrorCode::kInvalidArgument, "COLMAP threads must be >= 1, got ", threads);
  if (sequential_overlap < 1)
    throw_error(ErrorCode::kInvalidArgument, "sequential_overlap must be >= 1, got ", sequential_overlap);
  if (!(spatial_max_distance > 0))
    throw_error(ErrorCode::kInvalidArgument, "spatial_max_distance must be positive, got ", spatial_max_distance);
  if (min_model_size < 2) throw_error(ErrorCode::kInvalidArgument, "min_model_size must be >= 2, got ", min_model_size);
  if (!(init_min_tri_angle > 0 && init_min_tri_angle < 90))
    throw_error(ErrorCode::kInvalidArgument, "init_min_tri_angle must be in (0, 90) degrees, got ", init_min_tri_angle);
  if (!(init_max_forward_motion > 0 && init_max_forward_motion <= 1))
    throw_error(ErrorCode::kInvalidArgument, "init_max_forward_motion must be in (0, 1], got ", init_max_forward_motion);
  if (init_min_num_inliers < 8)
    throw_error(ErrorCode::kInvalidArgument, "init_min_num_inliers must be >= 8, got ", init_min_num_inliers);
}

ColmapRunner::ColmapRunner(const ColmapRunnerOptions& options) : options_(options) { options_.validate(); }

void ColmapRunner::match(const std::filesystem::path& database, ColmapMatchStrategy strategy,
                         const std::filesystem::path& log) const {
  std::vector<std::string> argv = {options_.binary};
  switch (strategy) {
    case ColmapMatchStrategy::kExhaustive: argv.push_back("exhaustive_matcher"); break;
    case ColmapMatchStrategy::kSequential:
      argv.insert(argv.end(), {"sequential_matcher", "--SequentialMatching.overlap",
                               std::to_string(options_.sequential_overlap)});
      break;
    case ColmapMatchStrategy::kSpatial:
      argv.insert(argv.end(), {"spatial_matcher", "--SpatialMatching.is_gps", "0", "--SpatialMatching.ignore_z", "0",
                               "--SpatialMatching.max_distance", std::to_string(options_.spatial_max_distance),
                               "--SpatialMatching.max_num_neighbors", std::to_string(options_.spatial_max_neighbors)});
      break;
  }
  argv.insert(argv.end(), {"--database_path", database.string(), "--SiftMatching.use_gpu", "0",
                           "--SiftMatching.num_threads", std::to_string(options_.threads), "--random_seed",
                           std::to_string(options_.random_seed)});
  run_process(argv, log);
}

void ColmapRunner::match_pairs(const std::filesystem::path& database, const std::filesystem::path& pair_list,
                               const std::filesystem::path& log) const {
  run_process({options_.binary, "matches_importer", "--database_path", database.string(), "--match_list_path",
               pair_list.string(), "--match_type", "pairs", "--SiftMatching.use_gpu", "0",
               "--SiftMatching.num_threads", std::to_string(options_.threads), "--random_seed",
               std::to_string(options_.random_seed)},
              log);
}

std::filesystem::path ColmapRunner::map(const std::filesystem::path& database, const std::filesystem::path& image_dir,
                                        const std::filesystem::path& output_dir,
                                        const std::filesystem::path& log) const {
  std::filesystem::create_directories(output_dir);
  run_process({options_.binary, "mapper", "--database_path", database.string(), "--image_path", image_dir.string(),
               "--output_path", output_dir.string(), "--Mapper.num_threads", std::to_string(options_.threads),
               "--Mapper.min_model_size", std::to_string(options_.min_model_size), "--Mapper.ba_refine_focal_length",
               options_.refine_focal ? "1" : "0", "--Mapper.init_min_tri_angle",
               std::to_string(options_.init_min_tri_angle), "--Mapper.init_min_num_inliers",
               std::to_string(options_.init_min_num_inliers), "--Mapper.init_max_forward_motion",
               std::to_string(options_.init_max_forward_motion), "--random_seed", std::to_string(options_.random_seed)},
              log);
  // The largest sub-model by the size of its points3D.bin.
  std::filesystem::path best;
  uintmax_t best_size = 0;
  for (const auto& e : std::filesystem::directory_iterator(output_dir)) {
    const auto pts = e.path() / "points3D.bin";
    if (!e.is_directory() || !std::filesystem::exists(pts)) continue;
    const uintmax_t size = std::filesystem::file_size(pts);
    if (best.empty() || size > best_size) {
      best = e.path();
      best_size = size;
    }
  }
  if (best.empty())
    throw_error(ErrorCode::kExternalTool, "COLMAP mapper made no model from ", database.string(), " (log: ",
                log.string(), "); last lines:\n", tail_of_file(log, 8));
  return best;
}

void ColmapRunner::triangulate(const std::filesystem::path& database, const std::filesystem::path& image_dir,
                               const std::filesystem::path& input_model, const std::filesystem::path& output_dir,
                               const std::filesystem::path& log) const {
  std::filesystem::create_directories(output_dir);
  run_process({options_.binary, "point_triangulator", "--database_path", database.string(), "--image_path",
               image_dir.string(), "--input_path", input_model.string(), "--output_path", output_dir.string(),
               "--Mapper.num_threads", std::to_string(options_.threads), "--Mapper.ba_refine_focal_length", "0",
               "--Mapper.ba_refine_principal_point", "0", "--Mapper.ba_refine_extra_params", "0", "--random_seed",
               std::to_string(options_.random_seed)},
              log);
}

void ColmapRunner::register_images(const std::filesystem::path& database, const std::filesystem::path& input_model,
                                   const std::filesystem::path& output_dir, const std::filesystem::path& log) const {
  std::filesystem::create_directories(output_dir);
  run_process({options_.binary, "image_registrator", "--database_path", database.string(), "--input_path",
               input_model.string(), "--output_path", output_dir.string(), "--Mapper.num_threads",
               std::to_string(options_.threads), "--random_seed", std::to_string(options_.random_seed)},
              log);
}

ColmapMatchStrategy choose_match_strategy(size_t num_images, bool have_position_priors, size_t exhaustive_max) {
  if (num_images <= exhaustive_max) return ColmapMatchStrategy::kExhaustive;
  return have_position_priors ? ColmapMatchStrategy::kSpatial : ColmapMatchStrategy::kSequential;
}

}  // namespace visloc
