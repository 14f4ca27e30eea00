// Estimating a colour sensor's intrinsics and offset from posed views of a synthetic room.
#include "fslam/core/calibration/colour_calibration.hpp"

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "colour_rig.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::core {
namespace {

struct Scene {
  SyntheticRoom room = make_room(11);
  PinholeCamera camera = synth_default_camera().scaled(0.5);  // 320x240
  Trajectory trajectory;
  ColourCamera truth;
  Scene() {
    SynthOptions options;
    trajectory = make_trajectory(room, options);
    truth = test::offset_colour_camera(camera);
  }
  ColourCalibrationView view(std::size_t frame) const {
    ColourCalibrationView v;
    v.T_world_depth = trajectory[frame].T_world_camera;
    v.depth = render_view(room, camera, v.T_world_depth).depth;
    v.colour = test::colour_sensor_image(room, truth, v.T_world_depth);
    return v;
  }
};

TEST(ColourCalibration, RecoversTheColourSensorOfASyntheticRig) {
  const Scene scene;
  std::vector<ColourCalibrationPair> pairs;
  for (std::size_t a = 10; a + 10 < scene.trajectory.size(); a += 40)
    pairs.push_back({scene.view(a), scene.view(a + 10)});
  ColourCamera initial;  // "colour is registered": the depth camera, no offset
  initial.camera = scene.camera;
  ColourCalibrationConfig config;
  config.pixel_stride = 2;
  ColourCalibrationResult result;
  std::string why;
  ASSERT_TRUE(calibrate_colour_camera(pairs, scene.camera, initial, config, &result, &why)) << why;

  EXPECT_LT(result.final_cost, 0.5 * result.initial_cost);
  const ColourCamera& c = result.camera;
  EXPECT_NEAR(c.camera.fx, scene.truth.camera.fx, 0.01 * scene.truth.camera.fx);
  EXPECT_NEAR(c.camera.fy / c.camera.fx, 1.0, 1e-12);  // the initial aspect ratio is kept
  // The principal point and the in-plane offset trade against each other over a room's depth
  // range, so they are checked through what they do: where points at 1-4 m land in the image.
  for (const double z : {1.0, 2.0, 4.0}) {
    for (const Eigen::Vector2d& pixel : {Eigen::Vector2d(40, 30), Eigen::Vector2d(280, 200)}) {
      const Eigen::Vector3d p = scene.camera.unproject(pixel, z);
      const Eigen::Vector3d pe = p + c.t_colour_depth, pt = p + scene.truth.t_colour_depth;
      const Eigen::Vector2d est = c.camera.project(pe), tru = scene.truth.camera.project(pt);
      EXPECT_LT((est - tru).norm(), 1.0) << "z " << z << " m, pixel " << pixel.transpose();
    }
  }
}

TEST(ColourCalibration, BadInputIsAnError) {
  const Scene scene;
  ColourCamera initial;
  initial.camera = scene.camera;
  ColourCalibrationResult result;
  std::string why;
  EXPECT_FALSE(calibrate_colour_camera({}, scene.camera, initial, {}, &result, &why));
  ColourCalibrationPair pair{scene.view(10), scene.view(20)};
  pair.b.depth = cv::Mat(10, 10, CV_32FC1);
  EXPECT_FALSE(calibrate_colour_camera({pair}, scene.camera, initial, {}, &result, &why));
  pair = {scene.view(10), scene.view(20)};
  pair.a.depth.setTo(0.0f);  // no depth: nothing to compare
  EXPECT_FALSE(calibrate_colour_camera({pair}, scene.camera, initial, {}, &result, &why));
  EXPECT_NE(why.find("no depth sample"), std::string::npos) << why;
  ColourCalibrationConfig bad;
  bad.pixel_stride = 0;
  EXPECT_FALSE(calibrate_colour_camera({pair}, scene.camera, initial, bad, &result, &why));
}

}  // namespace
}  // namespace fslam::core
