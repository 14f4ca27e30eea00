// The options every command that talks to a running server shares: --prefix and --timeout.
#pragma once

#include <string>
#include <vector>

#include "fslam/client/client.hpp"

namespace CLI {
class App;
}

namespace fslam::cli {

// How a command finds the server instance of its map in the deployment's map directory
// (docs/deployment.md "Scale-out"): --instance, --discovery-ms.
struct DiscoveryArgs {
  std::string instance;  // talk to this instance, whatever the directory says of the map
  int settle_ms = 500;   // directory discovery ends this long after the last new instance
};

void add_discovery_options(CLI::App* app, DiscoveryArgs* args);

// The client options for talking about `map` on deployment `prefix`: the service prefix of the
// instance that serves it, or (allow_new) of the instance that creates it. False with `why` when
// no instance serves the map (nor would create it), or no server answered within timeout_ms.
bool locate_service(const std::string& prefix, const DiscoveryArgs& discovery, const std::string& map,
                    bool allow_new, int timeout_ms, client::ClientOptions* options, std::string* why);

struct ClientArgs {
  std::string prefix = "fslam";  // the deployment's topic prefix
  int timeout_s = 30;            // per request, including discovery of the server
  DiscoveryArgs discovery;

  int timeout_ms() const { return timeout_s * 1000; }
  bool locate(const std::string& map, bool allow_new, client::ClientOptions* options,
              std::string* why) const {
    return locate_service(prefix, discovery, map, allow_new, timeout_ms(), options, why);
  }
};

// --prefix, --timeout and the discovery options.
void add_client_options(CLI::App* app, ClientArgs* args);

// "a,b,c" -> finite numbers; `why` names `flag`.
bool parse_numbers(const std::string& text, const std::string& flag, std::vector<double>* values,
                   std::string* why);
// "tx,ty,tz,qx,qy,qz,qw" -> 7 finite numbers with a unit quaternion; `why` names the flag.
bool parse_pose_text(const std::string& text, double translation[3], double rotation[4],
                     std::string* why);
// "fx,fy,cx,cy,width,height" (--camera).
bool parse_camera_text(const std::string& text, client::CameraIntrinsics* camera, std::string* why);
// The view of a query on a served map: exactly one of --pose and --frame (frame < 0: not
// given), and --camera when not empty (else the camera the map was built with).
bool parse_view(const std::string& pose, long long frame, const std::string& camera,
                client::CameraView* view, std::string* why);

}  // namespace fslam::cli
