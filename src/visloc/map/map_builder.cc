#include "visloc/map/map_builder.h"

#include <algorithm>
#include <atomic>
#include <exception>
#include <cmath>
#include <iomanip>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <sstream>
#include <thread>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/map/map.h"
#include "visloc/map/segment_builder.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/sfm/colmap_database_writer.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;

void MapBuildOptions::validate() const {
  if (images_dir.empty()) throw_error(ErrorCode::kInvalidArgument, "map build: --images is required");
  if (!fs::is_directory(images_dir))
    throw_error(ErrorCode::kIo, images_dir.string(), ": no such image directory");
  if (!gps_csv.empty() && !fs::is_regular_file(gps_csv))
    throw_error(ErrorCode::kIo, gps_csv.string(), ": no such GPS file");
  if (poses == PoseSource::kKnown && known_poses.empty())
    throw_error(ErrorCode::kInvalidArgument, "map build: --poses known needs --known-poses MODEL_DIR");
  if (jobs < 0) throw_error(ErrorCode::kInvalidArgument, "map build: jobs must be >= 0, got ", jobs);
  if (!(fallback_focal_factor > 0))
    throw_error(ErrorCode::kInvalidArgument, "map build: fallback_focal_factor must be positive");
  if (pq_training_descriptors < 256 * 4)
    throw_error(ErrorCode::kInvalidArgument, "map build: pq_training_descriptors must be >= 1024");
  plan.validate();
  sift.validate();
  colmap.validate();
  itq.validate();
  pq.validate();
  registration.validate();
  embedding.validate();
  image_index.validate();
}

size_t MapBuildResult::failed() const {
  return static_cast<size_t>(std::count_if(segments.begin(), segments.end(), [](const auto& s) { return !s.ok; }));
}

namespace {

std::string segment_stem(int id) {
  std::ostringstream s;
  s << std::setw(4) << std::setfill('0') << id;
  return s.str();
}

bool is_image_file(const fs::path& p) {
  std::string e = p.extension().string();
  std::transform(e.begin(), e.end(), e.begin(), ::tolower);
  return e == ".jpg" || e == ".jpeg" || e == ".png";
}

nlohmann::json to_json(const SegmentBuildResult& r) {
  return {{"id", r.id},
          {"ok", r.ok},
          {"error", r.error},
          {"images", r.images},
          {"registered_images", r.registered_images},
          {"points", r.points},
          {"bytes_per_point", r.bytes_per_point},
          {"registration_rms_m", r.registration_rms_m},
          {"registration_median_m", r.registration_median_m},
          {"registration_max_m", r.registration_max_m},
          {"registration_inliers", r.registration_inliers},
          {"seconds", r.seconds},
          {"file_bytes", r.file_bytes},
          {"file_crc32c", r.file_crc32c}};
}

SegmentBuildResult segment_result_from_json(const nlohmann::json& j) {
  SegmentBuildResult r;
  r.id = j.at("id");
  r.ok = j.at("ok");
  r.error = j.value("error", "");
  r.images = j.value("images", size_t{0});
  r.registered_images = j.value("registered_images", size_t{0});
  r.points = j.value("points", size_t{0});
  r.bytes_per_point = j.value("bytes_per_point", 0.0);
  r.registration_rms_m = j.value("registration_rms_m", 0.0);
  r.registration_median_m = j.value("registration_median_m", 0.0);
  r.registration_max_m = j.value("registration_max_m", 0.0);
  r.registration_inliers = j.value("registration_inliers", 0);
  r.seconds = j.value("seconds", 0.0);
  r.file_bytes = j.value("file_bytes", uint64_t{0});
  r.file_crc32c = j.value("file_crc32c", uint32_t{0});
  return r;
}

nlohmann::json similarity_json(const Similarity3d& s) {
  nlohmann::json r = nlohmann::json::array();
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) r.push_back(s.rotation(i, k));
  return {{"scale", s.scale}, {"rotation_row_major", r}, {"translation", {s.translation.x(), s.translation.y(), s.translation.z()}}};
}

