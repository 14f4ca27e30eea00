// The options every command that talks to a running server shares: --prefix and --timeout.
#pragma once

#include <string>

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

// "tx,ty,tz,qx,qy,qz,qw" -> 7 finite numbers with a unit quaternion; `why` names the flag.
bool parse_pose_text(const std::string& text, double translation[3], double rotation[4],
                     std::string* why);

}  // namespace fslam::cli
