// Settings of the ROS 2 bridge (`ros2.*`, ros2_bridge.hpp, docs/ros2.md): which ROS 2 topics feed
// which session and map, and where the poses go.
#pragma once

#include <string>

namespace fslam::server {

struct Ros2Config {
  bool enabled = false;
  // Inputs (ROS names; DDS topics rt/<name>). colour_transport: raw (sensor_msgs/Image: rgb8,
  // bgr8, mono8) or compressed (sensor_msgs/CompressedImage: jpeg, png).
  std::string colour_topic = "/camera/color/image_raw";
  std::string colour_transport = "raw";
  std::string depth_topic = "/camera/aligned_depth_to_color/image_raw";  // 16UC1 mm or 32FC1 m
  std::string camera_info_topic = "/camera/color/camera_info";
  // Input QoS: best_effort readers match reliable and best-effort publishers (ROS 2's sensor
  // data profile); reliable readers match only reliable publishers and lose nothing.
  std::string reliability = "best_effort";
  double stamp_tolerance_ms = 20.0;  // colour and depth pair when their stamps differ this little
  // The session the frames feed and the map it builds (a new map: it must not exist yet).
  std::string session = "ros2";
  std::string map = "ros2";
  std::string frame_policy = "live";  // live or queue (docs/protocol.md)
  // Outputs: PoseStamped per tracked frame, Path of the keyframes, TFMessage map -> camera.
  std::string pose_topic = "/fslam/pose";
  std::string path_topic = "/fslam/path";
  std::string tf_topic = "/tf";
  std::string map_frame = "map";
  // The child of the published transform: its own name by default, so that it never gives the
  // driver's optical frame a second parent in a robot's TF tree.
  std::string camera_frame = "fslam_camera";
  bool is_valid(std::string* why) const;
};

}  // namespace fslam::server
