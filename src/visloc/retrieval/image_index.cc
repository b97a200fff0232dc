#include "visloc/retrieval/image_index.h"

#include <faiss/IndexFlat.h>
#include <faiss/IndexIVFPQ.h>
#include <faiss/MetaIndexes.h>
#include <faiss/impl/FaissException.h>
#include <faiss/impl/io.h>
#include <faiss/invlists/InvertedLists.h>
#include <faiss/index_io.h>

#include <limits>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <numeric>

#include "visloc/retrieval/faiss_layout.h"
#include "visloc/util/error.h"
#include "visloc/util/section_file.h"
#include "visloc/util/random.h"
#include "visloc/util/json_fields.h"

namespace visloc {

struct ImageIndex::Impl {
  std::unique_ptr<faiss::Index> index;
  faiss::IndexIVFPQ* ivfpq = nullptr;  // view into index when IVF-PQ
};

namespace {

const char* type_name(ImageIndexType t) { return t == ImageIndexType::kIvfPq ? "ivfpq" : "flat"; }

void configure_tables(faiss::IndexIVFPQ* ivfpq, bool precomputed) {
  ivfpq->use_precomputed_table = precomputed ? 1 : -1;
  if (precomputed) {
    ivfpq->precompute_table();
  } else if (ivfpq->precomputed_table.size() > 0) {  // FAISS's clear() of an empty table memsets a null pointer
    ivfpq->precomputed_table.clear();
  }
}

// Throws Error(kFormat) naming the index file, the message built from `parts`.
struct IndexFileError {
  const std::filesystem::path& path;
  template <typename... Parts>
  [[noreturn]] void operator()(const Parts&... parts) const {
    throw_error(ErrorCode::kFormat, path.string(), ": ", parts...);
  }
};

// What the META section of an index file says.
struct IndexMeta {
  ImageIndexOptions options;
  int dims = 0;
  size_t count = 0;
  int effective_nlist = 0, effective_pq_bits = 0;
};

IndexMeta parse_meta(std::string_view text, const IndexFileError& fail) {
  IndexMeta out;
  try {
    const auto meta = nlohmann::json::parse(text);
    // Integers only, in range (json_fields.h): a double such as 1e73 is refused, not converted.
    const JsonField m(meta, fail.path.string(), "META");
    auto as_int = [&m](const char* key) {
      return static_cast<int>(m.at(key).integer(std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
    };
    const std::string type = meta.at("type").get<std::string>();
    if (type != "ivfpq" && type != "flat") fail("unknown index type '", type, "'");
    out.options.type = type == "ivfpq" ? ImageIndexType::kIvfPq : ImageIndexType::kFlat;
    out.dims = as_int("dims");
    out.count = m.at("count").unsigned_integer(std::numeric_limits<size_t>::max());
    out.options.nlist = as_int("nlist");
    out.options.nprobe = as_int("nprobe");
    out.options.pq_bytes = as_int("pq_bytes");
    out.options.pq_bits = as_int("pq_bits");
    out.options.precomputed_tables = meta.at("precomputed_tables").get<bool>();
    out.options.max_training_vectors = as_int("max_training_vectors");
    out.options.seed = m.at("seed").unsigned_integer();
    out.effective_nlist = as_int("effective_nlist");
    out.effective_pq_bits = as_int("effective_pq_bits");
  } catch (const nlohmann::json::exception& ex) {
    fail("META is not valid (", ex.what(), ")");
  }
  try {
    out.options.validate();
  } catch (const Error& ex) {
    fail("stored options are invalid: ", ex.what());
  }
  return out;
}

// FAISS's reader allocates whatever sizes it reads before reading the data:
// walks the bytes first (faiss_layout.h), so that no count reaches it that
// the section's bytes do not back, and checks them against META.
void check_faiss_section(std::span<const uint8_t> bytes, const IndexMeta& meta, const IndexFileError& fail) {
  FaissLayoutFacts facts;
  try {
    facts = check_faiss_layout(bytes, meta.options.type == ImageIndexType::kIvfPq ? FaissLayout::kIvfPq
                                                                                   : FaissLayout::kIdMapFlat);
  } catch (const Error& ex) {
    fail(ex.what());
  }
  if (facts.dims != meta.dims || static_cast<uint64_t>(facts.count) != meta.count)
    fail("FAISS index has dimension ", facts.dims, " and ", facts.count, " vectors, META says ", meta.dims, " and ",
         meta.count);
  if (meta.options.type == ImageIndexType::kIvfPq &&
      (facts.nlist != static_cast<uint64_t>(meta.effective_nlist) ||
       facts.pq_m != static_cast<uint64_t>(meta.options.pq_bytes) ||
       facts.pq_nbits != static_cast<uint64_t>(meta.effective_pq_bits)))
    fail("FAISS index has ", facts.nlist, " lists and ", facts.pq_m, " sub-quantizers of ", facts.pq_nbits,
         " bits, META says ", meta.effective_nlist, ", ", meta.options.pq_bytes, " and ", meta.effective_pq_bits);
  if (meta.options.type == ImageIndexType::kIvfPq && meta.options.precomputed_tables) {
    // nlist × M × 2^nbits floats, computed at load: refuse what FAISS itself
    // would not precompute by default (faiss::precomputed_table_max_bytes).
    const double table_bytes = 4.0 * static_cast<double>(facts.nlist) * static_cast<double>(facts.pq_m) *
                               static_cast<double>(uint64_t{1} << facts.pq_nbits);
    if (table_bytes > static_cast<double>(faiss::precomputed_table_max_bytes))
      fail("precomputed tables would take ", table_bytes / (1 << 20), " MiB (", facts.nlist, " lists × ", facts.pq_m,
           " × 2^", facts.pq_nbits, "), more than FAISS's limit of ",
           faiss::precomputed_table_max_bytes >> 20, " MiB");
  }
}

std::unique_ptr<faiss::Index> read_faiss_section(std::span<const uint8_t> bytes, const IndexFileError& fail) {
  faiss::VectorIOReader reader;
  reader.data.assign(bytes.begin(), bytes.end());
  std::unique_ptr<faiss::Index> index;
  try {
    index.reset(faiss::read_index(&reader, faiss::IO_FLAG_SKIP_PRECOMPUTE_TABLE));
  } catch (const faiss::FaissException& ex) {
    fail("FAISS index section cannot be read (", ex.what(), ")");
  } catch (const std::bad_alloc&) {
    fail("FAISS index section cannot be read (its sizes ask for more memory than there is)");
  } catch (const std::exception& ex) {
    fail("FAISS index section cannot be read (", ex.what(), ")");
  }
  return index;
}

// FAISS's reader trusts the sizes it reads; searching an index whose arrays
// disagree with its counts reads out of bounds (found by fuzzing): these
// check every array the search touches against the counts.
void check_flat(const faiss::Index* idx, const char* what, faiss::Index::idx_t expected_ntotal, int dims,
                const IndexFileError& fail) {
  const auto* flat = dynamic_cast<const faiss::IndexFlat*>(idx);
  if (!flat) fail(what, " is not a flat FAISS index");
  if (flat->d != dims || flat->ntotal != expected_ntotal || flat->ntotal < 0 ||
      flat->code_size != static_cast<size_t>(flat->d) * sizeof(float) ||
      flat->codes.size() != static_cast<size_t>(flat->ntotal) * flat->code_size)
    fail(what, ": its sizes disagree (d ", flat->d, ", ", flat->ntotal, " vectors, ", flat->codes.size(), " bytes)");
}

void check_ivfpq(const faiss::IndexIVFPQ* ivfpq, int dims, const IndexFileError& fail) {
  if (ivfpq->nlist < 1 || !ivfpq->quantizer) fail("IVF-PQ index without lists or coarse quantizer");
  check_flat(ivfpq->quantizer, "coarse quantizer", static_cast<faiss::Index::idx_t>(ivfpq->nlist), dims, fail);
  const faiss::ProductQuantizer& pq = ivfpq->pq;
  if (pq.M < 1 || pq.nbits < 1 || pq.nbits > 16 || pq.d != static_cast<size_t>(dims) || pq.M * pq.dsub != pq.d ||
      pq.ksub != (size_t{1} << pq.nbits) || pq.centroids.size() != pq.d * pq.ksub ||
      ivfpq->code_size != pq.code_size || pq.code_size != (pq.M * pq.nbits + 7) / 8)
    fail("product quantizer sizes disagree (M ", pq.M, ", ", pq.nbits, " bits, d ", pq.d, ")");
  const auto* lists = dynamic_cast<const faiss::ArrayInvertedLists*>(ivfpq->invlists);
  if (!lists || lists->nlist != ivfpq->nlist || lists->code_size != ivfpq->code_size ||
      lists->codes.size() != lists->nlist || lists->ids.size() != lists->nlist)
    fail("inverted lists disagree with the index (", ivfpq->nlist, " lists)");
  size_t listed = 0;
  for (size_t l = 0; l < lists->nlist; ++l) {
    if (lists->codes[l].size() != lists->ids[l].size() * lists->code_size)
      fail("inverted list ", l, " has ", lists->ids[l].size(), " ids and ", lists->codes[l].size(), " code bytes");
    listed += lists->ids[l].size();
  }
  if (listed != static_cast<size_t>(ivfpq->ntotal))
    fail("inverted lists hold ", listed, " vectors, the index ", ivfpq->ntotal);
}

}  // namespace

void ImageIndexOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "image index option ", field, " = ", value, ": ", rule);
  };
  if (nlist < 1) bad("nlist", nlist, "must be at least 1");
  if (nprobe < 1) bad("nprobe", nprobe, "must be at least 1");
  if (pq_bytes < 1) bad("pq_bytes", pq_bytes, "must be at least 1");
  if (pq_bits < 1 || pq_bits > 16) bad("pq_bits", pq_bits, "must be in [1, 16]");
  if (max_training_vectors < 2) bad("max_training_vectors", max_training_vectors, "must be at least 2");
}

