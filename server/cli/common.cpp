#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>

#include "commands.hpp"

namespace fslam::cli {
namespace {
double now_s() {
  using namespace std::chrono;
  return duration<double>(steady_clock::now().time_since_epoch()).count();
}
}  // namespace

int fail(const std::string& message) {
  std::cerr << "fslam: error: " << message << std::endl;
  return 1;
}

Progress::Progress(std::string label, std::size_t total)
    : label_(std::move(label)), total_(total), tty_(isatty(STDERR_FILENO) != 0), start_s_(now_s()) {}

void Progress::update(std::size_t done) {
  const double elapsed = now_s() - start_s_;
  const double fraction = total_ ? static_cast<double>(done) / static_cast<double>(total_) : 1.0;
  const int decile = static_cast<int>(fraction * 10.0);
  if (!tty_ && decile == last_decile_) return;
  last_decile_ = decile;
  const double eta = done ? elapsed / static_cast<double>(done) * static_cast<double>(total_ - done) : 0.0;
  std::fprintf(stderr, "%s[%s] %zu/%zu (%3.0f%%) %.1f s elapsed, ~%.1f s left%s",
               tty_ ? "\r" : "", label_.c_str(), done, total_, 100.0 * fraction, elapsed, eta,
               tty_ ? "   " : "\n");
  std::fflush(stderr);
}

void Progress::finish() {
  if (tty_) std::fprintf(stderr, "\n");
  std::fprintf(stderr, "[%s] done: %zu in %.2f s\n", label_.c_str(), total_, now_s() - start_s_);
}

}  // namespace fslam::cli
