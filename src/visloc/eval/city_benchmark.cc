#include "visloc/eval/city_benchmark.h"

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <iterator>
#include <limits>
#include <map>
#include <set>
#include <sstream>

#include "visloc/eval/evaluation.h"
#include "visloc/eval/plot.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/synth/city_scene.h"
#include "visloc/synth/ray_renderer.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace fs = std::filesystem;

void CityBenchmarkOptions::validate() const {
  city.validate();
  if (leave_out_roads < 0) throw_error(ErrorCode::kInvalidArgument, "bench city: leave_out_roads must be >= 0");
  if (!(leave_out_road_end_m >= 0) || !std::isfinite(leave_out_road_end_m))
    throw_error(ErrorCode::kInvalidArgument, "bench city: leave_out_road_end_m must be a finite number >= 0");
  if (!(positive_max_distance_m > 0) || !(negative_min_distance_m >= positive_max_distance_m))
    throw_error(ErrorCode::kInvalidArgument,
                "bench city: need 0 < positive_max_distance_m <= negative_min_distance_m");
  if (!(wrong_position_m > 0) || !(wrong_rotation_deg > 0))
    throw_error(ErrorCode::kInvalidArgument, "bench city: wrong-pose thresholds must be positive");
  if (!(positive_min_visible_points > 0) || !(visibility_range_m > 0) ||
      !(true_segment_share > 0 && true_segment_share <= 1))
    throw_error(ErrorCode::kInvalidArgument,
                "bench city: need positive_min_visible_points > 0, visibility_range_m > 0 and "
                "true_segment_share in (0, 1]");
  if (!shared_data.empty() && !fs::is_directory(shared_data))
    throw_error(ErrorCode::kNotFound, shared_data.string(), ": no such shared data directory");
}

namespace {

struct CityPlacemark {
  int id = 0, road = 0;
  double arc_m = 0;     // along its road
  bool mapped = false;  // set by split_city
  Eigen::Vector3d enu = Eigen::Vector3d::Zero();
};

std::vector<CityPlacemark> read_city_placemarks(const fs::path& city_json) {
  std::vector<CityPlacemark> out;
  try {
    const auto j = nlohmann::json::parse(read_file(city_json));
    for (const auto& p : j.at("placemarks")) {
      CityPlacemark c;
      c.id = p.at("id").get<int>();
      c.road = p.at("road").get<int>();
      c.arc_m = p.at("arc_m").get<double>();
      const auto e = p.at("enu").get<std::vector<double>>();
      if (e.size() != 3) throw std::runtime_error("enu must have 3 numbers");
      c.enu = {e[0], e[1], e[2]};
      out.push_back(c);
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw_error(ErrorCode::kFormat, city_json.string(), ": bad placemarks: ", e.what());
  }
  return out;
}

// Foreign photos: every k-th image of each shared data set, round robin
// over the sets, at most n in all (sorted names: the same set every run).
std::vector<fs::path> foreign_photos(const fs::path& shared, size_t n) {
  std::vector<std::vector<fs::path>> sets;
  auto images_in = [](const fs::path& dir) {
    std::vector<fs::path> files;
    std::error_code ec;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
      if (is_image_file(it->path())) files.push_back(it->path());
    }
    std::sort(files.begin(), files.end());
    return files;
  };
  if (shared.empty()) return {};
  sets.push_back(images_in(shared / "kitti07" / "images"));
  sets.push_back(images_in(shared / "opensfm-lund" / "images"));
  std::error_code ec;
  std::vector<fs::path> scenes;
  for (fs::directory_iterator it(shared / "strecha", ec), end; !ec && it != end; it.increment(ec))
    scenes.push_back(it->path());
  std::sort(scenes.begin(), scenes.end());
  for (const auto& s : scenes) sets.push_back(images_in(s / "images"));
  sets.erase(std::remove_if(sets.begin(), sets.end(), [](const auto& s) { return s.empty(); }), sets.end());
  if (sets.empty() || n == 0) return {};
  // Spread each set evenly, then take round robin.
  const size_t per_set = (n + sets.size() - 1) / sets.size();
  std::vector<std::vector<fs::path>> picked;
  for (const auto& s : sets) {
    std::vector<fs::path> p;
    const size_t k = std::min(per_set, s.size());
    for (size_t j = 0; j < k; ++j) p.push_back(s[j * s.size() / k]);
    picked.push_back(p);
  }
  std::vector<fs::path> out;
  for (size_t j = 0; out.size() < n; ++j) {
    bool any = false;
    for (const auto& p : picked)
      if (j < p.size() && out.size() < n) {
        out.push_back(p[j]);
        any = true;
      }
    if (!any) break;
  }
  return out;
}

double median_or_zero(const std::vector<double>& v) { return v.empty() ? 0.0 : median(v); }

// Confidence, its inputs and the pose's uncertainty (when there is a pose).
void add_pose_evidence(const LocalizationResult& r, nlohmann::json* entry) {
  (*entry)["confidence"] = r.confidence;
  if (r.segment < 0) return;
  (*entry)["confidence_features"] = r.confidence_features.to_json();
  if (r.under_street.assessed) {
    (*entry)["drop_below_map_camera_m"] = r.under_street.drop_below_camera_m;
    (*entry)["map_camera_plan_distance_m"] = r.under_street.camera_plan_distance_m;
    if (r.under_street.above_ground_m) (*entry)["above_map_ground_m"] = *r.under_street.above_ground_m;
    if (r.under_street.under_street) (*entry)["under_street"] = true;
  }
  if (r.uncertainty.valid) {
    (*entry)["position_sigma"] = r.uncertainty.position_sigma;
    (*entry)["rotation_sigma_deg"] = r.uncertainty.rotation_sigma_deg;
    if (r.uncertainty.relative_position_sigma > 0)
      (*entry)["relative_position_sigma"] = r.uncertainty.relative_position_sigma;
    (*entry)["sigma_scale"] = r.uncertainty.sigma_scale;
    (*entry)["map_point_uncertainty"] = r.uncertainty.map_point_uncertainty;
  }
}

nlohmann::json pose_summary(const std::vector<double>& errors_m, size_t count, size_t registered, size_t wrong) {
  return {{"queries", count},
          {"registered", registered},
          {"wrong_poses", wrong},
          {"misses", count - registered},
          {"median_position_error_m", errors_m.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(errors_m))}};
}


