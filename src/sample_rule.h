/* The out-of-contract rule for one sample and the statistic of one pixel,
 * as inline functions shared by the host passes (sanitise.c, input_stats.c)
 * and the cudnn backend's device pass (cudnn_kernels_body.cuh), so that a
 * frame checked on the GPU is checked by the same definition, bit for bit
 * (protocol/FEATURES.md, "Out-of-contract values" and "Input statistics").
 * Internal to src/; C and CUDA C++.
 *
 * A sample is HF_FEATURES_PER_SAMPLE values: colour, highlight, alpha,
 * depth, tangent x, tangent y (HF_FEATURE_NAMES order). */
#ifndef HF_SAMPLE_RULE_H
#define HF_SAMPLE_RULE_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "hfcore.h"

#ifdef __CUDACC__
#define HF_RULE_FN static __host__ __device__ __forceinline__
#else
#define HF_RULE_FN static inline
#endif

/* ---- the rule ------------------------------------------------------------ */

/* In contract: covered with every feature in range, or uncovered (all 0).
 * Comparisons are false for NaN, so NaN is never in range. Branch-free:
 * covered and uncovered samples alternate unpredictably. */
HF_RULE_FN int hf_rule_ok_f32(const float *s) {
  const float m = HF_FEATURE_LIGHT_MAX;
  float c = s[0], h = s[1], a = s[2], d = s[3], x = s[4], y = s[5];
  int in = (a > 0.0f) & (a <= 1.0f) & (c >= 0.0f) & (c <= m) & (h >= 0.0f) & (h <= m) &
           (d >= 0.0f) & (d <= 1.0f) & (x >= -1.0f) & (x <= 1.0f) & (y >= -1.0f) & (y <= 1.0f);
  int zero = (c == 0.0f) & (h == 0.0f) & (a == 0.0f) & (d == 0.0f) & (x == 0.0f) & (y == 0.0f);
  return in | zero;
}

/* Orders halves as integers: key(a) < key(b) iff a < b for non-NaN a, b
 * (-0 just below +0); NaNs land outside [key(-Inf), key(+Inf)]. */
HF_RULE_FN uint16_t hf_rule_key16(uint16_t h) {
  return (uint16_t)((h & 0x8000u) ? ~(unsigned)h : (unsigned)h | 0x8000u);
}
#define HF_RULE_K_NEG_ZERO 0x7fffu   /* key16(0x8000): a lower bound 0 takes -0 */
#define HF_RULE_K_POS_ZERO 0x8000u   /* key16(0x0000) */
#define HF_RULE_K_NEG_ONE  0x43ffu   /* key16(0xbc00) */
#define HF_RULE_K_ONE      0xbc00u   /* key16(0x3c00) */
#define HF_RULE_K_LIGHT    0xd400u   /* key16(0x5400) = 64.0 */

/* hf_rule_ok_f32 on a sample of binary16 values, without widening them. */
HF_RULE_FN int hf_rule_ok_f16(const uint16_t *s) {
  unsigned c = hf_rule_key16(s[0]), h = hf_rule_key16(s[1]), a = hf_rule_key16(s[2]);
  unsigned d = hf_rule_key16(s[3]), x = hf_rule_key16(s[4]), y = hf_rule_key16(s[5]);
  int in = (a > HF_RULE_K_POS_ZERO) & (a <= HF_RULE_K_ONE) & (c >= HF_RULE_K_NEG_ZERO) &
           (c <= HF_RULE_K_LIGHT) & (h >= HF_RULE_K_NEG_ZERO) & (h <= HF_RULE_K_LIGHT) &
           (d >= HF_RULE_K_NEG_ZERO) & (d <= HF_RULE_K_ONE) & (x >= HF_RULE_K_NEG_ONE) &
           (x <= HF_RULE_K_ONE) & (y >= HF_RULE_K_NEG_ONE) & (y <= HF_RULE_K_ONE);
  int zero = ((s[0] | s[1] | s[2] | s[3] | s[4] | s[5]) & 0x7fffu) == 0;
  return in | zero;
}

