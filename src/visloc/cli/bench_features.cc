// visloc bench features: SIFT time and features per image at several maximum
// image sides (median over the set, one thread).
// visloc bench sift-colmap: how well our OpenCV SIFT matches COLMAP's SIFT of
// the same images, compared with COLMAP matched to itself.
#include <algorithm>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>

#include "visloc/baselines/fundamental_inliers.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/matching/exact_matcher.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"
#include "visloc/util/statistics.h"
#include "visloc/image/image_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;
namespace {


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

}  // namespace

void add_bench_features(CLI::App& bench) {
  struct Args {
    std::vector<std::string> inputs;
    std::vector<int> sides{1024, 1600};
    bool json = false;
    SiftOptions sift;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand("features", "SIFT time and features per image (medians, one thread)");
  cmd->add_option("images", args->inputs, "Image files or directories (searched recursively)")->required();
  cmd->add_option("--max-side", args->sides, "Maximum image sides to measure")->capture_default_str();
  cmd->add_flag("--json", args->json, "Print JSON instead of a table");
  add_sift_options(cmd, args->sift, false);
  cmd->callback([args] {
    auto images = expand_images(args->inputs);
    nlohmann::json out = nlohmann::json::array();
    if (!args->json)
      std::cout << images.size() << " images\n"
                << std::setw(9) << "max side" << std::setw(14) << "median ms" << std::setw(16)
                << "median features" << std::setw(10) << "min ms" << std::setw(10) << "max ms\n";
    for (int side : args->sides) {
      SiftOptions o = args->sift;
      o.max_image_side = side;
      SiftExtractor sift(o);
      sift.extract_file(images.front());  // warm-up (page cache, OpenCV init)
      std::vector<double> ms, count;
      for (const auto& p : images) {
        GrayImage img = read_gray_image(p, o.image);
        Timer t;
        FeatureSet f = sift.extract(img);
        ms.push_back(t.elapsed_ms());
        count.push_back(static_cast<double>(f.size()));
      }
      out.push_back({{"max_side", side}, {"images", images.size()}, {"median_ms", median(ms)},
                     {"median_features", median(count)},
                     {"min_ms", *std::min_element(ms.begin(), ms.end())},
                     {"max_ms", *std::max_element(ms.begin(), ms.end())}});
      if (!args->json)
        std::cout << std::fixed << std::setprecision(1) << std::setw(9) << side << std::setw(14) << median(ms)
                  << std::setw(16) << median(count) << std::setw(10) << out.back()["min_ms"].get<double>()
                  << std::setw(10) << out.back()["max_ms"].get<double>() << "\n";
    }
    if (args->json) std::cout << nlohmann::json{{"features", out}}.dump(2) << "\n";
  });
}

void add_bench_sift_colmap(CLI::App& bench) {
  struct Args {
    std::vector<std::string> scenes;
    double ratio = 0.8;
    double threshold = 4.0;
    bool json = false;
    int max_side = 1600;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "sift-colmap",
      "Our SIFT against COLMAP's SIFT in a COLMAP database: verified matches per adjacent image pair\n"
      "(query image i+1 against reference image i; exact NN, ratio test, fundamental RANSAC)");
  cmd->add_option("--scene", args->scenes, "Scene directory with images/ and colmap/database.db")->required();
  cmd->add_option("--ratio", args->ratio, "Ratio test threshold")->capture_default_str();
  cmd->add_option("--threshold", args->threshold, "Fundamental matrix RANSAC threshold, pixels")->capture_default_str();
  cmd->add_option("--max-side", args->max_side, "Maximum image side for our SIFT")->capture_default_str();
  cmd->add_flag("--json", args->json, "Print JSON");
  cmd->callback([args] {
    struct Config {
      std::string name;
      SiftOptions sift;
    };
    std::vector<Config> configs;
    SiftOptions base;
    base.max_image_side = args->max_side;
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

    nlohmann::json scenes = nlohmann::json::array();
    for (const auto& scene : args->scenes) {
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
        const size_t cc = verified_matches(colmap_features[i + 1], ref, args->ratio, args->threshold);
        colmap_counts.push_back(double(cc));
        nlohmann::json pj = {{"query", images[i + 1].name}, {"reference", images[i].name}, {"colmap_to_colmap", cc}};
        for (size_t c = 0; c < configs.size(); ++c) {
          const size_t oc = verified_matches(ours[c][i + 1], ref, args->ratio, args->threshold);
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
      scenes.push_back(sj);
      if (!args->json) {
        std::cout << sj["scene"].get<std::string>() << ": " << pairs.size() << " pairs; COLMAP->COLMAP median "
                  << median(colmap_counts) << " verified matches (" << median(colmap_nfeat) << " features)\n";
        for (const auto& m : sj["methods"])
          std::cout << "  " << std::left << std::setw(24) << m["name"].get<std::string>() << std::right
                    << " median " << std::setw(6) << m["median_verified"].get<double>() << " verified, "
                    << std::fixed << std::setprecision(2) << m["median_ratio_to_colmap"].get<double>()
                    << " of COLMAP's, " << std::setprecision(0) << m["median_features"].get<double>()
                    << " features\n";
      }
    }
    if (args->json) std::cout << nlohmann::json{{"scenes", scenes}}.dump(2) << "\n";
  });
}

}  // namespace visloc::cli
