// `fslam eval`: ATE and RPE of an estimated trajectory against ground truth (docs/evaluation.md).
#include <cmath>
#include <cstdio>
#include <algorithm>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/ate.hpp"
#include "fslam/core/eval/depth_agreement.hpp"
#include "fslam/core/eval/rpe.hpp"
#include "fslam/core/eval/trajectory_plot.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::cli {
namespace {

struct EvalOptions {
  std::string gt_path;
  std::string est_path;
  std::string json_path;
  std::string plot_path;
  bool sim3 = false;
  double max_difference = 0.02;  // seconds
  double rpe_delta = 1.0;        // frames or seconds
  std::string rpe_unit = "frames";
  DatasetArgs dataset;  // set: score each step's depth agreement (core/eval/depth_agreement.hpp)
  int depth_delta = 1;  // frames between the two depths of a step
  bool residual_grid = false;  // with dataset: the signed residuals' medians over the image
};

nlohmann::json stats_json(const core::ErrorStats& s) {
  return {{"count", s.count}, {"rmse", s.rmse},  {"mean", s.mean}, {"median", s.median},
          {"std", s.std},     {"min", s.min},    {"max", s.max}};
}

std::string row(const char* name, std::size_t count, double rmse, double mean, double median,
                double std, double min, double max) {
  char buffer[160];
  std::snprintf(buffer, sizeof(buffer), "%-16s %7zu %10.6f %10.6f %10.6f %10.6f %10.6f %10.6f\n",
                name, count, rmse, mean, median, std, min, max);
  return buffer;
}

std::string row(const char* name, const core::ErrorStats& s) {
  return row(name, s.count, s.rmse, s.mean, s.median, s.std, s.min, s.max);
}

// Per-step median |dz| of one side, in metres.
std::vector<double> step_medians(const std::vector<core::DepthAgreementStep>& steps,
                                 bool ground_truth) {
  std::vector<double> medians;
  for (const auto& s : steps)
    medians.push_back((ground_truth ? s.ground_truth : s.estimate).median_abs_m);
  return medians;
}

// The `count` steps where one side (the ground truth when `ground_truth`, else the estimate)
// disagrees with the depth most beyond the other, printed as rows and returned as JSON.
nlohmann::json worst_steps(std::vector<core::DepthAgreementStep> steps, bool ground_truth,
                           std::size_t count) {
  const auto margin = [&](const core::DepthAgreementStep& s) {
    const double d = s.ground_truth.median_abs_m - s.estimate.median_abs_m;
    return ground_truth ? d : -d;
  };
  std::sort(steps.begin(), steps.end(),
            [&](const auto& a, const auto& b) { return margin(a) > margin(b); });
  steps.resize(std::min(count, steps.size()));
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& s : steps) {
    std::printf("  %6lld -> %-6lld %8.2f %8.2f %9.3f %9.3f\n", static_cast<long long>(s.frame_a),
                static_cast<long long>(s.frame_b), 1e3 * s.ground_truth.median_abs_m,
                1e3 * s.estimate.median_abs_m, s.ground_truth.inlier_fraction,
                s.estimate.inlier_fraction);
    rows.push_back({{"frame_a", s.frame_a},
                    {"frame_b", s.frame_b},
                    {"ground_truth_median_m", s.ground_truth.median_abs_m},
                    {"estimate_median_m", s.estimate.median_abs_m},
                    {"ground_truth_inliers", s.ground_truth.inlier_fraction},
                    {"estimate_inliers", s.estimate.inlier_fraction}});
  }
  return rows;
}

