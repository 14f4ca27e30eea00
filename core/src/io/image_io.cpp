#include "fslam/core/io/image_io.hpp"

#include "fslam/core/error.hpp"

#include <cmath>
#include <cstring>
#include <memory>

#include <OpenImageIO/imageio.h>
#include <opencv2/core.hpp>

namespace fslam::core {
namespace {

// Opens `path` and reads every pixel in the file's own channel count as `type`.
bool read_raw(const std::string& path, OIIO::TypeDesc type, int cv_depth, cv::Mat* out,
              int* channels, std::string* why) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) {
    std::string err = OIIO::geterror();
    return fail(why, path + ": cannot read image" + (err.empty() ? "" : " (" + err + ")"));
  }
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0)
    return fail(why, path + ": image has no pixels");
  *channels = spec.nchannels;
  cv::Mat m(spec.height, spec.width, CV_MAKETYPE(cv_depth, spec.nchannels));
  if (!in->read_image(0, 0, 0, spec.nchannels, type, m.data)) {
    return fail(why, path + ": cannot decode image (" + in->geterror() + ")");
  }
  *out = m;
  return true;
}

}  // namespace

bool read_colour_image(const std::string& path, cv::Mat* rgb, std::string* why) {
  cv::Mat raw;
  int channels = 0;
  if (!read_raw(path, OIIO::TypeDesc::UINT8, CV_8U, &raw, &channels, why)) return false;
  if (channels == 3) {
    *rgb = raw;
  } else if (channels == 4) {
    cv::Mat parts[4];
    cv::split(raw, parts);
    cv::merge(parts, 3, *rgb);
  } else if (channels == 1) {
    cv::Mat parts[3] = {raw, raw, raw};
    cv::merge(parts, 3, *rgb);
  } else {
    return fail(why, path + ": expected a grey, RGB or RGBA image, found " +
                         std::to_string(channels) + " channels");
  }
  return true;
}

bool read_depth_image(const std::string& path, double scale, cv::Mat* depth_m, std::string* why) {
  if (!(scale > 0.0) || !std::isfinite(scale))
    return fail(why, path + ": depth scale must be positive, got " + std::to_string(scale));
  auto in = OIIO::ImageInput::open(path);
  if (!in) return fail(why, path + ": cannot read depth image (" + OIIO::geterror() + ")");
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.nchannels != 1)
    return fail(why, path + ": depth must have one channel, found " +
                         std::to_string(spec.nchannels));
  if (spec.format != OIIO::TypeDesc::UINT16)
    return fail(why, path + ": depth must be 16-bit, found " + std::string(spec.format.c_str()));
  cv::Mat raw(spec.height, spec.width, CV_16UC1);
  if (!in->read_image(0, 0, 0, 1, OIIO::TypeDesc::UINT16, raw.data))
    return fail(why, path + ": cannot decode depth image (" + in->geterror() + ")");
  cv::Mat out(raw.size(), CV_32FC1);
  const float inv_scale = static_cast<float>(1.0 / scale);
  for (int v = 0; v < raw.rows; ++v) {
    const auto* src = raw.ptr<std::uint16_t>(v);
    auto* dst = out.ptr<float>(v);
    for (int u = 0; u < raw.cols; ++u) {
      // 0 and 65535 are the sensors' "no return" codes.
      dst[u] = (src[u] == 0 || src[u] == 65535) ? 0.0f : static_cast<float>(src[u]) * inv_scale;
    }
  }
  *depth_m = out;
  return true;
}

bool read_single_channel_image(const std::string& path, cv::Mat* image, std::string* why) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) return fail(why, path + ": cannot read image (" + OIIO::geterror() + ")");
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.nchannels != 1)
    return fail(why, path + ": expected one channel, found " + std::to_string(spec.nchannels));
  int cv_type = 0;
  if (spec.format == OIIO::TypeDesc::UINT8) cv_type = CV_8UC1;
  else if (spec.format == OIIO::TypeDesc::UINT16) cv_type = CV_16UC1;
  else cv_type = CV_32FC1;
  const OIIO::TypeDesc type = cv_type == CV_8UC1    ? OIIO::TypeDesc::UINT8
                              : cv_type == CV_16UC1 ? OIIO::TypeDesc::UINT16
                                                    : OIIO::TypeDesc::FLOAT;
  cv::Mat m(spec.height, spec.width, cv_type);
  if (!in->read_image(0, 0, 0, 1, type, m.data))
    return fail(why, path + ": cannot decode image (" + in->geterror() + ")");
  *image = m;
  return true;
}

bool write_image(const std::string& path, const cv::Mat& image, std::string* why,
                 const ImageWriteOptions& options) {
  if (image.empty()) return fail(why, path + ": refusing to write an empty image");
  OIIO::TypeDesc type;
  switch (image.depth()) {
    case CV_8U: type = OIIO::TypeDesc::UINT8; break;
    case CV_16U: type = OIIO::TypeDesc::UINT16; break;
    case CV_32F: type = OIIO::TypeDesc::FLOAT; break;
    default: return fail(why, path + ": unsupported pixel type for writing");
  }
  const cv::Mat m = image.isContinuous() ? image : image.clone();
  auto out = OIIO::ImageOutput::create(path);
  if (!out) return fail(why, path + ": no image writer for this extension (" + OIIO::geterror() + ")");
  OIIO::ImageSpec spec(m.cols, m.rows, m.channels(), type);
  if (options.png_compression >= 0) spec.attribute("png:compressionLevel", options.png_compression);
  if (options.png_filter != ImageWriteOptions::kPngAdaptive)
    spec.attribute("png:filter", static_cast<int>(options.png_filter));
  if (!out->open(path, spec)) return fail(why, path + ": cannot open for writing (" + out->geterror() + ")");
  if (!out->write_image(type, m.data) || !out->close())
    return fail(why, path + ": cannot write image (" + out->geterror() + ")");
  return true;
}

bool png_declared_size(const std::uint8_t* data, std::size_t n, std::uint32_t* width, std::uint32_t* height) {
  // Signature (8 bytes), then the IHDR chunk: length (4), "IHDR", width and height big-endian.
  static const std::uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (n < 24 || std::memcmp(data, kSignature, 8) != 0 || std::memcmp(data + 12, "IHDR", 4) != 0) return false;
  const auto be32 = [&](std::size_t i) {
    return std::uint32_t{data[i]} << 24 | std::uint32_t{data[i + 1]} << 16 | std::uint32_t{data[i + 2]} << 8 | data[i + 3];
  };
  *width = be32(16);
  *height = be32(20);
  return true;
}

cv::Mat depth_to_u16(const cv::Mat& depth_m, double scale) {
  CV_Assert(depth_m.type() == CV_32FC1);
  cv::Mat out(depth_m.size(), CV_16UC1);
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* src = depth_m.ptr<float>(v);
    auto* dst = out.ptr<std::uint16_t>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      const double raw = std::round(static_cast<double>(src[u]) * scale);
      dst[u] = (std::isfinite(raw) && raw > 0.0 && raw < 65535.0) ? static_cast<std::uint16_t>(raw)
                                                                  : 0;
    }
  }
  return out;
}

}  // namespace fslam::core
