// Runs the real `fslam` and `fslam-server` binaries from integration tests.
#pragma once

#include <signal.h>
#include <sys/types.h>
#include <sys/wait.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <utility>

#include "test_support.hpp"

namespace fslam::test {

// Runs a shell command; returns its exit status and what it wrote to stdout and stderr.
// Safe to call from several threads at once.
inline int run_command(const std::string& command, std::string* out, std::string* err) {
  static std::atomic<int> calls{0};
  const auto dir = fresh_temp_dir("run" + std::to_string(calls++));
  const std::string full = command + " >" + (dir / "out").string() + " 2>" + (dir / "err").string();
  const int status = std::system(full.c_str());
  std::stringstream o, e;
  o << std::ifstream(dir / "out").rdbuf();
  e << std::ifstream(dir / "err").rdbuf();
  *out = o.str();
  *err = e.str();
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

inline std::string fslam_bin() { return (bin_dir() / "fslam").string(); }

// `fslam stream` in queue policy (every frame tracked), waiting for its close as long as mapping
// takes in this build (60 s times the time scale); callers add the source, prefix and session.
inline std::string queue_stream_command() {
  return fslam_bin() + " stream --policy queue --timeout " + std::to_string(scaled_s(60));
}

// Starts fslam-server in the background with `args`, output to `log`; returns its pid (or -1).
inline pid_t start_server(const std::string& args, const std::string& log) {
  const std::string server = (bin_dir() / "fslam-server").string();
  const std::string pid_file = log + ".pid";
  std::system((server + " " + args + " >" + log + " 2>&1 & echo $! >" + pid_file).c_str());
  pid_t pid = -1;
  std::ifstream(pid_file) >> pid;
  return pid;
}

// SIGTERM and wait for the process to exit (a server saves its maps on the way out).
inline void stop_process(pid_t pid) {
  if (pid <= 0) return;
  kill(pid, SIGTERM);
  for (int i = 0; i < 600 && kill(pid, 0) == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
}

// A server a test started, stopped when the guard goes out of scope: an assertion that ends the
// test early never leaves the process running.
class ScopedServer {
 public:
  ScopedServer(const std::string& args, const std::string& log) : pid_(start_server(args, log)) {}
  ~ScopedServer() { stop(); }
  ScopedServer(const ScopedServer&) = delete;
  ScopedServer& operator=(const ScopedServer&) = delete;
  pid_t pid() const { return pid_; }
  void stop() {
    stop_process(pid_);
    pid_ = -1;
  }
  // The caller stops the process from here on (its own way, timed, say).
  pid_t release() { return std::exchange(pid_, -1); }

 private:
  pid_t pid_;
};

}  // namespace fslam::test
