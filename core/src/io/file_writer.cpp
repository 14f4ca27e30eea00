#include "fslam/core/io/file_writer.hpp"

#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <unistd.h>

#include "fslam/core/error.hpp"

namespace fslam::core {

FileWriter::~FileWriter() {
  if (fd_ >= 0) ::close(fd_);
}

bool FileWriter::open(const std::string& path, std::string* why) {
  if (fd_ >= 0) ::close(fd_);
  path_ = path;
  error_.clear();
  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) return fail(why, path + ": cannot open for writing: " + std::strerror(errno));
  return true;
}

bool FileWriter::write(const void* data, std::size_t size) {
  if (fd_ < 0 && error_.empty()) error_ = "not open";
  if (!error_.empty()) return false;
  const char* p = static_cast<const char*>(data);
  while (size > 0) {
    const ssize_t n = ::write(fd_, p, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      error_ = std::string("write failed: ") + (n < 0 ? std::strerror(errno) : "no progress");
      return false;
    }
    p += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

bool FileWriter::close(std::string* why) {
  if (fd_ < 0) return fail(why, path_ + ": " + (error_.empty() ? "not open" : error_));
  // Delayed allocation can report a full disk only at fsync or close: both are checked.
  if (error_.empty() && ::fsync(fd_) != 0) error_ = std::string("fsync failed: ") + std::strerror(errno);
  if (::close(fd_) != 0 && error_.empty()) error_ = std::string("close failed: ") + std::strerror(errno);
  fd_ = -1;
  if (!error_.empty()) return fail(why, path_ + ": " + error_);
  return true;
}

bool write_file(const std::string& path, const std::string& content, std::string* why) {
  FileWriter out;
  if (!out.open(path, why)) return false;
  out.write(content);
  return out.close(why);
}

bool sync_directory(const std::string& dir, std::string* why) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return fail(why, dir + ": cannot open folder: " + std::strerror(errno));
  const bool ok = ::fsync(fd) == 0;
  const int saved = errno;
  ::close(fd);
  if (!ok) return fail(why, dir + ": fsync failed: " + std::strerror(saved));
  return true;
}

}  // namespace fslam::core
