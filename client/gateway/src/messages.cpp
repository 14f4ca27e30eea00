#include "messages.hpp"

#include <cmath>
#include <cstring>
#include <set>

#include <nlohmann/json.hpp>
#include <opencv2/core/mat.hpp>
#include <opencv2/imgcodecs.hpp>

namespace fslam::client::gateway {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

bool finite_number(const nlohmann::json& j, const char* key, double* out) {
  const auto it = j.find(key);
  if (it == j.end() || !it->is_number()) return false;
  *out = it->get<double>();
  return std::isfinite(*out);
}

}  // namespace

std::string binary_frame(const char tag[4], const nlohmann::json& header, const std::uint8_t* payload,
                         std::size_t size) {
  const std::string text = header.dump();
  const std::size_t head = 8 + text.size();
  const std::size_t padded = (head + 7) / 8 * 8;
  std::string out(padded + size, '\0');
  std::memcpy(out.data(), tag, 4);
  const auto n = static_cast<std::uint32_t>(text.size());
  for (int k = 0; k < 4; ++k) out[4 + k] = static_cast<char>((n >> (8 * k)) & 0xff);
  std::memcpy(out.data() + 8, text.data(), text.size());
  if (size > 0) std::memcpy(out.data() + padded, payload, size);
  return out;
}

bool parse_view(const nlohmann::json& view, CameraView* out, std::string* why) {
  if (!view.is_object()) return fail(why, "view: expected an object");
  *out = {};
  if (view.contains("frame")) {
    if (!view["frame"].is_number_unsigned()) return fail(why, "view: frame must be a frame id");
    out->from_frame = true;
    out->frame_id = view["frame"].get<std::uint64_t>();
    return true;  // the map's camera (width 0)
  }
  const auto& t = view.value("t", nlohmann::json()), &q = view.value("q", nlohmann::json());
  if (!t.is_array() || t.size() != 3 || !q.is_array() || q.size() != 4) {
    return fail(why, "view: needs t [x, y, z] and q [qx, qy, qz, qw]");
  }
  for (int k = 0; k < 7; ++k) {
    const nlohmann::json& v = k < 3 ? t[k] : q[k - 3];
    if (!v.is_number() || !std::isfinite(v.get<double>())) return fail(why, "view: t and q must be finite numbers");
    (k < 3 ? out->translation[k] : out->rotation[k - 3]) = v.get<double>();
  }
  double fx, fy, cx, cy, w, h;
  if (!finite_number(view, "fx", &fx) || !finite_number(view, "fy", &fy) ||
      !finite_number(view, "cx", &cx) || !finite_number(view, "cy", &cy) ||
      !finite_number(view, "width", &w) || !finite_number(view, "height", &h)) {
    return fail(why, "view: needs finite fx, fy, cx, cy, width, height");
  }
  if (!(w >= 1 && h >= 1 && w <= 4096 && h <= 4096) || w != std::floor(w) || h != std::floor(h)) {
    return fail(why, "view: width and height must be whole numbers of pixels, 1..4096");
  }
  out->intrinsics = {static_cast<float>(fx), static_cast<float>(fy), static_cast<float>(cx),
                     static_cast<float>(cy), static_cast<std::uint32_t>(w), static_cast<std::uint32_t>(h)};
  return true;
}

void instance_colour(std::uint32_t id, std::uint8_t rgb[3]) {
  // Hues a golden angle apart: neighbouring ids look different.
  const double hue = std::fmod(static_cast<double>(id) * 137.50776, 360.0) / 60.0;
  const double x = 1.0 - std::abs(std::fmod(hue, 2.0) - 1.0);
  double r = 0, g = 0, b = 0;
  switch (static_cast<int>(hue)) {
    case 0: r = 1; g = x; break;
    case 1: r = x; g = 1; break;
    case 2: g = 1; b = x; break;
    case 3: g = x; b = 1; break;
    case 4: r = x; b = 1; break;
    default: r = 1; b = x;
  }
  const double lo = 0.25;  // keep colours light enough to read over a dark map
  rgb[0] = static_cast<std::uint8_t>(255 * (lo + (1 - lo) * r));
  rgb[1] = static_cast<std::uint8_t>(255 * (lo + (1 - lo) * g));
  rgb[2] = static_cast<std::uint8_t>(255 * (lo + (1 - lo) * b));
}

bool labels_overlay_png(const RenderedImage& labels, std::vector<std::uint8_t>* png,
                        std::size_t* covered, std::size_t* instances, std::string* why) {
  const int w = static_cast<int>(labels.width), h = static_cast<int>(labels.height);
  const bool ids = labels.bytes_per_channel == 2;
  if (labels.channels != 1 || labels.pixels.size() != std::size_t(w) * h * labels.bytes_per_channel) {
    return fail(why, "segment result: unexpected labels image");
  }
  cv::Mat bgra(h, w, CV_8UC4, cv::Scalar(0, 0, 0, 0));
  std::set<std::uint32_t> seen;
  *covered = 0;
  constexpr std::uint8_t kAlpha = 255;  // the page chooses how strongly it blends
  for (int i = 0; i < w * h; ++i) {
    std::uint32_t label = 0;
    if (ids) std::memcpy(&label, &labels.pixels[2 * i], 2);  // little-endian 16-bit rows
    else label = labels.pixels[i] != 0 ? 1 : 0;
    if (label == 0) continue;
    ++*covered;
    std::uint8_t rgb[3] = {255, 196, 0};  // a prompt's object
    if (ids) {
      seen.insert(label - 1);
      instance_colour(label - 1, rgb);
    }
    cv::Vec4b& px = bgra.at<cv::Vec4b>(i / w, i % w);
    px = {rgb[2], rgb[1], rgb[0], kAlpha};
  }
  *instances = ids ? seen.size() : (*covered > 0 ? 1 : 0);
  if (!cv::imencode(".png", bgra, *png, {cv::IMWRITE_PNG_COMPRESSION, 3})) {
    return fail(why, "segment result: cannot encode the overlay");
  }
  return true;
}

bool rgb_png(const RenderedImage& colour, std::vector<std::uint8_t>* png, std::string* why) {
  const int w = static_cast<int>(colour.width), h = static_cast<int>(colour.height);
  if (colour.channels != 3 || colour.bytes_per_channel != 1 || colour.pixels.size() != std::size_t(w) * h * 3) {
    return fail(why, "render result: unexpected colour image");
  }
  cv::Mat bgr(h, w, CV_8UC3);
  for (int i = 0; i < w * h; ++i) {
    bgr.data[3 * i] = colour.pixels[3 * i + 2];
    bgr.data[3 * i + 1] = colour.pixels[3 * i + 1];
    bgr.data[3 * i + 2] = colour.pixels[3 * i];
  }
  if (!cv::imencode(".png", bgr, *png, {cv::IMWRITE_PNG_COMPRESSION, 3})) {
    return fail(why, "render result: cannot encode the image");
  }
  return true;
}

}  // namespace fslam::client::gateway
