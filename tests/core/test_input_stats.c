/* Input statistics (src/input_stats.c) on constructed frames whose values
 * are known exactly, the trained-range metadata (src/input_range.c) and its
 * way through the weights loader and writer. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <cmocka.h>

#include "hfcore.h"

#define F HF_FEATURES_PER_SAMPLE

/* Sets sample k of pixel p to a covered fragment of alpha a (0: uncovered,
 * all features 0 as FEATURES.md says). */
static void set_alpha(float *in, int spp, int p, int k, float a) {
  float *s = in + ((size_t)p * spp + k) * F;
  if (a == 0.0f) {
    memset(s, 0, F * sizeof(float));
    return;
  }
  s[0] = 0.7f, s[1] = 0.1f, s[2] = a, s[3] = 0.5f, s[4] = 0.6f, s[5] = -0.8f;
}

/* A 4x2 frame at 4 spp:
 *   p0 -         p1 .25 - - -       p2 .5 .5 .5 .5     p3 .125 .375 - -
 *   p4 1 1 1 1   p5 .75 .25 .5 -    p6 -               p7 .0625 - - -
 * Hair pixels: 6 of 8; all samples covered: p2, p4; strand alphas (mean of
 * the covered samples) sorted: .0625 .25 .25 .5 .5 1, so the median (3rd
 * of 6) is .25 and the 90th percentile (ceil(5.4) = 6th) is 1. */
static const float FRAME[8][4] = {
  {0, 0, 0, 0},          {0.25f, 0, 0, 0},        {0.5f, 0.5f, 0.5f, 0.5f}, {0.125f, 0.375f, 0, 0},
  {1, 1, 1, 1},          {0.75f, 0.25f, 0.5f, 0}, {0, 0, 0, 0},             {0.0625f, 0, 0, 0}};

static float *known_frame(void) {
  float *in = calloc(8 * 4 * F, sizeof(float));
  for (int p = 0; p < 8; p++)
    for (int k = 0; k < 4; k++) set_alpha(in, 4, p, k, FRAME[p][k]);
  return in;
}

static void check_known(const hf_input_stats *s) {
  assert_int_equal(s->width, 4);
  assert_int_equal(s->height, 2);
  assert_int_equal(s->spp, 4);
  assert_int_equal(s->hair_pixels, 6);
  assert_int_equal(s->full_pixels, 2);
  assert_true(s->value[HF_STAT_STRAND_ALPHA_P50] == 0.25);
  assert_true(s->value[HF_STAT_STRAND_ALPHA_P90] == 1.0);
  assert_true(s->value[HF_STAT_FULL_COVERAGE] == 2.0 / 6.0);
  assert_true(s->value[HF_STAT_HAIR_FRACTION] == 0.75);
  assert_true(s->value[HF_STAT_LONG_SIDE] == 4.0);
}

static void test_pixel_helpers(void **state) {
  float *in = known_frame();
  static const int covered[8] = {0, 1, 4, 2, 4, 3, 0, 1};
  static const float width[8] = {0, 0.25f, 0.5f, 0.25f, 1, 0.5f, 0, 0.0625f};
  for (int p = 0; p < 8; p++) {
    assert_int_equal(hf_pixel_covered(in + p * 4 * F, 4), covered[p]);
    assert_true(hf_pixel_strand_alpha(in + p * 4 * F, 4) == width[p]);
  }
  /* Fewer samples read: p5's first two are .75 and .25. */
  assert_int_equal(hf_pixel_covered(in + 5 * 4 * F, 2), 2);
  assert_true(hf_pixel_strand_alpha(in + 5 * 4 * F, 2) == 0.5f);
  free(in);
}

static void test_known_frame(void **state) {
  float *in = known_frame();
  hf_input_stats s;
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 4, 2, 4, &s), HF_OK);
  check_known(&s);
  /* The same frame in half floats (every value here is exact in f16). */
  uint16_t *h = malloc(8 * 4 * F * sizeof(uint16_t));
  for (int i = 0; i < 8 * 4 * F; i++) h[i] = hf_f32_to_f16(in[i]);
  memset(&s, 0xff, sizeof s);
  assert_int_equal(hf_input_stats_compute(h, HF_F16, 4, 2, 4, &s), HF_OK);
  check_known(&s);
  /* As a 1x8 frame the long side is 8; nothing else changes. */
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 1, 8, 4, &s), HF_OK);
  assert_true(s.value[HF_STAT_LONG_SIDE] == 8.0);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 0.25);
  free(h);
  free(in);
}

