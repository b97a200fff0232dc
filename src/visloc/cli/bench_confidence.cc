// visloc bench confidence: fit the localizer's confidence model on reports
// (eval/confidence_fit.h), or check a model (the builtin one by default) on
// them: precision, recall and the precision-recall curve.
#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/eval/confidence_fit.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

void add_bench_confidence(CLI::App& bench) {
  struct Args {
    std::vector<std::string> reports;
    std::string out, model;
    bool fit = false;
    ConfidenceFitOptions fit_options;
    WrongPoseRule rule;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "confidence",
      "The localizer's confidence on the poses of benchmark reports (report.json of 'bench city' or 'eval', run "
      "with --min-confidence 0 to see every pose): with --fit, fit the logistic model and its threshold (the "
      "builtin model in pipeline/confidence.cc came from this, on synthetic cities only); without, check a model "
      "(the builtin one, or --model) on them. Writes model.json / check.json and a precision-recall plot to --out");
  cmd->add_option("--reports", a->reports, "report.json files (bench city or eval)")->required();
  cmd->add_option("--out", a->out, "Output directory")->required();
  cmd->add_flag("--fit", a->fit, "Fit a model on the reports (else check one)");
  cmd->add_option("--model", a->model, "Check this model.json (written by --fit) instead of the builtin model");
  cmd->add_option("--target-precision", a->fit_options.target_precision,
                  "--fit: the threshold gives at least this precision on the registered poses")
      ->capture_default_str();
  cmd->add_option("--l2", a->fit_options.l2, "--fit: L2 penalty on the standardized weights (< 0: chosen by 5-fold cross-validation)")->capture_default_str();
  cmd->add_option("--min-inliers", a->fit_options.min_inliers,
                  "Poses with at least this many inliers are the registered ones")
      ->capture_default_str();
  cmd->add_option("--wrong-position", a->rule.position_m, "A pose farther than this (m) from the truth is wrong")
      ->capture_default_str();
  cmd->add_option("--wrong-rotation", a->rule.rotation_deg, "... or turned more than this (degrees)")
      ->capture_default_str();
  cmd->callback([a] {
    a->fit_options.validate();
    if (!(a->rule.position_m > 0) || !(a->rule.rotation_deg > 0))
      throw_error(ErrorCode::kInvalidArgument, "bench confidence: --wrong-position and --wrong-rotation must be > 0");
    if (a->fit && !a->model.empty())
      throw_error(ErrorCode::kInvalidArgument, "bench confidence: --fit and --model exclude each other");
    std::vector<ConfidenceSample> samples;
    for (const auto& r : a->reports) {
      const auto s = read_confidence_samples(r, a->rule);
      std::cerr << "bench confidence: " << r << ": " << s.size() << " poses\n";
      samples.insert(samples.end(), s.begin(), s.end());
    }
    const fs::path out = a->out;
    fs::create_directories(out);
    ConfidenceModel model = ConfidenceModel::builtin();
    nlohmann::json summary;
    if (a->fit) {
      const ConfidenceFit fit = fit_confidence(samples, a->fit_options);
      model = fit.model;
      summary = fit.to_json();
      write_file_atomic(out / "model.json", model.to_json().dump(2));
      std::cout << "Fitted model (C++ for ConfidenceModel::builtin):\n" << confidence_model_code(model);
    } else if (!a->model.empty()) {
      try {
        model = ConfidenceModel::from_json(nlohmann::json::parse(read_file(a->model)));
      } catch (const nlohmann::json::exception& e) {
        throw_error(ErrorCode::kFormat, a->model, ": not JSON: ", e.what());
      } catch (const Error& e) {
        throw_error(ErrorCode::kFormat, a->model, ": ", e.what());
      }
    }
    // Precision and recall of the model on these poses (registered: ≥ min_inliers).
    const ConfidenceCheck check = check_confidence(samples, model, a->fit_options.min_inliers);
    plot_precision_recall(out / "precision_recall", a->fit ? "Confidence (fit)" : "Confidence (check)", check.curve,
                          model.threshold);
    summary["checked"] = check.to_json();
    write_file_atomic(out / (a->fit ? "fit.json" : "check.json"), summary.dump(2));
    std::cout << "Poses with >= " << a->fit_options.min_inliers << " inliers: " << check.poses_with_min_inliers
              << "; at confidence >= " << model.threshold << ": " << check.right_registered << " right registered, "
              << check.right_lost << " right lost, " << check.wrong_registered << " wrong registered.\n";
  });
}

}  // namespace visloc::cli
