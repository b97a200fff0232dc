// Micro-benchmarks of the per-candidate distance kernels of the cascade
// search, each beside its baseline in the same run:
//   Hamming distance of 128-bit codes (XOR + popcount) vs L2 on raw uint8 SIFT;
//   PQ asymmetric distance (16 table lookups) vs L2 on float descriptors;
//   CRC32C throughput (segment files are verified at open).
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/util/crc32c.h"

namespace {

constexpr size_t kPoints = 4096;

std::vector<uint8_t> random_bytes(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> v(n);
  for (auto& b : v) b = static_cast<uint8_t>(rng());
  return v;
}

void BM_HammingPopcount(benchmark::State& state) {
  auto bytes = random_bytes(kPoints * sizeof(visloc::HashCode), 1);
  const auto* codes = reinterpret_cast<const visloc::HashCode*>(bytes.data());
  const visloc::HashCode q = codes[7];
  for (auto _ : state) {
    uint32_t sum = 0;
    for (size_t i = 0; i < kPoints; ++i) sum += visloc::hamming_distance(q, codes[i]);
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_HammingPopcount);

void BM_RawSiftL2Baseline(benchmark::State& state) {
  auto desc = random_bytes(kPoints * 128, 2);
  auto q = random_bytes(128, 3);
  for (auto _ : state) {
    uint64_t sum = 0;
    for (size_t i = 0; i < kPoints; ++i) {
      uint32_t d = 0;
      const uint8_t* p = desc.data() + i * 128;
      for (int k = 0; k < 128; ++k) {
        const int x = int(p[k]) - int(q[k]);
        d += static_cast<uint32_t>(x * x);
      }
      sum += d;
    }
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_RawSiftL2Baseline);

void BM_PqAdcLookup(benchmark::State& state) {
  auto codes = random_bytes(kPoints * visloc::kPqCodeBytes, 4);
  std::vector<float> table(visloc::kPqTableSize);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1000);
  for (auto& t : table) t = u(rng);
  for (auto _ : state) {
    float sum = 0;
    for (size_t i = 0; i < kPoints; ++i) sum += visloc::adc_distance(table.data(), codes.data() + i * visloc::kPqCodeBytes);
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_PqAdcLookup);

void BM_FloatL2Baseline(benchmark::State& state) {
  std::vector<float> desc(kPoints * 128), q(128);
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> u(0, 255);
  for (auto& x : desc) x = u(rng);
  for (auto& x : q) x = u(rng);
  for (auto _ : state) {
    float sum = 0;
    for (size_t i = 0; i < kPoints; ++i) {
      float d = 0;
      const float* p = desc.data() + i * 128;
      for (int k = 0; k < 128; ++k) d += (p[k] - q[k]) * (p[k] - q[k]);
      sum += d;
    }
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_FloatL2Baseline);

void BM_Crc32c(benchmark::State& state) {
  auto data = random_bytes(1 << 20, 7);
  for (auto _ : state) benchmark::DoNotOptimize(visloc::crc32c(data.data(), data.size()));
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(data.size()));
}
BENCHMARK(BM_Crc32c);

}  // namespace
