// The online mapper on the synthetic room: Gaussians from keyframes, training on the paper's
// total loss, held-out quality, insertion only where the map is unexplained, feature channels,
// pruning bounds and bad input.
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "fslam/core/eval/image_metrics.hpp"
#include "fslam/core/io/keyframe_images_file.hpp"
#include "fslam/core/mapping/mapper.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"
#include "fslam/core/tracking/keyframe_policy.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

struct Fixture {
  SyntheticRoom room = make_room(3);
  Trajectory trajectory;
  PinholeCamera camera = synth_default_camera().scaled(0.25);  // 160x120: fast enough for CI
  Fixture() {
    SynthOptions options;
    options.frames = 40;
    trajectory = make_trajectory(room, options);
  }
  MapperKeyframe keyframe(std::size_t k) const {
    const SynthView view = render_view(room, camera, trajectory[k].T_world_camera);
    MapperKeyframe kf;
    kf.frame_id = static_cast<std::int64_t>(k);
    kf.T_world_camera = trajectory[k].T_world_camera;
    kf.camera = camera;
    kf.colour = view.colour;
    kf.depth = view.depth;
    return kf;
  }
};

MapperConfig small_config() {
  MapperConfig config;
  config.training_scale = 1.0;
  config.insert_stride = 1;
  config.feature_dim = 0;
  config.iterations_per_keyframe = 30;
  return config;
}

struct Quality {
  double psnr = 0, depth_l1_cm = 0;
};

Quality render_quality(const Mapper& mapper, const Fixture& f, std::size_t k) {
  const MapperKeyframe truth = f.keyframe(k);
  RenderView view;
  view.camera = f.camera;
  view.T_camera_world = truth.T_world_camera.inverse();
  RenderResult r;
  std::string why;
  auto rasterizer = make_cpu_rasterizer();
  EXPECT_TRUE(rasterizer->forward(mapper.map(), view, RenderSettings{}, &r, &why)) << why;
  cv::Mat rgb(f.camera.height, f.camera.width, CV_8UC3), median(f.camera.height, f.camera.width, CV_32FC1);
  for (int v = 0; v < f.camera.height; ++v)
    for (int u = 0; u < f.camera.width; ++u) {
      for (int c = 0; c < 3; ++c)
        rgb.at<cv::Vec3b>(v, u)[c] = cv::saturate_cast<uchar>(255.0f * r.colour.at(c, v, u) + 0.5f);
      median.at<float>(v, u) = r.median_depth.at(0, v, u);
    }
  Quality q;
  DepthL1Result depth;
  EXPECT_TRUE(compute_psnr(rgb, truth.colour, ImageMetricsConfig{}, &q.psnr, &why)) << why;
  EXPECT_TRUE(compute_depth_l1(median, truth.depth, cv::Mat(), &depth, &why)) << why;
  q.depth_l1_cm = depth.l1_cm;
  return q;
}

TEST(Mapper, BuildsAMapThatRendersHeldOutViews) {
  Fixture f;
  Mapper mapper(small_config(), make_cpu_rasterizer());
  std::string why;
  for (std::size_t k : {0u, 10u, 20u, 30u}) {
    RefinementStats stats;
    ASSERT_TRUE(mapper.add_keyframe(f.keyframe(k), &stats, &why)) << why;
    EXPECT_EQ(stats.iterations, 30);
    EXPECT_GT(stats.inserted, 0u);
  }
  ASSERT_TRUE(mapper.optimise(60, &why)) << why;
  EXPECT_EQ(mapper.versions().latest()->size(), mapper.map().size());
  // Frames between the keyframes were never trained on.
  for (std::size_t k : {5u, 15u, 25u}) {
    const Quality q = render_quality(mapper, f, k);
    EXPECT_GT(q.psnr, 20.0) << "held-out frame " << k;
    EXPECT_LT(q.depth_l1_cm, 5.0) << "held-out frame " << k;
  }
}

// A refinement told to stop (a server shutting down) publishes what it did and says so.
TEST(Mapper, RefinementStopsWhenToldAndPublishes) {
  Fixture f;
  Mapper mapper(small_config(), make_cpu_rasterizer());
  std::string why;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(0), nullptr, &why)) << why;
  const std::uint64_t version = mapper.versions().version_number();
  std::atomic<bool> stop{true};
  EXPECT_FALSE(mapper.refine(50, &why, nullptr, &stop));
  EXPECT_NE(why.find("stopped after 0 of 50 steps"), std::string::npos) << why;
  EXPECT_EQ(mapper.versions().version_number(), version + 1);
  stop = false;
  int reported = 0;
  EXPECT_TRUE(mapper.refine(20, &why, [&](int done, int) { reported = done; }, &stop)) << why;
  EXPECT_EQ(reported, 20);
}

