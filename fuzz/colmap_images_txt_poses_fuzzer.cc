// Fuzzes the poses of a COLMAP images.txt (geometry/pose_list.h
// read_colmap_images_txt_poses), then computes every camera centre.
#include "fuzz_harness.h"
#include "visloc/geometry/pose_list.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("images.txt", data, size);
  fuzz::accepts([&] {
    double sum = 0;
    for (const NamedPose& p : read_colmap_images_txt_poses(path)) sum += p.cam_from_world.center().norm() + p.name.size();
    if (sum == 0.125) std::fputc('.', stderr);
  });
  return 0;
}
