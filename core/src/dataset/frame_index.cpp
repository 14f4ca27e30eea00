#include "fslam/core/dataset/frame_index.hpp"

#include "fslam/core/error.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <system_error>
#include <utility>

#include <opencv2/core.hpp>

#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/image_io.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

std::string size_text(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

// Serves every layout from its FrameIndex; immutable after construction, so load() may run on
// many threads at once.
class IndexedDataset final : public Dataset {
 public:
  explicit IndexedDataset(FrameIndex index) : index_(std::move(index)) {
    has_labels_ = std::any_of(index_.frames.begin(), index_.frames.end(), [](const FrameRecord& r) {
      return !r.instance_label_path.empty() || !r.class_label_path.empty();
    });
    has_ground_truth_ =
        std::any_of(index_.frames.begin(), index_.frames.end(),
                    [](const FrameRecord& r) { return r.T_world_camera_gt.has_value(); });
  }

  std::string kind() const override { return index_.kind; }
  const std::string& root() const override { return index_.root; }
  std::size_t size() const override { return index_.frames.size(); }
  const PinholeCamera& camera() const override { return index_.camera; }
  std::string camera_source() const override { return index_.camera_source; }
  double depth_scale() const override { return index_.depth_scale; }
  std::int64_t id(std::size_t index) const override { return index_.frames.at(index).id; }
  double timestamp(std::size_t index) const override { return index_.frames.at(index).timestamp; }
  bool has_ground_truth() const override { return has_ground_truth_; }
  bool has_labels() const override { return has_labels_; }

  Trajectory ground_truth() const override {
    Trajectory trajectory;
    for (const FrameRecord& r : index_.frames)
      if (r.T_world_camera_gt) trajectory.push_back({r.timestamp, *r.T_world_camera_gt});
    return trajectory;
  }

  bool load(std::size_t index, RgbdFrame* frame, std::string* why) const override {
    if (!check_index(index, why)) return false;
    const FrameRecord& r = index_.frames[index];
    RgbdFrame out;
    out.id = r.id;
    out.timestamp = r.timestamp;
    out.camera = index_.camera;
    out.T_world_camera_gt = r.T_world_camera_gt;
    if (!read_colour_image(r.colour_path, &out.colour, why) ||
        (!index_.colour_camera && !check_size(r.colour_path, out.colour, why)) ||
        !read_depth_image(r.depth_path, index_.depth_scale, &out.depth, why) ||
        !check_size(r.depth_path, out.depth, why))
      return false;
    if (index_.colour_camera) {
      std::string reason;
      if (!register_colour_to_depth(out.colour, out.depth, index_.camera, *index_.colour_camera,
                                    &out.colour, &reason))
        return fail(why, r.colour_path + ": " + reason);
    }
    *frame = std::move(out);
    return true;
  }

  bool load_labels(std::size_t index, cv::Mat* instance, cv::Mat* cls,
                   std::string* why) const override {
    if (!check_index(index, why)) return false;
    const FrameRecord& r = index_.frames[index];
    if (r.instance_label_path.empty() && r.class_label_path.empty())
      return fail(why, index_.root + ": frame " + std::to_string(r.id) + " has no label images");
    cv::Mat images[2];
    const std::string* paths[2] = {&r.instance_label_path, &r.class_label_path};
    for (int k = 0; k < 2; ++k) {
      const std::string& path = *paths[k];
      if (path.empty()) continue;
      if (!read_single_channel_image(path, &images[k], why)) return false;
      if (images[k].depth() != CV_8U && images[k].depth() != CV_16U)
        return fail(why, path + ": label images must be 8- or 16-bit integers");
      if (!check_size(path, images[k], why)) return false;
    }
    if (instance) *instance = images[0];
    if (cls) *cls = images[1];
    return true;
  }

 private:
  bool check_index(std::size_t index, std::string* why) const {
    if (index < index_.frames.size()) return true;
    return fail(why, index_.root + ": frame index " + std::to_string(index) + " is out of range (" +
                         std::to_string(index_.frames.size()) + " frames selected)");
  }

  bool check_size(const std::string& path, const cv::Mat& image, std::string* why) const {
    const PinholeCamera& c = index_.camera;
    if (image.cols == c.width && image.rows == c.height) return true;
    return fail(why, path + ": image is " + size_text(image.cols, image.rows) +
                         " but the camera (" + index_.camera_source + ") is " +
                         size_text(c.width, c.height));
  }

  FrameIndex index_;
  bool has_labels_ = false;
  bool has_ground_truth_ = false;
};

}  // namespace

