// Per-Gaussian and per-pixel math of the splatting renderer, forward and backward, shared by the
// CPU rasterizer (core/render) and the CUDA backend (design.md: one source of math).
// Scalar T: float in production, double in the finite-difference reference tests.
// Matrices are row-major T[9]; quaternions are w, x, y, z.
#pragma once

#include <math.h>  // sqrt, exp, log: device functions under nvcc, the C library on the host

#include <cstddef>

#include "fslam/core/math/host_device.hpp"

namespace fslam::core::math {

constexpr float kAlphaMin = 1.0f / 255.0f;    // splat-pixel pairs below are skipped (3DGS)
constexpr float kAlphaMax = 0.99f;            // alpha is clamped here (3DGS)
constexpr float kTransmittanceMin = 1e-4f;    // a pixel stops compositing below this
constexpr float kLowPassVariance = 0.3f;      // pixels^2 added to every 2D covariance (3DGS)
constexpr float kFovClampFactor = 1.3f;       // Jacobian's x/z, y/z within 1.3x the view (clamp_to_view)

// A view for the renderer: world-to-camera transform and pinhole intrinsics.
template <typename T>
struct SplatCamera {
  T R[9];  // rotation of T_camera_world
  T t[3];  // translation of T_camera_world, metres
  T fx, fy, cx, cy;  // pixels, pixel centres at integer coordinates
  T near_plane;      // metres; Gaussians whose mean is nearer are culled
  int width, height;
};

// One Gaussian as the rasteriser's per-pixel loop needs it.
template <typename T>
struct ProjectedGaussian {
  T u, v;       // pixel position of the mean
  T conic[3];   // inverse 2D covariance [[c0, c1], [c1, c2]], pixels^-2
  T opacity;    // effective opacity in (0, 1) after the 3D filter
  T depth;      // camera z of the mean, metres (sort key)
  T plane[2];   // camera-plane depth slopes, metres per pixel (eq. planar depth field)
  T colour[3];  // view-dependent colour from SH, clamped at 0
  T power_floor;  // log(kAlphaMin / opacity): a lower exponent gives alpha < kAlphaMin
  T extent[2];    // half-width and half-height (pixels) of the ellipse where alpha >= kAlphaMin
  int radius;     // pixels around (u, v) where alpha can reach kAlphaMin; 0 = culled
};

// Read-only view of a map's parameters (shapes as in GaussianMap; host or device pointers).
template <typename T>
struct SplatScene {
  std::size_t count = 0;
  const T* means = nullptr;           // [N, 3]
  const T* rotations = nullptr;       // [N, 4] w, x, y, z
  const T* log_scales = nullptr;      // [N, 3]
  const T* opacity_logits = nullptr;  // [N]
  const T* sh = nullptr;              // [N, K, 3]
  const T* features = nullptr;        // [N, D] (null when D = 0)
  const T* filter_3d = nullptr;       // [N] (null = no filter)
  int sh_degree = 0;
  int feature_dim = 0;

