// Timestamp association as the TUM RGB-D benchmark's associate.py does it.
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

namespace fslam::core {

// Greedy one-to-one matching: all pairs with |a - (b + offset)| < max_difference, taken in order
// of increasing difference, each stamp used once; the result is sorted by a.
// Returns index pairs (i into a, j into b).
std::vector<std::pair<std::size_t, std::size_t>> associate_timestamps(
    const std::vector<double>& a, const std::vector<double>& b, double offset = 0.0,
    double max_difference = 0.02);

}  // namespace fslam::core