ImageIndex::ImageIndex() : impl_(std::make_unique<Impl>()) {}
ImageIndex::~ImageIndex() = default;
ImageIndex::ImageIndex(ImageIndex&&) noexcept = default;
ImageIndex& ImageIndex::operator=(ImageIndex&&) noexcept = default;

ImageIndex ImageIndex::train(std::span<const float> training, int dims, const ImageIndexOptions& options) {
  options.validate();
  if (dims < 1) throw_error(ErrorCode::kInvalidArgument, "image index: dims = ", dims, " must be at least 1");
  if (training.size() % static_cast<size_t>(dims) != 0)
    throw_error(ErrorCode::kInvalidArgument, "image index: ", training.size(), " floats is not a multiple of dims ",
                dims);
  const size_t n = training.size() / dims;
  ImageIndex out;
  out.options_ = options;
  out.dims_ = dims;
  if (options.type == ImageIndexType::kFlat) {
    auto idmap = std::make_unique<faiss::IndexIDMap>(new faiss::IndexFlatL2(dims));
    idmap->own_fields = true;
    out.impl_->index = std::move(idmap);
    return out;
  }
  if (dims % options.pq_bytes != 0)
    throw_error(ErrorCode::kInvalidArgument, "image index option pq_bytes = ", options.pq_bytes,
                ": must divide the vector dimension ", dims);
  if (n < 2)
    throw_error(ErrorCode::kInvalidArgument, "image index: IVF-PQ needs at least 2 training vectors, got ", n);
  // Sample the training set.
  std::vector<float> sample;
  std::span<const float> train_set = training;
  if (n > static_cast<size_t>(options.max_training_vectors)) {
    RandomGenerator rng(options.seed);
    const size_t m = static_cast<size_t>(options.max_training_vectors);
    const std::vector<size_t> idx = sample_sorted_indices(n, m, rng);
    sample.resize(m * dims);
    for (size_t i = 0; i < m; ++i)
      std::copy_n(training.data() + idx[i] * dims, dims, sample.data() + i * dims);
    train_set = sample;
  }
  const size_t nt = train_set.size() / dims;
  out.effective_nlist_ = static_cast<int>(std::min<size_t>(options.nlist, std::max<size_t>(1, nt / 39)));
  out.effective_pq_bits_ = std::min(options.pq_bits, static_cast<int>(std::floor(std::log2(static_cast<double>(nt)))));
  if (options.precomputed_tables) {  // the limit load() enforces: never write an index that cannot be read
    const double table_bytes = 4.0 * out.effective_nlist_ * options.pq_bytes * std::ldexp(1.0, out.effective_pq_bits_);
    if (table_bytes > static_cast<double>(faiss::precomputed_table_max_bytes))
      throw_error(ErrorCode::kInvalidArgument, "image index: precomputed tables would take ", table_bytes / (1 << 20),
                  " MiB, more than FAISS's limit of ", faiss::precomputed_table_max_bytes >> 20,
                  " MiB; use fewer lists or bits, or no precomputed tables");
  }
  auto* quantizer = new faiss::IndexFlatL2(dims);
  auto ivfpq = std::make_unique<faiss::IndexIVFPQ>(quantizer, dims, out.effective_nlist_, options.pq_bytes,
                                                   out.effective_pq_bits_);
  ivfpq->own_fields = true;
  ivfpq->cp.seed = static_cast<int>(options.seed & 0x7fffffff);
  ivfpq->pq.cp.seed = static_cast<int>((options.seed + 1) & 0x7fffffff);
  ivfpq->cp.min_points_per_centroid = 1;  // sizes are chosen above; no FAISS warnings
  ivfpq->pq.cp.min_points_per_centroid = 1;
  ivfpq->use_precomputed_table = options.precomputed_tables ? 1 : -1;
  ivfpq->nprobe = static_cast<size_t>(options.nprobe);
  try {
    ivfpq->train(static_cast<faiss::Index::idx_t>(nt), train_set.data());
  } catch (const faiss::FaissException& ex) {
    throw_error(ErrorCode::kInvalidArgument, "image index training failed: ", ex.what());
  }
  configure_tables(ivfpq.get(), options.precomputed_tables);
  out.impl_->ivfpq = ivfpq.get();
  out.impl_->index = std::move(ivfpq);
  return out;
}