// A map saved with its keyframe images and loaded into a fresh mapper refines as the mapper that
// built it would: the images come back through keyframe_images.bin at the kept scale, the
// restored keyframes are renumbered -n..-1, and refinement on them lifts held-out quality.
TEST(Mapper, RestoredKeyframeImagesRefineALoadedMap) {
  Fixture f;  // 160x120 input
  MapperConfig config = small_config();
  config.training_scale = 0.5;  // 80x60 training views, images kept at 160x120
  config.refine_scale = 1.0;
  config.iterations_per_keyframe = 10;
  Mapper built(config, make_cpu_rasterizer());
  std::string why;
  const std::vector<std::size_t> keyframes = {0, 10, 20, 30};
  for (std::size_t k : keyframes) ASSERT_TRUE(built.add_keyframe(f.keyframe(k), nullptr, &why)) << why;
  const auto images = built.published_keyframe_images();
  ASSERT_EQ(images->size(), keyframes.size());
  for (std::size_t i = 0; i < keyframes.size(); ++i) {
    EXPECT_EQ((*images)[i].frame_id, static_cast<std::int64_t>(keyframes[i]));
    EXPECT_EQ((*images)[i].colour.cols, 160);
    EXPECT_LT(((*images)[i].T_world_camera.matrix() - f.trajectory[keyframes[i]].T_world_camera.matrix()).norm(), 1e-9);
  }
  const auto dir = test::fresh_temp_dir("kfi_refine");
  const std::string path = (dir / "keyframe_images.bin").string();
  ASSERT_TRUE(write_keyframe_images_file(path, *images, &why)) << why;
  std::vector<KeyframeImages> saved;
  ASSERT_TRUE(read_keyframe_images_file(path, &saved, &why)) << why;

  Mapper loaded(config, make_cpu_rasterizer());
  ASSERT_TRUE(loaded.set_map(*built.versions().latest(), &why)) << why;
  const auto mean_quality = [&](const Mapper& m) {
    Quality mean;
    for (std::size_t k : {5u, 15u, 25u}) {
      const Quality q = render_quality(m, f, k);
      mean.psnr += q.psnr / 3.0;
      mean.depth_l1_cm += q.depth_l1_cm / 3.0;
    }
    return mean;
  };
  const Quality before = mean_quality(loaded);
  ASSERT_TRUE(loaded.restore_keyframes(saved, &why)) << why;
  EXPECT_EQ(loaded.keyframe_ids(), (std::vector<std::int64_t>{-4, -3, -2, -1}));
  EXPECT_FALSE(loaded.restore_keyframes(saved, &why)) << "restoring twice";
  ASSERT_TRUE(loaded.refine(80, &why)) << why;
  ASSERT_TRUE(built.refine(80, &why)) << why;
  const Quality after = mean_quality(loaded), original = mean_quality(built);
  std::printf("held-out: loaded %.2f dB %.2f cm, refined after loading %.2f dB %.2f cm, refined by the "
              "mapper that built it %.2f dB %.2f cm\n", before.psnr, before.depth_l1_cm, after.psnr,
              after.depth_l1_cm, original.psnr, original.depth_l1_cm);
  EXPECT_GT(after.psnr, before.psnr + 0.5);
  EXPECT_GT(after.psnr, original.psnr - 0.5);
  EXPECT_LT(after.depth_l1_cm, original.depth_l1_cm + 0.3);

  // Images of another size than the input camera at the kept scale are refused, saying so.
  Mapper other(config, make_cpu_rasterizer());
  std::vector<KeyframeImages> small = saved;
  cv::resize(saved[0].colour, small[0].colour, cv::Size(80, 60));
  EXPECT_FALSE(other.restore_keyframes(small, &why));
  EXPECT_NE(why.find("must be 160x120"), std::string::npos) << why;
}

