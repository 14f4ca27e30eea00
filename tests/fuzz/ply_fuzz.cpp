// Fuzz target: the 3DGS PLY reader (maps a user loads, or a map folder after a crash), binary
// and ASCII. Seeds: small maps written by write_gaussian_ply (tests/fuzz/make_seeds.cpp).
#include <cstdint>
#include <string>

#include "fslam/core/io/gaussian_ply.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fslam::fuzz::write_scratch("map.ply", data, size);
  fslam::core::GaussianMap map;
  std::string why;
  if (!fslam::core::read_gaussian_ply(path, &map, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  if (!map.is_consistent(&why)) __builtin_trap();  // the reader promises a consistent map
  return 0;
}
