/* The cudnn backend against cpu-ref, and its behaviour without a GPU.
 *
 * Whether this machine has a usable CUDA device is asked of the CUDA
 * runtime directly, not of the backend, so the "no GPU" test checks the
 * backend's answer instead of trusting it. Tests that need a device print
 * "SKIP: no CUDA device: <reason>" and skip. */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE   /* memfd_create */
#endif
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>
#include <cmocka.h>

#include <cuda_runtime_api.h>

#include "cudnn_graph.h"
#include "hfcore.h"

static char no_gpu_reason[256];   /* "" when a device is present */

static void find_device(void) {
  int n = 0;
  cudaError_t e = cudaGetDeviceCount(&n);
  if (e != cudaSuccess)
    snprintf(no_gpu_reason, sizeof no_gpu_reason, "cudaGetDeviceCount: %s", cudaGetErrorString(e));
  else if (n < 1)
    snprintf(no_gpu_reason, sizeof no_gpu_reason, "cudaGetDeviceCount: 0 devices");
}

#define REQUIRE_GPU()                                              \
  do {                                                             \
    if (no_gpu_reason[0]) {                                        \
      printf("SKIP: no CUDA device: %s\n", no_gpu_reason);         \
      skip();                                                      \
    }                                                              \
  } while (0)

static void test_availability(void **state) {
  (void)state;
  hf_backend *b = NULL;
  char why[512];
  int rc = hf_backend_create("cudnn", &b, why, sizeof why);
  if (no_gpu_reason[0]) {
    printf("  cudnn unavailable as expected: %s\n", why);
    assert_int_equal(rc, HF_EUNAVAILABLE);
    assert_null(b);
    assert_true(strlen(why) > 0);
    assert_non_null(strstr(why, "no CUDA device"));
    /* "Driver insufficient" is the runtime's word for no driver at all, too:
     * the reason says which it is. */
    if (strstr(no_gpu_reason, "insufficient"))
      assert_non_null(strstr(why, access("/proc/driver/nvidia/version", F_OK) == 0
                                      ? "update the NVIDIA driver"
                                      : "no NVIDIA driver is loaded"));
    /* auto falls back to a CPU backend and says why cudnn was passed over. */
    assert_int_equal(hf_backend_create("auto", &b, why, sizeof why), HF_OK);
    printf("  auto: %s\n", why);
    assert_string_not_equal(hf_backend_name(b), "cudnn");
    assert_true(!strcmp(hf_backend_name(b), "cpu") || !strcmp(hf_backend_name(b), "cpu-ref"));
    assert_non_null(strstr(why, "cudnn unavailable"));
  } else {
    assert_int_equal(rc, HF_OK);
    printf("  cudnn: %s\n", why);   /* the device and the cuDNN found at run time */
    assert_non_null(strstr(why, "cuDNN"));
    assert_string_equal(hf_backend_name(b), "cudnn");
    hf_backend_destroy(b);
    assert_int_equal(hf_backend_create("auto", &b, why, sizeof why), HF_OK);
    assert_string_equal(hf_backend_name(b), "cudnn");
  }
  hf_backend_destroy(b);
}

static uint64_t rng = 0x9E3779B97F4A7C15ull;
static float frand(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (float)(rng >> 40) / (float)(1 << 24);
}

static double rel_l2(const float *got, const float *want, size_t n) {
  double num = 0, den = 0;
  for (size_t i = 0; i < n; i++) {
    assert_false(isnan(got[i]));
    assert_false(isinf(got[i]));
    num += (got[i] - (double)want[i]) * (got[i] - (double)want[i]);
    den += (double)want[i] * want[i];
  }
  return den > 0 ? sqrt(num / den) : sqrt(num);
}

typedef struct ctx {
  hf_backend *gpu, *ref;
} ctx;