  FSLAM_HD int sh_stride() const { return 3 * (sh_degree + 1) * (sh_degree + 1); }
  FSLAM_HD T filter(std::size_t i) const { return filter_3d != nullptr ? filter_3d[i] : T(0); }
};

// The view of any parameter arrays named as in GaussianMap (means, rotations, log_scales,
// opacity_logits, sh, features, filter_3d; each with data()): host vectors or device buffers.
template <typename T, typename Arrays>
SplatScene<T> splat_scene_of(const Arrays& a, std::size_t count, int sh_degree, int feature_dim, bool has_filter) {
  SplatScene<T> s;
  s.count = count;
  s.means = a.means.data();
  s.rotations = a.rotations.data();
  s.log_scales = a.log_scales.data();
  s.opacity_logits = a.opacity_logits.data();
  s.sh = a.sh.data();
  s.features = feature_dim > 0 ? a.features.data() : nullptr;
  s.filter_3d = has_filter ? a.filter_3d.data() : nullptr;
  s.sh_degree = sh_degree;
  s.feature_dim = feature_dim;
  return s;
}

// Output buffers of the forward pass; sizes from the camera. Any may be null except colour,
// depth and alpha.
template <typename T>
struct RasterOutputs {
  T* colour = nullptr;        // [3, H, W] composited colour plus T_final * background
  T* depth = nullptr;         // [H, W] expected camera-plane depth (unnormalised, eq. D_exp)
  T* median_depth = nullptr;  // [H, W] planar depth where accumulated opacity first exceeds 0.5
  T* alpha = nullptr;         // [H, W] accumulated opacity 1 - T_final
  T* features = nullptr;      // [D, H, W]
};

// Gradient of the loss w.r.t. a ProjectedGaussian's fields, summed over its pixels.
template <typename T>
struct ProjectedGradient {
  T u, v;
  T conic[3];
  T opacity;
  T depth;
  T plane[2];
  T colour[3];
};

// Gradients of the loss w.r.t. the rasteriser's outputs (shapes as RasterOutputs); null = zero.
template <typename T>
struct RasterOutputGrads {
  const T* colour = nullptr;
  const T* depth = nullptr;
  const T* median_depth = nullptr;
  const T* alpha = nullptr;
  const T* features = nullptr;
};

// A Gaussian's summed 2D gradient as both backward passes store it: u, v, conic[3], opacity,
// depth, plane[2], colour[3], importance rgb, importance feature (then the D feature gradients).
constexpr int kGrad2dFixed = 14;

template <typename T>
FSLAM_HD void pack_gradient_2d(const ProjectedGradient<T>& g, T imp_rgb, T imp_feat, T out[kGrad2dFixed]) {
  const T values[kGrad2dFixed] = {g.u,        g.v,     g.conic[0], g.conic[1], g.conic[2], g.opacity, g.depth,
                                  g.plane[0], g.plane[1], g.colour[0], g.colour[1], g.colour[2], imp_rgb, imp_feat};
  for (int k = 0; k < kGrad2dFixed; ++k) out[k] = values[k];
}

template <typename T>
FSLAM_HD ProjectedGradient<T> unpack_gradient_2d(const T* in) {
  ProjectedGradient<T> g;
  g.u = in[0];
  g.v = in[1];
  for (int k = 0; k < 3; ++k) g.conic[k] = in[2 + k];
  g.opacity = in[5];
  g.depth = in[6];
  g.plane[0] = in[7];
  g.plane[1] = in[8];
  for (int k = 0; k < 3; ++k) g.colour[k] = in[9 + k];
  return g;
}

// ---------------------------------------------------------------- small linear algebra
template <typename T>
FSLAM_HD void mat_mul(const T A[9], const T B[9], T C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C[3 * r + c] = A[3 * r] * B[c] + A[3 * r + 1] * B[3 + c] + A[3 * r + 2] * B[6 + c];
}
// C = A^T B
template <typename T>
FSLAM_HD void mat_tmul(const T A[9], const T B[9], T C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C[3 * r + c] = A[r] * B[c] + A[3 + r] * B[3 + c] + A[6 + r] * B[6 + c];
}
// C = A B^T
template <typename T>
FSLAM_HD void mat_mul_t(const T A[9], const T B[9], T C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C[3 * r + c] = A[3 * r] * B[3 * c] + A[3 * r + 1] * B[3 * c + 1] + A[3 * r + 2] * B[3 * c + 2];
}
template <typename T>
FSLAM_HD void mat_vec(const T A[9], const T x[3], T y[3]) {
  for (int r = 0; r < 3; ++r) y[r] = A[3 * r] * x[0] + A[3 * r + 1] * x[1] + A[3 * r + 2] * x[2];
}
template <typename T>
FSLAM_HD void mat_tvec(const T A[9], const T x[3], T y[3]) {
  for (int c = 0; c < 3; ++c) y[c] = A[c] * x[0] + A[3 + c] * x[1] + A[6 + c] * x[2];
}

template <typename T>
FSLAM_HD T sigmoid(T x) {
  return T(1) / (T(1) + exp(-x));
}

// ---------------------------------------------------------------- rotation
// Rotation of the normalised quaternion q (any non-zero norm).
template <typename T>
FSLAM_HD void quat_to_rotmat(const T q[4], T R[9]) {
  const T n = T(1) / sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const T w = q[0] * n, x = q[1] * n, y = q[2] * n, z = q[3] * n;
  R[0] = T(1) - T(2) * (y * y + z * z);
  R[1] = T(2) * (x * y - w * z);
  R[2] = T(2) * (x * z + w * y);
  R[3] = T(2) * (x * y + w * z);
  R[4] = T(1) - T(2) * (x * x + z * z);
  R[5] = T(2) * (y * z - w * x);
  R[6] = T(2) * (x * z - w * y);
  R[7] = T(2) * (y * z + w * x);
  R[8] = T(1) - T(2) * (x * x + y * y);
}

// dL/dq from dL/dR, through the normalisation.
template <typename T>
FSLAM_HD void quat_to_rotmat_backward(const T q[4], const T dR[9], T dq[4]) {
  const T norm = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const T w = q[0] / norm, x = q[1] / norm, y = q[2] / norm, z = q[3] / norm;
  T g[4];
  g[0] = T(2) * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]);
  g[1] = T(2) * (y * dR[1] + z * dR[2] + y * dR[3] - T(2) * x * dR[4] - w * dR[5] + z * dR[6] +
                 w * dR[7] - T(2) * x * dR[8]);
  g[2] = T(2) * (-T(2) * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] +
                 z * dR[7] - T(2) * y * dR[8]);
  g[3] = T(2) * (-T(2) * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - T(2) * z * dR[4] +
                 y * dR[5] + x * dR[6] + y * dR[7]);
  // q_hat = q / |q|: dq = (g - q_hat (q_hat . g)) / |q|
  const T dot = w * g[0] + x * g[1] + y * g[2] + z * g[3];
  dq[0] = (g[0] - w * dot) / norm;
  dq[1] = (g[1] - x * dot) / norm;
  dq[2] = (g[2] - y * dot) / norm;
  dq[3] = (g[3] - z * dot) / norm;
}

