/* The cpu backend (oneDNN) must compute what cpu-ref computes: every preset
 * variant, odd sizes that need padding, batches, f32 and f16 io, and the
 * same answer again after its plan cache has been reused and evicted. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "backend.h"
#include "hfcore.h"

/* Relative L2 error allowed for float32 results. Half-float output is
 * rounded by both backends, and a value on a rounding boundary can land one
 * half ulp (2^-11 relative) apart, so f16 output gets f16's resolution. */
#define TOL_F32 1e-4
#define TOL_F16 1e-3

typedef struct fixture {
  hf_backend *cpu, *ref;
} fixture;

static int setup(void **state) {
  fixture *f = calloc(1, sizeof *f);
  char why[256];
  if (!f) return -1;
  if (hf_backend_create("cpu", &f->cpu, why, sizeof why) != HF_OK) {
    fprintf(stderr, "cpu backend unavailable: %s\n", why);
    free(f);
    return -1;
  }
  if (hf_backend_create("cpu-ref", &f->ref, why, sizeof why) != HF_OK) {
    hf_backend_destroy(f->cpu);
    free(f);
    return -1;
  }
  *state = f;
  return 0;
}

static int teardown(void **state) {
  fixture *f = *state;
  hf_backend_destroy(f->cpu);
  hf_backend_destroy(f->ref);
  free(f);
  return 0;
}

static uint64_t rng_next(uint64_t *s) {
  *s ^= *s << 13;
  *s ^= *s >> 7;
  *s ^= *s << 17;
  return *s;
}

/* Feature-like inputs: colour, highlight, alpha, depth in [0, 1], tangents
 * in [-1, 1], with some samples empty (all zero) as in real frames. A
 * network with an estimate gets values of the same kind in its estimate's
 * block (out of contract where a group of six straddles it: sanitised the
 * same way for both backends). */
static float *random_input(const hf_net_config *c, int batch, int w, int h, uint64_t seed) {
  size_t n = (size_t)batch * w * h * c->in_channels;
  float *in = malloc(n * sizeof *in);
  assert_non_null(in);
  uint64_t s = seed * 2654435761u + 1;
  for (size_t i = 0; i < n; i += HF_FEATURES_PER_SAMPLE) {
    int empty = rng_next(&s) % 4 == 0;
    for (int k = 0; k < HF_FEATURES_PER_SAMPLE && i + k < n; k++) {
      float u = (float)(rng_next(&s) >> 11) / (float)(1ull << 53);
      in[i + k] = empty ? 0.0f : (k >= 4 ? 2.0f * u - 1.0f : u);
    }
  }
  return in;
}

static void to_f16(const float *src, size_t n, uint16_t *dst) {
  for (size_t i = 0; i < n; i++) dst[i] = hf_f32_to_f16(src[i]);
}

static void as_f32(const void *src, hf_dtype t, size_t n, float *dst) {
  for (size_t i = 0; i < n; i++)
    dst[i] = t == HF_F32 ? ((const float *)src)[i] : hf_f16_to_f32(((const uint16_t *)src)[i]);
}

/* Runs model on a batch of w x h frames and returns the output as floats. */
static float *run(hf_model *m, const float *in, int batch, int w, int h, hf_dtype in_t,
                  hf_dtype out_t) {
  const hf_net_config *c = hf_model_config(m);
  size_t nin = (size_t)batch * w * h * c->in_channels, nout = (size_t)batch * w * h * 3;
  void *inbuf = (void *)in;
  uint16_t *in16 = NULL;
  if (in_t == HF_F16) {
    in16 = malloc(nin * sizeof *in16);
    assert_non_null(in16);
    to_f16(in, nin, in16);
    inbuf = in16;
  }
  void *out = malloc(nout * (out_t == HF_F32 ? 4 : 2));
  float *res = malloc(nout * sizeof *res);
  assert_non_null(out);
  assert_non_null(res);
  hf_io io = {batch, w, h, inbuf, in_t, out, out_t};
  hf_timing t = {-1, -1, -1};
  assert_int_equal(hf_model_run(m, &io, &t), HF_OK);
  assert_true(t.input_us >= 0 && t.infer_us >= 0 && t.output_us >= 0);
  as_f32(out, out_t, nout, res);
  free(out);
  free(in16);
  return res;
}

