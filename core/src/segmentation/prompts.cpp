#include "fslam/core/segmentation/prompts.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <queue>
#include <tuple>

#include "fslam/core/error.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "feature_space.hpp"

namespace fslam::core {
namespace {

using segmentation_detail::check_features;
using segmentation_detail::FeatureSpace;
using segmentation_detail::spatial_neighbours;

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

bool PromptSelector::select_by_boxes(const Rasterizer& rasterizer, const RenderView& view,
                                     const std::vector<BoxPrompt>& boxes, std::vector<std::uint8_t>* selected,
                                     std::string* why) const {
  selected->assign(map_.size(), 0);
  for (const BoxPrompt& box : boxes) {
    std::vector<std::uint8_t> one;
    if (!select_by_box(rasterizer, view, box, &one, why)) return false;
    for (std::size_t i = 0; i < one.size(); ++i) (*selected)[i] |= one[i];
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
