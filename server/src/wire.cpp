#include "fslam/server/wire.hpp"

#include <cstdio>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <utility>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/server/render_images.hpp"

namespace fslam::server {

// ---- frames ----------------------------------------------------------------------------------

namespace {

// Focal lengths a real camera can have at the frame's size: a field of view between about 0.1
// and 179 degrees. Outside, the projection math overflows or degenerates.
bool plausible_focal(double f, int size) {
  return f >= 0.005 * size && f <= 1000.0 * size;
}

// The encoding as the integer it is on the wire. Reading an enum object that holds a value outside
// its enumerators as the enum is undefined behaviour in C++, and a peer's bytes (or an in-process
// caller's) can hold any value; found by tests/fuzz/frame_fuzz.cpp.
std::uint32_t encoding_value(const fslam_proto_Image& image) {
  std::uint32_t value = 0;
  static_assert(sizeof(image.encoding) == sizeof(value), "the IDL enum is 32 bits");
  std::memcpy(&value, &image.encoding, sizeof value);
  return value;
}

bool accept_image(const fslam_proto_Image& image, int channels, int bytes_per_channel,
                  const char* what, EncodedImage* out, std::string* why) {
  const std::string name(what);
  const std::size_t n = image.data._length;
  if (n == 0 || image.data._buffer == nullptr) return core::fail(why, name + ": empty payload");
  if (n > kMaxImageBytes) return core::fail(why, name + ": payload over the size limit");
  const std::uint32_t encoding = encoding_value(image);
  if (encoding != fslam_proto_ENCODING_RAW && encoding != fslam_proto_ENCODING_PNG &&
      encoding != fslam_proto_ENCODING_JPEG) {
    return core::fail(why, name + ": unknown encoding " + std::to_string(encoding));
  }
  if (image.channels != channels || image.bytes_per_channel != bytes_per_channel) {
    return core::fail(why, name + ": expected " + std::to_string(channels) + " channel(s) of " +
                               std::to_string(bytes_per_channel) + " byte(s), got " +
                               std::to_string(image.channels) + " of " +
                               std::to_string(image.bytes_per_channel));
  }
  if (image.encoding == fslam_proto_ENCODING_RAW) {
    const std::size_t expected = static_cast<std::size_t>(image.width) * image.height * channels *
                                 bytes_per_channel;
    if (n != expected) {
      return core::fail(why, name + ": raw payload of " + std::to_string(n) + " bytes, expected " +
                                 std::to_string(expected));
    }
  } else {
    // What the decoder would allocate, from the header, before it runs.
    std::uint32_t w = 0, h = 0;
    if (!encoded_image_size(image.data._buffer, n, image.encoding, &w, &h)) {
      return core::fail(why, name + ": the " + (image.encoding == fslam_proto_ENCODING_PNG ? "PNG" : "JPEG") +
                                 " header cannot be read");
    }
    if (w != image.width || h != image.height) {
      return core::fail(why, name + ": the payload's header says " + std::to_string(w) + "x" +
                                 std::to_string(h) + ", the frame " + std::to_string(image.width) + "x" +
                                 std::to_string(image.height));
    }
  }
  out->encoding = image.encoding;
  out->width = image.width;
  out->height = image.height;
  out->channels = image.channels;
  out->bytes_per_channel = image.bytes_per_channel;
  out->data.assign(image.data._buffer, image.data._buffer + n);
  return true;
}

bool decode_image(const EncodedImage& image, int cv_type, const char* what, cv::Mat* out,
                  std::string* why) {
  const std::string name(what);
  if (image.encoding == fslam_proto_ENCODING_RAW) {
    *out = cv::Mat(static_cast<int>(image.height), static_cast<int>(image.width), cv_type);
    std::memcpy(out->data, image.data.data(), image.data.size());
    return true;
  }
  const cv::Mat bytes(1, static_cast<int>(image.data.size()), CV_8UC1,
                      const_cast<std::uint8_t*>(image.data.data()));
  cv::Mat decoded = cv::imdecode(bytes, cv_type == CV_16UC1 ? cv::IMREAD_UNCHANGED : cv::IMREAD_COLOR);
  if (decoded.empty()) return core::fail(why, name + ": cannot decode the payload");
  if (decoded.type() != cv_type) return core::fail(why, name + ": wrong pixel type after decoding");
  if (decoded.cols != static_cast<int>(image.width) || decoded.rows != static_cast<int>(image.height)) {
    return core::fail(why, name + ": decoded size differs from the declared one");
  }
  if (cv_type == CV_8UC3) cv::cvtColor(decoded, decoded, cv::COLOR_BGR2RGB);
  *out = decoded;
  return true;
}

}  // namespace

bool encoded_image_size(const std::uint8_t* d, std::size_t n, fslam_proto_ImageEncoding encoding,
                        std::uint32_t* width, std::uint32_t* height) {
  auto be16 = [&](std::size_t i) { return static_cast<std::uint32_t>(d[i]) << 8 | d[i + 1]; };
  if (encoding == fslam_proto_ENCODING_PNG) return core::png_declared_size(d, n, width, height);
  if (encoding == fslam_proto_ENCODING_JPEG) {
    // Markers from SOI on, each with a 16-bit length, up to the first start-of-frame.
    if (n < 4 || d[0] != 0xFF || d[1] != 0xD8) return false;
    std::size_t i = 2;
    while (i + 4 <= n) {
      if (d[i] != 0xFF) return false;
      const std::uint8_t marker = d[i + 1];
      if (marker == 0xFF) { ++i; continue; }  // fill byte
      if (marker == 0xD8 || (marker >= 0xD0 && marker <= 0xD7) || marker == 0x01) { i += 2; continue; }
      const std::size_t length = be16(i + 2);
      if (length < 2) return false;
      const bool sof = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
      if (sof) {
        if (i + 9 > n) return false;
        *height = be16(i + 5);
        *width = be16(i + 7);
        return true;
      }
      i += 2 + length;
    }
    return false;
  }
  return false;
}

bool accept_frame(const fslam_proto_Frame& msg, EncodedFrame* out, std::string* why) {
  const fslam_proto_Intrinsics& k = msg.intrinsics;
  core::PinholeCamera camera{k.fx, k.fy, k.cx, k.cy, static_cast<int>(k.width),
                             static_cast<int>(k.height)};
  std::string reason;
  if (!camera.is_valid(&reason)) return core::fail(why, "intrinsics: " + reason);
  if (static_cast<std::size_t>(k.width) * k.height > kMaxFramePixels) {
    return core::fail(why, "frame of " + std::to_string(k.width) + "x" + std::to_string(k.height) +
                               " pixels is over the limit of " + std::to_string(kMaxFramePixels) + " (4K)");
  }
  if (!plausible_focal(camera.fx, camera.width) || !plausible_focal(camera.fy, camera.height)) {
    return core::fail(why, "intrinsics: focal lengths fx=" + std::to_string(camera.fx) + ", fy=" +
                               std::to_string(camera.fy) + " are implausible for a " +
                               std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                               " image");
  }
  if (!(msg.depth_scale > 0) || !std::isfinite(msg.depth_scale)) {
    return core::fail(why, "depth scale must be positive and finite");
  }
  if (!std::isfinite(msg.timestamp)) return core::fail(why, "timestamp must be finite");
  if (msg.frame_id > static_cast<std::uint64_t>(INT64_MAX)) return core::fail(why, "frame id must be below 2^63");
  if (encoding_value(msg.depth) == fslam_proto_ENCODING_JPEG) return core::fail(why, "depth: JPEG is lossy; send RAW or PNG");
  if (msg.colour.width != k.width || msg.colour.height != k.height || msg.depth.width != k.width ||
      msg.depth.height != k.height) {
    return core::fail(why, "colour and depth must have the intrinsics' size");
  }
  out->T_world_camera_gt.reset();
  if (msg.has_gt_pose) {
    Eigen::Isometry3d T;
    if (!from_wire(msg.gt_pose, &T, &reason)) return core::fail(why, "ground-truth " + reason);
    out->T_world_camera_gt = T;
  }
  if (!accept_image(msg.colour, 3, 1, "colour", &out->colour, why) ||
      !accept_image(msg.depth, 1, 2, "depth", &out->depth, why)) {
    return false;
  }
  out->frame_id = msg.frame_id;
  out->timestamp = msg.timestamp;
  out->camera = camera;
  out->depth_scale = msg.depth_scale;
  return true;
}

bool decode_frame(const EncodedFrame& in, core::RgbdFrame* frame, std::string* why) {
  cv::Mat colour, depth_raw;
  if (!decode_image(in.colour, CV_8UC3, "colour", &colour, why) ||
      !decode_image(in.depth, CV_16UC1, "depth", &depth_raw, why)) {
    return false;
  }
  cv::Mat depth;
  depth_raw.convertTo(depth, CV_32FC1, 1.0 / in.depth_scale);
  depth.setTo(0.0f, depth_raw == 65535);
  frame->id = static_cast<std::int64_t>(in.frame_id);
  frame->timestamp = in.timestamp;
  frame->colour = colour;
  frame->depth = depth;
  frame->camera = in.camera;
  frame->T_world_camera_gt = in.T_world_camera_gt;
  return true;
}

bool decode_frame(const fslam_proto_Frame& msg, core::RgbdFrame* frame, std::string* why) {
  EncodedFrame encoded;
  return accept_frame(msg, &encoded, why) && decode_frame(encoded, frame, why);
}

// ---- poses ----------------------------------------------------------------------------------

void to_wire(const Eigen::Isometry3d& T, fslam_proto_Pose* pose) {
  const Eigen::Quaterniond q(T.rotation());
  for (int k = 0; k < 3; ++k) pose->translation[k] = T.translation()[k];
  pose->rotation[0] = q.x();
  pose->rotation[1] = q.y();
  pose->rotation[2] = q.z();
  pose->rotation[3] = q.w();
}

bool from_wire(const fslam_proto_Pose& pose, Eigen::Isometry3d* T, std::string* why) {
  const Eigen::Quaterniond q(pose.rotation[3], pose.rotation[0], pose.rotation[1], pose.rotation[2]);
  const Eigen::Vector3d t(pose.translation[0], pose.translation[1], pose.translation[2]);
  if (!t.allFinite() || !std::isfinite(q.norm()) || std::abs(q.norm() - 1.0) > 1e-3) {
    return core::fail(why, "pose: translation must be finite and the quaternion unit length");
  }
  T->setIdentity();
  T->linear() = q.normalized().toRotationMatrix();
  T->translation() = t;
  return true;
}

// ---- requests --------------------------------------------------------------------------------

Query query_of(const fslam_proto_Request& msg) {
  Query query;
  query.client = text(msg.client);
  query.request_id = msg.request_id;
  query.map_name = text(msg.map_name);
  query.path = text(msg.path);
  query.kind = msg.kind;
  query.render = msg.render;
  if (msg.kind == fslam_proto_REQUEST_SEGMENT) {
    const fslam_proto_SegmentRequest& seg = msg.segment;
    query.segment_mode = seg.mode;
    query.points = floats(seg.points);
    query.boxes = floats(seg.boxes);
    query.text = text(seg.text);
    query.has_output_view = seg.has_output_view;
    query.output_view = seg.output_view;
  }
  if (msg.kind == fslam_proto_REQUEST_MAP_GAUSSIANS) query.export_request = export_request_of(msg);
  if (msg.kind == fslam_proto_REQUEST_REFINE_MAP) query.refine_steps = msg.refine_steps;
  return query;
}

// ---- results ---------------------------------------------------------------------------------

std::vector<ChannelImage> render_channels(const core::RenderResult& rendered,
                                          const core::PinholeCamera& camera,
                                          std::uint32_t channels, float depth_scale) {
  std::vector<ChannelImage> out;
  if (channels & fslam_proto_CHANNEL_COLOUR) {
    out.push_back({fslam_proto_CHANNEL_COLOUR, colour_to_rgb8(rendered.colour)});
  }
  if (channels & fslam_proto_CHANNEL_DEPTH) {
    const core::PlanarImage& d = rendered.depth;
    cv::Mat depth(d.height, d.width, CV_16UC1, cv::Scalar(0));
    for (int v = 0; v < d.height; ++v)
      for (int u = 0; u < d.width; ++u) {
        const float alpha = rendered.alpha.at(0, v, u);
        if (alpha < 0.5f) continue;
        const double raw = std::round(d.at(0, v, u) / alpha * depth_scale);
        if (raw > 0 && raw < 65535) depth.at<std::uint16_t>(v, u) = static_cast<std::uint16_t>(raw);
      }
    out.push_back({fslam_proto_CHANNEL_DEPTH, depth});
  }
  if (channels & fslam_proto_CHANNEL_NORMALS) {
    out.push_back({fslam_proto_CHANNEL_NORMALS, normals_to_rgb8(rendered.median_depth, camera.intrinsics())});
  }
  if (channels & fslam_proto_CHANNEL_OPACITY) {
    cv::Mat grey;
    plane_to_mat(rendered.alpha, 0).convertTo(grey, CV_8U, 255.0);
    out.push_back({fslam_proto_CHANNEL_OPACITY, grey});
  }
  return out;
}

bool encode_png(const cv::Mat& image, std::vector<std::uint8_t>* bytes) {
  cv::Mat file_order = image;
  if (image.type() == CV_8UC3) cv::cvtColor(image, file_order, cv::COLOR_RGB2BGR);
  return cv::imencode(".png", file_order, *bytes, {cv::IMWRITE_PNG_COMPRESSION, 1});
}

bool attach_images(const std::vector<cv::Mat>& mats, dds_sequence_fslam_proto_Image* sequence, ResultImages* out) {
  std::vector<std::vector<std::uint8_t>>& buffers = out->buffers;
  std::vector<fslam_proto_Image>& images = out->images;
  buffers.resize(mats.size());
  images.resize(mats.size());
  for (std::size_t i = 0; i < mats.size(); ++i) {
    const cv::Mat& image = mats[i];
    if (!encode_png(image, &buffers[i])) return false;
    images[i] = {fslam_proto_ENCODING_PNG,
                 static_cast<std::uint32_t>(image.cols),
                 static_cast<std::uint32_t>(image.rows),
                 static_cast<std::uint8_t>(image.channels()),
                 static_cast<std::uint8_t>(image.elemSize1()),
                 {static_cast<std::uint32_t>(buffers[i].size()),
                  static_cast<std::uint32_t>(buffers[i].size()), buffers[i].data(), false}};
  }
  *sequence = {static_cast<std::uint32_t>(images.size()), static_cast<std::uint32_t>(images.size()),
               images.data(), false};
  return true;
}

void describe_view(const core::RenderView& view, const Eigen::Isometry3d& T_world_camera,
                   fslam_proto_Pose* pose, fslam_proto_Intrinsics* intrinsics) {
  to_wire(T_world_camera, pose);
  *intrinsics = {static_cast<float>(view.camera.fx), static_cast<float>(view.camera.fy),
                        static_cast<float>(view.camera.cx), static_cast<float>(view.camera.cy),
                        static_cast<std::uint32_t>(view.camera.width),
                        static_cast<std::uint32_t>(view.camera.height)};
}

void Replies::result(const char* client, std::uint64_t request_id, const std::string& map_name,
                     const std::string& error) const {
  fslam_proto_Result r{};
  std::string c = text(client), m = map_name, e = error, empty;
  r.client = c.data();
  r.request_id = request_id;
  r.map_name = m.data();
  r.status = error.empty() ? fslam_proto_RESULT_OK : fslam_proto_RESULT_ERROR;
  r.error = e.data();
  r.path = empty.data();
  dds_write(result_writer_, &r);
}

bool render_to_wire(const core::Rasterizer& rasterizer, const core::GaussianMap& map,
                    const core::RenderView& view, std::uint32_t channels, float depth_scale,
                    dds_sequence_fslam_proto_Image* images, ResultImages* out, std::string* why) {
  core::RenderSettings settings;
  settings.features = false;
  core::RenderResult rendered;
  if (!rasterizer.forward(map, view, settings, &rendered, why)) return false;
  std::vector<cv::Mat> mats;
  for (ChannelImage& channel : render_channels(rendered, view.camera, channels, depth_scale)) {
    mats.push_back(channel.image);
  }
  if (!attach_images(mats, images, out)) return core::fail(why, "render: cannot encode a result image");
  return true;
}

void Replies::result(const fslam_proto_Result& result) const { dds_write(result_writer_, &result); }

client::Entity Replies::view_writer() const {
  return client::make_writer(participant_, views_topic_, client::Delivery::newest);
}

void Replies::pose(const std::string& session, std::uint64_t frame_id, double timestamp,
                   const core::TrackingResult& tracked, double decode_ms, double queue_ms,
                   double track_ms) const {
  fslam_proto_PoseStamped pose{};
  std::string name = session;
  pose.session = name.data();
  pose.frame_id = frame_id;
  pose.timestamp = timestamp;
  to_wire(tracked.T_world_camera, &pose.T_world_camera);
  pose.state = static_cast<fslam_proto_TrackingState>(static_cast<int>(tracked.state));
  pose.keyframe = tracked.keyframe;
  pose.decode_ms = static_cast<float>(decode_ms);
  pose.queue_ms = static_cast<float>(queue_ms);
  pose.track_ms = static_cast<float>(track_ms);
  std::string note = tracked.message;
  pose.note = note.data();
  dds_write(pose_writer_, &pose);
}

void Replies::skip(const std::string& session, std::uint64_t frame_id, double timestamp,
                   const std::string& reason) const {
  fslam_proto_PoseStamped pose{};
  std::string name = session, note = reason;
  pose.session = name.data();
  pose.frame_id = frame_id;
  pose.timestamp = timestamp;
  pose.T_world_camera.rotation[3] = 1.0;
  pose.state = fslam_proto_TRACKING_SKIPPED;
  pose.note = note.data();
  dds_write(pose_writer_, &pose);
}

std::string number_text(double x) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", x);
  return text;
}

}  // namespace fslam::server