static int setup(void **state) {
  if (no_gpu_reason[0]) return 0;
  ctx *c = calloc(1, sizeof *c);
  char why[512];
  if (!c || hf_backend_create("cudnn", &c->gpu, why, sizeof why) ||
      hf_backend_create("cpu-ref", &c->ref, why, sizeof why)) {
    fprintf(stderr, "setup: %s\n", why);
    return -1;
  }
  *state = c;
  return 0;
}

static int teardown(void **state) {
  ctx *c = *state;
  if (c) {
    hf_backend_destroy(c->gpu);
    hf_backend_destroy(c->ref);
    free(c);
  }
  return 0;
}

/* Random weights of a variant, and its cpu-ref model to compare with. */
static hf_weights *weights_and_ref(ctx *c, const char *variant, uint64_t seed,
                                   hf_net_config *cfg, hf_model **rm) {
  hf_weights *w;
  assert_int_equal(hf_variant_preset(variant, cfg), HF_OK);
  assert_int_equal(hf_weights_init_random(cfg, seed, &w), HF_OK);
  assert_int_equal(hf_model_create(c->ref, w, rm), HF_OK);
  return w;
}

/* A GPU model made with one backend environment variable set (the
 * backend reads them when a model is created). */
static int gpu_model_with(ctx *c, const char *var, const char *val, const hf_weights *w,
                          hf_model **gm) {
  assert_int_equal(setenv(var, val, 1), 0);
  int rc = hf_model_create(c->gpu, w, gm);
  unsetenv(var);
  return rc;
}

/* One variant at one size and batch: relative L2 against cpu-ref < 1e-2. */
static void compare(ctx *c, const hf_net_config *cfg, hf_model *gm, hf_model *rm, int batch,
                    int width, int height) {

  const size_t npx = (size_t)batch * width * height;
  float *in = malloc(npx * cfg->in_channels * sizeof(float));
  float *want = malloc(npx * 3 * sizeof(float)), *got = malloc(npx * 3 * sizeof(float));
  assert_non_null(in);
  assert_non_null(want);
  assert_non_null(got);
  for (size_t i = 0; i < npx * cfg->in_channels; i++) in[i] = frand();
  hf_io io = {batch, width, height, in, HF_F32, want, HF_F32};
  assert_int_equal(hf_model_run(rm, &io, NULL), HF_OK);
  io.out = got;
  hf_timing t;
  assert_int_equal(hf_model_run(gm, &io, &t), HF_OK);
  double rel = rel_l2(got, want, npx * 3);
  printf("  %-10s batch %d %4dx%-4d rel L2 %.2e  in %.0f us, net %.0f us, out %.0f us\n",
         cfg->name, batch, width, height, rel, t.input_us, t.infer_us, t.output_us);
  assert_true(rel < 1e-2);
  assert_true(t.infer_us > 0);
  assert_true(t.input_us > 0);
  assert_true(t.output_us > 0);
  /* A second run replays the cached plan (CUDA graph). The backend passes
   * over engines noted nondeterministic, so this is expected to be bit for
   * bit; the assertion allows what an unnoted one could change, far below
   * the accuracy bar, and the line says which it was. */
  float *again = malloc(npx * 3 * sizeof(float));
  assert_non_null(again);
  io.out = again;
  assert_int_equal(hf_model_run(gm, &io, NULL), HF_OK);
  const int same = !memcmp(again, got, npx * 3 * sizeof(float));
  const double rerun = rel_l2(again, got, npx * 3);
  printf("  %-10s second run: %s (relative L2 %.1e)\n", cfg->name,
         same ? "bit-identical" : "differs", rerun);
  assert_true(rerun < 1e-4);
  free(again);
  free(in);
  free(want);
  free(got);
  (void)c;
}