// Prints, per depth bin, the median signed residual of every image cell under both sides' poses
// (mm; "." below kMinSamples) and returns them as JSON (metres, null below kMinSamples).
nlohmann::json residual_grid_report(const core::DepthResidualGrid& gt, const core::DepthResidualGrid& est) {
  constexpr std::size_t kMinSamples = 200;
  nlohmann::json bins = nlohmann::json::array();
  std::printf("\nresidual grid: median of z_b - z_moved over the steps, by where the sample lands in b "
              "(%d x %d cells) and its depth [mm]; ground truth | estimate\n", est.cols, est.rows);
  for (int bin = 0; bin < est.bins(); ++bin) {
    const double lo = bin == 0 ? 0.0 : est.depth_edges[static_cast<std::size_t>(bin - 1)];
    const bool last = bin == est.bins() - 1;
    const double hi = last ? std::numeric_limits<double>::infinity() : est.depth_edges[static_cast<std::size_t>(bin)];
    nlohmann::json side[2] = {nlohmann::json::array(), nlohmann::json::array()};
    std::size_t samples = 0;
    std::string lines;
    for (int r = 0; r < est.rows; ++r) {
      nlohmann::json row[2] = {nlohmann::json::array(), nlohmann::json::array()};
      for (int k = 0; k < 2; ++k) {
        const core::DepthResidualGrid& g = k == 0 ? gt : est;
        for (int c = 0; c < g.cols; ++c) {
          const double m = g.median(bin, r, c, kMinSamples);
          if (k == 1) samples += g.count(bin, r, c);
          row[k].push_back(std::isfinite(m) ? nlohmann::json(m) : nlohmann::json(nullptr));
          char cell[16];
          if (std::isfinite(m)) std::snprintf(cell, sizeof cell, "%+6.1f", 1e3 * m);
          else std::snprintf(cell, sizeof cell, "%6s", ".");
          lines += cell;
        }
        lines += k == 0 ? "  |" : "\n";
        side[k].push_back(row[k]);
      }
    }
    if (samples == 0) continue;
    if (last) std::printf("depth from %.1f m (%zu samples under the estimate)\n%s", lo, samples, lines.c_str());
    else std::printf("depth %.1f-%.1f m (%zu samples under the estimate)\n%s", lo, hi, samples, lines.c_str());
    bins.push_back({{"min_depth_m", lo},
                    {"max_depth_m", last ? nlohmann::json(nullptr) : nlohmann::json(hi)},
                    {"samples", samples},
                    {"ground_truth_median_m", side[0]},
                    {"estimate_median_m", side[1]}});
  }
  return {{"cols", est.cols}, {"rows", est.rows}, {"min_samples", kMinSamples}, {"bins", bins}};
}

// Scores every step of both trajectories on the dataset's depth and prints the summary and the
// steps where each side disagrees most with the other; false with `why` on failure.
bool depth_agreement_report(const EvalOptions& o, const core::Dataset& dataset,
                            const core::Trajectory& gt, const core::Trajectory& est,
                            nlohmann::json* out, std::string* why) {
  core::AssociationConfig association;
  association.max_difference = o.max_difference;
  const core::DepthAgreementConfig config;
  std::vector<core::DepthAgreementStep> steps;
  std::optional<Progress> progress;
  core::DepthResidualGrid gt_grid, est_grid;
  if (!core::depth_agreement_steps(dataset, gt, est, association,
                                   static_cast<std::size_t>(o.depth_delta), config, &steps, why,
                                   [&](std::size_t done, std::size_t total) {
                                     if (!progress) progress.emplace("depth agreement", total);
                                     progress->update(done);
                                   },
                                   o.residual_grid ? &gt_grid : nullptr,
                                   o.residual_grid ? &est_grid : nullptr))
    return false;
  if (progress) progress->finish();

  const std::vector<double> gt_medians = step_medians(steps, true);
  const std::vector<double> est_medians = step_medians(steps, false);
  const auto gt_stats = core::summarize_errors(gt_medians);
  const auto est_stats = core::summarize_errors(est_medians);
  const std::size_t estimate_better = static_cast<std::size_t>(
      std::count_if(steps.begin(), steps.end(), [](const auto& s) {
        return s.estimate.median_abs_m < s.ground_truth.median_abs_m;
      }));
  std::printf("\ndepth agreement: %zu steps of %d frame(s) on %s; per step the median |dz| "
              "between frame a's depth moved into frame b and b's depth [m]\n",
              steps.size(), o.depth_delta, dataset.root().c_str());
  std::printf("%-16s %7s %10s %10s %10s %10s %10s %10s\n", "pose", "steps", "rmse", "mean",
              "median", "std", "min", "max");
  std::cout << row("ground truth", gt_stats) << row("estimate", est_stats);
  std::printf("the estimate agrees better on %zu of %zu steps\n", estimate_better, steps.size());
  constexpr std::size_t kShown = 5;
  std::printf("\nsteps where the ground truth disagrees most with the depth, against the "
              "estimate\n  %6s    %-6s %8s %8s %9s %9s\n", "frame", "frame", "gt mm", "est mm",
              "gt inl", "est inl");
  nlohmann::json worst_gt = worst_steps(steps, true, kShown);
  std::printf("steps where the estimate disagrees most, against the ground truth\n");
  nlohmann::json worst_est = worst_steps(steps, false, kShown);
  nlohmann::json frame_a, frame_b;
  for (const auto& s : steps) {
    frame_a.push_back(s.frame_a);
    frame_b.push_back(s.frame_b);
  }
  *out = {{"delta_frames", o.depth_delta},
          {"steps", steps.size()},
          {"inlier_distance_m", config.inlier_distance},
          {"ground_truth_median_m", stats_json(gt_stats)},
          {"estimate_median_m", stats_json(est_stats)},
          {"estimate_better_steps", estimate_better},
          {"worst_ground_truth_steps", worst_gt},
          {"worst_estimate_steps", worst_est},
          {"per_step",
           {{"frame_a", frame_a},
            {"frame_b", frame_b},
            {"ground_truth_median_m", gt_medians},
            {"estimate_median_m", est_medians}}}};
  if (o.residual_grid) (*out)["residual_grid"] = residual_grid_report(gt_grid, est_grid);
  return true;
}

