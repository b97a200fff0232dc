#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <unistd.h>

#include <filesystem>
#include <random>

#include "visloc/baselines/faiss_baselines.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/map_building/hash_blend_fit.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

// FAISS k-means on one thread: OpenMP threads spinning on a loaded machine are slower.
const int kOneThread = (set_faiss_threads(1), 1);

fs::path temp_dir(const std::string& name) { return unique_temp_dir("visloc_map_test_" + name); }

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
  s.images.push_back({"a.jpg", 1, 640, 480, {500, 500, 320, 240}, {1, 0, 0, 0}, {0, 0, 1}});
  s.extra_meta["enu_from_segment"] = {
      {"scale", 1.0}, {"rotation_row_major", {1, 0, 0, 0, 1, 0, 0, 0, 1}}, {"translation", {0, 0, 0}}};
  return s;
}

}  // namespace

TEST(SegmentFile, RoundTripIsMappedAndMeasured) {
  auto dir = temp_dir("roundtrip");
  SegmentData s = random_segment(3000, 1);
  write_segment_file(dir / "s.vlseg", s, {.coordinates = PointCoordinates::kFloat32});  // int16: segment_file_test
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
  // The lookup tables are built from the codes at open: every point once per table.
  ASSERT_NE(v.lookup, nullptr);
  EXPECT_TRUE(v.lookup->uses_16bit_ids());
  for (int k = 0; k < 8; ++k) {
    size_t total = 0;
    for (size_t i = 0; i < 3000; i += 97) EXPECT_GE(v.lookup->bucket_size(k, hash_subcode(s.codes[i], k)), 1u);
    for (uint32_t b = 0; b < kHashBuckets; ++b) total += v.lookup->bucket_size(k, b);
    EXPECT_EQ(total, 3000u);
  }
  EXPECT_EQ(seg->format_version(), kFloatXyzSegmentFileVersion);
  EXPECT_EQ(v.hasher.projection[129], 1.0f);
  // Arrays are views into the mapping, 64-byte aligned.
  EXPECT_EQ(reinterpret_cast<uintptr_t>(v.codes) % 64, 0u);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(seg->xyz().data()) % 64, 0u);
  ASSERT_EQ(seg->images().size(), 1u);
  EXPECT_EQ(seg->images()[0].name, "a.jpg");
  EXPECT_EQ(seg->images()[0].camera_params[2], 320.0);
  EXPECT_EQ(seg->meta()["enu_from_segment"]["scale"], 1.0);
  // 12 + 16 + 16 bytes per point, measured from the sections; no tables on disk.
  EXPECT_DOUBLE_EQ(seg->bytes().per_point_bytes_per_point(3000), 44.0);
  EXPECT_EQ(seg->bytes().lookup_tables, 0u);
  EXPECT_EQ(seg->bytes().hasher, (128u + 128u * 128u) * 4u);
  EXPECT_GT(seg->bytes().lookup_memory, 3000u * 16);
  EXPECT_EQ(seg->bytes().file, fs::file_size(dir / "s.vlseg"));
}

