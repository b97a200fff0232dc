#include "bench/matching_benchmark.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <sstream>
#include <string_view>
#include <unordered_set>

#include "bench/reranking_study.h"
#include "visloc/baselines/faiss_baselines.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map/map.h"
#include "visloc/map_building/hash_blend_fit.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/exact_matcher.h"
#include "visloc/matching/hamming_blend.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;

void MatchingBenchmarkOptions::validate() const {
  if (scenes.empty()) throw_error(ErrorCode::kInvalidArgument, "bench matching: no scene (map and query list)");
  if (extract && images.empty()) throw_error(ErrorCode::kInvalidArgument, "--extract needs --images DIR");
  if (!(ratio > 0 && ratio <= 1)) throw_error(ErrorCode::kInvalidArgument, "ratio must be in (0, 1], got ", ratio);
  if (!std::isfinite(inlier_px))
    throw_error(ErrorCode::kInvalidArgument, "bench matching: inlier_px must be a finite number, got ", inlier_px);
  if (extract) sift.validate();
}

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
  double candidates = 0;  // Σ per-query candidates per feature
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

struct SceneResult {
  std::string map;
  size_t points = 0;
  std::vector<MethodTotals> methods;
};

// A map's first segment with its raw (mean) point descriptors.
struct LoadedMap {
  std::string map_dir;
  // The hash blend's weight fitted on the map (`map fit-blend`), at the
  // first method that asks for it.
  mutable std::optional<double> fitted_blend_weight;
  Map map;
  std::unique_ptr<Segment> segment;
  size_t points = 0;
  DescriptorMatrix descriptors;
  std::vector<float> descriptors_float;
};

// The queries of a scene and what the methods share.
struct SceneQueries {
  const MatchingBenchmarkOptions& options;
  const std::vector<QueryImage>& queries;
  std::span<const float> xyz;
  std::vector<PairSet> exact_sets;  // per query: the exact method's 1-1 pairs
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

LoadedMap load_map(const std::string& map_dir) {
  LoadedMap m;
  m.map_dir = map_dir;
  m.map = Map::open(map_dir);
  const auto& man = m.map.manifest();
  if (man.segments.empty()) throw_error(ErrorCode::kFormat, map_dir, ": map has no segments");
  m.segment = m.map.open_segment(0);
  m.points = m.segment->num_points();
  if (man.segments[0].descriptors_file.empty())
    throw_error(
        ErrorCode::kInvalidArgument, map_dir,
        ": the map kept no point descriptors (imported with --no-descriptors); the raw-SIFT baselines need them");
  m.descriptors = read_point_descriptor_file(fs::path(map_dir) / man.segments[0].descriptors_file);
  if (m.descriptors.rows() != m.points)
    throw_error(ErrorCode::kFormat, map_dir, ": descriptor file and segment disagree");
  m.descriptors_float.assign(m.descriptors.data(), m.descriptors.data() + m.descriptors.size_bytes());
  return m;
}

// The pinhole part of the query's COLMAP camera (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL).
void set_query_camera(QueryImage& q, const ColmapDbImage& im, const std::vector<ColmapDbCamera>& cams) {
  for (const auto& c : cams)
    if (c.camera_id == im.camera_id && (c.model == 0 || c.model == 1 || c.model == 2) && c.params.size() >= 3) {
      q.fx = c.params[0];
      q.fy = c.model == 1 ? c.params[1] : c.params[0];
      q.cx = c.model == 1 ? c.params[2] : c.params[1];
      q.cy = c.model == 1 ? c.params[3] : c.params[2];
      q.has_truth = true;
    }
}

// Queries: features from the COLMAP database (default) or extracted from
// images (in the original image's pixels, like COLMAP's); reference poses
// from the map's holdout file.
std::vector<QueryImage> load_queries(const MatchingBenchmarkOptions& a, const std::string& map_dir,
                                     const MapManifest& man, const std::string& query_list) {
  std::string db_path = a.database;
  if (db_path.empty()) db_path = man.source.value("database", "");
  auto truth = read_truth(man.holdout_file.empty() ? fs::path() : fs::path(map_dir) / man.holdout_file);
  std::vector<QueryImage> queries;
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
      q.features = sift->extract_file(fs::path(a.images) / n);
    } else {
      if (!cdb) throw_error(ErrorCode::kInvalidArgument, map_dir, ": no database known; pass --database");
      if (!im) throw_error(ErrorCode::kNotFound, db_path, ": no image named ", n);
      q.features = cdb->features(im->image_id);
    }
    auto tr = truth.find(n);
    if (tr != truth.end() && im) {
      set_query_camera(q, *im, cams);
      q.q = tr->second.first;
      q.t = tr->second.second;
    }
    queries.push_back(std::move(q));
  }
  if (queries.empty()) throw_error(ErrorCode::kInvalidArgument, query_list, ": no query images");
  return queries;
}

