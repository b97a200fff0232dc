#include "visloc/retrieval/retrieval_map.h"

#include <nlohmann/json.hpp>
#include <numeric>

#include "visloc/util/error.h"
#include "visloc/util/json_fields.h"
#include "visloc/util/section_file.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;

RetrievalMap RetrievalMap::build(std::span<const DescriptorMatrix* const> images, std::vector<std::string> image_names,
                                 SegmentTable segments, const TriangulationEmbeddingOptions& embedding_options,
                                 const ImageIndexOptions& index_options) {
  if (image_names.size() != images.size() || segments.image_count() != images.size())
    throw_error(ErrorCode::kInvalidArgument, "retrieval map: ", images.size(), " images, ", image_names.size(),
                " names and ", segments.image_count(), " rows in the segment table");
  for (const auto& n : image_names)
    if (n.empty() || n.find('\n') != std::string::npos)
      throw_error(ErrorCode::kInvalidArgument, "retrieval map: image name '", n, "' is empty or holds a newline");
  RetrievalMap m;
  m.embedding_ = TriangulationEmbedding::train(images, embedding_options);
  const int dims = m.embedding_.dims();
  std::vector<float> vectors(images.size() * static_cast<size_t>(dims));
  for (size_t i = 0; i < images.size(); ++i) m.embedding_.embed(*images[i], vectors.data() + i * dims);
  std::vector<int64_t> ids(images.size());
  std::iota(ids.begin(), ids.end(), int64_t{0});
  m.index_ = ImageIndex::build(vectors, ids, dims, index_options);
  m.segments_ = std::move(segments);
  m.image_names_ = std::move(image_names);
  return m;
}

RetrievalQueryResult RetrievalMap::query(const DescriptorMatrix& descriptors, const SegmentVoterOptions& options) const {
  options.validate();
  RetrievalQueryResult r;
  Timer t;
  const auto v = embedding_.embed(descriptors);
  r.embed_ms = t.elapsed_ms();
  t.reset();
  r.images = index_.search(v, options.top_images);
  r.search_ms = t.elapsed_ms();
  t.reset();
  r.candidates = SegmentVoter(segments_, options).all_votes(r.images);
  r.voted_segments = r.candidates.size();
  for (const SegmentCandidate& c : r.candidates) r.total_votes += c.votes;
  if (r.candidates.size() > static_cast<size_t>(options.max_candidates)) r.candidates.resize(options.max_candidates);
  r.vote_ms = t.elapsed_ms();
  return r;
}

void RetrievalMap::save(const fs::path& dir) const {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw_error(ErrorCode::kIo, dir.string(), ": cannot create directory (", ec.message(), ")");
  embedding_.save(dir / "embedding.vltemb");
  index_.save(dir / "index.vlidx");
  std::string names;
  for (size_t i = 0; i < image_names_.size(); ++i) names += (i ? "\n" : "") + image_names_[i];
  SectionFileWriter w(dir / "images.vlimg", "RIMG", kRetrievalImagesFileVersion);
  w.add_text("META", nlohmann::json{{"count", image_names_.size()}, {"segments", segments_.segment_count()}}.dump());
  w.add_text("NAME", names);
  w.add_array<uint32_t>("SOFF", segments_.offsets());
  w.add_array<int32_t>("SIDS", segments_.segment_ids());
  w.commit();
}

RetrievalMap RetrievalMap::load(const fs::path& dir) {
  RetrievalMap m;
  const fs::path images_path = dir / "images.vlimg";
  SectionFileReader r(images_path, "RIMG", 1, kRetrievalImagesFileVersion);
  nlohmann::json meta;
  try {
    meta = nlohmann::json::parse(r.text("META"));
  } catch (const nlohmann::json::exception& ex) {
    throw_error(ErrorCode::kFormat, images_path.string(), ": META is not valid JSON (", ex.what(), ")");
  }
  // An integer that fits (a count of 1e102 is refused, not converted): the
  // names below must then agree with it.
  const size_t count = JsonField(meta, images_path.string(), "META").at("count").unsigned_integer(UINT32_MAX - 1);
  const std::string_view names = r.text("NAME");
  size_t start = 0;
  while (count > 0 && start <= names.size()) {
    const size_t end = names.find('\n', start);
    m.image_names_.emplace_back(names.substr(start, end == std::string_view::npos ? std::string_view::npos : end - start));
    if (end == std::string_view::npos) break;
    start = end + 1;
  }
  if (m.image_names_.size() != count)
    throw_error(ErrorCode::kFormat, images_path.string(), ": ", m.image_names_.size(), " names, META says ", count);
  const auto off = r.array<uint32_t>("SOFF", static_cast<int64_t>(count) + 1);
  const auto ids = r.array<int32_t>("SIDS");
  try {
    m.segments_ = SegmentTable(std::vector<uint32_t>(off.begin(), off.end()), std::vector<int32_t>(ids.begin(), ids.end()));
  } catch (const Error& ex) {
    throw_error(ErrorCode::kFormat, images_path.string(), ": ", ex.what());
  }
  m.embedding_ = TriangulationEmbedding::load(dir / "embedding.vltemb");
  m.index_ = ImageIndex::load(dir / "index.vlidx");
  if (m.index_.dims() != m.embedding_.dims())
    throw_error(ErrorCode::kFormat, dir.string(), ": index dimension ", m.index_.dims(), " differs from the embedding's ",
                m.embedding_.dims());
  if (m.index_.size() != count)
    throw_error(ErrorCode::kFormat, dir.string(), ": index holds ", m.index_.size(), " images, the image table ", count);
  return m;
}

}  // namespace visloc
