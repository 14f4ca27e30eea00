// The service end to end on the loopback profile: the real fslam-server, `fslam stream` and the
// client library, with a topic prefix of this test's own.
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "cli_runner.hpp"
#include "fslam/client/client.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;

double ate_from(const std::string& out) {
  const auto at = out.find("ATE RMSE ");
  return at == std::string::npos ? -1.0 : std::stod(out.substr(at + 9));
}

class Service : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    test::use_loopback_dds();  // inherited by every process started below
    dir_ = test::fresh_temp_dir("service").string();
    prefix_ = "svc" + std::to_string(getpid());
    std::string out, err;
    synth_status_ = run_command(fslam_bin() + " synth --out " + dir_ + "/seq --frames 100 --seed 5",
                                &out, &err);
    const std::string server = (test::bin_dir() / "fslam-server").string();
    std::system((server + " --prefix " + prefix_ + " >" + dir_ + "/server.log 2>&1 & echo $! >" +
                 dir_ + "/server.pid")
                    .c_str());
    std::ifstream(dir_ + "/server.pid") >> server_pid_;
  }
  static void TearDownTestSuite() {
    if (server_pid_ > 0) {
      kill(server_pid_, SIGTERM);
      for (int i = 0; i < 300 && kill(server_pid_, 0) == 0; ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
  void SetUp() override {
    ASSERT_EQ(synth_status_, 0);
    ASSERT_GT(server_pid_, 0) << "fslam-server did not start";
  }
  static std::string dir_, prefix_;
  static int synth_status_;
  static pid_t server_pid_;
};
std::string Service::dir_, Service::prefix_;
int Service::synth_status_ = -1;
pid_t Service::server_pid_ = -1;

// One client streams 100 frames and receives 100 poses, as accurate as the in-process tracker.
TEST_F(Service, StreamReceivesEveryPoseWithInProcessAccuracy) {
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " stream --dataset " + dir_ + "/seq --prefix " + prefix_ +
                            " --session a --out " + dir_ + "/streamed.txt",
                        &out, &err),
            0)
      << out << err;
  EXPECT_NE(out.find("poses received 100"), std::string::npos) << out;
  const double streamed = ate_from(out);
  ASSERT_EQ(run_command(fslam_bin() + " track --dataset " + dir_ + "/seq --out " + dir_ + "/t.txt",
                        &out, &err),
            0)
      << out << err;
  const double in_process = ate_from(out);
  ASSERT_GT(streamed, 0.0);
  ASSERT_GT(in_process, 0.0);
  EXPECT_LT(streamed, 1.5 * in_process + 1e-4) << "streamed " << streamed << " m, in process "
                                               << in_process << " m";
}

// The server states every setting it runs with before it serves.
TEST_F(Service, ServerPrintsItsEffectiveConfigurationFirst) {
  std::string log;
  for (int i = 0; i < 300 && log.find("serving on") == std::string::npos; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    std::stringstream text;
    text << std::ifstream(dir_ + "/server.log").rdbuf();
    log = text.str();
  }
  const auto config = log.find("effective configuration:\n");
  ASSERT_NE(config, std::string::npos) << log;
  EXPECT_NE(log.find("\nserver:\n  prefix: " + prefix_ + "\n"), std::string::npos) << log;
  EXPECT_NE(log.find("\n    kernel: huber\n"), std::string::npos) << log;
  EXPECT_LT(config, log.find("serving on")) << log;
}

// Bad input gets an error result and the server keeps serving.
TEST_F(Service, MalformedFramesGetErrorResults) {
  client::ClientOptions options;
  options.prefix = prefix_;
  client::Client c(options);
  std::mutex mutex;
  std::vector<std::string> errors;
  client::StatusUpdate status_b;
  c.on_result([&](const client::ResultUpdate& r) {
    std::lock_guard<std::mutex> lock(mutex);
    if (!r.ok) errors.push_back(r.error);
  });
  c.on_status([&](const client::StatusUpdate& s) {
    std::lock_guard<std::mutex> lock(mutex);
    if (s.session == "b") status_b = s;
  });
  std::vector<std::uint8_t> rgb(32 * 24 * 3, 100);
  std::vector<std::uint16_t> depth(32 * 24, 2000);
  client::FrameInput frame;
  frame.intrinsics = {30.f, 30.f, 15.5f, 11.5f, 32, 24};
  frame.rgb = rgb.data();
  frame.depth = depth.data();
  std::string why;
  for (int i = 0; i < 500 && c.matched_servers() == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_TRUE(c.push_frame("never-opened", frame, &why)) << why;  // valid frame, unknown session
  ASSERT_TRUE(c.open_session("b", "b", 10000, &why)) << why;
  frame.intrinsics.cx = 500.f;  // principal point outside the image
  frame.frame_id = 1;
  ASSERT_TRUE(c.push_frame("b", frame, &why)) << why;
  for (int i = 0; i < 500; ++i) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (errors.size() >= 2) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  {
    std::lock_guard<std::mutex> lock(mutex);
    ASSERT_EQ(errors.size(), 2u);
    EXPECT_NE(errors[0].find("unknown session"), std::string::npos) << errors[0];
    EXPECT_NE(errors[1].find("intrinsics"), std::string::npos) << errors[1];
  }
  // The status topic (about once a second) reports the rejected frame with its reason.
  for (int i = 0; i < 400; ++i) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (status_b.frames_received >= 1) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  {
    std::lock_guard<std::mutex> lock(mutex);
    EXPECT_EQ(status_b.frames_received, 1u);
    EXPECT_EQ(status_b.frames_dropped, 1u);
    EXPECT_EQ(status_b.frames_processed, 0u);
    EXPECT_NE(status_b.last_drop_reason.find("intrinsics"), std::string::npos);
    EXPECT_GT(status_b.resident_bytes, 0u);
  }
  EXPECT_TRUE(c.close_session("b", 30000, &why)) << why;
  EXPECT_FALSE(c.close_session("b", 5000, &why));
  EXPECT_NE(why.find("unknown session"), std::string::npos) << why;
  EXPECT_EQ(kill(server_pid_, 0), 0) << "the server must survive bad input";
}

}  // namespace
}  // namespace fslam
