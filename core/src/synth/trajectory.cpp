// A hand-held-like camera path: sums of slow sinusoids for the walk, a look-at target with a
// sweeping yaw so the whole furnished half of the room is seen within the first two seconds, and
// a small high-frequency shake. All phases and periods come from the seed.
#include <cmath>

#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"
#include "synth_random.hpp"

namespace fslam::core {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kTwoPi = 6.283185307179586;
constexpr double kDeg = 0.017453292519943295;

struct Wave {
  double amplitude = 0.0;
  double period = 1.0;  // s
  double phase = 0.0;   // rad
  double at(double t) const { return amplitude * std::sin(kTwoPi * t / period + phase); }
};

Wave wave(synth::Rng& rng, double amplitude, double period_lo, double period_hi) {
  return {amplitude, rng.uniform(period_lo, period_hi), rng.uniform(0.0, kTwoPi)};
}

// Camera rotation looking along `forward` with the image's "up" towards world +z.
Matrix3d look_along(const Vector3d& forward) {
  const Vector3d z = forward.normalized();
  const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();  // right
  const Vector3d y = z.cross(x);                               // down
  Matrix3d R;
  R.col(0) = x;
  R.col(1) = y;
  R.col(2) = z;
  return R;
}

// Frame i's pose: camera rotation R at centre p.
StampedPose frame_pose(std::size_t i, const Matrix3d& R, const Vector3d& p) {
  StampedPose pose;
  pose.timestamp = static_cast<double>(i) / kSynthFrameRate;
  pose.T_world_camera.linear() = R;
  pose.T_world_camera.translation() = p;
  return pose;
}

// The loop: periodic in the lap, so each lap ends where it began; the gaze sweeps over the
// furniture as the wander's does (views of a bare wall alone leave GICP degenerate).
Trajectory loop_trajectory(const SyntheticRoom& room, const SynthOptions& options) {
  synth::Rng rng(synth::stream_seed(options.seed, synth::Stream::trajectory));
  const Vector3d centre = room.camera_zone.center();
  const Vector3d half = 0.5 * room.camera_zone.sizes();
  const double direction = rng.sign();
  const double start = rng.uniform(0.0, kTwoPi);
  const double lap_frames = static_cast<double>(options.frames) / options.laps;
  Trajectory trajectory;
  trajectory.reserve(options.frames);
  for (std::size_t i = 0; i < options.frames; ++i) {
    const double a = start + direction * kTwoPi * static_cast<double>(i) / lap_frames;  // lap angle
    // Height and gaze wobble with harmonics of the lap, so they repeat exactly each lap.
    const Vector3d p = centre + Vector3d(0.8 * half.x() * std::cos(a), 0.8 * half.y() * std::sin(a),
                                         0.5 * half.z() * std::sin(2.0 * a));
    // Gaze: the furniture's centre (room.look_at), swept sideways and up and down.
    const Vector3d look = room.look_at + Vector3d(0.4 * std::sin(3.0 * a), 0.25 * std::cos(2.0 * a), 0.15 * std::sin(a));
    const Vector3d forward = look - p;
    const Matrix3d R = look_along(forward) *
                       Eigen::AngleAxisd(3.0 * kDeg * std::sin(4.0 * a), Vector3d::UnitZ()).toRotationMatrix();
    trajectory.push_back(frame_pose(i, R, p));
  }
  return trajectory;
}

double smoothstep(double u) { return u * u * (3.0 - 2.0 * u); }

// Where frame i is in its lap of a loop path, [0, 1): options.frames cover options.laps laps.
double lap_position(std::size_t i, const SynthOptions& options) {
  const double lap_frames = static_cast<double>(options.frames) / options.laps;
  const double lap = static_cast<double>(i) / lap_frames;  // as the hall's figures were made
  return lap - std::floor(lap);
}

// The hall's loop (a lap: east leg, east turn, west leg, west turn): the centre runs along the
// corridor r north of its middle line going east and r south going west, joined by half circles
// of radius r; the gaze looks at the north bays going east, swings through west (back down the
// corridor) in the east turn, looks at the south bays going west and swings through east in the
// west turn, tilted down towards the tables and swept sideways twice a leg. Everything is
// periodic in the lap.
Trajectory hall_loop_trajectory(const SyntheticRoom& hall, const SynthOptions& options) {
  constexpr double kLeg = 0.36, kTurn = 0.14;  // fractions of a lap (2 legs + 2 turns = 1)
  constexpr double kR = 0.3;                   // m, half the distance between the two legs
  const double x0 = hall.camera_zone.min().x(), x1 = hall.camera_zone.max().x();
  const double c = hall.camera_zone.center().y();
  Trajectory trajectory;
  trajectory.reserve(options.frames);
  for (std::size_t i = 0; i < options.frames; ++i) {
    const double s = lap_position(i, options);
    Vector3d p;
    double gaze = 0.0;  // yaw of the view from world +x, rad
    if (s < kLeg) {  // east leg, looking north
      const double u = s / kLeg;
      p = {x0 + u * (x1 - x0), c + kR, 0.0};
      gaze = 0.25 * kTwoPi + 12.0 * kDeg * std::sin(2.0 * kTwoPi * u);
    } else if (s < kLeg + kTurn) {  // east turn: north -> west -> south
      const double u = (s - kLeg) / kTurn;
      const double phi = 0.25 * kTwoPi - 0.5 * kTwoPi * u;
      p = {x1 + kR * std::cos(phi), c + kR * std::sin(phi), 0.0};
      gaze = 0.25 * kTwoPi + 0.5 * kTwoPi * smoothstep(u);
    } else if (s < 2.0 * kLeg + kTurn) {  // west leg, looking south
      const double u = (s - kLeg - kTurn) / kLeg;
      p = {x1 - u * (x1 - x0), c - kR, 0.0};
      gaze = 0.75 * kTwoPi + 12.0 * kDeg * std::sin(2.0 * kTwoPi * u);
    } else {  // west turn: south -> east -> north
      const double u = (s - 2.0 * kLeg - kTurn) / kTurn;
      const double phi = 0.75 * kTwoPi - 0.5 * kTwoPi * u;
      p = {x0 + kR * std::cos(phi), c + kR * std::sin(phi), 0.0};
      gaze = 0.75 * kTwoPi + 0.5 * kTwoPi * smoothstep(u);
    }
    p.z() = hall.camera_zone.center().z() + 0.08 * std::sin(2.0 * kTwoPi * s);
    const Vector3d forward(std::cos(gaze), std::sin(gaze), -0.22 + 0.05 * std::sin(3.0 * kTwoPi * s));
    const Matrix3d R = look_along(forward) *
                       Eigen::AngleAxisd(2.0 * kDeg * std::sin(4.0 * kTwoPi * s), Vector3d::UnitZ()).toRotationMatrix();
    trajectory.push_back(frame_pose(i, R, p));
  }
  return trajectory;
}

// The ring's loop: the corridor's centre line (c/2 in from the outer walls) counter-clockwise,
// east along the south side first, at constant speed, its corners rounded with radius kR; the
// view looks ahead, swept sideways six times a lap and tilted down a little. Periodic in the lap.
Trajectory ring_loop_trajectory(const SyntheticRoom& ring, const SynthOptions& options) {
  constexpr double kR = 1.0;  // m, radius of the rounded corners
  const double x0 = ring.camera_zone.min().x() + kR, x1 = ring.camera_zone.max().x() - kR;
  const double y0 = ring.camera_zone.min().y() + kR, y1 = ring.camera_zone.max().y() - kR;
  const double corner = 0.25 * kTwoPi * kR;
  const double legs[4] = {x1 - x0, y1 - y0, x1 - x0, y1 - y0};  // south, east, north, west
  const Vector3d starts[4] = {{x0, y0 - kR, 0}, {x1 + kR, y0, 0}, {x1, y1 + kR, 0}, {x0 - kR, y1, 0}};
  const Vector3d centres[4] = {{x1, y0, 0}, {x1, y1, 0}, {x0, y1, 0}, {x0, y0, 0}};  // of the corner after each leg
  const double length = 2.0 * (legs[0] + legs[1]) + 4.0 * corner;
  Trajectory trajectory;
  trajectory.reserve(options.frames);
  for (std::size_t i = 0; i < options.frames; ++i) {
    const double s_lap = lap_position(i, options);
    double s = s_lap * length;
    Vector3d p;
    double heading = 0.0;  // direction of travel, yaw from world +x
    for (int side = 0; side < 4; ++side) {
      const double side_heading = 0.25 * kTwoPi * side;
      if (s < legs[side]) {
        p = starts[side] + s * Vector3d(std::cos(side_heading), std::sin(side_heading), 0.0);
        heading = side_heading;
        break;
      }
      s -= legs[side];
      if (s < corner || side == 3) {
        const double a = std::min(s, corner) / kR;  // turned so far in this corner, rad
        const double phi = side_heading - 0.25 * kTwoPi + a;  // from the corner's centre
        p = centres[side] + kR * Vector3d(std::cos(phi), std::sin(phi), 0.0);
        heading = side_heading + a;
        break;
      }
      s -= corner;
    }
    p.z() = ring.camera_zone.center().z() + 0.06 * std::sin(3.0 * kTwoPi * s_lap);
    const double gaze = heading + 15.0 * kDeg * std::sin(6.0 * kTwoPi * s_lap);
    const Vector3d forward(std::cos(gaze), std::sin(gaze), -0.15 + 0.05 * std::sin(5.0 * kTwoPi * s_lap));
    const Matrix3d R = look_along(forward) *
                       Eigen::AngleAxisd(2.0 * kDeg * std::sin(4.0 * kTwoPi * s_lap), Vector3d::UnitZ()).toRotationMatrix();
    trajectory.push_back(frame_pose(i, R, p));
  }
  return trajectory;
}

}  // namespace

