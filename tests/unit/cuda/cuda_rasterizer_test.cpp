// GPU parity of the rasteriser: the CUDA forward pass runs core's splat math on the same
// depth-sorted tile lists as the CPU rasteriser, so every output must agree up to float rounding
// (the device's exp and fused multiply-adds). Skips where no GPU is usable.
#include <algorithm>
#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "fslam/cuda/cuda_backend.hpp"

namespace fslam::cuda {
namespace {

// A cloud of Gaussians 1-4 m in front of the origin: random rotations, anisotropic scales,
// opacities, SH degree 1 colours, D = 16 features and a 3D filter.
core::GaussianMap random_map(std::size_t n) {
  core::GaussianMap map;
  map.sh_degree = 1;
  map.feature_dim = 16;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), unit(0.0f, 1.0f);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::vector<float> sh(12), f(16);
  for (std::size_t i = 0; i < n; ++i) {
    const float z = 1.0f + 3.0f * unit(rng);
    const float mean[3] = {1.2f * z * u(rng) * 0.6f, 0.9f * z * u(rng) * 0.6f, z};
    float q[4] = {normal(rng), normal(rng), normal(rng), normal(rng)};
    const float norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (float& c : q) c /= norm;
    const float log_scale[3] = {std::log(0.004f + 0.03f * unit(rng)), std::log(0.004f + 0.03f * unit(rng)),
                                std::log(0.001f + 0.01f * unit(rng))};
    for (float& c : sh) c = 0.5f * u(rng);
    for (float& c : f) c = normal(rng);
    map.push_back(mean, q, log_scale, 3.0f * u(rng), sh.data(), f.data(), 1e-6f * unit(rng));
  }
  return map;
}

// Largest |a - b| / max(1, |a|) over an image, and the count of pixels beyond `tolerance`.
std::pair<double, std::size_t> compare(const core::PlanarImage& a, const core::PlanarImage& b, double tolerance) {
  EXPECT_EQ(a.data.size(), b.data.size());
  double worst = 0;
  std::size_t beyond = 0;
  for (std::size_t i = 0; i < std::min(a.data.size(), b.data.size()); ++i) {
    const double e = std::abs(a.data[i] - b.data[i]) / std::max(1.0, std::abs(static_cast<double>(a.data[i])));
    worst = std::max(worst, e);
    if (e > tolerance) ++beyond;
  }
  return {worst, beyond};
}

TEST(CudaRasterizer, ForwardMatchesTheCpuRasterizer) {
  std::string why;
  auto gpu = make_cuda_rasterizer(0, &why);
  if (!gpu) GTEST_SKIP() << "no usable GPU: " << why;
  const auto cpu = core::make_cpu_rasterizer();
  const core::GaussianMap map = random_map(20000);
  core::RenderSettings settings;
  settings.background = {0.1f, 0.2f, 0.3f};
  // Two sizes that are not multiples of the 16-pixel tile, and a turned, shifted camera.
  for (int view_index = 0; view_index < 2; ++view_index) {
    core::RenderView view;
    view.camera = view_index == 0 ? core::PinholeCamera{300.0, 300.0, 159.5, 119.5, 321, 243}
                                  : core::PinholeCamera{520.0, 525.0, 330.0, 235.0, 640, 480};
    if (view_index == 1) {
      view.T_camera_world = Eigen::Translation3d(0.1, -0.05, 0.3) * Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY());
    }
    core::RenderResult a, b;
    ASSERT_TRUE(cpu->forward(map, view, settings, &a, &why)) << why;
    ASSERT_TRUE(gpu->forward(map, view, settings, &b, &why)) << why;
    const std::size_t pixels = a.alpha.data.size();
    ASSERT_GT(a.stats.blend_steps, 10 * pixels) << "the premise: a dense render";
    for (const auto& [name, pa, pb] : {std::make_tuple("colour", &a.colour, &b.colour),
                                       std::make_tuple("depth", &a.depth, &b.depth),
                                       std::make_tuple("alpha", &a.alpha, &b.alpha),
                                       std::make_tuple("features", &a.features, &b.features)}) {
      const auto [worst, beyond] = compare(*pa, *pb, 1e-3);
      EXPECT_LT(worst, 2e-2) << name;                    // no pixel far off anywhere
      EXPECT_LE(beyond, pa->data.size() / 1000) << name;  // and all but a few within float rounding
    }
    // The median depth jumps where the transmittance crosses 0.5 within rounding: a few pixels
    // may take the neighbouring splat's depth.
    const auto [worst_median, beyond_median] = compare(a.median_depth, b.median_depth, 1e-3);
    EXPECT_LE(beyond_median, pixels / 500) << "worst " << worst_median;
    EXPECT_NEAR(static_cast<double>(b.stats.visible), static_cast<double>(a.stats.visible), 1e-3 * a.stats.visible);
    EXPECT_NEAR(static_cast<double>(b.stats.tile_entries), static_cast<double>(a.stats.tile_entries),
                1e-3 * a.stats.tile_entries);
    EXPECT_NEAR(static_cast<double>(b.stats.blend_steps), static_cast<double>(a.stats.blend_steps),
                1e-3 * a.stats.blend_steps);
    EXPECT_EQ(a.visible, b.visible);
  }
}

TEST(CudaRasterizer, BadInputAndBackwardAreClearErrors) {
  std::string why;
  auto gpu = make_cuda_rasterizer(0, &why);
  if (!gpu) GTEST_SKIP() << "no usable GPU: " << why;
  const core::GaussianMap map = random_map(100);
  core::RenderView view;
  view.camera = core::PinholeCamera{0.0, 300.0, 159.5, 119.5, 320, 240};  // zero focal length
  core::RenderSettings settings;
  core::RenderResult result;
  EXPECT_FALSE(gpu->forward(map, view, settings, &result, &why));
  EXPECT_NE(why.find("render view"), std::string::npos) << why;
  view.camera = core::PinholeCamera{300.0, 300.0, 159.5, 119.5, 320, 240};
  ASSERT_TRUE(gpu->forward(map, view, settings, &result, &why)) << why;
  core::GaussianGradients grads;
  EXPECT_FALSE(gpu->backward(map, view, settings, result, core::RenderGradients{}, &grads, &why));
  EXPECT_NE(why.find("CPU rasteriser"), std::string::npos) << why;
  EXPECT_FALSE(make_cuda_rasterizer(-1, &why));
  EXPECT_FALSE(why.empty());
}

}  // namespace
}  // namespace fslam::cuda
