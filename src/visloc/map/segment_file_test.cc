// Segment files' point coordinates: float32 (version 2) and quantized uint16
// (version 3), the writer's choice between them, and the reader's checks of
// the quantization parameters.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>

#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/random.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path temp_dir(const std::string& name) { return unique_temp_dir("visloc_segment_file_" + name); }

// n points uniform in [0, extent)³ + offset; enu_from_segment with `scale`
// (none when scale is 0).
SegmentData segment(size_t n, double extent, double scale, double offset = 0) {
  RandomGenerator rng(11);
  SegmentData s;
  s.segment_id = 4;
  for (size_t i = 0; i < 3 * n; ++i) s.xyz.push_back(static_cast<float>(offset + rng.uniform(0, extent)));
  for (size_t i = 0; i < n; ++i) s.codes.push_back({{rng.next(), rng.next()}});
  for (size_t i = 0; i < n * 16; ++i) s.pq_codes.push_back(static_cast<uint8_t>(rng.next()));
  s.hasher.mean.assign(128, 3.0f);
  s.hasher.projection.assign(128 * 128, 0.0f);
  for (int i = 0; i < 128; ++i) s.hasher.projection[i * 128 + i] = 1.0f;
  s.images.push_back({"a.jpg", 1, 640, 480, {500, 500, 320, 240}, {1, 0, 0, 0}, {0, 0, 1}});
  if (scale > 0)
    s.extra_meta["enu_from_segment"] = {
        {"scale", scale}, {"rotation_row_major", {1, 0, 0, 0, 1, 0, 0, 0, 1}}, {"translation", {1, 2, 3}}};
  return s;
}

SegmentWriteOptions coordinates(PointCoordinates c, double max_error_m = 0.002) {
  SegmentWriteOptions o;
  o.coordinates = c;
  o.max_quantization_error_m = max_error_m;
  return o;
}

uint32_t written_version(const SegmentData& s, const SegmentWriteOptions& o, const fs::path& dir) {
  write_segment_file(dir / "v.vlseg", s, o);
  return Segment::open(dir / "v.vlseg")->format_version();
}

// Copies segment file `in` to `out` with kind version `version`, after
// `edit` changed META and the sections (by tag, in file order).
using Sections = std::vector<std::pair<std::string, std::vector<uint8_t>>>;
void rewrite(const fs::path& in, const fs::path& out, uint32_t version,
             const std::function<void(nlohmann::json&, Sections&)>& edit) {
  Sections sections;
  nlohmann::json meta;
  {
    SectionFileReader r(in, "SEGM", 1, kSegmentFileVersion);
    for (const SectionEntry& e : r.sections()) {
      const std::string tag(e.tag, strnlen(e.tag, sizeof(e.tag)));
      const auto b = r.bytes(tag);
      if (tag == "META")
        meta = nlohmann::json::parse(std::string(b.begin(), b.end()));
      else
        sections.emplace_back(tag, std::vector<uint8_t>(b.begin(), b.end()));
    }
  }
  edit(meta, sections);
  SectionFileWriter w(out, "SEGM", version);
  w.add_text("META", meta.dump());
  for (const auto& [tag, bytes] : sections) w.add(tag, bytes.data(), bytes.size());
  w.commit();
}

// The Error(kFormat) message of opening `path`, "" when it opens.
std::string open_error(const fs::path& path) {
  try {
    Segment::open(path);
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kFormat) << e.what();
    return e.what();
  }
  return "";
}

bool mentions(const std::string& message, const std::string& part) { return message.find(part) != std::string::npos; }

}  // namespace

TEST(SegmentCoordinates, Float32IsVersion2AndExact) {
  const auto dir = temp_dir("float32");
  const SegmentData s = segment(500, 50, 1.0);
  write_segment_file(dir / "f.vlseg", s, coordinates(PointCoordinates::kFloat32));
  auto seg = Segment::open(dir / "f.vlseg");
  EXPECT_EQ(seg->format_version(), 2u);
  EXPECT_FALSE(seg->xyz_quantization().has_value());
  ASSERT_EQ(seg->xyz().size(), s.xyz.size());
  for (size_t i = 0; i < s.xyz.size(); ++i) ASSERT_EQ(seg->xyz()[i], s.xyz[i]) << i;
  EXPECT_EQ(seg->bytes().per_point, 44u * 500);
  EXPECT_EQ(seg->bytes().xyz_memory, 0u);
}

