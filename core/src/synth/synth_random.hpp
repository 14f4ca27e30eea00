// Portable, counter-based randomness for the synthetic data generator. The standard library's
// distributions differ between implementations, so every random number here is derived from
// SplitMix64 by our own code: the same seed gives the same bytes on every platform.
#pragma once

#include <cmath>
#include <cstdint>

namespace fslam::core::synth {

// SplitMix64's output function: a bijective 64-bit mixer.
inline std::uint64_t mix64(std::uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

inline std::uint64_t hash_combine(std::uint64_t a, std::uint64_t b) {
  return mix64(a ^ (mix64(b) + 0x632be59bd9b4e019ULL + (a << 6) + (a >> 2)));
}

// Uniform in [0, 1) with 53 random bits.
inline double to_unit(std::uint64_t bits) {
  return static_cast<double>(bits >> 11) * (1.0 / 9007199254740992.0);
}

// Independent streams of one seed (room, trajectory, noise).
enum class Stream : std::uint64_t { room = 1, trajectory = 2, noise = 3 };
inline std::uint64_t stream_seed(std::uint64_t seed, Stream stream) {
  return hash_combine(mix64(seed), static_cast<std::uint64_t>(stream));
}

// Sequential generator for scene and trajectory parameters.
class Rng {
 public:
  explicit Rng(std::uint64_t seed) : state_(seed) {}
  std::uint64_t next() {
    state_ += 0x9e3779b97f4a7c15ULL;
    return mix64(state_);
  }
  double uniform() { return to_unit(next()); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Integer in [0, n).
  int below(int n) { return static_cast<int>(uniform() * n); }
  double sign() { return uniform() < 0.5 ? -1.0 : 1.0; }

 private:
  std::uint64_t state_;
};

// Approximately standard normal from 64 random bits: the Irwin-Hall sum of four 16-bit
// uniforms, rescaled to unit variance (tails end at +-3.46). Several times cheaper than
// Box-Muller, which matters at a few million draws per frame.
inline double approx_gaussian(std::uint64_t bits) {
  const double sum = static_cast<double>((bits & 0xffff) + ((bits >> 16) & 0xffff) +
                                         ((bits >> 32) & 0xffff) + (bits >> 48));
  return (sum * (1.0 / 65536.0) - 2.0) * 1.7320508075688772;
}

}  // namespace fslam::core::synth
