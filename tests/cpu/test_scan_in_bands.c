/* The cpu backend checks a frame and makes its input statistics in enc0's
 * bands, as the convolution reads it (model_run_scan), instead of in a
 * pass of its own before the run. Its results, reports and statistics
 * must be those of the common path (check, sanitised copy, run), which a
 * second backend opened with HF_CPU_ENC_BAND_KB=0 takes, for every bundled
 * variant, float32 and float16 frames, one frame and several, bad samples
 * in any band of any frame; and the backend must answer its contract:
 * HF_OK for a clean frame it reads in bands, HF_RUN_UNCLEAN with nothing
 * written for a frame with bad samples, HF_RUN_DECLINED for a frame it
 * does not read in bands; and where dec0 writes the caller's frames, the
 * output guard applied to each row as it is made must give the values and
 * counts of the guard's pass after the run. ctest also runs this with the smallest bands
 * (HF_CPU_BAND_KB=1: one output row of enc0 per band). */
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

#include "cpu_run.h"

static hf_backend *banded, *common;

static int setup(void **state) {
  char why[256];
  /* The band size is read when the backend opens. */
  if (hf_backend_create("cpu", &banded, why, sizeof why) != HF_OK) {
    fprintf(stderr, "cpu backend unavailable: %s\n", why);
    return -1;
  }
  const char *was = getenv("HF_CPU_ENC_BAND_KB");
  char *keep = was ? strdup(was) : NULL;
  setenv("HF_CPU_ENC_BAND_KB", "0", 1);
  int rc = hf_backend_create("cpu", &common, why, sizeof why);
  if (keep) setenv("HF_CPU_ENC_BAND_KB", keep, 1);
  else unsetenv("HF_CPU_ENC_BAND_KB");
  free(keep);
  if (rc != HF_OK) {
    fprintf(stderr, "cpu backend unavailable: %s\n", why);
    return -1;
  }
  return 0;
}

static int teardown(void **state) {
  hf_backend_destroy(banded);
  hf_backend_destroy(common);
  return 0;
}

/* Frames of in-contract features as float32: a quarter of the samples
 * empty, colour and highlight in [0, 2), alpha in (0, 1], depth in [0, 1],
 * tangents in [-1, 1]; each value exact in binary16. */
static float *frames(int spp, int batch, int w, int h, uint64_t seed) {
  size_t samples = (size_t)batch * w * h * spp;
  float *in = malloc(samples * HF_FEATURES_PER_SAMPLE * sizeof *in);
  assert_non_null(in);
  uint64_t s = seed * 2654435761u + 1;
  for (size_t i = 0; i < samples; i++) {
    float *v = in + i * HF_FEATURES_PER_SAMPLE;
    int empty = rng_next(&s) % 4 == 0;
    for (int k = 0; k < HF_FEATURES_PER_SAMPLE; k++) {
      float u = (float)(rng_next(&s) >> 11) / (float)(1ull << 53);
      float x = k < 2 ? 2.0f * u : k == 2 ? (u >= 0x1p-10f ? u : 1.0f) : k == 3 ? u : 2.0f * u - 1.0f;
      v[k] = empty ? 0.0f : hf_f16_to_f32(hf_f32_to_f16(x));
    }
  }
  return in;
}

/* Makes sample `sample` of pixel (x, y) of frame n out of contract, of a
 * kind chosen by kind (NaN, infinity, alpha 0 with colour, out of range). */
static void plant(float *in, int spp, int w, int h, int n, int x, int y, int sample, int kind) {
  float *v = in + ((((size_t)n * h + y) * w + x) * spp + sample) * HF_FEATURES_PER_SAMPLE;
  switch (kind % 4) {
  case 0: v[0] = NAN; break;
  case 1: v[3] = INFINITY; break;
  case 2: v[2] = 0.0f, v[0] = 0.5f; break;
  default: v[4] = -3.0f; break;
  }
}

