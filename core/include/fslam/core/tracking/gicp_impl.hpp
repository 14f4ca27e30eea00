// Template definitions of linearize and align (gicp.hpp), included by the translation units that
// call them, so TBB stays out of gicp.hpp. gicp.cpp compiles them once for KdTreeTarget and
// LocalMap (declared extern at the end); other targets instantiate from here. One
// per-correspondence factor (accumulate_gicp_factor) serves every reduction.
#pragma once

#include <cassert>
#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"
#include "fslam/core/tracking/gicp.hpp"
#include "fslam/core/tracking/kdtree_target.hpp"
#include "fslam/core/tracking/local_map.hpp"

namespace fslam::core {

using Matrix36d = Eigen::Matrix<double, 3, 6>;

// Residual of eq. residual at the transformed source mean q = T mu_s, and its Jacobian with
// respect to the left perturbation T <- exp(xi) T, xi = [rho; phi]: d(q) = q + rho + phi x q
// to first order, so dq/dxi = [I, -hat(q)] and J = dd/dxi = -[I, -hat(q)] = [-I, hat(q)].
inline Eigen::Vector3d gicp_residual(const Eigen::Vector3d& mu_target, const Eigen::Vector3d& q,
                                     Matrix36d* J) {
  J->leftCols<3>() = -Eigen::Matrix3d::Identity();
  J->rightCols<3>() = hat(q);
  return mu_target - q;
}

// rho(m) of a robust kernel on the Mahalanobis distance r = sqrt(m), and its IRLS weight
// drho/dm (the Gauss-Newton system is weighted by it, so cost and weight stay consistent).
struct RobustValue {
  double cost = 0.0;
  double weight = 1.0;
};

// m: squared Mahalanobis distance d^T C^-1 d; kernel_scale: k on sqrt(m).
inline RobustValue robust_kernel(RobustKernel kernel, double kernel_scale, double m) {
  const double k2 = kernel_scale * kernel_scale;
  switch (kernel) {
    case RobustKernel::huber: {
      if (m <= k2) return {m, 1.0};
      const double r = std::sqrt(m);
      return {2.0 * kernel_scale * r - k2, kernel_scale / r};
    }
    case RobustKernel::cauchy: {
      const double u = m / k2;
      return {k2 * std::log1p(u), 1.0 / (1.0 + u)};
    }
    case RobustKernel::none: break;
  }
  return {m, 1.0};
}

// Eq. feat_dist's similarity per source point, kept across the Gauss-Newton iterations of one
// align: the features do not change within it, so a correspondence that stays (most do after the
// first iterations) reuses its similarity instead of reading the target's feature row again, a
// cache miss per correspondence in a local map of ~70k rows (perf: a quarter of the factor's own
// time on the synthetic room). Each source point's slot is written only by its own factor.
struct FeatureSimilarityMemo {
  std::vector<const TargetPoint*> target;  // [source size], the target point of `similarity`
  std::vector<double> similarity;
};

// What one linearisation fixes for all of its factors.
struct GicpFactorContext {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  // of T_target_source
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  float max_distance = 0.0f;
  RobustKernel kernel = RobustKernel::none;
  double kernel_scale = 1.0;
  bool use_opacity = false;
  bool use_features = false;  // config on, and source and target carry features of equal size
  double feature_gamma = 0.0;
  double feature_noise = 1.0;
  int feature_dim = 0;
  double feature_residual_weight = 0.0;  // > 0 only with features and the source's gradients
  FeatureSimilarityMemo* memo = nullptr;  // align's, for its iterations; none: computed each time
};

// The context for linearising `source` against `target` at T_target_source.
template <typename Target>
GicpFactorContext make_gicp_factor_context(const GaussianPoints& source, const Target& target,
                                           const Eigen::Isometry3d& T_target_source,
                                           const GicpConfig& config) {
  GicpFactorContext ctx;
  ctx.R = T_target_source.linear();
  ctx.t = T_target_source.translation();
  ctx.max_distance = config.max_correspondence_distance;
  ctx.kernel = config.kernel;
  ctx.kernel_scale = config.kernel_scale;
  ctx.use_opacity = config.use_opacity;
  // A feature-size mismatch means the two sides come from different encoders: the similarity
  // is undefined, so the term is off (GicpResult::features_used reports it).
  ctx.use_features = config.use_features && source.has_features() && target.feature_dim() > 0 &&
                     target.feature_dim() == source.feature_dim;
  ctx.feature_gamma = config.feature_gamma;
  ctx.feature_noise = config.feature_noise;
  ctx.feature_dim = ctx.use_features ? source.feature_dim : 0;
  ctx.feature_residual_weight =
      ctx.use_features && source.has_feature_gradient() ? config.feature_residual_weight : 0.0;
  return ctx;
}

// Adds source point i's correspondence to `system` (nothing when it has none within range).
//
// Eq. feat_gicp read literally adds d_f inside alpha_i(...) as a term that does not depend on T
// once correspondences are fixed, so it could never move a Gauss-Newton step. We use the reading
// under which "features help resolve misalignments": the feature similarity of eq. feat_dist
// multiplies the Mahalanobis term, so semantically inconsistent correspondences count less.
// alpha is the opacity of the *target* Gaussian pi(i) (the map's volumetric composition); the
// source opacities are not used.
template <typename Target>
inline void accumulate_gicp_factor(const GaussianPoints& source, std::size_t i,
                                   const Target& target, const GicpFactorContext& ctx,
                                   LinearSystem* system) {
  const Eigen::Vector3d q = ctx.R * source.means[i].cast<double>() + ctx.t;  // eq. rigid_transform
  // Eq. correspondence: the nearest target mean within the correspondence distance.
  const TargetPoint* match = target.nearest(q.cast<float>(), ctx.max_distance, nullptr);
  if (match == nullptr) return;

  // C = Sigma_t + R Sigma_s R^T (eq. residual_dist), inverted by cofactors (it is symmetric).
  const Eigen::Matrix3d C = match->covariance.cast<double>() +
                            ctx.R * source.covariances[i].cast<double>() * ctx.R.transpose();
  const double a = C(0, 0), b = C(0, 1), c = C(0, 2), d = C(1, 1), e = C(1, 2), f = C(2, 2);
  Eigen::Matrix3d M;
  M(0, 0) = d * f - e * e;
  M(0, 1) = M(1, 0) = c * e - b * f;
  M(0, 2) = M(2, 0) = b * e - c * d;
  M(1, 1) = a * f - c * c;
  M(1, 2) = M(2, 1) = b * c - a * e;
  M(2, 2) = a * d - b * b;
  const double det = a * M(0, 0) + b * M(0, 1) + c * M(0, 2);
  const double trace = a + d + f;
  // A singular or non-finite C (det <= 1e-12 (trace/3)^3: a vanishing eigenvalue) is skipped.
  if (!(det > 1e-12 * trace * trace * trace / 27.0)) return;
  M /= det;

  Matrix36d J;  // eq. residual and its Jacobian
  const Eigen::Vector3d residual = gicp_residual(match->mean.cast<double>(), q, &J);
  const Eigen::Vector3d Md = M * residual;
  const double m = residual.dot(Md);  // the Mahalanobis term of eq. gicp_pose
  const RobustValue robust = robust_kernel(ctx.kernel, ctx.kernel_scale, m);

  double weight = 1.0;  // eq. feat_gicp (multiplicative reading, see above)
  double alpha = 1.0;
  if (ctx.use_opacity) {
    alpha = static_cast<double>(match->opacity);
    weight *= alpha;
  }
  if (ctx.use_features) {
    const float* fs = source.feature(i);
    const float* ft = target.feature(*match);
    const double spread = source.has_feature_spread() ? source.feature_spread[i] : 0.0;
    const double scale = 2.0 * spread + ctx.feature_noise;
    double similarity;
    if (ctx.memo != nullptr && ctx.memo->target[i] == match) {
      similarity = ctx.memo->similarity[i];
    } else {
      float feature_distance = 0.0f;
      for (int k = 0; k < ctx.feature_dim; ++k) {
        const float diff = fs[k] - ft[k];
        feature_distance += diff * diff;
      }
      // Eq. feat_dist, the distance scaled by the spread expected of a correct correspondence:
      // the points are up to a lattice cell apart, so their latents differ by about the spread
      // of each; the target's is taken equal to the source's (same surface, a nearby view).
      similarity = std::exp(-ctx.feature_gamma * static_cast<double>(feature_distance) / scale);
      if (ctx.memo != nullptr) {
        ctx.memo->target[i] = match;
        ctx.memo->similarity[i] = similarity;
      }
    }
    weight *= similarity;
    system->feature_weight_sum += similarity;
    if (ctx.feature_residual_weight > 0.0) {
      // The frame's latent where the target mean lands, to first order about the source point:
      // r = f_s + G (T^-1 mu_t - mu_s) - f_t; d r / d xi = G R^T [-I, hat(mu_t)].
      const Eigen::Vector3d mu_t = match->mean.cast<double>();
      const Eigen::Vector3d offset = ctx.R.transpose() * (mu_t - ctx.t) - source.means[i].cast<double>();
      const float* G = source.feature_gradient.data() + i * static_cast<std::size_t>(ctx.feature_dim) * 3;
      Matrix36d dY;
      dY.leftCols<3>() = -ctx.R.transpose();
      dY.rightCols<3>() = ctx.R.transpose() * hat(mu_t);
      Eigen::Matrix3d A = Eigen::Matrix3d::Zero();  // sum_k G_k G_k^T
      Eigen::Vector3d v = Eigen::Vector3d::Zero();  // sum_k G_k r_k
      double r2 = 0.0;
      for (int k = 0; k < ctx.feature_dim; ++k) {
        const Eigen::Vector3d Gk(G[3 * k], G[3 * k + 1], G[3 * k + 2]);
        const double r = fs[k] - ft[k] + Gk.dot(offset);
        A.noalias() += Gk * Gk.transpose();
        v += r * Gk;
        r2 += r * r;
      }
      // Welsch on the scaled distance: cost lambda_f (1 - d_f) / gamma, IRLS weight lambda_f d_f / s.
      const double e = r2 / scale;
      const double df = std::exp(-ctx.feature_gamma * e);
      const double wf = alpha * ctx.feature_residual_weight * df / scale;
      system->H.noalias() += (wf * dY.transpose()) * A * dY;
      system->b.noalias() += (wf * dY.transpose()) * v;
      system->cost += alpha * ctx.feature_residual_weight * (ctx.feature_gamma > 0.0 ? (1.0 - df) / ctx.feature_gamma : e);
    }
  }

  const Eigen::Matrix<double, 6, 3> JtM = J.transpose() * M;
  const double w = weight * robust.weight;
  system->H.noalias() += (w * JtM) * J;
  system->b.noalias() += (w * JtM) * residual;
  system->cost += weight * robust.cost;
  system->squared_distance_sum += residual.squaredNorm();
  system->mahalanobis_sum += m;
  ++system->inliers;
}

namespace gicp_detail {

template <typename Factor>
LinearSystem reduce(std::size_t n, const SerialReduction& /*reduction*/, const Factor& factor) {
  LinearSystem system;
  for (std::size_t i = 0; i < n; ++i) factor(i, &system);
  return system;
}

// Deterministic reduce: the same split and join order on every run and any thread count, so a
// sequence tracks reproducibly (it differs from the serial sum only by rounding).
template <typename Factor>
LinearSystem reduce(std::size_t n, const TbbReduction& reduction, const Factor& factor) {
  const std::size_t grain = reduction.grain > 0 ? reduction.grain : 1;
  return tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, n, grain), LinearSystem{},
      [&](const tbb::blocked_range<std::size_t>& range, LinearSystem partial) {
        for (std::size_t i = range.begin(); i != range.end(); ++i) factor(i, &partial);
        return partial;
      },
      [](LinearSystem lhs, const LinearSystem& rhs) {
        lhs += rhs;
        return lhs;
      });
}

