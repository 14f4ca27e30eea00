#include "fslam/client/ros2_messages.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

namespace fslam::client::ros2 {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

// Reads plain CDR: values aligned to their size, counted from the first byte after the
// encapsulation header; either byte order.
class CdrReader {
 public:
  CdrReader(const std::uint8_t* bytes, std::size_t n) : base_(bytes + 4), n_(n < 4 ? 0 : n - 4) {
    ok_ = n >= 4 && bytes[0] == 0 && (bytes[1] == 0 || bytes[1] == 1);
    big_ = ok_ && bytes[1] == 0;
  }
  bool ok() const { return ok_; }
  template <class T>
  T get() {
    T value{};
    align(sizeof(T));
    if (!take(sizeof(T))) return value;
    std::uint8_t raw[sizeof(T)];
    std::memcpy(raw, base_ + at_ - sizeof(T), sizeof(T));
    if (big_) std::reverse(raw, raw + sizeof(T));
    std::memcpy(&value, raw, sizeof(T));
    return value;
  }
  std::string string() {
    const std::uint32_t length = get<std::uint32_t>();  // with the terminating NUL
    if (!ok_ || length == 0 || !take(length)) return ok_ = false, std::string();
    return std::string(reinterpret_cast<const char*>(base_ + at_ - length), length - 1);
  }
  // A sequence<uint8>: its bytes in place.
  const std::uint8_t* octets(std::size_t* size) {
    const std::uint32_t length = get<std::uint32_t>();
    *size = length;
    if (!ok_ || !take(length)) return ok_ = false, nullptr;
    return base_ + at_ - length;
  }
  Stamp stamp() {
    Stamp s;
    s.sec = get<std::int32_t>();
    s.nanosec = get<std::uint32_t>();
    return s;
  }

 private:
  void align(std::size_t a) { at_ = (at_ + a - 1) / a * a; }
  bool take(std::size_t k) {
    if (!ok_ || at_ > n_ || k > n_ - at_) return ok_ = false;
    at_ += k;
    return true;
  }
  const std::uint8_t* base_;
  std::size_t n_, at_ = 0;
  bool ok_ = false, big_ = false;
};

bool truncated(std::string* why, const char* type) {
  return fail(why, std::string(type) + ": truncated or malformed CDR record");
}

bool rows_fit(const ImageMsg& msg, std::size_t bytes_per_pixel, std::string* why) {
  const std::size_t row = static_cast<std::size_t>(msg.width) * bytes_per_pixel;
  if (msg.width == 0 || msg.height == 0) return fail(why, "image of size 0");
  if (msg.step < row) {
    return fail(why, "image step " + std::to_string(msg.step) + " is under a row of " +
                         std::to_string(msg.width) + " " + msg.encoding + " pixels (" +
                         std::to_string(row) + " bytes)");
  }
  const std::size_t expected = static_cast<std::size_t>(msg.step) * msg.height;
  if (msg.data == nullptr || msg.size < expected) {
    return fail(why, msg.encoding + " image of " + std::to_string(msg.width) + "x" +
                         std::to_string(msg.height) + " (step " + std::to_string(msg.step) +
                         ") needs " + std::to_string(expected) + " bytes, has " +
                         std::to_string(msg.size));
  }
  return true;
}

bool host_is_big_endian() {
  const std::uint16_t one = 1;
  std::uint8_t first;
  std::memcpy(&first, &one, 1);
  return first == 0;
}

}  // namespace

std::string dds_topic(const std::string& ros_topic) {
  std::string name = ros_topic;
  while (!name.empty() && name.front() == '/') name.erase(name.begin());
  return "rt/" + name;
}

dds_qos_t* make_qos(bool reliable, int depth, bool writer) {
  dds_qos_t* qos = dds_create_qos();
  dds_qset_reliability(qos, reliable ? DDS_RELIABILITY_RELIABLE : DDS_RELIABILITY_BEST_EFFORT, DDS_SECS(1));
  dds_qset_durability(qos, DDS_DURABILITY_VOLATILE);
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, depth);
  if (writer) {
    const dds_data_representation_id_t xcdr1[] = {DDS_DATA_REPRESENTATION_XCDR1};
    dds_qset_data_representation(qos, 1, xcdr1);
  } else {
    const dds_data_representation_id_t both[] = {DDS_DATA_REPRESENTATION_XCDR1, DDS_DATA_REPRESENTATION_XCDR2};
    dds_qset_data_representation(qos, 2, both);
  }
  return qos;
}

Stamp Stamp::from_seconds(double seconds) {
  Stamp s;
  const double whole = std::floor(seconds);
  s.sec = static_cast<std::int32_t>(whole);
  s.nanosec = static_cast<std::uint32_t>(std::min(999999999.0, std::round((seconds - whole) * 1e9)));
  return s;
}

