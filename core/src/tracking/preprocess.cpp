#include "fslam/core/tracking/preprocess.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <tuple>
#include <vector>

#include <Eigen/Geometry>
#include <flann/flann.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/math/unproject.hpp"

namespace fslam::core {

namespace {

using core::fail;

// A depth image the camera describes: non-empty CV_32FC1 metres, valid intrinsics, same size.
bool check_depth_and_camera(const cv::Mat& depth, const PinholeCamera& camera, std::string* why) {
  if (depth.empty() || depth.type() != CV_32FC1) return fail(why, "depth must be a non-empty CV_32FC1 image in metres");
  std::string reason;
  if (!camera.is_valid(&reason)) return fail(why, "bad intrinsics: " + reason);
  if (depth.cols != camera.width || depth.rows != camera.height) {
    return fail(why, "depth is " + std::to_string(depth.cols) + "x" + std::to_string(depth.rows) +
                         " but the camera is " + std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  return true;
}

constexpr float kMissing = std::numeric_limits<float>::quiet_NaN();

// FLANN reads the means in place as an [N, 3] row-major float matrix.
static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "Vector3f must be unpadded");

// Running moments of neighbour offsets q = p - centre. Offsets are centimetres where coordinates
// are metres, so E[q q^T] - E[q] E[q]^T keeps its precision in float, which the same formula
// over raw coordinates would not.
struct OffsetMoments {
  float n = 0.0f;
  float sx = 0.0f, sy = 0.0f, sz = 0.0f;
  float sxx = 0.0f, sxy = 0.0f, sxz = 0.0f, syy = 0.0f, syz = 0.0f, szz = 0.0f;

  void add(float x, float y, float z) {
    n += 1.0f;
    sx += x;
    sy += y;
    sz += z;
    sxx += x * x;
    sxy += x * y;
    sxz += x * z;
    syy += y * y;
    syz += y * z;
    szz += z * z;
  }

  // Sample covariance of the points added (the centre included as the offset 0).
  Eigen::Matrix3f covariance() const {
    const float inv = 1.0f / n;
    const float mx = sx * inv, my = sy * inv, mz = sz * inv;
    Eigen::Matrix3f c;
    c(0, 0) = sxx * inv - mx * mx;
    c(0, 1) = c(1, 0) = sxy * inv - mx * my;
    c(0, 2) = c(2, 0) = sxz * inv - mx * mz;
    c(1, 1) = syy * inv - my * my;
    c(1, 2) = c(2, 1) = syz * inv - my * mz;
    c(2, 2) = szz * inv - mz * mz;
    return c;
  }
};

// Unit eigenvector of the smallest eigenvalue of a symmetric positive semi-definite 3x3 matrix.
// The characteristic polynomial q(l) = l^3 - c2 l^2 + c1 l - c0 is negative, increasing and
// concave left of its smallest root, so Newton's method from l = 0 climbs to that root without
// overshooting, in two or three steps for a surface (smallest eigenvalue far below the others).
// The eigenvector is then the largest column of adj(A - l I), i.e. the largest cross product of
// two rows. No trigonometry and one eigenvector instead of the three of Eigen's computeDirect
// (the same answer to float precision; see the test against it), in scalar code the compiler
// keeps in registers: this runs once per point.
Eigen::Vector3f smallest_eigenvector(const Eigen::Matrix3f& raw) {
  const float scale = raw.cwiseAbs().maxCoeff();
  // All samples coincide (or overflowed): any direction is as good.
  if (!(scale > 0.0f && scale <= std::numeric_limits<float>::max()))
    return Eigen::Vector3f::UnitZ();
  const float inv_scale = 1.0f / scale;  // entries in [-1, 1] from here on
  const float a00 = raw(0, 0) * inv_scale, a01 = raw(0, 1) * inv_scale, a02 = raw(0, 2) * inv_scale;
  const float a11 = raw(1, 1) * inv_scale, a12 = raw(1, 2) * inv_scale, a22 = raw(2, 2) * inv_scale;
  const float c2 = a00 + a11 + a22;
  const float c1 = (a11 * a22 - a12 * a12) + (a00 * a22 - a02 * a02) + (a00 * a11 - a01 * a01);
  const float c0 =
      a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02);
  float lambda = 0.0f;
  for (int iteration = 0; iteration < 16 && c0 > 0.0f; ++iteration) {
    const float q = ((lambda - c2) * lambda + c1) * lambda - c0;
    const float dq = (3.0f * lambda - 2.0f * c2) * lambda + c1;
    if (!(q < 0.0f && dq > 0.0f)) break;  // at the root up to rounding
    const float step = -q / dq;
    lambda += step;
    // Quadratic convergence: the error left is about step^2 / lambda, far below what moves the
    // eigenvector (its angle error is about error / (second eigenvalue - lambda)).
    if (step <= 1e-3f * lambda) break;
  }
  const float b00 = a00 - lambda, b11 = a11 - lambda, b22 = a22 - lambda;
  // Columns of adj(B), B = A - lambda I with rows (b00 a01 a02), (a01 b11 a12), (a02 a12 b22).
  const Eigen::Vector3f c[3] = {
      {b11 * b22 - a12 * a12, a12 * a02 - a01 * b22, a01 * a12 - b11 * a02},
      {a02 * a12 - a01 * b22, b00 * b22 - a02 * a02, a02 * a01 - b00 * a12},
      {a01 * a12 - a02 * b11, a02 * a01 - b00 * a12, b00 * b11 - a01 * a01}};
  const float norms[3] = {c[0].squaredNorm(), c[1].squaredNorm(), c[2].squaredNorm()};
  const int best =
      norms[0] >= norms[1] ? (norms[0] >= norms[2] ? 0 : 2) : (norms[1] >= norms[2] ? 1 : 2);
  // Cross products at rounding level: B has rank <= 1 (collinear samples), and every direction
  // across the line is an eigenvector of the smallest eigenvalue.
  constexpr float kRankOneLevel = 1e-12f;
  if (norms[best] > kRankOneLevel) return c[best] / std::sqrt(norms[best]);
  const Eigen::Vector3f rows[3] = {{b00, a01, a02}, {a01, b11, a12}, {a02, a12, b22}};
  const int longest = rows[0].squaredNorm() >= rows[1].squaredNorm()
                          ? (rows[0].squaredNorm() >= rows[2].squaredNorm() ? 0 : 2)
                          : (rows[1].squaredNorm() >= rows[2].squaredNorm() ? 1 : 2);
  return rows[longest].squaredNorm() > 0.0f ? rows[longest].unitOrthogonal()
                                            : Eigen::Vector3f::UnitZ();
}

// v where mask is all ones, +0 where it is zero (NaN included). A bit mask rather than
// `in ? v : 0.0f`, which GCC 12 does not if-convert in the window loop below, leaving it scalar.
inline float masked(float v, std::uint32_t mask) {
  std::uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  bits &= mask;
  std::memcpy(&v, &bits, sizeof v);
  return v;
}

// Depth on the image lattice (every stride-th pixel in u and v) as camera-frame points, stored
// as three padded planes so that the window sums below read neighbours without bounds checks
// and vectorise across a row.
struct Lattice {
  static constexpr int kChunk = 32;  // centres per vectorised block; the pitch is padded to it
  int rows = 0;
  int cols = 0;
  int pad = 0;                 // NaN cells around the image, >= the window radius
  int pitch = 0;               // floats per padded row: pad + round_up(cols, kChunk) + pad
  std::vector<float> x, y, z;  // [rows + 2 pad, pitch] metres, camera frame; NaN = missing
  std::size_t valid = 0;

