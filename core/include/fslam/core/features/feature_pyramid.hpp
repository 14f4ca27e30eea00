// The feature pyramid one image encoder produces per frame (paper sec. "Online Feature
// Rasterization": F^(l), l in {16, 8, 4}), and the bilinear look-up that turns it into the
// concatenated per-point vector u_i the feature autoencoder compresses.
//
// Layout: every level covers the whole frame (the encoders resize without keeping aspect, as
// SAM2 does), stored channel-major float32 so that one point's C channels are C reads at a fixed
// offset apart. Levels are in the paper's order, coarsest first: with the default contract
// [256, 64, 64], [64, 128, 128], [32, 256, 256], so u_i = [coarse | mid | fine] has 352 entries.
#pragma once

#include <cstddef>
#include <vector>

namespace fslam::core {

// Channels and spatial size of one level.
struct FeatureLevelShape {
  int channels = 0;
  int height = 0;  // rows
  int width = 0;   // columns
  bool operator==(const FeatureLevelShape& o) const {
    return channels == o.channels && height == o.height && width == o.width;
  }
  bool operator!=(const FeatureLevelShape& o) const { return !(*this == o); }
};

// One feature map.
struct FeatureLevel {
  FeatureLevelShape shape;
  std::vector<float> data;  // [C, H, W] float32, channel-major: data[(c * H + y) * W + x]

  // Sizes data for `s` (values unspecified).
  void resize(const FeatureLevelShape& s) {
    shape = s;
    data.resize(static_cast<std::size_t>(s.channels) * s.height * s.width);
  }
  const float* channel(int c) const {
    return data.data() + static_cast<std::size_t>(c) * shape.height * shape.width;
  }
  float* channel(int c) {
    return data.data() + static_cast<std::size_t>(c) * shape.height * shape.width;
  }
  float at(int c, int y, int x) const { return channel(c)[y * shape.width + x]; }
};

struct FeaturePyramid {
  // Size of the frame that was encoded (pixels); sample_features maps its pixel coordinates
  // onto each level.
  int image_width = 0;
  int image_height = 0;
  std::vector<FeatureLevel> levels;  // coarsest first (paper order)

  // Sum of the levels' channels: the length of a sampled vector u_i (352 by default).
  int dim() const;
  std::vector<FeatureLevelShape> shapes() const;
};

// Sum of the channels of `shapes`.
int feature_dim(const std::vector<FeatureLevelShape>& shapes);

// Bilinear sample of every level at (u, v), pixel coordinates of the encoded frame with pixel
// centres at integers ((0, 0) is the centre of the top-left pixel), concatenated in level order
// into out[0 .. dim()). A level of W_l columns sees u at x_l = (u + 0.5) * W_l / image_width - 0.5
// (the frame and the level span the same extent); x_l, y_l are clamped to the level's outermost
// pixel centres, so points on or beyond the border take the border value.
void sample_features(const FeaturePyramid& pyramid, float u, float v, float* out);
std::vector<float> sample_features(const FeaturePyramid& pyramid, float u, float v);

}  // namespace fslam::core
