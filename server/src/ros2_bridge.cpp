#include "fslam/server/ros2_bridge.hpp"

#include <cstdio>
#include <utility>

#include <Eigen/Geometry>

#include "fslam/core/error.hpp"
#include "fslam/server/wire.hpp"
#include "ros2/geometry_msgs.h"
#include "ros2/nav_msgs.h"
#include "ros2/sensor_msgs.h"
#include "ros2/tf2_msgs.h"

namespace fslam::server {

namespace ros2 = client::ros2;

namespace {

// How many problems are logged one by one before only every 100th is.
constexpr std::uint64_t kLoggedProblems = 20;
// Frame ids whose pose has not come yet, kept at most (skipped frames never get one).
constexpr std::size_t kStampsKept = 1024;

ros2::ImageMsg view(const sensor_msgs_msg_dds__Image_& m) {
  ros2::ImageMsg v;
  v.stamp = {m.header.stamp.sec, m.header.stamp.nanosec};
  v.frame_id = m.header.frame_id ? m.header.frame_id : "";
  v.height = m.height;
  v.width = m.width;
  v.encoding = m.encoding ? m.encoding : "";
  v.is_bigendian = m.is_bigendian;
  v.step = m.step;
  v.data = m.data._buffer;
  v.size = m.data._length;
  return v;
}

client::Entity topic(const client::Entity& participant, const dds_topic_descriptor_t* desc,
                     const std::string& ros_name) {
  const std::string name = ros2::dds_topic(ros_name);
  return client::Entity(client::check_dds(dds_create_topic(participant.get(), desc, name.c_str(), nullptr, nullptr),
                                          "create topic " + name));
}

client::Entity endpoint(const client::Entity& participant, const client::Entity& topic, bool reliable,
                        int depth, bool writer) {
  dds_qos_t* qos = ros2::make_qos(reliable, depth, writer);
  const dds_entity_t e = writer ? dds_create_writer(participant.get(), topic.get(), qos, nullptr)
                                : dds_create_reader(participant.get(), topic.get(), qos, nullptr);
  dds_delete_qos(qos);
  return client::Entity(client::check_dds(e, writer ? "create writer" : "create reader"));
}

void header(const ros2::Stamp& stamp, std::string& frame, std_msgs_msg_dds__Header_* h) {
  h->stamp.sec = stamp.sec;
  h->stamp.nanosec = stamp.nanosec;
  h->frame_id = frame.data();
}

void pose_of(const Eigen::Isometry3d& T, geometry_msgs_msg_dds__Pose_* p) {
  const Eigen::Quaterniond q(T.rotation());
  p->position = {T.translation().x(), T.translation().y(), T.translation().z()};
  p->orientation = {q.x(), q.y(), q.z(), q.w()};
}

}  // namespace

bool Ros2Config::is_valid(std::string* why) const {
  if (!enabled) return true;
  if (colour_transport != "raw" && colour_transport != "compressed") {
    return core::fail(why, "ros2: colour_transport must be raw or compressed, not '" + colour_transport + "'");
  }
  if (reliability != "best_effort" && reliability != "reliable") {
    return core::fail(why, "ros2: reliability must be best_effort or reliable, not '" + reliability + "'");
  }
  if (frame_policy != "live" && frame_policy != "queue") {
    return core::fail(why, "ros2: frame_policy must be live or queue, not '" + frame_policy + "'");
  }
  if (!(stamp_tolerance_ms >= 0.0) || stamp_tolerance_ms > 1000.0) {
    return core::fail(why, "ros2: stamp_tolerance_ms must be in [0, 1000]");
  }
  for (const std::string* t : {&colour_topic, &depth_topic, &camera_info_topic, &pose_topic, &path_topic, &tf_topic}) {
    if (t->empty() || t->find_first_of(" \t*?") != std::string::npos) {
      return core::fail(why, "ros2: topic name '" + *t + "' is empty or holds spaces or wildcards");
    }
  }
  if (session.empty() || map.empty() || map_frame.empty() || camera_frame.empty()) {
    return core::fail(why, "ros2: session, map, map_frame and camera_frame must not be empty");
  }
  return true;
}

// A colour message converted: RGB rows, or a JPEG / PNG file as it came.
struct Ros2Bridge::Colour {
  ros2::Stamp stamp;
  fslam_proto_ImageEncoding encoding = fslam_proto_ENCODING_RAW;
  std::uint32_t width = 0, height = 0;
  std::vector<std::uint8_t> bytes;
};

struct Ros2Bridge::Depth {
  ros2::Stamp stamp;
  std::uint32_t width = 0, height = 0;
  float depth_scale = 1000.0f;
  std::vector<std::uint16_t> units;  // [H, W]
};

Ros2Bridge::Ros2Bridge(Server* server, const ServerConfig& config)
    : server_(server), config_(config), pairer_(config.ros2.stamp_tolerance_ms * 1e-3) {}

Ros2Bridge::~Ros2Bridge() {
  stop_input();
  server_->set_pose_listener(nullptr);
}

bool Ros2Bridge::start(std::string* why) {
  const Ros2Config& r = config_.ros2;
  const bool reliable = r.reliability == "reliable";
  const int depth = r.frame_policy == "live" ? 2 : 16;
  try {
    participant_ = client::make_participant(config_.domain);
    colour_topic_ = r.colour_transport == "raw"
                        ? topic(participant_, &sensor_msgs_msg_dds__Image__desc, r.colour_topic)
                        : topic(participant_, &sensor_msgs_msg_dds__CompressedImage__desc, r.colour_topic);
    depth_topic_ = topic(participant_, &sensor_msgs_msg_dds__Image__desc, r.depth_topic);
    info_topic_ = topic(participant_, &sensor_msgs_msg_dds__CameraInfo__desc, r.camera_info_topic);
    colour_reader_ = endpoint(participant_, colour_topic_, reliable, depth, false);
    depth_reader_ = endpoint(participant_, depth_topic_, reliable, depth, false);
    info_reader_ = endpoint(participant_, info_topic_, reliable, 1, false);
    pose_topic_ = topic(participant_, &geometry_msgs_msg_dds__PoseStamped__desc, r.pose_topic);
    path_topic_ = topic(participant_, &nav_msgs_msg_dds__Path__desc, r.path_topic);
    tf_topic_ = topic(participant_, &tf2_msgs_msg_dds__TFMessage__desc, r.tf_topic);
    // Outputs reliable (ROS 2's default profile: RViz and `ros2 topic echo` subscribe with it).
    pose_writer_ = endpoint(participant_, pose_topic_, true, 100, true);
    path_writer_ = endpoint(participant_, path_topic_, true, 10, true);
    tf_writer_ = endpoint(participant_, tf_topic_, true, 100, true);
    waitset_ = client::make_waitset(participant_, {&colour_reader_, &depth_reader_, &info_reader_});
  } catch (const client::DdsError& e) {
    return core::fail(why, std::string("ROS 2 bridge: ") + e.what());
  }
  server_->set_pose_listener([this](const Server::TrackedPose& p) { on_pose(p); });
  if (!server_->open_session(r.session, r.map, r.frame_policy == "live", why)) return false;
  stop_ = false;
  reader_ = std::thread([this] { read_loop(); });
  return true;
}

void Ros2Bridge::stop_input() {
  if (!reader_.joinable()) return;
  stop_ = true;
  dds_waitset_set_trigger(waitset_.get(), true);
  reader_.join();
}

Ros2BridgeStats Ros2Bridge::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

std::string Ros2Bridge::describe() const {
  const Ros2Config& r = config_.ros2;
  char text[640];
  std::snprintf(text, sizeof text,
                "ROS 2 bridge: session '%s' on map '%s' (%s policy) from %s (%s) + %s + %s, %s readers; "
                "poses on %s, keyframes on %s, %s -> %s on %s",
                r.session.c_str(), r.map.c_str(), r.frame_policy.c_str(), ros2::dds_topic(r.colour_topic).c_str(),
                r.colour_transport == "raw" ? "sensor_msgs/Image" : "sensor_msgs/CompressedImage",
                ros2::dds_topic(r.depth_topic).c_str(), ros2::dds_topic(r.camera_info_topic).c_str(),
                r.reliability == "reliable" ? "reliable" : "best-effort (match reliable and best-effort publishers)",
                ros2::dds_topic(r.pose_topic).c_str(), ros2::dds_topic(r.path_topic).c_str(),
                r.map_frame.c_str(), r.camera_frame.c_str(), ros2::dds_topic(r.tf_topic).c_str());
  return text;
}

void Ros2Bridge::problem(bool unpaired, const std::string& message) {
  std::uint64_t count;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++(unpaired ? stats_.unpaired : stats_.rejected);
    stats_.last_problem = message;
    count = stats_.unpaired + stats_.rejected;
  }
  server_->report_rejected(config_.ros2.session, "ROS 2 input: " + message);
  if (log_ && (count <= kLoggedProblems || count % 100 == 0)) {
    log_("ROS 2 input: " + message + " (" + std::to_string(count) + " problem(s) so far)");
  }
}