/* Reading only the first sample of each pixel: hair p1 p2 p3 p4 p5 p7, all
 * fully covered (1 of 1); widths .25 .5 .125 1 .75 .0625 -> sorted .0625
 * .125 .25 .5 .75 1: median .25, p90 1. */
static void test_spp_one(void **state) {
  float *in1 = calloc(8 * F, sizeof(float));
  for (int p = 0; p < 8; p++) set_alpha(in1, 1, p, 0, FRAME[p][0]);
  hf_input_stats s;
  assert_int_equal(hf_input_stats_compute(in1, HF_F32, 4, 2, 1, &s), HF_OK);
  assert_int_equal(s.hair_pixels, 6);
  assert_true(s.value[HF_STAT_FULL_COVERAGE] == 1.0);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 0.25);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P90] == 1.0);
  free(in1);
}

/* 256 hair pixels with widths k/256 (k = 1..256, 8 significant bits at
 * most: exact in the histogram) and 256 empty ones: median k = 128, p90
 * k = ceil(230.4) = 231. */
static void test_percentiles_nearest_rank(void **state) {
  enum { N = 512 };
  float *in = calloc((size_t)N * F, sizeof(float));
  for (int p = 0; p < 256; p++) set_alpha(in, 1, 2 * p, 0, (float)(p + 1) / 256.0f);
  hf_input_stats s;
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 32, 16, 1, &s), HF_OK);
  assert_int_equal(s.hair_pixels, 256);
  assert_true(s.value[HF_STAT_HAIR_FRACTION] == 0.5);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 128.0 / 256.0);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P90] == 231.0 / 256.0);
  free(in);
}

/* A value with more than 8 significant bits reports its bin's lower edge:
 * 0.3 -> 0.298828125 (1.0011001b x 2^-2), within 0.8% below. Values below
 * 2^-16 report 0, values from 1 up (and +inf) report 1. */
static void test_bin_edges(void **state) {
  float px[F] = {0};
  hf_input_stats s;
  px[2] = 0.3f;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 0.298828125);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] <= 0.3 &&
              s.value[HF_STAT_STRAND_ALPHA_P50] > 0.3 * (1 - 1.0 / 128));
  px[2] = 1e-6f;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 0.0);
  px[2] = 0x1p-16f;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 0x1p-16);
  px[2] = 3.0f;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P90] == 1.0);
  px[2] = INFINITY;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == 1.0);
  /* NaN and negative alpha are not coverage (hf_st_estimate agrees). */
  px[2] = NAN;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_int_equal(s.hair_pixels, 0);
  px[2] = -0.5f;
  assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
  assert_int_equal(s.hair_pixels, 0);
}

/* The half-float path reads alpha straight from binary16: for every one of
 * the 65536 halves, a pixel of it (one sample, or two with a fixed 0.5
 * beside it) gives the same statistics as the frame widened to float
 * first: coverage of zeros, negatives, NaNs and infinity, subnormals. */
static void test_f16_matches_widened(void **state) {
  for (int spp = 1; spp <= 2; spp++)
    for (uint32_t h = 0; h < 65536; h++) {
      uint16_t px16[2 * F] = {0};
      float px32[2 * F] = {0};
      px16[2] = (uint16_t)h;
      px16[F + 2] = hf_f32_to_f16(0.5f);
      for (int i = 0; i < 2 * F; i++) px32[i] = hf_f16_to_f32(px16[i]);
      hf_input_stats a, b;
      assert_int_equal(hf_input_stats_compute(px16, HF_F16, 1, 1, spp, &a), HF_OK);
      assert_int_equal(hf_input_stats_compute(px32, HF_F32, 1, 1, spp, &b), HF_OK);
      if (a.hair_pixels != b.hair_pixels || a.full_pixels != b.full_pixels ||
          memcmp(a.value, b.value, sizeof a.value))
        fail_msg("half 0x%04x at %d spp: f16 and f32 paths differ", h, spp);
    }
}