bool method_wanted(const std::vector<std::string>& prefixes, const std::string& name) {
  if (prefixes.empty()) return true;
  for (const auto& m : prefixes)
    if (name.rfind(m, 0) == 0) return true;
  return false;
}

void score_one_to_one(const SceneQueries& s, MethodTotals& mt, size_t qi, const std::vector<uint32_t>& f,
                      const std::vector<uint32_t>& p) {
  const QueryImage& q = s.queries[qi];
  const PairSet& exact = s.exact_sets[qi];
  mt.matches += f.size();
  for (size_t i = 0; i < f.size(); ++i) {
    if (q.has_truth && reprojects(q, &s.xyz[3 * p[i]], q.features.keypoints[f[i]], s.options.inlier_px)) ++mt.inliers;
    if (exact.count(pair_key(f[i], p[i]))) ++mt.exact_found;
  }
}

// Exact first: its 1-1 sets (into s.exact_sets) are the reference of recall_vs_exact.
MethodTotals run_exact(SceneQueries& s, const LoadedMap& m) {
  const double ratio = s.options.ratio;
  s.exact_sets.assign(s.queries.size(), PairSet());
  ExactMatcher exact(m.descriptors);
  MethodTotals mt{"exact"};
  mt.bytes_per_point = 12.0 + double(m.descriptors.size_bytes()) / double(m.points);
  mt.bytes_per_point_total = mt.bytes_per_point;
  exact.match(s.queries[0].features.descriptors, {.ratio = ratio});  // warm-up
  for (size_t qi = 0; qi < s.queries.size(); ++qi) {
    Timer t;
    auto matches = exact.match(s.queries[qi].features.descriptors, {.ratio = ratio});
    mt.ms += t.elapsed_ms();
    std::vector<uint32_t> f, p;
    for (const auto& r : matches) {
      f.push_back(r.query);
      p.push_back(r.database);
      s.exact_sets[qi].insert(pair_key(r.query, r.database));
    }
    mt.exact_total += matches.size();
    score_one_to_one(s, mt, qi, f, p);
    mt.candidates += double(m.points);
    mt.features += s.queries[qi].features.size();
    mt.searched_features += s.queries[qi].features.size();
    ++mt.queries;
  }
  return mt;
}

struct FaissConfig {
  std::string name;
  FaissPqIndexKind kind;
  int w;
};

MethodTotals run_faiss_method(const SceneQueries& s, const LoadedMap& m, const FaissConfig& c, FaissPqIndex& index) {
  const double ratio = s.options.ratio;
  MethodTotals mt{c.name};
  // xyz + PQ code + 8-byte id in an inverted list; plus the coarse and PQ centroids.
  mt.bytes_per_point = 12 + 16 + 8;
  const double fixed =
      c.kind == FaissPqIndexKind::kIvfAdc ? (256.0 * 128 + 256 * 128) * 4 : (2 * 256 * 64 + 256 * 128) * 4.0;
  mt.bytes_per_point_total = mt.bytes_per_point + fixed / double(m.points);
  index.match(s.queries[0].features.descriptors, c.w, ratio);  // warm-up
  for (size_t qi = 0; qi < s.queries.size(); ++qi) {
    FaissSearchStats st;
    Timer t;
    auto matches = index.match(s.queries[qi].features.descriptors, c.w, ratio, &st);
    mt.ms += t.elapsed_ms();
    std::vector<uint32_t> f, p;
    for (const auto& r : matches) f.push_back(r.query), p.push_back(r.database);
    mt.exact_total += s.exact_sets[qi].size();
    score_one_to_one(s, mt, qi, f, p);
    mt.candidates += st.distances_per_query;
    mt.features += s.queries[qi].features.size();
    mt.searched_features += s.queries[qi].features.size();
    ++mt.queries;
  }
  return mt;
}

