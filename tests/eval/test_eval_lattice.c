/* The lattice measure of `hairfilter eval` (client/cli/eval_lattice.c):
 * noise has the energy of its variance and a peak near 1, a smooth
 * gradient has no peak, dots every 8 pixels and a 2-pixel checkerboard
 * (which repeats every 8 pixels too) stand out at period 8, and the edge
 * cases (identical images, too small, period out of range) give their
 * documented values. The windowed measure finds a lattice confined to one
 * part of a frame that the whole frame's peak misses, gives its amplitude,
 * leaves out windows with too little hair, and finds nothing in noise or
 * in a few outliers over an exact image. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "eval_lattice.h"

#define W 256
#define H 192
#define C 3

/* Uniform in [-0.5, 0.5) from the pixel's index (SplitMix64's finaliser:
 * no structure at any period). */
static double noise(size_t i) {
  uint64_t z = (uint64_t)i + 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return (double)(z >> 11) / 9007199254740992.0 - 0.5;
}

/* a: the truth (0.5 everywhere); b: a plus amp times noise plus pattern(x, y). */
static void images(float **a, float **b, double amp, double (*pattern)(int x, int y)) {
  *a = malloc((size_t)W * H * C * sizeof(float));
  *b = malloc((size_t)W * H * C * sizeof(float));
  assert_non_null(*a);
  assert_non_null(*b);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++)
      for (int c = 0; c < C; c++) {
        size_t i = ((size_t)y * W + x) * C + c;
        (*a)[i] = 0.5f;
        (*b)[i] = (float)(0.5 + amp * noise(i) + (pattern ? pattern(x, y) : 0));
      }
}

static double none(int x, int y) { return 0; }
static double dots8(int x, int y) { return x % 8 == 3 && y % 8 == 5 ? 0.2 : 0; }
static double checker2(int x, int y) { return (x + y) % 2 ? 0.02 : -0.02; }
static double ramp(int x, int y) { return 0.3 * x / W + 0.1 * y / H; }

static void noise_has_its_variance_and_no_peak(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0.2, none);
  /* Uniform of width 0.2: variance 0.04 / 12. */
  double var = 0.04 / 12;
  for (int p = 2; p <= 17; p++) {
    double e = eval_lattice_energy(a, b, W, H, C, p);
    assert_true(e > 0.8 * var && e < 1.2 * var);
  }
  for (int p = 3; p <= 16; p++) {
    double k = eval_lattice_peak(a, b, W, H, C, p);
    assert_true(k > 0.7 && k < 1.4);
  }
  free(a);
  free(b);
}

static void dots_every_8_pixels_stand_out(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0.2, dots8);
  double k8 = eval_lattice_peak(a, b, W, H, C, 8);
  assert_true(k8 >= 10 * EVAL_LATTICE_VISIBLE);
  /* Period 16 holds the 8-pixel pattern twice over; 11, with no common
   * factor, spreads the dots evenly over its phases: what is left is the
   * noise's energy and the dots' own variance (0.2^2 / 64 (1 - 1 / 64)). */
  assert_true(eval_lattice_peak(a, b, W, H, C, 16) >= EVAL_LATTICE_VISIBLE);
  double var = 0.04 / 12 + 0.04 / 64 * (1 - 1.0 / 64);
  double e11 = eval_lattice_energy(a, b, W, H, C, 11);
  assert_true(e11 > 0.8 * var && e11 < 1.2 * var);
  free(a);
  free(b);
}

static void checkerboard_repeats_every_8_pixels(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0.2, checker2);
  assert_true(eval_lattice_peak(a, b, W, H, C, 8) >= EVAL_LATTICE_VISIBLE);
  /* At period 7 both neighbours (6 and 8) hold it and 7 does not. */
  assert_true(eval_lattice_peak(a, b, W, H, C, 7) < 0.5);
  free(a);
  free(b);
}

static void smooth_error_has_no_peak(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0, ramp);
  double k = eval_lattice_peak(a, b, W, H, C, 8);
  assert_true(k > 0.8 && k < 1.25);
  free(a);
  free(b);
}

static void edge_cases(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0, none);
  assert_true(eval_lattice_energy(a, b, W, H, C, 8) == 0);
  assert_true(eval_lattice_peak(a, b, W, H, C, 8) == 0);
  free(a);
  free(b);
  /* A pattern alone: the neighbouring periods see only the few dots of
   * the frame's last part period. */
  images(&a, &b, 0, dots8);
  assert_true(eval_lattice_peak(a, b, W, H, C, 8) >= 10 * EVAL_LATTICE_VISIBLE);
  assert_true(isnan(eval_lattice_peak(a, b, W, H, C, 2)));
  assert_true(isnan(eval_lattice_peak(a, b, W, H, C, EVAL_LATTICE_MAX_PERIOD + 1)));
  assert_true(isnan(eval_lattice_energy(a, b, W, H, C, 1)));
  assert_true(isnan(eval_lattice_energy(a, b, W, H, C, EVAL_LATTICE_MAX_PERIOD + 2)));
  /* Two periods of 9 need 18 pixels each way. */
  assert_true(isnan(eval_lattice_peak(a, b, 17, 40, C, 8)));
  assert_false(isnan(eval_lattice_peak(a, b, 18, 18, C, 8)));
  free(a);
  free(b);
}

