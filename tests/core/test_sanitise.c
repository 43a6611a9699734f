/* Out-of-contract values (protocol/FEATURES.md): the sanitising rule on
 * every kind of bad value against a plain reference of the documented rule,
 * in float32 and binary16, at every position of the vector loops; the
 * output guard; and hf_model_run on every CPU backend: a frame with a bad
 * sample gives finite results equal to those of the same frame with the
 * sample made what the rule says, the backends agree, and the caller's
 * input is never written; the widening of a binary16 frame for a float32
 * backend (hf_features_widen) against the sanitised halves widened, and
 * its input statistics against hf_input_stats_compute's. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "hfcore.h"
#include "test_paths.h"

static uint64_t rng = 0x2545f4914f6cdd1dull;
static uint32_t next(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (uint32_t)(rng >> 11);
}

/* ---- the rule, written out plainly ------------------------------------------ */

static const float LO[6] = {0, 0, 0, 0, -1, -1}, HI[6] = {64, 64, 1, 1, 1, 1};

/* Applies the documented rule to one sample; returns 1 when it changed it. */
static int reference_rule(float *s) {
  int finite = 1, zero = 1, in = s[2] > 0;
  for (int f = 0; f < 6; f++) {
    finite &= isfinite(s[f]) != 0;
    zero &= s[f] == 0;
    in &= s[f] >= LO[f] && s[f] <= HI[f];
  }
  if (zero || (finite && in)) return 0;
  if (!finite || s[2] <= 0) {
    for (int f = 0; f < 6; f++) s[f] = 0;
    return 1;
  }
  for (int f = 0; f < 6; f++) s[f] = s[f] < LO[f] ? LO[f] : s[f] > HI[f] ? HI[f] : s[f];
  return 1;
}

/* A feature value: mostly in range, often at or just past a bound, some
 * non-finite. */
static float special(int f) {
  static const float pal[] = {0.0f, -0.0f, 1.0f, -1.0f, 0.5f, 64.0f, 64.0625f, -1.0009766f,
                              1.0009766f, 1e-40f, -1e-40f, 1e30f, -1e30f, 2.0f, 100.0f, 6e-8f};
  uint32_t r = next();
  switch (r % 16) {
  case 0: return NAN;
  case 1: return -NAN;
  case 2: return INFINITY;
  case 3: return -INFINITY;
  case 4: case 5: case 6: case 7: return pal[(r >> 4) % 16];
  default: return f >= 4 ? (float)(r >> 8) / 8388608.0f - 1.0f : (float)(r >> 8) / 16777216.0f;
  }
}

/* n samples: a third clean covered, a third all zero, a third with one or
 * more special values. */
static float *make_samples(size_t n) {
  float *s = malloc(n * 6 * sizeof *s);
  for (size_t i = 0; i < n; i++) {
    float *p = s + i * 6;
    int kind = next() % 3;
    for (int f = 0; f < 6; f++)
      p[f] = kind == 1 ? 0.0f : f >= 4 ? (float)(next() >> 8) / 8388608.0f - 1.0f
                                       : (float)((next() >> 8) + 1) / 16777217.0f;
    if (kind == 2)
      for (int k = 0, m = 1 + next() % 3; k < m; k++) p[next() % 6] = special(next() % 6);
  }
  return s;
}

static int same_bits(float a, float b) { return memcmp(&a, &b, 4) == 0; }

static void check_rule_f32(int w, int h, int spp) {
  size_t n = (size_t)w * h * spp;
  float *s = make_samples(n), *want = malloc(n * 6 * sizeof(float));
  memcpy(want, s, n * 6 * sizeof(float));
  uint64_t changed = 0;
  size_t first = n;
  for (size_t i = 0; i < n; i++)
    if (reference_rule(want + i * 6)) {
      changed++;
      if (first == n) first = i;
    }
  hf_input_report r, c;
  hf_features_check(s, HF_F32, w, h, spp, &c);
  assert_int_equal(c.samples, changed);
  hf_features_sanitise(s, HF_F32, w, h, spp, &r);
  assert_int_equal(r.samples, changed);
  for (size_t i = 0; i < n * 6; i++)
    if (!same_bits(s[i], want[i]) && !(s[i] == 0 && want[i] == 0)) {
      fprintf(stderr, "value %zu: %g, want %g\n", i, s[i], want[i]);
      fail();
    }
  if (changed) {
    assert_int_equal((size_t)r.y * w + r.x, first / spp);
    assert_int_equal(r.sample, (int)(first % spp));
    assert_true(r.feature >= 0 && r.feature < 6);
    assert_true(r.kind >= HF_SANITISED_NONFINITE && r.kind <= HF_SANITISED_CLAMPED);
    assert_memory_equal(&c, &r, sizeof r);
  } else {
    assert_int_equal(r.x, -1);
  }
  /* Sanitised input is clean. */
  hf_features_check(s, HF_F32, w, h, spp, &c);
  assert_int_equal(c.samples, 0);
  free(s);
  free(want);
}