  std::size_t index(int lv, int lu) const {
    return static_cast<std::size_t>(lv + pad) * pitch + static_cast<std::size_t>(lu + pad);
  }
  Eigen::Vector3f point(std::size_t i) const { return {x[i], y[i], z[i]}; }
};

void unproject_lattice(const cv::Mat& depth, const math::Intrinsics& k,
                       const PreprocessConfig& config, Lattice* lattice) {
  const int stride = config.stride;
  Lattice& l = *lattice;
  l.rows = (depth.rows + stride - 1) / stride;
  l.cols = (depth.cols + stride - 1) / stride;
  l.pad = config.covariance.window_radius;
  l.pitch = 2 * l.pad + (l.cols + Lattice::kChunk - 1) / Lattice::kChunk * Lattice::kChunk;
  const std::size_t cells = static_cast<std::size_t>(l.rows + 2 * l.pad) * l.pitch;
  l.x.assign(cells, kMissing);
  l.y.assign(cells, kMissing);
  l.z.assign(cells, kMissing);
  l.valid = 0;
  for (int lv = 0; lv < l.rows; ++lv) {
    const int v = lv * stride;
    const float* row = depth.ptr<float>(v);  // [W] metres
    for (int lu = 0; lu < l.cols; ++lu) {
      const int u = lu * stride;
      const float z = row[u];
      if (!math::depth_is_valid(z, config.min_depth, config.max_depth)) continue;
      float p[3];
      math::unproject_pixel(k, static_cast<float>(u), static_cast<float>(v), z, p);
      const std::size_t i = l.index(lv, lu);
      l.x[i] = p[0];
      l.y[i] = p[1];
      l.z[i] = p[2];
      ++l.valid;
    }
  }
}

// Depth samples math::depth_is_valid accepts, over every pixel. The predicate is written out
// as (z > min) & (z < max), which is the same for every float (NaN fails both comparisons) but
// has no short-circuit, so the loop vectorises: 0.04 instead of 0.38 ms per VGA frame here.
// The Preprocess.ValidPixelCountUsesDepthIsValid test pins the two together.
std::size_t count_valid_pixels(const cv::Mat& depth, const PreprocessConfig& config) {
  const float lo = config.min_depth, hi = config.max_depth;
  std::size_t count = 0;
  for (int v = 0; v < depth.rows; ++v) {
    const float* row = depth.ptr<float>(v);  // [W] metres
    std::uint32_t row_count = 0;
    for (int u = 0; u < depth.cols; ++u)
      row_count += static_cast<std::uint32_t>((row[u] > lo) & (row[u] < hi));
    count += row_count;
  }
  return count;
}

// Covariances from the projective neighbourhood: the lattice cells within +-window_radius,
// closer than max_neighbour_distance in 3D. On an organised image these are the k-NN up to the
// depth-discontinuity gate, without a search. The window is summed one offset at a time over a
// block of kChunk centres, so the inner loop is a branch-free vector loop; the moments are of
// offsets from the centre (see OffsetMoments).
void covariances_from_lattice(const Lattice& l, const CovarianceConfig& config,
                              GaussianPoints* out) {
  constexpr int kChunk = Lattice::kChunk;
  const int r = config.window_radius;
  const float max_d2 = config.max_neighbour_distance * config.max_neighbour_distance;
  out->reserve(l.valid);
  for (int lv = 0; lv < l.rows; ++lv) {
    for (int u0 = 0; u0 < l.cols; u0 += kChunk) {
      const std::size_t c0 = l.index(lv, u0);
      const float* cx = l.x.data() + c0;
      const float* cy = l.y.data() + c0;
      const float* cz = l.z.data() + c0;
      // Window sums for kChunk centres: count, sum of offsets, sum of offset products.
      float n[kChunk] = {}, sx[kChunk] = {}, sy[kChunk] = {}, sz[kChunk] = {};
      float sxx[kChunk] = {}, sxy[kChunk] = {}, sxz[kChunk] = {};
      float syy[kChunk] = {}, syz[kChunk] = {}, szz[kChunk] = {};
      for (int dv = -r; dv <= r; ++dv) {
        for (int du = -r; du <= r; ++du) {
          const std::ptrdiff_t shift = static_cast<std::ptrdiff_t>(dv) * l.pitch + du;
          const float* nx = cx + shift;
          const float* ny = cy + shift;
          const float* nz = cz + shift;
          for (int i = 0; i < kChunk; ++i) {
            const float dx = nx[i] - cx[i], dy = ny[i] - cy[i], dz = nz[i] - cz[i];
            // NaN (missing neighbour or centre) fails the gate; the centre itself passes.
            const std::uint32_t in = dx * dx + dy * dy + dz * dz <= max_d2 ? ~0u : 0u;
            const float mx = masked(dx, in), my = masked(dy, in), mz = masked(dz, in);
            n[i] += masked(1.0f, in);
            sx[i] += mx;
            sy[i] += my;
            sz[i] += mz;
            sxx[i] += mx * mx;
            sxy[i] += mx * my;
            sxz[i] += mx * mz;
            syy[i] += my * my;
            syz[i] += my * mz;
            szz[i] += mz * mz;
          }
        }
      }
      const int width = std::min(kChunk, l.cols - u0);
      for (int i = 0; i < width; ++i) {
        if (static_cast<int>(n[i]) - 1 < config.min_neighbours) continue;  // missing centres: 0
        OffsetMoments m;
        m.n = n[i];
        m.sx = sx[i];
        m.sy = sy[i];
        m.sz = sz[i];
        m.sxx = sxx[i];
        m.sxy = sxy[i];
        m.sxz = sxz[i];
        m.syy = syy[i];
        m.syz = syz[i];
        m.szz = szz[i];
        out->means.emplace_back(cx[i], cy[i], cz[i]);
        out->covariances.push_back(regularise_covariance(m.covariance(), config.plane_epsilon));
      }
    }
  }
}

// One point per occupied voxel of edge `voxel_size`: the centroid of the lattice points in it.
// Output order is the voxels' lexicographic order, so the result does not depend on hashing.
void voxel_downsample(const Lattice& lattice, float voxel_size, std::vector<Eigen::Vector3f>* out) {
  struct Entry {
    std::int32_t x, y, z;
    std::uint32_t index;  // Lattice::index of the point
  };
  std::vector<Entry> entries;
  entries.reserve(lattice.valid);
  const float inv = 1.0f / voxel_size;
  for (int lv = 0; lv < lattice.rows; ++lv) {
    for (int lu = 0; lu < lattice.cols; ++lu) {
      const std::size_t i = lattice.index(lv, lu);
      const Eigen::Vector3f p = lattice.point(i);
      if (p.x() != p.x()) continue;  // missing
      entries.push_back({static_cast<std::int32_t>(std::floor(p.x() * inv)),
                         static_cast<std::int32_t>(std::floor(p.y() * inv)),
                         static_cast<std::int32_t>(std::floor(p.z() * inv)),
                         static_cast<std::uint32_t>(i)});
    }
  }
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z);
  });
  out->clear();
  for (std::size_t begin = 0; begin < entries.size();) {
    std::size_t end = begin;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    while (end < entries.size() && entries[end].x == entries[begin].x &&
           entries[end].y == entries[begin].y && entries[end].z == entries[begin].z) {
      sum += lattice.point(entries[end].index).cast<double>();
      ++end;
    }
    out->push_back((sum / static_cast<double>(end - begin)).cast<float>());
    begin = end;
  }
}

