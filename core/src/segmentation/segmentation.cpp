#include "fslam/core/segmentation/segmentation.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <numeric>
#include <queue>
#include <tuple>

#include <flann/flann.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/math/splat_math.hpp"

namespace fslam::core {
namespace {

float sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

// For each of the `count` points (rows of xyz in `points`, the points `index` was built on), the
// rows of its `knn` nearest other points within `radius`.
std::vector<std::vector<int>> knn_within(const flann::Index<flann::L2<float>>& index,
                                         const std::vector<float>& points, int knn, float radius) {
  const std::size_t m = points.size() / 3;
  std::vector<std::vector<int>> out(m);
  if (m == 0) return out;
  const int k = std::min<int>(knn + 1, static_cast<int>(m));
  std::vector<int> idx(m * static_cast<std::size_t>(k));
  std::vector<float> d2(m * static_cast<std::size_t>(k));
  flann::Matrix<int> im(idx.data(), m, static_cast<std::size_t>(k));
  flann::Matrix<float> dm(d2.data(), m, static_cast<std::size_t>(k));
  flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
  params.cores = 1;
  const_cast<flann::Index<flann::L2<float>>&>(index).knnSearch(
      flann::Matrix<float>(const_cast<float*>(points.data()), m, 3), im, dm, k, params);
  const float r2 = radius * radius;
  for (std::size_t q = 0; q < m; ++q)
    for (int j = 0; j < k; ++j) {
      const int other = idx[q * k + j];
      if (other < 0 || static_cast<std::size_t>(other) == q || d2[q * k + j] > r2) continue;
      out[q].push_back(other);
    }
  return out;
}

// The Gaussians taking part, their standardised latents and a k-d tree over their means.
class FeatureSpace {
 public:
  FeatureSpace(const GaussianMap& map, const FeatureGraphConfig& config) : map_(map), config_(config) {
    for (std::size_t i = 0; i < map.size(); ++i)
      if (sigmoid(map.opacity_logits[i]) >= config.min_opacity) active_.push_back(static_cast<int>(i));
    d_ = map.feature_dim;
    // Latents have no fixed scale: centre them per channel and divide by one spread for all
    // channels (the RMS of the channels' standard deviations). A per-channel scale would blow
    // up channels that carry only noise.
    mean_.assign(static_cast<std::size_t>(d_), 0.0f);
    inv_std_.assign(static_cast<std::size_t>(d_), 1.0f);
    if (active_.empty() || d_ == 0) return;
    std::vector<double> sum(d_, 0.0), sum2(d_, 0.0);
    for (int i : active_)
      for (int c = 0; c < d_; ++c) {
        const double f = map.features[static_cast<std::size_t>(i) * d_ + c];
        sum[c] += f;
        sum2[c] += f * f;
      }
    const double n = static_cast<double>(active_.size());
    double variance = 0.0;
    for (int c = 0; c < d_; ++c) {
      mean_[c] = static_cast<float>(sum[c] / n);
      variance += std::max(0.0, sum2[c] / n - (sum[c] / n) * (sum[c] / n)) / d_;
    }
    inv_std_.assign(static_cast<std::size_t>(d_), static_cast<float>(1.0 / std::max(std::sqrt(variance), 1e-6)));
    z_.resize(map.size() * static_cast<std::size_t>(d_));
    for (std::size_t i = 0; i < map.size(); ++i) standardise(&map.features[i * d_], &z_[i * d_]);
    points_.resize(active_.size() * 3);
    for (std::size_t k = 0; k < active_.size(); ++k)
      for (int a = 0; a < 3; ++a) points_[k * 3 + a] = map.means[static_cast<std::size_t>(active_[k]) * 3 + a];
    index_ = std::make_unique<flann::Index<flann::L2<float>>>(
        flann::Matrix<float>(points_.data(), active_.size(), 3), flann::KDTreeSingleIndexParams(10));
    index_->buildIndex();
  }

  const std::vector<int>& active() const { return active_; }
  int dim() const { return d_; }
  void standardise(const float* f, float* z) const {
    for (int c = 0; c < d_; ++c) z[c] = (f[c] - mean_[c]) * inv_std_[c];
  }
  const float* z(int i) const { return &z_[static_cast<std::size_t>(i) * d_]; }
  // RMS difference of two standardised latents.
  float distance(const float* a, const float* b) const {
    float s = 0;
    for (int c = 0; c < d_; ++c) s += (a[c] - b[c]) * (a[c] - b[c]);
    return std::sqrt(s / static_cast<float>(d_));
  }
  bool alike(int i, int j) const { return distance(z(i), z(j)) < config_.feature_threshold; }

  // Spatial neighbours (map indices) of every map index: k nearest within the radius.
  std::vector<std::vector<int>> neighbours() const {
    std::vector<std::vector<int>> out(map_.size());
    if (active_.empty()) return out;
    const std::vector<std::vector<int>> rows =
        knn_within(*index_, points_, config_.knn, config_.max_neighbour_distance);
    for (std::size_t q = 0; q < rows.size(); ++q)
      for (int other : rows[q]) {
        out[static_cast<std::size_t>(active_[q])].push_back(active_[static_cast<std::size_t>(other)]);
      }
    return out;
  }

