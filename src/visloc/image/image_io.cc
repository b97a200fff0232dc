#include "visloc/image/image_io.h"

#include <algorithm>
#include <cctype>

#include <exiv2/exiv2.hpp>
#if VISLOC_IMAGE_FILES
#include <opencv2/imgcodecs.hpp>
#endif
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstring>

#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace {

std::optional<double> exif_double(const Exiv2::ExifData& exif, const char* key) {
  auto it = exif.findKey(Exiv2::ExifKey(key));
  if (it == exif.end() || it->count() == 0) return std::nullopt;
  const auto r = it->toRational(0);
  if (r.second == 0) return std::nullopt;
  const double v = static_cast<double>(r.first) / r.second;
  if (!std::isfinite(v) || v <= 0) return std::nullopt;
  return v;
}

std::optional<double> exif_dms(const Exiv2::ExifData& exif, const char* key) {
  auto it = exif.findKey(Exiv2::ExifKey(key));
  if (it == exif.end() || it->count() < 3) return std::nullopt;
  double v = 0, scale = 1;
  for (long i = 0; i < 3; ++i) {
    const auto r = it->toRational(i);
    if (r.second == 0) {
      if (r.first == 0) { scale /= 60; continue; }
      return std::nullopt;
    }
    v += static_cast<double>(r.first) / r.second * scale;
    scale /= 60;
  }
  return v;
}

std::string exif_string(const Exiv2::ExifData& exif, const char* key) {
  auto it = exif.findKey(Exiv2::ExifKey(key));
  if (it == exif.end()) return "";
  std::string s = it->toString();
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  return s;
}

}  // namespace

void ImageReadOptions::validate() const {
  if (max_pixels <= 0)
    throw_error(ErrorCode::kInvalidArgument, "max_pixels must be positive, got ", max_pixels);
}

std::optional<double> ImageMetadata::focal_px() const {
  if (focal_35mm && width > 0) return *focal_35mm / 36.0 * std::max(width, height);
  if (focal_mm && focal_plane_px_per_mm) return *focal_mm * *focal_plane_px_per_mm;
  return std::nullopt;
}

ImageMetadata read_image_metadata(const std::filesystem::path& path, const ImageReadOptions& options) {
  options.validate();
  const std::string name = path.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw_error(ErrorCode::kIo, name, ": no such image file");
  ImageMetadata m;
  try {
    auto image = Exiv2::ImageFactory::open(name);
    if (image.get() == nullptr) throw_error(ErrorCode::kFormat, name, ": not an image");
    image->readMetadata();
    m.width = image->pixelWidth();
    m.height = image->pixelHeight();
    const Exiv2::ExifData& exif = image->exifData();
    if (!exif.empty()) {
      m.focal_mm = exif_double(exif, "Exif.Photo.FocalLength");
      m.focal_35mm = exif_double(exif, "Exif.Photo.FocalLengthIn35mmFilm");
      auto fpx = exif_double(exif, "Exif.Photo.FocalPlaneXResolution");
      auto unit_it = exif.findKey(Exiv2::ExifKey("Exif.Photo.FocalPlaneResolutionUnit"));
      if (fpx && unit_it != exif.end()) {
        const long unit = static_cast<long>(unit_it->toLong(0));
        const double mm_per_unit = unit == 2 ? 25.4 : unit == 3 ? 10.0 : unit == 4 ? 1.0 : 0.0;
        if (mm_per_unit > 0) m.focal_plane_px_per_mm = *fpx / mm_per_unit;
      }
      auto lat = exif_dms(exif, "Exif.GPSInfo.GPSLatitude");
      auto lon = exif_dms(exif, "Exif.GPSInfo.GPSLongitude");
      if (lat && lon) {
        GeoPosition g;
        g.lat = exif_string(exif, "Exif.GPSInfo.GPSLatitudeRef") == "S" ? -*lat : *lat;
        g.lon = exif_string(exif, "Exif.GPSInfo.GPSLongitudeRef") == "W" ? -*lon : *lon;
        auto alt_it = exif.findKey(Exiv2::ExifKey("Exif.GPSInfo.GPSAltitude"));
        if (alt_it != exif.end() && alt_it->count() > 0) {
          const auto r = alt_it->toRational(0);
          if (r.second != 0) g.alt = static_cast<double>(r.first) / r.second;
          auto ref = exif.findKey(Exiv2::ExifKey("Exif.GPSInfo.GPSAltitudeRef"));
          if (ref != exif.end() && ref->toLong(0) == 1) g.alt = -g.alt;
        }
        m.gps = g;
      }
      m.camera_make = exif_string(exif, "Exif.Image.Make");
      m.camera_model = exif_string(exif, "Exif.Image.Model");
    }
  } catch (const Exiv2::Error& e) {
    throw_error(ErrorCode::kFormat, name, ": not a readable image (", e.what(), ")");
  }
  if (m.width <= 0 || m.height <= 0)
    throw_error(ErrorCode::kFormat, name, ": not a readable image (no pixel dimensions)");
  if (static_cast<int64_t>(m.width) * m.height > options.max_pixels)
    throw_error(ErrorCode::kInvalidArgument, name, ": ", m.width, "x", m.height, " = ",
                static_cast<int64_t>(m.width) * m.height, " pixels exceeds the limit of ",
                options.max_pixels, " (raise --max-pixels to accept it)");
  return m;
}

