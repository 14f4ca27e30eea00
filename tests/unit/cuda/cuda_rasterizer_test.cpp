// GPU parity of the rasteriser: the CUDA forward pass runs core's splat math on the same
// depth-sorted tile lists as the CPU rasteriser, so every output must agree up to float rounding
// (the device's exp and fused multiply-adds). Skips where no GPU is usable.
#include <algorithm>
#include <cmath>
#include <random>
#include <tuple>

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

// Relative L2 difference of two gradient arrays.
double relative_difference(const std::vector<float>& a, const std::vector<float>& b) {
  EXPECT_EQ(a.size(), b.size());
  double diff = 0, norm = 0;
  for (std::size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    diff += (static_cast<double>(a[i]) - b[i]) * (static_cast<double>(a[i]) - b[i]);
    norm += static_cast<double>(a[i]) * a[i];
  }
  return std::sqrt(diff / std::max(norm, 1e-30));
}

// The backward pass runs the same splat-pixel step (math::splat_pair_backward) and projection
// backward; only the summation order (atomics) and the device's rounding differ.
TEST(CudaRasterizer, BackwardMatchesTheCpuRasterizer) {
  std::string why;
  auto gpu = make_cuda_rasterizer(0, &why);
  if (!gpu) GTEST_SKIP() << "no usable GPU: " << why;
  const auto cpu = core::make_cpu_rasterizer();
  const core::GaussianMap map = random_map(5000);
  core::RenderSettings settings;
  settings.background = {0.1f, 0.2f, 0.3f};
  core::RenderView view;
  view.camera = core::PinholeCamera{300.0, 300.0, 159.5, 119.5, 321, 243};
  core::RenderResult a, b;
  ASSERT_TRUE(cpu->forward(map, view, settings, &a, &why)) << why;
  ASSERT_TRUE(gpu->forward(map, view, settings, &b, &why)) << why;
  std::mt19937 rng(5);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  core::RenderGradients g;
  const int W = view.camera.width, H = view.camera.height;
  for (auto [image, channels] : {std::make_pair(&g.colour, 3), std::make_pair(&g.depth, 1),
                                 std::make_pair(&g.median_depth, 1), std::make_pair(&g.alpha, 1),
                                 std::make_pair(&g.features, map.feature_dim)}) {
    *image = core::PlanarImage(W, H, channels);
    for (float& v : image->data) v = 1e-3f * normal(rng);
  }
  core::GaussianGradients ga, gb;
  ASSERT_TRUE(cpu->backward(map, view, settings, a, g, &ga, &why)) << why;
  ASSERT_TRUE(gpu->backward(map, view, settings, b, g, &gb, &why)) << why;
  for (const auto& [name, x, y] :
       {std::make_tuple("means", &ga.means, &gb.means), std::make_tuple("rotations", &ga.rotations, &gb.rotations),
        std::make_tuple("log_scales", &ga.log_scales, &gb.log_scales),
        std::make_tuple("opacity_logits", &ga.opacity_logits, &gb.opacity_logits),
        std::make_tuple("sh", &ga.sh, &gb.sh), std::make_tuple("features", &ga.features, &gb.features),
        std::make_tuple("importance_rgb", &ga.importance_rgb, &gb.importance_rgb),
        std::make_tuple("importance_feature", &ga.importance_feature, &gb.importance_feature)}) {
    double norm = 0;
    for (float v : *x) norm += static_cast<double>(v) * v;
    ASSERT_GT(norm, 0.0) << name << ": the premise, a gradient to compare";
    EXPECT_LT(relative_difference(*x, *y), 2e-3) << name;
  }
  // A result from another rasteriser's forward pass is refused.
  EXPECT_FALSE(gpu->backward(map, view, settings, a, g, &gb, &why));
  EXPECT_NE(why.find("not from the CUDA rasteriser"), std::string::npos) << why;
}

TEST(CudaRasterizer, BadInputIsAClearError) {
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
  core::RenderGradients wrong;
  wrong.colour = core::PlanarImage(10, 10, 3);
  EXPECT_FALSE(gpu->backward(map, view, settings, result, wrong, &grads, &why));
  EXPECT_NE(why.find("wrong shape"), std::string::npos) << why;
  EXPECT_FALSE(make_cuda_rasterizer(-1, &why));
  EXPECT_FALSE(why.empty());
}

}  // namespace
}  // namespace fslam::cuda