  // Active map indices within `radius` of `p` (world frame, metres), nearest first.
  std::vector<int> within(const Eigen::Vector3f& p, float radius) const {
    std::vector<int> out;
    if (active_.empty()) return out;
    float q[3] = {p.x(), p.y(), p.z()};
    std::vector<std::vector<int>> idx;
    std::vector<std::vector<float>> d2;
    flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
    params.sorted = true;
    index_->radiusSearch(flann::Matrix<float>(q, 1, 3), idx, d2, radius * radius, params);
    for (int k : idx[0]) out.push_back(active_[static_cast<std::size_t>(k)]);
    return out;
  }

 private:
  const GaussianMap& map_;
  FeatureGraphConfig config_;
  std::vector<int> active_;  // map indices
  int d_ = 0;
  std::vector<float> mean_, inv_std_, z_, points_;
  std::unique_ptr<flann::Index<flann::L2<float>>> index_;
};

struct UnionFind {
  std::vector<int> parent;
  explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int find(int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void join(int a, int b) { parent[find(a)] = find(b); }
};

bool check_features(const GaussianMap& map, std::string* why) {
  if (map.feature_dim > 0 && map.features.size() != map.size() * static_cast<std::size_t>(map.feature_dim)) {
    return fail(why, "segmentation: the map's feature array does not match its size");
  }
  if (!has_features(map)) return fail(why, "segmentation: the map carries no features (its latents are all alike)");
  return true;
}

// A copy of the map's geometry and opacity (colour DC only) whose D feature channels the caller
// fills: rendering them gives per-pixel sums of blending weights per channel.
GaussianMap geometry_copy(const GaussianMap& map, int channels) {
  GaussianMap g;
  g.sh_degree = 0;
  g.feature_dim = channels;
  g.means = map.means;
  g.rotations = map.rotations;
  g.log_scales = map.log_scales;
  g.opacity_logits = map.opacity_logits;
  g.filter_3d = map.filter_3d;
  const int k = map.sh_per_gaussian();
  g.sh.resize(map.size() * 3);
  for (std::size_t i = 0; i < map.size(); ++i)
    for (int c = 0; c < 3; ++c) g.sh[i * 3 + c] = map.sh[i * static_cast<std::size_t>(k) + c];
  g.features.assign(map.size() * static_cast<std::size_t>(channels), 0.0f);
  return g;
}

// Grows the object from `seeds` over the spatial neighbour graph, best match first: a Gaussian
// joins while its latent is within `threshold` of the object's running mean latent, which
// starts at the prompt's `zp`. Comparing with the mean rather than with the neighbour keeps the
// region from creeping across a boundary through the blended latents there. A Gaussian reached
// only across a bend or step (not a smooth pair, `smooth` [N] lists them per Gaussian) must be
// within bend_ratio x threshold: the surface's shape marks object boundaries the latents blur.
// `selected` [N] is all zero on entry and marks the region on return.
void grow(const FeatureSpace& space, const std::vector<std::vector<int>>& neighbours,
          const std::vector<std::vector<int>>& smooth, float bend_ratio, const std::vector<int>& seeds,
          const float* zp, float threshold, std::vector<std::uint8_t>* selected) {
  const int dim = space.dim();
  std::vector<double> sum(zp, zp + dim);
  double count = 1.0;  // the prompt counts as one member
  std::vector<float> mean(zp, zp + dim);
  // (distance to the mean when queued, scaled by 1 / bend_ratio across a bend; Gaussian; across a bend)
  using Entry = std::tuple<float, int, bool>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> queue;
  enum : std::uint8_t { kNone = 0, kAcrossBend = 1, kSmooth = 2 };
  std::vector<std::uint8_t> queued(selected->size(), kNone);
  for (int s : seeds) {
    queue.push({space.distance(space.z(s), mean.data()), s, false});
    queued[static_cast<std::size_t>(s)] = kSmooth;
  }
  while (!queue.empty()) {
    const auto [key, i, bend] = queue.top();
    queue.pop();
    if ((*selected)[static_cast<std::size_t>(i)]) continue;  // joined through an earlier entry
    const float* zi = space.z(i);
    if (space.distance(zi, mean.data()) >= (bend ? bend_ratio * threshold : threshold)) continue;
    (*selected)[static_cast<std::size_t>(i)] = 1;
    count += 1.0;
    for (int c = 0; c < dim; ++c) {
      sum[c] += zi[c];
      mean[c] = static_cast<float>(sum[c] / count);
    }
    const std::vector<int>& on_surface = smooth[static_cast<std::size_t>(i)];
    for (int j : neighbours[static_cast<std::size_t>(i)]) {
      const bool across = bend_ratio < 1.0f && std::find(on_surface.begin(), on_surface.end(), j) == on_surface.end();
      std::uint8_t& q = queued[static_cast<std::size_t>(j)];
      if (q == kSmooth || (q == kAcrossBend && across)) continue;  // queued already, as easily
      q = across ? kAcrossBend : kSmooth;
      const float d = space.distance(space.z(j), mean.data());
      queue.push({across ? d / bend_ratio : d, j, across});
    }
  }
}

struct PromptView {
  RenderResult render;
  Eigen::Isometry3d T_world_camera;
};

bool render_prompt_view(const Rasterizer& rasterizer, const GaussianMap& map, const RenderView& view,
                        PromptView* out, std::string* why) {
  RenderSettings settings;
  settings.features = true;
  if (!rasterizer.forward(map, view, settings, &out->render, why)) return false;
  out->T_world_camera = view.T_camera_world.inverse();
  return true;
}

// The surface point and standardised rendered latent at pixel (u, v); false when nothing opaque.
bool prompt_at(const FeatureSpace& space, const PromptView& pv, const RenderView& view, int u, int v,
               Eigen::Vector3f* point, std::vector<float>* zp) {
  const RenderResult& r = pv.render;
  if (u < 0 || v < 0 || u >= r.alpha.width || v >= r.alpha.height) return false;
  const float alpha = r.alpha.at(0, v, u), depth = r.median_depth.at(0, v, u);
  if (alpha < kMinObjectAlpha || depth <= 0.0f) return false;
  std::vector<float> f(static_cast<std::size_t>(space.dim()));
  for (int c = 0; c < space.dim(); ++c) f[c] = r.features.at(c, v, u) / alpha;
  zp->resize(f.size());
  space.standardise(f.data(), zp->data());
  const Eigen::Vector3d p_camera = view.camera.unproject(Eigen::Vector2d(u, v), depth);
  *point = (pv.T_world_camera * p_camera).cast<float>();
  return true;
}

// Seeds near `point` that are alike the prompt; the nearest alike one within twice the neighbour
// radius when none is within seed_radius.
std::vector<int> seeds_at(const FeatureSpace& space, const PromptConfig& config,
                          const Eigen::Vector3f& point, const float* zp, float threshold) {
  std::vector<int> seeds;
  for (int i : space.within(point, config.seed_radius))
    if (space.distance(space.z(i), zp) < threshold) seeds.push_back(i);
  if (!seeds.empty()) return seeds;
  for (int i : space.within(point, 2.0f * config.graph.max_neighbour_distance)) {
    if (space.distance(space.z(i), zp) < threshold) return {i};
  }
  return seeds;
}

// The thresholds a prompt is grown at: graph.feature_threshold alone, or the adaptive range.
std::vector<float> prompt_thresholds(const PromptConfig& config) {
  if (!config.adaptive_threshold) return {config.graph.feature_threshold};
  std::vector<float> out;
  for (int k = 0;; ++k) {
    const float t = config.min_threshold + static_cast<float>(k) * config.threshold_step;
    if (t > config.max_threshold + 1e-4f) break;
    out.push_back(t);
  }
  return out;
}

// Whether growth from Gaussian i to its neighbour j stays on one smooth surface: both flat
// (their normal is defined), normals within the angle, each mean near the other's tangent plane.
// normals: [N, 3] world frame, zero where the Gaussian is not flat.
bool smooth_pair(const GaussianMap& map, const std::vector<float>& normals, float min_cos, float max_offset,
                 int i, int j) {
  const float* ni = &normals[static_cast<std::size_t>(i) * 3];
  const float* nj = &normals[static_cast<std::size_t>(j) * 3];
  const float* xi = &map.means[static_cast<std::size_t>(i) * 3];
  const float* xj = &map.means[static_cast<std::size_t>(j) * 3];
  float dot = 0, off_i = 0, off_j = 0;
  for (int a = 0; a < 3; ++a) {
    dot += ni[a] * nj[a];
    off_i += ni[a] * (xj[a] - xi[a]);
    off_j += nj[a] * (xi[a] - xj[a]);
  }
  return std::abs(dot) >= min_cos && std::abs(off_i) <= max_offset && std::abs(off_j) <= max_offset;
}

// Per Gaussian, its unit normal (the axis of its smallest scale; [N, 3] world frame), or zero
// where the smallest scale exceeds flat_ratio x the middle one: no surface direction to trust.
std::vector<float> gaussian_normals(const GaussianMap& map, float flat_ratio) {
  std::vector<float> normals(map.size() * 3, 0.0f);
  for (std::size_t i = 0; i < map.size(); ++i) {
    const float* ls = &map.log_scales[i * 3];
    int order[3] = {0, 1, 2};
    std::sort(order, order + 3, [&](int a, int b) { return ls[a] < ls[b]; });
    if (std::exp(ls[order[0]] - ls[order[1]]) > flat_ratio) continue;
    float R[9];
    math::quat_to_rotmat(&map.rotations[i * 4], R);  // row-major, columns are the Gaussian's axes
    for (int a = 0; a < 3; ++a) normals[i * 3 + a] = R[a * 3 + order[0]];
  }
  return normals;
}

// Per Gaussian, those of its neighbours that lie on one smooth surface with it (smooth_pair).
std::vector<std::vector<int>> smooth_neighbours(const GaussianMap& map, const std::vector<std::vector<int>>& neighbours,
                                                const PromptConfig& config) {
  std::vector<std::vector<int>> out(neighbours.size());
  if (!config.smooth_growth) return out;
  const std::vector<float> normals = gaussian_normals(map, config.flat_ratio);
  const float min_cos = std::cos(config.smooth_max_angle_deg * static_cast<float>(M_PI) / 180.0f);
  for (std::size_t i = 0; i < neighbours.size(); ++i)
    for (int j : neighbours[i])
      if (smooth_pair(map, normals, min_cos, config.smooth_max_offset, static_cast<int>(i), j)) out[i].push_back(j);
  return out;
}

// The step from `region` (grown at one threshold) to `next` (grown at the next, `next_threshold`):
// what it adds off the seeds' smooth surface (not reached from `seeds` over smooth pairs within
// `next`; a surface reached through a few leaked boundary Gaussians is off it too), and how far
// that addition's mean latent lies from the region's.
PromptStep describe_step(const FeatureSpace& space, const std::vector<std::vector<int>>& smooth,
                         const std::vector<int>& seeds, const std::vector<std::uint8_t>& region,
                         const std::vector<std::uint8_t>& next, float next_threshold) {
  std::vector<std::uint8_t> reached(next.size(), 0);
  std::deque<int> queue;
  for (int s : seeds)
    if (next[static_cast<std::size_t>(s)] && !reached[static_cast<std::size_t>(s)]) {
      reached[static_cast<std::size_t>(s)] = 1;
      queue.push_back(s);
    }
  while (!queue.empty()) {
    const int i = queue.front();
    queue.pop_front();
    for (int j : smooth[static_cast<std::size_t>(i)]) {
      if (reached[static_cast<std::size_t>(j)] || !next[static_cast<std::size_t>(j)]) continue;
      reached[static_cast<std::size_t>(j)] = 1;
      queue.push_back(j);
    }
  }
  const int dim = space.dim();
  std::vector<double> sum_region(static_cast<std::size_t>(dim), 0.0), sum_off(static_cast<std::size_t>(dim), 0.0);
  PromptStep step;
  for (std::size_t i = 0; i < next.size(); ++i) {
    const bool off = next[i] && !region[i] && !reached[i];
    if (!region[i] && !off) continue;
    std::vector<double>& sum = region[i] ? sum_region : sum_off;
    const float* z = space.z(static_cast<int>(i));
    for (int c = 0; c < dim; ++c) sum[c] += z[c];
    ++(region[i] ? step.count : step.leaked);
  }
  if (step.count == 0 || step.leaked == 0) return step;
  std::vector<float> mean_region(static_cast<std::size_t>(dim)), mean_off(static_cast<std::size_t>(dim));
  for (int c = 0; c < dim; ++c) {
    mean_region[c] = static_cast<float>(sum_region[c] / static_cast<double>(step.count));
    mean_off[c] = static_cast<float>(sum_off[c] / static_cast<double>(step.leaked));
  }
  step.contrast = space.distance(mean_region.data(), mean_off.data()) / next_threshold;
  return step;
}

// Every Gaussian's `knn` nearest Gaussians of any opacity within `max_neighbour_distance`.
std::vector<std::vector<int>> spatial_neighbours(const GaussianMap& map, const FeatureGraphConfig& config) {
  if (map.empty()) return {};
  std::vector<float> points(map.means);
  flann::Index<flann::L2<float>> index(flann::Matrix<float>(points.data(), map.size(), 3),
                                       flann::KDTreeSingleIndexParams(10));
  index.buildIndex();
  return knn_within(index, points, config.knn, config.max_neighbour_distance);
}

// The prompt's refinement in 3D (PromptConfig::fill_rounds): Gaussians outside `region` whose
// spatial neighbours are at least `fraction` inside join it, `rounds` times, all of a round at once.
void fill_region(const std::vector<std::vector<int>>& spatial, int rounds, float fraction,
                 std::vector<std::uint8_t>* region) {
  std::vector<std::size_t> joining;
  for (int round = 0; round < rounds; ++round) {
    joining.clear();
    for (std::size_t i = 0; i < region->size(); ++i) {
      const std::vector<int>& near = spatial[i];
      if ((*region)[i] || near.size() < 3) continue;  // too few neighbours to outvote
      std::size_t inside = 0;
      for (int j : near) inside += (*region)[static_cast<std::size_t>(j)];
      if (static_cast<float>(inside) >= fraction * static_cast<float>(near.size())) joining.push_back(i);
    }
    if (joining.empty()) return;
    for (std::size_t i : joining) (*region)[i] = 1;
  }
}

// Grows one prompt's region at each of the prompt's thresholds (seeds_for(threshold) gives its
// seeds) and adds the one pick_prompt_threshold keeps, refined by fill_region, to `selected`. False when
// no threshold has seeds.
template <typename SeedsFor>
bool select_region(const FeatureSpace& space, const std::vector<std::vector<int>>& neighbours,
                   const std::vector<std::vector<int>>& smooth, const std::vector<std::vector<int>>& spatial,
                   const PromptConfig& config, const SeedsFor& seeds_for, const float* zp,
                   std::vector<std::uint8_t>* selected) {
  const std::vector<float> thresholds = prompt_thresholds(config);
  std::vector<std::vector<std::uint8_t>> regions(thresholds.size());
  std::vector<std::vector<int>> seeds(thresholds.size());
  bool any = false;
  for (std::size_t k = 0; k < thresholds.size(); ++k) {
    regions[k].assign(selected->size(), 0);
    seeds[k] = seeds_for(thresholds[k]);
    if (seeds[k].empty()) continue;
    any = true;
    grow(space, neighbours, smooth, config.smooth_growth ? config.bend_ratio : 1.0f, seeds[k], zp, thresholds[k],
         &regions[k]);
  }
  if (!any) return false;
  std::vector<PromptStep> steps(thresholds.size());
  for (std::size_t k = 0; k < thresholds.size(); ++k) {
    if (k + 1 < thresholds.size()) {
      steps[k] = describe_step(space, smooth, seeds[k + 1], regions[k], regions[k + 1], thresholds[k + 1]);
    } else {
      steps[k].count = static_cast<std::size_t>(std::count(regions[k].begin(), regions[k].end(), 1));
    }
  }
  const std::size_t picked = pick_prompt_threshold(steps, config);
  std::vector<std::uint8_t>& region = regions[picked];
  fill_region(spatial, config.fill_rounds, config.fill_fraction, &region);
  for (std::size_t i = 0; i < region.size(); ++i)
    if (region[i]) (*selected)[i] = 1;
  return true;
}

}  // namespace

// Paper sec. "Novel-View Open-Set Segmentation": a prompt selects the object in 3D; the
// threshold that bounds it is chosen per prompt (docs/segmentation.md). +1 keeps an empty region
// from making every jump infinite.
std::size_t pick_prompt_threshold(const std::vector<PromptStep>& steps, const PromptConfig& config) {
  if (steps.empty()) return 0;
  for (std::size_t k = 0; k + 1 < steps.size(); ++k) {
    const PromptStep& s = steps[k];
    if (s.count == 0 || s.count < config.min_jump_region) continue;
    const double before = static_cast<double>(s.count) + 1.0;
    const double ratio = (before + static_cast<double>(s.leaked)) / before;
    if (ratio >= config.min_jump && s.contrast >= config.min_contrast) return k;
  }
  return steps.size() - 1;
}

bool has_features(const GaussianMap& map) {
  if (map.feature_dim <= 0 || map.features.empty()) return false;
  const auto [lo, hi] = std::minmax_element(map.features.begin(), map.features.end());
  return *hi > *lo;
}

bool FeatureGraphConfig::is_valid(std::string* why) const {
  if (knn < 1) return fail(why, "segmentation: knn must be >= 1");
  if (!(max_neighbour_distance > 0)) return fail(why, "segmentation: max_neighbour_distance must be > 0");
  if (!(feature_threshold > 0)) return fail(why, "segmentation: feature_threshold must be > 0");
  if (!(min_opacity >= 0 && min_opacity < 1)) return fail(why, "segmentation: min_opacity must be in [0, 1)");
  return true;
}

bool PromptlessConfig::is_valid(std::string* why) const { return graph.is_valid(why); }

bool PromptConfig::is_valid(std::string* why) const {
  if (!(seed_radius > 0)) return fail(why, "segmentation: seed_radius must be > 0");
  if (adaptive_threshold) {
    if (!(min_threshold > 0 && max_threshold >= min_threshold)) {
      return fail(why, "segmentation: prompt thresholds need 0 < min_threshold <= max_threshold");
    }
    if (!(threshold_step > 0)) return fail(why, "segmentation: threshold_step must be > 0");
    if (!(min_jump > 1)) return fail(why, "segmentation: min_jump must be > 1");
    if (!(min_contrast >= 0)) return fail(why, "segmentation: min_contrast must be >= 0");
    if (smooth_growth) {
      if (!(smooth_max_angle_deg > 0 && smooth_max_angle_deg < 90)) {
        return fail(why, "segmentation: smooth_max_angle_deg must be in (0, 90)");
      }
      if (!(smooth_max_offset >= 0)) return fail(why, "segmentation: smooth_max_offset must be >= 0");
      if (!(flat_ratio > 0 && flat_ratio <= 1)) return fail(why, "segmentation: flat_ratio must be in (0, 1]");
      if (!(bend_ratio > 0 && bend_ratio <= 1)) return fail(why, "segmentation: bend_ratio must be in (0, 1]");
    }
  }
  if (fill_rounds < 0) return fail(why, "segmentation: fill_rounds must be >= 0");
  if (fill_rounds > 0 && !(fill_fraction > 0 && fill_fraction <= 1)) {
    return fail(why, "segmentation: fill_fraction must be in (0, 1]");
  }
  return graph.is_valid(why);
}

bool cluster_instances(const GaussianMap& map, const PromptlessConfig& config, GaussianLabels* labels,
                       std::string* why) {
  if (!config.is_valid(why) || !check_features(map, why)) return false;
  const FeatureSpace space(map, config.graph);
  const std::vector<std::vector<int>> neighbours = space.neighbours();
  // Neighbour pairs joined in order of latent difference, and only while the two regions'
  // mean latents stay alike: a region cannot creep across an object boundary through the
  // blended latents there (single linkage would chain through them).
  std::vector<std::tuple<float, int, int>> edges;
  for (int i : space.active())
    for (int j : neighbours[static_cast<std::size_t>(i)]) {
      if (j <= i) continue;
      const float d = space.distance(space.z(i), space.z(j));
      if (d < config.graph.feature_threshold) edges.emplace_back(d, i, j);
    }
  std::sort(edges.begin(), edges.end());
  const int dim = space.dim();
  std::vector<float> sum(map.size() * static_cast<std::size_t>(dim));  // per root: sum of z
  std::vector<float> count(map.size(), 1.0f);
  for (int i : space.active()) std::copy(space.z(i), space.z(i) + dim, &sum[static_cast<std::size_t>(i) * dim]);
  std::vector<float> mean_a(static_cast<std::size_t>(dim)), mean_b(static_cast<std::size_t>(dim));
  UnionFind sets(map.size());
  for (const auto& [d, i, j] : edges) {
    const int a = sets.find(i), b = sets.find(j);
    if (a == b) continue;
    float* sa = &sum[static_cast<std::size_t>(a) * dim];
    float* sb = &sum[static_cast<std::size_t>(b) * dim];
    for (int c = 0; c < dim; ++c) {
      mean_a[c] = sa[c] / count[a];
      mean_b[c] = sb[c] / count[b];
    }
    if (space.distance(mean_a.data(), mean_b.data()) >= config.graph.feature_threshold) continue;
    sets.parent[a] = b;
    for (int c = 0; c < dim; ++c) sb[c] += sa[c];
    count[b] += count[a];
  }
  // Small regions (texture speckle, boundary Gaussians) join their most alike neighbour region.
  for (int round = 0; round < 8; ++round) {
    std::map<int, std::size_t> size;
    for (int i : space.active()) ++size[sets.find(i)];
    std::map<int, std::pair<float, int>> best;  // small root -> (distance, other root)
    for (int i : space.active()) {
      const int a = sets.find(i);
      if (size[a] >= config.min_instance_gaussians) continue;
      for (int j : neighbours[static_cast<std::size_t>(i)]) {
        const int b = sets.find(j);
        if (b == a) continue;
        const float d = space.distance(space.z(i), space.z(j));
        auto it = best.find(a);
        if (it == best.end() || d < it->second.first) best[a] = {d, b};
      }
    }
    if (best.empty()) break;
    for (const auto& [a, target] : best) sets.join(a, target.second);
  }
  std::map<int, std::size_t> size;
  for (int i : space.active()) ++size[sets.find(i)];
  std::vector<std::pair<std::size_t, int>> order;  // (size, root), largest first
  for (const auto& [root, n] : size)
    if (n >= config.min_instance_gaussians) order.push_back({n, root});
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  std::map<int, int> id;
  for (std::size_t k = 0; k < order.size(); ++k) id[order[k].second] = static_cast<int>(k);
  labels->label.assign(map.size(), -1);
  labels->count = static_cast<int>(order.size());
  for (int i : space.active()) {
    const auto it = id.find(sets.find(i));
    if (it != id.end()) labels->label[static_cast<std::size_t>(i)] = it->second;
  }
  return true;
}

void carry_instance_ids(const GaussianMap& previous_map, const GaussianLabels& previous,
                        const GaussianMap& map, float radius, GaussianLabels* labels) {
  if (previous_map.empty() || labels->count == 0) return;
  std::vector<float> points(previous_map.means);
  flann::Index<flann::L2<float>> index(flann::Matrix<float>(points.data(), previous_map.size(), 3),
                                       flann::KDTreeSingleIndexParams(10));
  index.buildIndex();
  // votes[new id][old id] = Gaussians of the new instance next to the old one.
  std::vector<std::map<int, std::size_t>> votes(static_cast<std::size_t>(labels->count));
  flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
  params.cores = 1;
  int nn = 0;
  float d2 = 0;
  for (std::size_t i = 0; i < map.size(); ++i) {
    const int l = labels->label[i];
    if (l < 0) continue;
    float q[3] = {map.means[i * 3], map.means[i * 3 + 1], map.means[i * 3 + 2]};
    flann::Matrix<int> im(&nn, 1, 1);
    flann::Matrix<float> dm(&d2, 1, 1);
    index.knnSearch(flann::Matrix<float>(q, 1, 3), im, dm, 1, params);
    if (d2 > radius * radius) continue;
    const int old = previous.label[static_cast<std::size_t>(nn)];
    if (old >= 0) ++votes[static_cast<std::size_t>(l)][old];
  }
  // Greedy by vote count: each old id goes to at most one new instance.
  std::vector<std::tuple<std::size_t, int, int>> pairs;  // (votes, new, old)
  for (int l = 0; l < labels->count; ++l)
    for (const auto& [old, n] : votes[static_cast<std::size_t>(l)]) pairs.push_back({n, l, old});
  std::sort(pairs.begin(), pairs.end(), [](const auto& a, const auto& b) { return std::get<0>(a) > std::get<0>(b); });
  std::vector<int> mapping(static_cast<std::size_t>(labels->count), -1);
  std::vector<bool> taken(static_cast<std::size_t>(std::max(previous.count, 0)), false);
  for (const auto& [n, l, old] : pairs) {
    if (mapping[static_cast<std::size_t>(l)] >= 0 || old >= previous.count || taken[static_cast<std::size_t>(old)]) continue;
    mapping[static_cast<std::size_t>(l)] = old;
    taken[static_cast<std::size_t>(old)] = true;
  }
  int next = previous.count;
  for (int& m : mapping)
    if (m < 0) m = next++;
  for (int& l : labels->label)
    if (l >= 0) l = mapping[static_cast<std::size_t>(l)];
  labels->count = next;
}

bool render_labels(const Rasterizer& rasterizer, const GaussianMap& map, const GaussianLabels& labels,
                   const RenderView& view, float min_alpha, cv::Mat* ids, std::string* why) {
  if (labels.label.size() != map.size()) return fail(why, "render labels: one label per Gaussian expected");
  constexpr int kChunk = 16;  // labels rendered per pass, as one-hot feature channels
  const int chunks = std::max(1, (labels.count + kChunk - 1) / kChunk);
  GaussianMap g = geometry_copy(map, kChunk);
  RenderSettings settings;
  settings.features = true;
  cv::Mat best(view.camera.height, view.camera.width, CV_32FC1, cv::Scalar(0));
  cv::Mat total(view.camera.height, view.camera.width, CV_32FC1, cv::Scalar(0));
  *ids = cv::Mat(view.camera.height, view.camera.width, CV_32SC1, cv::Scalar(-1));
  for (int chunk = 0; chunk < chunks; ++chunk) {
    std::fill(g.features.begin(), g.features.end(), 0.0f);
    for (std::size_t i = 0; i < map.size(); ++i) {
      const int c = labels.label[i] - chunk * kChunk;
      if (c >= 0 && c < kChunk) g.features[i * kChunk + static_cast<std::size_t>(c)] = 1.0f;
    }
    RenderResult r;
    if (!rasterizer.forward(g, view, settings, &r, why)) return false;
    for (int v = 0; v < view.camera.height; ++v)
      for (int u = 0; u < view.camera.width; ++u)
        for (int c = 0; c < kChunk; ++c) {
          const float w = r.features.at(c, v, u);
          total.at<float>(v, u) += w;
          if (w > best.at<float>(v, u)) {
            best.at<float>(v, u) = w;
            ids->at<int>(v, u) = chunk * kChunk + c;
          }
        }
  }
  ids->setTo(-1, total < min_alpha);
  return true;
}

bool render_selection(const Rasterizer& rasterizer, const GaussianMap& map,
                      const std::vector<std::uint8_t>& selected, const RenderView& view,
                      float min_alpha, cv::Mat* mask, std::string* why) {
  if (selected.size() != map.size()) return fail(why, "render selection: one flag per Gaussian expected");
  GaussianMap g = geometry_copy(map, 1);
  for (std::size_t i = 0; i < map.size(); ++i) g.features[i] = selected[i] ? 1.0f : 0.0f;
  RenderSettings settings;
  settings.features = true;
  RenderResult r;
  if (!rasterizer.forward(g, view, settings, &r, why)) return false;
  *mask = cv::Mat(view.camera.height, view.camera.width, CV_8UC1, cv::Scalar(0));
  for (int v = 0; v < view.camera.height; ++v)
    for (int u = 0; u < view.camera.width; ++u) {
      const float alpha = r.alpha.at(0, v, u), in = r.features.at(0, v, u);
      if (alpha >= min_alpha && in >= 0.5f * alpha) mask->at<std::uint8_t>(v, u) = 255;
    }
  return true;
}

// The feature space and neighbour graph of one map, built once for all its prompts.
struct PromptSelector::Graph {
  Graph(const GaussianMap& map, const PromptConfig& config)
      : space(map, config.graph),
        neighbours(space.neighbours()),
        smooth(smooth_neighbours(map, neighbours, config)),
        spatial(config.fill_rounds > 0 ? spatial_neighbours(map, config.graph) : std::vector<std::vector<int>>()) {}
  FeatureSpace space;
  std::vector<std::vector<int>> neighbours;
  std::vector<std::vector<int>> smooth;   // the neighbours on one smooth surface with each
  std::vector<std::vector<int>> spatial;  // neighbours of any opacity, for the refinement in 3D
};

PromptSelector::PromptSelector(const GaussianMap& map, const PromptConfig& config)
    : map_(map), config_(config) {
  if (config.is_valid(&error_) && check_features(map, &error_)) graph_ = std::make_unique<Graph>(map, config);
}

PromptSelector::~PromptSelector() = default;

bool PromptSelector::select_by_points(const Rasterizer& rasterizer, const RenderView& view,
                                      const std::vector<Eigen::Vector2d>& points,
                                      std::vector<std::uint8_t>* selected, std::string* why) const {
  if (!graph_) return fail(why, error_);
  if (points.empty()) return fail(why, "point prompt: no points");
  const GaussianMap& map = map_;
  const PromptConfig& config = config_;
  const FeatureSpace& space = graph_->space;
  const std::vector<std::vector<int>>& neighbours = graph_->neighbours;
  PromptView pv;
  if (!render_prompt_view(rasterizer, map, view, &pv, why)) return false;
  selected->assign(map.size(), 0);
  for (const Eigen::Vector2d& p : points) {
    const int u = static_cast<int>(std::lround(p.x())), v = static_cast<int>(std::lround(p.y()));
    Eigen::Vector3f point;
    std::vector<float> zp;
    if (!prompt_at(space, pv, view, u, v, &point, &zp)) {
      return fail(why, "point prompt (" + std::to_string(u) + ", " + std::to_string(v) +
                           ") hits no surface of the map in this view");
    }
    const auto seeds_for = [&](float threshold) { return seeds_at(space, config, point, zp.data(), threshold); };
    if (!select_region(space, neighbours, graph_->smooth, graph_->spatial, config, seeds_for, zp.data(), selected)) {
      return fail(why, "point prompt (" + std::to_string(u) + ", " + std::to_string(v) +
                           "): no Gaussian near the prompted surface has its features");
    }
  }
  return true;
}

bool PromptSelector::select_by_box(const Rasterizer& rasterizer, const RenderView& view,
                                   const BoxPrompt& box, std::vector<std::uint8_t>* selected,
                                   std::string* why) const {
  if (!graph_) return fail(why, error_);
  if (!(box.u1 > box.u0 && box.v1 > box.v0)) return fail(why, "box prompt: empty box");
  const GaussianMap& map = map_;
  const PromptConfig& config = config_;
  const FeatureSpace& space = graph_->space;
  const std::vector<std::vector<int>>& neighbours = graph_->neighbours;
  PromptView pv;
  if (!render_prompt_view(rasterizer, map, view, &pv, why)) return false;
  // The inner half of the box: the object most likely fills it, its border may be background.
  const double cu = 0.5 * (box.u0 + box.u1), cv = 0.5 * (box.v0 + box.v1);
  const double hu = 0.25 * (box.u1 - box.u0), hv = 0.25 * (box.v1 - box.v0);
  std::vector<std::vector<float>> latents;
  std::vector<Eigen::Vector3f> surface;
  for (int v = static_cast<int>(std::ceil(cv - hv)); v <= static_cast<int>(std::floor(cv + hv)); ++v)
    for (int u = static_cast<int>(std::ceil(cu - hu)); u <= static_cast<int>(std::floor(cu + hu)); ++u) {
      Eigen::Vector3f point;
      std::vector<float> zp;
      if (prompt_at(space, pv, view, u, v, &point, &zp)) latents.push_back(std::move(zp));
    }
  if (latents.empty()) return fail(why, "box prompt: the box's centre hits no surface of the map");
  std::vector<float> median(static_cast<std::size_t>(space.dim()));
  std::vector<float> column(latents.size());
  for (int c = 0; c < space.dim(); ++c) {
    for (std::size_t k = 0; k < latents.size(); ++k) column[k] = latents[k][static_cast<std::size_t>(c)];
    std::nth_element(column.begin(), column.begin() + static_cast<long>(column.size() / 2), column.end());
    median[static_cast<std::size_t>(c)] = column[column.size() / 2];
  }
  selected->assign(map.size(), 0);
  std::vector<Eigen::Vector3f> grid;  // surface points on a 3x3 grid over the inner half
  for (int gy = -1; gy <= 1; ++gy)
    for (int gx = -1; gx <= 1; ++gx) {
      Eigen::Vector3f point;
      std::vector<float> zp;
      if (prompt_at(space, pv, view, static_cast<int>(std::lround(cu + gx * hu)),
                    static_cast<int>(std::lround(cv + gy * hv)), &point, &zp)) {
        grid.push_back(point);
      }
    }
  const auto seeds_for = [&](float threshold) {
    std::vector<int> seeds;
    for (const Eigen::Vector3f& point : grid)
      for (int s : seeds_at(space, config, point, median.data(), threshold)) seeds.push_back(s);
    return seeds;
  };
  if (!select_region(space, neighbours, graph_->smooth, graph_->spatial, config, seeds_for, median.data(), selected)) {
    return fail(why, "box prompt: no Gaussian inside the box has the box's features");
  }
  return true;
}

bool select_by_points(const Rasterizer& rasterizer, const GaussianMap& map, const RenderView& view,
                      const std::vector<Eigen::Vector2d>& points, const PromptConfig& config,
                      std::vector<std::uint8_t>* selected, std::string* why) {
  return PromptSelector(map, config).select_by_points(rasterizer, view, points, selected, why);
}

bool select_by_box(const Rasterizer& rasterizer, const GaussianMap& map, const RenderView& view,
                   const BoxPrompt& box, const PromptConfig& config,
                   std::vector<std::uint8_t>* selected, std::string* why) {
  return PromptSelector(map, config).select_by_box(rasterizer, view, box, selected, why);
}

}  // namespace fslam::core
