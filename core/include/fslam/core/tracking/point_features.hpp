// Features for feature-guided GICP (paper eq. feat_gicp, feat_dist): each camera-frame source
// point takes the frame's latent (LatentFeatures::latent_image) at the pixel it projects to, and
// each keyframe re-observes the local map's target features.
#pragma once

#include <cstddef>

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/render/planar_image.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"
#include "fslam/core/tracking/local_map.hpp"

namespace fslam::core {

// latent: [D, h, w] over the whole frame of `camera` (any resolution; pixel centres map as
// PinholeCamera::scaled does). Bilinear, clamped at the borders; points behind the camera get
// zeros. Sets points->feature_dim = D and fills points->features, and points->feature_spread
// with the mean of ||f(x + s) - f(x)||^2 over the four steps s of one latent cell. With
// `gradient`, also points->feature_gradient (central differences over one cell each way, through
// the projection's Jacobian), which only the feature residual (gicp.feature_residual_weight) reads.
void sample_point_features(const PlanarImage& latent, const PinholeCamera& camera,
                           GaussianPoints* points_camera, bool gradient = false);

// Whether a depth image sees a world point: in front of the camera, inside the image, and
// within max_depth_difference (metres) of the depth at the pixel holding its projection (an
// occluded point is not seen). depth: CV_32FC1 metres, 0 = missing, the size of `camera`.
// uv (optional): the projection, set when seen.
bool depth_sees(const PinholeCamera& camera, const cv::Mat& depth, const Eigen::Isometry3d& T_camera_world,
                const Eigen::Vector3f& point_world, float max_depth_difference, Eigen::Vector2d* uv = nullptr);

// A keyframe re-observes the map: every stored point it sees takes the keyframe's latent where it
// projects (sampled as above), so target features follow the newest view as the paper's map
// features follow the keyframes they are fitted to (L_feat of eq. modeling_losses). Seen:
// depth_sees (occluded points keep theirs). latent: [D, h, w] over the frame of
// `camera`; depth: [H, W] CV_32FC1 metres, 0 = missing, the size of `camera`. Does nothing
// unless the map's feature_dim is D. Returns the number of points refreshed.
std::size_t refresh_map_features(const PlanarImage& latent, const PinholeCamera& camera,
                                 const cv::Mat& depth, const Eigen::Isometry3d& T_world_camera,
                                 float max_depth_difference, LocalMap* map);

}  // namespace fslam::core