static void test_presets_vs_cpu_ref(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  static const int sizes[][2] = {{37, 23}, {129, 65}};
  static const int batches[] = {1, 4};
  for (int i = 0; i < hf_variant_preset_count(); i++) {
    hf_net_config cfg;
    hf_weights *w;
    assert_int_equal(hf_variant_preset(hf_variant_preset_name(i), &cfg), HF_OK);
    assert_int_equal(hf_weights_init_random(&cfg, 100 + i, &w), HF_OK);
    hf_model *gm, *rm;
    assert_int_equal(hf_model_create(c->gpu, w, &gm), HF_OK);
    assert_int_equal(hf_model_create(c->ref, w, &rm), HF_OK);
    assert_string_equal(hf_model_precision(gm), "fp16");
    size_t weights_only = hf_model_device_bytes(gm);
    assert_true(weights_only >= w->num_params * 2);
    for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++)
      for (size_t b = 0; b < sizeof batches / sizeof batches[0]; b++)
        compare(c, &cfg, gm, rm, batches[b], sizes[s][0], sizes[s][1]);
    /* Activations and workspace of the cached plans are counted too. */
    assert_true(hf_model_device_bytes(gm) > weights_only);
    hf_model_destroy(gm);
    hf_model_destroy(rm);
    hf_weights_free(w);
  }
}

/* Fills in16 ([H][W][in_channels], FP16, in whatever memory the caller
 * chose) with random features, runs gm on it (FP16 out into out16) and rm
 * on the same values widened to float32: the relative L2 of gm's output
 * against rm's. */
static double f16_against_ref(hf_model *gm, hf_model *rm, const hf_net_config *cfg, int W,
                              int H, uint16_t *in16, uint16_t *out16) {
  const size_t npx = (size_t)W * H;
  float *in = malloc(npx * cfg->in_channels * 4), *want = malloc(npx * 12), *got = malloc(npx * 12);
  assert_non_null(in);
  assert_non_null(want);
  assert_non_null(got);
  for (size_t i = 0; i < npx * cfg->in_channels; i++) {
    in16[i] = hf_f32_to_f16(frand());
    in[i] = hf_f16_to_f32(in16[i]);
  }
  hf_io io = {1, W, H, in, HF_F32, want, HF_F32};
  assert_int_equal(hf_model_run(rm, &io, NULL), HF_OK);
  hf_io io16 = {1, W, H, in16, HF_F16, out16, HF_F16};
  assert_int_equal(hf_model_run(gm, &io16, NULL), HF_OK);
  for (size_t i = 0; i < npx * 3; i++) got[i] = hf_f16_to_f32(out16[i]);
  double rel = rel_l2(got, want, npx * 3);
  free(in);
  free(want);
  free(got);
  return rel;
}

/* FP16 in and out, and more shapes than the plan cache holds, so plans are
 * evicted and rebuilt. */
static void test_f16_io_and_plan_eviction(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  hf_net_config cfg;
  hf_model *gm, *rm;
  hf_weights *w = weights_and_ref(c, "Base", 5, &cfg, &rm);
  /* Fewer cached plans than the shapes below. */
  assert_int_equal(gpu_model_with(c, "HF_CUDNN_PLANS", "2", w, &gm), HF_OK);
  static const int sizes[][2] = {{8, 8}, {17, 9}, {33, 31}, {64, 8}, {7, 70}, {17, 9}, {8, 8}};
  for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++) {
    const int W = sizes[s][0], H = sizes[s][1];
    const size_t npx = (size_t)W * H;
    uint16_t *in16 = malloc(npx * cfg.in_channels * 2), *out16 = malloc(npx * 6);
    assert_non_null(in16);
    assert_non_null(out16);
    double rel = f16_against_ref(gm, rm, &cfg, W, H, in16, out16);
    printf("  f16 io %dx%d: rel L2 %.2e\n", W, H, rel);
    assert_true(rel < 1e-2);
    free(in16);
    free(out16);
  }
  hf_model_destroy(gm);
  hf_model_destroy(rm);
  hf_weights_free(w);
}

/* Each decoder form alone (HF_CUDNN_DECONV), and the diagnostic switches
 * (dense copies only, no fusion, no CUDA graph), give the same network. */
