// Per-pixel SSIM math shared by the evaluation (core), the CUDA backend and the mapping loss:
// single-scale SSIM (Wang et al. 2004) with a normalised Gaussian window, as 3DGS's
// loss_utils.ssim computes it (zero-padded 'same' convolution per channel).
// Scalar type T: float in kernels and the loss, double in the evaluation. The variance
// E[x^2] - mu^2 cancels and C2 = 9e-4 is small, so a float window whose weights sum to 1 + 1e-7
// already moves SSIM by ~1e-5; metrics reported to 4 digits are computed in double.
#pragma once

#include <math.h>  // exp: a device function under nvcc, the C library on the host

#include "fslam/core/math/host_device.hpp"

namespace fslam::core::math {

constexpr int kSsimWindow = 11;     // pixels, odd
constexpr float kSsimSigma = 1.5f;  // pixels
constexpr double kSsimK1 = 0.01;    // C1 = (K1 L)^2
constexpr double kSsimK2 = 0.03;    // C2 = (K2 L)^2

// Unnormalised 1D Gaussian weight of tap k in [0, window): exp(-(k - window / 2)^2 / (2 sigma^2)).
template <typename T>
FSLAM_HD T ssim_gaussian_tap(int k, int window, T sigma) {
  const double d = static_cast<double>(k - window / 2);
  const double s = static_cast<double>(sigma);
  return static_cast<T>(exp(-d * d / (2.0 * s * s)));
}

// Normalised 1D window: weights[window] summing to 1. The 2D window is the outer product
// w2(a, b) = weights[a] * weights[b], which also sums to 1.
template <typename T>
FSLAM_HD void ssim_gaussian_window(int window, T sigma, T* weights) {
  T sum = T(0);
  for (int k = 0; k < window; ++k) sum += (weights[k] = ssim_gaussian_tap<T>(k, window, sigma));
  for (int k = 0; k < window; ++k) weights[k] /= sum;
}

// Stabilising constants for pixel values in [0, data_range].
template <typename T>
FSLAM_HD T ssim_c1(T data_range) {
  return static_cast<T>(kSsimK1 * kSsimK1) * data_range * data_range;
}
template <typename T>
FSLAM_HD T ssim_c2(T data_range) {
  return static_cast<T>(kSsimK2 * kSsimK2) * data_range * data_range;
}

// SSIM from the local (Gaussian-weighted) moments of x and y:
// ((2 mu_x mu_y + C1)(2 cov_xy + C2)) / ((mu_x^2 + mu_y^2 + C1)(var_x + var_y + C2)),
// var_x = E[x^2] - mu_x^2, cov_xy = E[xy] - mu_x mu_y.
template <typename T>
FSLAM_HD T ssim_from_moments(T mu_x, T mu_y, T var_x, T var_y, T cov_xy, T c1, T c2) {
  return ((T(2) * mu_x * mu_y + c1) * (T(2) * cov_xy + c2)) /
         ((mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2));
}

// SSIM at pixel (u, v) of channel c of two planar images x, y ([channels, height, width],
// row-major), straight from the definition: the window's taps outside the image read 0 and keep
// their weight (zero-padded 'same' convolution, no renormalisation), as in 3DGS.
// weights: the normalised 1D window from ssim_gaussian_window, `window` taps.
template <typename T>
FSLAM_HD T ssim_pixel(const T* x, const T* y, int width, int height, int u, int v, int c,
                      const T* weights, int window, T c1, T c2) {
  const int half = window / 2;
  const T* xc = x + static_cast<long long>(c) * width * height;
  const T* yc = y + static_cast<long long>(c) * width * height;
  T mx = T(0), my = T(0), mxx = T(0), myy = T(0), mxy = T(0);
  for (int a = 0; a < window; ++a) {
    const int vv = v + a - half;
    if (vv < 0 || vv >= height) continue;
    for (int b = 0; b < window; ++b) {
      const int uu = u + b - half;
      if (uu < 0 || uu >= width) continue;
      const T w = weights[a] * weights[b];
      const T xi = xc[vv * width + uu];
      const T yi = yc[vv * width + uu];
      mx += w * xi;
      my += w * yi;
      mxx += w * xi * xi;
      myy += w * yi * yi;
      mxy += w * xi * yi;
    }
  }
  return ssim_from_moments(mx, my, mxx - mx * mx, myy - my * my, mxy - mx * my, c1, c2);
}

}  // namespace fslam::core::math