const char* to_string(SynthPath path) { return path == SynthPath::loop ? "loop" : "wander"; }

bool parse_synth_path(const std::string& text, SynthPath* path, std::string* why) {
  if (text == "wander") return *path = SynthPath::wander, true;
  if (text == "loop") return *path = SynthPath::loop, true;
  if (why) *why = "unknown synthetic path '" + text + "' (wander or loop)";
  return false;
}

Trajectory make_trajectory(const SyntheticRoom& room, const SynthOptions& options) {
  if (options.path == SynthPath::loop) {
    switch (room.scene) {
      case SynthScene::hall: return hall_loop_trajectory(room, options);
      case SynthScene::ring: return ring_loop_trajectory(room, options);
      case SynthScene::room: break;
    }
    return loop_trajectory(room, options);
  }
  synth::Rng rng(synth::stream_seed(options.seed, synth::Stream::trajectory));
  const Vector3d centre = room.camera_zone.center();
  const Vector3d half = 0.5 * room.camera_zone.sizes();

  // The walk, in units of the zone's half extents (each axis stays within [-1, 1]).
  const Wave walk_x[2] = {wave(rng, 0.7, 14.0, 18.0), wave(rng, 0.3, 5.0, 7.0)};
  const Wave walk_y[2] = {wave(rng, 0.8, 10.0, 13.0), wave(rng, 0.2, 4.0, 5.0)};
  const Wave walk_z = wave(rng, 1.0, 7.0, 9.0);
  // Where the camera looks: a slowly drifting point ahead, at the depth and height of
  // room.look_at (m).
  const Wave target_x = wave(rng, 0.12, 9.0, 13.0);
  const Wave target_y = wave(rng, 0.2, 11.0, 15.0);
  const Wave target_z = wave(rng, 0.1, 8.0, 11.0);
  // The sweep: starts at one extreme (side chosen by the seed) and crosses to the other within
  // the first 2 s, its amplitude breathing slowly; plus small pitch and roll oscillations.
  const double sweep_sign = rng.sign();
  const double sweep_period = 4.0;  // s: one extreme to the other in 60 frames
  const Wave sweep_breath = wave(rng, 0.25, 15.0, 20.0);
  const Wave yaw_slow = wave(rng, 3.0 * kDeg, 11.0, 14.0);
  const Wave pitch = wave(rng, 3.0 * kDeg, 6.0, 8.0);
  const Wave roll = wave(rng, 2.5 * kDeg, 7.0, 10.0);
  // Shake: three octaves around 2, 3.5 and 6 Hz; millimetres and a tenth of a degree.
  Wave shake_t[3][3], shake_r[3][3];
  const double shake_t_amp[3] = {0.0008, 0.0005, 0.0003};
  const double shake_r_amp[3] = {0.12 * kDeg, 0.07 * kDeg, 0.04 * kDeg};
  const double shake_hz[3][2] = {{1.7, 2.3}, {3.1, 3.9}, {5.2, 6.4}};
  for (int axis = 0; axis < 3; ++axis)
    for (int k = 0; k < 3; ++k) {
      shake_t[axis][k] = wave(rng, shake_t_amp[k], 1.0 / shake_hz[k][1], 1.0 / shake_hz[k][0]);
      shake_r[axis][k] = wave(rng, shake_r_amp[k], 1.0 / shake_hz[k][1], 1.0 / shake_hz[k][0]);
    }

  Trajectory trajectory;
  trajectory.reserve(options.frames);
  for (std::size_t i = 0; i < options.frames; ++i) {
    const double t = static_cast<double>(i) / kSynthFrameRate;
    Vector3d p =
        centre + Vector3d(half.x() * (walk_x[0].at(t) + walk_x[1].at(t)),
                          half.y() * (walk_y[0].at(t) + walk_y[1].at(t)), half.z() * walk_z.at(t));
    // The target follows the camera sideways, so the sweep alone sets where the view points.
    const Vector3d target(p.x() + target_x.at(t), room.look_at.y() + target_y.at(t),
                          room.look_at.z() + target_z.at(t));

    const double sweep_amplitude =
        22.0 * kDeg * (1.0 + 0.5 * (sweep_breath.at(t) - sweep_breath.at(0.0)));
    const double yaw =
        sweep_sign * sweep_amplitude * std::cos(kTwoPi * t / sweep_period) + yaw_slow.at(t);
    Vector3d shake_p, shake_phi;
    for (int axis = 0; axis < 3; ++axis) {
      shake_p[axis] = shake_t[axis][0].at(t) + shake_t[axis][1].at(t) + shake_t[axis][2].at(t);
      shake_phi[axis] = shake_r[axis][0].at(t) + shake_r[axis][1].at(t) + shake_r[axis][2].at(t);
    }
    p += shake_p;

    // Yaw about the world vertical, then pitch and roll about the camera's own axes
    // (camera x right, z forward; positive pitch looks up).
    const Matrix3d R =
        Eigen::AngleAxisd(yaw, Vector3d::UnitZ()).toRotationMatrix() * look_along(target - p) *
        Eigen::AngleAxisd(pitch.at(t), Vector3d::UnitX()).toRotationMatrix() *
        Eigen::AngleAxisd(roll.at(t), Vector3d::UnitZ()).toRotationMatrix() * so3_exp(shake_phi);
    trajectory.push_back(frame_pose(i, R, p));
  }
  return trajectory;
}

}  // namespace fslam::core
