// `visloc bench end-to-end`: the whole localizer on a query set, once per
// paper setting (1, 2, 3, 3+) on the same features in the same run, so that
// the settings' times are comparable ratios (setting 1 = the baseline: full
// cascade search + classical RANSAC). Feature extraction is done once per
// query and reported apart; "ms/query" excludes it.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/eval/protocols.h"
#include "visloc/pipeline/localizer.h"

namespace visloc {

struct EndToEndBenchmarkOptions {
  std::filesystem::path map;
  std::filesystem::path queries;     // query image names, one per line
  std::filesystem::path images_dir;  // the query images (needed with QueryFeatureSource::kImages)
  std::filesystem::path truth;       // reference poses 'name qw qx qy qz tx ty tz' (the map's frame)
  std::filesystem::path intrinsics;  // optional per-image intrinsics 'name MODEL w h params...'
  QueryFeatureSource query_features = QueryFeatureSource::kImages;  // our SIFT or the model's own
  std::vector<std::string> settings{"1", "2", "3", "3+"};  // paper settings in order; the first is the baseline
  int repeat = 1;                    // localizations per query and setting (times: their median)
  LocalizerOptions localizer;        // its setting is replaced by each of `settings`
  void validate() const;             // throws Error(kInvalidArgument) naming the bad field
};

struct EndToEndBenchmarkResult {
  // map, query_features, median_feature_ms, rows (per setting: registered,
  // median errors, median ms excluding features, matching, RANSAC, speed-up)
  nlohmann::json report;
  std::string table;  // Markdown table and the features line
};

// `progress` (may be empty) is called after each query's features (done, total).
EndToEndBenchmarkResult run_end_to_end_benchmark(const EndToEndBenchmarkOptions& options,
                                                 const std::function<void(size_t, size_t)>& progress = {});
// A `progress` for a terminal: "\rbench end-to-end: features DONE/TOTAL" on `out`, a newline after the last.
std::function<void(size_t, size_t)> end_to_end_progress_printer(std::ostream& out);

class OptionTable;
// The options as command-line options (bench/option_tables.cc): --map, --queries, --images, --truth,
// --intrinsics, --query-features, --settings, --repeat and the localizer's (--setting, ..., --cache-mib).
void add_options(OptionTable& table, EndToEndBenchmarkOptions& options);

}  // namespace visloc
