// visloc bench matching: 2D-3D matching of held-out query images against a
// map imported with those images held out (`map import --holdout`), every
// method in the same run on the same queries (the paper's Fig. 5 and
// Table II matching rows):
//   exact         exhaustive NN on the raw (mean) SIFT, ratio 0.8 (the "kd-tree" row)
//   ivfadc-w1/w8  FAISS IVFADC, K_c = 256, PQ 16 × 8 bits, w cells visited
//   imi-w16/w64   FAISS inverted multi-index 2 × 8 bits, PQ 16 × 8 bits
//   lsh-cascade   CasHash-style: 8 random 16-bit tables, Hamming top L_R, PQ
//   ccs-*         the cascade search: without the refined step, full search,
//                 prioritized; LUT radius 0 (paper) and 1 (multi-index probing)
// Per method: milliseconds per query (matching only, one thread), coarse
// candidates per feature, 1-1 matches, recall of the exact method's 1-1
// matches, bytes per point, and — scored with the held-out images' reference
// (SfM) poses — 1-1 matches within 4 px and, for the cascade, the 1-M set's
// size and features with a candidate within 4 px under both 1-M rules.
#include <Eigen/Geometry>
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <unordered_set>

#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/map/map.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/exact_matcher.h"
#include "visloc/baselines/faiss_baselines.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace visloc::cli {
namespace fs = std::filesystem;
namespace {

struct QueryImage {
  std::string name;
  FeatureSet features;
  bool has_truth = false;
  Eigen::Quaterniond q{1, 0, 0, 0};
  Eigen::Vector3d t{0, 0, 0};
  double fx = 0, fy = 0, cx = 0, cy = 0;  // pinhole part of the query camera
};

// 1-1 pairs as a set of (feature << 32 | point).
using PairSet = std::unordered_set<uint64_t>;
inline uint64_t pair_key(uint32_t f, uint32_t p) { return (uint64_t(f) << 32) | p; }

struct MethodTotals {
  std::string name;
  double ms = 0;
  size_t queries = 0;
  double candidates = 0;       // Σ per-query candidates per feature
  size_t matches = 0, inliers = 0;
  size_t exact_total = 0, exact_found = 0;
  double bytes_per_point = 0, bytes_per_point_total = 0;
  bool has_many = false;
  size_t many_features = 0, many_candidates = 0, many_inlier_features = 0;
  size_t searched_features = 0, features = 0;
  nlohmann::json extra = nlohmann::json::object();

  nlohmann::json to_json() const {
    const double nq = queries ? double(queries) : 1.0;
    nlohmann::json j = {{"name", name},
                        {"ms_per_query", ms / nq},
                        {"candidates_per_feature", candidates / nq},
                        {"matches_1to1", double(matches) / nq},
                        {"inliers_1to1_4px", double(inliers) / nq},
                        {"recall_vs_exact", exact_total ? double(exact_found) / double(exact_total) : 0.0},
                        {"bytes_per_point", bytes_per_point},
                        {"bytes_per_point_total", bytes_per_point_total},
                        {"features_searched_fraction", features ? double(searched_features) / double(features) : 1.0}};
    if (has_many) {
      j["matches_1toM_features"] = double(many_features) / nq;
      j["candidates_1toM"] = double(many_candidates) / nq;
      j["inlier_features_1toM_4px"] = double(many_inlier_features) / nq;
    }
    for (auto& [k, v] : extra.items()) j[k] = v;
    return j;
  }
  void add(const MethodTotals& o) {
    ms += o.ms;
    queries += o.queries;
    candidates += o.candidates;
    matches += o.matches;
    inliers += o.inliers;
    exact_total += o.exact_total;
    exact_found += o.exact_found;
    many_features += o.many_features;
    many_candidates += o.many_candidates;
    many_inlier_features += o.many_inlier_features;
    searched_features += o.searched_features;
    features += o.features;
    has_many = has_many || o.has_many;
  }
};

bool reprojects(const QueryImage& q, const float* xyz, const Keypoint& kp, double threshold_px) {
  const Eigen::Vector3d x = q.q * Eigen::Vector3d(xyz[0], xyz[1], xyz[2]) + q.t;
  if (x.z() <= 1e-9) return false;
  const double u = q.fx * x.x() / x.z() + q.cx, v = q.fy * x.y() / x.z() + q.cy;
  return std::hypot(u - kp.x, v - kp.y) < threshold_px;
}

std::map<std::string, std::pair<Eigen::Quaterniond, Eigen::Vector3d>> read_truth(const fs::path& p) {
  std::map<std::string, std::pair<Eigen::Quaterniond, Eigen::Vector3d>> out;
  if (!fs::exists(p)) return out;
  std::istringstream in(read_file(p));
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    std::string name;
    double w, x, y, z, tx, ty, tz;
    if (s >> name >> w >> x >> y >> z >> tx >> ty >> tz)
      out[name] = {Eigen::Quaterniond(w, x, y, z).normalized(), Eigen::Vector3d(tx, ty, tz)};
  }
  return out;
}