ImageIndex ImageIndex::build(std::span<const float> vectors, std::span<const int64_t> ids, int dims,
                             const ImageIndexOptions& options) {
  ImageIndex index = train(vectors, dims, options);
  index.add(vectors, ids);
  return index;
}

void ImageIndex::add(std::span<const float> vectors, std::span<const int64_t> ids) {
  VISLOC_CHECK(impl_->index != nullptr, "add() on an empty ImageIndex");
  if (vectors.size() != ids.size() * static_cast<size_t>(dims_))
    throw_error(ErrorCode::kInvalidArgument, "image index add: ", vectors.size(), " floats for ", ids.size(),
                " ids of dimension ", dims_);
  static_assert(sizeof(faiss::Index::idx_t) == sizeof(int64_t));
  impl_->index->add_with_ids(static_cast<faiss::Index::idx_t>(ids.size()), vectors.data(),
                             reinterpret_cast<const faiss::Index::idx_t*>(ids.data()));
}

std::vector<ImageSearchResult> ImageIndex::search(std::span<const float> query, int top) const {
  std::vector<ImageSearchResult> out;
  search(query, top, out);
  while (!out.empty() && out.back().image < 0) out.pop_back();
  return out;
}

void ImageIndex::search(std::span<const float> queries, int top, std::vector<ImageSearchResult>& out) const {
  VISLOC_CHECK(impl_->index != nullptr, "search() on an empty ImageIndex");
  if (top < 1) throw_error(ErrorCode::kInvalidArgument, "image index search: top = ", top, " must be at least 1");
  if (queries.size() % static_cast<size_t>(dims_) != 0)
    throw_error(ErrorCode::kInvalidArgument, "image index search: ", queries.size(),
                " floats is not a multiple of dims ", dims_);
  const size_t n = queries.size() / dims_;
  std::vector<float> distances(n * top);
  std::vector<faiss::Index::idx_t> labels(n * top);
  impl_->index->search(static_cast<faiss::Index::idx_t>(n), queries.data(), top, distances.data(), labels.data());
  out.resize(n * top);
  for (size_t i = 0; i < n * top; ++i) out[i] = {labels[i], distances[i]};
}

