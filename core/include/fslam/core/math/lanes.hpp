// SIMD lanes for the CPU backend: N pixels of a tile row at once through the same per-pixel
// math the CUDA backend runs one pixel at a time (math/splat_math.hpp is written on a "pixel"
// type P that is either a scalar or Lanes). GCC / Clang vector extensions, so the compiler emits
// what the target offers: AVX2 with FSLAM_X86_64_LEVEL=v3 (the default), SSE2 on plain x86-64,
// NEON on Arm. CPU only: nothing here is marked host+device.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#if defined(__AVX__)
#include <immintrin.h>
#endif

// Its own namespace: argument-dependent lookup finds these for Lanes, while plain exp(float) in
// fslam::core::math still means the C library's.
namespace fslam::core::simd {

template <typename T>
struct LaneInt;  // the signed integer as wide as T: the lanes of a mask
template <>
struct LaneInt<float> {
  using type = std::int32_t;
};
template <>
struct LaneInt<double> {
  using type = std::int64_t;
};

// A per-lane condition: all bits set where true.
template <typename T, int N>
struct LaneMask {
  using I = typename LaneInt<T>::type;
  typedef I V __attribute__((vector_size(N * sizeof(I))));
  V v;

  static LaneMask none() { return {V{} + I(0)}; }
  friend LaneMask operator&(LaneMask a, LaneMask b) { return {a.v & b.v}; }
  friend LaneMask operator|(LaneMask a, LaneMask b) { return {a.v | b.v}; }
  friend LaneMask operator~(LaneMask a) { return {~a.v}; }
  LaneMask& operator|=(LaneMask b) {
    v |= b.v;
    return *this;
  }
  bool operator[](int i) const { return v[i] != 0; }
};

// The mask as bits, lane i in bit i (one instruction for 8 float lanes with AVX).
template <typename T, int N>
unsigned bits(LaneMask<T, N> m) {
#if defined(__AVX__)
  if constexpr (sizeof(T) == 4 && N == 8) {
    return static_cast<unsigned>(_mm256_movemask_ps(reinterpret_cast<__m256>(m.v)));
  }
#endif
  unsigned b = 0;
  for (int i = 0; i < N; ++i) b |= static_cast<unsigned>(m.v[i] != 0) << i;
  return b;
}

template <typename T, int N>
bool any(LaneMask<T, N> m) {
  return bits(m) != 0;
}

template <typename T, int N>
int count(LaneMask<T, N> m) {
  return __builtin_popcount(bits(m));
}

// N values of T (pixels of one tile row); implicit from a scalar (broadcast), so the shared math
// mixes the Gaussian's scalars and the pixels' lanes as it mixes scalars.
template <typename T, int N>
struct Lanes {
  typedef T V __attribute__((vector_size(N * sizeof(T))));
  using Mask = LaneMask<T, N>;
  using IV = typename Mask::V;
  V v;

  Lanes() = default;
  Lanes(T s) : v(V{} + s) {}  // NOLINT: broadcast on purpose
  static Lanes of(V x) {
    Lanes l;
    l.v = x;
    return l;
  }
  // 0, 1, .., N-1 plus `start`.
  static Lanes iota(T start) {
    Lanes l;
    for (int i = 0; i < N; ++i) l.v[i] = start + T(i);
    return l;
  }
  static Lanes load(const T* p) {
    Lanes l;
    std::memcpy(&l.v, p, sizeof(V));
    return l;
  }
  void store(T* p) const { std::memcpy(p, &v, sizeof(V)); }
  T operator[](int i) const { return v[i]; }

  friend Lanes operator+(Lanes a, Lanes b) { return of(a.v + b.v); }
  friend Lanes operator-(Lanes a, Lanes b) { return of(a.v - b.v); }
  friend Lanes operator*(Lanes a, Lanes b) { return of(a.v * b.v); }
  friend Lanes operator/(Lanes a, Lanes b) { return of(a.v / b.v); }
  friend Lanes operator-(Lanes a) { return of(-a.v); }
  Lanes& operator+=(Lanes b) {
    v += b.v;
    return *this;
  }
  Lanes& operator-=(Lanes b) {
    v -= b.v;
    return *this;
  }
  friend Mask operator<(Lanes a, Lanes b) { return {a.v < b.v}; }
  friend Mask operator<=(Lanes a, Lanes b) { return {a.v <= b.v}; }
  friend Mask operator>(Lanes a, Lanes b) { return {a.v > b.v}; }
  friend Mask operator>=(Lanes a, Lanes b) { return {a.v >= b.v}; }
  friend Mask operator==(Lanes a, Lanes b) { return {a.v == b.v}; }
};

// m ? a : b per lane, through the bits (portable across GCC and Clang vector types).
template <typename T, int N>
Lanes<T, N> select(LaneMask<T, N> m, Lanes<T, N> a, Lanes<T, N> b) {
  using IV = typename LaneMask<T, N>::V;
  using V = typename Lanes<T, N>::V;
  return Lanes<T, N>::of(reinterpret_cast<V>((m.v & reinterpret_cast<IV>(a.v)) |
                                             (~m.v & reinterpret_cast<IV>(b.v))));
}

template <typename T, int N>
Lanes<T, N> min_value(Lanes<T, N> a, Lanes<T, N> b) {
  return select(a < b, a, b);
}

template <typename T, int N>
Lanes<T, N> abs_value(Lanes<T, N> a) {
  return select(a < Lanes<T, N>(T(0)), -a, a);
}

template <typename T, int N>
T sum(Lanes<T, N> a) {
  T s = T(0);
  for (int i = 0; i < N; ++i) s += a.v[i];
  return s;
}

// exp per lane. Double (the finite-difference reference tests): the C library's, lane by lane,
// so those tests check the lane code against exact arithmetic.
template <int N>
Lanes<double, N> exp(Lanes<double, N> x) {
  Lanes<double, N> y;
  for (int i = 0; i < N; ++i) y.v[i] = std::exp(x.v[i]);
  return y;
}

// Float: Cephes' expf (range reduction to |r| <= ln2 / 2, degree-6 polynomial, 2^n through the
// exponent bits), within 2 ulp of expf over [-87, 88]; vectorised, unlike the C library's.
template <int N>
Lanes<float, N> exp(Lanes<float, N> x) {
  using L = Lanes<float, N>;
  using IV = typename L::IV;
  x = min_value(L(88.0f), select(x < L(-87.0f), L(-87.0f), x));
  // n = round(x / ln2) with the 1.5 * 2^23 trick (round to nearest for |t| < 2^22).
  const L t = x * L(1.44269504088896341f);
  const L n = (t + L(12582912.0f)) - L(12582912.0f);
  const L r = x - n * L(0.693359375f) - n * L(-2.12194440e-4f);
  L p = L(1.9875691500e-4f);
  p = p * r + L(1.3981999507e-3f);
  p = p * r + L(8.3334519073e-3f);
  p = p * r + L(4.1665795894e-2f);
  p = p * r + L(1.6666665459e-1f);
  p = p * r + L(5.0000001201e-1f);
  const L y = p * r * r + r + L(1.0f);
  const IV bits = (__builtin_convertvector(n.v, IV) + 127) << 23;
  return y * L::of(reinterpret_cast<typename L::V>(bits));
}

}  // namespace fslam::core::simd
