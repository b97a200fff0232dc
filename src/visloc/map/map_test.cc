#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/map/colmap_import.h"
#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/faiss_baselines.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

// FAISS k-means on one thread: OpenMP threads spinning on a loaded machine are slower.
const int kOneThread = (set_faiss_threads(1), 1);

fs::path temp_dir(const std::string& name) {
  fs::path p = fs::temp_directory_path() / ("visloc_map_test_" + name);
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

SegmentData random_segment(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  SegmentData s;
  s.segment_id = 7;
  for (size_t i = 0; i < 3 * n; ++i) s.xyz.push_back(float(rng() % 1000) * 0.01f);
  s.hasher.mean.assign(128, 3.0f);
  s.hasher.projection.assign(128 * 128, 0.0f);
  for (int i = 0; i < 128; ++i) s.hasher.projection[i * 128 + i] = 1.0f;
  for (size_t i = 0; i < n; ++i) s.codes.push_back({{rng(), rng()}});
  for (size_t i = 0; i < n * 16; ++i) s.pq_codes.push_back(static_cast<uint8_t>(rng()));
  s.tables = build_cascade_tables(s.codes);
  s.images.push_back({"a.jpg", 1, 640, 480, {500, 500, 320, 240}, {1, 0, 0, 0}, {0, 0, 1}});
  s.extra_meta["enu_from_segment"] = {{"scale", 1.0}};
  return s;
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(SegmentFile, RoundTripIsMappedAndMeasured) {
  auto dir = temp_dir("roundtrip");
  SegmentData s = random_segment(3000, 1);
  write_segment_file(dir / "s.vlseg", s);
  auto seg = Segment::open(dir / "s.vlseg");
  ASSERT_EQ(seg->num_points(), 3000u);
  EXPECT_EQ(seg->id(), 7u);
  EXPECT_TRUE(std::equal(s.xyz.begin(), s.xyz.end(), seg->xyz().begin()));
  const auto& v = seg->index();
  for (size_t i = 0; i < 3000; ++i) {
    ASSERT_EQ(v.codes[i].w[0], s.codes[i].w[0]);
    ASSERT_EQ(v.codes[i].w[1], s.codes[i].w[1]);
  }
  EXPECT_EQ(0, std::memcmp(v.pq_codes, s.pq_codes.data(), s.pq_codes.size()));
  EXPECT_EQ(0, std::memcmp(v.lut_ids, s.tables.ids.data(), s.tables.ids.size() * 4));
  EXPECT_EQ(v.hasher.projection[129], 1.0f);
  // Arrays are views into the mapping, 64-byte aligned.
  EXPECT_EQ(reinterpret_cast<uintptr_t>(v.codes) % 64, 0u);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(seg->xyz().data()) % 64, 0u);
  ASSERT_EQ(seg->images().size(), 1u);
  EXPECT_EQ(seg->images()[0].name, "a.jpg");
  EXPECT_EQ(seg->images()[0].camera_params[2], 320.0);
  EXPECT_EQ(seg->meta()["enu_from_segment"]["scale"], 1.0);
  // 12 + 16 + 16 + 8 × 4 bytes per point, measured from the sections.
  EXPECT_DOUBLE_EQ(seg->bytes().per_point_bytes_per_point(3000), 76.0);
  EXPECT_EQ(seg->bytes().lut_offsets, 8u * 65537 * 4);
  EXPECT_EQ(seg->bytes().file, fs::file_size(dir / "s.vlseg"));
}

TEST(SegmentFile, RejectsTruncatedCorruptedAndWrongVersion) {
  auto dir = temp_dir("reject");
  const fs::path p = dir / "s.vlseg";
  write_segment_file(p, random_segment(500, 2));
  const std::string good = read_file(p);
  write_file_atomic(p, good.substr(0, good.size() - 100));
  EXPECT_NE(error_of([&] { Segment::open(p); }).find(p.string()), std::string::npos);
  std::string flipped = good;
  flipped[good.size() / 3] ^= 0x04;
  write_file_atomic(p, flipped);
  EXPECT_NE(error_of([&] { Segment::open(p); }).find(p.string()), std::string::npos);
  {
    SectionFileWriter w(p, "SEGM", kSegmentFileVersion + 1);
    w.add_text("META", "{}");
    w.commit();
  }
  const std::string e = error_of([&] { Segment::open(p); });
  EXPECT_NE(e.find("version"), std::string::npos) << e;
  {
    SectionFileWriter w(p, "FEAT", 1);
    w.add_text("META", "{}");
    w.commit();
  }
  EXPECT_FALSE(error_of([&] { Segment::open(p); }).empty());
  // Structurally wrong tables (valid CRCs) are caught by the index check.
  SegmentData bad = random_segment(500, 3);
  bad.tables.ids[10] = 100000;
  write_segment_file(p, bad);
  EXPECT_NE(error_of([&] { Segment::open(p); }).find("out of range"), std::string::npos);
}

TEST(MapImport, FountainWithHoldout) {
  const fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "colmap" / "sparse" / "points3D.bin")) GTEST_SKIP() << "shared data absent: " << scene;
  auto out = temp_dir("fountain");
  ColmapImportOptions o;
  o.holdout_images = read_name_list(scene / "queries.txt");
  ASSERT_EQ(o.holdout_images.size(), 3u);
  o.itq.iterations = 3;  // speed; quality is measured by the benchmark
  o.pq.iterations = 3;
  auto r = import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", out, o);
  EXPECT_EQ(r.images, 8u);
  EXPECT_EQ(r.holdout.images_removed, 3u);
  EXPECT_GT(r.holdout.points_dropped, 0u);
  // The held-out images' observations are gone: every kept point has ≥ 2.
  ColmapModel full = read_colmap_model(scene / "colmap" / "sparse");
  EXPECT_EQ(r.points + r.holdout.points_dropped, full.points.size());
  MapInfo info = map_info(out);
  ASSERT_EQ(info.segments.size(), 1u);
  EXPECT_EQ(info.segments[0].points, r.points);
  EXPECT_EQ(info.segments[0].images, 8u);
  EXPECT_DOUBLE_EQ(info.segments[0].bytes.per_point_bytes_per_point(r.points), 76.0);
  EXPECT_EQ(info.manifest.holdout_images, o.holdout_images);
  EXPECT_TRUE(fs::exists(out / "holdout.txt"));
  DescriptorMatrix d = read_point_descriptor_file(out / info.manifest.segments[0].descriptors_file);
  EXPECT_EQ(d.rows(), r.points);
  // A second import into the same directory is refused without overwrite.
  EXPECT_THROW(import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", out, o), Error);
  // A manifest whose segment size disagrees with the file is rejected.
  auto m = read_manifest(out);
  m.segments[0].file_bytes += 1;
  write_manifest(out, m);
  EXPECT_THROW(map_info(out), Error);
}
