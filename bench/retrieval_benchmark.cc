#include "bench/retrieval_benchmark.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <map>
#include <memory>
#include <numeric>
#include <ostream>
#include <set>
#include <sstream>

#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/util/error.h"
#include "visloc/util/random.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;
namespace {

constexpr int kRecallAt[] = {1, 5, 10, 20, 50};
constexpr int kMaxRetrieved = 50;

// A name list that must not be empty.
std::vector<std::string> read_names(const fs::path& path) {
  std::vector<std::string> names = read_name_list(path);
  if (names.empty()) throw_error(ErrorCode::kInvalidArgument, path.string(), ": no image names");
  return names;
}

std::vector<std::string> list_images(const fs::path& dir) {
  if (!fs::is_directory(dir)) throw_error(ErrorCode::kIo, dir.string(), ": not a directory");
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && is_image_file(e.path())) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  if (names.empty()) throw_error(ErrorCode::kInvalidArgument, dir.string(), ": no images");
  return names;
}

struct Truth {
  std::map<std::string, ImagePlacement> placement;
  std::map<std::string, int> placemark;
  std::string kind;  // "poses" or "gps"
};

Truth read_truth(const fs::path& path) {
  Truth t;
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  if (ext == ".csv") {
    t.kind = "gps";
    const auto records = read_gps_csv(path);
    if (records.empty()) throw_error(ErrorCode::kInvalidArgument, path.string(), ": no records");
    const EnuFrame enu(records.front().position);
    for (const auto& r : records) {
      ImagePlacement p;
      p.center = enu.to_enu(r.position);
      t.placement[r.image] = p;
      if (r.placemark) t.placemark[r.image] = *r.placemark;
    }
  } else {
    t.kind = "poses";
    for (const auto& named : read_pose_list(path)) {
      ImagePlacement p;
      p.center = named.cam_from_world.center();
      p.viewing_direction = named.cam_from_world.viewing_direction();
      t.placement[named.name] = p;
    }
  }
  return t;
}

double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / static_cast<double>(v.size());
}

// One retrieval method: a global descriptor and an index over it.
struct Method {
  std::string name;
  int dims = 0;
  std::function<void(const DescriptorMatrix&, float*)> embed;
  ImageIndexOptions index;
  size_t descriptor_fixed_bytes = 0;  // learned parameters of the descriptor
  double retained_variance = 1.0;
};

struct QueryOutcome {
  std::vector<bool> correct_at;  // per kRecallAt
  bool top_candidate_correct = false;
  size_t candidates = 0;
};

struct Evaluation {
  nlohmann::json json;
  std::vector<float> map_vectors;    // n × dims
  std::vector<float> query_vectors;  // q × dims
};

struct Dataset {
  std::vector<std::string> map_names, query_names;
  std::vector<const DescriptorMatrix*> map_desc, query_desc;
  std::vector<ImagePlacement> map_place, query_place;
  std::vector<int64_t> query_self;  // leave-one-out: the query's own map id, else -1
  SegmentTable segments;
};

// SIFT descriptors, extracted once per image and kept in memory for the run.
struct Features {
  std::map<fs::path, DescriptorMatrix> cache;
  std::vector<double> sift_ms;                    // per extraction
  std::vector<const DescriptorMatrix*> training;  // the images the embedding learns on
  double descriptors_per_image = 0;               // mean over the map images
};

// Map and query names (map names sorted).
void select_images(const RetrievalBenchmarkOptions& o, Dataset& d) {
  std::vector<std::string> all = list_images(o.images);
  if (o.leave_one_out) {
    d.map_names = o.map_list.empty() ? all : read_names(o.map_list);
    d.query_names = d.map_names;
  } else {
    d.query_names = read_names(o.queries);
    if (o.map_list.empty()) {
      const std::set<std::string> q(d.query_names.begin(), d.query_names.end());
      for (const auto& n : all)
        if (!q.count(n)) d.map_names.push_back(n);
    } else {
      d.map_names = read_names(o.map_list);
    }
  }
  std::sort(d.map_names.begin(), d.map_names.end());
}