TEST(SegmentCoordinates, Int16IsVersion3WithinHalfAStep) {
  const auto dir = temp_dir("int16");
  const size_t n = 2000;
  const SegmentData s = segment(n, 37.5, 0, -12.25);  // no scale: int16 is forced
  write_segment_file(dir / "q.vlseg", s, coordinates(PointCoordinates::kInt16));
  auto seg = Segment::open(dir / "q.vlseg");
  EXPECT_EQ(seg->format_version(), 3u);
  ASSERT_TRUE(seg->xyz_quantization().has_value());
  const XyzQuantization& q = *seg->xyz_quantization();
  ASSERT_EQ(seg->xyz().size(), s.xyz.size());
  std::array<double, 3> worst{0, 0, 0};
  for (size_t i = 0; i < s.xyz.size(); ++i) {
    const double err = std::abs(double(seg->xyz()[i]) - double(s.xyz[i]));
    // step / 2, plus half a float ulp from decoding into float.
    const double ulp = std::nextafter(std::abs(s.xyz[i]), INFINITY) - std::abs(s.xyz[i]);
    ASSERT_LE(err, q.step[i % 3] / 2 + ulp / 2) << i;
    worst[i % 3] = std::max(worst[i % 3], err);
  }
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(q.step[a], 37.5 / 65535, 37.5 / 65535 * 0.01) << a;  // the points' box, 65,535 steps
    EXPECT_GT(worst[a], q.step[a] / 4) << a;                         // the data are really rounded
  }
  EXPECT_DOUBLE_EQ(q.max_rounding_error(), 0.5 * std::max({q.step[0], q.step[1], q.step[2]}));
  EXPECT_EQ(seg->bytes().per_point, 38u * n);
  EXPECT_EQ(seg->bytes().xyz_memory, 12u * n);
  // The codes are untouched.
  for (size_t i = 0; i < n; ++i) ASSERT_EQ(hamming_distance(seg->index().codes[i], s.codes[i]), 0u) << i;
}

TEST(SegmentCoordinates, AFlatAxisDecodesExactly) {
  const auto dir = temp_dir("flat");
  SegmentData s = segment(100, 10, 1.0);
  for (size_t i = 2; i < s.xyz.size(); i += 3) s.xyz[i] = 1.75f;
  write_segment_file(dir / "q.vlseg", s, coordinates(PointCoordinates::kInt16));
  auto seg = Segment::open(dir / "q.vlseg");
  for (size_t i = 2; i < s.xyz.size(); i += 3) ASSERT_EQ(seg->xyz()[i], 1.75f);
}

TEST(SegmentCoordinates, AutoQuantizesWithinTheBoundInMetres) {
  const auto dir = temp_dir("auto");
  const SegmentWriteOptions automatic;  // the default
  EXPECT_EQ(automatic.coordinates, PointCoordinates::kAuto);
  // A 200-unit box: worst rounding error 200 / 65535 / 2 = 1.53 units × 10⁻³.
  EXPECT_EQ(written_version(segment(300, 200, 1.0), automatic, dir), 3u);  // 1.53 mm
  EXPECT_EQ(written_version(segment(300, 200, 1.5), automatic, dir), 2u);  // 2.29 mm: float32
  EXPECT_EQ(written_version(segment(300, 200, 0.5), automatic, dir), 3u);  // 0.76 mm
  EXPECT_EQ(written_version(segment(300, 300, 1.0), automatic, dir), 2u);  // 2.29 mm: float32
  EXPECT_EQ(written_version(segment(300, 10, 0), automatic, dir), 2u);     // no metric scale: float32
  EXPECT_EQ(written_version(segment(300, 200, 1.0), coordinates(PointCoordinates::kAuto, 0.001), dir), 2u);
  EXPECT_EQ(written_version(segment(300, 200, 1.5), coordinates(PointCoordinates::kInt16), dir), 3u);
  EXPECT_EQ(written_version(segment(300, 10, 1.0), coordinates(PointCoordinates::kFloat32), dir), 2u);
  // An unusable scale (the reader rejects it) leaves the choice to float32.
  SegmentData s = segment(300, 10, 1.0);
  s.extra_meta["enu_from_segment"]["scale"] = "1";
  EXPECT_FALSE(choose_xyz_quantization(s, automatic).has_value());
}

