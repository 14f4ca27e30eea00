#include "fslam/core/tracking/point_features.hpp"

#include <algorithm>
#include <cmath>

namespace fslam::core {

void sample_point_features(const PlanarImage& latent, const PinholeCamera& camera,
                           GaussianPoints* points) {
  const int d = latent.channels;
  points->feature_dim = d;
  points->features.assign(points->size() * static_cast<std::size_t>(d), 0.0f);
  const double sx = static_cast<double>(latent.width) / camera.width;
  const double sy = static_cast<double>(latent.height) / camera.height;
  for (std::size_t i = 0; i < points->size(); ++i) {
    const Eigen::Vector3d p = points->means[i].cast<double>();
    if (!(p.z() > 0)) continue;
    const Eigen::Vector2d uv = camera.project(p);
    const double x = std::clamp((uv.x() + 0.5) * sx - 0.5, 0.0, latent.width - 1.0);
    const double y = std::clamp((uv.y() + 0.5) * sy - 0.5, 0.0, latent.height - 1.0);
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const int x1 = std::min(x0 + 1, latent.width - 1), y1 = std::min(y0 + 1, latent.height - 1);
    const float tx = static_cast<float>(x - x0), ty = static_cast<float>(y - y0);
    float* f = &points->features[i * static_cast<std::size_t>(d)];
    for (int c = 0; c < d; ++c) {
      f[c] = (1 - ty) * ((1 - tx) * latent.at(c, y0, x0) + tx * latent.at(c, y0, x1)) +
             ty * ((1 - tx) * latent.at(c, y1, x0) + tx * latent.at(c, y1, x1));
    }
  }
}

}  // namespace fslam::core