// FAISS IVFADC and IMI (trained on the segment's point descriptors, once per kind).
void run_faiss(const SceneQueries& s, const LoadedMap& m, const std::function<void(const MethodTotals&)>& done) {
  const std::vector<FaissConfig> faiss_configs = {{"ivfadc-w1", FaissPqIndexKind::kIvfAdc, 1},
                                                  {"ivfadc-w8", FaissPqIndexKind::kIvfAdc, 8},
                                                  {"imi-w64", FaissPqIndexKind::kImi, 64},
                                                  {"imi-w16", FaissPqIndexKind::kImi, 16}};
  std::map<int, std::unique_ptr<FaissPqIndex>> faiss_indexes;
  for (const auto& c : faiss_configs) {
    if (!method_wanted(s.options.methods, c.name)) continue;
    auto& index = faiss_indexes[int(c.kind)];
    if (!index) {
      FaissPqIndexOptions o;
      o.kind = c.kind;
      index = std::make_unique<FaissPqIndex>(m.descriptors_float.data(), m.points, o);
    }
    done(run_faiss_method(s, m, c, *index));
  }
}

struct CascadeConfig {
  std::string name;
  bool lsh;
  CascadeSearchOptions options;
  // Opt-in (only when a --method names it): the hash-code blend at the weight
  // `map fit-blend` fits on the map (an imported COLMAP map).
  bool fitted_blend = false;
};

// `ratio`: the 1-1 sets' ν_h (--ratio), as for every other method; the 1-M
// sets' ν stays 0.9 unless ν_h is above it.
std::vector<CascadeConfig> cascade_configs(float ratio) {
  std::vector<CascadeConfig> configs;
  auto opts = [ratio](int radius, bool refined, bool prioritize, OneToManyRule rule) {
    CascadeSearchOptions o;
    o.ratio_one_to_one = ratio;
    o.ratio_one_to_many = std::max(o.ratio_one_to_many, ratio);
    o.lut_radius = radius;
    o.refined = refined;
    o.prioritize = prioritize;
    o.one_to_many_rule = rule;
    return o;
  };
  const auto best = OneToManyRule::kBestRatio, group = OneToManyRule::kGroupRatio;
  configs.push_back({"lsh-cascade-r0", true, opts(0, true, false, best)});
  configs.push_back({"lsh-cascade-r1", true, opts(1, true, false, best)});
  configs.push_back({"ccs-no-refined-r0", false, opts(0, false, false, best)});
  configs.push_back({"ccs-no-refined-r1", false, opts(1, false, false, best)});
  configs.push_back({"ccs-full-r0", false, opts(0, true, false, best)});
  configs.push_back({"ccs-full-r1", false, opts(1, true, false, best)});
  {
    // The same search with the portable scalar kernels (the SIMD reference).
    CascadeConfig scalar{"ccs-full-r1-scalar", false, opts(1, true, false, best)};
    scalar.options.simd = SimdLevel::kScalar;
    configs.push_back(scalar);
  }
  {
    // Without software prefetching (its baseline; the same matches).
    CascadeConfig plain{"ccs-full-r1-no-prefetch", false, opts(1, true, false, best)};
    plain.options.prefetch = false;
    configs.push_back(plain);
  }
  configs.push_back({"ccs-full-r1-group1M", false, opts(1, true, false, group)});
  // Query-directed probing (radius 1): per table the exact bucket and the k
  // one-bit-away buckets whose bits lie nearest their hyperplanes (lut_flips;
  // 16 is ccs-full-r1). Named apart from ccs-full-r1, so that a --method
  // prefix of the plain search does not select them.
  for (int flips : {8, 6, 4, 2}) {
    CascadeConfig directed{"ccs-directed-full-f" + std::to_string(flips), false, opts(1, true, false, best)};
    directed.options.lut_flips = flips;
    configs.push_back(directed);
  }
  // ... only for features whose radius-1 coarse list exceeds N.
  for (int min_list : {100, 200, 400}) {
    CascadeConfig directed{"ccs-directed-full-f4-above" + std::to_string(min_list), false, opts(1, true, false, best)};
    directed.options.lut_flips = 4;
    directed.options.lut_flips_min_list = min_list;
    configs.push_back(directed);
  }
  configs.push_back({"ccs-prioritized-r0", false, opts(0, true, true, best)});
  configs.push_back({"ccs-prioritized-r1", false, opts(1, true, true, best)});
  {
    CascadeConfig directed{"ccs-directed-prioritized-f4", false, opts(1, true, true, best)};
    directed.options.lut_flips = 4;
    configs.push_back(directed);
  }
  configs.push_back({"ccs-prioritized-r1-group1M", false, opts(1, true, true, group)});
  // The search ranking by the hash-code blend (hash_blend_weight) at the
  // map's fitted weight. Named apart from ccs-full-r1 and ccs-prioritized-r1.
  configs.push_back({"ccs-blend-full-r1", false, opts(1, true, false, best), true});
  configs.push_back({"ccs-blend-prioritized-r1", false, opts(1, true, true, best), true});
  return configs;
}

