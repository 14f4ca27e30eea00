#include "fslam/core/io/trajectory_io.hpp"

#include <cmath>
#include <iomanip>
#include <sstream>

#include "fslam/core/error.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/file_writer.hpp"
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
  std::ostringstream out;
  out << "# timestamp tx ty tz qx qy qz qw (camera-to-world)\n" << std::fixed;
  for (const StampedPose& p : trajectory) {
    const auto t = to_tum(p.T_world_camera);
    out << std::setprecision(6) << p.timestamp << std::setprecision(9);
    for (double v : t) out << ' ' << v;
    out << '\n';
  }
  return write_file(path, out.str(), why);
}

const StampedPose* nearest_pose(const Trajectory& trajectory, double t, double max_difference) {
  const StampedPose* best = nullptr;
  for (const StampedPose& p : trajectory)
    if (!best || std::abs(p.timestamp - t) < std::abs(best->timestamp - t)) best = &p;
  return best && std::abs(best->timestamp - t) <= max_difference ? best : nullptr;
}

}  // namespace fslam::core
