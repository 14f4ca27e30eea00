// The rasteriser's algorithm (core/render/rasterize_impl.hpp, the stages every backend runs)
// against a per-pixel reference, analytic cases of the camera-plane depth, and every gradient
// against central finite differences in double precision. The backends themselves (CPU, CUDA),
// reached through the backend factory, are one suite: tests/unit/server/rasterizer_backends_test.cpp.
#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include "fslam/core/render/rasterize_impl.hpp"
#include "fslam/core/render/rasterizer.hpp"

namespace fslam::core {
namespace {

using render_impl::RasterOutputGrads;
using render_impl::RasterOutputs;
using render_impl::RasterState;
using render_impl::SceneGrads;
using render_impl::SplatScene;

// A map in double precision (GaussianMap is float).
struct Scene {
  int sh_degree = 0;
  int feature_dim = 0;
  std::vector<double> means, rotations, log_scales, opacity_logits, sh, features, filter_3d;
  std::size_t size() const { return opacity_logits.size(); }
  SplatScene<double> view() const {
    return math::splat_scene_of<double>(*this, size(), sh_degree, feature_dim, !filter_3d.empty());
  }
  // This scene's arrays as the gradients a backward pass adds into (importance not asked for).
  SceneGrads<double> as_grads() {
    SceneGrads<double> g;
    g.means = means.data();
    g.rotations = rotations.data();
    g.log_scales = log_scales.data();
    g.opacity_logits = opacity_logits.data();
    g.sh = sh.data();
    g.features = features.empty() ? nullptr : features.data();
    return g;
  }
  std::vector<std::pair<std::string, std::vector<double>*>> params() {
    return {{"means", &means},          {"rotations", &rotations}, {"log_scales", &log_scales},
            {"opacity_logits", &opacity_logits}, {"sh", &sh},      {"features", &features}};
  }
};

math::SplatCamera<double> make_camera(int width, int height, double yaw = 0.0) {
  math::SplatCamera<double> cam{};
  const double c = std::cos(yaw), s = std::sin(yaw);
  const double R[9] = {c, 0, s, 0, 1, 0, -s, 0, c};
  for (int k = 0; k < 9; ++k) cam.R[k] = R[k];
  cam.t[0] = 0.05;
  cam.t[1] = -0.02;
  cam.t[2] = 0.1;
  cam.fx = 0.9 * width;
  cam.fy = 0.9 * width;
  cam.cx = 0.5 * width - 0.3;
  cam.cy = 0.5 * height + 0.2;
  cam.near_plane = 0.05;
  cam.width = width;
  cam.height = height;
  return cam;
}

// Gaussians between 1.5 and 3 m in front of the camera, overlapping each other, opacities low
// enough that no alpha reaches the 0.99 clamp and no pixel terminates early.
Scene make_scene(int count, int sh_degree, int feature_dim, bool filter, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Scene s;
  s.sh_degree = sh_degree;
  s.feature_dim = feature_dim;
  const int K = (sh_degree + 1) * (sh_degree + 1);
  for (int i = 0; i < count; ++i) {
    const double z = 2.2 + 0.7 * u(rng);
    s.means.insert(s.means.end(), {0.35 * z * u(rng), 0.25 * z * u(rng), z});
    s.rotations.insert(s.rotations.end(), {1.0 + 0.3 * u(rng), 0.5 * u(rng), 0.5 * u(rng), 0.5 * u(rng)});
    s.log_scales.insert(s.log_scales.end(), {std::log(0.12 + 0.08 * u(rng)),
                                             std::log(0.09 + 0.05 * u(rng)),
                                             std::log(0.05 + 0.03 * u(rng))});
    s.opacity_logits.push_back(0.2 * u(rng));  // opacity 0.45..0.55
    for (int k = 0; k < 3 * K; ++k) s.sh.push_back(k < 3 ? 0.8 * u(rng) : 0.3 * u(rng));
    for (int c = 0; c < feature_dim; ++c) s.features.push_back(u(rng));
    if (filter) s.filter_3d.push_back(0.0004 * (1.5 + u(rng)));
  }
  return s;
}

struct Images {
  std::vector<double> colour, depth, median, alpha, features;
  Images(int w, int h, int d)
      : colour(3 * w * h), depth(w * h), median(w * h), alpha(w * h), features(d * w * h) {}
  RasterOutputs<double> outputs() {
    RasterOutputs<double> o;
    o.colour = colour.data();
    o.depth = depth.data();
    o.median_depth = median.data();
    o.alpha = alpha.data();
    o.features = features.empty() ? nullptr : features.data();
    return o;
  }
};

const double kBackground[3] = {0.2, 0.1, 0.3};

TEST(Rasterizer, TiledForwardEqualsPerPixelReference) {
  const Scene scene = make_scene(40, 1, 3, true, 7);
  const auto cam = make_camera(45, 37, 0.1);  // not a multiple of the tile size
  Images tiled(45, 37, 3), ref(45, 37, 3);
  RasterState<double> st;
  render_impl::rasterize_forward(scene.view(), cam, kBackground, true, &st, tiled.outputs());
  render_impl::rasterize_reference(scene.view(), cam, kBackground, ref.outputs());
  EXPECT_GT(st.visible, 30u);
  double coverage = 0.0;
  for (double a : tiled.alpha) coverage += a;
  EXPECT_GT(coverage / tiled.alpha.size(), 0.15);
  // Equal up to rounding: the tiled pass runs rows of pixels as lanes, and the compiler may fuse
  // their multiply-adds differently from the reference's scalar code.
  auto same = [](const std::vector<double>& a, const std::vector<double>& b, const char* what) {
    ASSERT_EQ(a.size(), b.size());
    for (std::size_t i = 0; i < a.size(); ++i) {
      ASSERT_NEAR(a[i], b[i], 1e-12 * (1.0 + std::abs(b[i]))) << what << "[" << i << "]";
    }
  };
  same(tiled.colour, ref.colour, "colour");
  same(tiled.depth, ref.depth, "depth");
  same(tiled.median, ref.median, "median depth");
  same(tiled.alpha, ref.alpha, "alpha");
  same(tiled.features, ref.features, "features");
}

// Production precision: float lanes with the vectorised exp (math/lanes.hpp) against the
// scalar reference with the C library's expf, on the same scene.
TEST(Rasterizer, FloatLanesMatchTheScalarReference) {
  const Scene scene = make_scene(60, 1, 4, true, 9);
  struct FloatScene {
    std::vector<float> means, rotations, log_scales, opacity_logits, sh, features, filter_3d;
  } fs;
  auto to_float = [](const std::vector<double>& v) { return std::vector<float>(v.begin(), v.end()); };
  fs.means = to_float(scene.means);
  fs.rotations = to_float(scene.rotations);
  fs.log_scales = to_float(scene.log_scales);
  fs.opacity_logits = to_float(scene.opacity_logits);
  fs.sh = to_float(scene.sh);
  fs.features = to_float(scene.features);
  fs.filter_3d = to_float(scene.filter_3d);
  const SplatScene<float> view = math::splat_scene_of<float>(fs, scene.size(), 1, 4, true);
  const auto dcam = make_camera(70, 53, -0.05);
  math::SplatCamera<float> cam{};
  for (int k = 0; k < 9; ++k) cam.R[k] = static_cast<float>(dcam.R[k]);
  for (int k = 0; k < 3; ++k) cam.t[k] = static_cast<float>(dcam.t[k]);
  cam.fx = static_cast<float>(dcam.fx);
  cam.fy = static_cast<float>(dcam.fy);
  cam.cx = static_cast<float>(dcam.cx);
  cam.cy = static_cast<float>(dcam.cy);
  cam.near_plane = 0.05f;
  cam.width = 70;
  cam.height = 53;
  const std::size_t plane = 70 * 53;
  std::vector<float> colour(3 * plane), depth(plane), median(plane), alpha(plane), features(4 * plane);
  std::vector<float> rcolour(3 * plane), rdepth(plane), rmedian(plane), ralpha(plane), rfeatures(4 * plane);
  const float background[3] = {0.2f, 0.1f, 0.3f};
  RasterState<float> st;
  render_impl::rasterize_forward(view, cam, background, true, &st,
                                 {colour.data(), depth.data(), median.data(), alpha.data(), features.data()});
  render_impl::rasterize_reference(view, cam, background,
                                   {rcolour.data(), rdepth.data(), rmedian.data(), ralpha.data(), rfeatures.data()});
  ASSERT_GT(st.blend_steps, 10000u);
  double worst = 0.0;
  auto compare = [&](const std::vector<float>& a, const std::vector<float>& b) {
    for (std::size_t i = 0; i < a.size(); ++i) worst = std::max(worst, std::abs(double(a[i]) - b[i]));
  };
  compare(colour, rcolour);
  compare(depth, rdepth);
  compare(alpha, ralpha);
  compare(features, rfeatures);
  EXPECT_LT(worst, 2e-5);  // a few float ulps of values of order 1 (colour, metres, opacity)
  // The median depth is a choice (the splat where opacity first passes 0.5): rounding may move
  // it to the neighbouring splat on a rare pixel, never far.
  std::size_t moved = 0;
  for (std::size_t i = 0; i < plane; ++i) moved += std::abs(median[i] - rmedian[i]) > 1e-4f;
  EXPECT_LE(moved, plane / 500);
}

// An off-centre principal point: a crop of a view is the same pinhole with the principal point
// moved by the crop's corner, and it renders the window of the whole view, also where the
// principal point lies outside the crop. The scene keeps the Gaussians centred near the crop, so
// that no Jacobian is clamped to the view (math::clamp_to_view) in either render.
TEST(Rasterizer, CropRendersTheWindowOfTheWholeView) {
  const auto whole = make_camera(48, 40, -0.05);
  for (const auto& [x0, y0] : {std::pair{14, 6}, std::pair{30, 26}}) {  // the second misses (cx, cy)
    const int w = 17, h = 13;
    Scene all = make_scene(200, 0, 2, true, 11), scene = all;
    scene.means.clear(), scene.rotations.clear(), scene.log_scales.clear();
    scene.opacity_logits.clear(), scene.sh.clear(), scene.features.clear(), scene.filter_3d.clear();
    for (std::size_t i = 0; i < all.size(); ++i) {
      const double* m = &all.means[3 * i];
      double c[3];
      for (int r = 0; r < 3; ++r)
        c[r] = whole.R[3 * r] * m[0] + whole.R[3 * r + 1] * m[1] + whole.R[3 * r + 2] * m[2] + whole.t[r];
      const double u = whole.fx * c[0] / c[2] + whole.cx, v = whole.fy * c[1] / c[2] + whole.cy;
      if (u < x0 - 2 || u > x0 + w + 1 || v < y0 - 1.5 || v > y0 + h + 1) continue;
      auto copy = [&](const std::vector<double>& from, std::vector<double>* to, int k) {
        to->insert(to->end(), from.begin() + k * i, from.begin() + k * (i + 1));
      };
      copy(all.means, &scene.means, 3);
      copy(all.rotations, &scene.rotations, 4);
      copy(all.log_scales, &scene.log_scales, 3);
      copy(all.opacity_logits, &scene.opacity_logits, 1);
      copy(all.sh, &scene.sh, 3);
      copy(all.features, &scene.features, 2);
      copy(all.filter_3d, &scene.filter_3d, 1);
    }
    ASSERT_GT(scene.size(), 3u);
    Images full(48, 40, 2), part(w, h, 2);
    RasterState<double> st;
    render_impl::rasterize_forward(scene.view(), whole, kBackground, true, &st, full.outputs());
    auto crop = whole;
    crop.cx -= x0;
    crop.cy -= y0;
    crop.width = w;
    crop.height = h;
    render_impl::rasterize_forward(scene.view(), crop, kBackground, true, &st, part.outputs());
    double max_diff = 0.0, coverage = 0.0;
    for (int v = 0; v < h; ++v)
      for (int u = 0; u < w; ++u) {
        const int p = v * w + u, q = (v + y0) * 48 + (u + x0);
        for (int c = 0; c < 3; ++c)
          max_diff = std::max(max_diff, std::abs(part.colour[c * w * h + p] - full.colour[c * 1920 + q]));
        max_diff = std::max(max_diff, std::abs(part.median[p] - full.median[q]));
        max_diff = std::max(max_diff, std::abs(part.features[w * h + p] - full.features[1920 + q]));
        coverage += part.alpha[p] / (w * h);
      }
    EXPECT_GT(coverage, 0.15) << "crop at " << x0 << "," << y0;
    EXPECT_LT(max_diff, 1e-9) << "crop at " << x0 << "," << y0;
  }
}

// One flat (disc) Gaussian: its camera-plane depth must follow the disc's plane, unlike the
// constant per-Gaussian depth of eq. old_depth.
TEST(Rasterizer, PlanarDepthFollowsTiltedDisc) {
  Scene s;
  s.sh_degree = 0;
  const double tilt = 0.6;  // radians about the camera's y axis
  s.means = {0.05, -0.03, 2.0};
  s.rotations = {std::cos(tilt / 2), 0.0, std::sin(tilt / 2), 0.0};
  s.log_scales = {std::log(0.3), std::log(0.3), std::log(1e-4)};
  s.opacity_logits = {8.0};
  s.sh = {1.0, 1.0, 1.0};
  math::SplatCamera<double> cam = make_camera(64, 48);
  for (int k = 0; k < 9; ++k) cam.R[k] = (k % 4 == 0) ? 1.0 : 0.0;
  cam.t[0] = cam.t[1] = cam.t[2] = 0.0;
  cam.fx = cam.fy = 400.0;  // a Kinect-like 0.14 degrees per pixel
  Images img(64, 48, 0);
  RasterState<double> st;
  render_impl::rasterize_forward(s.view(), cam, kBackground, false, &st, img.outputs());
  // Disc normal n = R_y(tilt) e_z; the ray through pixel (u, v) meets the plane at
  // z = (n . mu) / (n . r), r = ((u - cx) / fx, (v - cy) / fy, 1).
  const double n[3] = {std::sin(tilt), 0.0, std::cos(tilt)};
  const double nd = n[0] * s.means[0] + n[1] * s.means[1] + n[2] * s.means[2];
  const double u0 = cam.fx * s.means[0] / s.means[2] + cam.cx;
  const double v0 = cam.fy * s.means[1] / s.means[2] + cam.cy;
  int checked = 0;
  for (int dv = -3; dv <= 3; ++dv) {
    for (int du = -3; du <= 3; ++du) {
      const int u = static_cast<int>(std::lround(u0)) + du, v = static_cast<int>(std::lround(v0)) + dv;
      const double r[3] = {(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0};
      const double plane_z = nd / (n[0] * r[0] + n[1] * r[1] + n[2] * r[2]);
      const std::size_t pix = static_cast<std::size_t>(v) * 64 + u;
      ASSERT_GT(img.median[pix], 0.0);
      // First-order expansion: the error grows with the square of the offset,
      // about z tan^2(tilt) (offset / fx)^2: 0.05 mm at 3 px, 6 um at 1 px.
      EXPECT_NEAR(img.median[pix], plane_z, 1e-4) << "pixel " << u << "," << v;
      if (std::abs(du) <= 1 && std::abs(dv) <= 1) {
        EXPECT_NEAR(img.median[pix], plane_z, 1e-5);
      }
      ++checked;
    }
  }
  EXPECT_EQ(checked, 49);
  // A constant per-Gaussian depth would be off by the slope, about z tan(0.6) / fx per pixel.
  const std::size_t centre = static_cast<std::size_t>(std::lround(v0)) * 64 + std::lround(u0);
  EXPECT_GT(std::abs(img.median[centre + 3] - img.median[centre]), 0.008);
}

TEST(Rasterizer, OpaqueGaussianColourAndMedian) {
  Scene s;
  s.means = {0.0, 0.0, 1.5};
  s.rotations = {1.0, 0.0, 0.0, 0.0};
  s.log_scales = {std::log(0.2), std::log(0.2), std::log(0.2)};
  s.opacity_logits = {20.0};  // opacity ~1 -> alpha clamps at 0.99
  s.sh = {rgb_to_sh_dc(0.8f), rgb_to_sh_dc(0.4f), rgb_to_sh_dc(0.1f)};
  math::SplatCamera<double> cam = make_camera(32, 32);
  for (int k = 0; k < 9; ++k) cam.R[k] = (k % 4 == 0) ? 1.0 : 0.0;
  cam.t[0] = cam.t[1] = cam.t[2] = 0.0;
  cam.cx = cam.cy = 16.0;
  Images img(32, 32, 0);
  RasterState<double> st;
  const double black[3] = {0, 0, 0};
  render_impl::rasterize_forward(s.view(), cam, black, false, &st, img.outputs());
  const std::size_t c = 16 * 32 + 16;
  const double a = math::kAlphaMax;  // the clamp, 0.99 in float
  EXPECT_NEAR(img.alpha[c], a, 1e-12);
  EXPECT_NEAR(img.colour[c], a * 0.8, 1e-6);
  EXPECT_NEAR(img.colour[1024 + c], a * 0.4, 1e-6);
  EXPECT_NEAR(img.colour[2048 + c], a * 0.1, 1e-6);
  EXPECT_NEAR(img.median[c], 1.5, 1e-9);        // isotropic: flat depth field at the centre
  EXPECT_NEAR(img.depth[c], a * 1.5, 1e-9);     // expected depth is not normalised by alpha
}

// Loss = sum over outputs of <weights, output>; the gradient images are the weights.
struct LinearLoss {
  std::vector<double> colour, depth, median, alpha, features;
  double operator()(const Images& im) const {
    double sum = 0.0;
    auto dot = [&](const std::vector<double>& w, const std::vector<double>& x) {
      for (std::size_t i = 0; i < w.size(); ++i) sum += w[i] * x[i];
    };
    dot(colour, im.colour);
    dot(depth, im.depth);
    dot(median, im.median);
    dot(alpha, im.alpha);
    dot(features, im.features);
    return sum;
  }
  RasterOutputGrads<double> grads() const {
    auto p = [](const std::vector<double>& v) { return v.empty() ? nullptr : v.data(); };
    RasterOutputGrads<double> g;
    g.colour = p(colour);
    g.depth = p(depth);
    g.median_depth = p(median);
    g.alpha = p(alpha);
    g.features = p(features);
    return g;
  }
};

// Weights in [-1, 1] from `seed` for the outputs switched on (drawn in this order).
LinearLoss random_linear_loss(int W, int H, int D, unsigned seed, bool colour, bool depth, bool median, bool alpha,
                              bool features) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto random = [&](std::size_t n) {
    std::vector<double> v(n);
    for (double& x : v) x = u(rng);
    return v;
  };
  const std::size_t plane = static_cast<std::size_t>(W) * H;
  LinearLoss loss;
  if (colour) loss.colour = random(3 * plane);
  if (depth) loss.depth = random(plane);
  if (median) loss.median = random(plane);
  if (alpha) loss.alpha = random(plane);
  if (features) loss.features = random(static_cast<std::size_t>(D) * plane);
  return loss;
}

struct GradCase {
  const char* name;
  int sh_degree;
  int feature_dim;
  bool filter;
  bool colour, depth, median, alpha, features;
};

class RasterizerGradient : public ::testing::TestWithParam<GradCase> {};

TEST_P(RasterizerGradient, MatchesCentralDifferences) {
  const GradCase& gc = GetParam();
  const int W = 24, H = 20;
  Scene scene = make_scene(7, gc.sh_degree, gc.feature_dim, gc.filter, 11);
  const auto cam = make_camera(W, H, 0.05);
  const LinearLoss loss =
      random_linear_loss(W, H, gc.feature_dim, 3, gc.colour, gc.depth, gc.median, gc.alpha, gc.features);

  auto evaluate = [&](const Scene& s) {
    Images im(W, H, s.feature_dim);
    RasterState<double> st;
    render_impl::rasterize_forward(s.view(), cam, kBackground, true, &st, im.outputs());
    return loss(im);
  };
  Images im(W, H, scene.feature_dim);
  RasterState<double> st;
  render_impl::rasterize_forward(scene.view(), cam, kBackground, true, &st, im.outputs());
  ASSERT_GE(st.visible, 6u);
  Scene grad = scene;
  for (auto& [name, values] : grad.params()) std::fill(values->begin(), values->end(), 0.0);
  render_impl::rasterize_backward(scene.view(), cam, kBackground, true, st, im.outputs(),
                                  loss.grads(), grad.as_grads());

  auto params = scene.params();
  auto analytic = grad.params();
  int nonzero = 0;
  for (std::size_t p = 0; p < params.size(); ++p) {
    std::vector<double>& values = *params[p].second;
    for (std::size_t k = 0; k < values.size(); ++k) {
      const double saved = values[k];
      const double h = 1e-6;
      values[k] = saved + h;
      const double up = evaluate(scene);
      values[k] = saved - h;
      const double down = evaluate(scene);
      values[k] = saved;
      const double fd = (up - down) / (2 * h);
      const double a = (*analytic[p].second)[k];
      EXPECT_NEAR(a, fd, 1e-6 + 1e-5 * std::abs(fd))
          << gc.name << ": d/d " << params[p].first << "[" << k << "]";
      if (std::abs(fd) > 1e-4) ++nonzero;
    }
  }
  EXPECT_GT(nonzero, 10) << "the test must exercise real gradients";
}

INSTANTIATE_TEST_SUITE_P(
    Outputs, RasterizerGradient,
    ::testing::Values(GradCase{"colour", 0, 0, false, true, false, false, false, false},
                      GradCase{"colour_sh1_filter", 1, 0, true, true, false, false, false, false},
                      GradCase{"colour_sh2", 2, 0, false, true, false, false, false, false},
                      GradCase{"colour_sh3", 3, 0, true, true, false, false, false, false},
                      GradCase{"expected_depth", 0, 0, true, false, true, false, false, false},
                      GradCase{"median_depth", 0, 0, false, false, false, true, false, false},
                      GradCase{"alpha", 0, 0, true, false, false, false, true, false},
                      GradCase{"features", 0, 4, false, false, false, false, false, true},
                      GradCase{"everything", 1, 3, true, true, true, true, true, true}),
    [](const auto& info) { return std::string(info.param.name); });

// The backward pass sums a Gaussian's per-tile gradients in tile order whichever thread ran
// which tile, so its gradients are the same bit for bit at any thread count and on every run
// (a map, and every figure measured on one, reproduces). 200 Gaussians over 10 x 8 tiles, most
// spanning several tiles.
TEST(Rasterizer, BackwardIsTheSameAtAnyThreadCount) {
  const int W = 160, H = 120;
  const Scene scene = make_scene(200, 1, 5, true, 21);
  const auto cam = make_camera(W, H, 0.03);
  const LinearLoss loss = random_linear_loss(W, H, 5, 4, true, true, true, true, true);
  auto gradients = [&](int threads) {
    Scene grad = scene;
    for (auto& [name, values] : grad.params()) std::fill(values->begin(), values->end(), 0.0);
    std::vector<double> importance(2 * scene.size(), 0.0);
    tbb::task_arena arena(threads);
    arena.execute([&] {
      Images im(W, H, scene.feature_dim);
      RasterState<double> st;
      render_impl::rasterize_forward(scene.view(), cam, kBackground, true, &st, im.outputs());
      SceneGrads<double> g = grad.as_grads();
      g.importance_rgb = importance.data();
      g.importance_feature = importance.data() + scene.size();
      render_impl::rasterize_backward(scene.view(), cam, kBackground, true, st, im.outputs(), loss.grads(), g);
      EXPECT_GT(st.tile_ids.size(), 2 * st.visible) << "Gaussians must span several tiles";
    });
    grad.filter_3d = importance;  // compared with the rest
    return grad;
  };
  Scene one = gradients(1);
  int nonzero = 0;
  for (double m : one.means) nonzero += m != 0.0;
  EXPECT_GT(nonzero, 300);
  for (int threads : {4, 2, 4}) {
    Scene many = gradients(threads);
    auto a = one.params(), b = many.params();
    a.emplace_back("importance", &one.filter_3d);
    b.emplace_back("importance", &many.filter_3d);
    for (std::size_t p = 0; p < a.size(); ++p) {
      ASSERT_EQ(a[p].second->size(), b[p].second->size());
      std::size_t differ = 0;
      for (std::size_t k = 0; k < a[p].second->size(); ++k) differ += (*a[p].second)[k] != (*b[p].second)[k];
      EXPECT_EQ(differ, 0u) << a[p].first << " at " << threads << " threads";
    }
  }
}

// Eq. importance on a one-pixel image: sum_x |dL/dalpha_i(x)| is |dL/dalpha_i| there, which
// follows from the opacity-logit gradient: dL/dlogit = dL/dalpha * G * coef * s (1 - s).
TEST(Rasterizer, ImportanceIsAbsoluteAlphaGradient) {
  Scene scene = make_scene(3, 0, 2, false, 5);
  math::SplatCamera<double> cam = make_camera(1, 1);
  for (int k = 0; k < 9; ++k) cam.R[k] = (k % 4 == 0) ? 1.0 : 0.0;
  cam.t[0] = cam.t[1] = cam.t[2] = 0.0;
  cam.cx = cam.cy = 0.0;
  cam.fx = cam.fy = 40.0;
  for (std::size_t i = 0; i < scene.size(); ++i) {
    scene.means[3 * i] = 0.01 * static_cast<double>(i);
    scene.means[3 * i + 1] = -0.01;
  }
  Images im(1, 1, 2);
  RasterState<double> st;
  render_impl::rasterize_forward(scene.view(), cam, kBackground, true, &st, im.outputs());
  ASSERT_EQ(st.visible, 3u);
  const std::vector<double> gcol = {0.7, -0.2, 0.4}, gfeat = {0.0, 0.0};
  RasterOutputGrads<double> go;
  go.colour = gcol.data();
  go.features = gfeat.data();
  std::vector<double> means(9), rot(12), ls(9), op(3), sh(9), feat(6), imp_rgb(3), imp_feat(3);
  SceneGrads<double> g{means.data(), rot.data(), ls.data(), op.data(), sh.data(), feat.data(),
                       imp_rgb.data(), imp_feat.data()};
  render_impl::rasterize_backward(scene.view(), cam, kBackground, true, st, im.outputs(), go, g);
  for (std::size_t i = 0; i < 3; ++i) {
    const auto& pg = st.projected[i];
    double gauss = 0.0;
    const double alpha = math::splat_alpha(pg, 0.0, 0.0, &gauss);
    ASSERT_GT(alpha, 0.0);
    const double s = math::sigmoid(scene.opacity_logits[i]);
    const double g_alpha = op[i] / (gauss * s * (1 - s));
    EXPECT_NEAR(imp_rgb[i], std::abs(g_alpha), 1e-9 + 1e-7 * std::abs(g_alpha));
    EXPECT_GT(imp_rgb[i], 1e-4);
    EXPECT_EQ(imp_feat[i], 0.0);  // zero feature gradient: no feature importance
  }
}

}  // namespace
}  // namespace fslam::core
