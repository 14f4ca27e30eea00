// `fslam train-autoencoder` through the real binary: a TUM-layout sequence in (rgb/ only), a
// weights file out that loads against the builtin encoder, and a clear error without images.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "cli_runner.hpp"
#include "fslam/core/features/feature_autoencoder.hpp"
#include "fslam/core/features/feature_encoder.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;

TEST(TrainAutoencoderCommand, WritesWeightsThatLoadForTheBuiltinEncoder) {
  const auto dir = test::fresh_temp_dir("ae");
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " synth --out " + (dir / "room").string() +
                            " --frames 4 --seed 103 --noise none",
                        &out, &err),
            0)
      << out << err;
  const std::string weights = (dir / "w.fae").string();
  ASSERT_EQ(run_command(fslam_bin() + " train-autoencoder --images " + (dir / "room").string() +
                            " --input-size 256 --steps 50 --batch 64 --pixels-per-image 500 "
                            "--out " + weights,
                        &out, &err),
            0)
      << out << err;
  // Four colour frames (not depth or label PNGs): three to train on, the last held out.
  EXPECT_NE(out.find("training samples (3 images)"), std::string::npos) << out;
  EXPECT_NE(out.find("held-out images (1)"), std::string::npos) << out;
  EXPECT_NE(err.find("encoding 4 images"), std::string::npos) << err;

  core::FeatureEncoderConfig encoder_config;  // the builtin encoder
  std::string why;
  const auto encoder = core::make_feature_encoder(encoder_config, &why);
  ASSERT_NE(encoder, nullptr) << why;
  core::FeatureAutoencoder ae;
  ASSERT_TRUE(ae.load(weights, encoder->level_shapes(), &why)) << why;
  EXPECT_EQ(ae.latent_dim(), 16);
  EXPECT_NE(ae.notes().find("builtin 256x256"), std::string::npos) << ae.notes();
}

TEST(TrainAutoencoderCommand, FailsClearlyWithoutImages) {
  const auto dir = test::fresh_temp_dir("ae");
  std::ofstream(dir / "notes.txt") << "not an image\n";
  std::string out, err;
  EXPECT_EQ(run_command(fslam_bin() + " train-autoencoder --images " + dir.string() + " --out " +
                            (dir / "w.fae").string(),
                        &out, &err),
            1);
  EXPECT_NE(err.find("no PNG or JPEG images"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(dir / "w.fae"));
}

}  // namespace
}  // namespace fslam