void ImageIndex::set_nprobe(int nprobe) {
  if (nprobe < 1) throw_error(ErrorCode::kInvalidArgument, "image index option nprobe = ", nprobe, ": must be at least 1");
  options_.nprobe = nprobe;
  if (impl_->ivfpq) impl_->ivfpq->nprobe = static_cast<size_t>(nprobe);
}

size_t ImageIndex::size() const { return impl_->index ? static_cast<size_t>(impl_->index->ntotal) : 0; }

size_t ImageIndex::bytes_per_image() const {
  if (impl_->ivfpq) return impl_->ivfpq->code_size + sizeof(faiss::Index::idx_t);
  return static_cast<size_t>(dims_) * sizeof(float) + sizeof(faiss::Index::idx_t);
}

size_t ImageIndex::fixed_bytes() const {
  const faiss::IndexIVFPQ* q = impl_->ivfpq;
  if (!q) return 0;
  return sizeof(float) * (q->nlist * static_cast<size_t>(q->d) + q->pq.centroids.size() + q->precomputed_table.size());
}

void ImageIndex::save(const std::filesystem::path& path) const {
  VISLOC_CHECK(impl_->index != nullptr, "saving an empty ImageIndex");
  faiss::VectorIOWriter writer;
  faiss::write_index(impl_->index.get(), &writer);
  const nlohmann::json meta = {{"type", type_name(options_.type)},
                               {"dims", dims_},
                               {"count", size()},
                               {"nlist", options_.nlist},
                               {"nprobe", options_.nprobe},
                               {"pq_bytes", options_.pq_bytes},
                               {"pq_bits", options_.pq_bits},
                               {"precomputed_tables", options_.precomputed_tables},
                               {"max_training_vectors", options_.max_training_vectors},
                               {"seed", options_.seed},
                               {"effective_nlist", effective_nlist_},
                               {"effective_pq_bits", effective_pq_bits_}};
  SectionFileWriter w(path, "IIDX", kImageIndexFileVersion);
  w.add_text("META", meta.dump());
  w.add("FAIS", writer.data.data(), writer.data.size());
  w.commit();
}