/* The rule on one out-of-contract sample of six floats, in place; says what
 * was wrong in kind (HF_SANITISED_*) and feature (the first feature that
 * made it so). A binary16 sample is fixed through float32 exactly: every
 * bound is exact in binary16, so the fixed half widens back to the fixed
 * float. */
HF_RULE_FN void hf_rule_fix_f32(float *s, int *kind, int *feature) {
  const float lo[HF_FEATURES_PER_SAMPLE] = {0.0f, 0.0f, 0.0f, 0.0f, -1.0f, -1.0f};
  const float hi[HF_FEATURES_PER_SAMPLE] = {HF_FEATURE_LIGHT_MAX, HF_FEATURE_LIGHT_MAX,
                                            1.0f, 1.0f, 1.0f, 1.0f};
  for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++)
    if (!isfinite(s[f])) {
      *kind = HF_SANITISED_NONFINITE, *feature = f;
      for (int g = 0; g < HF_FEATURES_PER_SAMPLE; g++) s[g] = 0.0f;
      return;
    }
  if (s[2] <= 0.0f) {
    *kind = HF_SANITISED_UNCOVERED, *feature = 2;
    for (int g = 0; g < HF_FEATURES_PER_SAMPLE; g++) s[g] = 0.0f;
    return;
  }
  *kind = HF_SANITISED_CLAMPED, *feature = -1;
  for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++)
    if (s[f] < lo[f] || s[f] > hi[f]) {
      if (*feature < 0) *feature = f;
      s[f] = s[f] < lo[f] ? lo[f] : hi[f];
    }
}

/* ---- the pixel's statistic --------------------------------------------- */

/* a when c, else +0, without a branch: compilers turn `c ? a : 0` into a
 * jump, and coverage is random from sample to sample (a third of the time
 * of a frame went to mispredicting it). */
HF_RULE_FN float hf_rule_keep_if(float a, int c) {
  uint32_t bits;
  memcpy(&bits, &a, sizeof bits);
  bits &= 0u - (uint32_t)c;
  memcpy(&a, &bits, sizeof a);
  return a;
}

/* Mean alpha of the covered samples of one pixel (spp samples of six
 * floats) and their count. Summed in sample order in float (adding +0 for
 * an uncovered sample changes no bit), which weights/input_stats.py does
 * too. */
HF_RULE_FN float hf_rule_strand_alpha_f32(const float *px, int spp, int *covered) {
  float sum = 0.0f;
  int n = 0;
  for (int k = 0; k < spp; k++) {
    float a = px[k * HF_FEATURES_PER_SAMPLE + 2];
    int c = a > 0.0f;
    sum += hf_rule_keep_if(a, c);
    n += c;
  }
  *covered = n;
  return n ? sum / (float)n : 0.0f;
}

/* The same over binary16 alphas. A covered half is positive and not NaN:
 * its float is exact (normal halves by moving the bits, subnormal ones as
 * a multiple of 2^-24, infinity as itself), so the sum is that of the
 * widened values, as when the frame is widened first (hf_f16_to_f32). */
HF_RULE_FN float hf_rule_strand_alpha_f16(const uint16_t *px, int spp, int *covered) {
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
    if (h - 1u < 0x3ffu) a = (float)h * 5.9604644775390625e-8f;   /* h * 2^-24 */
    else if (h == 0x7c00u) a = INFINITY;
    sum += hf_rule_keep_if(a, c);
    n += c;
  }
  *covered = n;
  return n ? sum / (float)n : 0.0f;
}

/* Bins of the strand-alpha histogram (HF_INPUT_STATS_BINS): 0 below 2^-16,
 * then 128 per octave up to 1 (the float's exponent and top 7 mantissa
 * bits), then >= 1. */
#define HF_RULE_LOW_KEY (111u << 7)   /* (bits of 2^-16) >> 16 */
#define HF_RULE_ONE_KEY (127u << 7)   /* (bits of 1.0) >> 16 */

/* The histogram bin of a strand alpha v > 0: below 2^-16 -> 0, from 1 (and
 * +inf) up -> the last bin. */