static double rel_l2(const float *a, const float *b, size_t n) {
  double num = 0, den = 0;
  for (size_t i = 0; i < n; i++) {
    assert_false(isnan(a[i]));
    assert_false(isnan(b[i]));
    double d = (double)a[i] - b[i];
    num += d * d;
    den += (double)b[i] * b[i];
  }
  assert_true(den > 0);
  return sqrt(num / den);
}

static void compare_cfg(fixture *f, hf_net_config cfg, int batch, int w, int h, hf_dtype in_t,
                        hf_dtype out_t, uint64_t seed) {
  const char *variant = cfg.name;
  hf_weights *wt;
  hf_model *mc, *mr;
  assert_int_equal(hf_weights_init_random(&cfg, seed, &wt), HF_OK);
  assert_int_equal(hf_model_create(f->cpu, wt, &mc), HF_OK);
  assert_int_equal(hf_model_create(f->ref, wt, &mr), HF_OK);
  assert_string_equal(hf_model_precision(mc), "fp32");
  float *in = random_input(&cfg, batch, w, h, seed + 7);
  float *a = run(mc, in, batch, w, h, in_t, out_t);
  float *b = run(mr, in, batch, w, h, in_t, out_t);
  double e = rel_l2(a, b, (size_t)batch * w * h * 3);
  double tol = out_t == HF_F16 ? TOL_F16 : TOL_F32;
  if (e >= tol)
    fail_msg("%s %dx%d batch %d in %s out %s: rel L2 %.3g >= %.1g", variant, w, h, batch,
             in_t == HF_F16 ? "f16" : "f32", out_t == HF_F16 ? "f16" : "f32", e, tol);
  free(a);
  free(b);
  free(in);
  hf_model_destroy(mc);
  hf_model_destroy(mr);
  hf_weights_free(wt);
}

static void compare(fixture *f, const char *variant, int batch, int w, int h, hf_dtype in_t,
                    hf_dtype out_t, uint64_t seed) {
  hf_net_config cfg;
  assert_int_equal(hf_variant_preset(variant, &cfg), HF_OK);
  compare_cfg(f, cfg, batch, w, h, in_t, out_t, seed);
}

/* Every preset at odd, aligned and tiny sizes. */
static void test_presets_match_ref(void **state) {
  static const int sizes[][2] = {{37, 23}, {64, 48}, {1, 1}};
  int n = hf_variant_preset_count();
  assert_true(n >= 7);
  for (int v = 0; v < n; v++)
    for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++)
      compare(*state, hf_variant_preset_name(v), 1, sizes[s][0], sizes[s][1], HF_F32, HF_F32,
              100 + v);
}

/* Batches of three, with every io dtype combination. */
static void test_batch_and_dtypes(void **state) {
  static const hf_dtype t[][2] = {{HF_F32, HF_F32}, {HF_F16, HF_F32}, {HF_F32, HF_F16},
                                  {HF_F16, HF_F16}};
  for (size_t k = 0; k < sizeof t / sizeof t[0]; k++) {
    compare(*state, "Base", 3, 37, 23, t[k][0], t[k][1], 200 + k);
    compare(*state, "Shallow", 3, 20, 9, t[k][0], t[k][1], 300 + k);
  }
  compare(*state, "Deep", 3, 33, 17, HF_F16, HF_F32, 400);
  /* Large enough that the tap sums and concat copies are split over
   * threads (they stay on one thread below ~64K values). */
  compare(*state, "Base", 2, 150, 100, HF_F32, HF_F32, 401);
  /* Aligned float32 frames: dec0 writes the caller's output, transformed,
   * over several bands and seams of every decoder. */
  compare(*state, "Base", 2, 160, 96, HF_F32, HF_F32, 402);
  /* ... and its float16 frames, a row at a time through the thread's row. */
  compare(*state, "Base", 2, 160, 96, HF_F32, HF_F16, 403);
  compare(*state, "Base", 2, 160, 96, HF_F16, HF_F16, 404);
  /* A network with an estimate: planar frames interleaved into a copy,
   * halves included, batched, aligned and not. */
  compare(*state, "KernelAC", 2, 37, 23, HF_F16, HF_F16, 405);
  compare(*state, "KernelAC", 3, 64, 48, HF_F16, HF_F32, 406);
  compare(*state, "KernelAC", 2, 64, 48, HF_F32, HF_F16, 407);
  /* ... and one whose kernel mixes the samples' sums with the estimate's. */
  compare(*state, "KernelMix", 2, 37, 23, HF_F16, HF_F16, 408);
  compare(*state, "KernelMix", 3, 64, 48, HF_F32, HF_F32, 409);
}