// Runs fn(i) for i in [0, n) on `jobs` threads. The first exception stops
// the hand-out of new items and is rethrown here once every thread has ended.
void parallel_for(size_t n, int jobs, const std::function<void(size_t)>& fn) {
  std::atomic<size_t> next{0};
  std::mutex error_mutex;
  std::exception_ptr error;
  auto worker = [&] {
    for (size_t i = next++; i < n; i = next++) {
      try {
        fn(i);
      } catch (...) {
        std::lock_guard lock(error_mutex);
        if (!error) error = std::current_exception();
        next = n;
      }
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < std::min<int>(jobs, static_cast<int>(n)); ++t) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  if (error) std::rethrow_exception(error);
}

// The camera's "up" (image −y) in world coordinates. Street-level cameras are
// upright on average, so the sum over a segment's cameras gives the world's up.
Eigen::Vector3d camera_up(const CameraPose& pose) {
  return pose.rotation.conjugate() * Eigen::Vector3d(0, -1, 0);
}

PinholeCamera camera_of(const ColmapCamera& c) {
  try {
    return PinholeCamera::from_colmap(colmap_camera_model_name(c.model_id), static_cast<int>(c.width),
                                      static_cast<int>(c.height), c.params);
  } catch (const Error& e) {
    throw_error(ErrorCode::kInvalidArgument, "known poses: camera ", c.camera_id, ": ", e.what());
  }
}

// Known poses as a COLMAP model: read from a model directory, or made from a
// pose list and an intrinsics list (one COLMAP camera per image).
ColmapModel load_known_poses(const MapBuildOptions& opt) {
  if (fs::is_directory(opt.known_poses)) return read_colmap_model(opt.known_poses);
  if (opt.known_intrinsics.empty())
    throw_error(ErrorCode::kInvalidArgument, "map build: ", opt.known_poses.string(),
                " is a pose list; it needs --known-intrinsics (lines 'name MODEL w h params', '*' for all images)");
  const std::vector<NamedPose> poses = read_pose_list(opt.known_poses);
  std::map<std::string, PinholeCamera> cams;
  for (const NamedCamera& c : read_intrinsics_list(opt.known_intrinsics)) cams[c.name] = c.camera;
  ColmapModel model;
  uint32_t id = 0;
  for (const NamedPose& p : poses) {
    auto it = cams.find(p.name);
    if (it == cams.end()) it = cams.find("*");
    if (it == cams.end())
      throw_error(ErrorCode::kNotFound, opt.known_intrinsics.string(), ": no intrinsics for image '", p.name,
                  "' (and no '*' line)");
    const PinholeCamera& k = it->second;
    ++id;
    ColmapCamera cam;
    cam.camera_id = id;
    cam.model_id = 2;  // SIMPLE_RADIAL
    cam.width = static_cast<uint64_t>(k.width);
    cam.height = static_cast<uint64_t>(k.height);
    cam.params = {k.focal, k.cx, k.cy, k.k1};
    model.cameras.push_back(cam);
    ColmapImage im;
    im.image_id = id;
    im.name = p.name;
    im.camera_id = id;
    const Eigen::Quaterniond& q = p.cam_from_world.rotation;
    im.cam_from_world_q_wxyz = {q.w(), q.x(), q.y(), q.z()};
    const Eigen::Vector3d& t = p.cam_from_world.translation;
    im.cam_from_world_t = {t.x(), t.y(), t.z()};
    model.images.push_back(std::move(im));
  }
  return model;
}

struct BuildContext {
  fs::path map_dir;
  const MapBuildOptions* options = nullptr;
  std::vector<GpsRecord> records;
  std::vector<Eigen::Vector3d> enu;  // per record
  const EnuFrame* frame = nullptr;
  SegmentPlan plan;
  const ColmapModel* known = nullptr;
  Similarity3d enu_from_known;  // kKnown: the known frame → ENU (one transform for the map)
  PqCodebook codebook;
};

fs::path feature_path(const BuildContext& ctx, const std::string& image) {
  return ctx.map_dir / "work" / "features" / (image + ".vlfeat");
}

SegmentBuildResult build_segment(const BuildContext& ctx, int id) {
  const MapBuildOptions& opt = *ctx.options;
  Timer timer;
  SegmentBuildResult res;
  res.id = id;
  const fs::path work = ctx.map_dir / "work" / ("seg" + segment_stem(id));
  fs::remove_all(work);
  fs::create_directories(work);
  const fs::path log = work / "log.txt";
  const fs::path db_path = work / "database.db";

  // Images of the segment's placemarks, in route order.
  std::vector<size_t> images;
  for (int pm : ctx.plan.segments[id])
    for (size_t i : ctx.plan.placemarks[pm].images) images.push_back(i);
  res.images = images.size();

  // 1. Our features into a fresh COLMAP database.
  std::map<std::string, int64_t> db_id_of;
  std::vector<ColmapTextCamera> text_cameras;
  std::vector<ColmapTextImage> text_images;
  {
    ColmapDatabaseWriter db(db_path);
    std::map<std::tuple<int, int, double, bool>, int64_t> camera_ids;
    for (size_t i : images) {
      const std::string& name = ctx.records[i].image;
      FeatureSet f = read_feature_file(feature_path(ctx, name));
      PinholeCamera cam;
      if (ctx.known) {
        const auto& im = ctx.known->images[ctx.known->image_index_by_name(name)];
        cam = camera_of(ctx.known->cameras[ctx.known->camera_index(im.camera_id)]);
      } else {
        ImageMetadata meta = read_image_metadata(opt.images_dir / name, opt.sift.image);
        cam = PinholeCamera::centered(meta.width, meta.height, meta.focal_px());
      }
      const double fallback = opt.fallback_focal_factor * std::max(cam.width, cam.height);
      const auto key = std::make_tuple(cam.width, cam.height, cam.has_focal ? cam.focal : 0.0, cam.has_focal);
      auto it = camera_ids.find(key);
      if (it == camera_ids.end() || ctx.known) {
        const int64_t cid = db.add_camera(cam, fallback);
        it = camera_ids.insert_or_assign(key, cid).first;
        if (ctx.known) text_cameras.push_back({cid, cam});
      }
      const int64_t iid = db.add_image(name, it->second, ctx.enu[i]);
      db.add_features(iid, f);
      db_id_of[name] = iid;
      if (ctx.known) {
        const auto& im = ctx.known->images[ctx.known->image_index_by_name(name)];
        text_images.push_back({iid, it->second, name, colmap_image_pose(im)});
      }
    }
    db.commit();
  }

  // 2. COLMAP: matching, then mapper or triangulation from known poses.
  ColmapRunner colmap(opt.colmap);
  if (ctx.known && images.size() > opt.exhaustive_max_images) {
    // Known poses: match only views that can overlap (near, looking alike).
    std::ostringstream pairs;
    size_t n_pairs = 0;
    for (size_t a = 0; a < text_images.size(); ++a)
      for (size_t b = a + 1; b < text_images.size(); ++b) {
        const CameraPose& pa = text_images[a].cam_from_world;
        const CameraPose& pb = text_images[b].cam_from_world;
        if ((pa.center() - pb.center()).norm() > opt.pair_max_distance) continue;
        if (pa.viewing_direction().dot(pb.viewing_direction()) < std::cos(opt.pair_max_angle_deg * M_PI / 180)) continue;
        pairs << text_images[a].name << ' ' << text_images[b].name << '\n';
        ++n_pairs;
      }
    if (n_pairs == 0) throw_error(ErrorCode::kInvalidArgument, "segment ", id, ": no overlapping image pairs");
    write_file_atomic(work / "pairs.txt", pairs.str());
    colmap.match_pairs(db_path, work / "pairs.txt", log);
  } else {
    colmap.match(db_path, choose_match_strategy(images.size(), true, opt.exhaustive_max_images), log);
  }
  fs::path model_dir;
  if (ctx.known) {
    write_colmap_text_model(work / "known", text_cameras, text_images);
    model_dir = work / "sparse" / "0";
    colmap.triangulate(db_path, opt.images_dir, work / "known", model_dir, log);
  } else {
    model_dir = colmap.map(db_path, opt.images_dir, work / "sparse", log);
  }
  ColmapModel model = read_colmap_model(model_dir);
  res.registered_images = model.images.size();
  if (model.points.size() < 20)
    throw_error(ErrorCode::kExternalTool, "segment ", id, ": COLMAP reconstructed only ", model.points.size(),
                " points from ", images.size(), " images (log: ", log.string(), ")");

  // 3. Geo-registration: segment frame → ENU.
  Similarity3d enu_from_segment;
  std::vector<Eigen::Vector3d> src, dst;
  std::map<std::string, size_t> record_of;
  for (size_t i : images) record_of[ctx.records[i].image] = i;
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  for (const auto& im : model.images) {
    auto it = record_of.find(im.name);
    if (it == record_of.end()) continue;
    const CameraPose pose = colmap_image_pose(im);
    src.push_back(pose.center());
    up += camera_up(pose);
    dst.push_back(ctx.enu[it->second]);
  }
  if (ctx.known) {
    enu_from_segment = ctx.enu_from_known;
    res.registration_inliers = static_cast<int>(src.size());
    std::vector<double> r;
    double sum2 = 0;
    for (size_t k = 0; k < src.size(); ++k) {
      r.push_back((enu_from_segment.apply(src[k]) - dst[k]).norm());
      sum2 += r.back() * r.back();
    }
    std::sort(r.begin(), r.end());
    res.registration_rms_m = r.empty() ? 0 : std::sqrt(sum2 / r.size());
    res.registration_median_m = r.empty() ? 0 : r[r.size() / 2];
    res.registration_max_m = r.empty() ? 0 : r.back();
  } else {
    const SimilarityEstimate e = estimate_street_similarity_ransac(src, dst, up, opt.registration);
    enu_from_segment = e.transform;
    res.registration_inliers = e.inlier_count;
    res.registration_rms_m = e.rms_residual;
    res.registration_median_m = e.median_residual;
    res.registration_max_m = e.max_residual;
  }

  // 4. Compress: mean SIFT per point, ITQ, LUTs, PQ with the map's codebook.
  ColmapDatabase db(db_path);
  PointDescriptors desc = compute_point_descriptors(model, db);
  SegmentData data = make_segment_data(model, desc, ctx.codebook, opt.itq, static_cast<uint32_t>(id));
  std::vector<int> placemark_ids;
  for (int pm : ctx.plan.segments[id]) placemark_ids.push_back(ctx.plan.placemarks[pm].id);
  data.extra_meta["enu_from_segment"] = similarity_json(enu_from_segment);
  data.extra_meta["placemarks"] = placemark_ids;
  data.extra_meta["registration"] = {{"rms_m", res.registration_rms_m},
                                     {"median_m", res.registration_median_m},
                                     {"max_m", res.registration_max_m},
                                     {"inliers", res.registration_inliers},
                                     {"images", src.size()}};
  fs::create_directories(ctx.map_dir / "segments");
  fs::create_directories(ctx.map_dir / "descriptors");
  const fs::path seg_path = ctx.map_dir / "segments" / (segment_stem(id) + ".vlseg");
  write_segment_file(seg_path, data);
  write_point_descriptor_file(ctx.map_dir / "descriptors" / (segment_stem(id) + ".vldesc"),
                              round_descriptors(desc.mean), desc.track_size);
  res.points = data.num_points();
  {
    const std::string contents = read_file(seg_path);
    res.file_bytes = contents.size();
    res.file_crc32c = crc32c(contents.data(), contents.size());
  }
  res.bytes_per_point = double(res.file_bytes) / std::max<size_t>(1, res.points);
  res.ok = true;
  res.seconds = timer.elapsed_ms() / 1000.0;
  return res;
}

}  // namespace