HF_RULE_FN unsigned hf_rule_stat_bin(float v) {
  uint32_t bits;
  memcpy(&bits, &v, sizeof bits);
  int b = (int)(bits >> 16) - (int)HF_RULE_LOW_KEY + 1;
  b = b < 0 ? 0 : b;
  return (unsigned)(b > HF_INPUT_STATS_BINS - 1 ? HF_INPUT_STATS_BINS - 1 : b);
}

/* ---- the output guard ------------------------------------------------------ */

#define HF_RULE_F16_MAX_BITS 0x7bffu  /* 65504 */
#define HF_RULE_F16_ONE_BITS 0x3c00u

/* One output pixel (colour, highlight, alpha) kept in its ranges
 * (hf_output_guard): NaN becomes the channel's neutral value (colour 1,
 * highlight 0, alpha 0), anything else is clamped to [-HF_OUTPUT_MAX,
 * HF_OUTPUT_MAX], [0, HF_OUTPUT_MAX], [0, 1]. 1 when it changed. */
HF_RULE_FN int hf_rule_guard_f32(float *o) {
  float c = o[0], h = o[1], a = o[2];
  if ((c >= -HF_OUTPUT_MAX) & (c <= HF_OUTPUT_MAX) & (h >= 0.0f) & (h <= HF_OUTPUT_MAX) &
      (a >= 0.0f) & (a <= 1.0f))
    return 0;
  /* Comparisons, not fminf/fmaxf: those may return either zero for -0
   * against +0 (glibc versions differ, and a device's min/max and
   * saturation differ again), so a -0 beside a fixed value is kept, the
   * same everywhere. */
  o[0] = isnan(c)               ? 1.0f
         : c < -HF_OUTPUT_MAX ? -HF_OUTPUT_MAX
         : c > HF_OUTPUT_MAX  ? HF_OUTPUT_MAX
                              : c;
  o[1] = isnan(h) ? 0.0f : h < 0.0f ? 0.0f : h > HF_OUTPUT_MAX ? HF_OUTPUT_MAX : h;
  o[2] = isnan(a) ? 0.0f : a < 0.0f ? 0.0f : a > 1.0f ? 1.0f : a;
  return 1;
}

/* The same on binary16 values (HF_OUTPUT_MAX is above the largest half,
 * so colour and highlight are kept finite: within +-65504). */
HF_RULE_FN int hf_rule_guard_f16(uint16_t *o) {
  const uint16_t max = HF_RULE_F16_MAX_BITS, neg_max = 0x8000u | HF_RULE_F16_MAX_BITS;
  uint16_t c = o[0], h = o[1], a = o[2];
  uint16_t kc = hf_rule_key16(c), kh = hf_rule_key16(h), ka = hf_rule_key16(a);
  if ((kc >= hf_rule_key16(neg_max)) & (kc <= hf_rule_key16(max)) &
      (kh >= HF_RULE_K_NEG_ZERO) & (kh <= hf_rule_key16(max)) & (ka >= HF_RULE_K_NEG_ZERO) &
      (ka <= HF_RULE_K_ONE))
    return 0;
  int nan_c = (c & 0x7fffu) > 0x7c00u, nan_h = (h & 0x7fffu) > 0x7c00u;
  int nan_a = (a & 0x7fffu) > 0x7c00u;
  o[0] = nan_c ? (uint16_t)HF_RULE_F16_ONE_BITS
         : kc < hf_rule_key16(neg_max) ? neg_max
         : kc > hf_rule_key16(max) ? max : c;
  o[1] = nan_h || kh < HF_RULE_K_NEG_ZERO ? (uint16_t)0 : kh > hf_rule_key16(max) ? max : h;
  o[2] = nan_a || ka < HF_RULE_K_NEG_ZERO ? (uint16_t)0
         : ka > HF_RULE_K_ONE ? (uint16_t)HF_RULE_F16_ONE_BITS : a;
  return 1;
}

#endif /* HF_SAMPLE_RULE_H */
