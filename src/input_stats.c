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

/* a when c, else +0, without a branch: compilers turn `c ? a : 0` into a
 * jump, and coverage is random from sample to sample (a third of the time
 * of a frame went to mispredicting it). */
static inline float keep_if(float a, int c) {
  uint32_t bits;
  memcpy(&bits, &a, sizeof bits);
  bits &= 0u - (uint32_t)c;
  memcpy(&a, &bits, sizeof a);
  return a;
}

/* Mean alpha of the covered samples of one pixel and their count. Summed
 * in sample order in float (adding +0 for an uncovered sample changes no
 * bit), which the numpy twin does too. */
static inline float strand_alpha(const float *px, int spp, int *covered) {
  float sum = 0.0f;
  int n = 0;
  for (int k = 0; k < spp; k++) {
    float a = px[k * HF_FEATURES_PER_SAMPLE + 2];
    int c = a > 0.0f;
    sum += keep_if(a, c);
    n += c;
  }
  *covered = n;
  return n ? sum / (float)n : 0.0f;
}

/* The same over binary16 alphas. A covered half is positive and not NaN:
 * its float is exact (normal halves by moving the bits, subnormal ones as
 * a multiple of 2^-24, infinity as itself), so the sum is that of the
 * widened values, as when the frame is widened first (hf_f16_to_f32). */
static inline float strand_alpha_f16(const uint16_t *px, int spp, int *covered) {
  float sum = 0.0f;
  int n = 0;
  for (int k = 0; k < spp; k++) {
    uint32_t h = px[k * HF_FEATURES_PER_SAMPLE + 2];
    int c = h - 1u < 0x7c00u;                   /* 1..0x7c00: sign 0, not 0, not NaN */
    uint32_t bits = (h << 13) + (112u << 23);   /* normal: rebias the exponent */
    float a;
    memcpy(&a, &bits, sizeof a);
    /* Subnormals and infinity are rare in real frames: branches that are
     * almost never taken cost nothing. (0 is uncovered: not used.) */
    if (h - 1u < 0x3ffu) a = (float)h * 0x1p-24f;
    else if (h == 0x7c00u) a = INFINITY;
    sum += keep_if(a, c);
    n += c;
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

static inline unsigned bin_of(float v) {
  uint32_t bits;
  memcpy(&bits, &v, sizeof bits);
  /* v > 0 here: below 2^-16 -> 0, from 1 (and +inf) up -> the last bin. */
  int b = (int)(bits >> 16) - (int)LOW_KEY + 1;
  b = b < 0 ? 0 : b;
  return (unsigned)(b > (int)NBINS - 1 ? (int)NBINS - 1 : b);
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

_Static_assert(NBINS == HF_INPUT_STATS_BINS, "the histogram's bins");

void hf_input_stats_acc_init(hf_input_stats_acc *a) { memset(a, 0, sizeof *a); }

/* Pixels [p0, p1) into a; inlined once more for f16 frames of 4 spp (the
 * bundled variants'), whose sample loop is then unrolled: the statistics
 * run inside the pass that widens an f16 frame (hf_features_widen), where
 * they were the slowest part. */
static inline __attribute__((always_inline)) void add_pixels(hf_input_stats_acc *a,
                                                            const void *in, hf_dtype dtype,
                                                            int spp, size_t p0, size_t p1) {
  const size_t stride = (size_t)spp * HF_FEATURES_PER_SAMPLE;
  /* The counts in locals: through a, every histogram increment would make
   * the compiler store and reload them (they might alias). */
  uint64_t hair = 0, full = 0, *hist = a->hist;
  for (size_t p = p0; p < p1; p++) {
    int n;
    float v = dtype == HF_F32 ? strand_alpha((const float *)in + p * stride, spp, &n)
                              : strand_alpha_f16((const uint16_t *)in + p * stride, spp, &n);
    if (!n) continue;
    hair++;
    full += n == spp;
    hist[bin_of(v)]++;
  }
  a->hair += hair;
  a->full += full;
}

void hf_input_stats_add(hf_input_stats_acc *a, const void *in, hf_dtype dtype, int spp,
                        size_t p0, size_t p1) {
  if (dtype == HF_F16 && spp == 4) add_pixels(a, in, HF_F16, 4, p0, p1);
  else add_pixels(a, in, dtype, spp, p0, p1);
}

void hf_input_stats_merge(hf_input_stats_acc *a, const hf_input_stats_acc *b) {
  a->hair += b->hair;
  a->full += b->full;
  for (unsigned i = 0; i < NBINS; i++) a->hist[i] += b->hist[i];
}

void hf_input_stats_finish(const hf_input_stats_acc *a, int width, int height, int spp,
                           hf_input_stats *out) {
  memset(out, 0, sizeof *out);
  uint64_t npx = (uint64_t)width * (uint64_t)height, hair = a->hair;
  out->width = width;
  out->height = height;
  out->spp = spp;
  out->hair_pixels = hair;
  out->full_pixels = a->full;
  double *v = out->value;
  v[HF_STAT_HAIR_FRACTION] = (double)hair / (double)npx;
  v[HF_STAT_LONG_SIDE] = width > height ? width : height;
  if (hair) {
    v[HF_STAT_STRAND_ALPHA_P50] = hist_rank(a->hist, (hair + 1) / 2);
    v[HF_STAT_STRAND_ALPHA_P90] = hist_rank(a->hist, (9 * hair + 9) / 10);
    v[HF_STAT_FULL_COVERAGE] = (double)a->full / (double)hair;
  } else {
    v[HF_STAT_STRAND_ALPHA_P50] = v[HF_STAT_STRAND_ALPHA_P90] = NAN;
    v[HF_STAT_FULL_COVERAGE] = NAN;
  }
}

int hf_input_stats_compute(const void *in, hf_dtype dtype, int width, int height, int spp,
                           hf_input_stats *out) {
  if (!out) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  if (!in || width < 1 || height < 1 || spp < 1 || spp > HF_MAX_SPP ||
      (dtype != HF_F32 && dtype != HF_F16))
    return HF_EINVAL;
  hf_input_stats_acc a;
  hf_input_stats_acc_init(&a);
  hf_input_stats_add(&a, in, dtype, spp, 0, (size_t)width * height);
  hf_input_stats_finish(&a, width, height, spp, out);
  return HF_OK;
}
