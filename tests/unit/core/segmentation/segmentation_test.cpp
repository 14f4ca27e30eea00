// Promptless clustering, prompts and label rendering on a constructed map whose objects are
// known: two touching panels with different latents, and a third panel with the first one's
// latent but apart in space.
#include <cmath>
#include <algorithm>
#include <map>
#include <memory>
#include <numeric>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "fslam/core/eval/image_metrics.hpp"
#include "fslam/core/segmentation/segmentation.hpp"
#include "panel_scene.hpp"

namespace fslam::core {
namespace {

struct Scene {
  GaussianMap map = test::panel_map();
  RenderView view;
  std::unique_ptr<Rasterizer> rasterizer = make_cpu_rasterizer();
  std::size_t left = 3000, right = 3000, far = 900;  // Gaussians per panel, in this order
  Scene() { view.camera = test::kPanelCamera; }
  cv::Mat truth() const { return test::panel_truth(); }
};

TEST(Segmentation, PromptlessFindsTheThreePanels) {
  Scene s;
  ASSERT_EQ(s.map.size(), s.left + s.right + s.far) << "panel sizes changed";
  PromptlessConfig config;
  config.min_instance_gaussians = 100;
  GaussianLabels labels;
  std::string why;
  ASSERT_TRUE(cluster_instances(s.map, config, &labels, &why)) << why;
  ASSERT_EQ(labels.count, 3);
  // Each panel is one instance, and the same-latent panels apart in space are two.
  auto label_of = [&](std::size_t begin, std::size_t end) {
    std::map<int, std::size_t> n;
    for (std::size_t i = begin; i < end; ++i) ++n[labels.label[i]];
    EXPECT_EQ(n.size(), 1u) << "panel [" << begin << ", " << end << ") is split";
    return n.begin()->first;
  };
  const int l = label_of(0, s.left), r = label_of(s.left, s.left + s.right),
            f = label_of(s.left + s.right, s.map.size());
  EXPECT_NE(l, r);
  EXPECT_NE(l, f);
  EXPECT_EQ(l, 0);  // numbered by size: the 50 x 60 panels first
  cv::Mat ids;
  ASSERT_TRUE(render_labels(*s.rasterizer, s.map, labels, s.view, 0.5f, &ids, &why)) << why;
  InstanceOverlap overlap;
  InstanceMatchConfig match;
  match.predicted_none = -1;
  ASSERT_TRUE(accumulate_instance_overlap(ids, s.truth(), match, &overlap, &why)) << why;
  const InstanceMatchResult score = match_instances(overlap);
  EXPECT_EQ(score.iou.size(), 3u);
  EXPECT_GT(score.miou, 0.9);
}

TEST(Segmentation, InstanceIdsCarryOverToALaterClustering) {
  Scene s;
  PromptlessConfig config;
  config.min_instance_gaussians = 100;
  GaussianLabels first, second;
  std::string why;
  ASSERT_TRUE(cluster_instances(s.map, config, &first, &why)) << why;
  // A later map version: the left panel lost half its Gaussians, so sizes (and the raw
  // numbering) change; carried ids must not.
  GaussianMap later = s.map;
  std::vector<std::uint8_t> keep(s.map.size(), 1);
  for (std::size_t i = 0; i < s.left; i += 2) keep[i] = 0;
  later.keep_only(keep);
  ASSERT_TRUE(cluster_instances(later, config, &second, &why)) << why;
  carry_instance_ids(s.map, first, later, 0.02f, &second);
  EXPECT_EQ(second.count, 3);
  std::size_t k = 0;
  for (std::size_t i = 0; i < s.map.size(); ++i) {
    if (!keep[i]) continue;
    EXPECT_EQ(second.label[k], first.label[i]) << "Gaussian " << i;
    ++k;
  }
}

TEST(Segmentation, APointPromptSelectsItsPanelOnly) {
  Scene s;
  PromptConfig config;
  std::vector<std::uint8_t> selected;
  std::string why;
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{50.0, 60.0}}, config, &selected, &why)) << why;
  std::size_t in_left = 0, elsewhere = 0;
  for (std::size_t i = 0; i < s.map.size(); ++i) {
    if (!selected[i]) continue;
    (i < s.left ? in_left : elsewhere) += 1;
  }
  EXPECT_GT(in_left, s.left * 95 / 100) << in_left << " of " << s.left;
  EXPECT_EQ(elsewhere, 0u) << "the far panel shares the latent but not the surface";
  cv::Mat mask;
  ASSERT_TRUE(render_selection(*s.rasterizer, s.map, selected, s.view, 0.5f, &mask, &why)) << why;
  EXPECT_GT(mask_iou(mask, s.truth(), 1), 0.9) << "mask " << cv::countNonZero(mask) << " px";
  // Off the map: a clear error.
  EXPECT_FALSE(select_by_points(*s.rasterizer, s.map, s.view, {{5.0, 5.0}}, config, &selected, &why));
  EXPECT_NE(why.find("hits no surface"), std::string::npos) << why;
}

