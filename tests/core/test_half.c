/* The f16 <-> f32 array conversions (src/half.c) against the scalar
 * reference, bit for bit: every one of the 65,536 half patterns, NaNs
 * included; floats around every half (midpoints, their neighbours),
 * subnormals, overflow, infinities and NaN payloads, and a stride through
 * all 2^32 float patterns; the scalar reference against the nearest half
 * computed in double; frames large enough to be split between threads;
 * both the vector and the scalar implementation; the chunks that threads
 * take (hf_parallel_chunks): every item exactly once, each worker's chunks
 * in order. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "hfcore.h"

static uint32_t bits(float f) {
  uint32_t x;
  memcpy(&x, &f, 4);
  return x;
}

static float from_bits(uint32_t x) {
  float f;
  memcpy(&f, &x, 4);
  return f;
}

/* Runs body once with the vector code (where the processor has it) and
 * once with the scalar code. */
#define BOTH_IMPLS(body)                         \
  for (int simd_ = 1; simd_ >= 0; simd_--) {     \
    int had_ = hf_half_use_simd(simd_);          \
    body;                                        \
    hf_half_use_simd(had_);                      \
  }

static void check_f16_to_f32(const uint16_t *src, size_t n) {
  float *got = malloc(n * sizeof *got);
  assert_non_null(got);
  memset(got, 0x5a, n * sizeof *got); /* a value left unwritten shows */
  hf_f16_to_f32_array(src, got, n);
  for (size_t i = 0; i < n; i++)
    if (bits(got[i]) != bits(hf_f16_to_f32(src[i])))
      fail_msg("%s: value %zu of %zu, half 0x%04x -> 0x%08x, want 0x%08x", hf_half_impl(), i, n,
               src[i], bits(got[i]), bits(hf_f16_to_f32(src[i])));
  if (n <= 0x10000) { /* the single-thread entry point, on the smaller sets */
    memset(got, 0, n * sizeof *got);
    hf_f16_to_f32_serial(src, got, n);
    for (size_t i = 0; i < n; i++) assert_int_equal(bits(got[i]), bits(hf_f16_to_f32(src[i])));
  }
  free(got);
}

static void check_f32_to_f16(const float *src, size_t n) {
  uint16_t *got = malloc(n * sizeof *got);
  assert_non_null(got);
  memset(got, 0x5a, n * sizeof *got);
  hf_f32_to_f16_array(src, got, n);
  for (size_t i = 0; i < n; i++)
    if (got[i] != hf_f32_to_f16(src[i]))
      fail_msg("%s: value %zu of %zu, float 0x%08x (%a) -> 0x%04x, want 0x%04x", hf_half_impl(),
               i, n, bits(src[i]), (double)src[i], got[i], hf_f32_to_f16(src[i]));
  if (n <= 0x10000) {
    memset(got, 0, n * sizeof *got);
    hf_f32_to_f16_serial(src, got, n);
    for (size_t i = 0; i < n; i++) assert_int_equal(got[i], hf_f32_to_f16(src[i]));
  }
  free(got);
}

/* Every half pattern, at every tail length the vector loop can leave. */
static void test_every_half(void **state) {
  (void)state;
  uint16_t *all = malloc(0x10000 * sizeof *all);
  assert_non_null(all);
  for (uint32_t h = 0; h < 0x10000; h++) all[h] = (uint16_t)h;
  BOTH_IMPLS({
    for (size_t cut = 0; cut < 17; cut++) check_f16_to_f32(all + cut, 0x10000 - cut);
  });
  free(all);
}

/* The reference itself: finite halves widen exactly (and narrow back
 * unchanged); a NaN keeps its sign and payload and is made quiet. */
static void test_reference_values(void **state) {
  (void)state;
  for (uint32_t h = 0; h < 0x10000; h++) {
    float f = hf_f16_to_f32((uint16_t)h);
    uint32_t e = (h >> 10) & 0x1f, m = h & 0x3ff, s = (h >> 15) & 1;
    if (e == 31 && m) {
      assert_true(isnan(f));
      assert_int_equal(bits(f), (s << 31) | 0x7fc00000u | (m << 13));
      assert_int_equal(hf_f32_to_f16(f), h | 0x200);
      continue;
    }
    double want = e == 0    ? ldexp((double)m, -24)
                  : e == 31 ? INFINITY
                            : ldexp(1024.0 + m, (int)e - 25);
    assert_true((double)f == (s ? -want : want));
    assert_int_equal(hf_f32_to_f16(f), h);
  }
}

