// The ROS 2 bridge (docs/ros2.md): ROS 2 camera topics in, ROS 2 poses out, at the DDS level as
// rmw_cyclonedds_cpp speaks it (topics rt/<name>, types <pkg>::msg::dds_::<Type>_, plain CDR), so
// that a robot's camera driver streams to the server and RViz shows its poses with no extra node.
// Colour (sensor_msgs/Image rgb8 / bgr8 / mono8, or CompressedImage jpeg / png) and depth (Image
// 16UC1 mm or 32FC1 m) pair by header stamp; CameraInfo gives the intrinsics; each pair becomes
// one frame of a session of its own, submitted through the path fslam/frames samples take (the
// session's frame policy applies). Each tracked pose goes out as geometry_msgs/PoseStamped, on
// /tf (map -> camera) and, at keyframes, as nav_msgs/Path of the keyframes. A message that cannot
// become a frame (unknown encoding, wrong size, no partner within the tolerance, no CameraInfo)
// is counted, logged and reported on the session's status; nothing throws.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "fslam/client/dds.hpp"
#include "fslam/client/ros2_messages.hpp"
#include "fslam/server/server.hpp"

namespace fslam::server {

struct Ros2BridgeStats {
  std::uint64_t colour_received = 0, depth_received = 0, camera_info_received = 0;
  std::uint64_t frames_submitted = 0;
  std::uint64_t unpaired = 0;  // colour or depth with no partner within the stamp tolerance
  std::uint64_t rejected = 0;  // unknown encodings, wrong sizes, no CameraInfo yet
  std::uint64_t poses_published = 0, keyframes = 0;
  std::string last_problem;
};

class Ros2Bridge {
 public:
  // `server` is active and outlives the bridge.
  Ros2Bridge(Server* server, const ServerConfig& config);
  ~Ros2Bridge();
  Ros2Bridge(const Ros2Bridge&) = delete;
  Ros2Bridge& operator=(const Ros2Bridge&) = delete;
  void set_log(std::function<void(const std::string&)> log) { log_ = std::move(log); }
  // Joins the DDS domain, opens the session (ros2.session on ros2.map) and starts reading.
  bool start(std::string* why);
  // Stops reading the ROS 2 inputs; poses of frames the server still tracks keep going out until
  // the bridge is destroyed (destroy it after Server::deactivate to publish every one).
  void stop_input();
  Ros2BridgeStats stats() const;
  // One line: topics, QoS and counts (for the log).
  std::string describe() const;

 private:
  struct Colour;
  struct Depth;
  void read_loop();
  void on_colour(const client::ros2::Stamp& stamp, std::unique_ptr<Colour> colour);
  void on_depth(const client::ros2::Stamp& stamp, std::unique_ptr<Depth> depth);
  void on_pairs(const std::vector<client::ros2::StampPairer::Outcome>& outcomes);
  void submit(const Colour& colour, const Depth& depth);
  void problem(bool unpaired, const std::string& message);
  void on_pose(const Server::TrackedPose& pose);

  Server* server_;
  ServerConfig config_;
  std::function<void(const std::string&)> log_;
  client::Entity participant_, colour_topic_, depth_topic_, info_topic_;
  client::Entity colour_reader_, depth_reader_, info_reader_, waitset_;
  client::Entity pose_topic_, path_topic_, tf_topic_, pose_writer_, path_writer_, tf_writer_;
  std::thread reader_;
  std::atomic<bool> stop_{false};

  // Reading thread only.
  client::ros2::StampPairer pairer_;
  std::map<std::uint64_t, std::unique_ptr<Colour>> colours_;  // waiting for a partner, by pairer id
  std::map<std::uint64_t, std::unique_ptr<Depth>> depths_;
  std::uint64_t next_id_ = 1;
  bool have_info_ = false;
  client::CameraIntrinsics intrinsics_;
  std::string info_problem_;  // why the latest CameraInfo is unusable

  mutable std::mutex mutex_;  // guards everything below
  Ros2BridgeStats stats_;
  std::uint64_t next_frame_id_ = 0;
  std::map<std::uint64_t, client::ros2::Stamp> stamps_;  // frame id -> header stamp, until its pose
  std::vector<std::pair<client::ros2::Stamp, Eigen::Isometry3d>> keyframes_;  // the Path
};

}  // namespace fslam::server
