// The CPU rasteriser's algorithm, templated on the scalar so that tests run it in double as the
// finite-difference reference, as a list of stages, each in its own file with forward and
// backward siblings (as the CUDA kernels in cuda/src): project_fwd.hpp -> binning.hpp (16x16
// tiles, depth sorted) -> composite_fwd.hpp (paper eq. blending, proj), and backward
// composite_bwd.hpp (per-splat backward parallelization, eq. transmittance_ckpt /
// transmittance_recover) -> project_bwd.hpp. The per-Gaussian and per-pixel math is
// fslam/core/math/splat_math.hpp's, shared with the CUDA backend.
// Internal to core/render and its tests; users go through fslam/core/render/rasterizer.hpp.
#pragma once

#include "fslam/core/render/binning.hpp"
#include "fslam/core/render/composite_bwd.hpp"
#include "fslam/core/render/composite_fwd.hpp"
#include "fslam/core/render/project_bwd.hpp"
#include "fslam/core/render/project_fwd.hpp"
#include "fslam/core/render/raster_inputs.hpp"
#include "fslam/core/render/raster_state.hpp"
#include "fslam/core/render/rasterize_reference.hpp"

namespace fslam::core::render_impl {

// Projects every Gaussian and bins them into depth-sorted tile lists.
template <typename T>
void project_and_bin(const SplatScene<T>& scene, const math::SplatCamera<T>& cam, RasterState<T>* state) {
  project_fwd(scene, cam, state);
  bin_to_tiles(state->rect, state);
}

// Forward pass (eq. blending with the camera-plane depth D_i(x)): the state keeps what the
// backward pass needs.
template <typename T>
void rasterize_forward(const SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                       const T background[3], bool render_features, RasterState<T>* state,
                       const RasterOutputs<T>& out) {
  project_and_bin(scene, cam, state);
  composite_fwd(scene, render_features ? scene.feature_dim : 0, background, state, out);
}

// Backward pass: adds (+=) dL/d(parameters) to `grads` from the output gradients `grad_out`
// (null planes are zero) of the forward pass that left `st` and `out`.
template <typename T>
void rasterize_backward(const SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                        const T background[3], bool render_features, const RasterState<T>& st,
                        const RasterOutputs<T>& out, const RasterOutputGrads<T>& grad_out,
                        const SceneGrads<T>& grads) {
  const int D = render_features ? scene.feature_dim : 0;
  const CompositeBwdInputs<T> in{background, out, grad_out, cam.width, cam.height, D,
                                 grad_out.features != nullptr && D > 0};
  composite_bwd(scene, in, st);
  project_bwd(scene, cam, D, st, grads);
}

}  // namespace fslam::core::render_impl
