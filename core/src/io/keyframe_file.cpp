#include "fslam/core/io/keyframe_file.hpp"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>

#include "fslam/core/error.hpp"
#include "fslam/core/io/file_writer.hpp"

namespace fslam::core {
namespace {

constexpr char kMagic[8] = {'F', 'S', 'L', 'M', 'K', 'F', 'D', '1'};
constexpr int kOrbBytes = 32;
// Most keypoints and global descriptor values one keyframe may declare (ORB keeps <= a few
// thousand; the thumbnail is 32x24 by default).
constexpr std::uint32_t kMaxKeypoints = 100000;
constexpr std::uint32_t kMaxGlobal = 1u << 16;

template <typename T>
void put(std::string* out, const T& value) {
  out->append(reinterpret_cast<const char*>(&value), sizeof(T));
}

// Reads from the bytes in order; every read is bounds-checked.
class Reader {
 public:
  explicit Reader(const std::string& bytes) : bytes_(bytes) {}
  template <typename T>
  bool get(T* value) {
    return get_bytes(value, sizeof(T));
  }
  bool get_bytes(void* out, std::size_t size) {
    if (size > bytes_.size() - at_) return false;
    if (size == 0) return true;  // `out` may be an empty vector's null data (memcpy must not see it)
    std::memcpy(out, bytes_.data() + at_, size);
    at_ += size;
    return true;
  }
  std::size_t left() const { return bytes_.size() - at_; }

 private:
  const std::string& bytes_;
  std::size_t at_ = 0;
};

bool finite(const float* v, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(v[i])) return false;
  return true;
}

}  // namespace

bool write_keyframe_file(const std::string& path, const std::vector<DescribedKeyframe>& keyframes,
                         std::string* why) {
  std::string out(kMagic, sizeof(kMagic));
  put(&out, static_cast<std::uint32_t>(keyframes.size()));
  for (const DescribedKeyframe& kf : keyframes) {
    const FrameDescription& d = kf.description;
    const std::size_t K = d.points.size();
    if (d.descriptors.rows != static_cast<int>(K) || (K > 0 && d.descriptors.cols != kOrbBytes) ||
        (K > 0 && d.descriptors.type() != CV_8UC1))
      return fail(why, path + ": keyframe " + std::to_string(kf.id) + " has descriptors that do not match its points");
    put(&out, static_cast<std::int64_t>(kf.id));
    const Eigen::Matrix3d R = kf.T_world_camera.rotation();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) put(&out, R(r, c));
    for (int a = 0; a < 3; ++a) put(&out, kf.T_world_camera.translation()[a]);
    put(&out, static_cast<std::uint32_t>(K));
    put(&out, static_cast<std::uint32_t>(d.global.size()));
    for (std::size_t i = 0; i < K; ++i) out.append(reinterpret_cast<const char*>(d.descriptors.ptr(static_cast<int>(i))), kOrbBytes);
    for (const Eigen::Vector3f& p : d.points)
      for (int a = 0; a < 3; ++a) put(&out, p[a]);
    for (float g : d.global) put(&out, g);
  }
  return write_file(path, out, why);
}

bool parse_keyframe_file(const std::string& bytes, const std::string& name,
                         std::vector<DescribedKeyframe>* keyframes, std::string* why) {
  keyframes->clear();  // and left empty on any error
  std::vector<DescribedKeyframe> parsed;
  Reader in(bytes);
  char magic[sizeof(kMagic)];
  if (!in.get_bytes(magic, sizeof(magic)) || std::memcmp(magic, kMagic, sizeof(kMagic)) != 0)
    return fail(why, name + ": not a keyframe file (no FSLMKFD1 header)");
  std::uint32_t count = 0;
  if (!in.get(&count)) return fail(why, name + ": truncated before the keyframe count");
  // Each keyframe takes at least its fixed fields (8 + 96 + 8 bytes).
  constexpr std::size_t kFixed = 8 + 12 * 8 + 8;
  if (count > in.left() / kFixed)
    return fail(why, name + ": " + std::to_string(count) + " keyframes declared, the file is too short for them");
  parsed.reserve(count);
  for (std::uint32_t k = 0; k < count; ++k) {
    const std::string where = name + ": keyframe " + std::to_string(k);
    DescribedKeyframe kf;
    double T[12];
    std::uint32_t K = 0, G = 0;
    if (!in.get(&kf.id) || !in.get_bytes(T, sizeof(T)) || !in.get(&K) || !in.get(&G))
      return fail(why, where + ": truncated");
    Eigen::Matrix3d R;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) R(r, c) = T[3 * r + c];
    const Eigen::Vector3d t(T[9], T[10], T[11]);
    if (!R.allFinite() || !t.allFinite()) return fail(why, where + ": non-finite pose");
    if (!(R.transpose() * R).isIdentity(1e-6) || !(R.determinant() > 0.0))
      return fail(why, where + ": pose rotation is not a rotation");
    kf.T_world_camera.linear() = R;
    kf.T_world_camera.translation() = t;
    if (K > kMaxKeypoints || G > kMaxGlobal) return fail(why, where + ": declares " + std::to_string(K) +
                                                              " keypoints and " + std::to_string(G) +
                                                              " descriptor values, more than allowed");
    const std::size_t need = static_cast<std::size_t>(K) * (kOrbBytes + 12) + static_cast<std::size_t>(G) * 4;
    if (need > in.left()) return fail(why, where + ": truncated (declares " + std::to_string(K) + " keypoints)");
    FrameDescription& d = kf.description;
    d.descriptors.create(static_cast<int>(K), kOrbBytes, CV_8UC1);
    for (std::uint32_t i = 0; i < K; ++i) in.get_bytes(d.descriptors.ptr(static_cast<int>(i)), kOrbBytes);
    std::vector<float> xyz(static_cast<std::size_t>(K) * 3);
    in.get_bytes(xyz.data(), xyz.size() * sizeof(float));
    d.global.resize(G);
    in.get_bytes(d.global.data(), d.global.size() * sizeof(float));
    if (!finite(xyz.data(), xyz.size()) || !finite(d.global.data(), d.global.size()))
      return fail(why, where + ": non-finite keypoint or descriptor value");
    d.points.reserve(K);
    for (std::uint32_t i = 0; i < K; ++i) d.points.emplace_back(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    parsed.push_back(std::move(kf));
  }
  if (in.left() != 0) return fail(why, name + ": " + std::to_string(in.left()) + " bytes after the last keyframe");
  *keyframes = std::move(parsed);
  return true;
}

bool read_keyframe_file(const std::string& path, std::vector<DescribedKeyframe>* keyframes, std::string* why) {
  std::ifstream file(path, std::ios::binary | std::ios::ate);
  if (!file) return fail(why, path + ": cannot open");
  const std::streamoff size = file.tellg();
  if (size < 0) return fail(why, path + ": cannot read its size");
  if (static_cast<std::size_t>(size) > kMaxKeyframeFileBytes)
    return fail(why, path + ": " + std::to_string(size) + " bytes, more than the " +
                         std::to_string(kMaxKeyframeFileBytes >> 20) + " MiB a keyframe file may hold");
  std::string bytes(static_cast<std::size_t>(size), '\0');
  file.seekg(0);
  if (!file.read(bytes.data(), size)) return fail(why, path + ": read failed");
  return parse_keyframe_file(bytes, path, keyframes, why);
}

}  // namespace fslam::core
