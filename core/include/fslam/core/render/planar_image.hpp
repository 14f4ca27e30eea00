// A float image stored plane by plane: the layout every renderer output, loss and gradient uses.
#pragma once

#include <cassert>
#include <cstddef>
#include <vector>

namespace fslam::core {

struct PlanarImage {
  int width = 0;
  int height = 0;
  int channels = 0;
  std::vector<float> data;  // [channels, height, width], row-major inside each plane

  PlanarImage() = default;
  PlanarImage(int w, int h, int c, float fill = 0.0f)
      : width(w), height(h), channels(c),
        data(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) *
                 static_cast<std::size_t>(c),
             fill) {}

  std::size_t pixels() const { return static_cast<std::size_t>(width) * height; }
  bool empty() const { return data.empty(); }
  bool same_shape(const PlanarImage& o) const {
    return width == o.width && height == o.height && channels == o.channels;
  }
  float* plane(int c) { return data.data() + c * pixels(); }
  const float* plane(int c) const { return data.data() + c * pixels(); }
  float& at(int c, int v, int u) {
    assert(c >= 0 && c < channels && v >= 0 && v < height && u >= 0 && u < width);
    return data[c * pixels() + static_cast<std::size_t>(v) * width + u];
  }
  float at(int c, int v, int u) const {
    assert(c >= 0 && c < channels && v >= 0 && v < height && u >= 0 && u < width);
    return data[c * pixels() + static_cast<std::size_t>(v) * width + u];
  }
};

}  // namespace fslam::core