/* Where dec0 writes the caller's frames (aligned sizes; U-Net variants),
 * float16 results are the float32 results rounded (hf_f32_to_f16), bit
 * for bit: the same floats, converted a row at a time. Sizes with bands
 * and seams in every decoder, and a batch. */
static void test_direct_f16_output(void **state) {
  fixture *f = *state;
  static const struct { const char *v; int batch, w, h; } k[] = {
      {"Base", 2, 160, 96}, {"Small", 1, 256, 64}, {"Deep", 1, 128, 128}};
  for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
    hf_net_config cfg;
    hf_weights *wt;
    hf_model *m;
    assert_int_equal(hf_variant_preset(k[i].v, &cfg), HF_OK);
    assert_int_equal(hf_weights_init_random(&cfg, 700 + i, &wt), HF_OK);
    assert_int_equal(hf_model_create(f->cpu, wt, &m), HF_OK);
    size_t nout = (size_t)k[i].batch * k[i].w * k[i].h * 3;
    float *in = random_input(&cfg, k[i].batch, k[i].w, k[i].h, 710 + i);
    float *o32 = malloc(nout * sizeof *o32);
    uint16_t *o16 = malloc(nout * sizeof *o16);
    assert_non_null(o32), assert_non_null(o16);
    hf_io io = {k[i].batch, k[i].w, k[i].h, in, HF_F32, o32, HF_F32};
    hf_timing t;
    assert_int_equal(hf_model_run(m, &io, &t), HF_OK);
    io.out = o16, io.out_dtype = HF_F16;
    assert_int_equal(hf_model_run(m, &io, &t), HF_OK);
    for (size_t j = 0; j < nout; j++)
      if (o16[j] != hf_f32_to_f16(o32[j]))
        fail_msg("%s %dx%d: value %zu is %04x, hf_f32_to_f16(%.9g) = %04x", k[i].v, k[i].w,
                 k[i].h, j, o16[j], o32[j], hf_f32_to_f16(o32[j]));
    free(in), free(o32), free(o16);
    hf_model_destroy(m);
    hf_weights_free(wt);
  }
}

/* The Kernel architecture beyond its preset: without a head, with the
 * smallest and largest kernels and heads, the head as two convolutions
 * summed (HF_CPU_HEAD=sum, read at model creation), every io
 * dtype, and frames large enough that the output stage is split over
 * threads, across the frames of a batch. */
static void test_kernel_configs(void **state) {
  hf_net_config cfg;
  assert_int_equal(hf_variant_preset("Kernel", &cfg), HF_OK);
  static const struct { int r, hidden; } k[] = {{2, 0}, {1, 1}, {4, 64}, {3, 16}};
  for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
    cfg.kernel_radius = k[i].r, cfg.kernel_hidden = k[i].hidden;
    cfg.out_channels = hf_kernel_taps(k[i].r) + 3;
    snprintf(cfg.name, sizeof cfg.name, "Kernel r%d h%d", k[i].r, k[i].hidden);
    compare_cfg(*state, cfg, 2, 21, 13, HF_F32, HF_F32, 600 + i);
  }
  compare(*state, "Kernel", 3, 37, 23, HF_F16, HF_F32, 610);
  compare(*state, "Kernel", 2, 37, 23, HF_F32, HF_F16, 611);
  compare(*state, "Kernel", 2, 150, 100, HF_F32, HF_F32, 612);
  compare(*state, "Kernel", 2, 64, 48, HF_F32, HF_F32, 613); /* aligned: read in place */
  assert_int_equal(setenv("HF_CPU_HEAD", "sum", 1), 0);
  compare(*state, "Kernel", 2, 37, 23, HF_F32, HF_F32, 614);
  compare(*state, "Kernel", 1, 64, 48, HF_F32, HF_F32, 615);
  compare(*state, "Kernel", 2, 150, 100, HF_F16, HF_F16, 616);
  assert_int_equal(unsetenv("HF_CPU_HEAD"), 0);
  /* The reference output stage on the backend's threads, for comparison. */
  assert_int_equal(setenv("HF_CPU_KERNEL_REF", "1", 1), 0);
  compare(*state, "Kernel", 2, 150, 100, HF_F32, HF_F16, 617);
  assert_int_equal(unsetenv("HF_CPU_KERNEL_REF"), 0);
}

