// Per-pixel and per-Gaussian math of the mapping losses, shared by the CPU loss code
// (core/mapping/image_losses) and the CUDA kernels: normals from depth and their backward, the
// cosine term, the SSIM moment gradients, the PCC per-pixel gradient, the eRank barrier, the
// thinness term and the eRank weight ramp (paper, "Depth-normal consistency & regularization").
// Scalar type T: float in production, double in the gradient tests.
#pragma once

#include <math.h>  // exp, log, sqrt: device functions under nvcc, the C library on the host

#include "fslam/core/math/host_device.hpp"
#include "fslam/core/math/unproject.hpp"

namespace fslam::core::math {

// ---- normals from depth ---------------------------------------------------------------------

// A depth sample that is > 0 and finite (z - z is NaN for +-inf and NaN): an observed depth that
// is supervised, a depth that takes part in a normal.
template <typename T>
FSLAM_HD bool positive_finite(T z) {
  return z > T(0) && z - z == T(0);
}

// Ray r = K^-1 [u, v, 1] of pixel (u, v): the unprojected point is P = z r, so dP/dz = r.
template <typename T>
FSLAM_HD void pixel_ray(const Intrinsics& k, int u, int v, T* r) {
  r[0] = (static_cast<T>(u) - static_cast<T>(k.cx)) / static_cast<T>(k.fx);
  r[1] = (static_cast<T>(v) - static_cast<T>(k.cy)) / static_cast<T>(k.fy);
  r[2] = T(1);
}

template <typename T>
FSLAM_HD void cross3(const T* a, const T* b, T* c) {
  c[0] = a[1] * b[2] - a[2] * b[1];
  c[1] = a[2] * b[0] - a[0] * b[2];
  c[2] = a[0] * b[1] - a[1] * b[0];
}

template <typename T>
FSLAM_HD T dot3(const T* a, const T* b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// The central differences of the unprojected neighbours of pixel (u, v):
// dx = P(u+1, v) - P(u-1, v), dy = P(u, v+1) - P(u, v-1), and c = dy x dx.
// dy x dx (not dx x dy) because P_u x P_v . P = z^3 / (fx fy) > 0 for any surface seen through
// the image, so dy x dx faces the camera (n . P < 0) without a sign flip that would break the
// gradient: a fronto-parallel plane gets (0, 0, -1).
template <typename T>
FSLAM_HD void normal_differences(const Intrinsics& k, int u, int v, T z_left, T z_right, T z_up,
                                 T z_down, T* dx, T* dy, T* c) {
  T rl[3], rr[3], ru[3], rd[3];
  pixel_ray(k, u - 1, v, rl);
  pixel_ray(k, u + 1, v, rr);
  pixel_ray(k, u, v - 1, ru);
  pixel_ray(k, u, v + 1, rd);
  for (int i = 0; i < 3; ++i) {
    dx[i] = z_right * rr[i] - z_left * rl[i];
    dy[i] = z_down * rd[i] - z_up * ru[i];
  }
  cross3(dy, dx, c);
}

// Paper eq. for n_exp / n_med / n_obs: n = (d_u P x d_v P) / |...| by finite differences (oriented
// towards the camera, see normal_differences). Pixel (u, v) of a row-major depth image
// [height, width]: the normal is defined when the pixel and its four neighbours are valid depths
// and the cross product is non-zero; otherwise n = 0 and false.
// The differences and unnormalised normal c = dy x dx at pixel (u, v), and |c|; false where the
// pixel or a neighbour has no depth, on the border, or where the differences are parallel.
template <typename T>
FSLAM_HD bool normal_stencil(const T* depth, int width, int height, const Intrinsics& k, int u,
                             int v, T* dx, T* dy, T* c, T* len) {
  if (u < 1 || v < 1 || u >= width - 1 || v >= height - 1) return false;
  const int i = v * width + u;
  const T zc = depth[i], zl = depth[i - 1], zr = depth[i + 1];
  const T zu = depth[i - width], zd = depth[i + width];
  if (!positive_finite(zc) || !positive_finite(zl) || !positive_finite(zr) ||
      !positive_finite(zu) || !positive_finite(zd))
    return false;
  normal_differences(k, u, v, zl, zr, zu, zd, dx, dy, c);
  *len = sqrt(dot3(c, c));
  return *len > T(0);
}

template <typename T>
FSLAM_HD bool normal_at_pixel(const T* depth, int width, int height, const Intrinsics& k, int u,
                              int v, T* n) {
  n[0] = n[1] = n[2] = T(0);
  T dx[3], dy[3], c[3], len;
  if (!normal_stencil(depth, width, height, k, u, v, dx, dy, c, &len)) return false;
  for (int j = 0; j < 3; ++j) n[j] = c[j] / len;
  return true;
}

// Vector-Jacobian product of normal_at_pixel: given g = dL/dn at pixel (u, v), writes
// dL/dz for the neighbours into grad_z = {left, right, up, down} (the centre depth does not enter
// the normal). Returns false (grad_z zero) where the normal is undefined. A kernel adds grad_z
// into the four neighbours atomically; the CPU loops scatter serially.
// n = c / |c| -> dL/dc = (g - n (n . g)) / |c|; c = dy x dx -> dL/ddy = dx x dL/dc,
// dL/ddx = dL/dc x dy; dx = z_r r_r - z_l r_l -> dL/dz_r = dL/ddx . r_r, dL/dz_l = -dL/ddx . r_l.
template <typename T>
FSLAM_HD bool normal_at_pixel_backward(const T* depth, int width, int height, const Intrinsics& k,
                                       int u, int v, const T* g, T* grad_z) {
  grad_z[0] = grad_z[1] = grad_z[2] = grad_z[3] = T(0);
  T dx[3], dy[3], c[3], len;
  if (!normal_stencil(depth, width, height, k, u, v, dx, dy, c, &len)) return false;
  T n[3], gc[3];
  for (int j = 0; j < 3; ++j) n[j] = c[j] / len;
  const T ng = dot3(n, g);
  for (int j = 0; j < 3; ++j) gc[j] = (g[j] - n[j] * ng) / len;
  T gdx[3], gdy[3];
  cross3(gc, dy, gdx);
  cross3(dx, gc, gdy);
  T rl[3], rr[3], ru[3], rd[3];
  pixel_ray(k, u - 1, v, rl);
  pixel_ray(k, u + 1, v, rr);
  pixel_ray(k, u, v - 1, ru);
  pixel_ray(k, u, v + 1, rd);
  grad_z[0] = -dot3(gdx, rl);
  grad_z[1] = dot3(gdx, rr);
  grad_z[2] = -dot3(gdy, ru);
  grad_z[3] = dot3(gdy, rd);
  return true;
}

// A normal is defined when non-zero: depth_to_normals writes exact zeros where it is not.
template <typename T>
FSLAM_HD bool normal_is_defined(const T* n) {
  return dot3(n, n) > T(0);
}

// Cosine term of eq. modeling_losses, 1 - n_a . n_b for unit normals; d/dn_a = -n_b (the
// normalisation's Jacobian is applied by normal_at_pixel_backward).
template <typename T>
FSLAM_HD T cosine_term(const T* n_a, const T* n_b, T* grad_a) {
  if (grad_a) {
    grad_a[0] = -n_b[0];
    grad_a[1] = -n_b[1];
    grad_a[2] = -n_b[2];
  }
  return T(1) - dot3(n_a, n_b);
}

// ---- SSIM backward --------------------------------------------------------------------------

// SSIM from the raw local moments mx = G*x, my = G*y, sxx = G*(x^2), syy = G*(y^2),
// sxy = G*(xy) (ssim_from_moments after var = sxx - mx^2, cov = sxy - mx my), and its partial
// derivatives with respect to the moments that depend on x. The loss gradient is then
// dL/dx = G^T*(dL/dmx) + 2 x G^T*(dL/dsxx) + y G^T*(dL/dsxy): three blurs instead of a
// window-sized loop per pixel.
// S = A1 A2 / (B1 B2), A1 = 2 mx my + C1, A2 = 2 (sxy - mx my) + C2, B1 = mx^2 + my^2 + C1,
// B2 = sxx - mx^2 + syy - my^2 + C2.
template <typename T>
FSLAM_HD T ssim_moment_gradients(T mx, T my, T sxx, T syy, T sxy, T c1, T c2, T* d_mx, T* d_sxx,
                                 T* d_sxy) {
  const T a1 = T(2) * mx * my + c1;
  const T a2 = T(2) * (sxy - mx * my) + c2;
  const T b1 = mx * mx + my * my + c1;
  const T b2 = sxx - mx * mx + syy - my * my + c2;
  const T inv_b1 = T(1) / b1, inv_b2 = T(1) / b2;
  const T inv_b = inv_b1 * inv_b2;
  const T s = a1 * a2 * inv_b;
  *d_mx = T(2) * my * (a2 - a1) * inv_b - T(2) * mx * s * (inv_b1 - inv_b2);
  *d_sxx = -s * inv_b2;
  *d_sxy = T(2) * a1 * inv_b;
  return s;
}

// ---- Pearson correlation (eq. pcc_loss) ------------------------------------------------------

// rho = S_ab / sqrt(S_aa S_bb) from centred sums over a block's valid pixels
// (S_ab = sum (a - mean a)(b - mean b), ...).
template <typename T>
FSLAM_HD T pearson_from_sums(T s_ab, T s_aa, T s_bb) {
  return s_ab / sqrt(s_aa * s_bb);
}

// d rho / d a_i for one valid pixel with centred values da = a_i - mean a, db = b_i - mean b:
// db / sqrt(S_aa S_bb) - rho da / S_aa (the means' own derivatives cancel since sum da = 0).
template <typename T>
FSLAM_HD T pearson_gradient(T da, T db, T s_aa, T s_bb, T rho) {
  return db / sqrt(s_aa * s_bb) - rho * da / s_aa;
}

// ---- Gaussian shape regularisers --------------------------------------------------------------

// eq. norm_singular and eq. entropy from log-scales l (s = exp(l)): p = softmax(2 l), computed
// with the maximum subtracted so that needles (p_k -> 0) stay finite in float. Writes p and
// log p (both [3]); returns H.
template <typename T>
FSLAM_HD T scale_entropy(const T* log_scales, T* p, T* log_p) {
  T m = T(2) * log_scales[0];
  for (int k = 1; k < 3; ++k) m = T(2) * log_scales[k] > m ? T(2) * log_scales[k] : m;
  T sum = T(0);
  for (int k = 0; k < 3; ++k) sum += (p[k] = exp(T(2) * log_scales[k] - m));
  const T log_sum = log(sum);
  T h = T(0);
  for (int k = 0; k < 3; ++k) {
    p[k] /= sum;
    log_p[k] = T(2) * log_scales[k] - m - log_sum;
    h -= p[k] * log_p[k];
  }
  return h;
}

// erank = exp(H) in [1, 3]: 1 for a needle, 3 for a sphere.
template <typename T>
FSLAM_HD T effective_rank(const T* log_scales) {
  T p[3], log_p[3];
  return exp(scale_entropy(log_scales, p, log_p));
}

// eq. erank_loss for one Gaussian (without lambda): -log(erank - 1 + eps), and when grad is
// non-null its derivative w.r.t. the three log-scales, written to grad[3]:
// dH/dl_j = -2 p_j (log p_j + H) (p = softmax(2 l)), dL/dH = -erank / (erank - 1 + eps).
template <typename T>
FSLAM_HD T erank_barrier(const T* log_scales, T epsilon, T* grad) {
  T p[3], log_p[3];
  const T h = scale_entropy(log_scales, p, log_p);
  const T erank = exp(h);
  const T arg = erank - T(1) + epsilon;
  if (grad) {
    const T d_h = -erank / arg;
    for (int j = 0; j < 3; ++j) grad[j] = d_h * (T(-2) * p[j] * (log_p[j] + h));
  }
  return -log(arg);
}

// eq. thin_loss for one Gaussian (without lambda): the smallest scale exp(min l), and its
// derivative w.r.t. the log-scales in grad[3] (non-zero only at the smallest; the first on ties).
template <typename T>
FSLAM_HD T thin_term(const T* log_scales, T* grad) {
  int k_min = 0;
  for (int k = 1; k < 3; ++k)
    if (log_scales[k] < log_scales[k_min]) k_min = k;
  const T s = exp(log_scales[k_min]);
  if (grad) {
    grad[0] = grad[1] = grad[2] = T(0);
    grad[k_min] = s;
  }
  return s;
}

// eq. lambda_ramp: lambda_0 + (lambda_max - lambda_0)(1 - exp(-t / T)); T <= 0 means no ramp.
template <typename T>
FSLAM_HD T lambda_ramp(T step, T lambda_0, T lambda_max, T ramp_steps) {
  if (!(ramp_steps > T(0))) return lambda_max;
  return lambda_0 + (lambda_max - lambda_0) * (T(1) - exp(-step / ramp_steps));
}

}  // namespace fslam::core::math
