#include <iostream>

#include <CLI/CLI.hpp>

#include "commands.hpp"
#include "fslam/core/build_config.hpp"
#include "fslam/server/backend_factory.hpp"

namespace fslam::cli {

void add_version_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand("version", "Print the version, the compiled-in backends and the "
                                             "backend this machine would use");
  auto backend = std::make_shared<std::string>("auto");
  app->add_option("--backend", *backend, "Backend to try: auto, cpu or cuda")
      ->check(CLI::IsMember({"auto", "cpu", "cuda"}));
  commands->push_back({app, [backend] {
    std::cout << "featureslam " << FSLAM_VERSION << "\n"
              << "backends compiled in: cpu" << (server::cuda_compiled_in() ? ", cuda" : "")
              << "\n";
    std::string notice, why;
    auto chosen = server::make_rasterizer(*backend, server::RasterUse::kRender, &notice, &why);
    if (!chosen) return fail(why);
    if (!notice.empty()) std::cout << notice << "\n";
    std::cout << "backend in use: " << chosen->name() << " (rendering; mapping: compute.backend, docs/architecture.md)" << std::endl;
    return 0;
  }});
}

}  // namespace fslam::cli
