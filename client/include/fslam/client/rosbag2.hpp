// Reads rosbag2 recordings in the sqlite3 storage (ROS 2 Humble's default): a folder with
// metadata.yaml and one or more .db3 files holding the tables
//   topics(id, name, type, serialization_format, offered_qos_profiles)
//   messages(id, topic_id, timestamp, data)
// Messages are plain CDR (ros2_messages.hpp parses the camera types). docs/ros2.md.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace fslam::client::rosbag2 {

struct Topic {
  std::string name;                  // ROS name, e.g. /camera/color/image_raw
  std::string type;                  // e.g. sensor_msgs/msg/Image
  std::string serialization_format;  // cdr
  std::size_t messages = 0;
};

// Where one message lives, to read it again later.
struct MessageRef {
  std::size_t topic = 0;     // index into Bag::topics()
  std::size_t file = 0;      // which .db3
  std::int64_t row = 0;      // messages.id
  std::int64_t timestamp_ns = 0;  // recording time (the bag's, not the header stamp)
};

class Bag {
 public:
  Bag();
  ~Bag();
  Bag(const Bag&) = delete;
  Bag& operator=(const Bag&) = delete;
  // Opens the folder: the files metadata.yaml lists (storage sqlite3), or every *.db3 in it when
  // it has no metadata.yaml. False with `why` naming the file.
  bool open(const std::string& folder, std::string* why);
  const std::string& folder() const { return folder_; }
  const std::vector<Topic>& topics() const { return topics_; }
  // Every message of the given topics (indices into topics()), in recording-time order.
  bool index(const std::vector<std::size_t>& topics, std::vector<MessageRef>* refs, std::string* why) const;
  // The CDR bytes of one message. Safe from several threads (one connection per call).
  bool read(const MessageRef& ref, std::vector<std::uint8_t>* data, std::string* why) const;

 private:
  struct File;
  std::string folder_;
  std::vector<std::string> files_;
  std::vector<Topic> topics_;
  // (file, topics.id in that file) of each topic.
  std::vector<std::vector<std::pair<std::size_t, std::int64_t>>> topic_ids_;
};

}  // namespace fslam::client::rosbag2
