# Third-party libraries, all from Debian packages (deploy/debian/setup.sh).

pkg_check_modules(CJSON REQUIRED IMPORTED_TARGET libcjson)
pkg_check_modules(OPENEXR REQUIRED IMPORTED_TARGET OpenEXR)
pkg_check_modules(PNG REQUIRED IMPORTED_TARGET libpng)
# zlib: the EXR reader inflates PXR24 chunks to check their size
# (src/exr_chunk_size.c).
pkg_check_modules(ZLIB REQUIRED IMPORTED_TARGET zlib)

# OpenEXRCore (the C API, openexr.h) is a separate library in OpenEXR 3.
find_library(OPENEXRCORE_LIB NAMES OpenEXRCore-3_1 OpenEXRCore REQUIRED)
find_path(OPENEXRCORE_INCLUDE openexr.h PATH_SUFFIXES OpenEXR REQUIRED)

# oneDNN (the fast CPU backend).
set(HF_HAVE_ONEDNN OFF)
if(HF_WITH_ONEDNN)
  find_path(DNNL_INCLUDE dnnl.h)
  find_library(DNNL_LIB dnnl)
  if(DNNL_INCLUDE AND DNNL_LIB)
    set(HF_HAVE_ONEDNN ON)
    message(STATUS "oneDNN found: ${DNNL_LIB}")
  else()
    message(STATUS "oneDNN not found: the cpu backend is not built")
  endif()
endif()

# CUDA runtime + cuDNN (the GPU backend). Only the runtime API is used: never
# link libcuda (the driver library), whose stub links but cannot run.
set(HF_HAVE_CUDNN OFF)
if(HF_WITH_CUDNN)
  include(CheckLanguage)
  check_language(CUDA)
  find_package(CUDAToolkit QUIET)
  if(CMAKE_CUDA_COMPILER AND CUDAToolkit_FOUND)
    find_path(CUDNN_INCLUDE cudnn.h HINTS ${CUDAToolkit_INCLUDE_DIRS})
    find_library(CUDNN_LIB cudnn HINTS ${CUDAToolkit_LIBRARY_DIR})
    if(CUDNN_INCLUDE AND CUDNN_LIB)
      set(HF_HAVE_CUDNN ON)
      if(NOT DEFINED CMAKE_CUDA_ARCHITECTURES)
        set(CMAKE_CUDA_ARCHITECTURES 75 80 86 89 90)
      endif()
      enable_language(CUDA)
      message(STATUS "CUDA ${CUDAToolkit_VERSION} and cuDNN found: the cudnn backend is built")
    else()
      message(STATUS "cuDNN not found: the cudnn backend is not built")
    endif()
  else()
    message(STATUS "CUDA toolkit not found: the cudnn backend is not built")
  endif()
endif()
