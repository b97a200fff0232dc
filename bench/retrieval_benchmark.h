// `visloc bench retrieval`: the retrieval stage (paper section III-A) on a set
// of map images and queries with known positions: recall of "at least one
// correct segment among the candidates" for N_t = 1, 5, 10, 20, 50 retrieved
// images, time per query on one core, memory fixed and per image; the
// system's T-embedding + IVF-PQ compared in the same run with exact search on
// the uncompressed embeddings and with VLAD of the same vocabulary, at the
// whitening / PCA dimensions asked for; then the same on a synthetic index of
// synthetic_size images (real map embeddings plus generated distractors).
//
// The bench takes the map's images directly and learns the embedding itself
// (no map is built): the image folder, the query names (a list, or leave one
// out), and a truth file giving every image's position (poses `name qw qx qy
// qz tx ty tz`, or a GPS CSV `image,lat,lon,alt[,placemark]` read in a local
// ENU frame). Segments are runs of placemarks_per_segment consecutive
// placemarks sharing `overlap` (DESIGN.md); placemarks come from the CSV's
// placemark column or are groups of placemark_size consecutive map images
// (names sorted). A query's correct segments are those holding the map image
// nearest to its true position among those facing within 90°
// (baselines/retrieval_truth.h).
//
// Timing: SIFT is reported separately (features_ms_per_image); ms_per_query
// is embedding + search + voting, with OpenMP limited to search_threads
// (default 1: omp_set_num_threads during the timed part; Eigen runs
// single-threaded).
//
// Also here: `visloc retrieval build|query`, the retrieval stage on its own
// (a retrieval map from a folder of images with every size parameter
// exposed, and the candidate segments of query images in a retrieval map).
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/baselines/retrieval_truth.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/retrieval/image_index.h"
#include "visloc/retrieval/segment_voter.h"
#include "visloc/retrieval/triangulation_embedding.h"

namespace visloc {

// SIFT as the retrieval commands extract it: images downscaled to 1024 pixels.
inline SiftOptions retrieval_sift_options() {
  SiftOptions o;
  o.max_image_side = 1024;
  return o;
}

struct RetrievalBenchmarkOptions {
  std::filesystem::path images;        // map images (and the queries unless query_images)
  std::filesystem::path query_images;  // empty: `images`
  std::filesystem::path queries;       // query names, one per line (exactly one of this and leave_one_out)
  bool leave_one_out = false;          // every map image in turn is a query, retrieved among the others
  std::filesystem::path truth;         // poses (world-to-camera) or GPS CSV (.csv) of map images and queries
  std::filesystem::path map_list;      // map image names (empty: every image of `images` not a query)
  std::filesystem::path train_images;  // learn the embedding on these images (empty: on the map's)
  int placemark_size = 1;              // consecutive map images per placemark without a placemark column
  SegmentRuleOptions segment_rule;
  std::vector<int> dims{0};                 // embedding dimensions compared (0: full whitening, k*128)
  TriangulationEmbeddingOptions embedding;  // output_dims ignored (see dims); seed also seeds the distractors
  bool democratic = false;                  // also democratic aggregation (exact search)
  bool vlad_ivfpq = false;                  // also VLAD with the IVF-PQ index
  ImageIndexOptions index;                  // type ignored: every method says its own
  SegmentVoterOptions voter;                // top_images: N_t of the candidate statistics (top1, cand)
  CorrectSegmentOptions truth_options;
  int search_threads = 1;  // OpenMP threads while timing queries
  SiftOptions sift = retrieval_sift_options();
  size_t synthetic_size = 100000;  // images of the synthetic index (real map + distractors); 0 skips it
  double synthetic_noise = 1.0;    // distractor = normalize(real map embedding + Gaussian noise of this norm)
  bool synthetic_exact = true;     // also time exact search on the synthetic index
  // Throws Error(kInvalidArgument) naming the bad option (as its command-line flag).
  void validate() const;
};

struct RetrievalBenchmarkResult {
  nlohmann::json report;  // {"dataset", "methods", "synthetic"} (synthetic: {} when skipped)
  std::string text;       // the dataset line and the recall/time tables (what the CLI prints without --json)
};

// `progress` (may be empty) receives one line when the embedding is trained.
// Throws Error naming the file or option on bad input.
RetrievalBenchmarkResult run_retrieval_benchmark(const RetrievalBenchmarkOptions& options,
                                                 const std::function<void(const std::string&)>& progress = {});

class OptionTable;
// The options as command-line options (bench/option_tables.cc): --images, --queries, --leave-one-out, --truth,
// the segment, embedding, index and voter options (--weighting one|rank), --synthetic-*, the SIFT options.
void add_options(OptionTable& table, RetrievalBenchmarkOptions& options);

// `visloc retrieval build`: SIFT on a folder of images, the T-embedding
// learned on them, an IVF-PQ index over them and the image -> segment table,
// written as a retrieval map (retrieval/retrieval_map.h; the same folder
// `map build` writes as MAP/retrieval, whose retrieval stage takes its images
// and segments from the map instead).
struct RetrievalMapBuildOptions {
  std::filesystem::path images;      // folder of the map images
  std::filesystem::path image_list;  // names to use, in route order (empty: every image, sorted by name)
  std::filesystem::path gps_csv;     // image,lat,lon,alt[,placemark]: placemarks (empty: placemark_size)
  std::filesystem::path out;         // retrieval map folder
  int placemark_size = 1;            // consecutive images per placemark without a placemark column
  SegmentRuleOptions segment_rule;
  TriangulationEmbeddingOptions embedding;
  ImageIndexOptions index;
  SiftOptions sift = retrieval_sift_options();
  void validate() const;  // Error(kInvalidArgument) naming the bad option
};

struct RetrievalMapBuildResult {
  size_t images = 0, segments = 0;
  int dims = 0;
  size_t bytes_per_image = 0, fixed_bytes = 0;  // index per image; index + embedding parameters
  double ms = 0;                                // embedding, index and writing (not SIFT)
  std::string summary;                          // one line (no newline)
};

RetrievalMapBuildResult build_retrieval_map(const RetrievalMapBuildOptions& options);
// --images, --list, --gps, --out, --placemark-size, the segment, embedding and index sizes, the SIFT options.
void add_options(OptionTable& table, RetrievalMapBuildOptions& options);

// `visloc retrieval query`: candidate segments of query images in a
// retrieval map (e.g. MAP/retrieval of a built map).
struct RetrievalMapQueryOptions {
  std::filesystem::path map;        // retrieval map folder
  std::vector<std::string> images;  // query image files
  SegmentVoterOptions voter;
  int nprobe = 0;  // IVF cells visited (0 or less: the map's)
  SiftOptions sift = retrieval_sift_options();
  void validate() const;
};

// Calls `per_image` once per query image, in order, as soon as it is done,
// with {"image", "candidates", "retrieved", "times_ms"}.
void query_retrieval_map(const RetrievalMapQueryOptions& options,
                         const std::function<void(const nlohmann::json&)>& per_image);
// --map, the query images, --top-images, --max-candidates, --nprobe, the SIFT options.
void add_options(OptionTable& table, RetrievalMapQueryOptions& options);

}  // namespace visloc