// The map's points as samples per segment (at most max_samples each, evenly
// strided), for counting what a query camera sees of each segment.
struct SegmentPointSample {
  int segment = -1;
  double points_per_sample = 1;  // the stride: visible samples × stride ≈ visible points
  std::vector<Eigen::Vector3d> xyz;
};

std::vector<SegmentPointSample> sample_segment_points(const fs::path& map_dir, size_t max_samples) {
  const Map map = Map::open(map_dir);
  std::vector<SegmentPointSample> out;
  for (size_t i = 0; i < map.manifest().segments.size(); ++i) {
    const auto seg = map.open_segment(i);
    SegmentPointSample s;
    s.segment = static_cast<int>(seg->id());
    const size_t n = seg->num_points();
    const size_t stride = std::max<size_t>(1, (n + max_samples - 1) / max_samples);
    s.points_per_sample = static_cast<double>(stride);
    const auto xyz = seg->xyz();
    for (size_t p = 0; p < n; p += stride) s.xyz.emplace_back(xyz[3 * p], xyz[3 * p + 1], xyz[3 * p + 2]);
    out.push_back(std::move(s));
  }
  return out;
}

// Points of each segment that the camera sees: in front, inside the image,
// within max_range_m, and not hidden by the city's buildings (a ray cast in
// the scene reaches the point). The query's own occluders (cars, trees) are
// ignored. Returns estimated point counts, one per sample set.
std::vector<double> visible_points(const synth::ViewRenderer& scene, const PinholeCamera& camera,
                                   const CameraPose& cam_from_world, const std::vector<SegmentPointSample>& samples,
                                   double max_range_m) {
  const Eigen::Matrix3d R = cam_from_world.rotation_matrix();
  const Eigen::Vector3d C = cam_from_world.center();
  std::vector<double> counts;
  for (const auto& s : samples) {
    size_t seen = 0;
    for (const Eigen::Vector3d& X : s.xyz) {
      const Eigen::Vector3d x = R * X + cam_from_world.translation;
      if (x.z() < 0.3) continue;
      const Eigen::Vector2d uv = camera.project(x);
      if (uv.x() < 0 || uv.y() < 0 || uv.x() >= camera.width || uv.y() >= camera.height) continue;
      const Eigen::Vector3d ray = X - C;
      const double d = ray.norm();
      if (d > max_range_m) continue;
      const auto hit = scene.cast_ray(C, ray / d);
      // Triangulated points lie on surfaces up to their error: tolerate some.
      if (!hit || *hit >= d - (0.3 + 0.02 * d)) ++seen;
    }
    counts.push_back(static_cast<double>(seen) * s.points_per_sample);
  }
  return counts;
}

using CityProgressCallback = std::function<void(const CityBenchmarkProgress&)>;

// Stage 1: the whole city (resumes: images already written are kept; a city
// made with other options is refused, since its scene is regenerated later).
void write_or_check_city(const fs::path& city_dir, const CityBenchmarkOptions& opt,
                         const CityProgressCallback& progress) {
  const bool city_complete = fs::exists(city_dir / "queries" / "truth.txt") && fs::exists(city_dir / "city.json");
  if (opt.stage != CityBenchmarkStage::kLocalize && !city_complete) {
    synth::CityOptions city = opt.city;
    city.resume = fs::exists(city_dir);
    synth::write_city(city, city_dir, [&](const synth::CityProgress& p) {
      if (progress) progress({"render", p.done, p.total});
    });
  } else {
    const auto existing = nlohmann::json::parse(read_file(city_dir / "city.json"), nullptr, false);
    if (existing.is_discarded() || !existing.contains("options") ||
        existing["options"] != nlohmann::json::parse(synth::city_options_json(opt.city)))
      throw_error(ErrorCode::kInvalidArgument, (city_dir / "city.json").string(),
                  ": the city was made with other options than these");
  }
}

// The city's placemarks split into mapped roads and the roads left out.
struct CityMapSplit {
  std::vector<CityPlacemark> placemarks;
  int max_road = 0;
  std::set<int> left_out;                        // roads
  size_t road_end_placemarks_left_out = 0;       // on mapped roads (leave_out_road_end_m)
  std::vector<GpsRecord> mapped;                 // every image of a mapped placemark
  std::vector<Eigen::Vector3d> mapped_centres;   // mapped placemarks
};