// Refinement at refine_scale recovers detail that training at training_scale alone cannot,
// measured on held-out views at the input size.
TEST(Mapper, RefinementAtRefineScaleSharpensTheInputSizeRender) {
  Fixture f;  // 160x120 input
  auto build = [&](double refine_scale) {
    MapperConfig config = small_config();
    config.training_scale = 0.5;  // 80x60 training views
    config.refine_scale = refine_scale;
    auto mapper = std::make_unique<Mapper>(config, make_cpu_rasterizer());
    std::string why;
    for (std::size_t k : {0u, 10u, 20u, 30u}) {
      RefinementStats stats;
      EXPECT_TRUE(mapper->add_keyframe(f.keyframe(k), &stats, &why)) << why;
    }
    EXPECT_TRUE(mapper->refine(60, &why)) << why;
    Quality mean;
    for (std::size_t k : {5u, 15u, 25u}) {
      const Quality q = render_quality(*mapper, f, k);
      mean.psnr += q.psnr / 3.0;
      mean.depth_l1_cm += q.depth_l1_cm / 3.0;
    }
    return mean;
  };
  const Quality coarse = build(0.0), fine = build(1.0);
  std::printf("held-out at 160x120 after refinement: at 80x60 %.2f dB %.2f cm, at 160x120 %.2f dB "
              "%.2f cm\n", coarse.psnr, coarse.depth_l1_cm, fine.psnr, fine.depth_l1_cm);
  EXPECT_GT(fine.psnr, coarse.psnr + 0.5);
  EXPECT_LT(fine.depth_l1_cm, coarse.depth_l1_cm + 0.1);
}

TEST(Mapper, OptimisationLowersTheLoss) {
  Fixture f;
  MapperConfig config = small_config();
  config.iterations_per_keyframe = 1;
  Mapper mapper(config, make_cpu_rasterizer());
  std::string why;
  RefinementStats first;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(0), &first, &why)) << why;
  const Quality before = render_quality(mapper, f, 0);
  ASSERT_TRUE(mapper.optimise(80, &why)) << why;
  const Quality after = render_quality(mapper, f, 0);
  EXPECT_GT(after.psnr, before.psnr + 1.0);
  EXPECT_GT(first.last_losses.rgb_l1, 0.0);
  EXPECT_GT(first.last_losses.depth_l1, 0.0);
  EXPECT_GT(first.last_losses.normal_expected, 0.0);
  EXPECT_GT(first.last_losses.thin, 0.0);
}

TEST(Mapper, InsertsOnlyWhereTheMapDoesNotExplainTheKeyframe) {
  Fixture f;
  MapperConfig config = small_config();
  // Without pruning: a pruned Gaussian leaves a hole that the next keyframe refills.
  config.prune_percentile_mapping = config.prune_percentile_tracking = 0.0;
  Mapper mapper(config, make_cpu_rasterizer());
  std::string why;
  RefinementStats a, b;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(12), &a, &why)) << why;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(12), &b, &why)) << why;
  EXPECT_GT(a.inserted, 5000u);
  EXPECT_LT(b.inserted, a.inserted / 10) << "the same view again is already explained";
}

// mapper.max_gaussians bounds the map: insertion stops there and says so; the next keyframe of
// new surface adds nothing.
TEST(Mapper, InsertionStopsAtMaxGaussians) {
  Fixture f;
  MapperConfig config = small_config();
  config.prune_percentile_mapping = config.prune_percentile_tracking = 0.0;
  config.min_opacity = 0.0f;
  config.max_gaussians = 3000;
  Mapper mapper(config, make_cpu_rasterizer());
  std::string why;
  RefinementStats a, b;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(12), &a, &why)) << why;
  EXPECT_EQ(a.inserted, 3000u) << "the unbounded mapper inserts over 5000 here";
  EXPECT_TRUE(a.at_capacity);
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(30), &b, &why)) << why;
  EXPECT_EQ(b.inserted, 0u);
  EXPECT_TRUE(b.at_capacity);
  EXPECT_LE(mapper.map().size(), 3000u);
}

