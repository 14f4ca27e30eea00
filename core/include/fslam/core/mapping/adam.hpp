// Adam (Kingma & Ba 2015) over per-Gaussian parameter arrays, as 3DGS runs it through PyTorch:
// bias-corrected moments, eps added after the square root of the corrected second moment, one
// step count per parameter tensor, and moments that follow the Gaussians through densification
// (new ones start at zero) and pruning.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fslam/core/map/gaussian_map.hpp"

namespace fslam::core {

// Held in double as PyTorch holds them: 1 - beta2 from a float 0.999 would be 1.3e-5 off.
// The update itself runs in float.
struct AdamSettings {
  double beta1 = 0.9;    // PyTorch's default, as in 3DGS
  double beta2 = 0.999;  // PyTorch's default, as in 3DGS
  double eps = 1e-15;    // 3DGS's value (PyTorch's default is 1e-8)
};

// One parameter tensor: `row` values per Gaussian, its learning rate, moments and step count.
struct AdamGroup {
  std::string name;
  std::size_t row = 1;  // values per Gaussian
  float lr = 0.0f;      // parameter units per step
  std::int64_t steps = 0;
  std::vector<float> m;  // [N, row] first moment
  std::vector<float> v;  // [N, row] second raw moment
  // Per-Gaussian decay (set_row_decay over S steps to `floor`): each Gaussian's rate is
  // lr * decay[min(k, S)] at its k-th step (counted in row_steps, [N]), decay[k] = floor^(k / S),
  // computed once; empty = no decay, the rate is lr.
  std::vector<float> decay;  // [S + 1] or empty
  std::vector<std::int32_t> row_steps;
};

// Adam state for N Gaussians and any number of groups, kept aligned with the map's rows.
class AdamOptimizer {
 public:
  explicit AdamOptimizer(std::size_t n = 0, AdamSettings settings = {});

  // Adds a group with zero moments for the current N; returns its index.
  int add_group(std::string name, std::size_t row, float lr);

  // One step of group `g`. params, grads: [N, stride]; the group's `row` values sit at the start
  // of each Gaussian's stride (stride = row for a whole array; a block of a wider array, such as
  // the DC or the higher-band columns of sh [N, K, 3], is passed by offset pointers and stride).
  // active (optional, [N]): only rows with active[i] != 0 are updated, parameters and moments;
  // the others are left exactly as they were (a visibility-masked, sparse step).
  void step(int g, float* params, const float* grads, std::size_t stride,
            const std::uint8_t* active = nullptr);
  // The same for a whole [N, row] array.
  void step(int g, std::vector<float>* params, const std::vector<float>& grads,
            const std::uint8_t* active = nullptr);

  void set_learning_rate(int g, float lr);
  // Each Gaussian's rate in group `g` decays log-linearly to `floor` times lr (3DGS: 1/100) over
  // its own first `steps` steps (3DGS's schedule over iterations, counted per Gaussian: in an
  // online map Gaussians start at different times); 0 turns the decay off (counts are kept, not
  // advanced). floor in (0, 1].
  void set_row_decay(int g, int steps, float floor = 0.01f);
  // Marks every current Gaussian of group `g` as past its decay (a loaded map's Gaussians).
  void settle_rows(int g);
  // Zeros the moments of group `g`, keeping its step count (3DGS does this on opacity reset).
  void reset_moments(int g);

  // Appends `count` Gaussians with zero moments to every group (densification).
  void grow(std::size_t count);
  // Keeps the Gaussians whose keep[i] is non-zero, in order, as GaussianMap::keep_only. keep: [N].
  void keep_only(const std::vector<std::uint8_t>& keep);

  std::size_t size() const { return n_; }
  int group_count() const { return static_cast<int>(groups_.size()); }
  const AdamGroup& group(int g) const { return groups_[static_cast<std::size_t>(g)]; }
  const AdamSettings& settings() const { return settings_; }

 private:
  AdamSettings settings_;
  std::size_t n_ = 0;
  std::vector<AdamGroup> groups_;
};

// ---- Gaussian maps -----------------------------------------------------------------------------

// Learning rates per parameter, the 3DGS defaults (Kerbl et al. 2023, arguments/__init__.py).
struct GaussianLearningRates {
  // Metres per step. 3DGS multiplies 1.6e-4 by the scene extent and decays it to 1/100 over
  // 30k iterations; an online map gets tens of steps per view rather than thousands, so we take
  // twice 3DGS's rate in metres, decayed per Gaussian (means_decay_steps below; refinement
  // decays it over all Gaussians instead, Mapper::refine).
  // Schedules go through set_learning_rate. The online values below (means, SH DC, log-scales)
  // were chosen on redkitchen 0-299 and checked on 300-599 (docs/mapping.md).
  float means = 3.2e-4f;
  float sh_dc = 1e-2f;           // SH units per step (4x 3DGS's feature_lr: few steps per view)
  float sh_rest = 2.5e-3f / 20;  // SH units per step, higher bands (3DGS feature_lr / 20)
  // Logit units per step. 0.05 is the original 3DGS release; the 2024 update of the official code
  // lowered it to 0.025. We keep 0.05.
  float opacity = 0.05f;
  float log_scales = 1e-2f;  // log metres per step (2x 3DGS's, as above)
  // 3DGS decays the means' rate to 1/100 over its iterations; online, each Gaussian's rate
  // decays so over its own first N steps (AdamOptimizer::set_row_decay), so a Gaussian settles
  // where its first views put it instead of wandering for colour with every later view. 0: a
  // constant rate. 30 was chosen on redkitchen 0-299 (docs/mapping.md).
  int means_decay_steps = 30;
  // The fraction of the rate a Gaussian's mean keeps after its decay: 3DGS's 1/100.
  float means_decay_floor = 0.01f;
  float rotations = 1e-3f;   // quaternion components (unnormalised) per step
  float features = 2.5e-3f;  // latent units per step; our choice (3DGS's SH DC rate), not from 3DGS
};

// Group indices of the optimiser make_gaussian_adam builds, one per 3DGS parameter tensor.
enum GaussianAdamGroup : int {
  kAdamMeans = 0,
  kAdamRotations,
  kAdamLogScales,
  kAdamOpacity,
  kAdamShDc,    // sh[:, 0, :]
  kAdamShRest,  // sh[:, 1:, :]
  kAdamFeatures,
  kAdamGroupCount
};

// An optimiser with one group per trainable array of `map` (filter_3d is not trained).
AdamOptimizer make_gaussian_adam(const GaussianMap& map, const GaussianLearningRates& rates = {},
                                 const AdamSettings& settings = {});

// Steps every group of an optimiser from make_gaussian_adam. grads: the same layout as *map
// (filter_3d ignored).
// active (optional, [N]): a sparse step of the Gaussians with active[i] != 0 only.
void step_gaussian_adam(AdamOptimizer* adam, GaussianMap* map, const GaussianMap& grads,
                        const std::vector<std::uint8_t>* active = nullptr);

}  // namespace fslam::core
