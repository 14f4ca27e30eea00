// The builtin encoder: a classical stand-in for SAM2's Hiera feature pyramid (paper sec. "Online
// Feature Rasterization") with the same three-level contract and no model file.
//
// Every descriptor channel is one "source" map (CIELAB lightness and shading-invariant chroma,
// their local standard deviation, oriented gradient energy, colour-edge energy, band-pass energy,
// soft colour-histogram bins), Gaussian-pooled over a window, resampled to its level, and
// normalised and weighted with fixed per-family constants.
//
// Units: "input pixels" are pixels of the frame resized to input_width x input_height (1024 x
// 1024 by default, SAM2's policy); the fine level is at stride 4, mid 8, coarse 16.
// - Pooling uses one cascade per source: index k holds the source blurred (sigma = 1 pixel) at
//   1/2^k of the fine level's resolution, i.e. pooled over sigma ~ 4 * 2^k input pixels. A level
//   at stride s takes the four pools from sigma = s up to 8 s, so it sees its own cell size up to
//   8 cells of context.
// - Derivatives are taken at strides 2, 4, 8 and 16 (scale d = 0..3): stride 2 on lightness
//   analysed at twice the fine level's resolution, so texture finer than the fine level's cells
//   still registers as energy; the others on the colour cascade.
// docs/features.md lists the channels and their limits.
#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "encoders.hpp"

