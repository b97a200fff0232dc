#include "visloc/eval/protocols.h"

#include <algorithm>
#include <fstream>

#include "visloc/colmap/bundler.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/image/image_io.h"
#include "visloc/map/map.h"
#include "visloc/sfm/colmap_database_writer.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;

QueryFeatureSource parse_query_feature_source(const std::string& name) {
  if (name == "images") return QueryFeatureSource::kImages;
  if (name == "database") return QueryFeatureSource::kDatabase;
  throw_error(ErrorCode::kInvalidArgument, "query features must be 'images' or 'database', got '", name, "'");
}

std::string to_string(QueryFeatureSource source) {
  return source == QueryFeatureSource::kImages ? "images" : "database";
}

// ---------------------------------------------------------------------------
// SourceFeatureStore

struct SourceFeatureStore::Impl {
  std::unique_ptr<ColmapDatabase> db;  // COLMAP import
  std::map<int64_t, ColmapDbCamera> cameras;
  fs::path list_dir, keys_dir;         // Bundler import
  bool root_sift = true;
};

SourceFeatureStore::SourceFeatureStore(const fs::path& map_dir, const fs::path& images_dir)
    : images_dir_(images_dir), impl_(std::make_unique<Impl>()) {
  const MapManifest man = read_manifest(map_dir);
  const std::string type = man.source.value("type", "");
  if (type == "colmap" && man.source.contains("database")) {
    model_dir_ = man.source.value("model", "");
    database_ = man.source.value("database", "");
    impl_->db = std::make_unique<ColmapDatabase>(database_);
    for (const auto& c : impl_->db->cameras()) impl_->cameras[c.camera_id] = c;
  } else if (type == "bundler" && man.source.contains("list")) {
    impl_->list_dir = fs::path(man.source.value("list", "")).parent_path();
    const std::string keys = man.source.value("keys", "");
    if (keys != "next to the images") impl_->keys_dir = keys;
    impl_->root_sift = man.source.value("descriptors", "rootsift") == "rootsift";
  } else {
    throw_error(ErrorCode::kInvalidArgument, map_dir.string(),
                ": the map was not imported from a COLMAP model + database or a Bundler model, so it has no "
                "feature store (use --query-features images)");
  }
}

SourceFeatureStore::~SourceFeatureStore() = default;

bool SourceFeatureStore::is_colmap() const { return impl_->db != nullptr; }

FeatureSet SourceFeatureStore::features(const std::string& image) const {
  if (!impl_->db) {
    FeatureSet f = read_lowe_key_file(find_lowe_key_file(impl_->list_dir, impl_->keys_dir, image), impl_->root_sift);
    f.image = image;
    return f;
  }
  const auto im = impl_->db->image_by_name(image);
  if (!im) throw_error(ErrorCode::kNotFound, database_.string(), ": no image named '", image, "'");
  FeatureSet f = impl_->db->features(im->image_id);
  f.image = image;
  return f;
}

PinholeCamera SourceFeatureStore::camera(const std::string& image) const {
  if (!impl_->db) {
    if (images_dir_.empty())
      throw_error(ErrorCode::kInvalidArgument, "Bundler key files do not give the size of '", image,
                  "': pass the image directory (--images) or --intrinsics");
    const ImageMetadata meta = read_image_metadata(images_dir_ / image);
    return PinholeCamera::centered(meta.width, meta.height, meta.focal_px());
  }
  const auto im = impl_->db->image_by_name(image);
  if (!im) throw_error(ErrorCode::kNotFound, database_.string(), ": no image named '", image, "'");
  const auto it = impl_->cameras.find(im->camera_id);
  if (it == impl_->cameras.end())
    throw_error(ErrorCode::kFormat, database_.string(), ": image '", image, "' names missing camera ", im->camera_id);
  const ColmapDbCamera& c = it->second;
  try {
    return PinholeCamera::from_colmap(colmap_camera_model_name(c.model), static_cast<int>(c.width),
                                      static_cast<int>(c.height), c.params);
  } catch (const Error& e) {
    throw_error(ErrorCode::kInvalidArgument, database_.string(), ": camera ", c.camera_id, ": ", e.what());
  }
}

// ---------------------------------------------------------------------------
// Queries

