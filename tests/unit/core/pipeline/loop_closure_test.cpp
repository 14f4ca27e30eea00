// Loop closure one keyframe at a time (LoopCloser, LoopThread): a lap of the synthetic room whose
// odometry drifts by a known amount per keyframe, closed where the lap returns to its start.
#include "fslam/core/pipeline/loop_closure.hpp"

#include <atomic>
#include <chrono>
#include <map>
#include <cmath>
#include <thread>

#include <gtest/gtest.h>

#include "fslam/core/pipeline/loop_thread.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::core {
namespace {

constexpr double kDeg = M_PI / 180.0;

// One lap of 120 frames (3 degrees a frame), a keyframe every 6th frame: 20 keyframes, the last
// one a step before the start pose. The odometry of keyframe k is D^k T_gt: each step adds a
// 0.4-degree turn about the world origin and 6 mm, so the lap ends ~30 cm and ~8 degrees off.
class LoopOnSynthRoom : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const SyntheticRoom room = make_room(3);
    SynthOptions options;
    options.frames = 120;
    options.path = SynthPath::loop;
    options.laps = 1;
    const Trajectory trajectory = make_trajectory(room, options);
    const TrackerConfig tracker_config = config();
    const Tracker prepare(tracker_config);
    keyframes_ = new std::vector<LoopKeyframe>();
    truth_ = new std::vector<Eigen::Isometry3d>();
    Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
    step.linear() = Eigen::AngleAxisd(0.4 * kDeg, Eigen::Vector3d(0.2, 1.0, 0.1).normalized()).toRotationMatrix();
    step.translation() = Eigen::Vector3d(0.004, -0.002, 0.004);
    Eigen::Isometry3d drift = Eigen::Isometry3d::Identity();
    for (std::size_t i = 0; i < trajectory.size(); i += 6) {
      const Eigen::Isometry3d& T_gt = trajectory[i].T_world_camera;
      const SynthView view = render_view(room, options.camera, T_gt);
      RgbdFrame frame;
      frame.id = static_cast<std::int64_t>(i);
      frame.colour = view.colour;
      frame.depth = view.depth;
      frame.camera = options.camera;
      LoopKeyframe kf;
      kf.id = kf.position = frame.id;
      kf.T_odom_camera = drift * T_gt;
      PreparedSource prepared;
      std::string why;
      ASSERT_TRUE(prepare.preprocess(frame, nullptr, &prepared, &why)) << why;
      ASSERT_TRUE(describe_frame(frame, tracker_config.relocalisation, tracker_config.preprocess.min_depth,
                                 tracker_config.preprocess.max_depth, &kf.description, &why))
          << why;
      kf.points = std::move(prepared.points);
      keyframes_->push_back(std::move(kf));
      truth_->push_back(T_gt);
      drift = step * drift;
    }
  }
  static void TearDownTestSuite() {
    delete keyframes_;
    delete truth_;
  }
  static TrackerConfig config() { return TrackerConfig{}; }
  static LoopClosureConfig loop_config() {
    LoopClosureConfig c;
    c.min_frame_gap = 60;  // half a lap
    return c;
  }
  // Largest distance between the keyframes' poses and the truth (the first keyframe is exact).
  static double max_error(const std::vector<std::pair<std::int64_t, Eigen::Isometry3d>>& poses) {
    double worst = 0.0;
    for (std::size_t k = 0; k < poses.size(); ++k)
      worst = std::max(worst, ((*truth_)[k].translation() - poses[k].second.translation()).norm());
    return worst;
  }

  static std::vector<LoopKeyframe>* keyframes_;
  static std::vector<Eigen::Isometry3d>* truth_;
};
std::vector<LoopKeyframe>* LoopOnSynthRoom::keyframes_ = nullptr;
std::vector<Eigen::Isometry3d>* LoopOnSynthRoom::truth_ = nullptr;

