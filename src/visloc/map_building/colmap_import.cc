#include "visloc/map_building/colmap_import.h"

#include <fcntl.h>
#include <stdio.h>

#include <cerrno>
#include <cstring>

#include <optional>
#include "visloc/map_building/segment_builder.h"

#include <iomanip>
#include <sstream>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/mapped_file.h"
#include "visloc/util/timer.h"
#include "visloc/util/random.h"

namespace visloc {
namespace fs = std::filesystem;

void ColmapImportOptions::validate() const {
  itq.validate();
  segment_file.validate();
  pq.validate();
  if (pq_training_database.empty() && !pq_training_images.empty())
    throw_error(ErrorCode::kInvalidArgument, "ColmapImportOptions.pq_training_images needs pq_training_database");
  if (fit_hash_blend.value_or(false) && !keep_descriptors)
    throw_error(ErrorCode::kInvalidArgument,
                "map import: fitting the hash blend (--fit-blend) needs the map's point descriptors (drop "
                "--no-descriptors)");
  hash_blend.validate();
}


namespace {

std::string segment_name(uint32_t id, const char* ext) {
  std::ostringstream s;
  s << std::setw(4) << std::setfill('0') << id << ext;
  return s.str();
}

// Descriptors of other images (an independent PQ training set), subsampled.
std::vector<float> database_training_descriptors(const fs::path& db_path, const std::vector<std::string>& names,
                                                 size_t max_rows, uint64_t seed) {
  ColmapDatabase db(db_path);
  std::vector<ColmapDbImage> images;
  if (names.empty()) images = db.images();
  else
    for (const auto& n : names) {
      auto im = db.image_by_name(n);
      if (!im) throw_error(ErrorCode::kNotFound, db_path.string(), ": no image named ", n);
      images.push_back(*im);
    }
  DescriptorMatrix all;
  for (const auto& im : images) all.append(db.descriptors(im.image_id));
  RandomGenerator rng(seed);
  const std::vector<size_t> rows = sample_sorted_indices(all.rows(), max_rows, rng);
  std::vector<float> out(rows.size() * kDescriptorDim);
  for (size_t i = 0; i < rows.size(); ++i)
    for (int j = 0; j < kDescriptorDim; ++j) out[i * kDescriptorDim + j] = all.row(rows[i])[j];
  return out;
}

uint32_t file_crc(const fs::path& p) {
  MappedFile f(p);
  return crc32c(f.data(), f.size());
}

// The steps shared by both imports, from a model in memory (its reading
// already timed in res.ms_read) and a descriptor source.
struct ModelSource {
  std::string model_name;            // starts error messages about the model
  ImageDescriptorSource descriptors;
  std::string descriptors_name;      // starts error messages about descriptors
  nlohmann::json segment_source;     // segment META "source"
  nlohmann::json manifest_source;    // manifest "source"
};

void check_out_dir(const fs::path& out_dir, const ColmapImportOptions& options) {
  if (fs::exists(out_dir / "manifest.json") && !options.overwrite)
    throw_error(ErrorCode::kInvalidArgument, out_dir.string(), ": a map already exists there (use --overwrite)");
}

// The new map is written whole into a sibling folder, MAP.import-staging,
// then swapped with MAP in one atomic step (renameat2 RENAME_EXCHANGE) and the
// old map deleted: a failure (a full disk, a kill) before the swap leaves the
// previous map as it was; the staging folder is removed on failure or by the
// next import. Only a map folder (or a new or empty one) is ever replaced.
class StagingDir {
 public:
  explicit StagingDir(fs::path map_dir) : map_dir_(std::move(map_dir)) {
    if (map_dir_.filename().empty()) map_dir_ = map_dir_.parent_path();  // "out/" → "out"
    dir_ = map_dir_;
    dir_ += ".import-staging";
    std::error_code ec;
    if (fs::exists(map_dir_, ec) && !fs::exists(map_dir_ / "manifest.json", ec) && !fs::is_empty(map_dir_, ec))
      throw_error(ErrorCode::kInvalidArgument, map_dir_.string(),
                  " exists and is not a visloc map; import into a new or empty folder");
    fs::remove_all(dir_, ec);
    if (ec) throw_error(ErrorCode::kIo, dir_.string(), ": cannot remove a stale staging folder (", ec.message(), ")");
    fs::create_directories(dir_, ec);
    if (ec) throw_error(ErrorCode::kIo, dir_.string(), ": cannot create the staging folder (", ec.message(), ")");
  }
  ~StagingDir() {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  StagingDir(const StagingDir&) = delete;
  StagingDir& operator=(const StagingDir&) = delete;
  const fs::path& dir() const { return dir_; }
  // Makes the staged map the map: one rename (or exchange), then the old map
  // (now in the staging folder) is deleted by the destructor.
  void publish() {
    std::error_code ec;
    if (!fs::exists(map_dir_, ec)) {
      fs::rename(dir_, map_dir_, ec);
      if (ec) throw_error(ErrorCode::kIo, map_dir_.string(), ": cannot move the new map into place (", ec.message(), ")");
      return;
    }
    if (::renameat2(AT_FDCWD, dir_.c_str(), AT_FDCWD, map_dir_.c_str(), RENAME_EXCHANGE) != 0)
      throw_error(ErrorCode::kIo, map_dir_.string(), ": cannot swap the new map into place (", std::strerror(errno), ")");
  }

 private:
  fs::path map_dir_, dir_;
};

void import_model_map(ColmapModel model, const ModelSource& source, const fs::path& map_dir,
                      const ColmapImportOptions& options, ColmapImportResult& res) {
  Timer t;
  std::vector<ColmapImage> held_out;
  for (const auto& n : options.holdout_images) {
    const int64_t i = model.image_index_by_name(n);
    if (i >= 0) held_out.push_back(model.images[i]);
  }
  if (!options.holdout_images.empty()) res.holdout = remove_images(model, options.holdout_images);
  if (model.points.size() < 2)
    throw_error(ErrorCode::kInvalidArgument, source.model_name, ": the model has ", model.points.size(),
                " 3D points left; a map needs at least 2");
  res.images = model.images.size();
  res.points = model.points.size();
  res.observations = model.num_observations();
  res.ms_read += t.elapsed_ms();

  t.reset();
  PointDescriptors desc = compute_point_descriptors(model, source.descriptors, source.descriptors_name);
  res.ms_descriptors = t.elapsed_ms();

  // PQ codebook, shared by every segment of the map.
  t.reset();
  PqCodebook codebook;
  if (options.pq_training_database.empty()) {
    codebook = PqCodebook::train(desc.mean.data(), desc.num_points, options.pq);
    res.pq_training_descriptors = options.pq.training_rows(desc.num_points);
    res.pq_training_source = "map point descriptors";
  } else {
    auto x = database_training_descriptors(options.pq_training_database, options.pq_training_images,
                                           options.pq.max_training, options.pq.seed);
    codebook = PqCodebook::train(x.data(), x.size() / kDescriptorDim, options.pq);
    res.pq_training_descriptors = options.pq.training_rows(x.size() / kDescriptorDim);
    res.pq_training_source = "image descriptors of " + options.pq_training_database.string();
  }
  res.ms_pq = t.elapsed_ms();

  t.reset();
  SegmentBuildStats seg_stats;
  // A map rotation is learned on the same descriptors as a segment's would be
  // (an imported map has one segment), and stored beside the codebook.
  std::optional<BinaryHasher> map_hasher;
  if (options.hash_rotation == HashRotationScope::kMap) {
    ItqResult itq = train_itq(desc.mean.data(), desc.num_points, options.itq);
    seg_stats.itq_final_error = itq.quantization_error.empty() ? 0 : itq.quantization_error.back();
    seg_stats.ms_itq = t.elapsed_ms();
    map_hasher = std::move(itq.hasher);
  }
  SegmentData seg = make_segment_data(model, desc, codebook, options.itq, 0, &seg_stats,
                                      map_hasher ? &*map_hasher : nullptr);
  // With --holdout the tracks lost the held-out views but each point's COLMAP
  // error is still its whole track's mean: the covariance leaves those views
  // out (conservative), the noise estimate mixes the two slightly.
  if (options.segment_file.point_uncertainty)
    point_uncertainty_of_model(model, &seg.point_uncertainty, &seg.keypoint_noise_px);
  res.itq_final_error = seg_stats.itq_final_error;
  res.ms_itq = seg_stats.ms_itq;
  seg.extra_meta["source"] = source.segment_source;
  res.ms_encode = seg_stats.ms_encode;

  t.reset();
  StagingDir staging(map_dir);
  const fs::path& out_dir = staging.dir();
  fs::create_directories(out_dir / "segments");
  MapManifest man;
  const std::string seg_file = "segments/" + segment_name(0, ".vlseg");
  write_segment_file(out_dir / seg_file, seg, options.segment_file);
  std::string desc_file;
  if (options.keep_descriptors) {
    fs::create_directories(out_dir / "descriptors");
    desc_file = "descriptors/" + segment_name(0, ".vldesc");
    write_point_descriptor_file(out_dir / desc_file, round_descriptors(desc.mean), desc.track_size);
  }
  nlohmann::json pq_meta = {{"dimension", kDescriptorDim},
                            {"subvectors", codebook.subvectors()},
                            {"bits", 8},
                            {"training_descriptors", res.pq_training_descriptors},
                            {"training_source", res.pq_training_source},
                            {"seed", options.pq.seed}};
  pq_meta.update(nlohmann::json::parse(codebook.quantizer_json()));
  codebook.write(out_dir / man.pq_codebook_file, pq_meta.dump());
  if (map_hasher) {
    man.hash_rotation_file = kHashRotationFileName;
    write_hash_rotation_file(out_dir / man.hash_rotation_file, *map_hasher,
                             nlohmann::json{{"training_descriptors", desc.num_points},
                                            {"training_source", "map point descriptors"},
                                            {"itq_iterations", options.itq.iterations},
                                            {"seed", options.itq.seed}}
                                 .dump());
  }
  if (!held_out.empty()) {
    std::ostringstream s;
    s << std::setprecision(17) << "# held-out images: name qw qx qy qz tx ty tz (world-to-camera, SfM pose)\n";
    for (const auto& im : held_out) {
      const auto& q = im.cam_from_world_q_wxyz;
      const auto& tt = im.cam_from_world_t;
      s << im.name << ' ' << q[0] << ' ' << q[1] << ' ' << q[2] << ' ' << q[3] << ' ' << tt[0] << ' ' << tt[1] << ' '
        << tt[2] << '\n';
    }
    man.holdout_file = "holdout.txt";
    write_file_atomic(out_dir / man.holdout_file, s.str());
  }
  man.holdout_images = options.holdout_images;
  man.parameters = {{"hash", {{"method", "itq"}, {"bits", kHashBits}, {"tables", kHashTables},
                              {"table_bits", kHashTableBits}, {"itq_iterations", options.itq.iterations},
                              {"seed", options.itq.seed}}},
                    {"pq", pq_meta},
                    {"point_descriptor", "mean of track"}};
  man.source = source.manifest_source;
  const fs::path seg_path = out_dir / seg_file;
  man.segments.push_back({0, seg_file, desc_file, desc.num_points, seg.images.size(), fs::file_size(seg_path),
                          file_crc(seg_path)});
  write_manifest(out_dir, man);
  res.ms_write = t.elapsed_ms();
  const bool colmap_source = source.manifest_source.value("type", "") == "colmap";
  if (options.fit_hash_blend.value_or(colmap_source && options.keep_descriptors)) {
    // On the staged map, so that the map replaces a previous one only whole.
    t.reset();
    // The fit reads the model and database again: the import's copies go first.
    model = ColmapModel{};
    desc = PointDescriptors{};
    seg = SegmentData{};
    // Its messages name the staging folder, which is gone by the time they are read.
    const auto named = [&](const std::string& message) {
      std::string m = message;
      const std::string staged = out_dir.string(), final_dir = map_dir.string();
      for (size_t at = m.find(staged); at != std::string::npos; at = m.find(staged, at + final_dir.size()))
        m.replace(at, staged.size(), final_dir);
      return m;
    };
    try {
      const MapBlendFit fit = fit_map_hash_blend(out_dir, options.hash_blend);
      store_map_hash_blend(out_dir, fit, /*lock_build=*/false);
      res.hash_blend_weight = fit.fit.weight;
    } catch (const Error& e) {
      if (options.fit_hash_blend.has_value())
        throw_error(e.code(), map_dir.string(), ": map import: fitting the hash blend (--fit-blend) failed, so the ",
                    "map was not written: ", named(e.what()));
      res.hash_blend_error = named(e.what());  // the default: the map is whole without it
    } catch (const std::exception& e) {        // e.g. out of memory
      if (options.fit_hash_blend.has_value()) throw;
      res.hash_blend_error = named(e.what());
    }
    res.ms_hash_blend = t.elapsed_ms();
  }
  staging.publish();
}

}  // namespace

ColmapImportResult import_colmap_map(const fs::path& model_dir, const fs::path& database, const fs::path& out_dir,
                                     const ColmapImportOptions& options) {
  options.validate();
  ColmapImportResult res;
  check_out_dir(out_dir, options);
  Timer t;
  ColmapModel model = read_colmap_model(model_dir);
  ColmapDatabase db(database);
  res.ms_read = t.elapsed_ms();
  ModelSource source;
  source.model_name = model_dir.string();
  source.descriptors_name = database.string();
  source.descriptors = database_descriptor_source(db);
  source.segment_source = {{"colmap", fs::absolute(model_dir).string()}};
  source.manifest_source = {{"type", "colmap"},
                            {"model", fs::absolute(model_dir).string()},
                            {"database", fs::absolute(database).string()}};
  import_model_map(std::move(model), source, out_dir, options, res);
  return res;
}

BundlerImportResult import_bundler_map(const fs::path& bundle_file, const fs::path& list_file, const fs::path& out_dir,
                                       const BundlerConversionOptions& bundler, const ColmapImportOptions& options) {
  options.validate();
  bundler.validate();
  if (options.fit_hash_blend.value_or(false))
    throw_error(ErrorCode::kInvalidArgument,
                "map import: the hash blend (--fit-blend) is fitted on a COLMAP model and database; a Bundler "
                "import has none");
  BundlerImportResult out;
  check_out_dir(out_dir, options);
  Timer t;
  BundlerModel bm = read_bundler_model(bundle_file, list_file, bundler);
  out.conversion = bm.stats;
  out.map.ms_read = t.elapsed_ms();
  ModelSource source;
  source.model_name = bundle_file.string();
  source.descriptors_name = "key files of " + list_file.string();
  source.descriptors = [&bm](const ColmapImage& image) { return bm.descriptors(image); };
  const std::string descriptor = bundler.root_sift ? "rootsift" : "lowe";
  source.segment_source = {{"bundler", fs::absolute(bundle_file).string()}};
  source.manifest_source = {{"type", "bundler"},
                            {"bundle", fs::absolute(bundle_file).string()},
                            {"list", fs::absolute(list_file).string()},
                            {"keys", bundler.keys_dir.empty() ? std::string("next to the images")
                                                              : fs::absolute(bundler.keys_dir).string()},
                            {"principal_point", bm.stats.principal_point},
                            {"descriptors", descriptor}};
  import_model_map(std::move(bm.model), source, out_dir, options, out.map);
  return out;
}

nlohmann::json to_json(const ColmapImportResult& r) {
  return {{"images", r.images},
          {"points", r.points},
          {"observations", r.observations},
          {"holdout",
           {{"images_removed", r.holdout.images_removed},
            {"observations_removed", r.holdout.observations_removed},
            {"points_dropped", r.holdout.points_dropped}}},
          {"pq_training", {{"descriptors", r.pq_training_descriptors}, {"source", r.pq_training_source}}},
          {"itq_final_error", r.itq_final_error},
          {"hash_blend_weight", r.hash_blend_weight ? nlohmann::json(*r.hash_blend_weight) : nlohmann::json()},
          {"hash_blend_error", r.hash_blend_error},
          {"ms",
           {{"read", r.ms_read},
            {"descriptors", r.ms_descriptors},
            {"pq", r.ms_pq},
            {"itq", r.ms_itq},
            {"encode", r.ms_encode},
            {"write", r.ms_write},
            {"hash_blend", r.ms_hash_blend}}}};
}

bool MapImportSources::is_bundler() const { return !bundle_file.empty() || !bundler_list.empty(); }

void MapImportSources::validate(const fs::path& out_dir) const {
  if (is_bundler()) {
    if (bundle_file.empty() || bundler_list.empty() || out_dir.empty())
      throw_error(ErrorCode::kInvalidArgument, "map import needs --bundler bundle.out --list LIST --out MAP");
    if (!colmap_model.empty() || !database.empty())
      throw_error(ErrorCode::kInvalidArgument, "map import: give either --bundler/--list or --colmap/--database");
  } else {
    if (colmap_model.empty() || database.empty() || out_dir.empty())
      throw_error(ErrorCode::kInvalidArgument,
                  "map import needs --colmap MODEL --database DB --out MAP, or --bundler FILE --list FILE --out MAP");
    if (!bundler.keys_dir.empty() || !bundler.root_sift)
      throw_error(ErrorCode::kInvalidArgument, "map import: --keys and --raw-sift belong to --bundler");
  }
}

MapImportResult import_map(const MapImportSources& sources, const fs::path& out_dir, ColmapImportOptions options) {
  sources.validate(out_dir);
  if (!sources.holdout_list.empty()) options.holdout_images = read_name_list(sources.holdout_list);
  if (!sources.pq_training_list.empty()) options.pq_training_images = read_name_list(sources.pq_training_list);
  MapImportResult r;
  r.root_sift = sources.bundler.root_sift;
  if (sources.is_bundler()) {
    BundlerImportResult b = import_bundler_map(sources.bundle_file, sources.bundler_list, out_dir, sources.bundler,
                                               options);
    r.map = b.map;
    r.bundler = b.conversion;
  } else {
    r.map = import_colmap_map(sources.colmap_model, sources.database, out_dir, options);
  }
  return r;
}

nlohmann::json to_json(const MapImportResult& r) {
  nlohmann::json j = to_json(r.map);
  if (const auto& c = r.bundler)
    j["bundler"] = {{"cameras", c->cameras},
                    {"cameras_unregistered", c->cameras_unregistered},
                    {"images", c->images},
                    {"images_dropped_no_principal_point", c->images_dropped_no_principal_point},
                    {"points_read", c->points_read},
                    {"points", c->points},
                    {"observations", c->observations},
                    {"observations_dropped", c->observations_dropped},
                    {"observations_off_key", c->observations_off_key},
                    {"keys", c->keys},
                    {"principal_point", c->principal_point},
                    {"descriptors", r.root_sift ? "rootsift" : "lowe"},
                    {"ms", {{"bundle", c->ms_bundle}, {"keys", c->ms_keys}}}};
  return j;
}

std::string import_summary(const MapImportResult& r, const MapImportSources& sources, const fs::path& out_dir) {
  std::ostringstream out;
  out << "imported " << (r.bundler ? sources.bundle_file : sources.colmap_model).string() << " -> "
      << out_dir.string() << "\n";
  if (const auto& c = r.bundler) {
    out << "  bundler: " << c->cameras << " cameras (" << c->cameras_unregistered << " unregistered, dropped with "
        << c->observations_dropped << " observations), " << c->points_read << " points read, " << c->keys
        << " keys; principal point from " << c->principal_point << "; descriptors "
        << (r.root_sift ? "RootSIFT" : "Lowe's (raw)") << "\n";
    if (c->images_dropped_no_principal_point)
      out << "  " << c->images_dropped_no_principal_point
          << " registered images without observations dropped (no principal point: give --images)\n";
    if (c->observations_off_key)
      out << "  warning: " << c->observations_off_key
          << " observations lie more than 1 px from their key (key files from another run?)\n";
  }
  const ColmapImportResult& m = r.map;
  out << "  images " << m.images << ", points " << m.points << ", observations " << m.observations << "\n";
  if (m.holdout.images_removed)
    out << "  held out " << m.holdout.images_removed << " images: " << m.holdout.observations_removed
        << " observations removed, " << m.holdout.points_dropped << " points dropped (< 2 observations)\n";
  out << "  PQ codebook trained on " << m.pq_training_descriptors << " descriptors (" << m.pq_training_source << ")\n"
      << std::fixed << std::setprecision(0) << "  time ms: read " << m.ms_read << ", descriptors " << m.ms_descriptors
      << ", pq " << m.ms_pq << ", itq " << m.ms_itq << ", encode " << m.ms_encode << ", write " << m.ms_write
      << (m.hash_blend_weight ? ", hash blend " + std::to_string(long(m.ms_hash_blend)) : std::string()) << "\n";
  if (m.hash_blend_weight)
    out << std::setprecision(2) << "  hash blend weight " << *m.hash_blend_weight
        << " fitted on the map and stored (localize and eval use it by default)\n";
  if (!m.hash_blend_error.empty())
    out << "  warning: the hash blend was not fitted (the search ranks by the PQ distance alone on this map): "
        << m.hash_blend_error << "\n";
  return out.str();
}

}  // namespace visloc
