#include "fslam/core/mapping/adam.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace fslam::core {
namespace {

TEST(Adam, FirstStepMovesByLearningRateTimesSign) {
  // Bias correction makes the first step lr * g / |g| whatever the gradient's magnitude.
  AdamOptimizer adam(4);
  const float lr = 0.01f;
  const int g = adam.add_group("p", 3, lr);
  std::vector<float> params = {1.0f, -2.0f, 0.5f,  3.0f, 0.0f, -0.25f,
                               7.0f, 1e-3f, -1.0f, 2.0f, 4.0f, -8.0f};
  const std::vector<float> grads = {1e-6f,  -1e3f, 0.3f,  -4.0f, 0.0f,  2e-5f,
                                    -1e-4f, 50.0f, -0.7f, 1.0f,  -1.0f, 123.0f};
  const std::vector<float> before = params;
  adam.step(g, &params, grads);
  for (std::size_t i = 0; i < params.size(); ++i) {
    const float sign = grads[i] > 0 ? 1.0f : (grads[i] < 0 ? -1.0f : 0.0f);
    EXPECT_NEAR(params[i] - before[i], -lr * sign, 1e-6) << i;
  }
  EXPECT_EQ(adam.group(g).steps, 1);
}

TEST(Adam, MatchesHandComputedThreeSteps) {
  // p0 = 1, lr = 0.1, betas 0.9 / 0.999, eps 1e-8, gradients 1, -2, 0.5. By hand (double):
  //   t=1: m = 0.1,    v = 0.001,      p = 1 - 0.1 * 1 / (1 + 1e-8)             = 0.900000001
  //   t=2: m = -0.11,  v = 0.004999,   p += 0.1 * (0.11/0.19) / (sqrt(v/0.001999) + eps) =
  //   0.936610353 t=3: m = -0.049, v = 0.005244001, p += 0.1 * (0.049/0.271) / sqrt(v/0.002997001)
  //   = 0.950279420
  AdamSettings settings;
  settings.eps = 1e-8;
  AdamOptimizer adam(2, settings);
  const int g = adam.add_group("p", 1, 0.1f);
  // The second parameter sees the negated gradients: the mirror image about its start.
  std::vector<float> params = {1.0f, 1.0f};
  const float grads[3] = {1.0f, -2.0f, 0.5f};
  const double expected_p[3] = {0.900000001, 0.9366103535, 0.9502794197};
  const double expected_m[3] = {0.1, -0.11, -0.049};
  const double expected_v[3] = {0.001, 0.004999, 0.005244001};
  for (int t = 0; t < 3; ++t) {
    adam.step(g, &params, {grads[t], -grads[t]});
    EXPECT_NEAR(params[0], expected_p[t], 1e-6) << "step " << t + 1;
    EXPECT_NEAR(params[1], 2.0 - expected_p[t], 1e-6) << "step " << t + 1;
    EXPECT_NEAR(adam.group(g).m[0], expected_m[t], 1e-7) << "step " << t + 1;
    EXPECT_NEAR(adam.group(g).m[1], -expected_m[t], 1e-7) << "step " << t + 1;
    EXPECT_NEAR(adam.group(g).v[0], expected_v[t], 1e-6 * expected_v[t]) << "step " << t + 1;
  }
  EXPECT_EQ(adam.group(g).steps, 3);
}

TEST(Adam, EpsIsAddedAfterTheSquareRoot) {
  // g = eps = 1e-8: the first step is lr * g / (|g| + eps) = lr / 2 (PyTorch). Adding eps under
  // the root instead would give lr * 1e-8 / sqrt(1e-16 + 1e-8) = 1e-4 lr. Eight values so both
  // the vectorised body and the scalar tail are covered.
  AdamSettings settings;
  settings.eps = 1e-8;
  AdamOptimizer adam(9, settings);
  const int g = adam.add_group("p", 1, 0.1f);
  std::vector<float> params(9, 0.0f);
  adam.step(g, &params, std::vector<float>(9, 1e-8f));
  for (float p : params) EXPECT_NEAR(p, -0.05f, 1e-6);
}

TEST(Adam, StepCountsArePerGroup) {
  AdamOptimizer adam(1);
  const int a = adam.add_group("a", 1, 0.1f);
  const int b = adam.add_group("b", 2, 0.1f);
  std::vector<float> pa = {0.0f}, pb = {0.0f, 0.0f};
  adam.step(a, &pa, {1.0f});
  adam.step(a, &pa, {1.0f});
  adam.step(b, &pb, {1.0f, -1.0f});
  EXPECT_EQ(adam.group(a).steps, 2);
  EXPECT_EQ(adam.group(b).steps, 1);
  EXPECT_NEAR(pa[0], -0.2f, 1e-6);  // constant gradient: each step exactly lr
  EXPECT_NEAR(pb[0], -0.1f, 1e-6);
  EXPECT_NEAR(pb[1], 0.1f, 1e-6);
}

TEST(Adam, StridedBlockMatchesContiguous) {
  // A group over columns 2..4 of an [N, 6] array steps like the same values packed.
  const std::size_t n = 5, stride = 6;
  std::vector<float> wide(n * stride), wide_grads(n * stride);
  for (std::size_t i = 0; i < wide.size(); ++i) {
    wide[i] = 0.1f * static_cast<float>(i);
    wide_grads[i] = std::sin(static_cast<float>(i));
  }
  std::vector<float> packed, packed_grads;
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t c = 2; c < 5; ++c) {
      packed.push_back(wide[i * stride + c]);
      packed_grads.push_back(wide_grads[i * stride + c]);
    }
  }
  const std::vector<float> untouched = wide;
  AdamOptimizer strided(n), flat(n);
  strided.add_group("block", 3, 0.05f);
  flat.add_group("block", 3, 0.05f);
  for (int t = 0; t < 4; ++t) {
    strided.step(0, wide.data() + 2, wide_grads.data() + 2, stride);
    flat.step(0, &packed, packed_grads);
  }
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t c = 0; c < stride; ++c) {
      const float got = wide[i * stride + c];
      if (c >= 2 && c < 5)
        EXPECT_EQ(got, packed[3 * i + c - 2]) << i << "," << c;
      else
        EXPECT_EQ(got, untouched[i * stride + c]) << "outside the block: " << i << "," << c;
    }
  }
  EXPECT_EQ(strided.group(0).m, flat.group(0).m);
  EXPECT_EQ(strided.group(0).v, flat.group(0).v);
}