namespace fslam::core::detail {
namespace {

constexpr int kPools = 6;   // pool indices 0..5: sigma ~ 4, 8, .., 128 input pixels
constexpr int kScales = 4;  // derivative scales 0..3: strides 2, 4, 8, 16 input pixels

// Per-family normalisation (docs/features.md, "Normalisation"): a channel is
// weight * t((value - offset) / scale) with fixed constants, so the same surface gives the same
// descriptor in every frame (no per-image statistics).
// - Colour (t = identity): `scale` is about the channels' spread over synthetic (`fslam synth`)
//   and 7-Scenes frames, so L*, ca and cb come out with standard deviations of 0.6-0.8.
// - Energies and spreads (t(x) = log(1 + x) of the RMS amplitude): `scale` is the knee of the
//   compression, which keeps strong edges (object boundaries) from dominating.
// - `weight` sets each family's share of the distance between two vectors u_i, chosen for
//   instance separation on synthetic rooms (tests/benchmarks/features_bench.cpp): chroma, which
//   shading does not move, above lightness; texture and spread below colour.
constexpr float kChromaAtMidGrey = 66.0f;  // L* + 16 at L* = 50
constexpr float kLightOffset = 50.0f;      // L* of mid grey
constexpr float kLightScale = 25.0f;       // CIELAB units
constexpr float kChromaScale = 25.0f;      // CIELAB units (a*, b* at L* = 50)
constexpr float kChromaWeight = 1.5f;
constexpr float kSpreadScale = 8.0f;       // CIELAB units
constexpr float kSpreadWeight = 0.25f;
constexpr float kGradScale = 4.0f;         // CIELAB units per pixel of the derivative's scale
constexpr float kBandScale = 3.0f;         // CIELAB units
constexpr float kTextureWeight = 0.75f;
constexpr float kBinWeight = 4.0f;         // a bin's pooled membership is in [0, 1]

// Soft colour histogram over (L*, ca, cb): 5 lightness centres x (grey + 7 hues), membership
// Gaussian in each factor and normalised, so the 40 bins of a pixel sum to 1.
constexpr int kLightBins = 5;
constexpr int kChromaBins = 8;
constexpr int kColourBins = kLightBins * kChromaBins;
constexpr float kLightSigma = 10.0f;   // L* units, centres 10, 30, .., 90
constexpr float kChromaRadius = 40.0f; // ca, cb units, the hue ring
constexpr float kChromaSigma = 20.0f;  // ca, cb units

enum class Source {
  L, ca, cb,               // CIELAB lightness and shading-invariant chroma (a*, b* / (L* + 16))
  L_std, ca_std, cb_std,   // local standard deviation of L, ca, cb within the pool window
  orient_0, orient_45, orient_90, orient_135,  // gradient energy of L* along 4 orientations
  colour_edge,             // |grad ca|^2 + |grad cb|^2
  band,                    // Laplacian-pyramid band of L* (L*_s - upsampled L*_{s+1}), squared
  colour_bin,              // soft colour-histogram membership
};

struct ChannelSpec {
  Source source = Source::L;
  int scale = 0;  // derivative scale for orient_*, colour_edge (d >= 1), band (d >= 1)
  int bin = 0;    // for colour_bin
  int pool = 0;   // pool index: sigma ~ 4 * 2^pool input pixels
};

const char* source_name(Source s) {
  switch (s) {
    case Source::L: return "L";
    case Source::ca: return "ca";
    case Source::cb: return "cb";
    case Source::L_std: return "Lstd";
    case Source::ca_std: return "castd";
    case Source::cb_std: return "cbstd";
    case Source::orient_0: return "E0";
    case Source::orient_45: return "E45";
    case Source::orient_90: return "E90";
    case Source::orient_135: return "E135";
    case Source::colour_edge: return "Ecol";
    case Source::band: return "band";
    case Source::colour_bin: return "bin";
  }
  return "?";
}

bool is_derivative(Source s) {
  return s == Source::orient_0 || s == Source::orient_45 || s == Source::orient_90 ||
         s == Source::orient_135 || s == Source::colour_edge || s == Source::band;
}

std::string channel_name(const ChannelSpec& c) {
  std::string n = source_name(c.source);
  if (c.source == Source::colour_bin) n += std::to_string(c.bin);
  if (is_derivative(c.source)) n += "/" + std::to_string(2 << c.scale);  // stride
  return n + "@" + std::to_string(4 << c.pool);                           // pooling sigma
}

// The channel tables, coarsest level first: 256, 64 and 32 channels.
std::array<std::vector<ChannelSpec>, kFeatureLevelCount> make_tables() {
  const Source orient[] = {Source::orient_0, Source::orient_45, Source::orient_90,
                           Source::orient_135};
  // Sources of one level; each is pooled at the level's 4 pool indices.
  const auto level = [](const std::vector<ChannelSpec>& sources, int first_pool) {
    std::vector<ChannelSpec> table;
    for (const auto& s : sources)
      for (int p = first_pool; p < first_pool + 4; ++p) {
        ChannelSpec c = s;
        c.pool = p;
        table.push_back(c);
      }
    return table;
  };
  const auto orientations = [&](int scale) {
    std::vector<ChannelSpec> v;
    for (Source o : orient) v.push_back({o, scale, 0, 0});
    return v;
  };
  const auto one = [](Source s, int scale) { return std::vector<ChannelSpec>{{s, scale, 0, 0}}; };
  const std::vector<ChannelSpec> colour = {{Source::L}, {Source::ca}, {Source::cb}};
  const std::vector<ChannelSpec> spread = {{Source::L_std}, {Source::ca_std}, {Source::cb_std}};
  const auto join = [](std::vector<std::vector<ChannelSpec>> parts) {
    std::vector<ChannelSpec> v;
    for (auto& p : parts) v.insert(v.end(), p.begin(), p.end());
    return v;
  };

  // Fine (stride 4): colour, stride-2 texture, stride-4 colour edges (camera chroma is coarser
  // than lightness) -- 8 sources x pools 4..32 = 32.
  const auto fine = join({colour, orientations(0), one(Source::colour_edge, 1)});
  // Mid (stride 8): colour and its spread, texture at strides 2 and 4, colour edges at 4 and 8
  // -- 16 sources x pools 8..64 = 64.
  const auto mid = join({colour, spread, orientations(0), orientations(1),
                         one(Source::colour_edge, 1), one(Source::colour_edge, 2)});
  // Coarse (stride 16): colour and its spread, texture, colour edges and band energy at strides
  // 4, 8, 16, and the colour histogram -- 64 sources x pools 16..128 = 256.
  std::vector<ChannelSpec> coarse = join({colour, spread});
  for (int d = 1; d < kScales; ++d)
    coarse = join({coarse, orientations(d), one(Source::colour_edge, d), one(Source::band, d)});
  for (int i = 0; i < kColourBins; ++i) coarse.push_back({Source::colour_bin, 0, i, 0});
  return {level(coarse, 2), level(mid, 1), level(fine, 0)};
}

using Cascade = std::array<cv::Mat, kPools>;  // CV_32FC1; [k] at sizes[k], empty below its start

class BuiltinFeatureEncoder final : public FeatureEncoder {
 public:
  explicit BuiltinFeatureEncoder(const BuiltinFeatureConfig& config)
      : config_(config), tables_(make_tables()) {
    fine_ = cv::Size(config.input_width / 4, config.input_height / 4);
    for (int k = 0; k < kPools; ++k)  // exact for k <= 2 (input is a multiple of 16)
      sizes_[k] = cv::Size((fine_.width + (1 << k) - 1) >> k, (fine_.height + (1 << k) - 1) >> k);
    for (int l = 0; l < kFeatureLevelCount; ++l) {
      const cv::Size s = sizes_[level_resolution(l)];
      shapes_.push_back({static_cast<int>(tables_[l].size()), s.height, s.width});
    }
    grey_lightness_.create(1, 256, CV_32F);
    for (int v = 0; v < 256; ++v) {  // sRGB decoding, then CIE L* of the luminance
      const double c = v / 255.0;
      const double Y = c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
      grey_lightness_.at<float>(v) = static_cast<float>(
          Y > 216.0 / 24389.0 ? 116.0 * std::cbrt(Y) - 16.0 : Y * 24389.0 / 27.0);
    }
  }

