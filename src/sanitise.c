/* Out-of-contract input and output values (protocol/FEATURES.md,
 * "Out-of-contract values"). hf_model_run applies this to every frame of
 * every backend, so what a bad sample does to a result is defined once:
 *
 *   - a sample with a non-finite feature (NaN, +-Inf), or with alpha <= 0
 *     and not all zero (alpha negative, or another feature non-zero), is
 *     uncovered: all six features 0;
 *   - a finite feature outside its range is clamped into it: color and
 *     highlight [0, HF_FEATURE_LIGHT_MAX], alpha (0, 1], depth [0, 1],
 *     tangent.x and tangent.y [-1, 1];
 *   - an output value outside its range is clamped into it, NaN replaced by
 *     the channel's neutral value (color 1, highlight 0, alpha 0).
 *
 * The bounds keep every backend's arithmetic finite: HF_FEATURE_LIGHT_MAX
 * (64) times 216 first-layer taps of weights below 1 stays under binary16's
 * 65504, and the later layers scale with it. Checking is one pass over the
 * input that only reads; the input is copied and changed only when a sample
 * needs it. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"
#include "sample_rule.h"

/* ---- frames -------------------------------------------------------------------- */

/* The whole-frame check runs before every backend pass (but the cudnn
 * backend's on frames in registered memory, which it checks on the device,
 * sample_rule.h), also in front of a GPU's upload of a staged frame, so it
 * has to run at about the speed of a copy of the frame (`hairfilter bench
 * --input-check` measures both; docs/PERFORMANCE.md). Scalar code per
 * sample (hf_rule_ok_f32) does not vectorize: the six features interleave.
 * These loops use GCC/Clang vector extensions on groups of four samples
 * (24 values): six vectors of four floats, or three of eight halves, whose
 * lanes hold the features in a fixed pattern. The predicate is
 * hf_rule_ok_f32's, rewritten per lane: every value in its range (alpha's
 * lower bound 0 included), and a non-zero value only in a sample whose
 * alpha is > 0. */
typedef float v4f __attribute__((vector_size(16)));
typedef int32_t v4i __attribute__((vector_size(16)));
typedef int16_t v8s __attribute__((vector_size(16)));

/* Number of in-contract groups of four samples from in, at most groups. */
static size_t good_groups_f32(const float *in, size_t groups) {
  const float m = HF_FEATURE_LIGHT_MAX;
  /* Lanes: c0 h0 a0 d0 | x0 y0 c1 h1 | a1 d1 x1 y1 | c2 h2 a2 d2 | x2 y2 c3 h3 | a3 d3 x3 y3 */
  const v4f lo[6] = {{0, 0, 0, 0}, {-1, -1, 0, 0}, {0, 0, -1, -1},
                     {0, 0, 0, 0}, {-1, -1, 0, 0}, {0, 0, -1, -1}};
  const v4f hi[6] = {{m, m, 1, 1}, {1, 1, m, m}, {1, 1, 1, 1},
                     {m, m, 1, 1}, {1, 1, m, m}, {1, 1, 1, 1}};
  const v4f zero = {0, 0, 0, 0};
  size_t g;
  for (g = 0; g < groups; g++) {
    v4f v[6];
    memcpy(v, in + g * 4 * HF_FEATURES_PER_SAMPLE, sizeof v);
    float a0 = v[0][2], a1 = v[2][0], a2 = v[3][2], a3 = v[5][0];
    const v4f alpha[6] = {{a0, a0, a0, a0}, {a0, a0, a1, a1}, {a1, a1, a1, a1},
                          {a2, a2, a2, a2}, {a2, a2, a3, a3}, {a3, a3, a3, a3}};
    v4i bad = {0, 0, 0, 0};
    for (int i = 0; i < 6; i++)
      bad |= ~((v[i] >= lo[i]) & (v[i] <= hi[i])) | ((v[i] != zero) & ~(alpha[i] > zero));
    if (bad[0] | bad[1] | bad[2] | bad[3]) break;
  }
  return g;
}

