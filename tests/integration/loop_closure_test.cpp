// Loop closure end to end through the real binary: a synthetic loop that returns to its start
// pose, tracked, its revisits found, the keyframe pose graph optimised (Ceres), the trajectory
// corrected and written.
#include <cstdio>
#include <regex>
#include <string>

#include <gtest/gtest.h>

#include "cli_runner.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;

double number_after(const std::string& text, const std::string& pattern) {
  std::smatch m;
  return std::regex_search(text, m, std::regex(pattern + R"(\s*([0-9.]+))")) ? std::stod(m[1]) : -1.0;
}

// One lap in 150 frames (about 2.4 degrees per frame), frame 149 one step before the start,
// synthesised into DIR/seq of a fresh temporary DIR, which is returned.
std::string synthetic_lap(const std::string& name) {
  const std::string dir = test::fresh_temp_dir(name).string();
  std::string out, err;
  EXPECT_EQ(run_command(fslam_bin() + " synth --out " + dir + "/seq --frames 150 --seed 3 --path loop --laps 1",
                        &out, &err),
            0)
      << err;
  return dir;
}

TEST(LoopClosureCli, ClosesTheSyntheticLoopAndKeepsTheTrajectory) {
  const std::string dir = synthetic_lap("loop");
  ASSERT_FALSE(HasFailure());
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " track --dataset " + dir + "/seq --out " + dir + "/t.txt --loop-closure"
                                      " --loop-gap 100",
                        &out, &err),
            0)
      << out << err;
  const double loops = number_after(out, R"(keyframes, )");
  EXPECT_GE(loops, 1.0) << out;
  EXPECT_NE(out.find("Termination: CONVERGENCE"), std::string::npos) << out;
  const double ate_before = number_after(out, R"(before loop closure: ATE RMSE)");
  const double last_before = number_after(out, R"(m, last frame)");
  const double ate_after = number_after(out, R"(\nATE RMSE)");
  const double last_after = number_after(out, R"(\nlast frame)");
  ASSERT_GT(ate_before, 0.0) << out;
  ASSERT_GT(ate_after, 0.0) << out;
  std::printf("ATE %.4f -> %.4f m, last frame %.4f -> %.4f m\n", ate_before, ate_after, last_before, last_after);
  EXPECT_LT(ate_after, 0.01) << out;                     // metres
  EXPECT_LE(ate_after, ate_before + 0.001) << out;       // the loop edges do not bend it
  EXPECT_LE(last_after, last_before + 0.001) << out;
  core::Trajectory written;
  std::string why;
  ASSERT_TRUE(core::read_tum_trajectory(dir + "/t.txt", &written, &why)) << why;
  EXPECT_EQ(written.size(), 150u);
  // Refused together with the relocalisation benchmark, with a reason.
  EXPECT_NE(run_command(fslam_bin() + " track --dataset " + dir + "/seq --out " + dir + "/u.txt --loop-closure"
                                      " --relocalise-every 5",
                        &out, &err),
            0);
  EXPECT_NE(err.find("--relocalise-every"), std::string::npos) << err;
}

// During tracking (`fslam run --loop-closure`): the loop thread finds the revisit while the lap is
// tracked and mapped, the map's Gaussians move with their keyframes, and the trajectory written is
// the final map world's: no worse than tracking alone.
TEST(LoopClosureCli, FslamRunClosesTheLoopDuringTrackingAndMovesTheMap) {
  const std::string dir = synthetic_lap("loop_run");
  ASSERT_FALSE(HasFailure());
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " track --dataset " + dir + "/seq --out " + dir + "/t.txt", &out, &err), 0)
      << out << err;
  const double ate_tracking = number_after(out, R"(\nATE RMSE)");
  ASSERT_GT(ate_tracking, 0.0) << out;
  ASSERT_EQ(run_command(fslam_bin() + " run --dataset " + dir + "/seq --out " + dir + "/run --threads 2 --renders 0"
                                      " --loop-closure --set loop_closure.min_frame_gap=100",
                        &out, &err),
            0)
      << out << err;
  const double loops = number_after(out, R"(loop closure: [0-9]+ keyframes,)");
  EXPECT_GE(loops, 1.0) << out;
  EXPECT_EQ(out.find("stopped:"), std::string::npos) << out;
  const double ate = number_after(out, R"(ATE RMSE)");
  ASSERT_GT(ate, 0.0) << out;
  std::printf("ATE tracking alone %.4f m, fslam run with loop closure %.4f m\n", ate_tracking, ate);
  EXPECT_LT(ate, 0.01) << out;  // metres
  EXPECT_LE(ate, ate_tracking + 0.001) << out;
  const double depth_l1 = number_after(out, R"(held-out frames[^\n]*depth L1)");
  if (depth_l1 >= 0.0) {
    EXPECT_LT(depth_l1, 5.0) << out;  // cm: the moved map still fits the frames
  }
  // Refused with a reason where it cannot work.
  EXPECT_NE(run_command(fslam_bin() + " run --dataset " + dir + "/seq --out " + dir + "/bad --renders 0"
                                      " --loop-closure --set tracker.relocalisation.enabled=false",
                        &out, &err),
            0);
  EXPECT_NE((out + err).find("tracker.relocalisation.enabled"), std::string::npos) << out << err;
}

}  // namespace
}  // namespace fslam
