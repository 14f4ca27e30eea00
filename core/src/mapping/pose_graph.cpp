#include "fslam/core/mapping/pose_graph.hpp"

#include <ceres/ceres.h>

#include "fslam/core/error.hpp"
#include "fslam/core/geometry/se3.hpp"

namespace fslam::core {
namespace {

// The residual of one edge (header comment), on node a's and b's [tx ty tz] and [qx qy qz qw].
struct RelativePoseError {
  RelativePoseError(const Eigen::Isometry3d& T_ab, double translation_sigma, double rotation_sigma)
      : t_ab(T_ab.translation()), q_ab(Eigen::Quaterniond(T_ab.linear()).normalized()),
        inv_t(1.0 / translation_sigma), inv_r(1.0 / rotation_sigma) {}

  template <typename T>
  bool operator()(const T* t_a_ptr, const T* q_a_ptr, const T* t_b_ptr, const T* q_b_ptr, T* r_ptr) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_a(t_a_ptr), t_b(t_b_ptr);
    const Eigen::Map<const Eigen::Quaternion<T>> q_a(q_a_ptr), q_b(q_b_ptr);
    const Eigen::Quaternion<T> q_a_inv = q_a.conjugate();
    const Eigen::Quaternion<T> q_ab_est = q_a_inv * q_b;
    const Eigen::Matrix<T, 3, 1> t_ab_est = q_a_inv * (t_b - t_a);
    const Eigen::Quaternion<T> dq = q_ab.template cast<T>().conjugate() * q_ab_est;
    Eigen::Map<Eigen::Matrix<T, 6, 1>> r(r_ptr);
    r.template head<3>() = (t_ab_est - t_ab.template cast<T>()) * T(inv_t);
    r.template tail<3>() = T(2.0) * dq.vec() * T(inv_r);
    return true;
  }

  Eigen::Vector3d t_ab;
  Eigen::Quaterniond q_ab;
  double inv_t, inv_r;
};

}  // namespace

bool PoseGraphConfig::is_valid(std::string* why) const {
  if (max_iterations < 1) return fail(why, "pose graph: max_iterations must be >= 1");
  return true;
}

bool optimise_pose_graph(std::vector<Eigen::Isometry3d>* T_world_node, const std::vector<PoseGraphEdge>& edges,
                         std::size_t fixed, const PoseGraphConfig& config, PoseGraphResult* result,
                         std::string* why) {
  if (!config.is_valid(why)) return false;
  const std::size_t n = T_world_node->size();
  if (fixed >= n) return fail(why, "pose graph: the fixed node " + std::to_string(fixed) + " is not one of " +
                                       std::to_string(n));
  for (const Eigen::Isometry3d& T : *T_world_node)
    if (!is_finite(T)) return fail(why, "pose graph: a node pose is not finite");
  for (const PoseGraphEdge& e : edges) {
    if (e.from >= n || e.to >= n || e.from == e.to)
      return fail(why, "pose graph: edge " + std::to_string(e.from) + " -> " + std::to_string(e.to) +
                           " does not join two of the " + std::to_string(n) + " nodes");
    if (!(e.translation_sigma > 0.0) || !(e.rotation_sigma > 0.0))
      return fail(why, "pose graph: edge sigmas must be > 0");
    if (!is_finite(e.T_from_to)) return fail(why, "pose graph: an edge measurement is not finite");
  }
  // Parameter blocks: translation [3] and quaternion [4] (x, y, z, w; Eigen's storage order).
  std::vector<Eigen::Vector3d> t(n);
  std::vector<Eigen::Quaterniond> q(n);
  for (std::size_t i = 0; i < n; ++i) {
    t[i] = (*T_world_node)[i].translation();
    q[i] = Eigen::Quaterniond((*T_world_node)[i].linear()).normalized();
  }
  ceres::Problem problem;
  for (const PoseGraphEdge& e : edges) {
    auto* cost = new ceres::AutoDiffCostFunction<RelativePoseError, 6, 3, 4, 3, 4>(
        new RelativePoseError(e.T_from_to, e.translation_sigma, e.rotation_sigma));
    ceres::LossFunction* loss = e.loop ? new ceres::HuberLoss(3.0) : nullptr;
    problem.AddResidualBlock(cost, loss, t[e.from].data(), q[e.from].coeffs().data(), t[e.to].data(),
                             q[e.to].coeffs().data());
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!problem.HasParameterBlock(t[i].data())) continue;  // a node no edge reaches stays put
    problem.SetManifold(q[i].coeffs().data(), new ceres::EigenQuaternionManifold);
  }
  if (problem.HasParameterBlock(t[fixed].data())) {
    problem.SetParameterBlockConstant(t[fixed].data());
    problem.SetParameterBlockConstant(q[fixed].coeffs().data());
  }
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  options.max_num_iterations = config.max_iterations;
  options.num_threads = 1;  // core has no hidden thread pools
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  result->converged = summary.termination_type == ceres::CONVERGENCE;
  result->iterations = static_cast<int>(summary.iterations.size());
  result->initial_cost = summary.initial_cost;
  result->final_cost = summary.final_cost;
  result->message = summary.BriefReport();
  if (!summary.IsSolutionUsable()) return fail(why, "pose graph: " + summary.BriefReport());
  for (std::size_t i = 0; i < n; ++i) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = q[i].normalized().toRotationMatrix();
    T.translation() = t[i];
    (*T_world_node)[i] = T;
  }
  return true;
}

}  // namespace fslam::core
