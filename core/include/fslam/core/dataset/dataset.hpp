// Recorded RGB-D sequences on disk behind one interface: TUM RGB-D, 7-Scenes and Replica
// (docs/datasets.md describes each layout and its conventions).
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/colour_camera.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {

// Which frames of a sequence to use: positions begin, begin + stride, ... below end (half-open,
// like a Python slice); positions count frames in the dataset's order, not file numbers.
struct FrameSelection {
  static constexpr std::size_t kToEnd = std::numeric_limits<std::size_t>::max();
  std::size_t begin = 0;
  std::size_t end = kToEnd;  // exclusive; past the end of the sequence means "to the end"
  std::size_t stride = 1;

  // "A:B", "A:B:S", "A:", ":B", "::S" (empty fields keep their defaults).
  static bool parse(const std::string& text, FrameSelection* selection, std::string* why);
  std::string to_string() const;  // the form parse() reads
  bool selects_all() const { return begin == 0 && end == kToEnd && stride == 1; }
  // Positions selected from `count` frames; fails (naming `source`) when none would be.
  bool apply(std::size_t count, const std::string& source, std::vector<std::size_t>* positions,
             std::string* why) const;
};

// "fx,fy,cx,cy" or "fx,fy,cx,cy,width,height" (commas or spaces); width and height stay 0 (taken
// from the images) when not given. Only the numbers are checked here, not the camera's validity.
bool parse_intrinsics(const std::string& text, PinholeCamera* camera, std::string* why);

struct DatasetOptions {
  std::string kind = "auto";  // auto | tum | 7scenes | replica
  FrameSelection frames;
  // Wins over the dataset's own intrinsics; width/height 0 means "the images' size".
  std::optional<PinholeCamera> intrinsics;
  // The colour sensor, when colour is not registered to depth: load() then resamples each
  // colour image onto the depth pixels (register_colour_to_depth), and colour images may have
  // their own size. Unset: colour and depth share camera().
  std::optional<ColourCamera> colour_camera;
};

// One opened sequence: an index validated once at opening, frames read from disk on demand.
class Dataset {
 public:
  virtual ~Dataset() = default;

  virtual std::string kind() const = 0;         // tum | 7scenes | replica
  virtual const std::string& root() const = 0;  // the folder it was opened from
  virtual std::size_t size() const = 0;         // frames after selection
  virtual const PinholeCamera& camera() const = 0;
  // Where camera() came from: a file, a preset, defaults or the caller's override.
  virtual std::string camera_source() const = 0;
  virtual double depth_scale() const = 0;  // raw depth units per metre

  // Frame `index` (0 .. size()-1 of the selection): colour (registered to depth when a colour
  // camera was given), depth in metres, camera, id, timestamp and ground truth when known. Fails naming the file when an image is unreadable,
  // not 16-bit single-channel depth, or not the camera's size. Safe to call from many threads.
  virtual bool load(std::size_t index, RgbdFrame* frame, std::string* why) const = 0;

  // RgbdFrame::id and ::timestamp of frame `index` (< size()), without loading it.
  virtual std::int64_t id(std::size_t index) const = 0;
  virtual double timestamp(std::size_t index) const = 0;

  virtual bool has_ground_truth() const = 0;
  // Camera-to-world poses of the selected frames that have one, stamped with their timestamps.
  virtual Trajectory ground_truth() const = 0;

  // True when at least one selected frame has a label image.
  virtual bool has_labels() const { return false; }
  // Per-frame instance and class label images (single-channel 8/16-bit, the camera's size);
  // either output may be null, and one that the frame lacks is left empty. False when the frame
  // has neither or an image is unreadable.
  virtual bool load_labels(std::size_t index, cv::Mat* instance, cv::Mat* cls,
                           std::string* why) const;
};

// The kinds open_dataset() understands, "auto" excluded.
const std::vector<std::string>& dataset_kinds();

// The kind of the sequence in `path`, from the files it holds (docs/datasets.md, "Kind detection").
bool detect_dataset_kind(const std::string& path, std::string* kind, std::string* why);

// Opens the sequence in `path` as options.kind (detected when "auto"), validating its index.
std::unique_ptr<Dataset> open_dataset(const std::string& path, const DatasetOptions& options,
                                      std::string* why);

}  // namespace fslam::core
