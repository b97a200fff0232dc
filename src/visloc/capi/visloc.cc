// The C API over visloc::Localizer. Every entry point catches every C++
// exception and turns it into a visloc_status and a message.
#include "visloc/capi/visloc.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <limits>
#include <new>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "visloc/image/image_io.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

struct visloc_localizer {
  explicit visloc_localizer(const std::filesystem::path& map_dir, const visloc::LocalizerOptions& options)
      : localizer(map_dir, options) {}
  visloc::Localizer localizer;
};

namespace {

using visloc::ErrorCode;

// Copies `message` into a caller buffer, truncated and NUL-terminated.
void copy_message(const char* message, char* buffer, size_t size) noexcept {
  if (buffer == nullptr || size == 0) return;
  const size_t n = std::min(std::strlen(message), size - 1);
  std::memcpy(buffer, message, n);
  buffer[n] = '\0';
}

visloc_status status_of(ErrorCode code) noexcept {
  switch (code) {
    case ErrorCode::kInvalidArgument: return VISLOC_INVALID_ARGUMENT;
    case ErrorCode::kIo: return VISLOC_IO_ERROR;
    case ErrorCode::kFormat: return VISLOC_FORMAT_ERROR;
    case ErrorCode::kNotFound: return VISLOC_NOT_FOUND;
    case ErrorCode::kNotImplemented: return VISLOC_NOT_IMPLEMENTED;
    case ErrorCode::kExternalTool:  // the localizer runs no external tool
    case ErrorCode::kInternal: return VISLOC_INTERNAL_ERROR;
  }
  return VISLOC_INTERNAL_ERROR;
}

// Runs `body` (returning visloc_status); any exception becomes a status and a
// message in `error`.
template <typename Body>
visloc_status guarded(char* error, size_t error_size, Body&& body) noexcept {
  try {
    return body();
  } catch (const visloc::Error& e) {
    copy_message(e.what(), error, error_size);
    return status_of(e.code());
  } catch (const std::bad_alloc&) {
    copy_message("out of memory", error, error_size);
    return VISLOC_OUT_OF_MEMORY;
  } catch (const std::filesystem::filesystem_error& e) {
    copy_message(e.what(), error, error_size);
    return VISLOC_IO_ERROR;
  } catch (const cv::Exception& e) {  // OpenCV's allocator reports exhaustion as StsNoMem, not bad_alloc
    copy_message(e.what(), error, error_size);
    return e.code == cv::Error::StsNoMem ? VISLOC_OUT_OF_MEMORY : VISLOC_INTERNAL_ERROR;
  } catch (const std::exception& e) {
    copy_message(e.what(), error, error_size);
    return VISLOC_INTERNAL_ERROR;
  } catch (...) {
    copy_message("unknown exception", error, error_size);
    return VISLOC_INTERNAL_ERROR;
  }
}

[[noreturn]] void invalid(const char* message) { visloc::throw_error(ErrorCode::kInvalidArgument, message); }

// The value of a C enum as the int a C caller may have stored in it: C lets
// any int through, and loading an out-of-range value as the C++ enum type is
// undefined behaviour, so the bytes are read as an int.
template <typename E>
int enum_value(const E& e) {
  static_assert(sizeof(E) == sizeof(int), "C enums are ints");
  int v;
  std::memcpy(&v, &e, sizeof v);
  return v;
}

visloc::PaperSetting paper_setting(const visloc_setting& s) {
  switch (enum_value(s)) {
    case VISLOC_SETTING_1: return visloc::PaperSetting::k1;
    case VISLOC_SETTING_2: return visloc::PaperSetting::k2;
    case VISLOC_SETTING_3: return visloc::PaperSetting::k3;
    case VISLOC_SETTING_3_PLUS: return visloc::PaperSetting::k3Plus;
  }
  visloc::throw_error(ErrorCode::kInvalidArgument, "options: setting must be VISLOC_SETTING_1, _2, _3 or _3_PLUS, got ",
                      enum_value(s));
}

visloc::LocalizerOptions localizer_options(const visloc_options& o) {
  visloc::LocalizerOptions l;
  l.cache_bytes = o.cache_bytes;
  l.max_segments = o.max_segments;
  // The fallback segments (4 by default) are not a field of the C options:
  // fewer when max_segments leaves no room for them.
  if (o.max_segments > 0)
    l.fallback_segments = std::min(l.fallback_segments, std::numeric_limits<int>::max() - o.max_segments);
  l.top_images = o.top_images;
  l.setting = paper_setting(o.setting);
  l.sift.max_image_side = o.max_image_side;
  l.sift.max_features = o.max_features;
  l.use_exif_focal = o.use_exif_focal != 0;
  if (o.min_inliers < 1)
    visloc::throw_error(ErrorCode::kInvalidArgument, "options: min_inliers must be >= 1, got ", o.min_inliers);
  l.ransac.min_inliers = static_cast<size_t>(o.min_inliers);
  l.min_confidence = o.min_confidence;
  l.validate();
  return l;
}

// Intrinsics of a width × height image.
visloc::PinholeCamera camera_of(const visloc_intrinsics& k, int width, int height) {
  if (!(std::isfinite(k.fx) && std::isfinite(k.fy) && k.fx > 0 && k.fy > 0))
    visloc::throw_error(ErrorCode::kInvalidArgument, "intrinsics: fx and fy must be positive, got ", k.fx, " and ",
                        k.fy);
  visloc::PinholeCamera cam;
  cam.width = width;
  cam.height = height;
  cam.focal = k.fx;
  cam.aspect = k.fy / k.fx;
  cam.has_focal = true;
  cam.cx = k.cx;
  cam.cy = k.cy;
  cam.k1 = k.k1;
  cam.validate();
  return cam;
}

void clear(visloc_result* r) noexcept {
  std::memset(r, 0, sizeof(*r));
  r->segment = -1;
}

void fill(const visloc::LocalizationResult& l, visloc_result* r) {
  clear(r);
  r->registered = l.registered ? 1 : 0;
  r->segment = l.segment;
  r->inliers = static_cast<int>(std::min<size_t>(l.inliers, std::numeric_limits<int>::max()));
  r->features = static_cast<int>(std::min<size_t>(l.features, std::numeric_limits<int>::max()));
  if (l.segment >= 0) {
    const auto q = l.cam_from_segment.q_wxyz();
    const Eigen::Vector3d c = l.cam_from_segment.center();
    for (int i = 0; i < 4; ++i) r->rotation_wxyz[i] = q[i];
    for (int i = 0; i < 3; ++i) {
      r->translation[i] = l.cam_from_segment.translation[i];
      r->center[i] = c[i];
    }
  } else {
    r->rotation_wxyz[0] = 1;
  }
  r->focal_px = l.focal_px;
  r->focal_estimated = l.focal_estimated ? 1 : 0;
  r->principal_point_offset[0] = l.principal_point_offset.x();
  r->principal_point_offset[1] = l.principal_point_offset.y();
  if (l.center_enu) {
    r->has_enu = 1;
    for (int i = 0; i < 3; ++i) r->enu[i] = (*l.center_enu)[i];
  }
  if (l.position) {
    r->has_geo = 1;
    r->latitude_deg = l.position->lat;
    r->longitude_deg = l.position->lon;
    r->altitude_m = l.position->alt;
  }
  if (l.heading_deg) {
    r->has_heading = 1;
    r->heading_deg = *l.heading_deg;
  }
  r->confidence = l.confidence;
  if (l.uncertainty.valid) {
    const visloc::PoseUncertainty& u = l.uncertainty;
    r->has_sigma = 1;
    r->position_sigma = u.position_sigma;
    r->rotation_sigma_deg = u.rotation_sigma_deg;
    r->position_sigma_m = u.position_sigma_m.value_or(0);
    r->horizontal_sigma_m = u.horizontal_sigma_m.value_or(0);
    r->vertical_sigma_m = u.vertical_sigma_m.value_or(0);
    r->has_heading_sigma = u.heading_sigma_deg ? 1 : 0;
    r->heading_sigma_deg = u.heading_sigma_deg.value_or(0);
  }
  r->times.features_ms = l.times.features;
  r->times.retrieval_ms = l.times.retrieval;
  r->times.matching_ms = l.times.matching;
  r->times.ransac_ms = l.times.ransac;
  r->times.total_ms = l.times.total;
  if (!l.error.empty()) copy_message(l.error.c_str(), r->error, sizeof(r->error));
}

}  // namespace

