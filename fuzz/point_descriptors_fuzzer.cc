// Fuzzes point descriptor files (map/map.h read_point_descriptor_file, kind
// "PDSC", MAP/descriptors/NNNN.vldesc), then walks every row read.
#include "fuzz_harness.h"
#include "visloc/map/map.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("descriptors/0000.vldesc", data, size);
  fuzz::accepts([&] {
    const DescriptorMatrix descriptors = read_point_descriptor_file(path);
    uint64_t sum = 0;
    for (size_t i = 0; i < descriptors.rows(); ++i) sum += descriptors.row(i)[0] + descriptors.row(i)[127];
    if (sum == 0xdeadbeef) std::fputc('.', stderr);
  });
  return 0;
}
