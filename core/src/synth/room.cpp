// The procedural room: a fixed list of furniture slots whose sizes, positions, colours and
// textures are drawn from the seed. Every slot is placed so that the camera zone stays clear
// and, from the zone, every object lies within the view sweep of make_trajectory.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "fslam/core/synth/synthetic_scene.hpp"
#include "synth_random.hpp"

namespace fslam::core {
namespace {

using Eigen::Isometry3d;
using Eigen::Vector3d;
using synth::Rng;

constexpr double kPi = 3.14159265358979323846;

Isometry3d pose(const Vector3d& t, double yaw = 0.0) {
  Isometry3d T = Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = t;
  return T;
}

SynthPrimitive box(const Vector3d& centre, const Vector3d& half_extents, double yaw = 0.0) {
  return {SynthShape::box, pose(centre, yaw), half_extents};
}

SynthPrimitive sphere(const Vector3d& centre, double radius) {
  return {SynthShape::sphere, pose(centre), Vector3d(radius, radius, radius)};
}

// Upright cylinder standing on z = bottom.
SynthPrimitive cylinder(const Vector3d& bottom_centre, double radius, double height) {
  return {SynthShape::cylinder, pose(bottom_centre + Vector3d(0.0, 0.0, 0.5 * height)),
          Vector3d(radius, radius, 0.5 * height)};
}

// h, s, v in [0, 1] (h wraps).
Vector3d hsv(double h, double s, double v) {
  h = h - std::floor(h);
  s = std::clamp(s, 0.0, 1.0);
  v = std::clamp(v, 0.0, 1.0);
  const double c = v * s;
  const double hp = h * 6.0;
  const double x = c * (1.0 - std::abs(std::fmod(hp, 2.0) - 1.0));
  Vector3d rgb;
  if (hp < 1.0) rgb = {c, x, 0.0};
  else if (hp < 2.0) rgb = {x, c, 0.0};
  else if (hp < 3.0) rgb = {0.0, c, x};
  else if (hp < 4.0) rgb = {0.0, x, c};
  else if (hp < 5.0) rgb = {x, 0.0, c};
  else rgb = {c, 0.0, x};
  return rgb + Vector3d::Constant(v - c);
}

SynthMaterial material(Rng& rng, SynthPattern pattern, const Vector3d& a, const Vector3d& b,
                       double period, double mottle_scale = 0.12, double mottle_amount = 0.2) {
  SynthMaterial m;
  m.pattern = pattern;
  m.colour_a = a;
  m.colour_b = b;
  m.period = period;
  m.mottle_scale = mottle_scale;
  m.mottle_amount = mottle_amount;
  m.texture_seed = static_cast<std::uint32_t>(rng.next() >> 32);
  return m;
}

// A light colour and a clearly darker one of a nearby hue: enough contrast for tracking.
std::pair<Vector3d, Vector3d> two_tone(Rng& rng, double hue, double saturation, double value) {
  const double h = hue + rng.uniform(-0.03, 0.03);
  const double s = saturation + rng.uniform(-0.08, 0.08);
  const double v = value + rng.uniform(-0.06, 0.06);
  return {hsv(h, s, v), hsv(h + rng.uniform(-0.06, 0.06), s + 0.1, v * rng.uniform(0.55, 0.7))};
}

SynthMaterial wood(Rng& rng, double period) {
  auto [a, b] = two_tone(rng, rng.uniform(0.06, 0.1), 0.55, 0.72);
  SynthMaterial m = material(rng, SynthPattern::planks, a, b, period, 0.1, 0.15);
  m.colour_c = 0.45 * b;
  return m;
}

SynthMaterial painted(Rng& rng, SynthPattern pattern, double period) {
  auto [a, b] = two_tone(rng, rng.uniform(), rng.uniform(0.3, 0.6), 0.8);
  SynthMaterial m = material(rng, pattern, a, b, period, 0.1, 0.2);
  m.colour_c = 0.5 * b;
  return m;
}

// Finishes the room and the ring share; each draws from `rng` in one fixed order.
SynthMaterial cabinet_material(Rng& rng) {
  return rng.uniform() < 0.5 ? wood(rng, 0.11) : painted(rng, SynthPattern::stripes, 0.12);
}
SynthMaterial leaves_material(Rng& rng) {
  return material(rng, SynthPattern::noise, hsv(rng.uniform(0.25, 0.35), 0.6, 0.6),
                  hsv(rng.uniform(0.22, 0.3), 0.7, 0.3), 0.05, 0.2, 0.15);
}
SynthMaterial cardboard_material(Rng& rng) {
  auto [a, b] = two_tone(rng, rng.uniform(0.08, 0.11), 0.45, 0.7);
  SynthMaterial m = material(rng, SynthPattern::stripes, a, b, 0.1, 0.05, 0.2);
  m.axis = Vector3d(0.0, 1.0, 0.4).normalized();
  return m;
}
SynthMaterial picture_material(Rng& rng) {
  auto [a, b] = two_tone(rng, rng.uniform(), 0.6, 0.85);
  return material(rng, SynthPattern::noise, a, hsv(rng.uniform(), 0.7, 0.45), 0.08, 0.03, 0.2);
}

void compute_bounds(SynthObject* object) {
  object->bounds.setEmpty();
  object->bounded = true;
  for (const SynthPrimitive& p : object->primitives) {
    Vector3d half = p.size;
    switch (p.shape) {
      case SynthShape::box: half = p.size; break;
      case SynthShape::sphere: half = Vector3d::Constant(p.size.x()); break;
      case SynthShape::cylinder: half = {p.size.x(), p.size.x(), p.size.z()}; break;
      case SynthShape::plane:
        object->bounded = false;
        object->bounds.setEmpty();
        return;
    }
    for (int corner = 0; corner < 8; ++corner) {
      const Vector3d c((corner & 1) ? half.x() : -half.x(), (corner & 2) ? half.y() : -half.y(),
                       (corner & 4) ? half.z() : -half.z());
      object->bounds.extend(p.T_object_primitive * c);
    }
  }
}

class RoomBuilder {
 public:
  explicit RoomBuilder(SyntheticRoom* room) : room_(room) {}

