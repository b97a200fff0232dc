#include "visloc/eval/city_benchmark.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <set>
#include <sstream>

#include "visloc/eval/evaluation.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map/map.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace fs = std::filesystem;

void CityBenchmarkOptions::validate() const {
  city.validate();
  if (leave_out_roads < 0) throw_error(ErrorCode::kInvalidArgument, "bench city: leave_out_roads must be >= 0");
  if (!(positive_max_distance_m > 0) || !(negative_min_distance_m >= positive_max_distance_m))
    throw_error(ErrorCode::kInvalidArgument,
                "bench city: need 0 < positive_max_distance_m <= negative_min_distance_m");
  if (!(wrong_position_m > 0) || !(wrong_rotation_deg > 0))
    throw_error(ErrorCode::kInvalidArgument, "bench city: wrong-pose thresholds must be positive");
  if (!shared_data.empty() && !fs::is_directory(shared_data))
    throw_error(ErrorCode::kNotFound, shared_data.string(), ": no such shared data directory");
}

namespace {

struct CityPlacemark {
  int id = 0, road = 0;
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
      std::string e = it->path().extension().string();
      std::transform(e.begin(), e.end(), e.begin(), ::tolower);
      if (e == ".jpg" || e == ".jpeg" || e == ".png") files.push_back(it->path());
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

nlohmann::json pose_summary(const std::vector<double>& errors_m, size_t count, size_t registered, size_t wrong) {
  return {{"queries", count},
          {"registered", registered},
          {"wrong_poses", wrong},
          {"misses", count - registered},
          {"median_position_error_m", errors_m.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(errors_m))}};
}

}  // namespace

