// Feature encoder cost and separability. Prints three tables:
// 1. time per frame (median over frames x repeats) at the given OpenCV thread count;
// 2. per descriptor family (builtin only), the median over its channels of the channel's
//    standard deviation over all pixels of all frames: the calibration behind the builtin's fixed
//    normalisation constants (docs/features.md);
// 3. on synthetic views with instance labels (`fslam synth`'s room), how well the sampled
//    vectors u_i (and their 16-D PCA projection, a stand-in for the autoencoder's latent) separate
//    instances: oracle nearest-centroid mIoU, and point-prompt mIoU (the connected region of
//    pixels within a feature distance tau of the prompt's, prompt at the instance's innermost
//    pixel, best tau of a fixed list).
// Usage: fslam_bench_features [--redkitchen DIR] [--frames N] [--threads 1] [--onnx MODEL]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <regex>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/features/feature_encoder.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace {

using namespace fslam::core;
using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Samples of one view on a grid of `step` pixels.
struct Samples {
  int cols = 0, rows = 0, step = 0;
  cv::Mat u;                    // [cols * rows, D] CV_32F
  std::vector<int> label;       // [cols * rows] instance id
};

Samples sample_grid(const FeaturePyramid& p, const cv::Mat& instance, int step) {
  Samples s;
  s.step = step;
  s.cols = instance.cols / step;
  s.rows = instance.rows / step;
  s.u.create(s.cols * s.rows, p.dim(), CV_32F);
  for (int r = 0; r < s.rows; ++r)
    for (int c = 0; c < s.cols; ++c) {
      const int x = c * step + step / 2, y = r * step + step / 2;
      sample_features(p, static_cast<float>(x), static_cast<float>(y),
                      s.u.ptr<float>(r * s.cols + c));
      s.label.push_back(instance.at<std::uint16_t>(y, x));
    }
  return s;
}

double rms_distance(const float* a, const float* b, int d) {
  double s = 0;
  for (int i = 0; i < d; ++i) s += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(s / d);
}

struct Scores {
  double centroid_miou = 0, prompt_miou = 0, best_tau = 0;
};

