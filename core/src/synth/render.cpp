// Ray casting of the synthetic room: one ray per pixel centre against analytic primitives,
// solid procedural textures box-filtered over the pixel footprint, lambertian shading from one
// point light plus ambient.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "fslam/core/synth/synthetic_scene.hpp"
#include "synth_random.hpp"

namespace fslam::core {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kMinT = 1e-6;  // nearest accepted hit, in depth units (m)

// ---------------------------------------------------------------------------------------------
// Textures

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

// Perlin's classic lattice hashing: a fixed permutation of 0..255 (built at compile time from
// an LCG), repeated so that nested lookups need no masking.
struct Permutation {
  std::uint8_t p[512];
};
constexpr Permutation make_permutation() {
  Permutation table{};
  std::uint8_t values[256] = {};
  for (int i = 0; i < 256; ++i) values[i] = static_cast<std::uint8_t>(i);
  std::uint32_t state = 0x2545f491u;
  for (int i = 255; i > 0; --i) {
    state = state * 1664525u + 1013904223u;
    const int j = static_cast<int>((state >> 8) % static_cast<std::uint32_t>(i + 1));
    const std::uint8_t t = values[i];
    values[i] = values[j];
    values[j] = t;
  }
  for (int i = 0; i < 512; ++i) table.p[i] = values[i & 255];
  return table;
}
constexpr Permutation kPermutation = make_permutation();

// Trilinear value noise with a quintic fade: smooth, in [-1, 1], feature size 1, periodic every
// 256 units (several metres even for the finest octave used here). The seed shifts the lattice.
double value_noise(const Vector3d& p, std::uint32_t seed) {
  const std::uint8_t* P = kPermutation.p;
  const double fx = std::floor(p.x()), fy = std::floor(p.y()), fz = std::floor(p.z());
  const int ix = static_cast<int>(static_cast<std::int64_t>(fx) + seed) & 255;
  const int iy = static_cast<int>(static_cast<std::int64_t>(fy) + (seed >> 8)) & 255;
  const int iz = static_cast<int>(static_cast<std::int64_t>(fz) + (seed >> 16)) & 255;
  auto fade = [](double t) { return t * t * t * (t * (t * 6.0 - 15.0) + 10.0); };
  const double u = fade(p.x() - fx), v = fade(p.y() - fy), w = fade(p.z() - fz);
  auto lerp = [](double a, double b, double t) { return a + (b - a) * t; };
  auto value = [](int h) { return h * (2.0 / 255.0) - 1.0; };
  const int a = P[ix] + iy, b = P[ix + 1] + iy;
  const int aa = P[a] + iz, ab = P[a + 1] + iz, ba = P[b] + iz, bb = P[b + 1] + iz;
  const double x00 = lerp(value(P[aa]), value(P[ba]), u);
  const double x10 = lerp(value(P[ab]), value(P[bb]), u);
  const double x01 = lerp(value(P[aa + 1]), value(P[ba + 1]), u);
  const double x11 = lerp(value(P[ab + 1]), value(P[bb + 1]), u);
  return lerp(lerp(x00, x10, v), lerp(x01, x11, v), w);
}

// Up to `octaves` octaves of value noise at feature size `scale` (m); octaves finer than about
// two pixel footprints `fw` (m) fade out instead of aliasing. Roughly in [-1, 1].
double fbm(const Vector3d& p, double scale, double fw, std::uint32_t seed, int octaves = 3) {
  double sum = 0.0, amplitude = 0.55, wavelength = scale;
  for (int octave = 0; octave < octaves; ++octave) {
    const double weight = smoothstep(1.5 * fw, 3.0 * fw, wavelength);
    if (weight <= 0.0) break;
    sum += weight * amplitude *
           value_noise(p / wavelength + Vector3d::Constant(17.3 * octave), seed + 0x9e37u * octave);
    amplitude *= 0.5;
    wavelength *= 0.5;
  }
  return sum;
}

// Integral of a 0/1 square wave of period P that is 1 on the second half of each period.
double square_integral(double x, double P) {
  const double c = std::floor(x / P);
  return c * 0.5 * P + std::max(0.0, x - c * P - 0.5 * P);
}

// The square wave box-filtered over [x - w, x + w]: soft edges, and its mean 0.5 when w >> P.
double soft_square(double x, double P, double w) {
  return (square_integral(x + w, P) - square_integral(x - w, P)) / (2.0 * w);
}

// Integral of the indicator of lines of width `width` centred on multiples of P.
double line_integral(double x, double P, double width) {
  const double y = x + 0.5 * width;
  const double c = std::floor(y / P);
  return c * width + std::min(y - c * P, width);
}

// Coverage of lines of width `width` every P, box-filtered over [x - w, x + w].
double soft_lines(double x, double P, double width, double w) {
  return (line_integral(x + w, P, width) - line_integral(x - w, P, width)) / (2.0 * w);
}

double cell_random(double cu, double cv, std::uint32_t seed) {
  return synth::to_unit(synth::hash_combine(
      static_cast<std::uint64_t>(static_cast<std::int64_t>(cu)) * 0x9e3779b1ULL + seed,
      static_cast<std::uint64_t>(static_cast<std::int64_t>(cv))));
}

// Albedo at object-frame point p with object-frame normal n; fw = pixel footprint (m).
Vector3d albedo(const SynthMaterial& m, const Vector3d& p, const Vector3d& n, double fw) {
  // In-plane coordinates (u, v) of the face: drop the dominant normal axis. On walls and
  // floors built by make_room, v is vertical (walls) or world y (floor and ceiling).
  const Vector3d an = n.cwiseAbs();
  double u, v;
  if (an.z() >= an.x() && an.z() >= an.y()) {
    u = p.x();
    v = p.y();
  } else if (an.x() >= an.y()) {
    u = p.y();
    v = p.z();
  } else {
    u = p.x();
    v = p.z();
  }
  // Pattern edges are blurred over at least 4 % of the period: sharp enough for features,
  // smooth enough for photometric gradients.
  const double soft = std::max(fw, 0.04 * m.period);
  const std::uint32_t seed = m.texture_seed;
  Vector3d colour = m.colour_a;
  switch (m.pattern) {
    case SynthPattern::noise: {
      const double t = std::clamp(0.5 + 0.9 * fbm(p, m.period, fw, seed), 0.0, 1.0);
      colour = m.colour_a + t * (m.colour_b - m.colour_a);
      break;
    }
    case SynthPattern::stripes: {
      const double s = p.dot(m.axis) + 0.15 * m.period * fbm(p, 2.0 * m.period, fw, seed + 1, 1);
      const double t = soft_square(s, m.period, soft);
      colour = m.colour_a + t * (m.colour_b - m.colour_a);
      break;
    }
    case SynthPattern::checker: {
      const double a = 2.0 * soft_square(u, 2.0 * m.period, soft) - 1.0;
      const double b = 2.0 * soft_square(v, 2.0 * m.period, soft) - 1.0;
      const double t = 0.5 + 0.5 * a * b;
      colour = m.colour_a + t * (m.colour_b - m.colour_a);
      break;
    }
    case SynthPattern::bricks: {
      const double bw = m.period, bh = m.period / 2.5, mortar = 0.012;
      const double row = std::floor(v / bh);
      const double us = u + (std::fmod(std::abs(row), 2.0) > 0.5 ? 0.5 * bw : 0.0);
      const double shade = cell_random(std::floor(us / bw), row, seed);
      colour = m.colour_a + (0.15 + 0.7 * shade) * (m.colour_b - m.colour_a);
      const double lines =
          std::max(soft_lines(us, bw, mortar, soft), soft_lines(v, bh, mortar, soft));
      colour += lines * (m.colour_c - colour);
      break;
    }
    case SynthPattern::planks: {
      // Planks run along u (object x on horizontal faces); staggered butt joints every six
      // plank widths.
      const double pw = m.period, pl = 6.0 * m.period;
      const double row = std::floor(v / pw);
      const double us = u + pl * cell_random(row, 7.0, seed);
      const double shade = cell_random(std::floor(us / pl), row, seed + 3);
      // Grain: soft stripes along the plank, warped by noise.
      const double grain_s = v + 0.25 * pw * fbm(Vector3d(u * 0.15, v, p.z()), pw, fw, seed + 5, 2);
      const double grain = soft_square(grain_s, 0.3 * pw, std::max(fw, 0.02 * pw));
      const double t = std::clamp(0.2 + 0.5 * shade + 0.3 * grain, 0.0, 1.0);
      colour = m.colour_a + t * (m.colour_b - m.colour_a);
      const double joints =
          std::max(soft_lines(v, pw, 0.004, soft), soft_lines(us, pl, 0.004, soft));
      colour += joints * (m.colour_c - colour);
      break;
    }
    case SynthPattern::tiles: {
      const double P = m.period;
      const double shade = cell_random(std::floor(u / P), std::floor(v / P), seed);
      colour = m.colour_a + (0.1 + 0.5 * shade) * (m.colour_b - m.colour_a);
      const double grout = std::max(soft_lines(u, P, 0.008, soft), soft_lines(v, P, 0.008, soft));
      colour += grout * (m.colour_c - colour);
      break;
    }
  }
  const double mottle = 1.0 + m.mottle_amount * fbm(p, m.mottle_scale, fw, seed + 101);
  return (colour * mottle).cwiseMax(0.0).cwiseMin(1.0);
}

// ---------------------------------------------------------------------------------------------
// Ray-primitive intersection in the primitive frame: o + t d for t in (kMinT, t_max). On a hit,
// t_max becomes the new t and `normal` the outward normal (unnormalised for spheres).

bool hit_box(const Vector3d& o, const Vector3d& d, const Vector3d& half, double* t_max,
             Vector3d* normal) {
  double t_near = -kInf, t_far = kInf;
  int axis = -1;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (std::abs(o[i]) > half[i]) return false;
      continue;
    }
    const double inv = 1.0 / d[i];
    double t0 = (-half[i] - o[i]) * inv, t1 = (half[i] - o[i]) * inv;
    if (t0 > t1) std::swap(t0, t1);
    if (t0 > t_near) {
      t_near = t0;
      axis = i;
    }
    t_far = std::min(t_far, t1);
  }
  if (axis < 0 || t_near > t_far || t_near <= kMinT || t_near >= *t_max) return false;
  *t_max = t_near;
  *normal = Vector3d::Zero();
  (*normal)[axis] = d[axis] > 0.0 ? -1.0 : 1.0;
  return true;
}