// ---------------------------------------------------------------- spherical harmonics
constexpr double kSh0 = 0.28209479177387814;
constexpr double kSh1 = 0.4886025119029199;

// Real SH basis up to `degree` at unit direction d and its gradient w.r.t. d (grad: [K, 3], may
// be null). K = (degree + 1)^2 <= 16.
template <typename T>
FSLAM_HD void sh_basis(int degree, const T d[3], T* basis, T* grad) {
  // Degree 2 and 3 constants, local so that device code can read them (namespace-scope arrays
  // are host-only under nvcc).
  constexpr double kSh2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                              -1.0925484305920792, 0.5462742152960396};
  constexpr double kSh3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                              0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                              -0.5900435899266435};
  const T x = d[0], y = d[1], z = d[2];
  auto set = [&](int k, T value, T gx, T gy, T gz) {
    basis[k] = value;
    if (grad != nullptr) {
      grad[3 * k] = gx;
      grad[3 * k + 1] = gy;
      grad[3 * k + 2] = gz;
    }
  };
  set(0, T(kSh0), T(0), T(0), T(0));
  if (degree < 1) return;
  const T c1 = T(kSh1);
  set(1, -c1 * y, T(0), -c1, T(0));
  set(2, c1 * z, T(0), T(0), c1);
  set(3, -c1 * x, -c1, T(0), T(0));
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  set(4, T(kSh2[0]) * x * y, T(kSh2[0]) * y, T(kSh2[0]) * x, T(0));
  set(5, T(kSh2[1]) * y * z, T(0), T(kSh2[1]) * z, T(kSh2[1]) * y);
  set(6, T(kSh2[2]) * (T(2) * zz - xx - yy), T(kSh2[2]) * (-T(2) * x), T(kSh2[2]) * (-T(2) * y),
      T(kSh2[2]) * (T(4) * z));
  set(7, T(kSh2[3]) * x * z, T(kSh2[3]) * z, T(0), T(kSh2[3]) * x);
  set(8, T(kSh2[4]) * (xx - yy), T(kSh2[4]) * (T(2) * x), T(kSh2[4]) * (-T(2) * y), T(0));
  if (degree < 3) return;
  set(9, T(kSh3[0]) * y * (T(3) * xx - yy), T(kSh3[0]) * T(6) * x * y,
      T(kSh3[0]) * (T(3) * xx - T(3) * yy), T(0));
  set(10, T(kSh3[1]) * x * y * z, T(kSh3[1]) * y * z, T(kSh3[1]) * x * z, T(kSh3[1]) * x * y);
  set(11, T(kSh3[2]) * y * (T(4) * zz - xx - yy), T(kSh3[2]) * (-T(2) * x * y),
      T(kSh3[2]) * (T(4) * zz - xx - T(3) * yy), T(kSh3[2]) * (T(8) * y * z));
  set(12, T(kSh3[3]) * z * (T(2) * zz - T(3) * xx - T(3) * yy), T(kSh3[3]) * (-T(6) * x * z),
      T(kSh3[3]) * (-T(6) * y * z), T(kSh3[3]) * (T(6) * zz - T(3) * xx - T(3) * yy));
  set(13, T(kSh3[4]) * x * (T(4) * zz - xx - yy), T(kSh3[4]) * (T(4) * zz - T(3) * xx - yy),
      T(kSh3[4]) * (-T(2) * x * y), T(kSh3[4]) * (T(8) * x * z));
  set(14, T(kSh3[5]) * z * (xx - yy), T(kSh3[5]) * (T(2) * x * z), T(kSh3[5]) * (-T(2) * y * z),
      T(kSh3[5]) * (xx - yy));
  set(15, T(kSh3[6]) * x * (xx - T(3) * yy), T(kSh3[6]) * (T(3) * xx - T(3) * yy),
      T(kSh3[6]) * (-T(6) * x * y), T(0));
}

