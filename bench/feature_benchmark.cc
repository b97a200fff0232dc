#include "bench/feature_benchmark.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "visloc/baselines/fundamental_inliers.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/image/image_io.h"
#include "visloc/matching/exact_matcher.h"
#include "visloc/util/error.h"
#include "visloc/util/statistics.h"
#include "visloc/util/timer.h"

namespace visloc {
namespace fs = std::filesystem;

void FeatureBenchmarkOptions::validate() const {
  if (inputs.empty()) throw_error(ErrorCode::kInvalidArgument, "bench features: no image file or directory given");
  if (max_sides.empty()) throw_error(ErrorCode::kInvalidArgument, "bench features: no maximum image side given");
  for (int side : max_sides) {
    SiftOptions o = sift;
    o.max_image_side = side;
    o.validate();
  }
}

void SiftColmapBenchmarkOptions::validate() const {
  if (scenes.empty()) throw_error(ErrorCode::kInvalidArgument, "bench sift-colmap: no scene given");
  if (!(ratio > 0 && ratio <= 1)) throw_error(ErrorCode::kInvalidArgument, "ratio must be in (0, 1], got ", ratio);
  if (!std::isfinite(threshold_px))
    throw_error(ErrorCode::kInvalidArgument, "bench sift-colmap: threshold_px must be a finite number, got ",
                threshold_px);
  SiftOptions o;
  o.max_image_side = max_image_side;
  o.validate();
}

namespace {

// One text stream (its format flags carry over from part to part, as on a
// console) whose new parts are handed to `progress` as they are finished.
class TextParts {
 public:
  explicit TextParts(const std::function<void(const std::string&)>& progress) : progress_(progress) {}
  std::ostream& stream() { return text_; }
  void part_done() {
    std::string all = text_.str();
    if (progress_ && all.size() > sent_) progress_(all.substr(sent_));
    sent_ = all.size();
  }
  std::string str() const { return text_.str(); }

