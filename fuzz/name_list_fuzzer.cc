// Fuzzes image name lists, one name per line (geometry/pose_list.h read_name_list).
#include "fuzz_harness.h"
#include "visloc/geometry/pose_list.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("queries.txt", data, size);
  fuzz::accepts([&] {
    size_t sum = 0;
    for (const std::string& name : read_name_list(path)) sum += name.size();
    if (sum == 0xdeadbeef) std::fputc('.', stderr);
  });
  return 0;
}
