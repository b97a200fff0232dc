#include "visloc/eval/segment_study.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <map>
#include <ostream>
#include <set>
#include <sstream>

#include "visloc/eval/evaluation.h"
#include "visloc/eval/plot.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;

void SegmentStudyOptions::validate() const {
  if (placemarks.empty() || overlaps.empty())
    throw_error(ErrorCode::kInvalidArgument, "bench segments: need at least one placemark count and one overlap");
  for (int p : placemarks)
    if (p < 1) throw_error(ErrorCode::kInvalidArgument, "bench segments: placemarks per segment ", p, " must be >= 1");
  for (int o : overlaps)
    if (o < 0) throw_error(ErrorCode::kInvalidArgument, "bench segments: overlap ", o, " must be >= 0");
  if (!(wrong_position_m > 0) || !(wrong_rotation_deg > 0))
    throw_error(ErrorCode::kInvalidArgument, "bench segments: wrong-pose thresholds must be positive");
  if (std::set<int>(placemarks.begin(), placemarks.end()).size() != placemarks.size() ||
      std::set<int>(overlaps.begin(), overlaps.end()).size() != overlaps.size())
    throw_error(ErrorCode::kInvalidArgument, "bench segments: a placemark count or overlap is given twice");
  if (*std::min_element(overlaps.begin(), overlaps.end()) >= *std::max_element(placemarks.begin(), placemarks.end()))
    throw_error(ErrorCode::kInvalidArgument,
                "bench segments: no configuration has an overlap smaller than its placemarks per segment");
  localizer.validate();
}

