/* Metrics of `hairfilter eval`: PSNR/MSE/SSIM on identical images, on
 * perturbations whose values are known in closed form, masks, and the
 * separable border-renormalised SSIM window against a direct 2D one. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "eval_metrics.h"

#define W 40
#define H 30
#define C 3

static float *image(float (*f)(int x, int y, int c)) {
  float *img = malloc((size_t)W * H * C * sizeof(float));
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++)
      for (int c = 0; c < C; c++) img[((size_t)y * W + x) * C + c] = f(x, y, c);
  return img;
}

static float f_random(int x, int y, int c) {
  uint32_t h = (uint32_t)x * 73856093u ^ (uint32_t)y * 19349663u ^ (uint32_t)c * 83492791u;
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return (float)(h & 0xffff) / 65535.0f;
}
static float f_half(int x, int y, int c) { return 0.5f; }
static float f_five8(int x, int y, int c) { return 0.625f; }
static float f_checker(int x, int y, int c) { return ((x + y) & 1) ? 0.375f : 0.625f; }

static void identical_images(void **state) {
  float *a = image(f_random);
  size_t n;
  assert_true(eval_mse(a, a, W, H, C, NULL, &n) == 0.0);
  assert_int_equal(n, W * H);
  assert_true(isinf(eval_psnr(0.0, 1.0)));
  assert_true(fabs(eval_ssim(a, a, W, H, C, NULL) - 1.0) < 1e-12);
  free(a);
}

/* A constant 0.5 against a constant 0.625 (both exact in float): MSE
 * 1/64, PSNR 10 log10(64) dB, and at every pixel (borders included: the
 * cut window is renormalised) SSIM = (2*0.5*0.625 + C1) / (0.5^2 + 0.625^2
 * + C1) since both variances are 0. */
static void constant_offset(void **state) {
  float *a = image(f_half), *b = image(f_five8);
  double mse = eval_mse(a, b, W, H, C, NULL, NULL);
  assert_true(fabs(mse - 0.015625) < 1e-12);
  assert_true(fabs(eval_psnr(mse, 1.0) - 18.061799739838872) < 1e-9);
  assert_true(fabs(eval_psnr(0.01, 1.0) - 20.0) < 1e-12);
  double want = (0.625 + 1e-4) / (0.640625 + 1e-4);
  assert_true(fabs(eval_ssim(a, b, W, H, C, NULL) - want) < 1e-9);
  double map[W * H];
  assert_int_equal(eval_ssim_map(a, b, W, H, C, 1, map), 0);
  assert_true(fabs(map[0] - want) < 1e-9 && fabs(map[W * H - 1] - want) < 1e-9);
  free(a);
  free(b);
}

/* Checkerboard 0.5 +- 0.125 against flat 0.5. With the 1D Gaussian g_i
 * (sigma 1.5, radius 5) and s = sum_i g_i (-1)^i, an interior pixel of
 * parity p = +-1 has mu = 0.5 + 0.125 p s^2, variance 0.125^2 (1 - s^4), no
 * covariance, so SSIM = (2 * 0.5 mu + C1) C2 / ((mu^2 + 0.25 + C1)(var + C2)).
 * g is computed here from the definition, not from eval_ssim_kernel. */
static void checkerboard_known_value(void **state) {
  float *a = image(f_checker), *b = image(f_half);
  assert_true(fabs(eval_mse(a, b, W, H, C, NULL, NULL) - 0.015625) < 1e-12);
  double g[11], z = 0, s = 0;
  for (int i = -5; i <= 5; i++) z += g[i + 5] = exp(-i * i / 4.5);
  for (int i = -5; i <= 5; i++) s += (i & 1 ? -1 : 1) * g[i + 5] / z;
  double map[W * H];
  assert_int_equal(eval_ssim_map(a, b, W, H, C, 0, map), 0);
  double c1 = 1e-4, c2 = 9e-4;
  for (int y = 5; y < H - 5; y++)
    for (int x = 5; x < W - 5; x++) {
      double p = ((x + y) & 1) ? -1 : 1;
      double mu = 0.5 + 0.125 * p * s * s, var = 0.015625 * (1 - s * s * s * s);
      double want = (2 * 0.5 * mu + c1) * c2 / ((mu * mu + 0.25 + c1) * (var + c2));
      assert_true(fabs(map[y * W + x] - want) < 1e-9);
    }
  /* The structure is lost: SSIM far below 1, and the same in all channels. */
  double ssim = eval_ssim(a, b, W, H, C, NULL);
  assert_true(ssim < 0.2);
  free(a);
  free(b);
}

/* Direct 2D Gaussian-window SSIM with the window cut to the image and
 * renormalised: the definition the separable code must match everywhere. */
