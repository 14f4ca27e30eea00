// Small fixed-size algebra of the splatting math: 3x3 products, the sigmoid, and the rotation of
// a quaternion with its backward. Matrices are row-major T[9]; quaternions are w, x, y, z.
#pragma once

#include <math.h>  // exp, sqrt: device functions under nvcc, the C library on the host

#include "fslam/core/math/host_device.hpp"

namespace fslam::core::math {

template <typename T>
FSLAM_HD void mat_mul(const T A[9], const T B[9], T C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C[3 * r + c] = A[3 * r] * B[c] + A[3 * r + 1] * B[3 + c] + A[3 * r + 2] * B[6 + c];
}
// C = A^T B
template <typename T>
FSLAM_HD void mat_tmul(const T A[9], const T B[9], T C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C[3 * r + c] = A[r] * B[c] + A[3 + r] * B[3 + c] + A[6 + r] * B[6 + c];
}
// C = A B^T
template <typename T>
FSLAM_HD void mat_mul_t(const T A[9], const T B[9], T C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C[3 * r + c] = A[3 * r] * B[3 * c] + A[3 * r + 1] * B[3 * c + 1] + A[3 * r + 2] * B[3 * c + 2];
}
template <typename T>
FSLAM_HD void mat_vec(const T A[9], const T x[3], T y[3]) {
  for (int r = 0; r < 3; ++r) y[r] = A[3 * r] * x[0] + A[3 * r + 1] * x[1] + A[3 * r + 2] * x[2];
}
template <typename T>
FSLAM_HD void mat_tvec(const T A[9], const T x[3], T y[3]) {
  for (int c = 0; c < 3; ++c) y[c] = A[c] * x[0] + A[3 + c] * x[1] + A[6 + c] * x[2];
}

template <typename T>
FSLAM_HD T sigmoid(T x) {
  return T(1) / (T(1) + exp(-x));
}

// Rotation of the normalised quaternion q (any non-zero norm).
template <typename T>
FSLAM_HD void quat_to_rotmat(const T q[4], T R[9]) {
  const T n = T(1) / sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const T w = q[0] * n, x = q[1] * n, y = q[2] * n, z = q[3] * n;
  R[0] = T(1) - T(2) * (y * y + z * z);
  R[1] = T(2) * (x * y - w * z);
  R[2] = T(2) * (x * z + w * y);
  R[3] = T(2) * (x * y + w * z);
  R[4] = T(1) - T(2) * (x * x + z * z);
  R[5] = T(2) * (y * z - w * x);
  R[6] = T(2) * (x * z - w * y);
  R[7] = T(2) * (y * z + w * x);
  R[8] = T(1) - T(2) * (x * x + y * y);
}

// dL/dq from dL/dR, through the normalisation.
template <typename T>
FSLAM_HD void quat_to_rotmat_backward(const T q[4], const T dR[9], T dq[4]) {
  const T norm = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const T w = q[0] / norm, x = q[1] / norm, y = q[2] / norm, z = q[3] / norm;
  T g[4];
  g[0] = T(2) * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]);
  g[1] = T(2) * (y * dR[1] + z * dR[2] + y * dR[3] - T(2) * x * dR[4] - w * dR[5] + z * dR[6] +
                 w * dR[7] - T(2) * x * dR[8]);
  g[2] = T(2) * (-T(2) * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] +
                 z * dR[7] - T(2) * y * dR[8]);
  g[3] = T(2) * (-T(2) * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - T(2) * z * dR[4] +
                 y * dR[5] + x * dR[6] + y * dR[7]);
  // q_hat = q / |q|: dq = (g - q_hat (q_hat . g)) / |q|
  const T dot = w * g[0] + x * g[1] + y * g[2] + z * g[3];
  dq[0] = (g[0] - w * dot) / norm;
  dq[1] = (g[1] - x * dot) / norm;
  dq[2] = (g[2] - y * dot) / norm;
  dq[3] = (g[3] - z * dot) / norm;
}

}  // namespace fslam::core::math
