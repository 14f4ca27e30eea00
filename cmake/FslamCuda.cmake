# Optional CUDA backend, decided once at configure time (like Ceres' USE_CUDA).
#   FSLAM_WITH_CUDA=AUTO  build it when nvcc is found (default)
#   FSLAM_WITH_CUDA=ON    require it
#   FSLAM_WITH_CUDA=OFF   never build it
# nvcc lives in the toolkit prefix (/usr/local/cuda/bin), usually not on PATH, and CMake 3.25
# does not look there by itself.
set(FSLAM_WITH_CUDA AUTO CACHE STRING "Build the CUDA backend: AUTO, ON or OFF")
set_property(CACHE FSLAM_WITH_CUDA PROPERTY STRINGS AUTO ON OFF)
set(FSLAM_HAVE_CUDA OFF)

if(NOT FSLAM_WITH_CUDA STREQUAL "OFF")
  if(NOT CMAKE_CUDA_COMPILER)
    find_program(FSLAM_NVCC nvcc HINTS ENV CUDA_HOME ENV CUDA_PATH PATH_SUFFIXES bin
                 PATHS /usr/local/cuda/bin /usr/local/cuda)
    if(FSLAM_NVCC)
      set(CMAKE_CUDA_COMPILER ${FSLAM_NVCC} CACHE FILEPATH "CUDA compiler" FORCE)
    endif()
  endif()
  if(CMAKE_CUDA_COMPILER)
    # `native` fails without a GPU and CUDA 13 rejects anything below 75.
    if(NOT DEFINED CMAKE_CUDA_ARCHITECTURES)
      set(CMAKE_CUDA_ARCHITECTURES "80;90" CACHE STRING "CUDA architectures")
    endif()
    enable_language(CUDA)
    find_package(CUDAToolkit REQUIRED)
    set(FSLAM_HAVE_CUDA ON)
  elseif(FSLAM_WITH_CUDA STREQUAL "ON")
    message(FATAL_ERROR "FSLAM_WITH_CUDA=ON but nvcc was not found; set CMAKE_CUDA_COMPILER")
  else()
    message(STATUS "nvcc not found: building without the CUDA backend")
  endif()
endif()
