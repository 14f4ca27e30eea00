// Projection, forward (paper eq. proj): one thread per Gaussian runs core's
// math::project_gaussian (fslam/core/math/projection.hpp) and its tile rectangle, so the CPU
// tests exercise the same code.
#include "launchers.hpp"

namespace fslam::cuda {
namespace {

namespace math = core::math;

__global__ void project_kernel(math::SplatScene<float> scene, math::SplatCamera<float> cam, int tile_size,
                               int tiles_x, int tiles_y, math::ProjectedGaussian<float>* __restrict__ projected,
                               int* __restrict__ rect, std::uint32_t* __restrict__ touched,
                               std::uint8_t* __restrict__ visible) {
  const std::size_t i = static_cast<std::size_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= scene.count) return;
  math::ProjectionTerms<float> terms;
  math::ProjectedGaussian<float> pg;
  if (!math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i, scene.log_scales + 3 * i,
                              scene.opacity_logits[i], scene.filter(i), scene.sh + i * scene.sh_stride(),
                              scene.sh_degree, cam, &pg, &terms)) {
    pg.radius = 0;
  }
  projected[i] = pg;
  int* r = rect + 4 * i;
  if (pg.radius > 0) {
    math::splat_tile_rect(pg, tile_size, tiles_x, tiles_y, r);
  } else {
    r[0] = r[1] = r[2] = r[3] = 0;
  }
  const int w = r[2] - r[0], h = r[3] - r[1];
  touched[i] = w > 0 && h > 0 ? static_cast<std::uint32_t>(w * h) : 0u;
  visible[i] = pg.radius > 0 ? 1 : 0;
}

}  // namespace

cudaError_t project_fwd(const core::math::SplatScene<float>& scene, const core::math::SplatCamera<float>& cam,
                        int tile_size, int tiles_x, int tiles_y, core::math::ProjectedGaussian<float>* projected,
                        int* rect, std::uint32_t* touched, std::uint8_t* visible, cudaStream_t stream) {
  if (scene.count == 0) return cudaSuccess;
  constexpr int kBlock = 128;
  const unsigned blocks = static_cast<unsigned>((scene.count + kBlock - 1) / kBlock);
  project_kernel<<<blocks, kBlock, 0, stream>>>(scene, cam, tile_size, tiles_x, tiles_y, projected, rect, touched,
                                                visible);
  return cudaGetLastError();
}

}  // namespace fslam::cuda