// Positions of map images and queries, and the map's segments.
void place_images(const RetrievalBenchmarkOptions& o, const Truth& truth, Dataset& d) {
  auto placement = [&](const std::string& name) {
    auto it = truth.placement.find(name);
    if (it == truth.placement.end())
      throw_error(ErrorCode::kNotFound, o.truth.string(), ": no entry for image '", name, "'");
    return it->second;
  };
  std::vector<int> placemarks;
  for (size_t i = 0; i < d.map_names.size(); ++i) {
    d.map_place.push_back(placement(d.map_names[i]));
    auto pm = truth.placemark.find(d.map_names[i]);
    placemarks.push_back(pm != truth.placemark.end() ? pm->second : static_cast<int>(i) / o.placemark_size);
  }
  d.segments = make_placemark_segments(placemarks, o.segment_rule);
  std::map<std::string, int64_t> map_id;
  for (size_t i = 0; i < d.map_names.size(); ++i) map_id[d.map_names[i]] = int64_t(i);
  for (const auto& q : d.query_names) {
    d.query_place.push_back(placement(q));
    d.query_self.push_back(o.leave_one_out ? map_id.at(q) : -1);
  }
}

// Map images first, then queries, then training images (each image once).
void extract_features(const RetrievalBenchmarkOptions& o, Dataset& d, Features& f) {
  const fs::path query_dir = o.query_images.empty() ? o.images : o.query_images;
  SiftExtractor sift(o.sift);
  auto features = [&](const fs::path& p) -> const DescriptorMatrix* {
    auto it = f.cache.find(p);
    if (it == f.cache.end()) {
      Timer t;
      FeatureSet extracted = sift.extract_file(p);
      f.sift_ms.push_back(t.elapsed_ms());
      it = f.cache.emplace(p, std::move(extracted.descriptors)).first;
    }
    return &it->second;
  };
  for (const auto& n : d.map_names) d.map_desc.push_back(features(o.images / n));
  for (const auto& n : d.query_names) d.query_desc.push_back(features(query_dir / n));
  f.training = d.map_desc;
  if (!o.train_images.empty()) {
    f.training.clear();
    for (const auto& n : list_images(o.train_images)) f.training.push_back(features(o.train_images / n));
  }
  for (const auto* m : d.map_desc) f.descriptors_per_image += double(m->rows());
  f.descriptors_per_image /= double(d.map_desc.size());
}

nlohmann::json summarize(const Method& m, const std::vector<QueryOutcome>& outcomes,
                         const std::vector<double>& embed_ms, const std::vector<double>& search_ms,
                         const std::vector<double>& vote_ms, size_t bytes_per_image, size_t fixed_bytes,
                         const ImageIndex& index) {
  nlohmann::json recall;
  for (size_t r = 0; r < std::size(kRecallAt); ++r) {
    size_t ok = 0;
    for (const auto& o : outcomes) ok += o.correct_at[r];
    recall[std::to_string(kRecallAt[r])] = outcomes.empty() ? 0.0 : double(ok) / double(outcomes.size());
  }
  size_t top = 0;
  double cand = 0;
  for (const auto& o : outcomes) top += o.top_candidate_correct, cand += double(o.candidates);
  const double n = outcomes.empty() ? 1.0 : double(outcomes.size());
  return {{"name", m.name},
          {"dims", m.dims},
          {"recall_at", recall},
          {"top_candidate_recall", double(top) / n},
          {"mean_candidates", cand / n},
          {"ms_per_query", mean(embed_ms) + mean(search_ms) + mean(vote_ms)},
          {"embed_ms", mean(embed_ms)},
          {"search_ms", mean(search_ms)},
          {"vote_ms", mean(vote_ms)},
          {"bytes_per_image", bytes_per_image},
          {"fixed_bytes", fixed_bytes},
          {"index", m.index.type == ImageIndexType::kIvfPq ? "ivfpq" : "flat"},
          {"effective_nlist", index.effective_nlist()},
          {"effective_pq_bits", index.effective_pq_bits()},
          {"retained_variance", m.retained_variance}};
}

