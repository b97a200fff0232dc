#include "visloc/geo/gps_csv.h"

#include <charconv>
#include <cmath>
#include <iomanip>
#include <set>
#include <sstream>

#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace {

std::string trim(std::string_view s) {
  size_t b = s.find_first_not_of(" \t\r");
  if (b == std::string_view::npos) return "";
  size_t e = s.find_last_not_of(" \t\r");
  return std::string(s.substr(b, e - b + 1));
}

std::vector<std::string> split(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string field;
  std::istringstream s(line);
  while (std::getline(s, field, sep)) out.push_back(trim(field));
  if (!line.empty() && line.back() == sep) out.emplace_back();
  return out;
}

}  // namespace

std::vector<GpsRecord> read_gps_csv(const std::filesystem::path& path) {
  std::string content = read_file(path);
  if (content.rfind("\xEF\xBB\xBF", 0) == 0) content.erase(0, 3);  // a UTF-8 byte-order mark (spreadsheets write one)
  std::istringstream in(content);
  std::vector<GpsRecord> records;
  std::set<std::string> seen;
  std::string line;
  int line_no = 0;
  auto fail = [&](const auto&... parts) {
    throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": ", parts...);
  };
  auto number = [&](const std::string& field, const char* what) {
    double v = 0;
    auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), v);
    if (ec != std::errc() || ptr != field.data() + field.size() || !std::isfinite(v))
      fail(what, " '", field, "' is not a number");
    return v;
  };
  while (std::getline(in, line)) {
    ++line_no;
    std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    if (records.empty() && t.rfind("image", 0) == 0) continue;  // header
    auto f = split(t, ',');
    if (f.size() != 4 && f.size() != 5)
      fail("expected 4 or 5 comma-separated fields (image,lat,lon,alt[,placemark]), found ", f.size());
    GpsRecord r;
    r.image = f[0];
    if (r.image.empty()) fail("empty image name");
    r.position.lat = number(f[1], "latitude");
    r.position.lon = number(f[2], "longitude");
    r.position.alt = f[3].empty() ? 0.0 : number(f[3], "altitude");
    if (std::abs(r.position.lat) > 90) fail("latitude ", r.position.lat, " outside [-90, 90]");
    if (std::abs(r.position.lon) > 180) fail("longitude ", r.position.lon, " outside [-180, 180]");
    if (f.size() == 5 && !f[4].empty()) {
      int pm = 0;
      auto [ptr, ec] = std::from_chars(f[4].data(), f[4].data() + f[4].size(), pm);
      if (ec != std::errc() || ptr != f[4].data() + f[4].size() || pm < 0)
        fail("placemark '", f[4], "' is not a non-negative integer");
      r.placemark = pm;
    }
    if (!seen.insert(r.image).second) fail("image '", r.image, "' listed twice");
    records.push_back(std::move(r));
  }
  if (records.empty()) throw_error(ErrorCode::kFormat, path.string(), ": no GPS records");
  return records;
}

void write_gps_csv(const std::filesystem::path& path, const std::vector<GpsRecord>& records) {
  std::ostringstream s;
  bool any_placemark = false;
  for (const auto& r : records) any_placemark |= r.placemark.has_value();
  s << (any_placemark ? "image,lat,lon,alt,placemark\n" : "image,lat,lon,alt\n");
  s << std::setprecision(12);
  for (const auto& r : records) {
    s << r.image << ',' << r.position.lat << ',' << r.position.lon << ',' << std::setprecision(6)
      << r.position.alt << std::setprecision(12);
    if (any_placemark) s << ',' << (r.placemark ? std::to_string(*r.placemark) : "");
    s << '\n';
  }
  write_file_atomic(path, s.str());
}

}  // namespace visloc
