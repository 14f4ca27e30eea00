#pragma once
// One definition of a sample percentile for every timing report (server status, fslam run /
// track / stream): linear interpolation between the two nearest order statistics.

#include <algorithm>
#include <cstddef>
#include <vector>

namespace fslam::core {

// q in [0, 1]; 0 for no samples.
inline double percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const double position = std::clamp(q, 0.0, 1.0) * static_cast<double>(values.size() - 1);
  const std::size_t lo = static_cast<std::size_t>(position);
  const std::size_t hi = std::min(lo + 1, values.size() - 1);
  return values[lo] + (position - static_cast<double>(lo)) * (values[hi] - values[lo]);
}

}  // namespace fslam::core
