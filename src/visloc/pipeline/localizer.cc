#include "visloc/pipeline/localizer.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <unordered_map>

#include "visloc/map/map.h"
#include "visloc/matching/cascade_correspondences.h"
#include "visloc/geo/similarity_transform.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/pipeline/segment_cache.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

PaperSetting parse_paper_setting(const std::string& name) {
  if (name == "1") return PaperSetting::k1;
  if (name == "2") return PaperSetting::k2;
  if (name == "3") return PaperSetting::k3;
  if (name == "3+") return PaperSetting::k3Plus;
  throw_error(ErrorCode::kInvalidArgument, "setting must be 1, 2, 3 or 3+, got '", name, "'");
}

std::string to_string(PaperSetting s) {
  switch (s) {
    case PaperSetting::k1: return "1";
    case PaperSetting::k2: return "2";
    case PaperSetting::k3: return "3";
    case PaperSetting::k3Plus: return "3+";
  }
  return "?";
}

void LocalizerOptions::validate() const {
  sift.validate();
  search.validate();
  ransac.validate();
  if (top_images < 1) throw_error(ErrorCode::kInvalidArgument, "top_images must be >= 1, got ", top_images);
  if (max_segments < 1) throw_error(ErrorCode::kInvalidArgument, "max_segments must be >= 1, got ", max_segments);
  if (fallback_segments < 0)
    throw_error(ErrorCode::kInvalidArgument, "fallback_segments must be >= 0, got ", fallback_segments);
  if (max_segments > std::numeric_limits<int>::max() - fallback_segments)
    throw_error(ErrorCode::kInvalidArgument, "max_segments + fallback_segments is too large");
  if (accept_inliers < 0)
    throw_error(ErrorCode::kInvalidArgument, "accept_inliers must be >= 0, got ", accept_inliers);
  if (cache_bytes < (1u << 20)) throw_error(ErrorCode::kInvalidArgument, "cache_bytes must be at least 1 MiB");
  if (!(min_confidence >= 0 && min_confidence <= 1))
    throw_error(ErrorCode::kInvalidArgument, "min_confidence must be in [0, 1], got ", min_confidence);
  point_votes.validate();
  under_street.validate();
}

HashBlendSource parse_hash_blend(const std::string& text, float& weight) {
  if (text == "map") return HashBlendSource::kMap;
  size_t used = 0;
  double w = std::numeric_limits<double>::quiet_NaN();
  try {
    if (!text.empty() && !std::isspace(static_cast<unsigned char>(text[0]))) w = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || !(w >= 0 && w <= 1))
    throw_error(ErrorCode::kInvalidArgument, "the hash blend must be 'map' or a weight in [0, 1], got '", text, "'");
  weight = static_cast<float>(w);
  return HashBlendSource::kGiven;
}

std::string hash_blend_text(const LocalizerOptions& options) {
  if (options.hash_blend_source == HashBlendSource::kMap) return "map";
  std::ostringstream s;
  s << options.search.hash_blend_weight;
  return s.str();
}

SegmentVoteSource parse_segment_vote_source(const std::string& name) {
  if (name == "auto") return SegmentVoteSource::kAuto;
  if (name == "images") return SegmentVoteSource::kImages;
  if (name == "points") return SegmentVoteSource::kPoints;
  if (name == "both") return SegmentVoteSource::kBoth;
  throw_error(ErrorCode::kInvalidArgument, "segment votes must be 'auto', 'images', 'points' or 'both', got '", name,
              "'");
}

const char* to_string(SegmentVoteSource source) {
  switch (source) {
    case SegmentVoteSource::kAuto:
      return "auto";
    case SegmentVoteSource::kImages:
      return "images";
    case SegmentVoteSource::kPoints:
      return "points";
    case SegmentVoteSource::kBoth:
      return "both";
  }
  return "?";
}

namespace {

struct SegmentFrame {
  Similarity3d enu_from_segment;
  bool georegistered = false;
};

SegmentFrame segment_frame(const Segment& seg) {
  SegmentFrame f;
  if (!seg.enu_from_segment()) return f;
  f.enu_from_segment = *seg.enu_from_segment();
  f.georegistered = true;
  return f;
}

}  // namespace