  SynthObject& add(SynthClass class_id, std::string name, const Isometry3d& T_world_object,
                   std::vector<SynthPrimitive> primitives, const SynthMaterial& m) {
    SynthObject o;
    o.instance_id = static_cast<std::uint16_t>(room_->objects.size() + 1);
    o.class_id = class_id;
    o.name = std::move(name);
    o.T_world_object = T_world_object;
    o.primitives = std::move(primitives);
    o.material = m;
    compute_bounds(&o);
    room_->objects.push_back(std::move(o));
    return room_->objects.back();
  }

  // A room face: the plane through `origin` facing the interior along `normal`, with the
  // texture's x axis horizontal (or along world x for floor and ceiling).
  void add_face(SynthClass class_id, std::string name, const Vector3d& origin,
                const Vector3d& normal, const SynthMaterial& m) {
    const Vector3d x = std::abs(normal.z()) > 0.5 ? Vector3d::UnitX()
                                                  : Vector3d::UnitZ().cross(normal).normalized();
    Isometry3d T = Isometry3d::Identity();
    T.linear().col(0) = x;
    T.linear().col(1) = normal.cross(x);
    T.linear().col(2) = normal;
    T.translation() = origin;
    add(class_id, std::move(name), T,
        {SynthPrimitive{SynthShape::plane, Isometry3d::Identity(), Vector3d::Zero()}}, m);
  }

