#include "depth_png.hpp"

#include <csetjmp>

#include <png.h>

namespace fslam::client {
namespace {

void append(png_structp png, png_bytep data, png_size_t n) {
  auto* out = static_cast<std::vector<std::uint8_t>*>(png_get_io_ptr(png));
  out->insert(out->end(), data, data + n);
}

void flush(png_structp) {}

}  // namespace

bool encode_depth_png(const std::uint16_t* depth, int width, int height,
                      std::vector<std::uint8_t>* out, std::string* why) {
  out->clear();
  out->reserve(static_cast<std::size_t>(width) * height);  // typical size is under a third of raw
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr) {
    png_destroy_write_struct(&png, &info);
    if (why) *why = "push_frame: cannot start the PNG encoder";
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {  // libpng reports errors by longjmp
    png_destroy_write_struct(&png, &info);
    if (why) *why = "push_frame: the PNG encoder failed on the depth image";
    return false;
  }
  png_set_write_fn(png, out, append, flush);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 16,
               PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_set_filter(png, 0, PNG_FILTER_NONE);
  png_set_compression_level(png, 1);  // frames are streamed, not archived
  png_write_info(png, info);
  png_set_swap(png);  // PNG is big-endian; the rows are host (little-endian) order
  for (int r = 0; r < height; ++r) {
    png_write_row(png, reinterpret_cast<png_const_bytep>(depth + static_cast<std::size_t>(r) * width));
  }
  png_write_end(png, info);
  png_destroy_write_struct(&png, &info);
  return true;
}

}  // namespace fslam::client