// Leaves the last leave_out_roads roads out of the map, and the last
// leave_out_road_end_m metres of every other road; writes OUT/map_gps.csv.
CityMapSplit split_city(const fs::path& city_dir, const fs::path& out, const CityBenchmarkOptions& opt) {
  CityMapSplit s;
  s.placemarks = read_city_placemarks(city_dir / "city.json");
  for (const auto& p : s.placemarks) s.max_road = std::max(s.max_road, p.road);
  for (int r = s.max_road; r > s.max_road - opt.leave_out_roads && r >= 0; --r) s.left_out.insert(r);
  if (static_cast<int>(s.left_out.size()) > s.max_road)
    throw_error(ErrorCode::kInvalidArgument, "bench city: the city has ", s.max_road + 1, " roads; leaving out ",
                opt.leave_out_roads, " would map none");
  std::map<int, double> road_end_arc;
  for (const auto& p : s.placemarks) road_end_arc[p.road] = std::max(road_end_arc[p.road], p.arc_m);
  for (auto& p : s.placemarks) {
    p.mapped = !s.left_out.count(p.road);
    if (p.mapped && opt.leave_out_road_end_m > 0 && p.arc_m > road_end_arc[p.road] - opt.leave_out_road_end_m) {
      p.mapped = false;
      ++s.road_end_placemarks_left_out;
    }
  }

  // The map: every image of a mapped placemark.
  std::map<int, const CityPlacemark*> placemark_by_id;
  for (const auto& p : s.placemarks) placemark_by_id[p.id] = &p;
  for (const auto& r : read_gps_csv(city_dir / "gps.csv")) {
    if (!r.placemark) throw_error(ErrorCode::kFormat, (city_dir / "gps.csv").string(), ": no placemark column");
    auto it = placemark_by_id.find(*r.placemark);
    if (it == placemark_by_id.end())
      throw_error(ErrorCode::kFormat, (city_dir / "gps.csv").string(), ": placemark ", *r.placemark, " of ", r.image,
                  " is not in city.json");
    if (it->second->mapped) s.mapped.push_back(r);
  }
  if (s.mapped.empty())
    throw_error(ErrorCode::kInvalidArgument, "bench city: leaving out ", opt.leave_out_roads, " roads and ",
                opt.leave_out_road_end_m, " m of every road's end maps no placemark");
  write_gps_csv(out / "map_gps.csv", s.mapped);
  for (const auto& p : s.placemarks)
    if (p.mapped) s.mapped_centres.push_back(p.enu);
  return s;
}

// Stage 2: builds OUT/map from the mapped images and writes its summary to
// OUT/map_build.json; the localize stage reads that summary instead.
nlohmann::json build_or_read_city_map(const fs::path& out, const fs::path& city_dir, const CityBenchmarkOptions& opt,
                                      const CityProgressCallback& progress,
                                      const std::function<void(const MapBuildProgress&)>& map_progress) {
  const fs::path build_summary_path = out / "map_build.json";
  nlohmann::json build_summary;
  if (opt.stage != CityBenchmarkStage::kLocalize) {
    MapBuildOptions mb = opt.map;
    mb.images_dir = city_dir / "images";
    mb.gps_csv = out / "map_gps.csv";
    mb.gps_lists_subset = true;  // the streets left out stay in the folder
    mb.poses = PoseSource::kKnown;
    mb.known_poses = city_dir / "sparse";
    if (progress) progress({"map", 0, 1});
    const MapBuildResult built = build_map(out / "map", mb, map_progress);
    if (built.failed() == built.segments.size())
      throw_error(ErrorCode::kExternalTool, "bench city: no segment of the map could be built (logs under ",
                  (out / "map" / "work").string(), ")");
    if (progress) progress({"map", 1, 1});
    size_t map_bytes = 0, points = 0;
    for (const auto& s : built.segments) {
      map_bytes += s.file_bytes;
      points += s.points;
    }
    build_summary = {
        {"segments", built.segments.size()},
        {"segments_failed", built.failed()},
        {"points", points},
        {"segment_bytes", map_bytes},
        {"build_seconds_this_run", built.seconds_total},
        // The build's hash-blend fit (null when not fitted; the error when the default fit failed).
        {"hash_blend_weight", built.hash_blend_weight ? nlohmann::json(*built.hash_blend_weight) : nlohmann::json()},
        {"hash_blend_error", built.hash_blend_error}};
    write_file_atomic(build_summary_path, build_summary.dump(2));
  } else {
    try {
      build_summary = nlohmann::json::parse(read_file(build_summary_path));
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      throw_error(ErrorCode::kFormat, build_summary_path.string(), ": ", e.what());
    }
  }
  return build_summary;
}

// Queries of one kind: how many, registered, wrong; registered ones' position errors.
struct QueryKindTally {
  size_t count = 0, registered = 0, wrong = 0;
  std::vector<double> errors_m;
};

// What localizing the queries gave: counts by kind, positives' timings and
// retrieval, and a JSON entry per query.
struct CityLocalizationTally {
  QueryKindTally positives, negatives, between, near_unseen, foreigners;
  std::vector<double> ms_excluding_features, ms_total, ms_retrieval, ms_matching, ms_ransac, ms_registered, ms_missed;
  size_t retrieval_hits = 0;              // the true segment among the first max_segments candidates
  size_t retrieval_hits_all = 0;          // ... among every candidate, the fallback segments' too
  size_t fallback_segments_searched = 0;  // positives whose first candidates gave no registered pose
  std::vector<double> true_ranks, top_vote_share, voted_segments;
  nlohmann::json per_query = nlohmann::json::array();
  uint64_t peak_city_queries = 0;  // peak memory before the foreign photos
  bool image_votes = false;        // the candidates were ranked with image votes
  bool point_votes = false;        // ... with point votes
  size_t point_vote_bytes = 0;     // their index's memory
  double hash_blend_weight = 0;    // the cascade search's (given, or the map's fitted one)
};

// What localizing a synthetic query needs to know of the city and the map.
struct CityQueryContext {
  const CityBenchmarkOptions& opt;
  const fs::path& city_dir;
  const CityMapSplit& split;
  const Localizer& localizer;
  const std::map<std::string, PinholeCamera>& intrinsics;
  const synth::ViewRenderer& scene_probe;
  const std::vector<SegmentPointSample>& point_samples;
};

