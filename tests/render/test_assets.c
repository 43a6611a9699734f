/* Loaded models as they come (no GL): header thickness fallback and width
 * warnings (the field case and models of other sizes and units), up axes
 * and units, guide interpolation, the ellipsoid fitted under the roots,
 * occluder meshes from files. */
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
#include "hr_dataset.h"

static void tmp_path(char *buf, size_t n, const char *name) {
  snprintf(buf, n, "/tmp/hf_test_assets_%d_%s", (int)getpid(), name);
}

static hfr_hair small_style(hfr_style s, int strands) {
  hfr_style_params p;
  assert_int_equal(hfr_style_defaults(s, &p), HF_OK);
  p.strands = strands;
  p.seed = 21;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  return h;
}

/* The reference writer's file: points only, header thickness 1.0. The
 * fallback is 1/2000 of the bounding radius, with a warning. */
static void test_field_case_thickness(void **state) {
  (void)state;
  hfr_hair h;
  char err[256] = "", warn[512] = "";
  assert_int_equal(hfr_hair_load(HF_TEST_DATA "/hair-default-header.hair", &h, err, sizeof err),
                   HF_OK);
  assert_null(h.thickness);
  assert_true(h.default_thickness == 1.0f);
  float c[3], r;
  hfr_hair_bounds(&h, c, &r);
  const char *why = NULL;
  float t = hfr_hair_default_thickness(&h, r, &why);
  assert_non_null(why);
  assert_true(fabsf(t - r / 2000) < 1e-6f * r);
  assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 1);
  print_message("warning: %s\n", warn);
  assert_non_null(strstr(warn, "header thickness 1.0"));
  assert_true(fabsf(h.default_thickness - r / 2000) < 1e-6f * r);
  /* Checked once, the value stands. */
  assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 0);
  assert_string_equal(warn, "");
  hfr_hair_free(&h);
}

/* Models of other sizes and units, written as the reference writer does:
 * the same fallback relative to their size; a plausible header is kept;
 * implausible per-point widths are reported and kept. */
static void test_widths_across_units(void **state) {
  (void)state;
  const float scales[] = {0.1f /* m */, 1, 10 /* cm */, 100 /* mm */, 1000};
  for (size_t i = 0; i < sizeof scales / sizeof scales[0]; i++) {
    hfr_hair h = small_style(HFR_STYLE_WAVY, 200);
    for (size_t k = 0; k < 3 * (size_t)h.points; k++) h.pos[k] *= scales[i];
    free(h.thickness);
    h.thickness = NULL;
    h.default_thickness = HFR_HAIR_UNSET_THICKNESS;
    char path[256], err[256], warn[512];
    tmp_path(path, sizeof path, "units.hair");
    assert_int_equal(hfr_hair_save(path, &h), HF_OK);
    hfr_hair_free(&h);
    assert_int_equal(hfr_hair_load(path, &h, err, sizeof err), HF_OK);
    remove(path);
    float c[3], r;
    hfr_hair_bounds(&h, c, &r);
    int warned = hfr_hair_check_widths(&h, warn, sizeof warn);
    print_message("scale %g: radius %g, drawn %g (%s)\n", scales[i], r, h.default_thickness,
                  warned ? "warned" : "kept");
    /* 1.0 is taken as unset wherever it is above radius / 1000. */
    if (r > 1000) {
      assert_int_equal(warned, 0);
      assert_true(h.default_thickness == 1.0f);
    } else {
      assert_int_equal(warned, 1);
      assert_true(fabsf(h.default_thickness / r - HFR_WIDTH_FALLBACK_REL) < 1e-7f);
    }
    /* A plausible header thickness (80 um on this head) is kept. */
    h.default_thickness = 0.0008f * scales[i];
    assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 0);
    assert_true(h.default_thickness == 0.0008f * scales[i]);
    /* Absurd ones are not: a tenth of the model, or zero. */
    h.default_thickness = 0.1f * r;
    assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 1);
    assert_true(fabsf(h.default_thickness / r - HFR_WIDTH_FALLBACK_REL) < 1e-7f);
    h.default_thickness = 0;
    assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 1);
    hfr_hair_free(&h);
  }
  /* Per-point widths: reported when implausible, never changed. */
  hfr_hair h = small_style(HFR_STYLE_STRAIGHT, 100);
  char warn[512];
  assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 0);
  h.thickness[5] = 1.0f; /* 1/3 of this model's radius */
  assert_int_equal(hfr_hair_check_widths(&h, warn, sizeof warn), 1);
  print_message("per point: %s\n", warn);
  assert_non_null(strstr(warn, "1 of"));
  assert_true(h.thickness[5] == 1.0f);
  hfr_hair_free(&h);
}

