// Real spherical harmonics up to degree 3 and their gradient w.r.t. the direction: the
// view-dependent colour of a Gaussian (3DGS).
#pragma once

#include "fslam/core/math/host_device.hpp"

namespace fslam::core::math {

constexpr double kSh0 = 0.28209479177387814;
constexpr double kSh1 = 0.4886025119029199;

// Real SH basis up to `degree` at unit direction d and its gradient w.r.t. d (grad: [K, 3], may
// be null). K = (degree + 1)^2 <= 16.
template <typename T>
FSLAM_HD void sh_basis(int degree, const T d[3], T* basis, T* grad) {
  // Degree 2 and 3 constants, local so that device code can read them (namespace-scope arrays
  // are host-only under nvcc).
  constexpr double kSh2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                              -1.0925484305920792, 0.5462742152960396};
  constexpr double kSh3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                              0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                              -0.5900435899266435};
  const T x = d[0], y = d[1], z = d[2];
  auto set = [&](int k, T value, T gx, T gy, T gz) {
    basis[k] = value;
    if (grad != nullptr) {
      grad[3 * k] = gx;
      grad[3 * k + 1] = gy;
      grad[3 * k + 2] = gz;
    }
  };
  set(0, T(kSh0), T(0), T(0), T(0));
  if (degree < 1) return;
  const T c1 = T(kSh1);
  set(1, -c1 * y, T(0), -c1, T(0));
  set(2, c1 * z, T(0), T(0), c1);
  set(3, -c1 * x, -c1, T(0), T(0));
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  set(4, T(kSh2[0]) * x * y, T(kSh2[0]) * y, T(kSh2[0]) * x, T(0));
  set(5, T(kSh2[1]) * y * z, T(0), T(kSh2[1]) * z, T(kSh2[1]) * y);
  set(6, T(kSh2[2]) * (T(2) * zz - xx - yy), T(kSh2[2]) * (-T(2) * x), T(kSh2[2]) * (-T(2) * y),
      T(kSh2[2]) * (T(4) * z));
  set(7, T(kSh2[3]) * x * z, T(kSh2[3]) * z, T(0), T(kSh2[3]) * x);
  set(8, T(kSh2[4]) * (xx - yy), T(kSh2[4]) * (T(2) * x), T(kSh2[4]) * (-T(2) * y), T(0));
  if (degree < 3) return;
  set(9, T(kSh3[0]) * y * (T(3) * xx - yy), T(kSh3[0]) * T(6) * x * y,
      T(kSh3[0]) * (T(3) * xx - T(3) * yy), T(0));
  set(10, T(kSh3[1]) * x * y * z, T(kSh3[1]) * y * z, T(kSh3[1]) * x * z, T(kSh3[1]) * x * y);
  set(11, T(kSh3[2]) * y * (T(4) * zz - xx - yy), T(kSh3[2]) * (-T(2) * x * y),
      T(kSh3[2]) * (T(4) * zz - xx - T(3) * yy), T(kSh3[2]) * (T(8) * y * z));
  set(12, T(kSh3[3]) * z * (T(2) * zz - T(3) * xx - T(3) * yy), T(kSh3[3]) * (-T(6) * x * z),
      T(kSh3[3]) * (-T(6) * y * z), T(kSh3[3]) * (T(6) * zz - T(3) * xx - T(3) * yy));
  set(13, T(kSh3[4]) * x * (T(4) * zz - xx - yy), T(kSh3[4]) * (T(4) * zz - T(3) * xx - yy),
      T(kSh3[4]) * (-T(2) * x * y), T(kSh3[4]) * (T(8) * x * z));
  set(14, T(kSh3[5]) * z * (xx - yy), T(kSh3[5]) * (T(2) * x * z), T(kSh3[5]) * (-T(2) * y * z),
      T(kSh3[5]) * (xx - yy));
  set(15, T(kSh3[6]) * x * (xx - T(3) * yy), T(kSh3[6]) * (T(3) * xx - T(3) * yy),
      T(kSh3[6]) * (-T(6) * x * y), T(0));
}

}  // namespace fslam::core::math
