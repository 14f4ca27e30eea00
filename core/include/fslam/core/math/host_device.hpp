// One source of per-pixel / per-Gaussian math for the CPU and CUDA backends (design.md).
#pragma once

#if defined(__CUDACC__)
#define FSLAM_HD __host__ __device__ inline
#else
#define FSLAM_HD inline
#endif

// A named piece of a larger function (the math here, the CPU rasteriser's stages), always inlined
// into it, so that splitting a function does not change its floating-point results: with -O3 and
// FMA (x86-64-v3), GCC's SLP vectoriser and multiply-add contraction otherwise group the
// operations differently across a call and change the last bits (measured on
// project_gaussian_backward).
#if defined(__CUDACC__)
#define FSLAM_HD_INLINE __host__ __device__ __forceinline__
#else
#define FSLAM_HD_INLINE inline __attribute__((always_inline))
#endif
