// Cutting a city into segments (paper section III-A): images taken at one
// spot form a placemark; placemarks are ordered along the route; a segment
// is a run of 8-10 consecutive placemarks, consecutive segments sharing 2
// placemarks, so that every place is inside a segment with some context.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "visloc/geo/enu_frame.h"
#include "visloc/geo/gps_csv.h"

namespace visloc {

enum class PlacemarkOrder {
  kCapture,  // the order of first appearance in the GPS list (a drive or a walk)
  kChain,    // nearest-neighbour chaining from an end (unordered collections)
};

struct SegmentPlanOptions {
  int min_placemarks = 8;      // a segment has between min and max placemarks...
  int max_placemarks = 10;
  int overlap = 2;             // ...and shares `overlap` with the next one
  double placemark_radius = 3.0;  // metres: consecutive images within it form a placemark (no placemark column)
  PlacemarkOrder order = PlacemarkOrder::kCapture;
  void validate() const;
};

struct Placemark {
  int id = 0;                   // the CSV's placemark id, or a running number
  std::vector<size_t> images;   // indices into the GPS records
  Eigen::Vector3d center_enu = Eigen::Vector3d::Zero();
};

struct SegmentPlan {
  std::vector<Placemark> placemarks;          // in route order
  std::vector<std::vector<int>> segments;     // indices into placemarks
};

// Groups images into placemarks: by the CSV's placemark column when every
// record has one, else consecutive images within `placemark_radius` of the
// group's first image.
std::vector<Placemark> group_placemarks(const std::vector<GpsRecord>& records, const EnuFrame& frame,
                                        double placemark_radius);

// Windows over n ordered placemarks: k = ceil((n - overlap) / (max - overlap))
// segments whose starts are spread evenly, each ending `overlap` placemarks
// after the next one starts (more overlap when a window would fall short
// of min). One segment when n <= max.
std::vector<std::vector<int>> partition_segments(int n, const SegmentPlanOptions& options);

SegmentPlan plan_segments(const std::vector<GpsRecord>& records, const EnuFrame& frame,
                          const SegmentPlanOptions& options);

}  // namespace visloc