MethodTotals run_cascade_method(const SceneQueries& s, const LoadedMap& m, const CascadeConfig& c,
                                CascadeMatcher& matcher, CascadeMatches& cm) {
  const Segment& seg = *m.segment;
  MethodTotals mt{c.name};
  mt.has_many = true;
  mt.bytes_per_point = seg.bytes().per_point_bytes_per_point(m.points);
  mt.bytes_per_point_total =
      seg.bytes().file_bytes_per_point(m.points) + double(m.map.codebook().centroids().size_bytes()) / double(m.points);
  mt.extra["lookup_memory_bytes_per_point"] = double(seg.bytes().lookup_memory) / double(m.points);
  if (c.fitted_blend) mt.extra["hash_blend_weight"] = c.options.hash_blend_weight;
  matcher.match(s.queries[0].features.descriptors, c.options, cm);  // warm-up
  double ms_hash = 0, ms_order = 0, ms_search = 0;
  for (size_t qi = 0; qi < s.queries.size(); ++qi) {
    const QueryImage& q = s.queries[qi];
    Timer t;
    matcher.match(q.features.descriptors, c.options, cm);
    mt.ms += t.elapsed_ms();
    ms_hash += cm.stats.ms_hash;
    ms_order += cm.stats.ms_order;
    ms_search += cm.stats.ms_search;
    mt.exact_total += s.exact_sets[qi].size();
    score_one_to_one(s, mt, qi, cm.query, cm.point);
    mt.candidates +=
        cm.stats.features_searched ? double(cm.stats.coarse_candidates) / double(cm.stats.features_searched) : 0;
    mt.features += q.features.size();
    mt.searched_features += cm.stats.features_searched;
    mt.many_features += cm.many_query.size();
    mt.many_candidates += cm.many_points.size();
    for (size_t r = 0; r < cm.many_query.size(); ++r) {
      bool any = false;
      for (uint32_t k = cm.many_offsets[r]; k < cm.many_offsets[r + 1] && !any; ++k)
        any = q.has_truth &&
              reprojects(q, &s.xyz[3 * cm.many_points[k]], q.features.keypoints[cm.many_query[r]], s.options.inlier_px);
      mt.many_inlier_features += any;
    }
    ++mt.queries;
  }
  const double nq = double(mt.queries);
  mt.extra["ms_hash"] = ms_hash / nq;
  mt.extra["ms_order"] = ms_order / nq;
  mt.extra["ms_search"] = ms_search / nq;
  return mt;
}

// Cascade methods: CCS on the mapped segment; the LSH cascade on LSH codes of
// the same descriptors with the segment's PQ codes.
// The map's fitted hash-blend weight at the benchmark's ν_h, fitted once.
double fitted_blend_weight(const SceneQueries& s, const LoadedMap& m) {
  if (!m.fitted_blend_weight) {
    MapBlendFitOptions o;
    o.fit.ratio_one_to_one = static_cast<float>(s.options.ratio);
    m.fitted_blend_weight = fit_map_hash_blend(m.map_dir, o).fit.weight;
  }
  return *m.fitted_blend_weight;
}