GrayImage read_gray_image(const std::filesystem::path& path, const ImageReadOptions& options,
                          ImageMetadata* metadata) {
  ImageMetadata m = read_image_metadata(path, options);
#if VISLOC_IMAGE_FILES
  cv::Mat mat = cv::imread(path.string(), cv::IMREAD_GRAYSCALE | cv::IMREAD_IGNORE_ORIENTATION);
#else
  cv::Mat mat;
  throw_error(ErrorCode::kNotImplemented, path.string(), ": this build decodes no image files "
              "(VISLOC_IMAGE_FILES=OFF, no OpenCV imgcodecs): pass the pixels (visloc_localize_gray)");
#endif
  if (mat.empty()) throw_error(ErrorCode::kFormat, path.string(), ": cannot decode image pixels");
  if (mat.cols != m.width || mat.rows != m.height)
    throw_error(ErrorCode::kFormat, path.string(), ": header says ", m.width, "x", m.height,
                " but the decoded image is ", mat.cols, "x", mat.rows);
  GrayImage img;
  img.width = mat.cols;
  img.height = mat.rows;
  img.pixels.resize(static_cast<size_t>(img.width) * img.height);
  for (int y = 0; y < img.height; ++y)
    std::memcpy(img.pixels.data() + static_cast<size_t>(y) * img.width, mat.ptr(y), img.width);
  if (metadata) *metadata = std::move(m);
  return img;
}

void write_image(const std::filesystem::path& path, int width, int height, int channels,
                 const uint8_t* pixels, int jpeg_quality) {
  VISLOC_CHECK(channels == 1 || channels == 3);
#if VISLOC_IMAGE_FILES
  cv::Mat mat(height, width, channels == 1 ? CV_8UC1 : CV_8UC3, const_cast<uint8_t*>(pixels));
  cv::Mat bgr;
  if (channels == 3) cv::cvtColor(mat, bgr, cv::COLOR_RGB2BGR); else bgr = mat;
  std::string ext = path.extension().string();
  std::vector<uchar> buffer;
  std::vector<int> params;
  if (ext == ".jpg" || ext == ".jpeg") params = {cv::IMWRITE_JPEG_QUALITY, jpeg_quality};
  if (!cv::imencode(ext.empty() ? ".png" : ext, bgr, buffer, params))
    throw_error(ErrorCode::kIo, path.string(), ": cannot encode image as '", ext, "'");
  write_file_atomic(path, std::string_view(reinterpret_cast<const char*>(buffer.data()), buffer.size()));
#else
  throw_error(ErrorCode::kNotImplemented, path.string(), ": this build encodes no image files (VISLOC_IMAGE_FILES=OFF)");
#endif
}

bool is_image_file(const std::filesystem::path& path) {
  std::string e = path.extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return e == ".jpg" || e == ".jpeg" || e == ".png";
}

}  // namespace visloc