 private:
  SyntheticRoom* room_;
};

SynthMaterial wall_material(Rng& rng, int style) {
  switch (style) {
    case 0: {  // brick
      auto [a, b] = two_tone(rng, rng.uniform(0.0, 0.07), 0.5, 0.68);
      SynthMaterial m =
          material(rng, SynthPattern::bricks, a, b, rng.uniform(0.28, 0.34), 0.2, 0.15);
      m.colour_c = hsv(0.1, 0.08, 0.82);
      return m;
    }
    case 1: {  // striped wallpaper
      auto [a, b] = two_tone(rng, rng.uniform(), rng.uniform(0.2, 0.35), 0.85);
      SynthMaterial m =
          material(rng, SynthPattern::stripes, a, b, rng.uniform(0.14, 0.22), 0.18, 0.22);
      m.axis = Vector3d::UnitX();  // stripes run vertically: they vary along the wall
      return m;
    }
    case 2: {  // checked wallpaper
      auto [a, b] = two_tone(rng, rng.uniform(), rng.uniform(0.2, 0.35), 0.85);
      return material(rng, SynthPattern::checker, a, b, rng.uniform(0.2, 0.28), 0.15, 0.2);
    }
    default: {  // sponged plaster
      auto [a, b] = two_tone(rng, rng.uniform(), rng.uniform(0.25, 0.4), 0.85);
      return material(rng, SynthPattern::noise, a, b, rng.uniform(0.18, 0.26), 0.06, 0.25);
    }
  }
}

}  // namespace

const char* to_string(SynthNoise noise) {
  switch (noise) {
    case SynthNoise::none: return "none";
    case SynthNoise::kinect: return "kinect";
  }
  return "unknown";
}

bool parse_synth_noise(const std::string& text, SynthNoise* noise, std::string* why) {
  if (text == "none") *noise = SynthNoise::none;
  else if (text == "kinect") *noise = SynthNoise::kinect;
  else {
    if (why) *why = "unknown noise model '" + text + "' (expected kinect or none)";
    return false;
  }
  return true;
}

const char* synth_class_name(SynthClass c) {
  switch (c) {
    case SynthClass::unlabelled: return "unlabelled";
    case SynthClass::wall: return "wall";
    case SynthClass::floor: return "floor";
    case SynthClass::ceiling: return "ceiling";
    case SynthClass::table: return "table";
    case SynthClass::chair: return "chair";
    case SynthClass::cabinet: return "cabinet";
    case SynthClass::shelf: return "shelf";
    case SynthClass::sofa: return "sofa";
    case SynthClass::lamp: return "lamp";
    case SynthClass::plant: return "plant";
    case SynthClass::box: return "box";
    case SynthClass::ball: return "ball";
    case SynthClass::cup: return "cup";
    case SynthClass::book: return "book";
    case SynthClass::vase: return "vase";
    case SynthClass::picture: return "picture";
    case SynthClass::rug: return "rug";
  }
  return "unknown";
}

bool is_structural(SynthClass c) {
  return c == SynthClass::wall || c == SynthClass::floor || c == SynthClass::ceiling;
}

PinholeCamera synth_default_camera() { return {525.0, 525.0, 319.5, 239.5, 640, 480}; }

namespace {

// Structure: four walls, floor, ceiling, each its own instance and material.
void add_structure(Rng& rng, double W, double D, double H, RoomBuilder& builder) {
  int wall_style = rng.below(4);
  const char* wall_names[4] = {"wall_south", "wall_north", "wall_west", "wall_east"};
  const Vector3d wall_origins[4] = {{0, 0, 0}, {0, D, 0}, {0, 0, 0}, {W, 0, 0}};
  const Vector3d wall_normals[4] = {Vector3d::UnitY(), -Vector3d::UnitY(), Vector3d::UnitX(),
                                    -Vector3d::UnitX()};
  for (int i = 0; i < 4; ++i) {
    builder.add_face(SynthClass::wall, wall_names[i], wall_origins[i], wall_normals[i],
                     wall_material(rng, wall_style));
    wall_style = (wall_style + 1 + rng.below(3)) % 4;  // neighbours differ
  }
  {
    SynthMaterial floor;
    if (rng.uniform() < 0.6) {
      floor = wood(rng, rng.uniform(0.14, 0.2));
    } else {
      auto [a, b] = two_tone(rng, rng.uniform(), rng.uniform(0.05, 0.25), 0.78);
      floor = material(rng, SynthPattern::tiles, a, b, rng.uniform(0.35, 0.5), 0.1, 0.18);
      floor.colour_c = 0.4 * b;
    }
    builder.add_face(SynthClass::floor, "floor", {0, 0, 0}, Vector3d::UnitZ(), floor);
    auto [a, b] = two_tone(rng, rng.uniform(), 0.06, 0.88);
    SynthMaterial ceiling = material(rng, SynthPattern::tiles, a, b, 0.6, 0.05, 0.25);
    ceiling.colour_c = 0.6 * b;
    builder.add_face(SynthClass::ceiling, "ceiling", {0, 0, H}, -Vector3d::UnitZ(), ceiling);
  }
}

// Where the table stands: the chairs and the things on it are placed relative to it.
struct TablePlacement {
  double x, y, l, w, h;
  Isometry3d T_world_table;
};

// Table in the middle of the far half, with a rug under it.
TablePlacement add_table(Rng& rng, double W, double D, RoomBuilder& builder) {
  const double table_x = 0.5 * W + rng.uniform(-0.2, 0.2);
  const double table_y = D * rng.uniform(0.56, 0.6);
  const double table_yaw = rng.uniform(-0.12, 0.12);
  const double table_l = rng.uniform(1.2, 1.45);
  const double table_w = rng.uniform(0.7, 0.85);
  const double table_h = rng.uniform(0.72, 0.78);
  const Isometry3d T_world_table = pose({table_x, table_y, 0.0}, table_yaw);
  {
    std::vector<SynthPrimitive> parts = {
        box({0, 0, table_h - 0.02}, {0.5 * table_l, 0.5 * table_w, 0.02})};
    for (int i = 0; i < 4; ++i) {
      const double x = (i & 1 ? 1.0 : -1.0) * (0.5 * table_l - 0.08);
      const double y = (i & 2 ? 1.0 : -1.0) * (0.5 * table_w - 0.08);
      parts.push_back(cylinder({x, y, 0.0}, 0.03, table_h - 0.04));
    }
    builder.add(SynthClass::table, "table", T_world_table, parts, wood(rng, 0.12));
  }
  {
    SynthMaterial rug =
        painted(rng, rng.uniform() < 0.5 ? SynthPattern::checker : SynthPattern::stripes,
                rng.uniform(0.16, 0.24));
    rug.axis = Vector3d::UnitX();
    builder.add(SynthClass::rug, "rug", T_world_table,
                {box({0, 0, 0.005}, {0.5 * table_l + 0.65, 0.5 * table_w + 0.5, 0.005})}, rug);
  }
  return {table_x, table_y, table_l, table_w, table_h, T_world_table};
}

// Two chairs behind the table, facing the camera; backrest on the chair's local +y.
void add_chairs(Rng& rng, const TablePlacement& table, RoomBuilder& builder) {
  const double table_l = table.l, table_w = table.w;
  const Isometry3d& T_world_table = table.T_world_table;
  for (int i = 0; i < 2; ++i) {
    const double seat_h = rng.uniform(0.44, 0.48);
    const double back_h = rng.uniform(0.4, 0.5);
    std::vector<SynthPrimitive> parts = {
        box({0, 0, seat_h - 0.025}, {0.22, 0.22, 0.025}),
        box({0, 0.2, seat_h + 0.5 * back_h}, {0.22, 0.02, 0.5 * back_h})};
    for (int k = 0; k < 4; ++k)
      parts.push_back(box({(k & 1 ? 0.19 : -0.19), (k & 2 ? 0.19 : -0.19), 0.5 * (seat_h - 0.05)},
                          {0.02, 0.02, 0.5 * (seat_h - 0.05)}));
    const Vector3d seat_in_table((i == 0 ? -0.25 : 0.25) * table_l + rng.uniform(-0.08, 0.08),
                                 0.5 * table_w + rng.uniform(0.12, 0.22), 0.0);
    const Isometry3d T = T_world_table * pose(seat_in_table, rng.uniform(-0.3, 0.3));
    builder.add(SynthClass::chair, "chair_" + std::to_string(i + 1), T, parts,
                rng.uniform() < 0.5 ? wood(rng, 0.08)
                                    : painted(rng, SynthPattern::noise, rng.uniform(0.05, 0.08)));
  }
}

// Table top: four slots in shuffled order for cup, vase, book and ball.
void add_table_top(Rng& rng, const TablePlacement& table, RoomBuilder& builder) {
  const double table_l = table.l, table_w = table.w, table_h = table.h;
  const Isometry3d& T_world_table = table.T_world_table;
  Vector3d slots[4];
  for (int i = 0; i < 4; ++i)
    slots[i] = {(i & 1 ? 0.27 : -0.27) * table_l + rng.uniform(-0.06, 0.06),
                (i & 2 ? 0.22 : -0.22) * table_w + rng.uniform(-0.04, 0.04), table_h};
  for (int i = 3; i > 0; --i) std::swap(slots[i], slots[rng.below(i + 1)]);
  auto on_table = [&](int slot, double yaw) { return T_world_table * pose(slots[slot], yaw); };

  const double cup_r = rng.uniform(0.04, 0.05);
  const double cup_h = rng.uniform(0.09, 0.12);
  SynthMaterial cup = painted(rng, SynthPattern::stripes, rng.uniform(0.025, 0.035));
  builder.add(SynthClass::cup, "cup", on_table(0, rng.uniform(0.0, 2.0 * kPi)),
              {cylinder({0, 0, 0}, cup_r, cup_h),
               box({cup_r + 0.012, 0, 0.55 * cup_h}, {0.014, 0.007, 0.3 * cup_h})},
              cup);
  const double vase_r = rng.uniform(0.07, 0.09);
  SynthMaterial vase = painted(rng, SynthPattern::stripes, rng.uniform(0.035, 0.05));
  vase.axis = Vector3d(1.0, 0.0, 1.5).normalized();
  builder.add(SynthClass::vase, "vase", on_table(1, 0.0),
              {sphere({0, 0, vase_r}, vase_r),
               cylinder({0, 0, 1.6 * vase_r}, 0.4 * vase_r, rng.uniform(0.12, 0.18))},
              vase);
  const Vector3d book_half(rng.uniform(0.08, 0.11), rng.uniform(0.11, 0.15),
                           rng.uniform(0.015, 0.025));
  SynthMaterial book = painted(rng, SynthPattern::checker, rng.uniform(0.04, 0.06));
  builder.add(SynthClass::book, "book_1", on_table(2, rng.uniform(-0.6, 0.6)),
              {box({0, 0, book_half.z()}, book_half),
               box({0.01, 0.005, 2.0 * book_half.z() + 0.7 * book_half.z()},
                   {0.9 * book_half.x(), 0.9 * book_half.y(), 0.7 * book_half.z()}, 0.25)},
              book);
  const double ball_r = rng.uniform(0.07, 0.09);
  builder.add(SynthClass::ball, "ball_1", on_table(3, 0.0), {sphere({0, 0, ball_r}, ball_r)},
              painted(rng, SynthPattern::checker, rng.uniform(0.05, 0.07)));
}

// Along the far wall (y = D): a cabinet on the west side, a shelf on the east side.
void add_far_wall(Rng& rng, double W, double D, RoomBuilder& builder) {
  {
    const double w = rng.uniform(0.8, 1.0);
    const double h = rng.uniform(0.8, 1.0);
    const double d = 0.45;
    std::vector<SynthPrimitive> parts = {box({0, 0, 0.5 * h}, {0.5 * w, 0.5 * d, 0.5 * h})};
    for (int k = 0; k < 2; ++k) {
      const double zc = (k == 0 ? 0.3 : 0.72) * h;
      parts.push_back(box({0, -0.5 * d - 0.01, zc}, {0.5 * w - 0.04, 0.01, 0.17 * h}));
      parts.push_back(box({0, -0.5 * d - 0.03, zc + 0.08 * h}, {0.09, 0.012, 0.012}));
    }
    builder.add(
        SynthClass::cabinet, "cabinet",
        pose({0.8 + 0.5 * w + rng.uniform(0.0, 0.15), D - 0.5 * d, 0.0}, rng.uniform(-0.03, 0.03)),
        parts, cabinet_material(rng));
  }
  {
    const double w = rng.uniform(0.85, 1.0);
    const double h = rng.uniform(1.7, 1.9);
    const double d = 0.34;
    std::vector<SynthPrimitive> parts;
    for (int side = -1; side <= 1; side += 2)
      parts.push_back(box({side * (0.5 * w - 0.015), 0, 0.5 * h}, {0.015, 0.5 * d, 0.5 * h}));
    parts.push_back(box({0, 0.5 * d - 0.01, 0.5 * h}, {0.5 * w, 0.01, 0.5 * h}));
    const int boards = 5;
    std::vector<double> board_z;
    for (int k = 0; k < boards; ++k) {
      const double z = 0.04 + (h - 0.06) * k / (boards - 1);
      board_z.push_back(z);
      parts.push_back(box({0, 0, z}, {0.5 * w - 0.03, 0.5 * d - 0.02, 0.015}));
    }
    const Isometry3d T_world_shelf =
        pose({W - 0.55 - 0.5 * w, D - 0.5 * d, 0.0}, rng.uniform(-0.03, 0.03));
    builder.add(SynthClass::shelf, "shelf", T_world_shelf, parts, wood(rng, 0.1));

    // A row of books standing on the second board.
    std::vector<SynthPrimitive> books;
    double x = -0.5 * w + 0.05;
    const double row_end = rng.uniform(0.15, 0.35) * w;
    while (x < row_end) {
      const double t = rng.uniform(0.025, 0.05);
      const double bh = rng.uniform(0.17, 0.26);
      const double bd = rng.uniform(0.14, 0.2);
      books.push_back(box({x + 0.5 * t, -0.5 * d + 0.5 * bd + 0.03, board_z[1] + 0.015 + 0.5 * bh},
                          {0.5 * t, 0.5 * bd, 0.5 * bh}));
      x += t + 0.003;
    }
    SynthMaterial book = painted(rng, SynthPattern::stripes, 0.09);
    book.axis = Vector3d::UnitX();
    builder.add(SynthClass::book, "book_2", T_world_shelf, books, book);
  }
}

// Corners: a plant (north-west) and a floor lamp (north-east).
void add_corners(Rng& rng, double W, double D, RoomBuilder& builder) {
  {
    const double pot_r = rng.uniform(0.15, 0.19);
    const double pot_h = rng.uniform(0.35, 0.45);
    std::vector<SynthPrimitive> parts = {cylinder({0, 0, 0}, pot_r, pot_h)};
    for (int k = 0; k < 3; ++k) {
      const double a = 2.0 * kPi * k / 3.0 + rng.uniform(-0.4, 0.4);
      parts.push_back(
          sphere({0.12 * std::cos(a), 0.12 * std::sin(a), pot_h + rng.uniform(0.2, 0.45)},
                 rng.uniform(0.17, 0.24)));
    }
    builder.add(SynthClass::plant, "plant", pose({0.42, D - 0.42, 0.0}), parts, leaves_material(rng));
  }
  {
    const double height = rng.uniform(1.45, 1.6);
    const double shade_r = rng.uniform(0.17, 0.21);
    std::vector<SynthPrimitive> parts = {cylinder({0, 0, 0}, 0.15, 0.03),
                                         cylinder({0, 0, 0.03}, 0.016, height - 0.1),
                                         cylinder({0, 0, height - 0.2}, shade_r, 0.26)};
    SynthMaterial lamp = painted(rng, SynthPattern::stripes, rng.uniform(0.05, 0.07));
    builder.add(SynthClass::lamp, "lamp", pose({W - 0.3, D - 0.3, 0.0}), parts, lamp);
  }
}

// West wall: sofa; east wall: a storage box.
void add_side_walls(Rng& rng, double W, double D, RoomBuilder& builder) {
  {
    const double length = rng.uniform(1.6, 1.9);
    const double y_end = D - rng.uniform(0.75, 0.9);
    std::vector<SynthPrimitive> parts = {
        box({0, 0, 0.2}, {0.5 * length, 0.42, 0.2}),
        box({0, 0.31, 0.62}, {0.5 * length - 0.18, 0.11, 0.22}),
    };
    for (int side = -1; side <= 1; side += 2) {
      parts.push_back(box({side * (0.5 * length - 0.09), 0, 0.3}, {0.09, 0.42, 0.3}));
      parts.push_back(
          box({side * (0.25 * length - 0.05), -0.1, 0.46}, {0.25 * length - 0.1, 0.3, 0.06}));
    }
    // Local +y (the backrest) faces the west wall.
    builder.add(SynthClass::sofa, "sofa", pose({0.47, y_end - 0.5 * length, 0.0}, 0.5 * kPi), parts,
                painted(rng, SynthPattern::checker, rng.uniform(0.09, 0.12)));
  }
  {
    // A storage box with a ball on top.
    const Vector3d half(rng.uniform(0.2, 0.26), rng.uniform(0.2, 0.26), rng.uniform(0.18, 0.25));
    const SynthMaterial cardboard = cardboard_material(rng);
    const Isometry3d T_world_box =
        pose({W - 0.1 - half.x(), D - rng.uniform(1.0, 1.2), 0.0}, rng.uniform(-0.2, 0.2));
    builder.add(SynthClass::box, "box_1", T_world_box, {box({0, 0, half.z()}, half)}, cardboard);
    const double r = rng.uniform(0.1, 0.13);
    builder.add(
        SynthClass::ball, "ball_2",
        T_world_box * pose({rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), 2.0 * half.z()}),
        {sphere({0, 0, r}, r)}, painted(rng, SynthPattern::stripes, 0.07));
  }
}

// Pictures: thin boards on the walls, their face on local -y.
void add_pictures(Rng& rng, double W, double D, RoomBuilder& builder) {
  auto picture = [&](const std::string& name, const Vector3d& at, double yaw) {
    const double w = rng.uniform(0.45, 0.7);
    const double h = rng.uniform(0.35, 0.5);
    const SynthMaterial paint = picture_material(rng);
    builder.add(SynthClass::picture, name, pose(at, yaw),
                {box({0, -0.012, 0}, {0.5 * w, 0.012, 0.5 * h})}, paint);
  };
  picture("picture_1", {rng.uniform(1.1, 1.5), D, rng.uniform(1.45, 1.6)}, 0.0);
  picture("picture_2", {0.0, D - rng.uniform(0.65, 0.8), rng.uniform(1.3, 1.45)}, 0.5 * kPi);
  picture("picture_3", {W, D - rng.uniform(0.65, 0.8), rng.uniform(1.3, 1.45)}, -0.5 * kPi);
}

// The far half of a W x D room (y > D / 2): table, chairs, the things on the table, cabinet,
// shelf, plant, lamp, sofa and box; the table's placement.
TablePlacement furnish_far_half(Rng& rng, double W, double D, RoomBuilder& builder) {
  const TablePlacement table = add_table(rng, W, D, builder);
  add_chairs(rng, table, builder);
  add_table_top(rng, table, builder);
  add_far_wall(rng, W, D, builder);
  add_corners(rng, W, D, builder);
  add_side_walls(rng, W, D, builder);
  return table;
}

// The yaw that turns an object's local +y (its back) against a wall whose normal into the room is n.
double facing(const Vector3d& n) { return std::atan2(n.x(), -n.y()); }

// One piece of furniture against a wall, its back to the wall: `at` is the point on the wall
// (floor level) and `n` the wall's normal into the corridor. `kind` picks a cabinet, a shelf, a
// plant or a storage box; each reaches at most 0.55 m out from the wall.
void add_wall_piece(Rng& rng, int kind, const std::string& name, const Vector3d& at, const Vector3d& n,
                    RoomBuilder& builder) {
  const auto place = [&](double depth) { return pose(at + depth * n, facing(n) + rng.uniform(-0.03, 0.03)); };
  switch (kind) {
    case 0: {  // cabinet with two drawers
      const double w = rng.uniform(0.7, 1.0), h = rng.uniform(0.8, 1.15), d = 0.42;
      std::vector<SynthPrimitive> parts = {box({0, 0, 0.5 * h}, {0.5 * w, 0.5 * d, 0.5 * h})};
      for (int k = 0; k < 2; ++k)
        parts.push_back(box({0, -0.5 * d - 0.01, (k == 0 ? 0.3 : 0.72) * h}, {0.5 * w - 0.04, 0.01, 0.17 * h}));
      builder.add(SynthClass::cabinet, "cabinet_" + name, place(0.5 * d), parts,
                  cabinet_material(rng));
      break;
    }
    case 1: {  // open shelf
      const double w = rng.uniform(0.8, 1.0), h = rng.uniform(1.5, 1.9), d = 0.34;
      std::vector<SynthPrimitive> parts;
      for (int side = -1; side <= 1; side += 2)
        parts.push_back(box({side * (0.5 * w - 0.015), 0, 0.5 * h}, {0.015, 0.5 * d, 0.5 * h}));
      parts.push_back(box({0, 0.5 * d - 0.01, 0.5 * h}, {0.5 * w, 0.01, 0.5 * h}));
      for (int k = 0; k < 4; ++k)
        parts.push_back(box({0, 0, 0.04 + (h - 0.06) * k / 3.0}, {0.5 * w - 0.03, 0.5 * d - 0.02, 0.015}));
      builder.add(SynthClass::shelf, "shelf_" + name, place(0.5 * d), parts, wood(rng, 0.1));
      break;
    }
    case 2: {  // potted plant
      const double pot_r = rng.uniform(0.15, 0.19), pot_h = rng.uniform(0.35, 0.45);
      std::vector<SynthPrimitive> parts = {cylinder({0, 0, 0}, pot_r, pot_h)};
      for (int k = 0; k < 3; ++k) {
        const double a = 2.0 * kPi * k / 3.0 + rng.uniform(-0.4, 0.4);
        parts.push_back(sphere({0.1 * std::cos(a), 0.1 * std::sin(a), pot_h + rng.uniform(0.2, 0.45)},
                               rng.uniform(0.15, 0.2)));
      }
      builder.add(SynthClass::plant, "plant_" + name, place(0.28), parts, leaves_material(rng));
      break;
    }
    default: {  // storage box
      const Vector3d half(rng.uniform(0.2, 0.26), rng.uniform(0.2, 0.26), rng.uniform(0.18, 0.3));
      builder.add(SynthClass::box, "box_" + name, place(half.y() + 0.02), {box({0, 0, half.z()}, half)},
                  cardboard_material(rng));
      break;
    }
  }
}

// A picture on a wall: a thin board at eye height, `at` on the wall, `n` into the corridor.
void add_wall_picture(Rng& rng, const std::string& name, const Vector3d& at, const Vector3d& n,
                      RoomBuilder& builder) {
  const double w = rng.uniform(0.45, 0.7), h = rng.uniform(0.35, 0.5);
  const SynthMaterial paint = picture_material(rng);
  builder.add(SynthClass::picture, "picture_" + name, pose(at + Vector3d(0, 0, rng.uniform(1.35, 1.6)), facing(n)),
              {box({0, -0.012, 0}, {0.5 * w, 0.012, 0.5 * h})}, paint);
}

}  // namespace