static size_t good_groups_f16(const uint16_t *in, size_t groups) {
  /* hf_rule_key16 less 0x8000, as signed lanes: SSE2 compares signed 16-bit
   * lanes in one instruction, unsigned ones in three. */
  const int16_t Z = (int16_t)((int)HF_RULE_K_NEG_ZERO - 0x8000),
                N = (int16_t)((int)HF_RULE_K_NEG_ONE - 0x8000),
                L = (int16_t)((int)HF_RULE_K_LIGHT - 0x8000),
                O = (int16_t)((int)HF_RULE_K_ONE - 0x8000);
  /* Lanes: c0 h0 a0 d0 x0 y0 c1 h1 | a1 d1 x1 y1 c2 h2 a2 d2 | x2 y2 c3 h3 a3 d3 x3 y3 */
  const v8s lo[3] = {{Z, Z, Z, Z, N, N, Z, Z}, {Z, Z, N, N, Z, Z, Z, Z}, {N, N, Z, Z, Z, Z, N, N}};
  const v8s hi[3] = {{L, L, O, O, O, O, L, L}, {O, O, O, O, L, L, O, O}, {O, O, L, L, O, O, O, O}};
  const v8s magn = {0x7fff, 0x7fff, 0x7fff, 0x7fff, 0x7fff, 0x7fff, 0x7fff, 0x7fff};
  const v8s zero = {0, 0, 0, 0, 0, 0, 0, 0};
  size_t g;
  for (g = 0; g < groups; g++) {
    v8s v[3];
    memcpy(v, in + g * 4 * HF_FEATURES_PER_SAMPLE, sizeof v);
    int16_t a0 = v[0][2], a1 = v[1][0], a2 = v[1][6], a3 = v[2][4];
    const v8s alpha[3] = {{a0, a0, a0, a0, a0, a0, a1, a1}, {a1, a1, a1, a1, a2, a2, a2, a2},
                          {a2, a2, a3, a3, a3, a3, a3, a3}};
    v8s bad = zero;
    for (int i = 0; i < 3; i++) {
      /* Per lane: negatives (sign set) become -magnitude - 1, so -0 sorts
       * just below +0; NaNs land outside [key(-Inf), key(+Inf)]. */
      v8s k = v[i] ^ ((v[i] >> 15) & magn);
      /* Covered: alpha's bits as a signed number > 0, i.e. alpha > +0 (a
       * NaN alpha fails its own range check). */
      bad |= ~((k >= lo[i]) & (k <= hi[i])) | (((v[i] & magn) != zero) & ~(alpha[i] > zero));
    }
    if (__builtin_memcmp(&bad, &zero, sizeof bad)) break;
  }
  return g;
}

/* The first out-of-contract sample at or after i, or n: groups of four by
 * vector, the rest (and the group that stopped the vector loop) by ok_*. */
#define NEXT_BAD(NAME, T, OK, GROUPS)                                            \
  static size_t NAME(const T *in, size_t i, size_t n) {                          \
    for (;;) {                                                                   \
      for (; i < n && (i % 4 || n - i < 4); i++)                                 \
        if (!OK(in + i * HF_FEATURES_PER_SAMPLE)) return i;                      \
      if (i >= n) return n;                                                      \
      i += 4 * GROUPS(in + i * HF_FEATURES_PER_SAMPLE, (n - i) / 4);             \
      if (n - i < 4) continue;                                                   \
      for (size_t end = i + 4; i < end; i++)                                     \
        if (!OK(in + i * HF_FEATURES_PER_SAMPLE)) return i;                      \
    }                                                                            \
  }
NEXT_BAD(next_bad_f32, float, hf_rule_ok_f32, good_groups_f32)
NEXT_BAD(next_bad_f16, uint16_t, hf_rule_ok_f16, good_groups_f16)

static void report_init(hf_input_report *r) {
  memset(r, 0, sizeof *r);
  r->x = r->y = r->sample = r->feature = -1;
}

/* The rule over samples [i, n) of a frame of dtype, counted into r (the
 * first bad sample located when r has none yet). fix: each bad sample is
 * rewritten in place; wide, when not NULL, is the float32 copy of an f16
 * in, whose bad samples get the fixed values instead. */