nlohmann::json run_city_benchmark(const fs::path& out, const CityBenchmarkOptions& opt,
                                  const std::function<void(const CityBenchmarkProgress&)>& progress,
                                  const std::function<void(const MapBuildProgress&)>& map_progress) {
  opt.validate();
  fs::create_directories(out);
  const fs::path city_dir = out / "city";

  // 1. The whole city (resumes: images already written are kept).
  if (!fs::exists(city_dir / "queries" / "truth.txt") || !fs::exists(city_dir / "city.json")) {
    if (progress) progress({"render", 0, 1});
    synth::CityOptions city = opt.city;
    city.resume = fs::exists(city_dir);
    synth::write_city(city, city_dir);
    if (progress) progress({"render", 1, 1});
  }
  const std::vector<CityPlacemark> placemarks = read_city_placemarks(city_dir / "city.json");
  int max_road = 0;
  for (const auto& p : placemarks) max_road = std::max(max_road, p.road);
  std::set<int> left_out;
  for (int r = max_road; r > max_road - opt.leave_out_roads && r >= 0; --r) left_out.insert(r);
  if (static_cast<int>(left_out.size()) > max_road)
    throw_error(ErrorCode::kInvalidArgument, "bench city: the city has ", max_road + 1, " roads; leaving out ",
                opt.leave_out_roads, " would map none");

  // 2. The map: every image of a placemark on a mapped road.
  std::map<int, const CityPlacemark*> placemark_by_id;
  for (const auto& p : placemarks) placemark_by_id[p.id] = &p;
  std::vector<GpsRecord> mapped;
  for (const auto& r : read_gps_csv(city_dir / "gps.csv")) {
    if (!r.placemark) throw_error(ErrorCode::kFormat, (city_dir / "gps.csv").string(), ": no placemark column");
    auto it = placemark_by_id.find(*r.placemark);
    if (it == placemark_by_id.end())
      throw_error(ErrorCode::kFormat, (city_dir / "gps.csv").string(), ": placemark ", *r.placemark, " of ", r.image,
                  " is not in city.json");
    if (!left_out.count(it->second->road)) mapped.push_back(r);
  }
  write_gps_csv(out / "map_gps.csv", mapped);
  std::vector<Eigen::Vector3d> mapped_centres;
  for (const auto& p : placemarks)
    if (!left_out.count(p.road)) mapped_centres.push_back(p.enu);

  MapBuildOptions mb = opt.map;
  mb.images_dir = city_dir / "images";
  mb.gps_csv = out / "map_gps.csv";
  mb.poses = PoseSource::kKnown;
  mb.known_poses = city_dir / "sparse";
  if (progress) progress({"map", 0, 1});
  const MapBuildResult built = build_map(out / "map", mb, map_progress);
  if (built.failed() == built.segments.size())
    throw_error(ErrorCode::kExternalTool, "bench city: no segment of the map could be built (logs under ",
                (out / "map" / "work").string(), ")");
  if (progress) progress({"map", 1, 1});

  // Segments of each placemark (for retrieval scoring).
  std::map<int, std::vector<int>> segments_of_placemark;
  {
    const MapManifest man = read_manifest(out / "map");
    std::set<int> built_ids;
    for (const auto& s : man.segments) built_ids.insert(static_cast<int>(s.id));
    const auto& plan = man.source.at("segment_placemarks");
    for (size_t s = 0; s < plan.size(); ++s)
      if (built_ids.count(static_cast<int>(s)))
        for (int pm : plan[s].get<std::vector<int>>()) segments_of_placemark[pm].push_back(static_cast<int>(s));
  }

  // 3. Localize: synthetic queries (positives and negatives), then foreign photos.
  const Localizer localizer(out / "map", opt.localizer);
  std::map<std::string, PinholeCamera> intrinsics;
  for (const auto& c : read_intrinsics_list(city_dir / "queries" / "intrinsics.txt")) intrinsics[c.name] = c.camera;
  const std::vector<NamedPose> truth = read_pose_list(city_dir / "queries" / "truth.txt");
  const std::vector<fs::path> foreign = foreign_photos(opt.shared_data, opt.foreign_photos);
  const size_t total = truth.size() + foreign.size();

  struct Kind {
    size_t count = 0, registered = 0, wrong = 0;
    std::vector<double> errors_m;
  } positives, negatives, between, foreigners;
  std::vector<double> ms_excluding_features, ms_total;
  size_t retrieval_hits = 0;
  std::vector<double> true_ranks;
  nlohmann::json per_query = nlohmann::json::array();
  size_t done = 0;
  for (const NamedPose& q : truth) {
    auto cam = intrinsics.find(q.name);
    const LocalizationResult r = localizer.localize_file(
        city_dir / "queries" / "images" / q.name,
        cam == intrinsics.end() ? std::nullopt : std::optional<PinholeCamera>(cam->second));
    const Eigen::Vector3d c = q.cam_from_world.center();
    double nearest = std::numeric_limits<double>::infinity();
    int nearest_pm = -1;
    for (const auto& p : placemarks) {
      if (left_out.count(p.road)) continue;
      const double d = (p.enu - c).head<2>().norm();
      if (d < nearest) {
        nearest = d;
        nearest_pm = p.id;
      }
    }
    const std::string kind = nearest <= opt.positive_max_distance_m   ? "positive"
                             : nearest >= opt.negative_min_distance_m ? "negative"
                                                                      : "between";
    Kind& k = kind == "positive" ? positives : kind == "negative" ? negatives : between;
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
    if (kind == "positive") {
      const auto& truth_segments = segments_of_placemark[nearest_pm];
      for (size_t i = 0; i < r.candidates.size() && rank < 0; ++i)
        if (std::find(truth_segments.begin(), truth_segments.end(), r.candidates[i]) != truth_segments.end())
          rank = static_cast<int>(i) + 1;
      if (rank > 0) {
        ++retrieval_hits;
        true_ranks.push_back(rank);
      }
      ms_excluding_features.push_back(r.times.total - r.times.features);
      ms_total.push_back(r.times.total);
    }
    per_query.push_back({{"image", q.name}, {"kind", kind}, {"distance_to_map_m", nearest},
                         {"registered", r.registered}, {"wrong", wrong}, {"inliers", r.inliers},
                         {"position_error_m", pos_err}, {"rotation_error_deg", rot_err},
                         {"true_segment_rank", rank}, {"error", r.error}});
    if (progress) progress({"localize", ++done, total});
  }
  for (const fs::path& photo : foreign) {
    const LocalizationResult r = localizer.localize_file(photo);
    ++foreigners.count;
    if (r.registered) {
      ++foreigners.registered;
      ++foreigners.wrong;
    }
    per_query.push_back({{"image", photo.string()}, {"kind", "foreign"}, {"registered", r.registered},
                         {"wrong", r.registered}, {"inliers", r.inliers}, {"error", r.error}});
    if (progress) progress({"localize", ++done, total});
  }

  // 4. Report.
  size_t map_bytes = 0, points = 0;
  for (const auto& s : built.segments) {
    map_bytes += s.file_bytes;
    points += s.points;
  }
  const size_t wrong_total = positives.wrong + negatives.wrong + foreigners.wrong;
  nlohmann::json report = {
      {"city", {{"road_length_m", nlohmann::json::parse(read_file(city_dir / "city.json")).at("counts").at("road_length_m")},
                {"roads", max_road + 1},
                {"roads_left_out", std::vector<int>(left_out.begin(), left_out.end())},
                {"placemarks_mapped", mapped_centres.size()},
                {"images_mapped", mapped.size()}}},
      {"map", {{"segments", built.segments.size()}, {"segments_failed", built.failed()}, {"points", points},
               {"segment_bytes", map_bytes}, {"build_seconds_this_run", built.seconds_total}}},
      {"positives", pose_summary(positives.errors_m, positives.count, positives.registered, positives.wrong)},
      {"negatives_unmapped_streets",
       pose_summary(negatives.errors_m, negatives.count, negatives.registered, negatives.wrong)},
      {"between_not_scored", {{"queries", between.count}, {"registered", between.registered}}},
      {"foreign_photos", {{"queries", foreigners.count}, {"registered", foreigners.registered}}},
      {"wrong_poses", wrong_total},
      {"wrong_pose_rule", {{"position_m", opt.wrong_position_m}, {"rotation_deg", opt.wrong_rotation_deg}}},
      {"retrieval",
       {{"positives_with_true_segment_among_candidates", retrieval_hits},
        {"fraction", positives.count ? double(retrieval_hits) / double(positives.count) : 0.0},
        {"median_rank_of_true_segment", true_ranks.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(true_ranks))}}},
      {"median_ms_per_positive", {{"total", ms_total.empty() ? 0.0 : median(ms_total)},
                                  {"excluding_features", ms_excluding_features.empty() ? 0.0 : median(ms_excluding_features)}}},
      {"per_query", per_query}};
  write_file_atomic(out / "report.json", report.dump(2));

  std::ostringstream md;
  md << std::fixed << std::setprecision(3);
  md << "# City benchmark\n\n"
     << "City: " << report["city"]["road_length_m"] << " m of street, " << (max_road + 1) << " roads, "
     << left_out.size() << " left out of the map; map: " << built.segments.size() << " segments ("
     << built.failed() << " failed), " << points << " points.\n\n"
     << "| queries | count | registered | wrong poses | misses | median position error (m) |\n|---|---|---|---|---|---|\n";
  auto row = [&](const char* name, const Kind& k) {
    md << "| " << name << " | " << k.count << " | " << k.registered << " | " << k.wrong << " | "
       << (k.count - k.registered) << " | " << (k.errors_m.empty() ? std::string("-") : std::to_string(median(k.errors_m)))
       << " |\n";
  };
  row("positives (near mapped streets)", positives);
  row("negatives (unmapped streets)", negatives);
  md << "| foreign photos | " << foreigners.count << " | " << foreigners.registered << " | " << foreigners.wrong
     << " | " << (foreigners.count - foreigners.registered) << " | - |\n\n"
     << "Wrong poses in all: " << wrong_total << " (a wrong pose: registered more than " << opt.wrong_position_m
     << " m or " << opt.wrong_rotation_deg << "° from the truth, or any registered foreign photo). "
     << between.count << " queries between " << opt.positive_max_distance_m << " and " << opt.negative_min_distance_m
     << " m from the map are not scored. A negative registered within the thresholds of its true pose (it sees "
     << "mapped facades) is not a wrong pose: " << (negatives.registered - negatives.wrong) << " here.\n\n"
     << "Retrieval: the true segment is among the candidates for " << retrieval_hits << "/" << positives.count
     << " positives";
  if (!true_ranks.empty()) md << " (median rank " << median(true_ranks) << ")";
  md << ".\n\nMedian milliseconds per positive: " << (ms_total.empty() ? 0.0 : median(ms_total))
     << " in all, " << (ms_excluding_features.empty() ? 0.0 : median(ms_excluding_features))
     << " excluding features.\n";
  write_file_atomic(out / "report.md", md.str());
  return report;
}

}  // namespace visloc