// Whether a --method that starts with `opt_in` names `name` (the fitted
// blend's methods run only when named that far: a plain "ccs" or "rerank"
// would ask a map that cannot be fitted for a fit).
bool named_past(const std::vector<std::string>& methods, const std::string& name, const std::string& opt_in) {
  return std::any_of(methods.begin(), methods.end(),
                     [&](const std::string& p) { return p.rfind(opt_in, 0) == 0 && name.rfind(p, 0) == 0; });
}

void run_cascades(const SceneQueries& s, const LoadedMap& m, const std::function<void(const MethodTotals&)>& done) {
  const size_t np = m.points;
  BinaryHasher lsh = make_lsh_hasher(m.descriptors_float.data(), np, 1);
  std::vector<HashCode> lsh_codes(np);
  HashWorkspace ws;
  encode_hash(lsh.view(), m.descriptors_float.data(), np, lsh_codes.data(), ws);
  CascadeLookup lsh_lookup(lsh_codes);
  CascadeIndexView lsh_view = m.segment->index();
  lsh_view.hasher = lsh.view();
  lsh_view.codes = lsh_codes.data();
  lsh_view.lookup = &lsh_lookup;
  CascadeMatcher ccs(m.segment->index(), m.map.codebook());
  CascadeMatcher lsh_matcher(lsh_view, m.map.codebook());
  CascadeMatches cm;
  for (auto c : cascade_configs(static_cast<float>(s.options.ratio))) {
    if (!method_wanted(s.options.methods, c.name)) continue;
    if (c.fitted_blend) {
      if (!named_past(s.options.methods, c.name, "ccs-blend")) continue;
      c.options.hash_blend_weight = float(fitted_blend_weight(s, m));
    }
    done(run_cascade_method(s, m, c, c.lsh ? lsh_matcher : ccs, cm));
  }
}

// The re-ranking study (bench/reranking_study.h): rerank-RANKER-lrL_R, the
// full search's short lists at radius 1 ranked by RANKER, at L_R 40 (the
// default) and 64 (the L_R lever). Run only when a --method asks for it (its
// FAISS training takes ~1 min per scene). Its ms/query is the ranking alone,
// with FAISS's generic per-feature tables: not what a kernel would cost.
struct ShortlistRanker {
  const char* name;
  double per_point_bytes;  // what a segment would hold in place of its 16-byte PQ codes
  double per_map_bytes;
  int faiss_subquantizers;  // 0: not a FAISS quantizer
  bool opq_rotation;
  int coarse_centroids = 0;
  int residual_splits = 0;
  double hamming_weight = 0;  // > 0: the search's PQ distance blended with the hash codes' (pq_hamming_distances)
  bool hamming_fitted = false;  // the blend at the weight fit_hamming_blend fits on the map's points
};
// Per point, what a segment would hold in place of its 16-byte PQ codes: no
// byte more with 16-byte codes (search-pq16, faiss-pq16, faiss-opq16), 16 more with
// 32-byte ones (FAISS's 32 × 256 × 4-dimension codebook has the 128 KiB of the
// 16 × 256 × 8 one), 112 more with the descriptors, 1 more with the coarse
// centroid's id (faiss-ivf256-pq16); per map, faiss-opq16's 128 × 128 float
// rotation, faiss-ivf256-pq16's 256 float centroids, the residual quantizers'
// codebooks less the PQ's 128 KiB (faiss-rq16 16 × 256 × 128 floats,
// faiss-prq2x8 2 × 8 × 256 × 64, faiss-prq4x4 4 × 4 × 256 × 32).
constexpr ShortlistRanker kShortlistRankers[] = {
    {"search-pq16", 0, 0, 0, false},
    {"exact", 128.0 - kPqCodeBytes, 0, 0, false},
    {"faiss-pq16", 0, 0, 16, false},
    {"faiss-pq32", 16, 0, 32, false},
    {"faiss-opq16", 0, double(kDescriptorDim) * kDescriptorDim * sizeof(float), 16, true},
    {"faiss-ivf256-pq16", 1, 256.0 * kDescriptorDim * sizeof(float), 16, false, 256},
    {"faiss-rq16", 0, (16.0 - 1.0) * 256 * kDescriptorDim * sizeof(float), 16, false, 0, 1},
    {"faiss-prq2x8", 0, (8.0 - 1.0) * 256 * kDescriptorDim * sizeof(float), 16, false, 0, 2},
    {"faiss-prq4x4", 0, (4.0 - 1.0) * 256 * kDescriptorDim * sizeof(float), 16, false, 0, 4},
    {"pq16-ham10", 0, 0, 0, false, 0, 0, 0.10},
    {"pq16-ham20", 0, 0, 0, false, 0, 0, 0.20},
    {"pq16-ham35", 0, 0, 0, false, 0, 0, 0.35},
    {"pq16-ham50", 0, 0, 0, false, 0, 0, 0.50},
    {"pq16-ham65", 0, 0, 0, false, 0, 0, 0.65},
    {"pq16-ham80", 0, 0, 0, false, 0, 0, 0.80},
    {"pq16-hamfit", 0, 0, 0, false, 0, 0, 0, true}};