// A keyframe that revisits a stored keyframe's pose (within revisit_translation and
// revisit_rotation_deg) takes its place; one from elsewhere is added; 0 keeps every keyframe.
TEST(Mapper, RevisitingKeyframeReplacesTheStoredOne) {
  Fixture f;
  MapperConfig config = small_config();
  config.iterations_per_keyframe = 2;
  std::string why;
  const auto stored_after = [&](const MapperConfig& c, std::vector<std::size_t> frames, bool* replaced) {
    Mapper mapper(c, make_cpu_rasterizer());
    RefinementStats s;
    for (std::size_t k : frames) EXPECT_TRUE(mapper.add_keyframe(f.keyframe(k), &s, &why)) << why;
    *replaced = s.replaced_keyframe;
    return mapper.keyframe_count();
  };
  const double step = pose_motion(f.trajectory[12].T_world_camera, f.trajectory[30].T_world_camera).translation;
  ASSERT_GT(step, config.revisit_translation) << "frames 12 and 30 must be apart";
  bool replaced = false;
  EXPECT_EQ(stored_after(config, {12, 30, 12}, &replaced), 2u);
  EXPECT_TRUE(replaced);
  EXPECT_EQ(stored_after(config, {12, 30}, &replaced), 2u);
  EXPECT_FALSE(replaced);
  config.revisit_translation = 0.0;
  EXPECT_EQ(stored_after(config, {12, 30, 12}, &replaced), 3u);
  EXPECT_FALSE(replaced);
}

// Past max_stored_keyframes the stored keyframe whose neighbours in time are closest makes room:
// the first and the newest stay, the count holds at the cap.
TEST(Mapper, StoredKeyframesStopAtTheirCapKeepingTheWidestSpread) {
  Fixture f;
  MapperConfig config = small_config();
  config.iterations_per_keyframe = 1;
  config.revisit_translation = 0.0;  // every keyframe would be kept
  config.max_stored_keyframes = 4;
  Mapper mapper(config, make_cpu_rasterizer());
  std::string why;
  RefinementStats s;
  // Frame 20 three times, as keyframes 20, 101 and 102: 101 sits between two copies of its own
  // pose, so dropping it leaves no gap; any other interior keyframe would leave one.
  const auto add = [&](std::size_t frame, std::int64_t id) {
    MapperKeyframe kf = f.keyframe(frame);
    kf.frame_id = id;
    return mapper.add_keyframe(kf, &s, &why);
  };
  ASSERT_TRUE(add(0, 0) && add(20, 20) && add(20, 101) && add(20, 102)) << why;
  EXPECT_FALSE(s.dropped_keyframe);
  ASSERT_TRUE(add(39, 39)) << why;
  EXPECT_TRUE(s.dropped_keyframe);
  EXPECT_EQ(mapper.keyframe_ids(), (std::vector<std::int64_t>{0, 20, 102, 39}));
  ASSERT_TRUE(add(10, 10)) << why;
  EXPECT_EQ(mapper.keyframe_count(), 4u);
  EXPECT_EQ(mapper.keyframe_ids().front(), 0);
  EXPECT_EQ(mapper.keyframe_ids().back(), 10);
  config.max_stored_keyframes = 2;
  EXPECT_FALSE(config.is_valid(&why));
  EXPECT_NE(why.find("max_stored_keyframes"), std::string::npos) << why;
}

TEST(Mapper, ImportancePruningRemovesAtMostThePercentileOfNewGaussians) {
  Fixture f;
  MapperConfig config = small_config();
  config.prune_percentile_tracking = 0.1;
  config.prune_percentile_mapping = 0.3;
  Mapper mapper(config, make_cpu_rasterizer());
  std::string why;
  RefinementStats s;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(0), &s, &why)) << why;
  EXPECT_TRUE(s.mapping_keyframe);  // the first keyframe
  EXPECT_GT(s.pruned_importance, 0u);
  EXPECT_LE(s.pruned_importance, static_cast<std::size_t>(0.3 * s.inserted) + 1);
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(2), &s, &why)) << why;
  EXPECT_FALSE(s.mapping_keyframe);  // a few centimetres from the first
  EXPECT_LE(s.pruned_importance, static_cast<std::size_t>(0.1 * s.inserted) + 1);
}

