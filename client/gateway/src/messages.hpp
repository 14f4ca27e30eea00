// The gateway's messages to and from browsers (docs/viewer.md "Gateway and page"): binary
// frames of a JSON header and a payload, camera views from JSON, result images as PNG overlays.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "fslam/client/client.hpp"

namespace fslam::client::gateway {

// A binary WebSocket message: 4-byte ASCII tag, uint32 little-endian header length H, H bytes of
// JSON, zero padding to a multiple of 8 bytes, then the payload.
std::string binary_frame(const char tag[4], const nlohmann::json& header, const std::uint8_t* payload,
                         std::size_t size);

// A camera view from the page: {"t": [3], "q": [qx, qy, qz, qw], "fx", "fy", "cx", "cy", "width",
// "height"} camera-to-world in the server's camera convention (x right, y down, z forward), or
// {"frame": N} for the tracked pose of frame N with the map's camera. False with `why` when a
// field is missing, not finite, or the size is beyond 4096 x 4096.
bool parse_view(const nlohmann::json& view, CameraView* out, std::string* why);

// A segmentation's labels as a PNG overlay, RGBA with alpha 0 where nothing was selected: one
// colour for a prompt's 8-bit mask, a colour per id for promptless 16-bit ids + 1. `covered`
// gets the labelled pixels, `instances` the distinct ids.
bool labels_overlay_png(const RenderedImage& labels, std::vector<std::uint8_t>* png,
                        std::size_t* covered, std::size_t* instances, std::string* why);
// An RGB render as PNG.
bool rgb_png(const RenderedImage& colour, std::vector<std::uint8_t>* png, std::string* why);
// An instance id's display colour (the page draws its legend with the same rule).
void instance_colour(std::uint32_t id, std::uint8_t rgb[3]);

}  // namespace fslam::client::gateway
