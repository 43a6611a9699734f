/* Quality metrics: masked MSE / PSNR and Gaussian-window SSIM. */
#include "eval_metrics.h"

#include <math.h>
#include <stdlib.h>

#include "hfcore.h"

double eval_mse(const float *a, const float *b, int w, int h, int c, const uint8_t *mask,
                size_t *count) {
  double sum = 0;
  size_t n = 0, npx = (size_t)w * h;
  for (size_t p = 0; p < npx; p++) {
    if (mask && !mask[p]) continue;
    for (int k = 0; k < c; k++) {
      double d = (double)a[p * c + k] - b[p * c + k];
      sum += d * d;
    }
    n++;
  }
  if (count) *count = n;
  return n ? sum / ((double)n * c) : 0.0;
}

double eval_psnr(double mse, double peak) {
  if (mse <= 0) return INFINITY;
  return 10.0 * log10(peak * peak / mse);
}

void eval_ssim_kernel(double k[2 * EVAL_SSIM_RADIUS + 1]) {
  double s = 0;
  for (int i = -EVAL_SSIM_RADIUS; i <= EVAL_SSIM_RADIUS; i++) {
    k[i + EVAL_SSIM_RADIUS] = exp(-(double)(i * i) / (2.0 * EVAL_SSIM_SIGMA * EVAL_SSIM_SIGMA));
    s += k[i + EVAL_SSIM_RADIUS];
  }
  for (int i = 0; i < 2 * EVAL_SSIM_RADIUS + 1; i++) k[i] /= s;
}

/* Separable Gaussian filter of n planes [h][w] (in place through tmp).
 * Each 1D pass divides by the weight of the taps inside the image, so the
 * 2D weights at a border pixel are the window cut to the image and
 * renormalised: the product of the two 1D renormalisations is exactly the
 * 2D one because the cut window is a rectangle. */
static void blur(double *planes, int n, int w, int h, double *tmp) {
  double k[2 * EVAL_SSIM_RADIUS + 1];
  eval_ssim_kernel(k);
  const int r = EVAL_SSIM_RADIUS;
  for (int p = 0; p < n; p++) {
    double *img = planes + (size_t)p * w * h;
    for (int y = 0; y < h; y++)
      for (int x = 0; x < w; x++) {
        double s = 0, ws = 0;
        for (int i = -r; i <= r; i++) {
          int xx = x + i;
          if (xx < 0 || xx >= w) continue;
          s += k[i + r] * img[(size_t)y * w + xx];
          ws += k[i + r];
        }
        tmp[(size_t)y * w + x] = s / ws;
      }
    for (int y = 0; y < h; y++)
      for (int x = 0; x < w; x++) {
        double s = 0, ws = 0;
        for (int i = -r; i <= r; i++) {
          int yy = y + i;
          if (yy < 0 || yy >= h) continue;
          s += k[i + r] * tmp[(size_t)yy * w + x];
          ws += k[i + r];
        }
        img[(size_t)y * w + x] = s / ws;
      }
  }
}

int eval_ssim_map(const float *a, const float *b, int w, int h, int c, int ch, double *map) {
  size_t n = (size_t)w * h;
  /* Five planes: x, y, x^2, y^2, xy, then blurred into local moments. */
  double *buf = malloc(6 * n * sizeof(double));
  if (!buf) return HF_ENOMEM;
  double *mx = buf, *my = buf + n, *xx = buf + 2 * n, *yy = buf + 3 * n, *xy = buf + 4 * n;
  for (size_t p = 0; p < n; p++) {
    double x = a[p * c + ch], y = b[p * c + ch];
    mx[p] = x;
    my[p] = y;
    xx[p] = x * x;
    yy[p] = y * y;
    xy[p] = x * y;
  }
  blur(buf, 5, w, h, buf + 5 * n);
  for (size_t p = 0; p < n; p++) {
    double vx = xx[p] - mx[p] * mx[p], vy = yy[p] - my[p] * my[p];
    double cov = xy[p] - mx[p] * my[p];
    map[p] = ((2 * mx[p] * my[p] + EVAL_SSIM_C1) * (2 * cov + EVAL_SSIM_C2)) /
             ((mx[p] * mx[p] + my[p] * my[p] + EVAL_SSIM_C1) * (vx + vy + EVAL_SSIM_C2));
  }
  free(buf);
  return 0;
}

int eval_ssim_mean_map(const float *a, const float *b, int w, int h, int c, double *acc) {
  size_t n = (size_t)w * h;
  double *map = malloc(n * sizeof(double));
  if (!map) return HF_ENOMEM;
  for (size_t p = 0; p < n; p++) acc[p] = 0;
  for (int ch = 0; ch < c; ch++) {
    if (eval_ssim_map(a, b, w, h, c, ch, map)) {
      free(map);
      return HF_ENOMEM;
    }
    for (size_t p = 0; p < n; p++) acc[p] += map[p] / c;
  }
  free(map);
  return 0;
}

double eval_masked_mean(const double *v, size_t n, const uint8_t *mask, double empty) {
  double s = 0;
  size_t cnt = 0;
  for (size_t p = 0; p < n; p++) {
    if (mask && !mask[p]) continue;
    s += v[p];
    cnt++;
  }
  return cnt ? s / cnt : empty;
}

double eval_ssim(const float *a, const float *b, int w, int h, int c, const uint8_t *mask) {
  size_t n = (size_t)w * h;
  double *acc = malloc(n * sizeof(double));
  if (!acc || eval_ssim_mean_map(a, b, w, h, c, acc)) {
    free(acc);
    return HF_ENOMEM;
  }
  double s = eval_masked_mean(acc, n, mask, 1.0);
  free(acc);
  return s;
}

double eval_channel_mse(const float *a, int sa, int ca, int wa, const float *b, int sb, int cb,
                        int wb, int w, int h, const uint8_t *mask) {
  double sum = 0;
  size_t n = 0, npx = (size_t)w * h;
  for (size_t p = 0; p < npx; p++) {
    if (mask && !mask[p]) continue;
    double x = a[p * sa + ca] * (wa < 0 ? 1.0 : a[p * sa + wa]);
    double y = b[p * sb + cb] * (wb < 0 ? 1.0 : b[p * sb + wb]);
    sum += (x - y) * (x - y);
    n++;
  }
  return n ? sum / n : 0.0;
}