// Synthetic feature maps: each object instance gets its own 3-vector; the rendered features of
// a trained map must approach them.
TEST(Mapper, LearnsFeatureChannels) {
  Fixture f;
  MapperConfig config = small_config();
  config.feature_dim = 3;
  config.iterations_per_keyframe = 1;
  Mapper mapper(config, make_cpu_rasterizer());
  const SynthView view = render_view(f.room, f.camera, f.trajectory[0].T_world_camera);
  MapperKeyframe kf = f.keyframe(0);
  kf.feature_target = PlanarImage(f.camera.width, f.camera.height, 3);
  for (int v = 0; v < f.camera.height; ++v)
    for (int u = 0; u < f.camera.width; ++u) {
      const int id = view.instance_label.at<std::uint16_t>(v, u);
      for (int c = 0; c < 3; ++c) kf.feature_target.at(c, v, u) = std::sin(1.7f * id + 2.1f * c);
    }
  std::string why;
  ASSERT_TRUE(mapper.add_keyframe(kf, nullptr, &why)) << why;
  auto feature_error = [&](const Mapper& m) {
    RenderView rv;
    rv.camera = f.camera;
    rv.T_camera_world = kf.T_world_camera.inverse();
    RenderResult r;
    EXPECT_TRUE(make_cpu_rasterizer()->forward(m.map(), rv, RenderSettings{}, &r, &why));
    double loss = 0;
    EXPECT_TRUE(l1_loss(r.features, kf.feature_target, nullptr, 1.0, &loss, nullptr, &why));
    return loss;
  };
  const double before = feature_error(mapper);
  ASSERT_TRUE(mapper.optimise(60, &why)) << why;
  const double after = feature_error(mapper);
  // Initialised from the target itself, so it starts close; training must make it closer still.
  EXPECT_LT(after, before);
  EXPECT_LT(after, 0.15);

  // Trained at half size, then refined at the input size against the target resampled to it.
  config.training_scale = 0.5;
  config.refine_scale = 1.0;
  Mapper refined(config, make_cpu_rasterizer());
  MapperKeyframe half = kf;
  half.feature_target = PlanarImage(f.camera.width / 2, f.camera.height / 2, 3);
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < half.feature_target.height; ++v)
      for (int u = 0; u < half.feature_target.width; ++u)
        half.feature_target.at(c, v, u) = kf.feature_target.at(c, 2 * v, 2 * u);
  ASSERT_TRUE(refined.add_keyframe(half, nullptr, &why)) << why;
  const double coarse = feature_error(refined);
  ASSERT_TRUE(refined.refine(60, &why)) << why;
  EXPECT_LT(feature_error(refined), coarse);
}

// A keyframe with the decoded L_feat's inputs: a pyramid whose channels are functions of the
// surface's instance (6 channels at half size, 4 at full size), phi(u) as the new Gaussians'
// initial latents, and the observation at 1024 sample pixels, for heads of `ae_config`'s shapes.
struct DecodedKeyframe {
  FeatureAutoencoder pretrained;
  FeaturePyramid pyramid;
  MapperKeyframe keyframe;
};

FeatureAutoencoderConfig small_autoencoder_config() {
  FeatureAutoencoderConfig ae_config;
  ae_config.level_channels = {6, 4};
  ae_config.latent_dim = 3;
  ae_config.encoder_hidden = 8;
  ae_config.head_hidden = 8;
  ae_config.lora_rank = 2;
  ae_config.online.warmup_steps = 10;
  ae_config.online.learning_rate = 1e-2f;
  return ae_config;
}

DecodedKeyframe decoded_keyframe(const Fixture& f) {
  DecodedKeyframe d{FeatureAutoencoder(small_autoencoder_config()), {}, {}};
  const SynthView view = render_view(f.room, f.camera, f.trajectory[0].T_world_camera);
  const int W = f.camera.width, H = f.camera.height;
  d.pyramid.image_width = W;
  d.pyramid.image_height = H;
  for (const FeatureLevelShape& s : {FeatureLevelShape{6, H / 2, W / 2}, FeatureLevelShape{4, H, W}}) {
    FeatureLevel level;
    level.resize(s);
    const int step = W / s.width;
    for (int c = 0; c < s.channels; ++c)
      for (int y = 0; y < s.height; ++y)
        for (int x = 0; x < s.width; ++x) {
          const int id = view.instance_label.at<std::uint16_t>(y * step, x * step);
          level.channel(c)[y * s.width + x] = std::sin(1.7f * id + 0.9f * c + 0.3f * s.channels);
        }
    d.pyramid.levels.push_back(std::move(level));
  }
  d.keyframe = f.keyframe(0);
  d.keyframe.feature_target = PlanarImage(W, H, 3);
  std::vector<float> u(10), latent(3);
  for (int v = 0; v < H; ++v)
    for (int x = 0; x < W; ++x) {
      sample_features(d.pyramid, static_cast<float>(x), static_cast<float>(v), u.data());
      d.pretrained.encode(u.data(), 1, latent.data());
      for (int c = 0; c < 3; ++c) d.keyframe.feature_target.at(c, v, x) = latent[c];
    }
  std::string why;
  EXPECT_TRUE(observe_features(d.pyramid, W, H, 1024, 1, d.pretrained.input_mean(), d.pretrained.input_std(),
                               &d.keyframe.feature_observation, &why)) << why;
  return d;
}