TEST(SegmentFile, ReadsVersionOneAndRebuildsItsTables) {
  auto dir = temp_dir("v1");
  const fs::path p = dir / "s.vlseg";
  SegmentData s = random_segment(700, 5);
  {
    // Version 1 as it was written: the ITQ rotation and the stored tables.
    SectionFileWriter w(p, "SEGM", 1);
    w.add_text("META", R"({"segment_id": 7, "points": 700, "images": 0})");
    w.add_array<float>("XYZ", s.xyz);
    w.add_array<HashCode>("CODE", s.codes);
    w.add_array<uint8_t>("PQ", s.pq_codes);
    w.add_array<float>("ITQMEAN", s.hasher.mean);
    w.add_array<float>("ITQW", s.hasher.projection);
    w.add_array<uint32_t>("LUTOFF", std::vector<uint32_t>(8 * 65537, 0));
    w.add_array<uint32_t>("LUTIDS", std::vector<uint32_t>(8 * 700, 0));
    w.add_text("IMAGES", "[]");
    w.commit();
  }
  auto seg = Segment::open(p);
  EXPECT_EQ(seg->format_version(), 1u);
  EXPECT_EQ(seg->bytes().lookup_tables, (8u * 65537 + 8u * 700) * 4);
  EXPECT_DOUBLE_EQ(seg->bytes().per_point_bytes_per_point(700), 44.0);
  size_t total = 0;
  for (uint32_t b = 0; b < kHashBuckets; ++b) total += seg->index().lookup->bucket_size(3, b);
  EXPECT_EQ(total, 700u);
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
  // Sections of the wrong size (valid CRCs) are caught.
  {
    SegmentData bad = random_segment(500, 3);
    SectionFileWriter w(p, "SEGM", kFloatXyzSegmentFileVersion);
    w.add_text("META", R"({"segment_id": 1, "points": 501})");
    w.add_array<float>("XYZ", bad.xyz);
    w.add_array<HashCode>("CODE", bad.codes);
    w.add_array<uint8_t>("PQ", bad.pq_codes);
    w.add_text("IMAGES", "[]");
    w.commit();
  }
  EXPECT_NE(error_of([&] { Segment::open(p); }).find("expected"), std::string::npos);
  // A segment without its own rotation opens only with its map's.
  SegmentData shared = random_segment(300, 4);
  const BinaryHasher rotation = shared.hasher;
  shared.hasher = {};
  write_segment_file(p, shared);
  EXPECT_NE(error_of([&] { Segment::open(p); }).find("map's hash rotation"), std::string::npos);
  auto opened = Segment::open(p, std::make_shared<const BinaryHasher>(rotation));
  EXPECT_TRUE(opened->uses_map_hasher());
  EXPECT_EQ(opened->index().hasher.projection[129], 1.0f);
  EXPECT_EQ(opened->bytes().hasher, 0u);
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
  EXPECT_DOUBLE_EQ(info.segments[0].bytes.per_point_bytes_per_point(r.points), 44.0);
  EXPECT_TRUE(Map::open(out).open_segment(0)->point_uncertainty().empty());  // opt-in
  EXPECT_EQ(info.manifest.holdout_images, o.holdout_images);
  EXPECT_TRUE(fs::exists(out / "holdout.txt"));
  // By default a COLMAP import fits the hash blend and stores it for its segment.
  ASSERT_TRUE(r.hash_blend_weight.has_value()) << r.hash_blend_error;
  EXPECT_EQ(info.manifest.fitted_hash_blend(), r.hash_blend_weight);
  EXPECT_TRUE(r.hash_blend_error.empty());
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

// --point-uncertainty: each point's triangulation covariance from its COLMAP
// track, 4 more bytes per point.
TEST(MapImport, PointUncertaintyFromTheTracks) {
  const fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "colmap" / "sparse" / "points3D.bin")) GTEST_SKIP() << "shared data absent: " << scene;
  auto out = temp_dir("fountain_uncertainty");
  ColmapImportOptions o;
  o.itq.iterations = 3;
  o.pq.iterations = 3;
  o.segment_file.point_uncertainty = true;
  auto r = import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", out, o);
  const MapInfo info = map_info(out);
  EXPECT_DOUBLE_EQ(info.segments[0].bytes.per_point_bytes_per_point(r.points), 48.0);
  EXPECT_TRUE(info.segments[0].point_uncertainty);
  EXPECT_EQ(info.to_json()["segments"][0]["point_uncertainty"], true);
  const auto segment = Map::open(out).open_segment(0);
  ASSERT_EQ(segment->point_uncertainty().size(), r.points);
  // COLMAP's mean reprojection errors on the Strecha photos: about a pixel.
  const double noise = segment->meta().at("point_uncertainty").at("keypoint_noise_px").get<double>();
  EXPECT_GT(noise, 0.1);
  EXPECT_LT(noise, 3.0);
  // Every point seen from 2+ of 11 photos around the fountain: known to
  // centimetres across its rays, worse along them, never "unknown".
  size_t unknown = 0;
  std::vector<double> majors;
  for (const PointUncertaintyCode& c : segment->point_uncertainty()) {
    unknown += c[2] == 255;
    majors.push_back(point_sigma_from_code(c[2]));
    EXPECT_LE(c[3], c[2]);
    EXPECT_GT(c[3], 0);
  }
  EXPECT_LT(unknown, r.points / 100);
  std::nth_element(majors.begin(), majors.begin() + majors.size() / 2, majors.end());
  const double median_major = majors[majors.size() / 2];
  EXPECT_GT(median_major, 1e-4);  // the model is in COLMAP's units (the scene spans a few)
  EXPECT_LT(median_major, 0.5);
}

