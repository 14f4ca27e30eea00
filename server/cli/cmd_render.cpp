// `fslam render`: colour, depth, normals and opacity side by side in one PNG, from a pose.
// Two sources: a map a running server serves (--map NAME; --frame N is then the server's tracked
// pose of frame N), or a saved map.ply rendered in-process (--ply; --frame N is the ground-truth
// or --trajectory pose of dataset frame N).
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <tbb/global_control.h>

#include "client_args.hpp"
#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/client/client.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/render_images.hpp"

namespace fslam::cli {
namespace {

struct RenderArgs {
  std::string ply;
  std::string map;
  ClientArgs client;
  std::string camera;      // fx,fy,cx,cy,width,height for --map (default: the map's camera)
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
  double t[3], q[4];
  if (!parse_pose_text(text, t, q, why)) return false;
  T->setIdentity();
  T->linear() = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).toRotationMatrix();
  T->translation() = Eigen::Vector3d(t[0], t[1], t[2]);
  return true;
}

// The channel names of --channels as render bits, in the order given.
bool parse_channels(const std::string& text, std::vector<std::uint32_t>* bits, std::string* why) {
  std::stringstream ss(text);
  std::string channel;
  while (std::getline(ss, channel, ',')) {
    if (channel == "colour" || channel == "color") bits->push_back(client::kColour);
    else if (channel == "depth") bits->push_back(client::kDepth);
    else if (channel == "normals") bits->push_back(client::kNormals);
    else if (channel == "opacity") bits->push_back(client::kOpacity);
    else {
      *why = "--channels: unknown channel '" + channel + "' (colour, depth, normals, opacity)";
      return false;
    }
  }
  if (bits->empty()) *why = "--channels: nothing to render";
  return !bits->empty();
}

// A render from a running server: the panels are the server's images (depth shown in colour).
int render_from_server(const RenderArgs& args, const std::vector<std::uint32_t>& bits) {
  std::string why;
  client::RenderQuery query;
  query.map_name = args.map;
  if (!parse_view(args.pose, args.frame, args.camera, &query, &why)) return fail(why);
  query.channels = 0;
  for (std::uint32_t bit : bits) query.channels |= bit;
  query.depth_scale = 1000.0f;
  client::ClientOptions options;
  if (!args.client.locate(args.map, false, &options, &why)) return fail(why);
  client::Client client(options);
  client::RenderOutput out;
  if (!client.render(query, &out, args.client.timeout_ms(), &why)) return fail(why);
  std::vector<cv::Mat> panels;
  for (std::uint32_t bit : bits) {
    for (client::RenderedImage& image : out.images) {
      if (image.channel != bit) continue;
      const int h = static_cast<int>(image.height), w = static_cast<int>(image.width);
      if (bit == client::kDepth) {
        cv::Mat metres;
        cv::Mat(h, w, CV_16UC1, image.pixels.data()).convertTo(metres, CV_32FC1, 1.0 / query.depth_scale);
        panels.push_back(server::depth_to_rgb8(metres, args.max_depth));
      } else if (bit == client::kOpacity) {
        cv::Mat rgb;
        cv::cvtColor(cv::Mat(h, w, CV_8UC1, image.pixels.data()), rgb, cv::COLOR_GRAY2RGB);
        panels.push_back(rgb);
      } else {
        panels.push_back(cv::Mat(h, w, CV_8UC3, image.pixels.data()).clone());
      }
    }
  }
  cv::Mat image;
  cv::hconcat(panels, image);
  if (!core::write_image(args.out, image, &why)) return fail(why);
  std::printf("rendered map '%s' (version %llu, %llu Gaussians) at %ux%u from (%.3f, %.3f, %.3f) -> %s\n",
              args.map.c_str(), static_cast<unsigned long long>(out.map_version),
              static_cast<unsigned long long>(out.map_gaussians), out.intrinsics.width,
              out.intrinsics.height, out.translation[0], out.translation[1], out.translation[2],
              args.out.c_str());
  return 0;
}

int run_render(const RenderArgs& args) {
  std::string why;
  std::vector<std::uint32_t> bits;
  if (!parse_channels(args.channels, &bits, &why)) return fail(why);
  if (args.ply.empty() == args.map.empty()) return fail("give exactly one of --map and --ply");
  if (args.pose.empty() == (args.frame < 0)) return fail("give exactly one of --pose and --frame");
  if (!args.map.empty()) return render_from_server(args, bits);
  if (args.dataset.path.empty()) return fail("--ply needs --dataset (for the camera)");
  core::DatasetOptions options;
  auto dataset = open_dataset(args.dataset, &options, &why);
  if (!dataset) return fail(why);
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
      const core::StampedPose* best = core::nearest_pose(trajectory, dataset->timestamp(i));
      if (!best) {
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
  auto rasterizer = server::make_rasterizer("auto", server::RasterUse::kRender, &notice, &why);
  if (!rasterizer) return fail(why);
  core::RenderView view;
  view.camera = dataset->camera();
  view.T_camera_world = T_world_camera.inverse();
  core::RenderSettings settings;
  settings.features = false;
  core::RenderResult r;
  if (!rasterizer->forward(map, view, settings, &r, &why)) return fail(why);

  std::vector<cv::Mat> panels;
  for (std::uint32_t bit : bits) {
    if (bit == client::kColour) panels.push_back(server::colour_to_rgb8(r.colour));
    if (bit == client::kDepth) panels.push_back(server::depth_to_rgb8(server::plane_to_mat(r.median_depth, 0), args.max_depth));
    if (bit == client::kNormals) panels.push_back(server::normals_to_rgb8(r.median_depth, view.camera.intrinsics()));
    if (bit == client::kOpacity) panels.push_back(server::opacity_to_rgb8(r.alpha));
  }
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
      "render", "Render a served map (--map) or a saved map.ply (--ply) from a pose or a frame's "
                "pose; channels side by side in one PNG");
  auto args = std::make_shared<RenderArgs>();
  app->add_option("--map", args->map, "A map the running server serves");
  app->add_option("--camera", args->camera,
                  "With --map: fx,fy,cx,cy,width,height (default: the camera the map was built with)");
  add_client_options(app, &args->client);
  app->add_option("--ply", args->ply, "A saved map (3DGS PLY, e.g. fslam run's map.ply), with --dataset");
  add_dataset_options(app, &args->dataset, false);
  app->add_option("--pose", args->pose, "Camera-to-world pose tx,ty,tz,qx,qy,qz,qw");
  app->add_option("--frame", args->frame,
                  "Render from frame N's pose: tracked by the server (--map), or the dataset's (--ply)");
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
