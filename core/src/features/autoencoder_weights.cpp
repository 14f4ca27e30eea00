// The feature autoencoder's weights file.
#include "fslam/core/features/feature_autoencoder.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include "autoencoder_math.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/io/file_writer.hpp"

namespace fslam::core {

using namespace autoencoder_detail;  // NOLINT: the file's own helpers, private to core/src/features

// ---- Weights file ------------------------------------------------------------------------------
// Little-endian throughout: magic "FSLAMFAE", u32 version, the config, u32 notes length + bytes,
// f32 mean[C], f32 std[C], u32 tensor count, then per tensor u32 name length + name, u32 rows,
// u32 cols, f32 data[rows * cols]. Nothing may follow.
namespace {

constexpr char kMagic[8] = {'F', 'S', 'L', 'A', 'M', 'F', 'A', 'E'};
constexpr std::uint32_t kVersion = 1;
constexpr std::uint32_t kMaxNotes = 1u << 20;
constexpr std::uint32_t kMaxName = 256;

class Writer {
 public:
  void u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) bytes_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  }
  void f32(float v) {
    std::uint32_t bits;
    std::memcpy(&bits, &v, 4);
    u32(bits);
  }
  void floats(const float* p, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i) f32(p[i]);
  }
  void text(const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size()));
    bytes_.insert(bytes_.end(), s.begin(), s.end());
  }
  void raw(const char* p, std::size_t n) { bytes_.insert(bytes_.end(), p, p + n); }
  const std::vector<char>& bytes() const { return bytes_; }

 private:
  std::vector<char> bytes_;
};

class Reader {
 public:
  explicit Reader(std::vector<char> bytes) : bytes_(std::move(bytes)) {}
  // Each read fails once the file is too short, naming what it was reading.
  bool u32(std::uint32_t* v, const char* what) {
    if (!need(4, what)) return false;
    *v = 0;
    for (int i = 0; i < 4; ++i)
      *v |= static_cast<std::uint32_t>(static_cast<unsigned char>(bytes_[pos_ + i])) << (8 * i);
    pos_ += 4;
    return true;
  }
  bool f32(float* v, const char* what) {
    std::uint32_t bits;
    if (!u32(&bits, what)) return false;
    std::memcpy(v, &bits, 4);
    return true;
  }
  bool floats(float* p, std::size_t n, const char* what) {
    if (!need(4 * n, what)) return false;
    for (std::size_t i = 0; i < n; ++i) f32(p + i, what);
    return true;
  }
  bool text(std::string* s, std::uint32_t max, const char* what) {
    std::uint32_t n;
    if (!u32(&n, what)) return false;
    if (n > max) return fail_with(std::string(what) + " is " + std::to_string(n) + " bytes long");
    if (!need(n, what)) return false;
    s->assign(bytes_.data() + pos_, n);
    pos_ += n;
    return true;
  }
  bool magic() {
    if (bytes_.size() < sizeof(kMagic) || std::memcmp(bytes_.data(), kMagic, sizeof(kMagic)) != 0)
      return fail_with("not a feature autoencoder file (wrong magic)");
    pos_ = sizeof(kMagic);
    return true;
  }
  bool at_end() {
    if (pos_ == bytes_.size()) return true;
    return fail_with(std::to_string(bytes_.size() - pos_) +
                     " unexpected bytes after the last tensor");
  }
  bool fail_with(const std::string& message) {
    error_ = message;
    return false;
  }
  const std::string& error() const { return error_; }

 private:
  bool need(std::size_t n, const char* what) {
    if (bytes_.size() - pos_ >= n) return true;
    return fail_with("truncated at byte " + std::to_string(bytes_.size()) + " while reading " +
                     what);
  }
  std::vector<char> bytes_;
  std::size_t pos_ = 0;
  std::string error_;
};

}  // namespace

bool FeatureAutoencoder::save(const std::string& path, std::string* why) const {
  Writer w;
  w.raw(kMagic, sizeof(kMagic));
  w.u32(kVersion);
  w.u32(static_cast<std::uint32_t>(config_.level_channels.size()));
  for (int c : config_.level_channels) w.u32(static_cast<std::uint32_t>(c));
  w.u32(static_cast<std::uint32_t>(config_.latent_dim));
  w.u32(static_cast<std::uint32_t>(config_.encoder_hidden));
  w.u32(static_cast<std::uint32_t>(config_.head_hidden));
  w.u32(static_cast<std::uint32_t>(config_.activation));
  w.u32(static_cast<std::uint32_t>(config_.lora_rank));
  w.f32(config_.lora_alpha);
  w.u32(config_.seed);
  w.text(notes_);
  w.floats(mean_.data(), mean_.size());
  w.floats(std_.data(), std_.size());
  w.u32(static_cast<std::uint32_t>(tensors_.size()));
  for (const auto& t : tensors_) {
    w.text(t.name);
    w.u32(static_cast<std::uint32_t>(t.rows));
    w.u32(static_cast<std::uint32_t>(t.cols));
    w.floats(params_.data() + t.offset, t.size());
  }
  // Checked writes and fsync (a full disk names the file): the file may be part of a map's save.
  if (!write_file(path, std::string(w.bytes().begin(), w.bytes().end()), why)) {
    if (why != nullptr) *why = "autoencoder: " + *why;
    return false;
  }
  return true;
}