static void scan_range(void *in, hf_dtype dtype, int width, int spp, size_t i, size_t n, int fix,
                       float *wide, hf_input_report *r) {
  for (;; i++) {
    i = dtype == HF_F32 ? next_bad_f32(in, i, n) : next_bad_f16(in, i, n);
    if (i >= n) break;
    float v[HF_FEATURES_PER_SAMPLE], before[HF_FEATURES_PER_SAMPLE];
    float *s32 = (float *)in + i * HF_FEATURES_PER_SAMPLE;
    uint16_t *s16 = (uint16_t *)in + i * HF_FEATURES_PER_SAMPLE;
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++)
      before[f] = v[f] = dtype == HF_F32 ? s32[f] : hf_f16_to_f32(s16[f]);
    int kind = 0, feature = 0;
    /* Every bound is exact in binary16, so fixing through float32 is exact
     * (and the fixed half widens back to the fixed float). */
    hf_rule_fix_f32(v, &kind, &feature);
    if (wide)
      memcpy(wide + i * HF_FEATURES_PER_SAMPLE, v, sizeof v);
    else if (fix)
      for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++) {
        if (dtype == HF_F32) s32[f] = v[f];
        else s16[f] = hf_f32_to_f16(v[f]);
      }
    if (!r->samples++) {
      size_t px = i / (size_t)spp;
      r->x = (int)(px % (size_t)width);
      r->y = (int)(px / (size_t)width);
      r->sample = (int)(i % (size_t)spp);
      r->feature = feature;
      r->kind = kind;
      r->value = before[feature];
    }
  }
}

static void scan(void *in, hf_dtype dtype, int width, int height, int spp, int fix,
                 hf_input_report *r) {
  report_init(r);
  scan_range(in, dtype, width, spp, 0, (size_t)width * height * spp, fix, NULL, r);
}

void hf_features_check(const void *in, hf_dtype dtype, int width, int height, int spp,
                       hf_input_report *report) {
  scan((void *)in, dtype, width, height, spp, 0, report);
}

void hf_features_sanitise(void *in, hf_dtype dtype, int width, int height, int spp,
                          hf_input_report *report) {
  scan(in, dtype, width, height, spp, 1, report);
}

void hf_features_report_counted(const void *in, hf_dtype dtype, int width, int spp,
                                uint64_t samples, size_t first, hf_input_report *report) {
  report_init(report);
  if (!samples) return;
  /* The one sample read again, unchanged, for what the report says of it. */
  scan_range((void *)in, dtype, width, spp, first, first + 1, 0, NULL, report);
  report->samples = samples;
}

/* ---- binary16 frames widened for a float32 backend ------------------------- */

/* Samples per chunk of the widening pass: 2048 samples are 24 KiB of
 * halves and 48 KiB of floats, so the halves stay in L1 from their
 * conversion to their check and statistics. Chunks are whole pixels, a
 * multiple of 4 of them (the check's groups of four samples stay whole). */
#define WIDEN_CHUNK_SAMPLES 2048
/* Samples per thread below which a thread costs more than it saves (the
 * conversion's threshold, 2^19 values, in samples). */
#define WIDEN_PER_THREAD (((size_t)1 << 19) / HF_FEATURES_PER_SAMPLE)
/* From this many floats out (1 MiB) the frame does not stay in the caches:
 * written with non-temporal stores (hf_f16_to_f32_stream). */
#define WIDEN_STREAM_MIN ((size_t)1 << 18)

/* A worker's report and statistics, made part by part (hf_scan_part). */
void hf_scan_part_init(hf_scan_part *s, hf_input_stats_acc *acc) {
  report_init(&s->report);
  s->acc = acc;
  if (acc) hf_input_stats_acc_init(acc);
}

/* Adds r (of samples scanned in a frame width pixels wide) to into: the
 * counts summed, the first bad sample the lowest of the two. */
