// Fuzzes Lowe's SIFT key files, plain or gzip (colmap/bundler.h
// read_lowe_key_file), with RootSIFT conversion and with Lowe's integers kept.
#include "fuzz_harness.h"
#include "visloc/colmap/bundler.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("0000.key", data, size);
  for (const bool root_sift : {true, false}) {
    fuzz::accepts([&] {
      const FeatureSet f = read_lowe_key_file(path, root_sift);
      f.check_consistent();
      uint64_t sum = f.image.size();
      for (size_t i = 0; i < f.descriptors.rows(); ++i) sum += f.descriptors.row(i)[5];
      if (sum == 0xdeadbeef) std::fputc('.', stderr);
    });
  }
  return 0;
}