static void test_forms_and_switches(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  static const struct { const char *var, *val; } cases[] = {
      {"HF_CUDNN_DECONV", "bwd-data"}, {"HF_CUDNN_DECONV", "d2s"},
      {"HF_CUDNN_DECONV", "phase"},    {"HF_CUDNN_DECONV", "shuffle"},
      {"HF_CUDNN_DENSE", "1"},         {"HF_CUDNN_NO_FUSION", "1"},
      {"HF_CUDNN_NO_GRAPH", "1"},
  };
  static const char *variants[] = {"Base", "Deep", "Residual"};
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++)
    for (size_t v = 0; v < sizeof variants / sizeof variants[0]; v++) {
      hf_net_config cfg;
      hf_model *gm, *rm;
      hf_weights *w = weights_and_ref(c, variants[v], 77 + v, &cfg, &rm);
      printf("  %s=%s\n", cases[k].var, cases[k].val);
      /* The model keeps what it read: the runs need not see the variable. */
      assert_int_equal(gpu_model_with(c, cases[k].var, cases[k].val, w, &gm), HF_OK);
      compare(c, &cfg, gm, rm, 1, 37, 23);
      compare(c, &cfg, gm, rm, 2, 129, 65);
      hf_model_destroy(gm);
      hf_model_destroy(rm);
      hf_weights_free(w);
    }
}

/* Frames submitted two at a time (upload of one while the other computes),
 * alternating sizes so consecutive runs use different plans, from plain and
 * from registered (pinned) memory, FP32 and FP16: each matches cpu-ref. */
static void test_pipelined_and_registered(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  hf_net_config cfg;
  hf_model *gm, *rm;
  hf_weights *w = weights_and_ref(c, "Base", 11, &cfg, &rm);
  assert_int_equal(hf_model_create(c->gpu, w, &gm), HF_OK);
  enum { FRAMES = 6 };
  static const int sizes[2][2] = {{61, 35}, {200, 120}};
  const size_t cin = cfg.in_channels, maxpx = 200 * 120;
  /* One arena for every frame's tensors, registered once, like a
   * hairfilterd shared-memory segment. */
  const size_t per_in = maxpx * cin * 4, per_out = maxpx * 3 * 4;
  const size_t arena_bytes = (FRAMES * (per_in + per_out) + 4095) / 4096 * 4096;
  uint8_t *arena = aligned_alloc(4096, arena_bytes);
  float *want = malloc(per_out);
  assert_non_null(arena);
  assert_non_null(want);
  for (int reg = 0; reg <= 1; reg++) {
    if (reg) assert_int_equal(hf_backend_host_register(c->gpu, arena, arena_bytes), HF_OK);
    for (int f16 = 0; f16 <= 1; f16++) {
      hf_io io[FRAMES];
      for (int f = 0; f < FRAMES; f++) {
        const int W = sizes[f % 2][0], H = sizes[f % 2][1];
        void *in = arena + f * per_in, *out = arena + FRAMES * per_in + f * per_out;
        for (size_t i = 0; i < (size_t)W * H * cin; i++) {
          const float v = frand();
          if (f16) ((uint16_t *)in)[i] = hf_f32_to_f16(v);
          else ((float *)in)[i] = v;
        }
        memset(out, 0xff, per_out);   /* NaN: every element must be written */
        io[f] = (hf_io){1, W, H, in, f16 ? HF_F16 : HF_F32, out, f16 ? HF_F16 : HF_F32};
      }
      /* Keep two in flight: submit f+1 before waiting for f. */
      assert_int_equal(hf_model_submit(gm, &io[0]), HF_OK);
      for (int f = 0; f < FRAMES; f++) {
        if (f + 1 < FRAMES) assert_int_equal(hf_model_submit(gm, &io[f + 1]), HF_OK);
        hf_timing t;
        assert_int_equal(hf_model_wait(gm, &t), HF_OK);
        assert_true(t.infer_us > 0);
      }
      for (int f = 0; f < FRAMES; f++) {
        const size_t n = (size_t)io[f].width * io[f].height;
        float *in32 = malloc(n * cin * 4), *got = malloc(n * 3 * 4);
        assert_non_null(in32);
        assert_non_null(got);
        for (size_t i = 0; i < n * cin; i++)
          in32[i] = f16 ? hf_f16_to_f32(((const uint16_t *)io[f].in)[i]) : ((const float *)io[f].in)[i];
        for (size_t i = 0; i < n * 3; i++)
          got[i] = f16 ? hf_f16_to_f32(((const uint16_t *)io[f].out)[i]) : ((const float *)io[f].out)[i];
        hf_io ref = {1, io[f].width, io[f].height, in32, HF_F32, want, HF_F32};
        assert_int_equal(hf_model_run(rm, &ref, NULL), HF_OK);
        const double rel = rel_l2(got, want, n * 3);
        printf("  pipelined %s %s frame %d %dx%d: rel L2 %.2e\n", reg ? "registered" : "staged",
               f16 ? "f16" : "f32", f, io[f].width, io[f].height, rel);
        assert_true(rel < 1e-2);
        free(in32);
        free(got);
      }
    }
    if (reg) hf_backend_host_unregister(c->gpu, arena);
  }
  free(arena);
  free(want);
  hf_model_destroy(gm);
  hf_model_destroy(rm);
  hf_weights_free(w);
}

