// Fuzzes T-embedding parameter files (retrieval/triangulation_embedding.h
// TriangulationEmbedding::load, kind "TEMB"), then embeds a few descriptors
// with sum and democratic pooling and computes their VLAD.
#include "fuzz_harness.h"
#include "visloc/retrieval/triangulation_embedding.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("embedding.vltemb", data, size);
  fuzz::accepts([&] {
    const TriangulationEmbedding embedding = TriangulationEmbedding::load(path);
    const DescriptorMatrix descriptors = fuzz::sample_descriptors(8);
    for (auto pooling : {EmbeddingPooling::kSum, EmbeddingPooling::kDemocratic}) {
      const std::vector<float> v = embedding.with_pooling(pooling).embed(descriptors);
      if (v.size() != size_t(embedding.dims()))
        fuzz::report_bug("embedding of the wrong size", std::to_string(v.size()));
    }
    (void)embedding.vlad(descriptors);
    (void)embedding.parameter_bytes();
  });
  return 0;
}
