/* The lattice measure of `hairfilter eval` (client/cli/eval_lattice.c):
 * noise has the energy of its variance and a peak near 1, a smooth
 * gradient has no peak, dots every 8 pixels and a 2-pixel checkerboard
 * (which repeats every 8 pixels too) stand out at period 8, and the edge
 * cases (identical images, too small, period out of range) give their
 * documented values. */
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

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(noise_has_its_variance_and_no_peak),
    cmocka_unit_test(dots_every_8_pixels_stand_out),
    cmocka_unit_test(checkerboard_repeats_every_8_pixels),
    cmocka_unit_test(smooth_error_has_no_peak),
    cmocka_unit_test(edge_cases),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
