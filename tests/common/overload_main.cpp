// fslam_overload: the overload probe of issue 23 as a bounded test tool. SESSIONS clients each
// open a session (live policy) into their own map and publish RAW frames of a synthetic sequence
// (forward, then backward, so the motion stays continuous) as fast as DDS takes them for
// SECONDS; one more client asks for 640x480 renders of the first map back to back; a probe
// client meanwhile renders a small view every 0.5 s and records how long each answer took. Then
// the probe checks that a new session opens and a render is answered after the load, and the
// tool prints a JSON report on stdout:
//   fslam_overload PREFIX SEQUENCE_DIR SECONDS SESSIONS
// {"sessions": [{"sent": N, "refused": N, "tracked": N, "skipped": N, "errors": N}, ...],
//  "hammer": {"ok": N, "failed": N}, "probe_ms": [...], "probe_failures": N,
//  "after": {"new_session": true|false, "render_ms": X}}
// It never kills anything: the test around it checks the server's memory and SIGTERM.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/client/client.hpp"

namespace {

using Clock = std::chrono::steady_clock;
constexpr int kSettleSeconds = 20;  // every frame sent is answered within this after the load
namespace fc = fslam::client;

struct Frames {
  std::vector<cv::Mat> rgb, depth;
  fc::CameraIntrinsics camera{525.f, 525.f, 319.5f, 239.5f, 640, 480};
};

// The first `n` frames of a `fslam synth` folder (rgb.txt / depth.txt, TUM layout).
bool load_frames(const std::string& dir, std::size_t n, Frames* frames) {
  for (const char* list : {"rgb.txt", "depth.txt"}) {
    std::ifstream in(dir + "/" + list);
    std::string line;
    while (std::getline(in, line) && (list[0] == 'r' ? frames->rgb : frames->depth).size() < n) {
      if (line.empty() || line[0] == '#') continue;
      std::istringstream fields(line);
      double stamp = 0;
      std::string file;
      fields >> stamp >> file;
      cv::Mat image = cv::imread(dir + "/" + file, list[0] == 'r' ? cv::IMREAD_COLOR : cv::IMREAD_UNCHANGED);
      if (image.empty()) return false;
      if (list[0] == 'r') {
        cv::cvtColor(image, image, cv::COLOR_BGR2RGB);
        frames->rgb.push_back(image);
      } else {
        frames->depth.push_back(image);
      }
    }
  }
  return !frames->rgb.empty() && frames->rgb.size() == frames->depth.size();
}

struct SessionCounts {
  std::atomic<std::uint64_t> sent{0}, refused{0}, tracked{0}, skipped{0}, errors{0};
};

void stream(const std::string& prefix, const Frames& frames, int index, double seconds,
            SessionCounts* counts) {
  fc::ClientOptions options;
  options.prefix = prefix;
  fc::Client client(options);
  const std::string session = "overload" + std::to_string(index);
  client.on_pose([&](const fc::PoseUpdate& p) {
    if (p.session != session) return;
    (p.skipped ? counts->skipped : counts->tracked).fetch_add(1);
  });
  client.on_result([&](const fc::ResultUpdate& r) {
    if (r.client != session || r.ok) return;
    if (counts->errors.fetch_add(1) < 2) std::fprintf(stderr, "fslam_overload: %s: %s\n", session.c_str(), r.error.c_str());
  });
  std::string why;
  fc::SessionOptions live;
  live.policy = fc::FramePolicy::live;
  if (!client.open_session(session, session, 10000, &why, live)) {
    std::fprintf(stderr, "overload: %s: %s\n", session.c_str(), why.c_str());
    return;
  }
  const std::size_t n = frames.rgb.size();
  const auto end = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  for (std::uint64_t i = 0; Clock::now() < end; ++i) {
    const std::size_t period = 2 * n - 2, k = i % period, f = k < n ? k : period - k;  // ping-pong
    fc::FrameInput in;
    in.frame_id = i;
    in.timestamp = static_cast<double>(i) / 30.0;
    in.intrinsics = frames.camera;
    in.depth_scale = 5000.0f;
    in.rgb = frames.rgb[f].ptr<std::uint8_t>();
    in.depth = frames.depth[f].ptr<std::uint16_t>();
    in.colour_encoding = fc::PayloadEncoding::raw;
    in.depth_encoding = fc::PayloadEncoding::raw;
    // A write the server's reader does not take in time (DDS flow control) is not sent.
    if (client.push_frame(session, in, &why)) counts->sent.fetch_add(1); else counts->refused.fetch_add(1);
  }
  // Every frame sent is answered: a pose, a skip, or an error result. Wait up to 60 s for that.
  const auto settle = Clock::now() + std::chrono::seconds(kSettleSeconds);
  while (Clock::now() < settle &&
         counts->tracked + counts->skipped + counts->errors < counts->sent) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  if (counts->tracked + counts->skipped + counts->errors < counts->sent) {
    std::fprintf(stderr, "fslam_overload: %s: %llu of %llu frames unanswered after %d s\n", session.c_str(),
                 static_cast<unsigned long long>(counts->sent - counts->tracked - counts->skipped - counts->errors),
                 static_cast<unsigned long long>(counts->sent.load()), kSettleSeconds);
  }
  client.close_session(session, 60000, &why);
}

double render_ms(fc::Client& client, const std::string& map, std::uint32_t w, std::uint32_t h,
                 int timeout_ms, bool* ok) {
  fc::RenderQuery q;
  q.map_name = map;
  q.from_frame = true;
  q.frame_id = 0;
  q.intrinsics = {w * 525.f / 640.f, w * 525.f / 640.f, w / 2.f - 0.5f, h / 2.f - 0.5f, w, h};
  q.channels = fc::kColour;
  fc::RenderOutput out;
  std::string why;
  const auto t0 = Clock::now();
  *ok = client.render(q, &out, timeout_ms, &why);
  static std::atomic<int> reported{0};
  if (!*ok && reported.fetch_add(1) < 3) std::fprintf(stderr, "fslam_overload: render: %s\n", why.c_str());
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: fslam_overload PREFIX SEQUENCE_DIR SECONDS SESSIONS\n");
    return 2;
  }
  const std::string prefix = argv[1];
  const double seconds = std::atof(argv[3]);
  const int sessions = std::atoi(argv[4]);
  Frames frames;
  if (!load_frames(argv[2], 60, &frames)) {
    std::fprintf(stderr, "fslam_overload: cannot read frames from %s\n", argv[2]);
    return 1;
  }
  try {
    std::vector<std::unique_ptr<SessionCounts>> counts;
    std::vector<std::thread> streams;
    for (int i = 0; i < sessions; ++i) {
      counts.push_back(std::make_unique<SessionCounts>());
      streams.emplace_back(stream, prefix, std::cref(frames), i, seconds, counts.back().get());
    }
    fc::ClientOptions options;
    options.prefix = prefix;
    std::atomic<bool> loading{true};
    std::atomic<std::uint64_t> hammer_ok{0}, hammer_failed{0};
    std::thread hammer([&] {
      fc::Client client(options);
      std::this_thread::sleep_for(std::chrono::seconds(2));  // the first map has a frame by then
      while (loading) {
        bool ok = false;
        render_ms(client, "overload0", 640, 480, 2000, &ok);
        (ok ? hammer_ok : hammer_failed).fetch_add(1);
      }
    });
    fc::Client probe(options);
    std::vector<double> probe_ms;
    int probe_failures = 0;
    std::this_thread::sleep_for(std::chrono::seconds(2));
    const auto end = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds - 2));
    while (Clock::now() < end) {
      bool ok = false;
      const double ms = render_ms(probe, "overload0", 160, 120, 10000, &ok);
      if (ok) probe_ms.push_back(ms); else ++probe_failures;
      std::this_thread::sleep_for(std::chrono::milliseconds(500));
    }
    for (auto& t : streams) t.join();
    loading = false;
    hammer.join();
    std::string why;
    const bool new_session = probe.open_session("after", "after_map", 10000, &why);
    if (!new_session) std::fprintf(stderr, "fslam_overload: new session: %s\n", why.c_str());
    probe.close_session("after", 10000, &why);
    bool after_ok = false;
    const double after_ms = render_ms(probe, "overload0", 160, 120, 10000, &after_ok);

    std::printf("{\"sessions\": [");
    for (int i = 0; i < sessions; ++i) {
      std::printf("%s{\"sent\": %llu, \"refused\": %llu, \"tracked\": %llu, \"skipped\": %llu, \"errors\": %llu}",
                  i ? ", " : "", static_cast<unsigned long long>(counts[i]->sent.load()),
                  static_cast<unsigned long long>(counts[i]->refused.load()),
                  static_cast<unsigned long long>(counts[i]->tracked.load()),
                  static_cast<unsigned long long>(counts[i]->skipped.load()),
                  static_cast<unsigned long long>(counts[i]->errors.load()));
    }
    std::printf("], \"hammer\": {\"ok\": %llu, \"failed\": %llu}, \"probe_ms\": [",
                static_cast<unsigned long long>(hammer_ok.load()),
                static_cast<unsigned long long>(hammer_failed.load()));
    for (std::size_t i = 0; i < probe_ms.size(); ++i) std::printf("%s%.1f", i ? ", " : "", probe_ms[i]);
    std::printf("], \"probe_failures\": %d, \"after\": {\"new_session\": %s, \"render_ok\": %s, \"render_ms\": %.1f}}\n",
                probe_failures, new_session ? "true" : "false", after_ok ? "true" : "false", after_ms);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fslam_overload: %s\n", e.what());
    return 1;
  }
  return 0;
}