struct Args {
  std::vector<std::string> maps, query_lists;
  std::string database, images;
  bool extract = false;
  bool json = false;
  int max_queries = 0;
  double ratio = 0.8;
  double inlier_px = 4.0;
  std::vector<std::string> methods;
  SiftOptions sift;
};

struct SceneResult {
  std::string map;
  size_t points = 0;
  std::vector<MethodTotals> methods;
};

SceneResult run_scene(const Args& a, const std::string& map_dir, const std::string& query_list) {
  SceneResult res;
  res.map = map_dir;
  Map map = Map::open(map_dir);
  const auto& man = map.manifest();
  if (man.segments.empty()) throw_error(ErrorCode::kFormat, map_dir, ": map has no segments");
  auto seg = map.open_segment(0);
  const size_t np = seg->num_points();
  res.points = np;
  if (man.segments[0].descriptors_file.empty())
    throw_error(ErrorCode::kInvalidArgument, map_dir,
                ": the map kept no point descriptors (imported with --no-descriptors); the raw-SIFT baselines need them");
  DescriptorMatrix db = read_point_descriptor_file(fs::path(map_dir) / man.segments[0].descriptors_file);
  if (db.rows() != np) throw_error(ErrorCode::kFormat, map_dir, ": descriptor file and segment disagree");
  std::vector<float> dbf(db.data(), db.data() + db.size_bytes());

  // Queries: features from the COLMAP database (default) or extracted from images.
  std::string db_path = a.database;
  if (db_path.empty()) db_path = man.source.value("database", "");
  auto truth = read_truth(man.holdout_file.empty() ? fs::path() : fs::path(map_dir) / man.holdout_file);
  std::vector<QueryImage> queries;
  {
    std::unique_ptr<ColmapDatabase> cdb;
    if (!db_path.empty()) cdb = std::make_unique<ColmapDatabase>(db_path);
    std::unique_ptr<SiftExtractor> sift;
    if (a.extract) sift = std::make_unique<SiftExtractor>(a.sift);
    auto names = read_name_list(query_list);
    if (a.max_queries > 0 && names.size() > size_t(a.max_queries)) names.resize(a.max_queries);
    std::vector<ColmapDbCamera> cams = cdb ? cdb->cameras() : std::vector<ColmapDbCamera>{};
    for (const auto& n : names) {
      QueryImage q;
      q.name = n;
      std::optional<ColmapDbImage> im = cdb ? cdb->image_by_name(n) : std::nullopt;
      if (a.extract) {
        if (a.images.empty()) throw_error(ErrorCode::kInvalidArgument, "--extract needs --images DIR");
        q.features = sift->extract_file(fs::path(a.images) / n);
      } else {
        if (!cdb) throw_error(ErrorCode::kInvalidArgument, map_dir, ": no database known; pass --database");
        if (!im) throw_error(ErrorCode::kNotFound, db_path, ": no image named ", n);
        q.features = cdb->features(im->image_id);
      }
      auto tr = truth.find(n);
      if (tr != truth.end() && im) {
        for (const auto& c : cams)
          if (c.camera_id == im->camera_id && (c.model == 0 || c.model == 1 || c.model == 2) && c.params.size() >= 3) {
            q.fx = c.params[0];
            q.fy = c.model == 1 ? c.params[1] : c.params[0];
            q.cx = c.model == 1 ? c.params[2] : c.params[1];
            q.cy = c.model == 1 ? c.params[3] : c.params[2];
            q.has_truth = true;
          }
        if (a.extract && q.features.image_width > 0 && q.has_truth) {
          // Extracted features are in the original image's pixels, like COLMAP's.
        }
        q.q = tr->second.first;
        q.t = tr->second.second;
      }
      queries.push_back(std::move(q));
    }
  }
  if (queries.empty()) throw_error(ErrorCode::kInvalidArgument, query_list, ": no query images");

  auto wanted = [&](const std::string& name) {
    if (a.methods.empty()) return true;
    for (const auto& m : a.methods)
      if (name.rfind(m, 0) == 0) return true;
    return false;
  };
  const auto xyz = seg->xyz();
  auto score_one_to_one = [&](MethodTotals& mt, const QueryImage& q, const std::vector<uint32_t>& f,
                              const std::vector<uint32_t>& p, const PairSet* exact) {
    mt.matches += f.size();
    for (size_t i = 0; i < f.size(); ++i) {
      if (q.has_truth && reprojects(q, &xyz[3 * p[i]], q.features.keypoints[f[i]], a.inlier_px)) ++mt.inliers;
      if (exact && exact->count(pair_key(f[i], p[i]))) ++mt.exact_found;
    }
  };

  // Exact first: its 1-1 sets are the reference of recall_vs_exact.
  std::vector<PairSet> exact_sets(queries.size());
  {
    ExactMatcher exact(db);
    MethodTotals mt{"exact"};
    mt.bytes_per_point = 12.0 + double(db.size_bytes()) / double(np);
    mt.bytes_per_point_total = mt.bytes_per_point;
    exact.match(queries[0].features.descriptors, {.ratio = a.ratio});  // warm-up
    for (size_t qi = 0; qi < queries.size(); ++qi) {
      Timer t;
      auto m = exact.match(queries[qi].features.descriptors, {.ratio = a.ratio});
      mt.ms += t.elapsed_ms();
      std::vector<uint32_t> f, p;
      for (const auto& r : m) {
        f.push_back(r.query);
        p.push_back(r.database);
        exact_sets[qi].insert(pair_key(r.query, r.database));
      }
      mt.exact_total += m.size();
      score_one_to_one(mt, queries[qi], f, p, &exact_sets[qi]);
      mt.candidates += double(np);
      mt.features += queries[qi].features.size();
      mt.searched_features += queries[qi].features.size();
      ++mt.queries;
    }
    res.methods.push_back(mt);
  }

  // FAISS IVFADC and IMI (trained on the segment's point descriptors).
  struct FaissConfig {
    std::string name;
    FaissPqIndexKind kind;
    int w;
  };
  const std::vector<FaissConfig> faiss_configs = {{"ivfadc-w1", FaissPqIndexKind::kIvfAdc, 1},
                                                  {"ivfadc-w8", FaissPqIndexKind::kIvfAdc, 8},
                                                  {"imi-w64", FaissPqIndexKind::kImi, 64},
                                                  {"imi-w16", FaissPqIndexKind::kImi, 16}};
  std::map<int, std::unique_ptr<FaissPqIndex>> faiss_indexes;
  for (const auto& c : faiss_configs) {
    if (!wanted(c.name)) continue;
    auto& index = faiss_indexes[int(c.kind)];
    if (!index) {
      FaissPqIndexOptions o;
      o.kind = c.kind;
      index = std::make_unique<FaissPqIndex>(dbf.data(), np, o);
    }
    MethodTotals mt{c.name};
    // xyz + PQ code + 8-byte id in an inverted list; plus the coarse and PQ centroids.
    mt.bytes_per_point = 12 + 16 + 8;
    const double fixed = c.kind == FaissPqIndexKind::kIvfAdc ? (256.0 * 128 + 256 * 128) * 4 : (2 * 256 * 64 + 256 * 128) * 4.0;
    mt.bytes_per_point_total = mt.bytes_per_point + fixed / double(np);
    index->match(queries[0].features.descriptors, c.w, a.ratio);  // warm-up
    for (size_t qi = 0; qi < queries.size(); ++qi) {
      FaissSearchStats st;
      Timer t;
      auto m = index->match(queries[qi].features.descriptors, c.w, a.ratio, &st);
      mt.ms += t.elapsed_ms();
      std::vector<uint32_t> f, p;
      for (const auto& r : m) f.push_back(r.query), p.push_back(r.database);
      mt.exact_total += exact_sets[qi].size();
      score_one_to_one(mt, queries[qi], f, p, &exact_sets[qi]);
      mt.candidates += st.distances_per_query;
      mt.features += queries[qi].features.size();
      mt.searched_features += queries[qi].features.size();
      ++mt.queries;
    }
    res.methods.push_back(mt);
  }

  // Cascade methods: CCS on the mapped segment; the LSH cascade on LSH codes
  // of the same descriptors with the segment's PQ codes.
  BinaryHasher lsh = make_lsh_hasher(dbf.data(), np, 1);
  std::vector<HashCode> lsh_codes(np);
  std::vector<float> ws;
  encode_hash(lsh.view(), dbf.data(), np, lsh_codes.data(), ws);
  CascadeLookup lsh_lookup(lsh_codes);
  CascadeIndexView lsh_view = seg->index();
  lsh_view.hasher = lsh.view();
  lsh_view.codes = lsh_codes.data();
  lsh_view.lookup = &lsh_lookup;
  CascadeMatcher ccs(seg->index(), map.codebook());
  CascadeMatcher lsh_matcher(lsh_view, map.codebook());

  struct CascadeConfig {
    std::string name;
    bool lsh;
    CascadeSearchOptions options;
  };
  std::vector<CascadeConfig> cascade_configs;
  auto opts = [](int radius, bool refined, bool prioritize, OneToManyRule rule) {
    CascadeSearchOptions o;
    o.lut_radius = radius;
    o.refined = refined;
    o.prioritize = prioritize;
    o.one_to_many_rule = rule;
    return o;
  };
  const auto best = OneToManyRule::kBestRatio, group = OneToManyRule::kGroupRatio;
  cascade_configs.push_back({"lsh-cascade-r0", true, opts(0, true, false, best)});
  cascade_configs.push_back({"lsh-cascade-r1", true, opts(1, true, false, best)});
  cascade_configs.push_back({"ccs-no-refined-r0", false, opts(0, false, false, best)});
  cascade_configs.push_back({"ccs-no-refined-r1", false, opts(1, false, false, best)});
  cascade_configs.push_back({"ccs-full-r0", false, opts(0, true, false, best)});
  cascade_configs.push_back({"ccs-full-r1", false, opts(1, true, false, best)});
  {
    // The same search with the portable scalar kernels (the SIMD reference).
    CascadeConfig scalar{"ccs-full-r1-scalar", false, opts(1, true, false, best)};
    scalar.options.simd = SimdLevel::kScalar;
    cascade_configs.push_back(scalar);
  }
  cascade_configs.push_back({"ccs-full-r1-group1M", false, opts(1, true, false, group)});
  cascade_configs.push_back({"ccs-prioritized-r0", false, opts(0, true, true, best)});
  cascade_configs.push_back({"ccs-prioritized-r1", false, opts(1, true, true, best)});
  cascade_configs.push_back({"ccs-prioritized-r1-group1M", false, opts(1, true, true, group)});
  CascadeMatches m;
  for (const auto& c : cascade_configs) {
    if (!wanted(c.name)) continue;
    CascadeMatcher& matcher = c.lsh ? lsh_matcher : ccs;
    MethodTotals mt{c.name};
    mt.has_many = true;
    mt.bytes_per_point = seg->bytes().per_point_bytes_per_point(np);
    mt.bytes_per_point_total = seg->bytes().file_bytes_per_point(np) + double(map.codebook().centroids().size_bytes()) / double(np);
    mt.extra["lookup_memory_bytes_per_point"] = double(seg->bytes().lookup_memory) / double(np);
    matcher.match(queries[0].features.descriptors, c.options, m);  // warm-up
    double ms_hash = 0, ms_order = 0, ms_search = 0;
    for (size_t qi = 0; qi < queries.size(); ++qi) {
      const QueryImage& q = queries[qi];
      Timer t;
      matcher.match(q.features.descriptors, c.options, m);
      mt.ms += t.elapsed_ms();
      ms_hash += m.stats.ms_hash;
      ms_order += m.stats.ms_order;
      ms_search += m.stats.ms_search;
      mt.exact_total += exact_sets[qi].size();
      score_one_to_one(mt, q, m.query, m.point, &exact_sets[qi]);
      mt.candidates += m.stats.features_searched ? double(m.stats.coarse_candidates) / double(m.stats.features_searched) : 0;
      mt.features += q.features.size();
      mt.searched_features += m.stats.features_searched;
      mt.many_features += m.many_query.size();
      mt.many_candidates += m.many_points.size();
      for (size_t r = 0; r < m.many_query.size(); ++r) {
        bool any = false;
        for (uint32_t k = m.many_offsets[r]; k < m.many_offsets[r + 1] && !any; ++k)
          any = q.has_truth && reprojects(q, &xyz[3 * m.many_points[k]], q.features.keypoints[m.many_query[r]], a.inlier_px);
        mt.many_inlier_features += any;
      }
      ++mt.queries;
    }
    const double nq = double(mt.queries);
    mt.extra["ms_hash"] = ms_hash / nq;
    mt.extra["ms_order"] = ms_order / nq;
    mt.extra["ms_search"] = ms_search / nq;
    res.methods.push_back(mt);
  }
  return res;
}

