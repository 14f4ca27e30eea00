// The rasterisers' inputs as the shared math takes them: float views of a GaussianMap and a
// RenderView, and the checks every backend's forward() and backward() make on them. Internal to
// core/render, the CUDA backend and the tests; users go through fslam/core/render/rasterizer.hpp.
#pragma once

#include <string>

#include "fslam/core/error.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/render/rasterizer.hpp"

namespace fslam::core::render_impl {

using math::SplatScene;

// The float views of a GaussianMap and a RenderView that the CPU backend and the benchmark use.
inline SplatScene<float> splat_scene(const GaussianMap& map) {
  return math::splat_scene_of<float>(map, map.size(), map.sh_degree, map.feature_dim, !map.filter_3d.empty());
}

inline math::SplatCamera<float> splat_camera(const RenderView& view, float near_plane) {
  math::SplatCamera<float> cam{};
  const Eigen::Matrix3d R = view.T_camera_world.rotation();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.R[3 * r + c] = static_cast<float>(R(r, c));
    cam.t[r] = static_cast<float>(view.T_camera_world.translation()[r]);
  }
  cam.fx = static_cast<float>(view.camera.fx);
  cam.fy = static_cast<float>(view.camera.fy);
  cam.cx = static_cast<float>(view.camera.cx);
  cam.cy = static_cast<float>(view.camera.cy);
  cam.near_plane = near_plane;
  cam.width = view.camera.width;
  cam.height = view.camera.height;
  return cam;
}

// The renderer's camera for a view, or false with `why` when the view or settings are invalid.
inline bool render_camera(const RenderView& view, const RenderSettings& settings,
               math::SplatCamera<float>* cam, std::string* why) {
  std::string reason;
  if (!view.camera.is_valid(&reason)) return fail(why, "render view: " + reason);
  if (!view.T_camera_world.matrix().allFinite()) return fail(why, "render view: non-finite pose");
  if (!(settings.near_plane > 0.0f)) return fail(why, "render settings: near plane must be > 0");
  *cam = splat_camera(view, settings.near_plane);
  return true;
}

// The checks every rasteriser's backward() makes: a valid view, a forward state, output
// gradients (empty = zero) shaped like the outputs. Sets the camera and the rendered feature
// channels D.
inline bool check_backward_inputs(const GaussianMap& map, const RenderView& view, const RenderSettings& settings,
                                  const RenderResult& result, const RenderGradients& output_grads,
                                  math::SplatCamera<float>* cam, int* D, std::string* why) {
  if (!render_camera(view, settings, cam, why)) return false;
  if (!result.backward_state) return fail(why, "backward: no forward state");
  *D = settings.features ? map.feature_dim : 0;
  const auto check = [&](const PlanarImage& g, const PlanarImage& like, const char* name) {
    if (g.empty() || g.same_shape(like)) return true;
    return fail(why, std::string("backward: gradient of ") + name + " has the wrong shape");
  };
  return check(output_grads.colour, result.colour, "colour") && check(output_grads.depth, result.depth, "depth") &&
         check(output_grads.median_depth, result.median_depth, "median depth") &&
         check(output_grads.alpha, result.alpha, "alpha") &&
         (*D == 0 || check(output_grads.features, result.features, "features"));
}

}  // namespace fslam::core::render_impl