PoseUncertainty pose_uncertainty(const PoseCovariance& cov, const CameraPose& cam_from_segment,
                                 const std::optional<Similarity3d>& enu_from_segment, double sigma_scale) {
  PoseUncertainty u;
  const double scale2 = sigma_scale * sigma_scale;
  const Eigen::Matrix3d R = cam_from_segment.rotation_matrix();
  const Eigen::Matrix3d center_cov = scale2 * cov.center(cam_from_segment);
  const Eigen::Matrix3d omega_cov = scale2 * cov.omega_t.topLeftCorner<3, 3>();
  u.valid = true;
  u.sigma_scale = sigma_scale;
  u.map_point_uncertainty = cov.with_point_uncertainty;
  u.position_sigma = std::sqrt(std::max(0.0, center_cov.trace()));
  u.rotation_sigma_deg = std::sqrt(std::max(0.0, omega_cov.trace())) * 180.0 / M_PI;
  if (enu_from_segment) {
    const Eigen::Matrix3d& Rs = enu_from_segment->rotation;
    const double s2 = enu_from_segment->scale * enu_from_segment->scale;
    const Eigen::Matrix3d enu_cov = s2 * Rs * center_cov * Rs.transpose();
    u.position_sigma_m = std::sqrt(std::max(0.0, enu_cov.trace()));
    u.horizontal_sigma_m = std::sqrt(std::max(0.0, enu_cov(0, 0) + enu_cov(1, 1)));
    u.vertical_sigma_m = std::sqrt(std::max(0.0, enu_cov(2, 2)));
    // Heading of d = Rs Rᵀ e_z; with R ← exp([ω]×) R, ∂d/∂ω = Rs Rᵀ [e_z]×.
    Eigen::Matrix3d ez_skew;
    ez_skew << 0, -1, 0, 1, 0, 0, 0, 0, 0;
    const Eigen::Matrix3d dd_domega = Rs * R.transpose() * ez_skew;
    const Eigen::Vector3d d = Rs * cam_from_segment.viewing_direction();
    const double h2 = d.x() * d.x() + d.y() * d.y();
    if (h2 > 1e-12) {
      const Eigen::RowVector3d dh_dd(d.y() / h2, -d.x() / h2, 0);
      const Eigen::RowVector3d g = dh_dd * dd_domega;
      const double var = g * omega_cov * g.transpose();
      u.heading_sigma_deg = std::sqrt(std::max(0.0, var)) * 180.0 / M_PI;
    }
  }
  return u;
}

// The per-query buffers of the search, reused across queries: a query takes
// one from the pool (one per concurrent query) and gives it back.
struct QueryWorkspace {
  CascadeWorkspace cascade;
  std::vector<HashCode> map_codes;  // the query hashed once with the map's rotation
  std::vector<int32_t> map_margins;  // and its bits' margins (query-directed probing)
  HashWorkspace encode;
  std::vector<float> vote_scratch;  // point votes per segment
  SegmentPointVoteResult point_votes;
  CascadeMatches matches;             // of the segment being searched
  CorrespondenceSet correspondences;  // the same matches, as RANSAC takes them
  std::vector<float> point_heights;   // the under-street check's scratch
  GuidedConfirmer guided;             // the guided confirmation's buffers
  std::vector<float> inlier_distances;  // the best pose's inliers' descriptor distances (scratch)
};

class WorkspacePool {
 public:
  std::unique_ptr<QueryWorkspace> take() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (free_.empty()) return std::make_unique<QueryWorkspace>();
    auto w = std::move(free_.back());
    free_.pop_back();
    return w;
  }
  void give_back(std::unique_ptr<QueryWorkspace> w) {
    std::lock_guard<std::mutex> lock(mutex_);
    free_.push_back(std::move(w));
  }

 private:
  std::mutex mutex_;
  std::vector<std::unique_ptr<QueryWorkspace>> free_;
};

struct Localizer::Impl {
  Map map;
  mutable WorkspacePool workspaces;
  std::unique_ptr<SegmentCache> cache;
  std::unique_ptr<RetrievalMap> retrieval;  // null when the map has none
  std::unique_ptr<SegmentPointVotes> point_votes;  // null without a map rotation or when not asked for
  // With point votes: per manifest position, the segments that share an image with it.
  std::vector<std::vector<uint32_t>> related_segments;
  SegmentVoterOptions voting;
  int max_segments = 4;    // candidates searched first (options' max_segments)
  int max_candidates = 8;  // max_segments + fallback_segments
  SegmentVoteSource segment_votes = SegmentVoteSource::kAuto;
  std::optional<EnuFrame> frame;
  std::unique_ptr<SiftExtractor> sift;
  CascadeSearchOptions search;
  RansacOptions ransac;

  // Candidate segments (positions in the manifest), best-voted first; fills
  // the retrieval's fields and time of `res`. Hashes the query with the map's
  // rotation into ws.map_codes when it votes with points (map_codes_ready).
  // retrieval_fill_pending: the retrieved images are still to fill the
  // places of the fallback segments that the point votes left
  // (fill_from_retrieval, only if the fallback segments are searched).
  std::vector<size_t> candidate_segments(const FeatureSet& f, QueryWorkspace& ws, LocalizationResult& res,
                                         bool& map_codes_ready, bool& retrieval_fill_pending) const;
  // Appends the retrieved images' segments not yet among the candidates, up
  // to max_candidates (with 0 votes in res).
  void fill_from_retrieval(const FeatureSet& f, std::vector<size_t>& candidates, LocalizationResult& res) const;
  // The manifest position of the segment with this id, if the map has it.
  std::optional<size_t> manifest_position(int32_t segment_id) const;
  // Appends the segment at manifest position `index` to the candidates, with
  // its votes in res's retrieval fields.
  void take_candidate(size_t index, float votes, std::vector<size_t>& candidates, LocalizationResult& res) const;
  void build_point_votes(const SegmentPointVoteOptions& options);
  class Search;
};

