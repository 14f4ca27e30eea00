#include "fslam/client/rosbag2.hpp"

#include <sqlite3.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>

namespace fslam::client::rosbag2 {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

// One read-only connection and the statements on it, closed on scope exit.
class Db {
 public:
  bool open(const std::string& path, std::string* why) {
    if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READONLY | SQLITE_OPEN_NOMUTEX, nullptr) != SQLITE_OK) {
      return fail(why, path + ": " + (db_ ? sqlite3_errmsg(db_) : "cannot open"));
    }
    return true;
  }
  ~Db() {
    for (sqlite3_stmt* s : statements_) sqlite3_finalize(s);
    if (db_) sqlite3_close(db_);
  }
  sqlite3_stmt* prepare(const char* sql, const std::string& path, std::string* why) {
    sqlite3_stmt* s = nullptr;
    if (sqlite3_prepare_v2(db_, sql, -1, &s, nullptr) != SQLITE_OK) {
      fail(why, path + ": " + sqlite3_errmsg(db_) + " (is it a rosbag2 sqlite3 file?)");
      return nullptr;
    }
    statements_.push_back(s);
    return s;
  }

 private:
  sqlite3* db_ = nullptr;
  std::vector<sqlite3_stmt*> statements_;
};

std::string trim(std::string s) {
  const auto b = s.find_first_not_of(" \t\r'\"");
  const auto e = s.find_last_not_of(" \t\r'\"");
  return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
}

// What this reader needs of metadata.yaml (rosbag2's BagMetadata): the storage and its files.
// A small line reader, not a YAML parser: the client links proto and codecs only (design.md).
bool read_metadata(const std::filesystem::path& path, std::vector<std::string>* files, std::string* why) {
  std::ifstream in(path);
  if (!in) return fail(why, path.string() + ": cannot read");
  std::string line, storage;
  bool in_files = false;
  while (std::getline(in, line)) {
    const std::string t = trim(line);
    if (t.rfind("storage_identifier:", 0) == 0) storage = trim(t.substr(19));
    if (t.rfind("relative_file_paths:", 0) == 0) {
      in_files = true;
      continue;
    }
    if (in_files) {
      if (t.rfind("- ", 0) == 0) files->push_back(trim(t.substr(2)));
      else if (!t.empty()) in_files = false;
    }
  }
  if (storage != "sqlite3") {
    return fail(why, path.string() + ": storage_identifier is '" + storage +
                         "'; only the sqlite3 storage is read (mcap: convert with `ros2 bag convert`)");
  }
  if (files->empty()) return fail(why, path.string() + ": no relative_file_paths");
  return true;
}

}  // namespace

Bag::Bag() = default;
Bag::~Bag() = default;

bool Bag::open(const std::string& folder, std::string* why) {
  namespace fs = std::filesystem;
  folder_ = folder;
  files_.clear();
  topics_.clear();
  topic_ids_.clear();
  const fs::path root(folder);
  if (!fs::is_directory(root)) return fail(why, folder + ": not a folder (a rosbag2 recording is one)");
  std::vector<std::string> names;
  if (fs::exists(root / "metadata.yaml")) {
    if (!read_metadata(root / "metadata.yaml", &names, why)) return false;
  } else {
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(root, ec))
      if (e.path().extension() == ".db3") names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    if (names.empty()) return fail(why, folder + ": no metadata.yaml and no .db3 file");
  }
  std::map<std::string, std::size_t> by_name;
  for (const std::string& name : names) {
    const std::string path = (root / name).string();
    Db db;
    if (!db.open(path, why)) return false;
    sqlite3_stmt* topics = db.prepare("SELECT id, name, type, serialization_format FROM topics", path, why);
    sqlite3_stmt* counts = db.prepare("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id", path, why);
    if (!topics || !counts) return false;
    const std::size_t file = files_.size();
    files_.push_back(path);
    std::map<std::int64_t, std::size_t> local;
    while (sqlite3_step(topics) == SQLITE_ROW) {
      auto text = [&](int c) {
        const unsigned char* s = sqlite3_column_text(topics, c);
        return s ? std::string(reinterpret_cast<const char*>(s)) : std::string();
      };
      const std::string topic_name = text(1);
      auto [it, fresh] = by_name.emplace(topic_name, topics_.size());
      if (fresh) {
        topics_.push_back({topic_name, text(2), text(3), 0});
        topic_ids_.emplace_back();
      }
      topic_ids_[it->second].push_back({file, sqlite3_column_int64(topics, 0)});
      local[sqlite3_column_int64(topics, 0)] = it->second;
    }
    while (sqlite3_step(counts) == SQLITE_ROW) {
      const auto it = local.find(sqlite3_column_int64(counts, 0));
      if (it != local.end()) topics_[it->second].messages += static_cast<std::size_t>(sqlite3_column_int64(counts, 1));
    }
  }
  return true;
}

bool Bag::index(const std::vector<std::size_t>& topics, std::vector<MessageRef>* refs, std::string* why) const {
  refs->clear();
  for (std::size_t file = 0; file < files_.size(); ++file) {
    Db db;
    if (!db.open(files_[file], why)) return false;
    sqlite3_stmt* s = db.prepare("SELECT id, timestamp FROM messages WHERE topic_id = ?", files_[file], why);
    if (!s) return false;
    for (std::size_t t : topics) {
      for (const auto& [f, id] : topic_ids_.at(t)) {
        if (f != file) continue;
        sqlite3_reset(s);
        sqlite3_bind_int64(s, 1, id);
        while (sqlite3_step(s) == SQLITE_ROW) {
          refs->push_back({t, file, sqlite3_column_int64(s, 0), sqlite3_column_int64(s, 1)});
        }
      }
    }
  }
  std::stable_sort(refs->begin(), refs->end(), [](const MessageRef& a, const MessageRef& b) {
    return a.timestamp_ns != b.timestamp_ns ? a.timestamp_ns < b.timestamp_ns
                                            : (a.file != b.file ? a.file < b.file : a.row < b.row);
  });
  return true;
}

bool Bag::read(const MessageRef& ref, std::vector<std::uint8_t>* data, std::string* why) const {
  if (ref.file >= files_.size()) return fail(why, "rosbag2: message of an unknown file");
  Db db;
  if (!db.open(files_[ref.file], why)) return false;
  sqlite3_stmt* s = db.prepare("SELECT data FROM messages WHERE id = ?", files_[ref.file], why);
  if (!s) return false;
  sqlite3_bind_int64(s, 1, ref.row);
  if (sqlite3_step(s) != SQLITE_ROW) {
    return fail(why, files_[ref.file] + ": no message with id " + std::to_string(ref.row));
  }
  const auto* bytes = static_cast<const std::uint8_t*>(sqlite3_column_blob(s, 0));
  data->assign(bytes, bytes + sqlite3_column_bytes(s, 0));
  return true;
}

}  // namespace fslam::client::rosbag2
