// Photo crops for posters: square RGB patches cut from the photographs of a
// folder (e.g. ../shared/data/), so that some surfaces of the synthetic city
// carry natural-image texture. Files are read in sorted name order and crops
// are chosen by a seed: the set is a pure function of (folder, options).
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include "visloc/synth/procedural_texture.h"

namespace visloc::synth {

struct PhotoCropOptions {
  int count = 32;          // crops to keep in memory
  int size = 256;          // side of a crop, pixels
  uint64_t seed = 1;
  void validate() const;
};

struct PhotoCrop {
  int size = 0;
  std::vector<uint8_t> rgb;  // size × size × 3, row-major, top row first
};

class PhotoCropSet {
 public:
  PhotoCropSet() = default;
  explicit PhotoCropSet(std::vector<PhotoCrop> crops) : crops_(std::move(crops)) {}
  bool empty() const { return crops_.empty(); }
  size_t size() const { return crops_.size(); }
  // Bilinear sample of crop `index` at (s, t) in [0, 1]² (t = 0 at the top).
  Rgb sample(size_t index, double s, double t) const;

 private:
  std::vector<PhotoCrop> crops_;
};

// Reads every *.jpg/*.jpeg/*.png below `folder` (recursively, sorted), and
// cuts `count` square crops (each from a seeded file, position and size
// between a quarter and the whole of the shorter side), resized to
// size × size. Throws Error naming the folder when it holds no image.
PhotoCropSet load_photo_crops(const std::filesystem::path& folder, const PhotoCropOptions& options);

}  // namespace visloc::synth
