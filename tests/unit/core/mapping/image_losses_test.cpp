#include "fslam/core/mapping/image_losses.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <functional>
#include <iostream>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/core/mapping/image_losses_impl.hpp"
#include "fslam/core/math/loss_math.hpp"
#include "fslam/core/math/ssim.hpp"

namespace fslam::core {
namespace {

using Buffer = std::vector<double>;

// Small odd-sized images so that every border case of the windows and blocks shows up.
constexpr int kW = 13, kH = 11;
constexpr std::size_t kPixels = static_cast<std::size_t>(kW) * kH;
const math::Intrinsics kIntrinsics{20.0f, 22.0f, 6.3f, 4.8f};

Buffer uniform(std::size_t n, double lo, double hi, std::mt19937& rng) {
  std::uniform_real_distribution<double> d(lo, hi);
  Buffer b(n);
  for (double& x : b) x = d(rng);
  return b;
}

// Mask [H, W] with about `fraction` of the pixels set to 1 (the rest 0).
Buffer random_mask(double fraction, std::mt19937& rng) {
  std::bernoulli_distribution keep(fraction);
  Buffer m(kPixels);
  for (double& x : m) x = keep(rng) ? 1.0 : 0.0;
  return m;
}

PlanarImage to_image(const Buffer& b, int channels) {
  PlanarImage img(kW, kH, channels);
  for (std::size_t i = 0; i < b.size(); ++i) img.data[i] = static_cast<float>(b[i]);
  return img;
}

// Checks `analytic` (dLoss/dx) against central differences of loss(x) at every element of x.
// h = 1e-6 keeps truncation (~h^2) and rounding (~1e-16 / h) errors below 1e-9 of the loss.
void expect_gradient_matches(const std::function<double(const Buffer&)>& loss, Buffer x,
                             const Buffer& analytic, const char* what) {
  ASSERT_EQ(x.size(), analytic.size());
  constexpr double kStep = 1e-6;
  int checked_non_zero = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double x0 = x[i];
    x[i] = x0 + kStep;
    const double up = loss(x);
    x[i] = x0 - kStep;
    const double down = loss(x);
    x[i] = x0;
    const double numeric = (up - down) / (2.0 * kStep);
    const double err = std::abs(numeric - analytic[i]);
    const double scale = std::max(std::abs(numeric), std::abs(analytic[i]));
    EXPECT_TRUE(err < 1e-8 || err < 1e-5 * scale)
        << what << ": element " << i << " analytic " << analytic[i] << " numeric " << numeric;
    checked_non_zero += std::abs(analytic[i]) > 1e-8 ? 1 : 0;
  }
  EXPECT_GT(checked_non_zero, 0) << what << ": a gradient of zeros proves nothing";
}

// ---- L1 ----------------------------------------------------------------------------------------

TEST(L1Loss, MaskedMeanAndGradientMatchFiniteDifferences) {
  std::mt19937 rng(1);
  constexpr int kC = 3;
  const Buffer observed = uniform(kC * kPixels, 0.0, 1.0, rng);
  const Buffer rendered = uniform(kC * kPixels, 0.0, 1.0, rng);
  const Buffer mask = random_mask(0.6, rng);
  constexpr double kWeight = 0.8;

  double direct = 0.0;
  int counted = 0;
  for (int c = 0; c < kC; ++c)
    for (std::size_t i = 0; i < kPixels; ++i)
      if (mask[i] > 0.5) {
        direct += std::abs(rendered[c * kPixels + i] - observed[c * kPixels + i]);
        ++counted;
      }
  direct = kWeight * direct / counted;

  Buffer grad(rendered.size(), 0.0);
  const double value = loss_impl::l1_loss(rendered.data(), observed.data(), mask.data(), kC,
                                          kPixels, false, kWeight, grad.data());
  EXPECT_NEAR(value, direct, 1e-14);
  for (std::size_t i = 0; i < kPixels; ++i) {
    if (mask[i] <= 0.5) {
      EXPECT_EQ(grad[i], 0.0) << "masked pixel " << i;
    }
  }
  expect_gradient_matches(
      [&](const Buffer& x) {
        return loss_impl::l1_loss<double>(x.data(), observed.data(), mask.data(), kC, kPixels,
                                          false, kWeight, nullptr);
      },
      rendered, grad, "L1");
}

TEST(L1Loss, ConstantOffsetCostsTheOffsetAndGradientsAccumulate) {
  std::mt19937 rng(2);
  const Buffer observed = uniform(2 * kPixels, 0.0, 1.0, rng);
  Buffer shifted(observed);
  for (double& x : shifted) x += 0.125;  // exact in float
  const PlanarImage obs = to_image(observed, 2), ren = to_image(shifted, 2);
  double loss = 0.0;
  PlanarImage grad;
  std::string why;
  ASSERT_TRUE(l1_loss(ren, obs, nullptr, 2.0, &loss, &grad, &why)) << why;
  EXPECT_NEAR(loss, 2.0 * 0.125, 1e-6);
  ASSERT_TRUE(grad.same_shape(ren));
  const float expected = static_cast<float>(2.0 / (2 * kPixels));
  for (float g : grad.data) EXPECT_FLOAT_EQ(g, expected);
  // A second call adds into the same buffer (the mapper sums several terms).
  ASSERT_TRUE(l1_loss(ren, obs, nullptr, 2.0, &loss, &grad, &why)) << why;
  for (float g : grad.data) EXPECT_FLOAT_EQ(g, 2.0f * expected);
}

TEST(DepthL1Loss, SkipsMissingObservedDepthAndMaskedPixels) {
  std::mt19937 rng(3);
  Buffer observed = uniform(kPixels, 0.5, 4.0, rng);
  observed[5] = 0.0;  // sensor holes
  observed[17] = std::nan("");
  observed[40] = INFINITY;
  observed[41] = -1.0;
  const Buffer rendered = uniform(kPixels, 0.5, 4.0, rng);
  const Buffer mask = random_mask(0.7, rng);

  double direct = 0.0;
  int counted = 0;
  for (std::size_t i = 0; i < kPixels; ++i)
    if (mask[i] > 0.5 && observed[i] > 0.0 && std::isfinite(observed[i])) {
      direct += std::abs(rendered[i] - observed[i]);
      ++counted;
    }
  direct /= counted;

  Buffer grad(kPixels, 0.0);
  const double value = loss_impl::l1_loss(rendered.data(), observed.data(), mask.data(), 1, kPixels,
                                          true, 1.0, grad.data());
  EXPECT_NEAR(value, direct, 1e-14);
  for (std::size_t i : {5, 17, 40, 41}) EXPECT_EQ(grad[i], 0.0) << "hole " << i;
  expect_gradient_matches(
      [&](const Buffer& x) {
        return loss_impl::l1_loss<double>(x.data(), observed.data(), mask.data(), 1, kPixels, true,
                                          1.0, nullptr);
      },
      rendered, grad, "depth L1");

  // The float wrapper agrees and only takes single-channel depth.
  double loss = 0.0;
  std::string why;
  const PlanarImage mask_img = to_image(mask, 1);
  ASSERT_TRUE(depth_l1_loss(to_image(rendered, 1), to_image(observed, 1), &mask_img, 1.0, &loss,
                            nullptr, &why))
      << why;
  EXPECT_NEAR(loss, direct, 1e-6);
  EXPECT_FALSE(depth_l1_loss(PlanarImage(kW, kH, 2), PlanarImage(kW, kH, 2), nullptr, 1.0, &loss,
                             nullptr, &why));
  EXPECT_NE(why.find("channel"), std::string::npos) << why;
}

// ---- SSIM --------------------------------------------------------------------------------------

// Mean of ssim.hpp's straight-from-the-definition ssim_pixel over the counted pixels x channels.
double reference_mean_ssim(const Buffer& x, const Buffer& y, const Buffer* mask, int channels) {
  double taps[math::kSsimWindow];
  math::ssim_gaussian_window(math::kSsimWindow, static_cast<double>(math::kSsimSigma), taps);
  double sum = 0.0;
  int count = 0;
  for (int c = 0; c < channels; ++c)
    for (int v = 0; v < kH; ++v)
      for (int u = 0; u < kW; ++u) {
        if (mask && (*mask)[v * kW + u] <= 0.5) continue;
        sum += math::ssim_pixel(x.data(), y.data(), kW, kH, u, v, c, taps, math::kSsimWindow,
                                math::ssim_c1(1.0), math::ssim_c2(1.0));
        ++count;
      }
  return sum / count;
}

TEST(SsimLoss, ValueIsOneMinusTheMeanOfSsimPixel) {
  std::mt19937 rng(4);
  constexpr int kC = 3;
  const Buffer x = uniform(kC * kPixels, 0.0, 1.0, rng);
  Buffer y(x);
  std::normal_distribution<double> noise(0.0, 0.25);
  for (double& v : y) v += noise(rng);
  const Buffer mask = random_mask(0.5, rng);
  constexpr double kWeight = 0.2;

  const double ssim_all = reference_mean_ssim(x, y, nullptr, kC);
  EXPECT_GT(ssim_all, 0.2);  // correlated, not identical
  EXPECT_LT(ssim_all, 0.95);
  EXPECT_NEAR(
      loss_impl::ssim_loss<double>(x.data(), y.data(), nullptr, kC, kW, kH, kWeight, nullptr),
      kWeight * (1.0 - ssim_all), 1e-13);
  EXPECT_NEAR(
      loss_impl::ssim_loss<double>(x.data(), y.data(), mask.data(), kC, kW, kH, kWeight, nullptr),
      kWeight * (1.0 - reference_mean_ssim(x, y, &mask, kC)), 1e-13);

  // The float path (what the mapper runs) agrees to float precision.
  double loss = 0.0;
  std::string why;
  ASSERT_TRUE(ssim_loss(to_image(x, kC), to_image(y, kC), nullptr, kWeight, &loss, nullptr, &why))
      << why;
  EXPECT_NEAR(loss, kWeight * (1.0 - ssim_all), 1e-5);
}

TEST(SsimLoss, IdenticalImagesHaveSsimOneAndNoGradient) {
  std::mt19937 rng(5);
  const Buffer x = uniform(3 * kPixels, 0.0, 1.0, rng);
  EXPECT_NEAR(reference_mean_ssim(x, x, nullptr, 3), 1.0, 1e-12);
  Buffer grad(x.size(), 0.0);
  EXPECT_NEAR(loss_impl::ssim_loss(x.data(), x.data(), static_cast<const double*>(nullptr), 3, kW,
                                   kH, 1.0, grad.data()),
              0.0, 1e-12);
  // SSIM is maximal at y = x, so the gradient vanishes there.
  for (double g : grad) EXPECT_NEAR(g, 0.0, 1e-12);
}

TEST(SsimLoss, GradientMatchesFiniteDifferencesWithMask) {
  std::mt19937 rng(6);
  constexpr int kC = 2;
  const Buffer y = uniform(kC * kPixels, 0.0, 1.0, rng);
  const Buffer x = uniform(kC * kPixels, 0.0, 1.0, rng);
  const Buffer mask = random_mask(0.6, rng);
  Buffer grad(x.size(), 0.0);
  loss_impl::ssim_loss(x.data(), y.data(), mask.data(), kC, kW, kH, 0.7, grad.data());
  expect_gradient_matches(
      [&](const Buffer& v) {
        return loss_impl::ssim_loss<double>(v.data(), y.data(), mask.data(), kC, kW, kH, 0.7,
                                            nullptr);
      },
      x, grad, "SSIM");
}

// Opt-in timing (--gtest_also_run_disabled_tests): SSIM loss + gradient, float, one thread.
TEST(SsimLossTiming, DISABLED_FloatLossAndGradient) {
  std::mt19937 rng(7);
  for (auto [w, h] : {std::pair{320, 240}, std::pair{640, 480}}) {
    PlanarImage x(w, h, 3), y(w, h, 3), grad(w, h, 3);
    std::uniform_real_distribution<float> d(0.0f, 1.0f);
    for (float& v : x.data) v = d(rng);
    for (float& v : y.data) v = d(rng);
    double loss = 0.0;
    constexpr int kRepeats = 20;
    double best_ms = 1e30;
    for (int r = 0; r < kRepeats; ++r) {
      const auto t0 = std::chrono::steady_clock::now();
      ASSERT_TRUE(ssim_loss(x, y, nullptr, 1.0, &loss, &grad));
      const auto t1 = std::chrono::steady_clock::now();
      best_ms = std::min(best_ms, std::chrono::duration<double, std::milli>(t1 - t0).count());
    }
    std::cout << "ssim_loss + grad 3x" << w << "x" << h << ": " << best_ms << " ms (best of "
              << kRepeats << ")\n";
  }
}

// ---- PCC ---------------------------------------------------------------------------------------

// Pearson correlation of the pairs (a_i, b_i) by the one-pass textbook formula, independent of
// the centred two-pass sums the loss uses.
double textbook_pearson(const std::vector<double>& a, const std::vector<double>& b) {
  const double n = static_cast<double>(a.size());
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    sa += a[i];
    sb += b[i];
    saa += a[i] * a[i];
    sbb += b[i] * b[i];
    sab += a[i] * b[i];
  }
  return (n * sab - sa * sb) / std::sqrt((n * saa - sa * sa) * (n * sbb - sb * sb));
}