// The paper's L_feat: the rendered latent decoded by the heads against the encoder's pyramid at
// the keyframe's sample pixels, the heads' LoRA trained online.
TEST(Mapper, DecodedFeatureLossTrainsTheLatentsAndTheHeadsLoRA) {
  Fixture f;
  const FeatureAutoencoderConfig ae_config = small_autoencoder_config();
  DecodedKeyframe d = decoded_keyframe(f);
  const FeatureAutoencoder& pretrained = d.pretrained;
  const FeaturePyramid& pyramid = d.pyramid;
  const MapperKeyframe& kf = d.keyframe;
  const int W = f.camera.width, H = f.camera.height;
  std::string why;
  MapperConfig config = small_config();
  config.feature_dim = 3;
  config.iterations_per_keyframe = 1;
  Mapper mapper(config, make_cpu_rasterizer());
  ASSERT_TRUE(mapper.set_feature_decoder(pretrained, &why)) << why;
  ASSERT_NE(mapper.feature_decoder(), nullptr);
  ASSERT_TRUE(mapper.add_keyframe(kf, nullptr, &why)) << why;
  RenderView rv;
  rv.camera = f.camera;
  rv.T_camera_world = kf.T_world_camera.inverse();
  // Another observation of the same view (other pixels) scores what was not trained on.
  FeatureObservation held;
  ASSERT_TRUE(observe_features(pyramid, W, H, 1024, 2, pretrained.input_mean(), pretrained.input_std(), &held, &why));
  const double start = mapper.decoded_feature_error(rv, held, pretrained, &why);
  ASSERT_TRUE(std::isfinite(start)) << why;
  ASSERT_TRUE(mapper.optimise(80, &why)) << why;
  const FeatureAutoencoder& online = *mapper.feature_decoder();
  EXPECT_EQ(online.online_steps(), mapper.total_steps());  // one LoRA step per mapping step
  const double trained_pretrained_heads = mapper.decoded_feature_error(rv, held, pretrained, &why);
  const double trained_online_heads = mapper.decoded_feature_error(rv, held, online, &why);
  std::printf("decoded L_feat, other pixels of the view: %.4f at insertion, %.4f after 80 steps with the "
              "pretrained heads, %.4f with the online heads\n", start, trained_pretrained_heads, trained_online_heads);
  // Latents and adapters learn together (with the untrained heads here the adapters carry most
  // of it: 0.66 -> 0.29, the latents alone under the pretrained heads barely move).
  EXPECT_LT(trained_online_heads, 0.8 * start);
  EXPECT_LT(trained_online_heads, 0.8 * trained_pretrained_heads);
  double lora_b = 0;
  for (int i = 0; i < static_cast<int>(online.tensors().size()); ++i)
    if (online.tensors()[i].name.find("lora_b") != std::string::npos)
      for (std::size_t k = 0; k < online.tensors()[i].size(); ++k) lora_b += std::abs(online.tensor_data(i)[k]);
  EXPECT_GT(lora_b, 0.0);
  // The body is frozen: the pretrained weights are untouched.
  for (std::size_t k = 0; k < online.body_size(); ++k) ASSERT_EQ(online.parameters()[k], pretrained.parameters()[k]);
  // The latent form needs no decoder; an observation of the wrong channel count is refused.
  MapperKeyframe bad = kf;
  bad.feature_observation.channels = 9;
  EXPECT_FALSE(mapper.add_keyframe(bad, nullptr, &why));
  EXPECT_NE(why.find("observation"), std::string::npos);
  FeatureAutoencoderConfig wide = ae_config;
  wide.latent_dim = 4;
  EXPECT_FALSE(mapper.set_feature_decoder(FeatureAutoencoder(wide), &why));
}