static void check_rule_f16(int w, int h, int spp) {
  size_t n = (size_t)w * h * spp;
  float *s = make_samples(n), *want = malloc(n * 6 * sizeof(float));
  uint16_t *h16 = malloc(n * 6 * sizeof *h16);
  for (size_t i = 0; i < n * 6; i++) {
    h16[i] = hf_f32_to_f16(s[i]);
    want[i] = hf_f16_to_f32(h16[i]);  /* the values the rule sees */
  }
  uint64_t changed = 0;
  for (size_t i = 0; i < n; i++) changed += (uint64_t)reference_rule(want + i * 6);
  hf_input_report r;
  hf_features_sanitise(h16, HF_F16, w, h, spp, &r);
  assert_int_equal(r.samples, changed);
  for (size_t i = 0; i < n * 6; i++) {
    uint16_t expect = hf_f32_to_f16(want[i]);
    if (h16[i] != expect && !((h16[i] | expect) == 0x8000u)) {
      fprintf(stderr, "half %zu: %04x, want %04x\n", i, h16[i], expect);
      fail();
    }
  }
  free(s);
  free(want);
  free(h16);
}

static void test_rule(void **state) {
  /* Sizes whose sample counts are 1, 2, 3 mod 4 exercise the scalar head
   * and tail around the vector loops. */
  static const int shapes[][3] = {{1, 1, 1}, {3, 1, 1}, {1, 1, 2}, {5, 3, 1},
                                  {7, 5, 4}, {64, 64, 4}, {33, 9, 2}, {17, 3, 3}};
  for (int rep = 0; rep < 4; rep++)
    for (size_t i = 0; i < sizeof shapes / sizeof shapes[0]; i++) {
      check_rule_f32(shapes[i][0], shapes[i][1], shapes[i][2]);
      check_rule_f16(shapes[i][0], shapes[i][1], shapes[i][2]);
    }
}

/* One bad value at every position of a clean frame, both dtypes. */
static void test_rule_each_position(void **state) {
  const int w = 3, h = 3, spp = 3, n = w * h * spp;
  for (int i = 0; i < n * 6; i++)
    for (int v = 0; v < 4; v++) {
      static const float bad[4] = {NAN, INFINITY, 65.0f, -2.0f};
      float s[27 * 6];
      for (int k = 0; k < n * 6; k++) s[k] = k % 6 == 4 ? -0.5f : 0.5f;
      s[i] = bad[v];
      uint16_t s16[27 * 6];
      for (int k = 0; k < n * 6; k++) s16[k] = hf_f32_to_f16(s[k]);
      hf_input_report r, r16;
      hf_features_sanitise(s, HF_F32, w, h, spp, &r);
      hf_features_sanitise(s16, HF_F16, w, h, spp, &r16);
      /* Colour and highlight take 65 (clamped), everything takes NaN and
       * Inf; -2 is out of every range; alpha 65 clamps. */
      assert_int_equal(r.samples, 1);
      assert_int_equal(r16.samples, 1);
      assert_int_equal(r.sample, (i / 6) % spp);
      assert_int_equal(r.feature, i % 6);
      assert_int_equal(r.x, (i / 6 / spp) % w);
      assert_int_equal(r.y, i / 6 / spp / w);
      int uncovered = v < 2 || (v == 3 && i % 6 == 2);
      assert_int_equal(r.kind, v < 2 ? HF_SANITISED_NONFINITE
                               : uncovered ? HF_SANITISED_UNCOVERED : HF_SANITISED_CLAMPED);
      for (int f = 0; f < 6; f++) {
        float want = uncovered ? 0.0f
                     : f == i % 6 ? (v == 2 ? HI[f] : LO[f])
                                  : (f == 4 ? -0.5f : 0.5f);
        assert_true(s[(i / 6) * 6 + f] == want);
        assert_true(hf_f16_to_f32(s16[(i / 6) * 6 + f]) == want);
      }
    }
}

/* hf_features_widen against its definition: the floats of the sanitised
 * halves bit for bit, the report of hf_features_check, the input unchanged;
 * without out, the same report and statistics.
 * plant: 0 for make_samples' mix (bad samples everywhere), else a clean
 * frame with that many bad samples at random places, so that the first one
 * may fall in any thread's chunks. */
