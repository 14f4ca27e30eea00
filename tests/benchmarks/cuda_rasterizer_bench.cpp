// The CUDA rasteriser's forward pass against the CPU's on a real map: median milliseconds per
// render at half and full size, blend steps per second, the ratio, and the largest colour and
// depth difference between the two. Needs a GPU; prints one table.
// Usage: fslam_bench_cuda_rasterizer --map OUT/map.ply --trajectory OUT/trajectory.txt
//            --camera fx,fy,cx,cy,width,height [--views N] [--repeats N] [--threads N]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <tbb/global_control.h>

#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/cuda/cuda_backend.hpp"

namespace {

using Clock = std::chrono::steady_clock;

// Median seconds of `repeats` forward passes of `rasterizer` (forward + backward with `backward`);
// the last result in *result.
double time_passes(const fslam::core::Rasterizer& rasterizer, const fslam::core::GaussianMap& map,
                   const fslam::core::RenderView& view, const fslam::core::RenderSettings& settings, int repeats,
                   bool backward, fslam::core::RenderResult* result) {
  std::vector<double> t;
  std::string why;
  const int W = view.camera.width, H = view.camera.height;
  fslam::core::RenderGradients grads;
  grads.colour = fslam::core::PlanarImage(W, H, 3, 1e-3f);
  grads.depth = fslam::core::PlanarImage(W, H, 1, 1e-3f);
  grads.median_depth = grads.depth;
  if (settings.features) grads.features = fslam::core::PlanarImage(W, H, map.feature_dim, 1e-3f);
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = Clock::now();
    fslam::core::GaussianGradients g;
    if (!rasterizer.forward(map, view, settings, result, &why) ||
        (backward && !rasterizer.backward(map, view, settings, *result, grads, &g, &why))) {
      std::fprintf(stderr, "error: %s\n", why.c_str());
      std::exit(1);
    }
    t.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

double max_difference(const fslam::core::PlanarImage& a, const fslam::core::PlanarImage& b) {
  double worst = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) {
    worst = std::max(worst, static_cast<double>(std::abs(a.data[i] - b.data[i])));
  }
  return worst;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"CUDA rasteriser forward pass against the CPU's"};
  std::string map_path, trajectory_path;
  std::vector<double> camera_values;
  int views = 5, repeats = 5, threads = 2;
  app.add_option("--map", map_path, "map.ply")->required();
  app.add_option("--trajectory", trajectory_path, "poses to render from (TUM)")->required();
  app.add_option("--camera", camera_values, "fx,fy,cx,cy,width,height of the full-size view")
      ->required()->delimiter(',')->expected(6);
  app.add_option("--views", views, "views spread over the trajectory")->capture_default_str();
  app.add_option("--repeats", repeats, "timed repeats per view (median kept)")->capture_default_str();
  app.add_option("--threads", threads, "TBB threads of the CPU rasteriser")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  tbb::global_control control(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));

  std::string why;
  fslam::core::GaussianMap map;
  fslam::core::Trajectory trajectory;
  if (!fslam::core::read_gaussian_ply(map_path, &map, &why) ||
      !fslam::core::read_tum_trajectory(trajectory_path, &trajectory, &why)) {
    std::fprintf(stderr, "error: %s\n", why.c_str());
    return 1;
  }
  auto gpu = fslam::cuda::make_cuda_rasterizer(0, &why);
  if (!gpu) {
    std::fprintf(stderr, "error: no usable GPU: %s\n", why.c_str());
    return 1;
  }
  const auto cpu = fslam::core::make_cpu_rasterizer();
  const fslam::core::PinholeCamera full{camera_values[0], camera_values[1], camera_values[2], camera_values[3],
                                        static_cast<int>(camera_values[4]), static_cast<int>(camera_values[5])};
  fslam::core::RenderSettings settings;
  settings.features = map.feature_dim > 0;
  std::printf("map %zu Gaussians, D = %d, SH degree %d; CPU on %d thread(s); %d views x %d repeats (median)\n",
              map.size(), map.feature_dim, map.sh_degree, threads, views, repeats);
  std::printf("%-9s %10s %9s %9s %8s %13s %13s %11s %11s %11s %11s\n", "size", "splats/px", "cpu ms", "cuda ms",
              "ratio", "cpu Mstep/s", "cuda Mstep/s", "max dRGB", "max dD (m)", "cpu f+b ms", "cuda f+b ms");
  for (double scale : {0.5, 1.0}) {
    const fslam::core::PinholeCamera camera = full.scaled(scale);
    double cpu_total = 0, gpu_total = 0, steps = 0, pixels = 0, d_rgb = 0, d_depth = 0, cpu_fb = 0, gpu_fb = 0;
    for (int v = 0; v < views; ++v) {
      fslam::core::RenderView view;
      view.camera = camera;
      const std::size_t k = trajectory.size() * static_cast<std::size_t>(v) / views;
      view.T_camera_world = trajectory[k].T_world_camera.inverse();
      fslam::core::RenderResult a, b;
      cpu_total += time_passes(*cpu, map, view, settings, repeats, false, &a);
      time_passes(*gpu, map, view, settings, 1, true, &b);  // warm-up: allocations, module load
      gpu_total += time_passes(*gpu, map, view, settings, repeats, false, &b);
      cpu_fb += time_passes(*cpu, map, view, settings, repeats, true, &a);
      gpu_fb += time_passes(*gpu, map, view, settings, repeats, true, &b);
      steps += static_cast<double>(a.stats.blend_steps);
      pixels += static_cast<double>(a.stats.pixels);
      d_rgb = std::max(d_rgb, max_difference(a.colour, b.colour));
      d_depth = std::max(d_depth, max_difference(a.depth, b.depth));
    }
    char size[32];
    std::snprintf(size, sizeof(size), "%dx%d", camera.width, camera.height);
    std::printf("%-9s %10.1f %9.2f %9.2f %7.1fx %13.1f %13.1f %11.2e %11.2e %11.2f %11.2f\n", size,
                steps / pixels, 1e3 * cpu_total / views, 1e3 * gpu_total / views, cpu_total / gpu_total,
                steps / cpu_total / 1e6, steps / gpu_total / 1e6, d_rgb, d_depth, 1e3 * cpu_fb / views,
                1e3 * gpu_fb / views);
  }
  std::printf("cuda ms: the whole forward() call, the upload of the map and the download of the images included\n");
  return 0;
}
