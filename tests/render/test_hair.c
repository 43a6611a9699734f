/* .hair round trip and malformed files; procedural styles. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "hfrender.h"
#include "hr_style.h"

static const float head_r[3] = HFR_HEAD_RADII;

static void tmp_path(char *buf, size_t n, const char *name) {
  snprintf(buf, n, "/tmp/hf_test_hair_%d_%s", (int)getpid(), name);
}

static hfr_hair small_style(hfr_style s, uint64_t seed) {
  hfr_style_params p;
  assert_int_equal(hfr_style_defaults(s, &p), HF_OK);
  p.strands = 300;
  p.seed = seed;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  return h;
}

static void test_round_trip(void **state) {
  (void)state;
  hfr_hair a = small_style(HFR_STYLE_WAVY, 5);
  /* Give it every optional array, and uneven segment counts. */
  a.color = malloc(12 * (size_t)a.points);
  assert_non_null(a.color);
  for (size_t i = 0; i < 3 * (size_t)a.points; i++) a.color[i] = (float)(i % 7) / 7;
  char path[256];
  tmp_path(path, sizeof path, "rt.hair");
  assert_int_equal(hfr_hair_save(path, &a), HF_OK);
  hfr_hair b;
  char err[256] = "";
  assert_int_equal(hfr_hair_load(path, &b, err, sizeof err), HF_OK);
  assert_int_equal(a.strands, b.strands);
  assert_int_equal(a.points, b.points);
  assert_non_null(b.segments);
  for (uint32_t s = 0; s < a.strands; s++)
    assert_int_equal(hfr_hair_strand_segments(&a, s), b.segments[s]);
  assert_memory_equal(a.pos, b.pos, 12 * (size_t)a.points);
  assert_memory_equal(a.thickness, b.thickness, 4 * (size_t)a.points);
  assert_memory_equal(a.transparency, b.transparency, 4 * (size_t)a.points);
  assert_memory_equal(a.color, b.color, 12 * (size_t)a.points);
  assert_string_equal(a.info, b.info);
  assert_true(a.default_thickness == b.default_thickness);
  remove(path);
  hfr_hair_free(&a);
  hfr_hair_free(&b);
}

/* A valid two-strand file in memory: strands of 1 and 2 segments. */
static size_t build_file(unsigned char *buf, uint32_t flags) {
  memset(buf, 0, 1024);
  memcpy(buf, "HAIR", 4);
  uint32_t strands = 2, points = 5, defseg = 3;
  memcpy(buf + 4, &strands, 4);
  memcpy(buf + 8, &points, 4);
  memcpy(buf + 12, &flags, 4);
  memcpy(buf + 16, &defseg, 4);
  size_t o = 128;
  if (flags & HFR_HAIR_SEGMENTS) {
    uint16_t seg[2] = {1, 2};
    memcpy(buf + o, seg, 4);
    o += 4;
  }
  for (int i = 0; i < 15; i++) {
    float f = (float)i * 0.1f;
    memcpy(buf + o, &f, 4);
    o += 4;
  }
  if (flags & HFR_HAIR_THICKNESS)
    for (int i = 0; i < 5; i++) {
      float f = 0.01f;
      memcpy(buf + o, &f, 4);
      o += 4;
    }
  if (flags & HFR_HAIR_TRANSPARENCY)
    for (int i = 0; i < 5; i++) {
      float f = 0.5f;
      memcpy(buf + o, &f, 4);
      o += 4;
    }
  return o;
}

static void expect_reject(const unsigned char *buf, size_t len, const char *why) {
  hfr_hair h;
  char err[256] = "";
  int rc = hfr_hair_load_mem(buf, len, &h, err, sizeof err);
  if (rc == HF_OK) fail_msg("accepted a malformed file: %s", why);
  assert_true(rc == HF_EFORMAT || rc == HF_ERANGE);
  assert_true(strlen(err) > 0);
  assert_null(h.pos);
}