std::unique_ptr<Dataset> make_indexed_dataset(FrameIndex index, const DatasetOptions& options,
                                              std::string* why) {
  if (index.frames.empty()) {
    fail(why, index.root + ": no frames found");
    return nullptr;
  }
  for (const FrameRecord& r : index.frames) {
    if (first_existing_file({r.colour_path}).empty()) {
      fail(why, r.colour_path + ": missing colour image");
      return nullptr;
    }
    if (first_existing_file({r.depth_path}).empty()) {
      fail(why, r.depth_path + ": missing depth image");
      return nullptr;
    }
  }
  if (options.intrinsics) {
    index.camera = *options.intrinsics;
    index.camera_source = "explicit intrinsics";
  }
  if (options.colour_camera) {
    std::string reason;
    if (!options.colour_camera->is_valid(&reason)) {
      fail(why, "colour camera: " + reason);
      return nullptr;
    }
    index.colour_camera = options.colour_camera;
  }
  // The first frame's depth image fixes the size when the intrinsics do not state one, and
  // catches a stated size that does not fit the images before any frame is processed.
  const std::string& probe = index.frames.front().depth_path;
  cv::Mat depth;
  if (!read_depth_image(probe, index.depth_scale, &depth, why)) return nullptr;
  PinholeCamera& camera = index.camera;
  if (camera.width == 0 && camera.height == 0) {
    camera.width = depth.cols;
    camera.height = depth.rows;
  } else if (camera.width != depth.cols || camera.height != depth.rows) {
    fail(why, probe + ": image is " + size_text(depth.cols, depth.rows) + " but " +
                  index.camera_source + " gives " + size_text(camera.width, camera.height));
    return nullptr;
  }
  std::string reason;
  if (!camera.is_valid(&reason)) {
    fail(why, index.camera_source + ": bad intrinsics: " + reason);
    return nullptr;
  }
  return std::make_unique<IndexedDataset>(std::move(index));
}

bool rigid_pose_from_matrix(const Eigen::Matrix4d& M, const std::string& source,
                            Eigen::Isometry3d* T, std::string* why) {
  if (!M.allFinite()) return fail(why, source + ": pose has non-finite values");
  if (!is_rigid(M, kPoseRigidityTolerance)) {
    const Eigen::Matrix3d R = M.topLeftCorner<3, 3>();
    std::ostringstream s;
    s << source << ": pose is not a rigid transform (rotation det " << R.determinant()
      << ", max |R^T R - I| "
      << (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() << ", last row "
      << M.row(3) << "; expected det 1, orthonormal, last row 0 0 0 1, within "
      << kPoseRigidityTolerance << ")";
    return fail(why, s.str());
  }
  *T = orthonormalise(M);
  return true;
}

bool camera_from_values(const std::vector<double>& values, PinholeCamera* camera,
                        std::string* why) {
  if (values.size() != 4 && values.size() != 6)
    return fail(why, "expected fx fy cx cy or fx fy cx cy width height, found " +
                         std::to_string(values.size()) + " numbers");
  PinholeCamera c;
  c.fx = values[0];
  c.fy = values[1];
  c.cx = values[2];
  c.cy = values[3];
  if (values.size() == 6) {
    constexpr double kMaxSide = 1 << 20;  // pixels; keeps the cast to int exact
    for (const double side : {values[4], values[5]})
      if (!(side >= 1.0 && side <= kMaxSide && side == std::floor(side)))
        return fail(why, "width and height must be positive integers");
    c.width = static_cast<int>(values[4]);
    c.height = static_cast<int>(values[5]);
  }
  *camera = c;
  return true;
}

std::string normalise_root(const std::string& path) {
  fs::path p = fs::path(path).lexically_normal();
  if (!p.has_filename() && p.has_parent_path() && p != p.root_path()) p = p.parent_path();
  const std::string s = p.string();
  return s.empty() ? "." : s;
}

std::string join_path(const std::string& dir, const std::string& name) {
  return (fs::path(dir) / name).string();
}

std::string parent_folder(const std::string& path) {
  const fs::path p(normalise_root(path));
  if (p.has_parent_path()) return p.parent_path().string();
  std::error_code ec;
  fs::path absolute = fs::absolute(p, ec).lexically_normal();
  if (!absolute.has_filename()) absolute = absolute.parent_path();
  return absolute.parent_path().string();
}

std::string first_existing_file(const std::vector<std::string>& candidates) {
  for (const std::string& candidate : candidates) {
    std::error_code ec;
    if (fs::is_regular_file(candidate, ec)) return candidate;
  }
  return {};
}

std::vector<NumberedFile> list_numbered_files(const std::string& dir, const std::string& prefix,
                                              const std::string& suffix) {
  std::vector<NumberedFile> files;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() <= prefix.size() + suffix.size() ||
        name.compare(0, prefix.size(), prefix) != 0 ||
        name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0)
      continue;
    const std::string digits =
        name.substr(prefix.size(), name.size() - prefix.size() - suffix.size());
    if (digits.size() > 18 ||
        !std::all_of(digits.begin(), digits.end(), [](unsigned char c) { return std::isdigit(c); }))
      continue;
    files.push_back({std::stoll(digits), digits, (fs::path(dir) / name).string()});
  }
  std::sort(files.begin(), files.end(),
            [](const NumberedFile& a, const NumberedFile& b) { return a.number < b.number; });
  return files;
}

}  // namespace fslam::core
