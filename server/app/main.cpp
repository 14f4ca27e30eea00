// `fslam-server`: runs the featureslam service until SIGINT or SIGTERM. The network profile comes
// from CYCLONEDDS_URI (on these machines always configs/dds/loopback.xml).
#include <CLI/CLI.hpp>

#include "fslam/server/serve_options.hpp"
#include "fslam/server/server.hpp"

int main(int argc, char** argv) {
  CLI::App app{"featureslam server: SLAM sessions over Cyclone DDS"};
  fslam::server::ServerConfig config;
  int domain = -1;
  fslam::server::add_server_options(&app, &config, &domain);
  CLI11_PARSE(app, argc, argv);
  if (domain >= 0) config.domain = static_cast<dds_domainid_t>(domain);
  return fslam::server::serve_until_signal(config);
}
