// fslam_load: bounded load for the overload and soak tests of issue 23 (docs/reliability.md).
// SESSIONS clients each open a session (live policy) into their own map and publish frames of a
// synthetic sequence (forward, then backward, so the motion stays continuous) at --rate Hz (0:
// as fast as DDS takes them) for SECONDS. --queriers clients ask the first map for renders
// (odd ones: promptless segmentations) at --query-rate Hz (0: back to back). A probe client
// renders a small view every 0.5 s and records how long each answer took, and listens to the
// server's status. Afterwards it checks that a new session opens and a render is answered, and
// prints a JSON report on stdout:
//   {"sessions": [{"sent", "refused", "tracked", "skipped", "errors", "latency_ms": [p50, p99]
//                  per 10 s window ...}], "queries": {"ok", "failed"}, "probe_ms": [...],
//    "probe_failures", "status": [[t_s, resident_mib, gaussians of all maps], ... per second],
//    "after": {"new_session", "render_ok", "render_ms"}}
// It never stops the server: the test around it checks memory, latency and SIGTERM.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/client/client.hpp"

namespace {

using Clock = std::chrono::steady_clock;
namespace fc = fslam::client;
constexpr int kSettleSeconds = 30;   // every frame sent is answered within this after the load
constexpr double kWindowSeconds = 10.0;  // latency percentiles per window

struct Options {
  std::string prefix, sequence, encoding = "raw";
  double seconds = 15, rate = 0, query_rate = 0;
  int sessions = 4, queriers = 1;
};

struct Frames {
  std::vector<cv::Mat> rgb, depth;
  fc::CameraIntrinsics camera{525.f, 525.f, 319.5f, 239.5f, 640, 480};
};

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// The first `n` frames of a `fslam synth` folder (rgb.txt / depth.txt, TUM layout).
bool load_frames(const std::string& dir, std::size_t n, Frames* frames) {
  for (const bool colour : {true, false}) {
    std::ifstream in(dir + (colour ? "/rgb.txt" : "/depth.txt"));
    std::vector<cv::Mat>& list = colour ? frames->rgb : frames->depth;
    std::string line;
    while (std::getline(in, line) && list.size() < n) {
      if (line.empty() || line[0] == '#') continue;
      std::istringstream fields(line);
      double stamp = 0;
      std::string file;
      fields >> stamp >> file;
      cv::Mat image = cv::imread(dir + "/" + file, colour ? cv::IMREAD_COLOR : cv::IMREAD_UNCHANGED);
      if (image.empty()) return false;
      if (colour) cv::cvtColor(image, image, cv::COLOR_BGR2RGB);
      list.push_back(image);
    }
  }
  return frames->rgb.size() > 1 && frames->rgb.size() == frames->depth.size();
}

struct SessionCounts {
  std::atomic<std::uint64_t> sent{0}, refused{0}, tracked{0}, skipped{0}, errors{0};
  std::mutex mutex;
  std::map<std::uint64_t, Clock::time_point> sent_at;         // frame id -> push time
  std::vector<std::vector<double>> latency_ms;                // per window: push -> pose
  std::uint64_t answered() const { return tracked + skipped + errors; }
};

void record_answer(SessionCounts* counts, std::uint64_t frame_id, Clock::time_point start) {
  std::lock_guard<std::mutex> lock(counts->mutex);
  const auto it = counts->sent_at.find(frame_id);
  if (it == counts->sent_at.end()) return;
  const auto window = static_cast<std::size_t>(std::chrono::duration<double>(it->second - start).count() / kWindowSeconds);
  if (counts->latency_ms.size() <= window) counts->latency_ms.resize(window + 1);
  counts->latency_ms[window].push_back(std::chrono::duration<double, std::milli>(Clock::now() - it->second).count());
  counts->sent_at.erase(it);
}

// The first frame of session 0 (map load0) that was tracked, -1 before: what queries render from.
// Not frame 0: the live policy may skip it when frame 1 arrives before it is taken.
std::atomic<std::int64_t> first_tracked_load0{-1};

void stream(const Options& o, const Frames& frames, int index, Clock::time_point start, SessionCounts* counts) {
  fc::ClientOptions options;
  options.prefix = o.prefix;
  const std::string session = "load" + std::to_string(index);  // read by the callbacks: outlives the client
  fc::Client client(options);
  client.on_pose([&](const fc::PoseUpdate& p) {
    if (p.session != session) return;
    (p.skipped ? counts->skipped : counts->tracked).fetch_add(1);
    if (!p.skipped) record_answer(counts, p.frame_id, start);
    std::int64_t none = -1;
    if (!p.skipped && index == 0) first_tracked_load0.compare_exchange_strong(none, static_cast<std::int64_t>(p.frame_id));
  });
  client.on_result([&](const fc::ResultUpdate& r) {
    if (r.client != session || r.ok) return;
    if (counts->errors.fetch_add(1) < 2) std::fprintf(stderr, "fslam_load: %s: %s\n", session.c_str(), r.error.c_str());
  });
  std::string why;
  fc::SessionOptions live;
  live.policy = fc::FramePolicy::live;
  if (!client.open_session(session, session, 10000, &why, live)) {
    std::fprintf(stderr, "fslam_load: %s: %s\n", session.c_str(), why.c_str());
    return;
  }
  const std::size_t n = frames.rgb.size(), period = 2 * n - 2;
  const auto end = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o.seconds));
  for (std::uint64_t i = 0; Clock::now() < end; ++i) {
    if (o.rate > 0) {
      std::this_thread::sleep_until(start + std::chrono::duration_cast<Clock::duration>(
                                                std::chrono::duration<double>(static_cast<double>(i) / o.rate)));
    }
    const std::size_t k = i % period, f = k < n ? k : period - k;  // ping-pong
    fc::FrameInput in;
    in.frame_id = i;
    in.timestamp = static_cast<double>(i) / 30.0;
    in.intrinsics = frames.camera;
    in.depth_scale = 5000.0f;
    in.rgb = frames.rgb[f].ptr<std::uint8_t>();
    in.depth = frames.depth[f].ptr<std::uint16_t>();
    const bool raw = o.encoding == "raw";
    in.colour_encoding = raw ? fc::PayloadEncoding::raw : fc::PayloadEncoding::jpeg;
    in.depth_encoding = raw ? fc::PayloadEncoding::raw : fc::PayloadEncoding::png;
    {
      std::lock_guard<std::mutex> lock(counts->mutex);
      counts->sent_at[i] = Clock::now();
    }
    // A write the server's reader does not take in time (DDS flow control) is not sent.
    if (client.push_frame(session, in, &why)) {
      counts->sent.fetch_add(1);
    } else {
      counts->refused.fetch_add(1);
      std::lock_guard<std::mutex> lock(counts->mutex);
      counts->sent_at.erase(i);
    }
  }
  const auto settle = Clock::now() + std::chrono::seconds(kSettleSeconds);
  while (Clock::now() < settle && counts->answered() < counts->sent) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  if (counts->answered() < counts->sent) {
    std::fprintf(stderr, "fslam_load: %s: %llu of %llu frames unanswered %d s after the load\n", session.c_str(),
                 static_cast<unsigned long long>(counts->sent - counts->answered()),
                 static_cast<unsigned long long>(counts->sent.load()), kSettleSeconds);
  }
  client.close_session(session, 60000, &why);
}