bool parse_image(const std::uint8_t* bytes, std::size_t n, ImageMsg* msg, std::string* why) {
  CdrReader r(bytes, n);
  if (!r.ok()) return fail(why, "sensor_msgs/msg/Image: not a CDR record (encapsulation header)");
  msg->stamp = r.stamp();
  msg->frame_id = r.string();
  msg->height = r.get<std::uint32_t>();
  msg->width = r.get<std::uint32_t>();
  msg->encoding = r.string();
  msg->is_bigendian = r.get<std::uint8_t>();
  msg->step = r.get<std::uint32_t>();
  msg->data = r.octets(&msg->size);
  return r.ok() || truncated(why, "sensor_msgs/msg/Image");
}

bool parse_compressed_image(const std::uint8_t* bytes, std::size_t n, CompressedImageMsg* msg,
                            std::string* why) {
  CdrReader r(bytes, n);
  if (!r.ok()) return fail(why, "sensor_msgs/msg/CompressedImage: not a CDR record (encapsulation header)");
  msg->stamp = r.stamp();
  msg->frame_id = r.string();
  msg->format = r.string();
  msg->data = r.octets(&msg->size);
  return r.ok() || truncated(why, "sensor_msgs/msg/CompressedImage");
}

bool parse_camera_info(const std::uint8_t* bytes, std::size_t n, CameraInfoMsg* msg, std::string* why) {
  CdrReader r(bytes, n);
  if (!r.ok()) return fail(why, "sensor_msgs/msg/CameraInfo: not a CDR record (encapsulation header)");
  msg->stamp = r.stamp();
  msg->frame_id = r.string();
  msg->height = r.get<std::uint32_t>();
  msg->width = r.get<std::uint32_t>();
  msg->distortion_model = r.string();
  const std::uint32_t nd = r.get<std::uint32_t>();
  if (!r.ok() || nd > 64) return truncated(why, "sensor_msgs/msg/CameraInfo");
  msg->d.resize(nd);
  for (double& d : msg->d) d = r.get<double>();
  for (double& k : msg->k) k = r.get<double>();
  // R, P, binning and the region of interest follow; featureslam reads the raw image's K only.
  return r.ok() || truncated(why, "sensor_msgs/msg/CameraInfo");
}

bool colour_to_rgb8(const ImageMsg& msg, std::vector<std::uint8_t>* rgb, std::string* why) {
  const std::string& e = msg.encoding;
  const bool mono = e == "mono8", bgr = e == "bgr8";
  if (e != "rgb8" && !bgr && !mono) {
    return fail(why, "colour: unknown encoding '" + e + "' (rgb8, bgr8 or mono8)");
  }
  if (!rows_fit(msg, mono ? 1 : 3, why)) return fail(why, "colour: " + *why);
  rgb->resize(static_cast<std::size_t>(msg.width) * msg.height * 3);
  std::uint8_t* out = rgb->data();
  for (std::uint32_t v = 0; v < msg.height; ++v) {
    const std::uint8_t* row = msg.data + static_cast<std::size_t>(v) * msg.step;
    for (std::uint32_t u = 0; u < msg.width; ++u, out += 3) {
      if (mono) {
        out[0] = out[1] = out[2] = row[u];
      } else if (bgr) {
        out[0] = row[3 * u + 2];
        out[1] = row[3 * u + 1];
        out[2] = row[3 * u];
      } else {
        std::memcpy(out, row + 3 * u, 3);
      }
    }
  }
  return true;
}

bool depth_to_u16(const ImageMsg& msg, std::vector<std::uint16_t>* depth, float* depth_scale,
                  std::string* why) {
  const std::string& e = msg.encoding;
  const bool mm = e == "16UC1" || e == "mono16", metres = e == "32FC1";
  if (!mm && !metres) return fail(why, "depth: unknown encoding '" + e + "' (16UC1 in mm or 32FC1 in m)");
  if (!rows_fit(msg, mm ? 2 : 4, why)) return fail(why, "depth: " + *why);
  const bool swap = (msg.is_bigendian != 0) != host_is_big_endian();
  depth->resize(static_cast<std::size_t>(msg.width) * msg.height);
  constexpr float kScale = 5000.0f;  // 32FC1 kept at 0.2 mm, up to 13.1 m
  *depth_scale = mm ? 1000.0f : kScale;
  std::uint16_t* out = depth->data();
  for (std::uint32_t v = 0; v < msg.height; ++v) {
    const std::uint8_t* row = msg.data + static_cast<std::size_t>(v) * msg.step;
    for (std::uint32_t u = 0; u < msg.width; ++u, ++out) {
      if (mm) {
        std::uint8_t b[2] = {row[2 * u], row[2 * u + 1]};
        if (swap) std::swap(b[0], b[1]);
        std::memcpy(out, b, 2);
      } else {
        std::uint8_t b[4];
        std::memcpy(b, row + 4 * u, 4);
        if (swap) std::reverse(b, b + 4);
        float z;
        std::memcpy(&z, b, 4);
        const float units = z * kScale;
        *out = std::isfinite(units) && units > 0.0f && units < 65535.0f
                   ? static_cast<std::uint16_t>(std::lround(units))
                   : 0;
      }
    }
  }
  return true;
}

