// Image pairs with the paper's one-many RANSAC (`visloc match`; its facade
// figure): SIFT on both images, matches from image 1 to image 2 by exact
// nearest neighbours, a 1-1 set for the hypotheses (ratio ν_h = 0.8) and a
// 1-M set for the verification (ratio ν = 0.9, up to M = 5 candidates),
// then two-view RANSAC (pose/two_view_ransac.h): F, H, or E with both
// cameras calibrated. Map building can call match_feature_sets +
// estimate_two_view to verify a segment's pairs.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/features/feature_set.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/pose/two_view_ransac.h"

namespace visloc {

struct PairMatchingOptions {
  float ratio_one_to_one = 0.8f;   // ν_h: the 1-1 set (hypotheses)
  float ratio_one_to_many = 0.9f;  // ν: the 1-M set (verification)
  int max_candidates = 5;          // M
  // kGroupRatio (default here): a feature keeps the candidates before the
  // first j ≥ 1 with d0/dj < ν (a group of near-equal candidates: repeated
  // windows); kBestRatio: the top M when d0/d1 < ν (cascade_index.h).
  OneToManyRule rule = OneToManyRule::kGroupRatio;
  void validate() const;
};

// Matches from a to b. Features with no acceptable candidate are left out.
TwoViewCorrespondences match_feature_sets(const FeatureSet& a, const FeatureSet& b, const PairMatchingOptions& options);

// Verifying one image pair of a map (map building's `--matcher twoview`):
// match_feature_sets, then estimate_two_view with the options' model, F or
// E (E needs both calibrations; the caller sets them), and the inliers as
// feature index pairs, as a COLMAP database's two-view geometry holds them.
struct PairVerificationOptions {
  PairMatchingOptions matching;
  // 1m-sprt; Sampson threshold 4 px, COLMAP's verification (max_error) and
  // the guided matcher's epipolar band, so that the matchers compare on
  // matching and RANSAC rather than on a tighter or looser band.
  TwoViewOptions estimation = [] {
    TwoViewOptions o;
    o.threshold_px = 4.0;
    return o;
  }();
  // The pair is verified by the model's 1-1 inliers (hypothesis-set features
  // whose 1-1 match fits), for every variant: at least min_inliers of them
  // (COLMAP's min_num_inliers) and at least min_inlier_ratio of the 1-1
  // matches (COLMAP's min_inlier_ratio). The 1-M set's extra candidates let
  // a wrong model gather inliers by chance, even between views that do not
  // overlap; they add inliers to a verified pair only.
  size_t min_inliers = 15;
  double min_inlier_ratio = 0.25;
  void validate() const;
};

struct VerifiedPair {
  bool verified = false;  // the model passed PairVerificationOptions' rules
  // Each matched feature of image 1 with its best candidate (COLMAP's raw
  // `matches`); the inliers: each inlier feature with the candidate that
  // fits, one per feature of image 2 (the 1-1 inlier, else the lowest
  // Sampson error, wins a feature of image 2 that several chose), sorted.
  std::vector<std::pair<uint32_t, uint32_t>> matches, inliers;
  TwoViewEstimate estimate;
};

VerifiedPair verify_image_pair(const FeatureSet& a, const FeatureSet& b, const PairVerificationOptions& options);

struct ImagePairOptions {
  SiftOptions sift;
  PairMatchingOptions matching;
  TwoViewOptions estimation;
  void validate() const;
};

struct ImagePairResult {
  FeatureSet features1, features2;
  TwoViewCorrespondences matches;
  TwoViewEstimate estimate;
  double ms_features = 0, ms_matching = 0;
  size_t one_to_one_matches() const;
  nlohmann::json to_json() const;
};

ImagePairResult match_image_pair(const std::filesystem::path& image1, const std::filesystem::path& image2,
                                 const ImagePairOptions& options);

// The inliers drawn side by side (both images scaled to `max_height`):
// 1-1 inliers in green, the extra inliers that 1-M verification found in
// orange (the paper's facade figure); every inlier a dot, lines for at most
// 120 of each kind. Atomic write; the format follows the extension.
void draw_pair_inliers(const std::filesystem::path& image1, const std::filesystem::path& image2,
                       const ImagePairResult& result, const std::filesystem::path& out, int max_height = 900);

// What `visloc match` is given: the pair; the model (none: E when the
// cameras are known, else F); the cameras: one focal length for both images
// (principal point at the centre) or an intrinsics file ('name MODEL width
// height params...' per image file name, '*' for all), neither: uncalibrated;
// where to draw the inliers (empty: nowhere).
struct ImagePairTask {
  std::filesystem::path image1, image2;
  std::optional<TwoViewModel> model;
  double focal = 0;
  std::filesystem::path intrinsics;
  std::filesystem::path drawing;
  ImagePairOptions options;
};

class OptionTable;
// `visloc match`'s options: image1, image2, --model, --ransac, --focal,
// --intrinsics, --out, --threshold, --iterations, --max-candidates, --rule,
// --max-features, --max-side, --seed.
void add_options(OptionTable& table, ImagePairTask& task);

// The task's options with its model (none: E or F) and, for E, both cameras'
// calibrations. Throws Error(kInvalidArgument) naming the option or the
// intrinsics file when the cameras are missing, given twice or do not fit.
ImagePairOptions resolve_image_pair_options(const ImagePairTask& task);

// The result as `visloc match` prints it: feature and match counts, the
// model's inliers and RANSAC counts, its matrix, times and, when `drawing` is
// not empty, "wrote DRAWING"; only the counts and "no F found" without a model.
std::string image_pair_summary(const ImagePairResult& result, const TwoViewOptions& estimation,
                               const std::filesystem::path& drawing);

}  // namespace visloc
