/* The load tool's histogram (client/cli/load_hist.h) against exact
 * nearest-rank percentiles of the same samples: within 1/128 of the value,
 * never outside what was recorded, merge equal to recording everything in
 * one, and the same 34 KiB however many samples. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "load_hist.h"

static uint64_t rng = 88172645463325252ull;
static uint64_t next(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return rng;
}

static int cmp(const void *a, const void *b) {
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return x < y ? -1 : x > y;
}

/* Nearest rank: the ceil(p/100 n)-th smallest. */
static double exact(const uint64_t *sorted, size_t n, double p) {
  size_t rank = (size_t)ceil(p / 100.0 * (double)n);
  if (rank < 1) rank = 1;
  return (double)sorted[rank - 1];
}

static void check_against_exact(uint64_t (*gen)(void), size_t n) {
  static lh_hist h;
  lh_reset(&h);
  uint64_t *v = malloc(n * sizeof *v);
  assert_non_null(v);
  for (size_t i = 0; i < n; i++) {
    v[i] = gen();
    lh_record(&h, v[i]);
  }
  qsort(v, n, sizeof *v, cmp);
  assert_int_equal(h.n, n);
  assert_int_equal(h.min, v[0]);
  assert_int_equal(h.max, v[n - 1]);
  static const double ps[] = {0.1, 1, 10, 50, 90, 95, 99, 99.9, 99.99};
  for (size_t i = 0; i < sizeof ps / sizeof ps[0]; i++) {
    double want = exact(v, n, ps[i]), got = lh_percentile(&h, ps[i]);
    if (fabs(got - want) > want / 128 + 0.5)
      fail_msg("p%g: histogram %g, exact %g (more than 1/128 apart)", ps[i], got, want);
    assert_true(got >= (double)v[0] && got <= (double)v[n - 1]);
  }
  assert_true(lh_percentile(&h, 100) == (double)v[n - 1]);
  double mean = 0;
  for (size_t i = 0; i < n; i++) mean += (double)v[i];
  assert_true(fabs(lh_mean(&h) - mean / (double)n) < 1e-6 * mean / (double)n + 1e-9);
  free(v);
}

static uint64_t uniform_ms(void) { return 1000 + next() % 50000; }           /* 1..51 ms */
static uint64_t heavy_tail(void) {                                            /* log-uniform 1 us..1000 s */
  double u = (double)(next() >> 11) / 9007199254740992.0;
  return (uint64_t)pow(10.0, 9.0 * u);
}
static uint64_t small(void) { return next() % 200; }                          /* the exact range */

static void test_uniform(void **s) { (void)s; check_against_exact(uniform_ms, 100000); }
static void test_heavy_tail(void **s) { (void)s; check_against_exact(heavy_tail, 100000); }
static void test_small_exact(void **s) {
  (void)s;
  static lh_hist h;
  lh_reset(&h);
  for (uint64_t i = 0; i < LH_SUB; i++) lh_record(&h, i);
  /* Below 128 us every value has its own bucket: percentiles are exact. */
  for (int p = 1; p <= 100; p++) {
    double want = ceil(p / 100.0 * LH_SUB) - 1;
    assert_true(lh_percentile(&h, p) == want);
  }
  check_against_exact(small, 5000);
}

static void test_merge_and_bounds(void **s) {
  (void)s;
  static lh_hist a, b, all;
  lh_reset(&a);
  lh_reset(&b);
  lh_reset(&all);
  assert_true(lh_percentile(&a, 50) == 0);   /* empty */
  for (int i = 0; i < 20000; i++) {
    uint64_t v = heavy_tail();
    lh_record(i % 3 ? &a : &b, v);
    lh_record(&all, v);
  }
  lh_merge(&a, &b);
  assert_memory_equal(a.count, all.count, sizeof a.count);
  assert_int_equal(a.n, all.n);
  assert_int_equal(a.min, all.min);
  assert_int_equal(a.max, all.max);
  /* Values past 2^40 us land in the last bucket; the max stays exact. */
  lh_record(&a, UINT64_MAX);
  assert_true(lh_percentile(&a, 100) == (double)UINT64_MAX);
  /* Bounded: the size does not depend on the samples. */
  assert_true(sizeof(lh_hist) < 36 * 1024);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_uniform),
    cmocka_unit_test(test_heavy_tail),
    cmocka_unit_test(test_small_exact),
    cmocka_unit_test(test_merge_and_bounds),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