  const std::vector<FeatureLevelShape>& level_shapes() const override { return shapes_; }

  std::string describe() const override {
    return "builtin " + std::to_string(config_.input_width) + "x" +
           std::to_string(config_.input_height) + " -> " + shapes_to_string(shapes_);
  }

  bool encode(const cv::Mat& rgb, FeaturePyramid* out, std::string* why) override {
    if (!check_encoder_input(rgb, why)) return false;
    compute_sources(rgb);
    out->image_width = rgb.cols;
    out->image_height = rgb.rows;
    out->levels.resize(kFeatureLevelCount);
    cv::Mat value;
    for (int l = 0; l < kFeatureLevelCount; ++l) {
      FeatureLevel& level = out->levels[l];
      level.resize(shapes_[l]);
      const cv::Size size = sizes_[level_resolution(l)];
      for (std::size_t c = 0; c < tables_[l].size(); ++c) {
        const ChannelSpec& spec = tables_[l][c];
        cv::Mat dst(size, CV_32FC1, level.channel(static_cast<int>(c)));  // the level's buffer
        if (sizes_[spec.pool] == size) {
          // Computed in place (OpenCV reuses a destination of the right size and type); the
          // copy is a safety net should an operation ever reallocate.
          value = dst;
          channel_value(spec, &value);
          if (value.data != dst.data) value.copyTo(dst);
          value.release();
        } else {
          // Pooled coarser than its level: smooth at that scale, so upsampled bilinearly.
          channel_value(spec, &value);
          cv::resize(value, dst, size, 0, 0, cv::INTER_LINEAR);
        }
      }
    }
    return true;
  }

 private:
  // Pool index of level l's own cell size: coarse 2, mid 1, fine 0.
  static int level_resolution(int l) { return kFeatureLevelCount - 1 - l; }

  static void blur(const cv::Mat& src, cv::Mat* dst) {
    cv::GaussianBlur(src, *dst, cv::Size(7, 7), 1.0, 1.0, cv::BORDER_REPLICATE);
  }

  // The pooling cascade of `native` (at sizes_[start]) from index `start` up.
  void pool(const cv::Mat& native, int start, Cascade* cascade) {
    blur(native, &(*cascade)[start]);
    for (int k = start + 1; k < kPools; ++k) {
      cv::resize((*cascade)[k - 1], down_, sizes_[k], 0, 0, cv::INTER_AREA);
      blur(down_, &(*cascade)[k]);
    }
  }

