// visloc bench retrieval: the retrieval stage (paper section III-A) on a set
// of map images and queries with known positions: recall of "at least one
// correct segment among the candidates" for N_t = 1, 5, 10, 20, 50 retrieved
// images, time per query on one core, memory fixed and per image; the
// system's T-embedding + IVF-PQ compared in the same run with exact search on
// the uncompressed embeddings and with VLAD of the same vocabulary, at the
// whitening / PCA dimensions asked for; then the same on a synthetic index of
// --synthetic-size images (real map embeddings plus generated distractors).
//
// Until map building exists (issue #6) the bench takes the map's images
// directly and learns the embedding itself: --images DIR, the query names
// (--queries LIST, or --leave-one-out), and a truth file giving every image's
// position (--truth: poses `name qw qx qy qz tx ty tz`, or a GPS CSV
// `image,lat,lon,alt[,placemark]` read in a local ENU frame). Segments are
// runs of --segment-placemarks consecutive placemarks sharing --overlap
// (DESIGN.md); placemarks come from the CSV's placemark column or are groups
// of --placemark-size consecutive map images (names sorted). A query's
// correct segments are those holding the map image nearest to its true
// position among those facing within 90° (baselines/retrieval_truth.h).
//
// Timing: SIFT is reported separately (features_ms_per_image); ms_per_query
// is embedding + search + voting, with OpenMP limited to --search-threads (default 1:
// omp_set_num_threads during the timed part; Eigen runs single-threaded).
#include <omp.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <numeric>
#include <set>

