#include "fslam/core/synth/synthetic_scene.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <opencv2/core.hpp>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

constexpr double kDeg = 3.14159265358979323846 / 180.0;

// The non-comment, non-empty lines of a text file.
std::vector<std::string> data_lines(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(in, line))
    if (!line.empty() && line[0] != '#') lines.push_back(line);
  return lines;
}

std::string file_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

SynthOptions small_options(std::size_t frames, SynthNoise noise) {
  SynthOptions options;
  options.frames = frames;
  options.seed = 1;
  options.noise = noise;
  return options;
}

TEST(SynthOptions, ValidationErrors) {
  std::string why;
  EXPECT_TRUE(SynthOptions{}.is_valid(&why)) << why;

  SynthOptions options;
  options.frames = 0;
  EXPECT_FALSE(options.is_valid(&why));
  EXPECT_NE(why.find("frames"), std::string::npos) << why;
  options.frames = SynthOptions::kMaxFrames + 1;
  EXPECT_FALSE(options.is_valid(&why));
  EXPECT_NE(why.find("frames"), std::string::npos) << why;

  options = SynthOptions{};
  options.camera.fx = 0.0;
  EXPECT_FALSE(options.is_valid(&why));
  EXPECT_NE(why.find("camera"), std::string::npos) << why;

  SynthNoise noise = SynthNoise::none;
  EXPECT_FALSE(parse_synth_noise("gaussian", &noise, &why));
  EXPECT_NE(why.find("gaussian"), std::string::npos) << why;
  ASSERT_TRUE(parse_synth_noise("kinect", &noise, &why));
  EXPECT_EQ(noise, SynthNoise::kinect);
  ASSERT_TRUE(parse_synth_noise("none", &noise, &why));
  EXPECT_EQ(noise, SynthNoise::none);
  EXPECT_STREQ(to_string(SynthNoise::kinect), "kinect");

  // Invalid options are rejected before anything is created.
  const fs::path dir = test::fresh_temp_dir("validation");
  options = SynthOptions{};
  options.frames = 0;
  EXPECT_FALSE(write_synthetic_sequence((dir / "new").string(), options, {}, &why));
  EXPECT_FALSE(fs::exists(dir / "new"));
  // The output folder must be empty, and must be a folder.
  std::ofstream(dir / "occupied.txt") << "x";
  EXPECT_FALSE(
      write_synthetic_sequence(dir.string(), small_options(1, SynthNoise::none), {}, &why));
  EXPECT_NE(why.find("not empty"), std::string::npos) << why;
  EXPECT_FALSE(write_synthetic_sequence((dir / "occupied.txt").string(),
                                        small_options(1, SynthNoise::none), {}, &why));
  EXPECT_NE(why.find("not a folder"), std::string::npos) << why;
  EXPECT_FALSE(write_synthetic_sequence("", small_options(1, SynthNoise::none), {}, &why));
}

TEST(SynthRoom, InstancesAreStableAndNamed) {
  const SyntheticRoom a = make_room(1);
  const SyntheticRoom b = make_room(2);
  ASSERT_EQ(a.objects.size(), b.objects.size());
  std::set<std::string> names;
  for (std::size_t i = 0; i < a.objects.size(); ++i) {
    const SynthObject& o = a.objects[i];
    EXPECT_EQ(o.instance_id, i + 1);
    EXPECT_EQ(o.name, b.objects[i].name);
    EXPECT_EQ(o.class_id, b.objects[i].class_id);
    EXPECT_NE(o.class_id, SynthClass::unlabelled);
    EXPECT_EQ(o.name.find(' '), std::string::npos);
    EXPECT_TRUE(names.insert(o.name).second) << "duplicate " << o.name;
    EXPECT_FALSE(o.primitives.empty()) << o.name;
  }
  // Different seeds give different rooms.
  EXPECT_GT((a.size - b.size).norm(), 0.01);
  EXPECT_STREQ(synth_class_name(SynthClass::chair), "chair");
  EXPECT_TRUE(is_structural(SynthClass::floor));
  EXPECT_FALSE(is_structural(SynthClass::rug));
}