int run_eval(const EvalOptions& o) {
  std::string why;
  if (o.residual_grid && o.dataset.path.empty()) return fail("--residual-grid needs --dataset (the depth it maps)");
  std::unique_ptr<core::Dataset> dataset;
  if (!o.dataset.path.empty()) {
    core::DatasetOptions options;
    dataset = open_dataset(o.dataset, &options, &why);
    if (!dataset) return fail(why);
  }
  core::Trajectory gt, est;
  std::string gt_name = o.gt_path;
  if (!o.gt_path.empty()) {
    if (!core::read_tum_trajectory(o.gt_path, &gt, &why)) return fail(why);
  } else if (dataset && dataset->has_ground_truth()) {
    gt = dataset->ground_truth();  // the selected frames' poses
    gt_name = dataset->root() + " (its ground truth)";
  } else {
    return fail(dataset ? dataset->root() + " has no ground truth: pass --gt"
                        : "--gt is required without --dataset");
  }
  if (!core::read_tum_trajectory(o.est_path, &est, &why)) return fail(why);

  core::AteConfig ate_config;
  ate_config.association.max_difference = o.max_difference;
  ate_config.alignment = o.sim3 ? core::Alignment::kSim3 : core::Alignment::kSE3;
  core::AteResult ate;
  if (!core::compute_ate(gt, est, ate_config, &ate, &why)) return fail("ATE: " + why);

  core::RpeConfig rpe_config;
  rpe_config.association = ate_config.association;
  rpe_config.unit = o.rpe_unit == "seconds" ? core::RpeUnit::kSeconds : core::RpeUnit::kFrames;
  rpe_config.delta = o.rpe_delta;
  rpe_config.scale = ate.scale;  // 1 under SE(3); the monocular scale under Sim(3)
  core::RpeResult rpe;
  if (!core::compute_rpe(gt, est, rpe_config, &rpe, &why)) return fail("RPE: " + why);

  std::printf("ground truth: %s (%zu poses)\nestimate:     %s (%zu poses)\n", gt_name.c_str(),
              gt.size(), o.est_path.c_str(), est.size());
  std::printf("association:  %zu pairs, max difference %.3f s\n", ate.pairs, o.max_difference);
  std::printf("alignment:    %s, scale %.6f\n", core::to_string(ate.alignment), ate.scale);
  std::printf("RPE delta:    %g %s\n\n", rpe_config.delta, core::to_string(rpe_config.unit));
  std::printf("%-16s %7s %10s %10s %10s %10s %10s %10s\n", "metric", "pairs", "rmse", "mean",
              "median", "std", "min", "max");
  std::cout << row("ATE trans [m]", ate.pairs, ate.rmse, ate.mean, ate.median, ate.std, ate.min,
                   ate.max);
  std::cout << row("RPE trans [m]", rpe.translation) << row("RPE rot [deg]", rpe.rotation);
  std::cout << std::flush;

  nlohmann::json depth;
  if (dataset && !depth_agreement_report(o, *dataset, gt, est, &depth, &why))
    return fail(why);

  if (!o.json_path.empty()) {
    nlohmann::json T = nlohmann::json::array();
    for (int i = 0; i < 4; ++i) {
      nlohmann::json matrix_row = nlohmann::json::array();
      for (int j = 0; j < 4; ++j) matrix_row.push_back(ate.T_gt_est.matrix()(i, j));
      T.push_back(matrix_row);
    }
    nlohmann::json out = {
        {"ground_truth", gt_name},
        {"estimate", o.est_path},
        {"association", {{"max_difference_s", o.max_difference}, {"offset_s", 0.0}}},
        {"ate",
         {{"alignment", core::to_string(ate.alignment)},
          {"pairs", ate.pairs},
          {"rmse_m", ate.rmse},
          {"mean_m", ate.mean},
          {"median_m", ate.median},
          {"std_m", ate.std},
          {"min_m", ate.min},
          {"max_m", ate.max},
          {"scale", ate.scale},
          {"T_gt_est", T}}},
        {"rpe",
         {{"delta", rpe_config.delta},
          {"unit", core::to_string(rpe_config.unit)},
          {"scale", rpe_config.scale},
          {"pairs", rpe.pairs},
          {"translation_m", stats_json(rpe.translation)},
          {"rotation_deg", stats_json(rpe.rotation)}}}};
    if (!depth.is_null()) out["depth_agreement"] = depth;
    std::ofstream file(o.json_path);
    if (!file) return fail(o.json_path + ": cannot open for writing");
    file << out.dump(2) << "\n";
    if (!file) return fail(o.json_path + ": write failed");
    std::cout << "\nwrote " << o.json_path << "\n";
  }

  if (!o.plot_path.empty()) {
    core::TrajectoryPlotConfig plot_config;
    const std::string name = o.est_path.substr(o.est_path.find_last_of('/') + 1);
    plot_config.title = name;
    cv::Mat rgb;
    if (!core::render_trajectory_plot(gt, ate, plot_config, &rgb, &why)) return fail(why);
    if (!core::write_image(o.plot_path, rgb, &why)) return fail(why);
    std::cout << (o.json_path.empty() ? "\n" : "") << "wrote " << o.plot_path << "\n";
  }
  std::cout << std::flush;
  return 0;
}

}  // namespace