// ---------------------------------------------------------------- projection (eq. proj)
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

// Gradients of the Gaussian's parameters; the caller adds them to its buffers.
template <typename T>
struct GaussianParamGradient {
  T mean[3];
  T quat[4];
  T log_scale[3];
  T opacity_logit;
  T sh[48];  // [K, 3]
};

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

  // Planar depth: depth = z; plane = -z^2 (w / m)_{x,y} / f, w = N y, y = N^T mu, m = y^T y.
  {
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

  // Opacity = sigmoid(logit) * prod_k scale_k / scale_eff_k.
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
  quat_to_rotmat_backward(quat, g_Rg, grad->quat);

  // Colour from SH: only unclamped channels pass gradient.
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
  T g_mean_world[3];
  for (int a = 0; a < 3; ++a) g_mean_world[a] = (g_dir[a] - p.dir[a] * dot) / p.dir_norm;
  // mean_cam = R mean + t.
  T g_from_cam[3];
  mat_tvec(cam.R, g_mean_cam, g_from_cam);
  for (int a = 0; a < 3; ++a) grad->mean[a] = g_mean_world[a] + g_from_cam[a];
}

// ---------------------------------------------------------------- per-pixel compositing
// The per-pixel functions below take the pixel quantities as P: a scalar (one pixel: CUDA, the
// references) or simd::Lanes (a row of pixels at once: the CPU backend, math/lanes.hpp). They are
// therefore branch-free; these are the scalar forms of the lane operations they use.
template <typename T>
FSLAM_HD T select(bool condition, T a, T b) {
  return condition ? a : b;
}
template <typename T>
FSLAM_HD T min_value(T a, T b) {
  return a < b ? a : b;
}
template <typename T>
FSLAM_HD T abs_value(T a) {
  return a < T(0) ? -a : a;
}

// Alpha of a projected Gaussian at pixel (px, py); 0 (and *gaussian 0) when below kAlphaMin:
// the pair is skipped.
template <typename T, typename P>
FSLAM_HD P splat_alpha(const ProjectedGaussian<T>& g, P px, P py, P* gaussian) {
  const P dx = px - g.u, dy = py - g.v;
  const P power = T(-0.5) * (g.conic[0] * dx * dx + g.conic[2] * dy * dy) - g.conic[1] * dx * dy;
  // Outside the footprint: nothing (the exponential of 0 keeps the lanes finite).
  const auto inside = (power <= P(T(0))) & (power >= P(g.power_floor));
  const P e = exp(select(inside, power, P(T(0))));
  const P alpha = g.opacity * e;
  const auto keep = inside & (alpha >= P(T(kAlphaMin)));
  *gaussian = select(keep, e, P(T(0)));
  return select(keep, min_value(alpha, P(T(kAlphaMax))), P(T(0)));
}

