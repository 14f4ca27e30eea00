// Frame preprocessing for tracking: valid depth -> camera-frame points, downsampling, and
// per-point covariances from neighbours (the source set of eq. gicp_sets).
#pragma once

#include <string>

#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {

struct CovarianceConfig {
  int min_neighbours = 6;       // fewer valid neighbours: the point is dropped
  int knn = 10;                 // k for FLANN k-NN on unorganised (voxel-downsampled) points
  int window_radius = 2;        // projective neighbourhood half-size, in lattice cells
  float max_neighbour_distance = 0.1f;  // metres; farther neighbours (other surfaces) are ignored
  // GICP's plane regularisation: eigenvalues replaced by (epsilon, 1, 1), so each covariance is
  // a thin unit disc along the local surface (Segal et al., small_gicp), well conditioned. The
  // scale is 1 m^2 whatever the sample spread; preprocess_frame then scales it by the sensor's
  // depth noise (PreprocessConfig::depth_noise), the one per-point scale that is kept.
  float plane_epsilon = 1e-3f;
  bool is_valid(std::string* why = nullptr) const;
};

// Axial depth noise of a structured-light sensor (Kinect v1), Nguyen, Izadi, Lovell, "Modeling
// Kinect Sensor Noise for Improved 3D Reconstruction and Tracking" (3DIMPVT 2012), eq. 6 without
// its angle term: sigma_z(z) = a + b (z - z0)^2 metres, the model fslam synth also draws from.
// A point's covariance is multiplied by (sigma_z(z) / sigma_z(reference_depth))^2, z its depth in
// the camera that observed it, so a point counts in eq. gicp_pose with the information its depth
// carries: a 2.5 m Kinect sample (9.6 mm; redkitchen depth comes in 19 mm steps there) weighs
// 1/26 of a 1 m one (1.9 mm). reference_depth only fixes where the robust kernel's scale is
// unchanged.
struct DepthNoiseModel {
  bool enabled = true;            // off: every point keeps the unit disc (scale-free GICP)
  float a = 0.0012f;              // metres
  float b = 0.0019f;              // 1/metre
  float z0 = 0.4f;                // metres
  float reference_depth = 1.0f;   // metres; the covariance is the unit disc at this depth
  float sigma(float z) const { return a + b * (z - z0) * (z - z0); }  // metres
  // The factor applied to a covariance observed at depth z (1 when disabled).
  float covariance_scale(float z) const {
    if (!enabled) return 1.0f;
    const float ratio = sigma(z) / sigma(reference_depth);
    return ratio * ratio;
  }
  bool is_valid(std::string* why = nullptr) const;
};

struct PreprocessConfig {
  float min_depth = 0.3f;   // metres; closer samples are missing (Kinect minimum range)
  float max_depth = 6.0f;   // metres; farther samples are missing (noise grows with z^2)
  int stride = 8;           // image-lattice stride: keep every stride-th pixel in u and v (8 at
                            // 640x480: same redkitchen ATE as 4 at ~40 % of the time, docs/tracking.md)
  float voxel_size = 0.0f;  // metres; > 0 additionally voxel-downsamples (one point per voxel)
  CovarianceConfig covariance;
  DepthNoiseModel depth_noise;  // per-point covariance scale by depth (see DepthNoiseModel)
  bool is_valid(std::string* why = nullptr) const;
};

// Per-frame statistics of preprocessing, for the tracker's quality report.
struct PreprocessStats {
  std::size_t valid_pixels = 0;     // depth samples inside [min_depth, max_depth]
  std::size_t lattice_points = 0;   // after the lattice stride
  std::size_t output_points = 0;    // after voxel downsampling and covariance estimation
};

// Camera-frame Gaussian points of `frame`, covariances scaled by config.depth_noise. Missing
// depth is 0, NaN, inf or out of range (the readers already map 0 and 65535 to 0). Returns false
// with `why` on bad input (sizes, intrinsics).
bool preprocess_frame(const RgbdFrame& frame, const PreprocessConfig& config, GaussianPoints* out,
                      PreprocessStats* stats, std::string* why);

// Covariances of unorganised points from their k nearest neighbours (FLANN), regularised as in
// CovarianceConfig; points with too few neighbours are removed (all arrays stay aligned).
void estimate_covariances_knn(const CovarianceConfig& config, GaussianPoints* points);

// The regularisation of CovarianceConfig applied to one raw sample covariance.
Eigen::Matrix3f regularise_covariance(const Eigen::Matrix3f& raw, float plane_epsilon);

}  // namespace fslam::core
