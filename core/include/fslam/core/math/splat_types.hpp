// The plain data the splatting math works on: the camera, a projected Gaussian, the scene's
// parameter arrays, the rendered planes and their gradients, and the renderer's constants.
// Shared by the CPU rasteriser (core/render) and the CUDA backend (design.md: one source of
// math). Scalar T: float in production, double in the finite-difference reference tests.
// Matrices are row-major T[9]; quaternions are w, x, y, z.
#pragma once

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

}  // namespace fslam::core::math