constexpr int kShortlistLengths[] = {40, 64};

std::string reranking_method(const ShortlistRanker& r, int list) {
  return std::string("rerank-") + r.name + "-lr" + std::to_string(list);
}

// Opt-in: only when a --method names it (an empty list runs every other
// method); the fitted blend only when named past "rerank-pq16-hamfit".
bool reranking_wanted(const std::vector<std::string>& methods, const ShortlistRanker& r, int list) {
  if (r.hamming_fitted)  // fitted at the search's L_R, 40
    return list == 40 && named_past(methods, reranking_method(r, list), "rerank-pq16-hamfit");
  return !methods.empty() && method_wanted(methods, reranking_method(r, list));
}

bool reranker_wanted(const std::vector<std::string>& methods, const ShortlistRanker& r) {
  return std::any_of(std::begin(kShortlistLengths), std::end(kShortlistLengths),
                     [&](int list) { return reranking_wanted(methods, r, list); });
}

void run_reranking(const SceneQueries& s, const LoadedMap& m, const std::function<void(const MethodTotals&)>& done) {
  const auto& methods = s.options.methods;
  if (std::none_of(std::begin(kShortlistRankers), std::end(kShortlistRankers),
                   [&](const ShortlistRanker& r) { return reranker_wanted(methods, r); }))
    return;
  const Segment& seg = *m.segment;
  const size_t np = m.points;
  if (m.map.codebook().subvectors() != kPqSubvectors || m.map.codebook().is_residual())
    throw_error(ErrorCode::kInvalidArgument, "the rerank-* methods study the short lists of a 16-byte PQ map; ",
                "this map has ", m.map.codebook().code_bytes(), "-byte codes of the ",
                to_string(m.map.codebook().quantizer()),
                " quantizer (map import --pq-bytes 16 --pq-quantizer product)");
  std::vector<std::unique_ptr<FaissPqReranker>> faiss_rerankers(std::size(kShortlistRankers));
  for (size_t r = 0; r < faiss_rerankers.size(); ++r) {
    const ShortlistRanker& ranker = kShortlistRankers[r];
    if (ranker.faiss_subquantizers > 0 && reranker_wanted(methods, ranker))
      faiss_rerankers[r] =
          std::make_unique<FaissPqReranker>(m.descriptors_float.data(), np,
                                            FaissPqReranker::Options{.subquantizers = ranker.faiss_subquantizers,
                                                                     .opq_rotation = ranker.opq_rotation,
                                                                     .coarse_centroids = ranker.coarse_centroids,
                                                                     .residual_splits = ranker.residual_splits});
  }
  CascadeMatcher ccs(seg.index(), m.map.codebook());
  CascadeMatches whole;
  const double base = seg.bytes().per_point_bytes_per_point(np);
  const double base_total =
      seg.bytes().file_bytes_per_point(np) + double(m.map.codebook().centroids().size_bytes()) / double(np);
  const auto ratio = static_cast<float>(s.options.ratio);
  std::vector<uint32_t> f, p;
  for (const int list : kShortlistLengths) {
    std::vector<MethodTotals> totals;
    std::vector<size_t> rankers;
    for (size_t r = 0; r < std::size(kShortlistRankers); ++r) {
      const ShortlistRanker& ranker = kShortlistRankers[r];
      const std::string name = reranking_method(ranker, list);
      if (!reranking_wanted(methods, ranker, list)) continue;
      MethodTotals mt{name};
      if (ranker.hamming_fitted) mt.extra["hash_blend_weight"] = fitted_blend_weight(s, m);
      mt.bytes_per_point = base + ranker.per_point_bytes;
      mt.bytes_per_point_total = base_total + ranker.per_point_bytes + ranker.per_map_bytes / double(np);
      totals.push_back(mt);
      rankers.push_back(r);
    }
    if (totals.empty()) continue;
    const CascadeSearchOptions o = whole_shortlist_options(list, 1, ratio);
    std::vector<HashCode> query_codes;
    HashWorkspace hash_ws;
    const auto blend_weight = [&](size_t r) {
      return kShortlistRankers[r].hamming_fitted ? fitted_blend_weight(s, m) : kShortlistRankers[r].hamming_weight;
    };
    const bool hamming_rankers = std::any_of(rankers.begin(), rankers.end(), [](size_t r) {
      return kShortlistRankers[r].hamming_weight > 0 || kShortlistRankers[r].hamming_fitted;
    });
    for (size_t qi = 0; qi < s.queries.size(); ++qi) {
      const QueryImage& q = s.queries[qi];
      ccs.match(q.features.descriptors, o, whole);  // once per query and L_R, for every ranker
      if (hamming_rankers) {
        query_codes.resize(q.features.descriptors.rows());
        encode_hash(seg.index().hasher, q.features.descriptors.data(), query_codes.size(), query_codes.data(), hash_ws);
      }
      for (size_t t = 0; t < totals.size(); ++t) {
        MethodTotals& mt = totals[t];
        const size_t r = rankers[t];
        const ShortlistDistances distances =
            faiss_rerankers[r] ? faiss_distances(whole, q.features.descriptors, *faiss_rerankers[r])
            : std::string_view(kShortlistRankers[r].name) == "exact"
                ? exact_distances(whole, q.features.descriptors, m.descriptors)
            : kShortlistRankers[r].hamming_weight > 0 || kShortlistRankers[r].hamming_fitted
                ? pq_hamming_distances(whole, q.features.descriptors, query_codes, seg.index().codes,
                                       seg.index().hasher.mean, blend_weight(r))
                : search_pq_distances(whole);
        Timer timer;
        rank_whole_shortlists(whole, distances, ratio, f, p);
        mt.ms += timer.elapsed_ms();
        mt.exact_total += s.exact_sets[qi].size();
        score_one_to_one(s, mt, qi, f, p);
        mt.candidates += whole.stats.features_searched
                             ? double(whole.stats.coarse_candidates) / double(whole.stats.features_searched)
                             : 0;
        mt.features += q.features.size();
        mt.searched_features += whole.stats.features_searched;
        ++mt.queries;
      }
    }
    for (const MethodTotals& mt : totals) done(mt);
  }
}