bool hit_sphere(const Vector3d& o, const Vector3d& d, double r, double* t_max, Vector3d* normal) {
  const double a = d.squaredNorm(), b = o.dot(d), c = o.squaredNorm() - r * r;
  const double disc = b * b - a * c;
  if (disc < 0.0) return false;
  const double t = (-b - std::sqrt(disc)) / a;
  if (t <= kMinT || t >= *t_max) return false;
  *t_max = t;
  *normal = o + t * d;
  return true;
}

bool hit_cylinder(const Vector3d& o, const Vector3d& d, double r, double h, double* t_max,
                  Vector3d* normal) {
  bool hit = false;
  const double a = d.x() * d.x() + d.y() * d.y();
  if (a > 0.0) {
    const double b = o.x() * d.x() + o.y() * d.y();
    const double c = o.x() * o.x() + o.y() * o.y() - r * r;
    const double disc = b * b - a * c;
    if (disc >= 0.0) {
      const double t = (-b - std::sqrt(disc)) / a;
      const double z = o.z() + t * d.z();
      if (t > kMinT && t < *t_max && std::abs(z) <= h) {
        *t_max = t;
        *normal = Vector3d(o.x() + t * d.x(), o.y() + t * d.y(), 0.0);
        hit = true;
      }
    }
  }
  if (d.z() != 0.0) {
    const double cap = d.z() > 0.0 ? -h : h;  // the cap facing the ray
    const double t = (cap - o.z()) / d.z();
    if (t > kMinT && t < *t_max) {
      const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
      if (x * x + y * y <= r * r) {
        *t_max = t;
        *normal = Vector3d(0.0, 0.0, cap > 0.0 ? 1.0 : -1.0);
        hit = true;
      }
    }
  }
  return hit;
}

