// ROS 2 input latency probe (opt-in benchmark, tests/benchmarks/ros2_latency_bench.sh): stands in
// for a camera driver, publishing a sequence as sensor_msgs Image (rgb8 + 32FC1) + CameraInfo at a
// fixed rate, and times each frame from its publication to the PoseStamped that carries its stamp.
#include <chrono>
#include <cstdio>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "fslam/client/ros2_messages.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/percentile.hpp"
#include "ros2/geometry_msgs.h"
#include "ros2/sensor_msgs.h"

namespace ros2 = fslam::client::ros2;
using Clock = std::chrono::steady_clock;

int main(int argc, char** argv) {
  CLI::App app("ROS 2 input latency: image publication -> PoseStamped");
  std::string dataset_path, ns = "/camera";
  std::string pose_topic = "/fslam/pose";
  double rate = 10;
  int settle_s = 10;
  app.add_option("--dataset", dataset_path, "Sequence to publish")->required();
  app.add_option("--namespace", ns, "Topics <ns>/color/image_raw, <ns>/depth/image_raw, <ns>/color/camera_info");
  app.add_option("--pose-topic", pose_topic, "The server's ros2.pose_topic");
  app.add_option("--rate", rate, "Frames per second");
  CLI11_PARSE(app, argc, argv);
  std::string why;
  auto dataset = fslam::core::open_dataset(dataset_path, fslam::core::DatasetOptions{}, &why);
  if (!dataset) return std::fprintf(stderr, "%s\n", why.c_str()), 1;
  const dds_entity_t p = dds_create_participant(DDS_DOMAIN_DEFAULT, nullptr, nullptr);
  auto endpoint = [&](const dds_topic_descriptor_t* d, const std::string& name, bool writer) {
    const dds_entity_t t = dds_create_topic(p, d, ros2::dds_topic(name).c_str(), nullptr, nullptr);
    dds_qos_t* q = ros2::make_qos(true, writer ? 4 : 1000, writer);
    const dds_entity_t e = writer ? dds_create_writer(p, t, q, nullptr) : dds_create_reader(p, t, q, nullptr);
    dds_delete_qos(q);
    return e;
  };
  const dds_entity_t colour = endpoint(&sensor_msgs_msg_dds__Image__desc, ns + "/color/image_raw", true);
  const dds_entity_t depth = endpoint(&sensor_msgs_msg_dds__Image__desc, ns + "/depth/image_raw", true);
  const dds_entity_t info = endpoint(&sensor_msgs_msg_dds__CameraInfo__desc, ns + "/color/camera_info", true);
  const dds_entity_t poses = endpoint(&geometry_msgs_msg_dds__PoseStamped__desc, pose_topic, false);
  for (int i = 0; i < 200; ++i) {
    dds_subscription_matched_status_t s{};
    dds_get_subscription_matched_status(poses, &s);
    dds_publication_matched_status_t c{};
    dds_get_publication_matched_status(depth, &c);
    if (s.current_count > 0 && c.current_count > 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  std::map<std::int64_t, Clock::time_point> sent;  // stamp (ns) -> publication
  std::vector<double> latency_ms;
  auto take = [&] {
    void* samples[16] = {nullptr};
    dds_sample_info_t si[16];
    for (int n; (n = dds_take(poses, samples, si, 16, 16)) > 0; dds_return_loan(poses, samples, n)) {
      const auto now = Clock::now();
      for (int i = 0; i < n; ++i) {
        if (!si[i].valid_data) continue;
        const auto& h = static_cast<geometry_msgs_msg_dds__PoseStamped_*>(samples[i])->header.stamp;
        const auto it = sent.find(std::int64_t{h.sec} * 1000000000 + h.nanosec);
        if (it != sent.end()) latency_ms.push_back(std::chrono::duration<double, std::milli>(now - it->second).count());
      }
    }
  };
  std::string frame = "camera_color_optical_frame", rgb8 = "rgb8", f32 = "32FC1", model = "plumb_bob";
  const auto start = Clock::now();
  for (std::size_t i = 0; i < dataset->size(); ++i) {
    // Poses are taken while waiting for the next frame's time, so that each is timed on arrival.
    const auto due = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(i / rate));
    while (Clock::now() < due) {
      take();
      std::this_thread::sleep_for(std::chrono::microseconds(500));
    }
    fslam::core::RgbdFrame f;
    if (!dataset->load(i, &f, &why)) return std::fprintf(stderr, "%s\n", why.c_str()), 1;
    const ros2::Stamp stamp = ros2::Stamp::from_seconds(100.0 + static_cast<double>(i) / rate);
    const auto w = static_cast<std::uint32_t>(f.camera.width), h = static_cast<std::uint32_t>(f.camera.height);
    sensor_msgs_msg_dds__Image_ c{}, d{};
    for (auto* m : {&c, &d}) {
      m->header.stamp = {stamp.sec, stamp.nanosec};
      m->header.frame_id = frame.data();
      m->width = w;
      m->height = h;
    }
    c.encoding = rgb8.data();
    c.step = 3 * w;
    c.data = {3 * w * h, 3 * w * h, f.colour.data, false};
    d.encoding = f32.data();
    d.step = 4 * w;
    d.data = {4 * w * h, 4 * w * h, f.depth.data, false};
    sensor_msgs_msg_dds__CameraInfo_ k{};
    k.header = c.header;
    k.width = w;
    k.height = h;
    k.distortion_model = model.data();
    const double K[9] = {f.camera.fx, 0, f.camera.cx, 0, f.camera.fy, f.camera.cy, 0, 0, 1};
    for (int j = 0; j < 9; ++j) k.k[j] = K[j];
    sent[std::int64_t{stamp.sec} * 1000000000 + stamp.nanosec] = Clock::now();
    dds_write(info, &k);
    dds_write(colour, &c);
    dds_write(depth, &d);
    take();
  }
  for (int i = 0; i < settle_s * 2000 && latency_ms.size() < sent.size(); ++i) {
    std::this_thread::sleep_for(std::chrono::microseconds(500));
    take();
  }
  std::printf("ros2 input: %zu frames published at %g Hz, %zu poses (the rest skipped by the live policy)\n",
              sent.size(), rate, latency_ms.size());
  if (!latency_ms.empty()) {
    std::printf("ros2 image -> PoseStamped, ms: p50 %.2f p99 %.2f\n", fslam::core::percentile(latency_ms, 0.5),
                fslam::core::percentile(latency_ms, 0.99));
  }
  dds_delete(p);
  return latency_ms.empty() ? 1 : 0;
}
