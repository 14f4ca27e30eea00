// Fuzz target: a request and a session control as a peer can publish them -> the checks made
// before anything is rendered or written (server/include/fslam/server/request_checks.hpp, wire.hpp,
// map_files.hpp): map and session names, save/load folders, poses, intrinsics and the pixel
// limit, render channels, a session's views, segment modes and prompts. Every refusal says why,
// and what is accepted holds: folders stay under map_dir, a valid map name is a valid folder,
// cameras are valid and within the limit, prompts lie in the view. Input layout: the fields in
// the order read below (fuzz_support.hpp's little-endian reader), then three strings, each a
// length byte and its bytes: map name, path, text. tests/fuzz/make_seeds.cpp writes seeds.
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "fslam/server/map_files.hpp"
#include "fslam/server/request_checks.hpp"
#include "fslam/server/wire.hpp"
#include "fuzz_support.hpp"

namespace {

constexpr std::uint64_t kMaxPixels = 4096ull * 4096ull;
constexpr std::size_t kMaxPrompts = 64;
const std::string kMapDir = "/srv/fslam/maps";

void refused_with_reason(bool ok, const std::string& why) {
  if (!ok && why.empty()) __builtin_trap();  // every refusal says why
}

void read_view(fslam::fuzz::ByteReader& in, fslam_proto_RenderRequest* r) {
  r->from_frame = (in.take<std::uint8_t>() & 1u) != 0;
  r->frame_id = in.take<std::uint64_t>();
  for (double& t : r->T_world_camera.translation) t = in.take<double>();
  for (double& q : r->T_world_camera.rotation) q = in.take<double>();
  r->intrinsics.fx = in.take<float>();
  r->intrinsics.fy = in.take<float>();
  r->intrinsics.cx = in.take<float>();
  r->intrinsics.cy = in.take<float>();
  r->intrinsics.width = in.take<std::uint16_t>();
  r->intrinsics.height = in.take<std::uint16_t>();
  r->channels = in.take<std::uint8_t>();
  r->depth_scale = in.take<float>();
}

std::vector<float> read_floats(fslam::fuzz::ByteReader& in) {
  std::vector<float> values(in.take<std::uint8_t>());
  for (float& v : values) v = in.take<float>();
  return values;
}

void point_at(std::vector<float>& values, dds_sequence_float* seq) {
  seq->_buffer = values.data();
  seq->_length = seq->_maximum = static_cast<std::uint32_t>(values.size());
  seq->_release = false;
}

// The view's camera, when its pose and intrinsics pass.
bool check_view(const fslam_proto_RenderRequest& r, fslam::core::PinholeCamera* camera) {
  std::string why;
  Eigen::Isometry3d T;
  const bool pose_ok = fslam::server::from_wire(r.T_world_camera, &T, &why);
  refused_with_reason(pose_ok, why);
  if (pose_ok) {
    const Eigen::Matrix3d R = T.linear();
    if (!T.matrix().allFinite() || !(R * R.transpose()).isIdentity(1e-6)) __builtin_trap();
  }
  const fslam::core::PinholeCamera map_camera{500.0, 500.0, 319.5, 239.5, 640, 480};
  const bool camera_ok = fslam::server::render_camera(r.intrinsics, map_camera, "fuzz", kMaxPixels, camera, &why);
  refused_with_reason(camera_ok, why);
  if (camera_ok) {
    std::string reason;
    if (!camera->is_valid(&reason)) __builtin_trap();
    if (static_cast<std::uint64_t>(camera->width) * static_cast<std::uint64_t>(camera->height) > kMaxPixels) {
      __builtin_trap();
    }
  }
  return pose_ok && camera_ok;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace fslam::server;
  fslam::fuzz::ByteReader in(data, size);
  fslam_proto_Request msg{};
  // Enum fields within their types' range (Cyclone drops a sample whose enum value lies past the
  // last enumerator; a C++ load of one outside the range is undefined): 8 request kinds, 3 unknown.
  msg.kind = static_cast<fslam_proto_RequestKind>(in.take<std::uint8_t>() & 7u);
  msg.request_id = in.take<std::uint64_t>();
  read_view(in, &msg.render);
  msg.segment.mode = static_cast<fslam_proto_SegmentMode>(in.take<std::uint8_t>() & 3u);
  msg.segment.has_output_view = (in.take<std::uint8_t>() & 1u) != 0;
  read_view(in, &msg.segment.output_view);
  std::vector<float> points = read_floats(in), boxes = read_floats(in);
  point_at(points, &msg.segment.points);
  point_at(boxes, &msg.segment.boxes);
  msg.since_version = in.take<std::uint64_t>();
  msg.gaussians_version = in.take<std::uint64_t>();
  msg.gaussians_first = in.take<std::uint32_t>();
  msg.gaussians_max = in.take<std::uint32_t>();
  std::string map_name = in.bytes(in.take<std::uint8_t>());
  std::string path = in.bytes(in.take<std::uint8_t>());
  std::string text = in.rest();
  // Strings on the wire end at their first NUL.
  for (std::string* s : {&map_name, &path, &text}) s->resize(std::string(s->c_str()).size());
  std::string client = "fuzz";
  msg.client = client.data();
  msg.map_name = map_name.data();
  msg.path = path.data();
  msg.segment.text = text.data();

  const Query query = query_of(msg);
  std::string why;
  // Names: a valid map name (session control uses the same rule) is also a valid folder.
  const bool name_ok = valid_map_name(query.map_name, &why);
  refused_with_reason(name_ok, why);
  std::string folder;
  if (name_ok && !resolve_map_folder(kMapDir, "", query.map_name, &folder, &why)) __builtin_trap();
  // Save / load folders stay under map_dir.
  why.clear();
  const bool folder_ok = resolve_map_folder(kMapDir, query.path, query.map_name, &folder, &why);
  refused_with_reason(folder_ok, why);
  if (folder_ok) {
    if (folder.compare(0, kMapDir.size() + 1, kMapDir + "/") != 0) __builtin_trap();
    for (const auto& part : std::filesystem::path(folder)) {
      if (part == "..") __builtin_trap();
    }
  }
  float depth_scale = 0.0f;
  why.clear();
  const bool channels_ok = check_render_channels(query.render.channels, query.render.depth_scale, &depth_scale, &why);
  refused_with_reason(channels_ok, why);
  if (channels_ok && !(std::isfinite(depth_scale) && depth_scale > 0.0f)) __builtin_trap();
  // A session's views (session control), from fields already read: the render's depth scale as
  // the rate, its channels, its from_frame as the localise mode.
  std::uint32_t view_channels = 0;
  why.clear();
  const bool views_ok =
      check_view_request(query.render.from_frame, query.render.depth_scale, query.render.channels, &view_channels, &why);
  refused_with_reason(views_ok, why);
  if (views_ok && query.render.depth_scale != 0.0f) {
    float unused = 0.0f;
    if (!query.render.from_frame || !check_render_channels(view_channels, 0.0f, &unused, &why)) __builtin_trap();
  }
  fslam::core::PinholeCamera camera, out_camera;
  const bool view_ok = check_view(query.render, &camera);
  if (query.has_output_view) check_view(query.output_view, &out_camera);
  why.clear();
  const bool mode_ok = check_segment_mode(query.segment_mode, query.text, &why);
  refused_with_reason(mode_ok, why);
  if (view_ok && mode_ok) {
    std::vector<Eigen::Vector2d> uv;
    std::vector<fslam::core::BoxPrompt> prompts;
    why.clear();
    const bool prompts_ok =
        check_prompts(query.segment_mode, query.points, query.boxes, camera, kMaxPrompts, &uv, &prompts, &why);
    refused_with_reason(prompts_ok, why);
    if (prompts_ok) {
      for (const Eigen::Vector2d& p : uv) {
        if (!(p.x() >= -0.5 && p.x() < camera.width - 0.5 && p.y() >= -0.5 && p.y() < camera.height - 0.5)) {
          __builtin_trap();
        }
      }
      for (const fslam::core::BoxPrompt& b : prompts) {
        if (!(b.u1 > b.u0 && b.v1 > b.v0 && b.u0 >= 0 && b.v0 >= 0 && b.u1 <= camera.width && b.v1 <= camera.height)) {
          __builtin_trap();
        }
      }
    }
  }
  return 0;
}