// Until map load0 has a tracked frame (at most 30 s; queries then fail and are counted).
void wait_for_first_pose() {
  for (int i = 0; i < 300 && first_tracked_load0.load() < 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

// A render of map load0 from its first tracked frame (or a promptless segmentation), timed.
double query_ms(fc::Client& client, bool segment, std::uint32_t w, std::uint32_t h, int timeout_ms, bool* ok) {
  fc::CameraView view;
  view.from_frame = true;
  view.frame_id = static_cast<std::uint64_t>(std::max<std::int64_t>(0, first_tracked_load0.load()));
  view.intrinsics = {w * 525.f / 640.f, w * 525.f / 640.f, w / 2.f - 0.5f, h / 2.f - 0.5f, w, h};
  std::string why;
  const auto t0 = Clock::now();
  if (segment) {
    fc::SegmentQuery q;
    q.map_name = "load0";
    q.view = view;
    fc::SegmentOutput out;
    *ok = client.segment(q, &out, timeout_ms, &why);
  } else {
    fc::RenderQuery q;
    static_cast<fc::CameraView&>(q) = view;
    q.map_name = "load0";
    q.channels = fc::kColour;
    fc::RenderOutput out;
    *ok = client.render(q, &out, timeout_ms, &why);
  }
  static std::atomic<int> reported{0};
  if (!*ok && reported.fetch_add(1) < 3) std::fprintf(stderr, "fslam_load: query: %s\n", why.c_str());
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

void print_report(const Options& o, std::vector<std::unique_ptr<SessionCounts>>& counts, std::uint64_t queries_ok,
                  std::uint64_t queries_failed, const std::vector<double>& probe_ms, int probe_failures,
                  const std::vector<std::array<double, 3>>& status, bool new_session, bool after_ok,
                  double after_ms) {
  const auto pct = [](std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
  };
  std::printf("{\"sessions\": [");
  for (int i = 0; i < o.sessions; ++i) {
    SessionCounts& c = *counts[i];
    std::printf("%s{\"sent\": %llu, \"refused\": %llu, \"tracked\": %llu, \"skipped\": %llu, \"errors\": %llu, "
                "\"latency_ms\": [", i ? ", " : "", static_cast<unsigned long long>(c.sent.load()),
                static_cast<unsigned long long>(c.refused.load()), static_cast<unsigned long long>(c.tracked.load()),
                static_cast<unsigned long long>(c.skipped.load()), static_cast<unsigned long long>(c.errors.load()));
    std::lock_guard<std::mutex> lock(c.mutex);
    for (std::size_t w = 0; w < c.latency_ms.size(); ++w) {
      std::printf("%s[%.1f, %.1f]", w ? ", " : "", pct(c.latency_ms[w], 0.5), pct(c.latency_ms[w], 0.99));
    }
    std::printf("]}");
  }
  std::printf("], \"queries\": {\"ok\": %llu, \"failed\": %llu}, \"probe_ms\": [",
              static_cast<unsigned long long>(queries_ok), static_cast<unsigned long long>(queries_failed));
  for (std::size_t i = 0; i < probe_ms.size(); ++i) std::printf("%s%.1f", i ? ", " : "", probe_ms[i]);
  std::printf("], \"probe_failures\": %d, \"status\": [", probe_failures);
  for (std::size_t i = 0; i < status.size(); ++i) {
    std::printf("%s[%.1f, %.1f, %.0f]", i ? ", " : "", status[i][0], status[i][1], status[i][2]);
  }
  std::printf("], \"after\": {\"new_session\": %s, \"render_ok\": %s, \"render_ms\": %.1f}}\n",
              new_session ? "true" : "false", after_ok ? "true" : "false", after_ms);
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{"Bounded load against a featureslam server (tests of issue 23)"};
  app.add_option("prefix", o.prefix)->required();
  app.add_option("sequence", o.sequence, "A fslam synth folder")->required();
  app.add_option("seconds", o.seconds)->required();
  app.add_option("sessions", o.sessions)->required();
  app.add_option("--rate", o.rate, "Frames per second per session (0: as fast as DDS takes them)");
  app.add_option("--encoding", o.encoding, "raw, or jpeg (colour; depth PNG)")->check(CLI::IsMember({"raw", "jpeg"}));
  app.add_option("--queriers", o.queriers, "Query clients: even ones render 640x480, odd ones segment");
  app.add_option("--query-rate", o.query_rate, "Queries per second per querier (0: back to back)");
  CLI11_PARSE(app, argc, argv);
  Frames frames;
  if (!load_frames(o.sequence, 60, &frames)) {
    std::fprintf(stderr, "fslam_load: cannot read frames from %s\n", o.sequence.c_str());
    return 1;
  }
  try {
    const auto start = Clock::now();
    std::vector<std::unique_ptr<SessionCounts>> counts;
    std::vector<std::thread> streams;
    for (int i = 0; i < o.sessions; ++i) {
      counts.push_back(std::make_unique<SessionCounts>());
      streams.emplace_back(stream, std::cref(o), std::cref(frames), i, start, counts.back().get());
    }
    fc::ClientOptions options;
    options.prefix = o.prefix;
    std::atomic<bool> loading{true};
    std::atomic<std::uint64_t> queries_ok{0}, queries_failed{0};
    std::vector<std::thread> queriers;
    for (int q = 0; q < o.queriers; ++q) {
      queriers.emplace_back([&, q] {
        fc::Client client(options);
        wait_for_first_pose();
        for (int i = 0; loading; ++i) {
          bool ok = false;
          query_ms(client, q % 2 == 1, 640, 480, 5000, &ok);
          (ok ? queries_ok : queries_failed).fetch_add(1);
          if (o.query_rate > 0) std::this_thread::sleep_for(std::chrono::duration<double>(1.0 / o.query_rate));
        }
      });
    }
    // Declared before the probe: its listener calls the status callback until the probe is
    // destroyed, so what the callback writes must outlive it (ASan: heap-use-after-free of
    // `latest` when it was declared after the probe).
    std::mutex status_mutex;
    std::map<std::string, std::pair<double, double>> latest;  // map -> (resident MiB, Gaussians)
    fc::Client probe(options);
    probe.on_status([&](const fc::StatusUpdate& s) {
      std::lock_guard<std::mutex> lock(status_mutex);
      latest[s.map_name] = {static_cast<double>(s.resident_bytes) / (1024.0 * 1024.0), static_cast<double>(s.map_gaussians)};
    });
    std::vector<double> probe_ms;
    std::vector<std::array<double, 3>> status;
    int probe_failures = 0;
    wait_for_first_pose();
    auto next_status = Clock::now();
    while (seconds_since(start) < o.seconds) {
      bool ok = false;
      const double ms = query_ms(probe, false, 160, 120, 10000, &ok);
      if (ok) probe_ms.push_back(ms); else ++probe_failures;
      if (Clock::now() >= next_status) {
        next_status += std::chrono::seconds(1);
        std::lock_guard<std::mutex> lock(status_mutex);
        double rss = 0, gaussians = 0;
        for (const auto& [map, v] : latest) rss = std::max(rss, v.first), gaussians += v.second;
        status.push_back({seconds_since(start), rss, gaussians});
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(500));
    }
    for (auto& t : streams) t.join();
    loading = false;
    for (auto& t : queriers) t.join();
    std::string why;
    const bool new_session = probe.open_session("after", "after_map", 10000, &why);
    if (!new_session) std::fprintf(stderr, "fslam_load: new session: %s\n", why.c_str());
    probe.close_session("after", 10000, &why);
    bool after_ok = false;
    const double after_ms = query_ms(probe, false, 160, 120, 10000, &after_ok);
    print_report(o, counts, queries_ok, queries_failed, probe_ms, probe_failures, status, new_session, after_ok, after_ms);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fslam_load: %s\n", e.what());
    return 1;
  }
  return 0;
}