bool hit_plane(const Vector3d& o, const Vector3d& d, double* t_max, Vector3d* normal) {
  if (!(d.z() < 0.0) || o.z() <= 0.0) return false;
  const double t = -o.z() / d.z();
  if (t <= kMinT || t >= *t_max) return false;
  *t_max = t;
  *normal = Vector3d::UnitZ();
  return true;
}

// Slab test: does the ray o + t d, with inv_d = 1 / d (infinities for zero components), enter
// the box before t_max?
bool enters_box(const Vector3d& o, const Vector3d& inv_d, const Eigen::AlignedBox3d& box,
                double t_max) {
  double t_near = 0.0, t_far = t_max;
  for (int i = 0; i < 3; ++i) {
    double t0 = (box.min()[i] - o[i]) * inv_d[i], t1 = (box.max()[i] - o[i]) * inv_d[i];
    if (t0 > t1) std::swap(t0, t1);
    // NaN (0 * inf: the origin on a slab plane of a parallel ray) keeps the interval unchanged.
    t_near = t0 > t_near ? t0 : t_near;
    t_far = t1 < t_far ? t1 : t_far;
    if (t_near > t_far) return false;
  }
  return true;
}

Eigen::AlignedBox3d transformed_box(const Eigen::AlignedBox3d& box, const Eigen::Isometry3d& T) {
  Eigen::AlignedBox3d out;
  for (int corner = 0; corner < 8; ++corner)
    out.extend(T * box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(corner)));
  return out;
}