void Ros2Bridge::read_loop() {
  const Ros2Config& r = config_.ros2;
  while (!stop_) {
    dds_attach_t triggered[3];
    dds_waitset_wait(waitset_.get(), triggered, 3, DDS_MSECS(200));
    client::take_each<sensor_msgs_msg_dds__CameraInfo_>(info_reader_.get(), [&](const sensor_msgs_msg_dds__CameraInfo_& m) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        ++stats_.camera_info_received;
      }
      ros2::CameraInfoMsg info;
      info.height = m.height;
      info.width = m.width;
      for (int i = 0; i < 9; ++i) info.k[i] = m.k[i];
      std::string why;
      if (ros2::intrinsics_of(info, &intrinsics_, &why)) {
        have_info_ = true;
        info_problem_.clear();
      } else if (why != info_problem_) {
        info_problem_ = why;
        problem(false, why + " (" + r.camera_info_topic + ")");
      }
    });
    auto colour_image = [&](const sensor_msgs_msg_dds__Image_& m) {
      auto c = std::make_unique<Colour>();
      const ros2::ImageMsg v = view(m);
      std::string why;
      if (!ros2::colour_to_rgb8(v, &c->bytes, &why)) return problem(false, why + " (" + r.colour_topic + ")");
      c->stamp = v.stamp;
      c->width = v.width;
      c->height = v.height;
      on_colour(v.stamp, std::move(c));
    };
    auto colour_compressed = [&](const sensor_msgs_msg_dds__CompressedImage_& m) {
      ros2::CompressedImageMsg v;
      v.stamp = {m.header.stamp.sec, m.header.stamp.nanosec};
      v.format = m.format ? m.format : "";
      v.data = m.data._buffer;
      v.size = m.data._length;
      client::PayloadEncoding kind;
      std::string why;
      if (!ros2::compressed_encoding(v, &kind, &why)) return problem(false, why + " (" + r.colour_topic + ")");
      auto c = std::make_unique<Colour>();
      c->stamp = v.stamp;
      c->encoding = kind == client::PayloadEncoding::jpeg ? fslam_proto_ENCODING_JPEG : fslam_proto_ENCODING_PNG;
      if (v.size == 0 || !encoded_image_size(v.data, v.size, c->encoding, &c->width, &c->height)) {
        return problem(false, "compressed colour: the " + v.format + " header cannot be read (" + r.colour_topic + ")");
      }
      c->bytes.assign(v.data, v.data + v.size);
      on_colour(v.stamp, std::move(c));
    };
    if (r.colour_transport == "raw") {
      client::take_each<sensor_msgs_msg_dds__Image_>(colour_reader_.get(), colour_image);
    } else {
      client::take_each<sensor_msgs_msg_dds__CompressedImage_>(colour_reader_.get(), colour_compressed);
    }
    client::take_each<sensor_msgs_msg_dds__Image_>(depth_reader_.get(), [&](const sensor_msgs_msg_dds__Image_& m) {
      auto d = std::make_unique<Depth>();
      const ros2::ImageMsg v = view(m);
      std::string why;
      if (!ros2::depth_to_u16(v, &d->units, &d->depth_scale, &why)) return problem(false, why + " (" + r.depth_topic + ")");
      d->stamp = v.stamp;
      d->width = v.width;
      d->height = v.height;
      on_depth(v.stamp, std::move(d));
    });
  }
}

