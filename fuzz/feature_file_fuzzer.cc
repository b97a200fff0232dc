// Fuzzes feature files (features/feature_set.h read_feature_file, kind
// "FEAT"), then walks every keypoint and descriptor row read.
#include "fuzz_harness.h"
#include "visloc/features/feature_set.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("image.jpg.vlfeat", data, size);
  fuzz::accepts([&] {
    const FeatureSet features = read_feature_file(path);
    features.check_consistent();
    uint64_t sum = features.image.size() + features.extractor.size();
    for (const Keypoint& k : features.keypoints) sum += k.x != 0;
    for (size_t i = 0; i < features.descriptors.rows(); ++i) sum += features.descriptors.row(i)[kDescriptorDim - 1];
    if (sum == 0xdeadbeef) std::fputc('.', stderr);
  });
  return 0;
}
