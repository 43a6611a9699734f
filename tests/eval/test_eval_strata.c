/* Regime tables of `hairfilter eval` (client/cli/eval_strata.c): bucket
 * edges, and the sums behind every bucket against direct computations on a
 * frame whose bucket membership is known. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "eval_metrics.h"
#include "eval_strata.h"

/* The strand-width edges sit on the input statistics' bins: a frame whose
 * every covered sample has the edge's alpha reports exactly the edge as
 * its median, and lands in the bucket above it; the next float below does
 * not. */
static void width_edges_are_bin_edges(void **state) {
  static const double edges[] = {245.0 / 8192, 51.0 / 512, 153.0 / 512, 179.0 / 256};
  for (int e = 0; e < 4; e++) {
    float px[HF_FEATURES_PER_SAMPLE] = {0};
    px[2] = (float)edges[e];
    hf_input_stats s;
    assert_int_equal(hf_input_stats_compute(px, HF_F32, 1, 1, 1, &s), HF_OK);
    assert_true(s.value[HF_STAT_STRAND_ALPHA_P50] == edges[e]);
    assert_int_equal(eval_bucket(EVAL_T_WIDTH_FR, edges[e]), e + 2);
    assert_int_equal(eval_bucket(EVAL_T_WIDTH_PX, nextafter(edges[e], 0)), e + 1);
  }
  assert_int_equal(eval_bucket(EVAL_T_WIDTH_PX, 0.0), 0);      /* none */
  assert_int_equal(eval_bucket(EVAL_T_WIDTH_FR, NAN), 0);
  assert_int_equal(eval_bucket(EVAL_T_WIDTH_PX, 1e-4), 1);
  assert_int_equal(eval_bucket(EVAL_T_WIDTH_PX, 1.0), 5);
  assert_string_equal(eval_bucket_name(EVAL_T_WIDTH_PX, 3), "0.1-0.3");
  assert_int_equal(eval_bucket(EVAL_T_COVER_PX, 0.29), 0);
  assert_int_equal(eval_bucket(EVAL_T_COVER_PX, 0.3), 1);
  assert_int_equal(eval_bucket(EVAL_T_COVER_PX, 0.9), 2);
  assert_int_equal(eval_bucket(EVAL_T_COVER_PX, 1.0), 2);
  assert_int_equal(eval_bucket(EVAL_T_RES_FR, 256), 0);
  assert_int_equal(eval_bucket(EVAL_T_RES_FR, 383), 0);
  assert_int_equal(eval_bucket(EVAL_T_RES_FR, 512), 1);
  assert_int_equal(eval_bucket(EVAL_T_RES_FR, 768), 2);
  assert_int_equal(eval_bucket(EVAL_T_RES_FR, 4096), 2);
  for (int t = 0; t < EVAL_TABLES; t++) assert_true(eval_bucket_count(t) <= EVAL_MAX_BUCKETS);
}

#define W 6
#define H 2
#define SPP 2
#define NPX (W * H)

/* Row 0: widths 0.02, 0.05, 0.2 (1 or 2 covered samples), 0.5, 0.9 and a hair
 * pixel without samples; row 1: no hair except x = 0 (width 0.2), whose gt
 * alpha 1 is dense. gt alpha in row 0: 0.2 0.2 0.6 0.6 1 0.5. */
static const float WIDTH[NPX] = {0.02f, 0.05f, 0.2f, 0.5f, 0.9f, 0, 0.2f, 0, 0, 0, 0, 0};
static const float GT_A[NPX] = {0.2f, 0.2f, 0.6f, 0.6f, 1, 0.5f, 1, 0, 0, 0, 0, 0};

static double get(const cJSON *o, const char *key) {
  const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
  return cJSON_IsNumber(v) ? v->valuedouble : NAN;
}

static const cJSON *bucket(const cJSON *m, const char *table, int b) {
  return cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(m, table), b);
}

