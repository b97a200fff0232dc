// The RANSAC loop every robust estimator of visloc runs (absolute pose:
// one_many_ransac.h; two-view geometry reuses it), shaped like RansacLib's
// and PoseLib's: the estimator owns its data and workspace and answers four
// questions, and the loop combines separate pieces:
//
//   sampler      s distinct hypotheses drawn uniformly from the N_h of the
//                hypothesis set (the 1-1 matches);
//   solver       the estimator's minimal solver: 0..kMaxModels models;
//   pre-verify   optional SPRT (sprt.h) over the hypothesis set in one
//                seeded random order, from a random start per model;
//   score        the estimator's full verification (1-1 or 1-M inliers);
//   termination  fixed count, classical adaptive (ε = score / N_h), or the
//                SPRT one (ε from the best model's hypothesis-set support).
//
// Estimator interface:
//   using Model = ...;  static constexpr int kMaxSampleSize, kMaxModels;
//   int sample_size() const;
//   size_t num_hypotheses() const;                               // N_h
//   int solve(const uint32_t* sample, Model* models);            // sample: hypothesis indices
//   bool hypothesis_consistent(const Model&, uint32_t h) const;  // ρ_1 of hypothesis h
//   size_t score(const Model&) const;                            // full verification
//   void on_verified(const Model&, size_t score);                // every fully verified model
//
// The random stream is part of the contract (same seed, same result): the
// SPRT order is drawn first (N_h − 1 draws, whatever the termination), then
// per sample s draws (repeats redrawn), then per model one draw for the SPRT
// start when SPRT is on. The loop allocates nothing per sample (an
// estimator's on_verified may record what it verifies).
#pragma once

#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <vector>

#include "visloc/pose/sprt.h"
#include "visloc/util/random.h"

namespace visloc {

enum class RansacTermination {
  kFixed,         // exactly max_iterations samples
  kClassic,       // log(1−η)/log(1−ε^s), ε = best score / N_h
  kSprtAdaptive,  // log(1−η)/log(1−ε^s(1−1/A)), ε = best model's hypothesis-set support / N_h
};

struct RansacLoopOptions {
  RansacTermination termination = RansacTermination::kSprtAdaptive;
  bool sprt = true;                 // pre-verify every model on the hypothesis set
  size_t max_iterations = 10000;    // the cap (kFixed: the count)
  double confidence = 0.9999;       // η
  double sprt_delta0 = 0.01;        // initial δ
  double sprt_delta_prior_weight = 100;
  double sprt_model_cost = 250;     // t_M, in point verifications
  double models_per_sample = 1;     // m_S
};

struct RansacLoopStatistics {
  size_t iterations = 0, models = 0, models_rejected_sprt = 0, models_verified = 0, best_iteration = 0;
  double final_epsilon = 0, final_delta = 0, final_threshold = 0, expected_samples = 0;
  double hypothesis_ms = 0, verification_ms = 0;
};

template <typename Model>
struct RansacLoopResult {
  Model best{};
  size_t best_score = 0;  // 0: no model was verified with any support
  RansacLoopStatistics stats;
};

// Draws s distinct indices of [0, n) (n ≥ s), redrawing repeats.
inline void sample_distinct(RandomGenerator& rng, uint32_t n, int s, uint32_t* out) {
  for (int k = 0; k < s; ++k) {
    uint32_t pick;
    bool repeated;
    do {
      pick = rng.below(n);
      repeated = false;
      for (int m = 0; m < k; ++m) repeated |= out[m] == pick;
    } while (repeated);
    out[k] = pick;
  }
}

// Wald's SPRT over the hypothesis set with δ learnt from rejected models.
class SprtPreverification {
 public:
  SprtPreverification(const RansacLoopOptions& o, int sample_size, size_t num_hypotheses)
      : options_(o), delta_(o.sprt_delta0) {
    test_.update(static_cast<double>(sample_size) / static_cast<double>(num_hypotheses), delta_, o.sprt_model_cost,
                 o.models_per_sample);
  }
  // True when the model is rejected; `consistent(h)` is ρ_1 of hypothesis h,
  // visited in `order` from `start`. `support` counts the consistent ones tested.
  template <typename Consistent>
  bool reject(const std::vector<uint32_t>& order, size_t start, Consistent&& consistent, size_t* support) {
    const size_t n = order.size();
    double lambda = 1.0;
    size_t tested = 0;
    *support = 0;
    for (size_t j = 0; j < n; ++j) {
      size_t idx = start + j;
      if (idx >= n) idx -= n;
      const bool c = consistent(order[idx]);
      *support += c ? 1 : 0;
      ++tested;
      if (test_.enabled()) {
        lambda *= c ? test_.consistent_factor : test_.inconsistent_factor;
        if (lambda > test_.threshold) {
          learn_delta(*support, tested);
          return true;
        }
      }
    }
    return false;
  }
  void set_epsilon(double epsilon) {
    test_.update(epsilon, delta_, options_.sprt_model_cost, options_.models_per_sample);
  }
  const SprtTest& test() const { return test_; }
  double delta() const { return delta_; }

