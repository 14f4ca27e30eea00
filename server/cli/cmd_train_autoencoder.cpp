// `fslam train-autoencoder`: pretrains the feature autoencoder (paper sec. "Online Feature
// Rasterization": "pretrained on unrelated datasets") on the feature pyramids of a folder of
// images, and writes the weights the mapper loads. docs/features_autoencoder.md.
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "commands.hpp"
#include "fslam/core/build_config.hpp"
#include "fslam/core/features/feature_autoencoder.hpp"
#include "fslam/core/features/feature_encoder.hpp"

namespace fslam::cli {
namespace {

namespace fs = std::filesystem;

struct TrainAutoencoderArgs {
  std::vector<std::string> images;
  std::vector<std::string> held_out;  // empty: every 10th image of `images`
  std::string encoder = "builtin";
  std::string onnx_model;
  int input_size = 0;  // 0: the encoder's default
  std::string out;
  core::AutoencoderPretrainOptions pretrain;
  int latent = core::FeatureAutoencoderConfig{}.latent_dim;
  int max_images = 0;  // 0: all
  int threads = 0;     // 0: OpenCV's default
};

bool is_image(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg";
}

// Images under `path`, sorted. A folder with an rgb/ subfolder is a TUM-layout sequence and
// contributes rgb/ only (its depth and label PNGs are not colour images).
void collect_images(const fs::path& path, std::vector<fs::path>* out) {
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) {
    if (is_image(path)) out->push_back(path);
    return;
  }
  if (fs::is_directory(path / "rgb", ec)) return collect_images(path / "rgb", out);
  std::vector<fs::path> entries;
  for (auto it = fs::directory_iterator(path, ec); !ec && it != fs::directory_iterator();
       it.increment(ec))
    entries.push_back(it->path());
  std::sort(entries.begin(), entries.end());
  for (const auto& entry : entries) {
    if (fs::is_directory(entry, ec)) collect_images(entry, out);
    else if (is_image(entry)) out->push_back(entry);
  }
}

int run_train_autoencoder(const TrainAutoencoderArgs& args) {
  std::string why;
  core::FeatureEncoderConfig encoder_config;
  if (!core::parse_feature_backend(args.encoder, &encoder_config.backend, &why)) return fail(why);
  encoder_config.onnx.model_path = args.onnx_model;
  if (args.input_size > 0) {
    encoder_config.builtin.input_width = encoder_config.builtin.input_height = args.input_size;
    encoder_config.onnx.input_width = encoder_config.onnx.input_height = args.input_size;
  }
  if (!encoder_config.is_valid(&why)) return fail(why);
  if (!args.pretrain.is_valid(&why)) return fail(why);
  if (args.threads > 0) cv::setNumThreads(args.threads);

  std::vector<fs::path> files, held_out_files;
  for (const auto* list : {&args.images, &args.held_out}) {
    const std::string option = list == &args.images ? "--images" : "--held-out";
    auto* found = list == &args.images ? &files : &held_out_files;
    for (const auto& dir : *list) {
      if (!fs::exists(dir)) return fail(option + ": " + dir + " does not exist");
      collect_images(dir, found);
    }
    if (found->empty() && !list->empty())
      return fail("no PNG or JPEG images found under the " + option + " folders (a folder with "
                  "an rgb/ subfolder is read as a TUM-layout sequence: rgb/ only)");
    if (args.max_images > 0 && found->size() > static_cast<std::size_t>(args.max_images)) {
      // An even spread over the list rather than its first frames.
      std::vector<fs::path> spread;
      for (int i = 0; i < args.max_images; ++i)
        spread.push_back((*found)[found->size() * i / args.max_images]);
      *found = std::move(spread);
    }
  }

  std::unique_ptr<core::FeatureEncoder> encoder = core::make_feature_encoder(encoder_config, &why);
  if (!encoder) return fail(why);
  core::FeatureAutoencoderConfig config;
  config.level_channels.clear();
  for (const auto& s : encoder->level_shapes()) config.level_channels.push_back(s.channels);
  config.latent_dim = args.latent;
  config.seed = args.pretrain.seed;
  if (!config.is_valid(&why)) return fail(why);

  // Without --held-out, every 10th image (the last one when there are fewer than 10) is held
  // out for the before/after error; the others are sampled for training.
  const std::size_t own = files.size();
  const auto held_out_image = [&](std::size_t i) {
    if (i >= own) return true;  // from --held-out
    if (!held_out_files.empty()) return false;
    return own >= 10 ? i % 10 == 9 : own >= 2 && i + 1 == own;
  };
  files.insert(files.end(), held_out_files.begin(), held_out_files.end());
  std::fprintf(stderr, "encoding %zu images with %s\n", files.size(), encoder->describe().c_str());
  std::vector<float> train, held_out;
  std::size_t train_images = 0, held_out_images = 0;
  std::mt19937 rng(args.pretrain.seed);
  core::FeaturePyramid pyramid;
  Progress encode_progress("encode", files.size());
  for (std::size_t i = 0; i < files.size(); ++i) {
    const cv::Mat bgr = cv::imread(files[i].string(), cv::IMREAD_COLOR);
    if (bgr.empty()) return fail("cannot read image " + files[i].string());
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    if (!encoder->encode(rgb, &pyramid, &why)) return fail(files[i].string() + ": " + why);
    const bool hold = held_out_image(i);
    core::sample_training_features(pyramid, args.pretrain.pixels_per_image, &rng,
                                   hold ? &held_out : &train);
    ++(hold ? held_out_images : train_images);
    encode_progress.update(i + 1);
  }
  encode_progress.finish();

  core::FeatureAutoencoder autoencoder(config);
  core::AutoencoderPretrainStats stats;
  Progress train_progress("train", static_cast<std::size_t>(args.pretrain.steps));
  double last_loss = 0.0;
  if (!core::pretrain_autoencoder_on_samples(
          train, held_out.empty() ? nullptr : &held_out, args.pretrain, &autoencoder,
          [&](int done, int, double loss) {
            last_loss = loss;
            train_progress.update(static_cast<std::size_t>(done));
          },
          &stats, &why))
    return fail(why);
  train_progress.finish();

  std::string dirs;
  for (const auto& d : args.images) dirs += (dirs.empty() ? "" : ", ") + d;
  autoencoder.set_notes(
      "fslam " FSLAM_VERSION " train-autoencoder; encoder: " + encoder->describe() + "; " +
      std::to_string(train_images) + " training images (" +
      std::to_string(args.pretrain.pixels_per_image) + " pixels each) from " + dirs + "; steps " +
      std::to_string(args.pretrain.steps) + ", batch " + std::to_string(args.pretrain.batch) +
      ", seed " + std::to_string(args.pretrain.seed));
  if (!autoencoder.save(args.out, &why)) return fail(why);

  std::printf("reconstruction error (mean |u_hat - u| in channel standard deviations, levels "
              "weighted equally):\n");
  std::printf("  training samples (%zu images): %.4f -> %.4f (last batches %.4f)\n", train_images,
              stats.train_error_before, stats.train_error_after, last_loss);
  if (held_out_images > 0)
    std::printf("  held-out images (%zu):          %.4f -> %.4f\n", held_out_images,
                stats.held_out_error_before, stats.held_out_error_after);
  else
    std::printf("  held-out images: none (one training image and no --held-out)\n");
  std::printf("wrote %s: %d -> %d -> %d latent, level channels", args.out.c_str(),
              config.input_dim(), config.encoder_hidden, config.latent_dim);
  for (int c : config.level_channels) std::printf(" %d", c);
  std::printf(", %.1f KiB\n", static_cast<double>(fs::file_size(args.out)) / 1024.0);
  return 0;
}

}  // namespace