StudyDataset city_study_dataset(const fs::path& dir) {
  const fs::path report_path = dir / "report.json";
  if (!fs::exists(report_path))
    throw_error(ErrorCode::kNotFound, report_path.string(),
                ": no city benchmark report; run 'visloc bench city --out ", dir.string(), "' first");
  StudyDataset d;
  d.name = "city";
  d.images_dir = dir / "city" / "images";
  d.gps_csv = dir / "map_gps.csv";
  d.known_poses = dir / "city" / "sparse";
  const CamerasByName cameras = read_intrinsics_by_name(dir / "city" / "queries" / "intrinsics.txt");
  std::map<std::string, CameraPose> truth;
  for (const auto& p : read_pose_list(dir / "city" / "queries" / "truth.txt")) truth[p.name] = p.cam_from_world;
  nlohmann::json report;
  try {
    report = nlohmann::json::parse(read_file(report_path));
    for (const auto& q : report.at("per_query")) {
      const std::string kind = q.at("kind").get<std::string>();
      if (kind != "positive" && kind != "negative") continue;  // foreign photos: not per segment layout
      const std::string name = q.at("image").get<std::string>();
      auto c = cameras.find(name);
      auto t = truth.find(name);
      if (c == cameras.end() || t == truth.end())
        throw_error(ErrorCode::kFormat, report_path.string(), ": query ", name, " has no intrinsics or truth");
      d.queries.push_back({dir / "city" / "queries" / "images" / name, c->second,
                           std::optional<CameraPose>(t->second), kind});
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw_error(ErrorCode::kFormat, report_path.string(), ": bad report: ", e.what());
  }
  if (d.queries.empty()) throw_error(ErrorCode::kFormat, report_path.string(), ": no positives or negatives");
  return d;
}

StudyDataset kitti_study_dataset(const fs::path& kitti, const fs::path& work_dir) {
  for (const char* f : {"gps.csv", "truth.txt", "calib.txt", "queries.txt"})
    if (!fs::exists(kitti / f)) throw_error(ErrorCode::kNotFound, (kitti / f).string(), ": missing (KITTI data set)");
  // P0 of calib.txt: f 0 cx 0 / 0 f cy 0 / 0 0 1 0.
  double f = 0, cx = 0, cy = 0;
  {
    std::istringstream in(read_file(kitti / "calib.txt"));
    std::string line;
    while (std::getline(in, line))
      if (line.rfind("P0:", 0) == 0) {
        std::istringstream ls(line.substr(3));
        double p[12];
        for (double& v : p)
          if (!(ls >> v)) throw_error(ErrorCode::kFormat, (kitti / "calib.txt").string(), ": P0 needs 12 numbers");
        f = p[0];
        cx = p[2];
        cy = p[6];
      }
    if (!(f > 0)) throw_error(ErrorCode::kFormat, (kitti / "calib.txt").string(), ": no P0 line");
  }
  const std::vector<std::string> query_names = read_name_list(kitti / "queries.txt");
  const std::set<std::string> is_query(query_names.begin(), query_names.end());
  std::vector<GpsRecord> map_records;
  for (const auto& r : read_gps_csv(kitti / "gps.csv"))
    if (!is_query.count(r.image)) map_records.push_back(r);
  if (map_records.empty()) throw_error(ErrorCode::kFormat, (kitti / "gps.csv").string(), ": no map frames");
  // The image size: from the first map image.
  const ImageMetadata meta = read_image_metadata(kitti / "images" / map_records.front().image);
  fs::create_directories(work_dir);
  StudyDataset d;
  d.name = "kitti";
  d.images_dir = kitti / "images";
  d.gps_csv = work_dir / "map_gps.csv";
  write_gps_csv(d.gps_csv, map_records);
  d.known_poses = kitti / "truth.txt";
  d.known_intrinsics = work_dir / "intrinsics.txt";
  std::ostringstream intr;
  intr << std::setprecision(10) << "* PINHOLE " << meta.width << " " << meta.height << " " << f << " " << f << " "
       << cx << " " << cy << "\n";
  write_file_atomic(d.known_intrinsics, intr.str());
  PinholeCamera cam = PinholeCamera::centered(meta.width, meta.height, f);
  cam.cx = cx;
  cam.cy = cy;
  std::map<std::string, CameraPose> truth;
  for (const auto& p : read_pose_list(kitti / "truth.txt")) truth[p.name] = p.cam_from_world;
  for (const auto& name : query_names) {
    auto t = truth.find(name);
    if (t == truth.end()) throw_error(ErrorCode::kFormat, (kitti / "truth.txt").string(), ": no pose for ", name);
    d.queries.push_back({kitti / "images" / name, cam, std::optional<CameraPose>(t->second), "positive"});
  }
  return d;
}

namespace {

// `dst` becomes a hard link to `src`, or, where links are impossible (another
// file system), a copy written under a temporary name and renamed: never a
// partial file under the final name.
void link_or_copy(const fs::path& src, const fs::path& dst) {
  std::error_code ec;
  fs::create_hard_link(src, dst, ec);
  if (!ec || fs::exists(dst)) return;
  const fs::path tmp = dst.string() + ".copying";
  fs::copy_file(src, tmp, fs::copy_options::overwrite_existing, ec);
  if (!ec) fs::rename(tmp, dst, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throw_error(ErrorCode::kIo, "cannot link or copy ", src.string(), " to ", dst.string(), ": ", ec.message());
  }
}

// Links every regular file of `from` missing in `to`.
void link_files(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  if (!fs::is_directory(from)) return;
  fs::create_directories(to);
  for (fs::directory_iterator it(from, ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_regular_file() || it->path().extension() == ".copying") continue;
    const fs::path dst = to / it->path().filename();
    if (!fs::exists(dst)) link_or_copy(it->path(), dst);
  }
}

// What a configuration's result depends on besides P and O: a result.json
// made under another fingerprint is not reused.
nlohmann::json study_fingerprint(const StudyDataset& d, const SegmentStudyOptions& o) {
  nlohmann::json queries = nlohmann::json::array();
  for (const auto& q : d.queries) queries.push_back(q.image.filename().string() + ":" + q.kind);
  nlohmann::json fingerprint = {{"dataset", d.name},
                                {"images", fs::absolute(d.images_dir).string()},
                                {"gps", fs::absolute(d.gps_csv).string()},
                                {"gps_bytes", fs::exists(d.gps_csv) ? fs::file_size(d.gps_csv) : 0},
                                {"queries", queries},
                                {"setting", to_string(o.localizer.setting)},
                                {"top_images", o.localizer.top_images},
                                {"max_segments", o.localizer.max_segments},
                                {"fallback_segments", o.localizer.fallback_segments},
                                {"accept_inliers", o.localizer.accept_inliers},
                                {"min_inliers", o.localizer.ransac.min_inliers},
                                {"threshold_px", o.localizer.ransac.threshold_px},
                                {"sift", nlohmann::json::parse(o.map.sift.to_json())},
                                {"wrong_position_m", o.wrong_position_m},
                                {"wrong_rotation_deg", o.wrong_rotation_deg}};
  // Results of 16-byte maps, made before the choice existed, stay reusable.
  if (o.map.pq.subvectors != kPqSubvectors) fingerprint["pq_bytes"] = o.map.pq.subvectors;
  // Likewise the product quantizer's.
  if (o.map.pq.quantizer != PqQuantizer::kProduct) {
    fingerprint["pq_quantizer"] = to_string(o.map.pq.quantizer);
    fingerprint["pq_residual_splits"] = o.map.pq.residual_splits;
    // Studies made before the beam was an option used FAISS's default, 5.
    if (o.map.pq.residual_beam != kFaissResidualBeam) fingerprint["pq_residual_beam"] = o.map.pq.residual_beam;
    // And FAISS's progressive k-means.
    if (!o.map.pq.residual_progressive_dim) fingerprint["pq_residual_kmeans"] = "plain";
  }
  return fingerprint;
}

const char* const kRowKeys[] = {"placemarks_per_segment", "overlap", "segments", "points", "segment_bytes",
                                "retrieval_bytes", "build_seconds", "positives", "registered",
                                "registered_fraction", "median_position_error_m", "negatives",
                                "negatives_registered", "wrong_poses", "median_ms_per_query_excluding_features"};

std::string config_name(int p, int o) { return "p" + std::to_string(p) + "_o" + std::to_string(o); }

using StudyProgressCallback = std::function<void(const SegmentStudyProgress&)>;

// At most max_queries of the dataset's queries, evenly strided (0: all).
StudyDataset study_queries(const StudyDataset& all_queries, const SegmentStudyOptions& opt) {
  StudyDataset dataset = all_queries;
  if (opt.max_queries > 0 && dataset.queries.size() > opt.max_queries) {
    dataset.queries.clear();
    const size_t n = all_queries.queries.size();
    for (size_t i = 0; i < opt.max_queries; ++i) dataset.queries.push_back(all_queries.queries[i * n / opt.max_queries]);
  }
  return dataset;
}

// The study's fingerprint: a directory made with other inputs or options
// is refused (its results and shared features would not apply). Writes it
// into dir, with the directory of the features the configurations share.
void claim_study_dir(const fs::path& dir, const StudyDataset& dataset, const SegmentStudyOptions& opt) {
  const fs::path fingerprint_path = dir / "study.json";
  const nlohmann::json fingerprint = study_fingerprint(dataset, opt);
  if (fs::exists(fingerprint_path)) {
    const auto earlier = nlohmann::json::parse(read_file(fingerprint_path), nullptr, false);
    if (earlier != fingerprint)
      throw_error(ErrorCode::kInvalidArgument, fingerprint_path.string(),
                  ": this study was made with other inputs or options; use another --out (or delete ", dir.string(),
                  ")");
  }
  fs::create_directories(dir / "shared" / "features");
  write_file_atomic(fingerprint_path, fingerprint.dump(2));
}

// The result of configuration (p, o) of an earlier run, if it is whole and for this configuration.
std::optional<nlohmann::json> earlier_result(const fs::path& result_path, int p, int o) {
  if (fs::exists(result_path)) {
    try {
      nlohmann::json row = nlohmann::json::parse(read_file(result_path));
      for (const char* key : kRowKeys) (void)row.at(key);
      if (row.at("placemarks_per_segment").get<int>() == p && row.at("overlap").get<int>() == o) return row;
    } catch (const std::exception&) {
      // A damaged result: run the configuration again.
    }
  }
  return std::nullopt;
}

// What building a configuration's map gave.
struct StudyMapBuild {
  size_t segments = 0, segments_failed = 0, points = 0;
  uint64_t segment_bytes = 0, retrieval_bytes = 0;
  double build_seconds = 0;
};

// Builds configuration (p, o)'s map in map_dir (features and codebook shared
// with the configurations before, through the study's shared/ directory).
StudyMapBuild build_study_map(const fs::path& map_dir, const fs::path& study_dir, const StudyDataset& dataset,
                              const SegmentStudyOptions& opt, int p, int o, const StudyProgressCallback& progress) {
  const fs::path shared_features = study_dir / "shared" / "features";
  const fs::path shared_codebook = study_dir / "shared" / "pq_codebook.vlpq";
  link_files(shared_features, map_dir / "work" / "features");
  fs::create_directories(map_dir);
  if (fs::exists(shared_codebook) && !fs::exists(map_dir / "pq_codebook.vlpq"))
    link_or_copy(shared_codebook, map_dir / "pq_codebook.vlpq");
  MapBuildOptions mb = opt.map;
  mb.pq_code_bytes = opt.map.pq.subvectors;  // the study's choice (its fingerprint), never a leftover codebook's
  mb.pq_quantizer = opt.map.pq.quantizer;    // likewise
  mb.images_dir = dataset.images_dir;
  mb.gps_csv = dataset.gps_csv;
  mb.gps_lists_subset = true;  // e.g. KITTI's even frames of a folder of all frames
  mb.poses = PoseSource::kKnown;
  mb.known_poses = dataset.known_poses;
  mb.known_intrinsics = dataset.known_intrinsics;
  mb.plan.min_placemarks = mb.plan.max_placemarks = p;
  mb.plan.overlap = o;
  if (progress) progress({dataset.name, p, o, "build", 0, 1});
  const MapBuildResult built = build_map(map_dir, mb);
  if (built.failed() == built.segments.size())
    throw_error(ErrorCode::kExternalTool, "bench segments: no segment of ", map_dir.string(),
                " could be built (logs under its work/)");
  link_files(map_dir / "work" / "features", shared_features);
  if (!fs::exists(shared_codebook)) link_or_copy(map_dir / "pq_codebook.vlpq", shared_codebook);
  StudyMapBuild b;
  b.segments = built.segments.size();
  b.segments_failed = built.failed();
  // Build time: the segments' own seconds summed (reused ones included;
  // independent of --jobs) and the retrieval index.
  double segment_seconds = 0;
  for (const auto& s : built.segments) segment_seconds += s.seconds;
  for (const auto& s : built.segments) {
    b.segment_bytes += s.file_bytes;
    b.points += s.points;
  }
  std::error_code ec;
  for (fs::recursive_directory_iterator it(map_dir / "retrieval", ec), end; !ec && it != end; it.increment(ec))
    if (it->is_regular_file()) b.retrieval_bytes += it->file_size();
  b.build_seconds = segment_seconds + built.seconds_retrieval;
  return b;
}

// What localizing the queries against a configuration's map gave.
struct StudyLocalization {
  size_t positives = 0, negatives = 0, registered = 0, wrong = 0, negatives_registered = 0;
  std::vector<double> errors, ms;  // positives' position errors; every query's milliseconds
};

StudyLocalization localize_study_queries(const fs::path& map_dir, const StudyDataset& dataset,
                                         const std::vector<FeatureSet>& query_features,
                                         const SegmentStudyOptions& opt, int p, int o,
                                         const StudyProgressCallback& progress) {
  const Localizer localizer(map_dir, opt.localizer);
  StudyLocalization l;
  for (size_t i = 0; i < dataset.queries.size(); ++i) {
    const StudyQuery& q = dataset.queries[i];
    const LocalizationResult r = localizer.localize_features(query_features[i], q.camera);
    l.ms.push_back(r.times.total);
    const bool positive = q.kind == "positive";
    positive ? ++l.positives : ++l.negatives;
    if (r.registered) {
      bool is_wrong = !q.truth;
      if (q.truth) {
        const double pe = position_error(r.cam_from_segment, *q.truth);
        const double re = rotation_error_deg(r.cam_from_segment, *q.truth);
        is_wrong = pe > opt.wrong_position_m || re > opt.wrong_rotation_deg;
        if (positive) l.errors.push_back(pe);
      }
      if (positive) ++l.registered;
      else ++l.negatives_registered;
      l.wrong += is_wrong;
    }
    if (progress && (i % 20 == 19 || i + 1 == dataset.queries.size()))
      progress({dataset.name, p, o, "localize", i + 1, dataset.queries.size()});
  }
  return l;
}

// A configuration's result.json.
nlohmann::json study_row(const std::string& dataset, int p, int o, const StudyMapBuild& b, const StudyLocalization& l) {
  return {{"dataset", dataset},
          {"placemarks_per_segment", p},
          {"overlap", o},
          {"segments", b.segments},
          {"segments_failed", b.segments_failed},
          {"points", b.points},
          {"segment_bytes", b.segment_bytes},
          {"retrieval_bytes", b.retrieval_bytes},
          {"build_seconds", b.build_seconds},
          {"positives", l.positives},
          {"registered", l.registered},
          {"registered_fraction", l.positives ? double(l.registered) / double(l.positives) : 0.0},
          {"median_position_error_m", l.errors.empty() ? nlohmann::json(nullptr) : nlohmann::json(median(l.errors))},
          {"negatives", l.negatives},
          {"negatives_registered", l.negatives_registered},
          {"wrong_poses", l.wrong},
          {"median_ms_per_query_excluding_features", l.ms.empty() ? 0.0 : median(l.ms)}};
}

}  // namespace

nlohmann::json run_segment_study(const fs::path& out, const StudyDataset& all_queries, const SegmentStudyOptions& opt,
                                 const std::function<void(const SegmentStudyProgress&)>& progress) {
  opt.validate();
  const StudyDataset dataset = study_queries(all_queries, opt);
  const fs::path dir = out / dataset.name;
  claim_study_dir(dir, dataset, opt);

  std::vector<std::pair<int, int>> configs;
  for (int p : opt.placemarks)
    for (int o : opt.overlaps)
      if (o < p) configs.emplace_back(p, o);

  // Query features, once (the localizer's extractor settings).
  std::vector<FeatureSet> query_features;
  auto ensure_query_features = [&] {
    if (!query_features.empty()) return;
    const SiftExtractor sift(opt.localizer.sift);
    for (size_t i = 0; i < dataset.queries.size(); ++i) {
      query_features.push_back(sift.extract_file(dataset.queries[i].image));
      if (progress) progress({dataset.name, 0, 0, "features", i + 1, dataset.queries.size()});
    }
  };

  nlohmann::json rows = nlohmann::json::array();
  for (const auto& [p, o] : configs) {
    const fs::path cdir = dir / config_name(p, o);
    const fs::path result_path = cdir / "result.json";
    if (std::optional<nlohmann::json> row = earlier_result(result_path, p, o)) {
      rows.push_back(std::move(*row));
      continue;
    }
    const fs::path map_dir = cdir / "map";
    const StudyMapBuild built = build_study_map(map_dir, dir, dataset, opt, p, o, progress);
    ensure_query_features();
    const StudyLocalization localized = localize_study_queries(map_dir, dataset, query_features, opt, p, o, progress);
    const nlohmann::json row = study_row(dataset.name, p, o, built, localized);
    write_file_atomic(result_path, row.dump(2));
    std::error_code ec;
    if (!opt.keep_maps) fs::remove_all(map_dir, ec);
    if (progress) progress({dataset.name, p, o, "done", 1, 1});
    rows.push_back(row);
  }
  return rows;
}

nlohmann::json collect_segment_study_rows(const fs::path& out, const std::string& dataset) {
  std::vector<nlohmann::json> rows;
  std::error_code ec;
  for (fs::directory_iterator it(out / dataset, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path result = it->path() / "result.json";
    if (!fs::is_regular_file(result)) continue;
    try {
      nlohmann::json row = nlohmann::json::parse(read_file(result));
      for (const char* key : kRowKeys) (void)row.at(key);
      if (it->path().filename() != config_name(row.at("placemarks_per_segment").get<int>(), row.at("overlap").get<int>()))
        continue;
      rows.push_back(std::move(row));
    } catch (const std::exception&) {
      // Damaged: left out (run_segment_study measures it again).
    }
  }
  std::sort(rows.begin(), rows.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    return std::make_pair(a["placemarks_per_segment"].get<int>(), a["overlap"].get<int>()) <
           std::make_pair(b["placemarks_per_segment"].get<int>(), b["overlap"].get<int>());
  });
  return nlohmann::json(rows);
}

void write_segment_study_report(const fs::path& out,
                                const std::vector<std::pair<std::string, nlohmann::json>>& rows_by_dataset) {
  std::ostringstream md;
  md << std::fixed;
  md << "# Segment design study (the paper's GSV model design)\n\n"
     << "Each map holds the same images, cut into segments of P placemarks that share O placemarks with their "
        "neighbours. Build seconds: the segments' seconds summed (as if built one at a time) plus the retrieval "
        "index; SIFT features and the PQ codebook are shared by all configurations and not counted. Milliseconds: median per query, excluding features, one core.\n";
  for (const auto& [name, rows] : rows_by_dataset) {
    md << "\n## " << name << "\n\n"
       << "| P | O | segments | registered | median error (m) | wrong poses | negatives registered | points | "
          "segments + retrieval MB | build s | ms/query |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    double max_mb = 0;
    std::set<int> overlaps;
    int p_min = 1 << 30, p_max = 0;
    for (const auto& r : rows) {
      const double mb = r["segment_bytes"].get<double>() / 1e6;
      max_mb = std::max(max_mb, mb);
      overlaps.insert(r["overlap"].get<int>());
      p_min = std::min(p_min, r["placemarks_per_segment"].get<int>());
      p_max = std::max(p_max, r["placemarks_per_segment"].get<int>());
      md << "| " << r["placemarks_per_segment"] << " | " << r["overlap"] << " | " << r["segments"] << " | "
         << r["registered"] << "/" << r["positives"] << " (" << std::setprecision(1)
         << 100.0 * r["registered_fraction"].get<double>() << "%) | " << std::setprecision(3)
         << (r["median_position_error_m"].is_null() ? std::string("-")
                                                    : Plot::fmt(r["median_position_error_m"].get<double>()))
         << " | " << r["wrong_poses"] << " | " << r["negatives_registered"] << "/" << r["negatives"] << " | "
         << r["points"] << " | " << std::setprecision(1) << mb << " + "
         << r["retrieval_bytes"].get<double>() / 1e6 << " | " << std::setprecision(0)
         << r["build_seconds"].get<double>() << " | " << std::setprecision(1)
         << r["median_ms_per_query_excluding_features"].get<double>() << " |\n";
    }
    if (rows.empty()) continue;
    md << "\n![" << name << "](segments_" << name << "_registration.svg) ![" << name << "](segments_" << name
       << "_bytes.svg)\n";
    // Plots: a line per overlap over P.
    static const char* colours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};
    static const cv::Scalar bgr[] = {{180, 119, 31}, {40, 39, 214}, {44, 160, 44}, {189, 103, 148}, {14, 127, 255},
                                     {75, 86, 140}};
    const double x0 = p_min == p_max ? p_min - 1 : p_min, x1 = p_min == p_max ? p_max + 1 : p_max;
    Plot reg(name + ": registered positives by segment size", "placemarks per segment", "registered fraction", x0,
             x1, 0, 1);
    Plot bytes(name + ": segment bytes by segment size", "placemarks per segment", "segment MB", x0, x1, 0,
               max_mb > 0 ? max_mb * 1.1 : 1);
    int k = 0;
    for (int o : overlaps) {
      std::vector<std::pair<double, const nlohmann::json*>> pts;
      for (const auto& r : rows)
        if (r["overlap"].get<int>() == o) pts.emplace_back(r["placemarks_per_segment"].get<double>(), &r);
      std::sort(pts.begin(), pts.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
      const char* c = colours[k % 6];
      const cv::Scalar b = bgr[k % 6];
      for (size_t i = 0; i < pts.size(); ++i) {
        const double y = (*pts[i].second)["registered_fraction"].get<double>();
        const double yb = (*pts[i].second)["segment_bytes"].get<double>() / 1e6;
        reg.point(pts[i].first, y, c, b);
        bytes.point(pts[i].first, yb, c, b);
        if (i > 0) {
          reg.line(pts[i - 1].first, (*pts[i - 1].second)["registered_fraction"].get<double>(), pts[i].first, y, c, b,
                   2);
          bytes.line(pts[i - 1].first, (*pts[i - 1].second)["segment_bytes"].get<double>() / 1e6, pts[i].first, yb,
                     c, b, 2);
        }
      }
      const double lx = x0 + 0.03 * (x1 - x0), ly = 0.95 - 0.06 * k, ymax = max_mb > 0 ? max_mb * 1.1 : 1;
      reg.point(lx, ly, c, b, 4);
      reg.label(lx, ly, "overlap " + std::to_string(o), 8, 4);
      bytes.point(lx, ymax * ly, c, b, 4);
      bytes.label(lx, ymax * ly, "overlap " + std::to_string(o), 8, 4);
      ++k;
    }
    reg.save(out / ("segments_" + name + "_registration"));
    bytes.save(out / ("segments_" + name + "_bytes"));
  }
  write_file_atomic(out / "report.md", md.str());
}

std::string run_segment_studies(const fs::path& out_dir, const fs::path& city_dir, const fs::path& kitti_dir,
                                const SegmentStudyOptions& options, std::ostream& log, bool tty) {
  if (city_dir.empty() && kitti_dir.empty())
    throw_error(ErrorCode::kInvalidArgument, "bench segments: give --city, --kitti or both");
  options.validate();
  fs::create_directories(out_dir);
  std::vector<StudyDataset> sets;
  if (!city_dir.empty()) sets.push_back(city_study_dataset(city_dir));
  if (!kitti_dir.empty()) sets.push_back(kitti_study_dataset(kitti_dir, out_dir / "kitti"));
  auto progress = [&log, tty](const SegmentStudyProgress& p) {
    if (p.stage == "features" && p.done != p.total && p.done % 50 != 0) return;
    log << (tty ? "\r" : "") << "bench segments: " << p.dataset;
    if (p.placemarks) log << " P=" << p.placemarks << " O=" << p.overlap;
    log << " " << p.stage;
    if (p.total > 1) log << " " << p.done << "/" << p.total;
    log << (tty && p.stage != "done" ? "     " : "\n") << std::flush;
  };
  std::vector<std::pair<std::string, nlohmann::json>> rows;
  for (const auto& d : sets) {
    run_segment_study(out_dir, d, options, progress);
    rows.emplace_back(d.name, collect_segment_study_rows(out_dir, d.name));  // earlier runs' configurations too
  }
  write_segment_study_report(out_dir, rows);
  return read_file(out_dir / "report.md");
}

}  // namespace visloc