/* in (float32) as dtype: the same values, as halves for HF_F16. */
static void *as_dtype(const float *in, size_t n, hf_dtype dtype) {
  if (dtype == HF_F32) {
    void *c = malloc(n * sizeof(float));
    assert_non_null(c);
    return memcpy(c, in, n * sizeof(float));
  }
  uint16_t *h = malloc(n * sizeof *h);
  assert_non_null(h);
  for (size_t i = 0; i < n; i++) h[i] = hf_f32_to_f16(in[i]);
  return h;
}

/* Where bad samples go, by case: none; the first pixel of the first frame;
 * the last pixel of the last frame; one in every frame at a row that moves
 * with the case (so across the band edges); many, scattered. */
#define CASES 5
static void plant_case(float *in, int spp, int batch, int w, int h, int which, uint64_t seed) {
  uint64_t s = seed + 77;
  switch (which) {
  case 0: break;
  case 1: plant(in, spp, w, h, 0, 0, 0, 0, 0); break;
  case 2: plant(in, spp, w, h, batch - 1, w - 1, h - 1, spp - 1, 1); break;
  case 3:
    for (int n = 0; n < batch; n++) plant(in, spp, w, h, n, (7 * n + 3) % w, (11 * n + 5) % h, n % spp, n + 2);
    break;
  default:
    for (int k = 0; k < 40; k++) {
      int n = (int)(rng_next(&s) % (uint64_t)batch), x = (int)(rng_next(&s) % (uint64_t)w);
      int y = (int)(rng_next(&s) % (uint64_t)h), sm = (int)(rng_next(&s) % (uint64_t)spp);
      plant(in, spp, w, h, n, x, y, sm, k);
    }
  }
}

/* Variant v on both backends, every case of bad samples, float32 and
 * float16 inputs and outputs: every output byte, report and statistic
 * equal. */
static void compare_variant(const char *variant, int batch, int w, int h, uint64_t seed) {
  hf_weights *wa, *wb;
  hf_model *a = load_variant(banded, variant, &wa), *b = load_variant(common, variant, &wb);
  const hf_net_config *c = hf_model_config(a);
  const size_t nin = (size_t)batch * w * h * c->in_channels;
  for (int which = 0; which < CASES; which++) {
    float *in = frames(c->spp, batch, w, h, seed + (uint64_t)which);
    plant_case(in, c->spp, batch, w, h, which, seed);
    for (int d = 0; d < 2; d++) {
      hf_dtype in_t = d ? HF_F16 : HF_F32, out_t = (which + d) % 2 ? HF_F16 : HF_F32;
      void *x = as_dtype(in, nin, in_t);
      hf_input_report ra[4], rb[4];
      hf_input_stats sa[4], sb[4];
      void *oa = run(a, x, in_t, batch, w, h, out_t, ra, sa);
      void *ob = run(b, x, in_t, batch, w, h, out_t, rb, sb);
      size_t nout = (size_t)batch * w * h * 3 * (out_t == HF_F32 ? 4 : 2);
      if (memcmp(oa, ob, nout))
        fail_msg("%s %dx%d batch %d, case %d, in %s out %s: the output differs from the "
                 "common path's", variant, w, h, batch, which, d ? "f16" : "f32",
                 out_t == HF_F32 ? "f32" : "f16");
      same_reports(ra, rb, sa, sb, batch);
      uint64_t bad = 0;
      for (int n = 0; n < batch; n++) bad += ra[n].samples;
      assert_int_equal(bad > 0, which > 0);
      free(oa);
      free(ob);
      free(x);
    }
    free(in);
  }
  hf_model_destroy(a);
  hf_model_destroy(b);
  hf_weights_free(wa);
  hf_weights_free(wb);
}

/* Every bundled variant at a size that needs no padding and splits into
 * several bands with a shorter last one (96x72), one frame and three. */
static void test_matches_common_path(void **state) {
  for (size_t v = 0; v < NVARIANTS; v++) {
    compare_variant(VARIANTS[v], 1, 96, 72, 100 + 10 * v);
    compare_variant(VARIANTS[v], 3, 64, 48, 105 + 10 * v);
  }
}

