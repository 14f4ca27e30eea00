// Image-space losses of the mapper (paper eq. modeling_losses) and the Gaussian shape
// regularisers (eq. erank_loss, eq. thin_loss), each with its exact gradient.
//
// Conventions shared by every loss here:
// - *loss receives the value already multiplied by `weight` (or lambda).
// - grad (optional): weight * dLoss/d(prediction) is ADDED into it, so the mapper sums several
//   terms into one buffer. An empty grad is first sized like the prediction and zeroed; a
//   non-empty one must have the prediction's shape.
// - mask (optional, nullptr = every pixel): [1, H, W], a pixel counts when its value is > 0.5;
//   it applies to every channel.
// - Means are over the counted elements (pixels x channels unless stated); a loss with nothing
//   to count is 0 and adds no gradient.
// - Bad shapes or settings return false with a message in *why (and leave *loss and grad as
//   they were).
// The per-pixel math lives in fslam/core/math/loss_math.hpp (shared with CUDA); the scalar
// templates in image_losses_impl.hpp (float here, double in the gradient tests).
#pragma once

#include <string>
#include <vector>

#include "fslam/core/math/unproject.hpp"
#include "fslam/core/render/planar_image.hpp"

namespace fslam::core {

// ---- L1 ----------------------------------------------------------------------------------------

// weight * mean |rendered - observed| over the counted pixels x channels (colour, features).
// dL/drendered = weight * sign(rendered - observed) / count (0 where they are equal).
bool l1_loss(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
             double weight, double* loss, PlanarImage* grad, std::string* why = nullptr);

// Depth [1, H, W], metres: as l1_loss, but a pixel also needs an observed depth that is > 0 and
// finite (sensor holes are not supervised). Mean over the counted pixels.
bool depth_l1_loss(const PlanarImage& rendered, const PlanarImage& observed,
                   const PlanarImage* mask, double weight, double* loss, PlanarImage* grad,
                   std::string* why = nullptr);

// ---- SSIM --------------------------------------------------------------------------------------

// weight * (1 - mean SSIM) over the counted pixels x channels, SSIM as fslam/core/math/ssim.hpp
// defines it (11 x 11 Gaussian window, sigma 1.5, zero-padded 'same' moments, C1 and C2 for
// data range 1, each channel on its own). The mask only selects which SSIM values are averaged;
// the windows still read every pixel. Exact gradient, by separable blurs (8 per channel).
bool ssim_loss(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
               double weight, double* loss, PlanarImage* grad, std::string* why = nullptr);

// ---- patch-wise Pearson correlation of depth (eq. pcc_loss) -----------------------------------

struct PccConfig {
  int block = 8;  // p, pixels: the image is tiled into p x p blocks from (0, 0); edge blocks
                  // are cut by the image border
  int min_valid_pixels = 32;  // a block with fewer valid pixels is skipped (>= 3: any two
                              // points correlate perfectly)
  double min_std = 1e-3;  // metres; a block whose rendered or observed depth varies less is
                          // skipped: its correlation is sensor noise and 1 / std blows the
                          // gradient up (a fronto-parallel wall renders constant depth)
};
bool validate(const PccConfig& config, std::string* why);

// Depth [1, H, W], metres. A pixel is valid when the observed depth is > 0 and finite and the
// mask allows. Per used block rho = zero-mean normalised cross-correlation of rendered and
// observed over its valid pixels; loss = weight * (1 - mean rho over the used blocks).
// blocks_used (optional): how many blocks entered the mean.
bool pcc_loss(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
              const PccConfig& config, double weight, double* loss, PlanarImage* grad,
              std::string* why = nullptr, int* blocks_used = nullptr);

// ---- normals -----------------------------------------------------------------------------------

// depth [1, H, W] metres -> normals [3, H, W]: camera-frame unit normals facing the camera
// (n . P < 0), by central differences of the unprojected left/right and up/down neighbours;
// exactly 0 where the pixel or one of its four neighbours has no depth (<= 0 or not finite),
// on the image border, and where the differences are parallel. normals is resized.
bool depth_to_normals(const PlanarImage& depth, const math::Intrinsics& intrinsics,
                      PlanarImage* normals, std::string* why = nullptr);

// Backward of depth_to_normals: grad_normals [3, H, W] = dL/dnormals; ADDS dL/ddepth into
// grad_depth ([1, H, W]; an empty one is sized and zeroed).
bool depth_to_normals_backward(const PlanarImage& depth, const math::Intrinsics& intrinsics,
                               const PlanarImage& grad_normals, PlanarImage* grad_depth,
                               std::string* why = nullptr);

// Normal consistency (eq. modeling_losses, L_nrm): weight * mean over the pixels where both
// normals are defined (non-zero) and the mask allows of (1 - n_r . n_o). Normals [3, H, W],
// unit where defined. Mean over counted pixels (not x 3). grad: w.r.t. the rendered normals,
// -weight * n_o / count (chain it through depth_to_normals_backward).
bool normal_consistency_loss(const PlanarImage& rendered_normals,
                             const PlanarImage& observed_normals, const PlanarImage* mask,
                             double weight, double* loss, PlanarImage* grad,
                             std::string* why = nullptr);

// ---- Gaussian shape regularisers ---------------------------------------------------------------

// eq. erank_loss: lambda * mean over Gaussians of -log(erank - 1 + epsilon), erank = exp(H) of
// the normalised squared scales (eq. norm_singular, eq. entropy). log_scales: [N, 3]
// (GaussianMap::log_scales); grad (optional) [N, 3] += dLoss/dlog_scales (empty: sized, zeroed).
// epsilon > 0 keeps the barrier finite for perfect needles (erank = 1).
bool erank_loss(const std::vector<float>& log_scales, double lambda, double epsilon, double* loss,
                std::vector<float>* grad, std::string* why = nullptr);

// eq. thin_loss: lambda * mean over Gaussians of the smallest scale exp(min_k log_scale);
// grad as for erank_loss (only the smallest axis of each Gaussian gets a gradient).
bool thin_loss(const std::vector<float>& log_scales, double lambda, double* loss,
               std::vector<float>* grad, std::string* why = nullptr);

// eq. lambda_ramp: the eRank weight at optimisation step `step`, rising from lambda_0 towards
// lambda_max with time constant ramp_steps (<= 0: lambda_max from the start).
double erank_lambda(int step, double lambda_0, double lambda_max, double ramp_steps);

}  // namespace fslam::core