static double ssim_direct(const float *a, const float *b, int ch, int px, int py) {
  double sw = 0, mx = 0, my = 0, xx = 0, yy = 0, xy = 0;
  for (int dy = -5; dy <= 5; dy++)
    for (int dx = -5; dx <= 5; dx++) {
      int x = px + dx, y = py + dy;
      if (x < 0 || y < 0 || x >= W || y >= H) continue;
      double wgt = exp(-(dx * dx + dy * dy) / 4.5);
      double u = a[((size_t)y * W + x) * C + ch], v = b[((size_t)y * W + x) * C + ch];
      sw += wgt;
      mx += wgt * u;
      my += wgt * v;
      xx += wgt * u * u;
      yy += wgt * v * v;
      xy += wgt * u * v;
    }
  mx /= sw; my /= sw; xx /= sw; yy /= sw; xy /= sw;
  double c1 = 1e-4, c2 = 9e-4;
  return (2 * mx * my + c1) * (2 * (xy - mx * my) + c2) /
         ((mx * mx + my * my + c1) * (xx - mx * mx + yy - my * my + c2));
}

static float f_random2(int x, int y, int c) { return 0.7f * f_random(x + 3, y + 11, c) + 0.1f; }

static void separable_matches_direct(void **state) {
  float *a = image(f_random), *b = image(f_random2);
  double map[W * H];
  for (int ch = 0; ch < C; ch++) {
    assert_int_equal(eval_ssim_map(a, b, W, H, C, ch, map), 0);
    for (int y = 0; y < H; y++)
      for (int x = 0; x < W; x++)
        assert_true(fabs(map[y * W + x] - ssim_direct(a, b, ch, x, y)) < 1e-9);
  }
  free(a);
  free(b);
}

/* Only masked pixels count: a perturbation outside the mask is invisible
 * to MSE, and the mean covers exactly the masked pixels. */
static void mask_selects_pixels(void **state) {
  float *a = image(f_half), *b = image(f_half);
  uint8_t mask[W * H];
  for (int p = 0; p < W * H; p++) mask[p] = (p % W) < W / 2;
  for (int y = 0; y < H; y++)
    for (int x = W / 2; x < W; x++)
      for (int c = 0; c < C; c++) b[((size_t)y * W + x) * C + c] = 0.9f;
  size_t n;
  assert_true(eval_mse(a, b, W, H, C, mask, &n) == 0.0);
  assert_int_equal(n, (W / 2) * H);
  assert_true(fabs(eval_mse(a, b, W, H, C, NULL, NULL) - 0.5 * 0.16) < 1e-6);
  /* One perturbed pixel inside the mask: 0.2^2 in one channel. */
  b[(5 * W + 3) * C + 1] = 0.7f;
  double want = 0.04 / ((double)(W / 2) * H * C);
  assert_true(fabs(eval_mse(a, b, W, H, C, mask, NULL) - want) < 1e-9);
  free(a);
  free(b);
}

/* Premultiplied channel error: (color*alpha) of two 2-pixel results. */
static void channel_mse_premultiplied(void **state) {
  const float a[6] = {2.0f, 0.5f, 0.5f, 9.0f, 1.0f, 0.0f};   /* color, hl, alpha */
  const float b[6] = {1.0f, 0.5f, 1.0f, 0.0f, 1.0f, 0.0f};
  /* pixel 0: 2*0.5 - 1*1 = 0; pixel 1: 9*0 - 0*0 = 0 */
  assert_true(eval_channel_mse(a, 3, 0, 2, b, 3, 0, 2, 2, 1, NULL) == 0.0);
  /* highlight*alpha: pixel 0: 0.25 vs 0.5 -> 0.0625; pixel 1: 0 vs 0 */
  assert_true(fabs(eval_channel_mse(a, 3, 1, 2, b, 3, 1, 2, 2, 1, NULL) - 0.03125) < 1e-12);
  /* alpha, unweighted: (0.5)^2 / 2 */
  assert_true(fabs(eval_channel_mse(a, 3, 2, -1, b, 3, 2, -1, 2, 1, NULL) - 0.125) < 1e-12);
}

static void kernel_is_normalised_gaussian(void **state) {
  double k[11], s = 0;
  eval_ssim_kernel(k);
  for (int i = 0; i < 11; i++) s += k[i];
  assert_true(fabs(s - 1) < 1e-12);
  assert_true(fabs(k[5] / k[6] - exp(1 / 4.5)) < 1e-12);
  assert_true(fabs(k[0] - k[10]) < 1e-15);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(identical_images),
    cmocka_unit_test(constant_offset),
    cmocka_unit_test(checkerboard_known_value),
    cmocka_unit_test(separable_matches_direct),
    cmocka_unit_test(mask_selects_pixels),
    cmocka_unit_test(channel_mse_premultiplied),
    cmocka_unit_test(kernel_is_normalised_gaussian),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
