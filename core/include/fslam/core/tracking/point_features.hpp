// Source features for feature-guided GICP (paper eq. feat_gicp, feat_dist): each camera-frame
// point takes the frame's latent (LatentFeatures::latent_image) at the pixel it projects to.
#pragma once

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/render/planar_image.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {

// latent: [D, h, w] over the whole frame of `camera` (any resolution; pixel centres map as
// PinholeCamera::scaled does). Bilinear, clamped at the borders; points behind the camera get
// zeros. Sets points->feature_dim = D and fills points->features.
void sample_point_features(const PlanarImage& latent, const PinholeCamera& camera,
                           GaussianPoints* points_camera);

}  // namespace fslam::core
