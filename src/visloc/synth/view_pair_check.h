// How well SIFT features of two views of the synthetic city match under the
// true geometry. Because the scene is known exactly, every keypoint of view A
// has a true 3D point (the first surface along its pixel ray); the point is
// covisible when it lies in front of view B, inside B's image, and B's ray
// towards it is not blocked. A ratio-test match (A → B) is true when B's
// keypoint lies within `reprojection_threshold_px` of the projection of A's
// 3D point. The epipolar test uses only the true relative pose: symmetric
// point-to-epipolar-line distance (both images) below `epipolar_threshold_px`.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>

#include "visloc/features/feature_set.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/synth/city_writer.h"
#include "visloc/synth/ray_renderer.h"

namespace visloc::synth {

struct ViewPairCheckOptions {
  double ratio = 0.8;                     // Lowe's ratio (distances)
  double reprojection_threshold_px = 3.0;
  double epipolar_threshold_px = 2.0;
  double depth_tolerance = 0.01;          // relative, plus 5 cm, for the visibility ray
  void validate() const;
};

struct ViewPairCheck {
  size_t features_a = 0;
  size_t features_b = 0;
  size_t with_surface_a = 0;   // keypoints of A that see a surface (not sky)
  size_t covisible_a = 0;      // ... whose point B sees
  size_t ratio_matches = 0;    // A → B nearest neighbour passing the ratio test
  size_t true_matches = 0;     // ... landing within the reprojection threshold
  size_t epipolar_inliers = 0; // ... within the epipolar threshold of the true geometry
  void add(const ViewPairCheck& o);
  double true_fraction_of_features() const { return features_a ? double(true_matches) / features_a : 0.0; }
  double true_fraction_of_covisible() const { return covisible_a ? double(true_matches) / covisible_a : 0.0; }
  double precision() const { return ratio_matches ? double(true_matches) / ratio_matches : 0.0; }
  double epipolar_precision() const { return ratio_matches ? double(epipolar_inliers) / ratio_matches : 0.0; }
};

// Symmetric epipolar distance (pixels, mean of both images) of a
// correspondence under the true relative pose.
double symmetric_epipolar_distance(const PinholeCamera& camera_a, const CameraPose& pose_a,
                                   const PinholeCamera& camera_b, const CameraPose& pose_b,
                                   const Eigen::Vector2d& pixel_a, const Eigen::Vector2d& pixel_b);

ViewPairCheck check_view_pair(const ViewRenderer& renderer, const FeatureSet& features_a,
                              const PinholeCamera& camera_a, const CameraPose& pose_a,
                              const FeatureSet& features_b, const PinholeCamera& camera_b,
                              const CameraPose& pose_b, const ViewPairCheckOptions& options = {});

// ---------------------------------------------------------------------------
// Adjacent placemarks of a rendered city: views with the same heading and
// elevation at placemarks k and k+1 of one road, for `pairs` values of k
// spread evenly. Views are split into side views (heading within 45° of
// the road's normal: facades) and along-street views.
struct AdjacentPairReport {
  int pairs = 0;         // placemark pairs
  size_t view_pairs = 0; // image pairs
  ViewPairCheck side, along;
  ViewPairCheck all() const {
    ViewPairCheck a = side;
    a.add(along);
    return a;
  }
  double sift_ms = 0;    // total SIFT time
};

// Reads the images of a city written by write_city(options, city_dir).
AdjacentPairReport measure_adjacent_placemarks(const CityOptions& options, const std::filesystem::path& city_dir,
                                               int pairs, const SiftOptions& sift,
                                               const ViewPairCheckOptions& check = {});

// What `synth city --measure-pairs` prints: the pair counts and SIFT time, then the checks of side,
// along-street and all view pairs (two lines each: counts, then fractions).
std::string adjacent_pair_summary(const AdjacentPairReport& report);

}  // namespace visloc::synth