ImageIndex ImageIndex::load(const std::filesystem::path& path) {
  SectionFileReader r(path, "IIDX", 1, kImageIndexFileVersion);
  const IndexFileError fail{path};
  const IndexMeta meta = parse_meta(r.text("META"), fail);
  ImageIndex out;
  out.options_ = meta.options;
  out.dims_ = meta.dims;
  out.effective_nlist_ = meta.effective_nlist;
  out.effective_pq_bits_ = meta.effective_pq_bits;
  const size_t count = meta.count;
  const auto bytes = r.bytes("FAIS");
  check_faiss_section(bytes, meta, fail);
  std::unique_ptr<faiss::Index> index = read_faiss_section(bytes, fail);
  if (index->d != out.dims_ || static_cast<size_t>(index->ntotal) != count)
    fail("FAISS index has dimension ", index->d, " and ", index->ntotal, " vectors, META says ", out.dims_, " and ",
         count);
  if (out.options_.type == ImageIndexType::kIvfPq) {
    auto* ivfpq = dynamic_cast<faiss::IndexIVFPQ*>(index.get());
    if (!ivfpq) fail("META says ivfpq but the FAISS index is not an IndexIVFPQ");
    check_ivfpq(ivfpq, out.dims_, fail);
    ivfpq->nprobe = static_cast<size_t>(out.options_.nprobe);
    configure_tables(ivfpq, out.options_.precomputed_tables);
    out.impl_->ivfpq = ivfpq;
  } else {
    const auto* idmap = dynamic_cast<faiss::IndexIDMap*>(index.get());
    if (!idmap) fail("META says flat but the FAISS index is not an IndexIDMap");
    if (idmap->id_map.size() != static_cast<size_t>(idmap->ntotal)) fail("id map disagrees with the vector count");
    check_flat(idmap->index, "flat index", idmap->ntotal, out.dims_, fail);
  }
  out.impl_->index = std::move(index);
  return out;
}

}  // namespace visloc