/* Dots in one 64 x 64 part only (the window at 128, 64 of period 8), of
 * RMS amplitude 0.02 over the phases there: one dot of height 0.16 per
 * period, sqrt(0.16^2 / 64 (1 - 1 / 64)) = 0.0198. */
static double local_dots8(int x, int y) {
  return x >= 128 && x < 192 && y >= 64 && y < 128 && x % 8 == 3 && y % 8 == 5 ? 0.16 : 0;
}

static void windows_find_a_local_lattice(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0.2, local_dots8);
  /* Diluted over the frame: 1/12 of it holds the dots. */
  assert_true(eval_lattice_peak(a, b, W, H, C, 8) < EVAL_LATTICE_VISIBLE);
  eval_lattice_window lw;
  assert_int_equal(eval_lattice_windows(a, b, NULL, W, H, C, 8, &lw), 1);
  /* Windows of 64, 32 apart: 7 across 256, 5 down 192. */
  assert_int_equal(lw.windows, 7 * 5);
  assert_true(lw.peak >= EVAL_LATTICE_WINDOW_PEAK);
  assert_int_equal(lw.peak_x, 128);
  assert_int_equal(lw.peak_y, 64);
  assert_int_equal(lw.x, 128);
  assert_int_equal(lw.y, 64);
  double want = sqrt(0.16 * 0.16 / 64 * (1 - 1.0 / 64));
  assert_true(lw.amplitude > 0.85 * want && lw.amplitude < 1.15 * want);
  assert_true(lw.amplitude >= EVAL_LATTICE_VISIBLE_AMPLITUDE);

  /* Without hair under it (mask 0 there) the lattice is not looked at. */
  uint8_t *mask = malloc((size_t)W * H);
  assert_non_null(mask);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) mask[(size_t)y * W + x] = !(x >= 96 && x < 224);
  assert_int_equal(eval_lattice_windows(a, b, mask, W, H, C, 8, &lw), 1);
  assert_true(lw.amplitude == 0);
  assert_true(lw.peak < EVAL_LATTICE_WINDOW_PEAK);
  /* No window with hair at all. */
  memset(mask, 0, (size_t)W * H);
  assert_int_equal(eval_lattice_windows(a, b, mask, W, H, C, 8, &lw), 0);
  assert_true(isnan(lw.peak));
  free(mask);
  free(a);
  free(b);
}

static void windows_find_nothing_in_noise(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0.2, none);
  eval_lattice_window lw;
  for (int p = 3; p <= 16; p++) {
    assert_int_equal(eval_lattice_windows(a, b, NULL, W, H, C, p, &lw), 1);
    assert_true(lw.peak > 0.5 && lw.peak < EVAL_LATTICE_WINDOW_PEAK);
    assert_true(lw.amplitude == 0);
  }
  free(a);
  free(b);
  /* Six outliers over an exact image, 8 pixels apart by chance: all in
   * one phase at period 8, so a window's peak says "pattern", but what a
   * viewer sees is six dots, not a lattice: its amplitude is too small. */
  images(&a, &b, 0, none);
  for (int i = 0; i < 6; i++) {
    size_t px = (size_t)(40 + 8 * i) * W + 70 + 8 * i;
    for (int c = 0; c < C; c++) b[px * C + c] += 0.2f;
  }
  assert_int_equal(eval_lattice_windows(a, b, NULL, W, H, C, 8, &lw), 1);
  assert_true(lw.peak >= EVAL_LATTICE_WINDOW_PEAK);
  assert_true(lw.amplitude > 0 && lw.amplitude < EVAL_LATTICE_VISIBLE_AMPLITUDE);
  free(a);
  free(b);
}

static void windows_edge_cases(void **state) {
  (void)state;
  float *a, *b;
  images(&a, &b, 0, none);
  eval_lattice_window lw;
  /* Identical images: measured, no pattern. */
  assert_int_equal(eval_lattice_windows(a, b, NULL, W, H, C, 8, &lw), 1);
  assert_true(lw.peak == 0 && lw.amplitude == 0);
  /* A window is the smaller side where that is less than 8 periods, and
   * needs 2 (P + 1) pixels. */
  assert_int_equal(eval_lattice_windows(a, b, NULL, 18, 40, C, 8, &lw), 1);
  assert_int_equal(lw.windows, 4);   /* 18 x 18 windows at y 0, 9, 18, 22 */
  assert_int_equal(eval_lattice_windows(a, b, NULL, 17, 40, C, 8, &lw), 0);
  assert_int_equal(eval_lattice_windows(a, b, NULL, W, H, C, 2, &lw), 0);
  assert_int_equal(eval_lattice_windows(a, b, NULL, W, H, C, EVAL_LATTICE_MAX_PERIOD + 1, &lw), 0);
  free(a);
  free(b);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(noise_has_its_variance_and_no_peak),
    cmocka_unit_test(dots_every_8_pixels_stand_out),
    cmocka_unit_test(checkerboard_repeats_every_8_pixels),
    cmocka_unit_test(smooth_error_has_no_peak),
    cmocka_unit_test(edge_cases),
    cmocka_unit_test(windows_find_a_local_lattice),
    cmocka_unit_test(windows_find_nothing_in_noise),
    cmocka_unit_test(windows_edge_cases),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
