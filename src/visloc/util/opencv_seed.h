// ScopedOpenCvSeed: OpenCV's RANSAC functions (findFundamentalMat,
// solvePnPRansac) sample with cv::theRNG(), the calling thread's generator.
// The guard seeds it for one call and puts the previous state back, so the
// library's results are reproducible and the caller's OpenCV state is left
// as it was.
#pragma once

#include <cstdint>

#include <opencv2/core.hpp>

namespace visloc {

class ScopedOpenCvSeed {
 public:
  explicit ScopedOpenCvSeed(uint64_t seed) : saved_(cv::theRNG().state) {
    cv::theRNG().state = seed != 0 ? seed : 0xffffffffull;  // OpenCV's RNG maps a zero state to this too
  }
  ~ScopedOpenCvSeed() { cv::theRNG().state = saved_; }
  ScopedOpenCvSeed(const ScopedOpenCvSeed&) = delete;
  ScopedOpenCvSeed& operator=(const ScopedOpenCvSeed&) = delete;

 private:
  uint64_t saved_;
};

}  // namespace visloc