void Ros2Bridge::on_colour(const ros2::Stamp& stamp, std::unique_ptr<Colour> colour) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.colour_received;
  }
  const std::uint64_t id = next_id_++;
  colours_[id] = std::move(colour);
  on_pairs(pairer_.add(ros2::StampPairer::Stream::colour, id, stamp.seconds()));
}

void Ros2Bridge::on_depth(const ros2::Stamp& stamp, std::unique_ptr<Depth> depth) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.depth_received;
  }
  const std::uint64_t id = next_id_++;
  depths_[id] = std::move(depth);
  on_pairs(pairer_.add(ros2::StampPairer::Stream::depth, id, stamp.seconds()));
}

void Ros2Bridge::on_pairs(const std::vector<ros2::StampPairer::Outcome>& outcomes) {
  for (const auto& o : outcomes) {
    if (o.paired) {
      const auto c = colours_.find(o.colour);
      const auto d = depths_.find(o.depth);
      if (c != colours_.end() && d != depths_.end()) submit(*c->second, *d->second);
      if (c != colours_.end()) colours_.erase(c);
      if (d != depths_.end()) depths_.erase(d);
      continue;
    }
    if (o.stream == ros2::StampPairer::Stream::colour) colours_.erase(o.id);
    else depths_.erase(o.id);
    problem(true, o.why);
  }
}

