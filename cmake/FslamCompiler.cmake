# Compiler set-up shared by every target: ccache when present, and one warnings helper.
find_program(FSLAM_CCACHE ccache)
if(FSLAM_CCACHE)
  set(CMAKE_C_COMPILER_LAUNCHER ${FSLAM_CCACHE})
  set(CMAKE_CXX_COMPILER_LAUNCHER ${FSLAM_CCACHE})
  set(CMAKE_CUDA_COMPILER_LAUNCHER ${FSLAM_CCACHE})
endif()

# Our own code builds clean with -Wall -Wextra; third-party headers come in as SYSTEM.
function(fslam_target_warnings target)
  target_compile_options(${target} PRIVATE
    $<$<COMPILE_LANGUAGE:CXX>:-Wall -Wextra>
    $<$<COMPILE_LANGUAGE:CUDA>:-Xcompiler=-Wall,-Wextra>)
endfunction()

# The x86-64 micro-architecture level the whole build targets (CPU code, and the host side of
# CUDA files, so that no inline function exists in two instruction sets). v3 = AVX2 + FMA (Intel
# since Haswell, AMD since Excavator/Zen), which the CPU rasteriser's lanes need to be fast
# (docs/benchmarks.md: 1.9x forward at 640x480 over v1). v1 runs on any x86-64; `native` tunes
# for the build machine (not for images shipped elsewhere). Ignored on other processors.
set(FSLAM_X86_64_LEVEL "v3" CACHE STRING "x86-64 level: v1, v2, v3, v4 or native")
set_property(CACHE FSLAM_X86_64_LEVEL PROPERTY STRINGS v1 v2 v3 v4 native)
set(FSLAM_X86_64_LEVEL_BUILT "")
if(CMAKE_SYSTEM_PROCESSOR MATCHES "^(x86_64|AMD64|amd64)$")
  if(FSLAM_X86_64_LEVEL STREQUAL "native")
    set(_fslam_march -march=native)
  elseif(FSLAM_X86_64_LEVEL STREQUAL "v1")
    set(_fslam_march -march=x86-64)
  elseif(FSLAM_X86_64_LEVEL MATCHES "^v[234]$")
    set(_fslam_march -march=x86-64-${FSLAM_X86_64_LEVEL})
  else()
    message(FATAL_ERROR "FSLAM_X86_64_LEVEL must be v1, v2, v3, v4 or native, not '${FSLAM_X86_64_LEVEL}'")
  endif()
  add_compile_options($<$<COMPILE_LANGUAGE:C,CXX>:${_fslam_march}>
                      $<$<COMPILE_LANGUAGE:CUDA>:-Xcompiler=${_fslam_march}>)
  set(FSLAM_X86_64_LEVEL_BUILT ${FSLAM_X86_64_LEVEL})
endif()