// Requirement: >= 8 object instances of >= 5 non-structural classes, every one of them seen in
// the first 60 frames; every pixel labelled; depths in a Kinect's range.
TEST(SynthRoom, EveryObjectVisibleWithinSixtyFrames) {
  for (std::uint64_t seed : {1, 2, 3}) {
    const SyntheticRoom room = make_room(seed);
    std::set<SynthClass> classes;
    std::map<std::uint16_t, const SynthObject*> objects;
    for (const SynthObject& o : room.objects)
      if (!is_structural(o.class_id)) {
        classes.insert(o.class_id);
        objects[o.instance_id] = &o;
      }
    EXPECT_GE(objects.size(), 8u);
    EXPECT_GE(classes.size(), 5u);

    SynthOptions options;
    options.seed = seed;
    options.frames = 60;
    const Trajectory trajectory = make_trajectory(room, options);
    const PinholeCamera camera = synth_default_camera().scaled(0.25);  // 160x120 for speed
    std::map<std::uint16_t, int> pixels;
    std::vector<double> depths;
    for (const StampedPose& pose : trajectory) {
      const SynthView view = render_view(room, camera, pose.T_world_camera);
      for (int v = 0; v < camera.height; ++v)
        for (int u = 0; u < camera.width; ++u) {
          const std::uint16_t id = view.instance_label.at<std::uint16_t>(v, u);
          ASSERT_GE(id, 1) << "unlabelled pixel";
          ASSERT_LE(static_cast<std::size_t>(id), room.objects.size());
          ASSERT_EQ(view.class_label.at<std::uint16_t>(v, u),
                    static_cast<std::uint16_t>(room.objects[id - 1].class_id));
          ++pixels[id];
          depths.push_back(view.depth.at<float>(v, u));
        }
    }
    for (const auto& [id, object] : objects)
      EXPECT_GE(pixels[id], 4) << "seed " << seed << ": " << object->name
                               << " not visible in the first 60 frames";
    std::sort(depths.begin(), depths.end());
    EXPECT_GT(depths[depths.size() / 20], 0.8) << "seed " << seed << ": 5th percentile depth (m)";
    EXPECT_LT(depths[depths.size() * 19 / 20], 3.8) << "seed " << seed << ": 95th percentile (m)";
  }
}

TEST(SynthTrajectory, HandheldMotionInsideFreeSpace) {
  for (std::uint64_t seed = 1; seed <= 5; ++seed) {
    const SyntheticRoom room = make_room(seed);
    SynthOptions options;
    options.seed = seed;
    options.frames = 900;  // 30 s
    const Trajectory trajectory = make_trajectory(room, options);
    ASSERT_EQ(trajectory.size(), options.frames);
    double step_sum = 0.0, step_max = 0.0, angle_sum = 0.0, angle_max = 0.0, jerk_max = 0.0;
    for (std::size_t i = 0; i < trajectory.size(); ++i) {
      const Eigen::Isometry3d& T = trajectory[i].T_world_camera;
      EXPECT_NEAR(trajectory[i].timestamp, i / kSynthFrameRate, 1e-12);
      ASSERT_TRUE(is_rigid(T.matrix(), 1e-9));
      // Inside the room and at least kCameraClearance from every surface.
      ASSERT_GE(synth_clearance(room, T.translation()), SyntheticRoom::kCameraClearance)
          << "seed " << seed << " frame " << i;
      if (i == 0) continue;
      const Eigen::Isometry3d delta = trajectory[i - 1].T_world_camera.inverse() * T;
      const double step = delta.translation().norm();
      const double angle = rotation_angle(delta.linear());
      step_sum += step;
      angle_sum += angle;
      step_max = std::max(step_max, step);
      angle_max = std::max(angle_max, angle);
      if (i >= 2) {
        const Eigen::Vector3d accel = T.translation() -
                                      2.0 * trajectory[i - 1].T_world_camera.translation() +
                                      trajectory[i - 2].T_world_camera.translation();
        jerk_max = std::max(jerk_max, accel.norm());
      }
    }
    const double n = static_cast<double>(trajectory.size() - 1);
    // Hand-held Kinect at 30 Hz: about 5-10 mm and 0.5-1.5 degrees per frame, smooth.
    EXPECT_GT(step_sum / n, 0.004) << "seed " << seed;
    EXPECT_LT(step_sum / n, 0.010) << "seed " << seed;
    EXPECT_LT(step_max, 0.015) << "seed " << seed;
    EXPECT_GT(angle_sum / n, 0.5 * kDeg) << "seed " << seed;
    EXPECT_LT(angle_sum / n, 1.2 * kDeg) << "seed " << seed;
    EXPECT_LT(angle_max, 2.2 * kDeg) << "seed " << seed;
    EXPECT_LT(jerk_max, 0.002) << "seed " << seed << ": change of velocity per frame (m)";
  }
}