static void report_merge(hf_input_report *into, const hf_input_report *r, int width, int spp) {
  if (!r->samples) return;
  if (into->samples) {
    size_t a = ((size_t)into->y * width + into->x) * spp + into->sample;
    size_t b = ((size_t)r->y * width + r->x) * spp + r->sample;
    if (a < b) {
      into->samples += r->samples;
      return;
    }
  }
  uint64_t total = into->samples + r->samples;
  uint64_t outputs = into->outputs;
  *into = *r;
  into->samples = total;
  into->outputs = outputs;
}

void hf_scan_part_add(hf_scan_part *s, const void *in, hf_dtype dtype, int width, int spp,
                      size_t p0, size_t p1) {
  hf_input_report r;
  report_init(&r);
  scan_range((void *)in, dtype, width, spp, p0 * spp, p1 * spp, 0, NULL, &r);
  report_merge(&s->report, &r, width, spp);
  if (s->acc) hf_input_stats_add(s->acc, in, dtype, spp, p0, p1);
}

void hf_scan_parts_finish(hf_scan_part *parts, int nparts, int width, int height, int spp,
                          hf_input_report *report, hf_input_stats *stats) {
  report_init(report);
  for (int k = 0; k < nparts; k++) report_merge(report, &parts[k].report, width, spp);
  if (stats) {
    for (int k = 1; k < nparts; k++) hf_input_stats_merge(parts[0].acc, parts[k].acc);
    hf_input_stats_finish(parts[0].acc, width, height, spp, stats);
  }
}

typedef struct widen_run {
  const void *in;               /* [pixels][spp * 6] of dtype */
  hf_dtype dtype;               /* HF_F32 only without out */
  float *out;
  int width, spp, stream;
  hf_scan_part part[HF_PARALLEL_MAX];
} widen_run;

/* Pixels [b, e): widened (when there is an out), checked and fixed,
 * counted. */
static void widen_chunk(void *arg, int worker, size_t b, size_t e) {
  widen_run *w = arg;
  hf_scan_part *part = &w->part[worker];
  if (!w->out) {
    /* Only read: in is the caller's and stays as it is. */
    hf_scan_part_add(part, w->in, w->dtype, w->width, w->spp, b, e);
    return;
  }
  const uint16_t *in = w->in;
  const size_t f = HF_FEATURES_PER_SAMPLE, s0 = b * w->spp, s1 = e * w->spp;
  if (w->stream) hf_f16_to_f32_stream(in + s0 * f, w->out + s0 * f, (s1 - s0) * f);
  else hf_f16_to_f32_serial(in + s0 * f, w->out + s0 * f, (s1 - s0) * f);
  /* A worker's chunks come in increasing order: its first bad sample is
   * the first one scan_range finds. */
  scan_range((void *)in, HF_F16, w->width, w->spp, s0, s1, 1, w->out, &part->report);
  if (part->acc) hf_input_stats_add(part->acc, in, HF_F16, w->spp, b, e);
}

/* A pass over a frame of width x height pixels of spp samples in chunks
 * of whole pixels (a multiple of 4 of them, about WIDEN_CHUNK_SAMPLES
 * samples: a chunk stays in the cache while fn works on it) split between
 * threads, fn(ctx, worker, b, e) adding its pixels' report and statistics
 * to part[worker]; the parts are merged into report and stats at the end.
 * The number of workers, or HF_ENOMEM when the statistics' counts cannot
 * be allocated (nothing run). */
static int scan_in_chunks(int width, int height, int spp, hf_scan_part part[HF_PARALLEL_MAX],
                          hf_chunk_fn fn, void *ctx, hf_input_report *report,
                          hf_input_stats *stats) {
  size_t px = (size_t)width * height;
  size_t chunk = (WIDEN_CHUNK_SAMPLES / spp + 3) & ~(size_t)3;
  size_t per_thread = (WIDEN_PER_THREAD + spp - 1) / spp;
  int nw = hf_parallel_workers(px, per_thread);
  hf_input_stats_acc *acc = NULL;
  /* A worker's own counts: no sharing of cache lines between threads. */
  if (stats && !(acc = malloc((size_t)nw * sizeof *acc))) return HF_ENOMEM;
  for (int k = 0; k < HF_PARALLEL_MAX; k++) hf_scan_part_init(&part[k], k < nw && acc ? &acc[k] : NULL);
  nw = hf_parallel_chunks(px, chunk, per_thread, fn, ctx);
  if (nw < 1) nw = 1; /* an empty frame: worker 0's empty counts */
  hf_scan_parts_finish(part, nw, width, height, spp, report, stats);
  free(acc);
  return nw;
}