TEST(PccLoss, AffineRelationInEveryBlockGivesRhoOne) {
  std::mt19937 rng(8);
  PccConfig config;
  config.block = 4;
  config.min_valid_pixels = 3;
  const Buffer observed = uniform(kPixels, 0.5, 3.0, rng);
  // rendered = a_b * observed + c_b with a different scale and offset in each block: PCC ignores
  // scale and bias per block, so the loss is 0 wherever a_b > 0.
  auto make_rendered = [&](bool flip_first_block) {
    Buffer r(kPixels);
    for (int v = 0; v < kH; ++v)
      for (int u = 0; u < kW; ++u) {
        const int block = (v / 4) * 4 + u / 4;
        double a = 0.5 + 0.1 * block, c = 0.3 - 0.05 * block;
        if (flip_first_block && block == 0) a = -a;
        r[v * kW + u] = a * observed[v * kW + u] + c;
      }
    return r;
  };
  int used = 0;
  const Buffer rendered = make_rendered(false);
  EXPECT_NEAR(loss_impl::pcc_loss<double>(rendered.data(), observed.data(), nullptr, kW, kH, config,
                                          1.5, nullptr, &used),
              0.0, 1e-12);
  // 4 x 3 blocks; the 1-pixel-wide last column holds 4, 4 and 3 pixels, all >= 3.
  EXPECT_EQ(used, 12);
  // A negative scale in one block makes its rho -1: loss = 1.5 * (1 - (11 - 1) / 12).
  const Buffer flipped = make_rendered(true);
  EXPECT_NEAR(loss_impl::pcc_loss<double>(flipped.data(), observed.data(), nullptr, kW, kH, config,
                                          1.5, nullptr, &used),
              1.5 * (1.0 - 10.0 / 12.0), 1e-12);
}

