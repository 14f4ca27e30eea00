// Private to core/src/features: the dense algebra the feature autoencoder's files share (row-major
// Eigen views of its flat buffers, the activations and their derivatives, the portable uniform
// draw of its initial weights).
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <random>
#include <string>
#include <vector>

#include "fslam/core/features/feature_autoencoder.hpp"

namespace fslam::core::autoencoder_detail {

using RowMat = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Stride = Eigen::OuterStride<>;
using In = Eigen::Map<const RowMat, 0, Stride>;  // a [rows, cols] block of a wider buffer
using Out = Eigen::Map<RowMat, 0, Stride>;

inline In in(const float* p, int rows, int cols, int stride) { return In(p, rows, cols, Stride(stride)); }
inline In in(const float* p, int rows, int cols) { return in(p, rows, cols, cols); }
inline Out out(float* p, int rows, int cols, int stride) { return Out(p, rows, cols, Stride(stride)); }
inline Out out(float* p, int rows, int cols) { return out(p, rows, cols, cols); }
inline Eigen::Map<const Eigen::RowVectorXf> row(const float* p, int n) {
  return Eigen::Map<const Eigen::RowVectorXf>(p, n);
}
// dst[j] += sum over i of m[i * stride + j] for j < cols, the rows added in order: a bias's
// gradient. A plain loop: Eigen's colwise().sum() assigned to a Map summed the columns before the
// first 32-byte-aligned one differently from the rest, so the bias gradients, and with them the
// trained weights, depended on where the gradient buffer landed in memory.
inline void add_column_sums(const float* m, int rows, int cols, int stride, float* dst) {
  for (int i = 0; i < rows; ++i) {
    const float* row = m + static_cast<std::size_t>(i) * static_cast<std::size_t>(stride);
    for (int j = 0; j < cols; ++j) dst[j] += row[j];
  }
}
inline bool ends_with(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}
constexpr double kPi = 3.14159265358979323846;

// Portable uniform [0, 1) from mt19937's standardised output (std::uniform_real_distribution
// differs between standard libraries, and the initial weights should not).
inline float uniform01(std::mt19937* rng) {
  return static_cast<float>((*rng)() >> 8) * (1.0f / 16777216.0f);
}

// GELU, tanh form (Hendrycks & Gimpel 2016): 0.5 x (1 + tanh(k (x + 0.044715 x^3))).
constexpr float kGeluK = 0.7978845608f;  // sqrt(2 / pi)
constexpr float kGeluC = 0.044715f;

inline Eigen::Map<const Eigen::ArrayXf> array(const std::vector<float>& v) {
  return Eigen::Map<const Eigen::ArrayXf>(v.data(), static_cast<Eigen::Index>(v.size()));
}

inline void activate(AutoencoderActivation a, const std::vector<float>& pre, std::vector<float>* act) {
  act->resize(pre.size());
  const auto x = array(pre);
  auto y = Eigen::Map<Eigen::ArrayXf>(act->data(), static_cast<Eigen::Index>(act->size()));
  if (a == AutoencoderActivation::relu) y = x.max(0.0f);
  else y = 0.5f * x * (1.0f + (kGeluK * (x + kGeluC * x.cube())).tanh());
}

// grad *= activation'(pre), elementwise.
inline void activate_backward(AutoencoderActivation a, const std::vector<float>& pre, float* grad) {
  const auto x = array(pre);
  auto g = Eigen::Map<Eigen::ArrayXf>(grad, static_cast<Eigen::Index>(pre.size()));
  if (a == AutoencoderActivation::relu) {
    g *= (x > 0.0f).cast<float>();
  } else {
    const Eigen::ArrayXf t = (kGeluK * (x + kGeluC * x.cube())).tanh();
    g *= 0.5f * (1.0f + t) +
         0.5f * x * (1.0f - t.square()) * kGeluK * (1.0f + 3.0f * kGeluC * x.square());
  }
}

inline std::size_t sz(int n, int c) { return static_cast<std::size_t>(n) * static_cast<std::size_t>(c); }

}  // namespace fslam::core::autoencoder_detail
