// `fslam eval`: ATE and RPE of an estimated trajectory against ground truth (docs/evaluation.md).
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "fslam/core/eval/ate.hpp"
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

int run_eval(const EvalOptions& o) {
  std::string why;
  core::Trajectory gt, est;
  if (!core::read_tum_trajectory(o.gt_path, &gt, &why)) return fail(why);
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

  std::printf("ground truth: %s (%zu poses)\nestimate:     %s (%zu poses)\n", o.gt_path.c_str(),
              gt.size(), o.est_path.c_str(), est.size());
  std::printf("association:  %zu pairs, max difference %.3f s\n", ate.pairs, o.max_difference);
  std::printf("alignment:    %s, scale %.6f\n", core::to_string(ate.alignment), ate.scale);
  std::printf("RPE delta:    %g %s\n\n", rpe_config.delta, core::to_string(rpe_config.unit));
  std::printf("%-16s %7s %10s %10s %10s %10s %10s %10s\n", "metric", "pairs", "rmse", "mean",
              "median", "std", "min", "max");
  std::cout << row("ATE trans [m]", ate.pairs, ate.rmse, ate.mean, ate.median, ate.std, ate.min,
                   ate.max);
  const auto& t = rpe.translation;
  const auto& r = rpe.rotation;
  std::cout << row("RPE trans [m]", t.count, t.rmse, t.mean, t.median, t.std, t.min, t.max)
            << row("RPE rot [deg]", r.count, r.rmse, r.mean, r.median, r.std, r.min, r.max);

  if (!o.json_path.empty()) {
    nlohmann::json T = nlohmann::json::array();
    for (int i = 0; i < 4; ++i) {
      nlohmann::json matrix_row = nlohmann::json::array();
      for (int j = 0; j < 4; ++j) matrix_row.push_back(ate.T_gt_est.matrix()(i, j));
      T.push_back(matrix_row);
    }
    const nlohmann::json out = {
        {"ground_truth", o.gt_path},
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
  app->add_option("--gt", o->gt_path, "Ground-truth trajectory (TUM format)")
      ->required()
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
  commands->push_back({app, [o] { return run_eval(*o); }});
}

}  // namespace fslam::cli