static void check_widen(int w, int h, int spp, int plant) {
  size_t n = (size_t)w * h * spp;
  float *s = make_samples(n), *got = malloc(n * 6 * sizeof(float)),
        *want = malloc(n * 6 * sizeof(float));
  uint16_t *h16 = malloc(n * 6 * sizeof *h16), *copy = malloc(n * 6 * sizeof *copy);
  if (plant) {
    for (size_t i = 0; i < n * 6; i++) s[i] = i % 6 == 4 ? -0.25f : 0.5f;
    for (int k = 0; k < plant; k++) s[(n / 2 + next() % (n - n / 2)) * 6 + next() % 6] = 100.0f;
  }
  for (size_t i = 0; i < n * 6; i++) h16[i] = hf_f32_to_f16(s[i]);
  memcpy(copy, h16, n * 6 * sizeof *copy);
  hf_input_report c, r, sr;
  hf_features_check(h16, HF_F16, w, h, spp, &c);
  hf_features_sanitise(copy, HF_F16, w, h, spp, &sr);
  for (size_t i = 0; i < n * 6; i++) want[i] = hf_f16_to_f32(copy[i]);
  memcpy(copy, h16, n * 6 * sizeof *copy);
  hf_input_stats st, want_st;
  assert_int_equal(hf_input_stats_compute(h16, HF_F16, w, h, spp, &want_st), HF_OK);
  assert_int_equal(hf_features_widen(h16, got, w, h, spp, &r, &st), HF_OK);
  assert_memory_equal(got, want, n * 6 * sizeof(float));
  assert_memory_equal(&st, &want_st, sizeof st);
  memset(got, 0, n * 6 * sizeof(float));
  assert_int_equal(hf_features_widen(h16, got, w, h, spp, &r, NULL), HF_OK);
  assert_memory_equal(got, want, n * 6 * sizeof(float));
  assert_memory_equal(&r, &c, sizeof r);
  assert_int_equal(r.samples, sr.samples);
  assert_true(!plant || (r.samples >= 1 && r.samples <= (uint64_t)plant));
  assert_memory_equal(h16, copy, n * 6 * sizeof *copy);
  /* Without out: the same report and statistics, nothing written. */
  memset(&r, 0x5a, sizeof r);
  memset(&st, 0x5a, sizeof st);
  assert_int_equal(hf_features_widen(h16, NULL, w, h, spp, &r, &st), HF_OK);
  assert_memory_equal(&r, &c, sizeof r);
  assert_memory_equal(&st, &want_st, sizeof st);
  assert_memory_equal(h16, copy, n * 6 * sizeof *copy);
  /* hf_features_scan: the same for halves; for floats, hf_features_check's
   * report and hf_input_stats_compute's values, the floats unchanged. */
  memset(&r, 0x5a, sizeof r);
  memset(&st, 0x5a, sizeof st);
  assert_int_equal(hf_features_scan(h16, HF_F16, w, h, spp, &r, &st), HF_OK);
  assert_memory_equal(&r, &c, sizeof r);
  assert_memory_equal(&st, &want_st, sizeof st);
  memcpy(want, s, n * 6 * sizeof(float));
  hf_features_check(s, HF_F32, w, h, spp, &c);
  assert_int_equal(hf_input_stats_compute(s, HF_F32, w, h, spp, &want_st), HF_OK);
  memset(&r, 0x5a, sizeof r);
  memset(&st, 0x5a, sizeof st);
  assert_int_equal(hf_features_scan(s, HF_F32, w, h, spp, &r, &st), HF_OK);
  assert_memory_equal(&r, &c, sizeof r);
  assert_memory_equal(&st, &want_st, sizeof st);
  assert_true(!plant || (r.samples >= 1 && r.samples <= (uint64_t)plant));
  memset(&r, 0x5a, sizeof r);
  assert_int_equal(hf_features_scan(s, HF_F32, w, h, spp, &r, NULL), HF_OK);
  assert_memory_equal(&r, &c, sizeof r);
  assert_memory_equal(s, want, n * 6 * sizeof(float));
  free(s), free(got), free(want), free(h16), free(copy);
}

/* hf_features_copy_sanitised: the copy is hf_features_sanitise's result
 * bit for bit, with the same report, in both dtypes; the source is not
 * written. plant: bad values planted in the second half of a clean frame
 * (else make_samples' third of bad samples). */
static void check_copy_sanitised(int w, int h, int spp, int plant) {
  size_t n = (size_t)w * h * spp, vals = n * 6;
  float *s = make_samples(n);
  if (plant) {
    for (size_t i = 0; i < vals; i++) s[i] = i % 6 == 4 ? -0.25f : 0.5f;
    for (int k = 0; k < plant; k++) s[(n / 2 + next() % (n - n / 2)) * 6 + next() % 6] = NAN;
  }
  for (int f16 = 0; f16 < 2; f16++) {
    const size_t es = f16 ? 2 : 4;
    const hf_dtype dt = f16 ? HF_F16 : HF_F32;
    uint8_t *src = malloc(vals * es), *keep = malloc(vals * es), *want = malloc(vals * es),
            *got = malloc(vals * es);
    assert_non_null(src), assert_non_null(keep), assert_non_null(want), assert_non_null(got);
    for (size_t i = 0; i < vals; i++)
      if (f16) ((uint16_t *)src)[i] = hf_f32_to_f16(s[i]);
      else ((float *)src)[i] = s[i];
    memcpy(keep, src, vals * es);
    memcpy(want, src, vals * es);
    hf_input_report wr, r;
    hf_features_sanitise(want, dt, w, h, spp, &wr);
    memset(got, 0x5a, vals * es);
    memset(&r, 0x5a, sizeof r);
    assert_int_equal(hf_features_copy_sanitised(src, got, dt, w, h, spp, &r), HF_OK);
    assert_memory_equal(got, want, vals * es);
    assert_memory_equal(&r, &wr, sizeof r);
    assert_memory_equal(src, keep, vals * es);
    assert_true(!plant || (r.samples >= 1 && r.samples <= (uint64_t)plant));
    free(src), free(keep), free(want), free(got);
  }
  free(s);
}

/* check(w, h, spp, plant) over small shapes, clean and with 3 bad values,
 * then over a frame large enough to be split between threads (and, when
 * widened, written with non-temporal stores) that is not a whole number of
 * chunks, with 0 to 1000 bad values: wherever a thread finds the first bad
 * sample, the report names the frame's first. */
