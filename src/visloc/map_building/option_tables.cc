// The map building options as command-line options (util/option_table.h):
// `visloc map build` (MapBuildOptions) and `visloc map import` (its sources
// and ColmapImportOptions).
#include <climits>
#include <optional>
#include <string>

#include "visloc/map_building/colmap_import.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/util/option_table.h"

namespace visloc {
namespace {

void add_hash_rotation(OptionTable& t, HashRotationScope& scope, std::string help) {
  t.choice("--hash-rotation", scope, {{"segment", HashRotationScope::kSegment}, {"map", HashRotationScope::kMap}},
           std::move(help));
}

constexpr const char* kPqBytesHelp =
    "Bytes per PQ code of a map point (the codes that rank a feature's candidates; not the retrieval "
    "index's): 16 (the paper's; 44 bytes per point with float32 coordinates, 38 with int16) or 32 (16 bytes "
    "more per point, a finer ranking: bench matching measured 0.90 of exact matching's 1-1 matches against "
    "0.755 on the Strecha scenes; segment format version 4)";

constexpr const char* kPqQuantizerHelp =
    "The PQ codes' quantizer: 'product' (the paper's: M sub-vectors, a centroid each) or 'residual' (16-byte "
    "codes of 16 codebooks added over --pq-residual-splits parts of the descriptor, trained and encoded by "
    "FAISS's residual quantizer: the same bytes per point, a finer ranking, a slower precise step; on the "
    "Strecha scenes FAISS's quantizers of this kind kept 0.87 of exact matching's 1-1 matches at 2 splits "
    "(0.90 at 1, 0.82 at 4) against 0.755 for the PQ; training takes seconds (fountain-P11: 6 s); codebook format "
    "version 3)";

constexpr const char* kResidualSplitsHelp =
    "With --pq-quantizer residual: parts of the descriptor (128 / S dimensions, 16 / S codebooks each); "
    "fewer parts rank better and cost more per candidate (a candidate reads 16 × 128 / S floats of codebook)";
constexpr const char* kResidualBeamHelp =
    "With --pq-quantizer residual: the beam of the codebooks' training and of the encoding, 1 to 64; a wider "
    "beam encodes closer and trains and encodes longer (on the Strecha scenes 1 ranked as well as FAISS's "
    "default 5, 0.872 against 0.869 of exact matching's 1-1 matches, and trained 3.6x faster with progressive "
    "k-means)";

// Training only: a resumed build, which keeps its codebook, ignores it.
void add_residual_kmeans(OptionTable& t, PqTrainingOptions& o) {
  t.choice("--pq-residual-kmeans", o.residual_progressive_dim, {{"progressive", true}, {"plain", false}},
           "With --pq-quantizer residual: each codebook's k-means, 'plain' (one run) or 'progressive' in the "
           "dimensions (FAISS's default: k-means on a growing prefix of the dimensions, several runs); on the "
           "Strecha scenes both ranked alike (0.871 and 0.872 of exact matching's 1-1 matches) and progressive "
           "trained 38x longer); training only: a resumed build keeps its codebook and ignores it");
}

void add_residual_options(OptionTable& t, PqTrainingOptions& o) {
  t.choice("--pq-residual-splits", o.residual_splits, {{"1", 1}, {"2", 2}, {"4", 4}}, kResidualSplitsHelp);
  t.add("--pq-residual-beam", o.residual_beam, kResidualBeamHelp).range(1, kResidualMaxBeam);
  add_residual_kmeans(t, o);
}

// A whole-number option of `map build` left empty unless given (an existing
// map's value then applies): a value `valid` refuses names `choices`.
void add_optional_whole_choice(OptionTable& t, const std::string& flag, std::optional<int>& field, bool (*valid)(int),
                               const std::string& choices, std::string help) {
  t.text(
      flag, "",
      [&field, flag, valid, choices](const std::string& text) {
        if (text.empty()) return;
        const int64_t value = parse_whole_number(text, flag, INT_MIN, INT_MAX);
        if (!valid(int(value)))
          throw_error(ErrorCode::kInvalidArgument, flag, ": '", text, "' is not one of the choices (", choices, ")");
        field = int(value);
      },
      std::move(help));
}

// --pq-residual-splits / --pq-residual-beam of `map build`: empty unless
// given (an existing map keeps its codebook's; resolve_pq_residual).
void add_resumable_residual_options(OptionTable& t, MapBuildOptions& o) {
  add_optional_whole_choice(t, "--pq-residual-splits", o.pq_residual_splits, valid_residual_splits, "1, 2, 4",
                            std::string(kResidualSplitsHelp) + "; default: the existing map's, 2 for a new map");
  t.text(
      "--pq-residual-beam", "",
      [&o](const std::string& text) {
        if (text.empty()) return;
        o.pq_residual_beam = int(parse_whole_number(text, "--pq-residual-beam", 1, kResidualMaxBeam));
      },
      std::string(kResidualBeamHelp) + "; default: the existing map's, 1 for a new map");
}

void add_point_coordinates(OptionTable& t, SegmentWriteOptions& o) {
  t.choice(
      "--point-coordinates", o.coordinates,
      {{"auto", PointCoordinates::kAuto}, {"float32", PointCoordinates::kFloat32}, {"int16", PointCoordinates::kInt16}},
      "Segment files' point coordinates: 'int16' (6 instead of 12 bytes per point, the segment's box in "
      "65,536 steps), 'float32', or 'auto' (int16 when the worst rounding error is at most 2 mm; segments "
      "without a metric scale keep float32)");
  t.flag("--point-uncertainty", o.point_uncertainty,
         "Store each point's triangulation uncertainty (4 bytes per point): a pose's reported sigma then includes "
         "the map's own error (first-order, not calibrated by a fitted factor), which matters for photos taken "
         "far from the map's cameras. Needs the model's reprojection errors (a segment without any gets none); "
         "resuming a build with it rebuilds the segments made without it");
}

}  // namespace

void add_pq_bytes_option(OptionTable& t, PqTrainingOptions& o) {
  t.choice("--pq-bytes", o.subvectors, {{"16", kPqSubvectors}, {"32", kPqFineSubvectors}}, kPqBytesHelp);
  t.choice("--pq-quantizer", o.quantizer, {{"product", PqQuantizer::kProduct}, {"residual", PqQuantizer::kResidual}},
           kPqQuantizerHelp);
  add_residual_options(t, o);
}

void add_options(OptionTable& t, MapBuildOptions& o) {
  t.add("--images", o.images_dir, "Directory of the map's images").require();
  // 'exif' (no CSV): GPS from each image's EXIF.
  t.text("--gps", o.gps_csv.empty() ? "exif" : o.gps_csv.string(),
         [&o](const std::string& text) {
           o.gps_csv = text == "exif" ? std::filesystem::path() : std::filesystem::path(text);
         },
         "GPS CSV (image,lat,lon,alt[,placemark]) or 'exif'");
  t.flag("--gps-subset", o.gps_lists_subset,
         "The GPS CSV lists a subset of --images: build from those only (default: every image in the folder "
         "must have a line)");
  t.choice("--poses", o.poses, {{"sfm", PoseSource::kSfm}, {"known", PoseSource::kKnown}},
           "Where poses come from: 'sfm' (COLMAP mapper) or 'known' (triangulate)");
  t.add("--known-poses", o.known_poses,
        "With --poses known: a COLMAP model directory (text or binary) with the images' exact poses, "
        "or a pose list 'name qw qx qy qz tx ty tz' (world-to-camera; needs --known-intrinsics)");
  t.add("--known-intrinsics", o.known_intrinsics,
        "With a pose list: intrinsics 'name MODEL width height params...' per line ('*' for every image)");
  t.choice("--matcher", o.matcher,
           {{"auto", PairMatcher::kDefault},
            {"guided", PairMatcher::kGuided},
            {"colmap", PairMatcher::kColmap},
            {"twoview", PairMatcher::kTwoView}},
           "Pair matching: 'guided' (known poses: features near the epipolar line, RootSIFT ratio test; "
           "fast), 'colmap' (COLMAP's matcher and verification), 'twoview' (exact matching with 1-1 and 1-M "
           "sets, verified by two-view RANSAC, see --pair-ransac; E with known poses, else F), 'auto' (guided "
           "with known poses, else colmap)");
  t.add("--sampson", o.guided.max_sampson_px, "Guided matching: epipolar band, Sampson distance (px)");
  t.choice("--pair-ransac", o.pair_verification.estimation.variant,
           {{"classic", RansacVariant::kClassic11},
            {"1m", RansacVariant::kOneManyFixed},
            {"1m-sprt", RansacVariant::kOneManySprt}},
           "--matcher twoview: classic (1-1 hypotheses and verification), 1m (1-M verification, fixed "
           "iterations), 1m-sprt (1-M with SPRT: the paper's one-many RANSAC)");
  t.add("--pair-threshold", o.pair_verification.estimation.threshold_px,
        "--matcher twoview: inlier threshold, Sampson distance (px; COLMAP's verification uses 4)")
      .positive();
  t.choice("--executor", o.executor, {{"local", BuildExecutor::kLocal}, {"slurm", BuildExecutor::kSlurm}},
           "Where segments are built: 'local' (threads, see --jobs) or 'slurm' (one job array; every task "
           "runs 'visloc map build-segment MAP N' on a node that sees the map directory)");
  t.add("--slurm-partition", o.slurm.partition, "Slurm partition (default: the cluster's)");
  t.add("--slurm-cpus", o.slurm.cpus_per_task,
        "CPUs per Slurm task (give --colmap-threads the same to use them in COLMAP)");
  t.add("--slurm-args", o.slurm.extra_args, "More sbatch options for the array, e.g. \"--mem=8G --time=2:00:00\"");
  t.add("--jobs", o.jobs, "Local executor: segments built in parallel (0: number of cores)");
  t.add("--colmap", o.colmap.binary, "COLMAP executable");
  t.add("--colmap-threads", o.colmap.threads, "Threads per COLMAP call");
  t.add("--exhaustive-max", o.exhaustive_max_images,
        "COLMAP exhaustive matching for segments up to this many images, spatial matching above");
  t.add("--spatial-neighbors", o.colmap.spatial_max_neighbors,
        "Spatial matching: nearest images matched to each image");
  t.add("--min-placemarks", o.plan.min_placemarks, "Placemarks per segment, at least");
  t.add("--max-placemarks", o.plan.max_placemarks, "Placemarks per segment, at most");
  t.add("--overlap", o.plan.overlap, "Placemarks shared by consecutive segments");
  t.add("--placemark-radius", o.plan.placemark_radius,
        "Metres: consecutive images this close form a placemark (without a placemark column)");
  t.action("--chain-order", [&o] { o.plan.order = PlacemarkOrder::kChain; },
           "Order placemarks by nearest-neighbour chaining (unordered collections) instead of capture order");
  t.add("--registration-threshold", o.registration.inlier_threshold,
        "Metres: GPS inlier threshold of the geo-registration");
  t.add("--retrieval-dims", o.embedding.output_dims,
        "Retrieval embedding dimensions after PCA-whitening (0: full 4096)");
  t.flag("!--no-retrieval", o.build_retrieval, "Do not build the retrieval index");
  add_fit_blend_options(t, o.fit_hash_blend);
  t.add("--pq-training-images", o.pq_training_images,
        "The PQ codebook trains on at most this many images, spread over the map (with --executor slurm "
        "only their features are extracted before the array; each task extracts its segment's)");
  t.text(
      "--hash-rotation", "",
      [&o](const std::string& text) {
        if (!text.empty()) o.hash_rotation = parse_hash_rotation_scope(text);
      },
      "ITQ hash rotation: 'map' (one for the map, MAP/hash_rotation.vlitq: 64 KiB less per segment, a query "
      "hashed once, and the localizer can vote for segments with the query's local features) or 'segment' "
      "(one per segment, in its file); default: the existing map's, 'map' for a new map");
  add_point_coordinates(t, o.segment_file);
  add_optional_whole_choice(t, "--pq-bytes", o.pq_code_bytes, valid_pq_subvectors, "16, 32",
                            std::string(kPqBytesHelp) + "; default: the existing map's, 16 for a new map");
  t.text(
      "--pq-quantizer", "",
      [&o](const std::string& text) {
        if (text.empty()) return;
        if (text == "product")
          o.pq_quantizer = PqQuantizer::kProduct;
        else if (text == "residual")
          o.pq_quantizer = PqQuantizer::kResidual;
        else
          throw_error(ErrorCode::kInvalidArgument, "--pq-quantizer: '", text,
                      "' is not one of the choices (product, residual)");
      },
      std::string(kPqQuantizerHelp) + "; default: the existing map's, 'product' for a new map");
  add_resumable_residual_options(t, o);
  add_residual_kmeans(t, o.pq);
  add_options(t, o.sift);
}

void add_options(OptionTable& t, MapImportSources& s) {
  t.add("--colmap", s.colmap_model, "COLMAP model directory (cameras/images/points3D, .bin or .txt)");
  t.add("--database", s.database, "COLMAP database.db holding the model's keypoints and descriptors");
  t.add("--bundler", s.bundle_file, "Bundler v0.3 bundle.out (plain or gzip)");
  t.add("--list", s.bundler_list, "Bundler image list (\"name [0 focal]\" per camera of bundle.out)");
  t.add("--keys", s.bundler.keys_dir,
        "Folder of the Lowe key files (NAME.key or NAME.key.gz, NAME the listed image name or its\n"
        "file name, extension replaced); default: next to the listed images, relative to the list");
  t.add("--images", s.bundler.images_dir,
        "Bundler: image folder; the principal point is the image centre read from each image's size\n"
        "(default: derived from the key files and the views' centred coordinates; unused by --colmap)");
  t.action("--raw-sift", [&s] { s.bundler.root_sift = false; },
           "Bundler: keep Lowe's L2 SIFT integers instead of converting them to RootSIFT\n"
           "(our queries and COLMAP's features are RootSIFT: keep the default unless the queries are raw too)");
  t.add("--holdout", s.holdout_list,
        "File listing images to remove from the model (Dubrovnik protocol) and keep as queries\n"
        "(Bundler: names as written in the list)");
  t.add("--pq-train-images", s.pq_training_list, "File listing the images of --pq-train-database to use");
}

void add_options(OptionTable& t, ColmapImportOptions& o) {
  t.add("--pq-train-database", o.pq_training_database,
        "Train the PQ codebook on the image descriptors of this COLMAP database (an independent set)\n"
        "instead of a sample of the map's own point descriptors");
  t.add("--itq-iterations", o.itq.iterations, "ITQ iterations");
  add_hash_rotation(t, o.hash_rotation,
                    "ITQ hash rotation stored in the segment ('segment') or in MAP/hash_rotation.vlitq ('map')");
  add_point_coordinates(t, o.segment_file);
  add_pq_bytes_option(t, o.pq);
  t.add("--seed", o.itq.seed, "Seed of ITQ's initial rotation and of PQ training");
  t.action("--no-descriptors", [&o] { o.keep_descriptors = false; },
           "Do not keep the mean descriptors (descriptors/*.vldesc; needed by the raw-SIFT baselines)");
  t.flag("--overwrite", o.overwrite, "Replace an existing map in --out");
  add_fit_blend_options(t, o.fit_hash_blend);
}

void add_fit_blend_options(OptionTable& t, std::optional<bool>& fit) {
  t.action(
      "--fit-blend", [&fit] { fit = true; },
      "Fit the cascade search's hash-blend weight on the new map's own data and store it in its manifest (as "
      "`visloc map fit-blend --store`), where localize and eval take it by default; fail if it cannot be "
      "fitted. The default fits it too, but only warns when it cannot (a Bundler import or --no-descriptors "
      "is not fitted)");
  t.action(
      "--no-fit-blend", [&fit] { fit = false; },
      "Do not fit the hash-blend weight: the search ranks by the PQ distance alone on the new map (a weight "
      "stored earlier stays, for the segments it was fitted on)");
}

}  // namespace visloc
