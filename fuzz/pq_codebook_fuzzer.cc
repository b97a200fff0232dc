// Fuzzes PQ codebook files (matching/pq_codebook.h PqCodebook::read, kind
// "PQCB"), then uses the codebook: an ADC table (a product quantizer) or the
// additive kernel (a residual one), an encoding and a reconstruction.
#include <array>

#include "fuzz_harness.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/matching/search_kernels.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("pq_codebook.vlpq", data, size);
  fuzz::accepts([&] {
    std::string meta;
    const PqCodebook codebook = PqCodebook::read(path, &meta);
    std::array<float, 128> query{};
    for (size_t i = 0; i < query.size(); ++i) query[i] = float(i % 7) * 10.0f;
    std::array<uint8_t, kPqMaxSubvectors> code{};
    codebook.encode(query.data(), 1, code.data());
    float d = 0;
    if (codebook.is_residual()) {
      const uint32_t id = 0;
      search_kernels(SimdLevel::kScalar)
          .additive.direct(codebook.residual_splits())(codebook.centroids().data(), query.data(), code.data(), &id, 1,
                                                       &d);
    } else {
      std::vector<float> table(codebook.table_size());
      codebook.distance_table(query.data(), table.data());
      d = adc_distance(table.data(), code.data(), codebook.subvectors());
    }
    if (!(codebook.reconstruction_sqdist(code.data(), query.data()) >= 0) && d == d)
      fuzz::report_bug("negative squared distance", path.string());
  });
  return 0;
}