  void compute_sources(const cv::Mat& rgb) {
    // Area resampling is SAM2's resize and the analysis at strides 2 and 4 in one step: first
    // to twice the fine level's resolution, then (an exact halving) to the fine level's.
    cv::resize(rgb, rgb2_, cv::Size(2 * fine_.width, 2 * fine_.height), 0, 0, cv::INTER_AREA);
    cv::resize(rgb2_, rgb1_, fine_, 0, 0, cv::INTER_AREA);
    rgb1_.convertTo(rgbf_, CV_32FC3, 1.0 / 255.0);
    cv::cvtColor(rgbf_, lab_, cv::COLOR_RGB2Lab);  // float: L* in [0, 100], a*, b* in ~[-110, 110]
    cv::split(lab_, ch_);
    // Shading-invariant chroma: a* and b* scale like L* + 16 (both follow the cube root of
    // luminance), so their ratio cancels shading and exposure; rescaled to a*, b* at L* = 50.
    cv::add(ch_[0], 16.0f, e_);
    cv::divide(ch_[1], e_, ch_[1], kChromaAtMidGrey);
    cv::divide(ch_[2], e_, ch_[2], kChromaAtMidGrey);
    for (int i = 0; i < 3; ++i) {
      pool(ch_[i], 0, &colour_[i]);
      cv::multiply(ch_[i], ch_[i], e_);
      pool(e_, 0, &colour_sq_[i]);
    }

    // Derivatives (Sobel / 8: a central-difference derivative per pixel of their scale). The
    // four oriented energies are |grad L|^2 cos^2(theta - theta_k), theta_k = 0, 45, 90, 135 deg.
    const auto derivative = [](const cv::Mat& src, cv::Mat* dx, cv::Mat* dy) {
      cv::Sobel(src, *dx, CV_32F, 1, 0, 3, 1.0 / 8.0, 0.0, cv::BORDER_REPLICATE);
      cv::Sobel(src, *dy, CV_32F, 0, 1, 3, 1.0 / 8.0, 0.0, cv::BORDER_REPLICATE);
    };
    for (int d = 0; d < kScales; ++d) {
      const int start = std::max(0, d - 1);
      if (d == 0) {
        // Stride 2: lightness at twice the fine resolution, from luma through a table of the
        // L* of sRGB greys (exact for greys, and several times cheaper than a Lab conversion
        // at this size), blurred like the cascade; its energies are area-pooled onto the fine
        // grid.
        cv::cvtColor(rgb2_, grey2_, cv::COLOR_RGB2GRAY);
        cv::LUT(grey2_, grey_lightness_, light2_);
        blur(light2_, &blur2_);
        derivative(blur2_, &gx_, &gy_);
      } else {
        // Stride 2^(d+1): the colour cascade at index d - 1.
        derivative(colour_[0][d - 1], &gx_, &gy_);
      }
      const auto add_energy = [&](const cv::Mat& energy, Cascade* cascade) {
        if (d == 0) {
          cv::resize(energy, fine_energy_, fine_, 0, 0, cv::INTER_AREA);
          pool(fine_energy_, start, cascade);
        } else {
          pool(energy, start, cascade);
        }
      };
      cv::multiply(gx_, gx_, e_);
      add_energy(e_, &orient_[d][0]);
      cv::multiply(gy_, gy_, e_);
      add_energy(e_, &orient_[d][2]);
      cv::add(gx_, gy_, e_);
      cv::multiply(e_, e_, e2_, 0.5);
      add_energy(e2_, &orient_[d][1]);
      cv::subtract(gx_, gy_, e_);
      cv::multiply(e_, e_, e2_, 0.5);
      add_energy(e2_, &orient_[d][3]);
      if (d == 0) continue;  // colour edges and bands from stride 4 up
      derivative(colour_[1][d - 1], &gx_, &gy_);
      cv::multiply(gx_, gx_, e_);
      cv::accumulateSquare(gy_, e_);
      derivative(colour_[2][d - 1], &gx_, &gy_);
      cv::accumulateSquare(gx_, e_);
      cv::accumulateSquare(gy_, e_);
      pool(e_, start, &colour_edge_[d]);
      // Laplacian-pyramid band: this scale's lightness less the next coarser one.
      cv::resize(colour_[0][d], up_, sizes_[d - 1], 0, 0, cv::INTER_LINEAR);
      cv::subtract(colour_[0][d - 1], up_, e_);
      cv::multiply(e_, e_, e2_);
      pool(e2_, start, &band_[d]);
    }

    // Soft colour histogram from the colour at pool index 1 (cells of ~8 input pixels), computed
    // as whole-image operations (vectorised exp) rather than per pixel.
    const int bin_start = 1;
    const cv::Mat& L = colour_[0][bin_start];
    const cv::Mat& ca = colour_[1][bin_start];
    const cv::Mat& cb = colour_[2][bin_start];
    for (int i = 0; i < kLightBins; ++i) {  // exp(-(L - c_i)^2 / (2 sigma^2))
      cv::subtract(L, 10.0f + 20.0f * i, e_);
      cv::multiply(e_, e_, e2_, -0.5 / (kLightSigma * kLightSigma));
      cv::exp(e2_, light_[i]);
      if (i == 0) light_[i].copyTo(sum_light_); else sum_light_ += light_[i];
    }
    for (int j = 0; j < kChromaBins; ++j) {  // exp(-|(ca, cb) - p_j|^2 / (2 sigma^2))
      const double theta = 2.0 * 3.14159265358979323846 * (j - 1) / (kChromaBins - 1);
      const float pa = j == 0 ? 0.0f : static_cast<float>(kChromaRadius * std::cos(theta));
      const float pb = j == 0 ? 0.0f : static_cast<float>(kChromaRadius * std::sin(theta));
      cv::subtract(ca, pa, e_);
      cv::multiply(e_, e_, e2_);
      cv::subtract(cb, pb, e_);
      cv::accumulateSquare(e_, e2_);
      e2_ *= -0.5 / (kChromaSigma * kChromaSigma);
      cv::exp(e2_, chroma_[j]);
      if (j == 0) chroma_[j].copyTo(sum_chroma_); else sum_chroma_ += chroma_[j];
    }
    cv::multiply(sum_light_, sum_chroma_, e_);
    cv::divide(1.0, e_, e2_);  // so that a pixel's 40 memberships sum to 1
    for (int i = 0; i < kLightBins; ++i) cv::multiply(light_[i], e2_, light_[i]);
    for (int i = 0; i < kLightBins; ++i)
      for (int j = 0; j < kChromaBins; ++j) {
        cv::multiply(light_[i], chroma_[j], e_);
        pool(e_, bin_start, &colour_bin_[i * kChromaBins + j]);
      }
  }

