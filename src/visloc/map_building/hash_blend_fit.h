// The hash-code blend's weight of a map (CascadeSearchOptions::
// hash_blend_weight, matching/hamming_blend.h), fitted on the map's own
// data: `visloc map fit-blend`. The views are observations of the map's
// points in its own images, read again from the COLMAP models and databases
// the map was made from:
//   - a map imported from a COLMAP model (map import --colmap): the model and
//     database its manifest names, its held-out images removed again;
//   - a built map (map build): each segment's MAP/work/segNNNN/database.db
//     and the model under its sparse/ (map build keeps them).
// The map must have kept its point descriptors: each segment's model's track
// means must be its descriptors (the check that model and database are still
// those the map was made from). The views are shared among the segments by
// their points; their counts are summed over the segments, and the weight is
// the grid weight with the most net right 1-1 matches in the sum.
// store_map_hash_blend writes it into the map's manifest (MapHashBlend), with
// the checksums of the segments it was fitted on; the localizer then uses it
// by default (LocalizerOptions::hash_blend_source).
#pragma once

#include <cstddef>
#include <filesystem>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "visloc/matching/hamming_blend.h"

namespace visloc {

struct MapBlendFitOptions {
  // Points sampled over the map, shared among its segments by their points:
  // each a distractor, and a held-out view when it has 2 views or more.
  size_t views = 4000;
  HammingBlendFitOptions fit;
  void validate() const;  // throws kInvalidArgument
};

struct MapBlendFit {
  struct SegmentSource {
    int segment = 0;
    std::string model, database;
    size_t points = 0, views = 0;
  };
  HammingBlendFit fit;  // summed over the segments; its weight chosen on the sum
  std::vector<SegmentSource> segments;
  std::vector<uint32_t> segment_crc32c;  // the manifest's segment files' checksums at the fit, in its order
  size_t points = 0;  // the map's
  int weight_steps = 20;
  double ms = 0;  // reading the models and databases, and the fits
  nlohmann::json to_json() const;
  std::string summary(const std::string& map_dir) const;
};

// Throws Error(kInvalidArgument) naming the map when it is neither kind or
// kept no descriptors or model, Error(kFormat) when a model's means are not
// its descriptors, and the model's and database's readers' errors.
MapBlendFit fit_map_hash_blend(const std::filesystem::path& map_dir, const MapBlendFitOptions& options = {});

// Writes the fit's weight into the map's manifest (atomically; the rest of the
// manifest unchanged). Throws Error(kInvalidArgument) naming the map when its
// segments are no longer those the fit read (the map was rebuilt meanwhile),
// or, with `lock_build`, when a build of the map is running (it holds
// MAP/work/build.lock and rewrites the manifest as its segments finish; the
// builder itself stores with lock_build false).
void store_map_hash_blend(const std::filesystem::path& map_dir, const MapBlendFit& fit, bool lock_build = true);

}  // namespace visloc
