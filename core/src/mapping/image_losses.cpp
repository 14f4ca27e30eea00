#include "fslam/core/mapping/image_losses.hpp"

#include <cmath>
#include <string>

#include "fslam/core/error.hpp"
#include "fslam/core/mapping/image_losses_impl.hpp"
#include "fslam/core/math/loss_math.hpp"

namespace fslam::core {
namespace {

std::string shape(const PlanarImage& img) {
  return "[" + std::to_string(img.channels) + ", " + std::to_string(img.height) + ", " +
         std::to_string(img.width) + "]";
}

bool check_image(const PlanarImage& img, const char* what, const char* name, std::string* why) {
  if (img.width <= 0 || img.height <= 0 || img.channels <= 0 ||
      img.data.size() != img.pixels() * static_cast<std::size_t>(img.channels))
    return fail(why, std::string(what) + ": " + name + " image " + shape(img) +
                         " is empty or its data does not match its shape");
  return true;
}

// rendered and observed: same non-empty shape, `channels` of them when > 0; mask [1, H, W].
bool check_pair(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
                int channels, const char* what, std::string* why) {
  if (!check_image(rendered, what, "rendered", why) ||
      !check_image(observed, what, "observed", why))
    return false;
  if (!rendered.same_shape(observed))
    return fail(why, std::string(what) + ": rendered " + shape(rendered) + " and observed " +
                         shape(observed) + " differ in shape");
  if (channels > 0 && rendered.channels != channels)
    return fail(why, std::string(what) + ": expected " + std::to_string(channels) +
                         " channel(s), got " + shape(rendered));
  if (mask) {
    if (!check_image(*mask, what, "mask", why)) return false;
    if (mask->channels != 1 || mask->width != rendered.width || mask->height != rendered.height)
      return fail(why, std::string(what) + ": mask " + shape(*mask) + " must be [1, " +
                           std::to_string(rendered.height) + ", " + std::to_string(rendered.width) +
                           "]");
  }
  return true;
}

// An empty grad is sized like `like` and zeroed; a non-empty one must match it.
bool prepare_grad(const PlanarImage& like, PlanarImage* grad, const char* what, std::string* why) {
  if (!grad) return true;
  if (grad->empty()) {
    *grad = PlanarImage(like.width, like.height, like.channels, 0.0f);
    return true;
  }
  if (!grad->same_shape(like) ||
      grad->data.size() != like.pixels() * static_cast<std::size_t>(like.channels))
    return fail(why, std::string(what) + ": gradient " + shape(*grad) + " must be " + shape(like) +
                         " (or empty)");
  return true;
}

// The weight is finite and there is somewhere to put the value.
bool check_weight(double weight, const double* loss, const char* what, std::string* why) {
  if (!std::isfinite(weight)) return fail(why, std::string(what) + ": weight must be finite");
  if (!loss) return fail(why, std::string(what) + ": no output for the loss value");
  return true;
}

const float* mask_data(const PlanarImage* mask) { return mask ? mask->data.data() : nullptr; }
float* grad_data(PlanarImage* grad) { return grad ? grad->data.data() : nullptr; }

bool check_log_scales(const std::vector<float>& log_scales, std::vector<float>* grad,
                      const char* what, std::string* why) {
  if (log_scales.size() % 3 != 0)
    return fail(why, std::string(what) + ": log_scales holds " + std::to_string(log_scales.size()) +
                         " values, not [N, 3]");
  if (grad) {
    if (grad->empty()) grad->assign(log_scales.size(), 0.0f);
    if (grad->size() != log_scales.size())
      return fail(why, std::string(what) + ": gradient holds " + std::to_string(grad->size()) +
                           " values, log_scales " + std::to_string(log_scales.size()));
  }
  return true;
}

bool check_intrinsics(const math::Intrinsics& k, const char* what, std::string* why) {
  if (!(std::isfinite(k.fx) && std::isfinite(k.fy) && std::isfinite(k.cx) && std::isfinite(k.cy) &&
        k.fx > 0.0f && k.fy > 0.0f))
    return fail(why, std::string(what) + ": intrinsics need finite fx, fy > 0 and cx, cy");
  return true;
}

}  // namespace

bool l1_loss(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
             double weight, double* loss, PlanarImage* grad, std::string* why) {
  constexpr const char* kWhat = "L1 loss";
  if (!check_pair(rendered, observed, mask, 0, kWhat, why) ||
      !check_weight(weight, loss, kWhat, why) || !prepare_grad(rendered, grad, kWhat, why))
    return false;
  *loss = loss_impl::l1_loss(rendered.data.data(), observed.data.data(), mask_data(mask),
                             rendered.channels, rendered.pixels(), false, weight, grad_data(grad));
  return true;
}

bool depth_l1_loss(const PlanarImage& rendered, const PlanarImage& observed,
                   const PlanarImage* mask, double weight, double* loss, PlanarImage* grad,
                   std::string* why) {
  constexpr const char* kWhat = "depth L1 loss";
  if (!check_pair(rendered, observed, mask, 1, kWhat, why) ||
      !check_weight(weight, loss, kWhat, why) || !prepare_grad(rendered, grad, kWhat, why))
    return false;
  *loss = loss_impl::l1_loss(rendered.data.data(), observed.data.data(), mask_data(mask), 1,
                             rendered.pixels(), true, weight, grad_data(grad));
  return true;
}

bool ssim_loss(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
               double weight, double* loss, PlanarImage* grad, std::string* why) {
  constexpr const char* kWhat = "SSIM loss";
  if (!check_pair(rendered, observed, mask, 0, kWhat, why) ||
      !check_weight(weight, loss, kWhat, why) || !prepare_grad(rendered, grad, kWhat, why))
    return false;
  *loss = loss_impl::ssim_loss(rendered.data.data(), observed.data.data(), mask_data(mask),
                               rendered.channels, rendered.width, rendered.height, weight,
                               grad_data(grad));
  return true;
}

bool validate(const PccConfig& config, std::string* why) {
  if (config.block < 2)
    return fail(why, "PCC block must be at least 2 pixels, got " + std::to_string(config.block));
  if (config.min_valid_pixels < 3 || config.min_valid_pixels > config.block * config.block)
    return fail(why, "PCC min_valid_pixels must be in [3, block^2 = " +
                         std::to_string(config.block * config.block) + "], got " +
                         std::to_string(config.min_valid_pixels));
  if (!std::isfinite(config.min_std) || !(config.min_std > 0.0))
    return fail(why, "PCC min_std must be positive (metres)");
  return true;
}

bool pcc_loss(const PlanarImage& rendered, const PlanarImage& observed, const PlanarImage* mask,
              const PccConfig& config, double weight, double* loss, PlanarImage* grad,
              std::string* why, int* blocks_used) {
  constexpr const char* kWhat = "PCC loss";
  if (!validate(config, why) || !check_pair(rendered, observed, mask, 1, kWhat, why) ||
      !check_weight(weight, loss, kWhat, why) || !prepare_grad(rendered, grad, kWhat, why))
    return false;
  *loss = loss_impl::pcc_loss(rendered.data.data(), observed.data.data(), mask_data(mask),
                              rendered.width, rendered.height, config, weight, grad_data(grad),
                              blocks_used);
  return true;
}

bool depth_to_normals(const PlanarImage& depth, const math::Intrinsics& intrinsics,
                      PlanarImage* normals, std::string* why) {
  constexpr const char* kWhat = "depth_to_normals";
  if (!check_image(depth, kWhat, "depth", why) || !check_intrinsics(intrinsics, kWhat, why))
    return false;
  if (depth.channels != 1)
    return fail(why, std::string(kWhat) + ": depth " + shape(depth) + " must have one channel");
  *normals = PlanarImage(depth.width, depth.height, 3, 0.0f);
  loss_impl::depth_to_normals(depth.data.data(), depth.width, depth.height, intrinsics,
                              normals->data.data());
  return true;
}

bool depth_to_normals_backward(const PlanarImage& depth, const math::Intrinsics& intrinsics,
                               const PlanarImage& grad_normals, PlanarImage* grad_depth,
                               std::string* why) {
  constexpr const char* kWhat = "depth_to_normals_backward";
  if (!check_image(depth, kWhat, "depth", why) ||
      !check_image(grad_normals, kWhat, "normal gradient", why) ||
      !check_intrinsics(intrinsics, kWhat, why))
    return false;
  if (depth.channels != 1 || grad_normals.channels != 3 || grad_normals.width != depth.width ||
      grad_normals.height != depth.height)
    return fail(why, std::string(kWhat) + ": depth " + shape(depth) + " and normal gradient " +
                         shape(grad_normals) + " must be [1, H, W] and [3, H, W]");
  if (!grad_depth) return fail(why, std::string(kWhat) + ": no depth gradient to add into");
  if (!prepare_grad(depth, grad_depth, kWhat, why)) return false;
  loss_impl::depth_to_normals_backward(depth.data.data(), depth.width, depth.height, intrinsics,
                                       grad_normals.data.data(), grad_depth->data.data());
  return true;
}

bool normal_consistency_loss(const PlanarImage& rendered_normals,
                             const PlanarImage& observed_normals, const PlanarImage* mask,
                             double weight, double* loss, PlanarImage* grad, std::string* why) {
  constexpr const char* kWhat = "normal consistency loss";
  if (!check_pair(rendered_normals, observed_normals, mask, 3, kWhat, why) ||
      !check_weight(weight, loss, kWhat, why) || !prepare_grad(rendered_normals, grad, kWhat, why))
    return false;
  *loss = loss_impl::normal_consistency_loss(rendered_normals.data.data(),
                                             observed_normals.data.data(), mask_data(mask),
                                             rendered_normals.pixels(), weight, grad_data(grad));
  return true;
}

bool erank_loss(const std::vector<float>& log_scales, double lambda, double epsilon, double* loss,
                std::vector<float>* grad, std::string* why) {
  constexpr const char* kWhat = "eRank loss";
  if (!check_weight(lambda, loss, kWhat, why)) return false;
  if (!std::isfinite(epsilon) || !(epsilon > 0.0))
    return fail(why, std::string(kWhat) + ": epsilon must be positive (it bounds the barrier)");
  if (!check_log_scales(log_scales, grad, kWhat, why)) return false;
  *loss = loss_impl::erank_loss(log_scales.data(), log_scales.size() / 3, lambda, epsilon,
                                grad ? grad->data() : nullptr);
  return true;
}

bool thin_loss(const std::vector<float>& log_scales, double lambda, double* loss,
               std::vector<float>* grad, std::string* why) {
  constexpr const char* kWhat = "thin loss";
  if (!check_weight(lambda, loss, kWhat, why) || !check_log_scales(log_scales, grad, kWhat, why))
    return false;
  *loss = loss_impl::thin_loss(log_scales.data(), log_scales.size() / 3, lambda,
                               grad ? grad->data() : nullptr);
  return true;
}

double erank_lambda(int step, double lambda_0, double lambda_max, double ramp_steps) {
  return math::lambda_ramp(static_cast<double>(step), lambda_0, lambda_max, ramp_steps);
}

}  // namespace fslam::core