// Keeps the entries of `values` (rows of `width`) whose keep flag is set, in order.
template <typename T>
void compact_rows(const std::vector<char>& keep, std::size_t width, std::vector<T>* values) {
  if (values->empty()) return;
  std::size_t w = 0;
  for (std::size_t i = 0; i < keep.size(); ++i) {
    if (!keep[i]) continue;
    if (w != i) std::copy_n(values->begin() + i * width, width, values->begin() + w * width);
    ++w;
  }
  values->resize(w * width);
}

}  // namespace

bool CovarianceConfig::is_valid(std::string* why) const {
  if (min_neighbours < 2)
    return fail(why,
                "min_neighbours must be at least 2 (a plane needs the point and two "
                "neighbours), got " +
                    std::to_string(min_neighbours));
  if (knn < min_neighbours)
    return fail(why, "knn (" + std::to_string(knn) + ") must be at least min_neighbours (" +
                         std::to_string(min_neighbours) + ")");
  if (window_radius < 1)
    return fail(
        why, "window_radius must be at least 1 lattice cell, got " + std::to_string(window_radius));
  const int window_cells = (2 * window_radius + 1) * (2 * window_radius + 1) - 1;
  if (window_cells < min_neighbours)
    return fail(why, "window_radius " + std::to_string(window_radius) + " holds only " +
                         std::to_string(window_cells) + " neighbours, fewer than min_neighbours (" +
                         std::to_string(min_neighbours) + ")");
  if (!(std::isfinite(max_neighbour_distance) && max_neighbour_distance > 0.0f))
    return fail(why, "max_neighbour_distance must be positive and finite (metres), got " +
                         std::to_string(max_neighbour_distance));
  if (!(plane_epsilon > 0.0f && plane_epsilon <= 1.0f))
    return fail(why, "plane_epsilon must be in (0, 1], got " + std::to_string(plane_epsilon));
  return true;
}

