#include "fslam/core/mapping/adam.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <utility>

namespace fslam::core {
namespace {

struct AdamCoefficients {
  float b1, one_minus_b1, b2, one_minus_b2;
  float bc2_sqrt;  // sqrt(1 - b2^t)
  float eps;
};

// One Adam update of `count` values:
//   m = b1 m + (1 - b1) g,  v = b2 v + (1 - b2) g^2,  p -= size * m / (sqrt(v) / sqrt(1 - b2^t) + eps)
// with size = lr / (1 - b1^t). A plain loop on purpose: GCC vectorises it (this file is built with
// -fno-math-errno, so std::sqrt is an IEEE vsqrtps), and IEEE arithmetic gives the vectorised and
// the scalar iterations the same bits, so a value's update does not depend on where its array
// starts in memory. Eigen's packet sqrt (rsqrt and a Newton step) differed from the scalar sqrt
// of the peeled elements in the last bit, and rsqrt differs between CPU vendors: maps with
// features then depended on the heap's layout (docs/architecture.md, "Reproducible numbers").
void adam_update(const AdamCoefficients& c, float size, float* __restrict p,
                 const float* __restrict g, float* __restrict m, float* __restrict v,
                 std::size_t count) {
  for (std::size_t k = 0; k < count; ++k) {
    m[k] = c.b1 * m[k] + c.one_minus_b1 * g[k];
    v[k] = c.b2 * v[k] + c.one_minus_b2 * (g[k] * g[k]);
    p[k] -= size * (m[k] / (std::sqrt(v[k]) / c.bc2_sqrt + c.eps));
  }
}

}  // namespace

AdamOptimizer::AdamOptimizer(std::size_t n, AdamSettings settings) : settings_(settings), n_(n) {}

int AdamOptimizer::add_group(std::string name, std::size_t row, float lr) {
  AdamGroup group;
  group.name = std::move(name);
  group.row = row;
  group.lr = lr;
  group.m.assign(n_ * row, 0.0f);
  group.v.assign(n_ * row, 0.0f);
  group.row_steps.assign(n_, 0);
  groups_.push_back(std::move(group));
  return static_cast<int>(groups_.size()) - 1;
}

void AdamOptimizer::step(int g, float* params, const float* grads, std::size_t stride,
                         const std::uint8_t* active) {
  AdamGroup& group = groups_[static_cast<std::size_t>(g)];
  assert(stride >= group.row);
  ++group.steps;
  if (n_ == 0 || group.row == 0) return;

  // Kingma & Ba, Alg. 1 with PyTorch's placement of eps (adam_update below).
  const double t = static_cast<double>(group.steps);
  AdamCoefficients c;
  c.b1 = static_cast<float>(settings_.beta1);
  c.one_minus_b1 = static_cast<float>(1.0 - settings_.beta1);
  c.b2 = static_cast<float>(settings_.beta2);
  c.one_minus_b2 = static_cast<float>(1.0 - settings_.beta2);
  c.bc2_sqrt = static_cast<float>(std::sqrt(1.0 - std::pow(settings_.beta2, t)));
  c.eps = static_cast<float>(settings_.eps);
  const float step_size = static_cast<float>(group.lr / (1.0 - std::pow(settings_.beta1, t)));
  const std::size_t row = group.row;
  if (active == nullptr && group.decay.empty() && stride == row) {
    adam_update(c, step_size, params, grads, group.m.data(), group.v.data(), row * n_);
    return;
  }
  // Row by row. Sparse (as 3DGS's visibility-masked Adam): rows that are not active keep their
  // parameters and moments, so momentum from earlier views does not move what this view cannot
  // see. Decaying: a Gaussian's rate is lr * floor^(min(k, N) / N) at its k-th step.
  const int N = group.decay.empty() ? 0 : static_cast<int>(group.decay.size()) - 1;
  for (std::size_t i = 0; i < n_; ++i) {
    if (active != nullptr && !active[i]) continue;
    float size = step_size;
    if (N > 0) {
      std::int32_t& k = group.row_steps[i];
      size *= group.decay[static_cast<std::size_t>(std::min(k, N))];
      if (k < N) ++k;
    }
    adam_update(c, size, params + i * stride, grads + i * stride, group.m.data() + i * row,
                group.v.data() + i * row, row);
  }
}

void AdamOptimizer::step(int g, std::vector<float>* params, const std::vector<float>& grads,
                         const std::uint8_t* active) {
  const std::size_t row = group(g).row;
  assert(params->size() == n_ * row && grads.size() == n_ * row);
  step(g, params->data(), grads.data(), row, active);
}

void AdamOptimizer::set_learning_rate(int g, float lr) {
  groups_[static_cast<std::size_t>(g)].lr = lr;
}

void AdamOptimizer::set_row_decay(int g, int steps, float floor) {
  assert(floor > 0.0f && floor <= 1.0f);
  AdamGroup& group = groups_[static_cast<std::size_t>(g)];
  group.decay.clear();
  if (steps <= 0) return;
  group.decay.resize(static_cast<std::size_t>(steps) + 1);
  for (int k = 0; k <= steps; ++k)
    group.decay[static_cast<std::size_t>(k)] = std::pow(floor, static_cast<float>(k) / static_cast<float>(steps));
}

void AdamOptimizer::settle_rows(int g) {
  AdamGroup& group = groups_[static_cast<std::size_t>(g)];
  std::fill(group.row_steps.begin(), group.row_steps.end(), std::numeric_limits<std::int32_t>::max());
}

void AdamOptimizer::reset_moments(int g) {
  AdamGroup& group = groups_[static_cast<std::size_t>(g)];
  std::fill(group.m.begin(), group.m.end(), 0.0f);
  std::fill(group.v.begin(), group.v.end(), 0.0f);
}

void AdamOptimizer::grow(std::size_t count) {
  n_ += count;
  for (AdamGroup& group : groups_) {
    group.m.resize(n_ * group.row, 0.0f);
    group.v.resize(n_ * group.row, 0.0f);
    group.row_steps.resize(n_, 0);
  }
}

void AdamOptimizer::keep_only(const std::vector<std::uint8_t>& keep) {
  assert(keep.size() == n_);
  std::size_t kept = 0;
  for (std::uint8_t k : keep) kept += k ? 1 : 0;
  for (AdamGroup& group : groups_) {
    keep_rows(&group.m, group.row, keep);
    keep_rows(&group.v, group.row, keep);
    keep_rows(&group.row_steps, 1, keep);
  }
  n_ = kept;
}

AdamOptimizer make_gaussian_adam(const GaussianMap& map, const GaussianLearningRates& rates,
                                 const AdamSettings& settings) {
  AdamOptimizer adam(map.size(), settings);
  const std::size_t rest = static_cast<std::size_t>(map.sh_per_gaussian()) - 3;
  // Added in GaussianAdamGroup order.
  adam.add_group("means", 3, rates.means);
  adam.add_group("rotations", 4, rates.rotations);
  adam.add_group("log_scales", 3, rates.log_scales);
  adam.add_group("opacity_logits", 1, rates.opacity);
  adam.add_group("sh_dc", 3, rates.sh_dc);
  adam.add_group("sh_rest", rest, rates.sh_rest);
  adam.add_group("features", static_cast<std::size_t>(map.feature_dim), rates.features);
  adam.set_row_decay(kAdamMeans, rates.means_decay_steps, rates.means_decay_floor);
  assert(adam.group_count() == kAdamGroupCount);
  return adam;
}

void step_gaussian_adam(AdamOptimizer* adam, GaussianMap* map, const GaussianMap& grads,
                        const std::vector<std::uint8_t>* active) {
  assert(adam->group_count() == kAdamGroupCount && adam->size() == map->size());
  assert(grads.sh_degree == map->sh_degree && grads.feature_dim == map->feature_dim);
  assert(active == nullptr || active->size() == map->size());
  const std::uint8_t* mask = active != nullptr ? active->data() : nullptr;
  adam->step(kAdamMeans, &map->means, grads.means, mask);
  adam->step(kAdamRotations, &map->rotations, grads.rotations, mask);
  adam->step(kAdamLogScales, &map->log_scales, grads.log_scales, mask);
  adam->step(kAdamOpacity, &map->opacity_logits, grads.opacity_logits, mask);
  // sh [N, K, 3]: the DC block is the first 3 values of each row, the higher bands the rest.
  assert(grads.sh.size() == map->sh.size());
  const std::size_t sh_row = static_cast<std::size_t>(map->sh_per_gaussian());
  const bool any = !map->sh.empty();
  adam->step(kAdamShDc, map->sh.data(), grads.sh.data(), sh_row, mask);
  adam->step(kAdamShRest, any ? map->sh.data() + 3 : nullptr, any ? grads.sh.data() + 3 : nullptr,
             sh_row, mask);
  adam->step(kAdamFeatures, &map->features, grads.features, mask);
}

}  // namespace fslam::core
