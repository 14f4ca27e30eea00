// Projection, backward: one thread per Gaussian chains its summed 2D gradient to its parameters
// through core's math::project_gaussian_backward (fslam/core/math/projection_backward.hpp).
#include "launchers.hpp"

namespace fslam::cuda {
namespace {

namespace math = core::math;

// Chains each Gaussian's summed 2D gradient to its parameters (math::project_gaussian_backward):
// out [N, P] with P = 11 + 3K + D + 2: mean 3, rotation 4, log-scale 3, opacity logit, SH [K, 3],
// features D, importance rgb and feature.
__global__ void project_bwd_kernel(math::SplatScene<float> scene, math::SplatCamera<float> cam,
                                   const math::ProjectedGaussian<float>* __restrict__ projected,
                                   const float* __restrict__ accum, int D, float* __restrict__ out) {
  const std::size_t i = static_cast<std::size_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= scene.count) return;
  const int K = (scene.sh_degree + 1) * (scene.sh_degree + 1);
  const int P = 11 + 3 * K + D + 2, stride = math::kGrad2dFixed + D;
  float* o = out + i * P;
  for (int k = 0; k < P; ++k) o[k] = 0.0f;
  if (projected[i].radius == 0) return;
  const float* a = accum + i * stride;
  const math::ProjectedGradient<float> pg = math::unpack_gradient_2d(a);
  math::ProjectedGaussian<float> again;
  math::ProjectionTerms<float> terms;
  math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i, scene.log_scales + 3 * i,
                         scene.opacity_logits[i], scene.filter(i), scene.sh + i * scene.sh_stride(), scene.sh_degree,
                         cam, &again, &terms);
  math::GaussianParamGradient<float> pgrad;
  math::project_gaussian_backward(scene.rotations + 4 * i, scene.filter(i), scene.sh + i * scene.sh_stride(),
                                  scene.sh_degree, cam, again, terms, pg, &pgrad);
  for (int k = 0; k < 3; ++k) o[k] = pgrad.mean[k];
  for (int k = 0; k < 4; ++k) o[3 + k] = pgrad.quat[k];
  for (int k = 0; k < 3; ++k) o[7 + k] = pgrad.log_scale[k];
  o[10] = pgrad.opacity_logit;
  for (int k = 0; k < 3 * K; ++k) o[11 + k] = pgrad.sh[k];
  for (int c = 0; c < D; ++c) o[11 + 3 * K + c] = a[math::kGrad2dFixed + c];
  o[11 + 3 * K + D] = a[12];
  o[12 + 3 * K + D] = a[13];
}

}  // namespace

cudaError_t project_bwd(const core::math::SplatScene<float>& scene, const core::math::SplatCamera<float>& cam,
                        const core::math::ProjectedGaussian<float>* projected, const float* accum, int feature_dim,
                        float* out, cudaStream_t stream) {
  if (scene.count == 0) return cudaSuccess;
  constexpr int kBlock = 128;
  const unsigned blocks = static_cast<unsigned>((scene.count + kBlock - 1) / kBlock);
  project_bwd_kernel<<<blocks, kBlock, 0, stream>>>(scene, cam, projected, accum, feature_dim, out);
  return cudaGetLastError();
}

}  // namespace fslam::cuda