// The heads saved with a map are the online ones of its newest version, and a mapper that
// extends the map continues them, unless they belong to other autoencoder weights.
TEST(Mapper, PublishedHeadsAreTheOnlineOnesAndAnExtendContinuesThem) {
  Fixture f;
  const DecodedKeyframe d = decoded_keyframe(f);
  MapperConfig config = small_config();
  config.feature_dim = 3;
  config.iterations_per_keyframe = 1;
  std::string why;
  Mapper latent_form(config, make_cpu_rasterizer());  // no decoder: nothing to save
  MapperKeyframe latent_kf = d.keyframe;
  latent_kf.feature_observation = {};
  ASSERT_TRUE(latent_form.add_keyframe(latent_kf, nullptr, &why)) << why;
  EXPECT_EQ(latent_form.published_heads(), nullptr);

  Mapper mapper(config, make_cpu_rasterizer());
  ASSERT_TRUE(mapper.set_feature_decoder(d.pretrained, &why)) << why;
  ASSERT_TRUE(mapper.add_keyframe(d.keyframe, nullptr, &why)) << why;
  ASSERT_TRUE(mapper.optimise(30, &why)) << why;
  const std::shared_ptr<const FeatureAutoencoder> heads = mapper.published_heads();
  ASSERT_NE(heads, nullptr);
  EXPECT_EQ(heads->online_steps(), mapper.feature_decoder()->online_steps());
  EXPECT_GT(heads->online_steps(), 0);
  EXPECT_EQ(heads->parameters(), mapper.feature_decoder()->parameters());
  EXPECT_NE(heads->parameters(), d.pretrained.parameters());  // LoRA moved
  EXPECT_TRUE(heads->same_body(d.pretrained));

  // Extend: the new mapper starts from the pretrained heads and continues the saved ones.
  Mapper extender(config, make_cpu_rasterizer());
  ASSERT_TRUE(extender.set_feature_decoder(d.pretrained, &why)) << why;
  ASSERT_TRUE(extender.continue_feature_decoder(*heads, &why)) << why;
  ASSERT_TRUE(extender.set_map(*mapper.versions().latest(), &why)) << why;
  EXPECT_EQ(extender.feature_decoder()->parameters(), heads->parameters());
  ASSERT_NE(extender.published_heads(), nullptr);
  EXPECT_EQ(extender.published_heads()->parameters(), heads->parameters());
  // Heads of other weights (another seed's body) map features elsewhere: refused, unchanged.
  FeatureAutoencoderConfig other_config = small_autoencoder_config();
  other_config.seed = 2;
  const FeatureAutoencoder other(other_config);
  EXPECT_FALSE(other.same_body(d.pretrained));
  EXPECT_FALSE(extender.continue_feature_decoder(other, &why));
  EXPECT_NE(why.find("other autoencoder weights"), std::string::npos) << why;
  EXPECT_EQ(extender.feature_decoder()->parameters(), heads->parameters());
  // Without a decoder there is nothing to continue.
  EXPECT_TRUE(latent_form.continue_feature_decoder(*heads, &why)) << why;
  EXPECT_EQ(latent_form.published_heads(), nullptr);
}