static void test_axes_and_units(void **state) {
  (void)state;
  hfr_axis a;
  assert_int_equal(hfr_axis_from_name("Z", &a), HF_OK);
  assert_int_equal(a, HFR_AXIS_Z);
  assert_int_equal(hfr_axis_from_name("+y", &a), HF_OK);
  assert_int_equal(a, HFR_AXIS_Y);
  assert_int_equal(hfr_axis_from_name("-x", &a), HF_OK);
  assert_int_equal(a, HFR_AXIS_NEG_X);
  assert_int_equal(hfr_axis_from_name("w", &a), HF_ENOTFOUND);
  float s;
  assert_int_equal(hfr_units_scale("cm", &s), HF_OK);
  assert_true(s == 0.1f);
  assert_int_equal(hfr_units_scale("m", &s), HF_OK);
  assert_true(s == 10);
  assert_int_equal(hfr_units_scale("furlong", &s), HF_ENOTFOUND);
  /* Every up axis goes to +y; z-up's front (-y) goes to +z; the scale
   * applies to positions and widths. */
  const float up[HFR_AXIS_COUNT][3] = {{0, 1, 0}, {0, 0, 1}, {1, 0, 0},
                                       {0, -1, 0}, {0, 0, -1}, {-1, 0, 0}};
  for (int k = 0; k < HFR_AXIS_COUNT; k++) {
    hfr_hair h = {0};
    h.strands = 1, h.points = 3, h.default_segments = 2;
    float pos[9] = {up[k][0], up[k][1], up[k][2], 0, -1, 0, 0, 0, 0}, th[3] = {1, 2, 3};
    if (k == HFR_AXIS_Y || k == HFR_AXIS_NEG_Y) pos[3] = 0, pos[4] = 0, pos[5] = -1;
    h.pos = pos, h.thickness = th, h.default_thickness = 1;
    assert_int_equal(hfr_hair_orient(&h, (hfr_axis)k, 2), HF_OK);
    assert_true(fabsf(pos[0]) < 1e-6f && fabsf(pos[1] - 2) < 1e-6f && fabsf(pos[2]) < 1e-6f);
    if (k == HFR_AXIS_Z) assert_true(fabsf(pos[5] - 2) < 1e-6f); /* front to +z */
    assert_true(th[2] == 6 && h.default_thickness == 2);
    assert_int_equal(hfr_hair_orient(&h, (hfr_axis)k, 0), HF_EINVAL);
  }
}

/* Children: count, roots within the local guide spacing of their guide,
 * spread over it, the same for a seed, different for another. */
static void test_children(void **state) {
  (void)state;
  hfr_hair g = small_style(HFR_STYLE_CURLY, 120);
  hfr_children_params p;
  hfr_children_defaults(&p);
  p.children = 9;
  hfr_hair a, b, c;
  assert_int_equal(hfr_hair_interpolate(&g, &p, &a), HF_OK);
  assert_int_equal(hfr_hair_interpolate(&g, &p, &b), HF_OK);
  p.seed = 2;
  assert_int_equal(hfr_hair_interpolate(&g, &p, &c), HF_OK);
  assert_int_equal(a.strands, 120 * 10);
  assert_int_equal(a.points, 10 * g.points);
  assert_memory_equal(a.pos, b.pos, 12 * (size_t)a.points);
  assert_true(memcmp(a.pos, c.pos, 12 * (size_t)a.points) != 0);
  const uint32_t n1 = g.default_segments + 1;
  double far = 0, sum = 0;
  int counted = 0;
  for (uint32_t s = 0; s < g.strands; s++) {
    const float *gr = g.pos + 3 * (size_t)s * n1;
    /* The nearest other guide root: the local spacing. */
    float spacing = INFINITY;
    for (uint32_t q = 0; q < g.strands; q++) {
      if (q == s) continue;
      const float *o = g.pos + 3 * (size_t)q * n1;
      float d = sqrtf((o[0] - gr[0]) * (o[0] - gr[0]) + (o[1] - gr[1]) * (o[1] - gr[1]) +
                      (o[2] - gr[2]) * (o[2] - gr[2]));
      if (d < spacing) spacing = d;
    }
    const float *ga = a.pos + 3 * (size_t)(s * 10) * n1;
    assert_memory_equal(ga, gr, 12 * (size_t)n1); /* the guide is kept as it is */
    for (int ch = 1; ch < 10; ch++) {
      const float *cr = a.pos + 3 * (size_t)(s * 10 + ch) * n1;
      float d = sqrtf((cr[0] - gr[0]) * (cr[0] - gr[0]) + (cr[1] - gr[1]) * (cr[1] - gr[1]) +
                      (cr[2] - gr[2]) * (cr[2] - gr[2]));
      assert_true(d <= p.spread * spacing * 1.0001f + 1e-6f);
      far = fmax(far, d / spacing);
      sum += d / spacing, counted++;
      for (uint32_t i = 0; i < 3 * n1; i++) assert_true(isfinite(cr[i]));
    }
  }
  print_message("child root offsets: mean %.3f, max %.3f guide spacings\n", sum / counted, far);
  /* Uniform over a disc of radius 0.5: mean 1/3, reaching near the edge. */
  assert_true(sum / counted > 0.25 && sum / counted < 0.42);
  assert_true(far > 0.45);
  hfr_hair_free(&a);
  hfr_hair_free(&b);
  hfr_hair_free(&c);
  /* Every guide written twice: the copy is no neighbour, so the children
   * spread over the spacing to the other guides as before, not all on
   * their guide's root. */
  hfr_hair twice = g;
  twice.strands = 2 * g.strands, twice.points = 2 * g.points;
  twice.pos = malloc(sizeof(float) * 3 * twice.points);
  assert_non_null(twice.pos);
  memcpy(twice.pos, g.pos, sizeof(float) * 3 * g.points);
  memcpy(twice.pos + 3 * (size_t)g.points, g.pos, sizeof(float) * 3 * g.points);
  twice.thickness = NULL, twice.transparency = NULL, twice.color = NULL, twice.segments = NULL;
  p.children = 9, p.seed = 1;
  assert_int_equal(hfr_hair_interpolate(&twice, &p, &c), HF_OK);
  double on_root = 0, off = 0;
  for (uint32_t s = 0; s < twice.strands; s++) {
    const float *gr = twice.pos + 3 * (size_t)s * n1;
    for (int ch = 1; ch < 10; ch++) {
      const float *cr = c.pos + 3 * (size_t)(s * 10 + ch) * n1;
      float d = sqrtf((cr[0] - gr[0]) * (cr[0] - gr[0]) + (cr[1] - gr[1]) * (cr[1] - gr[1]) +
                      (cr[2] - gr[2]) * (cr[2] - gr[2]));
      on_root += d == 0, off += d;
    }
  }
  print_message("guides written twice: %.0f children on their guide's root, mean offset %.4g\n",
                on_root, off / (twice.strands * 9.0));
  assert_true(on_root == 0);
  free(twice.pos);
  hfr_hair_free(&c);
  /* Limits. */
  p.children = 100000;
  assert_int_equal(hfr_hair_interpolate(&g, &p, &c), HF_EINVAL);
  hfr_hair_free(&g);
}

