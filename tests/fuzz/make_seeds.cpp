// Writes the seed corpora of the fuzz targets (tests/fuzz/corpus/<target>/), all generated here:
// valid inputs of every kind each parser accepts, so that the fuzzer starts past the first checks.
//   fslam_fuzz_make_seeds OUT_DIR [ONNX_MODEL_DIR]
// run_fuzz.sh --seeds regenerates the committed corpora with it.
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "fslam/core/features/feature_autoencoder.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/keyframe_file.hpp"
#include "fslam/core/io/keyframe_images_file.hpp"

namespace fs = std::filesystem;

namespace {

class Bytes {
 public:
  template <typename T>
  Bytes& put(T value) {
    const auto* p = reinterpret_cast<const std::uint8_t*>(&value);
    data.insert(data.end(), p, p + sizeof(T));
    return *this;
  }
  Bytes& append(const std::vector<std::uint8_t>& bytes) {
    data.insert(data.end(), bytes.begin(), bytes.end());
    return *this;
  }
  std::vector<std::uint8_t> data;
};

void write(const fs::path& path, const std::vector<std::uint8_t>& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()),
                                              static_cast<std::streamsize>(bytes.size()));
}
void write(const fs::path& path, const std::string& text) {
  write(path, std::vector<std::uint8_t>(text.begin(), text.end()));
}

// encoding 0 RAW, 1 PNG, 2 JPEG (fslam_proto_ImageEncoding).
std::vector<std::uint8_t> encode(const cv::Mat& image, int encoding) {
  if (encoding == 0) return std::vector<std::uint8_t>(image.datastart, image.dataend);
  std::vector<std::uint8_t> out;
  cv::imencode(encoding == 1 ? ".png" : ".jpg", image, out);
  return out;
}

// frame_fuzz.cpp's layout.
std::vector<std::uint8_t> frame(int colour_encoding, int depth_encoding, bool with_pose) {
  const int w = 16, h = 12;
  cv::Mat colour(h, w, CV_8UC3), depth(h, w, CV_16UC1);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      colour.at<cv::Vec3b>(v, u) = cv::Vec3b(u * 15, v * 20, 128);
      depth.at<std::uint16_t>(v, u) = static_cast<std::uint16_t>(u == 0 ? 0 : 1000 + 10 * (u + v));
    }
  }
  const auto c = encode(colour, colour_encoding), d = encode(depth, depth_encoding);
  Bytes b;
  b.put<std::uint64_t>(7).put<double>(1.5);
  b.put<float>(20.0f).put<float>(20.0f).put<float>(7.5f).put<float>(5.5f);
  b.put<std::uint16_t>(w).put<std::uint16_t>(h).put<float>(1000.0f);
  b.put<std::uint8_t>(colour_encoding).put<std::uint16_t>(w).put<std::uint16_t>(h);
  b.put<std::uint8_t>(3).put<std::uint8_t>(1);
  b.put<std::uint8_t>(depth_encoding).put<std::uint16_t>(w).put<std::uint16_t>(h);
  b.put<std::uint8_t>(1).put<std::uint8_t>(2);
  b.put<std::uint8_t>(with_pose ? 1 : 0);
  for (double t : {0.1, -0.2, 1.0}) b.put<double>(t);
  for (double q : {0.0, 0.0, 0.0, 1.0}) b.put<double>(q);
  b.put<std::uint32_t>(static_cast<std::uint32_t>(c.size())).append(c).append(d);
  return b.data;
}

// request_fuzz.cpp's layout: kind, id, the prompt view, segment mode, output view, points, boxes,
// export fields, then map name, path and text (a length byte each, the text the rest).
struct RequestSeed {
  int kind = 0;           // fslam_proto_RequestKind: 0 render, 1 save, 2 load, 3 segment, 4 export
  bool from_frame = false;
  std::uint16_t width = 0, height = 0;  // 0: the map's camera
  int channels = 1;
  int mode = 0;           // fslam_proto_SegmentMode: 0 promptless, 1 points, 2 boxes, 3 text
  std::vector<float> points, boxes;
  std::string map = "room", path, text;
};

