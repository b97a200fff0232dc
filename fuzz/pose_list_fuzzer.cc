// Fuzzes pose lists, "name qw qx qy qz tx ty tz" per line (geometry/pose_list.h
// read_pose_list), then computes every camera centre.
#include "fuzz_harness.h"
#include "visloc/geometry/pose_list.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("truth.txt", data, size);
  fuzz::accepts([&] {
    double sum = 0;
    for (const NamedPose& p : read_pose_list(path)) sum += p.cam_from_world.center().norm() + p.name.size();
    if (sum == 0.125) std::fputc('.', stderr);
  });
  return 0;
}
