#include "fslam/core/io/keyframe_file.hpp"

#include <cmath>
#include <cstdint>
#include <cstring>

#include "fslam/core/error.hpp"
#include "fslam/core/io/file_writer.hpp"
#include "binary_record.hpp"

namespace fslam::core {
namespace {

constexpr char kMagic[8] = {'F', 'S', 'L', 'M', 'K', 'F', 'D', '1'};
constexpr int kOrbBytes = 32;
// Most keypoints and global descriptor values one keyframe may declare (ORB keeps <= a few
// thousand; the thumbnail is 32x24 by default).
constexpr std::uint32_t kMaxKeypoints = 100000;
constexpr std::uint32_t kMaxGlobal = 1u << 16;

using io_detail::ByteReader;
using io_detail::put;

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
    io_detail::put_pose(&out, kf.T_world_camera);
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
  ByteReader in(bytes);
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
    std::uint32_t K = 0, G = 0;
    if (!in.get(&kf.id)) return fail(why, where + ": truncated");
    if (!io_detail::get_pose(&in, where, &kf.T_world_camera, why)) return false;
    if (!in.get(&K) || !in.get(&G)) return fail(why, where + ": truncated");
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
  std::string bytes;
  return io_detail::read_capped_file(path, kMaxKeyframeFileBytes, "a keyframe file", &bytes, why) &&
         parse_keyframe_file(bytes, path, keyframes, why);
}

}  // namespace fslam::core
