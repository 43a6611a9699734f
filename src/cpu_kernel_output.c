/* The Kernel architecture's output stage for the cpu backend: the values of
 * hf_kernel_output_rows (net_config.c, the reference), computed a row at a
 * time across the row's pixels so that the compiler vectorises every loop.
 *
 * Why not the reference: it works pixel by pixel, 49 scalar expf calls and
 * short dot products per pixel for the 7x7 kernel, several times the time
 * of this file's rows (docs/PERFORMANCE.md, HF_CPU_KERNEL_REF). Why not
 * oneDNN's softmax: it wants the logits dense, without the three
 * corrections between pixels (a strided tensor gets its reference
 * implementation), which costs a copy, and the weighted sums need one more
 * pass over its result.
 *
 * A row's logits are transposed into planes, one per tap, so that every
 * step below is the same operation on consecutive pixels: the maximum over
 * the taps inside the frame, the exponentials, their sum and the three
 * weighted sums of the per-pixel sums (planes too). Taps outside the frame
 * are not masked but skipped: a tap's offset (dx, dy) is outside for whole
 * rows (dy) or for the first or last |dx| pixels of a row (dx), so each
 * tap's loop runs over the pixels for which it is inside. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "backend.h"

/* The per-tap loops carry HF_CPU_CLONES (backend.h): in the SSE2 build they
 * ran four lanes wide (docs/PERFORMANCE.md, "The Kernel output stage's
 * vector width"). */

/* Plane pitch for a row of width pixels: a multiple of 16 floats that is
 * not a multiple of 512, so that the taps' planes of one pixel do not all
 * fall in the same cache sets (a power-of-two pitch made the transpose
 * several times slower). */
static size_t plane_pitch(int width) {
  size_t p = ((size_t)width + 15) & ~(size_t)15;
  return p % 512 ? p : p + 16;
}

/* The taps' logits, then the maximum, the denominator and six weighted
 * sums (three without mixing, but the scratch is the same). */
size_t hf_cpu_kernel_scratch(int width, int radius) {
  return plane_pitch(width) * ((size_t)hf_kernel_taps(radius) + 8);
}

void hf_cpu_kernel_sums_row(const float *px, int width, int stride, int spp, int ksums,
                            float *planes, size_t plane) {
  const int nk = hf_kernel_sums_floats(ksums);
  for (int x = 0; x < width; x++) {
    /* one pixel's sums by the reference's rule, then into the planes */
    float s[6];
    hf_input_view v = {px + (size_t)x * stride, 1, 1, 1, stride};
    hf_pixel_sums_rows(&v, spp, ksums, 0, 1, s);
    for (int k = 0; k < nk; k++) planes[k * plane + x] = s[k];
  }
}

void hf_cpu_kernel_sums(const hf_input_view *in, int spp, int ksums, int y0, int y1,
                        float *planes) {
  const size_t plane = (size_t)in->width * in->height;
  for (int y = y0; y < y1; y++)
    hf_cpu_kernel_sums_row(in->data + (size_t)y * in->pitch * in->stride, in->width, in->stride,
                           spp, ksums, planes + (size_t)y * in->width, plane);
}

/* e^x for x <= 0 (the logits less their maximum), 0 below -87 where e^x
 * nears the smallest normal float: Cephes' expf (S. L. Moshier, Cephes
 * Math Library 2.2, expf.c), e^x = 2^n e^r with |r| <= ln 2 / 2 and e^r a
 * degree-7 polynomial, within 2 ulp of expf. Written out so that it
 * vectorises; libm's expf is a call per value. The two selections are
 * bit masks, not conditional expressions: GCC if-converts those in the
 * plain build but not in the multiversioned clones below, which then ran
 * one value at a time. */
static inline float od_exp(float x) {
  union { int32_t i; float f; } in = {.f = x}, lo = {.f = -87.0f}, out;
  const int32_t below = -(int32_t)(x < -87.0f); /* all ones below -87, else 0 */
  in.i = (in.i & ~below) | (lo.i & below);      /* max(x, -87) */
  const float c = in.f;
  int n = (int)(c * 1.44269504088896341f - 0.5f); /* round(c / ln 2), c <= 0 */
  float fn = (float)n;
  float r = c - fn * 0.693359375f + fn * 2.12194440e-4f; /* c - n ln 2, in two parts */
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  union { int32_t i; float f; } s = {.i = (n + 127) << 23}; /* 2^n, n >= -126 */
  out.f = p * s.f;
  out.i &= ~below; /* 0 below -87 */
  return out.f;
}

/* Tap (dx, dy) for pixels x0..x1-1 of a row: its logits l less their
 * maximum m, exponentiated, summed into den and, weighted by the
 * neighbours' sums qn, qc, qh (already offset by the tap), into an, ac, ah.
 * Separate, with restrict parameters, so that GCC knows the planes apart
 * (it vectorises nothing while it has to check them at run time). */
HF_CPU_CLONES static void tap_accumulate(int x0, int x1, const float *restrict l, const float *restrict m,
                           const float *restrict qn, const float *restrict qc,
                           const float *restrict qh, float *restrict den, float *restrict an,
                           float *restrict ac, float *restrict ah) {
#pragma omp simd
  for (int x = x0; x < x1; x++) {
    float e = od_exp(l[x] - m[x]);
    den[x] += e;
    an[x] += e * qn[x];
    ac[x] += e * qc[x];
    ah[x] += e * qh[x];
  }
}

