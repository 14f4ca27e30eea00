// fslam_dds_probe: a participant that tries to take part in a deployment without going through
// discovery first, for the DDS Security tests (tests/integration/dds_security_test.sh). It
// listens to poses and status on <prefix>, and can open a session and push frames into it
// blindly, then prints what it got:
//   fslam_dds_probe PREFIX LISTEN_S [SESSION PUSH_N]
// Output lines: "client: error ..." (no participant), "open: ok|<why>", "pushed: N|<why>",
// "poses N", "status N".
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include "fslam/client/client.hpp"

int main(int argc, char** argv) {
  if (argc != 3 && argc != 5) {
    std::fprintf(stderr, "usage: fslam_dds_probe PREFIX LISTEN_S [SESSION PUSH_N]\n");
    return 2;
  }
  fslam::client::ClientOptions options;
  options.prefix = argv[1];
  const double listen_s = std::atof(argv[2]);
  try {
    std::atomic<int> poses{0}, status{0};  // outlive the client, whose listener calls the callbacks
    fslam::client::Client client(options);
    client.on_pose([&](const fslam::client::PoseUpdate&) { ++poses; });
    client.on_status([&](const fslam::client::StatusUpdate&) { ++status; });
    const auto start = std::chrono::steady_clock::now();
    if (argc == 5) {
      const std::string session = argv[3];
      std::string why;
      std::printf("open: %s\n", client.open_session(session, session, 3000, &why) ? "ok" : why.c_str());
      std::vector<std::uint8_t> rgb(32 * 24 * 3, 90);
      std::vector<std::uint16_t> depth(32 * 24, 1500);
      fslam::client::FrameInput frame;
      frame.intrinsics = {30.f, 30.f, 15.5f, 11.5f, 32, 24};
      frame.rgb = rgb.data();
      frame.depth = depth.data();
      const int n = std::atoi(argv[4]);
      int pushed = 0;
      for (int i = 0; i < n; ++i) {
        frame.frame_id = static_cast<std::uint64_t>(i);
        if (!client.push_frame(session, frame, &why)) break;
        ++pushed;
      }
      if (pushed == n) std::printf("pushed: %d\n", pushed);
      else std::printf("pushed: %d, then %s\n", pushed, why.c_str());
    }
    std::this_thread::sleep_until(start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                              std::chrono::duration<double>(listen_s)));
    std::printf("poses %d\nstatus %d\n", poses.load(), status.load());
  } catch (const std::exception& e) {
    std::printf("client: error %s\n", e.what());
  }
  return 0;
}
