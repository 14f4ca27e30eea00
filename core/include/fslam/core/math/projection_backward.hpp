// Projection of one Gaussian, backward (paper eq. proj): dL/d(parameters) from dL/d(projected
// fields) through the quantities project_gaussian computed (projection.hpp), in the chain rule's
// pieces: the camera-plane depth, opacity with the 3D filter, and the SH colour each in a function
// of its own; the pixel position and the conic (through EWA's J and the camera-frame covariance to
// the rotation and effective scales) in project_gaussian_backward itself, because split out too
// they changed its results in the last bits (FSLAM_HD_INLINE, host_device.hpp).
#pragma once

#include "fslam/core/math/host_device.hpp"
#include "fslam/core/math/projection.hpp"
#include "fslam/core/math/small_linalg.hpp"
#include "fslam/core/math/spherical_harmonics.hpp"
#include "fslam/core/math/splat_types.hpp"

namespace fslam::core::math {

// Gradients of the Gaussian's parameters; the caller adds them to its buffers.
template <typename T>
struct GaussianParamGradient {
  T mean[3];
  T quat[4];
  T log_scale[3];
  T opacity_logit;
  T sh[48];  // [K, 3]
};

// Camera-plane depth: depth = z; plane = -z^2 (w / m)_{x,y} / f, w = N y, y = N^T mu, m = y^T y
// with N = R R_g S^-1, to the camera-frame mean, the Gaussian's rotation and effective scales.
template <typename T>
FSLAM_HD_INLINE void planar_depth_backward(const SplatCamera<T>& cam, const ProjectionTerms<T>& p,
                                           const ProjectedGradient<T>& g, T g_mean_cam[3], T g_Rg[9],
                                           T g_scale_eff[3]) {
  const T z = p.mean_cam[2];
  g_mean_cam[2] += g.depth;
  const T qx = p.w_plane[0] / p.m_plane, qy = p.w_plane[1] / p.m_plane;
  g_mean_cam[2] += g.plane[0] * (-T(2) * z * qx / cam.fx) + g.plane[1] * (-T(2) * z * qy / cam.fy);
  const T g_q[3] = {g.plane[0] * (-z * z / cam.fx), g.plane[1] * (-z * z / cam.fy), T(0)};
  // q = w / m: dL/dw = g_q / m; dL/dm = -(g_q . w) / m^2.
  const T g_m = -(g_q[0] * p.w_plane[0] + g_q[1] * p.w_plane[1]) / (p.m_plane * p.m_plane);
  T g_w[3];
  for (int k = 0; k < 3; ++k) g_w[k] = g_q[k] / p.m_plane;
  // w = N y, m = y^T y: dL/dy = N^T g_w + 2 g_m y; dL/dN = g_w y^T + mu (dL/dy)^T.
  T N[9], Ng[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) Ng[3 * r + c] = p.R_g[3 * r + c] / p.scale_eff[c];
  mat_mul(cam.R, Ng, N);
  T g_y[3];
  mat_tvec(N, g_w, g_y);
  for (int k = 0; k < 3; ++k) g_y[k] += T(2) * g_m * p.y_plane[k];
  // y = N^T mu: dL/dmu += N g_y.
  T g_mu[3];
  mat_vec(N, g_y, g_mu);
  for (int k = 0; k < 3; ++k) g_mean_cam[k] += g_mu[k];
  T g_N[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      g_N[3 * r + c] = g_w[r] * p.y_plane[c] + p.mean_cam[r] * g_y[c];
  // N = R Ng, Ng = R_g S^-1.
  T g_Ng[9];
  mat_tmul(cam.R, g_N, g_Ng);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      g_Rg[3 * r + c] += g_Ng[3 * r + c] / p.scale_eff[c];
      g_scale_eff[c] -= g_Ng[3 * r + c] * p.R_g[3 * r + c] / (p.scale_eff[c] * p.scale_eff[c]);
    }
}

// Opacity = sigmoid(logit) * prod_k scale_k / scale_eff_k and scale_eff = sqrt(scale^2 + f) with
// scale = exp(log_scale): the opacity logit's and the log-scales' gradients.
template <typename T>
FSLAM_HD_INLINE void opacity_scale_backward(T filter_variance, const ProjectionTerms<T>& p,
                                            const ProjectedGradient<T>& g, const T g_scale_eff[3],
                                            GaussianParamGradient<T>* grad) {
  grad->opacity_logit = g.opacity * p.filter_coef * p.opacity_raw * (T(1) - p.opacity_raw);
  T g_scale[3];
  for (int k = 0; k < 3; ++k) {
    // scale_eff = sqrt(scale^2 + f): d/dscale = scale / scale_eff.
    g_scale[k] = g_scale_eff[k] * p.scale[k] / p.scale_eff[k];
    if (filter_variance > T(0)) {
      // d(scale / scale_eff)/dscale = f / scale_eff^3
      const T ratio = p.scale[k] / p.scale_eff[k];
      g_scale[k] += g.opacity * p.opacity_raw * (p.filter_coef / ratio) * filter_variance /
                    (p.scale_eff[k] * p.scale_eff[k] * p.scale_eff[k]);
    }
    grad->log_scale[k] = g_scale[k] * p.scale[k];
  }
}

// Colour from SH (only unclamped channels pass gradient) to the SH coefficients and, through the
// view direction dir = (mean - centre) / |mean - centre|, to the world-frame mean.
template <typename T>
FSLAM_HD_INLINE void sh_colour_backward(const T* sh, int sh_degree, const ProjectionTerms<T>& p,
                                        const ProjectedGradient<T>& g, GaussianParamGradient<T>* grad,
                                        T g_mean_world[3]) {
  const int K = (sh_degree + 1) * (sh_degree + 1);
  T basis[16], basis_grad[48];
  sh_basis<T>(sh_degree, p.dir, basis, basis_grad);
  T g_dir[3] = {T(0), T(0), T(0)};
  for (int c = 0; c < 3; ++c) {
    const T gc = p.colour_raw[c] > T(0) ? g.colour[c] : T(0);
    for (int k = 0; k < K; ++k) {
      grad->sh[3 * k + c] = gc * basis[k];
      for (int a = 0; a < 3; ++a) g_dir[a] += gc * sh[3 * k + c] * basis_grad[3 * k + a];
    }
  }
  // dir = (mean - centre) / |mean - centre|.
  const T dot = g_dir[0] * p.dir[0] + g_dir[1] * p.dir[1] + g_dir[2] * p.dir[2];
  for (int a = 0; a < 3; ++a) g_mean_world[a] = (g_dir[a] - p.dir[a] * dot) / p.dir_norm;
}

// Backward of project_gaussian: dL/d(parameters) from dL/d(projected fields).
template <typename T>
FSLAM_HD void project_gaussian_backward(const T quat[4], T filter_variance, const T* sh,
                                        int sh_degree,
                                        const SplatCamera<T>& cam, const ProjectedGaussian<T>& out,
                                        const ProjectionTerms<T>& p,
                                        const ProjectedGradient<T>& g,
                                        GaussianParamGradient<T>* grad) {
  T g_mean_cam[3] = {T(0), T(0), T(0)};
  T g_scale_eff[3] = {T(0), T(0), T(0)};
  T g_Rg[9] = {T(0), T(0), T(0), T(0), T(0), T(0), T(0), T(0), T(0)};
  const T x = p.mean_cam[0], y = p.mean_cam[1], z = p.mean_cam[2];

  // Pixel position u = fx x / z + cx, v = fy y / z + cy.
  g_mean_cam[0] += g.u * cam.fx / z;
  g_mean_cam[1] += g.v * cam.fy / z;
  g_mean_cam[2] += -(g.u * cam.fx * x + g.v * cam.fy * y) / (z * z);

  // Conic = inverse of the 2D covariance: dL/dSigma2D = -Q G_Q Q with G_Q symmetric.
  {
    const T Q00 = out.conic[0], Q01 = out.conic[1], Q11 = out.conic[2];
    const T G00 = g.conic[0], G01 = T(0.5) * g.conic[1], G11 = g.conic[2];
    // A = G_Q Q
    const T A00 = G00 * Q00 + G01 * Q01, A01 = G00 * Q01 + G01 * Q11;
    const T A10 = G01 * Q00 + G11 * Q01, A11 = G01 * Q01 + G11 * Q11;
    const T S00 = -(Q00 * A00 + Q01 * A10);
    const T S01 = -(Q00 * A01 + Q01 * A11);
    const T S11 = -(Q01 * A01 + Q11 * A11);
    // Sigma2D = J Sigma_cam J^T (+ const): dL/dSigma_cam = J^T S J, dL/dJ = 2 S J Sigma_cam.
    const T S[4] = {S00, S01, S01, S11};
    T g_cov_cam[9];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        T sum = T(0);
        for (int a = 0; a < 2; ++a)
          for (int b = 0; b < 2; ++b) sum += p.J[3 * a + r] * S[2 * a + b] * p.J[3 * b + c];
        g_cov_cam[3 * r + c] = sum;
      }
    T g_J[6];
    for (int a = 0; a < 2; ++a)
      for (int c = 0; c < 3; ++c) {
        T sum = T(0);
        for (int b = 0; b < 2; ++b)
          for (int k = 0; k < 3; ++k) sum += S[2 * a + b] * p.J[3 * b + k] * p.cov_cam[3 * k + c];
        g_J[3 * a + c] = T(2) * sum;
      }
    // J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]], tx = x/z (unless clamped).
    T tx = x / z, ty = y / z;
    bool clamped_x, clamped_y;  // the same as p.clamp_x, p.clamp_y
    clamp_to_view(cam, &tx, &ty, &clamped_x, &clamped_y);
    g_mean_cam[2] += -g_J[0] * cam.fx / (z * z) - g_J[4] * cam.fy / (z * z);
    // J02 = -fx tx / z: with tx = x / z (unclamped) this is -fx x / z^2.
    if (p.clamp_x) {
      g_mean_cam[2] += g_J[2] * cam.fx * tx / (z * z);
    } else {
      g_mean_cam[0] += -g_J[2] * cam.fx / (z * z);
      g_mean_cam[2] += g_J[2] * T(2) * cam.fx * x / (z * z * z);
    }
    if (p.clamp_y) {
      g_mean_cam[2] += g_J[5] * cam.fy * ty / (z * z);
    } else {
      g_mean_cam[1] += -g_J[5] * cam.fy / (z * z);
      g_mean_cam[2] += g_J[5] * T(2) * cam.fy * y / (z * z * z);
    }
    // Sigma_cam = R Sigma_w R^T: dL/dSigma_w = R^T G R; Sigma_w = M M^T, M = R_g S_eff:
    // dL/dM = (G_w + G_w^T) M.
    T tmp[9], g_cov_w[9];
    mat_tmul(cam.R, g_cov_cam, tmp);
    mat_mul(tmp, cam.R, g_cov_w);
    T M[9];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) M[3 * r + c] = p.R_g[3 * r + c] * p.scale_eff[c];
    T Gs[9];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) Gs[3 * r + c] = g_cov_w[3 * r + c] + g_cov_w[3 * c + r];
    T g_M[9];
    mat_mul(Gs, M, g_M);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        g_Rg[3 * r + c] += g_M[3 * r + c] * p.scale_eff[c];
        g_scale_eff[c] += g_M[3 * r + c] * p.R_g[3 * r + c];
      }
  }

  // Planar depth (camera-plane depth coefficients).
  planar_depth_backward(cam, p, g, g_mean_cam, g_Rg, g_scale_eff);

  // Opacity = sigmoid(logit) * prod_k scale_k / scale_eff_k, scale_eff = sqrt(scale^2 + f).
  opacity_scale_backward(filter_variance, p, g, g_scale_eff, grad);
  quat_to_rotmat_backward(quat, g_Rg, grad->quat);

  // Colour from SH (only unclamped channels pass gradient) and the view direction.
  T g_mean_world[3];
  sh_colour_backward(sh, sh_degree, p, g, grad, g_mean_world);
  // mean_cam = R mean + t.
  T g_from_cam[3];
  mat_tvec(cam.R, g_mean_cam, g_from_cam);
  for (int a = 0; a < 3; ++a) grad->mean[a] = g_mean_world[a] + g_from_cam[a];
}

}  // namespace fslam::core::math