/* The pass of hf_features_widen and hf_features_scan: a frame of dtype
 * (HF_F16 when out is not NULL), each worker with its own report and
 * statistics. */
static int widen_or_scan(const void *in, hf_dtype dtype, float *out, int width, int height,
                         int spp, hf_input_report *report, hf_input_stats *stats) {
  size_t n = (size_t)width * height * spp;
  widen_run w = {.in = in, .dtype = dtype, .out = out, .width = width, .spp = spp,
                 .stream = n * HF_FEATURES_PER_SAMPLE >= WIDEN_STREAM_MIN};
  int nw = scan_in_chunks(width, height, spp, w.part, widen_chunk, &w, report, stats);
  return nw < 0 ? nw : HF_OK;
}

typedef struct copy_run {
  const uint8_t *in;
  uint8_t *out;
  hf_dtype dtype;
  int width, spp;
  hf_scan_part part[HF_PARALLEL_MAX];
} copy_run;

/* Pixels [b, e): copied, then the rule applied to the copy while it is
 * still in the cache. */
static void copy_chunk(void *arg, int worker, size_t b, size_t e) {
  copy_run *c = arg;
  const size_t px_bytes = (size_t)c->spp * HF_FEATURES_PER_SAMPLE * (c->dtype == HF_F16 ? 2 : 4);
  memcpy(c->out + b * px_bytes, c->in + b * px_bytes, (e - b) * px_bytes);
  scan_range(c->out, c->dtype, c->width, c->spp, b * c->spp, e * c->spp, 1, NULL,
             &c->part[worker].report);
}

int hf_features_copy_sanitised(const void *in, void *out, hf_dtype dtype, int width, int height,
                               int spp, hf_input_report *report) {
  copy_run c = {.in = in, .out = out, .dtype = dtype, .width = width, .spp = spp};
  int nw = scan_in_chunks(width, height, spp, c.part, copy_chunk, &c, report, NULL);
  return nw < 0 ? nw : HF_OK;
}

int hf_features_widen(const uint16_t *in, float *out, int width, int height, int spp,
                      hf_input_report *report, hf_input_stats *stats) {
  return widen_or_scan(in, HF_F16, out, width, height, spp, report, stats);
}

int hf_features_scan(const void *in, hf_dtype dtype, int width, int height, int spp,
                     hf_input_report *report, hf_input_stats *stats) {
  return widen_or_scan(in, dtype, NULL, width, height, spp, report, stats);
}

/* ---- the estimate, interleaved after the samples ------------------------------------ */

/* The estimate's rule on one pixel's colour, highlight, alpha: 0 when it
 * was in contract, else the kind, with the first feature at fault. */
static int fix_estimate(float e[HF_ESTIMATE_CHANNELS], int *feature) {
  const float m = HF_FEATURE_LIGHT_MAX;
  float c = e[0], h = e[1], a = e[2];
  if ((a > 0.0f) & (a <= 1.0f) & (c >= 0.0f) & (c <= m) & (h >= 0.0f) & (h <= m)) return 0;
  if ((c == 0.0f) & (h == 0.0f) & (a == 0.0f)) return 0;  /* no hair: all zero */
  for (int f = 0; f < HF_ESTIMATE_CHANNELS; f++)
    if (!isfinite(e[f])) {
      *feature = f;
      memset(e, 0, HF_ESTIMATE_CHANNELS * sizeof *e);
      return HF_SANITISED_NONFINITE;
    }
  if (a <= 0.0f) {
    *feature = 2;
    memset(e, 0, HF_ESTIMATE_CHANNELS * sizeof *e);
    return HF_SANITISED_UNCOVERED;
  }
  *feature = c < 0.0f || c > m ? 0 : h < 0.0f || h > m ? 1 : 2;
  e[0] = fminf(fmaxf(c, 0.0f), m);
  e[1] = fminf(fmaxf(h, 0.0f), m);
  e[2] = fminf(a, 1.0f);
  return HF_SANITISED_CLAMPED;
}