static void test_no_hair_and_bad_args(void **state) {
  float *in = calloc(6 * 4 * F, sizeof(float));
  hf_input_stats s;
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 3, 2, 4, &s), HF_OK);
  assert_int_equal(s.hair_pixels, 0);
  assert_true(s.value[HF_STAT_HAIR_FRACTION] == 0.0);
  assert_true(isnan(s.value[HF_STAT_STRAND_ALPHA_P50]));
  assert_true(isnan(s.value[HF_STAT_STRAND_ALPHA_P90]));
  assert_true(isnan(s.value[HF_STAT_FULL_COVERAGE]));
  assert_true(s.value[HF_STAT_LONG_SIDE] == 3.0);
  assert_int_equal(hf_input_stats_compute(NULL, HF_F32, 3, 2, 4, &s), HF_EINVAL);
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 0, 2, 4, &s), HF_EINVAL);
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 3, 2, 17, &s), HF_EINVAL);
  assert_int_equal(hf_input_stats_compute(in, (hf_dtype)7, 3, 2, 4, &s), HF_EINVAL);
  assert_int_equal(s.hair_pixels, 0);
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 3, 2, 4, NULL), HF_EINVAL);
  free(in);
}

static void test_names(void **state) {
  for (int k = 0; k < HF_STAT_COUNT; k++)
    assert_int_equal(hf_input_stat_from_name(hf_input_stat_name(k)), k);
  assert_string_equal(hf_input_stat_name(HF_STAT_STRAND_ALPHA_P50), "strand_alpha_p50");
  assert_string_equal(hf_input_stat_name(HF_STAT_LONG_SIDE), "long_side");
  assert_string_equal(hf_input_stat_name(HF_STAT_COUNT), "unknown");
  assert_int_equal(hf_input_stat_from_name("strand_width"), HF_ENOTFOUND);
}

/* ---- trained range ------------------------------------------------------- */

static const char *NARROW =
  "{\"definition\": 1, \"spp\": 4, \"frames\": 12, \"strand_alpha_p50\": [0.015, 0.02],"
  " \"full_coverage\": [0, 0.05], \"long_side\": [256, 256], \"future_stat\": [1, 2]}";

static void test_range_parse_and_check(void **state) {
  hf_input_range r;
  char err[200];
  assert_int_equal(hf_input_range_parse(NARROW, 4, &r, err, sizeof err), HF_OK);
  assert_true(r.present);
  assert_int_equal(r.frames, 12);
  assert_int_equal(r.spp, 4);
  assert_int_equal(r.has, (1u << HF_STAT_STRAND_ALPHA_P50) | (1u << HF_STAT_FULL_COVERAGE) |
                              (1u << HF_STAT_LONG_SIDE));
  assert_true(r.lo[HF_STAT_STRAND_ALPHA_P50] == 0.015 && r.hi[HF_STAT_STRAND_ALPHA_P50] == 0.02);

  /* The known frame: median .25 > .02, full coverage 1/3 > .05, long side
   * 4 < 256; p90 and hair fraction have no range. */
  float *in = known_frame();
  hf_input_stats s;
  assert_int_equal(hf_input_stats_compute(in, HF_F32, 4, 2, 4, &s), HF_OK);
  unsigned m = hf_input_range_check(&r, &s);
  assert_int_equal(m, (1u << HF_STAT_STRAND_ALPHA_P50) | (1u << HF_STAT_FULL_COVERAGE) |
                          (1u << HF_STAT_LONG_SIDE));
  char msg[256];
  assert_int_equal(hf_input_range_describe(&r, &s, m, msg, sizeof msg), HF_OK);
  assert_string_equal(msg, "strand_alpha_p50 0.25 (trained 0.015..0.02), full_coverage 0.3333 "
                           "(trained 0..0.05), long_side 4 (trained 256..256)");
  /* Cut output is still a terminated string. */
  assert_int_equal(hf_input_range_describe(&r, &s, m, msg, 20), HF_ERANGE);
  assert_true(strlen(msg) < 20);

  /* Inside the range (bounds included): no bit. */
  r.lo[HF_STAT_STRAND_ALPHA_P50] = 0.25, r.hi[HF_STAT_STRAND_ALPHA_P50] = 0.25;
  r.hi[HF_STAT_FULL_COVERAGE] = 1;
  r.lo[HF_STAT_LONG_SIDE] = 4;
  assert_int_equal(hf_input_range_check(&r, &s), 0);
  /* A frame with no hair is never out of range; nor is anything without
   * a range present. */
  float *empty = calloc(8 * 4 * F, sizeof(float));
  hf_input_stats e;
  assert_int_equal(hf_input_stats_compute(empty, HF_F32, 4, 2, 4, &e), HF_OK);
  r.lo[HF_STAT_LONG_SIDE] = 256;
  assert_int_equal(hf_input_range_check(&r, &e), 0);
  hf_input_range none;
  memset(&none, 0, sizeof none);
  assert_int_equal(hf_input_range_check(&none, &s), 0);
  free(empty);
  free(in);
}