void put_view(Bytes& b, const RequestSeed& r) {
  b.put<std::uint8_t>(r.from_frame ? 1 : 0).put<std::uint64_t>(5);
  for (double t : {0.1, 0.0, -0.5}) b.put<double>(t);
  for (double q : {0.0, 0.0, 0.0, 1.0}) b.put<double>(q);
  b.put<float>(500.0f).put<float>(500.0f).put<float>(r.width / 2.0f - 0.5f).put<float>(r.height / 2.0f - 0.5f);
  b.put<std::uint16_t>(r.width).put<std::uint16_t>(r.height);
  b.put<std::uint8_t>(static_cast<std::uint8_t>(r.channels)).put<float>(0.0f);
}

std::vector<std::uint8_t> request(const RequestSeed& r) {
  Bytes b;
  b.put<std::uint8_t>(static_cast<std::uint8_t>(r.kind)).put<std::uint64_t>(1ull << 62);
  put_view(b, r);
  b.put<std::uint8_t>(static_cast<std::uint8_t>(r.mode)).put<std::uint8_t>(0);
  put_view(b, r);
  for (const std::vector<float>* v : {&r.points, &r.boxes}) {
    b.put<std::uint8_t>(static_cast<std::uint8_t>(v->size()));
    for (float x : *v) b.put<float>(x);
  }
  b.put<std::uint64_t>(0).put<std::uint64_t>(0).put<std::uint32_t>(0).put<std::uint32_t>(0);
  for (const std::string* s : {&r.map, &r.path}) {
    b.put<std::uint8_t>(static_cast<std::uint8_t>(s->size()));
    b.append(std::vector<std::uint8_t>(s->begin(), s->end()));
  }
  b.append(std::vector<std::uint8_t>(r.text.begin(), r.text.end()));
  return b.data;
}

