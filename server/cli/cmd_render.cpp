// `fslam render`: renders a saved map (map.ply) from a pose: colour, depth, normals and opacity
// side by side in one PNG. The pose is given directly, or as the ground-truth or tracked pose of
// a dataset frame.
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/core.hpp>
#include <tbb/global_control.h>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/text_tables.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/server/backend_factory.hpp"
#include "render_images.hpp"

namespace fslam::cli {
namespace {

struct RenderArgs {
  std::string ply;
  DatasetArgs dataset;
  std::string pose;        // tx,ty,tz,qx,qy,qz,qw (camera-to-world)
  long long frame = -1;    // a dataset frame position
  std::string trajectory;  // with --frame: take the pose from here (else the ground truth)
  std::string channels = "colour,depth,normals,opacity";
  std::string out;
  int threads = 2;
  double max_depth = 5.0;
};

bool parse_pose(const std::string& text, Eigen::Isometry3d* T, std::string* why) {
  std::vector<double> v;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    double x = 0;
    if (!core::parse_double(item, &x) || !std::isfinite(x)) {
      *why = "--pose: '" + item + "' is not a number";
      return false;
    }
    v.push_back(x);
  }
  if (v.size() != 7) {
    *why = "--pose expects tx,ty,tz,qx,qy,qz,qw (7 numbers), got " + std::to_string(v.size());
    return false;
  }
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 1e-3) {
    *why = "--pose: the quaternion is not unit length";
    return false;
  }
  T->setIdentity();
  T->linear() = q.normalized().toRotationMatrix();
  T->translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return true;
}

int run_render(const RenderArgs& args) {
  std::string why;
  core::DatasetOptions options;
  if (!args.dataset.to_options(&options, &why)) return fail(why);
  auto dataset = core::open_dataset(args.dataset.path, options, &why);
  if (!dataset) return fail(why);
  if (args.pose.empty() == (args.frame < 0)) return fail("give exactly one of --pose and --frame");
  Eigen::Isometry3d T_world_camera;
  if (!args.pose.empty()) {
    if (!parse_pose(args.pose, &T_world_camera, &why)) return fail(why);
  } else {
    if (static_cast<std::size_t>(args.frame) >= dataset->size()) {
      return fail("--frame " + std::to_string(args.frame) + " is outside the dataset's " +
                  std::to_string(dataset->size()) + " frames");
    }
    const std::size_t i = static_cast<std::size_t>(args.frame);
    if (!args.trajectory.empty()) {
      core::Trajectory trajectory;
      if (!core::read_tum_trajectory(args.trajectory, &trajectory, &why)) return fail(why);
      const double t = dataset->timestamp(i);
      const core::StampedPose* best = nullptr;
      for (const auto& p : trajectory)
        if (!best || std::abs(p.timestamp - t) < std::abs(best->timestamp - t)) best = &p;
      if (!best || std::abs(best->timestamp - t) > 0.02) {
        return fail(args.trajectory + " has no pose within 20 ms of frame " + std::to_string(i));
      }
      T_world_camera = best->T_world_camera;
    } else {
      core::RgbdFrame frame;
      if (!dataset->load(i, &frame, &why)) return fail(why);
      if (!frame.T_world_camera_gt) return fail("frame " + std::to_string(i) + " has no ground truth; give --trajectory");
      T_world_camera = *frame.T_world_camera_gt;
    }
  }
  core::GaussianMap map;
  if (!core::read_gaussian_ply(args.ply, &map, &why)) return fail(why);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(std::max(1, args.threads)));
  std::string notice;
  auto rasterizer = server::make_rasterizer("auto", &notice, &why);
  if (!rasterizer) return fail(why);
  core::RenderView view;
  view.camera = dataset->camera();
  view.T_camera_world = T_world_camera.inverse();
  core::RenderSettings settings;
  settings.features = false;
  core::RenderResult r;
  if (!rasterizer->forward(map, view, settings, &r, &why)) return fail(why);

  std::vector<cv::Mat> panels;
  std::stringstream ss(args.channels);
  std::string channel;
  while (std::getline(ss, channel, ',')) {
    if (channel == "colour" || channel == "color") {
      panels.push_back(colour_to_rgb8(r.colour));
    } else if (channel == "depth") {
      panels.push_back(depth_to_rgb8(plane_to_mat(r.median_depth, 0), args.max_depth));
    } else if (channel == "normals") {
      panels.push_back(normals_to_rgb8(r.median_depth, view.camera.intrinsics()));
    } else if (channel == "opacity") {
      panels.push_back(opacity_to_rgb8(r.alpha));
    } else {
      return fail("--channels: unknown channel '" + channel +
                  "' (colour, depth, normals, opacity)");
    }
  }
  if (panels.empty()) return fail("--channels: nothing to render");
  cv::Mat image;
  cv::hconcat(panels, image);
  if (!core::write_image(args.out, image, &why)) return fail(why);
  std::printf("rendered %zu of %zu Gaussians at %dx%d (%s) -> %s\n", r.stats.visible, map.size(),
              view.camera.width, view.camera.height, args.channels.c_str(), args.out.c_str());
  return 0;
}

}  // namespace

void add_render_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "render", "Render a saved map (map.ply) from a pose or a dataset frame's pose; channels "
                "side by side in one PNG");
  auto args = std::make_shared<RenderArgs>();
  app->add_option("--ply", args->ply, "The map (3DGS PLY, e.g. fslam run's map.ply)")->required();
  add_dataset_options(app, &args->dataset);
  app->add_option("--pose", args->pose, "Camera-to-world pose tx,ty,tz,qx,qy,qz,qw");
  app->add_option("--frame", args->frame, "Render from this dataset frame's pose");
  app->add_option("--trajectory", args->trajectory,
                  "With --frame: the tracked pose from this TUM trajectory (default: ground truth)");
  app->add_option("--channels", args->channels, "colour,depth,normals,opacity (any order)")
      ->capture_default_str();
  app->add_option("--max-depth", args->max_depth, "Depth colour map range, metres")
      ->capture_default_str();
  app->add_option("--threads", args->threads, "Rendering threads")->capture_default_str();
  app->add_option("--out", args->out, "PNG to write")->required();
  commands->push_back({app, [args] { return run_render(*args); }});
}

}  // namespace fslam::cli