TEST(PccLoss, ValueAndGradientWithSkippedBlocks) {
  std::mt19937 rng(9);
  PccConfig config;
  config.block = 4;
  config.min_valid_pixels = 6;  // the 1-pixel-wide edge column (<= 4 pixels) is always skipped
  config.min_std = 1e-3;
  Buffer observed = uniform(kPixels, 0.5, 3.0, rng);
  const Buffer rendered = uniform(kPixels, 0.5, 3.0, rng);
  // Block (0, 1): a flat wall with 0.1 mm of noise (std < min_std = 1 mm) -> skipped.
  std::uniform_real_distribution<double> flat_noise(-1e-4, 1e-4);
  for (int v = 0; v < 4; ++v)
    for (int u = 4; u < 8; ++u) observed[v * kW + u] = 2.0 + flat_noise(rng);
  // Block (1, 0): only 5 valid observed pixels -> skipped.
  for (int v = 4; v < 8; ++v)
    for (int u = 0; u < 4; ++u)
      if ((v - 4) * 4 + u >= 5) observed[v * kW + u] = 0.0;
  // Block (2, 2): a few holes, still used.
  observed[8 * kW + 8] = 0.0;
  observed[9 * kW + 9] = std::nan("");
  const Buffer mask(kPixels, 1.0);

  // Independent value: textbook Pearson per block over the valid pixels.
  double rho_sum = 0.0;
  int blocks = 0;
  for (int v0 = 0; v0 < kH; v0 += 4)
    for (int u0 = 0; u0 < kW; u0 += 4) {
      std::vector<double> a, b;
      for (int v = v0; v < std::min(v0 + 4, kH); ++v)
        for (int u = u0; u < std::min(u0 + 4, kW); ++u)
          if (observed[v * kW + u] > 0.0) {
            a.push_back(rendered[v * kW + u]);
            b.push_back(observed[v * kW + u]);
          }
      const bool flat = u0 == 4 && v0 == 0;
      if (static_cast<int>(a.size()) < config.min_valid_pixels || flat) continue;
      rho_sum += textbook_pearson(a, b);
      ++blocks;
    }
  ASSERT_EQ(blocks, 12 - 3 - 2);  // 3 edge-column blocks, the flat one and the sparse one

  Buffer grad(kPixels, 0.0);
  int used = 0;
  const double value = loss_impl::pcc_loss(rendered.data(), observed.data(), mask.data(), kW, kH,
                                           config, 0.9, grad.data(), &used);
  EXPECT_EQ(used, blocks);
  EXPECT_NEAR(value, 0.9 * (1.0 - rho_sum / blocks), 1e-12);
  for (int v = 0; v < 4; ++v)
    for (int u = 4; u < 8; ++u) EXPECT_EQ(grad[v * kW + u], 0.0) << "flat block";
  for (int v = 0; v < kH; ++v) EXPECT_EQ(grad[v * kW + 12], 0.0) << "edge column";
  EXPECT_EQ(grad[8 * kW + 8], 0.0) << "hole";
  expect_gradient_matches(
      [&](const Buffer& x) {
        return loss_impl::pcc_loss<double>(x.data(), observed.data(), mask.data(), kW, kH, config,
                                           0.9, nullptr, nullptr);
      },
      rendered, grad, "PCC");

  // The float wrapper agrees.
  double loss = 0.0;
  std::string why;
  ASSERT_TRUE(pcc_loss(to_image(rendered, 1), to_image(observed, 1), nullptr, config, 0.9, &loss,
                       nullptr, &why, &used))
      << why;
  EXPECT_EQ(used, blocks);
  EXPECT_NEAR(loss, value, 1e-5);
}

