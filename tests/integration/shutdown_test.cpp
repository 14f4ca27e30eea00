// Stopping the server (SIGTERM) while clients still stream or its mappers are behind, and a
// `fslam stream` whose close the server does not answer in time (issue 23: "SIGTERM honoured
// within seconds", nothing accepted lost).
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "cli_runner.hpp"
#include "test_support.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;
using Clock = std::chrono::steady_clock;

std::string read_text(const std::string& path) {
  std::stringstream text;
  text << std::ifstream(path).rdbuf();
  return text.str();
}

// SIGTERM, then the seconds until `pid` is gone (at most `limit_s`, then SIGKILL: a test that
// fails does not leave the server behind).
double seconds_to_stop(pid_t pid, double limit_s) {
  const auto start = Clock::now();
  kill(pid, SIGTERM);
  while (kill(pid, 0) == 0) {
    if (std::chrono::duration<double>(Clock::now() - start).count() > limit_s) {
      kill(pid, SIGKILL);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// The Gaussian count in a PLY's header ("element vertex N"), -1 without one.
long ply_vertices(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line) && line != "end_header") {
    if (line.rfind("element vertex ", 0) == 0) return std::stol(line.substr(15));
  }
  return -1;
}

// A client that keeps streaming after the stop used to hold the server: nobody took its frames
// any more, the full frame reader made Cyclone's delivery wait for room, and deleting the reader
// waited for that delivery for as long as the client went on (52 s for a client with a 30-s
// timeout). The server now drops what comes after the stop while it deletes the reader.
TEST(ServiceShutdown, SigtermIsHonouredWhileAClientKeepsStreaming) {
  test::use_loopback_dds();
  const std::string dir = test::fresh_temp_dir("shutdown_stream").string();
  const std::string prefix = "shs" + std::to_string(getpid());
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " synth --out " + dir + "/seq --frames 200 --seed 5", &out, &err), 0) << err;
  test::ScopedServer server("--prefix " + prefix, dir + "/server.log");
  ASSERT_GT(server.pid(), 0);
  // The stream in the background: queue policy at 30 Hz, patient (60 s) about unanswered frames.
  const std::string stream_log = dir + "/stream.log";
  std::system((fslam_bin() + " stream --policy queue --rate 30 --timeout 60 --dataset " + dir + "/seq --prefix " +
               prefix + " --session s >" + stream_log + " 2>&1 & echo $! >" + stream_log + ".pid")
                  .c_str());
  pid_t stream = -1;
  std::ifstream(stream_log + ".pid") >> stream;
  ASSERT_GT(stream, 0);
  // Stop the server once the stream is well under way (20 % = 40 frames sent).
  for (int i = 0; i < 600 && read_text(stream_log).find("( 20%)") == std::string::npos; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  ASSERT_NE(read_text(stream_log).find("( 20%)"), std::string::npos) << read_text(stream_log);
  const double stop_s = seconds_to_stop(server.release(), 30.0 * test::time_scale());
  test::stop_process(stream);
  EXPECT_LT(stop_s, 10.0 * test::time_scale()) << "SIGTERM with a client streaming\n" << read_text(dir + "/server.log");
  // It tracked what it took and said so on the way out.
  EXPECT_NE(read_text(dir + "/server.log").find("fslam-server: stopped; frames received"), std::string::npos);
}

// A mapper far behind (here: a million steps per keyframe) keeps `fslam stream`'s close from
// being answered: the stream still writes its poses and report, but fails, since the map is not
// final. SIGTERM then does not wait for that backlog: the keyframes go into the map without their
// optimisation steps, and the map is saved with them.
TEST(ServiceShutdown, AnUnansweredCloseFailsTheStreamAndShutdownSkipsTheMappersBacklog) {
  test::use_loopback_dds();
  const std::string dir = test::fresh_temp_dir("shutdown_backlog").string();
  const std::string prefix = "shb" + std::to_string(getpid());
  std::string out, err;
  ASSERT_EQ(run_command(fslam_bin() + " synth --out " + dir + "/seq --frames 10 --seed 5", &out, &err), 0) << err;
  test::ScopedServer server("--prefix " + prefix + " --map-dir " + dir + "/maps" +
                                " --set mapper.iterations_per_keyframe=1000000",
                            dir + "/server.log");
  ASSERT_GT(server.pid(), 0);
  const int rc = run_command(fslam_bin() + " stream --policy queue --timeout 1 --dataset " + dir + "/seq --prefix " +
                                 prefix + " --session s --map slow --out " + dir + "/poses.txt --report " + dir +
                                 "/report.json",
                             &out, &err);
  EXPECT_EQ(rc, 1) << out << err;
  EXPECT_NE(err.find("close: "), std::string::npos) << err;
  EXPECT_NE(err.find("the map may still be being mapped"), std::string::npos) << err;
  const nlohmann::json report = nlohmann::json::parse(read_text(dir + "/report.json"));
  EXPECT_FALSE(report.value("closed", true));
  EXPECT_EQ(report.value("tracked", 0), 10);  // the poses are complete all the same

  const double stop_s = seconds_to_stop(server.release(), 60.0 * test::time_scale());
  EXPECT_LT(stop_s, 10.0 * test::time_scale()) << "SIGTERM with the mapper behind\n" << read_text(dir + "/server.log");
  EXPECT_GT(ply_vertices(dir + "/maps/slow/map.ply"), 1000) << read_text(dir + "/server.log");
}

}  // namespace
}  // namespace fslam
