// One rasteriser suite over every backend compiled into the binary (design.md: tests are
// parameterised over every backend). The backends are reached the one way the code allows, the
// backend factory (server::make_rasterizer; docs/architecture.md: only backend_factory.cpp sees
// fslam/cuda), which is why this suite lives in the server's test binary. Each backend's float
// render and gradients are checked against the CPU algorithm run in double precision
// (core/render/rasterize_impl.hpp), so the CPU backend is held to float rounding and the CUDA
// backend, which runs the same math on the same depth-sorted tile lists, to float rounding plus
// the device's exp, fused multiply-adds and atomic summation order. A backend that is compiled in
// but unusable here (no GPU) skips with the reason.
#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/core/render/rasterize_impl.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/server/backend_factory.hpp"

namespace fslam::server {
namespace {

std::vector<std::string> compiled_backends() {
  std::vector<std::string> names = {"cpu"};
  if (cuda_compiled_in()) names.push_back("cuda");
  return names;
}

class RasterizerBackend : public ::testing::TestWithParam<std::string> {
 protected:
  // The backend under test, or nullptr after GTEST_SKIP when it cannot run here.
  std::unique_ptr<core::Rasterizer> make() {
    std::string notice, why;
    auto rasterizer = make_rasterizer(GetParam(), RasterUse::kMapping, &notice, &why);
    if (!rasterizer) fail_or_skip(why);
    return rasterizer;
  }

