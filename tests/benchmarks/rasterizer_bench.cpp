// Rasteriser throughput on a real map: forward and forward + backward Gaussian-pixel blend steps
// per second at the input resolution and at half of it, and the ratio to the straightforward
// per-pixel reference (fslam/core/render/rasterize_impl.hpp). Prints one table.
// Usage: fslam_bench_rasterizer --map OUT/map.ply --dataset DIR --trajectory OUT/trajectory.txt
#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <tbb/global_control.h>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/render/rasterize_impl.hpp"
#include "fslam/core/render/rasterizer.hpp"

namespace {

using Clock = std::chrono::steady_clock;
double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace

int main(int argc, char** argv) {
  std::string map_path, dataset_path, trajectory_path;
  int views = 5, repeats = 3, threads = 2;
  bool reference = true;
  CLI::App app{"fslam rasteriser benchmark"};
  app.add_option("--map", map_path, "map.ply")->required();
  app.add_option("--dataset", dataset_path, "dataset whose camera is used")->required();
  app.add_option("--trajectory", trajectory_path, "poses to render from (TUM)")->required();
  app.add_option("--views", views, "views spread over the trajectory")->capture_default_str();
  app.add_option("--repeats", repeats, "timed repeats per view (median kept)")->capture_default_str();
  app.add_option("--threads", threads, "TBB threads")->capture_default_str();
  app.add_flag("!--no-reference", reference, "skip the per-pixel reference (slow)");
  CLI11_PARSE(app, argc, argv);
  tbb::global_control control(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(threads));

  std::string why;
  fslam::core::GaussianMap map;
  if (!fslam::core::read_gaussian_ply(map_path, &map, &why)) {
    std::fprintf(stderr, "error: %s\n", why.c_str());
    return 1;
  }
  fslam::core::DatasetOptions options;
  auto dataset = fslam::core::open_dataset(dataset_path, options, &why);
  fslam::core::Trajectory trajectory;
  if (!dataset || !fslam::core::read_tum_trajectory(trajectory_path, &trajectory, &why)) {
    std::fprintf(stderr, "error: %s\n", why.c_str());
    return 1;
  }
  auto rasterizer = fslam::core::make_cpu_rasterizer();
  fslam::core::RenderSettings settings;
  settings.features = map.feature_dim > 0;
  std::printf("map %zu Gaussians, D = %d, SH degree %d, %d thread(s), %d views x %d repeats\n",
              map.size(), map.feature_dim, map.sh_degree, threads, views, repeats);
  std::printf("%-9s %8s %10s %9s %9s %12s %12s %10s\n", "size", "visible", "splats/px", "fwd ms",
              "f+b ms", "fwd Mstep/s", "f+b Mstep/s", "ref ratio");
  for (double scale : {0.5, 1.0}) {
    const fslam::core::PinholeCamera camera = dataset->camera().scaled(scale);
    double fwd_total = 0, fb_total = 0, steps_total = 0, visible_total = 0, pixels_total = 0;
    double ref_time = 0, ref_fwd_time = 0;
    for (int v = 0; v < views; ++v) {
      const std::size_t k = trajectory.size() * static_cast<std::size_t>(v) / views;
      fslam::core::RenderView view;
      view.camera = camera;
      view.T_camera_world = trajectory[k].T_world_camera.inverse();
      std::vector<double> fwd, fb;
      fslam::core::RenderResult result;
      for (int r = 0; r < repeats; ++r) {
        const auto t0 = Clock::now();
        rasterizer->forward(map, view, settings, &result, &why);
        const auto t1 = Clock::now();
        fslam::core::RenderGradients grads;
        grads.colour = fslam::core::PlanarImage(camera.width, camera.height, 3, 1e-3f);
        grads.depth = fslam::core::PlanarImage(camera.width, camera.height, 1, 1e-3f);
        grads.median_depth = grads.depth;
        if (settings.features) {
          grads.features = fslam::core::PlanarImage(camera.width, camera.height, map.feature_dim, 1e-3f);
        }
        fslam::core::GaussianGradients g;
        rasterizer->backward(map, view, settings, result, grads, &g, &why);
        const auto t2 = Clock::now();
        fwd.push_back(seconds(t0, t1));
        fb.push_back(seconds(t0, t2));
      }
      std::sort(fwd.begin(), fwd.end());
      std::sort(fb.begin(), fb.end());
      fwd_total += fwd[fwd.size() / 2];
      fb_total += fb[fb.size() / 2];
      steps_total += static_cast<double>(result.stats.blend_steps);
      visible_total += static_cast<double>(result.stats.visible);
      pixels_total += static_cast<double>(result.stats.pixels);
      if (reference && v == 0) {
        // The reference is single-threaded by construction; compare it with our forward pass
        // on one thread for the same view.
        const auto cam = fslam::core::render_impl::splat_camera(view, settings.near_plane);
        const auto scene = fslam::core::render_impl::splat_scene(map);
        fslam::core::PlanarImage c(camera.width, camera.height, 3), d(camera.width, camera.height, 1),
            m(camera.width, camera.height, 1), a(camera.width, camera.height, 1),
            f(camera.width, camera.height, std::max(1, map.feature_dim));
        fslam::core::render_impl::RasterOutputs<float> out{c.data.data(), d.data.data(),
                                                           m.data.data(), a.data.data(),
                                                           map.feature_dim > 0 ? f.data.data() : nullptr};
        const float background[3] = {0, 0, 0};
        const auto t0 = Clock::now();
        fslam::core::render_impl::rasterize_reference(scene, cam, background, out);
        ref_time = seconds(t0, Clock::now());
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        const auto t1 = Clock::now();
        rasterizer->forward(map, view, settings, &result, &why);
        ref_fwd_time = seconds(t1, Clock::now());
      }
    }
    char size[32];
    std::snprintf(size, sizeof(size), "%dx%d", camera.width, camera.height);
    char ratio[32] = "-";
    if (reference) std::snprintf(ratio, sizeof(ratio), "%.0fx", ref_time / ref_fwd_time);
    std::printf("%-9s %8.0f %10.1f %9.1f %9.1f %12.1f %12.1f %10s\n", size, visible_total / views,
                steps_total / pixels_total, 1e3 * fwd_total / views, 1e3 * fb_total / views,
                steps_total / fwd_total / 1e6, steps_total / fb_total / 1e6, ratio);
  }
  std::printf("splats/px: Gaussian-pixel pairs composited per pixel (alpha >= 1/255, before the "
              "pixel saturates); Mstep/s: those pairs per second; ref ratio: per-pixel reference "
              "time / our forward time, both on one thread, first view\n");
  return 0;
}
