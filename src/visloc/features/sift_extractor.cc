#include "visloc/features/sift_extractor.h"

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>

#include "visloc/util/error.h"

namespace visloc {

void SiftOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "SIFT option ", field, " = ", value, ": ", rule);
  };
  if (max_image_side < 0) bad("max_image_side", max_image_side, "must be >= 0 (0: no limit)");
  if (max_image_side > 0 && max_image_side < 32) bad("max_image_side", max_image_side, "must be >= 32");
  if (max_features <= 0) bad("max_features", max_features, "must be positive");
  if (!(contrast_threshold > 0 && contrast_threshold < 1))
    bad("contrast_threshold", contrast_threshold, "must be in (0, 1)");
  if (!(edge_threshold > 1)) bad("edge_threshold", edge_threshold, "must be > 1");
  if (!(sigma > 0)) bad("sigma", sigma, "must be positive");
  if (octave_layers < 1 || octave_layers > 10) bad("octave_layers", octave_layers, "must be in [1, 10]");
  image.validate();
}

std::string SiftOptions::to_json() const {
  return nlohmann::json{{"type", "opencv-sift"},
                        {"opencv", CV_VERSION},
                        {"max_image_side", max_image_side},
                        {"max_features", max_features},
                        {"contrast_threshold", contrast_threshold},
                        {"edge_threshold", edge_threshold},
                        {"sigma", sigma},
                        {"octave_layers", octave_layers},
                        {"root_sift", root_sift}}
      .dump();
}

void sift_to_uint8(const float* in, bool root_sift, uint8_t* out) {
  float v[kDescriptorDim];
  if (root_sift) {
    double l1 = 0;
    for (int i = 0; i < kDescriptorDim; ++i) l1 += std::abs(in[i]);
    const double inv = l1 > 0 ? 1.0 / l1 : 0.0;
    for (int i = 0; i < kDescriptorDim; ++i) v[i] = static_cast<float>(std::sqrt(std::abs(in[i]) * inv));
  } else {
    double l2 = 0;
    for (int i = 0; i < kDescriptorDim; ++i) l2 += double(in[i]) * in[i];
    const double inv = l2 > 0 ? 1.0 / std::sqrt(l2) : 0.0;
    for (int i = 0; i < kDescriptorDim; ++i) v[i] = static_cast<float>(in[i] * inv);
  }
  for (int i = 0; i < kDescriptorDim; ++i)
    out[i] = static_cast<uint8_t>(std::min(255.0f, std::round(512.0f * v[i])));
}

namespace {
// Position bias of OpenCV's SIFT keypoints, in pixels of the image given to
// it (see extract()). It comes from the default, imprecise upscaling of the
// first octave; OpenCV >= 4.8 can avoid it (enable_precise_upscale), which we
// do not request, so the bias holds for every OpenCV version we build with.
constexpr double kOpenCvSiftUpsampleShift = 0.25;
}  // namespace

struct SiftExtractor::Impl {
  cv::Ptr<cv::SIFT> sift;
};

SiftExtractor::SiftExtractor(const SiftOptions& options) : options_(options), impl_(std::make_unique<Impl>()) {
  options_.validate();
  impl_->sift = cv::SIFT::create(options_.max_features, options_.octave_layers,
                                 options_.contrast_threshold, options_.edge_threshold, options_.sigma);
}

SiftExtractor::~SiftExtractor() = default;

FeatureSet SiftExtractor::extract(const GrayImage& image) const {
  VISLOC_CHECK(image.width > 0 && image.height > 0 && image.pixels.size() == size_t(image.width) * image.height);
  cv::Mat full(image.height, image.width, CV_8UC1, const_cast<uint8_t*>(image.pixels.data()));
  cv::Mat work = full;
  const int side = std::max(image.width, image.height);
  if (options_.max_image_side > 0 && side > options_.max_image_side) {
    const double s = double(options_.max_image_side) / side;
    cv::resize(full, work,
               cv::Size(std::max(1, int(std::lround(image.width * s))), std::max(1, int(std::lround(image.height * s)))),
               0, 0, cv::INTER_AREA);
  }
  const double sx = double(image.width) / work.cols, sy = double(image.height) / work.rows;

  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  impl_->sift->detectAndCompute(work, cv::noArray(), kps, desc);

  // Deterministic order, independent of OpenCV's threading.
  std::vector<int> order(kps.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    const auto &ka = kps[a], &kb = kps[b];
    if (ka.response != kb.response) return ka.response > kb.response;
    if (ka.pt.y != kb.pt.y) return ka.pt.y < kb.pt.y;
    if (ka.pt.x != kb.pt.x) return ka.pt.x < kb.pt.x;
    if (ka.size != kb.size) return ka.size < kb.size;
    return ka.angle < kb.angle;
  });
  if (order.size() > size_t(options_.max_features)) order.resize(options_.max_features);

  FeatureSet f;
  f.image_width = image.width;
  f.image_height = image.height;
  f.extractor = options_.to_json();
  f.keypoints.resize(order.size());
  f.descriptors.resize(order.size());
  // OpenCV puts the centre of the top-left pixel at (0, 0); ours is (0.5, 0.5).
  // OpenCV's SIFT also starts from an image doubled with
  // resize(INTER_LINEAR), whose pixel j samples the input at j/2 - 0.25, but
  // it reports a keypoint found at j as j/2: every keypoint lies 0.25 input
  // pixels right of and below its true position, whatever its octave (the
  // octaves below are exact 2× decimations). Measured against COLMAP's SIFT
  // on the Strecha photos: +0.25 px in x and y before this correction.
  constexpr double kOpenCvToOurs = 0.5 - kOpenCvSiftUpsampleShift;
  for (size_t i = 0; i < order.size(); ++i) {
    const cv::KeyPoint& k = kps[order[i]];
    Keypoint& out = f.keypoints[i];
    out.x = static_cast<float>((k.pt.x + kOpenCvToOurs) * sx);
    out.y = static_cast<float>((k.pt.y + kOpenCvToOurs) * sy);
    out.scale = static_cast<float>(0.5 * k.size * std::sqrt(sx * sy));
    out.orientation = static_cast<float>(k.angle * std::numbers::pi / 180.0);
    sift_to_uint8(desc.ptr<float>(order[i]), options_.root_sift, f.descriptors.row(i));
  }
  return f;
}

FeatureSet SiftExtractor::extract_file(const std::filesystem::path& path, ImageMetadata* metadata) const {
  GrayImage image = read_gray_image(path, options_.image, metadata);
  FeatureSet f = extract(image);
  f.image = path.filename().string();
  return f;
}

void set_opencv_threads(int threads) {
  if (threads < 1) throw_error(ErrorCode::kInvalidArgument, "OpenCV threads must be >= 1, got ", threads);
  cv::setNumThreads(threads);
}

}  // namespace visloc
