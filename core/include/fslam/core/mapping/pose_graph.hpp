// A pose graph over keyframes, optimised with Ceres (issue 20's loop closure): nodes are
// camera-to-world poses, edges relative poses measured by tracking (consecutive keyframes) or by
// a verified revisit (a loop). Residual of edge (a, b) with measurement T_ab:
//   r = [ R_a^T (t_b - t_a) - t_ab ;  2 vec(q_ab^-1 q_a^-1 q_b) ]  scaled by 1 / sigma,
// the form of Ceres' pose_graph_3d example, with a Huber loss on the loop edges so that one wrong
// loop cannot bend the whole trajectory.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace fslam::core {

struct PoseGraphEdge {
  std::size_t from = 0, to = 0;                     // node indices
  Eigen::Isometry3d T_from_to = Eigen::Isometry3d::Identity();  // measured: from <- to
  double translation_sigma = 0.01;                  // metres
  double rotation_sigma = 0.0087;                   // radians (0.5 degrees)
  bool loop = false;                                // robustified (Huber at 3 sigma)
};

struct PoseGraphConfig {
  int max_iterations = 100;
  bool is_valid(std::string* why = nullptr) const;
};

struct PoseGraphResult {
  bool converged = false;
  int iterations = 0;
  double initial_cost = 0.0, final_cost = 0.0;
  std::string message;  // Ceres' brief report
};

// Moves T_world_node (all but node `fixed`, which anchors the world) to best agree with `edges`.
// False with `why` for bad input (an edge naming no node, non-finite poses, sigmas <= 0).
bool optimise_pose_graph(std::vector<Eigen::Isometry3d>* T_world_node, const std::vector<PoseGraphEdge>& edges,
                         std::size_t fixed, const PoseGraphConfig& config, PoseGraphResult* result,
                         std::string* why);

}  // namespace fslam::core
