// Fuzz target: the dataset index readers (TUM rgb.txt / depth.txt / groundtruth.txt /
// intrinsics.txt, 7-Scenes pose and intrinsics files, Replica traj.txt and cam_params.json).
// Input: one byte choosing the layout, then that layout's text files separated by NUL bytes (an
// empty part = the file is absent). The images exist but are empty: opening checks the index,
// reading a frame is not fuzzed here (frame_fuzz covers the decoders).
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "fslam/core/dataset/readers.hpp"
#include "fuzz_support.hpp"

namespace fs = std::filesystem;

namespace {

std::vector<std::string> split_nul(const std::string& text, std::size_t parts) {
  std::vector<std::string> out;
  std::string rest = text;
  for (std::size_t i = 0; i + 1 < parts; ++i) {
    auto [head, tail] = fslam::fuzz::split_once(rest, std::string(1, '\0'));
    out.push_back(head);
    rest = tail;
  }
  out.push_back(rest);
  return out;
}

void put(const fs::path& file, const std::string& text) {
  if (text.empty()) {
    fs::remove(file);
    return;
  }
  fslam::fuzz::write_scratch(fs::relative(file, fslam::fuzz::scratch_dir()).string(),
                             reinterpret_cast<const std::uint8_t*>(text.data()), text.size());
}

void touch(const fs::path& file) { fslam::fuzz::write_scratch(fs::relative(file, fslam::fuzz::scratch_dir()).string(), nullptr, 0); }

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const int layout = data[0] % 3;
  const std::string text(reinterpret_cast<const char*>(data + 1), size - 1);
  const fs::path root = fs::path(fslam::fuzz::scratch_dir()) / ("layout" + std::to_string(layout));
  fs::create_directories(root / "results");
  fslam::core::DatasetOptions options;
  std::string why;
  std::unique_ptr<fslam::core::Dataset> dataset;
  if (layout == 0) {
    const auto parts = split_nul(text, 4);
    put(root / "rgb.txt", parts[0]);
    put(root / "depth.txt", parts[1]);
    put(root / "groundtruth.txt", parts[2]);
    put(root / "intrinsics.txt", parts[3]);
    dataset = fslam::core::open_tum_dataset(root.string(), options, &why);
  } else if (layout == 1) {
    const auto parts = split_nul(text, 3);
    for (const char* stem : {"frame-000000", "frame-000001"}) {
      touch(root / (std::string(stem) + ".color.png"));
      touch(root / (std::string(stem) + ".depth.png"));
    }
    put(root / "frame-000000.pose.txt", parts[0]);
    put(root / "frame-000001.pose.txt", parts[1]);
    put(root / "camera-intrinsics.txt", parts[2]);
    dataset = fslam::core::open_seven_scenes_dataset(root.string(), options, &why);
  } else {
    const auto parts = split_nul(text, 2);
    for (const char* n : {"000000", "000001"}) {
      touch(root / "results" / (std::string("frame") + n + ".jpg"));
      touch(root / "results" / (std::string("depth") + n + ".png"));
    }
    put(root / "traj.txt", parts[0]);
    put(root / "cam_params.json", parts[1]);
    dataset = fslam::core::open_replica_dataset(root.string(), options, &why);
  }
  if (!dataset && why.empty()) __builtin_trap();  // every refusal says why
  return 0;
}