extern "C" {

const char* visloc_version(void) { return VISLOC_VERSION_STRING; }

const char* visloc_status_string(visloc_status status) {
  switch (enum_value(status)) {
    case VISLOC_OK: return "ok";
    case VISLOC_INVALID_ARGUMENT: return "invalid argument";
    case VISLOC_NOT_FOUND: return "not found";
    case VISLOC_IO_ERROR: return "input/output error";
    case VISLOC_FORMAT_ERROR: return "bad file format";
    case VISLOC_NOT_IMPLEMENTED: return "not implemented";
    case VISLOC_OUT_OF_MEMORY: return "out of memory";
    case VISLOC_INTERNAL_ERROR: return "internal error";
  }
  return "unknown status";
}

void visloc_options_init(visloc_options* options) {
  if (options == nullptr) return;
  const visloc::LocalizerOptions d;
  std::memset(options, 0, sizeof(*options));
  options->cache_bytes = d.cache_bytes;
  options->max_segments = d.max_segments;
  options->top_images = d.top_images;
  options->setting = VISLOC_SETTING_3_PLUS;
  options->max_image_side = d.sift.max_image_side;
  options->max_features = d.sift.max_features;
  options->threads = 0;
  options->use_exif_focal = d.use_exif_focal ? 1 : 0;
  options->min_inliers = static_cast<int>(d.ransac.min_inliers);
  options->min_confidence = d.min_confidence;
}

visloc_status visloc_localizer_open(const char* map_dir, const visloc_options* options, visloc_localizer** out,
                                    char* error, size_t error_size) {
  copy_message("", error, error_size);
  if (out != nullptr) *out = nullptr;
  return guarded(error, error_size, [&]() -> visloc_status {
    if (out == nullptr) invalid("visloc_localizer_open: out is NULL");
    if (map_dir == nullptr || map_dir[0] == '\0') invalid("visloc_localizer_open: map_dir is NULL or empty");
    visloc_options o;
    visloc_options_init(&o);
    if (options != nullptr) o = *options;
    if (o.threads < 0) visloc::throw_error(ErrorCode::kInvalidArgument, "options: threads must be >= 0 (0: leave OpenCV's thread count), got ", o.threads);
    const visloc::LocalizerOptions l = localizer_options(o);
    *out = new visloc_localizer(map_dir, l);
    if (o.threads > 0) visloc::set_opencv_threads(o.threads);  // the app asked for it: process-wide
    return VISLOC_OK;
  });
}

void visloc_localizer_close(visloc_localizer* localizer) {
  try {
    delete localizer;
  } catch (...) {  // destructors do not throw; nothing may cross the boundary regardless
  }
}

visloc_status visloc_localize_file(const visloc_localizer* localizer, const char* image_path,
                                   const visloc_intrinsics* intrinsics, visloc_result* result) {
  if (result == nullptr) return VISLOC_INVALID_ARGUMENT;
  clear(result);
  return guarded(result->error, sizeof(result->error), [&]() -> visloc_status {
    if (localizer == nullptr) invalid("visloc_localize_file: localizer is NULL");
    if (image_path == nullptr || image_path[0] == '\0') invalid("visloc_localize_file: image_path is NULL or empty");
    // As Localizer::localize_file, but a bad file keeps its error code.
    const visloc::Localizer& loc = localizer->localizer;
    visloc::Timer decode;
    visloc::ImageMetadata meta;
    const visloc::GrayImage image = visloc::read_gray_image(image_path, loc.options().sift.image, &meta);
    const double decode_ms = decode.elapsed_ms();
    std::optional<visloc::PinholeCamera> camera;
    if (intrinsics != nullptr) {
      camera = camera_of(*intrinsics, image.width, image.height);
    } else if (loc.options().use_exif_focal) {
      if (const std::optional<double> focal = meta.focal_px())
        camera = visloc::PinholeCamera::centered(image.width, image.height, focal);
    }
    visloc::LocalizationResult r = loc.localize_image(image, camera);
    r.times.features += decode_ms;
    r.times.total += decode_ms;
    fill(r, result);
    return VISLOC_OK;
  });
}

visloc_status visloc_localize_gray(const visloc_localizer* localizer, const uint8_t* pixels, int width, int height,
                                   int stride_bytes, const visloc_intrinsics* intrinsics, visloc_result* result) {
  if (result == nullptr) return VISLOC_INVALID_ARGUMENT;
  clear(result);
  return guarded(result->error, sizeof(result->error), [&]() -> visloc_status {
    if (localizer == nullptr) invalid("visloc_localize_gray: localizer is NULL");
    if (pixels == nullptr) invalid("visloc_localize_gray: pixels is NULL");
    if (width <= 0 || height <= 0)
      visloc::throw_error(ErrorCode::kInvalidArgument, "visloc_localize_gray: width and height must be positive, got ",
                          width, "x", height);
    if (stride_bytes < width)
      visloc::throw_error(ErrorCode::kInvalidArgument, "visloc_localize_gray: stride_bytes ", stride_bytes,
                          " is less than the width ", width);
    const visloc::Localizer& loc = localizer->localizer;
    const int64_t max_pixels = loc.options().sift.image.max_pixels;
    if (static_cast<int64_t>(width) * height > max_pixels)
      visloc::throw_error(ErrorCode::kInvalidArgument, "visloc_localize_gray: ", width, "x", height,
                          " is over the limit of ", max_pixels, " pixels");
    visloc::Timer copy;
    visloc::GrayImage image;
    image.width = width;
    image.height = height;
    image.pixels.resize(static_cast<size_t>(width) * static_cast<size_t>(height));
    for (int y = 0; y < height; ++y)
      std::memcpy(image.pixels.data() + static_cast<size_t>(y) * width,
                  pixels + static_cast<size_t>(y) * static_cast<size_t>(stride_bytes), static_cast<size_t>(width));
    const double copy_ms = copy.elapsed_ms();
    std::optional<visloc::PinholeCamera> camera;
    if (intrinsics != nullptr) camera = camera_of(*intrinsics, width, height);
    visloc::LocalizationResult r = loc.localize_image(image, camera);
    r.times.features += copy_ms;
    r.times.total += copy_ms;
    fill(r, result);
    return VISLOC_OK;
  });
}

}  // extern "C"
