// Little-endian binary records shared by the map-side files a server writes and reads back
// (keyframes.bin, keyframe_images.bin): appending values, a bounds-checked reader, a rigid pose
// with its checks, and reading a whole file under a size cap. Internal to core/src/io.
#pragma once

#include <cstddef>
#include <cstring>
#include <string>

#include <Eigen/Geometry>

namespace fslam::core::io_detail {

template <typename T>
void put(std::string* out, const T& value) {
  out->append(reinterpret_cast<const char*>(&value), sizeof(T));
}

// Reads from the bytes in order; every read is bounds-checked and false past the end.
class ByteReader {
 public:
  explicit ByteReader(const std::string& bytes) : bytes_(bytes) {}
  template <typename T>
  bool get(T* value) {
    return get_bytes(value, sizeof(T));
  }
  bool get_bytes(void* out, std::size_t size) {
    if (size > left()) return false;
    if (size > 0) std::memcpy(out, bytes_.data() + at_, size);  // `out` may be an empty vector's null data
    at_ += size;
    return true;
  }
  // A u32-length-prefixed blob, viewed in place.
  bool get_blob(const unsigned char** data, std::uint32_t* size) {
    if (!get(size) || *size > left()) return false;
    *data = reinterpret_cast<const unsigned char*>(bytes_.data() + at_);
    at_ += *size;
    return true;
  }
  std::size_t left() const { return bytes_.size() - at_; }

 private:
  const std::string& bytes_;
  std::size_t at_ = 0;
};

// f64[12]: the rotation row-major, then the translation.
void put_pose(std::string* out, const Eigen::Isometry3d& T);
// Reads put_pose's record; false with "<where>: truncated" / "non-finite pose" / "pose rotation
// is not a rotation".
bool get_pose(ByteReader* in, const std::string& where, Eigen::Isometry3d* T, std::string* why);

// The whole of `path` into `bytes`; refused past `max_bytes` (`what` names the kind of file).
bool read_capped_file(const std::string& path, std::size_t max_bytes, const char* what, std::string* bytes,
                      std::string* why);

}  // namespace fslam::core::io_detail
