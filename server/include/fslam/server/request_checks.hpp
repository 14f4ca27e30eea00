// The checks a request gets before anything is rendered (docs/protocol.md): what a peer sends
// in a Request, checked against the server's limits and the prompt view. Pure functions, so that
// tests/fuzz/request_fuzz.cpp reaches every refusal.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/segmentation/prompts.hpp"
#include "fslam/proto/types.h"

namespace fslam::server {

// The views a session asks for when it opens (SessionControl view_rate_hz, view_channels): none
// (rate 0), or a localise session's at a finite positive rate, of known channels (0: colour and
// depth); `channels` gets the ones to render.
bool check_view_request(bool localise, float rate_hz, std::uint32_t requested_channels, std::uint32_t* channels,
                        std::string* why);

// A render's channels (a non-empty set of CHANNEL_* bits) and depth scale (0: 1000 units per
// metre); `depth_scale` gets the one to use.
bool check_render_channels(std::uint32_t channels, float requested_depth_scale, float* depth_scale,
                           std::string* why);

// The camera a view is rendered with: the request's intrinsics, or (width 0) `map_camera`, the
// camera map `map_name` was built with; valid and at most `max_pixels` pixels.
bool render_camera(const fslam_proto_Intrinsics& intrinsics, const core::PinholeCamera& map_camera,
                   const std::string& map_name, std::uint64_t max_pixels, core::PinholeCamera* camera,
                   std::string* why);

// A segment request's mode is one of SEGMENT_*, and a text query has a text.
bool check_segment_mode(fslam_proto_SegmentMode mode, const std::string& text, std::string* why);

// The prompts of a segment request against their mode and the prompt view's `camera`: at most
// `max_prompts` points or boxes, points inside the view, boxes non-empty and inside it. `uv` and
// `boxes` get them.
bool check_prompts(fslam_proto_SegmentMode mode, const std::vector<float>& points,
                   const std::vector<float>& box_values, const core::PinholeCamera& camera,
                   std::size_t max_prompts, std::vector<Eigen::Vector2d>* uv,
                   std::vector<core::BoxPrompt>* boxes, std::string* why);

}  // namespace fslam::server
