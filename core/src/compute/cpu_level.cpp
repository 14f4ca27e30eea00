#include "fslam/core/compute/cpu_level.hpp"

#include <cstring>

#include "fslam/core/build_config.hpp"

namespace fslam::core {

#if defined(__x86_64__)
// Compiled for plain x86-64 whatever the build's level, so that the check itself runs anywhere.
__attribute__((target("arch=x86-64"))) bool cpu_runs_this_build(std::string* why) {
  __builtin_cpu_init();
  const char* level = FSLAM_X86_64_LEVEL;
  std::string missing;
  auto need = [&](bool present, const char* name) {
    if (!present) missing += std::string(missing.empty() ? "" : ", ") + name;
  };
  const bool v2 = std::strcmp(level, "v2") == 0, v3 = std::strcmp(level, "v3") == 0,
             v4 = std::strcmp(level, "v4") == 0;
  if (v2 || v3 || v4) {
    need(__builtin_cpu_supports("sse4.2"), "SSE4.2");
    need(__builtin_cpu_supports("popcnt"), "POPCNT");
  }
  if (v3 || v4) {
    need(__builtin_cpu_supports("avx2"), "AVX2");
    need(__builtin_cpu_supports("fma"), "FMA");
    need(__builtin_cpu_supports("bmi2"), "BMI2");
  }
  if (v4) {
    need(__builtin_cpu_supports("avx512f"), "AVX-512F");
    need(__builtin_cpu_supports("avx512bw"), "AVX-512BW");
  }
  if (missing.empty()) return true;
  if (why != nullptr) {
    *why = std::string("this build targets x86-64-") + level + " but the processor lacks " + missing +
           "; rebuild with cmake -DFSLAM_X86_64_LEVEL=v1 (docs/architecture.md)";
  }
  return false;
}
#else
bool cpu_runs_this_build(std::string*) { return true; }
#endif

}  // namespace fslam::core