/* One worker's estimates changed in hf_features_interleave, and the first
 * of them (a worker's chunks come in increasing order). */
typedef struct interleave_part {
  uint64_t changed;
  size_t first;
  int feature, kind;
  float value;
} interleave_part;

typedef struct interleave_run {
  const uint8_t *samples, *est;
  uint8_t *out;
  hf_dtype dtype;
  int width, spp;
  size_t esz, ns, stride;       /* bytes per value; values per pixel: samples', all */
  hf_scan_part scan[HF_PARALLEL_MAX];   /* each worker's samples' report and statistics */
  interleave_part part[HF_PARALLEL_MAX];
} interleave_run;

/* Pixels interleave_chunk counts into the statistics at a time, from the
 * copy it has just written (still in the cache). */
#define INTERLEAVE_STATS_PIXELS 64

/* Pixels [b, e): each pixel's samples copied into out (the one read of
 * them from the input) and checked there, its estimate read once into a
 * local and written after them under the estimate's rule; the statistics
 * counted from out. What is checked is what the backend runs though
 * another process may write the input meanwhile (a shared-memory segment:
 * hf_model_reads_input_once). The check reads the pixel just written, in
 * L1: no second pass over the frame, no stage to copy through. */
static void interleave_chunk(void *arg, int worker, size_t b, size_t e) {
  interleave_run *r = arg;
  interleave_part *part = &r->part[worker];
  hf_scan_part *scan = &r->scan[worker];
  const size_t esz = r->esz, ns = r->ns, spp = (size_t)r->spp;
  for (size_t q = b; q < e; q += INTERLEAVE_STATS_PIXELS) {
    const size_t qe = e - q < INTERLEAVE_STATS_PIXELS ? e : q + INTERLEAVE_STATS_PIXELS;
    for (size_t p = q; p < qe; p++) {
      uint8_t *d = r->out + p * r->stride * esz;
      memcpy(d, r->samples + p * ns * esz, ns * esz);
      size_t bad = r->dtype == HF_F32 ? next_bad_f32((const float *)d, 0, spp)
                                      : next_bad_f16((const uint16_t *)d, 0, spp);
      if (bad < spp) {
        /* Out of contract (rare): counted, and located as the frame's. */
        hf_input_report one;
        report_init(&one);
        scan_range(d, r->dtype, 1, r->spp, bad, spp, 0, NULL, &one);
        one.x = (int)(p % (size_t)r->width);
        one.y = (int)(p / (size_t)r->width);
        report_merge(&scan->report, &one, r->width, r->spp);
      }
      uint8_t raw[HF_ESTIMATE_CHANNELS * sizeof(float)];
      memcpy(raw, r->est + p * HF_ESTIMATE_CHANNELS * esz, HF_ESTIMATE_CHANNELS * esz);
      uint8_t *de = d + ns * esz;
      float v[HF_ESTIMATE_CHANNELS], before[HF_ESTIMATE_CHANNELS];
      for (int f = 0; f < HF_ESTIMATE_CHANNELS; f++) {
        if (r->dtype == HF_F32) {
          memcpy(&v[f], raw + f * sizeof(float), sizeof(float));
        } else {
          uint16_t h;
          memcpy(&h, raw + f * sizeof h, sizeof h);
          v[f] = hf_f16_to_f32(h);
        }
      }
      memcpy(before, v, sizeof v);
      int feature = 0, kind = fix_estimate(v, &feature);
      if (!kind) {
        memcpy(de, raw, HF_ESTIMATE_CHANNELS * esz);
        continue;
      }
      /* Every bound is exact in binary16: a fixed half is the fixed float. */
      if (r->dtype == HF_F32)
        memcpy(de, v, sizeof v);
      else
        for (int f = 0; f < HF_ESTIMATE_CHANNELS; f++) ((uint16_t *)de)[f] = hf_f32_to_f16(v[f]);
      if (!part->changed++) {
        part->first = p;
        part->feature = feature;
        part->kind = kind;
        part->value = before[feature];
      }
    }
    if (scan->acc)
      hf_input_stats_add_strided(scan->acc, r->out + q * r->stride * esz, r->dtype, r->spp,
                                 r->stride, 0, qe - q);
  }
}