 private:
  void fail_or_skip(const std::string& why) {
    if (GetParam() == "cpu") {
      ADD_FAILURE() << "the CPU rasteriser must always be available: " << why;
    } else {
      GTEST_SKIP() << "backend " << GetParam() << " compiled in but not usable here: " << why;
    }
  }
};

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

// The map's parameters in double, named as GaussianMap's arrays (for math::splat_scene_of).
struct DoubleMap {
  std::vector<double> means, rotations, log_scales, opacity_logits, sh, features, filter_3d;
  explicit DoubleMap(const core::GaussianMap& m)
      : means(m.means.begin(), m.means.end()), rotations(m.rotations.begin(), m.rotations.end()),
        log_scales(m.log_scales.begin(), m.log_scales.end()),
        opacity_logits(m.opacity_logits.begin(), m.opacity_logits.end()), sh(m.sh.begin(), m.sh.end()),
        features(m.features.begin(), m.features.end()), filter_3d(m.filter_3d.begin(), m.filter_3d.end()) {}
};

// The render and gradients of the CPU algorithm in double precision, on the float camera every
// backend renders with (render_impl::render_camera).
struct Reference {
  std::vector<double> colour, depth, median_depth, alpha, features;
  std::vector<double> means, rotations, log_scales, opacity_logits, sh, g_features, importance_rgb,
      importance_feature;
  std::vector<std::uint8_t> visible;
  std::size_t tile_entries = 0;
  std::uint64_t blend_steps = 0;
};

Reference reference(const core::GaussianMap& map, const core::RenderView& view, const core::RenderSettings& settings,
                    const core::RenderGradients* grads) {
  core::math::SplatCamera<float> camf;
  std::string why;
  EXPECT_TRUE(core::render_impl::render_camera(view, settings, &camf, &why)) << why;
  core::math::SplatCamera<double> cam{};
  for (int k = 0; k < 9; ++k) cam.R[k] = camf.R[k];
  for (int k = 0; k < 3; ++k) cam.t[k] = camf.t[k];
  cam.fx = camf.fx;
  cam.fy = camf.fy;
  cam.cx = camf.cx;
  cam.cy = camf.cy;
  cam.near_plane = camf.near_plane;
  cam.width = camf.width;
  cam.height = camf.height;
  const DoubleMap dm(map);
  const auto scene = core::math::splat_scene_of<double>(dm, map.size(), map.sh_degree, map.feature_dim,
                                                         !map.filter_3d.empty());
  const std::size_t pixels = static_cast<std::size_t>(cam.width) * cam.height, n = map.size();
  const int D = map.feature_dim;
  Reference r;
  r.colour.resize(3 * pixels);
  r.depth.resize(pixels);
  r.median_depth.resize(pixels);
  r.alpha.resize(pixels);
  r.features.resize(D * pixels);
  const double background[3] = {settings.background[0], settings.background[1], settings.background[2]};
  core::math::RasterOutputs<double> out{r.colour.data(), r.depth.data(), r.median_depth.data(), r.alpha.data(),
                                        r.features.data()};
  core::render_impl::RasterState<double> st;
  core::render_impl::rasterize_forward(scene, cam, background, true, &st, out);
  for (const auto& g : st.projected) r.visible.push_back(g.radius > 0 ? 1 : 0);
  r.tile_entries = st.tile_ids.size();
  r.blend_steps = st.blend_steps;
  if (grads == nullptr) return r;
  const auto to_double = [](const core::PlanarImage& image) {
    return std::vector<double>(image.data.begin(), image.data.end());
  };
  const std::vector<double> gc = to_double(grads->colour), gd = to_double(grads->depth),
                            gm = to_double(grads->median_depth), ga = to_double(grads->alpha),
                            gf = to_double(grads->features);
  core::math::RasterOutputGrads<double> go{gc.data(), gd.data(), gm.data(), ga.data(), gf.data()};
  r.means.assign(3 * n, 0.0);
  r.rotations.assign(4 * n, 0.0);
  r.log_scales.assign(3 * n, 0.0);
  r.opacity_logits.assign(n, 0.0);
  r.sh.assign(map.sh.size(), 0.0);
  r.g_features.assign(map.features.size(), 0.0);
  r.importance_rgb.assign(n, 0.0);
  r.importance_feature.assign(n, 0.0);
  core::render_impl::SceneGrads<double> sg{r.means.data(),          r.rotations.data(), r.log_scales.data(),
                                           r.opacity_logits.data(), r.sh.data(),        r.g_features.data(),
                                           r.importance_rgb.data(),  r.importance_feature.data()};
  core::render_impl::rasterize_backward(scene, cam, background, true, st, out, go, sg);
  return r;
}

// Largest |a - b| / max(1, |b|) over an image, and the count of values beyond `tolerance`.
std::pair<double, std::size_t> compare(const core::PlanarImage& a, const std::vector<double>& b, double tolerance) {
  EXPECT_EQ(a.data.size(), b.size());
  double worst = 0;
  std::size_t beyond = 0;
  for (std::size_t i = 0; i < std::min(a.data.size(), b.size()); ++i) {
    const double e = std::abs(a.data[i] - b[i]) / std::max(1.0, std::abs(b[i]));
    worst = std::max(worst, e);
    if (e > tolerance) ++beyond;
  }
  return {worst, beyond};
}

// Relative L2 difference of a gradient array from its reference.
double relative_difference(const std::vector<float>& a, const std::vector<double>& b) {
  EXPECT_EQ(a.size(), b.size());
  double diff = 0, norm = 0;
  for (std::size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    diff += (a[i] - b[i]) * (a[i] - b[i]);
    norm += b[i] * b[i];
  }
  return std::sqrt(diff / std::max(norm, 1e-30));
}

// The forward pass composites the same depth-sorted tile lists with the same per-pixel math, so
// every output agrees up to float rounding.
TEST_P(RasterizerBackend, ForwardMatchesTheDoublePrecisionAlgorithm) {
  const auto rasterizer = make();
  if (!rasterizer) return;
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
    std::string why;
    core::RenderResult b;
    ASSERT_TRUE(rasterizer->forward(map, view, settings, &b, &why)) << why;
    const Reference a = reference(map, view, settings, nullptr);
    const std::size_t pixels = a.alpha.size();
    ASSERT_GT(a.blend_steps, 10 * pixels) << "the premise: a dense render";
    for (const auto& [name, pa, pb] : {std::make_tuple("colour", &a.colour, &b.colour),
                                       std::make_tuple("depth", &a.depth, &b.depth),
                                       std::make_tuple("alpha", &a.alpha, &b.alpha),
                                       std::make_tuple("features", &a.features, &b.features)}) {
      const auto [worst, beyond] = compare(*pb, *pa, 1e-3);
      EXPECT_LT(worst, 2e-2) << name;               // no pixel far off anywhere
      EXPECT_LE(beyond, pa->size() / 1000) << name;  // and all but a few within float rounding
    }
    // The median depth jumps where the transmittance crosses 0.5 within rounding: a few pixels
    // may take the neighbouring splat's depth.
    const auto [worst_median, beyond_median] = compare(b.median_depth, a.median_depth, 1e-3);
    EXPECT_LE(beyond_median, pixels / 500) << "worst " << worst_median;
    std::size_t visible = 0, flipped = 0;
    ASSERT_EQ(b.visible.size(), a.visible.size());
    for (std::size_t i = 0; i < a.visible.size(); ++i) {
      visible += a.visible[i];
      flipped += a.visible[i] != b.visible[i];
    }
    // A Gaussian right at a culling bound (opacity, footprint, image edge) may fall either way.
    EXPECT_LE(flipped, 1 + visible / 1000) << "Gaussians culled by one and not the other";
    EXPECT_NEAR(static_cast<double>(b.stats.visible), static_cast<double>(visible), 1.0 + 1e-3 * visible);
    EXPECT_NEAR(static_cast<double>(b.stats.tile_entries), static_cast<double>(a.tile_entries),
                1e-3 * a.tile_entries);
    EXPECT_NEAR(static_cast<double>(b.stats.blend_steps), static_cast<double>(a.blend_steps), 1e-3 * a.blend_steps);
  }
}

// The backward pass runs the same splat-pixel step (math::splat_pair_backward) and projection
// backward; only float rounding (and on the GPU, the summation order of atomics) differ.
TEST_P(RasterizerBackend, BackwardMatchesTheDoublePrecisionAlgorithm) {
  const auto rasterizer = make();
  if (!rasterizer) return;
  const core::GaussianMap map = random_map(5000);
  core::RenderSettings settings;
  settings.background = {0.1f, 0.2f, 0.3f};
  core::RenderView view;
  view.camera = core::PinholeCamera{300.0, 300.0, 159.5, 119.5, 321, 243};
  std::string why;
  core::RenderResult b;
  ASSERT_TRUE(rasterizer->forward(map, view, settings, &b, &why)) << why;
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
  core::GaussianGradients gb;
  ASSERT_TRUE(rasterizer->backward(map, view, settings, b, g, &gb, &why)) << why;
  const Reference a = reference(map, view, settings, &g);
  for (const auto& [name, x, y] :
       {std::make_tuple("means", &a.means, &gb.means), std::make_tuple("rotations", &a.rotations, &gb.rotations),
        std::make_tuple("log_scales", &a.log_scales, &gb.log_scales),
        std::make_tuple("opacity_logits", &a.opacity_logits, &gb.opacity_logits),
        std::make_tuple("sh", &a.sh, &gb.sh), std::make_tuple("features", &a.g_features, &gb.features),
        std::make_tuple("importance_rgb", &a.importance_rgb, &gb.importance_rgb),
        std::make_tuple("importance_feature", &a.importance_feature, &gb.importance_feature)}) {
    double norm = 0;
    for (double v : *x) norm += v * v;
    ASSERT_GT(norm, 0.0) << name << ": the premise, a gradient to compare";
    EXPECT_LT(relative_difference(*y, *x), 2e-3) << name;
  }
}

// A backward state no rasteriser made.
struct ForeignState final : core::RenderBackwardState {};

// One opaque Gaussian renders where it should and its gradients point the right way; bad views,
// maps, gradients and forward states are clear errors.
TEST_P(RasterizerBackend, RendersAndRejectsBadInput) {
  const auto rasterizer = make();
  if (!rasterizer) return;
  core::GaussianMap map;
  map.feature_dim = 2;
  const float mean[3] = {0.f, 0.f, 2.f}, rot[4] = {1.f, 0.f, 0.f, 0.f};
  const float ls[3] = {std::log(0.1f), std::log(0.1f), std::log(0.1f)};
  const float sh[3] = {0.5f, 0.5f, 0.5f}, feat[2] = {1.f, -1.f};
  map.push_back(mean, rot, ls, 2.0f, sh, feat);
  core::RenderView view;
  view.camera = core::PinholeCamera{50, 50, 31.5, 23.5, 64, 48};
  core::RenderResult result;
  std::string why;
  ASSERT_TRUE(rasterizer->forward(map, view, core::RenderSettings{}, &result, &why)) << why;
  EXPECT_EQ(result.colour.channels, 3);
  EXPECT_EQ(result.features.channels, 2);
  EXPECT_GT(result.alpha.at(0, 23, 31), 0.8f);
  EXPECT_NEAR(result.features.at(0, 23, 31) / result.alpha.at(0, 23, 31), 1.0f, 1e-5f);
  EXPECT_GT(result.stats.blend_steps, 0u);

  core::RenderGradients rg;
  rg.colour = core::PlanarImage(64, 48, 3, 1.0f);
  core::GaussianGradients grads;
  ASSERT_TRUE(rasterizer->backward(map, view, core::RenderSettings{}, result, rg, &grads, &why)) << why;
  EXPECT_GT(grads.opacity_logits[0], 0.0f);  // more opacity, more colour on every pixel
  rg.colour = core::PlanarImage(10, 10, 3, 1.0f);
  EXPECT_FALSE(rasterizer->backward(map, view, core::RenderSettings{}, result, rg, &grads, &why));
  EXPECT_NE(why.find("wrong shape"), std::string::npos) << why;
  rg.colour = core::PlanarImage(64, 48, 3, 1.0f);
  core::RenderResult foreign = result;
  foreign.backward_state = std::make_shared<ForeignState>();
  EXPECT_FALSE(rasterizer->backward(map, view, core::RenderSettings{}, foreign, rg, &grads, &why));
  EXPECT_NE(why.find("not from the"), std::string::npos) << why;

  core::RenderView bad = view;
  bad.camera.fx = 0;
  EXPECT_FALSE(rasterizer->forward(map, bad, core::RenderSettings{}, &result, &why));
  EXPECT_NE(why.find("render view"), std::string::npos) << why;
  map.means[0] = std::nanf("");
  EXPECT_FALSE(rasterizer->forward(map, view, core::RenderSettings{}, &result, &why));
  EXPECT_NE(why.find("non-finite"), std::string::npos) << why;
}

INSTANTIATE_TEST_SUITE_P(Compiled, RasterizerBackend, ::testing::ValuesIn(compiled_backends()),
                         [](const auto& info) { return info.param; });

}  // namespace
}  // namespace fslam::server
