// The server's totals (ServerStats' counters), counted by sessions and queries alike.
#pragma once

#include <cstdint>
#include <mutex>

#include "fslam/server/server.hpp"

namespace fslam::server {

class Counters {
 public:
  void add(std::uint64_t ServerStats::*counter) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++(stats_.*counter);
  }
  ServerStats totals() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return stats_;
  }

 private:
  mutable std::mutex mutex_;
  ServerStats stats_;  // sessions and maps stay 0: the server counts those where they live
};

}  // namespace fslam::server