bool DepthNoiseModel::is_valid(std::string* why) const {
  if (!enabled) return true;
  if (!(std::isfinite(a) && a > 0.0f))
    return fail(why, "a must be positive and finite (metres), got " + std::to_string(a));
  if (!(std::isfinite(b) && b >= 0.0f))
    return fail(why, "b must be >= 0 and finite (1/metre), got " + std::to_string(b));
  if (!std::isfinite(z0)) return fail(why, "z0 must be finite (metres)");
  if (!(std::isfinite(reference_depth) && reference_depth > 0.0f))
    return fail(why, "reference_depth must be positive and finite (metres), got " +
                         std::to_string(reference_depth));
  return true;
}

bool PreprocessConfig::is_valid(std::string* why) const {
  if (!(std::isfinite(min_depth) && min_depth >= 0.0f))
    return fail(why,
                "min_depth must be >= 0 and finite (metres), got " + std::to_string(min_depth));
  if (!(std::isfinite(max_depth) && max_depth > min_depth))
    return fail(why, "max_depth must be finite and greater than min_depth (" +
                         std::to_string(min_depth) + " m), got " + std::to_string(max_depth));
  if (stride < 1)
    return fail(why, "stride must be at least 1 pixel, got " + std::to_string(stride));
  if (!(std::isfinite(voxel_size) && voxel_size >= 0.0f))
    return fail(why, "voxel_size must be >= 0 and finite (metres; 0 disables downsampling), got " +
                         std::to_string(voxel_size));
  std::string reason;
  if (!covariance.is_valid(&reason)) return fail(why, "covariance." + reason);
  if (!depth_noise.is_valid(&reason)) return fail(why, "depth_noise." + reason);
  // Voxel centroids lie about voxel_size apart: a narrower gate leaves at most the 4 edge
  // neighbours of a surface in range, fewer than any useful min_neighbours, and drops every point.
  if (voxel_size > 0.0f && covariance.max_neighbour_distance < 2.0f * voxel_size)
    return fail(why, "covariance.max_neighbour_distance (" +
                         std::to_string(covariance.max_neighbour_distance) +
                         " m) must be at least 2 * voxel_size (" + std::to_string(voxel_size) +
                         " m) when voxel downsampling");
  return true;
}

