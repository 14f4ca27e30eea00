// The server's wire conversions, all in one place: fslam_proto_* samples to core types and back
// (docs/protocol.md). Frames come in two steps: accept_frame makes the cheap checks and an owned
// copy of the payloads when a sample arrives, decode_frame decodes on the session's tracking
// thread, so that a frame the live policy skips is never decoded. Poses, views, result images
// and requests convert here too, and Replies writes the server's results and poses.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <dds/dds.h>
#include <opencv2/core/mat.hpp>

#include "fslam/client/dds.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/core/tracking/tracker.hpp"
#include "fslam/proto/types.h"
#include "fslam/server/map_export.hpp"

namespace fslam::server {

// ---- frames ----------------------------------------------------------------------------------

// Largest payload accepted per image: a 4K RGB frame, raw.
constexpr std::size_t kMaxImageBytes = 3840u * 2160u * 3u;
// Largest frame accepted, in pixels (4K): checked on the declared size and on the PNG or JPEG
// header before anything is decoded, so that a small payload cannot decode to gigabytes.
constexpr std::size_t kMaxFramePixels = 3840u * 2160u;

// The image size a PNG (IHDR) or JPEG (first SOF marker) payload declares in its header; false
// when the header cannot be read.
bool encoded_image_size(const std::uint8_t* data, std::size_t n, fslam_proto_ImageEncoding encoding,
                        std::uint32_t* width, std::uint32_t* height);

// One image payload as it came (RAW rows, PNG or JPEG), owned.
struct EncodedImage {
  fslam_proto_ImageEncoding encoding = fslam_proto_ENCODING_RAW;
  std::uint32_t width = 0, height = 0;
  std::uint8_t channels = 0, bytes_per_channel = 0;
  std::vector<std::uint8_t> data;
};

// A frame accepted for a session and not decoded yet.
struct EncodedFrame {
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;              // seconds
  core::PinholeCamera camera;          // of colour and depth
  float depth_scale = 1000.0f;         // raw depth units per metre
  EncodedImage colour;                 // RGB
  EncodedImage depth;                  // 16-bit, lossless
  std::optional<Eigen::Isometry3d> T_world_camera_gt;  // evaluation only
};

// The checks that need no decoding, then an owned copy into `out`. False with `why` on: zero,
// non-finite or implausible intrinsics, a non-positive or non-finite depth scale, a non-finite
// timestamp, sizes that disagree with the intrinsics, channels or bytes per channel that do not
// fit, a lossy depth encoding, an unknown encoding, an empty or oversized payload, a raw payload
// of the wrong length, a ground-truth pose that is not a finite rigid transform.
bool accept_frame(const fslam_proto_Frame& msg, EncodedFrame* out, std::string* why);

// Decodes colour (RAW RGB, PNG or JPEG) and depth (RAW or PNG, 16-bit; 0 and 65535 missing)
// into `frame` (depth in metres by depth_scale). False with `why` when a payload does not decode
// to its declared size and type.
bool decode_frame(const EncodedFrame& in, core::RgbdFrame* frame, std::string* why);

// accept_frame then decode_frame.
bool decode_frame(const fslam_proto_Frame& msg, core::RgbdFrame* frame, std::string* why);

// ---- poses, strings, sequences ---------------------------------------------------------------

// T (world <- camera) as translation and quaternion x, y, z, w.
void to_wire(const Eigen::Isometry3d& T, fslam_proto_Pose* pose);
// The pose a sample carries; false with `why` unless the translation is finite and the
// quaternion unit length (within 1e-3).
bool from_wire(const fslam_proto_Pose& pose, Eigen::Isometry3d* T, std::string* why);

// A sample's string, "" for a null one.
inline const char* text(const char* s) { return s != nullptr ? s : ""; }

// An owned copy of a float sequence of a sample.
template <class Sequence>
std::vector<float> floats(const Sequence& seq) {
  return seq._buffer == nullptr ? std::vector<float>{}
                                : std::vector<float>(seq._buffer, seq._buffer + seq._length);
}

// ---- requests --------------------------------------------------------------------------------

// An owned copy of a fslam/requests sample.
struct Query {
  std::string client, map_name, path;
  std::uint64_t request_id = 0;
  fslam_proto_RequestKind kind = fslam_proto_REQUEST_RENDER;
  fslam_proto_RenderRequest render{};
  // REQUEST_SEGMENT
  fslam_proto_SegmentMode segment_mode = fslam_proto_SEGMENT_PROMPTLESS;
  std::vector<float> points, boxes;
  std::string text;
  bool has_output_view = false;
  fslam_proto_RenderRequest output_view{};
  ExportRequest export_request;  // REQUEST_MAP_GAUSSIANS
  std::uint32_t refine_steps = 0;  // REQUEST_REFINE_MAP
};

Query query_of(const fslam_proto_Request& msg);

// ---- results ---------------------------------------------------------------------------------

// A number as error texts print it (%g: "120", "0.5", "1e+06").
std::string number_text(double x);

// One channel of a render result on the wire (proto CHANNEL_* bits).
struct ChannelImage {
  std::uint32_t channel = 0;  // one CHANNEL_* bit
  cv::Mat image;              // CV_8UC3 RGB, CV_16UC1 depth, or CV_8UC1 opacity
};
// The requested channels in bit order: colour RGB8; depth as expected camera-plane depth divided
// by opacity (0 where opacity < 0.5 or beyond 16 bits) times depth_scale, 16-bit; normals of
// the median depth as normals_to_rgb8 draws them; opacity 8-bit.
std::vector<ChannelImage> render_channels(const core::RenderResult& rendered,
                                          const core::PinholeCamera& camera,
                                          std::uint32_t channels, float depth_scale);
// PNG bytes of a CV_8UC1 / CV_8UC3 (RGB) / CV_16UC1 image; false when encoding fails.
bool encode_png(const cv::Mat& image, std::vector<std::uint8_t>* bytes);

// The bytes and image descriptions a result's images point into; must outlive the write.
struct ResultImages {
  std::vector<std::vector<std::uint8_t>> buffers;
  std::vector<fslam_proto_Image> images;
};
// Images as PNG on the wire (a result's or a view's): `images` points into `out`. False when one
// does not encode.
bool attach_images(const std::vector<cv::Mat>& mats, dds_sequence_fslam_proto_Image* images, ResultImages* out);

// The view a result was rendered from: its pose (world <- camera) and intrinsics.
void describe_view(const core::RenderView& view, const Eigen::Isometry3d& T_world_camera,
                   fslam_proto_Pose* pose, fslam_proto_Intrinsics* intrinsics);

// Renders `channels` of `map` in `view` (render_channels) and attaches them as PNG to `images`,
// which points into `out`: a render request's answer and a localise session's view alike.
bool render_to_wire(const core::Rasterizer& rasterizer, const core::GaussianMap& map,
                    const core::RenderView& view, std::uint32_t channels, float depth_scale,
                    dds_sequence_fslam_proto_Image* images, ResultImages* out, std::string* why);

// The server's writers of results and poses, and its views topic (they must outlive it), shared
// by sessions and queries.
class Replies {
 public:
  Replies(dds_entity_t pose_writer, dds_entity_t result_writer, const client::Entity& participant,
          const client::Entity& views_topic)
      : pose_writer_(pose_writer), result_writer_(result_writer), participant_(participant), views_topic_(views_topic) {}
  // A result without images: OK when `error` is empty, else ERROR with it.
  void result(const char* client, std::uint64_t request_id, const std::string& map_name,
              const std::string& error) const;
  void result(const fslam_proto_Result& result) const;
  // A tracked frame's pose, with its stage times in milliseconds.
  void pose(const std::string& session, std::uint64_t frame_id, double timestamp,
            const core::TrackingResult& tracked, double decode_ms, double queue_ms,
            double track_ms) const;
  // A frame accepted and then not tracked under the live policy, on the pose stream.
  void skip(const std::string& session, std::uint64_t frame_id, double timestamp,
            const std::string& reason) const;
  // A writer of one localise session's renders on <prefix>/views (newest delivery: a newer view
  // replaces one not yet delivered), deleted with the session: a keep-last writer keeps the
  // newest sample of every instance it wrote for its life, and a view is a whole render.
  client::Entity view_writer() const;

 private:
  dds_entity_t pose_writer_, result_writer_;
  const client::Entity& participant_;
  const client::Entity& views_topic_;
};

}  // namespace fslam::server