 private:
  const std::function<void(const std::string&)>& progress_;
  std::ostringstream text_;
  size_t sent_ = 0;
};

std::vector<fs::path> expand_images(const std::vector<std::string>& inputs) {
  std::vector<fs::path> out;
  for (const auto& in : inputs) {
    if (fs::is_directory(in)) {
      std::vector<fs::path> dir;
      for (const auto& e : fs::recursive_directory_iterator(in))
        if (e.is_regular_file() && is_image_file(e.path())) dir.push_back(e.path());
      std::sort(dir.begin(), dir.end());
      out.insert(out.end(), dir.begin(), dir.end());
    } else if (fs::exists(in)) {
      out.emplace_back(in);
    } else {
      throw_error(ErrorCode::kIo, in, ": no such file or directory");
    }
  }
  if (out.empty()) throw_error(ErrorCode::kInvalidArgument, "no images found");
  return out;
}

// SIFT at one maximum side over every image: times and feature counts.
nlohmann::json measure_side(const std::vector<fs::path>& images, const SiftOptions& sift, int side) {
  SiftOptions o = sift;
  o.max_image_side = side;
  SiftExtractor extractor(o);
  extractor.extract_file(images.front());  // warm-up (page cache, OpenCV init)
  std::vector<double> ms, count;
  for (const auto& p : images) {
    GrayImage img = read_gray_image(p, o.image);
    Timer t;
    FeatureSet f = extractor.extract(img);
    ms.push_back(t.elapsed_ms());
    count.push_back(static_cast<double>(f.size()));
  }
  return {{"max_side", side},
          {"images", images.size()},
          {"median_ms", median(ms)},
          {"median_features", median(count)},
          {"min_ms", *std::min_element(ms.begin(), ms.end())},
          {"max_ms", *std::max_element(ms.begin(), ms.end())}};
}

// Verified matches of query features against reference features: exact
// nearest neighbour, ratio test, then a fundamental-matrix RANSAC.
size_t verified_matches(const FeatureSet& query, const FeatureSet& reference, double ratio, double threshold_px) {
  ExactMatcher matcher(reference.descriptors);
  auto matches = matcher.match(query.descriptors, {.ratio = ratio});
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  for (const auto& m : matches) pairs.emplace_back(m.query, m.database);
  auto inl = fundamental_inliers(query.keypoints, reference.keypoints, pairs, threshold_px);
  return static_cast<size_t>(std::count(inl.begin(), inl.end(), true));
}

struct SiftConfig {
  std::string name;
  SiftOptions sift;
};

std::vector<SiftConfig> sift_colmap_configs(int max_image_side) {
  std::vector<SiftConfig> configs;
  SiftOptions base;
  base.max_image_side = max_image_side;
  configs.push_back({"opencv-rootsift-c0.02", base});
  SiftOptions many = base;
  many.max_features = 16384;  // a feature count like the COLMAP databases' (~10-12K)
  configs.push_back({"opencv-rootsift-c0.02-16k", many});
  SiftOptions c04 = base;
  c04.contrast_threshold = 0.04;
  configs.push_back({"opencv-rootsift-c0.04", c04});
  SiftOptions plain = base;
  plain.root_sift = false;
  configs.push_back({"opencv-l2sift-c0.02", plain});
  return configs;
}

// Verified matches per adjacent pair (query i+1, reference i: COLMAP's
// features) of COLMAP's and of each configuration's query features.
nlohmann::json sift_colmap_scene(const SiftColmapBenchmarkOptions& o, const std::vector<SiftConfig>& configs,
                                 const std::string& scene) {
  ColmapDatabase db(fs::path(scene) / "colmap" / "database.db");
  auto images = db.images();
  std::vector<FeatureSet> colmap_features;
  for (const auto& im : images) colmap_features.push_back(db.features(im.image_id));
  std::vector<std::vector<FeatureSet>> ours(configs.size());
  for (size_t c = 0; c < configs.size(); ++c) {
    SiftExtractor sift(configs[c].sift);
    for (const auto& im : images) ours[c].push_back(sift.extract_file(fs::path(scene) / "images" / im.name));
  }
  std::vector<double> colmap_counts;
  std::vector<std::vector<double>> counts(configs.size()), ratios(configs.size()), nfeat(configs.size());
  nlohmann::json pairs = nlohmann::json::array();
  for (size_t i = 0; i + 1 < images.size(); ++i) {
    const FeatureSet& ref = colmap_features[i];
    const size_t cc = verified_matches(colmap_features[i + 1], ref, o.ratio, o.threshold_px);
    colmap_counts.push_back(double(cc));
    nlohmann::json pj = {{"query", images[i + 1].name}, {"reference", images[i].name}, {"colmap_to_colmap", cc}};
    for (size_t c = 0; c < configs.size(); ++c) {
      const size_t oc = verified_matches(ours[c][i + 1], ref, o.ratio, o.threshold_px);
      counts[c].push_back(double(oc));
      nfeat[c].push_back(double(ours[c][i + 1].size()));
      ratios[c].push_back(cc > 0 ? double(oc) / cc : 0.0);
      pj[configs[c].name] = oc;
    }
    pairs.push_back(pj);
  }
  std::vector<double> colmap_nfeat;
  for (const auto& f : colmap_features) colmap_nfeat.push_back(double(f.size()));
  nlohmann::json sj = {{"scene", fs::path(scene).filename().string()},
                       {"pairs", pairs},
                       {"colmap_median_features", median(colmap_nfeat)},
                       {"colmap_median_verified", median(colmap_counts)}};
  for (size_t c = 0; c < configs.size(); ++c)
    sj["methods"].push_back({{"name", configs[c].name},
                             {"median_features", median(nfeat[c])},
                             {"median_verified", median(counts[c])},
                             {"median_ratio_to_colmap", median(ratios[c])}});
  return sj;
}

void print_sift_colmap_scene(std::ostream& os, const nlohmann::json& sj) {
  os << sj["scene"].get<std::string>() << ": " << sj["pairs"].size() << " pairs; COLMAP->COLMAP median "
     << sj["colmap_median_verified"].get<double>() << " verified matches ("
     << sj["colmap_median_features"].get<double>() << " features)\n";
  for (const auto& m : sj["methods"])
    os << "  " << std::left << std::setw(24) << m["name"].get<std::string>() << std::right << " median " << std::setw(6)
       << m["median_verified"].get<double>() << " verified, " << std::fixed << std::setprecision(2)
       << m["median_ratio_to_colmap"].get<double>() << " of COLMAP's, " << std::setprecision(0)
       << m["median_features"].get<double>() << " features\n";
}

}  // namespace

FeatureBenchmarkResult run_feature_benchmark(const FeatureBenchmarkOptions& options,
                                             const std::function<void(const std::string&)>& progress) {
  options.validate();
  const std::vector<fs::path> images = expand_images(options.inputs);
  TextParts text(progress);
  std::ostream& os = text.stream();
  os << images.size() << " images\n"
     << std::setw(9) << "max side" << std::setw(14) << "median ms" << std::setw(16) << "median features"
     << std::setw(10) << "min ms" << std::setw(10) << "max ms\n";
  text.part_done();
  nlohmann::json sides = nlohmann::json::array();
  for (int side : options.max_sides) {
    sides.push_back(measure_side(images, options.sift, side));
    const nlohmann::json& row = sides.back();
    os << std::fixed << std::setprecision(1) << std::setw(9) << side << std::setw(14) << row["median_ms"].get<double>()
       << std::setw(16) << row["median_features"].get<double>() << std::setw(10) << row["min_ms"].get<double>()
       << std::setw(10) << row["max_ms"].get<double>() << "\n";
    text.part_done();
  }
  return {nlohmann::json{{"features", sides}}, text.str()};
}

SiftColmapBenchmarkResult run_sift_colmap_benchmark(const SiftColmapBenchmarkOptions& options,
                                                    const std::function<void(const std::string&)>& progress) {
  options.validate();
  const std::vector<SiftConfig> configs = sift_colmap_configs(options.max_image_side);
  TextParts text(progress);
  nlohmann::json scenes = nlohmann::json::array();
  for (const auto& scene : options.scenes) {
    scenes.push_back(sift_colmap_scene(options, configs, scene));
    print_sift_colmap_scene(text.stream(), scenes.back());
    text.part_done();
  }
  return {nlohmann::json{{"scenes", scenes}}, text.str()};
}

}  // namespace visloc