/* The ellipsoid fitted under a scalp's roots is the head; under a flat
 * patch it lies below the patch on the side away from the hair. Both leave
 * 98% of the roots on or outside. */
static void test_fit_roots(void **state) {
  (void)state;
  hfr_hair h = small_style(HFR_STYLE_STRAIGHT, 3000);
  hfr_ellipsoid e;
  assert_int_equal(hfr_ellipsoid_fit_roots(&h, &e), HF_OK);
  const float head[3] = HFR_HEAD_RADII;
  /* Its semi-axes, matched to the head's by direction. */
  for (int a = 0; a < 3; a++) {
    int k = 0;
    for (int j = 1; j < 3; j++)
      if (fabsf(e.axes[a][j]) > fabsf(e.axes[a][k])) k = j;
    print_message("axis %d (model %c): %.3f (head %.3f)\n", a, "xyz"[k], e.radii[a], head[k]);
    assert_true(fabsf(e.axes[a][k]) > 0.95f);
    assert_true(fabsf(e.radii[a] - head[k]) < 0.1f * head[k]);
  }
  for (int k = 0; k < 3; k++) assert_true(fabsf(e.centre[k]) < 0.1f);
  /* The same with every root written twice (as exporters often do): the
   * same head, not a flat patch's body. */
  hfr_hair d = {0};
  d.strands = h.strands, d.points = h.points + h.strands;
  d.segments = malloc(sizeof(uint16_t) * d.strands);
  d.pos = malloc(sizeof(float) * 3 * d.points);
  assert_non_null(d.segments);
  assert_non_null(d.pos);
  for (uint32_t s = 0, src = 0, dst = 0; s < h.strands; s++) {
    uint32_t n = hfr_hair_strand_segments(&h, s) + 1;
    d.segments[s] = (uint16_t)n;
    memcpy(d.pos + 3 * (size_t)dst, h.pos + 3 * (size_t)src, 3 * sizeof(float));
    memcpy(d.pos + 3 * ((size_t)dst + 1), h.pos + 3 * (size_t)src, 3 * n * sizeof(float));
    src += n, dst += n + 1;
  }
  hfr_ellipsoid ed;
  assert_int_equal(hfr_ellipsoid_fit_roots(&d, &ed), HF_OK);
  for (int a = 0; a < 3; a++) {
    print_message("roots written twice: axis %d %.3f (once: %.3f)\n", a, ed.radii[a], e.radii[a]);
    assert_true(fabsf(ed.radii[a] - e.radii[a]) < 0.01f * e.radii[a]);
  }
  hfr_hair_free(&d);
  hfr_hair_free(&h);

  /* A patch in y = 0 with strands growing up. */
  hfr_hair p = {0};
  p.strands = 400, p.points = 800, p.default_segments = 1;
  p.pos = malloc(12 * 800);
  assert_non_null(p.pos);
  for (int s = 0; s < 400; s++) {
    float *q = p.pos + 6 * s;
    q[0] = (float)(s % 20) / 19 - 0.5f, q[1] = 0, q[2] = (float)(s / 20) / 19 - 0.5f;
    q[3] = q[0], q[4] = 0.1f, q[5] = q[2];
  }
  assert_int_equal(hfr_ellipsoid_fit_roots(&p, &e), HF_OK);
  print_message("patch: centre %.3f %.3f %.3f\n", e.centre[0], e.centre[1], e.centre[2]);
  assert_true(e.centre[1] < 0);
  int outside = 0;
  for (int s = 0; s < 400; s++) {
    const float *q = p.pos + 6 * s;
    float d2 = 0;
    for (int a = 0; a < 3; a++) {
      float t = 0;
      for (int k = 0; k < 3; k++) t += (q[k] - e.centre[k]) * e.axes[a][k];
      d2 += (t / e.radii[a]) * (t / e.radii[a]);
    }
    outside += d2 >= 1;
  }
  assert_true(outside >= 0.98 * 400);
  hfr_mesh m;
  assert_int_equal(hfr_mesh_ellipsoid(&e, 16, 8, &m), HF_OK);
  assert_int_equal(m.vertices, 16 * 8 * 6);
  hfr_mesh_free(&m);
  p.strands = 3;
  assert_int_equal(hfr_ellipsoid_fit_roots(&p, &e), HF_EINVAL);
  /* A row of strands: roots along x, growing up (+y) and leaning to +z.
   * The body lies under them (-y), as wide as a quarter of the row. */
  p.strands = 400;
  for (int s = 0; s < 400; s++) {
    float *q = p.pos + 6 * s;
    q[0] = (float)s / 399 - 0.5f, q[1] = 0, q[2] = 0;
    q[3] = q[0], q[4] = 0.1f, q[5] = 0.02f;
  }
  assert_int_equal(hfr_ellipsoid_fit_roots(&p, &e), HF_OK);
  print_message("row: centre %.3f %.3f %.3f radii %.3f %.3f %.3f\n", e.centre[0], e.centre[1],
                e.centre[2], e.radii[0], e.radii[1], e.radii[2]);
  assert_true(e.centre[1] < 0);
  for (int a = 0; a < 3; a++) assert_true(e.radii[a] > 0.01f);
  /* Every root on or outside it. */
  for (int s = 0; s < 400; s += 7) {
    const float *q = p.pos + 6 * s;
    float d2 = 0;
    for (int a = 0; a < 3; a++) {
      float t = 0;
      for (int k = 0; k < 3; k++) t += (q[k] - e.centre[k]) * e.axes[a][k];
      d2 += (t / e.radii[a]) * (t / e.radii[a]);
    }
    assert_true(d2 >= 0.99f);
  }
  /* Roots all at one point: nothing to fit. */
  for (int s = 0; s < 400; s++) p.pos[6 * s] = p.pos[6 * s + 3] = 0;
  assert_int_equal(hfr_ellipsoid_fit_roots(&p, &e), HF_ERANGE);
  hfr_hair_free(&p);
}

