// `fslam eval` end to end: the real binary on the TUM reference trajectories.
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

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

}  // namespace
}  // namespace fslam
