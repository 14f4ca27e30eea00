#include "fslam/core/geometry/associate.hpp"

#include <gtest/gtest.h>

namespace fslam::core {
namespace {

TEST(Associate, GreedyByDifferenceOneToOne) {
  // b[0] is closest to a[1] (0.001) and would also match a[0] (0.009): the greedy order gives it
  // to a[1], leaving a[0] unmatched, exactly as associate.py does.
  const std::vector<double> a = {1.000, 1.010, 2.000};
  const std::vector<double> b = {1.009, 2.030, 1.985};
  const auto m = associate_timestamps(a, b, 0.0, 0.02);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0], (std::pair<std::size_t, std::size_t>{1, 0}));
  EXPECT_EQ(m[1], (std::pair<std::size_t, std::size_t>{2, 2}));
}

TEST(Associate, StrictThresholdAndOffset) {
  const std::vector<double> a = {0.0, 1.0};
  const std::vector<double> b = {0.02, 0.5};
  EXPECT_TRUE(associate_timestamps(a, {0.0200001}, 0.0, 0.02).empty());  // < max, not <=
  const auto m = associate_timestamps(a, b, 0.5, 0.02);  // b + 0.5 = {0.52, 1.0}
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0], (std::pair<std::size_t, std::size_t>{1, 1}));
}

}  // namespace
}  // namespace fslam::core
