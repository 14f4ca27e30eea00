// `fslam serve`: the same service as `fslam-server`, from the one tool.
#include <memory>

#include <CLI/CLI.hpp>

#include "commands.hpp"
#include "fslam/server/serve_options.hpp"

namespace fslam::cli {

void add_serve_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand("serve", "Run the SLAM service over DDS until Ctrl-C (as fslam-server)");
  auto options = std::make_shared<server::ServeOptions>();
  server::add_server_options(app, options.get());
  commands->push_back({app, [options] { return server::serve(*options); }});
}

}  // namespace fslam::cli
