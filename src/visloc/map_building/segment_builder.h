// From a reconstructed COLMAP model and the mean SIFT of its points to the
// compressed segment (paper section III-B): ITQ learned on the segment's
// descriptors (or the map's rotation) → 128-bit codes; PQ codes with the map's shared
// codebook; XYZ; the images' poses and cameras. Used by `map import` (one
// segment) and `map build` (many).
#pragma once

#include <cstdint>

#include "visloc/colmap/colmap_model.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"

namespace visloc {

struct SegmentBuildStats {
  double itq_final_error = 0;
  double ms_itq = 0, ms_encode = 0;
};

// Each point's triangulation covariance from its track (geometry/point_uncertainty.h)
// with the keypoint noise the model's reprojection errors give; both left
// empty (0) when the model has no errors (exact, planted points).
void point_uncertainty_of_model(const ColmapModel& model, std::vector<PointUncertaintyCode>* codes,
                                double* keypoint_noise_px);

// `map_hasher`: the map's hash rotation; null: ITQ learned on this segment.
// Its point_uncertainty is left empty: a caller that stores it
// (--point-uncertainty) fills it with point_uncertainty_of_model.
SegmentData make_segment_data(const ColmapModel& model, const PointDescriptors& descriptors,
                              const PqCodebook& codebook, const ItqOptions& itq, uint32_t segment_id,
                              SegmentBuildStats* stats = nullptr, const BinaryHasher* map_hasher = nullptr);

}  // namespace visloc
