// Relative pose error (RPE), the drift measure of Sturm et al. 2012 (TUM RGB-D benchmark):
// E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) with Q ground truth and P the estimate, over pairs of
// associated poses a fixed number of frames or seconds apart. docs/evaluation.md states the rules.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "fslam/core/eval/ate.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {

enum class RpeUnit {
  kFrames,   // delta counts associated poses: pair (k, k + delta)
  kSeconds,  // delta is a time span: pair (k, the associated pose nearest to t_k + delta) when
             // it lies within max(association max_difference, delta / 10) of t_k + delta
};
const char* to_string(RpeUnit unit);

struct RpeConfig {
  AssociationConfig association;
  RpeUnit unit = RpeUnit::kFrames;
  double delta = 1.0;  // frames (a whole number >= 1) or seconds (> 0), per `unit`
  double scale = 1.0;  // multiplies estimate translations; a monocular run passes the ATE Sim(3) scale
};
bool validate(const RpeConfig& config, std::string* why);

struct RpeResult {
  std::size_t pairs = 0;     // pose pairs that entered the statistics
  ErrorStats translation;    // metres, |trans(E_ij)|
  ErrorStats rotation;       // degrees, angle(rot(E_ij))
  std::vector<std::size_t> first;          // [pairs] est index of pose i
  std::vector<std::size_t> second;         // [pairs] est index of pose j
  std::vector<double> translation_errors;  // [pairs] metres
  std::vector<double> rotation_errors;     // [pairs] degrees
};

// Fails on an invalid config, non-finite poses, or when no pair is delta apart.
bool compute_rpe(const Trajectory& gt, const Trajectory& est, const RpeConfig& config,
                 RpeResult* result, std::string* why);

}  // namespace fslam::core
