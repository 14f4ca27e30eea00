// `fslam eval` end to end: the real binary on the TUM reference trajectories.
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cli_runner.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;

TEST(EvalCli, ReproducesTumReferenceAndWritesJsonAndPlot) {
  FSLAM_REQUIRE_DATA("evo_reference");
  const auto traj = test::data_dir() / "evo_reference" / "traj";
  const auto dir = test::fresh_temp_dir("eval");
  std::string out, err;
  const int code = run_command(fslam_bin() + " eval --gt " + (traj / "fr2_desk_groundtruth.txt").string() +
                           " --est " + (traj / "fr2_desk_ORB.txt").string() + " --json " +
                           (dir / "r.json").string() + " --plot " + (dir / "r.png").string(),
                       &out, &err);
  ASSERT_EQ(code, 0) << out << err;
  EXPECT_NE(out.find("ATE trans [m]       2223   0.008144   0.007514   0.007432"),
            std::string::npos)
      << out;
  std::stringstream json;
  json << std::ifstream(dir / "r.json").rdbuf();
  EXPECT_NE(json.str().find("\"pairs\": 2223"), std::string::npos) << json.str();
  EXPECT_NE(json.str().find("\"rmse_m\": 0.00814"), std::string::npos) << json.str();
  EXPECT_GT(std::filesystem::file_size(dir / "r.png"), 10000u);
}

TEST(EvalCli, ErrorsGoToStderrWithNonZeroExit) {
  const auto dir = test::fresh_temp_dir("bad");
  std::ofstream(dir / "bad.txt") << "1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n";
  std::string out, err;
  EXPECT_NE(run_command(fslam_bin() + " eval --gt " + (dir / "bad.txt").string() + " --est " +
                    (dir / "bad.txt").string(),
                &out, &err),
            0);
  EXPECT_NE(err.find("bad.txt:2"), std::string::npos) << err;
  EXPECT_NE(run_command(fslam_bin() + " eval --gt " + (dir / "missing.txt").string() + " --est x", &out,
                &err),
            0);
  EXPECT_FALSE(err.empty());
  ASSERT_EQ(run_command(fslam_bin() + " eval --help", &out, &err), 0) << err;
  EXPECT_NE(out.find("--rpe-unit"), std::string::npos) << out;
}

// A synthetic room of 12 frames (seed 3) in dir/room; its path.
std::string synth_room(const std::filesystem::path& dir) {
  const std::string room = (dir / "room").string();
  std::string out, err;
  EXPECT_EQ(run_command(fslam_bin() + " synth --out " + room + " --frames 12 --seed 3", &out, &err), 0) << err;
  return room;
}

// --dataset scores each step's depth agreement: an estimate that jumps 4 cm along world z at one
// frame of a synthetic room disagrees with the depth at that step and only there.
TEST(EvalCli, DepthAgreementFindsTheStepWhereAnEstimateJumps) {
  const auto dir = test::fresh_temp_dir("eval_depth");
  const std::string room = synth_room(dir);
  ASSERT_FALSE(HasFailure());
  std::string out, err;
  std::ifstream gt_file(room + "/groundtruth.txt");
  std::ofstream est_file(dir / "est.txt");
  std::string line;
  int pose = 0;
  while (std::getline(gt_file, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    double v[8];
    for (double& x : v) fields >> x;
    if (pose++ >= 6) v[3] += 0.04;  // frames 6.. moved 4 cm along world z
    est_file.precision(9);
    for (double x : v) est_file << x << ' ';
    est_file << '\n';
  }
  est_file.close();
  ASSERT_EQ(pose, 12);
  // Without --gt the dataset's own ground truth is the reference.
  const int code = run_command(fslam_bin() + " eval --est " + (dir / "est.txt").string() +
                                   " --dataset " + room + " --json " + (dir / "r.json").string(),
                               &out, &err);
  ASSERT_EQ(code, 0) << out << err;
  EXPECT_NE(out.find("depth agreement: 11 steps of 1 frame(s)"), std::string::npos) << out;
  const auto json = nlohmann::json::parse(std::ifstream(dir / "r.json"));
  const auto& depth = json.at("depth_agreement");
  EXPECT_EQ(depth.at("steps"), 11);
  const auto& worst = depth.at("worst_estimate_steps").at(0);
  EXPECT_EQ(worst.at("frame_a"), 5);
  EXPECT_EQ(worst.at("frame_b"), 6);
  EXPECT_GT(worst.at("estimate_median_m").get<double>(), 0.02);
  // Synthetic depth carries the sensor model's noise: the truth agrees to a few millimetres.
  EXPECT_LT(worst.at("ground_truth_median_m").get<double>(), 0.01);
  EXPECT_LT(depth.at("ground_truth_median_m").at("max").get<double>(), 0.01);

  // A dataset the estimate does not belong to is refused with the reason.
  EXPECT_NE(run_command(fslam_bin() + " eval --gt " + room + "/groundtruth.txt --est " +
                            (dir / "est.txt").string() + " --dataset " + room +
                            " --frames 0:3 --depth-delta 3",
                        &out, &err),
            0);
  EXPECT_NE(err.find("depth agreement"), std::string::npos) << err;
  EXPECT_NE(run_command(fslam_bin() + " eval --est " + (dir / "est.txt").string(), &out, &err), 0);
  EXPECT_NE(err.find("--gt is required without --dataset"), std::string::npos) << err;
}

// --residual-grid maps the signed residual over the image: on a synthetic room, whose depth noise
// is unbiased and whose trajectory is exact, the cells up to 2.5 m are flat to the noise of their
// medians (redkitchen's Kinect shows +-10 mm there, docs/tracking.md).
TEST(EvalCli, ResidualGridOfAnUnbiasedSensorIsFlat) {
  const auto dir = test::fresh_temp_dir("eval_grid");
  const std::string room = synth_room(dir);
  ASSERT_FALSE(HasFailure());
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " eval --est " + room + "/groundtruth.txt --dataset " + room +
                            " --depth-delta 3 --residual-grid --json " + (dir / "g.json").string(),
                        &out, &err),
            0)
      << out << err;
  EXPECT_NE(out.find("residual grid"), std::string::npos) << out;
  const auto grid = nlohmann::json::parse(std::ifstream(dir / "g.json")).at("depth_agreement").at("residual_grid");
  EXPECT_EQ(grid.at("cols"), 8);
  EXPECT_EQ(grid.at("rows"), 6);
  std::size_t cells = 0;
  double abs_sum = 0.0;
  for (const auto& bin : grid.at("bins")) {
    if (bin.at("max_depth_m").is_null() || bin.at("max_depth_m").get<double>() > 2.5) continue;
    const bool near = bin.at("max_depth_m").get<double>() <= 2.0;
    for (const char* side : {"ground_truth_median_m", "estimate_median_m"})
      for (const auto& row : bin.at(side))
        for (const auto& cell : row) {
          if (cell.is_null()) continue;
          ++cells;
          abs_sum += std::abs(cell.get<double>());
          if (near) {
            EXPECT_LT(std::abs(cell.get<double>()), 0.002) << side;  // metres
          }
        }
  }
  ASSERT_GT(cells, 20u);
  EXPECT_LT(abs_sum / static_cast<double>(cells), 0.002);  // metres, mean |median| over the cells
  EXPECT_NE(run_command(fslam_bin() + " eval --est " + room + "/groundtruth.txt --gt " + room +
                            "/groundtruth.txt --residual-grid",
                        &out, &err),
            0);
  EXPECT_NE(err.find("--residual-grid needs --dataset"), std::string::npos) << err;
}

}  // namespace
}  // namespace fslam
