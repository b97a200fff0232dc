// The 2D-3D matching benchmark behind `visloc bench matching`: held-out query
// images matched against a map imported with those images held out (`map
// import --holdout`), every method in the same run on the same queries (the
// paper's Fig. 5 and Table II matching rows):
//   exact         exhaustive NN on the raw (mean) SIFT, ratio 0.8 (the "kd-tree" row)
//   ivfadc-w1/w8  FAISS IVFADC, K_c = 256, PQ 16 × 8 bits, w cells visited
//   imi-w16/w64   FAISS inverted multi-index 2 × 8 bits, PQ 16 × 8 bits
//   lsh-cascade   CasHash-style: 8 random 16-bit tables, Hamming top L_R, PQ
//   ccs-*         the cascade search: without the refined step, full search,
//                 prioritized; LUT radius 0 (paper) and 1 (multi-index probing);
//                 ccs-directed-*: radius 1 probing 8, 6, 4 or 2 of 16 one-bit
//                 neighbours per table (query-directed, lut_flips), for every
//                 feature or those above 100, 200, 400 coarse candidates
//   rerank-*      only when a --method asks for it: the full search's short
//                 lists at radius 1 ranked by its own PQ, exact L2, FAISS PQ
//                 16 or 32 × 8 bits, OPQ + PQ 16 × 8 bits, at L_R 40 and 64:
//                 the recall levers (bench/reranking_study.h)
// Per method: milliseconds per query (matching only, one thread; rerank-*:
// the ranking alone), coarse
// candidates per feature, 1-1 matches, recall of the exact method's 1-1
// matches, bytes per point, and — scored with the held-out images' reference
// (SfM) poses — 1-1 matches within 4 px and, for the cascade, the 1-M set's
// size and features with a candidate within 4 px under both 1-M rules.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/features/sift_extractor.h"

namespace visloc {

struct MatchingBenchmarkScene {
  std::string map_dir;     // a map from `map import --holdout` (its first segment is searched)
  std::string query_list;  // the held-out query images' names, one a line
};

struct MatchingBenchmarkOptions {
  std::vector<MatchingBenchmarkScene> scenes;
  // COLMAP database with the queries' features (empty: each map's source database).
  std::string database;
  // Extract the queries' features from the files in `images` with `sift` instead.
  bool extract = false;
  std::string images;
  int max_queries = 0;               // per scene, the first ones of the list (<= 0: all)
  double ratio = 0.8;                // ratio test of the 1-1 sets (ν_h), in (0, 1]
  double inlier_px = 4.0;            // reprojection threshold with the reference pose, pixels (<= 0: no inliers)
  std::vector<std::string> methods;  // only methods whose name starts with one of these (empty: all but rerank-*)
  SiftOptions sift;                  // with `extract`
  // Throws Error(kInvalidArgument) naming the bad option.
  void validate() const;
};

struct MatchingBenchmarkResult {
  // {"methods": means per query over every scene, "scenes": [{"map", "points",
  // "methods"}], "openblas_threads"}.
  nlohmann::json report;
  std::string text;  // a table per scene (and over all scenes when several)
};

// Runs every wanted method on every scene, one thread (sets FAISS's thread
// count to 1, process-wide). `progress` (may be empty) receives a line per
// method and scene when it is done.
MatchingBenchmarkResult run_matching_benchmark(const MatchingBenchmarkOptions& options,
                                               const std::function<void(const std::string&)>& progress = {});

class OptionTable;
// The options but the scenes as command-line options (bench/option_tables.cc): --database, --extract, --images,
// --max-queries, --ratio, --inlier-px, --method, the SIFT options.
void add_options(OptionTable& table, MatchingBenchmarkOptions& options);

}  // namespace visloc