/* A model with nothing to fit an occluder under is drawn without one, and
 * the loader says so rather than leaving an empty background layer
 * unexplained; a row of strands gets one. */
static void test_fit_nothing_warned(void **state) {
  (void)state;
  hfr_hair t = {0};
  t.strands = 6, t.points = 12, t.default_segments = 1, t.default_thickness = 0.001f;
  t.pos = calloc(36, sizeof(float));
  assert_non_null(t.pos);
  for (int s = 0; s < 6; s++) t.pos[6 * s + 3] = 0.1f * s, t.pos[6 * s + 4] = 1; /* a tuft */
  char path[256], warn[1024], err[256];
  tmp_path(path, sizeof path, "tuft.hair");
  assert_int_equal(hfr_hair_save(path, &t), HF_OK);
  hfr_asset_opts o;
  hfr_asset_defaults(&o);
  hfr_hair h;
  hfr_mesh occ;
  assert_int_equal(hfr_asset_load(path, &o, &h, &occ, warn, sizeof warn, err, sizeof err), HF_OK);
  print_message("tuft: %s\n", warn);
  assert_non_null(strstr(warn, "no occluder fitted under the roots (the roots are all at one point)"));
  assert_int_equal(occ.vertices, 0);
  hfr_hair_free(&h);
  /* Three strands: too few. */
  t.strands = 3, t.points = 6;
  for (int s = 0; s < 3; s++) t.pos[6 * s] = t.pos[6 * s + 3] = (float)s;
  assert_int_equal(hfr_hair_save(path, &t), HF_OK);
  assert_int_equal(hfr_asset_load(path, &o, &h, &occ, warn, sizeof warn, err, sizeof err), HF_OK);
  assert_non_null(strstr(warn, "no occluder fitted under the roots (fewer than 4 strands)"));
  assert_int_equal(occ.vertices, 0);
  hfr_hair_free(&h);
  /* A row of six: an occluder, no such warning. */
  t.strands = 6, t.points = 12;
  for (int s = 0; s < 6; s++) t.pos[6 * s] = t.pos[6 * s + 3] = (float)s;
  assert_int_equal(hfr_hair_save(path, &t), HF_OK);
  assert_int_equal(hfr_asset_load(path, &o, &h, &occ, warn, sizeof warn, err, sizeof err), HF_OK);
  assert_null(strstr(warn, "no occluder"));
  assert_true(occ.vertices > 0);
  hfr_hair_free(&h);
  hfr_mesh_free(&occ);
  /* --occluder none: nothing asked for, nothing said. */
  t.strands = 3, t.points = 6;
  assert_int_equal(hfr_hair_save(path, &t), HF_OK);
  o.occluder = "none";
  assert_int_equal(hfr_asset_load(path, &o, &h, &occ, warn, sizeof warn, err, sizeof err), HF_OK);
  assert_null(strstr(warn, "no occluder"));
  hfr_hair_free(&h);
  remove(path);
  free(t.pos);
}

