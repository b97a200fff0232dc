// The FAISS layout walk (faiss_layout.h) against indexes written by the
// installed FAISS: it must read them to the last byte, and refuse any count
// that the bytes do not back before FAISS's reader allocates it.
#include <gtest/gtest.h>
#include <omp.h>

#include <cstring>
#include <filesystem>
#include <numeric>
#include <string>
#include <vector>

#include "visloc/retrieval/faiss_layout.h"
#include "visloc/retrieval/image_index.h"
#include "visloc/util/error.h"
#include "visloc/util/random.h"
#include "visloc/util/section_file.h"
#include "visloc/util/test_support.h"

namespace visloc {
namespace {

namespace fs = std::filesystem;

const int kOneThread = [] {
  omp_set_num_threads(1);
  return 1;
}();

constexpr int kDims = 16;

std::vector<float> random_vectors(size_t n, uint64_t seed) {
  RandomGenerator rng(seed);
  std::vector<float> v(n * kDims);
  for (float& x : v) x = static_cast<float>(rng.uniform());
  return v;
}

struct WrittenIndex {
  fs::path path;
  std::string meta;
  std::vector<uint8_t> faiss_bytes;
};

// Trains on `train` vectors, adds the first `added` of them, saves, and
// returns the file with its META and FAIS sections.
WrittenIndex write_index(ImageIndexType type, size_t train, size_t added, const std::string& name) {
  ImageIndexOptions o;
  o.type = type;
  o.nlist = 8;
  o.pq_bytes = 4;
  o.pq_bits = 4;
  const std::vector<float> vectors = random_vectors(train, 7);
  ImageIndex index = ImageIndex::train(vectors, kDims, o);
  std::vector<int64_t> ids(added);
  std::iota(ids.begin(), ids.end(), int64_t{1000});
  index.add(std::span<const float>(vectors.data(), added * kDims), ids);
  WrittenIndex out;
  out.path = unique_temp_path("visloc_faiss_layout_" + name + ".vlidx");
  index.save(out.path);
  SectionFileReader r(out.path, "IIDX", 1, kImageIndexFileVersion);
  out.meta = std::string(r.text("META"));
  const auto bytes = r.bytes("FAIS");
  out.faiss_bytes.assign(bytes.begin(), bytes.end());
  return out;
}

void rewrite(const WrittenIndex& w, const std::vector<uint8_t>& faiss_bytes, const fs::path& path) {
  SectionFileWriter writer(path, "IIDX", kImageIndexFileVersion);
  writer.add_text("META", w.meta);
  writer.add("FAIS", faiss_bytes.data(), faiss_bytes.size());
  writer.commit();
}

TEST(FaissLayout, ReadsWrittenIndexesToTheLastByte) {
  // 8 × 39 training vectors keep nlist at 8. Adding 2 leaves most lists
  // empty (FAISS writes the sparse list sizes), adding all fills them (full).
  struct Case {
    ImageIndexType type;
    size_t added;
    const char* name;
  };
  for (const Case& c : {Case{ImageIndexType::kFlat, 40, "flat"}, Case{ImageIndexType::kIvfPq, 2, "ivfpq_sparse"},
                        Case{ImageIndexType::kIvfPq, 312, "ivfpq_full"}}) {
    SCOPED_TRACE(c.name);
    const WrittenIndex w = write_index(c.type, 312, c.added, c.name);
    const FaissLayout layout = c.type == ImageIndexType::kIvfPq ? FaissLayout::kIvfPq : FaissLayout::kIdMapFlat;
    const FaissLayoutFacts facts = check_faiss_layout(w.faiss_bytes, layout);
    EXPECT_EQ(facts.dims, kDims);
    EXPECT_EQ(facts.count, static_cast<int64_t>(c.added));
    if (c.type == ImageIndexType::kIvfPq) {
      EXPECT_EQ(facts.nlist, 8u);
      EXPECT_EQ(facts.pq_m, 4u);
      EXPECT_EQ(facts.pq_nbits, 4u);
    }
    // The other layout is refused.
    const FaissLayout other = layout == FaissLayout::kIvfPq ? FaissLayout::kIdMapFlat : FaissLayout::kIvfPq;
    EXPECT_THROW(check_faiss_layout(w.faiss_bytes, other), Error);
    // Every truncation is refused, and so is a trailing byte.
    for (size_t size = 0; size < w.faiss_bytes.size(); ++size) {
      try {
        check_faiss_layout(std::span<const uint8_t>(w.faiss_bytes.data(), size), layout);
        ADD_FAILURE() << "a truncation to " << size << " of " << w.faiss_bytes.size() << " bytes was accepted";
        break;
      } catch (const Error& ex) {
        ASSERT_EQ(ex.code(), ErrorCode::kFormat);
      }
    }
    std::vector<uint8_t> longer = w.faiss_bytes;
    longer.push_back(0);
    EXPECT_THROW(check_faiss_layout(longer, layout), Error);
    fs::remove(w.path);
  }
}

TEST(FaissLayout, PlantedHugeCountsAreRefusedBeforeFaissAllocates) {
  // A count of 2^36 at every 4-byte offset of the FAISS section. Before the
  // walk, one such count in the product quantizer made FAISS's reader ask for
  // hundreds of gigabytes. Now every load either refuses the file (kFormat,
  // naming it) or, where the planted value is not a count, loads an index
  // that searches.
  for (ImageIndexType type : {ImageIndexType::kFlat, ImageIndexType::kIvfPq}) {
    const WrittenIndex w = write_index(type, 312, type == ImageIndexType::kFlat ? 3 : 20, "planted");
    const fs::path planted = unique_temp_path("visloc_faiss_layout_planted_copy.vlidx");
    int refused = 0, loaded = 0;
    for (size_t at = 0; at + 8 <= w.faiss_bytes.size(); at += 4) {
      std::vector<uint8_t> bytes = w.faiss_bytes;
      const uint64_t huge = uint64_t{1} << 36;
      std::memcpy(bytes.data() + at, &huge, sizeof(huge));
      rewrite(w, bytes, planted);
      bool walk_accepts = true;
      try {
        check_faiss_layout(bytes, type == ImageIndexType::kIvfPq ? FaissLayout::kIvfPq : FaissLayout::kIdMapFlat);
      } catch (const Error&) {
        walk_accepts = false;
      }
      try {
        const ImageIndex index = ImageIndex::load(planted);
        const std::vector<float> query = random_vectors(1, 99);
        index.search(query, 3);
        ++loaded;
      } catch (const Error& ex) {
        EXPECT_EQ(ex.code(), ErrorCode::kFormat) << ex.what();
        EXPECT_NE(std::string(ex.what()).find(planted.string()), std::string::npos) << ex.what();
        ++refused;
        // The walk alone refuses every planted count: FAISS's reader never
        // sees one (without it, this file reached FAISS's allocation).
        EXPECT_FALSE(walk_accepts) << "refused only after FAISS read it: " << ex.what();
      }
    }
    EXPECT_GT(refused, 0);
    fs::remove(planted);
    fs::remove(w.path);
  }
}

TEST(FaissLayout, CountsThatWrapAroundIn64BitsAreRefused) {
  // An IVF-PQ whose coarse quantizer claims 2^60 centroids of dimension 16
  // and stores none: 2^60 × 16 wraps to 0 in 64 bits. The walk must refuse it
  // before anything is sized by that count.
  auto put = [](std::vector<uint8_t>& b, auto v) {
    const auto* p = reinterpret_cast<const uint8_t*>(&v);
    b.insert(b.end(), p, p + sizeof(v));
  };
  auto header = [&](std::vector<uint8_t>& b, int32_t d, int64_t ntotal) {
    put(b, d);
    put(b, ntotal);
    put(b, int64_t{1} << 20);
    put(b, int64_t{1} << 20);
    put(b, uint8_t{1});
    put(b, int32_t{1});
  };
  const uint64_t huge = uint64_t{1} << 60;
  std::vector<uint8_t> b;
  b.insert(b.end(), {'I', 'w', 'P', 'Q'});
  header(b, kDims, 0);
  put(b, huge);          // nlist
  put(b, uint64_t{1});   // nprobe
  b.insert(b.end(), {'I', 'x', 'F', '2'});
  header(b, kDims, static_cast<int64_t>(huge));
  put(b, uint64_t{0});   // no floats
  put(b, uint8_t{0});    // direct map: none
  put(b, uint64_t{0});
  put(b, uint8_t{1});    // by_residual
  put(b, uint64_t{2});   // code size: 4 × 4 bits
  put(b, uint64_t{kDims});
  put(b, uint64_t{4});
  put(b, uint64_t{4});
  put(b, uint64_t{kDims << 4});
  for (int i = 0; i < (kDims << 4); ++i) put(b, 0.0f);
  b.insert(b.end(), {'i', 'l', 'a', 'r'});
  put(b, huge);
  put(b, uint64_t{2});
  b.insert(b.end(), {'f', 'u', 'l', 'l'});
  put(b, huge);
  try {
    check_faiss_layout(b, FaissLayout::kIvfPq);
    ADD_FAILURE() << "a quantizer of 2^60 centroids and no data was accepted";
  } catch (const Error& ex) {
    EXPECT_EQ(ex.code(), ErrorCode::kFormat);
    EXPECT_NE(std::string(ex.what()).find("coarse quantizer"), std::string::npos) << ex.what();
  }
}

}  // namespace
}  // namespace visloc