// The loop path returns exactly to its start pose after each lap, stays in free space, moves like
// a slow hand-held camera and covers ground between revisits (loop-closure tests need both).
// A loop trajectory's checks shared by the room's and the hall's: frame `lap` is the start pose
// again, every pose is rigid and in free space; returns how far it goes from its start and its
// largest step and turn between frames.
struct LoopSteps {
  double farthest = 0.0, step_max = 0.0, angle_max = 0.0;
};
LoopSteps check_loop(const SyntheticRoom& room, const Trajectory& trajectory, std::size_t lap, const std::string& what) {
  LoopSteps steps;
  const Eigen::Isometry3d& start = trajectory[0].T_world_camera;
  const Eigen::Isometry3d& back = trajectory[lap].T_world_camera;
  EXPECT_LT((back.translation() - start.translation()).norm(), 1e-9) << what;
  EXPECT_LT(rotation_angle(back.linear().transpose() * start.linear()), 1e-9) << what;
  for (std::size_t i = 0; i < trajectory.size(); ++i) {
    const Eigen::Isometry3d& T = trajectory[i].T_world_camera;
    EXPECT_TRUE(is_rigid(T.matrix(), 1e-9)) << what << " frame " << i;
    EXPECT_GE(synth_clearance(room, T.translation()), SyntheticRoom::kCameraClearance) << what << " frame " << i;
    steps.farthest = std::max(steps.farthest, (T.translation() - start.translation()).norm());
    if (i == 0) continue;
    const Eigen::Isometry3d delta = trajectory[i - 1].T_world_camera.inverse() * T;
    steps.step_max = std::max(steps.step_max, delta.translation().norm());
    steps.angle_max = std::max(steps.angle_max, rotation_angle(delta.linear()));
  }
  return steps;
}

TEST(SynthTrajectory, LoopReturnsToItsStartEveryLap) {
  for (std::uint64_t seed = 1; seed <= 5; ++seed) {
    const SyntheticRoom room = make_room(seed);
    SynthOptions options;
    options.seed = seed;
    options.frames = 1200;
    options.path = SynthPath::loop;
    options.laps = 2;
    const Trajectory trajectory = make_trajectory(room, options);
    ASSERT_EQ(trajectory.size(), options.frames);
    const LoopSteps steps = check_loop(room, trajectory, 600, "seed " + std::to_string(seed));
    EXPECT_GT(steps.farthest, 0.3) << "seed " << seed << ": the loop must leave its start";
    EXPECT_LT(steps.step_max, 0.015) << "seed " << seed;
    EXPECT_LT(steps.angle_max, 2.2 * kDeg) << "seed " << seed;
  }
  SynthOptions bad;
  bad.path = SynthPath::loop;
  bad.laps = 0;
  std::string why;
  EXPECT_FALSE(bad.is_valid(&why));
  EXPECT_NE(why.find("laps"), std::string::npos) << why;
  SynthPath path;
  EXPECT_FALSE(parse_synth_path("spiral", &path, &why));
  EXPECT_NE(why.find("spiral"), std::string::npos) << why;
}