TEST(Segmentation, ABoxPromptSelectsThePanelInside) {
  Scene s;
  PromptConfig config;
  std::vector<std::uint8_t> selected;
  std::string why;
  const BoxPrompt box{84.0, 35.0, 126.0, 85.0};  // inside the right panel
  ASSERT_TRUE(select_by_box(*s.rasterizer, s.map, s.view, box, config, &selected, &why)) << why;
  cv::Mat mask;
  ASSERT_TRUE(render_selection(*s.rasterizer, s.map, selected, s.view, 0.5f, &mask, &why)) << why;
  EXPECT_GT(mask_iou(mask, s.truth(), 2), 0.9);
  EXPECT_LT(mask_iou(mask, s.truth(), 1), 0.01);
}

// Several boxes select the union of their objects: here the left and right panels, never the
// far panel that shares the left one's latent.
TEST(Segmentation, SeveralBoxPromptsSelectTheUnionOfTheirObjects) {
  Scene s;
  const PromptSelector prompts(s.map, PromptConfig{});
  const BoxPrompt left{34.0, 35.0, 76.0, 85.0}, right{84.0, 35.0, 126.0, 85.0};
  std::vector<std::uint8_t> both, only_left, only_right;
  std::string why;
  ASSERT_TRUE(prompts.select_by_boxes(*s.rasterizer, s.view, {left, right}, &both, &why)) << why;
  ASSERT_TRUE(prompts.select_by_box(*s.rasterizer, s.view, left, &only_left, &why)) << why;
  ASSERT_TRUE(prompts.select_by_box(*s.rasterizer, s.view, right, &only_right, &why)) << why;
  ASSERT_EQ(both.size(), s.map.size());
  for (std::size_t i = 0; i < s.map.size(); ++i) {
    ASSERT_EQ(both[i], only_left[i] | only_right[i]) << "Gaussian " << i;
  }
  cv::Mat mask;
  ASSERT_TRUE(render_selection(*s.rasterizer, s.map, both, s.view, kMinObjectAlpha, &mask, &why)) << why;
  cv::Mat truth = s.truth(), panels = (truth == 1) | (truth == 2);
  cv::Mat panels_id(truth.size(), CV_32SC1, cv::Scalar(0));
  panels_id.setTo(1, panels);
  EXPECT_GT(mask_iou(mask, panels_id, 1), 0.9);
  EXPECT_LT(mask_iou(mask, truth, 3), 0.01) << "the far panel shares a latent, not a surface";
  // A box over nothing fails the whole request, naming the box's failure.
  const BoxPrompt empty_corner{0.0, 0.0, 20.0, 20.0};
  EXPECT_FALSE(prompts.select_by_boxes(*s.rasterizer, s.view, {right, empty_corner}, &both, &why));
  EXPECT_NE(why.find("hits no surface"), std::string::npos) << why;
}

// The label cache clusters each map version once, under the number it was first labelled as,
// and carries the ids of the version before; a version it cannot cluster leaves it unchanged.
TEST(Segmentation, TheLabelCacheClustersEachVersionOnceAndCarriesIds) {
  Scene s;
  InstanceLabelCache cache;
  const auto first_map = std::make_shared<const GaussianMap>(s.map);
  VersionLabels first, again, second, none;
  std::string why;
  EXPECT_FALSE(cache.holds(first_map));
  ASSERT_TRUE(cache.labels_for(1, first_map, &first, &why)) << why;
  ASSERT_EQ(first.labels->count, 3);
  EXPECT_TRUE(cache.holds(first_map));
  ASSERT_TRUE(cache.labels_for(2, first_map, &again, &why)) << why;
  EXPECT_EQ(again.labels, first.labels) << "clustered twice";
  EXPECT_EQ(again.version_number, 1u);
  // A later version whose left panel lost half its Gaussians: the raw numbering by size changes
  // (the right panel is now the largest), the carried ids do not.
  GaussianMap later = s.map;
  std::vector<std::uint8_t> keep(s.map.size(), 1);
  for (std::size_t i = 0; i < s.left; i += 2) keep[i] = 0;
  later.keep_only(keep);
  const auto later_map = std::make_shared<const GaussianMap>(later);
  ASSERT_TRUE(cache.labels_for(3, later_map, &second, &why)) << why;
  EXPECT_EQ(second.version_number, 3u);
  EXPECT_EQ(second.map, later_map);
  EXPECT_FALSE(cache.holds(first_map));
  ASSERT_EQ(second.labels->label.size(), later.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < s.map.size(); ++i) {
    if (!keep[i]) continue;
    EXPECT_EQ(second.labels->label[k], first.labels->label[i]) << "Gaussian " << i;
    ++k;
  }
  GaussianMap bare = s.map;
  bare.feature_dim = 0;
  bare.features.clear();
  EXPECT_FALSE(cache.labels_for(4, std::make_shared<const GaussianMap>(bare), &none, &why));
  EXPECT_NE(why.find("no features"), std::string::npos) << why;
  EXPECT_TRUE(cache.holds(later_map));
}

