/* Cem Yuksel's .hair format: a 128-byte little-endian header, then the
 * arrays the flag bits announce, in the order segments (uint16 per strand),
 * points (float3), thickness (float), transparency (float), colors (float3).
 *
 *   0 "HAIR"   4 strands   8 points   12 flags   16 default segments
 *   20 default thickness   24 default transparency   28 default colour[3]
 *   40 file info (88 bytes)                                               */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfrender.h"

#define HAIR_HEADER 128

static uint32_t rd_u32(const unsigned char *p) {
  return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static float rd_f32(const unsigned char *p) {
  uint32_t u = rd_u32(p);
  float f;
  memcpy(&f, &u, 4);
  return f;
}
static void wr_u32(unsigned char *p, uint32_t v) {
  p[0] = (unsigned char)v;
  p[1] = (unsigned char)(v >> 8);
  p[2] = (unsigned char)(v >> 16);
  p[3] = (unsigned char)(v >> 24);
}
static void wr_f32(unsigned char *p, float f) {
  uint32_t u;
  memcpy(&u, &f, 4);
  wr_u32(p, u);
}

/* Writes the refusal's message (printf-style) to err, returns code. */
__attribute__((format(printf, 4, 5))) static int fail(char *err, size_t errlen, int code,
                                                      const char *fmt, ...) {
  if (err && errlen) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
  }
  return code;
}

void hfr_hair_free(hfr_hair *h) {
  if (!h) return;
  free(h->segments);
  free(h->pos);
  free(h->thickness);
  free(h->transparency);
  free(h->color);
  memset(h, 0, sizeof *h);
}

uint32_t hfr_hair_strand_segments(const hfr_hair *h, uint32_t i) {
  return h->segments ? h->segments[i] : h->default_segments;
}

uint64_t hfr_hair_total_segments(const hfr_hair *h) {
  /* Every strand has segments + 1 points. */
  return (uint64_t)h->points - h->strands;
}

/* In double: a float model's coordinate differences and their squares
 * overflow float from about 1e19 (and the extent of coordinates near
 * FLT_MAX overflows outright), and underflow it below about 1e-19; double
 * holds every float model's extent exactly enough. */
void hfr_hair_extent(const hfr_hair *h, double c[3], double *radius) {
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t i = 0; i < h->points; i++)
    for (int k = 0; k < 3; k++) {
      double v = h->pos[3 * (size_t)i + k];
      if (v < lo[k]) lo[k] = v;
      if (v > hi[k]) hi[k] = v;
    }
  if (!h->points) {
    c[0] = c[1] = c[2] = 0;
    *radius = 0;
    return;
  }
  for (int k = 0; k < 3; k++) c[k] = 0.5 * (lo[k] + hi[k]);
  double r2 = 0;
  for (uint32_t i = 0; i < h->points; i++) {
    double d2 = 0;
    for (int k = 0; k < 3; k++) {
      double d = h->pos[3 * (size_t)i + k] - c[k];
      d2 += d * d;
    }
    if (d2 > r2) r2 = d2;
  }
  *radius = sqrt(r2);
}

