// Local features of one image, structure of arrays:
//   keypoints:   N × {x, y, scale, orientation} float32 (16 bytes each)
//   descriptors: N × 128 uint8, row-major, contiguous (COLMAP's storage)
// Pixel convention: the centre of the top-left pixel is (0.5, 0.5) (COLMAP's);
// coordinates refer to the original image even when SIFT ran on a downscaled
// copy. scale is the keypoint's Gaussian scale in original pixels, orientation
// in radians, counter-clockwise in image coordinates as OpenCV reports it.
#pragma once

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

namespace visloc {

inline constexpr int kDescriptorDim = 128;

struct Keypoint {
  float x = 0, y = 0, scale = 0, orientation = 0;
};
static_assert(sizeof(Keypoint) == 16);

// N × 128 uint8 descriptors in one contiguous buffer.
class DescriptorMatrix {
 public:
  DescriptorMatrix() = default;
  explicit DescriptorMatrix(size_t rows) : data_(rows * kDescriptorDim, 0) {}
  DescriptorMatrix(const uint8_t* data, size_t rows) : data_(data, data + rows * kDescriptorDim) {}

  size_t rows() const { return data_.size() / kDescriptorDim; }
  bool empty() const { return data_.empty(); }
  uint8_t* row(size_t i) { return data_.data() + i * kDescriptorDim; }
  const uint8_t* row(size_t i) const { return data_.data() + i * kDescriptorDim; }
  const uint8_t* data() const { return data_.data(); }
  uint8_t* data() { return data_.data(); }
  size_t size_bytes() const { return data_.size(); }
  void resize(size_t rows) { data_.resize(rows * kDescriptorDim); }
  void append(const DescriptorMatrix& other) { data_.insert(data_.end(), other.data_.begin(), other.data_.end()); }
  std::span<const uint8_t> bytes() const { return data_; }

 private:
  std::vector<uint8_t> data_;
};

struct FeatureSet {
  std::string image;   // image name (file name relative to its folder)
  int image_width = 0;
  int image_height = 0;
  std::vector<Keypoint> keypoints;
  DescriptorMatrix descriptors;
  std::string extractor;  // JSON of the options that produced it

  size_t size() const { return keypoints.size(); }
  // Throws Error(kInternal) when keypoints and descriptors disagree.
  void check_consistent() const;
};

// Feature files (.vlfeat): a SectionFile of kind "FEAT" (docs/formats.md)
// with sections META (JSON), KPTS (N × Keypoint) and DESC (N × 128 uint8).
inline constexpr uint32_t kFeatureFileVersion = 1;
void write_feature_file(const std::filesystem::path& path, const FeatureSet& features);
FeatureSet read_feature_file(const std::filesystem::path& path);

}  // namespace visloc