/* The row-vectorised output stage (hf_cpu_kernel_rows, whose exponential
 * runs in the widest vector unit the CPU has) against the reference
 * (hf_kernel_output_rows). Each pixel's logits are a maximum M (0, 20 or
 * 88) on one tap and M plus an offset on the others: offsets that weigh
 * (-1e-3 to -15, and ties), offsets across the exponential's cut-off at
 * -87 and far below it (down to -1e30). A block of pixels without a
 * covered sample puts the whole kernel of the corner pixel on uncovered
 * neighbours (colour 1, highlight 0, alpha from the corrections), and a
 * width that is no multiple of the vector width leaves a tail in every
 * tap's loop. ksums HF_KSUMS_MIXED: six sums a pixel (the estimate's other
 * than the samples') and the mixing channel, beta from about 0.02 to 0.98. */
static void kernel_rows_extreme_logits(int ksums) {
  enum { W = 37, H = 11, R = 3, SPP = 4, TAPS = (2 * R + 1) * (2 * R + 1), MAXCH = TAPS + 4 };
  static const float maxima[] = {0.0f, 20.0f, 88.0f};
  static const float offset[] = {0.0f,   -1e-3f,  -0.5f,  -1.0f,   -2.0f,   -5.0f,
                                 -10.0f, -15.0f,  -50.0f, -86.99f, -87.0f,  -87.01f,
                                 -87.5f, -100.0f, -1e4f,  -1e30f};
  const int K = hf_kernel_sums_floats(ksums), CH = TAPS + 3 + (ksums == HF_KSUMS_MIXED);
  static float raw[H * W * MAXCH], planes[6 * H * W], sums[H * W * 6], got[H * W * 3],
      want[H * W * 3];
  float *scratch = malloc(hf_cpu_kernel_scratch(W, R) * sizeof(float));
  assert_non_null(scratch);
  uint32_t rng = 12345;
  for (int i = 0; i < H * W; i++) {
    for (int j = 0; j < K; j += 3) {
      rng = rng * 1664525u + 1013904223u;
      float n = (float)(rng >> 29) * 0.5f; /* 0 to 3.5 */
      if (i % W < 6 && i / W < 6) n = 0.0f; /* the uncovered block */
      float c = n * (float)((rng >> 8) & 255) / 255.0f, h = n * (float)((rng >> 16) & 63) / 16.0f;
      planes[j * H * W + i] = sums[K * i + j] = n;
      planes[(j + 1) * H * W + i] = sums[K * i + j + 1] = c;
      planes[(j + 2) * H * W + i] = sums[K * i + j + 2] = h;
    }
    rng = rng * 1664525u + 1013904223u;
    const float m = maxima[(rng >> 8) % 3];
    const int top = (int)((rng >> 16) % TAPS);
    for (int k = 0; k < CH; k++) {
      rng = rng * 1664525u + 1013904223u;
      float v = k == top  ? m
                : k < TAPS ? m + offset[(rng >> 8) % (sizeof offset / sizeof offset[0])]
                           : ((float)((rng >> 8) & 1023) / 512.0f - 1.0f) * 0.25f;
      raw[(size_t)i * CH + k] = v;
    }
  }
  hf_cpu_kernel_rows(W, H, SPP, R, ksums, planes, raw, W, CH, 0, H, got, scratch);
  hf_kernel_output_rows(W, H, SPP, R, ksums, sums, raw, W, CH, 0, H, want);
  for (int i = 0; i < H * W * 3; i++) {
    assert_true(isfinite(got[i]));
    if (fabsf(got[i] - want[i]) > 1e-5f * (1.0f + fabsf(want[i])))
      fail_msg("output %d (pixel %d, channel %d): %.9g, reference %.9g", i, i / 3, i % 3,
               got[i], want[i]);
  }
  /* The corner pixel saw no covered sample: colour 1 and highlight 0 before
   * the corrections. */
  assert_true(fabsf(got[HF_OUT_COLOR] - (1.0f + raw[TAPS])) < 1e-6f);
  assert_true(fabsf(got[HF_OUT_HIGHLIGHT] - fmaxf(raw[TAPS + 1], 0.0f)) < 1e-6f);
  free(scratch);
}