static void test_malformed(void **state) {
  (void)state;
  unsigned char buf[1024], bad[1024];
  const uint32_t full = HFR_HAIR_SEGMENTS | HFR_HAIR_POINTS | HFR_HAIR_THICKNESS |
                        HFR_HAIR_TRANSPARENCY;
  size_t n = build_file(buf, full);
  hfr_hair h;
  char err[256];
  assert_int_equal(hfr_hair_load_mem(buf, n, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.strands, 2);
  assert_int_equal(hfr_hair_total_segments(&h), 3);
  hfr_hair_free(&h);

  expect_reject(buf, 64, "short header");
  expect_reject(buf, n - 1, "truncated arrays");
  memcpy(bad, buf, n);
  bad[0] = 'X';
  expect_reject(bad, n, "magic");
  memcpy(bad, buf, n);
  uint32_t v = 6; /* points no longer match the segments */
  memcpy(bad + 8, &v, 4);
  expect_reject(bad, n, "point count");
  memcpy(bad, buf, n);
  v = full & ~(uint32_t)HFR_HAIR_POINTS;
  memcpy(bad + 12, &v, 4);
  expect_reject(bad, n, "no points");
  memcpy(bad, buf, n);
  bad[128] = 0, bad[129] = 0; /* 0 segments, but the points of 1 */
  expect_reject(bad, n, "segments disagree with the points");
  memcpy(bad, buf, n);
  float nan = NAN; /* in both strands: nothing left to draw */
  memcpy(bad + 132 + 8, &nan, 4);
  memcpy(bad + 132 + 12 * 4, &nan, 4);
  expect_reject(bad, n, "NaN in every strand");
  memcpy(bad, buf, n);
  v = 0xFFFFFFFFu; /* absurd counts: rejected before any allocation */
  memcpy(bad + 4, &v, 4);
  memcpy(bad + 8, &v, 4);
  expect_reject(bad, n, "huge counts");
  /* Without a segments array the default count must describe the points. */
  size_t m = build_file(buf, HFR_HAIR_POINTS);
  expect_reject(buf, m, "default segments do not match");
  v = 4; /* 1 strand of 4 segments = 5 points */
  uint32_t one = 1;
  memcpy(buf + 4, &one, 4);
  memcpy(buf + 16, &v, 4);
  assert_int_equal(hfr_hair_load_mem(buf, m, &h, err, sizeof err), HF_OK);
  assert_null(h.segments);
  assert_int_equal(hfr_hair_strand_segments(&h, 0), 4);
  hfr_hair_free(&h);
  /* Missing file. */
  assert_int_equal(hfr_hair_load("/nonexistent/x.hair", &h, err, sizeof err), HF_EIO);
}

/* A strand of 0 segments (one point; the format allows it) is left out
 * and counted; the other strands keep their points, thickness and
 * transparency. A file of nothing but such strands is refused. */
static void test_single_point_strands(void **state) {
  (void)state;
  unsigned char buf[1024];
  const uint32_t flags = HFR_HAIR_SEGMENTS | HFR_HAIR_POINTS | HFR_HAIR_THICKNESS;
  /* Three strands: 0 segments (point 0), 2 segments (points 1-3), 0 (point 4). */
  memset(buf, 0, sizeof buf);
  memcpy(buf, "HAIR", 4);
  uint32_t strands = 3, points = 5;
  memcpy(buf + 4, &strands, 4);
  memcpy(buf + 8, &points, 4);
  memcpy(buf + 12, &flags, 4);
  uint16_t seg[3] = {0, 2, 0};
  memcpy(buf + 128, seg, 6);
  size_t o = 134;
  for (int i = 0; i < 15; i++, o += 4) {
    float f = (float)i;
    memcpy(buf + o, &f, 4);
  }
  for (int i = 0; i < 5; i++, o += 4) {
    float f = 0.01f * (float)(i + 1);
    memcpy(buf + o, &f, 4);
  }
  hfr_hair h;
  char err[256];
  assert_int_equal(hfr_hair_load_mem(buf, o, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.strands, 1);
  assert_int_equal(h.points, 3);
  assert_int_equal(h.dropped, 2);
  assert_int_equal(h.segments[0], 2);
  for (int i = 0; i < 9; i++) assert_true(h.pos[i] == (float)(i + 3)); /* points 1-3 */
  for (int i = 0; i < 3; i++) assert_true(h.thickness[i] == 0.01f * (float)(i + 2));
  hfr_hair_free(&h);
  seg[1] = 0; /* all single points: 3 strands, 3 points */
  points = 3;
  memcpy(buf + 8, &points, 4);
  memcpy(buf + 128, seg, 6);
  size_t m = 134 + 12 * 3 + 4 * 3;
  assert_int_equal(hfr_hair_load_mem(buf, m, &h, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "single point"));
  /* The same model without a segments array: a default of 0 segments. It
   * was called a damaged header. */
  const uint32_t noseg = HFR_HAIR_POINTS;
  uint32_t zero = 0;
  memset(buf, 0, sizeof buf);
  memcpy(buf, "HAIR", 4);
  memcpy(buf + 4, &points, 4);   /* 3 strands */
  memcpy(buf + 8, &points, 4);   /* 3 points */
  memcpy(buf + 12, &noseg, 4);
  memcpy(buf + 16, &zero, 4);    /* default segments */
  assert_int_equal(hfr_hair_load_mem(buf, 128 + 12 * 3, &h, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "every strand is a single point"));
  assert_null(strstr(err, "damaged"));
  /* 0 as the default with more points than strands does not add up. */
  points = 4;
  memcpy(buf + 8, &points, 4);
  assert_int_equal(hfr_hair_load_mem(buf, 128 + 12 * 4, &h, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "the header is damaged"));
}

/* What the reference reader (cyHairFile) takes, read the same way and
 * counted for the caller's warnings: bytes after the arrays, flag bits the
 * format does not define, out-of-range per-point values (clamped), and a
 * strand with a NaN/Inf value (left out, the others kept whole). */
static void test_read_as_reference(void **state) {
  (void)state;
  unsigned char buf[1024], bad[1024];
  const uint32_t full = HFR_HAIR_SEGMENTS | HFR_HAIR_POINTS | HFR_HAIR_THICKNESS |
                        HFR_HAIR_TRANSPARENCY;
  size_t n = build_file(buf, full);
  hfr_hair h;
  char err[256] = "";

  memcpy(bad, buf, n);
  memset(bad + n, 0xAB, 7);
  assert_int_equal(hfr_hair_load_mem(bad, n + 7, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.trailing_bytes, 7);
  assert_int_equal(h.points, 5);
  assert_true(h.transparency[4] == 0.5f); /* the trailing bytes are not read as values */
  hfr_hair_free(&h);

  memcpy(bad, buf, n);
  uint32_t v = full | 64 | 0x80000000u;
  memcpy(bad + 12, &v, 4);
  assert_int_equal(hfr_hair_load_mem(bad, n, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.unknown_flags, 64 | 0x80000000u);
  assert_int_equal(h.strands, 2);
  assert_int_equal(h.trailing_bytes, 0);
  hfr_hair_free(&h);

  /* Thickness -0.5 at point 1, transparency 1.5 at point 4, -Inf at 3. */
  memcpy(bad, buf, n);
  float f = -0.5f;
  size_t th = 132 + 60, tr = th + 20;
  memcpy(bad + th + 4, &f, 4);
  f = 1.5f;
  memcpy(bad + tr + 16, &f, 4);
  f = -INFINITY;
  memcpy(bad + tr + 12, &f, 4);
  assert_int_equal(hfr_hair_load_mem(bad, n, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.clamped, 3);
  assert_int_equal(h.dropped_nonfinite, 0);
  assert_true(h.thickness[1] == 0.0f);
  assert_true(h.transparency[4] == 1.0f);
  assert_true(h.transparency[3] == 0.0f);
  hfr_hair_free(&h);

  /* NaN in strand 0 (points 0-1): it is left out; strand 1 (points 2-4)
   * keeps its points and widths. */
  memcpy(bad, buf, n);
  f = NAN;
  memcpy(bad + 132 + 16, &f, 4); /* point 1, y */
  assert_int_equal(hfr_hair_load_mem(bad, n, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.strands, 1);
  assert_int_equal(h.points, 3);
  assert_int_equal(h.dropped_nonfinite, 1);
  assert_int_equal(h.segments[0], 2);
  for (int i = 0; i < 9; i++) assert_true(h.pos[i] == (float)(i + 6) * 0.1f);
  hfr_hair_free(&h);

  /* Inf thickness in strand 1 of a file without a segments array (two
   * strands of 1 segment each, 4 points). */
  unsigned char d[1024];
  memset(d, 0, sizeof d);
  memcpy(d, "HAIR", 4);
  uint32_t strands = 2, points = 4, flags = HFR_HAIR_POINTS | HFR_HAIR_THICKNESS, defseg = 1;
  memcpy(d + 4, &strands, 4);
  memcpy(d + 8, &points, 4);
  memcpy(d + 12, &flags, 4);
  memcpy(d + 16, &defseg, 4);
  for (int i = 0; i < 12; i++) {
    f = (float)i;
    memcpy(d + 128 + 4 * i, &f, 4);
  }
  for (int i = 0; i < 4; i++) {
    f = i == 3 ? INFINITY : 0.01f;
    memcpy(d + 176 + 4 * i, &f, 4);
  }
  assert_int_equal(hfr_hair_load_mem(d, 192, &h, err, sizeof err), HF_OK);
  assert_int_equal(h.strands, 1);
  assert_int_equal(h.points, 2);
  assert_int_equal(h.dropped_nonfinite, 1);
  assert_int_equal(hfr_hair_strand_segments(&h, 0), 1);
  for (int i = 0; i < 6; i++) assert_true(h.pos[i] == (float)i);
  hfr_hair_free(&h);

  /* A file shorter than its arrays is still refused, whatever else. */
  expect_reject(bad, n - 2, "truncated");
}

/* Each refusal gives the header's figures, so a file cut short is told
 * from a damaged header: the sizes, counts and flags it read. */
static void refused_saying(const unsigned char *buf, size_t len, const char *a, const char *b) {
  hfr_hair h;
  char err[512] = "";
  int rc = hfr_hair_load_mem(buf, len, &h, err, sizeof err);
  if (rc == HF_OK) fail_msg("accepted; want an error with '%s'", a);
  assert_null(h.pos);
  if (!strstr(err, a) || (b && !strstr(err, b)))
    fail_msg("error '%s' lacks '%s'%s%s", err, a, b ? " or " : "", b ? b : "");
}

static void test_refusals_say_why(void **state) {
  (void)state;
  unsigned char buf[1024], bad[1024];
  const uint32_t full = HFR_HAIR_SEGMENTS | HFR_HAIR_POINTS | HFR_HAIR_THICKNESS |
                        HFR_HAIR_TRANSPARENCY;
  size_t n = build_file(buf, full);   /* 128 + 4 + 60 + 20 + 20 = 232 bytes */
  memset(bad, 0, sizeof bad);
  assert_int_equal(n, 232);
  refused_saying(buf, 64, "64 bytes, shorter than the 128-byte header", "cut short");
  refused_saying(buf, n - 1, "231 bytes", "need 232");
  refused_saying(buf, 130, "2 strands and 5 points", "cut short");
  memcpy(bad, buf, n);
  bad[0] = 'X';
  refused_saying(bad, n, "\"HAIR\"", "not a .hair file");
  refused_saying(bad, 10, "\"HAIR\"", "not a .hair file");
  uint32_t v = 6;
  memcpy(bad, buf, n);
  memcpy(bad + 8, &v, 4);
  refused_saying(bad, 252, "segment counts make 5 points", "says 6");   /* the arrays of 6 points */
  memcpy(bad, buf, n);
  v = 0;
  memcpy(bad + 4, &v, 4);
  refused_saying(bad, n, "0 strands and 5 points", "nothing to draw");
  memcpy(bad, buf, n);
  v = 0xffffffffu;
  memcpy(bad + 8, &v, 4);
  refused_saying(bad, n, "4294967295 points", "more than");
  memcpy(bad, buf, n);
  v = HFR_HAIR_POINTS;
  memcpy(bad + 12, &v, 4);
  v = 70000;
  memcpy(bad + 16, &v, 4);
  refused_saying(bad, n, "default segment count of 70000", "1..65535");
  v = 1; /* 2 strands of 1 segment: 4 points, not 5 */
  memcpy(bad + 16, &v, 4);
  refused_saying(bad, 128 + 60, "2 strands of 1 segments (its default count) make 4 points",
                 "says 5");
  memcpy(bad, buf, n);
  v = HFR_HAIR_SEGMENTS;
  memcpy(bad + 12, &v, 4);
  refused_saying(bad, n, "flags 0x1 lack POINTS", NULL);
  /* Written big-endian: every value's bytes swapped. */
  memcpy(bad, buf, n);
  for (size_t at = 4; at < 40; at += 4)
    for (int k = 0; k < 2; k++) {
      unsigned char t = bad[at + k];
      bad[at + k] = bad[at + 3 - k];
      bad[at + 3 - k] = t;
    }
  refused_saying(bad, n, "reads as big-endian (flags 0xf000000, 0xf with their bytes swapped)",
                 "little-endian");
  v = 0x02000000u; /* POINTS alone, swapped */
  memcpy(bad + 12, &v, 4);
  refused_saying(bad, n, "reads as big-endian", NULL);
  v = 0x02000010u; /* not a swapped flag word: no points */
  memcpy(bad + 12, &v, 4);
  refused_saying(bad, n, "lack POINTS", NULL);
}

/* A few strands with points far from the rest (a damaged file, a writer
 * that left points uninitialised) are named, not framed: the model's
 * radius was theirs, refused with a --scale that shrank the rest out of
 * sight, or (up to 1e15) accepted and drawn as a speck with strands as
 * wide as the speck's frame. Every style's model passes. */
static void test_far_strands_named(void **state) {
  (void)state;
  char err[512];
  for (int s = 0; s < HFR_STYLE_COUNT; s++) {
    hfr_hair h = small_style((hfr_style)s, 3);
    if (hfr_hair_check_extent(&h, 1, err, sizeof err) != HF_OK)
      fail_msg("style %s: %s", hfr_style_name((hfr_style)s), err);
    hfr_hair_free(&h);
  }
  static const float far[] = {1e4f, 1e10f, 1e30f};
  for (size_t i = 0; i < sizeof far / sizeof far[0]; i++) {
    hfr_hair h = small_style(HFR_STYLE_STRAIGHT, 3);
    uint32_t second = hfr_hair_strand_segments(&h, 0) + 1u;   /* strand 1's first point */
    h.pos[3 * (size_t)second + 1] = far[i];
    assert_int_equal(hfr_hair_check_extent(&h, 1, err, sizeof err), HF_ERANGE);
    if (!strstr(err, "1 of 300 strands (the first: strand 1) reach coordinates up to") ||
        !strstr(err, "the file is damaged"))
      fail_msg("%g: %s", (double)far[i], err);
    hfr_hair_free(&h);
  }
}

/* Median over the strands of h of the largest radius (in head radii, 1 on
 * the scalp) over the first quarter of each strand's points. */
static float combed_height(const hfr_hair *h) {
  float *v = malloc(sizeof(float) * h->strands);
  assert_non_null(v);
  size_t base = 0;
  for (uint32_t s = 0; s < h->strands; s++) {
    uint32_t n = hfr_hair_strand_segments(h, s);
    float m = 0;
    for (uint32_t i = 0; i <= n / 4; i++) {
      float q = 0;
      for (int k = 0; k < 3; k++) {
        float x = h->pos[3 * (base + i) + k] / head_r[k];
        q += x * x;
      }
      m = fmaxf(m, sqrtf(q));
    }
    v[s] = m;
    base += n + 1;
  }
  for (uint32_t i = 1; i < h->strands; i++) /* insertion sort: 300 values */
    for (uint32_t j = i; j > 0 && v[j - 1] > v[j]; j--) {
      float t = v[j];
      v[j] = v[j - 1], v[j - 1] = t;
    }
  float med = v[h->strands / 2];
  free(v);
  return med;
}

/* Braided: combed flat over the scalp (the other styles stand off it by
 * their volume), into one plait at the nape or two behind the ears, the
 * tips hanging below the head. */
static void test_braided(void **state) {
  (void)state;
  hfr_hair straight = small_style(HFR_STYLE_STRAIGHT, 3);
  float loose = combed_height(&straight);
  hfr_hair_free(&straight);
  int one = 0, two = 0;
  for (uint64_t seed = 1; seed <= 8; seed++) {
    hfr_hair h = small_style(HFR_STYLE_BRAIDED, seed);
    float flat = combed_height(&h);
    if (!(flat < 1.03f && loose > 1.04f))
      fail_msg("seed %llu: braided's combed part %.4f head radii out, straight's %.4f",
               (unsigned long long)seed, (double)flat, (double)loose);
    int left = 0, right = 0, middle = 0;
    size_t base = 0;
    for (uint32_t s = 0; s < h.strands; s++) {
      base += hfr_hair_strand_segments(&h, s) + 1;
      const float *tip = h.pos + 3 * (base - 1);
      assert_true(tip[1] < -0.9f);   /* below the chin */
      if (tip[0] < -0.3f) left++;
      else if (tip[0] > 0.3f) right++;
      if (fabsf(tip[0]) < 0.35f) middle++;
    }
    if (middle == (int)h.strands) one++;
    else if (left + right == (int)h.strands && left > 50 && right > 50) two++;
    else fail_msg("seed %llu: tips neither in one plait nor in two: %d left, %d right, %d of "
                  "%u in the middle", (unsigned long long)seed, left, right, middle, h.strands);
    hfr_hair_free(&h);
  }
  assert_true(one > 0 && two > 0);   /* the seed picks */
  hfr_style s;
  assert_int_equal(hfr_style_from_name("braids", &s), HF_OK);
  assert_int_equal(s, HFR_STYLE_BRAIDED);
}

/* The largest share of h's strands that pass within 0.01 (0.1 mm on a
 * head of radius 1 dm) of one point of strand 0: how tightly the strands
 * of strand 0's tie meet. */
static float tightest_share(const hfr_hair *h) {
  uint32_t n0 = hfr_hair_strand_segments(h, 0), best = 0;
  for (uint32_t i = 0; i <= n0; i++) {
    const float *q = h->pos + 3 * i;
    uint32_t near = 0;
    size_t base = 0;
    for (uint32_t s = 0; s < h->strands; s++) {
      uint32_t n = hfr_hair_strand_segments(h, s);
      for (uint32_t j = 0; j <= n; j++) {
        const float *p = h->pos + 3 * (base + j);
        float d2 = 0;
        for (int k = 0; k < 3; k++) d2 += (p[k] - q[k]) * (p[k] - q[k]);
        if (d2 < 1e-4f) {
          near++;
          break;
        }
      }
      base += n + 1;
    }
    if (near > best) best = near;
  }
  return (float)best / h->strands;
}

static void test_gather(void **state) {
  (void)state;
  const hfr_style tied[] = {HFR_STYLE_PONYTAIL, HFR_STYLE_BRAIDED};
  for (int t = 0; t < 2; t++)
    for (uint64_t seed = 1; seed <= 2; seed++) {
      hfr_style_params p;
      hfr_style_defaults(tied[t], &p);
      p.strands = 300, p.seed = seed;
      /* Braided seed 1 or 2: one of them two plaits (strand 0's holds about
       * half the strands). */
      int plaits = tied[t] == HFR_STYLE_BRAIDED ? hr_braid_plaits(&p) : 1;
      float share[2];
      for (int g = 0; g < 2; g++) {
        p.gather = (float)g;
        hfr_hair h;
        assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
        share[g] = tightest_share(&h);
        hfr_hair_free(&h);
      }
      /* Gather 1: every strand of the tie through one point; 0: a disc 2 cm
       * across or the bundles' places, a few strands near any one point. */
      if (!(share[1] > 0.95f / plaits && share[0] < 0.2f))
        fail_msg("%s seed %llu (%d plaits): %.3f of the strands meet at gather 1, %.3f at 0",
                 hfr_style_name(tied[t]), (unsigned long long)seed, plaits, (double)share[1],
                 (double)share[0]);
    }
  /* Only the tied styles read it; out of [0, 1] refused, naming it. */
  hfr_style_params p;
  hfr_style_defaults(HFR_STYLE_WAVY, &p);
  p.gather = 0.5f;
  char err[256];
  assert_int_equal(hfr_style_check(&p, err, sizeof err), HF_EINVAL);
  assert_non_null(strstr(err, "ponytail and braided"));
  hfr_style_defaults(HFR_STYLE_PONYTAIL, &p);
  p.gather = 1.5f;
  assert_int_equal(hfr_style_check(&p, err, sizeof err), HF_EINVAL);
  assert_non_null(strstr(err, "gather 1.5 is outside [0, 1]"));
  p.gather = 1;
  assert_int_equal(hfr_style_check(&p, err, sizeof err), HF_OK);
}

static void test_styles(void **state) {
  (void)state;
  for (int s = 0; s < HFR_STYLE_COUNT; s++) {
    hfr_style back;
    assert_int_equal(hfr_style_from_name(hfr_style_name((hfr_style)s), &back), HF_OK);
    assert_int_equal(back, s);
    hfr_hair a = small_style((hfr_style)s, 11), b = small_style((hfr_style)s, 11);
    hfr_hair c = small_style((hfr_style)s, 12);
    assert_memory_equal(a.pos, b.pos, 12 * (size_t)a.points);
    assert_true(memcmp(a.pos, c.pos, 12 * (size_t)a.points) != 0);
    hfr_style_params p;
    hfr_style_defaults((hfr_style)s, &p);
    assert_true(p.strands >= 50000);
    /* Guide styles: 300 / (children + 1) guides, each with its children. */
    uint32_t strands = p.children ? 300u / (p.children + 1) * (p.children + 1) : 300u;
    assert_int_equal(a.strands, strands);
    assert_int_equal(a.points, strands * (p.segments + 1));
    /* The body the style grows on (0.99 of it: the occluder). */
    hfr_ellipsoid body;
    hfr_style_body((hfr_style)s, &body);
    float br[3], minr = 1e9f;
    for (int k = 0; k < 3; k++) br[k] = body.radii[k] / 0.99f, minr = fminf(minr, br[k]);
    if (s != HFR_STYLE_FUR) assert_memory_equal(head_r, br, sizeof br);
    float lo = 1e9f, hi = 0;
    for (uint32_t i = 0; i < a.points; i++) {
      float q = 0;
      for (int k = 0; k < 3; k++) {
        float x = a.pos[3 * i + k];
        assert_true(isfinite(x));
        q += (x / br[k]) * (x / br[k]);
      }
      q = sqrtf(q);
      /* Roots on the scalp (skin), nothing inside the body. */
      if (i % (p.segments + 1) == 0) assert_true(fabsf(q - 1) < 1e-3f);
      if (q < lo) lo = q;
      if (q > hi) hi = q;
    }
    assert_true(lo > 0.999f);
    assert_true(hi > 1 + 0.15f * p.length / minr); /* the hair leaves the scalp (fur lies down) */
    /* Widths and opacities as asked, tapering. */
    assert_non_null(a.thickness);
    for (uint32_t i = 0; i < a.points; i++)
      assert_true(a.thickness[i] > 0.2f * p.thickness && a.thickness[i] <= p.thickness * 1.0001f);
    hfr_hair_free(&a);
    hfr_hair_free(&b);
    hfr_hair_free(&c);
  }
  hfr_style s;
  assert_int_equal(hfr_style_from_name("afro", &s), HF_OK);
  assert_int_equal(s, HFR_STYLE_COILY);
  assert_int_equal(hfr_style_from_name("mohawk", &s), HF_ENOTFOUND);
  hfr_style_params p;
  hfr_style_defaults(HFR_STYLE_STRAIGHT, &p);
  p.segments = 2;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_EINVAL);
  hfr_style_defaults(HFR_STYLE_STRAIGHT, &p);
  p.strands = 3000000, p.segments = 1000;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_ERANGE);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_round_trip),
    cmocka_unit_test(test_malformed), cmocka_unit_test(test_refusals_say_why),
    cmocka_unit_test(test_single_point_strands),
    cmocka_unit_test(test_read_as_reference),
    cmocka_unit_test(test_styles), cmocka_unit_test(test_braided),
    cmocka_unit_test(test_gather),
    cmocka_unit_test(test_far_strands_named),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
