#include "fslam/core/io/trajectory_io.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "fslam/core/geometry/se3.hpp"

namespace fslam::core {

bool read_tum_trajectory(const std::string& path, Trajectory* trajectory, std::string* why) {
  auto fail = [&](const std::string& message) {
    if (why) *why = message;
    return false;
  };
  std::ifstream in(path);
  if (!in) return fail(path + ": cannot open trajectory file");
  Trajectory result;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    for (char& c : line)
      if (c == ',' || c == '\t' || c == '\r') c = ' ';
    const auto first = line.find_first_not_of(' ');
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream fields(line);
    double v[8];
    int n = 0;
    std::string token;
    while (n < 8 && fields >> token) {
      char* end = nullptr;
      v[n] = std::strtod(token.c_str(), &end);
      if (end == token.c_str() || *end != '\0')
        return fail(path + ":" + std::to_string(line_number) + ": '" + token +
                    "' is not a number");
      ++n;
    }
    if (n < 8)
      return fail(path + ":" + std::to_string(line_number) +
                  ": expected 'timestamp tx ty tz qx qy qz qw', found " + std::to_string(n) +
                  " fields");
    for (double x : v)
      if (!std::isfinite(x))
        return fail(path + ":" + std::to_string(line_number) + ": non-finite value");
    const double qnorm = std::sqrt(v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]);
    if (std::abs(qnorm - 1.0) > 1e-2)
      return fail(path + ":" + std::to_string(line_number) + ": quaternion norm " +
                  std::to_string(qnorm) + " is not 1");
    result.push_back({v[0], from_tum({v[1], v[2], v[3], v[4], v[5], v[6], v[7]})});
  }
  *trajectory = std::move(result);
  return true;
}

bool write_tum_trajectory(const std::string& path, const Trajectory& trajectory, std::string* why) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) {
    if (why) *why = path + ": cannot open for writing";
    return false;
  }
  std::fprintf(f, "# timestamp tx ty tz qx qy qz qw (camera-to-world)\n");
  for (const StampedPose& p : trajectory) {
    const auto t = to_tum(p.T_world_camera);
    std::fprintf(f, "%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n", p.timestamp, t[0], t[1], t[2],
                 t[3], t[4], t[5], t[6]);
  }
  if (std::fclose(f) != 0) {
    if (why) *why = path + ": write failed";
    return false;
  }
  return true;
}

}  // namespace fslam::core