// A narrow strip beside a wide panel whose latent is close to the strip's (RMS difference about
// 0.8 after standardising, inside the prompts' threshold range), and a third panel far in space
// and latent that sets the spread. `strip_z`: the strip's plane; the panel's is z = 2 m.
struct StripScene {
  explicit StripScene(float strip_z) {
    map.sh_degree = 0;
    map.feature_dim = test::kPanelFeatureDim;
    std::mt19937 rng(3);
    std::vector<float> wide(test::kPanelFeatureDim, 0.0f), strip(wide), other(wide);
    strip[0] = 1.0f;
    other[2] = 3.0f;
    test::add_panel(&map, -0.5f, 0.0f, wide, &rng);           // 3000 Gaussians, u in [29.5, 79.5)
    test::add_panel(&map, 0.0f, 0.1f, strip, &rng, strip_z);  // 600, u from 79.5, about 10 px wide
    test::add_panel(&map, 0.6f, 0.75f, other, &rng);          // 900, far
    view.camera = test::kPanelCamera;
  }
  std::size_t count(const std::vector<std::uint8_t>& selected, std::size_t from, std::size_t to) const {
    return static_cast<std::size_t>(std::count(selected.begin() + static_cast<long>(from),
                                                selected.begin() + static_cast<long>(to), 1));
  }
  GaussianMap map;
  RenderView view;
  std::unique_ptr<Rasterizer> rasterizer = make_cpu_rasterizer();
  const std::size_t wide_n = 3000, strip_n = 600;
};

// The strip stands 2.5 cm off the panel, as a picture on a wall: a fixed loose threshold floods
// the panel; the per-prompt threshold stops before the step where the region jumps from the
// strip across that step to both.
TEST(Segmentation, APromptStopsBeforeTheThresholdWhereItsRegionJumps) {
  StripScene s(1.975f);
  ASSERT_EQ(s.map.size(), s.wide_n + s.strip_n + 900);
  std::string why;
  std::vector<std::uint8_t> selected;

  PromptConfig fixed;  // the premise: at the loosest threshold the strip's region floods the panel
  fixed.adaptive_threshold = false;
  fixed.graph.feature_threshold = fixed.max_threshold;
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{85.0, 60.0}}, fixed, &selected, &why)) << why;
  EXPECT_GT(s.count(selected, 0, s.wide_n), s.wide_n / 2);

  PromptConfig adaptive;
  ASSERT_TRUE(adaptive.adaptive_threshold && adaptive.smooth_growth);
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{85.0, 60.0}}, adaptive, &selected, &why)) << why;
  EXPECT_GT(s.count(selected, s.wide_n, s.wide_n + s.strip_n), s.strip_n * 95 / 100);
  EXPECT_LT(s.count(selected, 0, s.wide_n), s.wide_n / 100);  // at most a few along the step
  EXPECT_EQ(s.count(selected, s.wide_n + s.strip_n, s.map.size()), 0u);

  // Without a jump (one uniform panel) the loosest threshold stands: the whole panel.
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{50.0, 60.0}}, adaptive, &selected, &why)) << why;
  EXPECT_GT(s.count(selected, 0, s.wide_n), s.wide_n * 95 / 100);
}

