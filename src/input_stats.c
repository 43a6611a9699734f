/* Input statistics: which regime a frame of features is in (strand width in
 * pixels, dense coverage, how much of the frame is hair, frame size), in one
 * pass over the samples' alpha. protocol/FEATURES.md ("Input statistics")
 * is the definition; weights/input_stats.py computes the same values with
 * numpy, bit for bit, so a range recorded in Python at training time is
 * checked here against the same numbers.
 *
 * The percentiles come from a fixed histogram rather than a sort: a sort
 * needs a copy of every pixel's value (16 MiB at 4096x1024) and O(n log n)
 * time in the daemon's worker, the histogram 16 KiB on the stack and one
 * increment per pixel. We write the histogram ourselves because its bins
 * must be reproducible exactly in numpy (they are the top 16 bits of the
 * IEEE 754 binary32 value, i.e. 128 bins per octave), and Debian 12 packages
 * no C histogram library (HdrHistogram_c is not packaged; GSL's
 * gsl_histogram does a binary search per value for non-uniform bins and
 * would be a large dependency for one counting loop). */
#include <math.h>
#include <string.h>

#include "hfcore.h"

/* Bins of the strand-alpha histogram: 0 below 2^-16, then 128 per octave
 * up to 1 (the float's exponent and top 7 mantissa bits), then >= 1. */
#define LOW_KEY   (111u << 7)              /* (bits of 2^-16) >> 16 */
#define ONE_KEY   (127u << 7)              /* (bits of 1.0) >> 16 */
#define NBINS     (2 + ONE_KEY - LOW_KEY)  /* 2050 */

static const char *const STAT_NAMES[HF_STAT_COUNT] = {
  [HF_STAT_STRAND_ALPHA_P50] = "strand_alpha_p50",
  [HF_STAT_STRAND_ALPHA_P90] = "strand_alpha_p90",
  [HF_STAT_FULL_COVERAGE] = "full_coverage",
  [HF_STAT_HAIR_FRACTION] = "hair_fraction",
  [HF_STAT_LONG_SIDE] = "long_side",
};

const char *hf_input_stat_name(int stat) {
  return stat >= 0 && stat < HF_STAT_COUNT ? STAT_NAMES[stat] : "unknown";
}

int hf_input_stat_from_name(const char *name) {
  for (int s = 0; name && s < HF_STAT_COUNT; s++)
    if (!strcmp(name, STAT_NAMES[s])) return s;
  return HF_ENOTFOUND;
}

/* Mean alpha of the covered samples of one pixel and their count. Summed
 * in sample order in float: the numpy twin does the same. */
static float strand_alpha(const float *px, int spp, int *covered) {
  float sum = 0.0f;
  int n = 0;
  for (int k = 0; k < spp; k++) {
    float a = px[k * HF_FEATURES_PER_SAMPLE + 2];
    if (a > 0.0f) {
      sum += a;
      n++;
    }
  }
  *covered = n;
  return n ? sum / (float)n : 0.0f;
}

int hf_pixel_covered(const float *px, int spp) {
  int n;
  strand_alpha(px, spp, &n);
  return n;
}

float hf_pixel_strand_alpha(const float *px, int spp) {
  int n;
  return strand_alpha(px, spp, &n);
}

static unsigned bin_of(float v) {
  if (!(v >= 1.0f)) {
    uint32_t bits;
    memcpy(&bits, &v, sizeof bits);
    uint32_t key = bits >> 16;
    return key < LOW_KEY ? 0 : 1 + key - LOW_KEY;
  }
  return NBINS - 1;   /* >= 1, +inf */
}

/* Lower edge of a bin: the value a percentile falling in it reports. */
static double bin_value(unsigned b) {
  if (b == 0) return 0.0;
  if (b == NBINS - 1) return 1.0;
  uint32_t bits = (b - 1 + LOW_KEY) << 16;
  float f;
  memcpy(&f, &bits, sizeof f);
  return f;
}

/* Value of the rank-th smallest (1-based) of the counted values. */
static double hist_rank(const uint64_t *hist, uint64_t rank) {
  uint64_t cum = 0;
  for (unsigned b = 0; b < NBINS; b++) {
    cum += hist[b];
    if (cum >= rank) return bin_value(b);
  }
  return NAN;
}

int hf_input_stats_compute(const void *in, hf_dtype dtype, int width, int height, int spp,
                           hf_input_stats *out) {
  if (!out) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  if (!in || width < 1 || height < 1 || spp < 1 || spp > HF_MAX_SPP ||
      (dtype != HF_F32 && dtype != HF_F16))
    return HF_EINVAL;
  uint64_t hist[NBINS];
  memset(hist, 0, sizeof hist);
  uint64_t npx = (uint64_t)width * (uint64_t)height, hair = 0, full = 0;
  const size_t stride = (size_t)spp * HF_FEATURES_PER_SAMPLE;
  float px[HF_MAX_SPP * HF_FEATURES_PER_SAMPLE];
  for (uint64_t p = 0; p < npx; p++) {
    const float *f;
    if (dtype == HF_F32) {
      f = (const float *)in + p * stride;
    } else {
      /* Only the alphas are read: widen those. */
      const uint16_t *h = (const uint16_t *)in + p * stride;
      for (int k = 0; k < spp; k++)
        px[k * HF_FEATURES_PER_SAMPLE + 2] = hf_f16_to_f32(h[k * HF_FEATURES_PER_SAMPLE + 2]);
      f = px;
    }
    int n;
    float a = strand_alpha(f, spp, &n);
    if (!n) continue;
    hair++;
    full += n == spp;
    hist[bin_of(a)]++;
  }
  out->width = width;
  out->height = height;
  out->spp = spp;
  out->hair_pixels = hair;
  out->full_pixels = full;
  double *v = out->value;
  v[HF_STAT_HAIR_FRACTION] = (double)hair / (double)npx;
  v[HF_STAT_LONG_SIDE] = width > height ? width : height;
  if (hair) {
    v[HF_STAT_STRAND_ALPHA_P50] = hist_rank(hist, (hair + 1) / 2);
    v[HF_STAT_STRAND_ALPHA_P90] = hist_rank(hist, (9 * hair + 9) / 10);
    v[HF_STAT_FULL_COVERAGE] = (double)full / (double)hair;
  } else {
    v[HF_STAT_STRAND_ALPHA_P50] = v[HF_STAT_STRAND_ALPHA_P90] = NAN;
    v[HF_STAT_FULL_COVERAGE] = NAN;
  }
  return HF_OK;
}