MapBuildResult build_map(const fs::path& map_dir, const MapBuildOptions& opt,
                         const std::function<void(const MapBuildProgress&)>& progress) {
  opt.validate();
  Timer total;
  MapBuildResult result;
  const int jobs = opt.jobs > 0 ? opt.jobs : std::max(1u, std::thread::hardware_concurrency());
  BuildContext ctx;
  ctx.map_dir = map_dir;
  ctx.options = &opt;
  fs::create_directories(map_dir / "work" / "features");

  // Inputs: GPS per image, from the CSV or from EXIF.
  if (!opt.gps_csv.empty()) {
    ctx.records = read_gps_csv(opt.gps_csv);
    std::vector<std::string> missing;
    for (const auto& r : ctx.records)
      if (!fs::is_regular_file(opt.images_dir / r.image)) missing.push_back(r.image);
    if (!missing.empty())
      throw_error(ErrorCode::kNotFound, opt.gps_csv.string(), ": ", missing.size(), " listed images are not in ",
                  opt.images_dir.string(), " (first: ", missing.front(), ")");
  } else {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(opt.images_dir))
      if (e.is_regular_file() && is_image_file(e.path())) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    std::vector<std::string> no_gps;
    for (const auto& f : files) {
      ImageMetadata m = read_image_metadata(f, opt.sift.image);
      if (!m.gps) {
        no_gps.push_back(f.filename().string());
        continue;
      }
      ctx.records.push_back({f.filename().string(), *m.gps, std::nullopt});
    }
    if (!no_gps.empty())
      throw_error(ErrorCode::kInvalidArgument, no_gps.size(), " images in ", opt.images_dir.string(),
                  " have no GPS in EXIF (first: ", no_gps.front(), "); give --gps FILE.csv");
  }
  if (ctx.records.size() < 2)
    throw_error(ErrorCode::kInvalidArgument, "map build: need at least 2 geotagged images, got ", ctx.records.size());

  // The ENU origin: kept from an earlier run of the same build, else the first image.
  std::optional<MapManifest> previous;
  if (fs::exists(map_dir / "manifest.json")) previous = read_manifest(map_dir);
  GeoPosition origin = ctx.records.front().position;
  if (previous && previous->enu_origin_lat_lon_alt) {
    const auto& o = *previous->enu_origin_lat_lon_alt;
    origin = {o[0], o[1], o[2]};
  }
  EnuFrame frame(origin);
  ctx.frame = &frame;
  for (const auto& r : ctx.records) ctx.enu.push_back(frame.to_enu(r.position));
  ctx.plan = plan_segments(ctx.records, frame, opt.plan);
  result.images = ctx.records.size();
  result.placemarks = ctx.plan.placemarks.size();

  // Known poses: one similarity from the poses' frame to ENU for the whole map.
  ColmapModel known;
  if (opt.poses == PoseSource::kKnown) {
    known = load_known_poses(opt);
    std::vector<Eigen::Vector3d> src, dst;
    Eigen::Vector3d up = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < ctx.records.size(); ++i) {
      const int64_t k = known.image_index_by_name(ctx.records[i].image);
      if (k < 0)
        throw_error(ErrorCode::kNotFound, opt.known_poses.string(), ": no pose for image '", ctx.records[i].image, "'");
      const auto& im = known.images[k];
      const CameraPose pose = colmap_image_pose(im);
      src.push_back(pose.center());
      up += camera_up(pose);
      dst.push_back(ctx.enu[i]);
    }
    ctx.enu_from_known = estimate_street_similarity_ransac(src, dst, up, opt.registration).transform;
    ctx.known = &known;
  }

  // Features, once per image (segments overlap), in parallel; cached.
  Timer t_features;
  {
    std::atomic<size_t> done{0};
    std::mutex m;
    std::vector<std::string> errors;
    SiftExtractor sift(opt.sift);
    parallel_for(ctx.records.size(), jobs, [&](size_t i) {
      const fs::path out = feature_path(ctx, ctx.records[i].image);
      bool have = false;
      if (fs::exists(out)) {
        try {
          read_feature_file(out);
          have = true;
        } catch (const Error&) {
        }
      }
      if (!have) {
        try {
          write_feature_file(out, sift.extract_file(opt.images_dir / ctx.records[i].image));
        } catch (const Error& e) {
          std::lock_guard lock(m);
          errors.push_back(e.what());
        }
      }
      const size_t d = ++done;
      if (progress) {
        std::lock_guard lock(m);
        progress({"features", d, ctx.records.size(), total.elapsed_ms() / 1000});
      }
    });
    if (!errors.empty())
      throw_error(ErrorCode::kIo, errors.size(), " images could not be read: ", errors.front());
  }
  result.seconds_features = t_features.elapsed_ms() / 1000;

  // The PQ codebook: trained once per map on descriptors sampled across all images.
  const fs::path codebook_path = map_dir / "pq_codebook.vlpq";
  size_t pq_training = 0;
  if (fs::exists(codebook_path)) {
    ctx.codebook = PqCodebook::read(codebook_path);
  } else {
    const size_t per_image = (opt.pq_training_descriptors + ctx.records.size() - 1) / ctx.records.size();
    std::vector<float> sample;
    std::mt19937_64 rng(opt.pq.seed);
    for (const auto& r : ctx.records) {
      FeatureSet f = read_feature_file(feature_path(ctx, r.image));
      std::vector<size_t> rows(f.size());
      for (size_t k = 0; k < rows.size(); ++k) rows[k] = k;
      std::shuffle(rows.begin(), rows.end(), rng);
      rows.resize(std::min(rows.size(), per_image));
      for (size_t k : rows)
        for (int d = 0; d < kDescriptorDim; ++d) sample.push_back(f.descriptors.row(k)[d]);
    }
    pq_training = sample.size() / kDescriptorDim;
    ctx.codebook = PqCodebook::train(sample.data(), pq_training, opt.pq);
    nlohmann::json pq_meta = {{"dimension", kDescriptorDim}, {"subvectors", kPqSubvectors}, {"bits", 8},
                              {"training_descriptors", pq_training},
                              {"training_source", "image descriptors sampled across the map"},
                              {"seed", opt.pq.seed}};
    ctx.codebook.write(codebook_path, pq_meta.dump());
  }

  // Segments, in parallel; each one's outcome is recorded as soon as it ends.
  Timer t_segments;
  const size_t n_segments = ctx.plan.segments.size();
  result.segments.resize(n_segments);
  std::mutex manifest_mutex;
  std::atomic<size_t> segments_done{0};
  std::set<int> only(opt.only_segments.begin(), opt.only_segments.end());
  for (int s : only)
    if (s < 0 || s >= static_cast<int>(n_segments))
      throw_error(ErrorCode::kInvalidArgument, "segment ", s, " does not exist (the map has ", n_segments, ")");

  auto write_current_manifest = [&] {
    MapManifest man;
    man.enu_origin_lat_lon_alt = std::array<double, 3>{origin.lat, origin.lon, origin.alt};
    nlohmann::json plan_json = nlohmann::json::array();
    for (size_t s = 0; s < n_segments; ++s) {
      nlohmann::json pms = nlohmann::json::array();
      for (int pm : ctx.plan.segments[s]) pms.push_back(ctx.plan.placemarks[pm].id);
      plan_json.push_back(pms);
    }
    nlohmann::json failed = nlohmann::json::array();
    for (const auto& r : result.segments)
      if (!r.ok && !r.error.empty()) failed.push_back({{"id", r.id}, {"error", r.error}});
    man.parameters = {{"hash", {{"method", "itq"}, {"bits", kHashBits}, {"tables", kHashTables},
                                {"table_bits", kHashTableBits}, {"itq_iterations", opt.itq.iterations},
                                {"seed", opt.itq.seed}}},
                      {"pq", {{"subvectors", kPqSubvectors}, {"bits", 8}, {"seed", opt.pq.seed}}},
                      {"point_descriptor", "mean of track"},
                      {"sift", nlohmann::json::parse(opt.sift.to_json())},
                      {"segments", {{"min_placemarks", opt.plan.min_placemarks},
                                    {"max_placemarks", opt.plan.max_placemarks},
                                    {"overlap", opt.plan.overlap}}}};
    man.source = {{"type", "build"},
                  {"images", fs::absolute(opt.images_dir).string()},
                  {"gps", opt.gps_csv.empty() ? std::string("exif") : fs::absolute(opt.gps_csv).string()},
                  {"poses", opt.poses == PoseSource::kKnown ? "known" : "sfm"},
                  {"segment_placemarks", plan_json},
                  {"failed_segments", failed}};
    for (const auto& r : result.segments) {
      if (!r.ok) continue;
      const std::string file = "segments/" + segment_stem(r.id) + ".vlseg";
      man.segments.push_back({static_cast<uint32_t>(r.id), file, "descriptors/" + segment_stem(r.id) + ".vldesc",
                              r.points, r.registered_images, r.file_bytes, r.file_crc32c});
    }
    write_manifest(map_dir, man);
  };

  parallel_for(n_segments, jobs, [&](size_t s) {
    const int id = static_cast<int>(s);
    const fs::path result_file = map_dir / "work" / ("seg" + segment_stem(id)) / "result.json";
    const fs::path seg_file = map_dir / "segments" / (segment_stem(id) + ".vlseg");
    SegmentBuildResult r;
    bool reuse = false;
    if (!only.count(id) && fs::exists(result_file) && fs::exists(seg_file)) {
      try {
        r = segment_result_from_json(nlohmann::json::parse(read_file(result_file)));
        reuse = r.ok;
      } catch (const std::exception&) {
      }
    }
    if (!only.empty() && !only.count(id) && !reuse) {
      // Not asked for and not finished: leave it as it is.
      r = SegmentBuildResult{};
      r.id = id;
      r.error = "not built";
    } else if (reuse) {
      r.reused = true;
    } else {
      try {
        r = build_segment(ctx, id);
      } catch (const Error& e) {
        if (e.code() == ErrorCode::kInternal) throw;
        r = SegmentBuildResult{};
        r.id = id;
        r.error = e.what();
      } catch (const std::filesystem::filesystem_error& e) {  // e.g. disk full, permissions
        r = SegmentBuildResult{};
        r.id = id;
        r.error = e.what();
      }
      write_file_atomic(result_file, to_json(r).dump(2));
    }
    std::lock_guard lock(manifest_mutex);
    result.segments[s] = r;
    write_current_manifest();
    const size_t d = ++segments_done;
    if (progress) progress({"segments", d, n_segments, total.elapsed_ms() / 1000});
  });
  result.seconds_segments = t_segments.elapsed_ms() / 1000;

  // Retrieval over the images of the segments that were built.
  if (opt.build_retrieval && result.failed() < n_segments) {
    Timer t_retrieval;
    if (progress) progress({"retrieval", 0, 1, total.elapsed_ms() / 1000});
    std::vector<std::vector<int32_t>> segments_of_record(ctx.records.size());
    for (const auto& r : result.segments) {
      if (!r.ok) continue;
      for (int pm : ctx.plan.segments[r.id])
        for (size_t i : ctx.plan.placemarks[pm].images) segments_of_record[i].push_back(r.id);
    }
    std::vector<std::string> names;
    std::vector<DescriptorMatrix> descriptors;
    std::vector<std::vector<int32_t>> segments_of_image;
    for (size_t i = 0; i < ctx.records.size(); ++i) {
      if (segments_of_record[i].empty()) continue;
      names.push_back(ctx.records[i].image);
      descriptors.push_back(read_feature_file(feature_path(ctx, ctx.records[i].image)).descriptors);
      segments_of_image.push_back(segments_of_record[i]);
    }
    std::vector<const DescriptorMatrix*> pointers;
    for (const auto& d : descriptors) pointers.push_back(&d);
    RetrievalMap::build(pointers, names, SegmentTable(segments_of_image), opt.embedding, opt.image_index)
        .save(map_dir / "retrieval");
    result.seconds_retrieval = t_retrieval.elapsed_ms() / 1000;
    if (progress) progress({"retrieval", 1, 1, total.elapsed_ms() / 1000});
  }
  result.seconds_total = total.elapsed_ms() / 1000;
  return result;
}

}  // namespace visloc
