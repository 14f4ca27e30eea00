// Kinect v1-like depth degradation (structured light) and mild colour noise. Every random number
// is a hash of (seed, frame, pixel, purpose), so rows can be processed in any order.
//
// References: C. V. Nguyen, S. Izadi, D. Lovell, "Modeling Kinect Sensor Noise for Improved 3D
// Reconstruction and Tracking", 3DIMPVT 2012 (axial sigma); K. Khoshelham, S. O. Elberink,
// "Accuracy and Resolution of Kinect Depth Data", Sensors 2012 (disparity quantisation, 1/8 px).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "fslam/core/synth/synthetic_scene.hpp"
#include "synth_random.hpp"

namespace fslam::core {
namespace {

constexpr double kHalfPi = 1.5707963267948966;
constexpr double kBaseline = 0.075;   // m, projector to the right of the depth camera
constexpr double kSubpixel = 8.0;     // disparity steps per pixel
constexpr double kMinRange = 0.5;     // m
constexpr double kMaxRange = 5.0;     // m
constexpr double kEdgeDropout = 0.5;  // probability at a depth discontinuity
constexpr double kRandomDropout = 0.005;
constexpr double kGrazingStart = 1.22;  // rad (70 deg): returns start to drop out
constexpr double kGrazingEnd = 1.48;    // rad (85 deg): no returns
constexpr double kColourSigma = 2.0;    // 8-bit levels

// Purposes of the per-pixel random numbers.
enum Draw : std::uint64_t { kEdge, kGrazing, kDropout, kDepth, kColour0 };

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

// Nguyen et al. (2012), eq. 6: sigma_z(z, theta) for z in metres, theta the angle between the
// surface normal and the viewing ray (clamped where the fit diverges).
double axial_sigma(double z, double theta) {
  theta = std::min(theta, 1.3);
  const double t = theta / (kHalfPi - theta);
  return 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4) + 0.0001 / std::sqrt(z) * t * t;
}

}  // namespace

void apply_kinect_noise(const PinholeCamera& camera, std::uint64_t seed, std::uint64_t frame,
                        SynthView* view) {
  assert(view && view->depth.type() == CV_32FC1 && view->normal.type() == CV_32FC3 &&
         view->colour.type() == CV_8UC3);
  const int W = view->depth.cols, H = view->depth.rows;
  const cv::Mat exact = view->depth.clone();
  const double fb = camera.fx * kBaseline;  // disparity (px) = fb / z
  const std::uint64_t key =
      synth::hash_combine(synth::stream_seed(seed, synth::Stream::noise), frame);

  tbb::parallel_for(tbb::blocked_range<int>(0, H, 8), [&](const tbb::blocked_range<int>& rows) {
    std::vector<std::uint8_t> shadowed(W);
    for (int v = rows.begin(); v < rows.end(); ++v) {
      const float* z_row = exact.ptr<float>(v);
      const float* z_up = exact.ptr<float>(std::max(v - 1, 0));
      const float* z_down = exact.ptr<float>(std::min(v + 1, H - 1));
      // Projector shadow: P (column u, disparity d) is hidden from the projector when some
      // surface at u' > u in the same row has d' - u' > d - u (the projector's ray to P passes
      // behind it). One right-to-left scan keeps the running maximum of d' - u'.
      double best = -std::numeric_limits<double>::infinity();
      for (int u = W - 1; u >= 0; --u) {
        shadowed[u] = 0;
        if (z_row[u] <= 0.0f) continue;
        const double key_u = fb / z_row[u] - u;
        shadowed[u] = best > key_u ? 1 : 0;
        best = std::max(best, key_u);
      }

      float* depth = view->depth.ptr<float>(v);
      const cv::Vec3f* normal = view->normal.ptr<cv::Vec3f>(v);
      cv::Vec3b* colour = view->colour.ptr<cv::Vec3b>(v);
      for (int u = 0; u < W; ++u) {
        const std::uint64_t pixel = key + (static_cast<std::uint64_t>(v) * W + u) * 16;
        auto bits = [&](std::uint64_t what) { return synth::mix64(pixel + what); };
        auto draw = [&](std::uint64_t what) { return synth::to_unit(bits(what)); };

        for (int c = 0; c < 3; ++c) {
          const double g = synth::approx_gaussian(bits(kColour0 + c));
          colour[u][c] = static_cast<std::uint8_t>(
              std::clamp(std::lround(colour[u][c] + kColourSigma * g), 0L, 255L));
        }

        const double z = z_row[u];
        if (z <= 0.0) continue;
        const Eigen::Vector3d ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
        const Eigen::Vector3d n(normal[u][0], normal[u][1], normal[u][2]);
        const double theta = std::acos(std::clamp(-n.dot(ray) / ray.norm(), -1.0, 1.0));
        bool edge = false;
        const float neighbours[4] = {z_row[std::max(u - 1, 0)], z_row[std::min(u + 1, W - 1)],
                                     z_up[u], z_down[u]};
        for (float zn : neighbours)
          if (zn > 0.0f && std::abs(zn - z) > 0.03 * z + 0.01) edge = true;

        if (shadowed[u] || z < kMinRange || z > kMaxRange || (edge && draw(kEdge) < kEdgeDropout) ||
            draw(kGrazing) < smoothstep(kGrazingStart, kGrazingEnd, theta) ||
            draw(kDropout) < kRandomDropout) {
          depth[u] = 0.0f;
          continue;
        }
        const double noisy = z + axial_sigma(z, theta) * synth::approx_gaussian(bits(kDepth));
        const double disparity = std::round(fb / noisy * kSubpixel) / kSubpixel;
        depth[u] = disparity > 0.0 ? static_cast<float>(fb / disparity) : 0.0f;
      }
    }
  });
}

}  // namespace fslam::core
