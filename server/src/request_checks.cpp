#include "fslam/server/request_checks.hpp"

#include <cmath>

#include "fslam/core/error.hpp"
#include "fslam/server/wire.hpp"

namespace fslam::server {

bool check_render_channels(std::uint32_t channels, float requested_depth_scale, float* depth_scale,
                           std::string* why) {
  constexpr std::uint32_t kKnown = fslam_proto_CHANNEL_COLOUR | fslam_proto_CHANNEL_DEPTH |
                                   fslam_proto_CHANNEL_NORMALS | fslam_proto_CHANNEL_OPACITY;
  if (channels == 0 || (channels & ~kKnown) != 0) {
    return core::fail(why, "render: channels must be a non-empty set of CHANNEL_* bits");
  }
  *depth_scale = requested_depth_scale == 0.0f ? 1000.0f : requested_depth_scale;
  if (!(*depth_scale > 0) || !std::isfinite(*depth_scale)) return core::fail(why, "render: depth_scale must be positive");
  return true;
}

bool check_view_request(bool localise, float rate_hz, std::uint32_t requested_channels, std::uint32_t* channels,
                        std::string* why) {
  *channels = 0;
  if (rate_hz == 0.0f) return true;
  if (!std::isfinite(rate_hz) || rate_hz < 0.0f)
    return core::fail(why, "views: view_rate_hz must be a finite number of views per second >= 0");
  if (!localise) return core::fail(why, "views are pushed to localise sessions only (mode SESSION_LOCALISE)");
  *channels = requested_channels == 0 ? fslam_proto_CHANNEL_COLOUR | fslam_proto_CHANNEL_DEPTH : requested_channels;
  float depth_scale = 0.0f;
  std::string reason;
  if (!check_render_channels(*channels, 0.0f, &depth_scale, &reason))
    return core::fail(why, "views: channels must be a set of CHANNEL_* bits");
  return true;
}

bool render_camera(const fslam_proto_Intrinsics& k, const core::PinholeCamera& map_camera,
                   const std::string& map_name, std::uint64_t max_pixels, core::PinholeCamera* camera,
                   std::string* why) {
  if (k.width != 0) {
    *camera = {k.fx, k.fy, k.cx, k.cy, static_cast<int>(k.width), static_cast<int>(k.height)};
  } else if (map_camera.width == 0) {
    return core::fail(why, "map '" + map_name + "' has no camera of its own; give intrinsics");
  } else {
    *camera = map_camera;
  }
  std::string reason;
  if (!camera->is_valid(&reason)) return core::fail(why, "intrinsics: " + reason);
  if (static_cast<std::uint64_t>(camera->width) * static_cast<std::uint64_t>(camera->height) > max_pixels) {
    return core::fail(why, std::to_string(camera->width) + "x" + std::to_string(camera->height) +
                               " is over the server's limit of " + std::to_string(max_pixels) + " pixels");
  }
  return true;
}

bool check_segment_mode(fslam_proto_SegmentMode mode, const std::string& text, std::string* why) {
  if (mode != fslam_proto_SEGMENT_PROMPTLESS && mode != fslam_proto_SEGMENT_POINTS &&
      mode != fslam_proto_SEGMENT_BOXES && mode != fslam_proto_SEGMENT_TEXT) {
    return core::fail(why, "segment: unknown mode " + std::to_string(static_cast<int>(mode)));
  }
  if (mode == fslam_proto_SEGMENT_TEXT && text.find_first_not_of(" \t\r\n") == std::string::npos) {
    return core::fail(why, "segment: a text query needs a text");
  }
  return true;
}

bool check_prompts(fslam_proto_SegmentMode mode, const std::vector<float>& points,
                   const std::vector<float>& box_values, const core::PinholeCamera& camera,
                   std::size_t max_prompts, std::vector<Eigen::Vector2d>* uv,
                   std::vector<core::BoxPrompt>* boxes, std::string* why) {
  const double w = camera.width, h = camera.height;
  if (points.size() / 2 > max_prompts || box_values.size() / 4 > max_prompts) {
    return core::fail(why, "segment: more than " + std::to_string(max_prompts) +
                               " points or boxes in one request (server.max_prompts)");
  }
  const std::string size = std::to_string(camera.width) + "x" + std::to_string(camera.height);
  if (mode == fslam_proto_SEGMENT_POINTS) {
    if (points.empty()) return core::fail(why, "segment: a point query needs at least one point (u, v)");
    if (points.size() % 2 != 0) {
      return core::fail(why, "segment: points are u, v pairs; got an odd number of coordinates (" +
                                 std::to_string(points.size()) + ")");
    }
    for (std::size_t i = 0; i < points.size(); i += 2) {
      const double u = points[i], v = points[i + 1];
      // Pixel centres at integers: a point belongs to the view when it rounds into its grid.
      if (!(u >= -0.5 && u < w - 0.5 && v >= -0.5 && v < h - 0.5)) {
        return core::fail(why, "segment: point (" + number_text(u) + ", " + number_text(v) +
                                   ") lies outside the " + size + " view");
      }
      uv->emplace_back(u, v);
    }
  } else if (mode == fslam_proto_SEGMENT_BOXES) {
    if (box_values.empty()) return core::fail(why, "segment: a box query needs at least one box (u0, v0, u1, v1)");
    if (box_values.size() % 4 != 0) {
      return core::fail(why, "segment: boxes are u0, v0, u1, v1 quadruples; got " +
                                 std::to_string(box_values.size()) + " numbers");
    }
    for (std::size_t i = 0; i < box_values.size(); i += 4) {
      const core::BoxPrompt b{box_values[i], box_values[i + 1], box_values[i + 2], box_values[i + 3]};
      const std::string name = "box (" + number_text(b.u0) + ", " + number_text(b.v0) + ", " + number_text(b.u1) +
                               ", " + number_text(b.v1) + ")";
      if (!(b.u1 > b.u0 && b.v1 > b.v0)) {
        return core::fail(why, "segment: " + name + " is empty: it needs u1 > u0 and v1 > v0");
      }
      if (!(b.u0 >= 0 && b.v0 >= 0 && b.u1 <= w && b.v1 <= h)) {
        return core::fail(why, "segment: " + name + " reaches outside the " + size + " view");
      }
      boxes->push_back(b);
    }
  }
  return true;
}


}  // namespace fslam::server