static void over_shapes(void (*check)(int, int, int, int)) {
  static const int shapes[][3] = {{1, 1, 1}, {5, 3, 1}, {7, 5, 4}, {33, 9, 2}, {64, 64, 4}};
  for (size_t i = 0; i < sizeof shapes / sizeof shapes[0]; i++) {
    check(shapes[i][0], shapes[i][1], shapes[i][2], 0);
    check(shapes[i][0], shapes[i][1], shapes[i][2], 3);
  }
  static const int plants[] = {0, 1, 5, 1000};
  for (size_t i = 0; i < sizeof plants / sizeof plants[0]; i++) check(517, 211, 4, plants[i]);
}

static void test_copy_sanitised(void **state) {
  (void)state;
  over_shapes(check_copy_sanitised);
}

static void test_widen(void **state) {
  (void)state;
  over_shapes(check_widen);
}

static void test_report_kinds(void **state) {
  float s[6] = {0.3f, 0.1f, 0.0f, 0.2f, 0.1f, 0.1f};  /* alpha 0, colour not */
  hf_input_report r;
  hf_features_sanitise(s, HF_F32, 1, 1, 1, &r);
  assert_int_equal(r.kind, HF_SANITISED_UNCOVERED);
  assert_int_equal(r.feature, 2);
  assert_true(r.value == 0.0f);
  for (int f = 0; f < 6; f++) assert_true(s[f] == 0.0f);
  float z[6] = {-0.0f, 0.0f, -0.0f, 0.0f, -0.0f, 0.0f};  /* uncovered: left alone */
  hf_features_sanitise(z, HF_F32, 1, 1, 1, &r);
  assert_int_equal(r.samples, 0);
  assert_true(signbit(z[0]));
  float c[6] = {0.5f, 70.0f, 1.5f, 0.5f, 0.0f, 0.0f};
  hf_features_sanitise(c, HF_F32, 1, 1, 1, &r);
  assert_int_equal(r.kind, HF_SANITISED_CLAMPED);
  assert_int_equal(r.feature, 1);
  assert_true(r.value == 70.0f);
  assert_true(c[1] == HF_FEATURE_LIGHT_MAX && c[2] == 1.0f && c[0] == 0.5f);
}

static void test_output_guard(void **state) {
  float o[8 * 3] = {
    1.0f, 0.5f, 0.5f,           /* in range */
    NAN, NAN, NAN,              /* neutral */
    INFINITY, INFINITY, INFINITY,
    -INFINITY, -1.0f, -0.5f,
    1e6f, 1e6f, 2.0f,
    -0.0f, -0.0f, -0.0f,        /* in range: left alone */
    -65504.0f, 65504.0f, 1.0f,  /* bounds */
    0.0f, 0.0f, 1.0000001f,
  };
  static const float want[8 * 3] = {
    1.0f, 0.5f, 0.5f,  1.0f, 0.0f, 0.0f,  65504.0f, 65504.0f, 1.0f,  -65504.0f, 0.0f, 0.0f,
    65504.0f, 65504.0f, 1.0f,  -0.0f, -0.0f, -0.0f,  -65504.0f, 65504.0f, 1.0f, 0.0f, 0.0f, 1.0f,
  };
  uint16_t h[8 * 3];
  for (int i = 0; i < 24; i++) h[i] = hf_f32_to_f16(o[i]);
  assert_int_equal(hf_output_guard(o, HF_F32, 8), 5);
  assert_memory_equal(o, want, sizeof want);
  /* In half, 1e6 and 1.0000001 are already Inf and 1. */
  assert_int_equal(hf_output_guard(h, HF_F16, 8), 4);
  for (int i = 0; i < 24; i++) assert_int_equal(h[i], hf_f32_to_f16(want[i]));
}

/* A frame large enough for the guard to be split between threads (and not
 * a whole number of its chunks), out-of-range pixels planted anywhere:
 * the same values and count as the guard one pixel at a time. */
static void test_output_guard_split(void **state) {
  const size_t px = 700001;
  static const float bad[6] = {NAN, INFINITY, -1.0f, 2.0f, 1e6f, -1e6f};
  float *o = malloc(px * 3 * sizeof *o), *want = malloc(px * 3 * sizeof *want);
  uint16_t *h = malloc(px * 3 * sizeof *h), *hwant = malloc(px * 3 * sizeof *hwant);
  assert_non_null(o), assert_non_null(want), assert_non_null(h), assert_non_null(hwant);
  for (size_t i = 0; i < px * 3; i++) o[i] = (float)(i % 7) / 8.0f;
  for (int k = 0; k < 200; k++) o[next() % (px * 3)] = bad[next() % 6];
  o[0] = NAN, o[px * 3 - 1] = 3.0f;   /* the first and the last pixel */
  for (size_t i = 0; i < px * 3; i++) h[i] = hf_f32_to_f16(o[i]);
  memcpy(want, o, px * 3 * sizeof *o);
  memcpy(hwant, h, px * 3 * sizeof *h);
  uint64_t n32 = 0, n16 = 0;
  for (size_t p = 0; p < px; p++) {
    n32 += hf_output_guard(want + p * 3, HF_F32, 1);
    n16 += hf_output_guard(hwant + p * 3, HF_F16, 1);
  }
  assert_true(n32 >= 2 && n32 <= 202);
  assert_int_equal(hf_output_guard(o, HF_F32, px), n32);
  assert_memory_equal(o, want, px * 3 * sizeof *o);
  assert_int_equal(hf_output_guard(h, HF_F16, px), n16);
  assert_memory_equal(h, hwant, px * 3 * sizeof *h);
  free(o), free(want), free(h), free(hwant);
}