fslam::core::GaussianMap small_map(int sh_degree, int feature_dim) {
  fslam::core::GaussianMap map;
  map.sh_degree = sh_degree;
  map.feature_dim = feature_dim;
  std::vector<float> sh(static_cast<std::size_t>(map.sh_per_gaussian()), 0.1f);
  std::vector<float> f(static_cast<std::size_t>(feature_dim), 0.5f);
  for (int i = 0; i < 3; ++i) {
    const float mean[3] = {0.1f * i, 0.2f, 1.0f + i}, rot[4] = {1, 0, 0, 0};
    const float log_scale[3] = {-3, -3.5f, -4};
    map.push_back(mean, rot, log_scale, 0.5f * i, sh.data(), feature_dim ? f.data() : nullptr, 1e-6f);
  }
  return map;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s OUT_DIR [ONNX_MODEL_DIR]\n", argv[0]);
    return 2;
  }
  const fs::path out = argv[1];
  std::string why;

  write(out / "frame/raw_raw", frame(0, 0, false));
  write(out / "frame/png_png_pose", frame(1, 1, true));
  write(out / "frame/jpeg_png", frame(2, 1, false));
  write(out / "frame/jpeg_raw_pose", frame(2, 0, true));

  RequestSeed r;
  write(out / "request/render_pose_map_camera", request(r));
  r.from_frame = true, r.width = 320, r.height = 240, r.channels = 15;
  write(out / "request/render_frame_all_channels", request(r));
  r.kind = 3, r.mode = 1, r.points = {10.0f, 20.0f, 300.0f, 200.0f};
  write(out / "request/segment_points", request(r));
  r.mode = 2, r.points = {}, r.boxes = {0.0f, 0.0f, 100.0f, 80.0f};
  write(out / "request/segment_boxes", request(r));
  r.mode = 3, r.boxes = {}, r.text = "the red chair";
  write(out / "request/segment_text", request(r));
  RequestSeed save;
  save.kind = 1, save.path = "kitchen/monday";
  write(out / "request/save_folder", request(save));
  save.kind = 2, save.map = "kitchen.v2", save.path = "";
  write(out / "request/load_by_name", request(save));
  save.kind = 4;
  write(out / "request/export", request(save));

  for (auto [sh, d] : {std::pair{0, 16}, std::pair{1, 0}, std::pair{3, 4}}) {
    const fs::path p = out / ("ply/sh" + std::to_string(sh) + "_d" + std::to_string(d) + ".ply");
    fs::create_directories(p.parent_path());
    if (!fslam::core::write_gaussian_ply(p.string(), small_map(sh, d), &why)) {
      std::fprintf(stderr, "%s\n", why.c_str());
      return 1;
    }
  }
  write(out / "ply/ascii.ply",
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "property float z\nproperty float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n"
        "property float opacity\nproperty float scale_0\nproperty float scale_1\n"
        "property float scale_2\nproperty float rot_0\nproperty float rot_1\nproperty float rot_2\n"
        "property float rot_3\nend_header\n0 0 1 0.1 0.2 0.3 0.5 -3 -3 -3 1 0 0 0\n"
        "0.5 0 2 0 0 0 -1 -4 -4 -4 0.7 0.7 0 0\n");

  write(out / "trajectory/tum.txt",
        "# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n1.033,0.01,0,0.02,0,0.0087,0,0.99996\n"
        "\n1.066\t0.02 0 0.04 0 0.0175 0 0.99985\n");

  {
    std::vector<fslam::core::DescribedKeyframe> keyframes(2);
    keyframes[1].id = 40;
    keyframes[1].T_world_camera.translation() = Eigen::Vector3d(0.1, 0.0, -0.2);
    for (auto& kf : keyframes) {
      kf.description.descriptors = cv::Mat(3, 32, CV_8UC1, cv::Scalar(0x5a));
      kf.description.points = {{0.0f, 0.0f, 1.0f}, {0.1f, 0.0f, 1.2f}, {0.0f, 0.1f, 0.9f}};
      kf.description.global = {0.5f, -0.5f, 0.5f, -0.5f};
    }
    fs::create_directories(out / "keyframes");
    if (!fslam::core::write_keyframe_file((out / "keyframes/two.bin").string(), keyframes, &why)) {
      std::fprintf(stderr, "%s\n", why.c_str());
      return 1;
    }
  }

  {
    // Two keyframes of a 16x12 camera kept at half scale.
    std::vector<fslam::core::KeyframeImages> keyframes(2);
    keyframes[1].frame_id = -1;
    keyframes[1].T_world_camera.translation() = Eigen::Vector3d(0.1, 0.0, -0.2);
    for (auto& kf : keyframes) {
      kf.input_camera = {12.0, 12.0, 7.5, 5.5, 16, 12};
      kf.colour = cv::Mat(6, 8, CV_8UC3, cv::Scalar(10, 120, 240));
      kf.depth = cv::Mat(6, 8, CV_32FC1, cv::Scalar(1.25f));
    }
    fs::create_directories(out / "keyframe_images");
    if (!fslam::core::write_keyframe_images_file((out / "keyframe_images/two.bin").string(), keyframes, &why)) {
      std::fprintf(stderr, "%s\n", why.c_str());
      return 1;
    }
  }

  const std::string nul(1, '\0');
  write(out / "dataset/tum",
        std::string(1, '\0') + "# rgb\n1.0 rgb/1.png\n1.033 rgb/2.png\n" + nul +
            "1.001 depth/1.png\n1.034 depth/2.png\n" + nul + "1.0 0 0 0 0 0 0 1\n1.1 0.1 0 0 0 0 0 1\n" +
            nul + "525 525 319.5 239.5 640 480\n");
  const std::string pose = "1 0 0 0.1\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
  write(out / "dataset/seven_scenes", std::string(1, '\1') + pose + nul + pose + nul + "585 0 320\n0 585 240\n0 0 1\n");
  write(out / "dataset/replica",
        std::string(1, '\2') + "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0.1 0 1 0 0 0 0 1 0 0 0 0 1\n" + nul +
            "{\"camera\": {\"w\": 1200, \"h\": 680, \"fx\": 600.0, \"fy\": 600.0, \"cx\": 599.5, "
            "\"cy\": 339.5, \"scale\": 6553.5}}\n");

  fslam::core::FeatureAutoencoderConfig small;
  small.level_channels = {4, 3, 2};
  small.latent_dim = 3;
  small.encoder_hidden = 5;
  small.head_hidden = 2;
  small.lora_rank = 1;
  fslam::core::FeatureAutoencoder model(small);
  model.set_notes("fuzz seed");
  fs::create_directories(out / "autoencoder");
  if (!model.save((out / "autoencoder/small.fae").string(), &why)) {
    std::fprintf(stderr, "%s\n", why.c_str());
    return 1;
  }

  if (argc > 2) {
    for (const auto& entry : fs::directory_iterator(argv[2])) {
      if (entry.path().extension() != ".onnx") continue;
      fs::create_directories(out / "onnx");
      fs::copy_file(entry.path(), out / "onnx" / entry.path().filename(),
                    fs::copy_options::overwrite_existing);
    }
  }
  std::printf("seeds written under %s\n", out.c_str());
  return 0;
}
