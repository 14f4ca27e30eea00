// The bad-input convention of core: `bool f(..., std::string* why)`.
#pragma once

#include <string>

namespace fslam::core {

// Stores `message` in *why when the caller asked for it, and returns false.
inline bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

}  // namespace fslam::core
