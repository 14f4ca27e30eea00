// The options every command that talks to a running server shares: --prefix and --timeout.
#pragma once

#include <string>
#include <vector>

#include "fslam/client/client.hpp"

namespace CLI {
class App;
}

namespace fslam::cli {

struct ClientArgs {
  std::string prefix = "fslam";  // the server's topic prefix
  int timeout_s = 30;            // per request, including discovery of the server

  client::ClientOptions options() const {
    client::ClientOptions o;
    o.prefix = prefix;
    return o;
  }
  int timeout_ms() const { return timeout_s * 1000; }
};

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
