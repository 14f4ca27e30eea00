// Writes a synthetic sequence in TUM RGB-D layout, frames in parallel. Each frame depends only on
// (seed, frame index), so the bytes are the same for any thread count.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <filesystem>
#include <limits>
#include <mutex>
#include <iomanip>
#include <sstream>
#include <string>

#include "fslam/core/error.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

// Writes `text` to `path` in one go; false with a message on any error.
bool write_text(const fs::path& path, const std::string& text, std::string* why) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) return fail(why, path.string() + ": cannot open for writing");
  const bool ok = std::fwrite(text.data(), 1, text.size(), f) == text.size();
  if (std::fclose(f) != 0 || !ok) return fail(why, path.string() + ": write failed");
  return true;
}

// zlib level 1 and a fixed row filter per image kind: with write_image's defaults, encoding took
// more time than rendering (colour 64 -> 13 ms with `sub`, depth 37 -> 6 ms with `none`, labels
// 4 -> 2 ms with `up`, at most 7 % more bytes).
bool write_png(const fs::path& path, const cv::Mat& image, ImageWriteOptions::PngFilter filter,
               std::string* why) {
  ImageWriteOptions options;
  options.png_compression = 1;
  options.png_filter = filter;
  return write_image(path.string(), image, why, options);
}

std::string header(const SynthOptions& options) {
  std::ostringstream s;
  s << "# fslam synth: seed " << options.seed << ", " << options.frames << " frames at "
    << kSynthFrameRate << " Hz, noise " << to_string(options.noise) << ", path " << to_string(options.path);
  if (options.path == SynthPath::loop) s << " (" << options.laps << " laps)";
  s << "\n";
  return s.str();
}

}  // namespace

bool SynthOptions::is_valid(std::string* why) const {
  if (frames == 0) return fail(why, "frames must be at least 1");
  if (frames > kMaxFrames)
    return fail(why, "frames must be at most " + std::to_string(kMaxFrames) + ", got " +
                         std::to_string(frames));
  if (noise != SynthNoise::none && noise != SynthNoise::kinect)
    return fail(why, "unknown noise model");
  if (path == SynthPath::loop && laps < 1) return fail(why, "laps must be at least 1");
  std::string camera_why;
  if (!camera.is_valid(&camera_why)) return fail(why, "camera: " + camera_why);
  return true;
}

std::string synth_timestamp(std::size_t frame) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(6) << static_cast<double>(frame) / kSynthFrameRate;
  return s.str();
}

bool write_synthetic_sequence(const std::string& dir, const SynthOptions& options,
                              const SynthProgress& progress, std::string* why) {
  if (!options.is_valid(why)) return false;
  if (dir.empty()) return fail(why, "no output folder given");
  const fs::path root(dir);
  std::error_code ec;
  if (fs::exists(root, ec)) {
    if (!fs::is_directory(root, ec)) return fail(why, dir + ": exists and is not a folder");
    if (!fs::is_empty(root, ec))
      return fail(why, dir + ": folder is not empty (choose a new or empty folder)");
  }
  for (const char* sub : {"rgb", "depth", "labels/instance", "labels/class"}) {
    fs::create_directories(root / sub, ec);
    if (ec)
      return fail(why, (root / sub).string() + ": cannot create folder (" + ec.message() + ")");
  }

  const SyntheticRoom room = make_scene(options.scene, options.seed);
  const Trajectory trajectory = make_trajectory(room, options);

  // Frames after a failure are skipped; of the frames that failed, the lowest is reported.
  std::atomic<bool> failed{false};
  std::mutex mutex;
  std::size_t failed_frame = std::numeric_limits<std::size_t>::max();
  std::string failure;
  std::size_t done = 0;

  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, options.frames, 1),
      [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t i = range.begin(); i < range.end(); ++i) {
          if (failed.load()) return;
          SynthView view = render_view(room, options.camera, trajectory[i].T_world_camera);
          if (options.noise == SynthNoise::kinect)
            apply_kinect_noise(options.camera, options.seed, i, &view);
          const std::string name = synth_timestamp(i) + ".png";
          std::string frame_why;
          const bool ok =
              write_png(root / "rgb" / name, view.colour, ImageWriteOptions::kPngSub, &frame_why) &&
              write_png(root / "depth" / name, depth_to_u16(view.depth, kSynthDepthScale),
                        ImageWriteOptions::kPngNone, &frame_why) &&
              write_png(root / "labels" / "instance" / name, view.instance_label, ImageWriteOptions::kPngUp,
                        &frame_why) &&
              write_png(root / "labels" / "class" / name, view.class_label, ImageWriteOptions::kPngUp,
                        &frame_why);
          std::lock_guard<std::mutex> lock(mutex);
          if (!ok) {
            failed.store(true);
            if (i < failed_frame) {
              failed_frame = i;
              failure = frame_why;
            }
            return;
          }
          ++done;
          if (progress) progress(done, options.frames);
        }
      });
  if (failed.load()) return fail(why, "frame " + std::to_string(failed_frame) + ": " + failure);

  // Index files last: their presence marks a complete sequence.
  std::ostringstream rgb, depth, classes, instances, intrinsics;
  rgb << "# color images\n" << header(options) << "# timestamp filename\n";
  depth << "# depth maps: 16-bit PNG, metres * " << kSynthDepthScale << ", 0 = missing\n"
        << header(options) << "# timestamp filename\n";
  for (std::size_t i = 0; i < options.frames; ++i) {
    const std::string stamp = synth_timestamp(i);
    rgb << stamp << " rgb/" << stamp << ".png\n";
    depth << stamp << " depth/" << stamp << ".png\n";
  }
  classes << "# semantic classes of labels/class/*.png (16-bit); 0 never occurs in fslam synth\n"
          << "# class_id name\n";
  for (int c = 0; c < kSynthClassCount; ++c)
    classes << c << " " << synth_class_name(static_cast<SynthClass>(c)) << "\n";
  instances << "# instances of labels/instance/*.png (16-bit); walls, floor and ceiling included\n"
            << "# instance_id class_id name\n";
  for (const SynthObject& o : room.objects)
    instances << o.instance_id << " " << static_cast<int>(o.class_id) << " " << o.name << "\n";
  const PinholeCamera& c = options.camera;
  intrinsics << "# pinhole intrinsics of rgb/ and depth/ (registered, no distortion)\n"
             << "# fx fy cx cy width height\n"
             << std::setprecision(10) << c.fx << " " << c.fy << " " << c.cx << " " << c.cy << " "
             << c.width << " " << c.height << "\n";
  return write_text(root / "rgb.txt", rgb.str(), why) &&
         write_text(root / "depth.txt", depth.str(), why) &&
         write_text(root / "classes.txt", classes.str(), why) &&
         write_text(root / "instances.txt", instances.str(), why) &&
         write_text(root / "intrinsics.txt", intrinsics.str(), why) &&
         write_tum_trajectory((root / "groundtruth.txt").string(), trajectory, why);
}

}  // namespace fslam::core