// A large scene's loop (hall or ring), 3,600 frames in 2 laps for `seed`: check_loop's checks,
// more than 8 m from its start (the start's surroundings leave the tracker's 6-m local map), and
// every step under `max_step` metres and `max_angle` radians. Returns the trajectory.
Trajectory check_large_loop(const SyntheticRoom& scene, std::uint64_t seed, double max_step, double max_angle) {
  SynthOptions options;
  options.seed = seed;
  options.scene = scene.scene;
  options.frames = 3600;
  options.path = SynthPath::loop;
  options.laps = 2;
  const Trajectory trajectory = make_trajectory(scene, options);
  EXPECT_EQ(trajectory.size(), options.frames);
  if (trajectory.size() != options.frames) return trajectory;
  const std::string what = std::string(to_string(scene.scene)) + " seed " + std::to_string(seed);
  const LoopSteps steps = check_loop(scene, trajectory, 1800, what);
  EXPECT_GT(steps.farthest, 8.0) << what << ": a lap must leave the 6-m local map";
  EXPECT_LT(steps.step_max, max_step) << what;
  EXPECT_LT(steps.angle_max, max_angle) << what;
  return trajectory;
}

// The hall's loop (make_hall, the loop path in it): back at the start pose every lap, always in
// free space, more than 8 m from its start (so a lap leaves the tracker's 6-m local map: loop
// closure has drift to remove), at walking pace (3,600 frames in 2 laps: under 2 cm and 1.3
// degrees a frame). Its instances are named uniquely.
TEST(SynthTrajectory, HallLoopLeavesTheLocalMapAndReturnsEveryLap) {
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    const SyntheticRoom hall = make_hall(seed);
    EXPECT_EQ(hall.scene, SynthScene::hall);
    EXPECT_GT(hall.size.x(), 12.0);
    std::set<std::string> names;
    for (const SynthObject& o : hall.objects) EXPECT_TRUE(names.insert(o.name).second) << o.name;
    check_large_loop(hall, seed, 0.02, 1.3 * kDeg);
  }
  SynthScene scene;
  std::string why;
  EXPECT_TRUE(parse_synth_scene("ring", &scene, &why));
  EXPECT_EQ(scene, SynthScene::ring);
  EXPECT_FALSE(parse_synth_scene("castle", &scene, &why));
  EXPECT_NE(why.find("castle"), std::string::npos) << why;
}

// The ring's loop (make_ring): back at the start pose every lap, always in free space (never
// inside the block), round the whole ring (its far side more than 8 m from the start: out of the
// 6-m local map), at walking pace (3,600 frames in 2 laps: under 2.2 cm and 1.6 degrees a frame).
// Its instances are named uniquely and are the same for every seed.
TEST(SynthTrajectory, RingLoopGoesRoundTheBlockAndReturnsEveryLap) {
  std::vector<std::string> first_names;
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    const SyntheticRoom ring = make_ring(seed);
    EXPECT_EQ(ring.scene, SynthScene::ring);
    EXPECT_GT(ring.size.x(), 13.0);
    std::set<std::string> names;
    std::vector<std::string> ordered;
    for (const SynthObject& o : ring.objects) {
      EXPECT_TRUE(names.insert(o.name).second) << o.name;
      ordered.push_back(o.name);
    }
    if (first_names.empty()) first_names = ordered;
    EXPECT_EQ(ordered, first_names) << "seed " << seed;
    const Trajectory trajectory = check_large_loop(ring, seed, 0.022, 1.6 * kDeg);
    // The centre line keeps well off the block and the furniture: 0.6 m from every surface.
    for (std::size_t i = 0; i < trajectory.size(); i += 10)
      EXPECT_GT(synth_clearance(ring, trajectory[i].T_world_camera.translation()), 0.6) << "frame " << i;
  }
}

