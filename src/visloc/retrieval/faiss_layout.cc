#include "visloc/retrieval/faiss_layout.h"

#include <cstring>
#include <limits>
#include <vector>

#include "visloc/util/error.h"

namespace visloc {
namespace {

constexpr uint32_t fourcc(const char (&s)[5]) {
  return static_cast<uint32_t>(static_cast<uint8_t>(s[0])) | static_cast<uint32_t>(static_cast<uint8_t>(s[1])) << 8 |
         static_cast<uint32_t>(static_cast<uint8_t>(s[2])) << 16 | static_cast<uint32_t>(static_cast<uint8_t>(s[3])) << 24;
}

std::string printable_fourcc(uint32_t h) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((h >> (8 * i)) & 0xff);
    s += (c >= 32 && c < 127) ? c : '?';
  }
  return s;
}

// A bounds-checked cursor: every read and every skip is checked against what
// is left, and a count is only accepted when count × element size fits.
class Cursor {
 public:
  explicit Cursor(std::span<const uint8_t> bytes) : bytes_(bytes) {}

  template <typename T>
  T read(const char* what) {
    if (left() < sizeof(T)) fail(what, ": the index ends early (", left(), " bytes left, ", sizeof(T), " needed)");
    T value;
    std::memcpy(&value, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return value;
  }

  void skip(uint64_t count, uint64_t element_bytes, const char* what) {
    if (element_bytes != 0 && count > left() / element_bytes)
      fail(what, ": ", count, " elements of ", element_bytes, " bytes, but only ", left(), " bytes follow");
    at_ += static_cast<size_t>(count * element_bytes);
  }

  // FAISS's READVECTOR: a uint64 count, then count elements.
  uint64_t vector(uint64_t element_bytes, const char* what) {
    const uint64_t count = read<uint64_t>(what);
    skip(count, element_bytes, what);
    return count;
  }

  size_t left() const { return bytes_.size() - at_; }

  template <typename... Parts>
  [[noreturn]] static void fail(const Parts&... parts) {
    throw_error(ErrorCode::kFormat, "FAISS index section: ", parts...);
  }

 private:
  std::span<const uint8_t> bytes_;
  size_t at_ = 0;
};

struct IndexHeader {
  int32_t d = 0;
  int64_t ntotal = 0;
};

// read_index_header: d, ntotal, two unused idx_t, is_trained, metric_type
// (and metric_arg for metrics other than inner product and L2).
IndexHeader read_header(Cursor& c, const char* what) {
  IndexHeader h;
  h.d = c.read<int32_t>(what);
  h.ntotal = c.read<int64_t>(what);
  c.read<int64_t>(what);
  c.read<int64_t>(what);
  const uint8_t trained = c.read<uint8_t>(what);
  if (trained > 1) Cursor::fail(what, ": is_trained byte ", int{trained}, " (FAISS reads it as a bool)");
  const int32_t metric = c.read<int32_t>(what);
  if (metric != 1) Cursor::fail(what, ": metric ", metric, ", visloc writes L2 (1)");
  if (h.d < 1) Cursor::fail(what, ": dimension ", h.d);
  if (h.ntotal < 0) Cursor::fail(what, ": ", h.ntotal, " vectors");
  return h;
}

// IndexFlatL2: header, then ntotal × d floats as a byte vector whose stored
// count is a quarter of its bytes (READXBVECTOR).
IndexHeader read_flat_l2(Cursor& c, const char* what) {
  const uint32_t h = c.read<uint32_t>(what);
  if (h != fourcc("IxF2")) Cursor::fail(what, ": index type '", printable_fourcc(h), "', expected IxF2 (flat L2)");
  const IndexHeader header = read_header(c, what);
  const uint64_t quarter_bytes = c.vector(4, what);
  // Compared by division: ntotal × d can wrap around in 64 bits (a crafted
  // ntotal of 2^60 with d = 16 would match 0 floats).
  const uint64_t d = static_cast<uint64_t>(header.d);
  if (quarter_bytes % d != 0 || quarter_bytes / d != static_cast<uint64_t>(header.ntotal))
    Cursor::fail(what, ": ", quarter_bytes, " floats stored for ", header.ntotal, " vectors of dimension ", header.d);
  return header;
}

FaissLayoutFacts read_idmap_flat(Cursor& c) {
  FaissLayoutFacts facts;
  const uint32_t h = c.read<uint32_t>("index type");
  if (h != fourcc("IxMp")) Cursor::fail("index type '", printable_fourcc(h), "', expected IxMp (flat with ids)");
  const IndexHeader outer = read_header(c, "id map header");
  const IndexHeader inner = read_flat_l2(c, "flat index");
  if (inner.d != outer.d || inner.ntotal != outer.ntotal)
    Cursor::fail("id map holds ", outer.ntotal, " vectors of dimension ", outer.d, ", its flat index ", inner.ntotal,
                 " of dimension ", inner.d);
  const uint64_t ids = c.vector(8, "id map");
  if (ids != static_cast<uint64_t>(outer.ntotal)) Cursor::fail("id map has ", ids, " ids for ", outer.ntotal, " vectors");
  facts.dims = outer.d;
  facts.count = outer.ntotal;
  return facts;
}

FaissLayoutFacts read_ivfpq(Cursor& c) {
  FaissLayoutFacts facts;
  const uint32_t h = c.read<uint32_t>("index type");
  if (h != fourcc("IwPQ")) Cursor::fail("index type '", printable_fourcc(h), "', expected IwPQ (IVF-PQ)");
  // read_ivf_header: header, nlist, nprobe, the coarse quantizer, the direct map.
  const IndexHeader header = read_header(c, "IVF-PQ header");
  const uint64_t nlist = c.read<uint64_t>("IVF-PQ nlist");
  c.read<uint64_t>("IVF-PQ nprobe");
  const IndexHeader quantizer = read_flat_l2(c, "coarse quantizer");
  if (quantizer.d != header.d || static_cast<uint64_t>(quantizer.ntotal) != nlist)
    Cursor::fail("coarse quantizer holds ", quantizer.ntotal, " centroids of dimension ", quantizer.d, " for ", nlist,
                 " lists of dimension ", header.d);
  if (nlist < 1) Cursor::fail("IVF-PQ has no lists");
  const uint8_t direct_map = c.read<uint8_t>("direct map type");
  if (direct_map != 0) Cursor::fail("direct map type ", int{direct_map}, ", visloc writes none (0)");
  if (c.vector(8, "direct map") != 0) Cursor::fail("a direct map without a type has entries");
  const uint8_t by_residual = c.read<uint8_t>("IVF-PQ by_residual");
  if (by_residual > 1) Cursor::fail("IVF-PQ by_residual byte ", int{by_residual}, " (FAISS reads it as a bool)");
  const uint64_t code_size = c.read<uint64_t>("IVF-PQ code size");
  // read_ProductQuantizer: d, M, nbits (uint64 each), centroids.
  const uint64_t pq_d = c.read<uint64_t>("product quantizer");
  const uint64_t m = c.read<uint64_t>("product quantizer");
  const uint64_t nbits = c.read<uint64_t>("product quantizer");
  if (pq_d != static_cast<uint64_t>(header.d) || m < 1 || pq_d % m != 0 || nbits < 1 || nbits > 16)
    Cursor::fail("product quantizer of dimension ", pq_d, ", ", m, " sub-quantizers, ", nbits,
                 " bits (needs the index dimension ", header.d, ", divisible, 1-16 bits)");
  if (code_size != (m * nbits + 7) / 8)
    Cursor::fail("code size ", code_size, " for ", m, " sub-quantizers of ", nbits, " bits");
  const uint64_t centroids = c.vector(4, "product quantizer centroids");
  if (centroids != pq_d << nbits)
    Cursor::fail(centroids, " product quantizer centroid floats, expected ", pq_d << nbits);
  // read_InvertedLists: "ilar", nlist, code_size, the list sizes, then each
  // non-empty list's codes and ids.
  const uint32_t lists_type = c.read<uint32_t>("inverted lists");
  if (lists_type != fourcc("ilar"))
    Cursor::fail("inverted lists of type '", printable_fourcc(lists_type), "', expected ilar (array)");
  const uint64_t lists_nlist = c.read<uint64_t>("inverted lists");
  const uint64_t lists_code_size = c.read<uint64_t>("inverted lists");
  if (lists_nlist != nlist || lists_code_size != code_size)
    Cursor::fail("inverted lists of ", lists_nlist, " lists and ", lists_code_size, " bytes per code, the index has ",
                 nlist, " and ", code_size);
  // nlist is backed by the quantizer's nlist × d floats (checked above
  // without overflow), so this allocation is bounded by the section's size.
  std::vector<uint64_t> sizes(nlist, 0);
  const uint32_t sizes_type = c.read<uint32_t>("inverted list sizes");
  if (sizes_type == fourcc("full")) {
    const uint64_t n = c.read<uint64_t>("inverted list sizes");
    if (n != nlist) Cursor::fail(n, " inverted list sizes for ", nlist, " lists");
    for (uint64_t& s : sizes) s = c.read<uint64_t>("inverted list sizes");
  } else if (sizes_type == fourcc("sprs")) {
    const uint64_t n = c.read<uint64_t>("inverted list sizes");
    if (n % 2 != 0 || n / 2 > nlist) Cursor::fail(n, " sparse inverted list entries for ", nlist, " lists");
    for (uint64_t i = 0; i < n / 2; ++i) {
      const uint64_t list = c.read<uint64_t>("inverted list sizes");
      const uint64_t size = c.read<uint64_t>("inverted list sizes");
      if (list >= nlist) Cursor::fail("inverted list ", list, " of ", nlist);
      sizes[list] = size;
    }
  } else {
    Cursor::fail("inverted list sizes of type '", printable_fourcc(sizes_type), "'");
  }
  uint64_t listed = 0;
  for (uint64_t l = 0; l < nlist; ++l) {
    if (sizes[l] == 0) continue;
    c.skip(sizes[l], code_size, "inverted list codes");
    c.skip(sizes[l], 8, "inverted list ids");
    listed += sizes[l];
  }
  if (listed != static_cast<uint64_t>(header.ntotal))
    Cursor::fail("inverted lists hold ", listed, " vectors, the index ", header.ntotal);
  facts.dims = header.d;
  facts.count = header.ntotal;
  facts.nlist = nlist;
  facts.pq_m = m;
  facts.pq_nbits = nbits;
  return facts;
}

}  // namespace

FaissLayoutFacts check_faiss_layout(std::span<const uint8_t> bytes, FaissLayout layout) {
  Cursor c(bytes);
  const FaissLayoutFacts facts = layout == FaissLayout::kIvfPq ? read_ivfpq(c) : read_idmap_flat(c);
  if (c.left() != 0) Cursor::fail(c.left(), " bytes after the end of the index");
  return facts;
}

}  // namespace visloc