TEST(SegmentCoordinates, NonFiniteCoordinatesAndBadOptions) {
  const auto dir = temp_dir("nonfinite");
  SegmentData s = segment(100, 10, 1.0);
  s.xyz[5] = std::nanf("");
  // auto keeps float32, whose reader names the bad point; int16 refuses to write.
  write_segment_file(dir / "n.vlseg", s);
  EXPECT_TRUE(mentions(open_error(dir / "n.vlseg"), "point 1 has a non-finite coordinate"));
  try {
    write_segment_file(dir / "n.vlseg", s, coordinates(PointCoordinates::kInt16));
    ADD_FAILURE() << "int16 accepted a NaN coordinate";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
    EXPECT_TRUE(mentions(e.what(), "finite")) << e.what();
  }
  for (double bad : {0.0, -0.002, double(NAN), double(INFINITY)}) {
    try {
      coordinates(PointCoordinates::kAuto, bad).validate();
      ADD_FAILURE() << bad << " accepted";
    } catch (const Error& e) {
      EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
      EXPECT_TRUE(mentions(e.what(), "max_quantization_error_m")) << e.what();
    }
  }
}

TEST(SegmentCoordinates, RejectsBadQuantizationParameters) {
  const auto dir = temp_dir("corrupt");
  const fs::path good = dir / "good.vlseg", bad = dir / "bad.vlseg";
  write_segment_file(good, segment(100, 10, 1.0), coordinates(PointCoordinates::kInt16));
  ASSERT_EQ(open_error(good), "");
  const auto with_meta = [&](const std::function<void(nlohmann::json&)>& edit) {
    rewrite(good, bad, 3, [&](nlohmann::json& meta, Sections&) { edit(meta); });
    return open_error(bad);
  };
  std::string e = with_meta([](nlohmann::json& m) { m["xyz_quantization"]["step"][1] = 0.0; });
  EXPECT_TRUE(mentions(e, "bad.vlseg") && mentions(e, "axis 1") && mentions(e, "step > 0")) << e;
  e = with_meta([](nlohmann::json& m) { m["xyz_quantization"]["step"][0] = -1e-4; });
  EXPECT_TRUE(mentions(e, "axis 0") && mentions(e, "step > 0")) << e;
  e = with_meta([](nlohmann::json& m) { m["xyz_quantization"]["step"][2] = double(NAN); });  // JSON null
  EXPECT_TRUE(mentions(e, "xyz_quantization.step") && mentions(e, "must be a number")) << e;
  e = with_meta([](nlohmann::json& m) { m["xyz_quantization"]["step"] = {1e-4, 1e-4}; });
  EXPECT_TRUE(mentions(e, "xyz_quantization.step")) << e;
  e = with_meta([](nlohmann::json& m) { m["xyz_quantization"]["origin"][0] = 1e39; });
  EXPECT_TRUE(mentions(e, "outside float32's range")) << e;
  e = with_meta([](nlohmann::json& m) { m["xyz_quantization"]["step"][0] = 1e35; });  // 65535 steps overflow
  EXPECT_TRUE(mentions(e, "outside float32's range")) << e;
  e = with_meta([](nlohmann::json& m) { m["xyz_quantization"] = "int16"; });
  EXPECT_TRUE(mentions(e, "xyz_quantization")) << e;
  e = with_meta([](nlohmann::json& m) { m.erase("xyz_quantization"); });
  EXPECT_TRUE(mentions(e, "lacks xyz_quantization in a version 3")) << e;
  e = with_meta([](nlohmann::json& m) { m["points"] = 99; });  // XYZ16 holds 100 points
  EXPECT_TRUE(mentions(e, "section 'XYZ16' has 600 bytes, expected 297 elements")) << e;
  // Sections: XYZ16 cut short, XYZ16 replaced by XYZ, both present.
  rewrite(good, bad, 3, [](nlohmann::json&, Sections& s) { s[0].second.resize(s[0].second.size() - 2); });
  e = open_error(bad);
  EXPECT_TRUE(mentions(e, "section 'XYZ16'") && mentions(e, "expected 300 elements")) << e;
  rewrite(good, bad, 3, [](nlohmann::json&, Sections& s) { s[0].first = "XYZ"; });
  EXPECT_TRUE(mentions(open_error(bad), "has no section 'XYZ' (its coordinates are in 'XYZ16')")) << open_error(bad);
  rewrite(good, bad, 3, [](nlohmann::json&, Sections& s) { s.push_back({"XYZ", std::vector<uint8_t>(1200)}); });
  EXPECT_TRUE(mentions(open_error(bad), "has no section 'XYZ'")) << open_error(bad);
  // A version 2 file never carries quantization parameters or XYZ16.
  rewrite(good, bad, 2, [](nlohmann::json&, Sections&) {});
  EXPECT_TRUE(mentions(open_error(bad), "has xyz_quantization in a version 2")) << open_error(bad);
}

