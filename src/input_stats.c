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
#include "sample_rule.h"

/* The strand-alpha histogram's bins (HF_INPUT_STATS_BINS) and a pixel's
 * strand alpha are sample_rule.h's, shared with the cudnn backend's device
 * pass. */
#define LOW_KEY HF_RULE_LOW_KEY
#define NBINS   HF_INPUT_STATS_BINS

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

int hf_pixel_covered(const float *px, int spp) {
  int n;
  hf_rule_strand_alpha_f32(px, spp, &n);
  return n;
}

float hf_pixel_strand_alpha(const float *px, int spp) {
  int n;
  return hf_rule_strand_alpha_f32(px, spp, &n);
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

_Static_assert(NBINS == 2 + HF_RULE_ONE_KEY - HF_RULE_LOW_KEY, "the histogram's bins");

void hf_input_stats_acc_init(hf_input_stats_acc *a) { memset(a, 0, sizeof *a); }

/* Pixels [p0, p1) into a, pixel p's samples at in + p * stride values;
 * inlined once more for f16 frames of 4 spp (the
 * bundled variants'), whose sample loop is then unrolled: the statistics
 * run inside the pass that widens an f16 frame (hf_features_widen), where
 * they were the slowest part. */
static inline __attribute__((always_inline)) void add_pixels(hf_input_stats_acc *a,
                                                            const void *in, hf_dtype dtype,
                                                            int spp, size_t stride, size_t p0,
                                                            size_t p1) {
  /* The counts in locals: through a, every histogram increment would make
   * the compiler store and reload them (they might alias). */
  uint64_t hair = 0, full = 0, *hist = a->hist;
  for (size_t p = p0; p < p1; p++) {
    int n;
    float v = dtype == HF_F32
                  ? hf_rule_strand_alpha_f32((const float *)in + p * stride, spp, &n)
                  : hf_rule_strand_alpha_f16((const uint16_t *)in + p * stride, spp, &n);
    if (!n) continue;
    hair++;
    full += n == spp;
    hist[hf_rule_stat_bin(v)]++;
  }
  a->hair += hair;
  a->full += full;
}

void hf_input_stats_add(hf_input_stats_acc *a, const void *in, hf_dtype dtype, int spp,
                        size_t p0, size_t p1) {
  const size_t stride = (size_t)spp * HF_FEATURES_PER_SAMPLE;
  if (dtype == HF_F16 && spp == 4) add_pixels(a, in, HF_F16, 4, stride, p0, p1);
  else add_pixels(a, in, dtype, spp, stride, p0, p1);
}

void hf_input_stats_add_strided(hf_input_stats_acc *a, const void *in, hf_dtype dtype, int spp,
                                size_t stride, size_t p0, size_t p1) {
  if (dtype == HF_F16 && spp == 4) add_pixels(a, in, HF_F16, 4, stride, p0, p1);
  else add_pixels(a, in, dtype, spp, stride, p0, p1);
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
