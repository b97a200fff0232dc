#include "visloc/synth/photo_crops.h"

#include <algorithm>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "visloc/synth/random.h"
#include "visloc/util/error.h"
#include "visloc/image/image_io.h"

namespace visloc::synth {

void PhotoCropOptions::validate() const {
  if (count < 1 || count > 4096)
    throw_error(ErrorCode::kInvalidArgument, "photo crop option count: must be in [1, 4096], got ", count);
  if (size < 16 || size > 2048)
    throw_error(ErrorCode::kInvalidArgument, "photo crop option size: must be in [16, 2048], got ", size);
}

Rgb PhotoCropSet::sample(size_t index, double s, double t) const {
  const PhotoCrop& c = crops_[index % crops_.size()];
  const double x = std::clamp(s, 0.0, 1.0) * (c.size - 1), y = std::clamp(t, 0.0, 1.0) * (c.size - 1);
  const int x0 = std::min(static_cast<int>(x), c.size - 2), y0 = std::min(static_cast<int>(y), c.size - 2);
  const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const auto px = [&](int xx, int yy) {
    const uint8_t* p = c.rgb.data() + (static_cast<size_t>(yy) * c.size + xx) * 3;
    return Rgb{p[0] / 255.0f, p[1] / 255.0f, p[2] / 255.0f};
  };
  return mix(mix(px(x0, y0), px(x0 + 1, y0), fx), mix(px(x0, y0 + 1), px(x0 + 1, y0 + 1), fx), fy);
}

PhotoCropSet load_photo_crops(const std::filesystem::path& folder, const PhotoCropOptions& options) {
  namespace fs = std::filesystem;
  options.validate();
  std::error_code ec;
  if (!fs::is_directory(folder, ec))
    throw_error(ErrorCode::kNotFound, folder.string(), ": photo folder does not exist or is not a directory");
  std::vector<fs::path> files;
  for (auto it = fs::recursive_directory_iterator(folder, ec); !ec && it != fs::recursive_directory_iterator();
       it.increment(ec)) {
    if (!it->is_regular_file()) continue;
    if (is_image_file(it->path())) files.push_back(it->path());
  }
  if (ec) throw_error(ErrorCode::kIo, folder.string(), ": cannot list photo folder: ", ec.message());
  std::sort(files.begin(), files.end());
  if (files.empty()) throw_error(ErrorCode::kNotFound, folder.string(), ": no JPEG or PNG image in photo folder");

  SplitMix64 rng(hash_keys(options.seed, 0xc809));
  // Crops grouped per file so that each photograph is decoded once.
  std::vector<std::vector<int>> crops_of_file(files.size());
  for (int i = 0; i < options.count; ++i)
    crops_of_file[static_cast<size_t>(rng.uniform_int(0, static_cast<int>(files.size()) - 1))].push_back(i);
  std::vector<PhotoCrop> crops(static_cast<size_t>(options.count));
  for (size_t f = 0; f < files.size(); ++f) {
    if (crops_of_file[f].empty()) continue;
    cv::Mat bgr = cv::imread(files[f].string(), cv::IMREAD_COLOR);
    if (bgr.empty()) throw_error(ErrorCode::kFormat, files[f].string(), ": cannot decode photo");
    for (const int i : crops_of_file[f]) {
      SplitMix64 crng(hash_keys(options.seed, 0xc80a, static_cast<uint64_t>(i)));
      const int shorter = std::min(bgr.cols, bgr.rows);
      const int side = std::max(8, static_cast<int>(shorter * crng.uniform(0.25, 1.0)));
      const int x = crng.uniform_int(0, bgr.cols - side), y = crng.uniform_int(0, bgr.rows - side);
      cv::Mat resized, rgb;
      cv::resize(bgr(cv::Rect(x, y, side, side)), resized, cv::Size(options.size, options.size), 0, 0,
                 cv::INTER_AREA);
      cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
      PhotoCrop& c = crops[static_cast<size_t>(i)];
      c.size = options.size;
      c.rgb.assign(rgb.data, rgb.data + static_cast<size_t>(options.size) * options.size * 3);
    }
  }
  return PhotoCropSet(std::move(crops));
}

}  // namespace visloc::synth
