// The command-line options of `fslam-server` and `fslam serve` (one definition for both).
#pragma once

#include <string>

#include "fslam/server/config_options.hpp"
#include "fslam/server/server.hpp"

namespace CLI {
class App;
}

namespace fslam::server {

struct ServeOptions {
  ConfigOptions config;  // --config, --set, --prefix, --queue, --status-period
  int domain = -1;       // --domain, -1: Cyclone's default

  // The server's configuration from the defaults and the command line, validated.
  bool resolve(ServerConfig* config_out, std::string* why) const;
};

void add_server_options(CLI::App* app, ServeOptions* options);

// Resolves the options, prints the effective configuration and serves until SIGINT or SIGTERM;
// returns the exit code (1 for a bad configuration, as for any other start-up error).
int serve(const ServeOptions& options);

}  // namespace fslam::server