TEST(Adam, AnUpdateDoesNotDependOnWhereTheArraysStart) {
  // The same parameters and gradients at each of 8 float offsets of one buffer, stepped by fresh
  // optimisers flat and row by row (decaying): bit-identical results. Eigen's packet sqrt (rsqrt
  // and a Newton step) gave the elements before the first aligned one other last bits than the
  // rest, so a map's update depended on where its arrays landed in memory.
  const std::size_t n = 7, row = 13;
  std::vector<float> values(n * row), grads(n * row);
  for (std::size_t i = 0; i < values.size(); ++i) {
    values[i] = 0.3f * std::sin(0.7f * static_cast<float>(i));
    grads[i] = 1e-3f * std::cos(1.3f * static_cast<float>(i)) * static_cast<float>(1 + i % 5);
  }
  for (const int decay : {0, 10}) {
    std::vector<float> reference;
    for (std::size_t offset = 0; offset < 8; ++offset) {
      std::vector<float> p(offset + values.size()), g(offset + grads.size());
      std::copy(values.begin(), values.end(), p.begin() + static_cast<std::ptrdiff_t>(offset));
      std::copy(grads.begin(), grads.end(), g.begin() + static_cast<std::ptrdiff_t>(offset));
      AdamOptimizer adam(n);
      const int group = adam.add_group("p", row, 0.01f);
      if (decay > 0) adam.set_row_decay(group, decay);
      for (int t = 0; t < 5; ++t) adam.step(group, p.data() + offset, g.data() + offset, row);
      const std::vector<float> got(p.begin() + static_cast<std::ptrdiff_t>(offset), p.end());
      if (offset == 0) reference = got;
      else EXPECT_EQ(got, reference) << "offset " << offset << " floats, decay " << decay;
    }
  }
}