/* The nearest half of x, ties to even, computed in double from the
 * definition (|x| below 65520, the first value that rounds to infinity). */
static uint16_t nearest_half(float x) {
  uint16_t sign = signbit(x) ? 0x8000 : 0;
  double a = fabs((double)x);
  if (a >= 65520.0) return sign | 0x7c00;
  /* Halves are uniform with spacing 2^-24 below 2^-14 and 2^(e-10) in
   * [2^e, 2^(e+1)). */
  int e;
  frexp(a, &e); /* a = f * 2^e, f in [0.5, 1) */
  double ulp = a < ldexp(1.0, -14) ? ldexp(1.0, -24) : ldexp(1.0, e - 11);
  double q = a / ulp, r = floor(q);
  if (q - r > 0.5 || (q - r == 0.5 && fmod(r, 2.0) == 1.0)) r += 1.0;
  double v = r * ulp;
  if (v == 0) return sign;
  /* Encode v (a half by construction). */
  int ve;
  frexp(v, &ve);
  if (v < ldexp(1.0, -14)) return sign | (uint16_t)(v / ldexp(1.0, -24));
  uint16_t exp = (uint16_t)(ve - 1 + 15);
  uint16_t man = (uint16_t)((v / ldexp(1.0, ve - 1) - 1.0) * 1024.0);
  return sign | (uint16_t)(exp << 10) | man;
}

/* Floats the rounding can go wrong on: around every half (the value, the
 * midpoint to the next, one float either side of it), subnormal and
 * overflow edges, zeros, infinities, NaNs with and without a payload in
 * the bits a half keeps, quiet and signalling; then a stride through every
 * float pattern. */
static size_t hard_floats(float *v, size_t cap) {
  size_t n = 0;
  for (uint32_t h = 0; h < 0x10000; h++) {
    if ((h & 0x7c00) == 0x7c00) continue;
    const float a = hf_f16_to_f32((uint16_t)h);
    v[n++] = a;
    if ((h & 0x7fff) < 0x7bff) {
      const float b = hf_f16_to_f32((uint16_t)(h + 1)), mid = 0.5f * (a + b);
      v[n++] = mid;
      v[n++] = nextafterf(mid, a);
      v[n++] = nextafterf(mid, b);
    }
  }
  const float edges[] = {65504.0f, 65519.996f, 65520.0f, 65536.0f, 1e6f, 3.4e38f, 5.96e-8f,
                         2.98e-8f, 2.9802322e-8f, 2.9802326e-8f, 1e-30f, 1e-45f, 1.17549435e-38f,
                         0.0f, INFINITY};
  for (size_t i = 0; i < sizeof edges / sizeof edges[0]; i++) {
    v[n++] = edges[i];
    v[n++] = -edges[i];
  }
  const uint32_t nans[] = {0x7fc00000u, 0x7f800001u, 0x7f802000u, 0x7fa00000u, 0x7fbfffffu,
                           0x7fffffffu, 0x7fc01fffu, 0x7f801fffu};
  for (size_t i = 0; i < sizeof nans / sizeof nans[0]; i++) {
    v[n++] = from_bits(nans[i]);
    v[n++] = from_bits(nans[i] | 0x80000000u);
  }
  for (uint64_t x = 0; x < 0x100000000ull && n < cap; x += 4093) v[n++] = from_bits((uint32_t)x);
  return n;
}

