// Gaussian maps as the standard 3DGS PLY (Kerbl et al. 2023, the INRIA layout that splat viewers
// load), with our feature latents and 3D filter appended as extra vertex properties.
//
// One `element vertex N`, every property a little-endian float, in this order:
//   x y z  nx ny nz (written as 0)  f_dc_0..2  f_rest_0..f_rest_{3(K-1)-1}  opacity
//   scale_0..2  rot_0..3  feat_0..feat_{D-1}  filter_3d
// f_rest is channel-major: f_rest_{c*(K-1) + k-1} = sh[i, k, c] for k >= 1. opacity is the logit,
// scale_* the log scales, rot_* the quaternion w, x, y, z. filter_3d is a variance in m^2; viewers
// that do not know it render without the 3D filter. (Mip-Splatting's `filter_3D` is a standard
// deviation, so it is deliberately not read as ours.)
#pragma once

#include <cstdint>
#include <string>

#include "fslam/core/map/gaussian_map.hpp"

namespace fslam::core {

// Writes `map` (which must be consistent) as binary little-endian PLY. Parent folders must exist.
// Every write and the sync to disk are checked (file_writer.hpp): a full disk is an error.
bool write_gaussian_ply(const std::string& path, const GaussianMap& map, std::string* why);

// Reads a 3DGS PLY, binary little-endian or ASCII. Properties are found by name in any order;
// sh_degree follows from the f_rest_* count (0, 9, 24 or 45), feature_dim from the feat_* count
// (contiguous from 0); filter_3d is 0 when absent. Unknown properties and elements are skipped.
// Errors name the file: missing required property, non-float property we need, truncated data,
// vertex count inconsistent with the file size, non-finite values, inconsistent map.
bool read_gaussian_ply(const std::string& path, GaussianMap* map, std::string* why);
// The size in bytes of the file write_gaussian_ply writes for `map`.
std::uint64_t gaussian_ply_bytes(const GaussianMap& map);

}  // namespace fslam::core
