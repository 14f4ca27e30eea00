// Procedural synthetic RGB-D sequences: a furnished room of analytic primitives, ray cast along a
// smooth hand-held-like trajectory, with exact depth, instance and class labels and an optional
// Kinect-like noise model. `fslam synth` writes them in TUM layout (docs/datasets.md).
//
// Conventions
// - World frame: z up, metres. The room interior is the box [0, size.x] x [0, size.y] x
//   [0, size.z]; the floor is z = 0. The camera walks near the wall y = 0 and looks towards +y.
// - Camera frame: OpenCV/TUM (x right, y down, z forward); poses are T_world_camera.
// - Depth is z along the optical axis (not the ray length), metres.
// - Everything is a pure function of the seed (and, for noise, of the frame index), so output
//   does not depend on thread count or scheduling.
#pragma once

#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {

inline constexpr double kSynthFrameRate = 30.0;     // Hz; frame i is at t = i / kSynthFrameRate
inline constexpr double kSynthDepthScale = 5000.0;  // 16-bit depth PNG units per metre (TUM)

enum class SynthNoise { none, kinect };
const char* to_string(SynthNoise noise);
// Accepts "none" and "kinect".
bool parse_synth_noise(const std::string& text, SynthNoise* noise, std::string* why);

// Semantic classes; the ids are what the class label images store and never change.
enum class SynthClass : std::uint16_t {
  unlabelled = 0,  // reserved, never rendered (every pixel of a closed room hits something)
  wall = 1,
  floor = 2,
  ceiling = 3,
  table = 4,
  chair = 5,
  cabinet = 6,
  shelf = 7,
  sofa = 8,
  lamp = 9,
  plant = 10,
  box = 11,
  ball = 12,
  cup = 13,
  book = 14,
  vase = 15,
  picture = 16,
  rug = 17,
};
inline constexpr int kSynthClassCount = 18;  // ids 0 .. kSynthClassCount - 1
const char* synth_class_name(SynthClass c);
// Walls, floor and ceiling.
bool is_structural(SynthClass c);

// 525 px focal length, principal point (319.5, 239.5), 640x480: the TUM "ROS default".
PinholeCamera synth_default_camera();

// The camera path: a wander through the camera zone, or laps of one closed loop that return
// exactly to the start pose (loop closure is tested against them).
enum class SynthPath { wander, loop };
const char* to_string(SynthPath path);
// Accepts "wander" and "loop".
bool parse_synth_path(const std::string& text, SynthPath* path, std::string* why);

// The scene: one furnished room (about 4.5 x 4 m, smaller than the tracker's 6-m local map), or
// a hall of three such room halves on each long side (about 13 x 8 m), whose loop path runs
// along both sides so that a lap leaves the local map and comes back (loop closure with drift),
// or a ring: a corridor about 2.5 m wide round a walled block (about 14 x 9 m outside), whose
// loop path walks round it looking ahead, so that each place is seen only when passed.
enum class SynthScene { room, hall, ring };
const char* to_string(SynthScene scene);
// Accepts "room", "hall" and "ring".
bool parse_synth_scene(const std::string& text, SynthScene* scene, std::string* why);

struct SynthOptions {
  std::size_t frames = 300;  // sequence length, frames at kSynthFrameRate
  std::uint64_t seed = 1;    // room layout, textures, trajectory and noise
  SynthNoise noise = SynthNoise::kinect;
  SynthScene scene = SynthScene::room;
  SynthPath path = SynthPath::wander;
  int laps = 2;              // path = loop: the frames cover this many laps
  PinholeCamera camera = synth_default_camera();  // colour and depth share these intrinsics

  // At least one frame, at most kMaxFrames; a valid camera.
  bool is_valid(std::string* why = nullptr) const;
  static constexpr std::size_t kMaxFrames = 1000000;
};

enum class SynthShape {
  box,       // size = half extents (m), centred on the primitive origin
  sphere,    // size.x() = radius (m)
  cylinder,  // size.x() = radius, size.z() = half height (m); axis = local z, capped
  plane,     // the plane local z = 0, seen only from +z (room faces); size unused
};

struct SynthPrimitive {
  SynthShape shape = SynthShape::box;
  Eigen::Isometry3d T_object_primitive = Eigen::Isometry3d::Identity();
  Eigen::Vector3d size = Eigen::Vector3d::Zero();
};

// Procedural surface patterns, evaluated as solid textures in the object frame and box-filtered
// over the pixel footprint so that distant patterns fade to their mean instead of aliasing.
enum class SynthPattern {
  noise,    // smooth value noise between colour_a and colour_b, feature size `period`
  stripes,  // soft stripes of width period / 2 across `axis`, slightly warped
  checker,  // soft checkerboard of cell `period` on the face's plane
  bricks,   // running-bond bricks period x period / 2.5, mortar colour_c
  planks,   // wooden planks period wide along object x, joints colour_c
  tiles,    // square tiles of `period`, grout colour_c
};

struct SynthMaterial {
  SynthPattern pattern = SynthPattern::noise;
  Eigen::Vector3d colour_a{0.7, 0.7, 0.7};          // albedo, RGB in [0, 1]
  Eigen::Vector3d colour_b{0.4, 0.4, 0.4};          // second albedo of the pattern
  Eigen::Vector3d colour_c{0.8, 0.8, 0.8};          // lines: mortar, grout, plank joints
  double period = 0.2;                              // metres, the pattern's size
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();  // stripes run across this object-frame axis
  double mottle_scale = 0.15;  // metres, feature size of the brightness mottling
  double mottle_amount = 0.2;  // relative brightness modulation of the mottling
  std::uint32_t texture_seed = 0;
};