SyntheticRoom make_room(std::uint64_t seed) {
  Rng rng(synth::stream_seed(seed, synth::Stream::room));
  SyntheticRoom room;
  const double W = rng.uniform(4.2, 4.7);  // x extent
  const double D = rng.uniform(3.9, 4.3);  // y extent: the camera looks along +y
  const double H = rng.uniform(2.5, 2.8);
  room.size = {W, D, H};
  room.camera_zone = Eigen::AlignedBox3d(Vector3d(0.5 * W - 0.45, 0.85, 1.35),
                                         Vector3d(0.5 * W + 0.45, 1.35, 1.6));
  RoomBuilder builder(&room);
  add_structure(rng, W, D, H, builder);
  const TablePlacement table = furnish_far_half(rng, W, D, builder);
  add_pictures(rng, W, D, builder);
  room.light_position = {table.x, 0.5 * (table.y + 1.1), H - 0.25};
  room.look_at = {table.x, table.y + 0.4, 0.9};
  return room;
}

SyntheticRoom make_hall(std::uint64_t seed) {
  constexpr int kBays = 3;  // per side
  Rng rng(synth::stream_seed(seed, synth::Stream::room));
  SyntheticRoom hall;
  hall.scene = SynthScene::hall;
  const double bay_w = rng.uniform(4.2, 4.6);  // x extent of a bay
  const double bay_d = rng.uniform(3.9, 4.2);  // y extent: half the hall's depth
  const double H = rng.uniform(2.6, 2.8);
  const double W = kBays * bay_w, D = 2.0 * bay_d;
  hall.size = {W, D, H};
  RoomBuilder builder(&hall);
  add_structure(rng, W, D, H, builder);
  for (int side = 0; side < 2; ++side) {
    for (int b = 0; b < kBays; ++b) {
      // A bay is furnished as a room's far half, in a room of its own frame, then placed.
      SyntheticRoom bay;
      RoomBuilder bay_builder(&bay);
      furnish_far_half(rng, bay_w, bay_d, bay_builder);
      Isometry3d T_hall_bay = pose({b * bay_w, D - bay_d, 0.0});
      if (side == 1) T_hall_bay = pose({W, D, 0.0}, kPi) * T_hall_bay;  // (x, y) -> (W - x, D - y)
      const std::string suffix = std::string(side == 0 ? "_n" : "_s") + std::to_string(b + 1);
      for (SynthObject& o : bay.objects) {
        builder.add(o.class_id, o.name + suffix, T_hall_bay * o.T_world_object, std::move(o.primitives), o.material);
      }
    }
  }
  // The corridor between the two rows of tables (their rugs reach about 1.7 m into each half).
  hall.camera_zone = Eigen::AlignedBox3d(Vector3d(2.0, 0.5 * D - 0.4, 1.35), Vector3d(W - 2.0, 0.5 * D + 0.4, 1.6));
  hall.light_position = {0.5 * W, 0.5 * D, H - 0.25};
  hall.look_at = {0.5 * W, D - 0.42 * bay_d, 0.9};  // the north tables' row, for the wander path
  return hall;
}

