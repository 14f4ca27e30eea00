// A token bucket: at most `rate` events per second on average, bursts of up to `burst`. Used for
// the per-session frame rate (server.max_session_fps) and the per-client request rate
// (server.max_client_requests_per_s). Not thread-safe: its owner's lock guards it.
#pragma once

#include <algorithm>
#include <chrono>

namespace fslam::server {

class RateLimit {
 public:
  using Clock = std::chrono::steady_clock;
  // rate <= 0: unlimited.
  explicit RateLimit(double rate = 0.0, double burst_seconds = 1.0)
      : rate_(rate), burst_(std::max(1.0, rate * burst_seconds)), tokens_(burst_) {}
  // True when one more event fits now (and counts it).
  bool take(Clock::time_point now = Clock::now()) {
    if (rate_ <= 0.0) return true;
    if (now > last_) {  // refill for the time since the last event
      tokens_ = std::min(burst_, tokens_ + std::chrono::duration<double>(now - last_).count() * rate_);
      last_ = now;
    }
    if (tokens_ < 1.0) return false;
    tokens_ -= 1.0;
    return true;
  }

 private:
  double rate_, burst_, tokens_;
  Clock::time_point last_ = Clock::now();
};

}  // namespace fslam::server