SceneResult run_scene(const MatchingBenchmarkOptions& o, const MatchingBenchmarkScene& scene,
                      const std::function<void(const std::string&)>& progress) {
  SceneResult res;
  res.map = scene.map_dir;
  const LoadedMap m = load_map(scene.map_dir);
  res.points = m.points;
  const std::vector<QueryImage> queries = load_queries(o, scene.map_dir, m.map.manifest(), scene.query_list);
  SceneQueries s{o, queries, m.segment->xyz(), {}};
  auto done = [&](const MethodTotals& mt) {
    res.methods.push_back(mt);
    if (progress) progress(scene.map_dir + ": " + mt.name + " done");
  };
  done(run_exact(s, m));
  run_faiss(s, m, done);
  run_cascades(s, m, done);
  run_reranking(s, m, done);
  return res;
}

// Means per query over every scene; bytes per point: point-weighted means.
std::vector<MethodTotals> combine_scenes(const std::vector<SceneResult>& scenes) {
  std::vector<MethodTotals> all;
  for (const auto& s : scenes)
    for (const auto& mt : s.methods) {
      auto it = std::find_if(all.begin(), all.end(), [&](const MethodTotals& x) { return x.name == mt.name; });
      if (it == all.end()) {
        all.push_back(mt);
      } else {
        it->add(mt);
      }
    }
  size_t total_points = 0;
  for (const auto& s : scenes) total_points += s.points;
  for (auto& mt : all) {
    double b = 0, bt = 0;
    for (const auto& s : scenes)
      for (const auto& x : s.methods)
        if (x.name == mt.name)
          b += x.bytes_per_point * double(s.points), bt += x.bytes_per_point_total * double(s.points);
    mt.bytes_per_point = b / double(total_points);
    mt.bytes_per_point_total = bt / double(total_points);
    mt.extra = nlohmann::json::object();
  }
  return all;
}