void add_eval_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "eval", "Trajectory accuracy: ATE (TUM association, Umeyama alignment) and RPE of an "
              "estimate against ground truth, both TUM format (docs/evaluation.md)");
  auto o = std::make_shared<EvalOptions>();
  app->add_option("--gt", o->gt_path,
                  "Ground-truth trajectory (TUM format); without it, --dataset's own")
      ->check(CLI::ExistingFile);
  app->add_option("--est", o->est_path, "Estimated trajectory (TUM format)")
      ->required()
      ->check(CLI::ExistingFile);
  app->add_option("--json", o->json_path, "Write the results as JSON to this file");
  app->add_option("--plot", o->plot_path,
                  "Draw top and side views coloured by ATE error into this image (.png)");
  app->add_flag("--sim3", o->sim3,
                "Align with scale (Sim(3), monocular); RPE then uses the same scale");
  app->add_option("--max-diff", o->max_difference,
                  "Largest timestamp difference of an associated pair, seconds")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app->add_option("--rpe-delta", o->rpe_delta, "RPE pair spacing in --rpe-unit")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app->add_option("--rpe-unit", o->rpe_unit, "RPE spacing unit: frames or seconds")
      ->capture_default_str()
      ->check(CLI::IsMember({"frames", "seconds"}));
  // Optional: the recording both trajectories belong to, for the depth agreement of each step.
  add_dataset_options(app, &o->dataset, false);
  app->add_option("--depth-delta", o->depth_delta,
                  "With --dataset: frames between the two depths of a scored step")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app->add_flag("--residual-grid", o->residual_grid,
                "With --dataset: map the signed depth residual over the image and by depth (a "
                "sensor's depth distortion shows as a pattern that grows with depth)");
  commands->push_back({app, [o] { return run_eval(*o); }});
}

}  // namespace fslam::cli
