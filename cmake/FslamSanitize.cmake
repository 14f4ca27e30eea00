# Instrumented builds (docs/reliability.md), each in its own build folder:
#   FSLAM_SANITIZE=address  ASan + UBSan over every target (deploy/setup.sh --sanitize address)
#   FSLAM_SANITIZE=thread   TSan (deploy/setup.sh --sanitize thread)
#   FSLAM_FUZZ=ON           libFuzzer targets in tests/fuzz, with ASan + UBSan; needs clang
#                           (tests/fuzz/run_fuzz.sh configures it)
set(FSLAM_SANITIZE "" CACHE STRING "Sanitizer build: empty, address or thread")
set_property(CACHE FSLAM_SANITIZE PROPERTY STRINGS "" address thread)
option(FSLAM_FUZZ "Build the libFuzzer targets (clang only)" OFF)

set(_fslam_compile_flags "")
set(_fslam_link_flags "")
if(FSLAM_SANITIZE STREQUAL "address")
  # UBSan aborts on the first finding so that ctest fails, like ASan does.
  set(_fslam_compile_flags -fsanitize=address,undefined -fno-sanitize-recover=undefined)
  set(_fslam_link_flags -fsanitize=address,undefined)
elseif(FSLAM_SANITIZE STREQUAL "thread")
  set(_fslam_compile_flags -fsanitize=thread)
  set(_fslam_link_flags -fsanitize=thread)
elseif(NOT FSLAM_SANITIZE STREQUAL "")
  message(FATAL_ERROR "FSLAM_SANITIZE must be empty, address or thread, not '${FSLAM_SANITIZE}'")
endif()

if(FSLAM_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    message(FATAL_ERROR "FSLAM_FUZZ=ON needs clang (libFuzzer): configure with -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++, or use tests/fuzz/run_fuzz.sh")
  endif()
  if(NOT FSLAM_SANITIZE STREQUAL "")
    message(FATAL_ERROR "FSLAM_FUZZ=ON brings its own ASan + UBSan; leave FSLAM_SANITIZE empty")
  endif()
  # Every library gets coverage instrumentation; only the fuzz executables link libFuzzer's main
  # (tests/fuzz/CMakeLists.txt adds -fsanitize=fuzzer to them).
  set(_fslam_compile_flags -fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined)
  set(_fslam_link_flags -fsanitize=address,undefined)
endif()

if(_fslam_compile_flags)
  add_compile_options("$<$<COMPILE_LANGUAGE:C,CXX>:${_fslam_compile_flags};-fno-omit-frame-pointer>")
  add_link_options(${_fslam_link_flags})
endif()
