// `fslam`: one command-line tool with subcommands, like git.
#include <exception>
#include <iostream>
#include <string>

#include <CLI/CLI.hpp>

#include "commands.hpp"
#include "fslam/core/build_config.hpp"
#include "fslam/server/process_setup.hpp"

int main(int argc, char** argv) {
  if (std::string why; !fslam::server::prepare_process(&why)) return fslam::cli::fail(why);
  CLI::App app{"featureslam " FSLAM_VERSION ": real-time feature-enriched 3DGS RGB-D SLAM"};
  app.require_subcommand(1);
  fslam::cli::CommandList commands;
  fslam::cli::add_version_command(app, &commands);
  fslam::cli::add_synth_command(app, &commands);
  fslam::cli::add_info_command(app, &commands);
  fslam::cli::add_calibrate_colour_command(app, &commands);
  fslam::cli::add_eval_command(app, &commands);
  fslam::cli::add_track_command(app, &commands);
  fslam::cli::add_run_command(app, &commands);
  fslam::cli::add_render_command(app, &commands);
  fslam::cli::add_segment_command(app, &commands);
  fslam::cli::add_stream_command(app, &commands);
  fslam::cli::add_serve_command(app, &commands);
  fslam::cli::add_map_commands(app, &commands);
  fslam::cli::add_segment_eval_command(app, &commands);
  fslam::cli::add_train_autoencoder_command(app, &commands);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);  // --help to stdout with 0, usage errors to stderr with non-zero
  }
  try {
    for (const auto& command : commands)
      if (command.app->parsed()) return command.run();
  } catch (const std::exception& e) {
    return fslam::cli::fail(e.what());
  }
  return fslam::cli::fail("no subcommand given (see fslam --help)");
}
