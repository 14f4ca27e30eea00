// `fslam serve`: the same service as `fslam-server`, from the one tool.
#include <memory>

#include <CLI/CLI.hpp>

#include "commands.hpp"
#include "fslam/server/serve_options.hpp"
#include "fslam/server/server.hpp"

namespace fslam::cli {

void add_serve_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand("serve", "Run the SLAM service over DDS until Ctrl-C (as fslam-server)");
  auto config = std::make_shared<server::ServerConfig>();
  auto domain = std::make_shared<int>(-1);
  server::add_server_options(app, config.get(), domain.get());
  commands->push_back({app, [config, domain] {
                         if (*domain >= 0) config->domain = static_cast<dds_domainid_t>(*domain);
                         return server::serve_until_signal(*config);
                       }});
}

}  // namespace fslam::cli