/* The device check's report (first bad sample, its kind, the count of
 * samples fixed, the output guard's count) and input statistics are
 * cpu-ref's. */
static void same_check(const hf_input_report *got, const hf_input_report *want,
                       const hf_input_stats *got_st, const hf_input_stats *want_st) {
  assert_int_equal(got->samples, want->samples);
  assert_int_equal(got->x, want->x);
  assert_int_equal(got->y, want->y);
  assert_int_equal(got->sample, want->sample);
  assert_int_equal(got->kind, want->kind);
  assert_int_equal(got->outputs, want->outputs);
  assert_int_equal(got_st->hair_pixels, want_st->hair_pixels);
  assert_memory_equal(got_st->value, want_st->value, sizeof got_st->value);
}

/* A registered batch of two 420x310 frames with out-of-contract samples,
 * checked on the device in one run (the kernels' frame index, and more
 * pixels than threads: each thread checks several): outputs, reports and
 * statistics as cpu-ref's frame by frame; then hf_model_submit without
 * reports (the model keeps its own) gives the same output. */
static void device_check_batch(ctx *c, const hf_net_config *cfg, hf_model *gm, hf_model *rm) {
  enum { B = 2 };
  const int W = 420, H = 310;
  const size_t cin = cfg->in_channels, n = (size_t)W * H;
  const size_t per_in = n * cin * 4, per_out = n * 3 * 4;
  const size_t arena_bytes = (B * (per_in + 2 * per_out) + 4095) / 4096 * 4096;
  uint8_t *arena = aligned_alloc(4096, arena_bytes);
  float *want = malloc(per_out);
  assert_non_null(arena);
  assert_non_null(want);
  assert_int_equal(hf_backend_host_register(c->gpu, arena, arena_bytes), HF_OK);
  float *in = (float *)arena, *out = (float *)(arena + B * per_in);
  float *again = (float *)(arena + B * (per_in + per_out));
  for (size_t i = 0; i < B * n * cin; i++) {
    static const float bad[] = {NAN, -INFINITY, -0.5f, 80.0f, 0.0f, 2.0f};
    in[i] = frand() < 0.002f ? bad[(int)(frand() * 6)] : frand();
  }
  hf_io io = {B, W, H, in, HF_F32, out, HF_F32};
  hf_input_report rep[B];
  hf_input_stats st[B];
  assert_int_equal(hf_model_run_stats(gm, &io, NULL, rep, st), HF_OK);
  for (int f = 0; f < B; f++) {
    hf_input_report want_rep;
    hf_input_stats want_st;
    hf_io ref = {1, W, H, in + n * cin * f, HF_F32, want, HF_F32};
    assert_int_equal(hf_model_run_stats(rm, &ref, NULL, &want_rep, &want_st), HF_OK);
    const double rel = rel_l2(out + n * 3 * f, want, n * 3);
    printf("  device check batch of %d %dx%d, frame %d: %llu samples fixed (cpu-ref %llu), rel L2 "
           "%.2e\n", B, W, H, f, (unsigned long long)rep[f].samples,
           (unsigned long long)want_rep.samples, rel);
    assert_true(rel < 1e-2);
    assert_true(rep[f].samples > 0);
    same_check(&rep[f], &want_rep, &st[f], &want_st);
  }
  io.out = again;
  assert_int_equal(hf_model_submit(gm, &io), HF_OK);
  assert_int_equal(hf_model_wait(gm, NULL), HF_OK);
  assert_true(rel_l2(again, out, B * n * 3) < 1e-4);
  hf_backend_host_unregister(c->gpu, arena);
  free(arena);
  free(want);
}