// The segments of the map image nearest to query q (facing it), the query
// itself left out.
std::set<int32_t> correct_segments(const Dataset& d, size_t q, const CorrectSegmentOptions& truth) {
  const int64_t self = d.query_self[q];
  std::vector<ImagePlacement> others;
  std::vector<int64_t> other_id;
  for (size_t i = 0; i < d.map_place.size(); ++i)
    if (static_cast<int64_t>(i) != self) others.push_back(d.map_place[i]), other_id.push_back(int64_t(i));
  std::set<int32_t> correct;
  for (int64_t i : nearest_map_images(d.query_place[q], others, truth))
    for (int32_t s : d.segments.segments(static_cast<size_t>(other_id[i]))) correct.insert(s);
  return correct;
}

// Searches, votes and scores every query against `index` (ids < table size
// are map images; larger ids are synthetic distractors with their own segments).
std::vector<QueryOutcome> run_queries(const Dataset& d, const ImageIndex& index, const SegmentTable& table,
                                      const std::vector<float>& query_vectors, int dims,
                                      const SegmentVoterOptions& voter_options, const CorrectSegmentOptions& truth,
                                      std::vector<double>& search_ms, std::vector<double>& vote_ms) {
  std::vector<QueryOutcome> out;
  for (size_t q = 0; q < d.query_names.size(); ++q) {
    const int64_t self = d.query_self[q];
    Timer ts;
    auto ranked = index.search(std::span<const float>(query_vectors.data() + q * dims, dims),
                               kMaxRetrieved + (self >= 0 ? 1 : 0));
    if (self >= 0)
      ranked.erase(std::remove_if(ranked.begin(), ranked.end(), [&](const auto& r) { return r.image == self; }),
                   ranked.end());
    if (ranked.size() > static_cast<size_t>(kMaxRetrieved)) ranked.resize(kMaxRetrieved);
    search_ms.push_back(ts.elapsed_ms());
    const std::set<int32_t> correct = correct_segments(d, q, truth);
    QueryOutcome o;
    for (int nt : kRecallAt) {
      SegmentVoterOptions vo = voter_options;
      vo.top_images = nt;
      Timer tv;
      const auto cands = SegmentVoter(table, vo).candidates(ranked);
      if (nt == voter_options.top_images) {
        vote_ms.push_back(tv.elapsed_ms());
        o.candidates = cands.size();
        o.top_candidate_correct = !cands.empty() && correct.count(cands.front().segment);
      }
      bool ok = false;
      for (const auto& c : cands) ok = ok || correct.count(c.segment) > 0;
      o.correct_at.push_back(ok);
    }
    out.push_back(o);
  }
  return out;
}

Evaluation evaluate(const Dataset& d, const Method& m, const SegmentVoterOptions& voter_options,
                    const CorrectSegmentOptions& truth, int threads) {
  Evaluation ev;
  const size_t n = d.map_desc.size();
  ev.map_vectors.resize(n * m.dims);
  for (size_t i = 0; i < n; ++i) m.embed(*d.map_desc[i], ev.map_vectors.data() + i * m.dims);
  std::vector<int64_t> ids(n);
  std::iota(ids.begin(), ids.end(), int64_t{0});
  const ImageIndex index = ImageIndex::build(ev.map_vectors, ids, m.dims, m.index);
  const int saved_threads = omp_get_max_threads();
  omp_set_num_threads(threads);
  std::vector<double> embed_ms, search_ms, vote_ms;
  ev.query_vectors.resize(d.query_desc.size() * m.dims);
  for (size_t q = 0; q < d.query_desc.size(); ++q) {
    Timer t;
    m.embed(*d.query_desc[q], ev.query_vectors.data() + q * m.dims);
    embed_ms.push_back(t.elapsed_ms());
  }
  const auto outcomes =
      run_queries(d, index, d.segments, ev.query_vectors, m.dims, voter_options, truth, search_ms, vote_ms);
  omp_set_num_threads(saved_threads);
  const size_t per_image = index.bytes_per_image() + (d.segments.bytes() + n - 1) / std::max<size_t>(n, 1);
  ev.json = summarize(m, outcomes, embed_ms, search_ms, vote_ms, per_image,
                      m.descriptor_fixed_bytes + index.fixed_bytes(), index);
  return ev;
}

