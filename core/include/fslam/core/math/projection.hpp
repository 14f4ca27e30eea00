// Projection of one Gaussian, forward (paper eq. proj): 3D covariance with the 3D smoothing
// filter, EWA's local affine projection, the conic, opacity-aware footprint, camera-plane depth
// coefficients and the SH colour. The backward is projection_backward.hpp.
#pragma once

#include <math.h>  // sqrt, exp, log, ceil: device functions under nvcc, the C library on the host

#include "fslam/core/math/host_device.hpp"
#include "fslam/core/math/small_linalg.hpp"
#include "fslam/core/math/spherical_harmonics.hpp"
#include "fslam/core/math/splat_types.hpp"

namespace fslam::core::math {

// Everything the forward projection computes that its backward needs again.
template <typename T>
struct ProjectionTerms {
  T R_g[9];         // Gaussian rotation (to world)
  T scale[3];       // exp(log_scale), metres
  T scale_eff[3];   // sqrt(scale^2 + filter variance)
  T opacity_raw;    // sigmoid(logit)
  T filter_coef;    // prod scale / scale_eff (3D filter opacity compensation)
  T mean_cam[3];    // camera frame
  T cov_cam[9];     // camera-frame 3D covariance
  T J[6];           // 2x3 Jacobian of the local affine projection, row-major
  T cov2d[3];       // a, b, c of [[a, b], [b, c]] before inversion (incl. low-pass)
  bool clamp_x, clamp_y;  // the Jacobian's x/z, y/z were clamped
  T y_plane[3];     // N^T mu_cam with N = R R_g S^-1 (planar depth)
  T w_plane[3];     // Sigma_cam^-1 mu_cam
  T m_plane;        // mu_cam^T Sigma_cam^-1 mu_cam
  T dir[3];         // unit view direction, world (SH)
  T dir_norm;       // |mean - camera centre|
  T colour_raw[3];  // 0.5 + SH before the clamp at 0
};

// Clamps x/z and y/z for the Jacobian of the projection to the image's extent in normalised
// coordinates, widened on each side by (kFovClampFactor - 1) of its half-size: 3DGS's
// 1.3 tan(fov/2) for a centred principal point, and the same window around a crop's own extent.
// Returns which coordinates were clamped.
template <typename T>
FSLAM_HD void clamp_to_view(const SplatCamera<T>& cam, T* tx, T* ty, bool* clamped_x,
                            bool* clamped_y) {
  const T left = -cam.cx / cam.fx, right = (T(cam.width) - cam.cx) / cam.fx;
  const T top = -cam.cy / cam.fy, bottom = (T(cam.height) - cam.cy) / cam.fy;
  const T margin_x = T(0.5) * (T(kFovClampFactor) - T(1)) * (right - left);
  const T margin_y = T(0.5) * (T(kFovClampFactor) - T(1)) * (bottom - top);
  const T lo_x = left - margin_x, hi_x = right + margin_x;
  const T lo_y = top - margin_y, hi_y = bottom + margin_y;
  *clamped_x = *tx < lo_x || *tx > hi_x;
  *clamped_y = *ty < lo_y || *ty > hi_y;
  *tx = *tx < lo_x ? lo_x : (*tx > hi_x ? hi_x : *tx);
  *ty = *ty < lo_y ? lo_y : (*ty > hi_y ? hi_y : *ty);
}

// The 3D smoothing filter (Mip-Splatting) on one Gaussian: scale = exp(log_scale), effective
// scales sqrt(scale^2 + filter variance), and the returned opacity compensation
// prod scale / scale_eff that keeps the Gaussian's mass.
template <typename T>
FSLAM_HD T filtered_scales(const T log_scale[3], T filter_variance, T scale[3], T scale_eff[3]) {
  T coef = T(1);
  for (int k = 0; k < 3; ++k) {
    scale[k] = exp(log_scale[k]);
    scale_eff[k] = sqrt(scale[k] * scale[k] + filter_variance);
    coef *= scale[k] / scale_eff[k];
  }
  return coef;
}

// Projects one Gaussian (eq. proj) and computes its opacity, planar depth coefficients and
// colour. sh: [K, 3]. Returns false when culled (behind the near plane, degenerate, invisible).
template <typename T>
FSLAM_HD bool project_gaussian(const T mean[3], const T quat[4], const T log_scale[3],
                               T opacity_logit, T filter_variance, const T* sh, int sh_degree,
                               const SplatCamera<T>& cam, ProjectedGaussian<T>* out,
                               ProjectionTerms<T>* terms) {
  ProjectionTerms<T>& p = *terms;
  out->radius = 0;
  mat_vec(cam.R, mean, p.mean_cam);
  for (int k = 0; k < 3; ++k) p.mean_cam[k] += cam.t[k];
  const T x = p.mean_cam[0], y = p.mean_cam[1], z = p.mean_cam[2];
  if (!(z > cam.near_plane)) return false;

  // 3D covariance Sigma = R_g S S R_g^T with the 3D smoothing filter added to S^2.
  quat_to_rotmat(quat, p.R_g);
  p.filter_coef = filtered_scales(log_scale, filter_variance, p.scale, p.scale_eff);
  T M[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) M[3 * r + c] = p.R_g[3 * r + c] * p.scale_eff[c];
  T cov_world[9], tmp[9];
  mat_mul_t(M, M, cov_world);
  mat_mul(cam.R, cov_world, tmp);
  mat_mul_t(tmp, cam.R, p.cov_cam);

  // Local affine approximation of the perspective projection (EWA), x/z and y/z clamped as in
  // 3DGS so that Gaussians far outside the view do not get enormous footprints.
  T tx = x / z, ty = y / z;
  clamp_to_view(cam, &tx, &ty, &p.clamp_x, &p.clamp_y);
  p.J[0] = cam.fx / z;
  p.J[1] = T(0);
  p.J[2] = -cam.fx * tx / z;
  p.J[3] = T(0);
  p.J[4] = cam.fy / z;
  p.J[5] = -cam.fy * ty / z;
  T JS[6];  // J Sigma_cam
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c)
      JS[3 * r + c] = p.J[3 * r] * p.cov_cam[c] + p.J[3 * r + 1] * p.cov_cam[3 + c] +
                      p.J[3 * r + 2] * p.cov_cam[6 + c];
  p.cov2d[0] = JS[0] * p.J[0] + JS[1] * p.J[1] + JS[2] * p.J[2] + T(kLowPassVariance);
  p.cov2d[1] = JS[0] * p.J[3] + JS[1] * p.J[4] + JS[2] * p.J[5];
  p.cov2d[2] = JS[3] * p.J[3] + JS[4] * p.J[4] + JS[5] * p.J[5] + T(kLowPassVariance);
  const T det = p.cov2d[0] * p.cov2d[2] - p.cov2d[1] * p.cov2d[1];
  if (!(det > T(0))) return false;
  out->conic[0] = p.cov2d[2] / det;
  out->conic[1] = -p.cov2d[1] / det;
  out->conic[2] = p.cov2d[0] / det;