void hfr_hair_bounds(const hfr_hair *h, float c[3], float *radius) {
  double cd[3], rd;
  hfr_hair_extent(h, cd, &rd);
  for (int k = 0; k < 3; k++) c[k] = (float)cd[k];
  /* A model of coincident points gets a unit sphere (to frame something);
   * hfr_hair_check_extent refuses such a model. */
  *radius = rd > 0 ? (float)rd : 1.0f;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* When a few strands (a tenth or fewer) reach coordinates over
 * OUTLIER_FACTOR times the other strands' typical reach, the extent is
 * theirs, not the model's: a damaged file or a writer's fault
 * (uninitialised points), which no --units or --scale mends. Writes why to
 * err and returns 1 then; 0 otherwise (also when memory runs out, the
 * plain refusal following). Needs the segments array or the default
 * count. */
#define OUTLIER_FACTOR 1e3
static int outlier_strands(const hfr_hair *h, char *err, size_t errlen) {
  if (!h->strands) return 0;
  double *reach = malloc(sizeof *reach * h->strands);
  if (!reach) return 0;
  uint32_t p = 0;
  for (uint32_t i = 0; i < h->strands; i++) {
    uint32_t n = hfr_hair_strand_segments(h, i) + 1u;
    double most = 0;
    for (uint32_t k = 0; k < n && p + k < h->points; k++)
      for (int c = 0; c < 3; c++) {
        double v = fabs((double)h->pos[3 * ((size_t)p + k) + (size_t)c]);
        if (v > most) most = v;
      }
    reach[i] = most;
    p += n;
  }
  double *sorted = malloc(sizeof *sorted * h->strands);
  if (!sorted) {
    free(reach);
    return 0;
  }
  memcpy(sorted, reach, sizeof *sorted * h->strands);
  qsort(sorted, h->strands, sizeof *sorted, cmp_double);
  double median = sorted[h->strands / 2], far = sorted[h->strands - 1];
  free(sorted);
  uint32_t out = 0, first = 0;
  for (uint32_t i = 0; i < h->strands; i++)
    if (reach[i] > median * OUTLIER_FACTOR && out++ == 0) first = i;
  free(reach);
  if (!out || median <= 0 || out > h->strands / 10) return 0;
  if (err)
    snprintf(err, errlen, "%u of %u strands (the first: strand %u) reach coordinates up to "
             "%.4g, over %g times the other strands' (their median reach %.4g): the file is "
             "damaged or its writer has a fault (uninitialised points?), and no --units or "
             "--scale frames the model; write the file again or leave those strands out",
             out, h->strands, first, far, OUTLIER_FACTOR, median);
  return 1;
}

int hfr_hair_check_extent(const hfr_hair *h, double scale, char *err, size_t errlen) {
  if (err && errlen) err[0] = 0;
  if (!h || !h->pos || !h->points) return HF_EINVAL;
  double c[3], r;
  hfr_hair_extent(h, c, &r);
  double rs = r * scale;
  /* Before the radius is judged: a few far strands make it theirs, and a
   * --scale fitted to it would shrink the model out of sight. */
  if (r > 0 && isfinite(r) && outlier_strands(h, err, errlen)) return HF_ERANGE;
  if (isfinite(rs) && rs >= HFR_RADIUS_MIN && rs <= HFR_RADIUS_MAX && r > 0) {
    /* Far from the origin float's spacing grows (2^-23 of the magnitude):
     * a model written there has its points rounded to a grid, and one
     * coarser than HFR_SPACING_MAX_REL of its radius has lost its shape
     * (strands zigzag between grid points, or collapse), whatever the
     * renderer does with it. */
    double most = 0;
    for (size_t k = 0; k < 3 * (size_t)h->points; k++)
      if (fabs((double)h->pos[k]) > most) most = fabs((double)h->pos[k]);
    float m = (float)most;
    double spacing = (double)nextafterf(m, INFINITY) - (double)m;
    if (spacing <= r * HFR_SPACING_MAX_REL) return HF_OK;
    if (err)
      snprintf(err, errlen, "coordinates reach %.4g (centre %.4g, %.4g, %.4g), where float's "
               "spacing is %.3g, more than %g of the bounding radius %.4g: the file's points "
               "are rounded to that grid and the model's shape is lost; write the model "
               "nearer the origin", most, c[0], c[1], c[2], spacing, HFR_SPACING_MAX_REL, r);
    return HF_ERANGE;
  }
  if (err) {
    if (r == 0)
      snprintf(err, errlen, "every point is at (%.4g, %.4g, %.4g): the model has no extent "
               "to frame or draw (a degenerate model, or coordinates so far from the origin "
               "that float cannot tell its points apart: write it nearer the origin)",
               c[0], c[1], c[2]);
    else if (scale != 1)
      snprintf(err, errlen, "bounding radius %.4g in the file's units (centre %.4g, %.4g, "
               "%.4g) is %.4g after --units/--scale, outside the %g..%g the renderer draws in "
               "float (about 1 is a head); a --scale of about %.3g brings it to 1",
               r, c[0], c[1], c[2], rs, HFR_RADIUS_MIN, HFR_RADIUS_MAX, 1 / r);
    else
      snprintf(err, errlen, "bounding radius %.4g (centre %.4g, %.4g, %.4g) is outside the "
               "%g..%g the renderer draws in float (about 1 is a head); give the file's unit "
               "(--units m|dm|cm|mm|in|ft) or a --scale (about %.3g brings it to 1)",
               r, c[0], c[1], c[2], HFR_RADIUS_MIN, HFR_RADIUS_MAX, 1 / r);
  }
  return HF_ERANGE;
}

/* 1 when points [p, p + n) (a strand, or the whole model) have a value
 * nothing can draw: a non-finite coordinate, thickness or transparency. */
static int strand_nonfinite(const hfr_hair *h, uint32_t p, uint32_t n) {
  for (size_t k = 3 * (size_t)p; k < 3 * ((size_t)p + n); k++)
    if (!isfinite(h->pos[k])) return 1;
  for (size_t k = p; k < (size_t)p + n; k++) {
    if (h->thickness && !isfinite(h->thickness[k])) return 1;
    if (h->transparency && !isfinite(h->transparency[k])) return 1;
  }
  return 0;
}

/* Leaves out, in place, the strands of 0 segments (a single point each:
 * every later stage, orientation, children, drawing, takes a strand to have
 * a segment) and those strand_nonfinite finds. Needs the segments array
 * (load_mem makes one when it has to drop from a file without). */
static void drop_strands(hfr_hair *h) {
  uint32_t ws = 0, wp = 0, rp = 0;
  for (uint32_t i = 0; i < h->strands; i++) {
    uint32_t n = h->segments[i] + 1u;
    int single = h->segments[i] == 0, bad = !single && strand_nonfinite(h, rp, n);
    if (single || bad) {
      if (single) h->dropped++;
      else h->dropped_nonfinite++;
      rp += n;
      continue;
    }
    memmove(h->pos + 3 * (size_t)wp, h->pos + 3 * (size_t)rp, 12 * (size_t)n);
    if (h->thickness) memmove(h->thickness + wp, h->thickness + rp, 4 * (size_t)n);
    if (h->transparency) memmove(h->transparency + wp, h->transparency + rp, 4 * (size_t)n);
    if (h->color) memmove(h->color + 3 * (size_t)wp, h->color + 3 * (size_t)rp, 12 * (size_t)n);
    h->segments[ws++] = h->segments[i];
    wp += n;
    rp += n;
  }
  h->strands = ws;
  h->points = wp;
}

int hfr_hair_load_mem(const void *buf, size_t len, hfr_hair *out, char *err, size_t errlen) {
  if (!buf || !out) return fail(err, errlen, HF_EINVAL, "null argument");
  memset(out, 0, sizeof *out);
  const unsigned char *p = buf;
  /* Every refusal gives the header's figures and what they mean, so a
   * file cut short is told from a damaged or hostile header. */
  if (len >= 4 && memcmp(p, "HAIR", 4))
    return fail(err, errlen, HF_EFORMAT, "does not start with \"HAIR\": not a .hair file "
                "(Cem Yuksel's format)");
  if (len < HAIR_HEADER)
    return fail(err, errlen, HF_EFORMAT, "%zu bytes, shorter than the 128-byte header: cut "
                 "short, copy the file again", len);
  uint32_t strands = rd_u32(p + 4), points = rd_u32(p + 8), flags = rd_u32(p + 12);
  uint32_t defseg = rd_u32(p + 16);
  /* A file written big-endian (a writer that dumped its structs on such a
   * machine) has its flags in the top byte: said as such, not as a file
   * without points. */
  uint32_t swapped = flags >> 24 | (flags >> 8 & 0xff00u) | (flags << 8 & 0xff0000u) | flags << 24;
  if (!(flags & HFR_HAIR_POINTS) && (swapped & HFR_HAIR_POINTS) && !(swapped & ~31u))
    return fail(err, errlen, HF_EFORMAT, "the header reads as big-endian (flags 0x%x, 0x%x with "
                 "their bytes swapped): the .hair format is little-endian; write the file with "
                 "a .hair writer, or swap every 2- and 4-byte value", flags, swapped);
  if (!(flags & HFR_HAIR_POINTS))
    return fail(err, errlen, HF_EFORMAT, "header flags 0x%x lack POINTS (0x2): the file has "
                 "no points, nothing to draw", flags);
  if (strands == 0 || points == 0)
    return fail(err, errlen, HF_EFORMAT, "the header says %u strands and %u points: an empty "
                 "model, nothing to draw", strands, points);
  if (strands > HFR_MAX_STRANDS || points > HFR_MAX_POINTS)
    return fail(err, errlen, HF_ERANGE, "the header says %u strands and %u points, more than "
                 "the %u strands and %u points this renderer takes (a damaged header, or a "
                 "model to split or decimate)", strands, points, HFR_MAX_STRANDS,
                 HFR_MAX_POINTS);
  /* A default of 0 segments with points == strands is legal (each strand
   * one point) but draws nothing, said as the segments array's case is;
   * with other counts, the header does not add up. */
  if (!(flags & HFR_HAIR_SEGMENTS) && defseg == 0 && points == strands)
    return fail(err, errlen, HF_EFORMAT, "every strand is a single point (no segments array, "
                 "a default of 0 segments): nothing to draw");
  if (!(flags & HFR_HAIR_SEGMENTS) && (defseg == 0 || defseg > 65535))
    return fail(err, errlen, HF_EFORMAT, "no segments array (flags 0x%x) and a default "
                 "segment count of %u in the header, outside 1..65535: the header is damaged",
                 flags, defseg);

  /* Exact size from the counts (64-bit: the limits keep it far from
   * overflow), compared before any allocation. Flag bits the format does
   * not define announce no array the reference reader knows of, so they
   * are ignored (and counted); so are bytes after the arrays, which it
   * never reads. */
  uint64_t need = HAIR_HEADER;
  if (flags & HFR_HAIR_SEGMENTS) need += 2ull * strands;
  need += 12ull * points;
  if (flags & HFR_HAIR_THICKNESS) need += 4ull * points;
  if (flags & HFR_HAIR_TRANSPARENCY) need += 4ull * points;
  if (flags & HFR_HAIR_COLORS) need += 12ull * points;
  if (len < need)
    return fail(err, errlen, HF_EFORMAT, "%zu bytes, but the header's %u strands and %u "
                 "points with arrays 0x%x need %llu: the file is cut short (copy it again) or "
                 "its header is damaged", len, strands, points, flags & 31u,
                 (unsigned long long)need);

  const unsigned char *q = p + HAIR_HEADER;
  uint64_t total = 0;
  uint32_t single = 0;
  if (flags & HFR_HAIR_SEGMENTS) {
    for (uint32_t i = 0; i < strands; i++) {
      uint32_t s = (uint32_t)q[2 * (size_t)i] | (uint32_t)q[2 * (size_t)i + 1] << 8;
      single += s == 0;
      total += s + 1u;
    }
    if (single == strands)
      return fail(err, errlen, HF_EFORMAT, "every strand is a single point (0 segments): "
                  "nothing to draw");
  } else {
    total = (uint64_t)strands * (defseg + 1u);
  }
  if (total != points && (flags & HFR_HAIR_SEGMENTS))
    return fail(err, errlen, HF_EFORMAT, "the strands' segment counts make %llu points (a "
                 "strand of n segments has n + 1), the header says %u: the file is damaged",
                 (unsigned long long)total, points);
  if (total != points)
    return fail(err, errlen, HF_EFORMAT, "the header's %u strands of %u segments (its "
                 "default count) make %llu points, the header says %u: the file is damaged",
                 strands, defseg, (unsigned long long)total, points);

  out->strands = strands;
  out->points = points;
  out->unknown_flags = flags & ~31u;
  out->trailing_bytes = len - need;
  out->default_segments = defseg;
  out->default_thickness = rd_f32(p + 20);
  out->default_transparency = rd_f32(p + 24);
  for (int k = 0; k < 3; k++) out->default_color[k] = rd_f32(p + 28 + 4 * k);
  memcpy(out->info, p + 40, 88);
  out->info[88] = 0;

  if (flags & HFR_HAIR_SEGMENTS) {
    out->segments = malloc(sizeof(uint16_t) * strands);
    if (!out->segments) goto nomem;
    for (uint32_t i = 0; i < strands; i++)
      out->segments[i] = (uint16_t)(q[2 * (size_t)i] | q[2 * (size_t)i + 1] << 8);
    q += 2 * (size_t)strands;
  }
  out->pos = malloc(12 * (size_t)points);
  if (!out->pos) goto nomem;
  for (size_t i = 0; i < 3 * (size_t)points; i++) out->pos[i] = rd_f32(q + 4 * i);
  q += 12 * (size_t)points;
  if (flags & HFR_HAIR_THICKNESS) {
    out->thickness = malloc(4 * (size_t)points);
    if (!out->thickness) goto nomem;
    for (size_t i = 0; i < points; i++) {
      float t = rd_f32(q + 4 * i);
      if (t < 0) { /* no width; NaN is left for drop_strands */
        t = 0;
        out->clamped++;
      }
      out->thickness[i] = t;
    }
    q += 4 * (size_t)points;
  }
  if (flags & HFR_HAIR_TRANSPARENCY) {
    out->transparency = malloc(4 * (size_t)points);
    if (!out->transparency) goto nomem;
    for (size_t i = 0; i < points; i++) {
      float t = rd_f32(q + 4 * i);
      if (t < 0 || t > 1) { /* +-Inf too; NaN is left for drop_strands */
        t = t < 0 ? 0.0f : 1.0f;
        out->clamped++;
      }
      out->transparency[i] = t;
    }
    q += 4 * (size_t)points;
  }
  if (flags & HFR_HAIR_COLORS) {
    out->color = malloc(12 * (size_t)points);
    if (!out->color) goto nomem;
    for (size_t i = 0; i < 3 * (size_t)points; i++) out->color[i] = rd_f32(q + 4 * i);
  }
  int nonfinite = strand_nonfinite(out, 0, out->points); /* any point at all */
  if (single || nonfinite) {
    if (!out->segments) { /* default segments: drop_strands needs them spelt out */
      out->segments = malloc(sizeof(uint16_t) * strands);
      if (!out->segments) goto nomem;
      for (uint32_t i = 0; i < strands; i++) out->segments[i] = (uint16_t)defseg;
    }
    drop_strands(out);
    if (!out->strands) {
      uint32_t bad = out->dropped_nonfinite;
      hfr_hair_free(out);
      if (err)
        snprintf(err, errlen, "every strand has a non-finite (NaN or Inf) point coordinate, "
                 "thickness or transparency (%u strands) or a single point: nothing to draw; "
                 "the file is damaged or was written wrongly", bad);
      return HF_EFORMAT;
    }
  }
  return HF_OK;
nomem:
  hfr_hair_free(out);
  return fail(err, errlen, HF_ENOMEM, "out of memory");
}

int hfr_hair_load(const char *path, hfr_hair *out, char *err, size_t errlen) {
  if (!path || !out) return fail(err, errlen, HF_EINVAL, "null argument");
  memset(out, 0, sizeof *out);
  FILE *f = fopen(path, "rb");
  if (!f) {
    if (err) snprintf(err, errlen, "%s: %s", path, strerror(errno));
    return HF_EIO;
  }
  long size = -1;
  if (fseek(f, 0, SEEK_END) == 0) size = ftell(f);
  if (size < 0 || fseek(f, 0, SEEK_SET) != 0) {
    fclose(f);
    if (err) snprintf(err, errlen, "%s: cannot size the file: %s", path, strerror(errno));
    return HF_EIO;
  }
  /* The largest valid file: header + every array at the limits. */
  uint64_t max = HAIR_HEADER + 2ull * HFR_MAX_STRANDS + 32ull * HFR_MAX_POINTS;
  if ((uint64_t)size > max) {
    fclose(f);
    return fail(err, errlen, HF_ERANGE, "%ld bytes, larger than any model this renderer "
                 "takes (%u strands, %u points with every array: %llu bytes)", size,
                 HFR_MAX_STRANDS, HFR_MAX_POINTS, (unsigned long long)max);
  }
  unsigned char *buf = malloc(size ? (size_t)size : 1);
  if (!buf) {
    fclose(f);
    return fail(err, errlen, HF_ENOMEM, "out of memory");
  }
  size_t got = fread(buf, 1, (size_t)size, f);
  fclose(f);
  if (got != (size_t)size) {
    free(buf);
    return fail(err, errlen, HF_EIO, "read %zu of its %ld bytes (changed while read?)", got,
                 size);
  }
  int rc = hfr_hair_load_mem(buf, got, out, err, errlen);
  free(buf);
  return rc;
}

static int write_all(FILE *f, const void *p, size_t n) {
  return fwrite(p, 1, n, f) == n ? HF_OK : HF_EIO;
}

static int write_floats(FILE *f, const float *v, size_t n) {
  unsigned char tmp[4096];
  size_t i = 0;
  while (i < n) {
    size_t k = 0;
    for (; k < sizeof tmp / 4 && i < n; k++, i++) wr_f32(tmp + 4 * k, v[i]);
    if (write_all(f, tmp, 4 * k)) return HF_EIO;
  }
  return HF_OK;
}

int hfr_hair_save(const char *path, const hfr_hair *h) {
  if (!path || !h || !h->pos || !h->strands) return HF_EINVAL;
  uint64_t total = 0;
  for (uint32_t i = 0; i < h->strands; i++) {
    uint32_t s = hfr_hair_strand_segments(h, i);
    if (s == 0 || s > 65535) return HF_ERANGE;
    total += s + 1u;
  }
  if (total != h->points) return HF_EINVAL;
  unsigned char hdr[HAIR_HEADER];
  memset(hdr, 0, sizeof hdr);
  memcpy(hdr, "HAIR", 4);
  uint32_t flags = HFR_HAIR_SEGMENTS | HFR_HAIR_POINTS;
  if (h->thickness) flags |= HFR_HAIR_THICKNESS;
  if (h->transparency) flags |= HFR_HAIR_TRANSPARENCY;
  if (h->color) flags |= HFR_HAIR_COLORS;
  wr_u32(hdr + 4, h->strands);
  wr_u32(hdr + 8, h->points);
  wr_u32(hdr + 12, flags);
  wr_u32(hdr + 16, h->default_segments);
  wr_f32(hdr + 20, h->default_thickness);
  wr_f32(hdr + 24, h->default_transparency);
  for (int k = 0; k < 3; k++) wr_f32(hdr + 28 + 4 * k, h->default_color[k]);
  memcpy(hdr + 40, h->info, strnlen(h->info, 88));

  FILE *f = fopen(path, "wb");
  if (!f) return HF_EIO;
  int rc = write_all(f, hdr, sizeof hdr);
  for (uint32_t i = 0; rc == HF_OK && i < h->strands; i++) {
    uint32_t s = hfr_hair_strand_segments(h, i);
    unsigned char b[2] = {(unsigned char)s, (unsigned char)(s >> 8)};
    rc = write_all(f, b, 2);
  }
  if (rc == HF_OK) rc = write_floats(f, h->pos, 3 * (size_t)h->points);
  if (rc == HF_OK && h->thickness) rc = write_floats(f, h->thickness, h->points);
  if (rc == HF_OK && h->transparency) rc = write_floats(f, h->transparency, h->points);
  if (rc == HF_OK && h->color) rc = write_floats(f, h->color, 3 * (size_t)h->points);
  if (fclose(f) != 0 && rc == HF_OK) rc = HF_EIO;
  return rc;
}