// A method of the T-embedding `e` (its own pooling: `pooled`) with the index `type`.
Method embedding_method(std::string name, const std::shared_ptr<const TriangulationEmbedding>& e,
                        const std::shared_ptr<const TriangulationEmbedding>& pooled, const ImageIndexOptions& index,
                        ImageIndexType type) {
  Method m;
  m.name = std::move(name);
  m.dims = e->dims();
  m.embed = [pooled](const DescriptorMatrix& x, float* out) { pooled->embed(x, out); };
  m.index = index;
  m.index.type = type;
  m.descriptor_fixed_bytes = e->parameter_bytes();
  m.retained_variance = e->train_stats().retained_variance;
  return m;
}

// The compared methods: per dimension T-embedding with IVF-PQ and exact
// search (and democratic pooling), then VLAD of the same vocabulary. PCA
// variants keep the leading components of the full embedding (identical to
// training them separately).
std::vector<Method> make_methods(const RetrievalBenchmarkOptions& o,
                                 const std::shared_ptr<const TriangulationEmbedding>& full) {
  std::vector<Method> methods;
  for (int dims : o.dims) {
    std::shared_ptr<const TriangulationEmbedding> e =
        dims == 0 || dims == full->dims() ? full : std::make_shared<TriangulationEmbedding>(full->reduced(dims));
    const std::string base = "temb-" + std::to_string(e->dims());
    for (auto type : {ImageIndexType::kIvfPq, ImageIndexType::kFlat})
      methods.push_back(
          embedding_method(base + (type == ImageIndexType::kIvfPq ? "-ivfpq" : "-exact"), e, e, o.index, type));
    if (o.democratic) {
      auto demo = std::make_shared<TriangulationEmbedding>(e->with_pooling(EmbeddingPooling::kDemocratic));
      methods.push_back(embedding_method(base + "-democratic-exact", e, demo, o.index, ImageIndexType::kFlat));
    }
  }
  for (auto type : {ImageIndexType::kFlat, ImageIndexType::kIvfPq}) {
    if (type == ImageIndexType::kIvfPq && !o.vlad_ivfpq) continue;
    Method m;
    m.name = type == ImageIndexType::kFlat ? "vlad-exact" : "vlad-ivfpq";
    m.dims = full->vlad_dims();
    m.embed = [full](const DescriptorMatrix& x, float* out) {
      const auto v = full->vlad(x);
      std::copy(v.begin(), v.end(), out);
    };
    m.index = o.index;
    m.index.type = type;
    m.descriptor_fixed_bytes = full->centroids().size_bytes();
    methods.push_back(m);
  }
  return methods;
}

// The real map embeddings of `ev` followed by distractors, each a random map
// embedding plus Gaussian noise, normalized (total × dims).
std::vector<float> synthetic_vectors(const RetrievalBenchmarkOptions& o, const Evaluation& ev, size_t n, int dims) {
  const size_t total = o.synthetic_size;
  std::vector<float> vectors(total * dims);
  std::copy(ev.map_vectors.begin(), ev.map_vectors.end(), vectors.begin());
  RandomGenerator rng(o.embedding.seed + 17);
  const double sigma = o.synthetic_noise / std::sqrt(double(dims));
  for (size_t i = n; i < total; ++i) {
    const float* base = ev.map_vectors.data() + rng.below64(n) * dims;
    float* v = vectors.data() + i * dims;
    double n2 = 0;
    for (int t = 0; t < dims; ++t) v[t] = base[t] + static_cast<float>(sigma * rng.normal()), n2 += double(v[t]) * v[t];
    const float inv = static_cast<float>(1.0 / std::sqrt(n2));
    for (int t = 0; t < dims; ++t) v[t] *= inv;
  }
  return vectors;
}