/* The regime line keeps three significant digits: strands 1e-5 px wide
 * and a hair fraction of 4e-4 are not printed as zeros. */
static void test_stats_line_small_values(void **state) {
  (void)state;
  hfr_frame_stats s = {.valid = 1, .alpha_p10 = 1.2e-5, .alpha_p50 = 1.46e-5,
                       .alpha_p90 = 1.79e-5, .sample_coverage = 1.1e-4,
                       .hair_pixels = 3.66e-4, .full_pixels = 0, .gt_opaque = -1,
                       .width_px_p10 = 1.33e-5, .width_px_p50 = 1.46e-5,
                       .width_px_p90 = 1.63e-5, .points_in_view = 125182,
                       .points_picked = 200000, .points_model = 200000};
  char line[512];
  hfr_frame_stats_format(&s, line, sizeof line);
  print_message("%s\n", line);
  assert_non_null(strstr(line, "covered-sample alpha p10/p50/p90 1.2e-05/1.46e-05/1.79e-05"));
  assert_non_null(strstr(line, "hair pixels 0.000366"));
  assert_non_null(strstr(line, "strand width p10/p50/p90 1.33e-05/1.46e-05/1.63e-05 px"));
  s.width_px_p50 = 0.0559, s.gt_opaque = 0.096;
  hfr_frame_stats_format(&s, line, sizeof line);
  assert_non_null(strstr(line, "/0.0559/"));
  assert_non_null(strstr(line, "opaque in the ground truth 0.096"));
  assert_non_null(strstr(line, "(at 125182 points in view, of the model's 200000)"));
  /* A model of more points than are measured says which ones "in view"
   * counts: it is of the picked points, not of the model's. */
  s.points_picked = 613150, s.points_model = 1226300, s.points_in_view = 613150;
  hfr_frame_stats_format(&s, line, sizeof line);
  assert_non_null(strstr(line, "(at 613150 points in view, of 613150 picked evenly from the "
                               "model's 1226300)"));
}

/* The typical diameter --regimes scales to its target width in pixels is
 * that of the points drawn with a width: tips written 0 do not make it 0,
 * and an array of zeros (which the renderer ignores for the header's
 * width) gives the header's width. A 0 left the target unreached (scale
 * 1) while the manifest recorded it. */
static void test_typical_thickness(void **state) {
  (void)state;
  hfr_hair h = {0};
  h.strands = 100, h.points = 300, h.default_segments = 2, h.default_thickness = 0.002f;
  h.pos = calloc(900, sizeof(float));
  h.thickness = calloc(300, sizeof(float));
  assert_non_null(h.pos);
  assert_non_null(h.thickness);
  for (int s = 0; s < 100; s++)
    for (int i = 0; i < 3; i++) h.pos[9 * s + 3 * i] = 0.1f * s, h.pos[9 * s + 3 * i + 1] = 0.5f * i;
  /* Every strand: a width at the root, 0 at its two other points. */
  for (int s = 0; s < 100; s++) h.thickness[3 * s] = 0.01f;
  assert_true(fabsf(hr_typical_thickness(&h) - 0.01f) < 1e-7f);
  /* Only zeros: the header's width, as drawn. */
  memset(h.thickness, 0, 300 * sizeof(float));
  float c[3], r;
  hfr_hair_bounds(&h, c, &r);
  float drawn = hfr_hair_default_thickness(&h, r, NULL);
  assert_true(drawn > 0);
  assert_true(fabsf(hr_typical_thickness(&h) - drawn) < 1e-9f);
  hfr_hair_free(&h);
}

/* A small OBJ: a quad (two triangles after triangulation) and a triangle;
 * normals made where it has none. Bad files are refused with a reason. */
static void test_mesh_file(void **state) {
  (void)state;
  char path[256], err[512] = "";
  tmp_path(path, sizeof path, "occ.obj");
  FILE *f = fopen(path, "w");
  assert_non_null(f);
  fputs("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf 1 2 5\n", f);
  fclose(f);
  hfr_mesh m;
  int rc = hfr_mesh_load(path, &m, err, sizeof err);
  if (rc == HF_EUNSUPPORTED) {
    remove(path);
    print_message("no mesh reader in this build: %s\n", err);
    skip();
  }
  assert_int_equal(rc, HF_OK);
  assert_int_equal(m.vertices, 9);
  for (uint32_t i = 0; i < m.vertices; i++) {
    const float *v = m.v + 6 * i;
    float l = sqrtf(v[3] * v[3] + v[4] * v[4] + v[5] * v[5]);
    assert_true(fabsf(l - 1) < 1e-4f);
  }
  assert_int_equal(hfr_mesh_orient(&m, HFR_AXIS_Z, 10), HF_OK);
  hfr_mesh_free(&m);
  f = fopen(path, "w");
  assert_non_null(f);
  fputs("v 0 0 0\nv 1 0 0\nl 1 2\n", f); /* lines only */
  fclose(f);
  assert_true(hfr_mesh_load(path, &m, err, sizeof err) < 0);
  print_message("lines only: %s\n", err);
  assert_true(strlen(err) > 0);
  remove(path);
  assert_true(hfr_mesh_load("/nonexistent/head.obj", &m, err, sizeof err) < 0);
}