/* Every bucket's numbers equal a direct computation over its pixels. */
static void sums_match_direct(void **state) {
  float in[NPX * SPP * HF_FEATURES_PER_SAMPLE] = {0}, gt[NPX * 3], res[NPX * 3];
  float rgb[NPX * 3], gt_rgb[NPX * 3];
  double map[NPX];
  uint8_t mask[NPX];
  for (int p = 0; p < NPX; p++) {
    if (WIDTH[p] > 0) {
      in[p * SPP * 6 + 2] = WIDTH[p];
      if (p % 2) in[p * SPP * 6 + 6 + 2] = WIDTH[p];   /* second sample too */
    }
    gt[3 * p] = 0.8f, gt[3 * p + 1] = 0.1f, gt[3 * p + 2] = GT_A[p];
    res[3 * p] = 0.7f, res[3 * p + 1] = 0.05f * p, res[3 * p + 2] = GT_A[p] * 0.5f;
    for (int c = 0; c < 3; c++) {
      gt_rgb[3 * p + c] = 0.1f * c + 0.01f * p;
      rgb[3 * p + c] = gt_rgb[3 * p + c] + 0.003f * (p + 1) * (c + 1);
    }
    map[p] = 0.1 + 0.07 * p;
    mask[p] = GT_A[p] > 0;
  }
  eval_regime r;
  assert_int_equal(eval_regime_compute(&r, in, SPP, gt, mask, W, H, 0, 0), 0);
  assert_int_equal(r.hair_pixels, 7);
  assert_int_equal(r.full_width, W);
  /* gt alphas of the hair pixels sorted: .2 .2 .5 .6 .6 1 1: median .6. */
  assert_true(r.gt_alpha_p50 == (double)0.6f);
  assert_int_equal(r.frame[EVAL_T_COVER_FR], 1);
  assert_int_equal(r.frame[EVAL_T_RES_FR], 0);
  /* Input hair pixels' widths .02 .05 .2 .2 .5 .9: median (3rd) in 0.1-0.3. */
  assert_int_equal(r.frame[EVAL_T_WIDTH_FR], 3);
  static const uint64_t want_w[6] = {1, 1, 1, 2, 1, 1}, want_c[3] = {2, 3, 2};
  for (int b = 0; b < 6; b++) assert_int_equal(r.bucket_pixels[EVAL_T_WIDTH_PX][b], want_w[b]);
  for (int b = 0; b < 3; b++) assert_int_equal(r.bucket_pixels[EVAL_T_COVER_PX][b], want_c[b]);

  eval_strata *s;
  assert_int_equal(eval_strata_create(1, &s), 0);
  eval_frame_score fs = {.mse = 0.5, .psnr = 3.0, .ssim = 0.25, .col = 1, .hl = 2, .alpha = 3};
  eval_strata_add(s, 0, &r, rgb, gt_rgb, res, gt, map, &fs);
  eval_strata_frame_done(s, &r);
  cJSON *m = eval_strata_method_json(s, 0);
  assert_non_null(m);
  for (int t = 0; t < EVAL_PIXEL_TABLES; t++)
    for (int b = 0; b < eval_bucket_count(t); b++) {
      double se = 0, ssim = 0, col = 0, hl = 0, al = 0;
      int n = 0;
      for (int p = 0; p < NPX; p++) {
        if (!mask[p] || r.pixel[t][p] != b) continue;
        for (int c = 0; c < 3; c++) se += pow((double)rgb[3 * p + c] - gt_rgb[3 * p + c], 2);
        ssim += map[p];
        col += pow(res[3 * p] * (double)res[3 * p + 2] - gt[3 * p] * (double)gt[3 * p + 2], 2);
        hl += pow(res[3 * p + 1] * (double)res[3 * p + 2] - gt[3 * p + 1] * (double)gt[3 * p + 2], 2);
        al += pow((double)res[3 * p + 2] - gt[3 * p + 2], 2);
        n++;
      }
      const cJSON *o = bucket(m, eval_table_key(t), b);
      assert_int_equal((int)get(o, "pixels"), n);
      if (!n) {
        assert_true(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(o, "psnr")));
        continue;
      }
      assert_int_equal((int)get(o, "frames"), 1);
      assert_true(fabs(get(o, "mse") - se / (3 * n)) < 1e-15);
      assert_true(fabs(get(o, "psnr") - 10 * log10(3 * n / se)) < 1e-9);
      assert_true(fabs(get(o, "ssim") - ssim / n) < 1e-15);
      assert_true(fabs(get(o, "color_alpha_mse") - col / n) < 1e-15);
      assert_true(fabs(get(o, "highlight_alpha_mse") - hl / n) < 1e-15);
      assert_true(fabs(get(o, "alpha_mse") - al / n) < 1e-15);
    }
  /* Frame tables carry the frame's own values, in its bucket only. */
  const cJSON *o = bucket(m, "coverage_frames", 1);
  assert_true(get(o, "psnr") == 3.0 && get(o, "ssim") == 0.25 && get(o, "mse") == 0.5);
  assert_int_equal((int)get(o, "pixels"), 7);
  assert_true(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(bucket(m, "coverage_frames", 0),
                                                            "psnr")));
  o = cJSON_GetObjectItemCaseSensitive(m, "overall");
  assert_true(get(o, "psnr") == 3.0 && get(o, "alpha_mse") == 3.0);
  cJSON_Delete(m);
  eval_strata_free(s);
  eval_regime_free(&r);
}

