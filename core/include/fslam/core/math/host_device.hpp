// One source of per-pixel / per-Gaussian math for the CPU and CUDA backends (design.md).
#pragma once

#if defined(__CUDACC__)
#define FSLAM_HD __host__ __device__ inline
#else
#define FSLAM_HD inline
#endif