SyntheticRoom make_ring(std::uint64_t seed) {
  Rng rng(synth::stream_seed(seed, synth::Stream::room));
  SyntheticRoom ring;
  ring.scene = SynthScene::ring;
  const double W = rng.uniform(13.5, 15.0), D = rng.uniform(8.5, 9.5), H = rng.uniform(2.6, 2.8);
  const double c = rng.uniform(2.3, 2.6);  // the corridor's width
  ring.size = {W, D, H};
  RoomBuilder builder(&ring);
  add_structure(rng, W, D, H, builder);
  builder.add(SynthClass::wall, "wall_block", pose({0.5 * W, 0.5 * D, 0.0}),
              {box({0, 0, 0.5 * H}, {0.5 * W - c, 0.5 * D - c, 0.5 * H})}, wall_material(rng, rng.below(4)));
  // The corridor's walls, counter-clockwise as the camera goes: outer south, east, north, west,
  // then the block's faces; each from `a` to `b` with its normal into the corridor and a fixed
  // number of pieces (so the instance list is the same for every seed).
  struct WallRun {
    const char* name;
    Vector3d a, b, n;
    int pieces, pictures;
  };
  const double m = 1.0;  // metres kept free at the outer corners
  const WallRun runs[8] = {
      {"s", {m, 0, 0}, {W - m, 0, 0}, Vector3d::UnitY(), 5, 2},
      {"e", {W, m, 0}, {W, D - m, 0}, -Vector3d::UnitX(), 3, 1},
      {"n", {W - m, D, 0}, {m, D, 0}, -Vector3d::UnitY(), 5, 2},
      {"w", {0, D - m, 0}, {0, m, 0}, Vector3d::UnitX(), 3, 1},
      {"bs", {c + 0.3, c, 0}, {W - c - 0.3, c, 0}, -Vector3d::UnitY(), 4, 1},
      {"be", {W - c, c + 0.3, 0}, {W - c, D - c - 0.3, 0}, Vector3d::UnitX(), 2, 1},
      {"bn", {W - c - 0.3, D - c, 0}, {c + 0.3, D - c, 0}, Vector3d::UnitY(), 4, 1},
      {"bw", {c, D - c - 0.3, 0}, {c, c + 0.3, 0}, -Vector3d::UnitX(), 2, 1},
  };
  int kind = 0;
  for (const WallRun& run : runs) {
    const Vector3d along = run.b - run.a;
    for (int k = 0; k < run.pieces; ++k) {
      const double u = (k + 0.5 + rng.uniform(-0.15, 0.15)) / run.pieces;
      add_wall_piece(rng, kind++ % 4, std::string(run.name) + "_" + std::to_string(k + 1), run.a + u * along, run.n,
                     builder);
    }
    for (int k = 0; k < run.pictures; ++k) {
      // In a gap between two pieces (the pieces stand at (k + 1/2) / pieces of the run).
      const double u = std::floor((k + 0.5) * run.pieces / run.pictures) / run.pieces;
      add_wall_picture(rng, std::string(run.name) + "_" + std::to_string(k + 1), run.a + u * along, run.n, builder);
    }
  }
  // The camera zone: the box the ring path's centre line spans (the block inside it is not free).
  ring.camera_zone = Eigen::AlignedBox3d(Vector3d(0.5 * c, 0.5 * c, 1.35), Vector3d(W - 0.5 * c, D - 0.5 * c, 1.6));
  ring.light_position = {0.5 * W, 0.5 * D, H - 0.25};  // above the block: its faces get ambient light only
  ring.look_at = {0.5 * W, 0.5 * D, 0.9};
  return ring;
}