/* ---- through hf_model_run on every CPU backend ---------------------------------- */

typedef struct frame {
  int w, h, spp;
  float *in;  /* [h][w][spp*6] */
} frame;

static frame load_field(const char *name, int spp) {
  char err[512];
  hf_image img;
  assert_int_equal(hf_exr_read(test_field(name), &img, err, sizeof err), HF_OK);
  frame f = {img.width, img.height, spp, malloc(sizeof(float) * img.width * img.height * spp * 6)};
  assert_int_equal(hf_features_from_image(&img, spp, f.in), spp);
  hf_image_free(&img);
  return f;
}

static float *run(hf_model *m, const frame *f, hf_dtype dt, hf_input_report *rep) {
  size_t nin = (size_t)f->w * f->h * f->spp * 6, nout = (size_t)f->w * f->h * 3;
  void *in = f->in;
  uint16_t *in16 = NULL;
  if (dt == HF_F16) {
    in16 = malloc(nin * 2);
    for (size_t i = 0; i < nin; i++) in16[i] = hf_f32_to_f16(f->in[i]);
    in = in16;
  }
  void *copy = malloc(nin * 4);
  memcpy(copy, in, nin * (dt == HF_F16 ? 2 : 4));
  float *out = malloc(nout * sizeof(float));
  hf_io io = {.batch = 1, .width = f->w, .height = f->h, .in = in, .in_dtype = dt,
              .out = out, .out_dtype = HF_F32};
  assert_int_equal(hf_model_run_report(m, &io, NULL, rep), HF_OK);
  assert_memory_equal(copy, in, nin * (dt == HF_F16 ? 2 : 4));  /* never written */
  for (size_t i = 0; i < nout; i++) assert_true(isfinite(out[i]));
  for (size_t p = 0; p < nout / 3; p++)
    assert_true(out[p * 3 + 2] >= 0 && out[p * 3 + 2] <= 1 && out[p * 3 + 1] >= 0);
  free(copy);
  free(in16);
  return out;
}

static void assert_same(const float *a, const float *b, size_t n) {
  for (size_t i = 0; i < n; i++)
    if (!same_bits(a[i], b[i])) {
      fprintf(stderr, "output %zu: %.9g vs %.9g\n", i, a[i], b[i]);
      fail();
    }
}

static double rel_l2(const float *a, const float *b, size_t n) {
  double num = 0, den = 0;
  for (size_t i = 0; i < n; i++) {
    num += ((double)a[i] - b[i]) * ((double)a[i] - b[i]);
    den += (double)b[i] * b[i];
  }
  return sqrt(num / (den > 0 ? den : 1));
}

/* The field case on one model: the Inf sample, the same value as NaN, and
 * its sample made uncovered by hand give the same output, bit for bit;
 * returns that output. */
static float *check_field_case(hf_model *m) {
  frame bad = load_field("features-one-inf-sample.exr", 4);
  size_t nin = (size_t)bad.w * bad.h * 24, nout = (size_t)bad.w * bad.h * 3;
  /* The documented bad sample: pixel (40, 40), sample 1, highlight +Inf. */
  size_t at = ((size_t)40 * bad.w + 40) * 24 + 1 * 6;
  assert_true(isinf(bad.in[at + 1]));
  hf_input_report rep;
  float *got = run(m, &bad, HF_F32, &rep);
  assert_int_equal(rep.samples, 1);
  assert_int_equal(rep.x, 40);
  assert_int_equal(rep.y, 40);
  assert_int_equal(rep.sample, 1);
  assert_int_equal(rep.feature, 1);
  assert_int_equal(rep.kind, HF_SANITISED_NONFINITE);
  assert_true(isinf(rep.value));
  assert_int_equal(rep.outputs, 0);
  frame zeroed = {bad.w, bad.h, 4, malloc(nin * sizeof(float))};
  memcpy(zeroed.in, bad.in, nin * sizeof(float));
  memset(zeroed.in + at, 0, 6 * sizeof(float));
  float *want = run(m, &zeroed, HF_F32, &rep);
  assert_int_equal(rep.samples, 0);
  assert_same(got, want, nout);
  /* NaN in its place, and in another feature: the same. */
  for (int f = 0; f < 6; f++) {
    frame nan = {bad.w, bad.h, 4, malloc(nin * sizeof(float))};
    memcpy(nan.in, zeroed.in, nin * sizeof(float));
    memcpy(nan.in + at, bad.in + at, 6 * sizeof(float));
    nan.in[at + 1] = 0.25f;
    nan.in[at + f] = f % 2 ? NAN : -NAN;
    float *o = run(m, &nan, HF_F32, &rep);
    assert_int_equal(rep.samples, 1);
    assert_int_equal(rep.feature, f);
    assert_same(o, want, nout);
    free(o);
    free(nan.in);
  }
  /* f16 input: the same rule, so the same as the zeroed frame in f16. */
  float *g16 = run(m, &bad, HF_F16, &rep), *w16 = run(m, &zeroed, HF_F16, NULL);
  assert_int_equal(rep.samples, 1);
  assert_same(g16, w16, nout);
  /* A huge finite colour is clamped: the same as 64 put there by hand. */
  frame huge = {bad.w, bad.h, 4, malloc(nin * sizeof(float))};
  memcpy(huge.in, zeroed.in, nin * sizeof(float));
  size_t at2 = ((size_t)10 * bad.w + 20) * 24;  /* pixel (20, 10), sample 0 */
  huge.in[at2 + 0] = 1e30f;
  huge.in[at2 + 2] = 0.5f;
  float *gh = run(m, &huge, HF_F32, &rep);
  assert_int_equal(rep.kind, HF_SANITISED_CLAMPED);
  huge.in[at2 + 0] = HF_FEATURE_LIGHT_MAX;
  float *wh = run(m, &huge, HF_F32, &rep);
  assert_int_equal(rep.samples, 0);
  assert_same(gh, wh, nout);
  free(gh), free(wh), free(huge.in);
  free(g16), free(w16);
  free(want);
  free(zeroed.in);
  free(bad.in);
  return got;
}

