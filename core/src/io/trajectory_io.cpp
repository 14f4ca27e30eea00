#include "fslam/core/io/trajectory_io.hpp"

#include <cmath>
#include <cstdio>

#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/text_tables.hpp"

namespace fslam::core {

bool read_tum_trajectory(const std::string& path, Trajectory* trajectory, std::string* why) {
  auto fail = [&](int line, const std::string& message) {
    if (why) *why = path + ":" + std::to_string(line) + ": " + message;
    return false;
  };
  std::vector<NumberRow> rows;  // rejects non-numbers and non-finite values, naming file and line
  if (!read_number_rows(path, &rows, why)) return false;
  Trajectory result;
  result.reserve(rows.size());
  for (const NumberRow& row : rows) {
    const std::vector<double>& v = row.values;
    if (v.size() < 8)
      return fail(row.line, "expected 'timestamp tx ty tz qx qy qz qw', found " +
                                std::to_string(v.size()) + " fields");
    const double qnorm = std::sqrt(v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]);
    if (std::abs(qnorm - 1.0) > 1e-2)
      return fail(row.line, "quaternion norm " + std::to_string(qnorm) + " is not 1");
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