/* hfr_asset_load: the width check comes before the units (1.0 in
 * centimetres is still the writer's unset value), children come last. */
static void test_asset_load(void **state) {
  (void)state;
  hfr_asset_opts o;
  hfr_asset_defaults(&o);
  o.up = HFR_AXIS_Y, o.scale = 0.1f; /* the field case is in centimetres */
  o.children.children = 3;
  hfr_hair h;
  hfr_mesh occ;
  char err[256] = "", warn[512] = "";
  assert_int_equal(hfr_asset_load(HF_TEST_DATA "/hair-default-header.hair", &o, &h, &occ, warn,
                                  sizeof warn, err, sizeof err), HF_OK);
  assert_true(strlen(warn) > 0);
  assert_int_equal(h.strands, 1500 * 4);
  float c[3], r;
  hfr_hair_bounds(&h, c, &r);
  assert_true(r > 1.5f && r < 2.5f); /* 19 cm */
  assert_non_null(h.thickness);
  assert_true(h.thickness[0] > 0.3f * r / 2000 && h.thickness[0] < 2 * r / 2000);
  assert_true(occ.vertices > 0);
  hfr_hair_free(&h);
  hfr_mesh_free(&occ);
  o.occluder = "none";
  o.thickness = 0.008f; /* 80 um in centimetres: no warning */
  o.children.children = 0;
  assert_int_equal(hfr_asset_load(HF_TEST_DATA "/hair-default-header.hair", &o, &h, &occ, warn,
                                  sizeof warn, err, sizeof err), HF_OK);
  assert_string_equal(warn, "");
  assert_int_equal(occ.vertices, 0);
  assert_true(fabsf(h.default_thickness - 0.0008f) < 1e-9f);
  hfr_hair_free(&h);
  /* --opacity replaces the file's transparency for every strand. */
  o.opacity = 0.25f;
  assert_int_equal(hfr_asset_load(HF_TEST_DATA "/hair-default-header.hair", &o, &h, &occ, warn,
                                  sizeof warn, err, sizeof err), HF_OK);
  assert_null(h.transparency);
  assert_true(fabsf(h.default_transparency - 0.75f) < 1e-6f);
  hfr_hair_free(&h);
  o.opacity = 1.5f;
  assert_int_equal(hfr_asset_load(HF_TEST_DATA "/hair-default-header.hair", &o, &h, &occ, warn,
                                  sizeof warn, err, sizeof err), HF_EINVAL);
  assert_non_null(strstr(err, "opacity 1.5"));
  o.opacity = 0;
  o.occluder = "/nonexistent/head.obj";
  assert_true(hfr_asset_load(HF_TEST_DATA "/hair-default-header.hair", &o, &h, &occ, warn,
                             sizeof warn, err, sizeof err) < 0);
  assert_true(strlen(err) > 0);
}

/* Writes h to a temporary file and loads it as o says. */
static int load_as(const hfr_hair *h, const hfr_asset_opts *o, hfr_hair *out, char *warn,
                   size_t warnlen, char *err, size_t errlen) {
  char path[256];
  tmp_path(path, sizeof path, "rules.hair");
  assert_int_equal(hfr_hair_save(path, h), HF_OK);
  hfr_mesh occ;
  int rc = hfr_asset_load(path, o, out, &occ, warn, warnlen, err, errlen);
  remove(path);
  if (rc == HF_OK) hfr_mesh_free(&occ);
  return rc;
}

/* A model written as other .hair readers take it but outside the format's
 * letter (bytes after the arrays, an undefined flag bit, a strand with a
 * NaN point, a transparency above 1) is drawn, each departure said. */