/* A batch in which only the middle frame is bad: per-frame reports, and
 * the clean frames' results as if run alone. */
static void check_batch(hf_model *m) {
  frame bad = load_field("features-one-inf-sample.exr", 4);
  frame good = load_field("frame-64x64.exr", 4);
  size_t nin = (size_t)good.w * good.h * 24, nout = (size_t)good.w * good.h * 3;
  float *in = malloc(3 * nin * sizeof(float)), *out = malloc(3 * nout * sizeof(float));
  memcpy(in, good.in, nin * sizeof(float));
  memcpy(in + nin, bad.in, nin * sizeof(float));
  memcpy(in + 2 * nin, good.in, nin * sizeof(float));
  hf_io io = {.batch = 3, .width = good.w, .height = good.h, .in = in, .in_dtype = HF_F32,
              .out = out, .out_dtype = HF_F32};
  hf_input_report rep[3];
  assert_int_equal(hf_model_run_report(m, &io, NULL, rep), HF_OK);
  assert_int_equal(rep[0].samples, 0);
  assert_int_equal(rep[1].samples, 1);
  assert_int_equal(rep[2].samples, 0);
  assert_true(isinf(in[nin + ((size_t)40 * 64 + 40) * 24 + 7]));
  float *alone = run(m, &good, HF_F32, NULL), *alone_bad = run(m, &bad, HF_F32, NULL);
  assert_true(rel_l2(out, alone, nout) < 1e-6);
  assert_true(rel_l2(out + nout, alone_bad, nout) < 1e-6);
  assert_true(rel_l2(out + 2 * nout, alone, nout) < 1e-6);
  free(alone), free(alone_bad), free(in), free(out), free(bad.in), free(good.in);
}

/* hf_model_submit/hf_model_wait: two runs pending, the bad one first; each
 * report is filled at submit and completed at the wait, and the results
 * are those of hf_model_run. */
static void check_submit(hf_model *m) {
  frame bad = load_field("features-one-inf-sample.exr", 4);
  frame good = load_field("frame-64x64.exr", 4);
  size_t nout = (size_t)good.w * good.h * 3;
  float *o1 = malloc(nout * sizeof(float)), *o2 = malloc(nout * sizeof(float));
  hf_io io1 = {.batch = 1, .width = bad.w, .height = bad.h, .in = bad.in, .in_dtype = HF_F32,
               .out = o1, .out_dtype = HF_F32};
  hf_io io2 = io1;
  io2.in = good.in;
  io2.out = o2;
  hf_input_report r1, r2;
  assert_int_equal(hf_model_submit_report(m, &io1, &r1), HF_OK);
  assert_int_equal(r1.samples, 1);
  assert_int_equal(hf_model_submit_report(m, &io2, &r2), HF_OK);
  assert_int_equal(r2.samples, 0);
  hf_timing t;
  assert_int_equal(hf_model_wait(m, &t), HF_OK);
  assert_int_equal(hf_model_wait(m, &t), HF_OK);
  assert_int_equal(r1.outputs, 0);
  assert_true(isinf(bad.in[((size_t)40 * 64 + 40) * 24 + 7]));  /* never written */
  float *w1 = run(m, &bad, HF_F32, NULL), *w2 = run(m, &good, HF_F32, NULL);
  assert_same(o1, w1, nout);
  assert_same(o2, w2, nout);
  free(w1), free(w2), free(o1), free(o2), free(bad.in), free(good.in);
}

/* Weights that overflow: every output would be NaN or Inf, and the guard
 * keeps each in its range. */
static void check_guard(hf_backend *b, const hf_net_config *c) {
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(c, 7, &w), HF_OK);
  w->dec_b[0][HF_OUT_COLOR] = 1e30f;
  w->dec_b[0][HF_OUT_HIGHLIGHT] = NAN;
  w->dec_b[0][HF_OUT_ALPHA] = -INFINITY;
  hf_model *m;
  assert_int_equal(hf_model_create(b, w, &m), HF_OK);
  frame f = load_field("frame-64x64.exr", c->spp);
  hf_input_report rep;
  float *o = run(m, &f, HF_F32, &rep);
  assert_int_equal(rep.outputs, (uint64_t)f.w * f.h);
  for (int p = 0; p < f.w * f.h; p++) {
    assert_true(o[p * 3] == HF_OUTPUT_MAX);
    assert_true(o[p * 3 + 1] == 0.0f);
    assert_true(o[p * 3 + 2] == 0.0f);
  }
  free(o);
  free(f.in);
  hf_model_destroy(m);
  hf_weights_free(w);
}

