// Image input: JPEG/PNG pixels through OpenCV, metadata (size, EXIF focal
// length, GPS) through exiv2. The pixel limit is checked from the header
// before any pixel is decoded. EXIF orientation is deliberately ignored (as
// COLMAP does) so that keypoints refer to the stored pixel grid.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "visloc/geo/enu_frame.h"

namespace visloc {

struct ImageReadOptions {
  int64_t max_pixels = 40'000'000;  // refuse larger images (width × height)
  void validate() const;
};

struct ImageMetadata {
  int width = 0;
  int height = 0;
  std::optional<double> focal_mm;        // Exif.Photo.FocalLength
  std::optional<double> focal_35mm;      // Exif.Photo.FocalLengthIn35mmFilm
  std::optional<double> focal_plane_px_per_mm;  // from FocalPlaneXResolution + unit
  std::optional<GeoPosition> gps;        // Exif.GPSInfo (alt 0 when absent)
  std::string camera_make, camera_model;

  // Focal length in pixels when EXIF allows it: the 35 mm equivalent first,
  // then focal mm × focal-plane resolution. Empty when unknown.
  std::optional<double> focal_px() const;
};

// A decoded 8-bit greyscale image, rows contiguous.
struct GrayImage {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> pixels;
  const uint8_t* row(int y) const { return pixels.data() + static_cast<size_t>(y) * width; }
};

// True for the image files visloc reads: .jpg, .jpeg, .png (any case).
bool is_image_file(const std::filesystem::path& path);

// Metadata only (no pixel decoding). Throws Error naming the file when it is
// missing, not an image, or over the pixel limit.
ImageMetadata read_image_metadata(const std::filesystem::path& path,
                                  const ImageReadOptions& options = {});

// Pixels (greyscale) and metadata.
GrayImage read_gray_image(const std::filesystem::path& path, const ImageReadOptions& options = {},
                          ImageMetadata* metadata = nullptr);

// Writes an 8-bit greyscale or RGB (channels = 3, interleaved) image; the
// format follows the extension (.png, .jpg). Atomic (temporary + rename).
void write_image(const std::filesystem::path& path, int width, int height, int channels,
                 const uint8_t* pixels, int jpeg_quality = 92);

}  // namespace visloc