// One query's search over its candidate segments (the steps of
// localize_features after retrieval), keeping the best pose in `res`.
class Localizer::Impl::Search {
 public:
  Search(Impl& impl, const LocalizerOptions& options, const FeatureSet& f, const PinholeCamera& camera,
         QueryWorkspace& ws, LocalizationResult& res, bool map_codes_ready)
      : impl_(impl),
        options_(options),
        f_(f),
        camera_(camera),
        ws_(ws),
        res_(res),
        map_codes_ready_(map_codes_ready),
        map_margins_ready_(map_codes_ready && impl.search.needs_margins()) {}

  // One pass over the candidates with the given search; the best pose wins.
  void search_candidates(const std::vector<size_t>& candidates, const CascadeSearchOptions& search);
  // search_candidates with the map's search options, then assess_best; when
  // no pose is registered and the search is prioritized, every feature of the
  // candidates once more (full_search_fallback).
  void search_pass(const std::vector<size_t>& candidates);
  // Confidence, uncertainty and the geographic pose of the best pose so far.
  // `final_assessment`: after a search pass (not a new best pose's early-stop
  // check), where the explained fraction is always measured and reported.
  void assess_best(bool final_assessment);

 private:
  // Cascade search of one segment into ws_.matches and ws_.correspondences.
  void match_segment(const Segment& seg, const CascadeSearchOptions& search);
  // One-many RANSAC on ws_.correspondences (no pose when the segment cannot win).
  PoseEstimate estimate_segment_pose() const;
  // Records the segment's pose; makes it the result when it has the most inliers.
  // `index`: the segment's manifest position.
  void keep_if_best(size_t index, const std::shared_ptr<const Segment>& seg, const PoseEstimate& pose);
  ConfidenceFeatures confidence_features() const;

  Impl& impl_;
  const LocalizerOptions& options_;
  const FeatureSet& f_;
  const PinholeCamera& camera_;
  QueryWorkspace& ws_;
  LocalizationResult& res_;
  bool map_codes_ready_;
  bool map_margins_ready_;  // ws_.map_margins are this query's
  // The best pose so far.
  size_t best_inliers_ = 0;
  bool best_has_enough_inliers_ = false;
  PoseQuality best_quality_;
  double best_ambiguous_share_ = 0;  // ConfidenceFeatures::ambiguous of the best pose
  double best_elsewhere_share_ = 0;  // ConfidenceFeatures::elsewhere of the best pose
  float best_inlier_distance_p90_ = 0;  // the best pose's inliers' descriptor distances, 90th percentile
  std::shared_ptr<const Segment> best_segment_;
  std::map<int, size_t> inliers_per_segment_;  // best inliers of each segment searched (the margin)
};

Localizer::Localizer(const std::filesystem::path& map_dir, const LocalizerOptions& options)
    : options_(options), impl_(std::make_unique<Impl>()) {
  options_.validate();
  impl_->map = Map::open(map_dir);
  const auto& man = impl_->map.manifest();
  if (man.segments.empty()) throw_error(ErrorCode::kFormat, map_dir.string(), ": the map has no segments");
  if (options_.hash_blend_source == HashBlendSource::kMap)
    options_.search.hash_blend_weight = static_cast<float>(man.fitted_hash_blend().value_or(0.0));
  impl_->cache = std::make_unique<SegmentCache>(impl_->map, options_.cache_bytes);
  impl_->voting.top_images = options_.top_images;
  impl_->max_segments = options_.max_segments;
  impl_->max_candidates = options_.max_segments + options_.fallback_segments;
  // Point votes on a map of more segments than are searched (each query
  // feature's nearest point by the map-wide hash codes); image votes from the
  // retrieval index otherwise, or with both.
  const bool many_segments = static_cast<int>(man.segments.size()) > options_.max_segments;
  const SegmentVoteSource source = options_.segment_votes;
  if (source != SegmentVoteSource::kImages && many_segments && impl_->map.hasher())
    impl_->build_point_votes(options_.point_votes);
  // (auto also loads the image votes: they fill the places point votes leave.)
  if (source != SegmentVoteSource::kPoints && std::filesystem::exists(map_dir / "retrieval"))
    impl_->retrieval = std::make_unique<RetrievalMap>(RetrievalMap::load(map_dir / "retrieval"));
  impl_->segment_votes = source;
  // With both votes, every segment's image votes count in the sum.
  impl_->voting.max_candidates = source == SegmentVoteSource::kBoth && impl_->point_votes
                                     ? static_cast<int>(man.segments.size())
                                     : impl_->max_candidates;
  if (many_segments && !impl_->point_votes &&
      (source == SegmentVoteSource::kPoints || source == SegmentVoteSource::kBoth))
    throw_error(ErrorCode::kFormat, map_dir.string(), ": segment votes '", to_string(source),
                "' need a map with one hash rotation for all its segments (map build --hash-rotation map)");
  if (many_segments && source == SegmentVoteSource::kBoth && !impl_->retrieval)
    throw_error(ErrorCode::kFormat, map_dir.string(), ": segment votes 'both' need the map's retrieval index");
  if (many_segments && !impl_->point_votes && !impl_->retrieval)
    throw_error(ErrorCode::kFormat, map_dir.string(), ": the map has ", man.segments.size(),
                " segments but no retrieval index to choose among them",
                impl_->map.hasher() ? "" : ", and a hash rotation per segment (no point votes)");
  if (man.enu_origin_lat_lon_alt) {
    const auto& o = *man.enu_origin_lat_lon_alt;
    impl_->frame.emplace(GeoPosition{o[0], o[1], o[2]});
  }
  impl_->sift = std::make_unique<SiftExtractor>(options_.sift);
  impl_->search = options_.search;
  impl_->ransac = options_.ransac;
  switch (options_.setting) {
    case PaperSetting::k1:
      impl_->search.prioritize = false;
      impl_->ransac.variant = RansacVariant::kClassic11;
      break;
    case PaperSetting::k2:
      impl_->search.prioritize = false;
      impl_->ransac.variant = RansacVariant::kOneManyFixed;
      break;
    case PaperSetting::k3:
      impl_->search.prioritize = true;
      impl_->ransac.variant = RansacVariant::kOneManyFixed;
      break;
    case PaperSetting::k3Plus:
      impl_->search.prioritize = true;
      impl_->ransac.variant = RansacVariant::kOneManySprt;
      break;
  }
}

