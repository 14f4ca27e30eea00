#include "binary_record.hpp"

#include <fstream>

#include "fslam/core/error.hpp"

namespace fslam::core::io_detail {

void put_pose(std::string* out, const Eigen::Isometry3d& T) {
  const Eigen::Matrix3d R = T.rotation();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) put(out, R(r, c));
  for (int a = 0; a < 3; ++a) put(out, T.translation()[a]);
}

bool get_pose(ByteReader* in, const std::string& where, Eigen::Isometry3d* T, std::string* why) {
  double v[12];
  if (!in->get_bytes(v, sizeof(v))) return fail(why, where + ": truncated");
  Eigen::Matrix3d R;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R(r, c) = v[3 * r + c];
  const Eigen::Vector3d t(v[9], v[10], v[11]);
  if (!R.allFinite() || !t.allFinite()) return fail(why, where + ": non-finite pose");
  if (!(R.transpose() * R).isIdentity(1e-6) || !(R.determinant() > 0.0))
    return fail(why, where + ": pose rotation is not a rotation");
  T->linear() = R;
  T->translation() = t;
  return true;
}

bool read_capped_file(const std::string& path, std::size_t max_bytes, const char* what, std::string* bytes,
                      std::string* why) {
  std::ifstream file(path, std::ios::binary | std::ios::ate);
  if (!file) return fail(why, path + ": cannot open");
  const std::streamoff size = file.tellg();
  if (size < 0) return fail(why, path + ": cannot read its size");
  if (static_cast<std::size_t>(size) > max_bytes)
    return fail(why, path + ": " + std::to_string(size) + " bytes, more than the " + std::to_string(max_bytes >> 20) +
                         " MiB " + what + " may hold");
  bytes->assign(static_cast<std::size_t>(size), '\0');
  file.seekg(0);
  if (!file.read(bytes->data(), size)) return fail(why, path + ": read failed");
  return true;
}

}  // namespace fslam::core::io_detail
