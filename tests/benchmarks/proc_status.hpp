// What the benchmarks read of a process from /proc (Linux): shared by the DDS memory benchmarks.
#pragma once

#include <fstream>
#include <string>

namespace fslam::bench {

// A field of /proc/PROCESS/status ("self" or a pid): KiB for the Vm* fields, a count for
// Threads; -1 when absent.
inline long proc_status(const std::string& process, const std::string& field) {
  std::ifstream status("/proc/" + process + "/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind(field + ":", 0) == 0) return std::stol(line.substr(field.size() + 1));
  return -1;
}

}  // namespace fslam::bench
