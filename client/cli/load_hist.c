/* Log-linear histogram (load_hist.h). Bucket b < LH_SUB holds the value b;
 * above, each power of two [2^m, 2^(m+1)) is cut into LH_SUB buckets of
 * width 2^(m - LH_SUB_BITS). */
#include "load_hist.h"

#include <math.h>
#include <string.h>

void lh_reset(lh_hist *h) { memset(h, 0, sizeof *h); }

static unsigned index_of(uint64_t v) {
  if (v < LH_SUB) return (unsigned)v;
  if (v >> LH_MAX_BITS) return LH_BUCKETS - 1;
  unsigned m = 63u - (unsigned)__builtin_clzll(v);     /* 2^m <= v < 2^(m+1), m >= 7 */
  unsigned shift = m - LH_SUB_BITS;
  return (shift + 1) * LH_SUB + (unsigned)((v >> shift) - LH_SUB);
}

/* Lowest value and width of bucket i. */
static void bucket(unsigned i, double *lo, double *width) {
  if (i < LH_SUB) {
    *lo = i;
    *width = 1;
    return;
  }
  unsigned shift = i / LH_SUB - 1;
  *lo = (double)((uint64_t)(LH_SUB + i % LH_SUB) << shift);
  *width = (double)((uint64_t)1 << shift);
}

void lh_record(lh_hist *h, uint64_t us) {
  h->count[index_of(us)]++;
  if (!h->n || us < h->min) h->min = us;
  if (us > h->max) h->max = us;
  h->n++;
  h->sum += (double)us;
}

void lh_merge(lh_hist *dst, const lh_hist *src) {
  if (!src->n) return;
  for (unsigned i = 0; i < LH_BUCKETS; i++) dst->count[i] += src->count[i];
  if (!dst->n || src->min < dst->min) dst->min = src->min;
  if (src->max > dst->max) dst->max = src->max;
  dst->n += src->n;
  dst->sum += src->sum;
}

double lh_percentile(const lh_hist *h, double p) {
  if (!h->n) return 0;
  if (p >= 100) return (double)h->max;
  uint64_t rank = (uint64_t)ceil(p / 100.0 * (double)h->n);
  if (rank < 1) rank = 1;
  uint64_t seen = 0;
  for (unsigned i = 0; i < LH_BUCKETS; i++) {
    seen += h->count[i];
    if (seen >= rank) {
      double lo, w;
      bucket(i, &lo, &w);
      double mid = lo + (w - 1) / 2;
      /* Never outside what was recorded. */
      if (mid < (double)h->min) mid = (double)h->min;
      if (mid > (double)h->max) mid = (double)h->max;
      return mid;
    }
  }
  return (double)h->max;
}

double lh_mean(const lh_hist *h) { return h->n ? h->sum / (double)h->n : 0; }