#include "visloc/cli/commands.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/cli/sift_options.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/retrieval/image_index.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/baselines/retrieval_truth.h"
#include "visloc/retrieval/segment_voter.h"
#include "visloc/retrieval/triangulation_embedding.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"
#include "visloc/util/random.h"
#include "visloc/image/image_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;
namespace {

constexpr int kRecallAt[] = {1, 5, 10, 20, 50};
constexpr int kMaxRetrieved = 50;

// A name list that must not be empty.
std::vector<std::string> read_names(const fs::path& path) {
  std::vector<std::string> names = visloc::read_name_list(path);
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

nlohmann::json summarize(const Method& m, const std::vector<QueryOutcome>& outcomes, const std::vector<double>& embed_ms,
                         const std::vector<double>& search_ms, const std::vector<double>& vote_ms,
                         size_t bytes_per_image, size_t fixed_bytes, const ImageIndex& index) {
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
    // Truth: nearest facing map image other than the query itself.
    std::vector<ImagePlacement> others;
    std::vector<int64_t> other_id;
    for (size_t i = 0; i < d.map_place.size(); ++i)
      if (static_cast<int64_t>(i) != self) others.push_back(d.map_place[i]), other_id.push_back(int64_t(i));
    std::set<int32_t> correct;
    for (int64_t i : nearest_map_images(d.query_place[q], others, truth))
      for (int32_t s : d.segments.segments(static_cast<size_t>(other_id[i]))) correct.insert(s);
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
  ev.json = summarize(m, outcomes, embed_ms, search_ms, vote_ms, per_image, m.descriptor_fixed_bytes + index.fixed_bytes(),
                      index);
  return ev;
}

void print_table(const std::string& title, const nlohmann::json& methods) {
  std::cout << title << "\n"
            << std::left << std::setw(28) << "method" << std::right;
  for (int r : kRecallAt) std::cout << std::setw(7) << ("R@" + std::to_string(r));
  std::cout << std::setw(8) << "top1" << std::setw(7) << "cand" << std::setw(10) << "ms/query" << std::setw(9)
            << "embed" << std::setw(9) << "search" << std::setw(10) << "B/image" << std::setw(13) << "fixed B\n";
  for (const auto& m : methods) {
    std::cout << std::left << std::setw(28) << m["name"].get<std::string>() << std::right << std::fixed
              << std::setprecision(3);
    for (int r : kRecallAt) std::cout << std::setw(7) << m["recall_at"][std::to_string(r)].get<double>();
    std::cout << std::setw(8) << m["top_candidate_recall"].get<double>() << std::setprecision(2) << std::setw(7)
              << m["mean_candidates"].get<double>() << std::setw(10) << m["ms_per_query"].get<double>() << std::setw(9)
              << m["embed_ms"].get<double>() << std::setw(9) << m["search_ms"].get<double>() << std::setw(10)
              << m["bytes_per_image"].get<size_t>() << std::setw(13) << m["fixed_bytes"].get<size_t>() << "\n";
  }
}

}  // namespace

void add_bench_retrieval(CLI::App& bench) {
  struct Args {
    std::string images, query_images, queries, truth, map_list, train_images;
    bool leave_one_out = false, json = false, democratic = false, vlad_ivfpq = false;
    int placemark_size = 1, threads = 1;
    SegmentRuleOptions segment_rule;
    std::vector<int> dims{0};
    TriangulationEmbeddingOptions embedding;
    ImageIndexOptions index;
    SegmentVoterOptions voter;
    std::string weighting = "rank";
    CorrectSegmentOptions truth_options;
    SiftOptions sift;
    size_t synthetic_size = 100000;
    double synthetic_noise = 1.0;
    bool synthetic_exact = true;
  };
  auto args = std::make_shared<Args>();
  args->sift.max_image_side = 1024;
  CLI::App* cmd = bench.add_subcommand(
      "retrieval",
      "Image retrieval (T-embedding + IVF-PQ, candidate segments): recall at N_t = 1,5,10,20,50, time per\n"
      "query, memory; compared with exact search and VLAD in the same run, and timed on a synthetic 100K index");
  cmd->add_option("--images", args->images, "Directory of the map images (and of the queries)")->required();
  cmd->add_option("--query-images", args->query_images, "Directory of the query images (default: --images)");
  cmd->add_option("--queries", args->queries, "Query image names, one per line");
  cmd->add_flag("--leave-one-out", args->leave_one_out,
                "Every map image in turn is a query, retrieved among the others");
  cmd->add_option("--truth", args->truth,
                  "Positions of map images and queries: poses 'name qw qx qy qz tx ty tz' (world-to-camera) or a\n"
                  "GPS CSV image,lat,lon,alt[,placemark] (.csv)")
      ->required();
  cmd->add_option("--map-list", args->map_list, "Map image names (default: every image of --images not a query)");
  cmd->add_option("--train-images", args->train_images,
                  "Learn the embedding on these images instead of the map's (an independent set)");
  cmd->add_option("--placemark-size", args->placemark_size,
                  "Consecutive map images per placemark when the truth has no placemark column")
      ->capture_default_str();
  cmd->add_option("--segment-placemarks", args->segment_rule.placemarks_per_segment, "Placemarks per segment")
      ->capture_default_str();
  cmd->add_option("--overlap", args->segment_rule.overlap, "Placemarks shared by neighbouring segments")
      ->capture_default_str();
  cmd->add_option("--dims", args->dims, "Embedding dimensions to compare (0: full whitening, k*128)")
      ->capture_default_str();
  cmd->add_option("--k", args->embedding.vocabulary_size, "Vocabulary size")->capture_default_str();
  cmd->add_option("--alpha", args->embedding.power_law_alpha, "Power-law exponent")->capture_default_str();
  cmd->add_option("--eigenvalue-floor", args->embedding.eigenvalue_floor,
                  "Whitening regularization: eigenvalues below floor * mean are raised to it")
      ->capture_default_str();
  cmd->add_option("--whitening-descriptors", args->embedding.max_whitening_descriptors,
                  "Descriptors sampled to learn centring and whitening")
      ->capture_default_str();
  cmd->add_option("--seed", args->embedding.seed, "Seed (sampling, k-means, synthetic distractors)")
      ->capture_default_str();
  cmd->add_flag("--democratic", args->democratic, "Also measure democratic aggregation (exact search)");
  cmd->add_flag("--vlad-ivfpq", args->vlad_ivfpq, "Also measure VLAD with the IVF-PQ index");
  cmd->add_option("--nlist", args->index.nlist, "IVF cells")->capture_default_str();
  cmd->add_option("--nprobe", args->index.nprobe, "IVF cells visited per query")->capture_default_str();
  cmd->add_option("--pq-bytes", args->index.pq_bytes, "PQ sub-quantizers (bytes per image code)")
      ->capture_default_str();
  cmd->add_option("--pq-bits", args->index.pq_bits, "Bits per PQ sub-code")->capture_default_str();
  cmd->add_flag("--precomputed-tables", args->index.precomputed_tables,
                "IVF-PQ precomputed residual tables (faster, nlist*M*2^b floats)");
  cmd->add_option("--top-images", args->voter.top_images, "N_t for the candidate statistics (top1, cand)")
      ->capture_default_str();
  cmd->add_option("--max-candidates", args->voter.max_candidates, "At most this many candidate segments")
      ->capture_default_str();
  cmd->add_option("--weighting", args->weighting, "Votes: one (per retrieved image) or rank (1/(rank+1))")
      ->check(CLI::IsMember({"one", "rank"}))
      ->capture_default_str();
  cmd->add_option("--max-view-angle", args->truth_options.max_view_angle_deg,
                  "Truth: map images facing within this angle of the query (degrees)")
      ->capture_default_str();
  cmd->add_option("--search-threads", args->threads, "OpenMP threads while timing queries")->capture_default_str();
  cmd->add_option("--synthetic-size", args->synthetic_size,
                  "Images of the synthetic index (real map + distractors); 0 skips it")
      ->capture_default_str();
  cmd->add_option("--synthetic-noise", args->synthetic_noise,
                  "Distractor = normalize(real map embedding + Gaussian noise of this norm)")
      ->capture_default_str();
  cmd->add_option("--synthetic-exact", args->synthetic_exact, "Also time exact search on the synthetic index")
      ->capture_default_str();
  cmd->add_flag("--json", args->json, "Print JSON");
  add_sift_options(cmd, args->sift, true);
  cmd->callback([args] {
    Args& a = *args;
    a.embedding.validate();
    a.index.validate();
    a.voter.weighting = a.weighting == "rank" ? VoteWeighting::kReciprocalRank : VoteWeighting::kOnePerImage;
    a.voter.validate();
    a.segment_rule.validate();
    a.truth_options.validate();
    if (a.placemark_size < 1)
      throw_error(ErrorCode::kInvalidArgument, "--placemark-size = ", a.placemark_size, ": must be at least 1");
    if (a.threads < 1) throw_error(ErrorCode::kInvalidArgument, "--search-threads = ", a.threads, ": must be at least 1");
    if (a.leave_one_out == !a.queries.empty())
      throw_error(ErrorCode::kInvalidArgument, "give exactly one of --queries LIST and --leave-one-out");
    for (int d : a.dims)
      if (d < 0 || d > a.embedding.vocabulary_size * kDescriptorDim)
        throw_error(ErrorCode::kInvalidArgument, "--dims ", d, ": must be 0 or in [1, k*128]");
    const fs::path image_dir = a.images;
    const fs::path query_dir = a.query_images.empty() ? image_dir : fs::path(a.query_images);

    // Image lists.
    Dataset d;
    std::vector<std::string> all = list_images(image_dir);
    if (a.leave_one_out) {
      d.map_names = a.map_list.empty() ? all : read_names(a.map_list);
      d.query_names = d.map_names;
    } else {
      d.query_names = read_names(a.queries);
      if (a.map_list.empty()) {
        const std::set<std::string> q(d.query_names.begin(), d.query_names.end());
        for (const auto& n : all)
          if (!q.count(n)) d.map_names.push_back(n);
      } else {
        d.map_names = read_names(a.map_list);
      }
    }
    std::sort(d.map_names.begin(), d.map_names.end());

    // Truth and segments.
    const Truth truth = read_truth(a.truth);
    auto placement = [&](const std::string& name) {
      auto it = truth.placement.find(name);
      if (it == truth.placement.end()) throw_error(ErrorCode::kNotFound, a.truth, ": no entry for image '", name, "'");
      return it->second;
    };
    std::vector<int> placemarks;
    for (size_t i = 0; i < d.map_names.size(); ++i) {
      d.map_place.push_back(placement(d.map_names[i]));
      auto pm = truth.placemark.find(d.map_names[i]);
      placemarks.push_back(pm != truth.placemark.end() ? pm->second : static_cast<int>(i) / a.placemark_size);
    }
    d.segments = make_placemark_segments(placemarks, a.segment_rule);
    std::map<std::string, int64_t> map_id;
    for (size_t i = 0; i < d.map_names.size(); ++i) map_id[d.map_names[i]] = int64_t(i);
    for (const auto& q : d.query_names) {
      d.query_place.push_back(placement(q));
      d.query_self.push_back(a.leave_one_out ? map_id.at(q) : -1);
    }

    // Features, extracted once per image and kept in memory for the run.
    SiftExtractor sift(a.sift);
    std::map<fs::path, DescriptorMatrix> cache;
    std::vector<double> sift_ms;
    auto features = [&](const fs::path& p) -> const DescriptorMatrix* {
      auto it = cache.find(p);
      if (it == cache.end()) {
        Timer t;
        FeatureSet f = sift.extract_file(p);
        sift_ms.push_back(t.elapsed_ms());
        it = cache.emplace(p, std::move(f.descriptors)).first;
      }
      return &it->second;
    };
    for (const auto& n : d.map_names) d.map_desc.push_back(features(image_dir / n));
    for (const auto& n : d.query_names) d.query_desc.push_back(features(query_dir / n));
    std::vector<const DescriptorMatrix*> train_desc = d.map_desc;
    if (!a.train_images.empty()) {
      train_desc.clear();
      for (const auto& n : list_images(a.train_images)) train_desc.push_back(features(fs::path(a.train_images) / n));
    }
    double descriptors_per_image = 0;
    for (const auto* m : d.map_desc) descriptors_per_image += double(m->rows());
    descriptors_per_image /= double(d.map_desc.size());

    // Embedding: trained once with full whitening; PCA variants keep its
    // leading components (identical to training them separately).
    TriangulationEmbeddingOptions eo = a.embedding;
    eo.output_dims = 0;
    TriangulationEmbeddingTrainStats train_stats;
    const auto full = std::make_shared<TriangulationEmbedding>(TriangulationEmbedding::train(train_desc, eo, &train_stats));
    if (!a.json)
      std::cerr << "embedding trained: k=" << full->vocabulary_size() << ", " << train_stats.kmeans_descriptors
                << " k-means / " << train_stats.whitening_descriptors << " whitening descriptors, "
                << std::fixed << std::setprecision(0) << train_stats.total_ms << " ms (k-means " << train_stats.kmeans_ms
                << ", covariance " << train_stats.covariance_ms << ", eigen " << train_stats.eigen_ms << ")\n";

    std::vector<Method> methods;
    std::vector<std::shared_ptr<TriangulationEmbedding>> variants;
    for (int dims : a.dims) {
      auto e = dims == 0 || dims == full->dims() ? full : std::make_shared<TriangulationEmbedding>(full->reduced(dims));
      variants.push_back(e);
      const std::string base = "temb-" + std::to_string(e->dims());
      for (auto type : {ImageIndexType::kIvfPq, ImageIndexType::kFlat}) {
        Method m;
        m.name = base + (type == ImageIndexType::kIvfPq ? "-ivfpq" : "-exact");
        m.dims = e->dims();
        m.embed = [e](const DescriptorMatrix& x, float* out) { e->embed(x, out); };
        m.index = a.index;
        m.index.type = type;
        m.descriptor_fixed_bytes = e->parameter_bytes();
        m.retained_variance = e->train_stats().retained_variance;
        methods.push_back(m);
      }
      if (a.democratic) {
        auto demo = std::make_shared<TriangulationEmbedding>(e->with_pooling(EmbeddingPooling::kDemocratic));
        Method m;
        m.name = base + "-democratic-exact";
        m.dims = e->dims();
        m.embed = [demo](const DescriptorMatrix& x, float* out) { demo->embed(x, out); };
        m.index = a.index;
        m.index.type = ImageIndexType::kFlat;
        m.descriptor_fixed_bytes = e->parameter_bytes();
        m.retained_variance = e->train_stats().retained_variance;
        methods.push_back(m);
      }
    }
    for (auto type : {ImageIndexType::kFlat, ImageIndexType::kIvfPq}) {
      if (type == ImageIndexType::kIvfPq && !a.vlad_ivfpq) continue;
      Method m;
      m.name = type == ImageIndexType::kFlat ? "vlad-exact" : "vlad-ivfpq";
      m.dims = full->vlad_dims();
      m.embed = [full](const DescriptorMatrix& x, float* out) {
        const auto v = full->vlad(x);
        std::copy(v.begin(), v.end(), out);
      };
      m.index = a.index;
      m.index.type = type;
      m.descriptor_fixed_bytes = full->centroids().size_bytes();
      methods.push_back(m);
    }

    nlohmann::json out_methods = nlohmann::json::array();
    std::vector<Evaluation> evaluations;
    for (const auto& m : methods) {
      evaluations.push_back(evaluate(d, m, a.voter, a.truth_options, a.threads));
      out_methods.push_back(evaluations.back().json);
    }

    // Synthetic index: the real map embeddings plus distractors.
    nlohmann::json synthetic = nlohmann::json::object();
    if (a.synthetic_size > d.map_names.size()) {
      nlohmann::json syn_methods = nlohmann::json::array();
      for (size_t mi = 0; mi < methods.size(); ++mi) {
        const Method& m = methods[mi];
        if (m.name.rfind("temb-", 0) != 0 || m.name.find("democratic") != std::string::npos) continue;
        if (m.index.type == ImageIndexType::kFlat && !a.synthetic_exact) continue;
        const Evaluation& ev = evaluations[mi];
        const size_t n = d.map_names.size(), total = a.synthetic_size;
        std::vector<float> vectors(total * m.dims);
        std::copy(ev.map_vectors.begin(), ev.map_vectors.end(), vectors.begin());
        RandomGenerator rng(a.embedding.seed + 17);
        const double sigma = a.synthetic_noise / std::sqrt(double(m.dims));
        for (size_t i = n; i < total; ++i) {
          const float* base = ev.map_vectors.data() + rng.below64(n) * m.dims;
          float* v = vectors.data() + i * m.dims;
          double n2 = 0;
          for (int t = 0; t < m.dims; ++t) v[t] = base[t] + static_cast<float>(sigma * rng.normal()), n2 += double(v[t]) * v[t];
          const float inv = static_cast<float>(1.0 / std::sqrt(n2));
          for (int t = 0; t < m.dims; ++t) v[t] *= inv;
        }
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
        omp_set_num_threads(a.threads);
        std::vector<double> search_ms, vote_ms;
        // Warm-up query (page faults of the freshly built index).
        index.search(std::span<const float>(ev.query_vectors.data(), m.dims), kMaxRetrieved);
        const auto outcomes =
            run_queries(d, index, table, ev.query_vectors, m.dims, a.voter, a.truth_options, search_ms, vote_ms);
        omp_set_num_threads(saved);
        std::vector<double> embed_ms{ev.json["embed_ms"].get<double>()};
        auto j = summarize(m, outcomes, embed_ms, search_ms, vote_ms,
                           index.bytes_per_image() + (table.bytes() + total - 1) / total,
                           m.descriptor_fixed_bytes + index.fixed_bytes(), index);
        j["build_ms"] = build_ms;
        syn_methods.push_back(j);
      }
      synthetic = {{"images", a.synthetic_size},
                   {"distractors", a.synthetic_size - d.map_names.size()},
                   {"noise", a.synthetic_noise},
                   {"methods", syn_methods}};
    }

    nlohmann::json dataset = {{"images", a.images},
                              {"map_images", d.map_names.size()},
                              {"queries", d.query_names.size()},
                              {"segments", d.segments.segment_count()},
                              {"truth", truth.kind},
                              {"leave_one_out", a.leave_one_out},
                              {"train_images", a.train_images.empty() ? std::string("map") : a.train_images},
                              {"descriptors_per_image", descriptors_per_image},
                              {"features_ms_per_image", mean(sift_ms)},
                              {"max_side", a.sift.max_image_side},
                              {"threads", a.threads},
                              {"top_images", a.voter.top_images},
                              {"max_candidates", a.voter.max_candidates},
                              {"weighting", a.weighting},
                              {"embedding_training_ms", train_stats.total_ms}};
    if (a.json) {
      std::cout << nlohmann::json{{"dataset", dataset}, {"methods", out_methods}, {"synthetic", synthetic}}.dump(2)
                << "\n";
      return;
    }
    std::cout << d.map_names.size() << " map images in " << d.segments.segment_count() << " segments, "
              << d.query_names.size() << " queries" << (a.leave_one_out ? " (leave-one-out)" : "") << "; "
              << std::fixed << std::setprecision(0) << descriptors_per_image << " descriptors/image, SIFT "
              << mean(sift_ms) << " ms/image (not in ms/query)\n";
    print_table("Recall of >=1 correct segment among <= " + std::to_string(a.voter.max_candidates) +
                    " candidates from the top N_t images (top1/cand at N_t=" + std::to_string(a.voter.top_images) + ")",
                out_methods);
    if (!synthetic.empty())
      print_table("Synthetic index of " + std::to_string(a.synthetic_size) + " images (real map + distractors), " +
                      std::to_string(a.threads) + " thread(s)",
                  synthetic["methods"]);
  });
}

// visloc retrieval build|query: the retrieval stage on its own, until map
// building (issue #6) writes it into the map.
void add_retrieval_command(CLI::App& app) {
  CLI::App* retrieval = app.add_subcommand(
      "retrieval", "Image retrieval on its own: build a retrieval map from images, query it");
  retrieval->require_subcommand(1);

  struct BuildArgs {
    std::string images, list, truth, out;
    int placemark_size = 1;
    SegmentRuleOptions segment_rule;
    TriangulationEmbeddingOptions embedding;
    ImageIndexOptions index;
    SiftOptions sift;
  };
  auto b = std::make_shared<BuildArgs>();
  b->sift.max_image_side = 1024;
  CLI::App* build = retrieval->add_subcommand(
      "build", "Learn the T-embedding on the images, index them (IVF-PQ), write the image -> segment table");
  build->add_option("--images", b->images, "Directory of the map images")->required();
  build->add_option("--list", b->list, "Image names to use, in route order (default: all, sorted by name)");
  build->add_option("--gps", b->truth, "GPS CSV image,lat,lon,alt[,placemark]: placemarks for the segments");
  build->add_option("--out", b->out, "Output directory")->required();
  build->add_option("--placemark-size", b->placemark_size,
                    "Consecutive images per placemark when there is no placemark column")
      ->capture_default_str();
  build->add_option("--segment-placemarks", b->segment_rule.placemarks_per_segment, "Placemarks per segment")
      ->capture_default_str();
  build->add_option("--overlap", b->segment_rule.overlap, "Placemarks shared by neighbouring segments")
      ->capture_default_str();
  build->add_option("--dims", b->embedding.output_dims, "Embedding dimensions (0: full whitening, k*128)")
      ->capture_default_str();
  build->add_option("--k", b->embedding.vocabulary_size, "Vocabulary size")->capture_default_str();
  build->add_option("--eigenvalue-floor", b->embedding.eigenvalue_floor, "Whitening regularization")
      ->capture_default_str();
  build->add_option("--nlist", b->index.nlist, "IVF cells")->capture_default_str();
  build->add_option("--nprobe", b->index.nprobe, "IVF cells visited per query")->capture_default_str();
  build->add_option("--pq-bytes", b->index.pq_bytes, "PQ bytes per image")->capture_default_str();
  add_sift_options(build, b->sift, true);
  build->callback([b] {
    b->embedding.validate();
    b->index.validate();
    b->segment_rule.validate();
    if (b->placemark_size < 1)
      throw_error(ErrorCode::kInvalidArgument, "--placemark-size = ", b->placemark_size, ": must be at least 1");
    const fs::path dir = b->images;
    std::vector<std::string> names = b->list.empty() ? list_images(dir) : read_names(b->list);
    std::map<std::string, int> placemark_of;
    if (!b->truth.empty())
      for (const auto& r : read_gps_csv(b->truth))
        if (r.placemark) placemark_of[r.image] = *r.placemark;
    std::vector<int> placemarks;
    for (size_t i = 0; i < names.size(); ++i) {
      auto it = placemark_of.find(names[i]);
      placemarks.push_back(it != placemark_of.end() ? it->second : static_cast<int>(i) / b->placemark_size);
    }
    SiftExtractor sift(b->sift);
    std::vector<DescriptorMatrix> descriptors;
    for (const auto& n : names) descriptors.push_back(sift.extract_file(dir / n).descriptors);
    std::vector<const DescriptorMatrix*> pointers;
    for (const auto& d : descriptors) pointers.push_back(&d);
    Timer t;
    const auto map = RetrievalMap::build(pointers, names, make_placemark_segments(placemarks, b->segment_rule),
                                         b->embedding, b->index);
    map.save(b->out);
    std::cout << "retrieval map " << b->out << ": " << names.size() << " images, " << map.segments().segment_count()
              << " segments, " << map.embedding().dims() << "-D embedding, index " << map.index().bytes_per_image()
              << " B/image + " << map.index().fixed_bytes() + map.embedding().parameter_bytes() << " B fixed ("
              << std::fixed << std::setprecision(0) << t.elapsed_ms() << " ms)\n";
  });

  struct QueryArgs {
    std::string map;
    std::vector<std::string> images;
    SegmentVoterOptions voter;
    int nprobe = 0;
    SiftOptions sift;
  };
  auto q = std::make_shared<QueryArgs>();
  q->sift.max_image_side = 1024;
  CLI::App* query = retrieval->add_subcommand(
      "query", "Candidate segments of query images; one JSON object per image and line");
  query->add_option("--map", q->map, "Retrieval map directory (visloc retrieval build)")->required();
  query->add_option("images", q->images, "Query images")->required();
  query->add_option("--top-images", q->voter.top_images, "N_t: retrieved images that vote")->capture_default_str();
  query->add_option("--max-candidates", q->voter.max_candidates, "At most this many segments")->capture_default_str();
  query->add_option("--nprobe", q->nprobe, "IVF cells visited (0: the map's)")->capture_default_str();
  add_sift_options(query, q->sift, true);
  query->callback([q] {
    q->voter.validate();
    RetrievalMap map = RetrievalMap::load(q->map);
    if (q->nprobe > 0) map.mutable_index().set_nprobe(q->nprobe);
    SiftExtractor sift(q->sift);
    for (const auto& path : q->images) {
      Timer t;
      const FeatureSet f = sift.extract_file(path);
      const double features_ms = t.elapsed_ms();
      const auto r = map.query(f.descriptors, q->voter);
      nlohmann::json images = nlohmann::json::array(), candidates = nlohmann::json::array();
      for (const auto& im : r.images)
        images.push_back({{"image", map.image_names()[static_cast<size_t>(im.image)]}, {"distance", im.distance}});
      for (const auto& c : r.candidates)
        candidates.push_back({{"segment", c.segment}, {"votes", c.votes}, {"best_rank", c.best_rank}});
      std::cout << nlohmann::json{{"image", fs::path(path).filename().string()},
                                  {"candidates", candidates},
                                  {"retrieved", images},
                                  {"times_ms",
                                   {{"features", features_ms},
                                    {"embedding", r.embed_ms},
                                    {"search", r.search_ms},
                                    {"voting", r.vote_ms}}}}
                       .dump()
                << "\n";
    }
  });
}

}  // namespace visloc::cli