TEST(PccLoss, RejectsBadConfig) {
  PccConfig config;
  std::string why;
  EXPECT_TRUE(validate(config, &why)) << why;
  config.min_valid_pixels = 2;
  EXPECT_FALSE(validate(config, &why));
  config = PccConfig{};
  config.block = 4;  // default min_valid_pixels 32 > 16 pixels in a block: nothing could count
  EXPECT_FALSE(validate(config, &why));
  EXPECT_NE(why.find("min_valid_pixels"), std::string::npos) << why;
}

// ---- normals -----------------------------------------------------------------------------------

// Depth of the plane {X : n . X = d} seen through pixel (u, v): z = d / (n . K^-1 [u, v, 1]).
Buffer plane_depth(const double n[3], double d) {
  Buffer depth(kPixels);
  for (int v = 0; v < kH; ++v)
    for (int u = 0; u < kW; ++u) {
      double r[3];
      math::pixel_ray(kIntrinsics, u, v, r);
      depth[v * kW + u] = d / math::dot3(n, r);
    }
  return depth;
}

TEST(DepthToNormals, FrontoParallelPlaneFacesTheCamera) {
  const PlanarImage depth(kW, kH, 1, 2.5f);
  PlanarImage normals;
  std::string why;
  ASSERT_TRUE(depth_to_normals(depth, kIntrinsics, &normals, &why)) << why;
  ASSERT_EQ(normals.channels, 3);
  for (int v = 0; v < kH; ++v)
    for (int u = 0; u < kW; ++u) {
      const bool border = u == 0 || v == 0 || u == kW - 1 || v == kH - 1;
      EXPECT_NEAR(normals.at(0, v, u), 0.0f, 1e-6);
      EXPECT_NEAR(normals.at(1, v, u), 0.0f, 1e-6);
      EXPECT_NEAR(normals.at(2, v, u), border ? 0.0f : -1.0f, 1e-6) << u << ", " << v;
    }
}