// One instance: a rigid group of primitives sharing a material and a label.
struct SynthObject {
  std::uint16_t instance_id = 0;  // index in SyntheticRoom::objects + 1
  SynthClass class_id = SynthClass::unlabelled;
  std::string name;  // unique, no spaces ("chair_1", "wall_north")
  Eigen::Isometry3d T_world_object = Eigen::Isometry3d::Identity();
  std::vector<SynthPrimitive> primitives;
  SynthMaterial material;
  // Object-frame bounding box of the primitives, for culling; empty (and unused) when the object
  // contains a plane.
  Eigen::AlignedBox3d bounds;
  bool bounded = true;
};

struct SyntheticRoom {
  SynthScene scene = SynthScene::room;
  Eigen::Vector3d size = Eigen::Vector3d::Zero();  // interior extent (m): [0, size] in world
  Eigen::Vector3d light_position = Eigen::Vector3d::Zero();  // point light, world (m)
  std::vector<SynthObject> objects;  // walls, floor, ceiling first; instance id = index + 1
  // Free space the camera centre stays in (world, m), at least kCameraClearance from every
  // surface, and the point it looks at on average.
  Eigen::AlignedBox3d camera_zone;
  Eigen::Vector3d look_at = Eigen::Vector3d::Zero();
  static constexpr double kCameraClearance = 0.5;  // metres
};

// The room for `seed`: size, furniture placement, sizes, colours and textures vary with the
// seed; the list of instances (names, classes, ids) is the same for every seed.
SyntheticRoom make_room(std::uint64_t seed);
// The hall for `seed`: three bays on the north side (y > size.y / 2), each furnished as the far
// half of a room (table, chairs, things on the table, cabinet, shelf, plant, lamp, sofa, box;
// names suffixed _n1 .. _n3), and three on the south side turned half a turn about the hall's
// centre (_s1 .. _s3). The camera zone is the corridor between them.
SyntheticRoom make_hall(std::uint64_t seed);
// The ring for `seed`: a walled block (instance wall_block) in the middle of a room, leaving a
// corridor about 2.5 m wide all round; along the corridor's walls stand cabinets, shelves,
// plants and storage boxes and hang pictures (names suffixed by the wall: _s, _e, _n, _w outside,
// _bs .. _bw on the block, and a number). The camera zone is the box the ring's centre line spans.
SyntheticRoom make_ring(std::uint64_t seed);
// make_room, make_hall or make_ring.
SyntheticRoom make_scene(SynthScene scene, std::uint64_t seed);

// Signed distance (m) from a world point to the nearest surface of the room: positive inside
// the free space, negative inside an object or outside the room.
double synth_clearance(const SyntheticRoom& room, const Eigen::Vector3d& p_world);

// Camera-to-world poses at t = i / kSynthFrameRate for i < options.frames. wander: the camera
// centre wanders smoothly through room.camera_zone (about 5-10 mm per frame) while the view
// sweeps across the furniture (about 0.5-1.5 degrees per frame), plus a slight deterministic
// shake. loop: the centre goes round an ellipse inside the zone, the view sweeping over the
// furniture, `laps` times in `frames` frames; frame k * frames / laps is the start pose again.
// In a hall the loop runs east along the corridor looking at the north bays, turns at the east
// end looking back down the corridor, runs west looking at the south bays and turns at the west
// end: the view turns 360 degrees a lap, never towards a bare end wall. In a ring the loop walks
// the corridor's centre line counter-clockwise looking ahead (swept from side to side), with
// rounded corners.
Trajectory make_trajectory(const SyntheticRoom& room, const SynthOptions& options);

struct SynthView {
  cv::Mat colour;          // [H, W] CV_8UC3, RGB, lambertian shading of the albedo
  cv::Mat depth;           // [H, W] CV_32FC1, metres along the optical axis; 0 = missing
  cv::Mat instance_label;  // [H, W] CV_16UC1, SynthObject::instance_id
  cv::Mat class_label;     // [H, W] CV_16UC1, SynthClass
  cv::Mat normal;          // [H, W] CV_32FC3, unit surface normal, camera frame, facing the camera
};

// Ray casts the room from one pose (one sample at each pixel centre); exact depth, no noise.
SynthView render_view(const SyntheticRoom& room, const PinholeCamera& camera,
                      const Eigen::Isometry3d& T_world_camera);

// Kinect v1-like degradation, in place, seeded by (seed, frame) only:
// - holes where the projector (7.5 cm right of the camera) is occluded, at depth
//   discontinuities (half the pixels), at grazing angles, beyond 0.5-5 m and 0.5% at random;
// - axial noise sigma = 0.0012 + 0.0019 (z - 0.4)^2 m plus Nguyen et al.'s (2012) angle term;
// - disparity quantised to 1/8 pixel (depth steps grow with z^2);
// - colour: approximately Gaussian noise of 2 levels per channel.
// Labels and normals are left exact.
void apply_kinect_noise(const PinholeCamera& camera, std::uint64_t seed, std::uint64_t frame,
                        SynthView* view);

// "%.6f" of frame / kSynthFrameRate: the stamp in file names and index files.
std::string synth_timestamp(std::size_t frame);

// Called after each frame is written, possibly from worker threads but never concurrently;
// `done` counts up to `total`.
using SynthProgress = std::function<void(std::size_t done, std::size_t total)>;

// Renders options.frames frames in parallel (TBB) into `dir`, which must be empty or not yet
// exist: rgb/, depth/, labels/instance/, labels/class/ (<stamp>.png), rgb.txt, depth.txt,
// groundtruth.txt, intrinsics.txt, classes.txt, instances.txt. The index files are written last,
// so a folder without them is incomplete.
bool write_synthetic_sequence(const std::string& dir, const SynthOptions& options,
                              const SynthProgress& progress, std::string* why);

}  // namespace fslam::core