// Method m's queries (embedded in `ev`) against the synthetic index.
nlohmann::json time_synthetic_index(const RetrievalBenchmarkOptions& o, const Dataset& d, const Method& m,
                                    const Evaluation& ev) {
  const size_t n = d.map_names.size(), total = o.synthetic_size;
  std::vector<float> vectors = synthetic_vectors(o, ev, n, m.dims);
  std::vector<int64_t> ids(total);
  std::iota(ids.begin(), ids.end(), int64_t{0});
  // Distractors form segments of 10 images after the real ones.
  std::vector<std::vector<int32_t>> of_image;
  for (size_t i = 0; i < n; ++i) {
    auto s = d.segments.segments(i);
    of_image.emplace_back(s.begin(), s.end());
  }
  for (size_t i = n; i < total; ++i)
    of_image.push_back({d.segments.segment_count() + static_cast<int32_t>((i - n) / 10)});
  const SegmentTable table(of_image);
  Timer tb;
  const ImageIndex index = ImageIndex::build(vectors, ids, m.dims, m.index);
  const double build_ms = tb.elapsed_ms();
  vectors = {};
  const int saved = omp_get_max_threads();
  omp_set_num_threads(o.search_threads);
  std::vector<double> search_ms, vote_ms;
  // Warm-up query (page faults of the freshly built index).
  index.search(std::span<const float>(ev.query_vectors.data(), m.dims), kMaxRetrieved);
  const auto outcomes =
      run_queries(d, index, table, ev.query_vectors, m.dims, o.voter, o.truth_options, search_ms, vote_ms);
  omp_set_num_threads(saved);
  std::vector<double> embed_ms{ev.json["embed_ms"].get<double>()};
  auto j = summarize(m, outcomes, embed_ms, search_ms, vote_ms,
                     index.bytes_per_image() + (table.bytes() + total - 1) / total,
                     m.descriptor_fixed_bytes + index.fixed_bytes(), index);
  j["build_ms"] = build_ms;
  return j;
}

// The synthetic index (real map embeddings plus distractors) for the
// T-embedding methods ({} when synthetic_size does not exceed the map).
nlohmann::json synthetic_report(const RetrievalBenchmarkOptions& o, const Dataset& d,
                                const std::vector<Method>& methods, const std::vector<Evaluation>& evaluations) {
  if (o.synthetic_size <= d.map_names.size()) return nlohmann::json::object();
  nlohmann::json syn_methods = nlohmann::json::array();
  for (size_t mi = 0; mi < methods.size(); ++mi) {
    const Method& m = methods[mi];
    if (m.name.rfind("temb-", 0) != 0 || m.name.find("democratic") != std::string::npos) continue;
    if (m.index.type == ImageIndexType::kFlat && !o.synthetic_exact) continue;
    syn_methods.push_back(time_synthetic_index(o, d, m, evaluations[mi]));
  }
  return {{"images", o.synthetic_size},
          {"distractors", o.synthetic_size - d.map_names.size()},
          {"noise", o.synthetic_noise},
          {"methods", syn_methods}};
}

nlohmann::json dataset_report(const RetrievalBenchmarkOptions& o, const Dataset& d, const Truth& truth,
                              const Features& f, const TriangulationEmbeddingTrainStats& train_stats) {
  return {{"images", o.images.string()},
          {"map_images", d.map_names.size()},
          {"queries", d.query_names.size()},
          {"segments", d.segments.segment_count()},
          {"truth", truth.kind},
          {"leave_one_out", o.leave_one_out},
          {"train_images", o.train_images.empty() ? std::string("map") : o.train_images.string()},
          {"descriptors_per_image", f.descriptors_per_image},
          {"features_ms_per_image", mean(f.sift_ms)},
          {"max_side", o.sift.max_image_side},
          {"threads", o.search_threads},
          {"top_images", o.voter.top_images},
          {"max_candidates", o.voter.max_candidates},
          {"weighting", o.voter.weighting == VoteWeighting::kReciprocalRank ? "rank" : "one"},
          {"embedding_training_ms", train_stats.total_ms}};
}

void print_table(std::ostream& out, const std::string& title, const nlohmann::json& methods) {
  out << title << "\n" << std::left << std::setw(28) << "method" << std::right;
  for (int r : kRecallAt) out << std::setw(7) << ("R@" + std::to_string(r));
  out << std::setw(8) << "top1" << std::setw(7) << "cand" << std::setw(10) << "ms/query" << std::setw(9) << "embed"
      << std::setw(9) << "search" << std::setw(10) << "B/image" << std::setw(13) << "fixed B\n";
  for (const auto& m : methods) {
    out << std::left << std::setw(28) << m["name"].get<std::string>() << std::right << std::fixed
        << std::setprecision(3);
    for (int r : kRecallAt) out << std::setw(7) << m["recall_at"][std::to_string(r)].get<double>();
    out << std::setw(8) << m["top_candidate_recall"].get<double>() << std::setprecision(2) << std::setw(7)
        << m["mean_candidates"].get<double>() << std::setw(10) << m["ms_per_query"].get<double>() << std::setw(9)
        << m["embed_ms"].get<double>() << std::setw(9) << m["search_ms"].get<double>() << std::setw(10)
        << m["bytes_per_image"].get<size_t>() << std::setw(13) << m["fixed_bytes"].get<size_t>() << "\n";
  }
}

