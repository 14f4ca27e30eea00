// Scalar templates behind image_losses.hpp over raw planar buffers ([channels, height, width],
// row-major), T = float for the PlanarImage wrappers and double for the gradient tests. Shapes
// are the caller's job (asserted); every function ADDS weight * dLoss/dprediction into grad
// when grad is non-null and returns the weighted value; statistics are summed in double.
#pragma once

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <vector>

#include "fslam/core/mapping/image_losses.hpp"
#include "fslam/core/math/loss_math.hpp"
#include "fslam/core/math/ssim.hpp"

namespace fslam::core::loss_impl {

template <typename T>
bool mask_allows(const T* mask, std::size_t i) {
  return mask == nullptr || mask[i] > T(0.5);
}

// ---- L1 ----------------------------------------------------------------------------------------

// Mean |r - o| over the counted pixels x channels; with observed_depth, a pixel also needs a
// positive finite observed value (single-channel depth).
template <typename T>
double l1_loss(const T* rendered, const T* observed, const T* mask, int channels,
               std::size_t pixels, bool observed_depth, double weight, T* grad) {
  auto counted = [&](std::size_t i) {
    return mask_allows(mask, i) && (!observed_depth || math::positive_finite(observed[i]));
  };
  std::size_t counted_pixels = 0;
  for (std::size_t i = 0; i < pixels; ++i) counted_pixels += counted(i) ? 1 : 0;
  if (counted_pixels == 0) return 0.0;
  const double count = static_cast<double>(counted_pixels) * channels;
  const T g = static_cast<T>(weight / count);
  double sum = 0.0;
  for (int c = 0; c < channels; ++c) {
    const std::size_t off = static_cast<std::size_t>(c) * pixels;
    for (std::size_t i = 0; i < pixels; ++i) {
      if (!counted(i)) continue;
      const T d = rendered[off + i] - observed[off + i];
      sum += std::abs(static_cast<double>(d));
      if (grad) grad[off + i] += d > T(0) ? g : (d < T(0) ? -g : T(0));
    }
  }
  return weight * sum / count;
}

// ---- SSIM --------------------------------------------------------------------------------------

// Zero-padded 'same' correlation with a symmetric 1D window (taps[half + k] == taps[half - k])
// along rows: taps outside the image read 0 and keep their weight, as ssim_pixel sums them.
// Each row is copied into a zero-padded line so that every tap pair is one contiguous,
// vectorisable loop; pairing the symmetric taps halves the multiplies.
template <typename T>
void blur_rows(const T* __restrict src, T* __restrict dst, int width, int height, const T* taps,
               int window) {
  const int half = window / 2;
  std::vector<T> line(static_cast<std::size_t>(width) + 2 * half, T(0));
  const T* p = line.data() + half;
  for (int v = 0; v < height; ++v) {
    const T* in = src + static_cast<std::size_t>(v) * width;
    T* out = dst + static_cast<std::size_t>(v) * width;
    std::copy(in, in + width, line.begin() + half);
    const T centre = taps[half];
    for (int u = 0; u < width; ++u) out[u] = centre * p[u];
    for (int k = 1; k <= half; ++k) {
      const T w = taps[half + k];
      for (int u = 0; u < width; ++u) out[u] += w * (p[u - k] + p[u + k]);
    }
  }
}

// The same along columns: each output row is a weighted sum of whole input rows; rows outside
// the image are zeros and drop out.
template <typename T>
void blur_cols(const T* __restrict src, T* __restrict dst, int width, int height, const T* taps,
               int window) {
  const int half = window / 2;
  const std::size_t stride = static_cast<std::size_t>(width);
  for (int v = 0; v < height; ++v) {
    T* out = dst + v * stride;
    const T* mid = src + v * stride;
    const T centre = taps[half];
    for (int u = 0; u < width; ++u) out[u] = centre * mid[u];
    for (int k = 1; k <= half; ++k) {
      const T w = taps[half + k];
      const bool has_up = v - k >= 0, has_down = v + k < height;
      const T* up = has_up ? src + (v - k) * stride : nullptr;
      const T* down = has_down ? src + (v + k) * stride : nullptr;
      if (has_up && has_down) {
        for (int u = 0; u < width; ++u) out[u] += w * (up[u] + down[u]);
      } else if (has_up) {
        for (int u = 0; u < width; ++u) out[u] += w * up[u];
      } else if (has_down) {
        for (int u = 0; u < width; ++u) out[u] += w * down[u];
      }
    }
  }
}

// The 2D Gaussian blur G* of ssim_pixel (outer-product window). With symmetric taps it is also
// its own adjoint, which the SSIM backward relies on.
template <typename T>
void blur(const T* src, T* dst, T* scratch, int width, int height, const T* taps, int window) {
  blur_rows(src, scratch, width, height, taps, window);
  blur_cols(scratch, dst, width, height, taps, window);
}

// weight * (1 - mean SSIM) over the counted pixels x channels (image_losses.hpp: ssim_loss).
template <typename T>
double ssim_loss(const T* rendered, const T* observed, const T* mask, int channels, int width,
                 int height, double weight, T* grad) {
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  std::size_t counted_pixels = 0;
  for (std::size_t i = 0; i < pixels; ++i) counted_pixels += mask_allows(mask, i) ? 1 : 0;
  if (counted_pixels == 0) return 0.0;
  const double count = static_cast<double>(counted_pixels) * channels;

  constexpr int window = math::kSsimWindow;
  T taps[window];
  math::ssim_gaussian_window(window, static_cast<T>(math::kSsimSigma), taps);
  for (int k = 0; k < window / 2; ++k) assert(taps[k] == taps[window - 1 - k]);
  const T c1 = math::ssim_c1(T(1)), c2 = math::ssim_c2(T(1));
  const T d_ssim = static_cast<T>(-weight / count);  // dLoss/dSSIM at a counted pixel

  // Planes, reused per channel: products, then the five moments; after the per-pixel step the
  // product planes hold the moment gradients and the blurred gradients.
  std::vector<T> buffer(9 * pixels);
  T* scratch = buffer.data();
  T* prod = scratch + pixels;
  T *mx = prod + pixels, *my = mx + pixels, *sxx = my + pixels, *syy = sxx + pixels,
    *sxy = syy + pixels;
  T* extra = sxy + pixels;  // second product plane
  double sum = 0.0;
  for (int c = 0; c < channels; ++c) {
    const T* x = rendered + static_cast<std::size_t>(c) * pixels;
    const T* y = observed + static_cast<std::size_t>(c) * pixels;
    blur(x, mx, scratch, width, height, taps, window);
    blur(y, my, scratch, width, height, taps, window);
    for (std::size_t i = 0; i < pixels; ++i) prod[i] = x[i] * x[i];
    blur(prod, sxx, scratch, width, height, taps, window);
    for (std::size_t i = 0; i < pixels; ++i) prod[i] = y[i] * y[i];
    blur(prod, syy, scratch, width, height, taps, window);
    for (std::size_t i = 0; i < pixels; ++i) prod[i] = x[i] * y[i];
    blur(prod, sxy, scratch, width, height, taps, window);

    // Per pixel: SSIM and dLoss/d(moments), written over the moment planes that are done with.
    for (std::size_t i = 0; i < pixels; ++i) {
      T d_mx, d_sxx, d_sxy;
      const T s = math::ssim_moment_gradients(mx[i], my[i], sxx[i], syy[i], sxy[i], c1, c2, &d_mx,
                                              &d_sxx, &d_sxy);
      const bool counted = mask_allows(mask, i);
      if (counted) sum += static_cast<double>(s);
      const T g = counted ? d_ssim : T(0);
      mx[i] = g * d_mx;
      sxx[i] = g * d_sxx;
      sxy[i] = g * d_sxy;
    }
    if (!grad) continue;
    // dL/dx = G^T*(dL/dmx) + 2 x G^T*(dL/dsxx) + y G^T*(dL/dsxy), G^T = G (symmetric taps).
    blur(mx, my, scratch, width, height, taps, window);
    blur(sxx, syy, scratch, width, height, taps, window);
    blur(sxy, extra, scratch, width, height, taps, window);
    T* gx = grad + static_cast<std::size_t>(c) * pixels;
    for (std::size_t i = 0; i < pixels; ++i)
      gx[i] += my[i] + T(2) * x[i] * syy[i] + y[i] * extra[i];
  }
  return weight * (1.0 - sum / count);
}

// ---- PCC (eq. pcc_loss) ------------------------------------------------------------------------

// One block that enters the mean, with what its gradient needs.
struct PccBlock {
  int u0, v0, u1, v1;  // pixel range [u0, u1) x [v0, v1)
  double mean_r, mean_o, s_rr, s_oo, rho;
};

// weight * (1 - mean rho over the used blocks) (image_losses.hpp: pcc_loss).
template <typename T>
double pcc_loss(const T* rendered, const T* observed, const T* mask, int width, int height,
                const PccConfig& config, double weight, T* grad, int* blocks_used) {
  const int p = config.block;
  const double min_var = config.min_std * config.min_std;
  auto valid = [&](std::size_t i) {
    return mask_allows(mask, i) && math::positive_finite(observed[i]);
  };
  std::vector<PccBlock> used;
  for (int v0 = 0; v0 < height; v0 += p) {
    for (int u0 = 0; u0 < width; u0 += p) {
      PccBlock b{u0, v0, std::min(u0 + p, width), std::min(v0 + p, height), 0, 0, 0, 0, 0};
      int n = 0;
      for (int v = b.v0; v < b.v1; ++v)
        for (int u = b.u0; u < b.u1; ++u) {
          const std::size_t i = static_cast<std::size_t>(v) * width + u;
          if (!valid(i)) continue;
          ++n;
          b.mean_r += rendered[i];
          b.mean_o += observed[i];
        }
      if (n < config.min_valid_pixels) continue;
      b.mean_r /= n;
      b.mean_o /= n;
      double s_ro = 0.0;  // centred sums: two passes keep float depths well conditioned
      for (int v = b.v0; v < b.v1; ++v)
        for (int u = b.u0; u < b.u1; ++u) {
          const std::size_t i = static_cast<std::size_t>(v) * width + u;
          if (!valid(i)) continue;
          const double dr = rendered[i] - b.mean_r, d_o = observed[i] - b.mean_o;
          b.s_rr += dr * dr;
          b.s_oo += d_o * d_o;
          s_ro += dr * d_o;
        }
      if (b.s_rr < n * min_var || b.s_oo < n * min_var) continue;
      b.rho = math::pearson_from_sums(s_ro, b.s_rr, b.s_oo);
      used.push_back(b);
    }
  }
  if (blocks_used) *blocks_used = static_cast<int>(used.size());
  if (used.empty()) return 0.0;
  double rho_sum = 0.0;
  for (const PccBlock& b : used) rho_sum += b.rho;
  const double nb = static_cast<double>(used.size());
  if (grad) {
    const double g = -weight / nb;  // dLoss/drho of each used block
    for (const PccBlock& b : used)
      for (int v = b.v0; v < b.v1; ++v)
        for (int u = b.u0; u < b.u1; ++u) {
          const std::size_t i = static_cast<std::size_t>(v) * width + u;
          if (!valid(i)) continue;
          grad[i] += static_cast<T>(g * math::pearson_gradient(rendered[i] - b.mean_r,
                                                               observed[i] - b.mean_o, b.s_rr,
                                                               b.s_oo, b.rho));
        }
  }
  return weight * (1.0 - rho_sum / nb);
}

// ---- normals -----------------------------------------------------------------------------------

// normals [3, H, W] from depth [H, W]; every pixel written (0 where undefined).
template <typename T>
void depth_to_normals(const T* depth, int width, int height, const math::Intrinsics& k,
                      T* normals) {
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u) {
      T n[3];
      math::normal_at_pixel(depth, width, height, k, u, v, n);
      const std::size_t i = static_cast<std::size_t>(v) * width + u;
      for (int j = 0; j < 3; ++j) normals[j * pixels + i] = n[j];
    }
}