// Loop closure moves a keyframe: the Gaussians it inserted move rigidly with it, the others stay.
TEST(Mapper, MovingAKeyframeMovesTheGaussiansItAnchors) {
  Fixture f;
  MapperConfig config = small_config();
  config.iterations_per_keyframe = 0;  // nothing but the move changes a mean
  Mapper mapper(config, make_cpu_rasterizer());
  std::string why;
  ASSERT_TRUE(mapper.add_keyframe(f.keyframe(0), nullptr, &why)) << why;
  const std::size_t first = mapper.map().size();
  const MapperKeyframe second = f.keyframe(30);
  ASSERT_TRUE(mapper.add_keyframe(second, nullptr, &why)) << why;
  const std::size_t n = mapper.map().size();
  ASSERT_GT(n, first) << "keyframe 30 must add Gaussians";
  const GaussianMap before = mapper.map();
  const std::uint64_t version = mapper.versions().version_number();

  Eigen::Isometry3d D = Eigen::Isometry3d::Identity();
  D.linear() = Eigen::AngleAxisd(2.0 * M_PI / 180.0, Eigen::Vector3d(0.3, 1.0, -0.2).normalized()).toRotationMatrix();
  D.translation() = Eigen::Vector3d(0.03, -0.01, 0.02);
  EXPECT_EQ(mapper.move_keyframes({{30, D * second.T_world_camera}, {7, Eigen::Isometry3d::Identity()}}), n - first);
  EXPECT_GT(mapper.versions().version_number(), version);
  const GaussianMap& after = mapper.map();
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d m0(before.means[3 * i], before.means[3 * i + 1], before.means[3 * i + 2]);
    const Eigen::Vector3d m1(after.means[3 * i], after.means[3 * i + 1], after.means[3 * i + 2]);
    const Eigen::Quaterniond q0(before.rotations[4 * i], before.rotations[4 * i + 1], before.rotations[4 * i + 2],
                                before.rotations[4 * i + 3]);
    const Eigen::Quaterniond q1(after.rotations[4 * i], after.rotations[4 * i + 1], after.rotations[4 * i + 2],
                                after.rotations[4 * i + 3]);
    if (i < first) {
      ASSERT_EQ(m1, m0) << "Gaussian " << i << " of keyframe 0 moved";
      ASSERT_TRUE(q1.coeffs() == q0.coeffs());
    } else {
      ASSERT_LT((m1 - D * m0).norm(), 1e-5) << "Gaussian " << i;  // metres
      ASSERT_LT(q1.angularDistance(Eigen::Quaterniond(D.rotation()) * q0), 1e-5) << "Gaussian " << i;
    }
  }
  // The same pose again, or a keyframe the mapper never took, moves nothing.
  EXPECT_EQ(mapper.move_keyframes({{30, D * second.T_world_camera}}), 0u);
  EXPECT_EQ(mapper.move_keyframes({{12345, D}}), 0u);
  // Optimising after the move still works from the moved keyframe's view.
  ASSERT_TRUE(mapper.optimise(5, &why)) << why;
}

TEST(Mapper, RejectsBadKeyframes) {
  Fixture f;
  Mapper mapper(small_config(), make_cpu_rasterizer());
  std::string why;
  MapperKeyframe kf = f.keyframe(0);
  kf.depth = cv::Mat(10, 10, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_FALSE(mapper.add_keyframe(kf, nullptr, &why));
  EXPECT_NE(why.find("depth"), std::string::npos);
  kf = f.keyframe(0);
  kf.camera.fx = 0;
  EXPECT_FALSE(mapper.add_keyframe(kf, nullptr, &why));
  kf = f.keyframe(0);
  kf.T_world_camera.translation().x() = std::nan("");
  EXPECT_FALSE(mapper.add_keyframe(kf, nullptr, &why));
  EXPECT_NE(why.find("pose"), std::string::npos);
  EXPECT_EQ(mapper.map().size(), 0u);
}

}  // namespace
}  // namespace fslam::core

namespace fslam::core {
namespace {

// Readers take whole versions while the writer publishes: every version they hold stays
// internally consistent, and version numbers only grow.
TEST(MapVersions, ReadersSeeWholeVersionsWhileTheWriterPublishes) {
  MapVersions versions;
  std::atomic<bool> stop{false};
  std::atomic<int> bad{0}, reads{0};
  auto reader = [&] {
    std::uint64_t last = 0;
    while (!stop.load()) {
      const std::uint64_t number = versions.version_number();
      const MapVersions::Version map = versions.latest();
      if (number < last) ++bad;
      last = number;
      std::string why;
      if (!map->is_consistent(&why)) ++bad;
      for (float m : map->means)
        if (m != static_cast<float>(map->size())) ++bad;  // each version is written whole
      ++reads;
    }
  };
  std::thread a(reader), b(reader);
  for (int n = 1; n <= 200; ++n) {
    GaussianMap map;
    map.feature_dim = 2;
    const float v = static_cast<float>(n);
    const float mean[3] = {v, v, v}, rot[4] = {1, 0, 0, 0}, ls[3] = {0, 0, 0};
    for (int i = 0; i < n; ++i) map.push_back(mean, rot, ls, 0.0f, nullptr, nullptr);
    versions.publish(std::make_shared<const GaussianMap>(std::move(map)));
    // Let the readers in every few versions, also on a loaded machine.
    if (n % 20 == 0) {
      const int seen = reads.load();
      while (reads.load() < seen + 2) std::this_thread::yield();
    }
  }
  stop = true;
  a.join();
  b.join();
  EXPECT_EQ(bad.load(), 0);
  EXPECT_GE(reads.load(), 20);
  EXPECT_EQ(versions.version_number(), 200u);
  EXPECT_EQ(versions.latest()->size(), 200u);
}

}  // namespace
}  // namespace fslam::core