// Per-frame precomputation: the camera centre and the camera-to-local rotation of every object
// and primitive, so that a pixel's ray d_camera = [x, y, 1] maps to each frame with one product.
struct FramePrimitive {
  SynthShape shape;
  Vector3d size;
  Vector3d origin;  // camera centre in the primitive frame
  Matrix3d R_p_c;   // camera-frame direction -> primitive frame
};

struct FrameObject {
  const SynthObject* object;
  Eigen::AlignedBox3d bounds_world;  // loose world box of the object, for culling
  Vector3d origin;                   // camera centre in the object frame
  Matrix3d R_o_c;
  std::vector<FramePrimitive> primitives;
};

struct Hit {
  double t = kInf;  // depth (m): rays have unit z in the camera frame
  int object = -1;
  int primitive = -1;
  Vector3d normal_primitive;
};

}  // namespace

SynthView render_view(const SyntheticRoom& room, const PinholeCamera& camera,
                      const Eigen::Isometry3d& T_world_camera) {
  const int W = camera.width, H = camera.height;
  SynthView view;
  view.colour.create(H, W, CV_8UC3);
  view.depth.create(H, W, CV_32FC1);
  view.instance_label.create(H, W, CV_16UC1);
  view.class_label.create(H, W, CV_16UC1);
  view.normal.create(H, W, CV_32FC3);

  std::vector<FrameObject> frame;
  frame.reserve(room.objects.size());
  for (const SynthObject& object : room.objects) {
    const Eigen::Isometry3d T_object_camera = object.T_world_object.inverse() * T_world_camera;
    FrameObject fo{&object, {}, T_object_camera.translation(), T_object_camera.linear(), {}};
    if (object.bounded) fo.bounds_world = transformed_box(object.bounds, object.T_world_object);
    for (const SynthPrimitive& prim : object.primitives) {
      const Eigen::Isometry3d T_primitive_camera =
          prim.T_object_primitive.inverse() * T_object_camera;
      fo.primitives.push_back(
          {prim.shape, prim.size, T_primitive_camera.translation(), T_primitive_camera.linear()});
    }
    frame.push_back(std::move(fo));
  }
  const Matrix3d R_world_camera = T_world_camera.linear();
  const Vector3d camera_centre = T_world_camera.translation();

  tbb::parallel_for(tbb::blocked_range<int>(0, H, 4), [&](const tbb::blocked_range<int>& rows) {
    for (int v = rows.begin(); v < rows.end(); ++v) {
      auto* colour = view.colour.ptr<cv::Vec3b>(v);
      auto* depth = view.depth.ptr<float>(v);
      auto* instance = view.instance_label.ptr<std::uint16_t>(v);
      auto* label = view.class_label.ptr<std::uint16_t>(v);
      auto* normal_out = view.normal.ptr<cv::Vec3f>(v);
      for (int u = 0; u < W; ++u) {
        const Vector3d ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
        const Vector3d inv_ray_world = (R_world_camera * ray).cwiseInverse();
        Hit hit;
        for (int k = 0; k < static_cast<int>(frame.size()); ++k) {
          const FrameObject& fo = frame[k];
          if (fo.object->bounded &&
              !enters_box(camera_centre, inv_ray_world, fo.bounds_world, hit.t))
            continue;
          for (int j = 0; j < static_cast<int>(fo.primitives.size()); ++j) {
            const FramePrimitive& fp = fo.primitives[j];
            const Vector3d d = fp.R_p_c * ray;
            Vector3d n;
            bool got = false;
            switch (fp.shape) {
              case SynthShape::box: got = hit_box(fp.origin, d, fp.size, &hit.t, &n); break;
              case SynthShape::sphere:
                got = hit_sphere(fp.origin, d, fp.size.x(), &hit.t, &n);
                break;
              case SynthShape::cylinder:
                got = hit_cylinder(fp.origin, d, fp.size.x(), fp.size.z(), &hit.t, &n);
                break;
              case SynthShape::plane: got = hit_plane(fp.origin, d, &hit.t, &n); break;
            }
            if (got) {
              hit.object = k;
              hit.primitive = j;
              hit.normal_primitive = n;
            }
          }
        }
        if (hit.object < 0) {  // cannot happen inside a closed room; kept well-defined anyway
          colour[u] = cv::Vec3b(0, 0, 0);
          depth[u] = 0.0f;
          instance[u] = 0;
          label[u] = 0;
          normal_out[u] = cv::Vec3f(0.0f, 0.0f, 0.0f);
          continue;
        }
        const FrameObject& fo = frame[hit.object];
        const SynthObject& object = *fo.object;
        const Matrix3d& R_object_primitive =
            object.primitives[hit.primitive].T_object_primitive.linear();
        Vector3d n_object = (R_object_primitive * hit.normal_primitive).normalized();
        const Vector3d d_object = fo.R_o_c * ray;
        if (n_object.dot(d_object) > 0.0) n_object = -n_object;
        const Vector3d p_object = fo.origin + hit.t * d_object;
        const Vector3d n_world = object.T_world_object.linear() * n_object;
        const Vector3d p_world = camera_centre + hit.t * (R_world_camera * ray);

        // Footprint of one pixel on the surface, for texture filtering.
        const double distance = hit.t * ray.norm();
        const double cos_view = std::abs(n_object.dot(d_object)) / d_object.norm();
        const double footprint = distance / (camera.fx * std::max(cos_view, 0.2));
        const Vector3d a = albedo(object.material, p_object, n_object, footprint);

        const Vector3d to_light = room.light_position - p_world;
        const double r2 = to_light.squaredNorm();
        const double lambert = std::max(0.0, n_world.dot(to_light) / std::sqrt(r2));
        const double shade = 0.38 + 0.85 * lambert / (1.0 + 0.06 * r2);
        const Vector3d rgb = (255.0 * shade * a).cwiseMin(255.0);
        colour[u] = cv::Vec3b(static_cast<std::uint8_t>(std::lround(rgb.x())),
                              static_cast<std::uint8_t>(std::lround(rgb.y())),
                              static_cast<std::uint8_t>(std::lround(rgb.z())));
        depth[u] = static_cast<float>(hit.t);
        instance[u] = object.instance_id;
        label[u] = static_cast<std::uint16_t>(object.class_id);
        const Vector3d n_camera = R_world_camera.transpose() * n_world;
        normal_out[u] =
            cv::Vec3f(static_cast<float>(n_camera.x()), static_cast<float>(n_camera.y()),
                      static_cast<float>(n_camera.z()));
      }
    }
  });
  return view;
}

}  // namespace fslam::core
