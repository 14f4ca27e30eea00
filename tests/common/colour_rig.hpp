// A synthetic RGB-D rig whose colour sensor is not registered to its depth camera, for the
// colour registration and calibration tests: a Kinect v1-like colour sensor and its images of a
// synthetic room.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/colour_camera.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::test {

// 10 % shorter focal length than the depth camera, principal point a few pixels off, 2.5 cm to
// the side.
inline core::ColourCamera offset_colour_camera(const core::PinholeCamera& depth_camera) {
  core::ColourCamera c;
  c.camera = depth_camera;
  c.camera.fx *= 0.9;
  c.camera.fy *= 0.9;
  c.camera.cx += 3.0;
  c.camera.cy -= 2.0;
  c.t_colour_depth = {-0.025, 0.004, 0.0};
  return c;
}

// The colour sensor's image of the room when the depth camera is at T_world_depth.
inline cv::Mat colour_sensor_image(const core::SyntheticRoom& room,
                                   const core::ColourCamera& colour,
                                   const Eigen::Isometry3d& T_world_depth) {
  // p_colour = p_depth + t, so the colour camera sits at -t in the depth frame.
  const Eigen::Isometry3d T_world_colour =
      T_world_depth * Eigen::Translation3d(-colour.t_colour_depth);
  return core::render_view(room, colour.camera, T_world_colour).colour;
}

}  // namespace fslam::test
