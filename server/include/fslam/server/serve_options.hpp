// The command-line options of `fslam-server` and `fslam serve` (one definition for both).
#pragma once

#include "fslam/server/server.hpp"

namespace CLI {
class App;
}

namespace fslam::server {

// --prefix, --domain (written to *domain, -1 = Cyclone's default), --queue, --status-period.
void add_server_options(CLI::App* app, ServerConfig* config, int* domain);

}  // namespace fslam::server