// A map whose segments share the map's hash rotation (MAP/hash_rotation.vlitq).
TEST(Map, SharedHashRotationOpensSegmentsWithoutTheirOwn) {
  auto dir = temp_dir("shared_rotation");
  fs::create_directories(dir / "segments");
  SegmentData s = random_segment(400, 9);
  const BinaryHasher rotation = s.hasher;
  s.hasher = {};
  write_segment_file(dir / "segments" / "0000.vlseg", s);
  std::vector<float> centroids(size_t(kPqTableSize) * kPqSubDim);
  for (size_t i = 0; i < centroids.size(); ++i) centroids[i] = float(i % 251);
  PqCodebook(centroids).write(dir / "pq_codebook.vlpq", "{}");
  write_hash_rotation_file(dir / kHashRotationFileName, rotation, "{}");
  MapManifest m;
  m.hash_rotation_file = kHashRotationFileName;
  m.segments.push_back({7, "segments/0000.vlseg", "", 400, 1, fs::file_size(dir / "segments" / "0000.vlseg"), 0});
  write_manifest(dir, m);
  Map map = Map::open(dir);
  ASSERT_NE(map.hasher(), nullptr);
  auto seg = map.open_segment(0);
  EXPECT_TRUE(seg->uses_map_hasher());
  EXPECT_EQ(seg->index().hasher.projection, map.hasher()->projection.data());
  const MapInfo info = map_info(dir);
  EXPECT_EQ(info.hash_rotation_bytes, fs::file_size(dir / kHashRotationFileName));
  EXPECT_EQ(info.segments[0].bytes.hasher, 0u);
  // Without the manifest's entry the segment cannot be hashed: a clear error.
  m.hash_rotation_file.clear();
  write_manifest(dir, m);
  EXPECT_NE(error_of([&] { Map::open(dir).open_segment(0); }).find("hash rotation"), std::string::npos);
  // A rotation that is not orthonormal, or not finite, is rejected naming the file.
  BinaryHasher bad = rotation;
  bad.projection[5] = 3.0f;
  write_hash_rotation_file(dir / "bad.vlitq", bad, "{}");
  EXPECT_NE(error_of([&] { read_hash_rotation_file(dir / "bad.vlitq"); }).find("bad.vlitq"), std::string::npos);
  bad = rotation;
  bad.mean[0] = std::nanf("");
  write_hash_rotation_file(dir / "bad.vlitq", bad, "{}");
  EXPECT_NE(error_of([&] { read_hash_rotation_file(dir / "bad.vlitq"); }).find("not finite"), std::string::npos);
}

