/* Image quality metrics of `hairfilter eval` (docs/QUALITY.md says exactly
 * how they are computed). Images are interleaved [h][w][c] float; a mask is
 * [h][w] bytes, nonzero where a pixel counts (the hair pixels: ground-truth
 * alpha > 0). */
#ifndef HF_EVAL_METRICS_H
#define HF_EVAL_METRICS_H

#include <stddef.h>
#include <stdint.h>

/* SSIM constants for data range 1: C1 = (0.01)^2, C2 = (0.03)^2, Gaussian
 * window of 11x11 taps (radius 5), sigma 1.5. */
#define EVAL_SSIM_RADIUS 5
#define EVAL_SSIM_SIGMA  1.5
#define EVAL_SSIM_C1     (0.01 * 0.01)
#define EVAL_SSIM_C2     (0.03 * 0.03)

/* Mean squared error over the masked pixels and all c channels (mask NULL:
 * every pixel). Returns 0 with *count = 0 when nothing is masked in. */
double eval_mse(const float *a, const float *b, int w, int h, int c, const uint8_t *mask,
                size_t *count);
/* 10 log10(peak^2 / mse); +infinity for mse == 0. */
double eval_psnr(double mse, double peak);

/* The 1D Gaussian weights of the window (2 * EVAL_SSIM_RADIUS + 1 taps,
 * normalised to sum 1). */
void eval_ssim_kernel(double k[2 * EVAL_SSIM_RADIUS + 1]);

/* SSIM map of channel ch of two [h][w][c] images into map [h][w]. Local
 * statistics use the Gaussian window; near the borders the window is cut to
 * the image and renormalised (no padding values are invented). Returns 0 or
 * HF_ENOMEM. */
int eval_ssim_map(const float *a, const float *b, int w, int h, int c, int ch, double *map);

/* SSIM averaged over all c channels at every pixel, into acc [h][w]. 0 or
 * HF_ENOMEM. */
int eval_ssim_mean_map(const float *a, const float *b, int w, int h, int c, double *acc);
/* Mean of v over the masked entries of n (mask NULL: all), or empty when
 * none is. */
double eval_masked_mean(const double *v, size_t n, const uint8_t *mask, double empty);

/* Mean over the masked pixels of the SSIM averaged over all c channels
 * (mask NULL: every pixel). Negative HF_E* code on failure; 1 for identical
 * images. */
double eval_ssim(const float *a, const float *b, int w, int h, int c, const uint8_t *mask);

/* Masked MSE of one channel pair, optionally weighted: channel ca of a times
 * (wa < 0 ? 1 : channel wa of a) against channel cb of b times
 * (wb < 0 ? 1 : channel wb of b). For alpha-premultiplied channel errors. */
double eval_channel_mse(const float *a, int ca_stride, int ca, int wa, const float *b,
                        int cb_stride, int cb, int wb, int w, int h, const uint8_t *mask);

#endif