void add_train_autoencoder_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "train-autoencoder",
      "Pretrain the feature autoencoder on the encoder's pyramids of a set of images and write "
      "its weights (docs/features_autoencoder.md)");
  auto args = std::make_shared<TrainAutoencoderArgs>();
  app->add_option("--images", args->images,
                  "Folders (searched recursively; TUM-layout sequences: rgb/ only) or files of "
                  "PNG/JPEG training images")
      ->required()
      ->expected(1, -1);
  app->add_option("--held-out", args->held_out,
                  "Folders or files of images only evaluated (e.g. another scene); without it "
                  "every 10th training image is held out")
      ->expected(1, -1);
  app->add_option("--encoder", args->encoder, "Image feature encoder: builtin or onnx")
      ->check(CLI::IsMember({"builtin", "onnx"}))
      ->capture_default_str();
  app->add_option("--onnx-model", args->onnx_model, "ONNX encoder model (with --encoder onnx)");
  app->add_option("--input-size", args->input_size,
                  "Encoder input width and height in pixels; 0 keeps the encoder's default "
                  "(1024). Use the size the SLAM run will use")
      ->check(CLI::Range(0, 16384))
      ->capture_default_str();
  app->add_option("--out", args->out, "Weights file to write (.fae)")->required();
  app->add_option("--steps", args->pretrain.steps, "Adam steps")
      ->check(CLI::Range(1, 10000000))
      ->capture_default_str();
  app->add_option("--batch", args->pretrain.batch, "Samples per step")
      ->check(CLI::Range(1, 1 << 20))
      ->capture_default_str();
  app->add_option("--lr", args->pretrain.learning_rate,
                  "Adam learning rate (cosine-decayed to a tenth)")
      ->capture_default_str();
  app->add_option("--pixels-per-image", args->pretrain.pixels_per_image,
                  "Random pixels sampled from each image")
      ->check(CLI::Range(1, 1 << 24))
      ->capture_default_str();
  app->add_option("--latent", args->latent, "Latent size D (the weights file carries it; maps built with it have D channels)")
      ->check(CLI::Range(1, 1024))
      ->capture_default_str();
  // CLI11 2.1 reads "-1" into an unsigned option as 2^32 - 1; refuse it instead.
  const CLI::Validator unsigned_integer(
      [](std::string& text) {
        return text.find_first_not_of("0123456789") == std::string::npos && !text.empty()
                   ? std::string()
                   : "expected a non-negative integer, got '" + text + "'";
      },
      "");
  app->add_option("--seed", args->pretrain.seed, "Seed of the weights, pixels and batches")
      ->check(unsigned_integer)
      ->capture_default_str();
  app->add_option("--max-images", args->max_images,
                  "Use at most this many images, evenly spread over the sorted list; 0 = all")
      ->check(CLI::Range(0, 1 << 30))
      ->capture_default_str();
  app->add_option("--threads", args->threads, "OpenCV threads for encoding; 0 = OpenCV's default")
      ->check(CLI::Range(0, 4096))
      ->capture_default_str();
  commands->push_back({app, [args] { return run_train_autoencoder(*args); }});
}

}  // namespace fslam::cli
