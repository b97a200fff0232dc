// GPS CSV: `image,lat,lon,alt[,placemark]`, one image per line, an optional
// header line (starting with "image"), '#' comments and blank lines ignored.
// Errors name the file and the line.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "visloc/geo/enu_frame.h"

namespace visloc {

struct GpsRecord {
  std::string image;
  GeoPosition position;
  std::optional<int> placemark;
};

std::vector<GpsRecord> read_gps_csv(const std::filesystem::path& path);
void write_gps_csv(const std::filesystem::path& path, const std::vector<GpsRecord>& records);

}  // namespace visloc