// The unit-disc convention of Segal et al. (GICP) and small_gicp: Sigma = U diag(eps, 1, 1) U^T
// with U the eigenvectors of the sample covariance, ascending. The scale is 1 (m^2), not the
// sample's spread: only the shape weights the residual, the pose estimate of eq. gicp_pose is
// invariant to a common scale of all covariances, and no point's noise level can dominate.
// With n the smallest-eigenvalue eigenvector this is I - (1 - eps) n n^T, so only n is solved
// for (smallest_eigenvector: 47 ns against computeDirect's 98 ns per matrix here).
Eigen::Matrix3f regularise_covariance(const Eigen::Matrix3f& raw, float plane_epsilon) {
  const Eigen::Vector3f n = smallest_eigenvector(raw);
  const float k = 1.0f - plane_epsilon;
  Eigen::Matrix3f out;
  out(0, 0) = 1.0f - k * n.x() * n.x();
  out(1, 1) = 1.0f - k * n.y() * n.y();
  out(2, 2) = 1.0f - k * n.z() * n.z();
  out(0, 1) = out(1, 0) = -k * n.x() * n.y();
  out(0, 2) = out(2, 0) = -k * n.x() * n.z();
  out(1, 2) = out(2, 1) = -k * n.y() * n.z();
  return out;
}

