#include "stream_rosbag2.hpp"

#include <cstdio>
#include <sstream>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/client/ros2_messages.hpp"
#include "fslam/client/rosbag2.hpp"
#include "fslam/core/error.hpp"

namespace fslam::cli {
namespace {

namespace ros2 = client::ros2;
namespace bag2 = client::rosbag2;

constexpr const char* kImage = "sensor_msgs/msg/Image";
constexpr const char* kCompressed = "sensor_msgs/msg/CompressedImage";
constexpr const char* kCameraInfo = "sensor_msgs/msg/CameraInfo";

class Rosbag2Dataset : public core::Dataset {
 public:
  bool open(const std::string& folder, const std::string& topics, double tolerance_ms, std::string* why) {
    if (!bag_.open(folder, why)) return false;
    if (!choose_topics(topics, why)) return false;
    std::vector<bag2::MessageRef> refs;
    if (!bag_.index({colour_, depth_, info_}, &refs, why)) return false;
    ros2::StampPairer pairer(tolerance_ms * 1e-3, 64);
    std::vector<bag2::MessageRef> by_id;
    std::vector<double> stamps;
    std::size_t unpaired = 0;
    std::vector<std::uint8_t> data;
    bool have_camera = false;
    for (const bag2::MessageRef& ref : refs) {
      if (!bag_.read(ref, &data, why)) return false;
      const Topic& t = bag_.topics()[ref.topic];
      if (ref.topic == info_) {
        ros2::CameraInfoMsg info;
        client::CameraIntrinsics k;
        if (!have_camera && ros2::parse_camera_info(data.data(), data.size(), &info, why) &&
            ros2::intrinsics_of(info, &k, why)) {
          camera_ = {k.fx, k.fy, k.cx, k.cy, static_cast<int>(k.width), static_cast<int>(k.height)};
          have_camera = true;
        }
        continue;
      }
      double stamp = 0;
      if (t.type == kCompressed) {
        ros2::CompressedImageMsg m;
        if (!ros2::parse_compressed_image(data.data(), data.size(), &m, why)) return false;
        stamp = m.stamp.seconds();
      } else {
        ros2::ImageMsg m;
        if (!ros2::parse_image(data.data(), data.size(), &m, why)) return false;
        stamp = m.stamp.seconds();
        if (ref.topic == depth_ && by_id.empty()) depth_scale_ = m.encoding == "32FC1" ? 5000.0 : 1000.0;
      }
      const std::uint64_t id = by_id.size();
      by_id.push_back(ref);
      stamps.push_back(stamp);
      const auto stream = ref.topic == colour_ ? ros2::StampPairer::Stream::colour : ros2::StampPairer::Stream::depth;
      for (const auto& o : pairer.add(stream, id, stamp)) {
        if (!o.paired) {
          ++unpaired;
          continue;
        }
        frames_.push_back({by_id[o.colour], by_id[o.depth], stamps[o.colour]});
      }
    }
    unpaired += pairer.flush().size();
    if (!have_camera) return core::fail(why, folder + ": no usable CameraInfo on " + bag_.topics()[info_].name);
    if (frames_.empty()) return core::fail(why, folder + ": no colour and depth messages pair within " +
                                                    std::to_string(tolerance_ms) + " ms");
    if (unpaired > 0) {
      std::fprintf(stderr, "rosbag2: %zu colour or depth message(s) had no partner within %g ms; skipped\n",
                   unpaired, tolerance_ms);
    }
    return true;
  }

  std::string kind() const override { return "rosbag2"; }
  const std::string& root() const override { return bag_.folder(); }
  std::size_t size() const override { return frames_.size(); }
  const core::PinholeCamera& camera() const override { return camera_; }
  std::string camera_source() const override { return bag_.topics()[info_].name + " (CameraInfo K)"; }
  double depth_scale() const override { return depth_scale_; }
  std::int64_t id(std::size_t index) const override { return static_cast<std::int64_t>(index); }
  double timestamp(std::size_t index) const override { return frames_.at(index).stamp; }
  bool has_ground_truth() const override { return false; }
  core::Trajectory ground_truth() const override { return {}; }

