// Per-Gaussian and per-pixel math of the splatting renderer, forward and backward, shared by the
// CPU rasterizer (core/render) and the CUDA backend (design.md: one source of math). One header
// per part: the plain data (splat_types.hpp), small algebra and rotations (small_linalg.hpp),
// spherical harmonics, the projection forward (projection.hpp, eq. proj) and backward
// (projection_backward.hpp), and the per-pixel compositing (compositing.hpp, eq. blending).
// Scalar T: float in production, double in the finite-difference reference tests.
#pragma once

#include "fslam/core/math/compositing.hpp"
#include "fslam/core/math/projection.hpp"
#include "fslam/core/math/projection_backward.hpp"
#include "fslam/core/math/small_linalg.hpp"
#include "fslam/core/math/spherical_harmonics.hpp"
#include "fslam/core/math/splat_types.hpp"