void print_table(std::ostream& os, const std::vector<MethodTotals>& methods) {
  os << std::left << std::setw(28) << "method" << std::right << std::setw(9) << "ms/query" << std::setw(10) << "cand/feat"
     << std::setw(9) << "1-1" << std::setw(9) << "1-1 in" << std::setw(8) << "recall" << std::setw(7) << "B/pt"
     << std::setw(9) << "1-M feat" << std::setw(9) << "1-M cand" << std::setw(9) << "1-M in" << std::setw(9) << "searched"
     << "\n";
  for (const auto& mt : methods) {
    auto j = mt.to_json();
    os << std::left << std::setw(28) << mt.name << std::right << std::fixed << std::setprecision(2) << std::setw(9)
       << j["ms_per_query"].get<double>() << std::setprecision(0) << std::setw(10)
       << j["candidates_per_feature"].get<double>() << std::setw(9) << j["matches_1to1"].get<double>() << std::setw(9)
       << j["inliers_1to1_4px"].get<double>() << std::setprecision(3) << std::setw(8)
       << j["recall_vs_exact"].get<double>() << std::setprecision(0) << std::setw(7) << j["bytes_per_point"].get<double>();
    if (mt.has_many)
      os << std::setw(9) << j["matches_1toM_features"].get<double>() << std::setw(9) << j["candidates_1toM"].get<double>()
         << std::setw(9) << j["inlier_features_1toM_4px"].get<double>();
    else
      os << std::setw(9) << "-" << std::setw(9) << "-" << std::setw(9) << "-";
    os << std::setprecision(3) << std::setw(9) << j["features_searched_fraction"].get<double>() << "\n";
  }
}

}  // namespace

