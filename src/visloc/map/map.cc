#include "visloc/map/map.h"

#include <algorithm>

#include <cmath>
#include <iomanip>
#include <limits>
#include <set>
#include <sstream>

#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/json_fields.h"
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
  if (hash_blend)
    j["hash_blend"] = {
        {"weight", hash_blend->weight}, {"segment_crc32c", hash_blend->segment_crc32c}, {"fit", hash_blend->fit}};
  return j;
}

std::optional<double> MapManifest::fitted_hash_blend() const {
  if (!hash_blend || hash_blend->segment_crc32c.size() != segments.size()) return std::nullopt;
  for (size_t i = 0; i < segments.size(); ++i)
    if (hash_blend->segment_crc32c[i] != segments[i].file_crc32c) return std::nullopt;
  return hash_blend->weight;
}

namespace {

// A file named by the manifest: relative, inside the map directory.
std::string map_relative_file(const JsonField& f) {
  std::string name = f.string();
  const fs::path p(name);
  if (name.empty()) f.fail("is empty");
  if (p.is_absolute()) f.fail("must be a path relative to the map directory, found '", name, "'");
  for (const auto& part : p)
    if (part == "..") f.fail("must stay inside the map directory, found '", name, "'");
  return name;
}

}  // namespace

MapManifest MapManifest::from_json(const nlohmann::json& json, const std::string& what) {
  MapManifest m;
  const JsonField j(json, what);
  if (!json.is_object()) j.fail("must be a JSON object, found ", json.type_name());
  if (j.at("format").string() != "visloc-map") throw_error(ErrorCode::kFormat, what, ": not a visloc map manifest");
  m.format_version = static_cast<int>(j.at("format_version").integer(std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
  if (m.format_version < 1 || m.format_version > kMapFormatVersion)
    throw_error(ErrorCode::kFormat, what, ": map format version ", m.format_version,
                " is not supported (this build reads 1..", kMapFormatVersion, ")");
  if (j.has("parameters")) {
    if (!json["parameters"].is_object()) j.at("parameters").fail("must be an object, found ", json["parameters"].type_name());
    m.parameters = json["parameters"];
  }
  m.pq_codebook_file = map_relative_file(j.at("pq_codebook_file"));
  if (j.has("hash_rotation_file") && !j.at("hash_rotation_file").string().empty())
    m.hash_rotation_file = map_relative_file(j.at("hash_rotation_file"));
  const JsonField segs = j.at("segments");
  std::set<uint32_t> ids;
  for (size_t i = 0; i < segs.size(); ++i) {
    const JsonField s = segs.at(i);
    MapSegmentEntry e;
    e.id = static_cast<uint32_t>(s.at("id").unsigned_integer(std::numeric_limits<uint32_t>::max()));
    if (!ids.insert(e.id).second) s.at("id").fail("repeats segment id ", e.id);
    e.file = map_relative_file(s.at("file"));
    if (s.has("descriptors_file") && !s.at("descriptors_file").string().empty())
      e.descriptors_file = map_relative_file(s.at("descriptors_file"));
    e.points = s.at("points").unsigned_integer(CascadeLookup::kMaxPoints);
    e.images = s.at("images").unsigned_integer(std::numeric_limits<uint32_t>::max());
    e.file_bytes = s.at("file_bytes").unsigned_integer();
    e.file_crc32c = static_cast<uint32_t>(s.at("file_crc32c").unsigned_integer(std::numeric_limits<uint32_t>::max()));
    m.segments.push_back(e);
  }
  if (j.has("source")) m.source = json["source"];
  if (j.has("holdout_images")) m.holdout_images = j.at("holdout_images").strings();
  if (j.has("holdout_file") && !j.at("holdout_file").string().empty())
    m.holdout_file = map_relative_file(j.at("holdout_file"));
  if (j.has("enu_origin")) {
    const JsonField o = j.at("enu_origin");
    const double lat = o.at("lat").number(), lon = o.at("lon").number(), alt = o.at("alt").number();
    if (!(lat >= -90 && lat <= 90)) o.at("lat").fail("must be a latitude in [-90, 90], found ", lat);
    if (!(lon >= -180 && lon <= 180)) o.at("lon").fail("must be a longitude in [-180, 180], found ", lon);
    if (!(std::abs(alt) <= 1e5)) o.at("alt").fail("must be an altitude within ±100 km, found ", alt);
    m.enu_origin_lat_lon_alt = std::array<double, 3>{lat, lon, alt};
  }
  if (j.has("hash_blend") && !json["hash_blend"].is_null()) {
    const JsonField b = j.at("hash_blend");
    MapHashBlend blend;
    blend.weight = b.at("weight").number();
    if (!(blend.weight >= 0 && blend.weight <= 1)) b.at("weight").fail("must be in [0, 1], found ", blend.weight);
    const JsonField crcs = b.at("segment_crc32c");
    for (size_t i = 0; i < crcs.size(); ++i)
      blend.segment_crc32c.push_back(
          static_cast<uint32_t>(crcs.at(i).unsigned_integer(std::numeric_limits<uint32_t>::max())));
    if (b.has("fit")) blend.fit = json["hash_blend"]["fit"];
    m.hash_blend = std::move(blend);
  }
  return m;
}

void write_manifest(const fs::path& dir, const MapManifest& m) {
  write_file_atomic(dir / "manifest.json", m.to_json().dump(2) + "\n");
}

MapManifest read_manifest(const fs::path& dir) {
  const fs::path p = dir / "manifest.json";
  if (!fs::exists(p)) throw_error(ErrorCode::kIo, dir.string(), ": not a visloc map (no manifest.json)");
  return MapManifest::from_json(parse_json(read_file(p), p.string()), p.string());
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
  if (s->index().pq_subvectors != codebook_.subvectors())
    throw_error(ErrorCode::kFormat, (dir_ / e.file).string(), ": PQ codes of ", s->index().pq_subvectors,
                " bytes, but the map's codebook (", (dir_ / manifest_.pq_codebook_file).string(), ") makes ",
                codebook_.code_bytes(), "-byte codes");
  return s;
}

MapInfo map_info(const fs::path& dir) {
  MapInfo info;
  Map map = Map::open(dir);
  info.manifest = map.manifest();
  info.codebook_bytes = fs::file_size(dir / map.manifest().pq_codebook_file);
  info.pq_code_bytes = map.codebook().code_bytes();
  info.pq_quantizer = map.codebook().quantizer();
  if (map.codebook().is_residual()) {
    info.pq_residual_splits = map.codebook().residual_splits();
    info.pq_residual_beam = map.codebook().residual_beam();
  }
  info.total_bytes = info.codebook_bytes;
  if (!map.manifest().hash_rotation_file.empty()) {
    info.hash_rotation_bytes = fs::file_size(dir / map.manifest().hash_rotation_file);
    info.total_bytes += info.hash_rotation_bytes;
  }
  for (size_t i = 0; i < map.manifest().segments.size(); ++i) {
    auto s = map.open_segment(i);
    MapSegmentInfo si{s->id(),    s->num_points(),       s->images().size(), s->format_version(),
                      s->bytes(), s->xyz_quantization(), std::nullopt};
    si.point_uncertainty = !s->point_uncertainty().empty();
    if (s->enu_from_segment()) si.metres_per_unit = s->enu_from_segment()->scale;
    info.total_points += si.points;
    info.total_per_point_bytes += si.bytes.per_point;
    info.total_bytes += si.bytes.file;
    info.segments.push_back(si);
  }
  return info;
}

nlohmann::json MapInfo::to_json() const {
  nlohmann::json segs = nlohmann::json::array();
  for (const auto& s : segments) {
    nlohmann::json error_m = nullptr;
    if (s.metres_per_unit) error_m = *s.metres_per_unit * s.xyz_rounding_error();
    segs.push_back({{"id", s.id},
                    {"points", s.points},
                    {"images", s.images},
                    {"file_bytes", s.bytes.file},
                    {"per_point_section_bytes", s.bytes.per_point},
                    {"format_version", s.format_version},
                    {"lookup_table_file_bytes", s.bytes.lookup_tables},
                    {"lookup_table_memory_bytes", s.bytes.lookup_memory},
                    {"xyz_coordinates", s.xyz_quantization ? "int16" : "float32"},
                    {"xyz_rounding_error", s.xyz_rounding_error()},  // segment units, per axis
                    {"xyz_rounding_error_m", error_m},               // null without a metric scale
                    {"xyz_decoded_memory_bytes", s.bytes.xyz_memory},
                    {"point_uncertainty", s.point_uncertainty},
                    {"hasher_bytes", s.bytes.hasher},
                    {"other_bytes", s.bytes.other},
                    {"bytes_per_point", s.bytes.per_point_bytes_per_point(s.points)},
                    {"file_bytes_per_point", s.bytes.file_bytes_per_point(s.points)}});
  }
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
            {"pq_code_bytes", pq_code_bytes},
            {"pq_quantizer", to_string(pq_quantizer)},
            {"pq_residual_splits", pq_residual_splits ? nlohmann::json(pq_residual_splits) : nlohmann::json()},
            {"pq_residual_beam", pq_residual_beam ? nlohmann::json(pq_residual_beam) : nlohmann::json()},
            {"hash_rotation_bytes", hash_rotation_bytes}}},
          {"holdout_images", manifest.holdout_images},
          {"hash_blend", manifest.hash_blend ? nlohmann::json{{"weight", manifest.hash_blend->weight},
                                                              {"current", manifest.fitted_hash_blend().has_value()}}
                                             : nlohmann::json()}};
}