/* ---- the estimate (hf_features_interleave) ------------------------------------ */

/* The estimate's rule written out: 1 when it changed e. */
static int reference_estimate(float *e) {
  int finite = isfinite(e[0]) && isfinite(e[1]) && isfinite(e[2]);
  if (e[0] == 0 && e[1] == 0 && e[2] == 0) return 0;
  if (finite && e[2] > 0 && e[2] <= 1 && e[0] >= 0 && e[0] <= 64 && e[1] >= 0 && e[1] <= 64)
    return 0;
  if (!finite || e[2] <= 0) {
    e[0] = e[1] = e[2] = 0;
    return 1;
  }
  for (int f = 0; f < 2; f++) e[f] = e[f] < 0 ? 0 : e[f] > 64 ? 64 : e[f];
  if (e[2] > 1) e[2] = 1;
  return 1;
}

/* A planar frame (samples, then estimate) interleaved, in float32 and
 * binary16: every pixel is its sanitised samples followed by its estimate
 * under the estimate's rule; the report counts both, the first change in
 * memory order (the samples' block comes first); the statistics are those
 * of the samples. */
static void check_interleave(int w, int h, int spp, int bad_samples) {
  const size_t px = (size_t)w * h, ns = (size_t)spp * 6, cin = ns + 3;
  float *planar = malloc(px * cin * sizeof(float));
  float *samples = bad_samples ? make_samples(px * spp) : NULL;
  for (size_t i = 0; i < px * ns; i++)
    planar[i] = samples ? samples[i] : (i % 6 == 2 ? 0.5f : 0.25f);
  float *est = planar + px * ns;
  for (size_t p = 0; p < px; p++)
    for (int f = 0; f < 3; f++)
      est[p * 3 + f] = p % 3 ? (float)((next() >> 8) + 1) / 16777217.0f : special(f);
  float *want = malloc(px * cin * sizeof(float));
  uint64_t changed = 0;
  long first_est = -1;
  for (size_t p = 0; p < px; p++) {
    memcpy(want + p * cin, planar + p * ns, ns * sizeof(float));
    for (int k = 0; k < spp; k++) changed += (uint64_t)reference_rule(want + p * cin + k * 6);
    memcpy(want + p * cin + ns, est + p * 3, 3 * sizeof(float));
    if (reference_estimate(want + p * cin + ns)) {
      changed++;
      if (first_est < 0) first_est = (long)p;
    }
  }
  float *out = malloc(px * cin * sizeof(float));
  hf_input_report r;
  hf_input_stats st, st_want;
  assert_int_equal(hf_features_interleave(planar, HF_F32, w, h, spp, out, &r, &st), HF_OK);
  assert_int_equal(r.samples, changed);
  for (size_t i = 0; i < px * cin; i++)
    if (!same_bits(out[i], want[i]) && !(out[i] == 0 && want[i] == 0)) {
      fprintf(stderr, "interleaved value %zu: %g, want %g\n", i, out[i], want[i]);
      fail();
    }
  hf_input_report rs;
  hf_features_check(planar, HF_F32, w, h, spp, &rs);
  if (!rs.samples && first_est >= 0) {
    assert_int_equal(r.sample, HF_REPORT_ESTIMATE);
    assert_int_equal((long)r.y * w + r.x, first_est);
    assert_true(r.feature >= 0 && r.feature < 3);
  } else if (rs.samples) {
    assert_int_equal(r.sample, rs.sample);
    assert_int_equal(r.x, rs.x);
    assert_int_equal(r.y, rs.y);
    assert_int_equal(r.feature, rs.feature);
  }
  assert_int_equal(hf_input_stats_compute(planar, HF_F32, w, h, spp, &st_want), HF_OK);
  assert_memory_equal(&st, &st_want, sizeof st);
  /* Binary16: the halves of the same frame give the halves of the result. */
  uint16_t *p16 = malloc(px * cin * 2), *o16 = malloc(px * cin * 2);
  for (size_t i = 0; i < px * cin; i++) p16[i] = hf_f32_to_f16(planar[i]);
  float *w16 = malloc(px * cin * sizeof(float));
  for (size_t p = 0; p < px; p++) {
    for (size_t i = 0; i < ns; i++) w16[p * cin + i] = hf_f16_to_f32(p16[p * ns + i]);
    for (int f = 0; f < 3; f++) w16[p * cin + ns + f] = hf_f16_to_f32(p16[px * ns + p * 3 + f]);
    for (int k = 0; k < spp; k++) reference_rule(w16 + p * cin + k * 6);
    reference_estimate(w16 + p * cin + ns);
  }
  assert_int_equal(hf_features_interleave(p16, HF_F16, w, h, spp, o16, &r, &st), HF_OK);
  assert_int_equal(hf_input_stats_compute(p16, HF_F16, w, h, spp, &st_want), HF_OK);
  assert_memory_equal(&st, &st_want, sizeof st);
  for (size_t i = 0; i < px * cin; i++) {
    uint16_t expect = hf_f32_to_f16(w16[i]);
    if (o16[i] != expect && !((o16[i] | expect) == 0x8000u)) {
      fprintf(stderr, "interleaved half %zu: %04x, want %04x\n", i, o16[i], expect);
      fail();
    }
  }
  free(planar), free(samples), free(want), free(out), free(p16), free(o16), free(w16);
}