void add_bench_matching(CLI::App& bench) {
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "matching",
      "2D-3D matching: CCS against exact, FAISS IVFADC/IMI and an LSH cascade, on maps imported with\n"
      "their query images held out (repeat --map/--queries for several scenes; one thread)");
  cmd->add_option("--map", args->maps, "Map directory (from `map import --holdout`)")->required();
  cmd->add_option("--queries", args->query_lists, "Query image list, one per --map")->required();
  cmd->add_option("--database", args->database,
                  "COLMAP database with the queries' features (default: the map's source database)");
  cmd->add_flag("--extract", args->extract, "Extract query features from image files with our SIFT instead");
  cmd->add_option("--images", args->images, "Image directory for --extract");
  cmd->add_option("--max-queries", args->max_queries, "Use at most this many queries per map (0: all)");
  cmd->add_option("--ratio", args->ratio, "Ratio test of the 1-1 sets (ν_h)")->capture_default_str();
  cmd->add_option("--inlier-px", args->inlier_px, "Reprojection threshold with the reference pose, pixels")
      ->capture_default_str();
  cmd->add_option("--method", args->methods, "Only methods whose name starts with this (repeatable)");
  cmd->add_flag("--json", args->json, "Print JSON");
  add_sift_options(cmd, args->sift, true);
  cmd->callback([args] {
    const Args& a = *args;
    if (a.maps.size() != a.query_lists.size())
      throw_error(ErrorCode::kInvalidArgument, "give one --queries per --map (", a.maps.size(), " maps, ",
                  a.query_lists.size(), " query lists)");
    set_faiss_threads(1);
    std::vector<SceneResult> scenes;
    std::vector<MethodTotals> all;
    for (size_t i = 0; i < a.maps.size(); ++i) {
      scenes.push_back(run_scene(a, a.maps[i], a.query_lists[i]));
      for (const auto& mt : scenes.back().methods) {
        auto it = std::find_if(all.begin(), all.end(), [&](const MethodTotals& x) { return x.name == mt.name; });
        if (it == all.end()) {
          all.push_back(mt);
        } else {
          it->add(mt);
        }
      }
    }
    // Bytes per point over all scenes: point-weighted means.
    size_t total_points = 0;
    for (const auto& s : scenes) total_points += s.points;
    for (auto& mt : all) {
      double b = 0, bt = 0;
      for (const auto& s : scenes)
        for (const auto& x : s.methods)
          if (x.name == mt.name) b += x.bytes_per_point * double(s.points), bt += x.bytes_per_point_total * double(s.points);
      mt.bytes_per_point = b / double(total_points);
      mt.bytes_per_point_total = bt / double(total_points);
      mt.extra = nlohmann::json::object();
    }
    const char* blas = std::getenv("OPENBLAS_NUM_THREADS");
    if (a.json) {
      nlohmann::json out = {{"methods", nlohmann::json::array()}, {"scenes", nlohmann::json::array()}};
      for (const auto& mt : all) out["methods"].push_back(mt.to_json());
      for (const auto& s : scenes) {
        nlohmann::json sj = {{"map", s.map}, {"points", s.points}, {"methods", nlohmann::json::array()}};
        for (const auto& mt : s.methods) sj["methods"].push_back(mt.to_json());
        out["scenes"].push_back(sj);
      }
      out["openblas_threads"] = blas ? blas : "unset";
      std::cout << out.dump(2) << "\n";
      return;
    }
    if (!blas || std::string(blas) != "1")
      std::cout << "note: OPENBLAS_NUM_THREADS is not 1; the exact method may use several threads\n";
    for (const auto& s : scenes) {
      std::cout << "\n" << s.map << " (" << s.points << " points, " << s.methods.front().queries << " queries)\n";
      print_table(std::cout, s.methods);
    }
    if (scenes.size() > 1) {
      std::cout << "\nall scenes (means per query)\n";
      print_table(std::cout, all);
    }
  });
}

}  // namespace visloc::cli
