// The hash-code blend's weight of a map (CascadeSearchOptions::
// hash_blend_weight, matching/hamming_blend.h), fitted on the map's own
// data: `visloc map fit-blend`. The views are observations of the map's
// points in its own images, read again from the COLMAP model and database a
// map was imported from (its held-out images removed as at the import), so
// it needs a one-segment map from `map import --colmap` that kept its point
// descriptors (the check that the model's track means are the map's
// descriptors, i.e. that model and database are still those of the import).
#pragma once

#include <cstddef>
#include <filesystem>
#include <nlohmann/json_fwd.hpp>
#include <string>

#include "visloc/matching/hamming_blend.h"

namespace visloc {

struct MapBlendFitOptions {
  size_t views = 4000;  // points whose held-out view is searched (and as many distractors)
  HammingBlendFitOptions fit;
  void validate() const;  // throws kInvalidArgument
};

struct MapBlendFit {
  HammingBlendFit fit;
  size_t points = 0;  // the segment's
  int weight_steps = 20;
  std::string model, database;
  double ms_read = 0, ms_fit = 0;
  nlohmann::json to_json() const;
  std::string summary(const std::string& map_dir) const;
};

// Throws Error(kInvalidArgument) naming the map when it is not such a map,
// Error(kFormat) when its model's means are not its descriptors, and the
// model's and database's readers' errors.
MapBlendFit fit_map_hash_blend(const std::filesystem::path& map_dir, const MapBlendFitOptions& options = {});

}  // namespace visloc