/* tap_accumulate for a kernel that mixes: also the estimate's sums qe
 * (count, colour, highlight planes, offset by the tap) into be[0..2]. */
HF_CPU_CLONES static void tap_accumulate_mixed(int x0, int x1, const float *restrict l,
                                 const float *restrict m, const float *restrict qn,
                                 const float *restrict qc, const float *restrict qh,
                                 const float *restrict en, const float *restrict ec,
                                 const float *restrict eh, float *restrict den,
                                 float *restrict an, float *restrict ac, float *restrict ah,
                                 float *restrict bn, float *restrict bc, float *restrict bh) {
#pragma omp simd
  for (int x = x0; x < x1; x++) {
    float e = od_exp(l[x] - m[x]);
    den[x] += e;
    an[x] += e * qn[x];
    ac[x] += e * qc[x];
    ah[x] += e * qh[x];
    bn[x] += e * en[x];
    bc[x] += e * ec[x];
    bh[x] += e * eh[x];
  }
}

HF_CPU_CLONES static void tap_max(int x0, int x1, const float *restrict l, float *restrict m) {
#pragma omp simd
  for (int x = x0; x < x1; x++) m[x] = l[x] > m[x] ? l[x] : m[x];
}

void hf_cpu_kernel_rows(int width, int height, int spp, int radius, int ksums,
                        const float *planes, const float *raw, int raw_pitch, int raw_stride,
                        int y0, int y1, float *out, float *scratch) {
  const int r = radius, side = 2 * r + 1, taps = side * side, w = width;
  const int mix = ksums == HF_KSUMS_MIXED;
  const size_t pitch = plane_pitch(width), plane = (size_t)width * height;
  float *logit = scratch, *m = logit + pitch * taps, *den = m + pitch;
  float *an = den + pitch, *ac = an + pitch, *ah = ac + pitch;
  float *bn = ah + pitch, *bc = bn + pitch, *bh = bc + pitch; /* the estimate's, mixing */
  for (int y = y0; y < y1; y++) {
    const float *row = raw + (size_t)y * raw_pitch * raw_stride;
    for (int x = 0; x < w; x++)
      for (int t = 0; t < taps; t++) logit[t * pitch + x] = row[(size_t)x * raw_stride + t];
    int dy0 = y - r < 0 ? -y : -r, dy1 = y + r >= height ? height - 1 - y : r;
    for (int x = 0; x < w; x++)
      m[x] = -INFINITY, den[x] = an[x] = ac[x] = ah[x] = bn[x] = bc[x] = bh[x] = 0;
    /* Pixel x sees tap dx when 0 <= x + dx < w: x from max(0, -dx) to
     * min(w, w - dx). */
    for (int dy = dy0; dy <= dy1; dy++)
      for (int dx = -r; dx <= r; dx++) {
        const float *l = logit + ((dy + r) * side + dx + r) * pitch;
        tap_max(dx < 0 ? -dx : 0, dx > 0 ? w - dx : w, l, m);
      }
    for (int dy = dy0; dy <= dy1; dy++)
      for (int dx = -r; dx <= r; dx++) {
        const float *l = logit + ((dy + r) * side + dx + r) * pitch;
        /* Pixel x's neighbour is pixel q + x of the planes; q may be -r.
         * Only x in x0..x1-1 is read, where q + x is inside the frame. */
        ptrdiff_t q = (ptrdiff_t)(y + dy) * width + dx;
        if (mix)
          tap_accumulate_mixed(dx < 0 ? -dx : 0, dx > 0 ? w - dx : w, l, m, planes + q,
                               planes + plane + q, planes + 2 * plane + q,
                               planes + 3 * plane + q, planes + 4 * plane + q,
                               planes + 5 * plane + q, den, an, ac, ah, bn, bc, bh);
        else
          tap_accumulate(dx < 0 ? -dx : 0, dx > 0 ? w - dx : w, l, m, planes + q,
                         planes + plane + q, planes + 2 * plane + q, den, an, ac, ah);
      }
    /* Mixing: the estimate's sums plus beta times the samples' less the
     * estimate's (hf_kernel_output_rows' order). */
    if (mix)
      for (int x = 0; x < w; x++) {
        const float mv = row[(size_t)x * raw_stride + taps + 3];
        const float beta = 1.0f / (1.0f + expf(-HF_KERNEL_MIX_GAIN * mv));
        an[x] = bn[x] + beta * (an[x] - bn[x]);
        ac[x] = bc[x] + beta * (ac[x] - bc[x]);
        ah[x] = bh[x] + beta * (ah[x] - bh[x]);
      }
    /* The weights are e / den: N = an / den, and C / N = ac / an. */
    for (int x = 0; x < w; x++) {
      const float *c = row + (size_t)x * raw_stride + taps;
      float n = an[x] / den[x];
      int ok = n > 1e-12f;
      float h = (ok ? ah[x] / an[x] : 0.0f) + c[1], a = n / (float)spp + c[2];
      float *o = out + ((size_t)y * width + x) * 3;
      o[HF_OUT_COLOR] = (ok ? ac[x] / an[x] : 1.0f) + c[0];
      o[HF_OUT_HIGHLIGHT] = h > 0.0f ? h : 0.0f;
      o[HF_OUT_ALPHA] = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
    }
  }
}
