#include "client_args.hpp"

#include <cmath>
#include <sstream>
#include <vector>

#include <CLI/CLI.hpp>

#include "fslam/client/map_directory.hpp"
#include "fslam/core/io/text_tables.hpp"

namespace fslam::cli {

void add_discovery_options(CLI::App* app, DiscoveryArgs* args) {
  app->add_option("--instance", args->instance,
                  "Talk to this server instance (default: the one the map directory names)");
  app->add_option("--discovery-ms", args->settle_ms,
                  "Map directory: decide this long after the last server instance was discovered")
      ->capture_default_str();
}

void add_client_options(CLI::App* app, ClientArgs* args) {
  app->add_option("--prefix", args->prefix, "Topic prefix of the deployment")->capture_default_str();
  app->add_option("--timeout", args->timeout_s, "Seconds to wait for the server's answer")
      ->capture_default_str();
  add_discovery_options(app, &args->discovery);
}

bool locate_service(const std::string& prefix, const DiscoveryArgs& discovery, const std::string& map,
                    bool allow_new, int timeout_ms, client::ClientOptions* options, std::string* why) {
  const client::MapDirectory directory(prefix, options->domain);
  std::string service;
  if (!discovery.instance.empty()) {
    // The instance's own record says where it serves.
    for (const client::MapClaimInfo& e : directory.discover(discovery.settle_ms, timeout_ms)) {
      if (e.map_name.empty() && e.instance == discovery.instance) service = e.service_prefix;
    }
    if (service.empty()) {
      *why = "no server instance '" + discovery.instance + "' on prefix '" + prefix + "'";
      return false;
    }
  } else {
    client::MapLocation location;
    if (!directory.locate(map, allow_new, discovery.settle_ms, timeout_ms, &location, why)) return false;
    service = location.service_prefix;
  }
  options->prefix = service;
  return true;
}

bool parse_numbers(const std::string& text, const std::string& flag, std::vector<double>* values,
                   std::string* why) {
  values->clear();
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    double x = 0;
    if (!core::parse_double(item, &x) || !std::isfinite(x)) {
      *why = flag + ": '" + item + "' is not a number";
      return false;
    }
    values->push_back(x);
  }
  return true;
}

bool parse_pose_text(const std::string& text, double translation[3], double rotation[4],
                     std::string* why) {
  std::vector<double> v;
  if (!parse_numbers(text, "--pose", &v, why)) return false;
  if (v.size() != 7) {
    *why = "--pose expects tx,ty,tz,qx,qy,qz,qw (7 numbers), got " + std::to_string(v.size());
    return false;
  }
  const double norm = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]);
  if (std::abs(norm - 1.0) > 1e-3) {
    *why = "--pose: the quaternion is not unit length";
    return false;
  }
  for (int k = 0; k < 3; ++k) translation[k] = v[k];
  for (int k = 0; k < 4; ++k) rotation[k] = v[3 + k] / norm;
  return true;
}

bool parse_camera_text(const std::string& text, client::CameraIntrinsics* camera, std::string* why) {
  std::vector<double> v;
  if (!parse_numbers(text, "--camera", &v, why)) return false;
  if (v.size() != 6 || v[4] < 1 || v[5] < 1) {
    *why = "--camera expects fx,fy,cx,cy,width,height";
    return false;
  }
  *camera = {static_cast<float>(v[0]), static_cast<float>(v[1]), static_cast<float>(v[2]),
             static_cast<float>(v[3]), static_cast<std::uint32_t>(v[4]), static_cast<std::uint32_t>(v[5])};
  return true;
}

bool parse_view(const std::string& pose, long long frame, const std::string& camera,
                client::CameraView* view, std::string* why) {
  if (pose.empty() == (frame < 0)) {
    *why = "give exactly one of --pose and --frame";
    return false;
  }
  if (!pose.empty()) {
    if (!parse_pose_text(pose, view->translation, view->rotation, why)) return false;
  } else {
    view->from_frame = true;
    view->frame_id = static_cast<std::uint64_t>(frame);
  }
  return camera.empty() || parse_camera_text(camera, &view->intrinsics, why);
}

}  // namespace fslam::cli