TEST(DepthToNormals, TiltedPlaneMatchesItsAnalyticNormal) {
  // Plane through (0, 0, 2) m tilted ~27 degrees from the optical axis, normal towards the
  // camera (n . X = d < 0 on the plane).
  double n[3] = {0.3, -0.4, -1.0};
  const double len = std::sqrt(math::dot3(n, n));
  for (double& c : n) c /= len;
  const double d = n[2] * 2.0;
  const Buffer depth = plane_depth(n, d);

  Buffer normals(3 * kPixels, 0.0);
  loss_impl::depth_to_normals(depth.data(), kW, kH, kIntrinsics, normals.data());
  // Central differences of points on a plane lie in the plane: exact up to rounding.
  for (int v = 1; v < kH - 1; ++v)
    for (int u = 1; u < kW - 1; ++u)
      for (int j = 0; j < 3; ++j)
        EXPECT_NEAR(normals[j * kPixels + v * kW + u], n[j], 1e-6) << u << ", " << v;

  // Float path: the depths' rounding (~1e-7 relative) moves the normal by ~1e-5.
  PlanarImage normals_f;
  ASSERT_TRUE(depth_to_normals(to_image(depth, 1), kIntrinsics, &normals_f));
  for (int j = 0; j < 3; ++j) EXPECT_NEAR(normals_f.at(j, 5, 6), n[j], 2e-4);
}