PreparedQuery prepare_query(const std::string& name, QueryFeatureSource source, const fs::path& image_dir,
                            const SiftOptions& sift, const SourceFeatureStore* store,
                            const std::optional<PinholeCamera>& intrinsics, bool use_exif_focal) {
  PreparedQuery q;
  q.name = name;
  Timer t;
  try {
    if (source == QueryFeatureSource::kDatabase) {
      if (!store) throw_error(ErrorCode::kInvalidArgument, "query features 'database' need a feature store");
      q.features = store->features(name);
      q.camera = intrinsics ? *intrinsics : store->camera(name);
    } else {
      ImageMetadata meta;
      q.features = SiftExtractor(sift).extract_file(image_dir / name, &meta);
      if (intrinsics) {
        q.camera = *intrinsics;
        if (q.camera.width == 0 && q.camera.height == 0) {  // only the focal was given
          q.camera.width = meta.width;
          q.camera.height = meta.height;
          q.camera.cx = meta.width / 2.0;
          q.camera.cy = meta.height / 2.0;
        } else if (q.camera.width != meta.width || q.camera.height != meta.height) {
          throw_error(ErrorCode::kInvalidArgument, (image_dir / name).string(), ": intrinsics are for a ",
                      q.camera.width, "x", q.camera.height, " image but the image is ", meta.width, "x", meta.height);
        }
      } else {
        std::optional<double> focal;
        if (use_exif_focal) focal = meta.focal_px();
        q.camera = PinholeCamera::centered(meta.width, meta.height, focal);
      }
    }
    q.features.image = name;
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kInternal) throw;
    q.error = e.what();
    q.features = FeatureSet{};
  }
  q.features_ms = t.elapsed_ms();
  return q;
}

LocalizationResult localize_prepared(const Localizer& localizer, const PreparedQuery& query) {
  LocalizationResult r;
  if (!query.error.empty()) {
    r.image = query.name;
    r.error = query.error;
  } else {
    r = localizer.localize_features(query.features, query.camera);
    r.image = query.name;
  }
  r.times.features = query.features_ms;
  r.times.total += query.features_ms;
  return r;
}

// ---------------------------------------------------------------------------
// COLMAP's image_registrator

ColmapRegistrationResult register_with_colmap(const ColmapModel& model, const fs::path& database,
                                              const std::vector<PreparedQuery>& queries,
                                              const ColmapRunnerOptions& colmap_options, const fs::path& work_dir) {
  ColmapRegistrationResult out;
  std::vector<const PreparedQuery*> usable;
  for (const auto& q : queries) {
    if (model.image_index_by_name(q.name) >= 0)
      throw_error(ErrorCode::kInvalidArgument, "COLMAP comparison: query '", q.name, "' is still in the model");
    if (q.error.empty() && q.features.size() > 0) usable.push_back(&q);
  }
  fs::remove_all(work_dir);
  fs::create_directories(work_dir);
  const fs::path db_path = work_dir / "database.db";
  fs::copy_file(database, db_path, fs::copy_options::overwrite_existing);
  // image_registrator tries every database image the model lacks: keep only
  // the model's images and the queries, so its time is the queries' alone.
  std::vector<std::string> others;
  {
    const ColmapDatabase copy(db_path);
    for (const auto& im : copy.images()) {
      const bool is_query = std::any_of(queries.begin(), queries.end(),
                                        [&](const PreparedQuery& q) { return q.name == im.name; });
      if (!is_query && model.image_index_by_name(im.name) < 0) others.push_back(im.name);
    }
  }
  {
    ColmapDatabaseWriter w(db_path, ColmapDatabaseWriter::Mode::kAppend);
    for (const auto& name : others) w.remove_image(name);
    for (const PreparedQuery* q : usable) {
      w.remove_image(q->name);  // the source database may hold the query with its own features
      const int64_t cam = w.add_camera(q->camera, 1.2 * std::max(q->camera.width, q->camera.height));
      const int64_t id = w.add_image(q->name, cam);
      w.add_features(id, q->features);
    }
    w.commit();
  }
  write_colmap_model_binary(model, work_dir / "model");
  {
    std::ofstream pairs(work_dir / "pairs.txt");
    for (const PreparedQuery* q : usable)
      for (const auto& im : model.images) pairs << q->name << ' ' << im.name << '\n';
    if (!pairs) throw_error(ErrorCode::kIo, (work_dir / "pairs.txt").string(), ": cannot write");
  }
  const ColmapRunner colmap(colmap_options);
  ColmapModel registered;
  if (!usable.empty()) {
    Timer t;
    colmap.match_pairs(db_path, work_dir / "pairs.txt", work_dir / "match.log");
    out.seconds_matching = t.elapsed_ms() / 1000;
    t.reset();
    colmap.register_images(db_path, work_dir / "model", work_dir / "registered", work_dir / "register.log");
    out.seconds_registration = t.elapsed_ms() / 1000;
    registered = read_colmap_model(work_dir / "registered");
  }
  const double n = std::max<size_t>(usable.size(), 1);
  for (const auto& q : queries) {
    LocalizationResult r;
    r.image = q.name;
    r.error = q.error;
    r.features = q.features.size();
    r.times.features = q.features_ms;
    const bool usable_query = q.error.empty() && q.features.size() > 0;
    r.times.matching = usable_query ? 1000 * out.seconds_matching / n : 0;
    r.times.ransac = usable_query ? 1000 * out.seconds_registration / n : 0;
    r.times.total = r.times.features + r.times.matching + r.times.ransac;
    const int64_t k = q.error.empty() ? registered.image_index_by_name(q.name) : -1;
    if (k >= 0) {
      const ColmapImage& im = registered.images[static_cast<size_t>(k)];
      r.registered = true;
      r.segment = 0;
      r.cam_from_segment = colmap_image_pose(im);
      for (int64_t id : im.point3d_ids) r.inliers += id != kColmapInvalidPoint3DId;
      const int64_t c = registered.camera_index(im.camera_id);
      if (c >= 0 && !registered.cameras[static_cast<size_t>(c)].params.empty())
        r.focal_px = registered.cameras[static_cast<size_t>(c)].params[0];  // COLMAP's (refined) focal
    }
    out.results.push_back(std::move(r));
  }
  return out;
}