// grad_depth [H, W] += dL/ddepth given grad_normals [3, H, W] = dL/dnormals.
template <typename T>
void depth_to_normals_backward(const T* depth, int width, int height, const math::Intrinsics& k,
                               const T* grad_normals, T* grad_depth) {
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  for (int v = 1; v < height - 1; ++v)
    for (int u = 1; u < width - 1; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * width + u;
      const T g[3] = {grad_normals[i], grad_normals[pixels + i], grad_normals[2 * pixels + i]};
      if (g[0] == T(0) && g[1] == T(0) && g[2] == T(0)) continue;
      T gz[4];
      if (!math::normal_at_pixel_backward(depth, width, height, k, u, v, g, gz)) continue;
      grad_depth[i - 1] += gz[0];
      grad_depth[i + 1] += gz[1];
      grad_depth[i - width] += gz[2];
      grad_depth[i + width] += gz[3];
    }
}

// weight * mean (1 - n_r . n_o) over the pixels where both are defined and the mask allows.
template <typename T>
double normal_consistency_loss(const T* rendered, const T* observed, const T* mask,
                               std::size_t pixels, double weight, T* grad) {
  auto load = [pixels](const T* img, std::size_t i, T* n) {
    for (int j = 0; j < 3; ++j) n[j] = img[j * pixels + i];
  };
  auto counted = [&](std::size_t i, T* nr, T* no) {
    load(rendered, i, nr);
    load(observed, i, no);
    return mask_allows(mask, i) && math::normal_is_defined(nr) && math::normal_is_defined(no);
  };
  std::size_t count = 0;
  T nr[3], no[3], gn[3];
  for (std::size_t i = 0; i < pixels; ++i) count += counted(i, nr, no) ? 1 : 0;
  if (count == 0) return 0.0;
  const double scale = weight / static_cast<double>(count);
  double sum = 0.0;
  for (std::size_t i = 0; i < pixels; ++i) {
    if (!counted(i, nr, no)) continue;
    sum += static_cast<double>(math::cosine_term(nr, no, gn));
    if (grad)
      for (int j = 0; j < 3; ++j) grad[j * pixels + i] += static_cast<T>(scale * gn[j]);
  }
  return scale * sum;
}