int hf_features_interleave(const void *in, hf_dtype dtype, int width, int height, int spp,
                           void *out, hf_input_report *report, hf_input_stats *stats) {
  const size_t esz = dtype == HF_F16 ? 2 : 4, px = (size_t)width * height;
  const size_t ns = (size_t)spp * HF_FEATURES_PER_SAMPLE;
  interleave_run r = {.samples = in, .est = (const uint8_t *)in + px * ns * esz, .out = out,
                      .dtype = dtype, .width = width, .spp = spp, .esz = esz, .ns = ns,
                      .stride = ns + HF_ESTIMATE_CHANNELS};
  /* Chunks as hf_features_widen's, each read from the input once. */
  int nw = scan_in_chunks(width, height, spp, r.scan, interleave_chunk, &r, report, stats);
  if (nw < 0) return nw;
  /* Samples out of contract (rare): fixed in the copy, pixel by pixel. */
  for (size_t p = 0; report->samples && p < px; p++) {
    hf_input_report one;
    hf_features_sanitise(r.out + p * r.stride * esz, dtype, 1, 1, spp, &one);
  }
  /* The first change in memory order: the samples' block comes first, then
   * the lowest pixel among the workers' first estimates. */
  const interleave_part *first = NULL;
  uint64_t changed = 0;
  for (int k = 0; k < nw; k++) {
    changed += r.part[k].changed;
    if (r.part[k].changed && (!first || r.part[k].first < first->first)) first = &r.part[k];
  }
  if (first && !report->samples) {
    report->x = (int)(first->first % (size_t)width);
    report->y = (int)(first->first / (size_t)width);
    report->sample = HF_REPORT_ESTIMATE;
    report->feature = first->feature;
    report->kind = first->kind;
    report->value = first->value;
  }
  report->samples += changed;
  return HF_OK;
}

/* ---- outputs ---------------------------------------------------------------------- */

/* Pixels [p0, p1) of out kept in range (sample_rule.h's guard, shared with
 * the cudnn backend's device pass); the number changed. */
static uint64_t guard_range(void *out, hf_dtype dtype, size_t p0, size_t p1) {
  uint64_t fixed = 0;
  if (dtype == HF_F32)
    for (size_t p = p0; p < p1; p++) fixed += hf_rule_guard_f32((float *)out + p * HF_OUT_CHANNELS);
  else
    for (size_t p = p0; p < p1; p++)
      fixed += hf_rule_guard_f16((uint16_t *)out + p * HF_OUT_CHANNELS);
  return fixed;
}

uint64_t hf_output_guard_serial(void *out, hf_dtype dtype, size_t pixels) {
  return guard_range(out, dtype, 0, pixels);
}

/* Pixels per chunk of the threaded guard (48 KiB of floats), and per
 * thread below which a thread costs more than it saves (the conversion's
 * threshold, 2^19 values). */
#define GUARD_CHUNK 4096
#define GUARD_PER_THREAD (((size_t)1 << 19) / HF_OUT_CHANNELS)

typedef struct guard_run {
  void *out;
  hf_dtype dtype;
  uint64_t fixed[HF_PARALLEL_MAX];
} guard_run;

static void guard_chunk(void *arg, int worker, size_t b, size_t e) {
  guard_run *g = arg;
  g->fixed[worker] += guard_range(g->out, g->dtype, b, e);
}

uint64_t hf_output_guard(void *out, hf_dtype dtype, size_t pixels) {
  guard_run g = {.out = out, .dtype = dtype};
  int nw = hf_parallel_chunks(pixels, GUARD_CHUNK, GUARD_PER_THREAD, guard_chunk, &g);
  uint64_t fixed = 0;
  for (int k = 0; k < nw; k++) fixed += g.fixed[k];
  return fixed;
}