TEST(SynthNoise, KinectModel) {
  const SyntheticRoom room = make_room(1);
  SynthOptions options;
  options.frames = 1;
  const Eigen::Isometry3d T = make_trajectory(room, options)[0].T_world_camera;
  const PinholeCamera camera = synth_default_camera();
  const SynthView exact = render_view(room, camera, T);
  SynthView noisy = exact;
  noisy.depth = exact.depth.clone();
  noisy.colour = exact.colour.clone();
  apply_kinect_noise(camera, 1, 0, &noisy);

  // Deterministic in (seed, frame), different for another frame.
  SynthView again = exact;
  again.depth = exact.depth.clone();
  again.colour = exact.colour.clone();
  apply_kinect_noise(camera, 1, 0, &again);
  EXPECT_EQ(cv::norm(again.depth, noisy.depth, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(again.colour, noisy.colour, cv::NORM_INF), 0.0);
  SynthView other = exact;
  other.depth = exact.depth.clone();
  other.colour = exact.colour.clone();
  apply_kinect_noise(camera, 1, 1, &other);
  EXPECT_GT(cv::norm(other.depth, noisy.depth, cv::NORM_L1), 0.0);

  const double fb = camera.fx * 0.075;  // disparity (px) = fb / z
  int holes = 0, shadow_candidates = 0, shadow_holes = 0;
  std::vector<double> errors;  // |noisy - exact| at 1.5-2.5 m away from edges
  for (int v = 1; v + 1 < camera.height; ++v)
    for (int u = 1; u + 1 < camera.width; ++u) {
      const float z = exact.depth.at<float>(v, u);
      const float zn = noisy.depth.at<float>(v, u);
      ASSERT_GT(z, 0.0f);
      if (zn == 0.0f) {
        ++holes;
      } else {
        // Disparity is quantised to 1/8 pixel.
        const double steps = fb / zn * 8.0;
        ASSERT_NEAR(steps, std::round(steps), 1e-3);
      }
      // The projector sits to the right: a surface whose right neighbour is more than two
      // disparity pixels nearer is always in its shadow.
      const float right = exact.depth.at<float>(v, u + 1);
      if (fb / right - fb / z > 2.0) {
        ++shadow_candidates;
        if (zn == 0.0f) ++shadow_holes;
      }
      const bool flat = std::abs(exact.depth.at<float>(v, u - 1) - z) < 0.02 &&
                        std::abs(right - z) < 0.02 &&
                        std::abs(exact.depth.at<float>(v - 1, u) - z) < 0.02 &&
                        std::abs(exact.depth.at<float>(v + 1, u) - z) < 0.02;
      if (zn > 0.0f && flat && z > 1.5f && z < 2.5f) errors.push_back(std::abs(zn - z));
    }
  const double pixels = (camera.width - 2.0) * (camera.height - 2.0);
  EXPECT_GT(holes / pixels, 0.01);
  EXPECT_LT(holes / pixels, 0.2);
  ASSERT_GT(shadow_candidates, 50);
  EXPECT_EQ(shadow_holes, shadow_candidates);
  // Nguyen et al.: sigma 3.5-5.8 mm at 1.5-2.5 m; quantisation adds 7-19 mm steps there.
  ASSERT_GT(errors.size(), 10000u);
  const double med = median(errors);
  EXPECT_GT(med, 0.002);
  EXPECT_LT(med, 0.010);

  // Mild colour noise (sigma 2 levels); labels untouched.
  cv::Mat diff;
  cv::absdiff(noisy.colour, exact.colour, diff);
  const cv::Scalar mean_diff = cv::mean(diff);
  EXPECT_GT(mean_diff[0], 0.8);
  EXPECT_LT(mean_diff[0], 2.5);
  EXPECT_EQ(cv::norm(noisy.instance_label, exact.instance_label, cv::NORM_INF), 0.0);
}

TEST(SynthSequence, SameBytesForAnyThreadCount) {
  const SynthOptions options = small_options(5, SynthNoise::kinect);
  const fs::path a = test::fresh_temp_dir("a"), b = test::fresh_temp_dir("b");
  std::string why;
  {
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    ASSERT_TRUE(write_synthetic_sequence(a.string(), options, {}, &why)) << why;
  }
  std::vector<std::size_t> reported;
  ASSERT_TRUE(write_synthetic_sequence(
      b.string(), options,
      [&](std::size_t done, std::size_t total) {
        EXPECT_EQ(total, options.frames);
        reported.push_back(done);
      },
      &why))
      << why;
  EXPECT_EQ(reported, (std::vector<std::size_t>{1, 2, 3, 4, 5}));

  std::size_t files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(a)) {
    if (!entry.is_regular_file()) continue;
    ++files;
    const fs::path relative = fs::relative(entry.path(), a);
    ASSERT_TRUE(fs::exists(b / relative)) << relative;
    EXPECT_TRUE(file_bytes(entry.path()) == file_bytes(b / relative)) << relative << " differs";
  }
  EXPECT_EQ(files, 4 * options.frames + 6);
}