// map fit-blend: the weight of fountain-P11's imported map, fitted on
// held-out views of its points read again from its model and database; the
// maps it cannot fit are refused with the reason.
TEST(MapImport, FitsTheHashBlendOnItsOwnViews) {
  const fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "colmap" / "sparse" / "points3D.bin")) GTEST_SKIP() << "shared data absent: " << scene;
  auto out = temp_dir("fountain_blend");
  ColmapImportOptions o;
  o.holdout_images = read_name_list(scene / "queries.txt");
  o.itq.iterations = 3;
  o.pq.iterations = 3;
  o.fit_hash_blend = true;  // fitted on the staged map and stored in its manifest
  o.hash_blend = {.views = 1500, .fit = {.weight_steps = 4}};
  const ColmapImportResult imported =
      import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", out / "map", o);
  o.fit_hash_blend = false;
  const MapBlendFit fit = fit_map_hash_blend(out / "map", {.views = 1500, .fit = {.weight_steps = 4}});
  EXPECT_EQ(fit.fit.queries, 1500u);  // every point has 2 views or more
  EXPECT_EQ(fit.fit.distractors, 1500u);
  EXPECT_GT(fit.fit.listed, 1400u);
  ASSERT_EQ(fit.fit.correct.size(), 5u);
  EXPECT_GT(fit.fit.correct[0], 1000u);  // a held-out view mostly finds its point
  // ... where a distractor, its point left out, seldom matches at all.
  EXPECT_LT(fit.fit.distractor_matched[0], 300u);
  ASSERT_EQ(fit.segments.size(), 1u);
  EXPECT_EQ(fit.segments[0].views, 1500u);
  EXPECT_NE(fit.segments[0].model.find("sparse"), std::string::npos);
  for (size_t k = 0; k < 5; ++k) EXPECT_LE(fit.fit.correct[k] + fit.fit.wrong[k], fit.fit.listed);
  EXPECT_GE(fit.fit.weight, 0.0);
  EXPECT_LE(fit.fit.weight, 1.0);
  const nlohmann::json j = fit.to_json();
  EXPECT_EQ(j["grid"].size(), 5u);
  EXPECT_EQ(j["weight"], fit.fit.weight);
  EXPECT_NE(fit.summary("M").find("<- chosen"), std::string::npos);
  // The import stored the same fit; its segment is the one fitted on.
  ASSERT_TRUE(imported.hash_blend_weight.has_value());
  EXPECT_EQ(*imported.hash_blend_weight, fit.fit.weight);
  EXPECT_EQ(to_json(imported)["hash_blend_weight"], fit.fit.weight);
  const MapManifest stored = read_manifest(out / "map");
  ASSERT_TRUE(stored.fitted_hash_blend().has_value());
  EXPECT_EQ(*stored.fitted_hash_blend(), fit.fit.weight);
  EXPECT_EQ(stored.hash_blend->segment_crc32c, fit.segment_crc32c);
  EXPECT_EQ(stored.hash_blend->fit["grid"], j["grid"]);
  EXPECT_FALSE(stored.hash_blend->fit.contains("ms"));
  EXPECT_FALSE(stored.hash_blend->fit["segments"][0].contains("model"));
  EXPECT_EQ(stored.hash_blend->fit["segments"][0]["views"], 1500);
  // store_map_hash_blend writes it again (the rest of the manifest as it was),
  // but not a fit of other segments than the map's.
  MapBlendFit other = fit;
  other.fit.weight = fit.fit.weight == 1.0 ? 0.0 : 1.0;  // as if fitted otherwise
  other.weight_steps = 7;
  store_map_hash_blend(out / "map", other);
  MapManifest restored = read_manifest(out / "map");
  ASSERT_TRUE(restored.hash_blend.has_value());
  EXPECT_EQ(restored.fitted_hash_blend(), other.fit.weight);
  EXPECT_EQ(restored.hash_blend->fit["weight_steps"], 7);
  restored.hash_blend = stored.hash_blend;  // the rest of the manifest as it was
  EXPECT_EQ(restored.to_json(), stored.to_json());
  store_map_hash_blend(out / "map", fit);
  EXPECT_EQ(read_manifest(out / "map").to_json(), stored.to_json());
  {
    // While a build holds the map's lock (it rewrites the manifest), nothing is stored.
    fs::create_directories(out / "map" / "work");
    const int fd = ::open((out / "map" / "work" / "build.lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::flock(fd, LOCK_EX | LOCK_NB), 0);
    const std::string locked = error_of([&] { store_map_hash_blend(out / "map", other); });
    EXPECT_NE(locked.find("a build of the map (or another store) is running"), std::string::npos) << locked;
    EXPECT_EQ(read_manifest(out / "map").to_json(), stored.to_json());
    store_map_hash_blend(out / "map", other, /*lock_build=*/false);  // what the build itself does
    EXPECT_EQ(read_manifest(out / "map").fitted_hash_blend(), other.fit.weight);
    ::close(fd);
    store_map_hash_blend(out / "map", fit);  // the lock released
    EXPECT_EQ(read_manifest(out / "map").to_json(), stored.to_json());
    fs::remove_all(out / "map" / "work");
  }
  MapBlendFit stale = fit;
  stale.segment_crc32c[0] ^= 1u;
  std::string stale_error = error_of([&] { store_map_hash_blend(out / "map", stale); });
  EXPECT_NE(stale_error.find("changed after the hash blend was fitted"), std::string::npos) << stale_error;
  EXPECT_EQ(read_manifest(out / "map").to_json(), stored.to_json());

  // The model no longer the import's: with no held-out images it has more points.
  MapManifest man = read_manifest(out / "map");
  man.holdout_images.clear();
  write_manifest(out / "map", man);
  std::string e = error_of([&] { fit_map_hash_blend(out / "map"); });
  EXPECT_NE(e.find("changed since the map was made"), std::string::npos) << e;
  // Without descriptors, or not from a COLMAP model.
  man.source["type"] = "built";
  write_manifest(out / "map", man);
  e = error_of([&] { fit_map_hash_blend(out / "map"); });
  EXPECT_NE(e.find("imported from a COLMAP model"), std::string::npos) << e;
  EXPECT_NE(e.find("'built'"), std::string::npos) << e;
  // A built map reads each segment's work folder.
  man.source["type"] = "build";
  write_manifest(out / "map", man);
  e = error_of([&] { fit_map_hash_blend(out / "map"); });
  EXPECT_NE(e.find("work/seg0000"), std::string::npos) << e;
  EXPECT_NE(e.find("was it removed"), std::string::npos) << e;
  o.keep_descriptors = false;
  o.fit_hash_blend = true;  // needs the descriptors
  e = error_of(
      [&] { import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", out / "bare", o); });
  EXPECT_NE(e.find("--fit-blend"), std::string::npos) << e;
  EXPECT_FALSE(fs::exists(out / "bare"));
  o.fit_hash_blend = false;
  import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", out / "bare", o);
  e = error_of([&] { fit_map_hash_blend(out / "bare"); });
  EXPECT_NE(e.find("kept no point descriptors"), std::string::npos) << e;
  EXPECT_NE(error_of([&] { fit_map_hash_blend(out / "map", {.views = 1, .fit = {}}); }).find("views"),
            std::string::npos);
}