TEST(DepthToNormals, UndefinedAroundMissingDepth) {
  PlanarImage depth(kW, kH, 1, 1.0f);
  depth.at(0, 5, 6) = 0.0f;  // hole
  depth.at(0, 2, 2) = NAN;   // invalid reading
  PlanarImage normals;
  ASSERT_TRUE(depth_to_normals(depth, kIntrinsics, &normals));
  auto defined = [&](int u, int v) {
    return normals.at(0, v, u) != 0.0f || normals.at(1, v, u) != 0.0f ||
           normals.at(2, v, u) != 0.0f;
  };
  const std::vector<std::pair<int, int>> undefined = {{6, 5}, {5, 5}, {7, 5}, {6, 4}, {6, 6},
                                                      {2, 2}, {1, 2}, {3, 2}, {2, 1}, {2, 3}};
  for (auto [u, v] : undefined) EXPECT_FALSE(defined(u, v)) << u << ", " << v;
  EXPECT_TRUE(defined(5, 4));  // diagonal neighbours are not used
  EXPECT_TRUE(defined(8, 8));
  EXPECT_FALSE(defined(0, 5));  // image border
}

// A rough surface: a tilted plane plus random relief, with a hole.
Buffer rough_depth(std::mt19937& rng) {
  const double n[3] = {0.2, 0.1, -1.0};
  Buffer depth = plane_depth(n, -2.0);
  std::uniform_real_distribution<double> relief(-0.1, 0.1);
  for (double& z : depth) z += relief(rng);
  // A hole below 0 rather than at 0, so that the +-h steps of the finite differences keep it a
  // hole: at 0, +h would make normals appear, a jump rather than a gradient.
  depth[6 * kW + 4] = -1.0;
  return depth;
}

TEST(DepthToNormalsBackward, MatchesFiniteDifferences) {
  std::mt19937 rng(10);
  const Buffer depth = rough_depth(rng);
  const Buffer weights = uniform(3 * kPixels, -1.0, 1.0, rng);  // dL/dn
  // L(depth) = sum weights . normals(depth)
  auto loss = [&](const Buffer& z) {
    Buffer normals(3 * kPixels, 0.0);
    loss_impl::depth_to_normals(z.data(), kW, kH, kIntrinsics, normals.data());
    double sum = 0.0;
    for (std::size_t i = 0; i < normals.size(); ++i) sum += weights[i] * normals[i];
    return sum;
  };
  Buffer grad(kPixels, 0.0);
  loss_impl::depth_to_normals_backward(depth.data(), kW, kH, kIntrinsics, weights.data(),
                                       grad.data());
  expect_gradient_matches(loss, depth, grad, "depth_to_normals");
}

TEST(NormalConsistencyLoss, ValueForARotationAndGradient) {
  // Observed normals straight at the camera, rendered tilted by 30 degrees: 1 - cos 30 each.
  PlanarImage observed(kW, kH, 3), rendered(kW, kH, 3);
  const double angle = M_PI / 6.0;
  for (std::size_t i = 0; i < kPixels; ++i) {
    observed.data[2 * kPixels + i] = -1.0f;
    rendered.data[i] = static_cast<float>(std::sin(angle));
    rendered.data[2 * kPixels + i] = static_cast<float>(-std::cos(angle));
  }
  // Undefined rendered normals (zeros) at a few pixels, a masked-out pixel: not counted.
  for (int j = 0; j < 3; ++j) rendered.data[j * kPixels + 7] = 0.0f;
  PlanarImage mask(kW, kH, 1, 1.0f);
  mask.data[9] = 0.0f;
  double loss = 0.0;
  PlanarImage grad;
  std::string why;
  ASSERT_TRUE(normal_consistency_loss(rendered, observed, &mask, 2.0, &loss, &grad, &why)) << why;
  EXPECT_NEAR(loss, 2.0 * (1.0 - std::cos(angle)), 1e-6);
  const float g = static_cast<float>(2.0 / (kPixels - 2));
  EXPECT_FLOAT_EQ(grad.at(2, 3, 3), g);  // -weight * n_o / count, n_o = (0, 0, -1)
  EXPECT_FLOAT_EQ(grad.at(0, 3, 3), 0.0f);
  EXPECT_EQ(grad.data[2 * kPixels + 7], 0.0f);
  EXPECT_EQ(grad.data[2 * kPixels + 9], 0.0f);
}

