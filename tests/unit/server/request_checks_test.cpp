#include "fslam/server/request_checks.hpp"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

namespace fslam::server {
namespace {

// A session's views (SessionControl view_rate_hz, view_channels): none at rate 0, otherwise a
// localise session's, of known channels, colour and depth when none are named.
TEST(RequestChecks, ViewsAreALocaliseSessionsAtAFiniteRateOfKnownChannels) {
  std::uint32_t channels = 99;
  std::string why;
  EXPECT_TRUE(check_view_request(false, 0.0f, 0, &channels, &why)) << why;
  EXPECT_EQ(channels, 0u) << "rate 0: no views";
  EXPECT_TRUE(check_view_request(true, 5.0f, 0, &channels, &why)) << why;
  EXPECT_EQ(channels, static_cast<std::uint32_t>(fslam_proto_CHANNEL_COLOUR | fslam_proto_CHANNEL_DEPTH));
  EXPECT_TRUE(check_view_request(true, 30.0f, fslam_proto_CHANNEL_OPACITY, &channels, &why)) << why;
  EXPECT_EQ(channels, static_cast<std::uint32_t>(fslam_proto_CHANNEL_OPACITY));

  const auto refused = [&](bool localise, float rate, std::uint32_t requested, const std::string& fragment) {
    std::string error;
    std::uint32_t out = 0;
    EXPECT_FALSE(check_view_request(localise, rate, requested, &out, &error)) << fragment;
    EXPECT_NE(error.find(fragment), std::string::npos) << error;
  };
  refused(false, 5.0f, 0, "localise sessions only");
  refused(true, -1.0f, 0, "finite number");
  refused(true, std::numeric_limits<float>::quiet_NaN(), 0, "finite number");
  refused(true, std::numeric_limits<float>::infinity(), 0, "finite number");
  refused(true, 5.0f, 16, "CHANNEL_* bits");
}

}  // namespace
}  // namespace fslam::server
