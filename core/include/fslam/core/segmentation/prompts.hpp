// Objects selected by point or box prompts in a view, refined in 3D (docs/segmentation.md): a
// selection flag per Gaussian, so that any view renders it (label_rendering.hpp).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/core/segmentation/feature_graph.hpp"

namespace fslam::core {

struct PromptConfig {
  // A prompt compares each Gaussian with the object's running mean latent, so it can afford a
  // looser threshold than promptless merging (chosen on the synthetic room, docs/segmentation.md).
  FeatureGraphConfig graph = loose_graph();
  static FeatureGraphConfig loose_graph() {
    FeatureGraphConfig g;
    g.feature_threshold = 0.8f;
    return g;
  }
  float seed_radius = 0.03f;  // metres around the prompted surface point: the region's seeds
  // Per-prompt threshold: the region is grown at every threshold from min_threshold to
  // max_threshold (step threshold_step) and kept at the last one before the first step that
  // leaks across a boundary into a neighbouring surface: the step adds at least (min_jump - 1)
  // times the region's Gaussians off the prompted surface, and what it adds looks different:
  // its mean latent lies at least min_contrast x the threshold from the region's. Without such
  // a step the loosest threshold stands. adaptive_threshold = false grows at
  // graph.feature_threshold only. Chosen on the synthetic room of seed 1 (docs/segmentation.md).
  bool adaptive_threshold = true;
  float min_threshold = 0.6f;
  float max_threshold = 1.0f;
  float threshold_step = 0.05f;
  float min_jump = 1.5f;  // ratio of Gaussian counts between neighbouring thresholds
  // The rest of the prompted object, reached through a few blended boundary Gaussians, adds
  // Gaussians whose mean latent is near the region's; a neighbouring surface adds Gaussians that
  // only just pass the threshold (on the synthetic room of seed 1: 0.65-0.99 x the threshold for
  // steps that cost the clicked object IoU, 0.26-0.63 for steps that gained it).
  float min_contrast = 0.55f;
  // A region of fewer Gaussians has no jump that counts: at the tightest thresholds a prompt's
  // region can be a few dozen Gaussians of its own surface's texture, and adding the rest of
  // that surface multiplies it (on the synthetic room a wall was cut to 0.2 IoU that way).
  std::size_t min_jump_region = 100;
  // Growth that stays on the prompted smooth surface is no leak: a step's jump counts only the
  // Gaussians it adds that are not reached from the seeds over smooth neighbour pairs (both
  // flat, normals within smooth_max_angle_deg, each mean within smooth_max_offset of the other's
  // tangent plane). A wall's texture patches then no longer cut it, while a picture standing off
  // the wall or a box on the floor still ends at its bend or step. false: every added Gaussian
  // counts (a leak is any jump) and bend_ratio is not used. Chosen on the synthetic room of
  // seed 1 (docs/segmentation.md).
  bool smooth_growth = true;
  float smooth_max_angle_deg = 20.0f;  // degrees between the two normals
  float smooth_max_offset = 0.008f;    // metres off the other's tangent plane
  float flat_ratio = 0.5f;  // a Gaussian has a normal when its smallest scale <= this x its middle one
  // Across a bend or step (a neighbour pair that is not smooth) a Gaussian joins only within
  // bend_ratio x the threshold; 1 = the surface's shape does not matter to growth.
  float bend_ratio = 0.8f;
  // Refinement in 3D: after growing, a Gaussian outside the region (of any opacity) joins when
  // at least fill_fraction of its spatial neighbours (graph.knn nearest within
  // graph.max_neighbour_distance, of any opacity) are in it, repeated fill_rounds times. It
  // closes the holes that texture specks, too unlike the object's mean to join, leave inside an
  // object; a Gaussian outside a boundary has most neighbours outside and stays out. 0 rounds:
  // no refinement. Chosen on the synthetic room of seed 1 (docs/segmentation.md).
  int fill_rounds = 3;
  float fill_fraction = 0.5f;
  bool is_valid(std::string* why = nullptr) const;
};

// One step of a prompt's growth, from threshold k to k + 1 (the loosest threshold's has only
// its count).
struct PromptStep {
  std::size_t count = 0;   // Gaussians in the region at threshold k
  std::size_t leaked = 0;  // Gaussians the step adds off the prompted surface
  float contrast = 0.0f;   // RMS latent difference of their mean to the region's, / threshold k + 1
};

// The index of the threshold a prompt keeps (PromptConfig): the one before the first step from
// a region of at least min_jump_region Gaussians with (count + 1 + leaked) / (count + 1) >=
// min_jump and contrast >= min_contrast (there the region crossed into a neighbouring
// surface), else the loosest.
std::size_t pick_prompt_threshold(const std::vector<PromptStep>& steps, const PromptConfig& config);

// A box prompt in pixels of the view: [u0, u1) x [v0, v1).
struct BoxPrompt {
  double u0 = 0, v0 = 0, u1 = 0, v1 = 0;
};

// Selects the object under point prompts (pixel coordinates of `view`): the prompted pixels'
// rendered latent, then the feature-graph region around the prompted surface points, restricted
// to Gaussians with a latent like the prompt's. selected: [N] 1 = in the object. Each point is
// its own prompt; the object is their union. False with `why` when a prompt hits no surface.
bool select_by_points(const Rasterizer& rasterizer, const GaussianMap& map, const RenderView& view,
                      const std::vector<Eigen::Vector2d>& points, const PromptConfig& config,
                      std::vector<std::uint8_t>* selected, std::string* why);

// A box prompt: the median rendered latent of the box's inner half and seeds on a 3x3 grid there.
bool select_by_box(const Rasterizer& rasterizer, const GaussianMap& map, const RenderView& view,
                   const BoxPrompt& box, const PromptConfig& config,
                   std::vector<std::uint8_t>* selected, std::string* why);

// Prompts on one map: the feature space and neighbour graph are built once, in the
// constructor, and every prompt reuses them (the free functions above build them per call).
// `map` must outlive the selector and stay unchanged. An invalid config or a map without
// features makes every call fail with the reason.
class PromptSelector {
 public:
  PromptSelector(const GaussianMap& map, const PromptConfig& config);
  ~PromptSelector();
  PromptSelector(const PromptSelector&) = delete;
  PromptSelector& operator=(const PromptSelector&) = delete;
  bool select_by_points(const Rasterizer& rasterizer, const RenderView& view,
                        const std::vector<Eigen::Vector2d>& points,
                        std::vector<std::uint8_t>* selected, std::string* why) const;
  bool select_by_box(const Rasterizer& rasterizer, const RenderView& view, const BoxPrompt& box,
                     std::vector<std::uint8_t>* selected, std::string* why) const;
  // Several box prompts: the union of their objects (each box selects as select_by_box does).
  // selected: [N]. False with `why` at the first box that selects nothing.
  bool select_by_boxes(const Rasterizer& rasterizer, const RenderView& view,
                       const std::vector<BoxPrompt>& boxes, std::vector<std::uint8_t>* selected,
                       std::string* why) const;

 private:
  struct Graph;
  const GaussianMap& map_;
  PromptConfig config_;
  std::string error_;
  std::unique_ptr<Graph> graph_;
};

}  // namespace fslam::core