Localizer::~Localizer() = default;

void Localizer::Impl::build_point_votes(const SegmentPointVoteOptions& options) {
  auto votes = std::make_unique<SegmentPointVotes>(options);
  const size_t n = map.manifest().segments.size();
  std::vector<size_t> points(n);
  for (size_t i = 0; i < n; ++i) points[i] = map.manifest().segments[i].points;
  const std::vector<size_t> indexed = point_vote_counts(points, options);
  std::unordered_map<std::string, std::vector<uint32_t>> segments_of_image;
  for (size_t i = 0; i < n; ++i) {
    const std::unique_ptr<Segment> seg = map.open_segment(i);
    if (!seg->uses_map_hasher()) return;  // a segment with its own rotation: codes do not compare
    votes->add_segment(static_cast<uint32_t>(i), {seg->index().codes, seg->num_points()}, indexed[i]);
    for (const SegmentImage& image : seg->images()) segments_of_image[image.name].push_back(static_cast<uint32_t>(i));
  }
  // Segments that share an image (overlap placemarks) may hold the same points.
  std::vector<std::vector<uint32_t>> related(n);
  for (const auto& [name, segments] : segments_of_image)
    for (uint32_t a : segments)
      for (uint32_t b : segments)
        if (a != b) related[a].push_back(b);
  votes->finalize(related);
  point_votes = std::move(votes);
  related_segments = std::move(related);
}

size_t Localizer::num_segments() const { return impl_->map.manifest().segments.size(); }
bool Localizer::has_retrieval() const { return impl_->retrieval != nullptr; }
bool Localizer::has_point_votes() const { return impl_->point_votes != nullptr; }
size_t Localizer::point_vote_bytes() const { return impl_->point_votes ? impl_->point_votes->memory_bytes() : 0; }
uint64_t Localizer::cache_resident_bytes() const { return impl_->cache->resident_bytes(); }

LocalizationResult Localizer::localize_file(const std::filesystem::path& image,
                                            const std::optional<PinholeCamera>& intrinsics) const {
  Timer total;
  LocalizationResult res;
  res.image = image.filename().string();
  try {
    ImageMetadata meta;
    FeatureSet f = impl_->sift->extract_file(image, &meta);
    PinholeCamera cam;
    if (intrinsics) {
      cam = *intrinsics;
      if (cam.width == 0 && cam.height == 0) {  // only the focal was given: the rest from the image
        cam.width = meta.width;
        cam.height = meta.height;
        cam.cx = meta.width / 2.0;
        cam.cy = meta.height / 2.0;
      } else if (cam.width != meta.width || cam.height != meta.height) {
        throw_error(ErrorCode::kInvalidArgument, image.string(), ": intrinsics are for a ", cam.width, "x",
                    cam.height, " image but the image is ", meta.width, "x", meta.height);
      }
    } else {
      std::optional<double> focal;
      if (options_.use_exif_focal) focal = meta.focal_px();
      cam = PinholeCamera::centered(meta.width, meta.height, focal);
    }
    const double features_ms = total.elapsed_ms();
    res = localize_features(f, cam);
    res.image = image.filename().string();
    res.times.features = features_ms;
    res.times.total = total.elapsed_ms();
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kInternal) throw;
    res.error = e.what();
    res.error_code = e.code();
    res.times.total = total.elapsed_ms();
  }
  return res;
}

