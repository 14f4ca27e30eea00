// `fslam calibrate-colour` on real Kinect v1 data, whose colour sensor is not registered to depth.
#include <cmath>
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "cli_runner.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;

TEST(CalibrateColourCli, FindsTheKinectColourSensorOfRedkitchen) {
  FSLAM_REQUIRE_DATA("redkitchen");
  const auto dir = test::fresh_temp_dir("calibrate_colour");
  const std::string out_file = (dir / "colour_camera.txt").string();
  std::string out, err;
  const int code = run_command(fslam_bin() + " calibrate-colour --dataset " +
                                   (test::data_dir() / "redkitchen").string() + " --out " + out_file,
                               &out, &err);
  ASSERT_EQ(code, 0) << out << err;
  double before = 0.0, after = 0.0;
  const auto costs = out.find("mean capped grey-level difference:");
  ASSERT_NE(costs, std::string::npos) << out;
  ASSERT_EQ(std::sscanf(out.c_str() + costs,
                        "mean capped grey-level difference: %lf with colour registered to depth, "
                        "%lf with the estimate",
                        &before, &after),
            2)
      << out;
  // Unregistered, the colours two views see at the same depth point differ ~8 grey levels; the
  // estimate removes a quarter of that (the rest is exposure, blur and occlusion).
  EXPECT_LT(after, 0.8 * before) << out;
  double fx = 0, fy = 0, cx = 0, cy = 0, tx = 0, ty = 0, tz = 0;
  FILE* f = std::fopen(out_file.c_str(), "r");
  ASSERT_NE(f, nullptr);
  const int read = std::fscanf(f, "%lf,%lf,%lf,%lf,%lf,%lf,%lf", &fx, &fy, &cx, &cy, &tx, &ty, &tz);
  std::fclose(f);
  ASSERT_EQ(read, 7);
  // Kinect v1's colour camera has a focal length of about 525 px at 640x480, the depth camera
  // 585 px (the value 7-Scenes gives for both).
  EXPECT_NEAR(fx, 525.0, 0.03 * 525.0) << out;
  EXPECT_DOUBLE_EQ(fx, fy);
  // The sensors sit a few centimetres apart.
  EXPECT_LT(std::hypot(tx, ty), 0.08) << out;
}

TEST(CalibrateColourCli, BadInputIsAClearError) {
  FSLAM_REQUIRE_DATA("redkitchen");
  const std::string dataset = (test::data_dir() / "redkitchen").string();
  std::string out, err;
  EXPECT_NE(run_command(fslam_bin() + " calibrate-colour --dataset " + dataset +
                            " --frames 0:5 --gap 10", &out, &err),
            0);
  EXPECT_NE(err.find("need more than --gap 10 frames"), std::string::npos) << err;
  EXPECT_NE(run_command(fslam_bin() + " calibrate-colour --dataset " + dataset +
                            " --colour-camera 500,500,320,240,0,0", &out, &err),
            0);
  EXPECT_NE(err.find("--colour-camera"), std::string::npos) << err;
}

}  // namespace
}  // namespace fslam
