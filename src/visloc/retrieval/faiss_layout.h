#pragma once
// A walk over the bytes of a serialized FAISS index, before faiss::read_index
// sees them. FAISS's reader trusts every count it reads: it resizes a vector
// to the stored size and only then reads the data, so a crafted count of a
// few bytes asks for hundreds of gigabytes (found by fuzzing the image index;
// where overcommit lets the allocation through, zero-filling it exhausts the
// machine). This walk knows the layouts visloc writes, an IndexIDMap over an
// IndexFlatL2 and an IndexIVFPQ over an IndexFlatL2 coarse quantizer with
// array inverted lists, and checks that every count is backed by the bytes
// that follow and agrees with the others. Anything else is refused.
//
// The layout is FAISS's on-disk format (index_write.cpp), unchanged since
// FAISS 1.6; the test walks indexes written by the installed FAISS and
// requires the walk to end exactly at the last byte.

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace visloc {

enum class FaissLayout { kIdMapFlat, kIvfPq };

struct FaissLayoutFacts {
  int dims = 0;
  int64_t count = 0;      // vectors in the index
  uint64_t nlist = 0;     // IVF-PQ only
  uint64_t pq_m = 0;      // IVF-PQ only
  uint64_t pq_nbits = 0;  // IVF-PQ only
};

// Walks `bytes` as `layout`. Returns the facts it read, or throws
// Error(kFormat) with a message naming the field that is wrong (without the
// file name; the caller adds it).
FaissLayoutFacts check_faiss_layout(std::span<const uint8_t> bytes, FaissLayout layout);

}  // namespace visloc
