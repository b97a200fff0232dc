// EnuFrame: a local east-north-up Cartesian frame (metres) tangent to the
// WGS84 ellipsoid at an origin, through GeographicLib's LocalCartesian
// (exact, no hand-made formula).
#pragma once

#include <Eigen/Core>
#include <memory>

namespace visloc {

struct GeoPosition {
  double lat = 0.0;  // degrees, WGS84
  double lon = 0.0;  // degrees
  double alt = 0.0;  // metres above the ellipsoid
};

class EnuFrame {
 public:
  // Throws Error(kInvalidArgument) for latitudes outside [-90, 90].
  explicit EnuFrame(const GeoPosition& origin);
  ~EnuFrame();
  EnuFrame(const EnuFrame& other);
  EnuFrame& operator=(const EnuFrame& other);

  const GeoPosition& origin() const { return origin_; }
  Eigen::Vector3d to_enu(const GeoPosition& p) const;
  GeoPosition to_geo(const Eigen::Vector3d& enu) const;

 private:
  struct Impl;
  GeoPosition origin_;
  std::unique_ptr<Impl> impl_;
};

// Heading in degrees clockwise from north of a direction in ENU.
double heading_deg_from_enu(const Eigen::Vector3d& direction_enu);

}  // namespace visloc