// Pixel columns of row py whose centres can lie inside the Gaussian's footprint
// (power >= power_floor): [*x_begin, *x_end). Conservative by 0.01 px so that splat_alpha stays
// the only decision; false when the row misses the footprint.
template <typename T>
FSLAM_HD bool splat_row_span(const ProjectedGaussian<T>& g, T py, int* x_begin, int* x_end) {
  // -0.5 (c0 dx^2 + 2 c1 dx dy + c2 dy^2) >= floor  <=>  c0 dx^2 + 2 c1 dy dx + c2 dy^2 - level <= 0
  const T dy = py - g.v;
  const T level = T(-2) * g.power_floor;
  const T b = g.conic[1] * dy;
  const T disc = b * b - g.conic[0] * (g.conic[2] * dy * dy - level);
  if (disc < T(0)) return false;
  const T root = sqrt(disc);
  const T lo = g.u + (-b - root) / g.conic[0] - T(0.01);
  const T hi = g.u + (-b + root) / g.conic[0] + T(0.01);
  *x_begin = static_cast<int>(ceil(lo));
  *x_end = static_cast<int>(floor(hi)) + 1;
  return *x_end > *x_begin;
}

// Tiles (tile_size pixels a side) whose pixel centres can lie inside the footprint, clipped to
// the tiles_x x tiles_y grid: rect = x0, y0, x1, y1 (x1, y1 exclusive). Pixel centres are at
// integers; tile t covers centres t * tile_size .. t * tile_size + tile_size - 1.
template <typename T>
FSLAM_HD void splat_tile_rect(const ProjectedGaussian<T>& g, int tile_size, int tiles_x, int tiles_y,
                              int rect[4]) {
  const int x0 = static_cast<int>(ceil(g.u - g.extent[0])) / tile_size;
  const int y0 = static_cast<int>(ceil(g.v - g.extent[1])) / tile_size;
  const int x1 = static_cast<int>(floor(g.u + g.extent[0])) / tile_size + 1;
  const int y1 = static_cast<int>(floor(g.v + g.extent[1])) / tile_size + 1;
  rect[0] = x0 > 0 ? x0 : 0;
  rect[1] = y0 > 0 ? y0 : 0;
  rect[2] = x1 < tiles_x ? x1 : tiles_x;
  rect[3] = y1 < tiles_y ? y1 : tiles_y;
}

// Rows of the footprint: [*y_begin, *y_end), the rows splat_row_span is asked about.
template <typename T>
FSLAM_HD void splat_row_range(const ProjectedGaussian<T>& g, int* y_begin, int* y_end) {
  *y_begin = static_cast<int>(ceil(g.v - g.extent[1]));
  *y_end = static_cast<int>(floor(g.v + g.extent[1])) + 1;
}

// Camera-plane depth of the Gaussian at pixel (px, py): beta^T [x - mu2D; 1].
template <typename T, typename P>
FSLAM_HD P splat_planar_depth(const ProjectedGaussian<T>& g, P px, P py) {
  return g.depth + g.plane[0] * (px - g.u) + g.plane[1] * (py - g.v);
}

// Backward of alpha and planar depth at one pixel: adds to the Gaussian's 2D gradient.
// g_alpha: dL/dalpha at this pixel, g_depth_here: dL/d(planar depth at this pixel).
template <typename T, typename P>
FSLAM_HD void splat_pixel_backward(const ProjectedGaussian<T>& g, P px, P py, P alpha, P gaussian,
                                   P g_alpha, P g_depth_here, ProjectedGradient<P>* grad) {
  const P dx = px - g.u, dy = py - g.v;
  const P ga = select(alpha < P(T(kAlphaMax)), g_alpha, P(T(0)));  // the clamp has zero gradient
  grad->opacity += ga * gaussian;
  const P g_power = ga * alpha;  // alpha = opacity exp(power)
  // power = -0.5 (c0 dx^2 + c2 dy^2) - c1 dx dy
  grad->conic[0] += T(-0.5) * g_power * dx * dx;
  grad->conic[1] += -g_power * dx * dy;
  grad->conic[2] += T(-0.5) * g_power * dy * dy;
  grad->u += g_power * (g.conic[0] * dx + g.conic[1] * dy);
  grad->v += g_power * (g.conic[1] * dx + g.conic[2] * dy);
  grad->depth += g_depth_here;
  grad->plane[0] += g_depth_here * dx;
  grad->plane[1] += g_depth_here * dy;
  grad->u -= g_depth_here * g.plane[0];
  grad->v -= g_depth_here * g.plane[1];
}