/* Frames from registered memory are checked on the device
 * (model_submit_scan): with out-of-contract samples of every kind, the
 * output is cpu-ref's on the host-sanitised frame, the report and the
 * statistics are cpu-ref's to the bit (the output guard's count too), and
 * the caller's input is left as it was; so is a clean frame's. Through
 * hf_model_submit_stats (two in flight) and hf_model_run_stats; then a
 * batch (device_check_batch). */
static void test_device_check(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  hf_net_config cfg;
  hf_model *gm, *rm;
  hf_weights *w = weights_and_ref(c, "Base", 12, &cfg, &rm);
  assert_int_equal(hf_model_create(c->gpu, w, &gm), HF_OK);
  const int W = 150, H = 97;
  const size_t cin = cfg.in_channels, n = (size_t)W * H;
  const size_t per_in = n * cin * 4, per_out = n * 3 * 4;
  const size_t arena_bytes = (2 * (per_in + per_out) + 4095) / 4096 * 4096;
  uint8_t *arena = aligned_alloc(4096, arena_bytes);
  uint8_t *saved = malloc(2 * per_in);
  float *in32 = malloc(per_in), *want = malloc(per_out), *got = malloc(per_out);
  assert_non_null(arena);
  assert_non_null(saved);
  assert_non_null(in32);
  assert_non_null(want);
  assert_non_null(got);
  assert_int_equal(hf_backend_host_register(c->gpu, arena, arena_bytes), HF_OK);
  for (int f16 = 0; f16 <= 1; f16++)
    for (int sync = 0; sync <= 1; sync++) {
      hf_io io[2];
      for (int f = 0; f < 2; f++) {
        const int dirty = f == 0;
        void *in = arena + f * per_in, *out = arena + 2 * per_in + f * per_out;
        for (size_t i = 0; i < n * cin; i++) {
          float v = frand();
          if (dirty && frand() < 0.004f) {
            static const float bad[] = {NAN, INFINITY, -3.0f, 100.0f, 0.0f, 1.5f};
            v = bad[(int)(frand() * 6)];
          }
          if (f16) ((uint16_t *)in)[i] = hf_f32_to_f16(v);
          else ((float *)in)[i] = v;
        }
        memset(out, 0xff, per_out);
        io[f] = (hf_io){1, W, H, in, f16 ? HF_F16 : HF_F32, out, HF_F32};
      }
      memcpy(saved, arena, 2 * per_in);
      hf_input_report rep[2];
      hf_input_stats st[2];
      if (sync) {
        for (int f = 0; f < 2; f++)
          assert_int_equal(hf_model_run_stats(gm, &io[f], NULL, &rep[f], &st[f]), HF_OK);
      } else {
        assert_int_equal(hf_model_submit_stats(gm, &io[0], &rep[0], &st[0]), HF_OK);
        assert_int_equal(hf_model_submit_stats(gm, &io[1], &rep[1], &st[1]), HF_OK);
        assert_int_equal(hf_model_wait(gm, NULL), HF_OK);
        assert_int_equal(hf_model_wait(gm, NULL), HF_OK);
      }
      assert_memory_equal(saved, arena, 2 * per_in);
      for (int f = 0; f < 2; f++) {
        for (size_t i = 0; i < n * cin; i++)
          in32[i] = f16 ? hf_f16_to_f32(((const uint16_t *)io[f].in)[i])
                        : ((const float *)io[f].in)[i];
        hf_input_report want_rep;
        hf_input_stats want_st;
        hf_io ref = {1, W, H, in32, HF_F32, want, HF_F32};
        assert_int_equal(hf_model_run_stats(rm, &ref, NULL, &want_rep, &want_st), HF_OK);
        memcpy(got, io[f].out, per_out);
        const double rel = rel_l2(got, want, n * 3);
        printf("  device check %s %s frame %d: %llu samples fixed (cpu-ref %llu), rel L2 %.2e\n",
               f16 ? "f16" : "f32", sync ? "run" : "submitted", f,
               (unsigned long long)rep[f].samples, (unsigned long long)want_rep.samples, rel);
        assert_true(rel < 1e-2);
        if (f == 0) assert_true(rep[f].samples > 0);
        /* Report and guard count as cpu-ref's; statistics of the frame as
         * it came (an f16 frame's from its halves, which widen exactly). */
        same_check(&rep[f], &want_rep, &st[f], &want_st);
        assert_int_equal(rep[f].feature, want_rep.feature);
        assert_int_equal(st[f].full_pixels, want_st.full_pixels);
      }
    }
  hf_backend_host_unregister(c->gpu, arena);
  free(arena);
  free(saved);
  free(in32);
  free(want);
  free(got);
  device_check_batch(c, &cfg, gm, rm);
  hf_model_destroy(gm);
  hf_model_destroy(rm);
  hf_weights_free(w);
}

