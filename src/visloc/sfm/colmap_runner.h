// ColmapRunner: drives the COLMAP 3.8 binary as a process for one segment:
// feature matching (exhaustive, sequential or spatial, on the CPU), the
// incremental mapper, or point_triangulator when poses are known. Output of
// every call goes to a log file; failures raise Error(kExternalTool) quoting
// the log's tail. COLMAP's seed is fixed so that runs repeat.
#pragma once

#include <filesystem>
#include <string>

namespace visloc {

enum class ColmapMatchStrategy { kExhaustive, kSequential, kSpatial };

struct ColmapRunnerOptions {
  std::string binary = "colmap";
  int threads = 1;                   // COLMAP threads per call
  int sequential_overlap = 10;       // images matched forward in sequential matching
  double spatial_max_distance = 50;  // metres, spatial matching (priors in ENU)
  int spatial_max_neighbors = 30;
  int min_model_size = 3;            // mapper: smallest model kept
  bool refine_focal = true;          // mapper: refine focal lengths in BA
  double init_min_tri_angle = 4;     // mapper: degrees (COLMAP's 16 rejects street sequences' small baselines)
  int init_min_num_inliers = 50;     // mapper: matches of the initial pair (COLMAP: 100)
  // mapper: largest forward-motion component of the initial pair (COLMAP:
  // 0.95). Photos walked along a street look along the motion: with 0.95 and
  // even 0.995 COLMAP found no initial pair in a Lund segment that it
  // reconstructs completely (10/10 images) with 1.0.
  double init_max_forward_motion = 1.0;
  int random_seed = 1;
  void validate() const;
};

class ColmapRunner {
 public:
  explicit ColmapRunner(const ColmapRunnerOptions& options);
  void match(const std::filesystem::path& database, ColmapMatchStrategy strategy,
             const std::filesystem::path& log) const;
  // Matches exactly the listed image pairs (names, one pair per line:
  // "a.jpg b.jpg"), through COLMAP's matches_importer.
  void match_pairs(const std::filesystem::path& database, const std::filesystem::path& pair_list,
                   const std::filesystem::path& log) const;
  // Runs the mapper into output_dir (COLMAP writes numbered sub-models);
  // returns the directory of the largest sub-model. Throws when none was made.
  std::filesystem::path map(const std::filesystem::path& database, const std::filesystem::path& image_dir,
                            const std::filesystem::path& output_dir, const std::filesystem::path& log) const;
  // Registers the database's images that `input_model` lacks into it
  // (COLMAP's image_registrator: 2D-3D from the verified matches, P3P RANSAC,
  // no triangulation); the model is written to output_dir.
  void register_images(const std::filesystem::path& database, const std::filesystem::path& input_model,
                       const std::filesystem::path& output_dir, const std::filesystem::path& log) const;
  void triangulate(const std::filesystem::path& database, const std::filesystem::path& image_dir,
                   const std::filesystem::path& input_model, const std::filesystem::path& output_dir,
                   const std::filesystem::path& log) const;

 private:
  ColmapRunnerOptions options_;
};

// Picks a matcher by collection size: exhaustive up to `exhaustive_max`
// images, spatial when every image has a position prior, else sequential.
ColmapMatchStrategy choose_match_strategy(size_t num_images, bool have_position_priors, size_t exhaustive_max = 60);

}  // namespace visloc
