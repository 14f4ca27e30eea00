// `fslam stream`: plays a dataset to a running fslam-server, writes the poses it sends back as a
// TUM trajectory and prints ATE when the dataset has ground truth.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <tuple>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "client_args.hpp"
#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/client/client.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/ate.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/tracking/tracker.hpp"
#include "stream_rosbag2.hpp"

namespace fslam::cli {
namespace {

struct StreamArgs {
  DatasetArgs dataset;
  std::string session = "stream";
  std::string map;
  std::string rate = "max";  // frames per second, or max
  std::string out;
  std::string report;        // JSON summary
  std::string prefix = "fslam";
  std::string policy = "server";  // live, queue, or the server's default
  std::string mode = "map";       // map (a new map), localise or extend (in a served map)
  double views_hz = 0.0;          // localise: renders at the localised poses, per second at most
  std::string views_out;          // folder for them (view_<frame>.png colour, _depth.png 16-bit mm)
  std::uint32_t refine = 0;       // map, extend: refinement steps at close
  DiscoveryArgs discovery;
  int timeout_s = 60;        // for the last poses after the last frame
  int window = 32;           // queue policy: frames sent and not answered yet, at most
  bool preload = false;      // read and encode every frame before the clock starts
  std::string rosbag2, rosbag2_topics;  // a rosbag2 recording instead of --dataset (stream_rosbag2.hpp)
  double rosbag2_tolerance_ms = 20.0;
};

// Frame-to-pose latency as the client sees it (push_frame called -> pose received, one clock)
// and where the server says its share went; the rest is encoding, transport and publishing.
using TimePoint = std::chrono::steady_clock::time_point;
struct SendTimes {
  TimePoint encode_start, written;  // encoding began (or, preloaded, the write), the write returned
  double encoded_ahead_ms = 0.0;    // --preload: the frame's encoding, done before the clock started
};

double ms_between(TimePoint a, TimePoint b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

// Per tracked frame, milliseconds: each stage's samples.
struct Latency {
  std::vector<double> total, encode, decode, queue, track, rest;
};

Latency latency_of(const std::map<std::uint64_t, SendTimes>& sent,
                   const std::map<std::uint64_t, TimePoint>& arrived,
                   const std::map<std::uint64_t, client::PoseUpdate>& poses) {
  Latency l;
  for (const auto& [id, t] : arrived) {
    const auto s = sent.find(id);
    if (s == sent.end()) continue;
    const client::PoseUpdate& p = poses.at(id);
    // A preloaded frame's encoding counts as if done in its slot, as a camera's client would.
    l.total.push_back(s->second.encoded_ahead_ms + ms_between(s->second.encode_start, t));
    l.encode.push_back(s->second.encoded_ahead_ms + ms_between(s->second.encode_start, s->second.written));
    l.decode.push_back(p.decode_ms);
    l.queue.push_back(p.queue_ms);
    l.track.push_back(p.track_ms);
    l.rest.push_back(ms_between(s->second.written, t) - p.decode_ms - p.queue_ms - p.track_ms);
  }
  return l;
}

// The stages in print order: name in the report, label, samples.
std::vector<std::tuple<const char*, const char*, const std::vector<double>*>> stages(const Latency& l) {
  return {{"frame_to_pose", "frame -> pose (client clock)", &l.total},
          {"client_encode_write", "  client: encode + write", &l.encode},
          {"server_decode", "  server: decode", &l.decode},
          {"server_queue", "  server: queue", &l.queue},
          {"server_track", "  server: track", &l.track},
          {"transport_publish", "  DDS transport + publish (rest)", &l.rest}};
}

void print_latency(const Latency& l) {
  if (l.total.empty()) return;
  std::printf("latency per tracked frame, ms (%zu frames)  p50      p99\n", l.total.size());
  for (const auto& [key, label, v] : stages(l)) {
    std::printf("  %-34s %8.2f %8.2f\n", label, percentile(*v, 0.5), percentile(*v, 0.99));
  }
}

nlohmann::json latency_json(const Latency& l) {
  nlohmann::json j;
  for (const auto& [key, label, v] : stages(l)) {
    j[key] = {{"p50_ms", v->empty() ? 0.0 : percentile(*v, 0.5)},
              {"p99_ms", v->empty() ? 0.0 : percentile(*v, 0.99)}};
  }
  return j;
}

// The wire frame of a dataset frame (`depth_raw`: its depth in sensor units, kept alive by the caller).
client::FrameInput frame_input(const core::RgbdFrame& frame, double depth_scale, const cv::Mat& depth_raw) {
  client::FrameInput input;
  input.frame_id = static_cast<std::uint64_t>(std::max<std::int64_t>(0, frame.id));  // the dataset's number
  input.timestamp = frame.timestamp;
  input.intrinsics = {static_cast<float>(frame.camera.fx), static_cast<float>(frame.camera.fy),
                      static_cast<float>(frame.camera.cx), static_cast<float>(frame.camera.cy),
                      static_cast<std::uint32_t>(frame.camera.width),
                      static_cast<std::uint32_t>(frame.camera.height)};
  input.depth_scale = static_cast<float>(depth_scale);
  input.rgb = frame.colour.ptr<std::uint8_t>();
  input.depth = depth_raw.ptr<std::uint16_t>();
  if (frame.T_world_camera_gt) {
    input.has_gt_pose = true;
    const Eigen::Quaterniond q(frame.T_world_camera_gt->rotation());
    for (int k = 0; k < 3; ++k) input.gt_translation[k] = frame.T_world_camera_gt->translation()[k];
    input.gt_rotation[0] = q.x();
    input.gt_rotation[1] = q.y();
    input.gt_rotation[2] = q.z();
    input.gt_rotation[3] = q.w();
  }
  return input;
}

// What the poses that came back say, after the stream.
struct StreamOutcome {
  core::Trajectory trajectory;    // tracked frames (localise, extend: lost ones left out)
  std::size_t skipped = 0, errors = 0, missing = 0;
  // localise, extend: frames lost (not in trajectory), with the server's reason
  std::vector<std::pair<std::uint64_t, std::string>> lost;
  std::size_t views = 0;          // localise --views: renders received at localised poses
  double elapsed = 0.0;  // seconds from the first frame to the last pose
  std::string close_error;  // empty when the server confirmed the close
  double close_s = 0.0;     // seconds from the close request to its answer (or to giving up)
};

// Prints the outcome, writes --out and --report; the exit code.
int report_stream(const StreamArgs& args, const core::Dataset& dataset, const StreamOutcome& o,
                  const Latency& latency, const std::vector<std::uint64_t>& tracked_ids) {
  std::string why;
  const std::size_t n = dataset.size();
  std::printf("frames sent %zu: tracked %zu, skipped %zu%s, errors %zu, no answer %zu; %.1f s to "
              "the last pose (%.1f tracked frames/s)\n",
              n, o.trajectory.size(), o.skipped,
              o.skipped > 0 ? " (live policy: a newer frame came while the tracker was busy)" : "",
              o.errors, o.missing, o.elapsed,
              static_cast<double>(o.trajectory.size()) / std::max(o.elapsed, 1e-9));
  print_latency(latency);
  if (o.close_error.empty()) std::printf("session closed in %.1f s (the server maps what it accepted first)\n", o.close_s);
  if (!args.out.empty()) {
    if (!core::write_tum_trajectory(args.out, o.trajectory, &why)) return fail(why);
    std::printf("wrote %s\n", args.out.c_str());
  }
  nlohmann::json report = {{"frames_sent", n},          {"tracked", o.trajectory.size()},
                           {"skipped", o.skipped},      {"errors", o.errors},
                           {"no_answer", o.missing},    {"seconds_to_last_pose", o.elapsed},
                           {"policy", args.policy},     {"rate", args.rate},
                           {"mode", args.mode},         {"closed", o.close_error.empty()},
                           {"preloaded", args.preload},
                           {"close_s", o.close_s},      {"latency", latency_json(latency)}};
  report["tracked_frame_ids"] = tracked_ids;
  if (dataset.has_ground_truth() && !o.trajectory.empty()) {
    core::AteResult ate;
    if (core::compute_ate(dataset.ground_truth(), o.trajectory, core::AteConfig{}, &ate, &why)) {
      std::printf("ATE RMSE %.4f m (mean %.4f) over %zu tracked frames, SE(3)\n", ate.rmse, ate.mean,
                  ate.pairs);
      report["ate"] = {{"rmse_m", ate.rmse}, {"mean_m", ate.mean}, {"pairs", ate.pairs}};
    }
  }
  if (args.mode != "map") {
    // The map's world is the ground truth's when it was streamed with it (the first frame's
    // pose), so a localised pose is compared with no alignment.
    report["lost"] = o.lost.size();
    nlohmann::json lost_frames = nlohmann::json::array();
    for (const auto& [id, note] : o.lost) {
      lost_frames.push_back({{"frame_id", id}, {"note", note}});
      std::fprintf(stderr, "frame %llu lost: %s\n", static_cast<unsigned long long>(id), note.c_str());
    }
    report["lost_frames"] = lost_frames;
    report["views"] = o.views;
    std::printf("localised %zu of %zu frames in the map (%zu lost)", o.trajectory.size(), n, o.lost.size());
    if (args.views_hz > 0) std::printf("; %zu views received", o.views);
    std::printf("\n");
    if (dataset.has_ground_truth()) {
      const core::Trajectory truth = dataset.ground_truth();
      std::vector<double> errors_m;
      for (const core::StampedPose& p : o.trajectory) {
        const core::StampedPose* gt = core::nearest_pose(truth, p.timestamp);
        if (gt != nullptr) errors_m.push_back((p.T_world_camera.translation() - gt->T_world_camera.translation()).norm());
      }
      std::sort(errors_m.begin(), errors_m.end());
      if (!errors_m.empty()) {
        const double median = errors_m[errors_m.size() / 2], worst = errors_m.back();
        const auto within = static_cast<std::size_t>(
            std::lower_bound(errors_m.begin(), errors_m.end(), 0.05) - errors_m.begin());
        std::printf("position error against ground truth, no alignment: median %.4f m, max %.4f m, "
                    "%zu of %zu within 5 cm\n", median, worst, within, errors_m.size());
        report["localisation"] = {{"median_error_m", median}, {"max_error_m", worst},
                                  {"within_5cm", within}, {"compared", errors_m.size()}};
      }
    }
  }
  if (!args.report.empty()) {
    std::ofstream(args.report) << report.dump(2) << "\n";
    std::printf("wrote %s\n", args.report.c_str());
  }
  // Skips are the live policy working; errors and frames with no outcome are failures.
  if (o.errors > 0) return fail(std::to_string(o.errors) + " frame(s) got an error from the server");
  if (o.missing > 0) return fail(std::to_string(o.missing) + " of " + std::to_string(n) + " frames got no answer");
  // The poses above are complete, but the map is not known to be: the server may still be
  // mapping (or refining) what it accepted. It finishes and keeps the map; a caller that reads,
  // saves or compares the map next must not take this run as done.
  if (!o.close_error.empty())
    return fail("close" + (args.refine > 0 ? " with --refine " + std::to_string(args.refine) : std::string()) +
                ": " + o.close_error + " (the map may still be being mapped; raise --timeout)");
  return 0;
}

// --rate as frames per second, 0 for 'max'; -1 when it is neither.
double parse_rate(const std::string& text) {
  if (text == "max") return 0.0;
  try {
    const double rate = std::stod(text);
    return rate > 0 ? rate : -1.0;
  } catch (const std::exception&) {
    return -1.0;
  }
}

// --policy: live, queue, or server (the server's server.frame_policy); false for anything else.
bool policy_of(const std::string& policy, client::SessionOptions* options) {
  if (policy == "live") options->policy = client::FramePolicy::live;
  else if (policy == "queue") options->policy = client::FramePolicy::queue;
  else if (policy != "server") return false;
  return true;
}

// --mode: map, localise or extend; false for anything else.
bool mode_of(const std::string& mode, client::SessionOptions* options) {
  if (mode == "localise") options->mode = client::SessionMode::localise;
  else if (mode == "extend") options->mode = client::SessionMode::extend;
  else if (mode != "map") return false;
  return true;
}

// SIGUSR1 pauses sending frames and the next one resumes it (odd count: paused). The client stays
// connected while paused, unlike a stopped process, whose participant lease runs out.
volatile std::sig_atomic_t pause_toggles = 0;
extern "C" void toggle_pause(int) { pause_toggles = pause_toggles + 1; }
bool pause_requested() { return pause_toggles % 2 == 1; }

int run_stream(const StreamArgs& args) {
  core::DatasetOptions options;
  std::string why;
  if (args.rosbag2.empty() == args.dataset.path.empty()) return fail("give one of --dataset and --rosbag2");
  auto dataset = args.rosbag2.empty() ? open_dataset(args.dataset, &options, &why)
                                      : open_rosbag2_dataset(args.rosbag2, args.rosbag2_topics,
                                                             args.rosbag2_tolerance_ms, &why);
  if (!dataset) return fail(why);
  const double rate = parse_rate(args.rate);
  if (rate < 0) return fail("--rate must be a positive number of frames per second or 'max'");
  client::SessionOptions session_options;
  if (!policy_of(args.policy, &session_options)) return fail("--policy must be live, queue or server");
  if (!mode_of(args.mode, &session_options)) return fail("--mode must be map, localise or extend");
  const bool localise = session_options.mode == client::SessionMode::localise;
  const bool new_map = session_options.mode == client::SessionMode::map;
  if (args.views_hz != 0.0 && !(localise && args.views_hz > 0.0 && std::isfinite(args.views_hz)))
    return fail("--views needs --mode localise and a positive number of views per second");
  if (!args.views_out.empty() && args.views_hz == 0.0) return fail("--views-out needs --views");
  if (args.refine > 0 && localise) return fail("--refine needs a session that maps (--mode map or extend)");
  session_options.view_rate_hz = args.views_hz;
  if (!args.views_out.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(args.views_out, ec);
    if (ec) return fail("--views-out " + args.views_out + ": " + ec.message());
  }
  // The instance that serves the map, or creates it (the map directory, docs/deployment.md).
  const std::string map = args.map.empty() ? args.session : args.map;
  client::ClientOptions copts;
  if (!locate_service(args.prefix, args.discovery, map, new_map, 10000, &copts, &why)) return fail(why);
  // The state the callbacks write is declared before the client: its listener thread calls
  // them until the client is destroyed (client.hpp).
  std::mutex mutex;
  std::map<std::uint64_t, client::PoseUpdate> poses;
  std::map<std::uint64_t, SendTimes> sent;
  std::map<std::uint64_t, TimePoint> arrived;
  std::map<std::uint64_t, std::string> skipped;  // frame -> why (live policy)
  std::atomic<std::size_t> errors{0}, views{0};
  client::Client client(copts);
  client.on_view([&](const client::ViewUpdate& v) {
    if (v.session != args.session) return;
    ++views;
    if (args.views_out.empty()) return;
    if (!v.error.empty()) return (void)std::fprintf(stderr, "\nview of frame %llu: %s\n",
                                                    static_cast<unsigned long long>(v.frame_id), v.error.c_str());
    for (const client::RenderedImage& image : v.render.images) {
      const int h = static_cast<int>(image.height), w = static_cast<int>(image.width);
      const std::string stem = args.views_out + "/view_" + std::to_string(v.frame_id);
      std::string write_why;
      bool ok = true;
      if (image.channel == client::kColour)
        ok = core::write_image(stem + ".png", cv::Mat(h, w, CV_8UC3, const_cast<std::uint8_t*>(image.pixels.data())), &write_why);
      else if (image.channel == client::kDepth)
        ok = core::write_image(stem + "_depth.png", cv::Mat(h, w, CV_16UC1, const_cast<std::uint8_t*>(image.pixels.data())), &write_why);
      if (!ok) std::fprintf(stderr, "\n%s\n", write_why.c_str());
    }
  });
  client.on_pose([&](const client::PoseUpdate& p) {
    if (p.session != args.session) return;
    const auto now = std::chrono::steady_clock::now();
    std::lock_guard<std::mutex> lock(mutex);
    if (p.skipped) {
      skipped[p.frame_id] = p.note;
      return;
    }
    poses[p.frame_id] = p;
    arrived[p.frame_id] = now;
  });
  client.on_result([&](const client::ResultUpdate& r) {
    if (!r.ok) ++errors, std::fprintf(stderr, "\nserver: %s\n", r.error.c_str());
  });
  const std::size_t n = dataset->size();
  // Frame i read from the dataset and encoded for the wire; `started`: when its encoding began
  // (the reading before it is the replay's, not a camera client's).
  auto encode_frame = [&](std::size_t i, client::EncodedFrame* out, TimePoint* started, std::string* err) {
    core::RgbdFrame frame;
    if (!dataset->load(i, &frame, err)) return false;
    cv::Mat depth_raw;
    frame.depth.convertTo(depth_raw, CV_16UC1, dataset->depth_scale());
    const client::FrameInput input = frame_input(frame, dataset->depth_scale(), depth_raw);
    *started = std::chrono::steady_clock::now();
    return client::Client::encode_frame(input, out, err);
  };
  // --preload: the whole sequence read and encoded before the session opens, so that playing it
  // takes no CPU from a server on the same machine (a camera hands its frames over; the reading
  // and decoding of a recorded dataset is the replay's cost, not the client's).
  std::vector<client::EncodedFrame> preloaded;
  std::vector<double> preload_ms;
  if (args.preload) {
    const auto t0 = std::chrono::steady_clock::now();
    Progress progress("preload", n);
    preloaded.resize(n);
    preload_ms.resize(n);
    std::size_t bytes = 0;
    for (std::size_t i = 0; i < n; ++i) {
      TimePoint started;
      if (!encode_frame(i, &preloaded[i], &started, &why)) return fail(why);
      preload_ms[i] = ms_between(started, std::chrono::steady_clock::now());
      bytes += preloaded[i].colour.size() + preloaded[i].depth.size();
      progress.update(i + 1);
    }
    progress.finish();
    std::fprintf(stderr, "preloaded %zu frames: %.1f MB encoded in %.1f s; encoding %.1f ms per frame "
                 "(median), counted in the latency below\n", n, static_cast<double>(bytes) / 1e6,
                 ms_between(t0, std::chrono::steady_clock::now()) / 1e3,
                 percentile(preload_ms, 0.5));
  }
  if (!client.open_session(args.session, map, 10000, &why, session_options)) {
    return fail(why);
  }
  std::fprintf(stderr, "streaming %zu frames of %s to session '%s' at %s\n", n,
               dataset->root().c_str(), args.session.c_str(),
               rate > 0 ? (args.rate + " fps").c_str() : "full speed");
  Progress progress("stream", n);
  std::signal(SIGUSR1, toggle_pause);
  const auto start = std::chrono::steady_clock::now();
  std::chrono::steady_clock::duration paused_for{};  // the --rate schedule moves on by the pauses
  // Queue sessions hold a bounded number of frames (server.queue_capacity, 64 by default): a
  // client faster than tracking waits for answers rather than overrunning it (frames the
  // server drops are errors). Live sessions skip instead, so they need no window.
  const bool windowed = args.policy == "queue" && args.window > 0;
  auto answered = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return poses.size() + skipped.size() + errors.load();
  };
  for (std::size_t i = 0; i < n; ++i) {
    if (windowed) {
      const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(args.timeout_s);
      while (i >= answered() + static_cast<std::size_t>(args.window)) {
        if (std::chrono::steady_clock::now() > give_up) {
          return fail("no answer for " + std::to_string(i - answered()) + " frames within " +
                      std::to_string(args.timeout_s) + " s");
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
      }
    }
    if (pause_requested()) {
      const auto paused_at = std::chrono::steady_clock::now();
      std::fprintf(stderr, "\n[stream] paused before frame %zu of %zu (SIGUSR1 resumes)\n", i + 1, n);
      while (pause_requested()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
      paused_for += std::chrono::steady_clock::now() - paused_at;
      std::fprintf(stderr, "[stream] resumed\n");
    }
    if (rate > 0) {
      std::this_thread::sleep_until(start + paused_for +
                                    std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                        std::chrono::duration<double>(static_cast<double>(i) / rate)));
    }
    client::EncodedFrame encoded_now;
    TimePoint encode_start = std::chrono::steady_clock::now();  // preloaded: the write's start
    if (!args.preload && !encode_frame(i, &encoded_now, &encode_start, &why)) return fail(why);
    const client::EncodedFrame& encoded = args.preload ? preloaded[i] : encoded_now;
    {
      std::lock_guard<std::mutex> lock(mutex);  // a pose may arrive before push returns
      sent[encoded.frame_id] = {encode_start, {}, args.preload ? preload_ms[i] : 0.0};
    }
    // Flow control: a server slow for a while slows the playback (up to --timeout), no more.
    if (!client.push_encoded(args.session, encoded, &why, args.timeout_s * 1000)) return fail(why);
    {
      std::lock_guard<std::mutex> lock(mutex);
      sent[encoded.frame_id].written = std::chrono::steady_clock::now();
    }
    progress.update(i + 1);
  }
  progress.finish();
  // Wait for every frame's outcome: a pose, a skip, or an error saying why not.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(args.timeout_s);
  while (answered() < n && std::chrono::steady_clock::now() <= deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  auto last_pose = start;
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (const auto& [id, t] : arrived) last_pose = std::max(last_pose, t);
  }
  // Closing waits for the server to finish mapping what it accepted (and to refine, with --refine).
  if (args.refine > 0) std::fprintf(stderr, "closing: the server maps what is left, then refines %u steps\n", args.refine);
  StreamOutcome outcome;
  const auto close_start = std::chrono::steady_clock::now();
  if (!client.close_session(args.session, std::max(30, args.timeout_s) * 1000, &why, args.refine))
    outcome.close_error = why;
  outcome.close_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - close_start).count();
  std::vector<std::uint64_t> tracked_ids;
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (const auto& [id, p] : poses) {
      if (!new_map && p.state == static_cast<int>(core::TrackingState::lost)) {
        outcome.lost.emplace_back(id, p.note);
        continue;
      }
      core::StampedPose sp;
      sp.timestamp = p.timestamp;
      const Eigen::Quaterniond q(p.rotation[3], p.rotation[0], p.rotation[1], p.rotation[2]);
      sp.T_world_camera.linear() = q.normalized().toRotationMatrix();
      sp.T_world_camera.translation() = Eigen::Vector3d(p.translation[0], p.translation[1], p.translation[2]);
      outcome.trajectory.push_back(sp);
      tracked_ids.push_back(id);
    }
    outcome.skipped = skipped.size();
  }
  outcome.elapsed = std::chrono::duration<double>(last_pose - start).count();
  outcome.errors = errors.load();
  outcome.views = views.load();
  outcome.missing = n - std::min(n, outcome.trajectory.size() + outcome.lost.size() + outcome.skipped + outcome.errors);
  return report_stream(args, *dataset, outcome, latency_of(sent, arrived, poses), tracked_ids);
}

}  // namespace

