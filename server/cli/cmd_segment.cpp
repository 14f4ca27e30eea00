// `fslam segment`: segmentation queries on a served map (docs/segmentation.md). Without a prompt
// it writes the map's instances (colour-coded, plus the 16-bit ids); with points, boxes or a text
// it writes the object's mask. --overlay draws the result over the rendered colour.
#include <cmath>
#include <cstdio>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "client_args.hpp"
#include "commands.hpp"
#include "fslam/client/client.hpp"
#include "fslam/core/io/image_io.hpp"

namespace fslam::cli {
namespace {

struct SegmentArgs {
  std::string map;
  ClientArgs client;
  std::string pose, camera;  // the prompt view (and the result's, unless --out-pose/--out-frame)
  long long frame = -1;
  std::string out_pose;
  long long out_frame = -1;
  std::string points, boxes, text;
  std::string out, overlay;
};

// A colour per instance id, far apart for neighbouring ids (golden-ratio hues); black for 0.
cv::Vec3b id_colour(int id) {
  if (id <= 0) return {0, 0, 0};
  const double hue = std::fmod(static_cast<double>(id) * 0.618033988749895, 1.0);
  cv::Mat hsv(1, 1, CV_8UC3, cv::Scalar(hue * 180.0, 200, 255)), rgb;
  cv::cvtColor(hsv, rgb, cv::COLOR_HSV2RGB);
  return rgb.at<cv::Vec3b>(0, 0);
}

// labels: CV_32SC1, 0 = nothing. Colour-coded ids, RGB.
cv::Mat colour_ids(const cv::Mat& labels) {
  cv::Mat rgb(labels.size(), CV_8UC3);
  for (int v = 0; v < labels.rows; ++v)
    for (int u = 0; u < labels.cols; ++u) rgb.at<cv::Vec3b>(v, u) = id_colour(labels.at<int>(v, u));
  return rgb;
}

// The labels blended half over the colour render, each region's boundary outlined in yellow.
cv::Mat overlay(const cv::Mat& colour, const cv::Mat& labels) {
  cv::Mat out = colour.clone();
  const cv::Vec3b outline(255, 255, 0);
  for (int v = 0; v < labels.rows; ++v)
    for (int u = 0; u < labels.cols; ++u) {
      const int id = labels.at<int>(v, u);
      if (id > 0) {
        const cv::Vec3b c = id_colour(id);
        cv::Vec3b& p = out.at<cv::Vec3b>(v, u);
        for (int k = 0; k < 3; ++k) p[k] = static_cast<std::uint8_t>((p[k] + c[k] + 1) / 2);
      }
      // A boundary pixel: a labelled pixel with a differently labelled 4-neighbour.
      bool edge = false;
      if (id > 0) {
        if (u > 0 && labels.at<int>(v, u - 1) != id) edge = true;
        if (u + 1 < labels.cols && labels.at<int>(v, u + 1) != id) edge = true;
        if (v > 0 && labels.at<int>(v - 1, u) != id) edge = true;
        if (v + 1 < labels.rows && labels.at<int>(v + 1, u) != id) edge = true;
      }
      if (edge) out.at<cv::Vec3b>(v, u) = outline;
    }
  return out;
}

// "<out>.ids.png" without the extension repeated: seg.png -> seg.ids.png.
std::string ids_path(const std::string& out) {
  const auto dot = out.rfind('.');
  const auto slash = out.rfind('/');
  const bool has_ext = dot != std::string::npos && (slash == std::string::npos || dot > slash);
  return (has_ext ? out.substr(0, dot) : out) + ".ids.png";
}

int run_segment(const SegmentArgs& args) {
  std::string why;
  client::SegmentQuery query;
  query.map_name = args.map;
  if (!parse_view(args.pose, args.frame, args.camera, &query.view, &why)) return fail(why);
  if (!args.out_pose.empty() || args.out_frame >= 0) {
    query.has_output_view = true;
    if (!parse_view(args.out_pose, args.out_frame, args.camera, &query.output_view, &why)) {
      return fail("--out-pose / --out-frame: " + why);
    }
  }
  const int prompts = !args.points.empty() + !args.boxes.empty() + !args.text.empty();
  if (prompts > 1) return fail("give at most one of --points, --boxes and --text");
  std::vector<double> values;
  if (!args.points.empty()) {
    query.mode = client::SegmentMode::points;
    if (!parse_numbers(args.points, "--points", &values, &why)) return fail(why);
    if (values.empty() || values.size() % 2 != 0) return fail("--points expects u,v pairs");
    query.points.assign(values.begin(), values.end());
  } else if (!args.boxes.empty()) {
    query.mode = client::SegmentMode::boxes;
    if (!parse_numbers(args.boxes, "--boxes", &values, &why)) return fail(why);
    if (values.empty() || values.size() % 4 != 0) return fail("--boxes expects u0,v0,u1,v1 quadruples");
    query.boxes.assign(values.begin(), values.end());
  } else if (!args.text.empty()) {
    query.mode = client::SegmentMode::text;
    query.text = args.text;
  }
  client::ClientOptions options;
  if (!args.client.locate(args.map, false, &options, &why)) return fail(why);
  client::Client client(options);
  client::SegmentOutput out;
  if (!client.segment(query, &out, args.client.timeout_ms(), &why)) return fail(why);

  const int h = static_cast<int>(out.labels.height), w = static_cast<int>(out.labels.width);
  cv::Mat colour(static_cast<int>(out.colour.height), static_cast<int>(out.colour.width), CV_8UC3,
                 out.colour.pixels.data());
  cv::Mat labels;  // CV_32SC1, 0 = nothing
  std::string summary;
  if (query.mode == client::SegmentMode::promptless) {
    const cv::Mat ids(h, w, CV_16UC1, out.labels.pixels.data());
    ids.convertTo(labels, CV_32SC1);
    std::set<int> seen(labels.begin<int>(), labels.end<int>());
    seen.erase(0);
    if (!core::write_image(args.out, colour_ids(labels), &why) ||
        !core::write_image(ids_path(args.out), ids, &why)) {
      return fail(why);
    }
    summary = std::to_string(seen.size()) + " instances in view -> " + args.out + " (ids + 1: " +
              ids_path(args.out) + ")";
  } else {
    const cv::Mat mask(h, w, CV_8UC1, out.labels.pixels.data());
    mask.convertTo(labels, CV_32SC1, 1.0 / 255.0);
    if (!core::write_image(args.out, mask, &why)) return fail(why);
    summary = "mask of " + std::to_string(cv::countNonZero(mask)) + " pixels -> " + args.out;
  }
  if (!args.overlay.empty()) {
    if (!core::write_image(args.overlay, overlay(colour, labels), &why)) return fail(why);
    summary += ", overlay -> " + args.overlay;
  }
  std::printf("segmented map '%s' (version %llu, %llu Gaussians) at %dx%d: %s\n", args.map.c_str(),
              static_cast<unsigned long long>(out.map_version),
              static_cast<unsigned long long>(out.map_gaussians), w, h, summary.c_str());
  return 0;
}

}  // namespace

void add_segment_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "segment", "Segment a served map from a view: instances without a prompt, or the object "
                 "under --points, --boxes or --text; writes ids or a mask (docs/segmentation.md)");
  auto args = std::make_shared<SegmentArgs>();
  app->add_option("--map", args->map, "A map the running server serves")->required();
  app->add_option("--pose", args->pose, "The view: camera-to-world pose tx,ty,tz,qx,qy,qz,qw");
  app->add_option("--frame", args->frame, "The view: the server's tracked pose of frame N");
  app->add_option("--camera", args->camera,
                  "fx,fy,cx,cy,width,height (default: the camera the map was built with)");
  app->add_option("--points", args->points, "Point prompts u,v[,u,v...] (pixels of the view)");
  app->add_option("--boxes", args->boxes, "Box prompts u0,v0,u1,v1[,...] (pixels of the view)");
  app->add_option("--text", args->text, "A text prompt (the server needs server.grounding_model)");
  app->add_option("--out-pose", args->out_pose,
                  "Render the result from this pose instead (prompts stay in the --pose/--frame view)");
  app->add_option("--out-frame", args->out_frame, "Render the result from frame N's tracked pose instead");
  app->add_option("--out", args->out,
                  "PNG to write: the mask (255 = object), or without a prompt the colour-coded "
                  "instances (and their 16-bit ids + 1 in <out>.ids.png)")
      ->required();
  app->add_option("--overlay", args->overlay, "PNG of the result blended over the rendered colour");
  add_client_options(app, &args->client);
  commands->push_back({app, [args] { return run_segment(*args); }});
}

}  // namespace fslam::cli