static void test_asset_read_as_reference(void **state) {
  (void)state;
  hfr_hair h = small_style(HFR_STYLE_WAVY, 201);
  uint32_t strands = h.strands;
  h.pos[3 * 5 + 1] = NAN; /* point 5: in strand 0 (every strand has more) */
  assert_true(hfr_hair_strand_segments(&h, 0) >= 5);
  assert_non_null(h.transparency);
  h.transparency[h.points - 1] = 1.25f;
  char path[256];
  tmp_path(path, sizeof path, "reference.hair");
  assert_int_equal(hfr_hair_save(path, &h), HF_OK);
  hfr_hair_free(&h);
  FILE *f = fopen(path, "r+b");
  assert_non_null(f);
  unsigned char flags[4];
  assert_int_equal(fseek(f, 12, SEEK_SET), 0);
  assert_int_equal(fread(flags, 1, 4, f), 4);
  flags[1] |= 0x01; /* bit 8 */
  assert_int_equal(fseek(f, 12, SEEK_SET), 0);
  assert_int_equal(fwrite(flags, 1, 4, f), 4);
  assert_int_equal(fseek(f, 0, SEEK_END), 0);
  assert_int_equal(fwrite("exporter tail", 1, 13, f), 13);
  assert_int_equal(fclose(f), 0);

  hfr_asset_opts o;
  hfr_asset_defaults(&o);
  o.occluder = "none";
  hfr_mesh occ;
  char warn[2048] = "", err[256] = "";
  assert_int_equal(hfr_asset_load(path, &o, &h, &occ, warn, sizeof warn, err, sizeof err), HF_OK);
  print_message("warnings: %s\n", warn);
  assert_int_equal(h.strands, strands - 1);
  assert_non_null(strstr(warn, "1 strand(s) with a NaN or Inf"));
  assert_non_null(strstr(warn, "1 per-point value(s) out of range clamped"));
  assert_non_null(strstr(warn, "flag bits 0x100"));
  assert_non_null(strstr(warn, "13 byte(s) after the arrays"));
  for (size_t i = 0; i < 3 * (size_t)h.points; i++) assert_true(isfinite(h.pos[i]));
  assert_true(h.transparency[h.points - 1] == 1.0f);
  hfr_hair_free(&h);
  hfr_mesh_free(&occ);
  remove(path);
}

/* --thickness is the user's diameter: kept at any width (it was replaced by
 * R / 2000 above 0.02 R), with a warning where implausible, and children
 * take it too. */