// ---------------------------------------------------------------------------
// Leave-one-out

void LeaveOneOutOptions::validate() const {
  localizer.validate();
  import.validate();
  colmap.validate();
  if (work_dir.empty()) throw_error(ErrorCode::kInvalidArgument, "leave-one-out needs a work directory");
  if (features == QueryFeatureSource::kImages && images_dir.empty())
    throw_error(ErrorCode::kInvalidArgument, "leave-one-out with query features 'images' needs an image directory");
}

LeaveOneOutResult run_leave_one_out(const fs::path& model_dir, const fs::path& database,
                                    const LeaveOneOutOptions& options) {
  options.validate();
  const ColmapModel model = read_colmap_model(model_dir);
  std::vector<std::string> names = options.images;
  if (names.empty())
    for (const auto& im : model.images) names.push_back(im.name);
  for (const auto& n : names)
    if (model.image_index_by_name(n) < 0)
      throw_error(ErrorCode::kNotFound, model_dir.string(), ": no image named '", n, "' in the model");

  const ColmapDatabase db(database);  // the "database" query features
  LeaveOneOutResult res;
  if (options.compare_colmap) res.colmap.emplace();
  fs::create_directories(options.work_dir);
  for (size_t i = 0; i < names.size(); ++i) {
    const std::string& name = names[i];
    const ColmapImage& im = model.images[static_cast<size_t>(model.image_index_by_name(name))];
    const CameraPose truth_pose = colmap_image_pose(im);
    res.truth[name].cam_from_world = truth_pose;
    res.truth[name].center = truth_pose.center();

    // Known intrinsics: the caller's, else the model's camera of that image.
    std::optional<PinholeCamera> intrinsics;
    if (const PinholeCamera* listed = find_listed_camera(options.intrinsics, name))
      intrinsics = *listed;
    else {
      const ColmapCamera& c = model.cameras[static_cast<size_t>(model.camera_index(im.camera_id))];
      try {
        intrinsics = PinholeCamera::from_colmap(colmap_camera_model_name(c.model_id), static_cast<int>(c.width),
                                                static_cast<int>(c.height), c.params);
      } catch (const Error& e) {
        throw_error(ErrorCode::kInvalidArgument, model_dir.string(), ": camera ", c.camera_id, " of image '", name,
                    "': ", e.what(), " (pass --intrinsics)");
      }
    }
    PreparedQuery q;
    if (options.features == QueryFeatureSource::kDatabase) {
      Timer t;
      q.name = name;
      const auto dbim = db.image_by_name(name);
      if (!dbim) throw_error(ErrorCode::kNotFound, database.string(), ": no image named '", name, "'");
      q.features = db.features(dbim->image_id);
      q.features.image = name;
      q.camera = *intrinsics;
      q.features_ms = t.elapsed_ms();
    } else {
      q = prepare_query(name, QueryFeatureSource::kImages, options.images_dir, options.localizer.sift, nullptr,
                        intrinsics);
    }

    Timer t_import;
    ColmapImportOptions io = options.import;
    io.holdout_images = {name};
    io.overwrite = true;
    io.keep_descriptors = false;
    io.fit_hash_blend = false;  // the folds search with the given map's weight (evaluation_run.cc)
    const fs::path map_dir = options.work_dir / "map";
    import_colmap_map(model_dir, database, map_dir, io);
    res.seconds_import += t_import.elapsed_ms() / 1000;
    {
      Localizer localizer(map_dir, options.localizer);
      res.results.push_back(localize_prepared(localizer, q));
    }
    if (options.compare_colmap) {
      ColmapModel without = model;
      remove_images(without, {name});
      ColmapRegistrationResult c = register_with_colmap(without, database, {q}, options.colmap, options.work_dir / "colmap");
      res.colmap->seconds_matching += c.seconds_matching;
      res.colmap->seconds_registration += c.seconds_registration;
      res.colmap->results.push_back(std::move(c.results.front()));
    }
    if (options.progress) options.progress(i + 1, names.size());
  }
  fs::remove_all(options.work_dir);
  return res;
}

}  // namespace visloc
