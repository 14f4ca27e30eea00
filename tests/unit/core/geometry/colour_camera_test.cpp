// Registering colour from a separate colour sensor onto the depth camera's pixels.
#include "fslam/core/geometry/colour_camera.hpp"

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "colour_rig.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::core {
namespace {

using test::colour_sensor_image;
using test::offset_colour_camera;

double mean_abs_difference(const cv::Mat& a, const cv::Mat& b) {
  const cv::Scalar m = cv::mean(cv::abs(a - b) + cv::abs(b - a));  // saturating per direction
  return (m[0] + m[1] + m[2]) / 3.0;
}

TEST(ColourCamera, ParsesAndPrintsTheSameValues) {
  ColourCamera c;
  std::string why;
  ASSERT_TRUE(ColourCamera::parse("521.38, 521.38 319.5,221.75,-0.0319,0.05,0", &c, &why)) << why;
  EXPECT_DOUBLE_EQ(c.camera.fx, 521.38);
  EXPECT_DOUBLE_EQ(c.camera.cy, 221.75);
  EXPECT_DOUBLE_EQ(c.t_colour_depth.x(), -0.0319);
  EXPECT_EQ(c.to_string(), "521.38,521.38,319.50,221.75,-0.0319,0.0500,0.0000");
  ColourCamera back;
  ASSERT_TRUE(ColourCamera::parse(c.to_string(), &back, &why)) << why;
  EXPECT_DOUBLE_EQ(back.camera.fx, c.camera.fx);
  for (const char* bad : {"", "1,2,3,4,5,6", "0,500,320,240,0,0,0", "500,500,320,240,0,0,nan",
                          "500,500,320,240,0,0,0,1", "500,500,x,240,0,0,0"})
    EXPECT_FALSE(ColourCamera::parse(bad, &c, &why)) << "accepted '" << bad << "'";
}

TEST(ColourCamera, TheDepthCameraItselfLeavesColourUnchanged) {
  const SyntheticRoom room = make_room(5);
  const PinholeCamera camera = synth_default_camera().scaled(0.25);
  SynthOptions options;
  const Trajectory trajectory = make_trajectory(room, options);
  const SynthView view = render_view(room, camera, trajectory[40].T_world_camera);
  ColourCamera same;
  same.camera = camera;
  cv::Mat registered;
  std::string why;
  ASSERT_TRUE(register_colour_to_depth(view.colour, view.depth, camera, same, &registered, &why))
      << why;
  EXPECT_EQ(cv::norm(registered, view.colour, cv::NORM_INF), 0.0);
}

TEST(ColourCamera, RegistrationRecoversTheColourTheDepthCameraWouldSee) {
  const SyntheticRoom room = make_room(5);
  const PinholeCamera camera = synth_default_camera().scaled(0.5);  // 320x240
  const ColourCamera colour = offset_colour_camera(camera);
  SynthOptions options;
  const Trajectory trajectory = make_trajectory(room, options);
  for (const std::size_t frame : {30u, 150u}) {
    const Eigen::Isometry3d& T = trajectory[frame].T_world_camera;
    const SynthView truth = render_view(room, camera, T);  // colour registered by construction
    const cv::Mat raw = colour_sensor_image(room, colour, T);
    cv::Mat registered;
    std::string why;
    ASSERT_TRUE(register_colour_to_depth(raw, truth.depth, camera, colour, &registered, &why))
        << why;
    const double before = mean_abs_difference(raw, truth.colour);
    const double after = mean_abs_difference(registered, truth.colour);
    // What is left (4.5 of 49.5 grey levels at frame 30) is resampling at texture and depth
    // edges, and surfaces one sensor sees past an occluder and the other does not.
    EXPECT_LT(after, 0.15 * before) << "frame " << frame;
    EXPECT_LT(after, 6.0) << "frame " << frame << ": " << after << " against " << before;
  }
}

TEST(ColourCamera, BadInputIsAnError) {
  const PinholeCamera camera = synth_default_camera().scaled(0.25);
  ColourCamera colour = offset_colour_camera(camera);
  const cv::Mat rgb(camera.height, camera.width, CV_8UC3, cv::Scalar::all(100));
  const cv::Mat depth(camera.height, camera.width, CV_32FC1, cv::Scalar(2.0f));
  cv::Mat out;
  std::string why;
  EXPECT_FALSE(register_colour_to_depth(cv::Mat(), depth, camera, colour, &out, &why));
  EXPECT_FALSE(register_colour_to_depth(rgb, cv::Mat(10, 10, CV_32FC1), camera, colour, &out, &why));
  colour.camera = camera.scaled(2.0);  // 320x240 images stated, 160x120 given
  EXPECT_FALSE(register_colour_to_depth(rgb, depth, camera, colour, &out, &why));
  EXPECT_NE(why.find("colour camera is 320x240"), std::string::npos) << why;
  // A frame without any depth still registers, by ray direction.
  colour.camera.width = colour.camera.height = 0;
  const cv::Mat no_depth(camera.height, camera.width, CV_32FC1, cv::Scalar(0.0f));
  EXPECT_TRUE(register_colour_to_depth(rgb, no_depth, camera, colour, &out, &why)) << why;
  EXPECT_EQ(out.size(), rgb.size());
}

}  // namespace
}  // namespace fslam::core