// Localizes one synthetic query, classifies it by its distance to the map and
// what it sees of it, and adds it to the tally.
void localize_city_query(const NamedPose& q, const CityQueryContext& ctx, CityLocalizationTally& t) {
  const CityBenchmarkOptions& opt = ctx.opt;
  auto cam = ctx.intrinsics.find(q.name);
  const LocalizationResult r = ctx.localizer.localize_file(
      ctx.city_dir / "queries" / "images" / q.name,
      cam == ctx.intrinsics.end() ? std::nullopt : std::optional<PinholeCamera>(cam->second));
  const Eigen::Vector3d c = q.cam_from_world.center();
  double nearest = std::numeric_limits<double>::infinity();
  for (const auto& p : ctx.split.placemarks) {
    if (!p.mapped) continue;
    const double d = (p.enu - c).head<2>().norm();
    if (d < nearest) {
      nearest = d;
    }
  }
  // What the query sees of each segment (positives only: near the map).
  std::vector<double> seen;
  double most_seen = 0;
  if (nearest <= opt.positive_max_distance_m && cam != ctx.intrinsics.end()) {
    seen = visible_points(ctx.scene_probe, cam->second, q.cam_from_world, ctx.point_samples, opt.visibility_range_m);
    for (double v : seen) most_seen = std::max(most_seen, v);
  }
  const std::string kind = nearest <= opt.positive_max_distance_m
                               ? (most_seen >= opt.positive_min_visible_points ? "positive" : "near_unseen")
                           : nearest >= opt.negative_min_distance_m ? "negative"
                                                                    : "between";
  QueryKindTally& k = kind == "positive"    ? t.positives
                      : kind == "negative"  ? t.negatives
                      : kind == "between"   ? t.between
                                            : t.near_unseen;
  ++k.count;
  double pos_err = -1, rot_err = -1;
  bool wrong = false;
  if (r.registered) {
    ++k.registered;
    pos_err = position_error(r.cam_from_segment, q.cam_from_world);
    rot_err = rotation_error_deg(r.cam_from_segment, q.cam_from_world);
    wrong = pos_err > opt.wrong_position_m || rot_err > opt.wrong_rotation_deg;
    k.wrong += wrong;
    k.errors_m.push_back(pos_err);
  }
  int rank = -1;
  std::vector<int> truth_segments;
  if (kind == "positive") {
    // True segments: those that show the query at least true_segment_share
    // as many points as the segment that shows it most.
    for (size_t i = 0; i < seen.size(); ++i)
      if (seen[i] >= opt.true_segment_share * most_seen) truth_segments.push_back(ctx.point_samples[i].segment);
    for (size_t i = 0; i < r.retrieval_segments.size() && rank < 0; ++i)
      if (std::find(truth_segments.begin(), truth_segments.end(), r.retrieval_segments[i]) != truth_segments.end())
        rank = static_cast<int>(i) + 1;
    if (rank > 0) {
      ++t.retrieval_hits_all;
      t.retrieval_hits += rank <= opt.localizer.max_segments;
      t.true_ranks.push_back(rank);
    }
    if (r.retrieval_total_votes > 0 && !r.retrieval_votes.empty()) {
      t.top_vote_share.push_back(r.retrieval_votes[0] / r.retrieval_total_votes);
      t.voted_segments.push_back(static_cast<double>(r.retrieval_voted_segments));
    }
    t.fallback_segments_searched += r.fallback_segments_searched;
    t.ms_excluding_features.push_back(r.times.total - r.times.features);
    t.ms_total.push_back(r.times.total);
    t.ms_retrieval.push_back(r.times.retrieval);
    t.ms_matching.push_back(r.times.matching);
    t.ms_ransac.push_back(r.times.ransac);
    (r.registered ? t.ms_registered : t.ms_missed).push_back(r.times.total - r.times.features);
  }
  nlohmann::json entry = {{"image", q.name},
                          {"kind", kind},
                          {"distance_to_map_m", nearest},
                          {"registered", r.registered},
                          {"wrong", wrong},
                          {"inliers", r.inliers},
                          {"position_error_m", pos_err},
                          {"rotation_error_deg", rot_err},
                          {"true_segment_rank", rank},
                          {"true_segments", truth_segments},
                          {"retrieval_segments", r.retrieval_segments},
                          {"retrieval_votes", r.retrieval_votes},
                          {"retrieval_voted_segments", r.retrieval_voted_segments},
                          {"most_visible_points", most_seen},
                          {"error", r.error},
                          {"fallback_segments_searched", r.fallback_segments_searched}};
  add_pose_evidence(r, &entry);
  if (r.segment >= 0) {  // the pose's error whether registered or not (confidence fits)
    entry["pose_position_error_m"] = position_error(r.cam_from_segment, q.cam_from_world);
    entry["pose_rotation_error_deg"] = rotation_error_deg(r.cam_from_segment, q.cam_from_world);
  }
  t.per_query.push_back(entry);
}