bool FeatureAutoencoder::same_body(const FeatureAutoencoder& other) const {
  const FeatureAutoencoderConfig& a = config_;
  const FeatureAutoencoderConfig& b = other.config_;
  return a.level_channels == b.level_channels && a.latent_dim == b.latent_dim &&
         a.encoder_hidden == b.encoder_hidden && a.head_hidden == b.head_hidden &&
         a.activation == b.activation && a.lora_rank == b.lora_rank && a.lora_alpha == b.lora_alpha &&
         mean_ == other.mean_ && std_ == other.std_ && body_size_ == other.body_size_ &&
         std::equal(params_.begin(), params_.begin() + static_cast<std::ptrdiff_t>(body_size_),
                    other.params_.begin());
}

bool FeatureAutoencoder::load(const std::string& path, std::string* why) {
  std::ifstream file(path, std::ios::binary);
  if (!file) return fail(why, "autoencoder: cannot open " + path);
  Reader r(std::vector<char>(std::istreambuf_iterator<char>(file), {}));
  const auto bad = [&](const std::string& message) {
    return fail(why, "autoencoder weights " + path + ": " + message);
  };
  if (!r.magic()) return bad(r.error());
  std::uint32_t version = 0;
  if (!r.u32(&version, "the version")) return bad(r.error());
  if (version != kVersion)
    return bad("version " + std::to_string(version) + ", this build reads version " +
               std::to_string(kVersion));

  FeatureAutoencoderConfig config;
  std::uint32_t levels = 0, v = 0;
  if (!r.u32(&levels, "the level count")) return bad(r.error());
  if (levels < 1 || levels > 16) return bad(std::to_string(levels) + " levels (1..16 allowed)");
  config.level_channels.assign(levels, 0);
  std::uint32_t dims[5];
  for (auto& c : config.level_channels) {
    if (!r.u32(&v, "the level channels")) return bad(r.error());
    c = static_cast<int>(std::min<std::uint32_t>(v, 1u << 30));
  }
  for (auto& d : dims)
    if (!r.u32(&d, "the layer sizes")) return bad(r.error());
  const auto to_int = [](std::uint32_t x) {
    return static_cast<int>(std::min<std::uint32_t>(x, 1u << 30));
  };
  config.latent_dim = to_int(dims[0]);
  config.encoder_hidden = to_int(dims[1]);
  config.head_hidden = to_int(dims[2]);
  if (dims[3] > 1) return bad("unknown activation code " + std::to_string(dims[3]));
  config.activation = static_cast<AutoencoderActivation>(dims[3]);
  config.lora_rank = to_int(dims[4]);
  if (!r.f32(&config.lora_alpha, "lora_alpha") || !r.u32(&config.seed, "the seed"))
    return bad(r.error());
  config.online = config_.online;  // a run-time setting, not the file's
  std::string reason;
  if (!config.is_valid(&reason)) return bad(reason);

  FeatureAutoencoder loaded(config);
  if (!r.text(&loaded.notes_, kMaxNotes, "the notes")) return bad(r.error());
  if (!r.floats(loaded.mean_.data(), loaded.mean_.size(), "the normalisation means") ||
      !r.floats(loaded.std_.data(), loaded.std_.size(), "the normalisation stds"))
    return bad(r.error());
  if (!loaded.set_normalisation(loaded.mean_, loaded.std_, &reason)) return bad(reason);
  std::uint32_t count = 0;
  if (!r.u32(&count, "the tensor count")) return bad(r.error());
  if (count != loaded.tensors_.size())
    return bad(std::to_string(count) + " tensors, the stored shapes need " +
               std::to_string(loaded.tensors_.size()));
  for (const auto& t : loaded.tensors_) {
    std::string name;
    std::uint32_t rows = 0, cols = 0;
    if (!r.text(&name, kMaxName, "a tensor name") || !r.u32(&rows, "a tensor shape") ||
        !r.u32(&cols, "a tensor shape"))
      return bad(r.error());
    if (name != t.name || rows != static_cast<std::uint32_t>(t.rows) ||
        cols != static_cast<std::uint32_t>(t.cols))
      return bad("tensor '" + name + "' [" + std::to_string(rows) + ", " + std::to_string(cols) +
                 "] where '" + t.name + "' [" + std::to_string(t.rows) + ", " +
                 std::to_string(t.cols) + "] belongs");
    float* p = loaded.params_.data() + t.offset;
    if (!r.floats(p, t.size(), "tensor data")) return bad(r.error());
    if (!std::all_of(p, p + t.size(), [](float x) { return std::isfinite(x); }))
      return bad("tensor '" + t.name + "' has non-finite values");
  }
  if (!r.at_end()) return bad(r.error());
  *this = std::move(loaded);
  return true;
}

bool FeatureAutoencoder::load(const std::string& path,
                              const std::vector<FeatureLevelShape>& encoder_levels,
                              std::string* why) {
  FeatureAutoencoder candidate(config_);
  if (!candidate.load(path, why)) return false;
  std::string reason;
  if (!candidate.check_levels(encoder_levels, &reason))
    return fail(why, reason + " (weights " + path + ")");
  *this = std::move(candidate);
  return true;
}

}  // namespace fslam::core