  // The normalised value of one channel at its pool index's resolution.
  void channel_value(const ChannelSpec& c, cv::Mat* value) const {
    const int k = c.pool;
    // weight * log(1 + sqrt(energy) / scale)
    const auto compress = [&](const cv::Mat& energy, float scale, float weight) {
      cv::max(energy, 0.0f, *value);
      cv::sqrt(*value, *value);
      value->convertTo(*value, CV_32F, 1.0 / scale, 1.0);
      cv::log(*value, *value);
      *value *= weight;
    };
    switch (c.source) {
      case Source::L:
        colour_[0][k].convertTo(*value, CV_32F, 1.0 / kLightScale, -kLightOffset / kLightScale);
        break;
      case Source::ca:
        colour_[1][k].convertTo(*value, CV_32F, kChromaWeight / kChromaScale);
        break;
      case Source::cb:
        colour_[2][k].convertTo(*value, CV_32F, kChromaWeight / kChromaScale);
        break;
      case Source::L_std:
      case Source::ca_std:
      case Source::cb_std: {  // variance = E[x^2] - E[x]^2 over the pool window
        const int i = static_cast<int>(c.source) - static_cast<int>(Source::L_std);
        compress(colour_sq_[i][k] - colour_[i][k].mul(colour_[i][k]), kSpreadScale,
                 kSpreadWeight);
        break;
      }
      case Source::orient_0: compress(orient_[c.scale][0][k], kGradScale, kTextureWeight); break;
      case Source::orient_45: compress(orient_[c.scale][1][k], kGradScale, kTextureWeight); break;
      case Source::orient_90: compress(orient_[c.scale][2][k], kGradScale, kTextureWeight); break;
      case Source::orient_135: compress(orient_[c.scale][3][k], kGradScale, kTextureWeight); break;
      case Source::colour_edge: compress(colour_edge_[c.scale][k], kGradScale, kTextureWeight); break;
      case Source::band: compress(band_[c.scale][k], kBandScale, kTextureWeight); break;
      case Source::colour_bin: colour_bin_[c.bin][k].convertTo(*value, CV_32F, kBinWeight); break;
    }
  }

  BuiltinFeatureConfig config_;
  std::array<std::vector<ChannelSpec>, kFeatureLevelCount> tables_;
  std::vector<FeatureLevelShape> shapes_;
  cv::Size fine_;
  std::array<cv::Size, kPools> sizes_;
  // Per-frame pooling cascades of the sources.
  std::array<Cascade, 3> colour_, colour_sq_;        // L*, ca, cb and their squares
  std::array<std::array<Cascade, 4>, kScales> orient_;
  std::array<Cascade, kScales> colour_edge_, band_;
  std::array<Cascade, kColourBins> colour_bin_;
  // Per-frame scratch images, kept so that their buffers are reused from frame to frame.
  cv::Mat rgb2_, rgb1_, rgbf_, lab_, ch_[3], grey2_, light2_, blur2_, gx_, gy_, e_, e2_, up_,
      fine_energy_, down_;
  cv::Mat light_[kLightBins], chroma_[kChromaBins], sum_light_, sum_chroma_;
  cv::Mat grey_lightness_;  // [1, 256] CV_32F: L* of the sRGB grey (v, v, v)
};

}  // namespace

std::unique_ptr<FeatureEncoder> make_builtin_encoder(const BuiltinFeatureConfig& config) {
  return std::make_unique<BuiltinFeatureEncoder>(config);
}

}  // namespace fslam::core::detail

namespace fslam::core {

std::vector<std::vector<std::string>> builtin_feature_channel_names() {
  std::vector<std::vector<std::string>> names;
  for (const auto& table : detail::make_tables()) {
    names.emplace_back();
    for (const auto& c : table) names.back().push_back(detail::channel_name(c));
  }
  return names;
}

}  // namespace fslam::core
