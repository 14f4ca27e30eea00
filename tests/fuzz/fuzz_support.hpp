// Shared pieces of the libFuzzer targets (docs/reliability.md): a private scratch folder for the
// readers that take a path, and a little-endian reader over the fuzzer's bytes.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

namespace fslam::fuzz {

// A folder of this process (made once, under $TMPDIR or /tmp), so parallel fuzzers never share.
inline const std::string& scratch_dir() {
  static const std::string dir = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::string templ = std::string(tmp != nullptr ? tmp : "/tmp") + "/fslam_fuzz_XXXXXX";
    if (mkdtemp(templ.data()) == nullptr) std::abort();
    return templ;
  }();
  return dir;
}

// Writes `n` bytes to scratch_dir()/name and returns the path.
inline std::string write_scratch(const std::string& name, const std::uint8_t* data, std::size_t n) {
  const std::string path = scratch_dir() + "/" + name;
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) std::abort();
  if (n > 0 && std::fwrite(data, 1, n, f) != n) std::abort();
  std::fclose(f);
  return path;
}

// Reads fixed-size little-endian fields from the front; past the end every field reads as 0, so
// any input is a valid (if short) message.
class ByteReader {
 public:
  ByteReader(const std::uint8_t* data, std::size_t n) : data_(data), n_(n) {}
  template <typename T>
  T take() {
    T value{};
    if (pos_ + sizeof(T) <= n_) std::memcpy(&value, data_ + pos_, sizeof(T));
    pos_ = pos_ + sizeof(T) <= n_ ? pos_ + sizeof(T) : n_;
    return value;
  }
  // Up to `count` bytes from the front (fewer at the end).
  std::string bytes(std::size_t count) {
    const std::size_t k = count < n_ - pos_ ? count : n_ - pos_;
    std::string out(reinterpret_cast<const char*>(data_ + pos_), k);
    pos_ += k;
    return out;
  }
  std::string rest() { return bytes(n_ - pos_); }

 private:
  const std::uint8_t* data_;
  std::size_t n_;
  std::size_t pos_ = 0;
};

// Splits `text` at the first occurrence of `separator` (the second part empty when absent).
inline std::pair<std::string, std::string> split_once(const std::string& text, const std::string& separator) {
  const std::size_t at = text.find(separator);
  if (at == std::string::npos) return {text, std::string()};
  return {text.substr(0, at), text.substr(at + separator.size())};
}

}  // namespace fslam::fuzz