void Ros2Bridge::submit(const Colour& colour, const Depth& depth) {
  const Ros2Config& r = config_.ros2;
  if (!have_info_) {
    return problem(false, "no usable CameraInfo on " + r.camera_info_topic + " yet: frame not built" +
                              (info_problem_.empty() ? "" : " (" + info_problem_ + ")"));
  }
  const client::CameraIntrinsics& k = intrinsics_;
  auto size = [](std::uint32_t w, std::uint32_t h) { return std::to_string(w) + "x" + std::to_string(h); };
  if (colour.width != k.width || colour.height != k.height || depth.width != k.width || depth.height != k.height) {
    return problem(false, "wrong size: colour " + size(colour.width, colour.height) + ", depth " +
                              size(depth.width, depth.height) + ", CameraInfo " + size(k.width, k.height) +
                              " (depth must be registered to colour, e.g. aligned_depth_to_color)");
  }
  std::uint64_t frame_id;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    frame_id = next_frame_id_++;
    stamps_[frame_id] = colour.stamp;
    while (stamps_.size() > kStampsKept) stamps_.erase(stamps_.begin());
    ++stats_.frames_submitted;
  }
  std::string session = r.session;
  fslam_proto_Frame f{};
  f.session = session.data();
  f.frame_id = frame_id;
  f.timestamp = colour.stamp.seconds();
  f.intrinsics = {k.fx, k.fy, k.cx, k.cy, k.width, k.height};
  f.depth_scale = depth.depth_scale;
  f.colour = {colour.encoding, colour.width, colour.height, 3, 1,
              {static_cast<std::uint32_t>(colour.bytes.size()), static_cast<std::uint32_t>(colour.bytes.size()),
               const_cast<std::uint8_t*>(colour.bytes.data()), false}};
  const std::uint32_t depth_bytes = static_cast<std::uint32_t>(depth.units.size() * sizeof(std::uint16_t));
  f.depth = {fslam_proto_ENCODING_RAW, depth.width, depth.height, 1, 2,
             {depth_bytes, depth_bytes,
              reinterpret_cast<std::uint8_t*>(const_cast<std::uint16_t*>(depth.units.data())), false}};
  f.gt_pose.rotation[3] = 1.0;
  server_->submit_frame(f);
}

void Ros2Bridge::on_pose(const Server::TrackedPose& p) {
  const Ros2Config& r = config_.ros2;
  if (p.session != r.session) return;
  ros2::Stamp stamp;
  std::vector<std::pair<ros2::Stamp, Eigen::Isometry3d>> path;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = stamps_.find(p.frame_id);
    if (it == stamps_.end()) return;
    stamp = it->second;
    stamps_.erase(stamps_.begin(), std::next(it));  // older ones were skipped: no pose will come
    ++stats_.poses_published;
    if (p.keyframe) {
      ++stats_.keyframes;
      keyframes_.push_back({stamp, p.T_world_camera});
      path = keyframes_;
    }
  }
  std::string map_frame = r.map_frame, camera_frame = r.camera_frame;
  geometry_msgs_msg_dds__PoseStamped_ pose{};
  header(stamp, map_frame, &pose.header);
  pose_of(p.T_world_camera, &pose.pose);
  dds_write(pose_writer_.get(), &pose);

  geometry_msgs_msg_dds__TransformStamped_ transform{};
  header(stamp, map_frame, &transform.header);
  transform.child_frame_id = camera_frame.data();
  const Eigen::Quaterniond q(p.T_world_camera.rotation());
  const Eigen::Vector3d& t = p.T_world_camera.translation();
  transform.transform.translation = {t.x(), t.y(), t.z()};
  transform.transform.rotation = {q.x(), q.y(), q.z(), q.w()};
  tf2_msgs_msg_dds__TFMessage_ tf{};
  tf.transforms = {1, 1, &transform, false};
  dds_write(tf_writer_.get(), &tf);

  if (path.empty()) return;
  std::vector<geometry_msgs_msg_dds__PoseStamped_> poses(path.size());
  for (std::size_t i = 0; i < path.size(); ++i) {
    header(path[i].first, map_frame, &poses[i].header);
    pose_of(path[i].second, &poses[i].pose);
  }
  nav_msgs_msg_dds__Path_ msg{};
  header(stamp, map_frame, &msg.header);
  msg.poses = {static_cast<std::uint32_t>(poses.size()), static_cast<std::uint32_t>(poses.size()), poses.data(), false};
  dds_write(path_writer_.get(), &msg);
}

}  // namespace fslam::server