void print_table(std::ostream& os, const std::vector<MethodTotals>& methods) {
  os << std::left << std::setw(28) << "method" << std::right << std::setw(9) << "ms/query" << std::setw(10)
     << "cand/feat" << std::setw(9) << "1-1" << std::setw(9) << "1-1 in" << std::setw(8) << "recall" << std::setw(7)
     << "B/pt" << std::setw(9) << "1-M feat" << std::setw(9) << "1-M cand" << std::setw(9) << "1-M in" << std::setw(9)
     << "searched"
     << "\n";
  for (const auto& mt : methods) {
    auto j = mt.to_json();
    os << std::left << std::setw(28) << mt.name << std::right << std::fixed << std::setprecision(2) << std::setw(9)
       << j["ms_per_query"].get<double>() << std::setprecision(0) << std::setw(10)
       << j["candidates_per_feature"].get<double>() << std::setw(9) << j["matches_1to1"].get<double>() << std::setw(9)
       << j["inliers_1to1_4px"].get<double>() << std::setprecision(3) << std::setw(8)
       << j["recall_vs_exact"].get<double>() << std::setprecision(0) << std::setw(7)
       << j["bytes_per_point"].get<double>();
    if (mt.has_many)
      os << std::setw(9) << j["matches_1toM_features"].get<double>() << std::setw(9)
         << j["candidates_1toM"].get<double>() << std::setw(9) << j["inlier_features_1toM_4px"].get<double>();
    else
      os << std::setw(9) << "-" << std::setw(9) << "-" << std::setw(9) << "-";
    os << std::setprecision(3) << std::setw(9) << j["features_searched_fraction"].get<double>() << "\n";
  }
}

nlohmann::json report_json(const std::vector<SceneResult>& scenes, const std::vector<MethodTotals>& all,
                           const char* blas) {
  nlohmann::json out = {{"methods", nlohmann::json::array()}, {"scenes", nlohmann::json::array()}};
  for (const auto& mt : all) out["methods"].push_back(mt.to_json());
  for (const auto& s : scenes) {
    nlohmann::json sj = {{"map", s.map}, {"points", s.points}, {"methods", nlohmann::json::array()}};
    for (const auto& mt : s.methods) sj["methods"].push_back(mt.to_json());
    out["scenes"].push_back(sj);
  }
  out["openblas_threads"] = blas ? blas : "unset";
  return out;
}

std::string report_text(const std::vector<SceneResult>& scenes, const std::vector<MethodTotals>& all,
                        const char* blas) {
  std::ostringstream os;
  if (!blas || std::string(blas) != "1")
    os << "note: OPENBLAS_NUM_THREADS is not 1; the exact method may use several threads\n";
  for (const auto& s : scenes) {
    os << "\n" << s.map << " (" << s.points << " points, " << s.methods.front().queries << " queries)\n";
    print_table(os, s.methods);
  }
  if (scenes.size() > 1) {
    os << "\nall scenes (means per query)\n";
    print_table(os, all);
  }
  return os.str();
}

}  // namespace

MatchingBenchmarkResult run_matching_benchmark(const MatchingBenchmarkOptions& options,
                                               const std::function<void(const std::string&)>& progress) {
  options.validate();
  set_faiss_threads(1);
  std::vector<SceneResult> scenes;
  for (const auto& scene : options.scenes) scenes.push_back(run_scene(options, scene, progress));
  const std::vector<MethodTotals> all = combine_scenes(scenes);
  const char* blas = std::getenv("OPENBLAS_NUM_THREADS");
  MatchingBenchmarkResult result;
  result.report = report_json(scenes, all, blas);
  result.text = report_text(scenes, all, blas);
  return result;
}

}  // namespace visloc
