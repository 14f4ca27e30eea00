#include "fslam/core/geometry/associate.hpp"

#include <algorithm>
#include <cmath>
#include <tuple>

namespace fslam::core {

std::vector<std::pair<std::size_t, std::size_t>> associate_timestamps(
    const std::vector<double>& a, const std::vector<double>& b, double offset,
    double max_difference) {
  // associate.py enumerates every pair; sorting b first finds the same candidate set in
  // O((|a| + |b|) log |b| + candidates).
  std::vector<std::size_t> b_order(b.size());
  for (std::size_t j = 0; j < b.size(); ++j) b_order[j] = j;
  std::sort(b_order.begin(), b_order.end(),
            [&](std::size_t x, std::size_t y) { return b[x] < b[y]; });
  std::vector<double> b_sorted(b.size());
  for (std::size_t k = 0; k < b.size(); ++k) b_sorted[k] = b[b_order[k]] + offset;

  std::vector<std::tuple<double, double, double, std::size_t, std::size_t>> candidates;
  for (std::size_t i = 0; i < a.size(); ++i) {
    auto it = std::lower_bound(b_sorted.begin(), b_sorted.end(), a[i] - max_difference);
    for (; it != b_sorted.end() && *it <= a[i] + max_difference; ++it) {
      const double diff = std::abs(a[i] - *it);
      if (diff < max_difference) {
        const std::size_t j = b_order[static_cast<std::size_t>(it - b_sorted.begin())];
        // Ties broken by the stamps themselves, as Python's tuple sort does.
        candidates.emplace_back(diff, a[i], b[j], i, j);
      }
    }
  }
  std::sort(candidates.begin(), candidates.end());

  std::vector<bool> a_used(a.size(), false), b_used(b.size(), false);
  std::vector<std::pair<std::size_t, std::size_t>> matches;
  for (const auto& [diff, ta, tb, i, j] : candidates) {
    if (a_used[i] || b_used[j]) continue;
    a_used[i] = b_used[j] = true;
    matches.emplace_back(i, j);
  }
  std::sort(matches.begin(), matches.end(),
            [&](const auto& x, const auto& y) { return a[x.first] < a[y.first]; });
  return matches;
}

}  // namespace fslam::core