TEST(NormalConsistencyLoss, ThroughDepthToNormalsMatchesFiniteDifferences) {
  // The mapper's chain: rendered depth -> normals -> consistency with the observed normals.
  std::mt19937 rng(11);
  const Buffer depth = rough_depth(rng);
  Buffer observed_depth = depth;
  for (double& z : observed_depth) z += 0.05 * std::sin(z * 7.0);
  observed_depth[3 * kW + 9] = 0.0;
  Buffer observed(3 * kPixels, 0.0);
  loss_impl::depth_to_normals(observed_depth.data(), kW, kH, kIntrinsics, observed.data());
  const Buffer mask = random_mask(0.8, rng);

  auto loss = [&](const Buffer& z, Buffer* grad_depth) {
    Buffer normals(3 * kPixels, 0.0), grad_normals(3 * kPixels, 0.0);
    loss_impl::depth_to_normals(z.data(), kW, kH, kIntrinsics, normals.data());
    const double value = loss_impl::normal_consistency_loss(
        normals.data(), observed.data(), mask.data(), kPixels, 0.6, grad_normals.data());
    if (grad_depth)
      loss_impl::depth_to_normals_backward(z.data(), kW, kH, kIntrinsics, grad_normals.data(),
                                           grad_depth->data());
    return value;
  };
  Buffer grad(kPixels, 0.0);
  const double value = loss(depth, &grad);
  EXPECT_GT(value, 0.0);
  EXPECT_LT(value, 0.6);
  expect_gradient_matches([&](const Buffer& z) { return loss(z, nullptr); }, depth, grad,
                          "normal consistency through depth");
}

// ---- Gaussian regularisers ---------------------------------------------------------------------

TEST(ErankLoss, EffectiveRankOfSphereDiscAndNeedle) {
  const double sphere[3] = {-2.0, -2.0, -2.0};
  const double disc[3] = {-2.0, -2.0, -14.0};
  const double needle[3] = {-2.0, -14.0, -14.0};
  EXPECT_NEAR(math::effective_rank(sphere), 3.0, 1e-12);
  EXPECT_NEAR(math::effective_rank(disc), 2.0, 1e-8);
  EXPECT_NEAR(math::effective_rank(needle), 1.0, 1e-8);
  // Two equal axes and a third with p = 1/2: H = 1.5 log 2 -> erank = 2^1.5.
  const double ratio[3] = {0.0, 0.0, 0.5 * std::log(2.0)};
  EXPECT_NEAR(math::effective_rank(ratio), std::pow(2.0, 1.5), 1e-12);
  // Float survives an extreme needle (s ratio e^-40) without NaN.
  const float extreme[3] = {0.0f, -40.0f, -40.0f};
  EXPECT_NEAR(math::effective_rank(extreme), 1.0f, 1e-6f);
}

TEST(ErankLoss, ValueAndGradient) {
  constexpr double kEps = 0.01;
  // The barrier: -log(2 + eps) for a sphere, -log(eps) -> large for a needle.
  std::vector<float> scales = {-2.0f, -2.0f, -2.0f, 0.0f, -12.0f, -12.0f};
  double loss = 0.0;
  std::vector<float> grad;
  std::string why;
  ASSERT_TRUE(erank_loss(scales, 0.5, kEps, &loss, &grad, &why)) << why;
  const double needle[3] = {0.0, -12.0, -12.0};
  const double needle_erank = math::effective_rank(needle);
  EXPECT_NEAR(loss, 0.5 * 0.5 * (-std::log(2.0 + kEps) - std::log(needle_erank - 1.0 + kEps)),
              1e-5);
  ASSERT_EQ(grad.size(), 6u);
  for (int j = 0; j < 3; ++j) EXPECT_NEAR(grad[j], 0.0f, 1e-7f) << "a sphere is the optimum";

  std::mt19937 rng(12);
  const Buffer log_scales = uniform(3 * 20, -4.0, 0.0, rng);
  Buffer g(log_scales.size(), 0.0);
  loss_impl::erank_loss(log_scales.data(), 20, 0.3, kEps, g.data());
  expect_gradient_matches(
      [&](const Buffer& l) {
        return loss_impl::erank_loss<double>(l.data(), 20, 0.3, kEps, nullptr);
      },
      log_scales, g, "eRank");
  // Gradient descent on the barrier widens a needle's thin axes (their log-scales grow).
  const double thin_needle[3] = {0.0, -3.0, -3.5};
  double gn[3];
  math::erank_barrier(thin_needle, kEps, gn);
  EXPECT_GT(gn[0], 0.0);
  EXPECT_LT(gn[1], 0.0);
  EXPECT_LT(gn[2], 0.0);
}

