// The token bucket behind server.max_session_fps and server.max_client_requests_per_s.
#include <chrono>

#include <gtest/gtest.h>

#include "fslam/server/rate_limit.hpp"

namespace fslam::server {
namespace {

using Clock = RateLimit::Clock;
using std::chrono::milliseconds;

TEST(RateLimit, AllowsABurstOfOneSecondThenTheRate) {
  const Clock::time_point t0 = Clock::now();
  RateLimit limit(10.0);  // 10 per second, bursts of 10
  int taken = 0;
  for (int i = 0; i < 30; ++i) taken += limit.take(t0) ? 1 : 0;
  EXPECT_EQ(taken, 10);  // the burst, all at once
  // Over the next 2 s at 100 attempts per second: 10 per second get through.
  taken = 0;
  for (int i = 1; i <= 200; ++i) taken += limit.take(t0 + milliseconds(10 * i)) ? 1 : 0;
  EXPECT_NEAR(taken, 20, 1);
}

TEST(RateLimit, ZeroMeansUnlimited) {
  RateLimit limit(0.0);
  const Clock::time_point t0 = Clock::now();
  for (int i = 0; i < 10000; ++i) ASSERT_TRUE(limit.take(t0));
}

}  // namespace
}  // namespace fslam::server
