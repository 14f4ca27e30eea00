#include "fslam/core/map/gaussian_map.hpp"

#include <cmath>
#include <utility>

namespace fslam::core {
namespace {

bool all_finite(const std::vector<float>& values) {
  for (float v : values) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

}  // namespace

void GaussianMap::clear() {
  means.clear();
  rotations.clear();
  log_scales.clear();
  opacity_logits.clear();
  sh.clear();
  features.clear();
  filter_3d.clear();
}

void GaussianMap::reserve(std::size_t n) {
  means.reserve(3 * n);
  rotations.reserve(4 * n);
  log_scales.reserve(3 * n);
  opacity_logits.reserve(n);
  sh.reserve(static_cast<std::size_t>(sh_per_gaussian()) * n);
  features.reserve(static_cast<std::size_t>(feature_dim) * n);
  filter_3d.reserve(n);
}

void GaussianMap::push_back(const float mean[3], const float rotation[4],
                            const float log_scale[3], float opacity_logit,
                            const float* sh_values, const float* feature_values,
                            float filter_variance) {
  means.insert(means.end(), mean, mean + 3);
  rotations.insert(rotations.end(), rotation, rotation + 4);
  log_scales.insert(log_scales.end(), log_scale, log_scale + 3);
  opacity_logits.push_back(opacity_logit);
  const int k = sh_per_gaussian();
  if (sh_values != nullptr) {
    sh.insert(sh.end(), sh_values, sh_values + k);
  } else {
    sh.insert(sh.end(), static_cast<std::size_t>(k), 0.0f);
  }
  if (feature_values != nullptr) {
    features.insert(features.end(), feature_values, feature_values + feature_dim);
  } else {
    features.insert(features.end(), static_cast<std::size_t>(feature_dim), 0.0f);
  }
  filter_3d.push_back(filter_variance);
}

void GaussianMap::append(const GaussianMap& other) {
  means.insert(means.end(), other.means.begin(), other.means.end());
  rotations.insert(rotations.end(), other.rotations.begin(), other.rotations.end());
  log_scales.insert(log_scales.end(), other.log_scales.begin(), other.log_scales.end());
  opacity_logits.insert(opacity_logits.end(), other.opacity_logits.begin(),
                        other.opacity_logits.end());
  sh.insert(sh.end(), other.sh.begin(), other.sh.end());
  features.insert(features.end(), other.features.begin(), other.features.end());
  filter_3d.insert(filter_3d.end(), other.filter_3d.begin(), other.filter_3d.end());
}

void GaussianMap::keep_only(const std::vector<std::uint8_t>& keep) {
  keep_rows(&means, 3, keep);
  keep_rows(&rotations, 4, keep);
  keep_rows(&log_scales, 3, keep);
  keep_rows(&opacity_logits, 1, keep);
  keep_rows(&sh, static_cast<std::size_t>(sh_per_gaussian()), keep);
  keep_rows(&features, static_cast<std::size_t>(feature_dim), keep);
  keep_rows(&filter_3d, 1, keep);
}

bool GaussianMap::is_consistent(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  if (sh_degree < 0 || sh_degree > kMaxShDegree) {
    return fail("SH degree " + std::to_string(sh_degree) + " is outside 0..3");
  }
  if (feature_dim < 0) return fail("negative feature dimension");
  const std::size_t n = size();
  struct Array {
    const char* name;
    const std::vector<float>* values;
    std::size_t row;
  };
  const Array arrays[] = {{"means", &means, 3},
                          {"rotations", &rotations, 4},
                          {"log_scales", &log_scales, 3},
                          {"opacity_logits", &opacity_logits, 1},
                          {"sh", &sh, static_cast<std::size_t>(sh_per_gaussian())},
                          {"features", &features, static_cast<std::size_t>(feature_dim)},
                          {"filter_3d", &filter_3d, 1}};
  for (const Array& a : arrays) {
    if (a.values->size() != n * a.row) {
      return fail(std::string(a.name) + " holds " + std::to_string(a.values->size()) +
                  " values, expected " + std::to_string(n * a.row));
    }
    if (!all_finite(*a.values)) return fail(std::string(a.name) + " holds a non-finite value");
  }
  for (std::size_t i = 0; i < n; ++i) {
    const float* q = rotations.data() + 4 * i;
    if (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] < 1e-12f) {
      return fail("rotation " + std::to_string(i) + " is zero");
    }
  }
  return true;
}

MapVersions::Version MapVersions::latest() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return latest_;
}

std::uint64_t MapVersions::version_number() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return number_;
}

void MapVersions::publish(Version map) {
  std::lock_guard<std::mutex> lock(mutex_);
  latest_ = std::move(map);
  ++number_;
}

void MapVersions::continue_after(std::uint64_t number) {
  std::lock_guard<std::mutex> lock(mutex_);
  number_ = number;
}

}  // namespace fslam::core