// The same strip flush with the panel, as a texture patch on a wall: the region's jump from the
// strip to the panel stays on one flat surface, so it is no leak and the prompt selects the
// whole surface; judging every added Gaussian (smooth_growth off) cuts it at the patch.
TEST(Segmentation, GrowthAlongOneFlatSurfaceIsNoLeak) {
  StripScene s(2.0f);
  std::string why;
  std::vector<std::uint8_t> selected;

  PromptConfig count_all;
  count_all.smooth_growth = false;
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{85.0, 60.0}}, count_all, &selected, &why)) << why;
  EXPECT_EQ(s.count(selected, 0, s.wide_n), 0u);

  PromptConfig smooth;
  ASSERT_TRUE(smooth.smooth_growth);
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{85.0, 60.0}}, smooth, &selected, &why)) << why;
  EXPECT_GT(s.count(selected, s.wide_n, s.wide_n + s.strip_n), s.strip_n * 95 / 100);
  EXPECT_GT(s.count(selected, 0, s.wide_n), s.wide_n * 95 / 100);
  EXPECT_EQ(s.count(selected, s.wide_n + s.strip_n, s.map.size()), 0u);  // apart in space and latent

  // Round Gaussians have no normal to trust: every step between them counts as a possible leak.
  for (std::size_t i = 0; i < s.map.size(); ++i) s.map.log_scales[i * 3 + 2] = s.map.log_scales[i * 3];
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{85.0, 60.0}}, smooth, &selected, &why)) << why;
  EXPECT_LT(s.count(selected, 0, s.wide_n), s.wide_n / 100);
}

// Across the strip's 2.5 cm step a Gaussian must be within bend_ratio x the threshold: at a
// threshold loose enough to flood the panel, the strip standing off it is selected alone, while
// the same strip flush with the panel still grows over it (one flat surface: no bend to cross).
TEST(Segmentation, GrowthAcrossAStepNeedsACloserLatent) {
  PromptConfig config;
  config.adaptive_threshold = false;
  config.graph.feature_threshold = 0.85f;
  config.bend_ratio = 1.0f;
  std::string why;
  std::vector<std::uint8_t> selected;
  StripScene off(1.975f), flush(2.0f);
  // The premise: ignoring the step, this threshold floods the panel from the strip.
  ASSERT_TRUE(select_by_points(*off.rasterizer, off.map, off.view, {{85.0, 60.0}}, config, &selected, &why)) << why;
  ASSERT_GT(off.count(selected, 0, off.wide_n), off.wide_n / 2);

  config.bend_ratio = 0.75f;
  ASSERT_TRUE(select_by_points(*off.rasterizer, off.map, off.view, {{85.0, 60.0}}, config, &selected, &why)) << why;
  EXPECT_GT(off.count(selected, off.wide_n, off.wide_n + off.strip_n), off.strip_n * 95 / 100);
  EXPECT_LT(off.count(selected, 0, off.wide_n), off.wide_n / 100);

  ASSERT_TRUE(select_by_points(*flush.rasterizer, flush.map, flush.view, {{85.0, 60.0}}, config, &selected, &why))
      << why;
  EXPECT_GT(flush.count(selected, 0, flush.wide_n), flush.wide_n * 95 / 100);
}

// The refinement in 3D: every 7th Gaussian of the left panel is a texture speck whose latent is
// far from both panels', and every 11th is nearly transparent (below the graph's min_opacity).
// Growth leaves both out; the refinement takes in what is surrounded by the object, and nothing
// of the touching right panel or of the far panel with the left one's latent.
TEST(Segmentation, TheRefinementIn3DClosesTheHolesSpecksLeaveInAnObject) {
  Scene s;
  std::vector<float> speck(static_cast<std::size_t>(test::kPanelFeatureDim), 0.0f);
  speck[6] = 3.0f;
  std::vector<std::size_t> specks, faint;
  for (std::size_t i = 0; i < s.left; ++i) {
    if (i % 7 == 3) {
      std::copy(speck.begin(), speck.end(), s.map.features.begin() + static_cast<long>(i * test::kPanelFeatureDim));
      specks.push_back(i);
    } else if (i % 11 == 5) {
      s.map.opacity_logits[i] = -3.0f;  // opacity 0.05
      faint.push_back(i);
    }
  }
  auto count = [](const std::vector<std::uint8_t>& selected, const std::vector<std::size_t>& which) {
    std::size_t n = 0;
    for (std::size_t i : which) n += selected[i];
    return n;
  };
  std::string why;
  std::vector<std::uint8_t> selected;
  PromptConfig none;
  none.fill_rounds = 0;
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{50.0, 60.0}}, none, &selected, &why)) << why;
  EXPECT_EQ(count(selected, specks), 0u) << "the premise: growth leaves the specks out";
  EXPECT_EQ(count(selected, faint), 0u);

  PromptConfig refined;
  ASSERT_GT(refined.fill_rounds, 0);
  ASSERT_TRUE(select_by_points(*s.rasterizer, s.map, s.view, {{50.0, 60.0}}, refined, &selected, &why)) << why;
  EXPECT_GT(count(selected, specks), specks.size() * 98 / 100) << count(selected, specks) << " of " << specks.size();
  EXPECT_GT(count(selected, faint), faint.size() * 98 / 100) << count(selected, faint) << " of " << faint.size();
  const auto in = [&](std::size_t from, std::size_t to) {
    return std::count(selected.begin() + static_cast<long>(from), selected.begin() + static_cast<long>(to), 1);
  };
  EXPECT_GT(in(0, s.left), static_cast<long>(s.left * 99 / 100));
  EXPECT_EQ(in(s.left, s.left + s.right), 0) << "the touching panel's edge has most neighbours outside";
  EXPECT_EQ(in(s.left + s.right, s.map.size()), 0) << "the far panel is 10 cm away";

  PromptConfig bad;
  bad.fill_rounds = -1;
  EXPECT_FALSE(bad.is_valid(&why));
  bad.fill_rounds = 2;
  bad.fill_fraction = 0.0f;  // would take in every neighbour of the object
  EXPECT_FALSE(bad.is_valid(&why));
}

