#include "visloc/retrieval/segment_voter.h"

#include <algorithm>

#include "visloc/util/error.h"

namespace visloc {

SegmentTable::SegmentTable(const std::vector<std::vector<int32_t>>& segments_of_image) : offsets_{0} {
  for (const auto& segs : segments_of_image) {
    std::vector<int32_t> s = segs;
    std::sort(s.begin(), s.end());
    s.erase(std::unique(s.begin(), s.end()), s.end());
    segment_ids_.insert(segment_ids_.end(), s.begin(), s.end());
    offsets_.push_back(static_cast<uint32_t>(segment_ids_.size()));
  }
  check();
}

SegmentTable::SegmentTable(std::vector<uint32_t> offsets, std::vector<int32_t> segment_ids)
    : offsets_(std::move(offsets)), segment_ids_(std::move(segment_ids)) {
  check();
}

void SegmentTable::check() {
  if (offsets_.empty() || offsets_.front() != 0 || offsets_.back() != segment_ids_.size())
    throw_error(ErrorCode::kFormat, "segment table: offsets do not span the ", segment_ids_.size(), " segment ids");
  for (size_t i = 1; i < offsets_.size(); ++i)
    if (offsets_[i] < offsets_[i - 1]) throw_error(ErrorCode::kFormat, "segment table: offsets decrease at image ", i - 1);
  int32_t max_id = -1;
  for (int32_t s : segment_ids_) {
    if (s < 0) throw_error(ErrorCode::kFormat, "segment table: negative segment id ", s);
    max_id = std::max(max_id, s);
  }
  segment_count_ = max_id + 1;
}

void SegmentRuleOptions::validate() const {
  if (placemarks_per_segment < 1)
    throw_error(ErrorCode::kInvalidArgument, "segment option placemarks_per_segment = ", placemarks_per_segment,
                ": must be at least 1");
  if (overlap < 0 || overlap >= placemarks_per_segment)
    throw_error(ErrorCode::kInvalidArgument, "segment option overlap = ", overlap,
                ": must be in [0, placemarks_per_segment)");
}

SegmentTable make_placemark_segments(std::span<const int> placemark_of_image, const SegmentRuleOptions& options) {
  options.validate();
  std::vector<int> distinct(placemark_of_image.begin(), placemark_of_image.end());
  std::sort(distinct.begin(), distinct.end());
  distinct.erase(std::unique(distinct.begin(), distinct.end()), distinct.end());
  const int count = static_cast<int>(distinct.size());
  const int size = options.placemarks_per_segment, stride = size - options.overlap;
  // Segments of each placemark rank.
  std::vector<std::vector<int32_t>> of_rank(count);
  int32_t segment = 0;
  for (int start = 0; start < count; start += stride, ++segment) {
    const int end = std::min(count, start + size);
    for (int r = start; r < end; ++r) of_rank[r].push_back(segment);
    if (end == count) break;
  }
  std::vector<std::vector<int32_t>> of_image;
  of_image.reserve(placemark_of_image.size());
  for (int p : placemark_of_image) {
    const auto rank = std::lower_bound(distinct.begin(), distinct.end(), p) - distinct.begin();
    of_image.push_back(of_rank[rank]);
  }
  return SegmentTable(of_image);
}

void SegmentVoterOptions::validate() const {
  if (top_images < 1)
    throw_error(ErrorCode::kInvalidArgument, "segment voter option top_images = ", top_images, ": must be at least 1");
  if (max_candidates < 1)
    throw_error(ErrorCode::kInvalidArgument, "segment voter option max_candidates = ", max_candidates,
                ": must be at least 1");
}

SegmentVoter::SegmentVoter(SegmentTable table, const SegmentVoterOptions& options)
    : table_(std::move(table)), options_(options) {
  options_.validate();
}

std::vector<SegmentCandidate> SegmentVoter::candidates(std::span<const ImageSearchResult> ranked) const {
  std::vector<SegmentCandidate> votes = all_votes(ranked);
  if (votes.size() > static_cast<size_t>(options_.max_candidates)) votes.resize(options_.max_candidates);
  return votes;
}

std::vector<SegmentCandidate> SegmentVoter::all_votes(std::span<const ImageSearchResult> ranked) const {
  std::vector<SegmentCandidate> votes;  // few (≤ 2 per retrieved image): linear search
  const size_t n = std::min(ranked.size(), static_cast<size_t>(options_.top_images));
  for (size_t r = 0; r < n; ++r) {
    const int64_t image = ranked[r].image;
    if (image < 0) continue;  // FAISS's padding when fewer results exist
    if (static_cast<size_t>(image) >= table_.image_count())
      throw_error(ErrorCode::kInvalidArgument, "segment voter: image id ", image, " is not in the segment table (",
                  table_.image_count(), " images)");
    const float w = options_.weighting == VoteWeighting::kOnePerImage ? 1.0f : 1.0f / static_cast<float>(r + 1);
    for (int32_t s : table_.segments(static_cast<size_t>(image))) {
      auto it = std::find_if(votes.begin(), votes.end(), [s](const SegmentCandidate& c) { return c.segment == s; });
      if (it == votes.end())
        votes.push_back({s, w, static_cast<int>(r)});
      else
        it->votes += w;
    }
  }
  std::sort(votes.begin(), votes.end(), [](const SegmentCandidate& a, const SegmentCandidate& b) {
    if (a.votes != b.votes) return a.votes > b.votes;
    if (a.best_rank != b.best_rank) return a.best_rank < b.best_rank;
    return a.segment < b.segment;
  });
  return votes;
}

}  // namespace visloc
