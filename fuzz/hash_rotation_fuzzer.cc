// Fuzzes hash rotation files (matching/binary_hasher.h
// read_hash_rotation_file, kind "ITQR"), then hashes descriptors with the
// rotation read and fingerprints it.
#include "fuzz_harness.h"
#include "visloc/matching/binary_hasher.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file(kHashRotationFileName, data, size);
  fuzz::accepts([&] {
    const BinaryHasher hasher = read_hash_rotation_file(path);
    const DescriptorMatrix descriptors = fuzz::sample_descriptors(4);
    std::vector<HashCode> codes(descriptors.rows());
    HashWorkspace workspace;
    encode_hash(hasher.view(), descriptors.data(), descriptors.rows(), codes.data(), workspace);
    (void)hash_rotation_fingerprint(hasher);
  });
  return 0;
}
