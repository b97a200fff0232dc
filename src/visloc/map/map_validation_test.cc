// Content that is well formed (checksums right) but means nothing valid must
// be rejected at load with Error(kFormat) naming the file and the field: the
// cases of the robustness issue, one test each.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <random>

#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path temp_dir(const std::string& name) { return unique_temp_dir("visloc_map_validation_" + name); }

SegmentData valid_segment(size_t n = 200) {
  std::mt19937_64 rng(3);
  SegmentData s;
  s.segment_id = 0;
  for (size_t i = 0; i < 3 * n; ++i) s.xyz.push_back(float(rng() % 1000) * 0.01f);
  s.hasher.mean.assign(128, 3.0f);
  s.hasher.projection.assign(128 * 128, 0.0f);
  for (int i = 0; i < 128; ++i) s.hasher.projection[i * 128 + i] = 1.0f;
  for (size_t i = 0; i < n; ++i) s.codes.push_back({{rng(), rng()}});
  for (size_t i = 0; i < n * 16; ++i) s.pq_codes.push_back(static_cast<uint8_t>(rng()));
  s.images.push_back({"a.jpg", 1, 640, 480, {500, 500, 320, 240}, {1, 0, 0, 0}, {0, 0, 1}});
  s.extra_meta["enu_from_segment"] = {
      {"scale", 2.0}, {"rotation_row_major", {0, -1, 0, 1, 0, 0, 0, 0, 1}}, {"translation", {1, 2, 3}}};
  return s;
}

// The Error(kFormat) message of f, or "" when it does not throw one.
std::string format_error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kFormat) << e.what();
    return e.what();
  }
  return "";
}

std::string segment_error(const SegmentData& s, const fs::path& dir) {
  const fs::path p = dir / "s.vlseg";
  write_segment_file(p, s);
  return format_error_of([&] { Segment::open(p); });
}

bool mentions(const std::string& message, const std::string& part) {
  return message.find(part) != std::string::npos;
}

}  // namespace

TEST(SegmentValidation, AcceptsAValidSegmentAndParsesItsFrame) {
  const auto dir = temp_dir("valid");
  write_segment_file(dir / "s.vlseg", valid_segment());
  auto seg = Segment::open(dir / "s.vlseg");
  ASSERT_TRUE(seg->enu_from_segment().has_value());
  EXPECT_DOUBLE_EQ(seg->enu_from_segment()->scale, 2.0);
  EXPECT_DOUBLE_EQ(seg->enu_from_segment()->translation.z(), 3.0);
}

TEST(SegmentValidation, RejectsNonFiniteArraysAndRotations) {
  const auto dir = temp_dir("finite");
  SegmentData s = valid_segment();
  s.xyz[7] = std::nanf("");
  EXPECT_TRUE(mentions(segment_error(s, dir), "non-finite")) << segment_error(s, dir);
  s = valid_segment();
  for (float& x : s.hasher.projection) x = std::nanf("");
  EXPECT_TRUE(mentions(segment_error(s, dir), "hash rotation is not finite"));
  s = valid_segment();
  s.hasher.projection[3] = 0.5f;  // no longer orthonormal
  EXPECT_TRUE(mentions(segment_error(s, dir), "orthonormal"));
  s = valid_segment();
  s.hasher.mean[0] = INFINITY;
  EXPECT_TRUE(mentions(segment_error(s, dir), "mean is not finite"));
}

TEST(SegmentValidation, RejectsBadEnuFromSegment) {
  const auto dir = temp_dir("enu");
  for (double scale : {0.0, -1.0}) {
    SegmentData s = valid_segment();
    s.extra_meta["enu_from_segment"]["scale"] = scale;
    const std::string e = segment_error(s, dir);
    EXPECT_TRUE(mentions(e, "enu_from_segment.scale") && mentions(e, "s.vlseg")) << e;
  }
  SegmentData s = valid_segment();
  s.extra_meta["enu_from_segment"]["rotation_row_major"] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  EXPECT_TRUE(mentions(segment_error(s, dir), "enu_from_segment.rotation_row_major"));
  s.extra_meta["enu_from_segment"]["rotation_row_major"] = {-1, 0, 0, 0, 1, 0, 0, 0, 1};  // a reflection
  EXPECT_TRUE(mentions(segment_error(s, dir), "determinant"));
  s = valid_segment();
  s.extra_meta["enu_from_segment"]["scale"] = "1";
  const std::string e = segment_error(s, dir);
  EXPECT_TRUE(mentions(e, "field 'enu_from_segment.scale' must be a number, found string")) << e;
  s = valid_segment();
  s.extra_meta["enu_from_segment"]["translation"] = {0, 1};
  EXPECT_TRUE(mentions(segment_error(s, dir), "enu_from_segment.translation"));
}