// Steps of a prompt's growth: the region's count at thresholds 0.6, 0.65, .., 1.0, what each
// step adds off the prompted surface and that addition's contrast (RMS latent difference of its
// mean to the region's, / the next threshold), as the synthetic room of seed 1 gave them.
std::vector<PromptStep> steps(const std::vector<std::size_t>& counts, const std::vector<std::size_t>& leaked,
                              const std::vector<float>& contrast) {
  std::vector<PromptStep> out(counts.size());
  for (std::size_t k = 0; k < counts.size(); ++k) out[k] = {counts[k], leaked[k], contrast[k]};
  return out;
}

TEST(Segmentation, APromptStopsBeforeTheFirstStepThatAddsALargeDifferentLookingSurface) {
  const PromptConfig config;
  // A picture: modest growth, then the wall behind it begins to leak in at the step from 4 to 5
  // (x1.5, contrast 0.80) and floods in at the next (x10, 0.90). The first leak counts.
  // (On that click: IoU 0.81 at threshold 3, 0.72 at 4, 0.49 at 5, 0.08 at 6.)
  const auto picture = steps({143, 165, 205, 227, 279, 423, 4215, 4402, 4560},
                             {11, 33, 18, 49, 141, 3804, 193, 156, 0},
                             {0.47f, 0.47f, 0.51f, 0.70f, 0.80f, 0.90f, 0.26f, 0.18f, 0.0f});
  EXPECT_EQ(pick_prompt_threshold(picture, config), 4u);
  // A wall: its region more than doubles at several steps, but every addition looks like the
  // wall (contrast <= 0.46): the rest of the wall, reached through its texture, not a leak.
  // (On that click: IoU 0.18 at threshold 0, 0.50 at 1, 0.83 at 8.)
  const auto wall = steps({38, 125, 277, 339, 528, 913, 1176, 1308, 1381},
                          {86, 161, 62, 188, 385, 262, 131, 70, 0},
                          {0.37f, 0.46f, 0.26f, 0.42f, 0.40f, 0.42f, 0.32f, 0.33f, 0.0f});
  EXPECT_EQ(pick_prompt_threshold(wall, config), 8u);
  // A cabinet: 33 -> 1006 at the first step is the cabinet itself, reached from a region too
  // small to count however different it looks (contrast 1.13).
  const auto cabinet = steps({33, 1006, 1039, 1067, 1099, 1120, 1133, 1147, 1164},
                             {975, 40, 28, 32, 21, 13, 14, 17, 0},
                             {1.13f, 0.35f, 0.24f, 0.47f, 0.42f, 0.45f, 0.47f, 0.50f, 0.0f});
  EXPECT_EQ(pick_prompt_threshold(cabinet, config), 8u);
  PromptConfig no_minimum = config;
  no_minimum.min_jump_region = 0;
  EXPECT_EQ(pick_prompt_threshold(cabinet, no_minimum), 0u) << "without the minimum region";
  // A book: the table it lies on floods in at the last step (x1.96, contrast 0.65; IoU 0.77 at
  // threshold 7, 0.47 at 8).
  const auto book = steps({112, 120, 129, 140, 147, 161, 174, 182, 357}, {8, 9, 11, 7, 14, 13, 8, 175, 0},
                          {0.60f, 0.68f, 0.59f, 0.71f, 0.68f, 0.67f, 0.59f, 0.65f, 0.0f});
  EXPECT_EQ(pick_prompt_threshold(book, config), 7u);
  PromptConfig bigger_jump = config;
  bigger_jump.min_jump = 2.0f;  // a jump smaller than min_jump is growth, not a leak
  EXPECT_EQ(pick_prompt_threshold(book, bigger_jump), 8u);
  PromptConfig more_contrast = config;
  more_contrast.min_contrast = 0.7f;  // an addition nearer the region's mean is the same object
  EXPECT_EQ(pick_prompt_threshold(book, more_contrast), 8u);
  // The first leak counts, not the largest: a leak into the floor, then the wall beyond it.
  const auto chain = steps({500, 520, 1100, 1150, 4000}, {10, 580, 40, 2850, 0}, {0.3f, 0.8f, 0.3f, 0.9f, 0.0f});
  EXPECT_EQ(pick_prompt_threshold(chain, config), 1u);
}