TEST(SegmentCoordinates, Version2FilesReadAsBefore) {
  const auto dir = temp_dir("v2");
  const SegmentData s = segment(300, 20, 1.0);
  const fs::path v2 = dir / "v2.vlseg", q = dir / "q.vlseg";
  write_segment_file(v2, s, coordinates(PointCoordinates::kFloat32));
  write_segment_file(q, s, coordinates(PointCoordinates::kInt16));
  const auto a = Segment::open(v2), b = Segment::open(q);
  EXPECT_EQ(a->format_version(), 2u);
  EXPECT_EQ(b->format_version(), 3u);
  EXPECT_EQ(a->bytes().per_point - b->bytes().per_point, 6u * 300);
  EXPECT_LT(b->bytes().file, a->bytes().file);
  EXPECT_EQ(a->meta().contains("xyz_quantization"), false);
  // The same points and codes either way, to within the rounding.
  for (size_t i = 0; i < s.xyz.size(); ++i) ASSERT_NEAR(a->xyz()[i], b->xyz()[i], 20.0 / 65535) << i;
  // A version-2 file with quantized coordinates' section is refused.
  rewrite(v2, dir / "bad.vlseg", 2, [](nlohmann::json&, Sections& sec) { sec.push_back({"XYZ16", {0, 0}}); });
  EXPECT_TRUE(mentions(open_error(dir / "bad.vlseg"), "has no section 'XYZ16'")) << open_error(dir / "bad.vlseg");
}

TEST(SegmentCoordinates, MapInfoReportsQuantization) {
  MapInfo info;
  MapSegmentInfo quantized;
  quantized.points = 10;
  quantized.xyz_quantization = XyzQuantization{{0, 0, 0}, {0.001, 0.002, 0.0005}};
  quantized.metres_per_unit = 0.5;
  MapSegmentInfo unscaled = quantized;
  unscaled.metres_per_unit.reset();
  MapSegmentInfo plain;
  plain.points = 10;
  info.segments = {quantized, unscaled, plain};
  const nlohmann::json j = info.to_json();
  EXPECT_EQ(j["segments"][0]["xyz_coordinates"], "int16");
  EXPECT_DOUBLE_EQ(j["segments"][0]["xyz_rounding_error"].get<double>(), 0.001);
  EXPECT_DOUBLE_EQ(j["segments"][0]["xyz_rounding_error_m"].get<double>(), 0.0005);
  EXPECT_TRUE(j["segments"][1]["xyz_rounding_error_m"].is_null());
  EXPECT_EQ(j["segments"][2]["xyz_coordinates"], "float32");
  EXPECT_EQ(j["segments"][2]["xyz_rounding_error"].get<double>(), 0.0);
  EXPECT_TRUE(mentions(info.summary("m"), "int16 (0.5 mm)")) << info.summary("m");
}

