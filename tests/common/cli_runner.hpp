// Runs the real `fslam` binary from integration tests.
#pragma once

#include <sys/wait.h>

#include <atomic>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

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

}  // namespace fslam::test