LocalizationResult Localizer::localize_image(const GrayImage& image,
                                             const std::optional<PinholeCamera>& intrinsics) const {
  Timer total;
  if (image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != static_cast<size_t>(image.width) * static_cast<size_t>(image.height))
    throw_error(ErrorCode::kInvalidArgument, "image: ", image.width, "x", image.height, " with ",
                image.pixels.size(), " pixels is not a valid greyscale image");
  if (static_cast<int64_t>(image.width) * image.height > options_.sift.image.max_pixels)
    throw_error(ErrorCode::kInvalidArgument, "image: ", image.width, "x", image.height,
                " is over the limit of ", options_.sift.image.max_pixels, " pixels");
  PinholeCamera cam = PinholeCamera::centered(image.width, image.height);
  if (intrinsics) {
    cam = *intrinsics;
    if (cam.width == 0 && cam.height == 0) {  // only the focal was given: the rest from the image
      cam.width = image.width;
      cam.height = image.height;
      cam.cx = image.width / 2.0;
      cam.cy = image.height / 2.0;
    } else if (cam.width != image.width || cam.height != image.height) {
      throw_error(ErrorCode::kInvalidArgument, "intrinsics are for a ", cam.width, "x", cam.height,
                  " image but the image is ", image.width, "x", image.height);
    }
  }
  cam.validate();
  const FeatureSet f = impl_->sift->extract(image);
  const double features_ms = total.elapsed_ms();
  LocalizationResult res = localize_features(f, cam);
  res.times.features = features_ms;
  res.times.total = total.elapsed_ms();
  return res;
}

std::vector<size_t> Localizer::Impl::candidate_segments(const FeatureSet& f, QueryWorkspace& ws,
                                                        LocalizationResult& res, bool& map_codes_ready,
                                                        bool& retrieval_fill_pending) const {
  Timer t;
  const auto& man = map.manifest();
  std::vector<size_t> candidates;
  if (!retrieval && !point_votes) {
    for (size_t i = 0; i < man.segments.size(); ++i) candidates.push_back(i);
    res.times.retrieval = t.elapsed_ms();
    return candidates;
  }
  const auto take = [&](size_t index, float votes) { take_candidate(index, votes, candidates, res); };
  if (!point_votes) {  // image votes only: the retrieval's candidates and votes as they are
    const RetrievalQueryResult q = retrieval->query(f.descriptors, voting);
    res.retrieval_voted_segments = q.voted_segments;
    res.retrieval_total_votes = q.total_votes;
    for (const SegmentCandidate& c : q.candidates)
      if (const auto index = manifest_position(c.segment)) take(*index, c.votes);
    res.times.retrieval = t.elapsed_ms();
    return candidates;
  }
  // Point votes as shares of their sum, per manifest position; with both
  // sources, plus the image votes' shares.
  // With the bits' margins too when the search will read them (one hash).
  ws.map_codes.resize(f.descriptors.rows());
  ws.map_margins.resize(search.needs_margins() ? f.descriptors.rows() * kHashBits : 0);
  encode_hash(map.hasher()->view(), f.descriptors.data(), f.descriptors.rows(), ws.map_codes.data(), ws.encode,
              search.needs_margins() ? ws.map_margins.data() : nullptr);
  map_codes_ready = true;
  point_votes->vote(ws.map_codes, ws.vote_scratch, ws.point_votes);
  std::vector<std::pair<size_t, float>> ranked;
  float point_sum = 0;
  for (const SegmentPointVote& v : ws.point_votes.segments) point_sum += v.votes;
  // Segments after the voted ones have votes 0 (nearest points without a
  // distinctive vote): share 0, in their order (the sort below is stable).
  for (const SegmentPointVote& v : ws.point_votes.segments)
    ranked.emplace_back(v.segment, point_sum > 0 ? v.votes / point_sum : 0.0f);
  float sources = point_sum > 0 ? 1.0f : 0.0f;  // the shares' sum over every segment
  const bool sum_images = retrieval && segment_votes == SegmentVoteSource::kBoth;
  if (sum_images) {
    const RetrievalQueryResult q = retrieval->query(f.descriptors, voting);
    for (const SegmentCandidate& c : q.candidates) {
      const auto index = manifest_position(c.segment);
      if (!index || q.total_votes <= 0) continue;
      const auto it = std::find_if(ranked.begin(), ranked.end(), [&](const auto& r) { return r.first == *index; });
      if (it != ranked.end())
        it->second += c.votes / q.total_votes;
      else
        ranked.emplace_back(*index, c.votes / q.total_votes);
    }
    sources += q.total_votes > 0 ? 1.0f : 0.0f;
  }
  std::stable_sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  res.retrieval_voted_segments =
      static_cast<size_t>(std::count_if(ranked.begin(), ranked.end(), [](const auto& r) { return r.second > 0; }));
  res.retrieval_total_votes = sources;
  for (size_t k = 0; k < ranked.size() && static_cast<int>(k) < max_candidates; ++k)
    take(ranked[k].first, ranked[k].second);
  // The segments after the voted ones (share 0: features had their nearest
  // point there but were not distinctive) rank before the retrieved images,
  // as measured (README #13). auto: the retrieved images fill the places the
  // point votes and those leave: now
  // when the first max_segments need them, else only before the fallback
  // segments are searched (most queries never are).
  if (retrieval && !sum_images && static_cast<int>(candidates.size()) < max_candidates) {
    if (static_cast<int>(candidates.size()) < max_segments)
      fill_from_retrieval(f, candidates, res);
    else
      retrieval_fill_pending = true;
  }
  res.times.retrieval = t.elapsed_ms();
  return candidates;
}

