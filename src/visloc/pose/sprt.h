// Wald's sequential probability ratio test for RANSAC model verification
// (O. Chum and J. Matas, "Optimal Randomized RANSAC", PAMI 30(8), 2008), as
// used by the one-many RANSAC's pre-verification (Tran et al., III-B).
//
//   ε = P(a point is consistent | good model), δ = P(consistent | bad model).
//   Likelihood ratio after the j-th tested point:
//     λ_j = λ_{j−1} · δ/ε              if the point is consistent,
//     λ_j = λ_{j−1} · (1−δ)/(1−ε)      otherwise;            λ_0 = 1.
//   The model is rejected as soon as λ_j > A.
//   Optimal threshold A (Chum & Matas eq. 9–11): with
//     C  = (1−δ) log((1−δ)/(1−ε)) + δ log(δ/ε)      (K2 = 1/C),
//     K1 = t_M / m_S   (time of one hypothesis, in units of one point
//                       verification, per model of the sample),
//   A is the fixed point of A = K1/K2 + 1 + log A, iterated from
//   A_0 = K1/K2 + 1:  A_{n+1} = K1/K2 + 1 + log(A_n).
//   α = 1/A bounds the probability of rejecting a good model, so the number
//   of samples until a good model is drawn and kept is geometric with mean
//     μ = 1 / (ε^s (1 − 1/A))                          (the paper's μ),
//   and the adaptive termination stops after
//     k = log(1 − η) / log(1 − ε^s (1 − 1/A))
//   samples, η the confidence.
// The test is only meaningful while δ < ε; otherwise (e.g. with the paper's
// initial ε = s/N_h below δ = 0.01) it is disabled (A = ∞) until a model
// with more support raises ε.
#pragma once

#include <cmath>
#include <limits>

namespace visloc {

struct SprtTest {
  double epsilon = 0;  // P(consistent | good)
  double delta = 0;    // P(consistent | bad)
  double threshold = std::numeric_limits<double>::infinity();  // A
  double consistent_factor = 1;    // δ/ε
  double inconsistent_factor = 1;  // (1−δ)/(1−ε)

  bool enabled() const { return std::isfinite(threshold); }

  // Recomputes A and the factors for (ε, δ), t_M and m_S.
  void update(double epsilon_in, double delta_in, double model_cost, double models_per_sample) {
    epsilon = epsilon_in;
    delta = delta_in;
    if (!(delta > 0 && epsilon > delta && epsilon < 1)) {
      threshold = std::numeric_limits<double>::infinity();
      consistent_factor = inconsistent_factor = 1;
      return;
    }
    consistent_factor = delta / epsilon;
    inconsistent_factor = (1 - delta) / (1 - epsilon);
    threshold = decision_threshold(epsilon, delta, model_cost, models_per_sample);
  }

  static double decision_threshold(double epsilon, double delta, double model_cost, double models_per_sample) {
    const double C = (1 - delta) * std::log((1 - delta) / (1 - epsilon)) + delta * std::log(delta / epsilon);
    const double k = model_cost * C / models_per_sample;  // K1/K2
    double A = k + 1;
    for (int i = 0; i < 50; ++i) {
      const double next = k + 1 + std::log(A);
      if (std::abs(next - A) < 1e-9 * A) {
        A = next;
        break;
      }
      A = next;
    }
    return A;
  }

  // Probability that a sample is all-inlier and its model survives the test.
  double good_sample_probability(int sample_size) const {
    const double p = std::pow(epsilon, sample_size);
    return enabled() ? p * (1 - 1 / threshold) : p;
  }
};

// Samples needed to draw, with confidence η, one sample whose probability
// of being good is p: log(1 − η)/log(1 − p), capped by `cap`.
inline double adaptive_iterations(double good_sample_probability, double confidence, double cap) {
  if (!(good_sample_probability > 0)) return cap;
  if (good_sample_probability >= 1) return 1;
  const double k = std::log(1 - confidence) / std::log1p(-good_sample_probability);
  return std::isfinite(k) ? std::min(k, cap) : cap;
}

}  // namespace visloc
