/* EXR and PNG helpers, feature naming, compositing. */
#include <float.h>
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

static char tmpdir[] = "/tmp/hf_test_image_XXXXXX";

static void test_exr_roundtrip(void **state) {
  int W = 37, H = 150, spp = 2; /* > one ZIP chunk of 16 lines */
  size_t n = (size_t)W * H * spp * 6;
  float *in = malloc(n * 4);
  for (size_t i = 0; i < n; i++) in[i] = (float)i * 0.001f - 3.0f;
  hf_image img;
  assert_int_equal(hf_features_to_image(in, W, H, spp, &img), HF_OK);
  assert_string_equal(img.names[7], "S1.highlight");
  char path[256];
  snprintf(path, sizeof path, "%s/f.exr", tmpdir);
  assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
  hf_image back;
  char err[256];
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  assert_int_equal(back.width, W);
  assert_int_equal(back.height, H);
  assert_int_equal(back.channels, 12);
  assert_int_equal(hf_features_spp(&back), 2);
  float *got = malloc(n * 4);
  assert_int_equal(hf_features_from_image(&back, spp, got), spp);
  assert_memory_equal(got, in, n * 4); /* float32 storage is exact */
  hf_image_free(&back);
  /* half storage: within half precision */
  assert_int_equal(hf_exr_write(path, &img, 1), HF_OK);
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  assert_int_equal(hf_features_from_image(&back, spp, got), spp);
  for (size_t i = 0; i < n; i++) assert_true(fabsf(got[i] - in[i]) <= 2e-3f * fabsf(in[i]) + 1e-6f);
  hf_image_free(&back);
  hf_image_free(&img);
  free(in), free(got);
}

static void test_exr_errors(void **state) {
  hf_image img;
  char err[256] = "", path[256];
  assert_int_equal(hf_exr_read("/nonexistent.exr", &img, err, sizeof err), HF_EIO);
  assert_non_null(strstr(err, "/nonexistent.exr"));
  snprintf(path, sizeof path, "%s/junk.exr", tmpdir);
  FILE *f = fopen(path, "wb");
  fputs("v/1\x01 this is not an exr file at all", f);
  fclose(f);
  assert_true(hf_exr_read(path, &img, err, sizeof err) < 0);
  assert_null(img.data);
}

static void test_features_missing_channel(void **state) {
  hf_image img;
  assert_int_equal(hf_image_alloc(&img, 2, 2, 6), HF_OK);
  for (int k = 0; k < 6; k++) snprintf(img.names[k], 32, "S0.%s", HF_FEATURE_NAMES[k]);
  strcpy(img.names[5], "S0.tangent.z");
  assert_int_equal(hf_features_spp(&img), 1);
  float in[24];
  assert_int_equal(hf_features_from_image(&img, 1, in), HF_ENOTFOUND);
  hf_image_free(&img);
}

static void test_composite(void **state) {
  float res[6] = {1.0f, 0.5f, 1.0f, 2.0f, 0.0f, 0.0f};
  float hair[3] = {0.5f, 0.25f, 0.1f}, light[3] = {2, 2, 2}, bg[3] = {0.1f, 0.2f, 0.3f}, rgb[6];
  hf_composite(res, 2, 1, hair, light, bg, rgb);
  assert_float_equal(rgb[0], 2 * (0.5f + 0.5f), 1e-6);   /* opaque: light*(hair*c+h) */
  assert_float_equal(rgb[2], 2 * (0.1f + 0.5f), 1e-6);
  assert_float_equal(rgb[3], 0.1f, 1e-6);               /* transparent: background */
  assert_float_equal(rgb[5], 0.3f, 1e-6);
  char path[256];
  snprintf(path, sizeof path, "%s/c.png", tmpdir);
  assert_int_equal(hf_png_write_rgb(path, rgb, 2, 1), HF_OK);
  FILE *f = fopen(path, "rb");
  unsigned char sig[8];
  assert_int_equal(fread(sig, 1, 8, f), 8);
  fclose(f);
  assert_memory_equal(sig, "\x89PNG\r\n\x1a\n", 8);
}

/* Finite colours whose products overflow float saturate at FLT_MAX instead
 * of giving infinities; values inside the range are the formula's. */
static void test_composite_saturates(void **state) {
  float res[9] = {1.0f, 0.5f, 1.0f, 0.5f, 0.0f, 0.25f, 0.0f, 0.0f, 0.0f};
  float hair[3] = {3e38f, -3e38f, 1e-30f}, light[3] = {3e38f, 3e38f, 1e30f};
  float bg[3] = {3e38f, -3e38f, 2.0f}, rgb[9];
  hf_composite(res, 3, 1, hair, light, bg, rgb);
  for (int i = 0; i < 9; i++) assert_true(isfinite(rgb[i]));
  assert_true(rgb[0] == FLT_MAX);    /* 3e38 * (3e38 + 0.5) */
  assert_true(rgb[1] == -FLT_MAX);   /* 3e38 * (-3e38 + 0.5) */
  assert_float_equal(rgb[2], 1e30 * (1e-30 + 0.5), 1e24);   /* in range: the formula */
  assert_true(rgb[3] == FLT_MAX);    /* 0.25 * 3e38 * 1.5e38 + 0.75 * 3e38 */
  assert_true(rgb[6] == 3e38f);      /* transparent: the background itself */
  assert_true(rgb[7] == -3e38f);
  assert_float_equal(rgb[8], 2.0f, 0);
}

static int setup(void **state) { return mkdtemp(tmpdir) ? 0 : -1; }
static int teardown(void **state) {
  char cmd[300];
  snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmpdir);
  return system(cmd);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_exr_roundtrip), cmocka_unit_test(test_exr_errors),
    cmocka_unit_test(test_features_missing_channel), cmocka_unit_test(test_composite),
    cmocka_unit_test(test_composite_saturates),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
