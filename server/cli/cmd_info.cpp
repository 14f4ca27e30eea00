// `fslam info`: what a dataset folder holds, as the readers see it, and a check of its first frame.
#include <cstdio>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>
#include <opencv2/core.hpp>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/core/dataset/dataset.hpp"

namespace fslam::cli {
namespace {

// Sum of the translations between consecutive poses, metres.
double path_length(const core::Trajectory& trajectory) {
  double length = 0.0;
  for (std::size_t i = 1; i < trajectory.size(); ++i)
    length += (trajectory[i].T_world_camera.translation() -
               trajectory[i - 1].T_world_camera.translation())
                  .norm();
  return length;
}

int run_info(const DatasetArgs& args) {
  core::DatasetOptions options;
  std::string why;
  const std::unique_ptr<core::Dataset> dataset = open_dataset(args, &options, &why);
  if (!dataset) return fail(why);

  const core::PinholeCamera& c = dataset->camera();
  const std::size_t n = dataset->size();
  const double t0 = dataset->timestamp(0);
  const double t1 = dataset->timestamp(n - 1);
  std::printf("dataset:      %s\n", dataset->root().c_str());
  std::printf("kind:         %s\n", dataset->kind().c_str());
  std::printf("frames:       %zu (selection %s), ids %lld .. %lld\n", n,
              options.frames.to_string().c_str(), static_cast<long long>(dataset->id(0)),
              static_cast<long long>(dataset->id(n - 1)));
  std::printf("intrinsics:   fx %.3f  fy %.3f  cx %.3f  cy %.3f  (%s)\n", c.fx, c.fy, c.cx, c.cy,
              dataset->camera_source().c_str());
  std::printf("image size:   %dx%d\n", c.width, c.height);
  std::printf("depth scale:  %g raw units per metre\n", dataset->depth_scale());
  std::printf("time span:    %.3f .. %.3f s (%.3f s", t0, t1, t1 - t0);
  if (n > 1 && t1 > t0) std::printf(", %.2f Hz mean", static_cast<double>(n - 1) / (t1 - t0));
  std::printf(")\n");
  if (dataset->has_ground_truth()) {
    const core::Trajectory gt = dataset->ground_truth();
    std::printf("ground truth: yes, %zu of %zu frames, path length %.3f m\n", gt.size(), n,
                path_length(gt));
  } else {
    std::printf("ground truth: no\n");
  }
  std::printf("labels:       %s\n", dataset->has_labels() ? "yes" : "no");

  core::RgbdFrame frame;
  if (!dataset->load(0, &frame, &why)) return fail(why);
  const cv::Mat valid = frame.depth > 0.0f;
  const int valid_count = cv::countNonZero(valid);
  std::printf("first frame:  id %lld at %.3f s, valid depth %.1f %%",
              static_cast<long long>(frame.id), frame.timestamp,
              100.0 * valid_count / static_cast<double>(frame.depth.total()));
  if (valid_count > 0) {
    double lo = 0.0, hi = 0.0;
    cv::minMaxLoc(frame.depth, &lo, &hi, nullptr, nullptr, valid);
    std::printf(", depth %.3f .. %.3f m", lo, hi);
  }
  std::printf("\n");
  return 0;
}

}  // namespace

void add_info_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "info",
      "Describe a dataset folder (kind, frames, intrinsics, ground truth) and check its "
      "first frame");
  auto args = std::make_shared<DatasetArgs>();
  add_dataset_options(app, args.get());
  commands->push_back({app, [args] { return run_info(*args); }});
}

}  // namespace fslam::cli
