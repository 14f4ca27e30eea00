// The rasteriser interface (design.md: a coarse interface with CPU and CUDA implementations):
// forward renders colour, camera-plane depth, median depth, opacity and features from a view;
// backward turns gradients of those images into gradients of every Gaussian parameter.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/render/planar_image.hpp"

namespace fslam::core {

struct RenderView {
  PinholeCamera camera;                 // intrinsics and output size
  Eigen::Isometry3d T_camera_world = Eigen::Isometry3d::Identity();
};

struct RenderSettings {
  float near_plane = 0.05;                      // metres; nearer Gaussians are culled
  std::array<float, 3> background{0, 0, 0};     // colour behind the map, [0, 1]
  bool features = true;                         // render the D feature channels
};

struct RenderStats {
  std::size_t gaussians = 0;         // in the map
  std::size_t pixels = 0;            // in the image
  std::size_t visible = 0;           // projected inside the view
  std::size_t tile_entries = 0;      // (Gaussian, tile) pairs after binning
  std::uint64_t blend_steps = 0;     // Gaussian-pixel pairs composited (alpha >= 1/255)
  std::uint64_t evaluated_pairs = 0; // pairs whose alpha the forward pass computed
  double mean_splats_per_pixel() const;
};

// The backend's bookkeeping from forward to backward; each rasteriser derives its own.
struct RenderBackwardState {
  virtual ~RenderBackwardState() = default;
};

struct RenderResult {
  PlanarImage colour;        // [3, H, W] RGB in [0, 1] over the background
  PlanarImage depth;         // [1, H, W] expected camera-plane depth, metres (not normalised)
  PlanarImage median_depth;  // [1, H, W] metres, 0 where opacity never reaches 0.5
  PlanarImage alpha;         // [1, H, W] accumulated opacity
  PlanarImage features;      // [D, H, W], empty when not rendered
  std::vector<std::uint8_t> visible;  // [N] 1 where the Gaussian projects into the view
  RenderStats stats;
  std::shared_ptr<const RenderBackwardState> backward_state;
};

// dL/d(outputs); an empty image means zero gradient for that output.
struct RenderGradients {
  PlanarImage colour, depth, median_depth, alpha, features;
};

// dL/d(parameters), the shapes of GaussianMap, plus the pruning cues.
struct GaussianGradients {
  std::vector<float> means, rotations, log_scales, opacity_logits, sh, features;
  std::vector<float> importance_rgb;      // [N] sum_x |dL_rgb / dalpha_i(x)| (eq. importance)
  std::vector<float> importance_feature;  // [N] sum_x |dL_feat / dalpha_i(x)| (eq. sem_importance)

  // Zeroed arrays sized for `map`.
  void reset(const GaussianMap& map);
};

class Rasterizer {
 public:
  virtual ~Rasterizer() = default;
  virtual std::string name() const = 0;
  // False with `why` on bad input (inconsistent map, invalid camera, non-finite pose).
  virtual bool forward(const GaussianMap& map, const RenderView& view,
                       const RenderSettings& settings, RenderResult* result,
                       std::string* why) const = 0;
  // Adds dL/d(parameters) into *grads (sized by GaussianGradients::reset). `result` must come
  // from forward() with the same map, view and settings.
  virtual bool backward(const GaussianMap& map, const RenderView& view,
                        const RenderSettings& settings, const RenderResult& result,
                        const RenderGradients& output_grads, GaussianGradients* grads,
                        std::string* why) const = 0;
};

// The CPU rasteriser: TBB over tiles, the math of fslam/core/math/splat_math.hpp.
std::unique_ptr<Rasterizer> make_cpu_rasterizer();

}  // namespace fslam::core