// Stage 3: localizes the synthetic queries (positives and negatives), then foreign photos.
CityLocalizationTally localize_city_queries(const fs::path& out, const fs::path& city_dir,
                                            const CityBenchmarkOptions& opt, const CityMapSplit& split,
                                            const CityProgressCallback& progress) {
  // The scene (regenerated from the options) and the map's points, to tell
  // which segments a positive query sees.
  synth::CityScene scene = synth::generate_city_scene(opt.city.layout);
  synth::add_markers(opt.city, scene);
  const synth::ViewRenderer scene_probe(scene, nullptr, opt.city.render);
  const std::vector<SegmentPointSample> point_samples = sample_segment_points(out / "map", 4000);

  const Localizer localizer(out / "map", opt.localizer);
  const CamerasByName intrinsics = read_intrinsics_by_name(city_dir / "queries" / "intrinsics.txt");
  const std::vector<NamedPose> truth = read_pose_list(city_dir / "queries" / "truth.txt");
  const std::vector<fs::path> foreign = foreign_photos(opt.shared_data, opt.foreign_photos);
  const size_t total = truth.size() + foreign.size();

  CityLocalizationTally t;
  t.image_votes = localizer.has_retrieval();
  t.point_votes = localizer.has_point_votes();
  t.point_vote_bytes = localizer.point_vote_bytes();
  t.hash_blend_weight = localizer.options().search.hash_blend_weight;
  const CityQueryContext ctx{opt, city_dir, split, localizer, intrinsics, scene_probe, point_samples};
  size_t done = 0;
  for (const NamedPose& q : truth) {
    localize_city_query(q, ctx, t);
    if (progress) progress({"localize", ++done, total});
  }
  // Peak memory over the city's queries (up to 1024×768), before the foreign
  // photos (up to 1536×1024: SIFT's pyramids of a larger image).
  t.peak_city_queries = peak_memory_bytes();
  for (const fs::path& photo : foreign) {
    const LocalizationResult r = localizer.localize_file(photo);
    ++t.foreigners.count;
    if (r.registered) {
      ++t.foreigners.registered;
      ++t.foreigners.wrong;
    }
    nlohmann::json entry = {{"image", photo.string()}, {"kind", "foreign"}, {"registered", r.registered},
                            {"wrong", r.registered}, {"inliers", r.inliers}, {"error", r.error}};
    add_pose_evidence(r, &entry);
    t.per_query.push_back(entry);
    if (progress) progress({"localize", ++done, total});
  }
  return t;
}

// Counts over the per-query entries that the report's JSON and Markdown share.
struct CityQueryCounts {
  std::vector<size_t> rank_histogram;  // [0]: not found
  size_t wrong_total = 0;
  // Confidence: poses with enough inliers that the threshold turned away,
  // right and wrong; uncertainty: registered positives' errors within 1σ, 2σ.
  size_t turned_away_right = 0, turned_away_wrong = 0, with_sigma = 0, within1 = 0, within2 = 0;
  size_t under_street_right = 0, under_street_wrong = 0;  // turned away above the threshold
};

CityQueryCounts count_city_queries(const CityLocalizationTally& t, const CityBenchmarkOptions& opt) {
  CityQueryCounts c;
  c.rank_histogram.assign(static_cast<size_t>(opt.localizer.max_segments + opt.localizer.fallback_segments) + 1, 0);
  for (const auto& q : t.per_query)
    if (q["kind"] == "positive") {
      const int r = q["true_segment_rank"].get<int>();
      ++c.rank_histogram[r > 0 && r < static_cast<int>(c.rank_histogram.size()) ? r : 0];
    }
  c.wrong_total = t.positives.wrong + t.negatives.wrong + t.foreigners.wrong;
  for (const auto& q : t.per_query) {
    const std::string kind = q["kind"];
    if (kind == "between" || kind == "near_unseen" || !q.contains("confidence_features")) continue;
    if (!q["registered"].get<bool>() &&
        q["inliers"].get<size_t>() >= opt.localizer.ransac.min_inliers) {
      const bool right = kind != "foreign" && q.contains("pose_position_error_m") &&
                         q["pose_position_error_m"].get<double>() <= opt.wrong_position_m &&
                         q["pose_rotation_error_deg"].get<double>() <= opt.wrong_rotation_deg;
      if (q.value("under_street", false) && q["confidence"].get<double>() >= opt.localizer.min_confidence)
        (right ? c.under_street_right : c.under_street_wrong)++;
      else
        (right ? c.turned_away_right : c.turned_away_wrong)++;
    }
    if (kind == "positive" && q["registered"].get<bool>() && q.contains("position_sigma")) {
      const double e = q["position_error_m"].get<double>(), sigma = q["position_sigma"].get<double>();
      ++c.with_sigma;
      c.within1 += e <= sigma;
      c.within2 += e <= 2 * sigma;
    }
  }
  return c;
}