// The dataset line and the tables of the real and the synthetic index.
std::string text_report(const RetrievalBenchmarkOptions& o, const Dataset& d, const Features& f,
                        const nlohmann::json& report) {
  std::ostringstream out;
  out << d.map_names.size() << " map images in " << d.segments.segment_count() << " segments, " << d.query_names.size()
      << " queries" << (o.leave_one_out ? " (leave-one-out)" : "") << "; " << std::fixed << std::setprecision(0)
      << f.descriptors_per_image << " descriptors/image, SIFT " << mean(f.sift_ms) << " ms/image (not in ms/query)\n";
  print_table(out,
              "Recall of >=1 correct segment among <= " + std::to_string(o.voter.max_candidates) +
                  " candidates from the top N_t images (top1/cand at N_t=" + std::to_string(o.voter.top_images) + ")",
              report["methods"]);
  if (!report["synthetic"].empty())
    print_table(out,
                "Synthetic index of " + std::to_string(o.synthetic_size) + " images (real map + distractors), " +
                    std::to_string(o.search_threads) + " thread(s)",
                report["synthetic"]["methods"]);
  return out.str();
}

std::string trained_line(const TriangulationEmbedding& e, const TriangulationEmbeddingTrainStats& s) {
  std::ostringstream line;
  line << "embedding trained: k=" << e.vocabulary_size() << ", " << s.kmeans_descriptors << " k-means / "
       << s.whitening_descriptors << " whitening descriptors, " << std::fixed << std::setprecision(0) << s.total_ms
       << " ms (k-means " << s.kmeans_ms << ", covariance " << s.covariance_ms << ", eigen " << s.eigen_ms << ")";
  return line.str();
}

// The placemark of every image: the CSV's placemark column where it has
// one, else groups of placemark_size consecutive images.
std::vector<int> placemarks_of(const std::vector<std::string>& names, const std::map<std::string, int>& placemark_of,
                               int placemark_size) {
  std::vector<int> placemarks;
  for (size_t i = 0; i < names.size(); ++i) {
    auto it = placemark_of.find(names[i]);
    placemarks.push_back(it != placemark_of.end() ? it->second : static_cast<int>(i) / placemark_size);
  }
  return placemarks;
}

}  // namespace

void RetrievalBenchmarkOptions::validate() const {
  embedding.validate();
  index.validate();
  voter.validate();
  segment_rule.validate();
  truth_options.validate();
  if (placemark_size < 1)
    throw_error(ErrorCode::kInvalidArgument, "--placemark-size = ", placemark_size, ": must be at least 1");
  if (search_threads < 1)
    throw_error(ErrorCode::kInvalidArgument, "--search-threads = ", search_threads, ": must be at least 1");
  if (leave_one_out == !queries.empty())
    throw_error(ErrorCode::kInvalidArgument, "give exactly one of --queries LIST and --leave-one-out");
  for (int d : dims)
    if (d < 0 || d > embedding.vocabulary_size * kDescriptorDim)
      throw_error(ErrorCode::kInvalidArgument, "--dims ", d, ": must be 0 or in [1, k*128]");
}