/* hf_model_prepare builds the plan ahead: the first run of that shape then
 * allocates nothing, and prepared plans survive eviction of the others. */
static void test_prepare(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  hf_net_config cfg;
  hf_model *gm, *rm;
  hf_weights *w = weights_and_ref(c, "Small", 3, &cfg, &rm);
  assert_int_equal(gpu_model_with(c, "HF_CUDNN_PLANS", "1", w, &gm), HF_OK);
  const size_t before = hf_model_device_bytes(gm);
  assert_int_equal(hf_model_prepare(gm, 2, 100, 60), HF_OK);
  const size_t prepared = hf_model_device_bytes(gm);
  assert_true(prepared > before);
  compare(c, &cfg, gm, rm, 2, 100, 60);   /* same plan: 100x60 pads to 104x64 */
  const size_t after_first = hf_model_device_bytes(gm);
  /* Other shapes come and go (one cached plan), the prepared one stays. */
  compare(c, &cfg, gm, rm, 1, 40, 40);
  compare(c, &cfg, gm, rm, 1, 48, 16);
  compare(c, &cfg, gm, rm, 2, 97, 57);    /* the prepared shape again */
  printf("  device bytes: %zu weights, %zu prepared, %zu after its first run\n", before, prepared,
         after_first);
  hf_model_destroy(gm);
  hf_model_destroy(rm);
  hf_weights_free(w);
}

/* test_cudnn_backend devprop FILE: cuDNN's description of this machine's
 * device (CUDNN_ATTR_DEVICEPROP_JSON_REPRESENTATION), the input of the
 * deviceless descriptor test (tests/data/cudnn/). */
static int dump_devprop(const char *path) {
  if (no_gpu_reason[0]) {
    printf("SKIP: no CUDA device: %s\n", no_gpu_reason);
    return 77;
  }
  cudnnHandle_t h;
  char json[8192];
  if (cudnnCreate(&h) != CUDNN_STATUS_SUCCESS) return 1;
  int rc = hf_cg_devprop_json(h, json, sizeof json);
  cudnnDestroy(h);
  FILE *f = rc ? NULL : fopen(path, "w");
  if (!f || fputs(json, f) < 0 || fclose(f)) {
    fprintf(stderr, "devprop: %s\n", rc ? hf_strerror(rc) : path);
    return 1;
  }
  printf("%s\n", json);
  return 0;
}