// lambda_max / lambda_min of the symmetric H; infinity when H is not positive definite.
inline double condition_number(const Matrix6d& H) {
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(H, Eigen::EigenvaluesOnly);
  if (eigen.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  const double lambda_min = eigen.eigenvalues()(0);
  const double lambda_max = eigen.eigenvalues()(5);
  if (!(lambda_min > 0.0)) return std::numeric_limits<double>::infinity();
  return lambda_max / lambda_min;
}

// H (of the left perturbation exp(xi) T: rotation about the world origin) for a perturbation
// that rotates about `centre` instead: xi = A xi_c with A = [I hat(centre); 0 I], H_c = A^T H A.
// About the camera centre the rotation columns scale with the scene's depth, not with how far
// the camera is from the world origin: H's own rotation columns grow with that distance, and
// the synthetic hall's loop, 8-10 m out, was declared lost there.
inline Matrix6d about_point(const Matrix6d& H, const Eigen::Vector3d& centre) {
  Matrix6d A = Matrix6d::Identity();
  A.block<3, 3>(0, 3) = hat(centre);
  return A.transpose() * H * A;
}

// The damped Gauss-Newton step (H + lambda diag(H)) delta = -b; false when it is not finite.
inline bool solve_step(const LinearSystem& system, double lm_lambda, Vector6d* delta) {
  if (system.inliers == 0 || !(system.H.diagonal().maxCoeff() > 0.0)) return false;
  Matrix6d H = system.H;
  H.diagonal() *= 1.0 + lm_lambda;
  const Eigen::LDLT<Matrix6d> ldlt(H);
  if (ldlt.info() != Eigen::Success) return false;
  *delta = -ldlt.solve(system.b);
  return delta->allFinite();
}

template <typename Target, typename Reduction>
LinearSystem linearize(const GaussianPoints& source, const Target& target,
                       const Eigen::Isometry3d& T_target_source, const GicpConfig& config,
                       const Reduction& reduction, FeatureSimilarityMemo* memo) {
  GicpFactorContext ctx = make_gicp_factor_context(source, target, T_target_source, config);
  ctx.memo = memo;  // read only where the features are used
  return reduce(source.size(), reduction, [&](std::size_t i, LinearSystem* system) {
    accumulate_gicp_factor(source, i, target, ctx, system);
  });
}

}  // namespace gicp_detail

