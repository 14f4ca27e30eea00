// The 3D Gaussian map in structure-of-arrays form, and the immutable versions the mapper
// publishes for tracking and queries (design.md: tracking never waits for mapping).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace fslam::core {

constexpr int kMaxShDegree = 3;

// Coefficients per colour channel for SH degree `degree`: (degree + 1)^2.
constexpr int sh_coefficients(int degree) { return (degree + 1) * (degree + 1); }

// Parameters as the optimiser sees them (3DGS conventions): the activations are
// scale = exp(log_scale), opacity = sigmoid(opacity_logit), colour = 0.5 + SH(view dir).
struct GaussianMap {
  int sh_degree = 0;     // 0..3
  int feature_dim = 16;  // D, channels of the feature latent (0 = none)

  std::vector<float> means;           // [N, 3] world frame, metres
  std::vector<float> rotations;       // [N, 4] quaternion w, x, y, z (Gaussian -> world); any norm
  std::vector<float> log_scales;      // [N, 3] log metres, Gaussian's own axes
  std::vector<float> opacity_logits;  // [N]
  std::vector<float> sh;              // [N, K, 3], K = sh_coefficients(sh_degree); k = 0 is DC
  std::vector<float> features;        // [N, D]
  std::vector<float> filter_3d;       // [N] variance of the 3D smoothing filter, m^2 (0 = none)

  std::size_t size() const { return opacity_logits.size(); }
  bool empty() const { return opacity_logits.empty(); }
  int sh_per_gaussian() const { return 3 * sh_coefficients(sh_degree); }

  void clear();
  void reserve(std::size_t n);
  // Appends one Gaussian. sh: sh_per_gaussian() values, features: feature_dim values (nullptr
  // for zeros), rotation w, x, y, z.
  void push_back(const float mean[3], const float rotation[4], const float log_scale[3],
                 float opacity_logit, const float* sh_values, const float* feature_values,
                 float filter_variance = 0.0f);
  // Appends every Gaussian of `other` (same sh_degree and feature_dim).
  void append(const GaussianMap& other);
  // Keeps the Gaussians whose keep[i] is true, in order. keep: [N].
  void keep_only(const std::vector<std::uint8_t>& keep);
  // Array sizes agree with size(), degree in range, every value finite.
  bool is_consistent(std::string* why = nullptr) const;
};

// Keeps the rows of `row` values whose keep[i] is non-zero, in order (values: [N, row]; an
// empty array stays empty). Shared by the map and the state that follows its rows.
template <typename T>
void keep_rows(std::vector<T>* values, std::size_t row, const std::vector<std::uint8_t>& keep) {
  if (values->empty() || row == 0) return;
  std::size_t out = 0;
  for (std::size_t i = 0; i < keep.size(); ++i) {
    if (!keep[i]) continue;
    if (out != i) {
      for (std::size_t k = 0; k < row; ++k) (*values)[out * row + k] = (*values)[i * row + k];
    }
    ++out;
  }
  values->resize(out * row);
}

// 0.5 + C0 * dc is the colour of a degree-0 Gaussian; the inverse for initialisation.
constexpr float kShC0 = 0.28209479177387814f;
inline float rgb_to_sh_dc(float rgb) { return (rgb - 0.5f) / kShC0; }
inline float sh_dc_to_rgb(float dc) { return 0.5f + kShC0 * dc; }

// Publishes immutable map versions: the mapper swaps in a new one, readers keep the version they
// took for as long as they use it.
class MapVersions {
 public:
  using Version = std::shared_ptr<const GaussianMap>;

  // The newest version (an empty map before the first publish).
  Version latest() const;
  // Number of the newest version (0 before the first publish).
  std::uint64_t version_number() const;
  void publish(Version map);
  // Continues another history (a map extended by a new session): the next publish is number + 1.
  void continue_after(std::uint64_t number);

 private:
  mutable std::mutex mutex_;
  Version latest_ = std::make_shared<const GaussianMap>();
  std::uint64_t number_ = 0;
};

}  // namespace fslam::core