TEST(Adam, KeepOnlyAndGrowKeepMomentsAligned) {
  AdamOptimizer adam(5);
  const float lr = 0.01f;
  const int g = adam.add_group("p", 2, lr);
  std::vector<float> params(10, 0.0f), grads(10);
  for (std::size_t i = 0; i < 5; ++i) {
    grads[2 * i] = static_cast<float>(i + 1);
    grads[2 * i + 1] = -static_cast<float>(i + 1);
  }
  adam.step(g, &params, grads);  // m = 0.1 g, v = 0.001 g^2

  adam.keep_only({1, 0, 1, 1, 0});
  ASSERT_EQ(adam.size(), 3u);
  ASSERT_EQ(adam.group(g).m.size(), 6u);
  const float kept_ids[3] = {1, 3, 4};  // i + 1 of Gaussians 0, 2, 3
  for (int r = 0; r < 3; ++r) {
    EXPECT_FLOAT_EQ(adam.group(g).m[2 * r], 0.1f * kept_ids[r]) << r;
    EXPECT_FLOAT_EQ(adam.group(g).m[2 * r + 1], -0.1f * kept_ids[r]) << r;
    EXPECT_FLOAT_EQ(adam.group(g).v[2 * r], 0.001f * kept_ids[r] * kept_ids[r]) << r;
  }

  adam.grow(2);
  ASSERT_EQ(adam.size(), 5u);
  ASSERT_EQ(adam.group(g).v.size(), 10u);
  for (std::size_t j = 6; j < 10; ++j) {
    EXPECT_EQ(adam.group(g).m[j], 0.0f);
    EXPECT_EQ(adam.group(g).v[j], 0.0f);
  }

  // Second step with gradient 1 everywhere: old rows continue their moments, new rows start at
  // zero but share the group's step count (t = 2), as 3DGS's concatenated tensors do.
  params.assign(10, 0.0f);
  adam.step(g, &params, std::vector<float>(10, 1.0f));
  EXPECT_EQ(adam.group(g).steps, 2);
  for (int r = 0; r < 3; ++r)
    EXPECT_FLOAT_EQ(adam.group(g).m[2 * r], 0.09f * kept_ids[r] + 0.1f) << r;
  // New rows: m = 0.1, v = 0.001; step = lr * (0.1 / 0.19) / sqrt(0.001 / 0.001999) = 0.744 lr.
  const float new_step = lr * (0.1f / 0.19f) / std::sqrt(0.001f / 0.001999f);
  for (std::size_t j = 6; j < 10; ++j) {
    EXPECT_FLOAT_EQ(adam.group(g).m[j], 0.1f);
    EXPECT_NEAR(params[j], -new_step, 1e-7) << j;
  }
  EXPECT_NEAR(new_step, 0.7441f * lr, 1e-4 * lr);
}

TEST(Adam, ResetMomentsKeepsStepCount) {
  AdamOptimizer adam(2);
  const int g = adam.add_group("opacity", 1, 0.05f);
  std::vector<float> p = {0.0f, 0.0f};
  adam.step(g, &p, {1.0f, 2.0f});
  adam.reset_moments(g);
  EXPECT_EQ(adam.group(g).m, (std::vector<float>{0.0f, 0.0f}));
  EXPECT_EQ(adam.group(g).v, (std::vector<float>{0.0f, 0.0f}));
  EXPECT_EQ(adam.group(g).steps, 1);
}

TEST(Adam, MinimisesIllConditionedQuadratic) {
  // f(p) = 1/2 sum a_i (p_i - c_i)^2 with curvatures spanning 200x; the learning rate decays
  // exponentially from 0.05 to 1e-5 over the run, as 3DGS schedules its means.
  const std::vector<float> a = {1.0f, 3.0f, 10.0f, 30.0f, 100.0f, 0.5f};
  const std::vector<float> c = {0.3f, -1.2f, 2.0f, 0.0f, -0.7f, 1.5f};
  AdamOptimizer adam(a.size());
  const int g = adam.add_group("p", 1, 0.05f);
  std::vector<float> p(a.size(), 0.0f), grads(a.size());
  const int steps = 3000;
  for (int t = 0; t < steps; ++t) {
    adam.set_learning_rate(g, 0.05f * std::pow(1e-5f / 0.05f, t / float(steps - 1)));
    for (std::size_t i = 0; i < p.size(); ++i) grads[i] = a[i] * (p[i] - c[i]);
    adam.step(g, &p, grads);
  }
  EXPECT_FLOAT_EQ(adam.group(g).lr, 1e-5f);
  for (std::size_t i = 0; i < p.size(); ++i) EXPECT_NEAR(p[i], c[i], 1e-4) << i;
}

TEST(GaussianAdam, GroupsFollowTheMapAndItsLearningRates) {
  GaussianMap map;
  map.sh_degree = 2;
  map.feature_dim = 3;
  const float mean[3] = {0, 0, 0}, rot[4] = {1, 0, 0, 0}, scale[3] = {0, 0, 0};
  for (int i = 0; i < 4; ++i) map.push_back(mean, rot, scale, 0.0f, nullptr, nullptr);
  const GaussianLearningRates rates;
  AdamOptimizer adam = make_gaussian_adam(map, rates);
  ASSERT_EQ(adam.group_count(), kAdamGroupCount);
  EXPECT_EQ(adam.size(), 4u);
  EXPECT_EQ(adam.group(kAdamShDc).row, 3u);
  EXPECT_EQ(adam.group(kAdamShRest).row, 24u);
  EXPECT_EQ(adam.group(kAdamFeatures).row, 3u);
  EXPECT_EQ(adam.settings().eps, 1e-15);

  // All gradients 1: the first step moves every parameter by exactly its group's rate.
  GaussianMap grads = map;
  for (auto* array : {&grads.means, &grads.rotations, &grads.log_scales, &grads.opacity_logits,
                      &grads.sh, &grads.features})
    array->assign(array->size(), 1.0f);
  const GaussianMap before = map;
  step_gaussian_adam(&adam, &map, grads);
  EXPECT_NEAR(map.means[5] - before.means[5], -3.2e-4f, 1e-9);
  EXPECT_NEAR(map.rotations[5], -1e-3f, 1e-8);  // x of Gaussian 1, from 0
  EXPECT_NEAR(map.log_scales[0], -1e-2f, 1e-8);
  EXPECT_NEAR(map.opacity_logits[3], -0.05f, 1e-8);
  EXPECT_NEAR(map.features[11], -2.5e-3f, 1e-8);
  for (std::size_t i = 0; i < map.size(); ++i) {
    for (int j = 0; j < map.sh_per_gaussian(); ++j) {
      const float expected = j < 3 ? -1e-2f : -1.25e-4f;  // DC, then the higher bands
      EXPECT_NEAR(map.sh[i * 27 + j], expected, 1e-9) << i << "," << j;
    }
  }

  // Pruning the map and the optimiser with one mask keeps them the same size.
  const std::vector<std::uint8_t> keep = {0, 1, 1, 0};
  map.keep_only(keep);
  adam.keep_only(keep);
  EXPECT_EQ(adam.size(), map.size());
  for (int k = 0; k < adam.group_count(); ++k)
    EXPECT_EQ(adam.group(k).m.size(), 2 * adam.group(k).row) << adam.group(k).name;
}

}  // namespace
}  // namespace fslam::core