TEST(SegmentValidation, RejectsBadMetaAndImages) {
  const auto dir = temp_dir("meta");
  SegmentData s = valid_segment();
  s.extra_meta["hash_rotation_crc32c"] = -5;
  EXPECT_TRUE(mentions(segment_error(s, dir), "hash_rotation_crc32c"));
  s = valid_segment();
  s.images[0].width = 0;
  EXPECT_TRUE(mentions(segment_error(s, dir), "image size"));
  s = valid_segment();
  s.images[0].camera_params = {500, 500, 320, NAN};
  EXPECT_FALSE(segment_error(s, dir).empty());
  s = valid_segment();
  s.images[0].camera_params = {-1000, 500, 320, 240};
  EXPECT_TRUE(mentions(segment_error(s, dir), "focal"));
  s = valid_segment();
  s.images[0].camera_params = {500, 500, 3200, 240};
  EXPECT_TRUE(mentions(segment_error(s, dir), "principal point"));
  s = valid_segment();
  s.images[0].cam_from_world_q_wxyz = {0, 0, 0, 0};
  EXPECT_TRUE(mentions(segment_error(s, dir), "unit quaternion"));
}

TEST(CodebookValidation, RejectsNaNAndDegenerateCentroids) {
  const auto dir = temp_dir("codebook");
  std::vector<float> c(size_t(kPqTableSize) * kPqSubDim);
  for (size_t i = 0; i < c.size(); ++i) c[i] = float(i % 97);
  PqCodebook(c).write(dir / "ok.vlpq", "{}");
  EXPECT_NO_THROW(PqCodebook::read(dir / "ok.vlpq"));
  std::vector<float> nan = c;
  nan[1000] = std::nanf("");
  PqCodebook(nan).write(dir / "nan.vlpq", "{}");
  EXPECT_TRUE(mentions(format_error_of([&] { PqCodebook::read(dir / "nan.vlpq"); }), "not finite"));
  PqCodebook(std::vector<float>(c.size(), 0.0f)).write(dir / "zero.vlpq", "{}");
  const std::string e = format_error_of([&] { PqCodebook::read(dir / "zero.vlpq"); });
  EXPECT_TRUE(mentions(e, "zero.vlpq") && mentions(e, "all equal")) << e;
}

