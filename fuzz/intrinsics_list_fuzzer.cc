// Fuzzes intrinsics lists, "name MODEL width height params..." per line
// (geometry/pose_list.h read_intrinsics_list), then projects a point with
// every camera read.
#include "fuzz_harness.h"
#include "visloc/geometry/pose_list.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("intrinsics.txt", data, size);
  fuzz::accepts([&] {
    double sum = 0;
    for (const NamedCamera& c : read_intrinsics_list(path))
      sum += c.camera.project(Eigen::Vector3d(0.1, -0.2, 1.0)).x() + c.camera.width + c.name.size();
    if (sum == 0.125) std::fputc('.', stderr);
  });
  return 0;
}
