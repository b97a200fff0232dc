#include "visloc/geo/enu_frame.h"

#include <GeographicLib/LocalCartesian.hpp>
#include <cmath>
#include <numbers>

#include "visloc/util/error.h"

namespace visloc {

struct EnuFrame::Impl {
  GeographicLib::LocalCartesian frame;
};

EnuFrame::EnuFrame(const GeoPosition& origin) : origin_(origin) {
  if (!(std::abs(origin.lat) <= 90.0) || !std::isfinite(origin.lon) || !std::isfinite(origin.alt))
    throw_error(ErrorCode::kInvalidArgument, "ENU origin must have latitude in [-90, 90] and finite "
                "longitude and altitude, got ", origin.lat, ", ", origin.lon, ", ", origin.alt);
  impl_ = std::make_unique<Impl>(Impl{GeographicLib::LocalCartesian(origin.lat, origin.lon, origin.alt)});
}

EnuFrame::~EnuFrame() = default;
EnuFrame::EnuFrame(const EnuFrame& other)
    : origin_(other.origin_), impl_(std::make_unique<Impl>(*other.impl_)) {}
EnuFrame& EnuFrame::operator=(const EnuFrame& other) {
  if (this != &other) {
    origin_ = other.origin_;
    impl_ = std::make_unique<Impl>(*other.impl_);
  }
  return *this;
}

Eigen::Vector3d EnuFrame::to_enu(const GeoPosition& p) const {
  Eigen::Vector3d e;
  impl_->frame.Forward(p.lat, p.lon, p.alt, e.x(), e.y(), e.z());
  return e;
}

GeoPosition EnuFrame::to_geo(const Eigen::Vector3d& enu) const {
  GeoPosition g;
  impl_->frame.Reverse(enu.x(), enu.y(), enu.z(), g.lat, g.lon, g.alt);
  return g;
}

double heading_deg_from_enu(const Eigen::Vector3d& d) {
  double h = std::atan2(d.x(), d.y()) * 180.0 / std::numbers::pi;
  return h < 0 ? h + 360.0 : h;
}

}  // namespace visloc