void Localizer::Impl::fill_from_retrieval(const FeatureSet& f, std::vector<size_t>& candidates,
                                          LocalizationResult& res) const {
  const RetrievalQueryResult q = retrieval->query(f.descriptors, voting);
  for (const SegmentCandidate& c : q.candidates) {
    if (static_cast<int>(candidates.size()) >= max_candidates) break;
    const auto index = manifest_position(c.segment);
    if (index && std::find(candidates.begin(), candidates.end(), *index) == candidates.end())
      take_candidate(*index, 0.0f, candidates, res);  // no point votes
  }
}

std::optional<size_t> Localizer::Impl::manifest_position(int32_t segment_id) const {
  const auto& segments = map.manifest().segments;
  for (size_t i = 0; i < segments.size(); ++i)
    if (static_cast<int32_t>(segments[i].id) == segment_id) return i;
  return std::nullopt;
}

void Localizer::Impl::take_candidate(size_t index, float votes, std::vector<size_t>& candidates,
                                     LocalizationResult& res) const {
  candidates.push_back(index);
  res.retrieval_segments.push_back(static_cast<int>(map.manifest().segments[index].id));
  res.retrieval_votes.push_back(votes);
}

void Localizer::Impl::Search::search_pass(const std::vector<size_t>& candidates) {
  const size_t listed_before = res_.candidates.size();
  search_candidates(candidates, impl_.search);
  assess_best(true);
  // Prioritized search stops at N_early matches; on repetitive facades they
  // can all be wrong. Before giving up, search every feature once more.
  if (!res_.registered && impl_.search.prioritize && options_.full_search_fallback) {
    CascadeSearchOptions full = impl_.search;
    full.prioritize = false;
    res_.candidates.resize(listed_before);  // listed again by the full search
    res_.full_search_fallback = true;
    search_candidates(candidates, full);
    assess_best(true);
  }
}

void Localizer::Impl::Search::search_candidates(const std::vector<size_t>& candidates,
                                                const CascadeSearchOptions& search) {
  for (size_t index : candidates) {
    // Candidates come best-voted first; a pose this well supported ends
    // the search (RANSAC on a wrong segment runs to its iteration cap).
    // (registered: enough inliers and confidence; a rejected pose, e.g. the
    // first pass's before the fallback, does not end it).
    if (options_.accept_inliers > 0 && res_.registered && best_inliers_ >= static_cast<size_t>(options_.accept_inliers))
      break;
    std::shared_ptr<const Segment> seg = impl_.cache->get(index);
    res_.candidates.push_back(static_cast<int>(seg->id()));
    Timer t;
    match_segment(*seg, search);
    res_.times.matching += t.elapsed_ms();
    t.reset();
    const PoseEstimate pose = estimate_segment_pose();
    res_.times.ransac += t.elapsed_ms();
    keep_if_best(index, seg, pose);
  }
}

void Localizer::Impl::Search::match_segment(const Segment& seg, const CascadeSearchOptions& search) {
  CascadeMatcher matcher(seg.index(), impl_.map.codebook(), ws_.cascade);
  if (seg.uses_map_hasher()) {
    // One hash of the query for every segment that shares the map's rotation.
    // Query-directed probing also reads the bits' margins: the same codes
    // hashed once more with them, if retrieval hashed the query without.
    const bool directed = search.needs_margins();
    if (!map_codes_ready_ || (directed && !map_margins_ready_)) {
      ws_.map_codes.resize(f_.descriptors.rows());
      ws_.map_margins.resize(directed ? f_.descriptors.rows() * kHashBits : 0);
      encode_hash(impl_.map.hasher()->view(), f_.descriptors.data(), f_.descriptors.rows(), ws_.map_codes.data(),
                  ws_.encode, directed ? ws_.map_margins.data() : nullptr);
      map_codes_ready_ = true;
      map_margins_ready_ = directed;
    }
    matcher.match_hashed(f_.descriptors, ws_.map_codes, search, ws_.matches,
                         directed ? std::span<const int32_t>(ws_.map_margins) : std::span<const int32_t>());
  } else {
    matcher.match(f_.descriptors, search, ws_.matches);
  }
  fill_correspondence_set(
      ws_.matches, f_.keypoints, seg.xyz(), ws_.correspondences,
      options_.map_point_uncertainty ? seg.point_uncertainty() : std::span<const PointUncertaintyCode>());
}

