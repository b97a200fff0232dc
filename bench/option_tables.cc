// Command-line option tables of the benchmark runners (util/option_table.h).
#include "bench/end_to_end_benchmark.h"
#include "bench/feature_benchmark.h"
#include "bench/matching_benchmark.h"
#include "bench/pose_benchmark.h"
#include "bench/retrieval_benchmark.h"
#include "visloc/util/option_table.h"

namespace visloc {

void add_options(OptionTable& t, RetrievalBenchmarkOptions& o) {
  t.add("--images", o.images, "Directory of the map images (and of the queries)").require();
  t.add("--query-images", o.query_images, "Directory of the query images (default: --images)");
  t.add("--queries", o.queries, "Query image names, one per line");
  t.flag("--leave-one-out", o.leave_one_out, "Every map image in turn is a query, retrieved among the others");
  t.add("--truth", o.truth,
        "Positions of map images and queries: poses 'name qw qx qy qz tx ty tz' (world-to-camera) or a\n"
        "GPS CSV image,lat,lon,alt[,placemark] (.csv)")
      .require();
  t.add("--map-list", o.map_list, "Map image names (default: every image of --images not a query)");
  t.add("--train-images", o.train_images,
        "Learn the embedding on these images instead of the map's (an independent set)");
  t.add("--placemark-size", o.placemark_size,
        "Consecutive map images per placemark when the truth has no placemark column");
  t.add("--segment-placemarks", o.segment_rule.placemarks_per_segment, "Placemarks per segment");
  t.add("--overlap", o.segment_rule.overlap, "Placemarks shared by neighbouring segments");
  t.add("--dims", o.dims, "Embedding dimensions to compare (0: full whitening, k*128)");
  t.add("--k", o.embedding.vocabulary_size, "Vocabulary size");
  t.add("--alpha", o.embedding.power_law_alpha, "Power-law exponent");
  t.add("--eigenvalue-floor", o.embedding.eigenvalue_floor,
        "Whitening regularization: eigenvalues below floor * mean are raised to it");
  t.add("--whitening-descriptors", o.embedding.max_whitening_descriptors,
        "Descriptors sampled to learn centring and whitening");
  t.add("--seed", o.embedding.seed, "Seed (sampling, k-means, synthetic distractors)");
  t.flag("--democratic", o.democratic, "Also measure democratic aggregation (exact search)");
  t.flag("--vlad-ivfpq", o.vlad_ivfpq, "Also measure VLAD with the IVF-PQ index");
  t.add("--nlist", o.index.nlist, "IVF cells");
  t.add("--nprobe", o.index.nprobe, "IVF cells visited per query");
  t.add("--pq-bytes", o.index.pq_bytes, "PQ sub-quantizers (bytes per image code)");
  t.add("--pq-bits", o.index.pq_bits, "Bits per PQ sub-code");
  t.flag("--precomputed-tables", o.index.precomputed_tables,
         "IVF-PQ precomputed residual tables (faster, nlist*M*2^b floats)");
  t.add("--top-images", o.voter.top_images, "N_t for the candidate statistics (top1, cand)");
  t.add("--max-candidates", o.voter.max_candidates, "At most this many candidate segments");
  t.choice("--weighting", o.voter.weighting,
           {{"one", VoteWeighting::kOnePerImage}, {"rank", VoteWeighting::kReciprocalRank}},
           "Votes: one (per retrieved image) or rank (1/(rank+1))");
  t.add("--max-view-angle", o.truth_options.max_view_angle_deg,
        "Truth: map images facing within this angle of the query (degrees)");
  t.add("--search-threads", o.search_threads, "OpenMP threads while timing queries");
  t.add("--synthetic-size", o.synthetic_size, "Images of the synthetic index (real map + distractors); 0 skips it");
  t.add("--synthetic-noise", o.synthetic_noise,
        "Distractor = normalize(real map embedding + Gaussian noise of this norm)");
  t.add("--synthetic-exact", o.synthetic_exact, "Also time exact search on the synthetic index");
  add_options(t, o.sift);
}

void add_options(OptionTable& t, RetrievalMapBuildOptions& o) {
  t.add("--images", o.images, "Directory of the map images").require();
  t.add("--list", o.image_list, "Image names to use, in route order (default: all, sorted by name)");
  t.add("--gps", o.gps_csv, "GPS CSV image,lat,lon,alt[,placemark]: placemarks for the segments");
  t.add("--out", o.out, "Output directory").require();
  t.add("--placemark-size", o.placemark_size, "Consecutive images per placemark when there is no placemark column");
  t.add("--segment-placemarks", o.segment_rule.placemarks_per_segment, "Placemarks per segment");
  t.add("--overlap", o.segment_rule.overlap, "Placemarks shared by neighbouring segments");
  t.add("--dims", o.embedding.output_dims, "Embedding dimensions (0: full whitening, k*128)");
  t.add("--k", o.embedding.vocabulary_size, "Vocabulary size");
  t.add("--eigenvalue-floor", o.embedding.eigenvalue_floor, "Whitening regularization");
  t.add("--nlist", o.index.nlist, "IVF cells");
  t.add("--nprobe", o.index.nprobe, "IVF cells visited per query");
  t.add("--pq-bytes", o.index.pq_bytes, "PQ bytes per image");
  add_options(t, o.sift);
}

void add_options(OptionTable& t, RetrievalMapQueryOptions& o) {
  t.add("--map", o.map, "Retrieval map directory (visloc retrieval build, or MAP/retrieval of a map)").require();
  t.add("images", o.images, "Query images").require();
  t.add("--top-images", o.voter.top_images, "N_t: retrieved images that vote");
  t.add("--max-candidates", o.voter.max_candidates, "At most this many segments");
  t.add("--nprobe", o.nprobe, "IVF cells visited (0: the map's)");
  add_options(t, o.sift);
}

void add_options(OptionTable& t, EndToEndBenchmarkOptions& o) {
  t.add("--map", o.map, "Map directory").require();
  t.add("--queries", o.queries, "Query image names, one per line").require();
  t.add("--images", o.images_dir, "Directory of the query images (with --query-features images)");
  t.add("--truth", o.truth, "Reference poses 'name qw qx qy qz tx ty tz' (the map's frame)").require();
  t.add("--intrinsics", o.intrinsics, "Per-image intrinsics 'name MODEL w h params...'");
  t.choice("--query-features", o.query_features,
           {{"images", QueryFeatureSource::kImages}, {"database", QueryFeatureSource::kDatabase}},
           "'images' (our SIFT) or 'database' (the model's own)");
  t.add("--settings", o.settings, "Settings to run, in order (space- or comma-separated)").split_at(',');
  t.add("--repeat", o.repeat, "Localize each query this many times per setting (times: median)");
  add_options(t, o.localizer);  // its --setting is replaced by each of --settings
}

void add_options(OptionTable& t, FeatureBenchmarkOptions& o) {
  t.add("images", o.inputs, "Image files or directories (searched recursively)").require();
  t.add("--max-side", o.max_sides, "Maximum image sides to measure");
  add_options(t, o.sift, false);
}

void add_options(OptionTable& t, SiftColmapBenchmarkOptions& o) {
  t.add("--scene", o.scenes, "Scene directory with images/ and colmap/database.db").require();
  t.add("--ratio", o.ratio, "Ratio test threshold");
  t.add("--threshold", o.threshold_px, "Fundamental matrix RANSAC threshold, pixels");
  t.add("--max-side", o.max_image_side, "Maximum image side for our SIFT");
}

void add_options(OptionTable& t, MatchingBenchmarkOptions& o) {
  t.add("--database", o.database, "COLMAP database with the queries' features (default: the map's source database)");
  t.flag("--extract", o.extract, "Extract query features from image files with our SIFT instead");
  t.add("--images", o.images, "Image directory for --extract");
  t.add("--max-queries", o.max_queries, "Use at most this many queries per map (0: all)").no_default();
  t.add("--ratio", o.ratio, "Ratio test of the 1-1 sets (ν_h)");
  t.add("--inlier-px", o.inlier_px, "Reprojection threshold with the reference pose, pixels");
  t.add("--method", o.methods, "Only methods whose name starts with this (repeatable; rerank-* run only when named)");
  add_options(t, o.sift);
}

void add_options(OptionTable& t, PoseBenchmarkOptions& o) {
  t.add("--family", o.families, "Families: calibrated, uncalibrated, facade");
  t.add("--inlier-ratio", o.inlier_ratios, "Inlier ratios of the 1-1 set");
  t.add("--features", o.features, "Numbers of query features");
  t.add("--trials", o.trials, "Trials per (family, features, inlier ratio)");
  t.add("--noise", o.noise_px, "Pixel noise (standard deviation)");
  t.add("--max-candidates", o.max_candidates, "Candidate list length M");
  t.add("--seed", o.seed, "Seed of the problems and the estimators");
  t.add("--threshold", o.ransac.threshold_px, "Reprojection threshold, pixels");
  t.add("--max-iterations", o.ransac.max_iterations, "Sample cap of the adaptive RANSACs");
  t.add("--fixed-iterations", o.ransac.fixed_iterations, "Samples of 1-M fixed");
  t.add("--opencv-iterations", o.opencv_iterations, "Iteration cap of OpenCV's RANSACs");
  t.flag("!--no-opencv", o.opencv, "Skip the OpenCV baselines");
}

}  // namespace visloc
