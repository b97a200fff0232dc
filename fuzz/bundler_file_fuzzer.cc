// Fuzzes Bundler v0.3 bundle.out files, plain or gzip (colmap/bundler.h
// read_bundler_file), then walks the cameras and points read.
#include "fuzz_harness.h"
#include "visloc/colmap/bundler.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("bundle.out", data, size);
  fuzz::accepts([&] {
    const BundlerFile bundle = read_bundler_file(path);
    size_t registered = 0;
    for (const BundlerCamera& c : bundle.cameras) registered += c.registered();
    for (const BundlerPoint& p : bundle.points)
      for (const BundlerView& v : p.views)
        if (v.camera >= bundle.cameras.size()) fuzz::report_bug("a view names a camera out of range", std::to_string(v.camera));
    if (registered == 0xdeadbeef) std::fputc('.', stderr);
  });
  return 0;
}
