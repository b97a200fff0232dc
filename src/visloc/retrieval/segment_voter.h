// Candidate segments from retrieved images (the paper's section III-A):
// a segment is a candidate when one of the top N_t retrieved images belongs
// to it; candidates are ranked by votes and at most `max_candidates` (4) are
// kept for the 2D-3D search.
//
// Segments (DESIGN.md): runs of `placemarks_per_segment` consecutive
// placemarks (8-10), neighbours sharing `overlap` (2) placemarks, so an image
// of an overlap placemark belongs to two segments.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "visloc/retrieval/image_index.h"

namespace visloc {

// Image → segments it belongs to, in compressed rows: image i's segments are
// segment_ids[offsets[i] .. offsets[i+1]). Image ids are 0..image_count()-1.
class SegmentTable {
 public:
  SegmentTable() : offsets_{0} {}
  explicit SegmentTable(const std::vector<std::vector<int32_t>>& segments_of_image);
  // From the stored arrays; throws Error(kFormat) when inconsistent.
  SegmentTable(std::vector<uint32_t> offsets, std::vector<int32_t> segment_ids);

  size_t image_count() const { return offsets_.size() - 1; }
  int32_t segment_count() const { return segment_count_; }
  std::span<const int32_t> segments(size_t image) const {
    return {segment_ids_.data() + offsets_[image], offsets_[image + 1] - offsets_[image]};
  }
  const std::vector<uint32_t>& offsets() const { return offsets_; }
  const std::vector<int32_t>& segment_ids() const { return segment_ids_; }
  size_t bytes() const { return offsets_.size() * sizeof(uint32_t) + segment_ids_.size() * sizeof(int32_t); }

 private:
  void check();  // validates and sets segment_count_
  std::vector<uint32_t> offsets_;
  std::vector<int32_t> segment_ids_;
  int32_t segment_count_ = 0;
};

struct SegmentRuleOptions {
  int placemarks_per_segment = 10;  // DESIGN.md: 8-10 consecutive placemarks
  int overlap = 2;                  // placemarks shared by neighbouring segments
  void validate() const;            // throws Error(kInvalidArgument) naming the field
};

// Segments over placemarks numbered along the route: segment s covers the
// distinct placemarks of rank [s·stride, s·stride + size), stride = size -
// overlap, the last segment ending at the last placemark. `placemark_of_image`
// holds any integers; their sorted distinct values give the ranks.
SegmentTable make_placemark_segments(std::span<const int> placemark_of_image, const SegmentRuleOptions& options);

enum class VoteWeighting {
  kOnePerImage,     // each retrieved image gives one vote to each of its segments
  kReciprocalRank,  // the image at rank r (0-based) gives 1 / (r + 1)
};

struct SegmentVoterOptions {
  int top_images = 20;      // N_t (paper: 20)
  int max_candidates = 4;   // paper: at most 4 segments are searched
  // Measured (visloc bench retrieval, lund leave-one-out, kitti07 0-99/100-159):
  // rank weighting keeps recall when N_t approaches the map size, where one
  // vote per image favours the segments with the most images.
  VoteWeighting weighting = VoteWeighting::kReciprocalRank;
  void validate() const;    // throws Error(kInvalidArgument) naming the field
};

struct SegmentCandidate {
  int32_t segment = -1;
  float votes = 0;
  int best_rank = 0;  // rank of the best retrieved image of the segment
};

class SegmentVoter {
 public:
  SegmentVoter(SegmentTable table, const SegmentVoterOptions& options);
  // Candidates from images ranked nearest first (only the first top_images
  // are used; ids outside the table are an error). Ordered by votes, then by
  // best rank, then by segment id.
  std::vector<SegmentCandidate> candidates(std::span<const ImageSearchResult> ranked) const;
  // Every segment that received a vote, in the same order (candidates() is
  // its first max_candidates): how the votes are spread over the map.
  std::vector<SegmentCandidate> all_votes(std::span<const ImageSearchResult> ranked) const;
  const SegmentTable& table() const { return table_; }
  const SegmentVoterOptions& options() const { return options_; }

 private:
  SegmentTable table_;
  SegmentVoterOptions options_;
};

}  // namespace visloc
