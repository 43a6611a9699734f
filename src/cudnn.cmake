# The cudnn backend (backend_cudnn.c and its cudnn_* helpers), included from
# src/CMakeLists.txt when CUDA and cuDNN were found.
#
# Runtime API only: cudart (static by default, so the binaries need no
# libcudart.so) and libcudnn; never CUDA::cuda_driver / -lcuda, whose stub
# links but cannot run. The driver library is loaded by cudart at run time,
# which is what lets a binary start, and the backend report "no CUDA
# device", on a machine without a GPU.
option(HF_CUDART_STATIC "Link the CUDA runtime statically" ON)

target_sources(hfcore PRIVATE
  ${CMAKE_CURRENT_LIST_DIR}/backend_cudnn.c
  ${CMAKE_CURRENT_LIST_DIR}/cudnn_util.c
  ${CMAKE_CURRENT_LIST_DIR}/cudnn_layout.c
  ${CMAKE_CURRENT_LIST_DIR}/cudnn_graph.c
  ${CMAKE_CURRENT_LIST_DIR}/cudnn_kernels.cu)
target_include_directories(hfcore PRIVATE ${CUDAToolkit_INCLUDE_DIRS} ${CUDNN_INCLUDE})
if(HF_CUDART_STATIC)
  target_link_libraries(hfcore PRIVATE CUDA::cudart_static)
else()
  target_link_libraries(hfcore PRIVATE CUDA::cudart)
endif()
target_link_libraries(hfcore PRIVATE ${CUDNN_LIB})
target_compile_definitions(hfcore PUBLIC HF_HAVE_CUDNN)

# The project's warning flags are GCC's; nvcc takes host-compiler flags
# through -Xcompiler only. Restrict the inherited options to C/C++ and hand
# the same ones to nvcc's host pass.
get_target_property(_hf_opts hfcore COMPILE_OPTIONS)
if(_hf_opts)
  set(_hf_wrapped)
  foreach(_o IN LISTS _hf_opts)
    list(APPEND _hf_wrapped "$<$<COMPILE_LANGUAGE:C,CXX>:${_o}>")
  endforeach()
  set_property(TARGET hfcore PROPERTY COMPILE_OPTIONS ${_hf_wrapped})
endif()
target_compile_options(hfcore PRIVATE
  $<$<COMPILE_LANGUAGE:CUDA>:-Xcompiler=-Wall,-Wextra,-Wno-unused-parameter>)
