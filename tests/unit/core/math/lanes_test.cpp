// The CPU's SIMD lanes (math/lanes.hpp): the vectorised expf against the C library's, and the
// mask operations the rasteriser's lane loops decide with.
#include <cmath>
#include <cstdint>
#include <cstring>

#include <gtest/gtest.h>

#include "fslam/core/math/lanes.hpp"
#include "fslam/core/math/splat_math.hpp"

namespace fslam::core {
namespace {

using L = simd::Lanes<float, 8>;

// Distance in units in the last place between two positive floats.
std::int64_t ulps(float a, float b) {
  std::int32_t ia, ib;
  std::memcpy(&ia, &a, 4);
  std::memcpy(&ib, &b, 4);
  return std::llabs(static_cast<std::int64_t>(ia) - ib);
}

TEST(Lanes, ExpIsWithinTwoUlpOfTheCLibrary) {
  std::int64_t worst = 0;
  float worst_x = 0;
  int checked = 0;
  for (float x = -87.0f; x <= 88.0f; x += 0.00731f) {
    const L y = simd::exp(L::iota(x) * 1.0f);
    for (int i = 0; i < 8; ++i) {
      const float xi = x + static_cast<float>(i);
      if (xi > 88.0f) continue;
      const float ref = static_cast<float>(std::exp(static_cast<double>(xi)));
      const std::int64_t u = ulps(y[i], ref);
      if (u > worst) {
        worst = u;
        worst_x = xi;
      }
      ++checked;
    }
  }
  EXPECT_GT(checked, 100000);
  EXPECT_LE(worst, 2) << "at x = " << worst_x;
  // The range the rasteriser uses (footprint exponents in [log(1/255), 0]) with a finer step.
  for (float x = -6.0f; x <= 0.0f; x += 1e-4f) {
    EXPECT_LE(ulps(simd::exp(L(x))[0], std::exp(x)), 2) << x;
  }
  // Clamped outside [-87, 88]: finite, no wrapped exponent.
  EXPECT_TRUE(std::isfinite(simd::exp(L(200.0f))[0]));
  EXPECT_GT(simd::exp(L(200.0f))[0], 1e38f);
  EXPECT_GE(simd::exp(L(-200.0f))[0], 0.0f);
  EXPECT_LT(simd::exp(L(-200.0f))[0], 1e-37f);
}

TEST(Lanes, MasksSelectAndCount) {
  const L a = L::iota(0.0f);  // 0..7
  const auto m = (a >= L(2.0f)) & (a < L(5.0f));
  EXPECT_EQ(simd::bits(m), 0b00011100u);
  EXPECT_EQ(simd::count(m), 3);
  EXPECT_TRUE(simd::any(m));
  EXPECT_FALSE(simd::any(m & ~m));
  const L s = simd::select(m, a, L(-1.0f));
  for (int i = 0; i < 8; ++i) EXPECT_EQ(s[i], (i >= 2 && i < 5) ? float(i) : -1.0f);
  EXPECT_EQ(simd::sum(a), 28.0f);
  EXPECT_EQ(simd::abs_value(L(-2.5f))[3], 2.5f);
}

// The shared per-pixel math gives each lane what the scalar call gives that pixel.
TEST(Lanes, SplatAlphaPerLaneMatchesTheScalarCall) {
  math::ProjectedGaussian<float> g{};
  g.u = 3.3f;
  g.v = 2.0f;
  g.conic[0] = 1.2f;
  g.conic[1] = 0.05f;
  g.conic[2] = 0.9f;
  g.opacity = 0.8f;
  g.power_floor = std::log(math::kAlphaMin / g.opacity);
  L gauss;
  const L alpha = math::splat_alpha(g, L::iota(0.0f), L(1.0f), &gauss);
  int reached = 0;
  for (int i = 0; i < 8; ++i) {
    float gs = 0.0f;
    const float a = math::splat_alpha(g, static_cast<float>(i), 1.0f, &gs);
    EXPECT_NEAR(alpha[i], a, 2e-7f) << i;
    EXPECT_NEAR(gauss[i], gs, 2e-7f) << i;
    if (a > 0.0f) ++reached;
    else EXPECT_EQ(gauss[i], 0.0f);  // a pixel the splat misses adds nothing
  }
  EXPECT_GE(reached, 4);
  EXPECT_LT(reached, 8);  // some lanes outside the footprint
}

}  // namespace
}  // namespace fslam::core