void add_stream_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "stream", "Play a dataset to a running fslam-server over DDS; write the poses it returns "
                "and print ATE when the dataset has ground truth. SIGUSR1 pauses sending and "
                "resumes it (a pause longer than the server's session lease closes the session)");
  auto args = std::make_shared<StreamArgs>();
  add_dataset_options(app, &args->dataset, false);
  app->add_option("--rosbag2", args->rosbag2,
                  "Play a rosbag2 recording (sqlite3 storage) of a ROS 2 RGB-D camera instead of --dataset");
  app->add_option("--rosbag2-topics", args->rosbag2_topics,
                  "colour,depth,camera_info topics of the recording (default: chosen by type)");
  app->add_option("--rosbag2-tolerance", args->rosbag2_tolerance_ms,
                  "Milliseconds within which colour and depth header stamps pair")
      ->capture_default_str();
  app->add_option("--session", args->session, "Session name")->capture_default_str();
  app->add_option("--map", args->map,
                  "Map to create (default: the session name; it must not exist on the server yet), or "
                  "with --mode localise or extend the served map to localise in or extend");
  app->add_option("--mode", args->mode,
                  "map: build a new map; localise: track against a served map without changing "
                  "it (the first frame, and any lost one, relocalises against its keyframes); "
                  "extend: relocalise in a served map, then keep mapping into it")
      ->capture_default_str();
  app->add_option("--views", args->views_hz,
                  "With --mode localise: the server renders the map at each localised pose, at most "
                  "this many per second, and pushes it back (colour and depth; the AR overlay)");
  app->add_option("--views-out", args->views_out,
                  "Folder for the views: view_<frame>.png (colour) and view_<frame>_depth.png (16-bit, mm)");
  app->add_option("--refine", args->refine,
                  "Map and extend sessions: at close, the server refines the map this many steps "
                  "(post-trajectory refinement) before it answers; raise --timeout for many");
  app->add_option("--rate", args->rate, "Frames per second, or max")->capture_default_str();
  app->add_option("--out", args->out, "Trajectory of the received poses (TUM)");
  app->add_option("--report", args->report,
                  "JSON summary: frames sent / tracked / skipped / errors, ATE, latency by stage");
  app->add_option("--prefix", args->prefix, "Topic prefix of the deployment")->capture_default_str();
  add_discovery_options(app, &args->discovery);
  app->add_option("--policy", args->policy,
                  "Frame policy of the session: live (track the newest frame, skip older ones "
                  "waiting), queue (track every frame), or the server's default")
      ->capture_default_str();
  app->add_option("--timeout", args->timeout_s,
                  "Seconds to wait for the last poses, and for the server to take a frame (flow control); "
                  "the close waits at least 30 s (the server maps what is left first)")
      ->capture_default_str();
  app->add_flag("--preload", args->preload,
               "Read and encode every frame before the session opens (held in memory, encoded: "
               "about 0.2-0.3 MB per 640x480 frame), so that playing at --rate takes no CPU from a "
               "server on this machine; each frame's encoding time still counts in its latency");
  app->add_option("--window", args->window,
                  "With --policy queue: at most this many frames sent and not answered yet (the "
                  "client waits; keep it under the server's queue_capacity); 0: no limit")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  commands->push_back({app, [args] { return run_stream(*args); }});
}

}  // namespace fslam::cli