static void test_thickness_option(void **state) {
  (void)state;
  hfr_hair h = small_style(HFR_STYLE_WAVY, 200);
  float c[3], r;
  hfr_hair_bounds(&h, c, &r);
  hfr_asset_opts o;
  hfr_asset_defaults(&o);
  o.occluder = "none";
  hfr_hair got;
  char warn[1024], err[256];
  const float rel[] = {0.001f, 0.019f, 0.021f, 0.1f, 2};
  for (size_t i = 0; i < sizeof rel / sizeof rel[0]; i++) {
    o.thickness = rel[i] * r;
    assert_int_equal(load_as(&h, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
    print_message("--thickness %g R: %s\n", rel[i], warn);
    float gc[3], gr;
    hfr_hair_bounds(&got, gc, &gr);
    const char *why = "";
    assert_true(hfr_hair_default_thickness(&got, gr, &why) == o.thickness);
    assert_null(why);
    if (rel[i] > HFR_WIDTH_MAX_REL)
      assert_non_null(strstr(warn, "--thickness"));
    else
      assert_string_equal(warn, "");
    hfr_hair_free(&got);
  }
  o.thickness = 0.1f * r;
  o.children.children = 3;
  assert_int_equal(load_as(&h, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
  assert_non_null(got.thickness);
  assert_true(got.thickness[0] > 0.05f * r); /* tapered at most to half */
  hfr_hair_free(&got);
  hfr_hair_free(&h);
}

/* A header transparency without per-point values: one rule with children
 * or without, a warning naming the value where it is not in [0, 1]. */
static void test_header_transparency(void **state) {
  (void)state;
  hfr_hair h = small_style(HFR_STYLE_STRAIGHT, 100);
  free(h.transparency);
  h.transparency = NULL;
  hfr_asset_opts o;
  hfr_asset_defaults(&o);
  o.occluder = "none";
  hfr_hair got;
  char warn[1024], err[256];
  const struct {
    float header, drawn;
    const char *said;
  } cases[] = {{NAN, 0, "(nan)"}, {INFINITY, 0, "(inf)"}, {-1, 0, "(-1)"}, {2, 0, "(2)"},
               {1, 1, "nothing is drawn"}, {0.3f, 0.3f, NULL}, {0, 0, NULL}};
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    h.default_transparency = cases[i].header;
    assert_true(hfr_hair_default_transparency(&h, NULL) == cases[i].drawn);
    for (int k = 0; k < 2; k++) {
      o.children.children = k ? 3 : 0;
      assert_int_equal(load_as(&h, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
      print_message("header %g, children %d: %s\n", cases[i].header, o.children.children, warn);
      if (cases[i].said)
        assert_non_null(strstr(warn, cases[i].said));
      else
        assert_string_equal(warn, "");
      if (k) {
        assert_non_null(got.transparency);
        for (uint32_t p = 0; p < got.points; p++)
          assert_true(got.transparency[p] == cases[i].drawn);
      } else {
        assert_null(got.transparency);
        assert_true(got.default_transparency == cases[i].drawn);
      }
      hfr_hair_free(&got);
    }
  }
  /* Every per-point value 1: nothing is drawn, and that is said. */
  h.transparency = malloc(sizeof(float) * h.points);
  assert_non_null(h.transparency);
  for (uint32_t p = 0; p < h.points; p++) h.transparency[p] = 1;
  o.children.children = 0;
  assert_int_equal(load_as(&h, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
  assert_non_null(strstr(warn, "nothing is drawn"));
  hfr_hair_free(&got);
  hfr_hair_free(&h);
}

/* Extents computed in double; a model whose extent float cannot draw
 * (huge, tiny, or every point coinciding) is refused with the radius and
 * the way out; an all-zero thickness array is taken as none. */
static void test_extent_and_zero_widths(void **state) {
  (void)state;
  hfr_hair h = small_style(HFR_STYLE_STRAIGHT, 100);
  double cd[3], rd;
  hfr_hair_extent(&h, cd, &rd);
  float c[3], r;
  hfr_hair_bounds(&h, c, &r);
  assert_true(fabs(rd - r) < 1e-6 * r);
  assert_int_equal(hfr_hair_check_extent(&h, 1, NULL, 0), HF_OK);
  hfr_asset_opts o;
  hfr_asset_defaults(&o);
  o.occluder = "none";
  hfr_hair got;
  char warn[1024], err[512];
  /* Coordinates near FLT_MAX: the radius is finite in double. */
  hfr_hair big = small_style(HFR_STYLE_STRAIGHT, 100);
  const float k = 1e38f / r;
  for (size_t i = 0; i < 3 * (size_t)big.points; i++) big.pos[i] *= k;
  hfr_hair_extent(&big, cd, &rd);
  assert_true(isfinite(rd) && fabs(rd / ((double)r * k) - 1) < 1e-5);
  const float scales[] = {1e30f, 1e-30f, 1e20f, 1e-10f};
  for (size_t s = 0; s < sizeof scales / sizeof scales[0] + 1; s++) {
    for (size_t i = 0; i < 3 * (size_t)h.points; i++)
      big.pos[i] = s < 4 ? h.pos[i] * scales[s] : 2e38f + h.pos[i]; /* last: all coincide */
    err[0] = 0;
    assert_int_equal(load_as(&big, &o, &got, warn, sizeof warn, err, sizeof err), HF_ERANGE);
    print_message("%s\n", err);
    assert_non_null(strstr(err, s < 4 ? "bounding radius" : "no extent"));
    if (s < 4) assert_non_null(strstr(err, "--units"));
  }
  /* Far from the origin, float rounds the file's points to a grid coarser
   * than the model's detail: refused, naming the grid and the way out
   * (the model at 1e6 is rounded to steps of 1/16, a third of its size
   * here). Nearer, it loads. */
  for (size_t i = 0; i < 3 * (size_t)h.points; i++) big.pos[i] = h.pos[i] * 0.2f / r + 1e6f;
  err[0] = 0;
  assert_int_equal(load_as(&big, &o, &got, warn, sizeof warn, err, sizeof err), HF_ERANGE);
  if (!strstr(err, "spacing is 0.0625") || !strstr(err, "nearer the origin"))
    fail_msg("far from the origin: %s", err);
  for (size_t i = 0; i < 3 * (size_t)h.points; i++) big.pos[i] = h.pos[i] * 0.2f / r + 100.0f;
  assert_int_equal(load_as(&big, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
  hfr_hair_free(&got);
  /* --scale brings a huge model into range. */
  for (size_t i = 0; i < 3 * (size_t)h.points; i++) big.pos[i] = h.pos[i] * 1e30f;
  o.scale = 1e-30f;
  assert_int_equal(load_as(&big, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
  float gc[3], gr;
  hfr_hair_bounds(&got, gc, &gr);
  assert_true(fabsf(gr / r - 1) < 1e-3f);
  hfr_hair_free(&got);
  hfr_hair_free(&big);
  o.scale = 1;
  /* All-zero per-point thickness: the header rule instead, with a warning. */
  for (uint32_t p = 0; p < h.points; p++) h.thickness[p] = 0;
  h.default_thickness = 0.0008f;
  assert_int_equal(hfr_hair_thickness_all_zero(&h), 1);
  assert_int_equal(load_as(&h, &o, &got, warn, sizeof warn, err, sizeof err), HF_OK);
  print_message("zero widths: %s\n", warn);
  assert_non_null(strstr(warn, "thickness is 0"));
  assert_null(got.thickness);
  assert_true(got.default_thickness == 0.0008f);
  hfr_hair_free(&got);
  /* A zero tip taper is not that. */
  h.thickness[1] = 0.0008f;
  assert_int_equal(hfr_hair_thickness_all_zero(&h), 0);
  hfr_hair_free(&h);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_field_case_thickness),
    cmocka_unit_test(test_widths_across_units),
    cmocka_unit_test(test_axes_and_units),
    cmocka_unit_test(test_children),
    cmocka_unit_test(test_fit_roots),
    cmocka_unit_test(test_fit_nothing_warned),
    cmocka_unit_test(test_stats_line_small_values),
    cmocka_unit_test(test_typical_thickness),
    cmocka_unit_test(test_mesh_file),
    cmocka_unit_test(test_asset_load),
    cmocka_unit_test(test_asset_read_as_reference),
    cmocka_unit_test(test_thickness_option),
    cmocka_unit_test(test_header_transparency),
    cmocka_unit_test(test_extent_and_zero_widths),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