// One splat's share of one pixel's backward pass (paper: per-splat backward, eq.
// transmittance_recover), front to back. The pixel's state: *trans the transmittance before the
// splat, pre [4 + D] the colour, depth and features composited in front of it, both rolled past
// the splat here; tot [4 + D] the pixel's final composite without the background; gp the output
// gradients (colour 3, depth, then D features when feature_grads); g_background =
// -T_final sum_c g_c background_c; g_alpha_out = T_final dL/d(accumulated opacity); g_median
// dL/d(median depth) when this splat gives the pixel's median depth, else 0. f [D] the splat's
// features. Adds to the splat's 2D gradient, its feature gradient [D] and the pruning cues
// sum |dL_rgb/dalpha|, sum |dL_feat/dalpha| (eq. importance, sem_importance).
// A pixel the splat does not reach (alpha 0 and gaussian 0 from splat_alpha) adds nothing and
// keeps its state, so a row of lanes can be passed whole.
template <typename T, typename P>
FSLAM_HD void splat_pair_backward(const ProjectedGaussian<T>& g, const T* f, int D, bool feature_grads, P px,
                                  P py, P alpha, P gaussian, const P* tot, const P* gp, P g_background,
                                  P g_alpha_out, P g_median, P* trans, P* pre, ProjectedGradient<P>* pg,
                                  P* feature_grad, P* imp_rgb, P* imp_feat) {
  const P Ti = *trans;
  const P w = alpha * Ti;
  const P one_minus = T(1) - alpha;
  const P inv_one_minus = T(1) / one_minus;
  const P d = splat_planar_depth(g, px, py);
  // dL/dalpha_i = sum_ch g_ch (T_i v_ch - S_ch / (1 - alpha_i)) with S the part composited
  // behind splat i (S = total - prefix - w v), plus the background and accumulated-opacity terms
  // (over 1 - alpha_i). Each channel group is summed as
  // T_i sum g v - (sum g (total - prefix) - w sum g v) / (1 - alpha_i).
  P gv = T(0), g_rest = T(0);
  for (int c = 0; c < 3; ++c) {
    pg->colour[c] += w * gp[c];
    gv += gp[c] * g.colour[c];
    g_rest += gp[c] * (tot[c] - pre[c]);
    pre[c] += w * g.colour[c];
  }
  const P g_alpha_rgb = Ti * gv - (g_rest - w * gv - g_background) * inv_one_minus;
  const P g_depth_out = gp[3];
  const P g_alpha_other =
      g_depth_out * (Ti * d - (tot[3] - pre[3] - w * d) * inv_one_minus) + g_alpha_out * inv_one_minus;
  pre[3] += w * d;
  const P g_depth_here = w * g_depth_out + g_median;
  P g_alpha_feat = T(0);
  if (feature_grads) {
    P fv = T(0), f_rest = T(0);
    for (int c = 0; c < D; ++c) {
      const P gf = gp[4 + c];
      feature_grad[c] += w * gf;
      fv += gf * f[c];
      f_rest += gf * (tot[4 + c] - pre[4 + c]);
      pre[4 + c] += w * f[c];
    }
    g_alpha_feat = Ti * fv - (f_rest - w * fv) * inv_one_minus;
  } else {
    for (int c = 0; c < D; ++c) pre[4 + c] += w * f[c];
  }
  const auto reached = alpha > P(T(0));
  *imp_rgb += select(reached, abs_value(g_alpha_rgb), P(T(0)));
  *imp_feat += select(reached, abs_value(g_alpha_feat), P(T(0)));
  splat_pixel_backward(g, px, py, alpha, gaussian, g_alpha_rgb + g_alpha_feat + g_alpha_other, g_depth_here, pg);
  *trans = Ti * one_minus;  // past splat i; the prefix sums were rolled above
}

}  // namespace fslam::core::math