TEST(ThinLoss, MeanSmallestScaleAndGradient) {
  std::vector<float> scales = {std::log(0.1f),  std::log(0.02f), std::log(0.3f),
                               std::log(0.05f), std::log(0.04f), std::log(0.06f)};
  double loss = 0.0;
  std::vector<float> grad;
  std::string why;
  ASSERT_TRUE(thin_loss(scales, 2.0, &loss, &grad, &why)) << why;
  EXPECT_NEAR(loss, 2.0 * (0.02 + 0.04) / 2.0, 1e-7);
  // d/dl of exp(l) is the scale itself, times lambda / N; only at each Gaussian's smallest axis.
  const std::vector<float> expected = {0.0f, 0.02f, 0.0f, 0.0f, 0.04f, 0.0f};
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(grad[i], expected[i], 1e-7) << i;

  std::mt19937 rng(13);
  const Buffer log_scales = uniform(3 * 20, -4.0, 0.0, rng);
  Buffer g(log_scales.size(), 0.0);
  loss_impl::thin_loss(log_scales.data(), 20, 0.7, g.data());
  expect_gradient_matches(
      [&](const Buffer& l) { return loss_impl::thin_loss<double>(l.data(), 20, 0.7, nullptr); },
      log_scales, g, "thin");
}

TEST(ErankLambda, RampsFromLambdaZeroToLambdaMax) {
  EXPECT_DOUBLE_EQ(erank_lambda(0, 0.01, 0.1, 100.0), 0.01);
  EXPECT_NEAR(erank_lambda(100, 0.01, 0.1, 100.0), 0.01 + 0.09 * (1.0 - std::exp(-1.0)), 1e-15);
  EXPECT_NEAR(erank_lambda(5000, 0.01, 0.1, 100.0), 0.1, 1e-12);
  EXPECT_DOUBLE_EQ(erank_lambda(3, 0.01, 0.1, 0.0), 0.1);  // no ramp
}

// ---- bad input ---------------------------------------------------------------------------------

TEST(ImageLosses, RejectBadShapesWithAReason) {
  const PlanarImage a(kW, kH, 3), b(kW, kH + 1, 3), mask(kW, kH, 2);
  double loss = 7.0;
  PlanarImage grad(kW, kH, 1);
  std::string why;
  EXPECT_FALSE(l1_loss(a, b, nullptr, 1.0, &loss, nullptr, &why));
  EXPECT_NE(why.find("differ in shape"), std::string::npos) << why;
  EXPECT_FALSE(ssim_loss(a, a, &mask, 1.0, &loss, nullptr, &why));
  EXPECT_NE(why.find("mask"), std::string::npos) << why;
  EXPECT_FALSE(ssim_loss(a, a, nullptr, 1.0, &loss, &grad, &why));
  EXPECT_NE(why.find("gradient"), std::string::npos) << why;
  EXPECT_FALSE(l1_loss(a, a, nullptr, NAN, &loss, nullptr, &why));
  EXPECT_FALSE(l1_loss(a, a, nullptr, 1.0, nullptr, nullptr, &why));
  EXPECT_FALSE(normal_consistency_loss(PlanarImage(kW, kH, 1), PlanarImage(kW, kH, 1), nullptr, 1.0,
                                       &loss, nullptr, &why));
  EXPECT_EQ(loss, 7.0) << "a failed call leaves the output alone";
  EXPECT_EQ(grad.data, std::vector<float>(kPixels, 0.0f));

  PlanarImage normals;
  EXPECT_FALSE(depth_to_normals(a, kIntrinsics, &normals, &why));
  EXPECT_FALSE(
      depth_to_normals(PlanarImage(kW, kH, 1), math::Intrinsics{0, 1, 0, 0}, &normals, &why));
  PlanarImage grad_depth;
  EXPECT_FALSE(depth_to_normals_backward(PlanarImage(kW, kH, 1), kIntrinsics,
                                         PlanarImage(kW, kH, 1), &grad_depth, &why));

  std::vector<float> scale_grad;
  EXPECT_FALSE(erank_loss({0.0f, 0.0f}, 1.0, 0.01, &loss, &scale_grad, &why));
  EXPECT_NE(why.find("[N, 3]"), std::string::npos) << why;
  EXPECT_FALSE(erank_loss({0.0f, 0.0f, 0.0f}, 1.0, 0.0, &loss, &scale_grad, &why));
  scale_grad.assign(6, 0.0f);
  EXPECT_FALSE(thin_loss({0.0f, 0.0f, 0.0f}, 1.0, &loss, &scale_grad, &why));
}

}  // namespace
}  // namespace fslam::core