PoseEstimate Localizer::Impl::Search::estimate_segment_pose() const {
  const CorrespondenceSet& set = ws_.correspondences;
  PoseEstimate pose;
  // Inliers are counted per query feature, so a segment with no more
  // matched features than the best pose's inliers cannot win: skip it.
  const bool can_win = set.points2d.size() > best_inliers_;
  if (can_win && (set.num_hypothesis_features() >= 6 || (camera_.has_focal && set.num_hypothesis_features() >= 3)))
    pose = estimate_pose(set, camera_, impl_.ransac);
  return pose;
}

void Localizer::Impl::Search::keep_if_best(size_t index, const std::shared_ptr<const Segment>& seg,
                                           const PoseEstimate& pose) {
  if (!pose.has_pose) return;
  size_t& seen = inliers_per_segment_[static_cast<int>(seg->id())];
  seen = std::max(seen, pose.num_inliers);
  if (pose.num_inliers <= best_inliers_) return;
  best_inliers_ = pose.num_inliers;
  best_has_enough_inliers_ = pose.registered;
  best_quality_ = pose.quality;
  // Measured now: the workspace's matches are the next segment's after this.
  // Rival candidates farther apart than the rival poses' 10% of the median
  // depth (PoseQuality), as close in descriptor as the 1-1 ratio test's ν_h.
  const CorrespondenceSet& set = ws_.correspondences;
  best_ambiguous_share_ = kAmbiguousWhenUnknown;
  if (std::isfinite(pose.quality.inlier_depth_median))
    best_ambiguous_share_ =
        ambiguous_inlier_share(set.candidate_offsets, set.candidates, ws_.matches.many_distances, pose.chosen_candidate,
                               0.1 * pose.quality.inlier_depth_median, impl_.search.ratio_one_to_one);
  // The guided confirmation's descriptor bound: as close as the pose's own
  // inliers are to their points (their 90th percentile, nearest rank).
  std::vector<float>& d = ws_.inlier_distances;
  d.clear();
  for (size_t i = 0; i < pose.chosen_candidate.size(); ++i)
    if (pose.chosen_candidate[i] >= 0) {
      const uint32_t c = set.candidate_offsets[i] + uint32_t(pose.chosen_candidate[i]);
      VISLOC_CHECK(c < set.candidate_offsets[i + 1] && c < ws_.matches.many_distances.size(),
                   "chosen candidate out of its feature's list");
      d.push_back(ws_.matches.many_distances[c]);
    }
  best_inlier_distance_p90_ = 0;
  if (!d.empty()) {
    const size_t p90 = (9 * d.size() + 9) / 10 - 1;
    std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(p90), d.end());
    best_inlier_distance_p90_ = d[p90];
  }
  best_elsewhere_share_ = kElsewhereWhenUnknown;
  if (impl_.point_votes && !ws_.point_votes.feature_offsets.empty()) {
    const auto position = static_cast<uint32_t>(index);
    const std::optional<double> share = elsewhere_inlier_share(
        ws_.point_votes, set.query_feature, pose.chosen_candidate, position, impl_.related_segments.at(position));
    if (share) best_elsewhere_share_ = *share;
  }
  best_segment_ = seg;
  res_.segment = static_cast<int>(seg->id());
  res_.inliers = pose.num_inliers;
  res_.cam_from_segment = pose.cam_from_world;
  res_.focal_px = pose.focal;
  res_.focal_estimated = !camera_.has_focal;
  res_.principal_point_offset = pose.principal_point_offset;
  res_.matches_one_to_one = ws_.matches.query.size();
  assess_best(false);  // for the early stop; assessed again once every candidate is searched
}

ConfidenceFeatures Localizer::Impl::Search::confidence_features() const {
  ConfidenceFeatures cf;
  cf.inliers = static_cast<double>(res_.inliers);
  cf.inlier_ratio = best_quality_.hypothesis_features
                        ? double(best_quality_.hypothesis_inliers) / double(best_quality_.hypothesis_features)
                        : 0.0;
  cf.coverage = best_quality_.coverage;
  cf.ambiguous = best_ambiguous_share_;
  cf.elsewhere = best_elsewhere_share_;
  cf.residual = best_quality_.median_residual_px / impl_.ransac.threshold_px;
  size_t other = 0;
  for (const auto& [id, n] : inliers_per_segment_)
    if (id != res_.segment) other = std::max(other, n);
  cf.margin = std::max(res_.inliers ? double(other) / double(res_.inliers) : 0.0,
                       best_quality_.best_score ? double(best_quality_.rival_score) / double(best_quality_.best_score)
                                                : 0.0);
  cf.vote_share = kVoteShareWithoutRetrieval;
  if (impl_.retrieval) {
    cf.vote_share = 0;
    for (size_t k = 0; k < res_.retrieval_segments.size(); ++k)
      if (res_.retrieval_segments[k] == res_.segment && res_.retrieval_total_votes > 0)
        cf.vote_share = res_.retrieval_votes[k] / res_.retrieval_total_votes;
  }
  return cf;
}