namespace fslam::core {
namespace {

TEST(Adam, SparseStepLeavesInactiveRowsUntouched) {
  AdamOptimizer adam(3);
  const int g = adam.add_group("p", 2, 0.1f);
  std::vector<float> params = {1, 2, 3, 4, 5, 6}, grads = {1, 1, 1, 1, 1, 1};
  const std::vector<std::uint8_t> active = {1, 0, 1};
  adam.step(g, &params, grads, active.data());
  // Active rows move by -lr * sign(grad) on a first step, the inactive row not at all.
  EXPECT_NEAR(params[0], 0.9f, 1e-6f);
  EXPECT_NEAR(params[5], 5.9f, 1e-6f);
  EXPECT_EQ(params[2], 3.0f);
  EXPECT_EQ(params[3], 4.0f);
  EXPECT_EQ(adam.group(g).m[2], 0.0f);
  EXPECT_EQ(adam.group(g).v[3], 0.0f);
  EXPECT_GT(adam.group(g).m[0], 0.0f);
}

TEST(Adam, RowDecayCountsEachGaussiansOwnSteps) {
  // A constant gradient makes Adam's bias-corrected step exactly its rate, so each step's size
  // shows the schedule: lr * 0.01^(k / N) at a row's k-th step, 0.01 lr from its N-th on.
  const float lr = 0.1f;
  const int N = 4;
  AdamOptimizer adam(2);
  const int g = adam.add_group("p", 1, lr);
  adam.set_row_decay(g, N);
  std::vector<float> params = {0, 0};
  const std::vector<std::uint8_t> only_first = {1, 0};
  for (int k = 0; k < 6; ++k) {
    std::vector<float> grads(params.size(), 1.0f);
    const std::vector<float> before = params;
    adam.step(g, &params, grads, only_first.data());
    const float expected = lr * std::pow(0.01f, static_cast<float>(std::min(k, N)) / N);
    EXPECT_NEAR(before[0] - params[0], expected, 1e-6f) << "step " << k;
    EXPECT_EQ(params[1], 0.0f);  // inactive: neither moved nor counted
  }
  // A Gaussian added now, or one that was inactive, starts at the full rate.
  adam.grow(1);
  params.push_back(0.0f);
  std::vector<float> grads(params.size(), 1.0f);
  std::vector<float> before = params;
  adam.step(g, &params, grads);
  EXPECT_NEAR(before[0] - params[0], lr * 0.01f, 1e-6f);
  EXPECT_GT(before[1] - params[1], 0.3f * lr);  // its first step (moments start at zero)
  EXPECT_GT(before[2] - params[2], 0.3f * lr);
  // Settled rows take the final rate; decay 0 takes lr for every row again.
  adam.settle_rows(g);
  before = params;
  adam.step(g, &params, grads);
  EXPECT_LT(before[2] - params[2], 0.05f * lr);
  adam.set_row_decay(g, 0);
  before = params;
  adam.step(g, &params, grads);
  EXPECT_NEAR(before[0] - params[0], lr, 1e-6f);
  // Another floor: a settled row steps at floor * lr.
  adam.set_row_decay(g, N, 0.1f);
  adam.settle_rows(g);
  before = params;
  adam.step(g, &params, grads);
  EXPECT_NEAR(before[0] - params[0], 0.1f * lr, 1e-6f);
  // Pruning keeps each row's count with it.
  adam.set_row_decay(g, N);
  adam.keep_only({0, 1, 1});
  EXPECT_EQ(adam.group(g).row_steps.size(), 2u);
}

}  // namespace
}  // namespace fslam::core
