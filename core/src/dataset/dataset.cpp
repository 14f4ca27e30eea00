#include "fslam/core/dataset/dataset.hpp"

#include "fslam/core/error.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <system_error>

#include "fslam/core/dataset/frame_index.hpp"
#include "fslam/core/dataset/readers.hpp"
#include "fslam/core/io/text_tables.hpp"

namespace fslam::core {
namespace {

std::vector<std::string> split(const std::string& text, const std::string& separators) {
  std::vector<std::string> parts;
  std::string current;
  for (char c : text) {
    if (separators.find(c) != std::string::npos) {
      parts.push_back(current);
      current.clear();
    } else {
      current += c;
    }
  }
  parts.push_back(current);
  return parts;
}

bool parse_count(const std::string& text, std::size_t* value) {
  if (text.empty() || text.size() > 18 ||
      !std::all_of(text.begin(), text.end(), [](unsigned char c) { return std::isdigit(c); }))
    return false;
  *value = static_cast<std::size_t>(std::stoull(text));
  return true;
}

bool is_folder(const std::string& path, std::string* why) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return fail(why, path + ": no such folder");
  if (!std::filesystem::is_directory(path, ec)) return fail(why, path + ": not a folder");
  return true;
}

}  // namespace

bool FrameSelection::parse(const std::string& text, FrameSelection* selection, std::string* why) {
  const std::string usage = "frame selection '" + text + "': ";
  const std::vector<std::string> parts = split(text, ":");
  if (parts.size() < 2 || parts.size() > 3)
    return fail(why, usage + "expected A:B or A:B:S (A: from A to the end, :B the first B)");
  FrameSelection s;
  bool has_end = false;
  const char* names[3] = {"first frame", "end", "stride"};
  std::size_t* fields[3] = {&s.begin, &s.end, &s.stride};
  for (std::size_t k = 0; k < parts.size(); ++k) {
    if (parts[k].empty()) continue;
    if (!parse_count(parts[k], fields[k]))
      return fail(why, usage + names[k] + " '" + parts[k] + "' is not a non-negative integer");
    if (k == 1) has_end = true;
  }
  if (s.stride == 0) return fail(why, usage + "stride must be at least 1");
  if (has_end && s.end <= s.begin)
    return fail(why, usage + "end must be greater than the first frame (B is exclusive)");
  *selection = s;
  return true;
}

std::string FrameSelection::to_string() const {
  std::string text = std::to_string(begin) + ":";
  if (end != kToEnd) text += std::to_string(end);
  if (stride != 1) text += ":" + std::to_string(stride);
  return text;
}

bool FrameSelection::apply(std::size_t count, const std::string& source,
                           std::vector<std::size_t>* positions, std::string* why) const {
  if (stride == 0) return fail(why, source + ": frame selection " + to_string() + " has stride 0");
  if (begin >= count || end <= begin)
    return fail(why, source + ": frame selection " + to_string() + " selects no frames of the " +
                         std::to_string(count) + " there are");
  positions->clear();
  for (std::size_t i = begin; i < std::min(end, count); i += stride) positions->push_back(i);
  return true;
}

bool parse_intrinsics(const std::string& text, PinholeCamera* camera, std::string* why) {
  const std::string usage = "intrinsics '" + text + "': ";
  std::vector<double> values;
  std::string reason;
  if (!parse_number_list(text, &values, &reason) ||
      !camera_from_values(values, camera, &reason))
    return fail(why, usage + reason);
  return true;
}

bool Dataset::load_labels(std::size_t, cv::Mat*, cv::Mat*, std::string* why) const {
  return fail(why, root() + ": this " + kind() + " dataset has no label images");
}

const std::vector<std::string>& dataset_kinds() {
  static const std::vector<std::string> kinds = {"tum", "7scenes", "replica"};
  return kinds;
}

bool detect_dataset_kind(const std::string& path, std::string* kind, std::string* why) {
  if (!is_folder(path, why)) return false;
  if (looks_like_tum(path))
    *kind = "tum";
  else if (looks_like_seven_scenes(path))
    *kind = "7scenes";
  else if (looks_like_replica(path))
    *kind = "replica";
  else
    return fail(why, path +
                         ": cannot tell the dataset kind: expected rgb.txt and depth.txt "
                         "(TUM RGB-D), frame-NNNNNN.depth.png here or in data/rgbd-frames "
                         "(7-Scenes), or results/depthNNNNNN.png (Replica); or name the kind");
  return true;
}

std::unique_ptr<Dataset> open_dataset(const std::string& path, const DatasetOptions& options,
                                      std::string* why) {
  const std::string root = normalise_root(path);
  std::string kind = options.kind;
  if (kind == "auto") {
    if (!detect_dataset_kind(root, &kind, why)) return nullptr;
  } else if (!is_folder(root, why)) {
    return nullptr;
  }
  if (kind == "tum") return open_tum_dataset(root, options, why);
  if (kind == "7scenes") return open_seven_scenes_dataset(root, options, why);
  if (kind == "replica") return open_replica_dataset(root, options, why);
  std::string known = "auto";
  for (const std::string& k : dataset_kinds()) known += ", " + k;
  fail(why, "unknown dataset kind '" + kind + "' (expected one of " + known + ")");
  return nullptr;
}

}  // namespace fslam::core
