#include <tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>

#include "commands.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::cli {
namespace {

struct SynthArgs {
  std::string out;
  std::size_t frames = core::SynthOptions{}.frames;
  std::uint64_t seed = core::SynthOptions{}.seed;
  std::string noise = core::to_string(core::SynthOptions{}.noise);
  std::string scene = core::to_string(core::SynthOptions{}.scene);
  std::string path = core::to_string(core::SynthOptions{}.path);
  int laps = core::SynthOptions{}.laps;
  int threads = 0;
};

std::uintmax_t folder_bytes(const std::filesystem::path& dir) {
  std::uintmax_t total = 0;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(dir, ec);
       !ec && it != std::filesystem::recursive_directory_iterator(); it.increment(ec))
    if (it->is_regular_file(ec)) total += it->file_size(ec);
  return total;
}

int run_synth(const SynthArgs& args) {
  core::SynthOptions options;
  options.frames = args.frames;
  options.seed = args.seed;
  std::string why;
  if (!core::parse_synth_noise(args.noise, &options.noise, &why)) return fail(why);
  if (!core::parse_synth_scene(args.scene, &options.scene, &why)) return fail(why);
  if (!core::parse_synth_path(args.path, &options.path, &why)) return fail(why);
  options.laps = args.laps;
  if (!options.is_valid(&why)) return fail(why);

  std::optional<tbb::global_control> threads;
  if (args.threads > 0)
    threads.emplace(tbb::global_control::max_allowed_parallelism,
                    static_cast<std::size_t>(args.threads));
  Progress progress("synth", options.frames);
  if (!core::write_synthetic_sequence(
          args.out, options, [&](std::size_t done, std::size_t) { progress.update(done); }, &why))
    return fail(why);
  progress.finish();

  const double mib = static_cast<double>(folder_bytes(args.out)) / (1024.0 * 1024.0);
  std::printf("wrote %zu frames (%dx%d, seed %llu, noise %s, scene %s, path %s, %.1f MiB) to %s\n", options.frames,
              options.camera.width, options.camera.height,
              static_cast<unsigned long long>(options.seed), core::to_string(options.noise),
              core::to_string(options.scene), core::to_string(options.path), mib,
              std::filesystem::absolute(args.out).c_str());
  return 0;
}

}  // namespace

void add_synth_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "synth",
      "Render a procedural indoor RGB-D sequence in TUM layout: colour, depth (16-bit, metres * "
      "5000), instance and class labels, ground-truth poses (docs/datasets.md)");
  auto args = std::make_shared<SynthArgs>();
  app->add_option("--out", args->out, "Output folder; created, must be empty if it exists")
      ->required();
  app->add_option("--frames", args->frames, "Number of frames at 30 Hz")
      ->check(CLI::Range(std::size_t{1}, core::SynthOptions::kMaxFrames))
      ->capture_default_str();
  // CLI11 2.1 reads "-1" into an unsigned option as 2^64 - 1; refuse it instead.
  const CLI::Validator unsigned_integer(
      [](std::string& text) {
        return text.find_first_not_of("0123456789") == std::string::npos && !text.empty()
                   ? std::string()
                   : "expected a non-negative integer, got '" + text + "'";
      },
      "");
  app->add_option("--seed", args->seed, "Seed of the room, trajectory and noise")
      ->check(unsigned_integer)
      ->capture_default_str();
  app->add_option("--noise", args->noise, "Depth and colour noise: kinect or none (exact)")
      ->check(CLI::IsMember({"kinect", "none"}))
      ->capture_default_str();
  app->add_option("--scene", args->scene,
                  "Scene: room (one furnished room), hall (about 13 x 8 m, furnished on both long "
                  "sides: its loop leaves the tracker's local map) or ring (a 2.5-m corridor round a "
                  "walled block, about 14 x 9 m: its loop looks ahead and sees each place only when passing)")
      ->check(CLI::IsMember({"room", "hall", "ring"}))
      ->capture_default_str();
  app->add_option("--path", args->path,
                  "Camera path: wander (through the room) or loop (laps of one closed loop, back "
                  "to the start pose after each)")
      ->check(CLI::IsMember({"wander", "loop"}))
      ->capture_default_str();
  app->add_option("--laps", args->laps, "Laps of the loop path in --frames")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app->add_option("--threads", args->threads, "Worker threads; 0 uses every core")
      ->check(CLI::Range(0, 4096))
      ->capture_default_str();
  commands->push_back({app, [args] { return run_synth(*args); }});
}

}  // namespace fslam::cli