// Reads back a noise-free sequence through its files only, checks the TUM layout, and warps
// frame 0 into frame 10 with the ground-truth poses.
TEST(SynthSequence, TumLayoutAndGeometricConsistency) {
  const SynthOptions options = small_options(11, SynthNoise::none);
  const fs::path dir = test::fresh_temp_dir("seq");
  std::string why;
  ASSERT_TRUE(write_synthetic_sequence(dir.string(), options, {}, &why)) << why;

  // Index files.
  const auto rgb = data_lines(dir / "rgb.txt");
  const auto depth = data_lines(dir / "depth.txt");
  ASSERT_EQ(rgb.size(), options.frames);
  ASSERT_EQ(depth.size(), options.frames);
  EXPECT_EQ(rgb[1], "0.033333 rgb/0.033333.png");
  EXPECT_EQ(depth[10], "0.333333 depth/0.333333.png");
  for (std::size_t i = 0; i < options.frames; ++i) {
    const std::string stamp = synth_timestamp(i);
    for (const char* sub : {"rgb", "depth", "labels/instance", "labels/class"})
      EXPECT_TRUE(fs::exists(dir / sub / (stamp + ".png"))) << sub << "/" << stamp;
  }
  const auto intrinsics = data_lines(dir / "intrinsics.txt");
  ASSERT_EQ(intrinsics.size(), 1u);
  PinholeCamera camera;
  std::istringstream(intrinsics[0]) >> camera.fx >> camera.fy >> camera.cx >> camera.cy >>
      camera.width >> camera.height;
  EXPECT_EQ(camera.fx, 525.0);
  EXPECT_EQ(camera.fy, 525.0);
  EXPECT_EQ(camera.cx, 319.5);
  EXPECT_EQ(camera.cy, 239.5);
  EXPECT_EQ(camera.width, 640);
  EXPECT_EQ(camera.height, 480);
  const auto class_lines = data_lines(dir / "classes.txt");
  EXPECT_EQ(class_lines.size(), static_cast<std::size_t>(kSynthClassCount));
  EXPECT_EQ(class_lines[5], "5 chair");
  std::map<int, int> class_of_instance;
  for (const std::string& line : data_lines(dir / "instances.txt")) {
    int id = 0, class_id = 0;
    std::string name;
    std::istringstream(line) >> id >> class_id >> name;
    EXPECT_FALSE(name.empty());
    class_of_instance[id] = class_id;
  }
  EXPECT_EQ(class_of_instance.size(), make_room(options.seed).objects.size());
  Trajectory gt;
  ASSERT_TRUE(read_tum_trajectory((dir / "groundtruth.txt").string(), &gt, &why)) << why;
  ASSERT_EQ(gt.size(), options.frames);
  EXPECT_NEAR(gt[10].timestamp, 10.0 / 30.0, 1e-6);

  struct Frame {
    cv::Mat colour, depth, instance, label;
  };
  auto load = [&](std::size_t i) {
    Frame f;
    const std::string name = synth_timestamp(i) + ".png";
    EXPECT_TRUE(read_colour_image((dir / "rgb" / name).string(), &f.colour, &why)) << why;
    EXPECT_TRUE(read_depth_image((dir / "depth" / name).string(), kSynthDepthScale, &f.depth, &why))
        << why;
    EXPECT_TRUE(
        read_single_channel_image((dir / "labels" / "instance" / name).string(), &f.instance, &why))
        << why;
    EXPECT_TRUE(
        read_single_channel_image((dir / "labels" / "class" / name).string(), &f.label, &why))
        << why;
    return f;
  };
  const Frame source = load(0), target = load(10);
  ASSERT_EQ(source.depth.size(), cv::Size(640, 480));
  ASSERT_EQ(source.instance.type(), CV_16UC1);
  ASSERT_EQ(source.colour.type(), CV_8UC3);

  // Labels agree with instances.txt, depth is the exact render to within the 16-bit step.
  const SyntheticRoom room = make_room(options.seed);
  const SynthView exact =
      render_view(room, camera, make_trajectory(room, options)[0].T_world_camera);
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      const int id = source.instance.at<std::uint16_t>(v, u);
      ASSERT_TRUE(class_of_instance.count(id)) << id;
      ASSERT_EQ(source.label.at<std::uint16_t>(v, u), class_of_instance[id]);
      ASSERT_NEAR(source.depth.at<float>(v, u), exact.depth.at<float>(v, u),
                  0.5 / kSynthDepthScale + 1e-6);
    }

  // Warp: X_target = T_target^-1 T_source unproject(u, v, z); compare with the target's depth,
  // interpolated as inverse depth (exact on planes) where all four neighbours share the
  // source pixel's instance.
  const Eigen::Isometry3d T_target_source = gt[10].T_world_camera.inverse() * gt[0].T_world_camera;
  EXPECT_GT(T_target_source.translation().norm(), 0.03);  // a real baseline
  std::vector<double> residuals;
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u) {
      const double z = source.depth.at<float>(v, u);
      if (z <= 0.0) continue;
      const Eigen::Vector3d X = T_target_source * camera.unproject(Eigen::Vector2d(u, v), z);
      if (X.z() < 0.1) continue;
      const Eigen::Vector2d px = camera.project(X);
      const int u0 = static_cast<int>(std::floor(px.x()));
      const int v0 = static_cast<int>(std::floor(px.y()));
      if (u0 < 0 || v0 < 0 || u0 + 1 >= camera.width || v0 + 1 >= camera.height) continue;
      const std::uint16_t id = source.instance.at<std::uint16_t>(v, u);
      double inv[4];
      bool usable = true;
      for (int k = 0; k < 4 && usable; ++k) {
        const int uu = u0 + (k & 1), vv = v0 + (k >> 1);
        const float zt = target.depth.at<float>(vv, uu);
        usable = zt > 0.0f && target.instance.at<std::uint16_t>(vv, uu) == id;
        inv[k] = 1.0 / zt;
      }
      if (!usable) continue;
      const double a = px.x() - u0, b = px.y() - v0;
      const double inv_z =
          (1 - a) * (1 - b) * inv[0] + a * (1 - b) * inv[1] + (1 - a) * b * inv[2] + a * b * inv[3];
      residuals.push_back(std::abs(1.0 / inv_z - X.z()));
    }
  EXPECT_GT(residuals.size(), 0.5 * camera.width * camera.height);
  EXPECT_LT(median(residuals), 0.001) << "median |depth residual| (m)";
}

}  // namespace
}  // namespace fslam::core