namespace {

std::string xyz_summary(const MapSegmentInfo& s) {
  if (!s.xyz_quantization) return s.point_uncertainty ? "float32, point uncertainty" : "float32";
  std::ostringstream out;
  out << "int16 (" << std::setprecision(3);
  if (s.metres_per_unit)
    out << 1000 * *s.metres_per_unit * s.xyz_rounding_error() << " mm)";
  else
    out << s.xyz_rounding_error() << " units)";
  if (s.point_uncertainty) out << ", point uncertainty";
  return out.str();
}

}  // namespace

std::string MapInfo::summary(const std::string& map_name) const {
  std::ostringstream out;
  out << "map " << map_name << ": " << segments.size() << " segment(s), " << total_points << " points\n"
      << std::setw(8) << "segment" << std::setw(10) << "points" << std::setw(8) << "images" << std::setw(12)
      << "file bytes" << std::setw(14) << "B/pt (points)" << std::setw(12) << "B/pt (file)"
      << "  xyz (worst rounding error)\n";
  for (const auto& s : segments)
    out << std::setw(8) << s.id << std::setw(10) << s.points << std::setw(8) << s.images << std::setw(12)
        << s.bytes.file << std::fixed << std::setprecision(1) << std::setw(14)
        << s.bytes.per_point_bytes_per_point(s.points) << std::setw(12) << s.bytes.file_bytes_per_point(s.points)
        << "  " << xyz_summary(s) << "\n";
  const double n = total_points ? double(total_points) : 1.0;
  out << std::fixed << std::setprecision(1) << "total: " << double(total_per_point_bytes) / n
      << " bytes/point in per-point sections (xyz 12, or 6 quantized, + hash 16 + PQ " << pq_code_bytes << ")"
      << (std::any_of(segments.begin(), segments.end(), [](const MapSegmentInfo& s) { return s.point_uncertainty; })
              ? " (+ 4 for the points' uncertainty where stored)"
              : "")
      << "; " << double(total_bytes) / n << " bytes/point in all files: segments (images, metadata"
      << (hash_rotation_bytes ? "" : ", a hash rotation each") << "), the shared PQ codebook ("
      << to_string(pq_quantizer);
  if (pq_residual_splits) out << " over " << pq_residual_splits << " part(s), beam " << pq_residual_beam;
  out << ", " << codebook_bytes << " bytes)"
      << (hash_rotation_bytes ? " and the shared hash rotation (" + std::to_string(hash_rotation_bytes) + " bytes)"
                              : std::string())
      << "\n";
  if (manifest.hash_blend) {
    out << std::setprecision(2) << "hash blend: weight " << manifest.hash_blend->weight;
    if (manifest.fitted_hash_blend())
      out << " (fitted on these segments; the search's default)\n";
    else
      out << " (fitted on other segments than the map's now: not used; run 'visloc map fit-blend --store')\n";
  }
  return out.str();
}

}  // namespace visloc
