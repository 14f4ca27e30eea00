// Test helpers for the ROS 2 interfaces: the CDR bytes Cyclone DDS writes for one sample of an
// idlc type (what goes on the wire and into a rosbag2 record), through a writer and a reader of
// the test's own in one participant.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <dds/dds.h>
#include <dds/ddsi/ddsi_serdata.h>

#include "fslam/client/ros2_messages.hpp"

namespace fslam::test {

// Encapsulation header included; empty when anything fails.
inline std::vector<std::uint8_t> cdr_of(dds_entity_t participant, const dds_topic_descriptor_t* desc,
                                        const void* sample, const std::string& topic_name) {
  std::vector<std::uint8_t> bytes;
  const dds_entity_t topic = dds_create_topic(participant, desc, topic_name.c_str(), nullptr, nullptr);
  if (topic < 0) return bytes;
  dds_qos_t* wq = client::ros2::make_qos(true, 1, true);
  dds_qos_t* rq = client::ros2::make_qos(true, 1, false);
  const dds_entity_t writer = dds_create_writer(participant, topic, wq, nullptr);
  const dds_entity_t reader = dds_create_reader(participant, topic, rq, nullptr);
  dds_delete_qos(wq);
  dds_delete_qos(rq);
  if (writer > 0 && reader > 0 && dds_write(writer, sample) == DDS_RETCODE_OK) {
    struct ddsi_serdata* sd = nullptr;
    dds_sample_info_t info;
    if (dds_takecdr(reader, &sd, 1, &info, DDS_ANY_STATE) == 1) {
      bytes.resize(ddsi_serdata_size(sd));
      ddsi_serdata_to_ser(sd, 0, bytes.size(), bytes.data());
      ddsi_serdata_unref(sd);
    }
  }
  dds_delete(reader);
  dds_delete(writer);
  dds_delete(topic);
  return bytes;
}

// Little-endian plain CDR laid out by hand, aligned from the byte after the encapsulation header.
class CdrLayout {
 public:
  CdrLayout() : bytes_{0x00, 0x01, 0x00, 0x00} {}  // CDR_LE
  template <class T>
  CdrLayout& put(T value) {
    while ((bytes_.size() - 4) % sizeof(T) != 0) bytes_.push_back(0);
    const auto* p = reinterpret_cast<const std::uint8_t*>(&value);
    bytes_.insert(bytes_.end(), p, p + sizeof(T));
    return *this;
  }
  CdrLayout& string(const std::string& s) {
    put<std::uint32_t>(static_cast<std::uint32_t>(s.size() + 1));
    bytes_.insert(bytes_.end(), s.begin(), s.end());
    bytes_.push_back(0);
    return *this;
  }
  CdrLayout& octets(const std::vector<std::uint8_t>& v) {
    put<std::uint32_t>(static_cast<std::uint32_t>(v.size()));
    bytes_.insert(bytes_.end(), v.begin(), v.end());
    return *this;
  }
  // Cyclone pads a sample to a multiple of 4 bytes (the padding is flagged in the encapsulation
  // options, bytes 2-3, as XCDR allows).
  std::vector<std::uint8_t> bytes() const { return bytes_; }

 private:
  std::vector<std::uint8_t> bytes_;
};

}  // namespace fslam::test