template <typename Target, typename Reduction>
LinearSystem linearize(const GaussianPoints& source, const Target& target,
                       const Eigen::Isometry3d& T_target_source, const GicpConfig& config,
                       const Reduction& reduction) {
  return gicp_detail::linearize(source, target, T_target_source, config, reduction, nullptr);
}

template <typename Target, typename Reduction>
GicpResult align(const GaussianPoints& source, const Target& target,
                 const Eigen::Isometry3d& T_init, const GicpConfig& config,
                 const Reduction& reduction) {
  assert(config.is_valid());
  GicpResult result;
  result.source_points = source.size();
  result.features_used = make_gicp_factor_context(source, target, T_init, config).use_features;

  // Gauss-Newton on se(3), re-associating every iteration (eq. gicp_pose / feat_gicp).
  FeatureSimilarityMemo memo;
  if (result.features_used) {
    memo.target.assign(source.size(), nullptr);
    memo.similarity.resize(source.size());
  }
  Eigen::Isometry3d T = T_init;
  bool failed = source.empty();
  for (int iteration = 0; !failed && iteration < config.max_iterations; ++iteration) {
    const LinearSystem system = gicp_detail::linearize(source, target, T, config, reduction, &memo);
    Vector6d delta;
    if (!gicp_detail::solve_step(system, config.lm_lambda, &delta)) {
      failed = true;
      break;
    }
    T = se3_exp(delta) * T;
    result.iterations = iteration + 1;
    if (delta.head<3>().norm() < config.translation_epsilon &&
        delta.tail<3>().norm() < config.rotation_epsilon) {
      result.converged = true;
      break;
    }
  }
  // No correspondences or no usable step: the initial guess is the only defensible answer.
  if (failed || !is_finite(T)) {
    T = T_init;
    result.converged = false;
  }

  const LinearSystem final_system = gicp_detail::linearize(source, target, T, config, reduction, &memo);
  result.T_target_source = T;
  result.inliers = final_system.inliers;
  result.inlier_ratio = source.empty() ? 0.0
                                       : static_cast<double>(final_system.inliers) /
                                             static_cast<double>(source.size());
  result.rms_residual = final_system.inliers == 0
                            ? 0.0
                            : std::sqrt(final_system.squared_distance_sum /
                                        static_cast<double>(final_system.inliers));
  result.cost = final_system.cost;
  if (final_system.inliers > 0)
    result.mean_mahalanobis = final_system.mahalanobis_sum / static_cast<double>(final_system.inliers);
  if (result.features_used && final_system.inliers > 0)
    result.mean_feature_weight = final_system.feature_weight_sum / static_cast<double>(final_system.inliers);
  result.H = final_system.H;
  result.condition_number = gicp_detail::condition_number(gicp_detail::about_point(final_system.H, T.translation()));
  if (final_system.inliers == 0) result.converged = false;
  return result;
}

// Compiled once, in gicp.cpp, for the targets of core; other targets instantiate from here.
#define FSLAM_GICP_INSTANTIATION(prefix, Target, Reduction)                                        \
  prefix template LinearSystem linearize<Target, Reduction>(const GaussianPoints&, const Target&,  \
                                                            const Eigen::Isometry3d&,              \
                                                            const GicpConfig&, const Reduction&);  \
  prefix template GicpResult align<Target, Reduction>(const GaussianPoints&, const Target&,        \
                                                      const Eigen::Isometry3d&, const GicpConfig&, \
                                                      const Reduction&);
FSLAM_GICP_INSTANTIATION(extern, KdTreeTarget, SerialReduction)
FSLAM_GICP_INSTANTIATION(extern, KdTreeTarget, TbbReduction)
FSLAM_GICP_INSTANTIATION(extern, LocalMap, SerialReduction)
FSLAM_GICP_INSTANTIATION(extern, LocalMap, TbbReduction)

}  // namespace fslam::core
