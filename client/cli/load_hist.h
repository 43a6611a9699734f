/* A streaming latency histogram of bounded size: log-linear buckets (HDR
 * histogram layout), 128 linear sub-buckets per power of two, so any value
 * is kept within 1/128 (0.8 %) of itself, from 1 us to 2^40 us, in 34 KiB
 * whatever the number of samples.
 *
 * Our own because the reference implementation, HdrHistogram_c, is not
 * packaged for Debian 12 (only its Java and Go ports are), and the layout is
 * a few lines of index arithmetic. Values are microseconds. */
#ifndef HF_LOAD_HIST_H
#define HF_LOAD_HIST_H

#include <stdint.h>

#define LH_SUB_BITS 7
#define LH_SUB (1u << LH_SUB_BITS)
#define LH_MAX_BITS 40
#define LH_BUCKETS ((LH_MAX_BITS - LH_SUB_BITS + 1) * LH_SUB)

typedef struct lh_hist {
  uint64_t count[LH_BUCKETS];
  uint64_t n;
  uint64_t min, max;       /* exact, us */
  double sum;              /* us, for the mean */
} lh_hist;

void lh_reset(lh_hist *h);
/* Records one value in us (values past 2^40 us count in the last bucket). */
void lh_record(lh_hist *h, uint64_t us);
/* dst += src. */
void lh_merge(lh_hist *dst, const lh_hist *src);
/* The value at percentile p (0..100) by nearest rank: the smallest recorded
 * value v such that at least p % of the values are <= v, within 1/128 of
 * it (the middle of its bucket; the exact max for p = 100). 0 when empty. */
double lh_percentile(const lh_hist *h, double p);
double lh_mean(const lh_hist *h);

#endif
