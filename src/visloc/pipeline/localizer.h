// Localizer: one photo in, a pose on the map out (DESIGN.md "Localization"):
//   SIFT → candidate segments: ≤ max_segments (4) by votes, of the query
//   features' nearest map points (segment_point_votes.h; a map with one hash
//   rotation and more than max_segments segments) or of the retrieved images
//   (T-embedding, IVF-PQ, top N_t images; the paper); every segment when the
//   map has neither) → per candidate segment: cascade
//   correspondence search + one-many RANSAC → the segment with the most
//   inliers; registered at ≥ 12 inliers and the confidence threshold. When
//   no pose registers, the next fallback_segments (4) by votes are searched. The pose is reported in the
//   segment's frame and, through the segment's enu_from_segment similarity,
//   as an ENU centre, WGS84 position and heading.
// Thread-safe: localize() may be called concurrently; segments are shared
// through an LRU cache of memory maps under a byte budget.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "visloc/features/sift_extractor.h"
#include "visloc/geo/enu_frame.h"
#include "visloc/geo/similarity_transform.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/pipeline/confidence.h"
#include "visloc/pipeline/segment_point_votes.h"
#include "visloc/pose/one_many_ransac.h"
#include "visloc/util/error.h"

namespace visloc {

// What ranks the candidate segments (issue #13). Measured on the city
// benchmark's 1.2 km map (13 segments, 498 positives, 4 candidates): the true
// segment among the candidates for 73.5% of positives with image votes,
// 93.0% with point votes (8,192 points per segment; 95.8% with all), 77.9%
// with the sum of both shares (the image votes' shares are the more
// concentrated, so they dominate the sum). On a second city (seed 7, 12
// segments) point votes gave 95.3%. Probing radius 1 for the votes (session
// 15, a rebuild of the first city: 495 positives) gave 95.4% against 93.5%,
// and 95.9% against 95.3% on the second, at 3-6× the retrieval time.
enum class SegmentVoteSource {
  kAuto,    // point votes when the map allows them (one hash rotation), else image votes
  kImages,  // the retrieved images' votes (the paper: T-embedding, top N_t images)
  kPoints,  // the query features' nearest map points (segment_point_votes.h)
  kBoth,    // the sum of the two vote shares
};
SegmentVoteSource parse_segment_vote_source(const std::string& name);  // "auto" | "images" | "points" | "both"
const char* to_string(SegmentVoteSource source);

// The paper's ablation (section IV): matching and RANSAC per setting.
enum class PaperSetting {
  k1,      // CCS full search, classical 1-1 RANSAC
  k2,      // CCS full search, 1-M RANSAC with 5000 iterations
  k3,      // CCS prioritized, 1-M RANSAC with 5000 iterations
  k3Plus,  // CCS prioritized, 1-M RANSAC with SPRT (default)
};
PaperSetting parse_paper_setting(const std::string& name);  // "1", "2", "3", "3+"
std::string to_string(PaperSetting setting);

// The query's longer side before SIFT. Measured on KITTI, Strecha and the
// synthetic city (issue #15): 800 px takes half the feature time of 1600 px
// on KITTI and less than half on Strecha, with no registration lost on any
// of the three (the city registered 9 more of 300); 1024 px does not halve
// KITTI's (1241 px images). Maps built from larger images may want more: --max-side.
inline constexpr int kDefaultQueryMaxSide = 800;

// Where the cascade search's hash-blend weight (CascadeSearchOptions::
// hash_blend_weight) comes from.
enum class HashBlendSource {
  kMap,    // the weight fitted on the map and stored in it (MapManifest::
           // fitted_hash_blend: `map fit-blend --store`); 0 when it has none
  kGiven,  // search.hash_blend_weight as given
};

struct LocalizerOptions {
  // Query features: the map builder's SIFT settings, except that the longer
  // side is capped at 800 px instead of 1600 (kDefaultQueryMaxSide).
  SiftOptions sift = [] {
    SiftOptions o;
    o.max_image_side = kDefaultQueryMaxSide;
    return o;
  }();
  CascadeSearchOptions search;      // CCS parameters
  // kMap: search.hash_blend_weight is replaced by the map's fitted weight (0
  // on a map without one) when the map is opened; Localizer::options() shows
  // the weight used.
  HashBlendSource hash_blend_source = HashBlendSource::kMap;
  RansacOptions ransac;             // pose parameters
  PaperSetting setting = PaperSetting::k3Plus;  // overrides search.prioritize and ransac.variant
  int top_images = 20;              // N_t
  int max_segments = 4;             // candidate segments searched first
  // When the candidate segments give no registered pose, search this many
  // more, the next by votes, the same way (0: none). Only queries that would
  // otherwise fail pay for them. On the city benchmark's 13-segment map the
  // true segment was ranked 5-8 for 19 of 495 positives and below 8 for 4.
  int fallback_segments = 4;
  // Point votes need a map with one hash rotation (map build --hash-rotation
  // map, the default for new maps) and are used only on a map of more
  // segments than max_segments. auto: point votes, the retrieved images
  // filling the places they leave; image votes alone on other maps.
  SegmentVoteSource segment_votes = SegmentVoteSource::kAuto;
  SegmentPointVoteOptions point_votes;
  // Stop searching further candidate segments once a registered pose has
  // this many inliers (0: search them all and keep the best, as the paper does).
  // Measured on KITTI with 4 segments: RANSAC on the wrong segments cost
  // 70 ms of 135 ms per query.
  int accept_inliers = 50;
  uint64_t cache_bytes = 512ull << 20;  // segment cache budget
  bool use_exif_focal = true;       // EXIF focal (when present) makes the query calibrated
  // Settings 3 and 3+: when the prioritized search gives no registered pose,
  // search all features of the candidates once more (not in the paper; it
  // costs time only on queries that would otherwise fail).
  bool full_search_fallback = true;
  // Registered only when the pose's confidence (confidence.h) is at least
  // this, besides ransac.min_inliers. The default is the builtin model's
  // threshold, chosen for a precision of ≥ 99.5% on its fit data; 0 keeps
  // every pose with enough inliers (the paper's rule).
  double min_confidence = kDefaultMinConfidence;
  // ... and, on a geo-registered segment, only when its camera is not under
  // the street (confidence.h, UnderStreetOptions).
  UnderStreetOptions under_street;
  // Include the map points' triangulation uncertainty (a segment's section
  // PTUNC) in a pose's covariance, and so in its reported σ. Off: the σ of
  // the photo's keypoint noise alone, as for a map without it.
  bool map_point_uncertainty = true;
  void validate() const;
};

class OptionTable;
// The options as command-line options: --setting, --top-images, ...,
// --min-confidence, the query's SIFT options, --cache-mib.
void add_options(OptionTable& table, LocalizerOptions& options);
// "map" → kMap (weight untouched); a number in [0, 1] → kGiven and the
// weight. Throws Error(kInvalidArgument) otherwise.
HashBlendSource parse_hash_blend(const std::string& text, float& weight);
// "map", or the given weight.
std::string hash_blend_text(const LocalizerOptions& options);

struct StageTimes {
  double features = 0, retrieval = 0, matching = 0, ransac = 0, total = 0;  // milliseconds
};

// 1σ uncertainty of a pose, from the covariance of its refinement on the
// inliers (pose_refinement.h, pose_covariance): the residual noise the
// inliers show, propagated to the camera centre and heading, each σ times
// the confidence model's sigma_scale (calibrated so that σ is the radius of
// 68% of the position errors on the model's training cities; pipeline/confidence.h).
// In the segment frame's units, and in metres / degrees of the ENU frame when
// the segment is geo-registered (as a GNSS receiver or ARCore reports its
// accuracy).
struct PoseUncertainty {
  bool valid = false;
  double position_sigma = 0;       // sigma_scale × sqrt(trace Σ_centre), segment units
  double rotation_sigma_deg = 0;   // sqrt(trace Σ_ω)
  // position_sigma over the inliers' 90th-percentile depth: unit-free, so it
  // compares across maps of any scale (0 when the depth is unknown).
  double relative_position_sigma = 0;
  std::optional<double> position_sigma_m, horizontal_sigma_m, vertical_sigma_m, heading_sigma_deg;
  double sigma_scale = 1;              // the factor applied
  bool map_point_uncertainty = false;  // the covariance includes the map points' uncertainty
};

// The uncertainty of a pose from the covariance of its refinement (valid):
// every σ is sigma_scale × the covariance's; the metre and heading σ are set
// when enu_from_segment is given (a geo-registered segment). Records the
// scale and whether the covariance included the map points' uncertainty.
PoseUncertainty pose_uncertainty(const PoseCovariance& covariance, const CameraPose& cam_from_segment,
                                 const std::optional<Similarity3d>& enu_from_segment, double sigma_scale);

struct LocalizationResult {
  std::string image;
  bool registered = false;
  std::string error;                 // a bad image: the reason (the rest go on)
  ErrorCode error_code = ErrorCode::kInternal;  // its kind, meaningful when error is set
  int segment = -1;                  // segment id of the best pose
  size_t inliers = 0;
  // Score in [0, 1] that the pose is right (confidence.h), 0 without a pose;
  // registered = inliers ≥ min_inliers and confidence ≥ min_confidence (and
  // the camera not under the street).
  double confidence = 0;
  ConfidenceFeatures confidence_features;  // what it was computed from (segment ≥ 0)
  PoseUncertainty uncertainty;
  // The under-street check of the best pose (assessed on a geo-registered
  // segment); under_street.under_street keeps the pose from registering.
  UnderStreetAssessment under_street;
  CameraPose cam_from_segment;       // world-to-camera in the segment frame
  double focal_px = 0;
  bool focal_estimated = false;
  // With an estimated focal: the estimated principal point minus the assumed
  // one (the image centre), pixels; the pose reprojects with both.
  Eigen::Vector2d principal_point_offset = Eigen::Vector2d::Zero();
  std::optional<Eigen::Vector3d> center_enu;
  std::optional<GeoPosition> position;   // WGS84
  std::optional<double> heading_deg;
  std::vector<int> candidates;       // segment ids searched, in order
  // Retrieval's candidate segments (ids, best first) with their votes, how
  // many segments received a vote and the votes in all: how decisive the
  // retrieval was. Image votes alone: the retrieved images' votes and their
  // sum, as the paper's voting gives them. With point votes: a segment's
  // share of each source's votes (summed with both; 0 for a segment that
  // only the images filled in), and the total is the number of sources.
  // Up to max_segments + fallback_segments: the fallback ones are listed
  // whether or not they were searched (`candidates` has those searched).
  // Empty / 0 when every segment is searched.
  std::vector<int> retrieval_segments;
  std::vector<float> retrieval_votes;
  size_t retrieval_voted_segments = 0;
  float retrieval_total_votes = 0;
  bool full_search_fallback = false; // the prioritized search failed; all features were searched
  bool fallback_segments_searched = false;  // no pose registered in the first max_segments candidates
  size_t features = 0;
  size_t matches_one_to_one = 0;     // of the best segment
  StageTimes times;
};

class Localizer {
 public:
  Localizer(const std::filesystem::path& map_dir, const LocalizerOptions& options = {});
  ~Localizer();
  Localizer(const Localizer&) = delete;
  Localizer& operator=(const Localizer&) = delete;

  // From an image file. `intrinsics` overrides EXIF; without either the focal
  // length is estimated (6-point DLT).
  LocalizationResult localize_file(const std::filesystem::path& image,
                                   const std::optional<PinholeCamera>& intrinsics = std::nullopt) const;
  // From decoded pixels (a camera frame in memory: no EXIF). `intrinsics`
  // (width/height 0: the image's, principal point at its centre) or, without
  // them, an estimated focal length. Unlike localize_file, a bad image or bad
  // intrinsics throw Error (kInvalidArgument) instead of filling `error`.
  LocalizationResult localize_image(const GrayImage& image,
                                    const std::optional<PinholeCamera>& intrinsics = std::nullopt) const;
  // From features already extracted (e.g. from a COLMAP database).
  LocalizationResult localize_features(const FeatureSet& features, const PinholeCamera& camera) const;

  const LocalizerOptions& options() const { return options_; }
  size_t num_segments() const;
  bool has_retrieval() const;
  // The point-vote index (SegmentPointVotes), when this map and the options have one.
  bool has_point_votes() const;
  size_t point_vote_bytes() const;
  uint64_t cache_resident_bytes() const;

 private:
  struct Impl;
  LocalizerOptions options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace visloc