void estimate_covariances_knn(const CovarianceConfig& config, GaussianPoints* points) {
  assert(points != nullptr);
  assert(config.is_valid());
  const std::size_t n = points->size();
  points->covariances.resize(n);
  if (n == 0) return;
  // k + 1: every query finds itself (or an exact duplicate) at distance 0.
  const std::size_t k = std::min<std::size_t>(static_cast<std::size_t>(config.knn) + 1, n);
  flann::Matrix<float> data(points->means.front().data(), n, 3);  // [N, 3] metres
  flann::Index<flann::L2<float>> index(data, flann::KDTreeSingleIndexParams(10));
  index.buildIndex();
  std::vector<int> indices(n * k);  // [N, k]
  std::vector<float> dists(n * k);  // [N, k] squared metres
  flann::Matrix<int> index_matrix(indices.data(), n, k);
  flann::Matrix<float> dist_matrix(dists.data(), n, k);
  flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
  params.cores = 1;  // core owns no thread pools; callers parallelise across frames if at all
  index.knnSearch(data, index_matrix, dist_matrix, k, params);

  const float max_d2 = config.max_neighbour_distance * config.max_neighbour_distance;
  std::vector<char> keep(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f c = points->means[i];
    OffsetMoments m;
    for (std::size_t j = 0; j < k; ++j) {
      if (!(dists[i * k + j] <= max_d2)) continue;
      const Eigen::Vector3f q = points->means[static_cast<std::size_t>(indices[i * k + j])] - c;
      m.add(q.x(), q.y(), q.z());
    }
    if (static_cast<int>(m.n) - 1 < config.min_neighbours) continue;
    keep[i] = 1;
    points->covariances[i] = regularise_covariance(m.covariance(), config.plane_epsilon);
  }
  compact_rows(keep, 1, &points->means);
  compact_rows(keep, 1, &points->covariances);
  compact_rows(keep, 1, &points->opacities);
  if (points->feature_dim > 0)
    compact_rows(keep, static_cast<std::size_t>(points->feature_dim), &points->features);
  compact_rows(keep, 1, &points->feature_spread);
}

bool preprocess_frame(const RgbdFrame& frame, const PreprocessConfig& config, GaussianPoints* out,
                      PreprocessStats* stats, std::string* why) {
  assert(out != nullptr);
  std::string reason;
  if (!config.is_valid(&reason)) return fail(why, "preprocess config: " + reason);
  if (!check_depth_and_camera(frame.depth, frame.camera, why)) return false;

  out->clear();
  Lattice lattice;
  unproject_lattice(frame.depth, frame.camera.intrinsics(), config, &lattice);
  if (config.voxel_size > 0.0f) {
    voxel_downsample(lattice, config.voxel_size, &out->means);
    estimate_covariances_knn(config.covariance, out);
  } else {
    covariances_from_lattice(lattice, config.covariance, out);
  }
  // The shape is GICP's unit disc; its size is the sensor's depth noise at the point's depth
  // (camera frame here, so z is the depth it was measured at). Scale-free GICP weighs a sample
  // on 2 cm disparity steps at 2.5 m like one at 1 m; on redkitchen those far samples, whose
  // quantisation moves with the camera, pulled every pose back towards the previous one (Sim(3)
  // scale 1.049 and ATE 4.56 cm on frames 0-599 without this, 1.022 and 2.93 cm with it).
  if (config.depth_noise.enabled) {
    for (std::size_t i = 0; i < out->size(); ++i)
      out->covariances[i] *= config.depth_noise.covariance_scale(out->means[i].z());
  }
  if (stats) {
    stats->valid_pixels = count_valid_pixels(frame.depth, config);
    stats->lattice_points = lattice.valid;
    stats->output_points = out->size();
  }
  return true;
}

}  // namespace fslam::core
