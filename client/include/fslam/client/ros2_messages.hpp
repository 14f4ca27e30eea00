// ROS 2 camera messages as featureslam reads them, from DDS samples (the server's ROS 2 bridge) or
// from rosbag2 records (`fslam stream --rosbag2`): one set of views, conversions and the stamp
// pairing of colour with depth, so that both paths build the same frame (docs/ros2.md).
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include <dds/dds.h>

#include "fslam/client/client.hpp"

namespace fslam::client::ros2 {

// The DDS topic of a ROS 2 topic, as rmw_cyclonedds_cpp names it: "/camera/x" -> "rt/camera/x".
std::string dds_topic(const std::string& ros_topic);

// QoS as rmw_cyclonedds_cpp sets it: volatile, keep last `depth`, reliable (ROS 2's default
// profile) or best effort (its sensor-data profile). Writers write plain CDR (XCDR1), as ROS 2
// does; readers take XCDR1 and XCDR2. The caller deletes it (dds_delete_qos).
dds_qos_t* make_qos(bool reliable, int depth, bool writer);

// builtin_interfaces/msg/Time.
struct Stamp {
  std::int32_t sec = 0;
  std::uint32_t nanosec = 0;
  double seconds() const { return sec + 1e-9 * nanosec; }
  static Stamp from_seconds(double seconds);
};

// sensor_msgs/msg/Image; `data` points at the message's bytes (not owned).
struct ImageMsg {
  Stamp stamp;
  std::string frame_id;
  std::uint32_t height = 0, width = 0;
  std::string encoding;
  std::uint8_t is_bigendian = 0;
  std::uint32_t step = 0;  // bytes per row
  const std::uint8_t* data = nullptr;
  std::size_t size = 0;
};

// sensor_msgs/msg/CompressedImage; `data` not owned.
struct CompressedImageMsg {
  Stamp stamp;
  std::string frame_id;
  std::string format;  // "jpeg", "png", or image_transport's "rgb8; jpeg compressed bgr8"
  const std::uint8_t* data = nullptr;
  std::size_t size = 0;
};

// sensor_msgs/msg/CameraInfo: what featureslam uses of it.
struct CameraInfoMsg {
  Stamp stamp;
  std::string frame_id;
  std::uint32_t height = 0, width = 0;
  std::string distortion_model;
  std::vector<double> d;
  double k[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};  // row-major [fx 0 cx; 0 fy cy; 0 0 1]
};

// Plain CDR (XCDR1) as rosbag2 stores it: a 4-byte encapsulation header (CDR_LE 00 01, CDR_BE
// 00 00), then the fields. False with `why` on a truncated or inconsistent record. Views point
// into `bytes`.
bool parse_image(const std::uint8_t* bytes, std::size_t n, ImageMsg* msg, std::string* why);
bool parse_compressed_image(const std::uint8_t* bytes, std::size_t n, CompressedImageMsg* msg,
                            std::string* why);
bool parse_camera_info(const std::uint8_t* bytes, std::size_t n, CameraInfoMsg* msg, std::string* why);

// Colour (rgb8, bgr8, mono8; rows of `step` bytes) to tightly packed RGB, [H, W, 3]. False with
// `why` on another encoding or a payload shorter than step * height or a step under the row.
bool colour_to_rgb8(const ImageMsg& msg, std::vector<std::uint8_t>* rgb, std::string* why);

// Depth to 16-bit raw units, [H, W], 0 = missing: 16UC1 is millimetres (depth_scale 1000),
// 32FC1 metres, stored at 0.2 mm (depth_scale 5000, as TUM) with non-finite, non-positive and
// beyond-13.1 m values missing. Either byte order (is_bigendian).
bool depth_to_u16(const ImageMsg& msg, std::vector<std::uint16_t>* depth, float* depth_scale,
                  std::string* why);

// The payload kind a CompressedImage's format names (its first "jpeg" or "png"); false otherwise.
bool compressed_encoding(const CompressedImageMsg& msg, PayloadEncoding* encoding, std::string* why);

// Intrinsics from K (fx = K[0], fy = K[4], cx = K[2], cy = K[5]) and the image size; false with
// `why` when K is not a pinhole matrix with positive focal lengths.
bool intrinsics_of(const CameraInfoMsg& msg, CameraIntrinsics* intrinsics, std::string* why);

// Pairs colour and depth messages whose header stamps lie within a tolerance, each stream in
// stamp order. A message that can no longer be paired (the other stream has moved past it by
// more than the tolerance, or more than `keep` wait) comes back as unpaired, with why.
class StampPairer {
 public:
  enum class Stream { colour, depth };
  struct Outcome {
    bool paired = false;
    std::uint64_t colour = 0, depth = 0;  // paired: the caller's ids of the two messages
    Stream stream = Stream::colour;       // unpaired: which message, its id and why
    std::uint64_t id = 0;
    std::string why;
  };
  explicit StampPairer(double tolerance_s, std::size_t keep = 8);
  // Adds a message; returns the pair it completes (if any) and the messages it leaves unpaired.
  std::vector<Outcome> add(Stream stream, std::uint64_t id, double stamp_s);
  // Everything still waiting, as unpaired (end of a recording).
  std::vector<Outcome> flush();
  double tolerance_s() const { return tolerance_s_; }

 private:
  struct Waiting {
    std::uint64_t id;
    double stamp;
  };
  Outcome unpaired(Stream stream, const Waiting& w, const std::string& reason) const;
  double tolerance_s_;
  std::size_t keep_;
  std::deque<Waiting> waiting_[2];
  double latest_[2];
};

}  // namespace fslam::client::ros2