static void test_f32_to_f16(void **state) {
  (void)state;
  enum { CAP = 4 * 0x10000 + 64 + (1 << 20) + 64 };
  float *v = malloc(CAP * sizeof *v);
  assert_non_null(v);
  size_t n = hard_floats(v, CAP);
  assert_true(n > 1000000);
  for (size_t i = 0; i < n; i++) {
    if (isnan(v[i])) {
      /* Sign and the payload's top 10 bits kept, made quiet. */
      uint32_t x = bits(v[i]);
      assert_int_equal(hf_f32_to_f16(v[i]), ((x >> 16) & 0x8000) | 0x7e00 | ((x >> 13) & 0x3ff));
    } else if (hf_f32_to_f16(v[i]) != nearest_half(v[i])) {
      fail_msg("reference: %a -> 0x%04x, nearest half 0x%04x", (double)v[i], hf_f32_to_f16(v[i]),
               nearest_half(v[i]));
    }
  }
  BOTH_IMPLS({
    for (size_t cut = 0; cut < 17; cut++) check_f32_to_f16(v + cut, n - cut);
    check_f32_to_f16(v + 3, 0x10000 - 3);
  });
  free(v);
}

/* Frames large enough to be split between threads (4 M values and
 * 3 M + 1), every value written and agreeing with the reference. */
static void test_threaded_frames(void **state) {
  (void)state;
  const size_t n = ((size_t)4 << 20) + 13;
  float *f = malloc(n * sizeof *f);
  uint16_t *h = malloc(n * sizeof *h);
  assert_non_null(f);
  assert_non_null(h);
  uint32_t r = 12345;
  for (size_t i = 0; i < n; i++) {
    r ^= r << 13, r ^= r >> 17, r ^= r << 5;
    h[i] = (uint16_t)r;
    f[i] = from_bits(r);
  }
  BOTH_IMPLS({
    check_f16_to_f32(h, n);
    check_f32_to_f16(f, n);
    /* A length whose halves round down below it: the last part must take
     * the rest. */
    check_f16_to_f32(h, ((size_t)3 << 20) + 1);
    check_f32_to_f16(f, ((size_t)3 << 20) + 1);
  });
  free(f);
  free(h);
}

static void test_impl_name(void **state) {
  (void)state;
  int had = hf_half_use_simd(0);
  assert_string_equal(hf_half_impl(), "scalar");
  hf_half_use_simd(had);
  assert_true(!strcmp(hf_half_impl(), "f16c") || !strcmp(hf_half_impl(), "scalar"));
  assert_int_equal(hf_half_use_simd(-1), had);
}

typedef struct chunk_seen {
  unsigned char *hits;          /* [n]: times each item was given */
  size_t last_end[HF_PARALLEL_MAX];
  int out_of_order, bad_worker;
} chunk_seen;

static void count_chunk(void *arg, int worker, size_t b, size_t e) {
  chunk_seen *c = arg;
  if (worker < 0 || worker >= HF_PARALLEL_MAX) {
    c->bad_worker = 1;
    return;
  }
  if (b < c->last_end[worker]) c->out_of_order = 1;
  c->last_end[worker] = e;
  for (size_t i = b; i < e; i++) c->hits[i]++;  /* items of one chunk: one worker */
}

static void test_parallel_chunks(void **state) {
  static const size_t sizes[][3] = {{0, 16, 1}, {1, 16, 1}, {1000, 7, 10}, {1 << 20, 4096, 1000},
                                    {(1 << 20) + 3, 1 << 16, 1 << 18}, {100, 0, 1}};
  for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
    size_t n = sizes[k][0];
    chunk_seen c;
    memset(&c, 0, sizeof c);
    c.hits = calloc(n + 1, 1);
    assert_non_null(c.hits);
    int nw = hf_parallel_chunks(n, sizes[k][1], sizes[k][2], count_chunk, &c);
    /* One chunk (chunk 0 is one chunk) needs one worker. */
    int one = sizes[k][1] == 0 || n <= sizes[k][1];
    assert_int_equal(nw, !n ? 0 : one ? 1 : hf_parallel_workers(n, sizes[k][2]));
    assert_true(nw <= HF_PARALLEL_MAX);
    assert_false(c.out_of_order);
    assert_false(c.bad_worker);
    for (size_t i = 0; i < n; i++)
      if (c.hits[i] != 1) fail_msg("item %zu of %zu given %d times", i, n, c.hits[i]);
    free(c.hits);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_every_half),      cmocka_unit_test(test_reference_values),
      cmocka_unit_test(test_f32_to_f16),      cmocka_unit_test(test_threaded_frames),
      cmocka_unit_test(test_impl_name),       cmocka_unit_test(test_parallel_chunks),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