// report.json.
nlohmann::json city_report_json(const fs::path& city_dir, const CityBenchmarkOptions& opt, const CityMapSplit& split,
                                const nlohmann::json& build_summary, const CityLocalizationTally& t,
                                const CityQueryCounts& c) {
  return {
      {"city",
       {{"road_length_m", nlohmann::json::parse(read_file(city_dir / "city.json")).at("counts").at("road_length_m")},
        {"roads", split.max_road + 1},
        {"roads_left_out", std::vector<int>(split.left_out.begin(), split.left_out.end())},
        {"road_end_left_out_m", opt.leave_out_road_end_m},
        {"road_end_placemarks_left_out", split.road_end_placemarks_left_out},
        {"placemarks_on_roads_left_out",
         std::count_if(split.placemarks.begin(), split.placemarks.end(),
                       [&](const CityPlacemark& p) { return split.left_out.count(p.road) > 0; })},
        {"placemarks_mapped", split.mapped_centres.size()},
        {"images_mapped", split.mapped.size()},
        {"building_designs", opt.city.layout.building_designs},
        {"building_design_share", opt.city.layout.building_designs > 0 ? opt.city.layout.building_design_share : 0.0}}},
      {"map", build_summary},
      {"peak_memory_bytes_of_localizing_process", peak_memory_bytes()},
      {"peak_memory_bytes_city_queries", t.peak_city_queries},
      {"localized_in_separate_process", opt.stage == CityBenchmarkStage::kLocalize},
      {"hash_blend", hash_blend_text(opt.localizer)},
      {"hash_blend_weight", std::round(t.hash_blend_weight * 1e6) / 1e6},
      {"segment_votes",
       {{"option", to_string(opt.localizer.segment_votes)},
        {"image_votes_used", t.image_votes},
        {"point_votes_used", t.point_votes},
        {"point_vote_index_bytes", t.point_vote_bytes},
        {"points_per_segment", opt.localizer.point_votes.points_per_segment},
        {"max_points", opt.localizer.point_votes.max_points},
        {"probe_radius", opt.localizer.point_votes.probe_radius},
        {"distinct_ratio", std::round(double(opt.localizer.point_votes.distinct_ratio) * 1000) / 1000},
        {"normalize_by_chance", opt.localizer.point_votes.normalize_by_chance}}},
      {"positives", pose_summary(t.positives.errors_m, t.positives.count, t.positives.registered, t.positives.wrong)},
      {"negatives_unmapped_streets",
       pose_summary(t.negatives.errors_m, t.negatives.count, t.negatives.registered, t.negatives.wrong)},
      {"between_not_scored", {{"queries", t.between.count}, {"registered", t.between.registered}}},
      {"near_but_unseen_not_scored",
       {{"queries", t.near_unseen.count},
        {"registered", t.near_unseen.registered},
        {"rule", {{"min_visible_points", opt.positive_min_visible_points}, {"range_m", opt.visibility_range_m}}}}},
      {"foreign_photos", {{"queries", t.foreigners.count}, {"registered", t.foreigners.registered}}},
      {"wrong_poses", c.wrong_total},
      {"wrong_pose_rule", {{"position_m", opt.wrong_position_m}, {"rotation_deg", opt.wrong_rotation_deg}}},
      {"confidence",
       {{"min_confidence", opt.localizer.min_confidence},
        {"turned_away_right_poses", c.turned_away_right},
        {"turned_away_wrong_poses", c.turned_away_wrong}}},
      {"under_street",
       {{"turned_away_right_poses", c.under_street_right}, {"turned_away_wrong_poses", c.under_street_wrong}}},
      {"uncertainty",
       {{"sigma_scale", ConfidenceModel::builtin().sigma_scale},
        {"sigma_scale_with_point_uncertainty", ConfidenceModel::builtin().sigma_scale_with_point_uncertainty},
        {"registered_positives_with_sigma", c.with_sigma},
        {"within_1_sigma", c.with_sigma ? double(c.within1) / double(c.with_sigma) : 0.0},
        {"within_2_sigma", c.with_sigma ? double(c.within2) / double(c.with_sigma) : 0.0}}},
      {"retrieval",
       {{"positives_with_true_segment_among_candidates", t.retrieval_hits},
        {"fraction", t.positives.count ? double(t.retrieval_hits) / double(t.positives.count) : 0.0},
        {"candidates", {{"first", opt.localizer.max_segments}, {"fallback", opt.localizer.fallback_segments}}},
        {"positives_with_true_segment_among_all_candidates", t.retrieval_hits_all},
        {"fraction_among_all_candidates",
         t.positives.count ? double(t.retrieval_hits_all) / double(t.positives.count) : 0.0},
        {"positives_that_searched_the_fallback_candidates", t.fallback_segments_searched},
        {"median_rank_of_true_segment",
         t.true_ranks.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(t.true_ranks))},
        {"rank_histogram", c.rank_histogram},
        {"true_segment_rule", {{"share_of_best", opt.true_segment_share}}},
        {"median_top_candidate_vote_share",
         t.top_vote_share.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(t.top_vote_share))},
        {"median_segments_voted",
         t.voted_segments.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(t.voted_segments))}}},
      {"median_ms_per_positive",
       {{"total", median_or_zero(t.ms_total)},
        {"excluding_features", median_or_zero(t.ms_excluding_features)},
        {"retrieval", median_or_zero(t.ms_retrieval)},
        {"matching", median_or_zero(t.ms_matching)},
        {"ransac", median_or_zero(t.ms_ransac)},
        {"registered_excluding_features", median_or_zero(t.ms_registered)},
        {"missed_excluding_features", median_or_zero(t.ms_missed)}}},
      {"per_query", t.per_query}};
}

namespace {
// Plots beside the report: where retrieval ranked the true segment (ranks
// 1..max_segments + fallback_segments, then "not among them"), and the
// cumulative position error of the registered positives.
void write_city_plots(const fs::path& out, const CityLocalizationTally& t, const CityQueryCounts& c) {
  const size_t ranks = c.rank_histogram.size();  // [0]: not among the candidates
  size_t most = 1;
  for (size_t n : c.rank_histogram) most = std::max(most, n);
  Plot bars("Rank of the true segment among the candidates (positives)", "rank (last: not among them)", "positives",
            0.5, double(ranks) + 0.5, 0, double(most) * 1.1);
  for (size_t k = 0; k < ranks; ++k) {
    const double x = double(k == 0 ? ranks : k);
    const double n = double(c.rank_histogram[k]);
    for (int dx = -6; dx <= 6; ++dx)  // a bar 13 px wide of 1-px lines: the plot draws lines
      bars.line(x + dx * 0.02, 0, x + dx * 0.02, n, k == 0 ? "#d62728" : "#1f77b4",
                k == 0 ? cv::Scalar(40, 39, 214) : cv::Scalar(180, 119, 31));
    bars.label(x, n, std::to_string(c.rank_histogram[k]), -6, -4);
  }
  bars.save(out / "retrieval_ranks");
  std::vector<double> e = t.positives.errors_m;
  std::sort(e.begin(), e.end());
  const double xmax = e.empty() ? 1.0 : std::max(0.05, e[std::min(e.size() - 1, e.size() * 95 / 100)] * 1.2);
  Plot curve("Cumulative position error (positives)", "position error (m)", "fraction of positives", 0, xmax, 0, 1);
  curve.cumulative_steps(e, double(std::max<size_t>(1, t.positives.count)), xmax);
  curve.save(out / "error_curve");
}
}  // namespace

// report.md.
namespace {
// `value` with `decimals` digits after the point.
std::string fixed_text(double value, int decimals) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(decimals) << value;
  return s.str();
}
}  // namespace