/* The backend's answers, called directly: what backend.c relies on. */
static void test_contract(void **state) {
  hf_weights *w, *w2;
  hf_model *m = load_variant(banded, "base", &w), *mc = load_variant(common, "base", &w2);
  const hf_net_config *c = hf_model_config(m);
  const int batch = 2, W = 64, H = 48;
  const size_t nin = (size_t)batch * W * H * c->in_channels, nout = (size_t)batch * W * H * 3;
  float *in = frames(c->spp, batch, W, H, 9);
  float *out = malloc(nout * sizeof *out), *mark = malloc(nout * sizeof *mark);
  assert_non_null(out);
  assert_non_null(mark);
  memset(mark, 0xa5, nout * sizeof *mark);
  hf_input_report rep[2], want;
  hf_input_stats st[2], st_want;
  hf_timing t;
  const hf_backend_ops *ops = m->backend->ops;
  assert_non_null(ops->model_run_scan);

  /* Clean aligned float32 frames: run, checked, counted. */
  hf_io io = {batch, W, H, in, HF_F32, out, HF_F32};
  int guarded = 0;
  assert_int_equal(ops->model_run_scan(m->impl, &io, &t, rep, st, &guarded), HF_OK);
  assert_int_equal(guarded, 1); /* Base at an aligned size: dec0 writes the frames */
  for (int n = 0; n < batch; n++) {
    const float *frame = in + (size_t)n * W * H * c->in_channels;
    assert_int_equal(rep[n].samples, 0);
    assert_int_equal(hf_input_stats_compute(frame, HF_F32, W, H, c->spp, &st_want), HF_OK);
    assert_int_equal(st[n].hair_pixels, st_want.hair_pixels);
    assert_memory_equal(st[n].value, st_want.value, sizeof st_want.value);
  }

  /* A bad sample in the second frame's last row: HF_RUN_UNCLEAN, the
   * reports hf_features_check's, nothing written. */
  plant(in, c->spp, W, H, 1, W - 2, H - 1, 1, 0);
  memcpy(out, mark, nout * sizeof *out);
  assert_int_equal(ops->model_run_scan(m->impl, &io, &t, rep, NULL, &guarded), HF_RUN_UNCLEAN);
  assert_memory_equal(out, mark, nout * sizeof *out);
  assert_int_equal(rep[0].samples, 0);
  hf_features_check(in + (size_t)W * H * c->in_channels, HF_F32, W, H, c->spp, &want);
  assert_int_equal(rep[1].samples, 1);
  assert_int_equal(rep[1].x, want.x);
  assert_int_equal(rep[1].y, H - 1);
  assert_int_equal(rep[1].sample, want.sample);

  /* A float32 frame that needs padding, and a backend without bands:
   * declined, nothing written. */
  hf_io padded = {1, 37, 23, in, HF_F32, out, HF_F32};
  memcpy(out, mark, nout * sizeof *out);
  assert_int_equal(ops->model_run_scan(m->impl, &padded, &t, rep, NULL, &guarded), HF_RUN_DECLINED);
  assert_int_equal(ops->model_run_scan(mc->impl, &io, &t, rep, NULL, &guarded), HF_RUN_DECLINED);
  assert_memory_equal(out, mark, nout * sizeof *out);

  /* Halves: run in bands at any size. */
  uint16_t *half = as_dtype(in, nin, HF_F16);
  hf_io hio = {1, 37, 23, half, HF_F16, out, HF_F32};
  assert_int_equal(ops->model_run_scan(m->impl, &hio, &t, rep, NULL, &guarded), HF_OK);
  assert_int_equal(rep[0].samples, 0);

  free(half);
  free(in);
  free(out);
  free(mark);
  hf_model_destroy(m);
  hf_model_destroy(mc);
  hf_weights_free(w);
  hf_weights_free(w2);
}

/* Weights whose colour output leaves its range on part of the frame: dec0
 * guards each row as it writes the caller's frames (float32 and float16),
 * with the values and counts of the guard's pass after the run. */