// ---- Gaussian shape regularisers ---------------------------------------------------------------

// lambda * mean over n Gaussians of the eRank barrier; log_scales, grad: [n, 3].
template <typename T>
double erank_loss(const T* log_scales, std::size_t n, double lambda, double epsilon, T* grad) {
  if (n == 0) return 0.0;
  const double scale = lambda / static_cast<double>(n);
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    T g[3];
    sum += static_cast<double>(
        math::erank_barrier(log_scales + 3 * i, static_cast<T>(epsilon), grad ? g : nullptr));
    if (grad)
      for (int j = 0; j < 3; ++j) grad[3 * i + j] += static_cast<T>(scale * g[j]);
  }
  return scale * sum;
}

// lambda * mean over n Gaussians of the smallest scale; log_scales, grad: [n, 3].
template <typename T>
double thin_loss(const T* log_scales, std::size_t n, double lambda, T* grad) {
  if (n == 0) return 0.0;
  const double scale = lambda / static_cast<double>(n);
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    T g[3];
    sum += static_cast<double>(math::thin_term(log_scales + 3 * i, grad ? g : nullptr));
    if (grad)
      for (int j = 0; j < 3; ++j) grad[3 * i + j] += static_cast<T>(scale * g[j]);
  }
  return scale * sum;
}

}  // namespace fslam::core::loss_impl