bool compressed_encoding(const CompressedImageMsg& msg, PayloadEncoding* encoding, std::string* why) {
  // image_transport writes "<raw encoding>; <jpeg|png> compressed <encoding>"; plain "jpeg" too.
  const std::size_t jpeg = msg.format.find("jpeg"), png = msg.format.find("png");
  if (jpeg == std::string::npos && png == std::string::npos) {
    return fail(why, "compressed colour: unknown format '" + msg.format + "' (jpeg or png)");
  }
  *encoding = jpeg < png ? PayloadEncoding::jpeg : PayloadEncoding::png;
  return true;
}

bool intrinsics_of(const CameraInfoMsg& msg, CameraIntrinsics* k, std::string* why) {
  const double* K = msg.k;
  const bool pinhole = K[1] == 0 && K[3] == 0 && K[6] == 0 && K[7] == 0 && K[8] == 1;
  if (!pinhole || !(K[0] > 0) || !(K[4] > 0) || msg.width == 0 || msg.height == 0) {
    return fail(why, "camera info: K must be [fx 0 cx; 0 fy cy; 0 0 1] with fx, fy > 0, and the size "
                     "non-zero (a calibrated camera)");
  }
  *k = {static_cast<float>(K[0]), static_cast<float>(K[4]), static_cast<float>(K[2]),
        static_cast<float>(K[5]), msg.width, msg.height};
  return true;
}

StampPairer::StampPairer(double tolerance_s, std::size_t keep)
    : tolerance_s_(tolerance_s), keep_(std::max<std::size_t>(1, keep)) {
  latest_[0] = latest_[1] = -std::numeric_limits<double>::infinity();
}

StampPairer::Outcome StampPairer::unpaired(Stream stream, const Waiting& w, const std::string& reason) const {
  Outcome o;
  o.stream = stream;
  o.id = w.id;
  char text[160];
  std::snprintf(text, sizeof text, "%s stamped %.6f s: %s", stream == Stream::colour ? "colour" : "depth",
                w.stamp, reason.c_str());
  o.why = text;
  return o;
}

std::vector<StampPairer::Outcome> StampPairer::add(Stream stream, std::uint64_t id, double stamp) {
  std::vector<Outcome> out;
  const int s = stream == Stream::colour ? 0 : 1, o = 1 - s;
  latest_[s] = std::max(latest_[s], stamp);
  auto& others = waiting_[o];
  auto best = others.end();
  for (auto it = others.begin(); it != others.end(); ++it) {
    if (std::abs(it->stamp - stamp) <= tolerance_s_ &&
        (best == others.end() || std::abs(it->stamp - stamp) < std::abs(best->stamp - stamp))) {
      best = it;
    }
  }
  if (best != others.end()) {
    Outcome pair;
    pair.paired = true;
    pair.colour = s == 0 ? id : best->id;
    pair.depth = s == 0 ? best->id : id;
    out.push_back(pair);
    others.erase(best);
  } else {
    waiting_[s].push_back({id, stamp});
    if (waiting_[s].size() > keep_) {
      out.push_back(unpaired(stream, waiting_[s].front(), "dropped, more than " + std::to_string(keep_) +
                                                              " messages waiting for a partner"));
      waiting_[s].pop_front();
    }
  }
  char tolerance[32];
  std::snprintf(tolerance, sizeof tolerance, "%g ms", tolerance_s_ * 1e3);
  for (int x = 0; x < 2; ++x) {
    auto& w = waiting_[x];
    while (!w.empty() && latest_[1 - x] > w.front().stamp + tolerance_s_) {
      out.push_back(unpaired(x == 0 ? Stream::colour : Stream::depth, w.front(),
                             std::string("no ") + (x == 0 ? "depth" : "colour") + " within " + tolerance));
      w.pop_front();
    }
  }
  return out;
}

std::vector<StampPairer::Outcome> StampPairer::flush() {
  std::vector<Outcome> out;
  for (int x = 0; x < 2; ++x) {
    for (const Waiting& w : waiting_[x]) {
      out.push_back(unpaired(x == 0 ? Stream::colour : Stream::depth, w, "never paired (end of input)"));
    }
    waiting_[x].clear();
  }
  return out;
}

}  // namespace fslam::client::ros2
