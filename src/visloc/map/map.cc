#include "visloc/map/map.h"

#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/mapped_file.h"
#include "visloc/util/section_file.h"

namespace visloc {
namespace fs = std::filesystem;

nlohmann::json MapManifest::to_json() const {
  nlohmann::json segs = nlohmann::json::array();
  for (const auto& s : segments)
    segs.push_back({{"id", s.id},
                    {"file", s.file},
                    {"descriptors_file", s.descriptors_file},
                    {"points", s.points},
                    {"images", s.images},
                    {"file_bytes", s.file_bytes},
                    {"file_crc32c", s.file_crc32c}});
  nlohmann::json j = {{"format", "visloc-map"},
                      {"format_version", format_version},
                      {"parameters", parameters},
                      {"pq_codebook_file", pq_codebook_file},
                      {"hash_rotation_file", hash_rotation_file},
                      {"segments", segs},
                      {"source", source},
                      {"holdout_images", holdout_images},
                      {"holdout_file", holdout_file}};
  j["enu_origin"] = enu_origin_lat_lon_alt
                        ? nlohmann::json{{"lat", (*enu_origin_lat_lon_alt)[0]},
                                         {"lon", (*enu_origin_lat_lon_alt)[1]},
                                         {"alt", (*enu_origin_lat_lon_alt)[2]}}
                        : nlohmann::json(nullptr);
  return j;
}

MapManifest MapManifest::from_json(const nlohmann::json& j, const std::string& what) {
  MapManifest m;
  try {
    if (j.at("format").get<std::string>() != "visloc-map")
      throw_error(ErrorCode::kFormat, what, ": not a visloc map manifest");
    m.format_version = j.at("format_version").get<int>();
    if (m.format_version < 1 || m.format_version > kMapFormatVersion)
      throw_error(ErrorCode::kFormat, what, ": map format version ", m.format_version,
                  " is not supported (this build reads 1..", kMapFormatVersion, ")");
    m.parameters = j.value("parameters", nlohmann::json::object());
    m.pq_codebook_file = j.at("pq_codebook_file").get<std::string>();
    m.hash_rotation_file = j.value("hash_rotation_file", "");
    for (const auto& s : j.at("segments")) {
      MapSegmentEntry e;
      e.id = s.at("id").get<uint32_t>();
      e.file = s.at("file").get<std::string>();
      e.descriptors_file = s.value("descriptors_file", "");
      e.points = s.at("points").get<size_t>();
      e.images = s.at("images").get<size_t>();
      e.file_bytes = s.at("file_bytes").get<uint64_t>();
      e.file_crc32c = s.at("file_crc32c").get<uint32_t>();
      m.segments.push_back(e);
    }
    m.source = j.value("source", nlohmann::json::object());
    m.holdout_images = j.value("holdout_images", std::vector<std::string>{});
    m.holdout_file = j.value("holdout_file", "");
    if (j.contains("enu_origin") && !j["enu_origin"].is_null())
      m.enu_origin_lat_lon_alt = std::array<double, 3>{j["enu_origin"].at("lat").get<double>(),
                                                       j["enu_origin"].at("lon").get<double>(),
                                                       j["enu_origin"].at("alt").get<double>()};
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, what, ": bad manifest: ", e.what());
  }
  return m;
}

void write_manifest(const fs::path& dir, const MapManifest& m) {
  write_file_atomic(dir / "manifest.json", m.to_json().dump(2) + "\n");
}

MapManifest read_manifest(const fs::path& dir) {
  const fs::path p = dir / "manifest.json";
  if (!fs::exists(p)) throw_error(ErrorCode::kIo, dir.string(), ": not a visloc map (no manifest.json)");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(read_file(p));
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, p.string(), ": not valid JSON: ", e.what());
  }
  return MapManifest::from_json(j, p.string());
}

void write_point_descriptor_file(const fs::path& path, const DescriptorMatrix& d, const std::vector<uint32_t>& track) {
  VISLOC_CHECK(track.size() == d.rows());
  SectionFileWriter w(path, "PDSC", kPointDescriptorFileVersion);
  w.add_text("META", nlohmann::json{{"points", d.rows()}, {"descriptor", "mean of track, uint8"}}.dump());
  w.add_array<uint8_t>("DESC", d.bytes());
  w.add_array<uint32_t>("TRACK", track);
  w.commit();
}

