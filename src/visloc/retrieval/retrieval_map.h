// RetrievalMap: the retrieval part of a map (DESIGN.md "map/ : retrieval
// index, image → segment table"), one directory:
//   DIR/embedding.vltemb  TriangulationEmbedding parameters (SectionFile "TEMB")
//   DIR/index.vlidx       ImageIndex over the map images (SectionFile "IIDX")
//   DIR/images.vlimg      SectionFile "RIMG": META (JSON: count, segments),
//                         NAME (image names joined by '\n'), SOFF (count+1
//                         uint32 offsets) and SIDS (int32 segment ids): the
//                         image → segment table; index ids are row numbers.
// Each file is written atomically; a map is read whole or rejected.
#pragma once

#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "visloc/retrieval/image_index.h"
#include "visloc/retrieval/segment_voter.h"
#include "visloc/retrieval/triangulation_embedding.h"

namespace visloc {

inline constexpr uint32_t kRetrievalImagesFileVersion = 1;

struct RetrievalQueryResult {
  std::vector<ImageSearchResult> images;       // nearest first (ids = rows of image_names)
  std::vector<SegmentCandidate> candidates;    // at most max_candidates
  size_t voted_segments = 0;                   // segments with any vote (candidates are the first of them)
  float total_votes = 0;                       // over all voted segments
  double embed_ms = 0, search_ms = 0, vote_ms = 0;
};

class RetrievalMap {
 public:
  // Learns the embedding on the map images, embeds them and builds the index.
  static RetrievalMap build(std::span<const DescriptorMatrix* const> images, std::vector<std::string> image_names,
                            SegmentTable segments, const TriangulationEmbeddingOptions& embedding_options,
                            const ImageIndexOptions& index_options);

  // Top images and candidate segments of one query image's descriptors.
  RetrievalQueryResult query(const DescriptorMatrix& descriptors, const SegmentVoterOptions& options) const;

  const TriangulationEmbedding& embedding() const { return embedding_; }
  const ImageIndex& index() const { return index_; }
  const SegmentTable& segments() const { return segments_; }
  const std::vector<std::string>& image_names() const { return image_names_; }
  ImageIndex& mutable_index() { return index_; }  // e.g. set_nprobe

  void save(const std::filesystem::path& dir) const;
  static RetrievalMap load(const std::filesystem::path& dir);

 private:
  TriangulationEmbedding embedding_;
  ImageIndex index_;
  SegmentTable segments_;
  std::vector<std::string> image_names_;
};

}  // namespace visloc