static void test_interleave_estimate(void **state) {
  check_interleave(7, 5, 4, 0);
  check_interleave(7, 5, 4, 1);
  check_interleave(13, 3, 1, 1);
  check_interleave(64, 33, 2, 1);
  check_interleave(97, 61, 16, 1);   /* pixels of 384 bytes, many statistics' groups a chunk */
  /* One bad sample far into its chunk, not its pixel's first: the report
   * places it in the frame, not in the pixel checked alone. */
  {
    const int w = 97, h = 61, spp = 16;
    const size_t px = (size_t)w * h, ns = (size_t)spp * 6;
    float *planar = calloc(px * (ns + 3), sizeof(float)), *out = malloc(px * (ns + 3) * 4);
    assert_non_null(planar);
    assert_non_null(out);
    for (size_t i = 0; i < px * ns; i += 6) planar[i + 2] = 0.5f;   /* alpha */
    const size_t bad = (size_t)40 * w + 50;
    planar[bad * ns + 5 * 6 + 1] = INFINITY;   /* sample 5's highlight */
    hf_input_report r;
    assert_int_equal(hf_features_interleave(planar, HF_F32, w, h, spp, out, &r, NULL), HF_OK);
    assert_int_equal(r.samples, 1);
    assert_int_equal(r.x, 50);
    assert_int_equal(r.y, 40);
    assert_int_equal(r.sample, 5);
    assert_int_equal(r.feature, 1);
    assert_true(out[bad * (ns + 3) + 5 * 6 + 1] == 0.0f);   /* uncovered: all zero */
    free(planar), free(out);
  }
  /* Named values: a NaN alpha, alpha 0 beside a colour, clamps. */
  float planar[4 * 6 + 4 * 3] = {0}, out[4 * 9];
  float *est = planar + 4 * 6;
  const float in_est[4][3] = {{0.5f, 0.25f, NAN}, {0.5f, 0.0f, 0.0f}, {70.0f, -1.0f, 1.5f},
                              {1.0f, 0.5f, 0.75f}};
  memcpy(est, in_est, sizeof in_est);
  hf_input_report r;
  assert_int_equal(hf_features_interleave(planar, HF_F32, 2, 2, 1, out, &r, NULL), HF_OK);
  assert_int_equal(r.samples, 3);
  assert_int_equal(r.sample, HF_REPORT_ESTIMATE);
  assert_int_equal(r.x, 0);
  assert_int_equal(r.kind, HF_SANITISED_NONFINITE);
  assert_int_equal(r.feature, 2);
  const float want[4][3] = {{0, 0, 0}, {0, 0, 0}, {64.0f, 0.0f, 1.0f}, {1.0f, 0.5f, 0.75f}};
  for (int p = 0; p < 4; p++)
    for (int c = 0; c < 3; c++) assert_true(out[p * 9 + 6 + c] == want[p][c]);
}

static void test_backends(void **state) {
  hf_net_config base, residual;
  assert_int_equal(hf_variant_preset("Base", &base), HF_OK);
  assert_int_equal(hf_variant_preset("Residual", &residual), HF_OK);
  float *first[2] = {NULL, NULL};
  int nb = 0;
  for (const char *const *name = hf_backend_list(); *name; name++) {
    if (!strcmp(*name, "cudnn")) continue;  /* tests/gpu */
    hf_backend *b;
    char why[256];
    assert_int_equal(hf_backend_create(*name, &b, why, sizeof why), HF_OK);
    const hf_net_config *cfgs[2] = {&base, &residual};
    for (int k = 0; k < 2; k++) {
      hf_weights *w;
      assert_int_equal(hf_weights_init_random(cfgs[k], 11 + k, &w), HF_OK);
      hf_model *m;
      assert_int_equal(hf_model_create(b, w, &m), HF_OK);
      float *o = check_field_case(m);
      if (k == 0) check_batch(m), check_submit(m);
      /* Every backend gives the cpu-ref answer (tests/cpu's tolerance). */
      if (!first[k]) first[k] = o;
      else {
        assert_true(rel_l2(o, first[k], 64 * 64 * 3) < 1e-4);
        free(o);
      }
      hf_model_destroy(m);
      hf_weights_free(w);
    }
    check_guard(b, &base);
    hf_backend_destroy(b);
    nb++;
  }
  assert_true(nb >= 1);
  free(first[0]);
  free(first[1]);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_rule),         cmocka_unit_test(test_rule_each_position),
    cmocka_unit_test(test_widen),        cmocka_unit_test(test_report_kinds),
    cmocka_unit_test(test_copy_sanitised),
    cmocka_unit_test(test_output_guard), cmocka_unit_test(test_output_guard_split),
    cmocka_unit_test(test_backends),     cmocka_unit_test(test_interleave_estimate),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
