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
