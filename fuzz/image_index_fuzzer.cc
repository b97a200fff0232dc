// Fuzzes image index files (retrieval/image_index.h ImageIndex::load, kind
// "IIDX", FAISS's serialization inside), then searches the index read.
#include "fuzz_harness.h"
#include "visloc/retrieval/image_index.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("index.vlidx", data, size);
  fuzz::accepts([&] {
    ImageIndex index = ImageIndex::load(path);
    (void)index.bytes_per_image();
    (void)index.fixed_bytes();
    // The dimension is the file's; a query of a million floats is the harness's limit, not a bug.
    if (index.dims() <= 0 || index.dims() > (1 << 20)) return;
    std::vector<float> query(size_t(index.dims()), 0.0f);
    query[0] = 1.0f;
    // Ids are the caller's (any int64): RetrievalMap checks them against its image table.
    (void)index.search(query, 5);
  });
  return 0;
}