/* Shared-memory segments as hairfilterd makes them (memfd, MAP_SHARED),
 * pinned with hf_backend_host_register and unpinned: both succeed, a frame
 * read from and written to a pinned segment matches cpu-ref, and the time
 * each call takes is printed. hairfilterd pins on its event-loop thread
 * (server/shm.c), so that time is how long every other connection waits
 * when a client creates a segment. */
static double now_ms(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec * 1e3 + t.tv_nsec / 1e6;
}

static void test_register_shared_segments(void **state) {
  REQUIRE_GPU();
  ctx *c = *state;
  hf_net_config cfg;
  hf_model *gm, *rm;
  hf_weights *w = weights_and_ref(c, "Base", 11, &cfg, &rm);
  assert_int_equal(hf_model_create(c->gpu, w, &gm), HF_OK);
  static const size_t mib[] = {8, 48, 192};
  const int W = 256, H = 256;
  const size_t in_bytes = (size_t)W * H * cfg.in_channels * 2;
  for (size_t k = 0; k < sizeof mib / sizeof mib[0]; k++) {
    const size_t bytes = mib[k] << 20;
    int fd = memfd_create("test-segment", MFD_CLOEXEC);
    assert_true(fd >= 0);
    assert_int_equal(ftruncate(fd, (off_t)bytes), 0);
    unsigned char *seg = mmap(NULL, bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    assert_true(seg != MAP_FAILED);
    memset(seg, 0, bytes);   /* a client has written it before it sends a frame */
    double t0 = now_ms();
    assert_int_equal(hf_backend_host_register(c->gpu, seg, bytes), HF_OK);
    double t_pin = now_ms() - t0;
    const double rel =
        f16_against_ref(gm, rm, &cfg, W, H, (uint16_t *)seg, (uint16_t *)(seg + in_bytes));
    t0 = now_ms();
    hf_backend_host_unregister(c->gpu, seg);
    double t_unpin = now_ms() - t0;
    printf("  segment %4zu MiB: pin %.3f ms, unpin %.3f ms; Base 256x256 f16 from it: rel L2 %.2e\n",
           mib[k], t_pin, t_unpin, rel);
    assert_true(rel < 1e-2);
    assert_int_equal(munmap(seg, bytes), 0);
    assert_int_equal(close(fd), 0);
  }
  hf_model_destroy(gm);
  hf_model_destroy(rm);
  hf_weights_free(w);
}

/* test_cudnn_backend fallback: the availability and fallback checks, which
 * run on every machine. test_cudnn_backend device: the comparisons with
 * cpu-ref, which need a GPU; without one the program says why and exits 77,
 * which ctest reports as skipped (not passed). */
int main(int argc, char **argv) {
  find_device();
  if (argc == 2 && !strcmp(argv[1], "fallback")) {
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_availability)};
    return cmocka_run_group_tests(tests, NULL, NULL);
  }
  if (argc == 2 && !strcmp(argv[1], "device")) {
    if (no_gpu_reason[0]) {
      printf("SKIP: no CUDA device: %s\n", no_gpu_reason);
      return 77;
    }
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_presets_vs_cpu_ref, setup, teardown),
        cmocka_unit_test_setup_teardown(test_f16_io_and_plan_eviction, setup, teardown),
        cmocka_unit_test_setup_teardown(test_forms_and_switches, setup, teardown),
        cmocka_unit_test_setup_teardown(test_pipelined_and_registered, setup, teardown),
        cmocka_unit_test_setup_teardown(test_prepare, setup, teardown),
        cmocka_unit_test_setup_teardown(test_register_shared_segments, setup, teardown),
        cmocka_unit_test_setup_teardown(test_device_check, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
  }
  if (argc == 3 && !strcmp(argv[1], "devprop")) return dump_devprop(argv[2]);
  fprintf(stderr, "usage: test_cudnn_backend fallback|device|devprop FILE.json\n");
  return 2;
}