TEST(ManifestValidation, RejectsWrongTypesAndRanges) {
  const auto dir = temp_dir("manifest");
  const nlohmann::json good = MapManifest{}.to_json();
  auto error_with = [&](const std::function<void(nlohmann::json&)>& edit) {
    nlohmann::json j = good;
    edit(j);
    write_file_atomic(dir / "manifest.json", j.dump());
    return format_error_of([&] { read_manifest(dir); });
  };
  EXPECT_EQ(error_with([](nlohmann::json&) {}), "");
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["format_version"] = 1.5; }), "format_version"));
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["format_version"] = 1e300; }), "format_version"));
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["segments"] = nullptr; }), "'segments' is null"));
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["segments"] = 3; }), "segments"));
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["pq_codebook_file"] = "../x.vlpq"; }), "inside the map"));
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["enu_origin"] = {{"lat", 91}, {"lon", 0}, {"alt", 0}}; }),
                       "enu_origin.lat"));
  const std::string seg_error = error_with([](auto& j) {
    j["segments"] = {{{"id", 0}, {"file", "a"}, {"points", "10"}, {"images", 1}, {"file_bytes", 1}, {"file_crc32c", 0}}};
  });
  EXPECT_TRUE(mentions(seg_error, "segments[0].points")) << seg_error;
  EXPECT_TRUE(mentions(error_with([](auto& j) {
                         j["segments"] = {{{"id", 0}, {"file", "a"}, {"points", 1}, {"images", 1}, {"file_bytes", 1}, {"file_crc32c", 0}},
                                          {{"id", 0}, {"file", "b"}, {"points", 1}, {"images", 1}, {"file_bytes", 1}, {"file_crc32c", 0}}};
                       }),
                       "repeats segment id"));
  // The stored hash-blend weight: in [0, 1], with its segments' checksums.
  EXPECT_TRUE(mentions(error_with([](auto& j) {
                         j["hash_blend"] = {{"weight", 1.5}, {"segment_crc32c", {}}};
                       }),
                       "hash_blend.weight"));
  EXPECT_TRUE(mentions(error_with([](auto& j) {
                         j["hash_blend"] = {{"weight", "a"}, {"segment_crc32c", {}}};
                       }),
                       "hash_blend.weight"));
  EXPECT_TRUE(mentions(error_with([](auto& j) {
                         j["hash_blend"] = {{"weight", 0.5}, {"segment_crc32c", {-1}}};
                       }),
                       "hash_blend.segment_crc32c[0]"));
  EXPECT_TRUE(mentions(error_with([](auto& j) { j["hash_blend"] = {{"weight", 0.5}}; }), "segment_crc32c"));
  EXPECT_EQ(error_with([](auto& j) { j["hash_blend"] = nullptr; }), "");
}

// The stored weight counts only for the segments it was fitted on.
TEST(ManifestHashBlend, RoundTripsAndCountsOnlyForItsSegments) {
  MapManifest m;
  m.segments = {{3, "segments/0003.vlseg", "", 10, 2, 100, 0xdeadbeefu},
                {4, "segments/0004.vlseg", "", 10, 2, 100, 7u}};
  EXPECT_FALSE(m.fitted_hash_blend().has_value());
  m.hash_blend = MapHashBlend{0.35, {0xdeadbeefu, 7u}, {{"views", 12}}};
  const MapManifest back = MapManifest::from_json(m.to_json(), "m");
  ASSERT_TRUE(back.hash_blend.has_value());
  EXPECT_EQ(back.hash_blend->segment_crc32c, m.hash_blend->segment_crc32c);
  EXPECT_EQ(back.hash_blend->fit["views"], 12);
  ASSERT_TRUE(back.fitted_hash_blend().has_value());
  EXPECT_EQ(*back.fitted_hash_blend(), 0.35);
  MapManifest changed = back;
  changed.segments[1].file_crc32c = 8u;  // a rebuilt segment
  EXPECT_FALSE(changed.fitted_hash_blend().has_value());
  changed = back;
  changed.segments.pop_back();  // a segment fewer
  EXPECT_FALSE(changed.fitted_hash_blend().has_value());
  changed = back;
  std::swap(changed.segments[0], changed.segments[1]);  // the same files in another order
  EXPECT_FALSE(changed.fitted_hash_blend().has_value());
  EXPECT_FALSE(MapManifest::from_json(MapManifest{}.to_json(), "m").hash_blend.has_value());
}

TEST(ReaderValidation, OnlyRegularFilesAreOpened) {
  const auto dir = temp_dir("fifo");
  ASSERT_EQ(::mkfifo((dir / "s.vlseg").c_str(), 0644), 0);
  ASSERT_EQ(::mkfifo((dir / "manifest.json").c_str(), 0644), 0);
  // Opening a FIFO for reading would wait forever for a writer: both fail at once.
  try {
    Segment::open(dir / "s.vlseg");
    ADD_FAILURE() << "a FIFO was opened as a segment";
  } catch (const Error& e) {
    EXPECT_TRUE(mentions(e.what(), "not a regular file")) << e.what();
  }
  try {
    read_manifest(dir);
    ADD_FAILURE() << "a FIFO was read as a manifest";
  } catch (const Error& e) {
    EXPECT_TRUE(mentions(e.what(), "FIFO")) << e.what();
  }
}
