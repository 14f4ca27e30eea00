// Files that are written whole or reported: every write, the flush to disk (fsync) and the close
// are checked, and a failure names the file and the system's reason ("No space left on device"),
// so that a full disk is a clear error and never a short file that looks complete.
#pragma once

#include <cstddef>
#include <string>

namespace fslam::core {

class FileWriter {
 public:
  FileWriter() = default;
  FileWriter(const FileWriter&) = delete;
  FileWriter& operator=(const FileWriter&) = delete;
  ~FileWriter();  // closes a file that close() did not (nothing is synced then)

  bool open(const std::string& path, std::string* why);  // created or truncated
  // False once any write has failed; the first failure's reason is what close() reports.
  bool write(const void* data, std::size_t size);
  bool write(const std::string& text) { return write(text.data(), text.size()); }
  bool close(std::string* why);  // fsync, then close

 private:
  int fd_ = -1;
  std::string path_, error_;
};

// The whole of `content` into `path`, synced to disk.
bool write_file(const std::string& path, const std::string& content, std::string* why);
// fsync of a folder: the names created or renamed in it reach the disk too.
bool sync_directory(const std::string& dir, std::string* why);

}  // namespace fslam::core