static void test_kernel_rows_extreme_logits(void **state) {
  (void)state;
  kernel_rows_extreme_logits(HF_KSUMS_SAMPLES);
}

static void test_kernel_rows_mixed(void **state) {
  (void)state;
  kernel_rows_extreme_logits(HF_KSUMS_MIXED);
}

/* The same frame gives the same bytes on a reused plan, after other sizes
 * and batches have gone through the cache and evicted it, and a batch's
 * frames equal the frames run alone. */
static void test_repeat_and_cache(void **state) {
  fixture *f = *state;
  hf_net_config cfg;
  hf_weights *wt;
  hf_model *m;
  assert_int_equal(hf_variant_preset("Base", &cfg), HF_OK);
  assert_int_equal(hf_weights_init_random(&cfg, 9, &wt), HF_OK);
  assert_int_equal(hf_model_create(f->cpu, wt, &m), HF_OK);
  const int w = 45, h = 30;
  size_t nout = (size_t)w * h * 3;
  float *in = random_input(&cfg, 2, w, h, 11);
  float *first = run(m, in, 1, w, h, HF_F32, HF_F32);
  float *again = run(m, in, 1, w, h, HF_F32, HF_F32);
  assert_memory_equal(first, again, nout * sizeof(float));
  free(again);
  /* More distinct sizes than the cache holds. */
  static const int other[][2] = {{8, 8}, {16, 24}, {40, 8}, {24, 40}, {72, 16}, {9, 70}};
  for (size_t k = 0; k < sizeof other / sizeof other[0]; k++) {
    float *o = run(m, in, 1, other[k][0], other[k][1], HF_F32, HF_F32);
    free(o);
  }
  again = run(m, in, 1, w, h, HF_F32, HF_F32);
  assert_memory_equal(first, again, nout * sizeof(float));
  /* Frame 0 of a batch of two against frame 0 alone; frame 1 against the
   * second frame run alone. oneDNN may split work differently for another
   * batch size, so this one is compared with the tolerance, not bytes. */
  float *pair = run(m, in, 2, w, h, HF_F32, HF_F32);
  float *second = run(m, in + (size_t)w * h * cfg.in_channels, 1, w, h, HF_F32, HF_F32);
  assert_true(rel_l2(pair, first, nout) < TOL_F32);
  assert_true(rel_l2(pair + nout, second, nout) < TOL_F32);
  assert_true(rel_l2(second, first, nout) > TOL_F32); /* different frames differ */
  free(first);
  free(again);
  free(pair);
  free(second);
  free(in);
  hf_model_destroy(m);
  hf_weights_free(wt);
}

/* The deconvolution path (HF_CPU_DECONV, read at model creation) computes
 * the same network as the default taps path. */
static void test_deconv_path_matches_ref(void **state) {
  assert_int_equal(setenv("HF_CPU_DECONV", "1", 1), 0);
  compare(*state, "Base", 1, 37, 23, HF_F32, HF_F32, 500);
  compare(*state, "Deep", 2, 33, 17, HF_F32, HF_F32, 501);
  compare(*state, "Shallow", 1, 64, 48, HF_F32, HF_F32, 502);
  assert_int_equal(unsetenv("HF_CPU_DECONV"), 0);
}

/* The registry lists "cpu", and "auto" prefers it over cpu-ref. */
static void test_registry(void **state) {
  const char *const *names = hf_backend_list();
  int found = 0;
  for (int i = 0; names[i]; i++) found |= !strcmp(names[i], "cpu");
  assert_true(found);
  hf_backend *b;
  char why[512];
  assert_int_equal(hf_backend_create("auto", &b, why, sizeof why), HF_OK);
  assert_string_not_equal(hf_backend_name(b), "cpu-ref");
  hf_backend_destroy(b);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_registry),
    cmocka_unit_test(test_presets_match_ref),
    cmocka_unit_test(test_batch_and_dtypes),
    cmocka_unit_test(test_direct_f16_output),
    cmocka_unit_test(test_kernel_configs),
    cmocka_unit_test(test_kernel_rows_extreme_logits),
    cmocka_unit_test(test_kernel_rows_mixed),
    cmocka_unit_test(test_repeat_and_cache),
    cmocka_unit_test(test_deconv_path_matches_ref),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