static void test_guard_in_rows(void **state) {
  hf_weights *wa, *wb;
  hf_model *a, *b;
  char path[1024], err[256];
  snprintf(path, sizeof path, "%s/base.safetensors", HF_WEIGHTS_DIR);
  if (hf_weights_load(path, &wa, err, sizeof err) != HF_OK) fail_msg("%s: %s", path, err);
  if (hf_weights_load(path, &wb, err, sizeof err) != HF_OK) fail_msg("%s: %s", path, err);
  const int batch = 2, W = 96, H = 72;
  float *in = frames(wa->cfg.spp, batch, W, H, 31);
  /* The raw colour of one pixel, from its transformed value c^3/32 + c/5 +
   * 1 (increasing) by bisection; the bias moved so that the first frame's
   * middle pixel's raw colour lands where the transform reaches
   * HF_OUTPUT_MAX, which puts part of the frame beyond it. */
  assert_int_equal(hf_model_create(common, wb, &b), HF_OK);
  hf_input_report r0[2];
  hf_input_stats s0[2];
  float *o0 = run(b, in, HF_F32, batch, W, H, HF_F32, r0, s0);
  float target = o0[((size_t)(H / 2) * W + W / 2) * 3 + HF_OUT_COLOR];
  double lo = -1e3, hi = 1e3, top = 0;
  for (int k = 0; k < 200; k++) {
    double mid = (lo + hi) / 2;
    if (mid * mid * mid / 32 + mid / 5 + 1 < target) lo = mid;
    else hi = mid;
  }
  const double raw = lo;
  lo = 0, hi = 1e3;
  for (int k = 0; k < 200; k++) {
    double mid = (lo + hi) / 2;
    if (mid * mid * mid / 32 + mid / 5 + 1 < HF_OUTPUT_MAX) lo = mid;
    else hi = mid;
  }
  top = lo;
  free(o0);
  hf_model_destroy(b);
  wa->dec_b[0][HF_OUT_COLOR] += (float)(top - raw);
  wb->dec_b[0][HF_OUT_COLOR] += (float)(top - raw);
  assert_int_equal(hf_model_create(banded, wa, &a), HF_OK);
  assert_int_equal(hf_model_create(common, wb, &b), HF_OK);
  for (int d = 0; d < 2; d++) {
    hf_dtype out_t = d ? HF_F16 : HF_F32;
    hf_input_report ra[2], rb[2];
    hf_input_stats sa[2], sb[2];
    void *oa = run(a, in, HF_F32, batch, W, H, out_t, ra, sa);
    void *ob = run(b, in, HF_F32, batch, W, H, out_t, rb, sb);
    assert_memory_equal(oa, ob, (size_t)batch * W * H * 3 * (d ? 2 : 4));
    same_reports(ra, rb, sa, sb, batch);
    for (int n = 0; n < batch; n++) {
      assert_true(ra[n].outputs > 0);
      assert_true(ra[n].outputs < (uint64_t)W * H);
    }
    free(oa);
    free(ob);
  }
  /* The run said it guarded, so backend.c does not read the output again. */
  float *out = malloc((size_t)batch * W * H * 3 * sizeof *out);
  assert_non_null(out);
  hf_io io = {batch, W, H, in, HF_F32, out, HF_F32};
  hf_input_report rep[2];
  hf_timing t;
  int guarded = 0;
  assert_int_equal(a->backend->ops->model_run_scan(a->impl, &io, &t, rep, NULL, &guarded), HF_OK);
  assert_int_equal(guarded, 1);
  for (size_t i = 0; i < (size_t)batch * W * H * 3; i += 3) assert_true(out[i] <= HF_OUTPUT_MAX);
  free(out);
  free(in);
  hf_model_destroy(a);
  hf_model_destroy(b);
  hf_weights_free(wa);
  hf_weights_free(wb);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_contract),
    cmocka_unit_test(test_matches_common_path),
    cmocka_unit_test(test_guard_in_rows),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
