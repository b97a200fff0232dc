// Fuzzes Bundler image lists ("name [0 focal]" per line; colmap/bundler.h
// read_bundler_list).
#include "fuzz_harness.h"
#include "visloc/colmap/bundler.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("list.txt", data, size);
  fuzz::accepts([&] {
    size_t sum = 0;
    for (const BundlerListEntry& e : read_bundler_list(path)) sum += e.name.size() + e.has_focal;
    if (sum == 0xdeadbeef) std::fputc('.', stderr);
  });
  return 0;
}
