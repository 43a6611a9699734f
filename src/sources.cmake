# hfcore's portable sources (the optional backends' are added in
# src/CMakeLists.txt), one list for the library and for the standalone
# fuzzing build (tests/fuzz/CMakeLists.txt), which compiles them itself
# under libFuzzer: a source added here is in both, so neither links
# without it.
set(HF_CORE_SOURCES
  errors.c
  net_config.c
  weights_alloc.c
  weights_load.c
  json_check.c
  weights_save.c
  backend.c
  backend_cpu_ref.c
  half.c
  parallel.c
  image.c
  exr_channels.c
  exr_read.c
  exr_chunk_size.c
  exr_write.c
  features.c
  input_stats.c
  input_range.c
  sanitise.c
  png.c
)