 private:
  // δ ← the pooled fraction of consistent points among those tested on
  // rejected models, with a prior of δ0 (weight: sprt_delta_prior_weight).
  void learn_delta(size_t consistent, size_t tested) {
    rejected_consistent_ += static_cast<double>(consistent);
    rejected_tested_ += static_cast<double>(tested);
    const double w = options_.sprt_delta_prior_weight;
    const double updated = (options_.sprt_delta0 * w + rejected_consistent_) / (w + rejected_tested_);
    if (std::abs(updated - delta_) > 0.05 * delta_) {
      delta_ = std::max(updated, 1e-6);
      test_.update(test_.epsilon, delta_, options_.sprt_model_cost, options_.models_per_sample);
    }
  }
  RansacLoopOptions options_;
  SprtTest test_;
  double delta_;
  double rejected_consistent_ = 0, rejected_tested_ = 0;
};

template <typename Estimator>
RansacLoopResult<typename Estimator::Model> run_ransac(Estimator& estimator, const RansacLoopOptions& options,
                                                       RandomGenerator& rng) {
  using Model = typename Estimator::Model;
  using Clock = std::chrono::steady_clock;
  auto ms = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  RansacLoopResult<Model> result;
  RansacLoopStatistics& st = result.stats;
  const int s = estimator.sample_size();
  const size_t nh = estimator.num_hypotheses();
  if (s < 1 || s > Estimator::kMaxSampleSize || nh < static_cast<size_t>(s)) return result;

  // The SPRT visiting order: the hypothesis set shuffled once per call.
  std::vector<uint32_t> order(nh);
  std::iota(order.begin(), order.end(), 0u);
  for (size_t i = nh - 1; i > 0; --i) std::swap(order[i], order[rng.below(static_cast<uint32_t>(i + 1))]);
  SprtPreverification sprt(options, s, nh);

  const size_t cap = options.max_iterations;
  size_t k_max = cap;
  std::array<uint32_t, Estimator::kMaxSampleSize> sample{};
  std::array<Model, Estimator::kMaxModels> models;
  size_t iter = 0;
  for (; iter < k_max; ++iter) {
    const auto t0 = Clock::now();
    sample_distinct(rng, static_cast<uint32_t>(nh), s, sample.data());
    const int num_models = estimator.solve(sample.data(), models.data());
    const auto t1 = Clock::now();
    st.hypothesis_ms += ms(t0, t1);
    for (int m = 0; m < num_models; ++m) {
      const Model& model = models[m];
      ++st.models;
      size_t support = 0;
      if (options.sprt) {
        const size_t start = rng.below(static_cast<uint32_t>(nh));
        if (sprt.reject(order, start, [&](uint32_t h) { return estimator.hypothesis_consistent(model, h); },
                        &support)) {
          ++st.models_rejected_sprt;
          continue;
        }
      }
      ++st.models_verified;
      const size_t score = estimator.score(model);
      estimator.on_verified(model, score);
      if (score <= result.best_score) continue;
      result.best_score = score;
      result.best = model;
      st.best_iteration = iter;
      if (options.termination == RansacTermination::kClassic) {
        const double eps = std::min(1.0, static_cast<double>(score) / static_cast<double>(nh));
        k_max = static_cast<size_t>(
            std::ceil(adaptive_iterations(std::pow(eps, s), options.confidence, static_cast<double>(cap))));
      } else if (options.termination == RansacTermination::kSprtAdaptive) {
        const double eps = std::max(static_cast<double>(support), static_cast<double>(s)) / static_cast<double>(nh);
        sprt.set_epsilon(eps);
        k_max = static_cast<size_t>(
            std::ceil(adaptive_iterations(sprt.test().good_sample_probability(s), options.confidence,
                                          static_cast<double>(cap))));
      }
    }
    st.verification_ms += ms(t1, Clock::now());
  }
  st.iterations = iter;
  if (options.sprt) {
    st.final_epsilon = sprt.test().epsilon;
    st.final_delta = sprt.delta();
    st.final_threshold = sprt.test().threshold;
    const double pg = sprt.test().good_sample_probability(s);
    st.expected_samples = pg > 0 ? 1.0 / pg : std::numeric_limits<double>::infinity();
  }
  return result;
}

}  // namespace visloc
