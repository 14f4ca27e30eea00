// `fslam-server`: runs the featureslam service until SIGINT or SIGTERM. The network profile comes
// from CYCLONEDDS_URI (on these machines always configs/dds/loopback.xml).
#include <CLI/CLI.hpp>

#include "fslam/server/serve_options.hpp"

int main(int argc, char** argv) {
  CLI::App app{"featureslam server: SLAM sessions over Cyclone DDS"};
  fslam::server::ServeOptions options;
  fslam::server::add_server_options(&app, &options);
  CLI11_PARSE(app, argc, argv);
  return fslam::server::serve(options);
}