RetrievalBenchmarkResult run_retrieval_benchmark(const RetrievalBenchmarkOptions& o,
                                                 const std::function<void(const std::string&)>& progress) {
  o.validate();
  Dataset d;
  select_images(o, d);
  const Truth truth = read_truth(o.truth);
  place_images(o, truth, d);
  Features f;
  extract_features(o, d, f);

  // Embedding: trained once with full whitening; PCA variants keep its
  // leading components.
  TriangulationEmbeddingOptions eo = o.embedding;
  eo.output_dims = 0;
  TriangulationEmbeddingTrainStats train_stats;
  const auto full =
      std::make_shared<const TriangulationEmbedding>(TriangulationEmbedding::train(f.training, eo, &train_stats));
  if (progress) progress(trained_line(*full, train_stats));

  const std::vector<Method> methods = make_methods(o, full);
  nlohmann::json out_methods = nlohmann::json::array();
  std::vector<Evaluation> evaluations;
  for (const auto& m : methods) {
    evaluations.push_back(evaluate(d, m, o.voter, o.truth_options, o.search_threads));
    out_methods.push_back(evaluations.back().json);
  }
  RetrievalBenchmarkResult r;
  r.report = {{"dataset", dataset_report(o, d, truth, f, train_stats)},
              {"methods", out_methods},
              {"synthetic", synthetic_report(o, d, methods, evaluations)}};
  r.text = text_report(o, d, f, r.report);
  return r;
}

void RetrievalMapBuildOptions::validate() const {
  embedding.validate();
  index.validate();
  segment_rule.validate();
  if (placemark_size < 1)
    throw_error(ErrorCode::kInvalidArgument, "--placemark-size = ", placemark_size, ": must be at least 1");
}

RetrievalMapBuildResult build_retrieval_map(const RetrievalMapBuildOptions& o) {
  o.validate();
  std::vector<std::string> names = o.image_list.empty() ? list_images(o.images) : read_names(o.image_list);
  std::map<std::string, int> placemark_of;
  if (!o.gps_csv.empty())
    for (const auto& r : read_gps_csv(o.gps_csv))
      if (r.placemark) placemark_of[r.image] = *r.placemark;
  const std::vector<int> placemarks = placemarks_of(names, placemark_of, o.placemark_size);
  SiftExtractor sift(o.sift);
  std::vector<DescriptorMatrix> descriptors;
  for (const auto& n : names) descriptors.push_back(sift.extract_file(o.images / n).descriptors);
  std::vector<const DescriptorMatrix*> pointers;
  for (const auto& d : descriptors) pointers.push_back(&d);
  Timer t;
  const auto map =
      RetrievalMap::build(pointers, names, make_placemark_segments(placemarks, o.segment_rule), o.embedding, o.index);
  map.save(o.out);
  RetrievalMapBuildResult r;
  r.ms = t.elapsed_ms();
  r.images = names.size();
  r.segments = static_cast<size_t>(map.segments().segment_count());
  r.dims = map.embedding().dims();
  r.bytes_per_image = map.index().bytes_per_image();
  r.fixed_bytes = map.index().fixed_bytes() + map.embedding().parameter_bytes();
  std::ostringstream line;
  line << "retrieval map " << o.out.string() << ": " << r.images << " images, " << r.segments << " segments, " << r.dims
       << "-D embedding, index " << r.bytes_per_image << " B/image + " << r.fixed_bytes << " B fixed (" << std::fixed
       << std::setprecision(0) << r.ms << " ms)";
  r.summary = line.str();
  return r;
}

void RetrievalMapQueryOptions::validate() const { voter.validate(); }

void query_retrieval_map(const RetrievalMapQueryOptions& o,
                         const std::function<void(const nlohmann::json&)>& per_image) {
  o.validate();
  RetrievalMap map = RetrievalMap::load(o.map);
  if (o.nprobe > 0) map.mutable_index().set_nprobe(o.nprobe);
  SiftExtractor sift(o.sift);
  for (const auto& path : o.images) {
    Timer t;
    const FeatureSet f = sift.extract_file(path);
    const double features_ms = t.elapsed_ms();
    const auto r = map.query(f.descriptors, o.voter);
    nlohmann::json images = nlohmann::json::array(), candidates = nlohmann::json::array();
    for (const auto& im : r.images)
      images.push_back({{"image", map.image_names()[static_cast<size_t>(im.image)]}, {"distance", im.distance}});
    for (const auto& c : r.candidates)
      candidates.push_back({{"segment", c.segment}, {"votes", c.votes}, {"best_rank", c.best_rank}});
    per_image(
        {{"image", fs::path(path).filename().string()},
         {"candidates", candidates},
         {"retrieved", images},
         {"times_ms",
          {{"features", features_ms}, {"embedding", r.embed_ms}, {"search", r.search_ms}, {"voting", r.vote_ms}}}});
  }
}

}  // namespace visloc
