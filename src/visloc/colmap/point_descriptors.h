// Mean SIFT descriptor of every 3D point of a COLMAP model: the average of
// the descriptors of the 2D points in its track, from the COLMAP database or
// any other source (a Bundler image's key file, colmap/bundler.h).
// The paper uses "mean descriptors" for each 3D point in all experiments
// (Tran et al., section IV). A track element (image_id, point2D_idx) names
// the point2D_idx-th keypoint of that image in the database.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"

namespace visloc {

struct PointDescriptors {
  size_t num_points = 0;
  std::vector<float> mean;           // num_points × 128, float mean of the track's uint8 descriptors
  std::vector<uint32_t> track_size;  // observations per point
  // With observation_sample > 0: one observation's descriptor (a track
  // element picked by a hash of the point's index) of that many points (all
  // when fewer), evenly spaced by index: held-out views of the points.
  std::vector<uint32_t> sampled_points;   // point indices, increasing
  DescriptorMatrix sampled_observations;  // a row per sampled point
};

// Reads each image's descriptors once. Throws Error(kFormat) naming the
// image when the database lacks it or has fewer keypoints than the model's
// 2D points refer to.
PointDescriptors compute_point_descriptors(const ColmapModel& model, const ColmapDatabase& database,
                                           size_t observation_sample = 0);

// The descriptors of one image of a model: row i belongs to its i-th 2D
// point (a COLMAP database's keypoints, a Bundler image's key file...).
using ImageDescriptorSource = std::function<DescriptorMatrix(const ColmapImage& image)>;

// The same from any descriptor source, called once per image that observes a
// point. `source_name` starts the error message when an image has fewer
// descriptors than its 2D points that the model refers to.
PointDescriptors compute_point_descriptors(const ColmapModel& model, const ImageDescriptorSource& source,
                                           const std::string& source_name, size_t observation_sample = 0);

// A database as a descriptor source: the descriptors of the image of the same
// name; Error(kFormat) naming the database when it lacks the image. The
// database must outlive the source.
ImageDescriptorSource database_descriptor_source(const ColmapDatabase& database);

// Rounds float descriptors to uint8 (clamped) rows.
DescriptorMatrix round_descriptors(const std::vector<float>& values);

}  // namespace visloc