TEST(Segmentation, AnAdaptivePromptConfigNeedsAnOrderedRange) {
  PromptConfig config;
  std::string why;
  EXPECT_TRUE(config.is_valid(&why)) << why;
  config.max_threshold = 0.5f * config.min_threshold;
  EXPECT_FALSE(config.is_valid(&why));
  config.adaptive_threshold = false;  // the range is not used then
  EXPECT_TRUE(config.is_valid(&why)) << why;
  config.adaptive_threshold = true;
  config.max_threshold = 1.0f;
  config.min_jump = 1.0f;
  EXPECT_FALSE(config.is_valid(&why));
  config.min_jump = 2.0f;
  config.min_contrast = -0.1f;
  EXPECT_FALSE(config.is_valid(&why));
  config.min_contrast = 0.55f;
  config.smooth_max_angle_deg = 90.0f;  // every pair would be "smooth"
  EXPECT_FALSE(config.is_valid(&why));
  config.smooth_max_angle_deg = 20.0f;
  config.flat_ratio = 0.0f;
  EXPECT_FALSE(config.is_valid(&why));
  config.flat_ratio = 0.5f;
  config.bend_ratio = 1.5f;  // would make a bend easier to cross than a flat surface
  EXPECT_FALSE(config.is_valid(&why));
  config.smooth_growth = false;  // not used then
  EXPECT_TRUE(config.is_valid(&why)) << why;
}

TEST(Segmentation, AMapWithoutFeaturesIsAClearError) {
  Scene s;
  s.map.feature_dim = 0;
  s.map.features.clear();
  GaussianLabels labels;
  std::string why;
  EXPECT_FALSE(cluster_instances(s.map, PromptlessConfig{}, &labels, &why));
  EXPECT_NE(why.find("no features"), std::string::npos) << why;
}

// Pixels predicted as no instance are misses of the ground truth, never a matched instance.
TEST(SegmentationMetrics, PixelsOfNoPredictionMatchNothing) {
  cv::Mat truth(1, 8, CV_32SC1), predicted(1, 8, CV_32SC1);
  const int t[8] = {1, 1, 1, 1, 2, 2, 0, 0}, p[8] = {5, 5, -1, -1, -1, -1, 7, -1};
  for (int u = 0; u < 8; ++u) {
    truth.at<int>(0, u) = t[u];
    predicted.at<int>(0, u) = p[u];
  }
  InstanceOverlap overlap;
  InstanceMatchConfig match;
  match.predicted_none = -1;
  std::string why;
  ASSERT_TRUE(accumulate_instance_overlap(predicted, truth, match, &overlap, &why)) << why;
  const InstanceMatchResult r = match_instances(overlap);
  // 1 <-> 5: IoU 2/4; 2 is covered by nothing (7 lies on ignored pixels): IoU 0. Without
  // predicted_none, -1 would have matched instance 2 with IoU 2/6.
  EXPECT_NEAR(r.iou.at(1), 0.5, 1e-12);
  EXPECT_NEAR(r.iou.at(2), 0.0, 1e-12);
  EXPECT_NEAR(r.miou, 0.25, 1e-12);
  EXPECT_EQ(r.gt_to_predicted.count(2), 0u);
}

}  // namespace
}  // namespace fslam::core
