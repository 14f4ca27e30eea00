#include "fslam/server/health_file.hpp"

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "fslam/server/map_directory.hpp"

namespace fslam::server {

HealthFile::~HealthFile() {
  std::error_code ec;
  std::filesystem::remove(path_, ec);
}

bool HealthFile::beat(const std::string& service_prefix, std::size_t maps, std::size_t sessions) {
  const std::string tmp = path_ + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << "serving " << service_prefix << " maps " << maps << " sessions " << sessions << " utc_ns "
        << utc_now_ns() << "\n";
    if (!out) return false;
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path_, ec);
  return !ec;
}

}  // namespace fslam::server