static void test_range_rejects(void **state) {
  static const struct { const char *json, *msg; } bad[] = {
    {"[1, 2]", "not a JSON object"},
    {"{\"spp\": 4, \"frames\": 1, \"hair_fraction\": [0, 1]}", "'definition'"},
    {"{\"definition\": 1, \"spp\": 2, \"frames\": 1, \"hair_fraction\": [0, 1]}", "'spp'"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 0, \"hair_fraction\": [0, 1]}", "'frames'"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 1.5, \"hair_fraction\": [0, 1]}", "'frames'"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 3, \"hair_fraction\": [1, 0]}", "'hair_fraction'"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 3, \"hair_fraction\": [0]}", "'hair_fraction'"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 3, \"long_side\": \"256\"}", "'long_side'"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 3}", "no statistic"},
    {"{\"definition\": 1, \"spp\": 4, \"frames\": 3, \"hair_fraction\": [0, 1]", "not a JSON"},
  };
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    hf_input_range r;
    char err[200] = "";
    assert_int_equal(hf_input_range_parse(bad[i].json, 4, &r, err, sizeof err), HF_EFORMAT);
    if (!strstr(err, bad[i].msg)) fail_msg("%s: '%s' lacks '%s'", bad[i].json, err, bad[i].msg);
    assert_false(r.present);
  }
  /* Another definition version: not an error, just not used. */
  hf_input_range r;
  assert_int_equal(hf_input_range_parse("{\"definition\": 2, \"whatever\": 1}", 4, &r, NULL, 0),
                   HF_OK);
  assert_false(r.present);
}

/* Through the weights writer and loader: kept exactly; a malformed entry
 * stops the load with a reason; files without one load with none. */
static void test_range_in_weights(void **state) {
  char dir[] = "/tmp/hf_test_range_XXXXXX", path[128], err[256];
  assert_non_null(mkdtemp(dir));
  snprintf(path, sizeof path, "%s/small.safetensors", dir);
  hf_net_config cfg;
  hf_weights *w = NULL, *back = NULL;
  assert_int_equal(hf_variant_preset("Small", &cfg), HF_OK);
  assert_int_equal(hf_weights_init_random(&cfg, 3, &w), HF_OK);
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  assert_int_equal(hf_weights_load(path, &back, err, sizeof err), HF_OK);
  assert_false(back->input_range.present);
  hf_weights_free(back);

  assert_int_equal(hf_input_range_parse(NARROW, 4, &w->input_range, err, sizeof err), HF_OK);
  w->input_range.lo[HF_STAT_STRAND_ALPHA_P50] = 0.1 + 0.2;   /* needs 17 digits */
  w->input_range.hi[HF_STAT_STRAND_ALPHA_P50] = 1.0 / 3.0;
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  assert_int_equal(hf_weights_load(path, &back, err, sizeof err), HF_OK);
  assert_true(back->input_range.present);
  assert_memory_equal(&back->input_range, &w->input_range, sizeof w->input_range);
  hf_weights_free(back);

  /* A malformed range in the file: spp of another variant. */
  w->input_range.spp = 2;
  assert_int_equal(hf_weights_save(path, w), HF_OK);
  assert_int_equal(hf_weights_load(path, &back, err, sizeof err), HF_EFORMAT);
  assert_null(back);
  assert_non_null(strstr(err, "input_range: 'spp' must be the variant's 4"));
  hf_weights_free(w);
  unlink(path);
  rmdir(dir);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_pixel_helpers),
    cmocka_unit_test(test_known_frame),
    cmocka_unit_test(test_spp_one),
    cmocka_unit_test(test_percentiles_nearest_rank),
    cmocka_unit_test(test_bin_edges),
    cmocka_unit_test(test_f16_matches_widened),
    cmocka_unit_test(test_no_hair_and_bad_args),
    cmocka_unit_test(test_names),
    cmocka_unit_test(test_range_parse_and_check),
    cmocka_unit_test(test_range_rejects),
    cmocka_unit_test(test_range_in_weights),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
