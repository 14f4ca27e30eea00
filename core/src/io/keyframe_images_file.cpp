#include "fslam/core/io/keyframe_images_file.hpp"

#include <cstdint>
#include <cstring>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/io/file_writer.hpp"
#include "fslam/core/io/image_io.hpp"
#include "binary_record.hpp"

namespace fslam::core {
namespace {

constexpr char kMagic[8] = {'F', 'S', 'L', 'M', 'K', 'F', 'I', '1'};
constexpr std::uint32_t kMaxSide = 1u << 14;  // pixels, width or height

using io_detail::ByteReader;
using io_detail::put;

bool put_png(std::string* out, const cv::Mat& image, std::string* why) {
  std::vector<std::uint8_t> png;
  // Level 1: these files are written while a server saves, often at shutdown.
  if (!cv::imencode(".png", image, png, {cv::IMWRITE_PNG_COMPRESSION, 1}))
    return fail(why, "cannot encode a keyframe image as PNG");
  put(out, static_cast<std::uint32_t>(png.size()));
  out->append(reinterpret_cast<const char*>(png.data()), png.size());
  return true;
}

// Decodes a PNG blob of the expected type, at most max_width x max_height (checked in its IHDR
// header before decoding, so a small blob cannot declare a huge image); false: not such a PNG.
bool decode(const std::uint8_t* data, std::uint32_t size, int flags, int type, int max_width, int max_height,
            cv::Mat* image) {
  std::uint32_t width = 0, height = 0;  // PNG only: no other decoder runs
  if (!png_declared_size(data, size, &width, &height) || width > static_cast<std::uint32_t>(max_width) ||
      height > static_cast<std::uint32_t>(max_height))
    return false;
  try {
    *image = cv::imdecode(cv::Mat(1, static_cast<int>(size), CV_8UC1, const_cast<std::uint8_t*>(data)), flags);
  } catch (const cv::Exception&) {
    return false;
  }
  return !image->empty() && image->type() == type;
}

}  // namespace

bool write_keyframe_images_file(const std::string& path, const std::vector<KeyframeImages>& keyframes,
                                std::string* why) {
  std::string out(kMagic, sizeof(kMagic));
  put(&out, static_cast<std::uint32_t>(keyframes.size()));
  for (const KeyframeImages& kf : keyframes) {
    const std::string where = path + ": keyframe " + std::to_string(kf.frame_id);
    if (kf.colour.type() != CV_8UC3 || kf.depth.type() != CV_32FC1 || kf.colour.size() != kf.depth.size() ||
        kf.colour.empty())
      return fail(why, where + ": colour (8-bit RGB) and depth (float) images of one size are needed");
    put(&out, kf.frame_id);
    for (const double v : {kf.input_camera.fx, kf.input_camera.fy, kf.input_camera.cx, kf.input_camera.cy}) put(&out, v);
    put(&out, static_cast<std::uint32_t>(kf.input_camera.width));
    put(&out, static_cast<std::uint32_t>(kf.input_camera.height));
    io_detail::put_pose(&out, kf.T_world_camera);
    cv::Mat bgr;
    cv::cvtColor(kf.colour, bgr, cv::COLOR_RGB2BGR);  // so that the PNG views in any viewer
    if (!put_png(&out, bgr, why) || !put_png(&out, depth_to_u16(kf.depth, kKeyframeDepthScale), why))
      return fail(why, where + ": " + (why ? *why : std::string()));
  }
  return write_file(path, out, why);
}

bool parse_keyframe_images_file(const std::string& bytes, const std::string& name,
                                std::vector<KeyframeImages>* keyframes, std::string* why) {
  keyframes->clear();  // and left empty on any error
  std::vector<KeyframeImages> parsed;
  ByteReader in(bytes);
  char magic[sizeof(kMagic)];
  if (!in.get_bytes(magic, sizeof(magic)) || std::memcmp(magic, kMagic, sizeof(kMagic)) != 0)
    return fail(why, name + ": not a keyframe images file (no FSLMKFI1 header)");
  std::uint32_t count = 0;
  if (!in.get(&count)) return fail(why, name + ": truncated before the keyframe count");
  // Each keyframe takes at least its fixed fields (8 + 32 + 8 + 96 + 8 bytes).
  constexpr std::size_t kFixed = 8 + 32 + 8 + 96 + 8;
  if (count > in.left() / kFixed)
    return fail(why, name + ": " + std::to_string(count) + " keyframes declared, the file is too short for them");
  parsed.reserve(count);
  for (std::uint32_t k = 0; k < count; ++k) {
    const std::string where = name + ": keyframe " + std::to_string(k);
    KeyframeImages kf;
    double cam[4];
    std::uint32_t width = 0, height = 0;
    if (!in.get(&kf.frame_id) || !in.get_bytes(cam, sizeof(cam)) || !in.get(&width) || !in.get(&height))
      return fail(why, where + ": truncated");
    if (width == 0 || height == 0 || width > kMaxSide || height > kMaxSide)
      return fail(why, where + ": input camera of " + std::to_string(width) + "x" + std::to_string(height) + " pixels");
    kf.input_camera = {cam[0], cam[1], cam[2], cam[3], static_cast<int>(width), static_cast<int>(height)};
    std::string reason;
    if (!kf.input_camera.is_valid(&reason)) return fail(why, where + ": input camera: " + reason);
    if (!io_detail::get_pose(&in, where, &kf.T_world_camera, why)) return false;
    const std::uint8_t *colour = nullptr, *depth = nullptr;
    std::uint32_t colour_size = 0, depth_size = 0;
    if (!in.get_blob(&colour, &colour_size) || !in.get_blob(&depth, &depth_size))
      return fail(why, where + ": truncated image");
    cv::Mat bgr, raw;
    const int w = kf.input_camera.width, h = kf.input_camera.height;
    if (!decode(colour, colour_size, cv::IMREAD_COLOR, CV_8UC3, w, h, &bgr))
      return fail(why, where + ": colour is not an 8-bit colour PNG within the input camera's size");
    if (!decode(depth, depth_size, cv::IMREAD_ANYDEPTH, CV_16UC1, w, h, &raw))
      return fail(why, where + ": depth is not a 16-bit PNG within the input camera's size");
    if (bgr.size() != raw.size())
      return fail(why, where + ": colour and depth images differ in size");
    cv::cvtColor(bgr, kf.colour, cv::COLOR_BGR2RGB);
    raw.convertTo(kf.depth, CV_32FC1, 1.0 / kKeyframeDepthScale);
    parsed.push_back(std::move(kf));
  }
  if (in.left() != 0) return fail(why, name + ": " + std::to_string(in.left()) + " bytes after the last keyframe");
  *keyframes = std::move(parsed);
  return true;
}

bool read_keyframe_images_file(const std::string& path, std::vector<KeyframeImages>* keyframes, std::string* why) {
  std::string bytes;
  return io_detail::read_capped_file(path, kMaxKeyframeImagesFileBytes, "a keyframe images file", &bytes, why) &&
         parse_keyframe_images_file(bytes, path, keyframes, why);
}

}  // namespace fslam::core