TEST_F(LoopOnSynthRoom, AVerifiedRevisitPullsTheDriftedLapBackToTheTruth) {
  LoopCloser closer(loop_config(), config());
  std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> odometry;
  std::size_t solves = 0;
  std::string why;
  for (const LoopKeyframe& kf : *keyframes_) {
    odometry.emplace_back(kf.id, kf.T_odom_camera);
    LoopEvent event;
    ASSERT_TRUE(closer.add(kf, &event, &why)) << why;
    if (event.older_id >= 0) {
      // Only keyframes half a lap apart may close, and only near the start.
      EXPECT_GE(kf.position - event.older_id, 60);
      EXPECT_TRUE(event.solved);
      ++solves;
    }
  }
  ASSERT_EQ(closer.size(), keyframes_->size());
  ASSERT_GE(closer.loops().size(), 1u) << closer.rejected() << " candidates refused";
  EXPECT_EQ(solves, closer.loops().size());
  const double before = max_error(odometry), after = max_error(closer.corrected_poses());
  std::printf("%zu loop(s), %zu refused; worst keyframe %.1f mm from the truth before, %.1f mm after\n",
              closer.loops().size(), closer.rejected(), 1000 * before, 1000 * after);
  EXPECT_GT(before, 0.04);       // metres: what the drift made of the lap
  EXPECT_LT(after, 0.3 * before);
  // The newest keyframe's correction maps its odometry onto its corrected pose; a frame between
  // keyframes takes the correction of the keyframe before it; before the first, none.
  const auto poses = closer.corrected_poses();
  const Eigen::Isometry3d C = closer.newest_correction();
  EXPECT_LT(((C * keyframes_->back().T_odom_camera).translation() - poses.back().second.translation()).norm(), 1e-9);
  EXPECT_TRUE(closer.correction(keyframes_->back().id + 3).isApprox(C, 1e-12));
  EXPECT_TRUE(closer.correction(-5).isApprox(Eigen::Isometry3d::Identity(), 1e-12));
  // Keyframes must come in order.
  LoopEvent event;
  EXPECT_FALSE(closer.add((*keyframes_)[0], &event, &why));
  EXPECT_NE(why.find("after keyframe"), std::string::npos) << why;
}

TEST_F(LoopOnSynthRoom, WithoutARevisitNothingMoves) {
  LoopClosureConfig c = loop_config();
  c.min_frame_gap = 1000;  // longer than the lap: no keyframe may close
  LoopCloser closer(c, config());
  std::string why;
  for (const LoopKeyframe& kf : *keyframes_) {
    LoopEvent event;
    ASSERT_TRUE(closer.add(kf, &event, &why)) << why;
    EXPECT_EQ(event.older_id, -1);
  }
  for (std::size_t k = 0; k < keyframes_->size(); ++k)
    EXPECT_TRUE(closer.corrected_poses()[k].second.isApprox((*keyframes_)[k].T_odom_camera, 1e-12));
  EXPECT_TRUE(closer.newest_correction().isApprox(Eigen::Isometry3d::Identity(), 1e-12));
}

// The same lap through the thread: poses published for the mapper, each keyframe once before the
// loop and all of them after each solve; the same corrections as the closer run inline.
TEST_F(LoopOnSynthRoom, TheLoopThreadPublishesMovesAndFinishes) {
  LoopCloser inline_closer(loop_config(), config());
  std::string why;
  for (const LoopKeyframe& kf : *keyframes_) {
    LoopEvent event;
    ASSERT_TRUE(inline_closer.add(kf, &event, &why)) << why;
  }
  std::atomic<int> wakes{0};
  LoopThread thread(loop_config(), config(), [&] { ++wakes; });
  for (const LoopKeyframe& kf : *keyframes_) thread.add(kf);
  thread.finish();
  std::map<std::int64_t, Eigen::Isometry3d> moved;
  for (int i = 0; i < 600 && !thread.done(); ++i) {
    for (const auto& [id, T] : thread.take_moves()) moved[id] = T;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(thread.done()) << "the loop thread did not finish within 30 s";
  for (const auto& [id, T] : thread.take_moves()) moved[id] = T;
  EXPECT_GE(wakes.load(), 1);
  const LoopThreadStats stats = thread.stats();
  EXPECT_EQ(stats.keyframes, keyframes_->size());
  EXPECT_EQ(stats.loops, inline_closer.loops().size());
  EXPECT_EQ(stats.solves, stats.loops);
  EXPECT_TRUE(stats.error.empty()) << stats.error;
  ASSERT_EQ(moved.size(), keyframes_->size());
  for (const auto& [id, T] : inline_closer.corrected_poses()) {
    EXPECT_LT((moved[id].translation() - T.translation()).norm(), 1e-6) << "keyframe " << id;
    EXPECT_LT((thread.map_pose(id, Eigen::Isometry3d::Identity()).translation() - T.translation()).norm(), 1e-6);
  }
  EXPECT_TRUE(thread.map_from_odom().isApprox(inline_closer.newest_correction(), 1e-9));
  EXPECT_TRUE(thread.correction(keyframes_->back().id).isApprox(inline_closer.newest_correction(), 1e-9));
  // Keyframes after finish are not taken.
  thread.add(keyframes_->back());
  EXPECT_EQ(thread.stats().keyframes, keyframes_->size());
}

}  // namespace
}  // namespace fslam::core