void Localizer::Impl::Search::assess_best(bool final_assessment) {
  LocalizationResult& res = res_;
  res.registered = false;
  res.confidence = 0;
  res.center_enu.reset();
  res.heading_deg.reset();
  res.position.reset();
  res.uncertainty = {};
  if (!best_segment_) return;
  const SegmentFrame frame = segment_frame(*best_segment_);
  ConfidenceFeatures& cf = res.confidence_features;
  cf = confidence_features();
  std::optional<Eigen::Vector3d> up;
  if (frame.georegistered) up = frame.enu_from_segment.rotation.transpose() * Eigen::Vector3d::UnitZ();
  MapCameraRange(best_segment_->images(), up).assess(res.cam_from_segment, &cf);
  // A pass over the segment's points: in an early-stop check only when the
  // model weighs it.
  const ConfidenceModel& model = ConfidenceModel::builtin();
  if (final_assessment || model.weights[kExplainedInput] != 0)
    cf.explained = explained_fraction(best_segment_->xyz(), res.cam_from_segment, camera_, res.focal_px,
                                      res.principal_point_offset, best_quality_.inlier_depth_p90, res.inliers);
  if (final_assessment) {
    GuidedConfirmationInput in;
    in.xyz = best_segment_->xyz();
    in.codes = best_segment_->index().pq_codes;
    in.codebook = &impl_.map.codebook();
    in.cam_from_segment = res.cam_from_segment;
    in.camera = &camera_;
    in.focal = res.focal_px;
    in.principal_point_offset = res.principal_point_offset;
    in.max_depth = best_quality_.inlier_depth_p90;
    in.keypoints = f_.keypoints;
    in.descriptors = &f_.descriptors;
    in.inlier_cells = best_quality_.inlier_cells;
    in.radius_px = 2 * impl_.ransac.threshold_px;
    in.max_distance = best_inlier_distance_p90_;
    cf.guided = ws_.guided.measure(in);
  }
  res.confidence = model.evaluate(cf);
  res.under_street = {};
  if (frame.georegistered)
    res.under_street = assess_under_street(res.cam_from_segment, best_segment_->images(), best_segment_->xyz(),
                                           frame.enu_from_segment, options_.under_street, ws_.point_heights,
                                           /*measure_ground=*/final_assessment);
  res.registered = best_has_enough_inliers_ && res.confidence >= options_.min_confidence &&
                   !(options_.under_street.enabled && res.under_street.under_street);
  if (best_quality_.covariance.valid) {
    res.uncertainty = pose_uncertainty(best_quality_.covariance, res.cam_from_segment,
                                       frame.georegistered ? std::optional(frame.enu_from_segment) : std::nullopt,
                                       model.sigma_scale_for(best_quality_.covariance.with_point_uncertainty));
    if (best_quality_.inlier_depth_p90 > 0)
      res.uncertainty.relative_position_sigma = res.uncertainty.position_sigma / best_quality_.inlier_depth_p90;
  }
  if (frame.georegistered) {
    const Eigen::Vector3d c = frame.enu_from_segment.apply(res.cam_from_segment.center());
    res.center_enu = c;
    const Eigen::Vector3d dir = frame.enu_from_segment.rotation * res.cam_from_segment.viewing_direction();
    res.heading_deg = heading_deg_from_enu(dir);
    if (impl_.frame) res.position = impl_.frame->to_geo(c);
  }
}

LocalizationResult Localizer::localize_features(const FeatureSet& f, const PinholeCamera& camera) const {
  Timer total;
  camera.validate();
  LocalizationResult res;
  res.image = f.image;
  res.features = f.size();
  struct Lease {
    WorkspacePool& pool;
    std::unique_ptr<QueryWorkspace> w;
    ~Lease() { pool.give_back(std::move(w)); }
  } lease{impl_->workspaces, impl_->workspaces.take()};
  bool map_codes_ready = false, retrieval_fill_pending = false;
  std::vector<size_t> candidates = impl_->candidate_segments(f, *lease.w, res, map_codes_ready, retrieval_fill_pending);
  Impl::Search search(*impl_, options_, f, camera, *lease.w, res, map_codes_ready);
  // The first max_segments candidates; the rest (fallback_segments) only
  // when those give no registered pose.
  const size_t first = std::min(candidates.size(), static_cast<size_t>(impl_->max_segments));
  const std::vector<size_t> primary(candidates.begin(), candidates.begin() + first);
  if (!primary.empty()) {
    res.candidates.clear();
    search.search_pass(primary);
    if (!res.registered && retrieval_fill_pending) {
      Timer t;
      impl_->fill_from_retrieval(f, candidates, res);
      res.times.retrieval += t.elapsed_ms();
    }
    const std::vector<size_t> fallback(candidates.begin() + first, candidates.end());
    if (!res.registered && !fallback.empty()) {
      res.fallback_segments_searched = true;
      search.search_pass(fallback);
    }
  }
  res.times.total = total.elapsed_ms();
  return res;
}

}  // namespace visloc