std::string city_report_markdown(const nlohmann::json& report, const CityBenchmarkOptions& opt,
                                 const CityMapSplit& split, const nlohmann::json& build_summary,
                                 const CityLocalizationTally& t, const CityQueryCounts& c) {
  const size_t points = build_summary.at("points").get<size_t>();
  std::ostringstream md;
  md << std::fixed << std::setprecision(3);
  md << "# City benchmark\n\n"
     << "City: " << report["city"]["road_length_m"] << " m of street, " << (split.max_road + 1) << " roads, "
     << split.left_out.size() << " left out of the map";
  if (opt.leave_out_road_end_m > 0)
    md << ", and the last " << opt.leave_out_road_end_m << " m of the others (" << split.road_end_placemarks_left_out
       << " placemarks)";
  if (opt.city.layout.building_designs > 0)
    md << "; a share " << opt.city.layout.building_design_share << " of the buildings copy one of "
       << opt.city.layout.building_designs << " designs (repeated facades)";
  md << "; map: " << build_summary.at("segments") << " segments (" << build_summary.at("segments_failed")
     << " failed), " << points << " points.\n\n"
     << "| queries | count | registered | wrong poses | misses | median position error (m) "
        "|\n|---|---|---|---|---|---|\n";
  auto row = [&](const char* name, const QueryKindTally& k) {
    md << "| " << name << " | " << k.count << " | " << k.registered << " | " << k.wrong << " | "
       << (k.count - k.registered) << " | " << (k.errors_m.empty() ? std::string("-") : std::to_string(median(k.errors_m)))
       << " |\n";
  };
  row("positives (near mapped streets)", t.positives);
  row("negatives (unmapped streets)", t.negatives);
  md << "| foreign photos | " << t.foreigners.count << " | " << t.foreigners.registered << " | " << t.foreigners.wrong
     << " | " << (t.foreigners.count - t.foreigners.registered) << " | - |\n\n"
     << "Wrong poses in all: " << c.wrong_total << " (a wrong pose: registered more than " << opt.wrong_position_m
     << " m or " << opt.wrong_rotation_deg << "° from the truth, or any registered foreign photo). " << t.between.count
     << " queries between " << opt.positive_max_distance_m << " and " << opt.negative_min_distance_m
     << " m from the map are not scored, nor " << t.near_unseen.count << " near the map that see fewer than "
     << opt.positive_min_visible_points
     << " of its points. A negative registered within the thresholds of its true pose (it sees "
     << "mapped facades) is not a wrong pose: " << (t.negatives.registered - t.negatives.wrong) << " here.\n\n"
     << "Confidence threshold " << opt.localizer.min_confidence << ": of the poses with at least "
     << opt.localizer.ransac.min_inliers << " inliers it turned away " << c.turned_away_wrong << " wrong and "
     << c.turned_away_right << " right ones; the under-street check " << c.under_street_wrong << " wrong and "
     << c.under_street_right << " right ones above the threshold. Uncertainty: of " << c.with_sigma
     << " registered positives, " << (c.with_sigma ? double(c.within1) / double(c.with_sigma) : 0.0)
     << " have their position error within 1σ and " << (c.with_sigma ? double(c.within2) / double(c.with_sigma) : 0.0)
     << " within 2σ. The cascade search's hash blend: weight " << fixed_text(t.hash_blend_weight, 2)
     << (opt.localizer.hash_blend_source == HashBlendSource::kMap ? " (the map's)" : " (given)") << ".\n\n"
     << "Retrieval (candidates ranked by "
     << (t.image_votes && t.point_votes ? (opt.localizer.segment_votes == SegmentVoteSource::kBoth
                                               ? "image and point votes"
                                               : "point votes, the retrieved images filling the places they leave")
         : t.point_votes                ? "point votes"
         : t.image_votes                ? "image votes"
                                        : "nothing: every segment is searched")
     << (t.point_votes ? "; point-vote index " + std::to_string((t.point_vote_bytes + 512 * 1024) / (1024 * 1024)) +
                             " MiB, probe radius " + std::to_string(opt.localizer.point_votes.probe_radius) +
                             ", vote ratio " + fixed_text(opt.localizer.point_votes.distinct_ratio, 2)
                       : std::string())
     << "): the true segment is among the " << opt.localizer.max_segments << " candidates searched first for "
     << t.retrieval_hits << "/" << t.positives.count << " positives";
  if (!t.true_ranks.empty()) md << " (median rank " << median(t.true_ranks) << ")";
  md << "; among those and the " << opt.localizer.fallback_segments << " fallback candidates for "
     << t.retrieval_hits_all << ", which were searched for the " << t.fallback_segments_searched
     << " positives whose first candidates gave no registered pose";
  md << "; by rank:";
  for (size_t r = 1; r < c.rank_histogram.size(); ++r) md << " " << r << ": " << c.rank_histogram[r] << ",";
  md << " not among them: " << c.rank_histogram[0] << ". A true segment shows the query at least "
     << opt.true_segment_share << " × the points of the segment that shows it most.";
  if (!t.top_vote_share.empty())
    md << " Votes: the top candidate holds a median " << median(t.top_vote_share) << " of the votes, spread over a median "
       << median(t.voted_segments) << " segments.";
  md << "\n\nMedian milliseconds per positive: " << (t.ms_total.empty() ? 0.0 : median(t.ms_total)) << " in all, "
     << (t.ms_excluding_features.empty() ? 0.0 : median(t.ms_excluding_features))
     << " excluding features (one core): retrieval " << median_or_zero(t.ms_retrieval) << ", matching "
     << median_or_zero(t.ms_matching) << ", RANSAC " << median_or_zero(t.ms_ransac) << "; registered positives "
     << median_or_zero(t.ms_registered) << ", missed " << median_or_zero(t.ms_missed)
     << ". Peak memory of the process that localized: " << std::setprecision(1)
     << double(t.peak_city_queries) / (1024.0 * 1024.0) << " MiB over the city's queries, "
     << double(peak_memory_bytes()) / (1024.0 * 1024.0) << " MiB with the foreign photos ("
     << (opt.stage == CityBenchmarkStage::kLocalize ? "a separate process that only localized"
                                                    : "the same process built the map: an upper bound")
     << ").\n\nPlots: retrieval_ranks.png (.svg), the rank of the true segment; error_curve.png (.svg), the "
     << "positives' cumulative position error.\n";
  return md.str();
}
}  // namespace