  bool load(std::size_t index, core::RgbdFrame* frame, std::string* why) const override {
    const Pair& p = frames_.at(index);
    std::vector<std::uint8_t> colour_bytes, depth_bytes;
    if (!bag_.read(p.colour, &colour_bytes, why) || !bag_.read(p.depth, &depth_bytes, why)) return false;
    const std::string where = " (" + bag_.folder() + ", frame " + std::to_string(index) + ")";
    cv::Mat colour;
    if (bag_.topics()[colour_].type == kCompressed) {
      ros2::CompressedImageMsg m;
      client::PayloadEncoding encoding;
      if (!ros2::parse_compressed_image(colour_bytes.data(), colour_bytes.size(), &m, why) ||
          !ros2::compressed_encoding(m, &encoding, why)) {
        return core::fail(why, *why + where);
      }
      const cv::Mat file(1, static_cast<int>(m.size), CV_8UC1, const_cast<std::uint8_t*>(m.data));
      cv::Mat bgr = cv::imdecode(file, cv::IMREAD_COLOR);
      if (bgr.empty()) return core::fail(why, "compressed colour does not decode" + where);
      cv::cvtColor(bgr, colour, cv::COLOR_BGR2RGB);
    } else {
      ros2::ImageMsg m;
      std::vector<std::uint8_t> rgb;
      if (!ros2::parse_image(colour_bytes.data(), colour_bytes.size(), &m, why) ||
          !ros2::colour_to_rgb8(m, &rgb, why)) {
        return core::fail(why, *why + where);
      }
      colour = cv::Mat(static_cast<int>(m.height), static_cast<int>(m.width), CV_8UC3, rgb.data()).clone();
    }
    ros2::ImageMsg d;
    std::vector<std::uint16_t> units;
    float scale = 1000.0f;
    if (!ros2::parse_image(depth_bytes.data(), depth_bytes.size(), &d, why) ||
        !ros2::depth_to_u16(d, &units, &scale, why)) {
      return core::fail(why, *why + where);
    }
    if (colour.cols != camera_.width || colour.rows != camera_.height || static_cast<int>(d.width) != camera_.width ||
        static_cast<int>(d.height) != camera_.height) {
      return core::fail(why, "colour " + std::to_string(colour.cols) + "x" + std::to_string(colour.rows) +
                                 " and depth " + std::to_string(d.width) + "x" + std::to_string(d.height) +
                                 " must have the CameraInfo's size" + where);
    }
    const cv::Mat raw(static_cast<int>(d.height), static_cast<int>(d.width), CV_16UC1, units.data());
    raw.convertTo(frame->depth, CV_32FC1, 1.0 / scale);
    frame->colour = colour;
    frame->camera = camera_;
    frame->id = static_cast<std::int64_t>(index);
    frame->timestamp = p.stamp;
    frame->T_world_camera_gt.reset();
    return true;
  }

 private:
  using Topic = bag2::Topic;
  struct Pair {
    bag2::MessageRef colour, depth;
    double stamp;  // the colour's header stamp, seconds
  };

  bool choose_topics(const std::string& names, std::string* why) {
    const auto& topics = bag_.topics();
    std::string listing;
    for (const Topic& t : topics) listing += "\n  " + t.name + " (" + t.type + ", " + std::to_string(t.messages) + ")";
    auto find = [&](const std::string& name, std::size_t* index) {
      for (std::size_t i = 0; i < topics.size(); ++i)
        if (topics[i].name == name) return *index = i, true;
      return false;
    };
    const std::size_t none = topics.size();
    colour_ = depth_ = info_ = none;
    if (!names.empty()) {
      std::stringstream in(names);
      std::string c, d, k;
      std::getline(in, c, ',');
      std::getline(in, d, ',');
      std::getline(in, k, ',');
      if (!find(c, &colour_) || !find(d, &depth_) || !find(k, &info_)) {
        return core::fail(why, "--rosbag2-topics '" + names + "': the bag has no such colour, depth or camera info "
                               "topic; it holds:" + listing);
      }
    } else {
      for (std::size_t i = 0; i < topics.size(); ++i) {
        const bool depth = topics[i].name.find("depth") != std::string::npos;
        if (topics[i].type == kImage && depth && depth_ == none) depth_ = i;
        else if ((topics[i].type == kImage || topics[i].type == kCompressed) && !depth && colour_ == none) colour_ = i;
        else if (topics[i].type == kCameraInfo && topics[i].name.find("depth") == std::string::npos && info_ == none) info_ = i;
      }
      if (info_ == none)
        for (std::size_t i = 0; i < topics.size(); ++i)
          if (topics[i].type == kCameraInfo) info_ = i;
      if (colour_ == none || depth_ == none || info_ == none) {
        return core::fail(why, bag_.folder() + ": needs a colour Image or CompressedImage topic, a depth Image topic "
                               "(a name with 'depth') and a CameraInfo topic (or --rosbag2-topics); it holds:" + listing);
      }
    }
    if (topics[colour_].type != kImage && topics[colour_].type != kCompressed) {
      return core::fail(why, topics[colour_].name + " is " + topics[colour_].type + ", not an image");
    }
    if (topics[depth_].type != kImage) return core::fail(why, topics[depth_].name + " is not a sensor_msgs/msg/Image");
    if (topics[info_].type != kCameraInfo) return core::fail(why, topics[info_].name + " is not a CameraInfo");
    for (std::size_t i : {colour_, depth_, info_}) {
      if (topics[i].serialization_format != "cdr") {
        return core::fail(why, topics[i].name + ": serialization '" + topics[i].serialization_format + "', not cdr");
      }
    }
    std::fprintf(stderr, "rosbag2: colour %s, depth %s, intrinsics %s\n", topics[colour_].name.c_str(),
                 topics[depth_].name.c_str(), topics[info_].name.c_str());
    return true;
  }

  bag2::Bag bag_;
  std::size_t colour_ = 0, depth_ = 0, info_ = 0;
  core::PinholeCamera camera_;
  double depth_scale_ = 1000.0;
  std::vector<Pair> frames_;
};

}  // namespace

std::unique_ptr<core::Dataset> open_rosbag2_dataset(const std::string& folder, const std::string& topics,
                                                    double tolerance_ms, std::string* why) {
  auto dataset = std::make_unique<Rosbag2Dataset>();
  if (!dataset->open(folder, topics, tolerance_ms, why)) return nullptr;
  return dataset;
}

}  // namespace fslam::cli