DescriptorMatrix read_point_descriptor_file(const fs::path& path) {
  SectionFileReader r(path, "PDSC", kPointDescriptorFileVersion, kPointDescriptorFileVersion);
  auto track = r.array<uint32_t>("TRACK");
  auto d = r.array<uint8_t>("DESC", int64_t(track.size()) * kDescriptorDim);
  return DescriptorMatrix(d.data(), track.size());
}

Map Map::open(const fs::path& dir) {
  Map m;
  m.dir_ = dir;
  m.manifest_ = read_manifest(dir);
  m.codebook_ = PqCodebook::read(dir / m.manifest_.pq_codebook_file);
  if (!m.manifest_.hash_rotation_file.empty())
    m.hasher_ = std::make_shared<const BinaryHasher>(read_hash_rotation_file(dir / m.manifest_.hash_rotation_file));
  return m;
}

std::unique_ptr<Segment> Map::open_segment(size_t index) const {
  VISLOC_CHECK(index < manifest_.segments.size());
  const auto& e = manifest_.segments[index];
  auto s = Segment::open(dir_ / e.file, hasher_);
  if (s->bytes().file != e.file_bytes || s->num_points() != e.points || s->id() != e.id)
    throw_error(ErrorCode::kFormat, (dir_ / e.file).string(), ": segment does not match the manifest (",
                s->bytes().file, " bytes, ", s->num_points(), " points, id ", s->id(), "; manifest says ",
                e.file_bytes, " bytes, ", e.points, " points, id ", e.id, ")");
  return s;
}

MapInfo map_info(const fs::path& dir) {
  MapInfo info;
  Map map = Map::open(dir);
  info.manifest = map.manifest();
  info.codebook_bytes = fs::file_size(dir / map.manifest().pq_codebook_file);
  info.total_bytes = info.codebook_bytes;
  if (!map.manifest().hash_rotation_file.empty()) {
    info.hash_rotation_bytes = fs::file_size(dir / map.manifest().hash_rotation_file);
    info.total_bytes += info.hash_rotation_bytes;
  }
  for (size_t i = 0; i < map.manifest().segments.size(); ++i) {
    auto s = map.open_segment(i);
    MapSegmentInfo si{s->id(), s->num_points(), s->images().size(), s->format_version(), s->bytes()};
    info.total_points += si.points;
    info.total_per_point_bytes += si.bytes.per_point;
    info.total_bytes += si.bytes.file;
    info.segments.push_back(si);
  }
  return info;
}

nlohmann::json MapInfo::to_json() const {
  nlohmann::json segs = nlohmann::json::array();
  for (const auto& s : segments)
    segs.push_back({{"id", s.id},
                    {"points", s.points},
                    {"images", s.images},
                    {"file_bytes", s.bytes.file},
                    {"per_point_section_bytes", s.bytes.per_point},
                    {"format_version", s.format_version},
                    {"lookup_table_file_bytes", s.bytes.lookup_tables},
                    {"lookup_table_memory_bytes", s.bytes.lookup_memory},
                    {"hasher_bytes", s.bytes.hasher},
                    {"other_bytes", s.bytes.other},
                    {"bytes_per_point", s.bytes.per_point_bytes_per_point(s.points)},
                    {"file_bytes_per_point", s.bytes.file_bytes_per_point(s.points)}});
  const double n = total_points ? double(total_points) : 1.0;
  return {{"segments", segs},
          {"total",
           {{"segments", segments.size()},
            {"points", total_points},
            {"bytes_per_point", double(total_per_point_bytes) / n},
            {"bytes_per_point_including_tables_and_codebook", double(total_bytes) / n},
            {"file_bytes_per_point", double(total_bytes) / n},
            {"bytes", total_bytes},
            {"pq_codebook_bytes", codebook_bytes},
            {"hash_rotation_bytes", hash_rotation_bytes}}},
          {"holdout_images", manifest.holdout_images}};
}

}  // namespace visloc