// Instances with at least min_samples grid samples are scored.
Scores score(const Samples& s, int min_samples) {
  const int n = s.u.rows, d = s.u.cols;
  std::map<int, std::vector<int>> members;
  for (int i = 0; i < n; ++i) members[s.label[i]].push_back(i);
  std::vector<int> ids;
  std::map<int, std::vector<float>> centroid;
  for (const auto& [id, m] : members) {
    std::vector<float> c(d, 0.0f);
    for (int i : m)
      for (int k = 0; k < d; ++k) c[k] += s.u.at<float>(i, k) / m.size();
    centroid[id] = c;
    if (static_cast<int>(m.size()) >= min_samples) ids.push_back(id);
  }
  Scores out;
  // Oracle nearest centroid over all instances present; IoU over the scored ones.
  std::vector<int> predicted(n);
  for (int i = 0; i < n; ++i) {
    double best = 1e30;
    for (const auto& [id, c] : centroid) {
      const double dist = rms_distance(s.u.ptr<float>(i), c.data(), d);
      if (dist < best) best = dist, predicted[i] = id;
    }
  }
  for (int id : ids) {
    int inter = 0, uni = 0;
    for (int i = 0; i < n; ++i) {
      const bool a = predicted[i] == id, b = s.label[i] == id;
      inter += a && b;
      uni += a || b;
    }
    out.centroid_miou += static_cast<double>(inter) / uni / ids.size();
  }
  // Point prompts: innermost sample of each instance (largest distance transform).
  const double taus[] = {0.02, 0.03, 0.05, 0.07, 0.1, 0.14, 0.2, 0.28, 0.4, 0.56, 0.8, 1.1, 1.6};
  out.prompt_miou = -1;
  for (double tau : taus) {
    double miou = 0;
    for (int id : ids) {
      cv::Mat mask(s.rows, s.cols, CV_8U);
      for (int i = 0; i < n; ++i) mask.data[i] = s.label[i] == id ? 255 : 0;
      cv::Mat dt;
      cv::distanceTransform(mask, dt, cv::DIST_L2, 3);
      cv::Point at;
      cv::minMaxLoc(dt, nullptr, nullptr, nullptr, &at);
      const float* prompt = s.u.ptr<float>(at.y * s.cols + at.x);
      cv::Mat near(s.rows, s.cols, CV_8U);
      for (int i = 0; i < n; ++i)
        near.data[i] = rms_distance(s.u.ptr<float>(i), prompt, d) < tau ? 255 : 0;
      cv::Mat region(s.rows + 2, s.cols + 2, CV_8U, cv::Scalar(0));
      cv::floodFill(near, region, at, cv::Scalar(128), nullptr, cv::Scalar(), cv::Scalar(),
                    4 | cv::FLOODFILL_MASK_ONLY | (255 << 8));
      int inter = 0, uni = 0;
      for (int r = 0; r < s.rows; ++r)
        for (int c = 0; c < s.cols; ++c) {
          const bool a = region.at<uchar>(r + 1, c + 1) != 0, b = s.label[r * s.cols + c] == id;
          inter += a && b;
          uni += a || b;
        }
      miou += static_cast<double>(inter) / uni / ids.size();
    }
    if (miou > out.prompt_miou) out.prompt_miou = miou, out.best_tau = tau;
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string redkitchen, onnx, dump;
  int frames = 10, threads = 1, repeats = 3, synth_views = 6, seed = 1;
  CLI::App app{"fslam feature encoder benchmark"};
  app.add_option("--redkitchen", redkitchen, "7-Scenes redkitchen folder (frame-*.color.jpg)");
  app.add_option("--frames", frames, "real frames to time")->capture_default_str();
  app.add_option("--repeats", repeats, "timed repeats per frame")->capture_default_str();
  app.add_option("--threads", threads, "OpenCV threads")->capture_default_str();
  app.add_option("--synth-views", synth_views, "synthetic views to score")->capture_default_str();
  app.add_option("--seed", seed, "synthetic room seed")->capture_default_str();
  app.add_option("--onnx", onnx, "score an ONNX encoder (1024x1024, ImageNet) instead");
  std::string channels;
  app.add_option("--channels", channels,
                 "score only the builtin channels whose level-qualified name (\"2:L@1\") "
                 "matches this regular expression");
  app.add_option("--dump", dump, "write each synthetic view, its labels and a PCA-3 picture of "
                 "its features (v<i>_{rgb,labels,pca}.png) into this folder");
  CLI11_PARSE(app, argc, argv);
  cv::setNumThreads(threads);

  FeatureEncoderConfig config;
  if (!onnx.empty()) {
    config.backend = FeatureBackend::onnx;
    config.onnx.model_path = onnx;
  }
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  if (!encoder) {
    std::fprintf(stderr, "error: %s\n", why.c_str());
    return 1;
  }
  std::printf("%s, %d OpenCV thread(s)\n", encoder->describe().c_str(), threads);

  // Frames: real ones when given, and synthetic views with labels.
  std::vector<cv::Mat> real;
  for (int i = 0; i < frames && !redkitchen.empty(); ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), "/frame-%06d.color.jpg", i * 50);
    cv::Mat bgr = cv::imread(redkitchen + name, cv::IMREAD_COLOR);
    if (bgr.empty()) break;
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    real.push_back(rgb);
  }
  std::vector<SynthView> views;
  const SyntheticRoom room = make_room(seed);
  SynthOptions options;
  options.frames = 300;
  options.seed = seed;
  const Trajectory trajectory = make_trajectory(room, options);
  for (int v = 0; v < synth_views; ++v) {
    const std::size_t k = trajectory.size() * v / synth_views;
    views.push_back(render_view(room, options.camera, trajectory[k].T_world_camera));
    apply_kinect_noise(options.camera, options.seed, k, &views.back());
  }

  // 1. Time per frame: wall time, and the calling thread's CPU time, which other processes on
  // a shared machine inflate less (with --threads 1 OpenCV runs everything on this thread).
  std::vector<double> wall, cpu;
  FeaturePyramid p;
  std::vector<const cv::Mat*> timed;
  for (const auto& f : real) timed.push_back(&f);
  for (const auto& v : views) timed.push_back(&v.colour);
  for (int r = 0; r < repeats; ++r)
    for (const cv::Mat* f : timed) {
      const double c0 = thread_cpu_ms();
      const auto t0 = Clock::now();
      if (!encoder->encode(*f, &p, &why)) {
        std::fprintf(stderr, "error: %s\n", why.c_str());
        return 1;
      }
      wall.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      cpu.push_back(thread_cpu_ms() - c0);
    }
  std::printf("\ntime per 640x480 frame (%zu real + %zu synthetic frames x %d repeats): "
              "median wall %.2f ms, median thread CPU %.2f ms\n",
              real.size(), views.size(), repeats, median(wall), median(cpu));

  // 2. Channel spread per family.
  if (config.backend == FeatureBackend::builtin) {
    const auto names = builtin_feature_channel_names();
    std::vector<cv::Mat> all;
    for (const auto& f : real) all.push_back(f);
    for (const auto& v : views) all.push_back(v.colour);
    std::map<std::string, std::vector<double>> family_std, family_mean;
    std::vector<std::vector<double>> sum(kFeatureLevelCount), sq(kFeatureLevelCount);
    double count[kFeatureLevelCount] = {0, 0, 0};
    for (const auto& img : all) {
      encoder->encode(img, &p, &why);
      for (int l = 0; l < kFeatureLevelCount; ++l) {
        const auto& level = p.levels[l];
        const int plane = level.shape.height * level.shape.width;
        sum[l].resize(names[l].size()), sq[l].resize(names[l].size());
        count[l] += plane;
        for (std::size_t c = 0; c < names[l].size(); ++c) {
          const float* ch = level.channel(static_cast<int>(c));
          for (int i = 0; i < plane; ++i) sum[l][c] += ch[i], sq[l][c] += double(ch[i]) * ch[i];
        }
      }
    }
    for (int l = 0; l < kFeatureLevelCount; ++l)
      for (std::size_t c = 0; c < names[l].size(); ++c) {
        std::string family = names[l][c].substr(0, names[l][c].find('@'));
        family = family.substr(0, family.find('/'));
        if (family.rfind("bin", 0) == 0) family = "bin";
        if (family.rfind("E", 0) == 0 && family != "Ecol") family = "E*";
        family += " (level " + std::to_string(l) + ")";
        const double mean = sum[l][c] / count[l];
        family_mean[family].push_back(mean);
        family_std[family].push_back(std::sqrt(std::max(0.0, sq[l][c] / count[l] - mean * mean)));
      }
    std::printf("\n%-20s %9s %12s %12s\n", "family", "channels", "median std", "median mean");
    for (const auto& [f, s] : family_std)
      std::printf("%-20s %9zu %12.3f %12.3f\n", f.c_str(), s.size(), median(s),
                  median(family_mean[f]));
  }

  // 3. Separability on synthetic views (grid of 8 px, instances of >= 40 samples).
  std::printf("\n%-6s %-10s %14s %14s %8s\n", "view", "features", "centroid mIoU", "prompt mIoU",
              "tau");
  double sums[4] = {0, 0, 0, 0};
  for (std::size_t v = 0; v < views.size(); ++v) {
    encoder->encode(views[v].colour, &p, &why);
    Samples s = sample_grid(p, views[v].instance_label, 8);
    if (!channels.empty()) {
      const auto names = builtin_feature_channel_names();
      const std::regex pattern(channels);
      std::vector<cv::Mat> keep;
      int col = 0;
      for (int l = 0; l < kFeatureLevelCount; ++l)
        for (const auto& name : names[l]) {
          if (std::regex_search(std::to_string(l) + ":" + name, pattern))
            keep.push_back(s.u.col(col));
          ++col;
        }
      if (keep.empty()) {
        std::fprintf(stderr, "error: no channel matches --channels '%s'\n", channels.c_str());
        return 1;
      }
      cv::hconcat(keep, s.u);
      if (v == 0) std::printf("scoring %zu channels\n", keep.size());
    }
    const Scores full = score(s, 40);
    cv::PCA pca(s.u, cv::Mat(), cv::PCA::DATA_AS_ROW, 16);
    Samples low = s;
    low.u = pca.project(s.u);
    const Scores latent = score(low, 40);
    if (!dump.empty()) {
      const std::string stem = dump + "/v" + std::to_string(v) + "_";
      cv::Mat bgr, labels, pca3;
      cv::cvtColor(views[v].colour, bgr, cv::COLOR_RGB2BGR);
      cv::imwrite(stem + "rgb.png", bgr);
      views[v].instance_label.convertTo(labels, CV_8U, 7);
      cv::applyColorMap(labels, labels, cv::COLORMAP_JET);
      cv::imwrite(stem + "labels.png", labels);
      cv::Mat first3 = low.u.colRange(0, 3).clone().reshape(3, s.rows);
      cv::normalize(first3, pca3, 0, 255, cv::NORM_MINMAX, CV_8UC3);
      cv::resize(pca3, pca3, views[v].colour.size(), 0, 0, cv::INTER_NEAREST);
      cv::imwrite(stem + "pca.png", pca3);
    }
    std::printf("%-6zu %-10s %14.3f %14.3f %8.2f\n", v, "u (352)", full.centroid_miou,
                full.prompt_miou, full.best_tau);
    std::printf("%-6zu %-10s %14.3f %14.3f %8.2f\n", v, "PCA 16", latent.centroid_miou,
                latent.prompt_miou, latent.best_tau);
    sums[0] += full.centroid_miou, sums[1] += full.prompt_miou;
    sums[2] += latent.centroid_miou, sums[3] += latent.prompt_miou;
  }
  const double n = static_cast<double>(views.size());
  std::printf("%-6s %-10s %14.3f %14.3f\n%-6s %-10s %14.3f %14.3f\n", "mean", "u (352)",
              sums[0] / n, sums[1] / n, "mean", "PCA 16", sums[2] / n, sums[3] / n);
  return 0;
}
