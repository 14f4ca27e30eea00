// The map export's records and chunked reads (server/include/fslam/server/map_export.hpp).
#include "fslam/server/map_export.hpp"

#include <cmath>
#include <memory>

#include <gtest/gtest.h>

#include "fslam/client/client.hpp"

namespace fslam::server {
namespace {

// n Gaussians along x, 1 cm apart; Gaussian i has log scales (-4, -5, -6), opacity logit 0, a
// rotation of 90 degrees about z (w = x = ... unnormalised on purpose) and DC colour (0.2, 0.5,
// 0.9); every other one a 3D filter of 1e-4 m^2.
core::GaussianMap line_map(std::size_t n) {
  core::GaussianMap map;
  map.sh_degree = 1;  // the DC term must be found among higher-degree coefficients
  map.feature_dim = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const float mean[3] = {0.01f * static_cast<float>(i), 0.5f, 2.0f};
    const float rotation[4] = {2.0f, 0.0f, 0.0f, 2.0f};  // w, x, y, z: 90 deg about z, norm 2.83
    const float log_scale[3] = {-4.0f, -5.0f, -6.0f};
    float sh[12] = {0};
    sh[0] = core::rgb_to_sh_dc(0.2f);
    sh[1] = core::rgb_to_sh_dc(0.5f);
    sh[2] = core::rgb_to_sh_dc(0.9f);
    sh[3] = 5.0f;  // a degree-1 term: not in the record
    map.push_back(mean, rotation, log_scale, 0.0f, sh, nullptr, i % 2 == 1 ? 1e-4f : 0.0f);
  }
  return map;
}

TEST(MapExport, RecordsHoldMeansScalesRotationColourAndOpacity) {
  const core::GaussianMap map = line_map(4);
  std::vector<std::uint8_t> bytes;
  encode_gaussian_records(map, 1, 2, &bytes);
  ASSERT_EQ(bytes.size(), 2 * kGaussianRecordBytes);
  const client::GaussianRecord plain = client::unpack_gaussian(bytes.data() + kGaussianRecordBytes);  // i = 2
  EXPECT_FLOAT_EQ(plain.mean[0], 0.02f);
  EXPECT_FLOAT_EQ(plain.mean[1], 0.5f);
  EXPECT_FLOAT_EQ(plain.mean[2], 2.0f);
  EXPECT_NEAR(plain.scale[0], std::exp(-4.0f), 1e-7);
  EXPECT_NEAR(plain.scale[2], std::exp(-6.0f), 1e-7);
  EXPECT_NEAR(plain.rotation[0], std::sqrt(0.5f), 1.0f / 127);  // normalised
  EXPECT_NEAR(plain.rotation[3], std::sqrt(0.5f), 1.0f / 127);
  EXPECT_NEAR(plain.rotation[1], 0.0f, 1e-6);
  EXPECT_NEAR(plain.rgb[0], 0.2 * 255, 1.0);
  EXPECT_NEAR(plain.rgb[1], 0.5 * 255, 1.0);
  EXPECT_NEAR(plain.rgb[2], 0.9 * 255, 1.0);
  EXPECT_NEAR(plain.opacity, 0.5 * 255, 1.0);  // sigmoid(0)
  // i = 1 has the filter: 1 cm added in quadrature, opacity scaled by prod(s / s_eff).
  const client::GaussianRecord filtered = client::unpack_gaussian(bytes.data());
  double coef = 1.0;
  for (int k = 0; k < 3; ++k) {
    const double s = std::exp(-4.0 - k), s_eff = std::sqrt(s * s + 1e-4);
    EXPECT_NEAR(filtered.scale[k], s_eff, 1e-6);
    coef *= s / s_eff;
  }
  EXPECT_NEAR(filtered.opacity, 0.5 * coef * 255, 1.0);
}

TEST(MapExport, ChunksOfOneReadComeFromTheVersionItBegan) {
  core::MapVersions versions;
  versions.publish(std::make_shared<const core::GaussianMap>(line_map(10)));
  MapExporter exporter;
  ExportChunk first, second, after;
  std::string why;
  ASSERT_TRUE(exporter.chunk(versions, {0, 0, 0, 4}, &first, &why)) << why;
  EXPECT_EQ(first.version, 1u);
  EXPECT_EQ(first.total, 10u);
  EXPECT_EQ(first.count, 4u);
  EXPECT_EQ(first.records.size(), 4 * kGaussianRecordBytes);
  // The map grows meanwhile: the read goes on in version 1.
  versions.publish(std::make_shared<const core::GaussianMap>(line_map(20)));
  ASSERT_TRUE(exporter.chunk(versions, {0, 1, 8, 4}, &second, &why)) << why;
  EXPECT_EQ(second.version, 1u);
  EXPECT_EQ(second.total, 10u);
  EXPECT_EQ(second.count, 2u) << "the last chunk holds what is left";
  EXPECT_FLOAT_EQ(client::unpack_gaussian(second.records.data()).mean[0], 0.08f);
  // Nothing newer than what the reader has: no records.
  ASSERT_TRUE(exporter.chunk(versions, {2, 0, 0, 0}, &after, &why)) << why;
  EXPECT_EQ(after.version, 2u);
  EXPECT_EQ(after.count, 0u);
  EXPECT_TRUE(after.records.empty());
  // A chunk never exceeds the cap, whatever is asked for.
  ExportChunk capped;
  ASSERT_TRUE(exporter.chunk(versions, {0, 0, 0, 1u << 30}, &capped, &why)) << why;
  EXPECT_EQ(capped.count, 20u);
  EXPECT_LE(capped.count, kMaxExportChunk);
}

TEST(MapExport, AVersionOutOfTheHoldIsRefused) {
  core::MapVersions versions;
  MapExporter exporter;
  ExportChunk chunk;
  std::string why;
  for (std::size_t v = 1; v <= MapExporter::kHeldVersions + 1; ++v) {
    versions.publish(std::make_shared<const core::GaussianMap>(line_map(5)));
    ASSERT_TRUE(exporter.chunk(versions, {0, 0, 0, 2}, &chunk, &why)) << why;
  }
  EXPECT_FALSE(exporter.chunk(versions, {0, 1, 2, 2}, &chunk, &why));
  EXPECT_NE(why.find("no longer held"), std::string::npos) << why;
  EXPECT_TRUE(exporter.chunk(versions, {0, 2, 2, 2}, &chunk, &why)) << why;
  EXPECT_FALSE(exporter.chunk(versions, {0, 2, 6, 2}, &chunk, &why)) << "first beyond the size";
  EXPECT_NE(why.find("beyond"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::server
