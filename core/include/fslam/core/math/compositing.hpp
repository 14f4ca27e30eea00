// Per-pixel compositing math (paper eq. blending, transmittance_recover), forward and backward:
// a splat's alpha and footprint at a pixel, its camera-plane depth, and one splat-pixel pair's
// backward step.
#pragma once

#include <math.h>  // exp, sqrt, floor, ceil: device functions under nvcc, the C library on the host

#include "fslam/core/math/host_device.hpp"
#include "fslam/core/math/splat_types.hpp"

namespace fslam::core::math {

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
