// `fslam-server`: runs the featureslam service until SIGINT or SIGTERM. The network profile comes
// from CYCLONEDDS_URI (on these machines always configs/dds/loopback.xml).
#include <cstdio>
#include <string>

#include <CLI/CLI.hpp>

#include "fslam/server/process_setup.hpp"
#include "fslam/server/serve_options.hpp"

int main(int argc, char** argv) {
  if (std::string why; !fslam::server::prepare_process(&why)) {
    std::fprintf(stderr, "fslam-server: %s\n", why.c_str());
    return 1;
  }
  CLI::App app{"featureslam server: SLAM sessions over Cyclone DDS"};
  fslam::server::ServeOptions options;
  fslam::server::add_server_options(&app, &options);
  CLI11_PARSE(app, argc, argv);
  return fslam::server::serve(options);
}