// 32-byte PQ codes: version 4 whatever the coordinates (16-byte segments keep
// versions 2 and 3), META's pq.subvectors, the codes read back byte for byte,
// and 16 more bytes per point.
TEST(SegmentPqCodes, ThirtyTwoByteCodesAreVersion4) {
  const auto dir = temp_dir("pq32");
  const size_t n = 700;
  SegmentData s = segment(n, 20, 1.0);
  RandomGenerator rng(5);
  s.pq_subvectors = 32;
  s.pq_codes.clear();
  for (size_t i = 0; i < n * 32; ++i) s.pq_codes.push_back(static_cast<uint8_t>(rng.next()));
  for (const auto& [coordinates, bytes_per_point] :
       {std::pair{PointCoordinates::kFloat32, 60u}, std::pair{PointCoordinates::kInt16, 54u}}) {
    write_segment_file(dir / "p.vlseg", s, SegmentWriteOptions{.coordinates = coordinates});
    auto seg = Segment::open(dir / "p.vlseg");
    EXPECT_EQ(seg->format_version(), 4u);
    EXPECT_EQ(seg->index().pq_subvectors, 32);
    EXPECT_EQ(seg->meta().at("pq").at("subvectors"), 32);
    EXPECT_EQ(seg->xyz_quantization().has_value(), coordinates == PointCoordinates::kInt16);
    EXPECT_EQ(0, std::memcmp(seg->index().pq_codes, s.pq_codes.data(), s.pq_codes.size()));
    EXPECT_EQ(seg->bytes().per_point, bytes_per_point * n);
  }
  // The 16-byte segment of the same points: versions 2 and 3, 16 bytes per code.
  const SegmentData s16 = segment(n, 20, 1.0);
  EXPECT_EQ(written_version(s16, coordinates(PointCoordinates::kFloat32), dir), 2u);
  EXPECT_EQ(written_version(s16, coordinates(PointCoordinates::kInt16), dir), 3u);
  EXPECT_EQ(Segment::open(dir / "v.vlseg")->index().pq_subvectors, 16);
  // The writer refuses other code sizes.
  SegmentData bad = s;
  bad.pq_subvectors = 24;
  EXPECT_THROW(write_segment_file(dir / "bad.vlseg", bad), Error);
}

TEST(SegmentPqCodes, RejectsCodeSizesThatDisagree) {
  const auto dir = temp_dir("pq32_bad");
  const size_t n = 300;
  SegmentData s = segment(n, 20, 1.0);
  s.pq_subvectors = 32;
  s.pq_codes.assign(n * 32, 7);
  write_segment_file(dir / "ok.vlseg", s, coordinates(PointCoordinates::kFloat32));
  ASSERT_EQ(open_error(dir / "ok.vlseg"), "");
  // META says 24, or nothing, in a version 4 file.
  rewrite(dir / "ok.vlseg", dir / "m24.vlseg", 4,
          [](nlohmann::json& meta, Sections&) { meta["pq"]["subvectors"] = 24; });
  EXPECT_TRUE(mentions(open_error(dir / "m24.vlseg"), "16 or 32")) << open_error(dir / "m24.vlseg");
  rewrite(dir / "ok.vlseg", dir / "none.vlseg", 4, [](nlohmann::json& meta, Sections&) { meta.erase("pq"); });
  EXPECT_TRUE(mentions(open_error(dir / "none.vlseg"), "pq")) << open_error(dir / "none.vlseg");
  // META says 16 over 32-byte codes; a version 3 reader's view of 32-byte codes.
  rewrite(dir / "ok.vlseg", dir / "m16.vlseg", 4,
          [](nlohmann::json& meta, Sections&) { meta["pq"]["subvectors"] = 16; });
  EXPECT_TRUE(mentions(open_error(dir / "m16.vlseg"), "'PQ'")) << open_error(dir / "m16.vlseg");
  rewrite(dir / "ok.vlseg", dir / "v2.vlseg", 2, [](nlohmann::json&, Sections&) {});
  EXPECT_TRUE(mentions(open_error(dir / "v2.vlseg"), "'PQ'")) << open_error(dir / "v2.vlseg");
  // A map whose codebook makes 16-byte codes refuses a 32-byte segment.
  fs::create_directories(dir / "map" / "segments");
  write_segment_file(dir / "map" / "segments" / "0004.vlseg", s, coordinates(PointCoordinates::kFloat32));
  std::vector<float> c(kPqCentroidFloats);
  for (size_t i = 0; i < c.size(); ++i) c[i] = float(i % 97);
  PqCodebook(c).write(dir / "map" / "pq_codebook.vlpq", "{}");
  MapManifest man;
  MapSegmentEntry entry;
  entry.id = 4;
  entry.file = "segments/0004.vlseg";
  entry.points = n;
  entry.images = 1;
  entry.file_bytes = fs::file_size(dir / "map" / "segments" / "0004.vlseg");
  man.segments.push_back(entry);
  write_file_atomic(dir / "map" / "manifest.json", man.to_json().dump());
  try {
    Map::open(dir / "map").open_segment(0);
    ADD_FAILURE() << "a 32-byte segment opened in a 16-byte map";
  } catch (const Error& e) {
    EXPECT_TRUE(mentions(e.what(), "0004.vlseg") && mentions(e.what(), "32 bytes") && mentions(e.what(), "16-byte"))
        << e.what();
  }
  PqCodebook(c, 32).write(dir / "map" / "pq_codebook.vlpq", "{}");
  EXPECT_EQ(Map::open(dir / "map").open_segment(0)->index().pq_subvectors, 32);
  const MapInfo info = map_info(dir / "map");
  EXPECT_EQ(info.pq_code_bytes, 32);
  EXPECT_EQ(info.to_json().at("total").at("pq_code_bytes"), 32);
  EXPECT_TRUE(mentions(info.summary("map"), "+ PQ 32)")) << info.summary("map");
}

