// visloc bench retrieval (the retrieval stage's recall, time and memory) and
// visloc retrieval build|query (the retrieval stage on its own): both run in
// bench/retrieval_benchmark.h; this file only binds their options.
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "bench/retrieval_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"

namespace visloc::cli {

void add_bench_retrieval(CLI::App& bench) {
  struct Args {
    RetrievalBenchmarkOptions options;
    std::string weighting = "rank";
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  RetrievalBenchmarkOptions& o = args->options;
  CLI::App* cmd = bench.add_subcommand(
      "retrieval",
      "Image retrieval (T-embedding + IVF-PQ, candidate segments): recall at N_t = 1,5,10,20,50, time per\n"
      "query, memory; compared with exact search and VLAD in the same run, and timed on a synthetic 100K index");
  cmd->add_option("--images", o.images, "Directory of the map images (and of the queries)")->required();
  cmd->add_option("--query-images", o.query_images, "Directory of the query images (default: --images)");
  cmd->add_option("--queries", o.queries, "Query image names, one per line");
  cmd->add_flag("--leave-one-out", o.leave_one_out, "Every map image in turn is a query, retrieved among the others");
  cmd->add_option("--truth", o.truth,
                  "Positions of map images and queries: poses 'name qw qx qy qz tx ty tz' (world-to-camera) or a\n"
                  "GPS CSV image,lat,lon,alt[,placemark] (.csv)")
      ->required();
  cmd->add_option("--map-list", o.map_list, "Map image names (default: every image of --images not a query)");
  cmd->add_option("--train-images", o.train_images,
                  "Learn the embedding on these images instead of the map's (an independent set)");
  cmd->add_option("--placemark-size", o.placemark_size,
                  "Consecutive map images per placemark when the truth has no placemark column")
      ->capture_default_str();
  cmd->add_option("--segment-placemarks", o.segment_rule.placemarks_per_segment, "Placemarks per segment")
      ->capture_default_str();
  cmd->add_option("--overlap", o.segment_rule.overlap, "Placemarks shared by neighbouring segments")
      ->capture_default_str();
  cmd->add_option("--dims", o.dims, "Embedding dimensions to compare (0: full whitening, k*128)")
      ->capture_default_str();
  cmd->add_option("--k", o.embedding.vocabulary_size, "Vocabulary size")->capture_default_str();
  cmd->add_option("--alpha", o.embedding.power_law_alpha, "Power-law exponent")->capture_default_str();
  cmd->add_option("--eigenvalue-floor", o.embedding.eigenvalue_floor,
                  "Whitening regularization: eigenvalues below floor * mean are raised to it")
      ->capture_default_str();
  cmd->add_option("--whitening-descriptors", o.embedding.max_whitening_descriptors,
                  "Descriptors sampled to learn centring and whitening")
      ->capture_default_str();
  cmd->add_option("--seed", o.embedding.seed, "Seed (sampling, k-means, synthetic distractors)")->capture_default_str();
  cmd->add_flag("--democratic", o.democratic, "Also measure democratic aggregation (exact search)");
  cmd->add_flag("--vlad-ivfpq", o.vlad_ivfpq, "Also measure VLAD with the IVF-PQ index");
  cmd->add_option("--nlist", o.index.nlist, "IVF cells")->capture_default_str();
  cmd->add_option("--nprobe", o.index.nprobe, "IVF cells visited per query")->capture_default_str();
  cmd->add_option("--pq-bytes", o.index.pq_bytes, "PQ sub-quantizers (bytes per image code)")->capture_default_str();
  cmd->add_option("--pq-bits", o.index.pq_bits, "Bits per PQ sub-code")->capture_default_str();
  cmd->add_flag("--precomputed-tables", o.index.precomputed_tables,
                "IVF-PQ precomputed residual tables (faster, nlist*M*2^b floats)");
  cmd->add_option("--top-images", o.voter.top_images, "N_t for the candidate statistics (top1, cand)")
      ->capture_default_str();
  cmd->add_option("--max-candidates", o.voter.max_candidates, "At most this many candidate segments")
      ->capture_default_str();
  cmd->add_option("--weighting", args->weighting, "Votes: one (per retrieved image) or rank (1/(rank+1))")
      ->check(CLI::IsMember({"one", "rank"}))
      ->capture_default_str();
  cmd->add_option("--max-view-angle", o.truth_options.max_view_angle_deg,
                  "Truth: map images facing within this angle of the query (degrees)")
      ->capture_default_str();
  cmd->add_option("--search-threads", o.search_threads, "OpenMP threads while timing queries")->capture_default_str();
  cmd->add_option("--synthetic-size", o.synthetic_size,
                  "Images of the synthetic index (real map + distractors); 0 skips it")
      ->capture_default_str();
  cmd->add_option("--synthetic-noise", o.synthetic_noise,
                  "Distractor = normalize(real map embedding + Gaussian noise of this norm)")
      ->capture_default_str();
  cmd->add_option("--synthetic-exact", o.synthetic_exact, "Also time exact search on the synthetic index")
      ->capture_default_str();
  cmd->add_flag("--json", args->json, "Print JSON");
  add_sift_options(cmd, o.sift, true);
  cmd->callback([args] {
    args->options.voter.weighting =
        args->weighting == "rank" ? VoteWeighting::kReciprocalRank : VoteWeighting::kOnePerImage;
    const bool json = args->json;
    const RetrievalBenchmarkResult r = run_retrieval_benchmark(args->options, [json](const std::string& line) {
      if (!json) std::cerr << line << "\n";
    });
    if (json)
      std::cout << r.report.dump(2) << "\n";
    else
      std::cout << r.text;
  });
}

// Used by fuzz/make_seeds.sh (a small retrieval map) and to inspect the
// retrieval stage of a built map (retrieval query --map MAP/retrieval).
void add_retrieval_command(CLI::App& app) {
  CLI::App* retrieval = app.add_subcommand(
      "retrieval",
      "Image retrieval alone: build a retrieval map from a folder of images, or query one (e.g. MAP/retrieval)");
  retrieval->require_subcommand(1);

  auto b = std::make_shared<RetrievalMapBuildOptions>();
  CLI::App* build = retrieval->add_subcommand(
      "build", "Learn the T-embedding on the images, index them (IVF-PQ), write the image -> segment table");
  build->add_option("--images", b->images, "Directory of the map images")->required();
  build->add_option("--list", b->image_list, "Image names to use, in route order (default: all, sorted by name)");
  build->add_option("--gps", b->gps_csv, "GPS CSV image,lat,lon,alt[,placemark]: placemarks for the segments");
  build->add_option("--out", b->out, "Output directory")->required();
  build
      ->add_option("--placemark-size", b->placemark_size,
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
  build->callback([b] { std::cout << build_retrieval_map(*b).summary << "\n"; });

  auto q = std::make_shared<RetrievalMapQueryOptions>();
  CLI::App* query =
      retrieval->add_subcommand("query", "Candidate segments of query images; one JSON object per image and line");
  query->add_option("--map", q->map, "Retrieval map directory (visloc retrieval build, or MAP/retrieval of a map)")
      ->required();
  query->add_option("images", q->images, "Query images")->required();
  query->add_option("--top-images", q->voter.top_images, "N_t: retrieved images that vote")->capture_default_str();
  query->add_option("--max-candidates", q->voter.max_candidates, "At most this many segments")->capture_default_str();
  query->add_option("--nprobe", q->nprobe, "IVF cells visited (0: the map's)")->capture_default_str();
  add_sift_options(query, q->sift, true);
  query->callback(
      [q] { query_retrieval_map(*q, [](const nlohmann::json& line) { std::cout << line.dump() << "\n"; }); });
}

}  // namespace visloc::cli