  p.opacity_raw = sigmoid(opacity_logit);
  out->opacity = p.opacity_raw * p.filter_coef;
  if (!(out->opacity > T(kAlphaMin))) return false;  // alpha <= opacity: never visible
  // Opacity-aware footprint: beyond r, opacity * exp(-r^2 / (2 lambda_max)) < kAlphaMin, so the
  // per-pixel test would skip every pixel anyway.
  const T mid = T(0.5) * (p.cov2d[0] + p.cov2d[2]);
  const T disc = mid * mid - det;
  const T lambda_max = mid + sqrt(disc > T(0) ? disc : T(0));
  const T level = T(2) * log(out->opacity / T(kAlphaMin));  // d^T Sigma2D^-1 d at alpha_min
  const int radius = static_cast<int>(ceil(sqrt(level * lambda_max)));
  out->power_floor = -T(0.5) * level;
  // The ellipse d^T Sigma^-1 d <= level spans sqrt(level Sigma_xx) by sqrt(level Sigma_yy):
  // tighter tile bounds than the circle of the largest axis.
  out->extent[0] = sqrt(level * p.cov2d[0]);
  out->extent[1] = sqrt(level * p.cov2d[2]);
  out->u = cam.fx * x / z + cam.cx;
  out->v = cam.fy * y / z + cam.cy;
  if (out->u + radius < T(-0.5) || out->u - radius > T(cam.width) - T(0.5) ||
      out->v + radius < T(-0.5) || out->v - radius > T(cam.height) - T(0.5) || radius <= 0) {
    return false;
  }
  out->depth = z;

  // Camera-plane depth (RaDeGS; paper: robust depth rasterization). The ray through pixel
  // (u', v') is r = ((u' - cx) / fx, (v' - cy) / fy, 1); the density along it peaks at
  // t* = r^T Sigma^-1 mu / r^T Sigma^-1 r; to first order around the centre ray r0 = mu / z,
  // t* = z - z^2 q . (r - r0), q = Sigma^-1 mu / (mu^T Sigma^-1 mu), so beta = (a, b, z).
  T N[9], Ng[9];  // N = R R_g S^-1: Sigma_cam^-1 = N N^T
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) Ng[3 * r + c] = p.R_g[3 * r + c] / p.scale_eff[c];
  mat_mul(cam.R, Ng, N);
  mat_tvec(N, p.mean_cam, p.y_plane);
  mat_vec(N, p.y_plane, p.w_plane);
  p.m_plane = p.y_plane[0] * p.y_plane[0] + p.y_plane[1] * p.y_plane[1] +
              p.y_plane[2] * p.y_plane[2];
  out->plane[0] = -z * z * (p.w_plane[0] / p.m_plane) / cam.fx;
  out->plane[1] = -z * z * (p.w_plane[1] / p.m_plane) / cam.fy;

  // View-dependent colour: 0.5 + sum_k SH_k(dir) c_k, clamped at 0 (3DGS).
  T centre[3];  // camera centre in world: -R^T t
  mat_tvec(cam.R, cam.t, centre);
  T dn2 = T(0);
  for (int k = 0; k < 3; ++k) {
    p.dir[k] = mean[k] + centre[k];
    dn2 += p.dir[k] * p.dir[k];
  }
  p.dir_norm = sqrt(dn2);
  for (int k = 0; k < 3; ++k) p.dir[k] /= p.dir_norm;
  T basis[16];
  sh_basis<T>(sh_degree, p.dir, basis, nullptr);
  const int K = (sh_degree + 1) * (sh_degree + 1);
  for (int c = 0; c < 3; ++c) {
    T value = T(0.5);
    for (int k = 0; k < K; ++k) value += basis[k] * sh[3 * k + c];
    p.colour_raw[c] = value;
    out->colour[c] = value > T(0) ? value : T(0);
  }
  out->radius = radius;
  return true;
}

}  // namespace fslam::core::math