/* A method that some frames lack (a baseline not rendered for them) is
 * scored on fewer pixels than the bucket's row says: its cells say over
 * how many of the bucket's frames, the others' cells say nothing. */
static void partial_method_marked(void **state) {
  (void)state;
  float in[NPX * SPP * HF_FEATURES_PER_SAMPLE] = {0}, gt[NPX * 3], res[NPX * 3];
  float rgb[NPX * 3], gt_rgb[NPX * 3];
  double map[NPX];
  uint8_t mask[NPX];
  for (int p = 0; p < NPX; p++) {
    if (WIDTH[p] > 0) in[p * SPP * 6 + 2] = WIDTH[p];
    gt[3 * p] = 0.8f, gt[3 * p + 1] = 0.1f, gt[3 * p + 2] = GT_A[p];
    res[3 * p] = 0.7f, res[3 * p + 1] = 0.1f, res[3 * p + 2] = GT_A[p];
    for (int c = 0; c < 3; c++) gt_rgb[3 * p + c] = 0.2f, rgb[3 * p + c] = 0.25f;
    map[p] = 0.5;
    mask[p] = GT_A[p] > 0;
  }
  eval_regime r;
  assert_int_equal(eval_regime_compute(&r, in, SPP, gt, mask, W, H, 0, 0), 0);
  eval_strata *s;
  assert_int_equal(eval_strata_create(2, &s), 0);
  eval_frame_score fs = {.mse = 0.0025, .psnr = 26.0, .ssim = 0.5};
  for (int frame = 0; frame < 2; frame++) {
    eval_strata_add(s, 0, &r, rgb, gt_rgb, res, gt, map, &fs);
    if (frame == 0) eval_strata_add(s, 1, &r, rgb, gt_rgb, res, gt, map, &fs);
    eval_strata_frame_done(s, &r);
  }
  char *text = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&text, &len);
  assert_non_null(f);
  const char *labels[2] = {"every frame", "first frame only"};
  eval_strata_print(s, labels, f);
  fclose(f);
  const char *line = strstr(text, "| every frame |");
  assert_non_null(line);
  char *first = strndup(line, (size_t)(strchr(line, '\n') - line));
  assert_non_null(first);
  assert_null(strstr(first, "frames)"));
  free(first);
  line = strstr(text, "| first frame only |");
  assert_non_null(line);
  assert_non_null(strstr(line, "26.02 / 0.5000 (1 of 2 frames) |"));
  free(text);
  eval_strata_free(s);
  eval_regime_free(&r);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(width_edges_are_bin_edges),
    cmocka_unit_test(sums_match_direct),
    cmocka_unit_test(partial_method_marked),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
