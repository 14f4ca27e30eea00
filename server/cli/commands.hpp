// Subcommands of the `fslam` tool. Each add_*_command registers its options on the root app and
// appends how to run it; main() runs the one that was parsed and turns exceptions into exit codes.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "fslam/core/eval/percentile.hpp"

namespace CLI {
class App;
}

namespace fslam::cli {

struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;  // returns the process exit code
};
using CommandList = std::vector<Command>;

void add_version_command(CLI::App& root, CommandList* commands);
void add_synth_command(CLI::App& root, CommandList* commands);
void add_eval_command(CLI::App& root, CommandList* commands);
void add_info_command(CLI::App& root, CommandList* commands);
void add_calibrate_colour_command(CLI::App& root, CommandList* commands);
void add_track_command(CLI::App& root, CommandList* commands);
void add_run_command(CLI::App& root, CommandList* commands);
void add_render_command(CLI::App& root, CommandList* commands);
void add_segment_command(CLI::App& root, CommandList* commands);
void add_stream_command(CLI::App& root, CommandList* commands);
void add_serve_command(CLI::App& root, CommandList* commands);
void add_map_commands(CLI::App& root, CommandList* commands);  // status, save-map, load-map
void add_segment_eval_command(CLI::App& root, CommandList* commands);
void add_train_autoencoder_command(CLI::App& root, CommandList* commands);

using core::percentile;  // fslam/core/eval/percentile.hpp

// Prints "fslam: error: <message>" to stderr and returns exit code 1.
int fail(const std::string& message);

// A progress line on stderr: rewritten in place on a terminal, every 10% otherwise.
class Progress {
 public:
  Progress(std::string label, std::size_t total);
  void update(std::size_t done);
  void finish();

 private:
  std::string label_;
  std::size_t total_;
  bool tty_;
  int last_decile_ = -1;
  double start_s_;
};

}  // namespace fslam::cli