SyntheticRoom make_scene(SynthScene scene, std::uint64_t seed) {
  switch (scene) {
    case SynthScene::hall: return make_hall(seed);
    case SynthScene::ring: return make_ring(seed);
    case SynthScene::room: break;
  }
  return make_room(seed);
}

const char* to_string(SynthScene scene) {
  switch (scene) {
    case SynthScene::hall: return "hall";
    case SynthScene::ring: return "ring";
    case SynthScene::room: break;
  }
  return "room";
}

bool parse_synth_scene(const std::string& text, SynthScene* scene, std::string* why) {
  if (text == "room") return *scene = SynthScene::room, true;
  if (text == "hall") return *scene = SynthScene::hall, true;
  if (text == "ring") return *scene = SynthScene::ring, true;
  if (why) *why = "unknown synthetic scene '" + text + "' (room, hall or ring)";
  return false;
}

double synth_clearance(const SyntheticRoom& room, const Vector3d& p_world) {
  double best = std::numeric_limits<double>::infinity();
  for (const SynthObject& object : room.objects) {
    const Vector3d p_object = object.T_world_object.inverse() * p_world;
    for (const SynthPrimitive& prim : object.primitives) {
      const Vector3d p = prim.T_object_primitive.inverse() * p_object;
      double d = 0.0;
      switch (prim.shape) {
        case SynthShape::box: {
          const Vector3d q = p.cwiseAbs() - prim.size;
          d = q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
          break;
        }
        case SynthShape::sphere: d = p.norm() - prim.size.x(); break;
        case SynthShape::cylinder: {
          const Eigen::Vector2d q(p.head<2>().norm() - prim.size.x(),
                                  std::abs(p.z()) - prim.size.z());
          d = q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
          break;
        }
        case SynthShape::plane: d = p.z(); break;
      }
      best = std::min(best, d);
    }
  }
  return best;
}

}  // namespace fslam::core