TEST(SegmentPointUncertainty, WrittenReadAndDroppedOnRequest) {
  const auto dir = temp_dir("ptunc");
  const size_t n = 500;
  SegmentData s = segment(n, 20, 1.0);
  RandomGenerator rng(3);
  for (size_t i = 0; i < n; ++i)
    s.point_uncertainty.push_back({uint8_t(rng.next()), uint8_t(rng.next()), uint8_t(rng.next()), uint8_t(rng.next())});
  s.keypoint_noise_px = 0.61;
  for (const auto& [point_coordinates, version] :
       {std::pair{PointCoordinates::kFloat32, 2u}, std::pair{PointCoordinates::kInt16, 3u}}) {
    write_segment_file(dir / "u.vlseg", s,
                       SegmentWriteOptions{.coordinates = point_coordinates, .point_uncertainty = true});
    auto seg = Segment::open(dir / "u.vlseg");
    EXPECT_EQ(seg->format_version(), version);  // readers before it ignore the section
    ASSERT_EQ(seg->point_uncertainty().size(), n);
    EXPECT_EQ(0, std::memcmp(seg->point_uncertainty().data(), s.point_uncertainty.data(), 4 * n));
    EXPECT_DOUBLE_EQ(seg->meta().at("point_uncertainty").at("keypoint_noise_px").get<double>(), 0.61);
    EXPECT_EQ(seg->bytes().per_point, (point_coordinates == PointCoordinates::kInt16 ? 42u : 48u) * n);
  }
  // Not written unless the options say so (opt-in), nor when the segment has none.
  write_segment_file(dir / "off.vlseg", s, coordinates(PointCoordinates::kFloat32));
  EXPECT_TRUE(Segment::open(dir / "off.vlseg")->point_uncertainty().empty());
  EXPECT_FALSE(Segment::open(dir / "off.vlseg")->meta().contains("point_uncertainty"));
  EXPECT_EQ(Segment::open(dir / "off.vlseg")->bytes().per_point, 44u * n);
  SegmentData none = segment(n, 20, 1.0);
  SegmentWriteOptions with = coordinates(PointCoordinates::kFloat32);
  with.point_uncertainty = true;
  write_segment_file(dir / "none.vlseg", none, with);
  EXPECT_TRUE(Segment::open(dir / "none.vlseg")->point_uncertainty().empty());
  // One code per point, or the writer refuses; a section of another size is rejected by name.
  SegmentData short_list = s;
  short_list.point_uncertainty.pop_back();
  EXPECT_THROW(write_segment_file(dir / "short.vlseg", short_list, with), Error);
  write_segment_file(dir / "ok.vlseg", s, with);
  rewrite(dir / "ok.vlseg", dir / "cut.vlseg", 2, [](nlohmann::json&, Sections& sections) {
    for (auto& [tag, bytes] : sections)
      if (tag == "PTUNC") bytes.resize(bytes.size() - 4);
  });
  const std::string message = open_error(dir / "cut.vlseg");
  EXPECT_TRUE(mentions(message, "'PTUNC'") && mentions(message, "cut.vlseg")) << message;
}