nlohmann::json run_city_benchmark(const fs::path& out, const CityBenchmarkOptions& opt,
                                  const std::function<void(const CityBenchmarkProgress&)>& progress,
                                  const std::function<void(const MapBuildProgress&)>& map_progress) {
  opt.validate();
  fs::create_directories(out);
  const fs::path city_dir = out / "city";

  // 1. The whole city; the roads of the map and those left out.
  write_or_check_city(city_dir, opt, progress);
  const CityMapSplit split = split_city(city_dir, out, opt);

  // 2. The map: every image of a placemark on a mapped road.
  const nlohmann::json build_summary = build_or_read_city_map(out, city_dir, opt, progress, map_progress);
  if (opt.stage == CityBenchmarkStage::kPrepare) return build_summary;

  // 3. Localize: synthetic queries (positives and negatives), then foreign photos.
  const CityLocalizationTally tally = localize_city_queries(out, city_dir, opt, split, progress);

  // 4. Report.
  const CityQueryCounts counts = count_city_queries(tally, opt);
  const nlohmann::json report = city_report_json(city_dir, opt, split, build_summary, tally, counts);
  // Both texts are made before either file is written: a bad build summary fails with neither file.
  const std::string markdown = city_report_markdown(report, opt, split, build_summary, tally, counts);
  write_file_atomic(out / "report.json", report.dump(2));
  write_file_atomic(out / "report.md", markdown);
  write_city_plots(out, tally, counts);
  return report;
}

void skip_absent_shared_data(CityBenchmarkOptions& o, std::ostream& log) {
  if (o.shared_data.empty() || fs::is_directory(o.shared_data)) return;
  log << "bench city: " << o.shared_data.string() << " is absent: no foreign photos\n";
  o.shared_data.clear();
}

void record_slurm_city_build(const fs::path& out_dir, MapBuildOptions& map) {
  if (map.executor != BuildExecutor::kSlurm) return;
  const fs::path out = fs::absolute(out_dir);
  std::vector<std::string> args = {"--images",
                                   (out / "city" / "images").string(),
                                   "--gps",
                                   (out / "map_gps.csv").string(),
                                   "--gps-subset",
                                   "--poses",
                                   "known",
                                   "--known-poses",
                                   (out / "city" / "sparse").string(),
                                   "--out",
                                   (out / "map").string(),
                                   "--min-placemarks",
                                   std::to_string(map.plan.min_placemarks),
                                   "--max-placemarks",
                                   std::to_string(map.plan.max_placemarks),
                                   "--overlap",
                                   std::to_string(map.plan.overlap)};
  if (map.segment_file.point_uncertainty) args.push_back("--point-uncertainty");
  if (map.fit_hash_blend) args.push_back(*map.fit_hash_blend ? "--fit-blend" : "--no-fit-blend");
  record_build_for_tasks(map, out / "map", args);
}

namespace {

// This process's arguments, from /proc/self/cmdline.
std::vector<std::string> own_arguments() {
  std::ifstream in("/proc/self/cmdline", std::ios::binary);
  const std::string cmdline((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<std::string> args;
  for (size_t start = 0; start < cmdline.size();) {
    const size_t end = cmdline.find('\0', start);
    args.push_back(cmdline.substr(start, end == std::string::npos ? std::string::npos : end - start));
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return args;
}

}  // namespace

int run_localize_stage_in_new_process(std::ostream& log) {
  std::vector<std::string> args = own_arguments();
  if (args.empty()) throw_error(ErrorCode::kInternal, "bench city: cannot read this process's command line");
  args.push_back("--stage");
  args.push_back("localize");
  std::vector<char*> argv;
  for (auto& x : args) argv.push_back(x.data());
  argv.push_back(nullptr);
  std::cout.flush();  // what this process printed comes before the new one's output
  log << "bench city: localizing in a fresh process (its peak memory goes into the report)\n";
  pid_t pid = 0;
  if (const int err = ::posix_spawn(&pid, "/proc/self/exe", nullptr, nullptr, argv.data(), environ))
    throw_error(ErrorCode::kInternal, "bench city: cannot start the localization process: ", std::strerror(err));
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0)
    if (errno != EINTR) throw_error(ErrorCode::kInternal, "bench city: waitpid: ", std::strerror(errno));
  if (!WIFEXITED(status))
    throw_error(ErrorCode::kInternal, "bench city: the localization process died from signal ", WTERMSIG(status));
  return WEXITSTATUS(status);
}

void CityBenchmarkProgressPrinter::operator()(const CityBenchmarkProgress& p) {
  if (!terminal_ && p.stage == last_stage_ && p.done != p.total && p.done % (p.stage == "render" ? 100 : 20) != 0)
    return;
  last_stage_ = p.stage;
  out_ << (terminal_ ? "\r" : "") << "bench city: " << p.stage << " " << p.done << "/" << p.total
       << (terminal_ && p.done != p.total ? "   " : "\n") << std::flush;
}

void CityBenchmarkProgressPrinter::operator()(const MapBuildProgress& p) {
  if (p.stage != "segments" || (p.done != p.total && !terminal_)) return;
  out_ << (terminal_ ? "\r" : "") << "bench city: map segments " << p.done << "/" << p.total
       << (terminal_ && p.done != p.total ? "   " : "\n") << std::flush;
}

}  // namespace visloc
