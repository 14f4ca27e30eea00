// Whether this processor runs the instruction set the build targets (FSLAM_X86_64_LEVEL): a
// build for x86-64-v3 on a processor without AVX2 would otherwise die of SIGILL at the first
// vector instruction. Executables check this first thing in main.
#pragma once

#include <string>

namespace fslam::core {

// False with `why` naming the missing extensions and the CMake option to rebuild with.
bool cpu_runs_this_build(std::string* why);

}  // namespace fslam::core
