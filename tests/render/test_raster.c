/* The GL passes on a headless context: hashed-alpha coverage statistics,
 * determinism of the sample mask, the A-buffer blend against a host
 * sort-and-blend, and the ranges of a whole rendered frame. */
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

#include <cjson/cJSON.h>

#include "hr_internal.h"
#include "hr_math.h"
#include "hr_shaders.h"
#include "test_common.h"

#define W 64
#define H 64
#define S 4


/* Parallel horizontal strands in the z = 0 plane, far enough apart not to
 * overlap. flat_view makes them just over one pixel wide, so that alpha =
 * opacity exactly and each is drawn as a quad of about one pixel. */
static void synthetic(hfr_hair *h, float opacity) {
  const int strands = 12, seg = 8;
  memset(h, 0, sizeof *h);
  h->strands = strands;
  h->points = strands * (seg + 1);
  h->default_segments = seg;
  h->pos = malloc(12 * (size_t)h->points);
  h->thickness = malloc(4 * (size_t)h->points);
  h->transparency = malloc(4 * (size_t)h->points);
  assert_non_null(h->pos);
  assert_non_null(h->thickness);
  assert_non_null(h->transparency);
  for (int s = 0; s < strands; s++)
    for (int i = 0; i <= seg; i++) {
      size_t p = (size_t)s * (seg + 1) + i;
      h->pos[3 * p] = -1 + 2.0f * i / seg;
      h->pos[3 * p + 1] = -1 + 2.0f * s / (strands - 1);
      h->pos[3 * p + 2] = 0;
      h->thickness[p] = 1.0f;
      h->transparency[p] = 1 - opacity;
    }
}

/* Thickness scale that makes a strand of model thickness 1 in the z = 0
 * plane px pixels wide: the camera looks straight at the plane, so every
 * point of it is at view depth = the camera distance. */
static float scale_for_pixels(hfr_renderer *r, const hfr_view *v, float px) {
  hr_camera cam;
  hr_camera_from_view(r, v, &cam);
  return px * hr_len(cam.eye) / cam.px_per_unit;
}

static void flat_view_on(hfr_renderer *r, hfr_view *v) {
  hfr_view_defaults(v);
  v->width = W, v->height = H;
  v->cam_yaw_deg = 0, v->cam_pitch_deg = 0;
  v->shadow_size = 0;
  v->thickness_scale = scale_for_pixels(r, v, 1.03f);
}

static void flat_view(hfr_view *v) { flat_view_on(R, v); }

static void pass(const hfr_view *v, uint32_t seed, int opaque, float *out) {
  hr_camera cam, light;
  hr_camera_from_view(R, v, &cam);
  hr_camera_light(R, v, &light);
  char err[512] = "";
  int rc = hr_pass_ms(R, v, &cam, &light, seed, 0, 0, opaque, out, NULL, err, sizeof err);
  if (rc != HF_OK) fail_msg("pass: %s", err);
}

/* Each sample the geometry covers is kept with probability alpha, the
 * samples of a pixel independently: per pixel with m covered samples the
 * kept count is Binomial(m, alpha). Checked through its mean and variance
 * over all pixels (fully correlated bits would inflate the variance ~m-fold). */
static void test_hashed_alpha_binomial(void **state) {
  (void)state;
  const float alphas[] = {0.1f, 0.3f, 0.7f};
  float *geo = malloc(sizeof(float) * W * H * S * 6), *st = malloc(sizeof(float) * W * H * S * 6);
  assert_non_null(geo);
  assert_non_null(st);
  for (size_t a = 0; a < sizeof alphas / sizeof alphas[0]; a++) {
    const double alpha = alphas[a];
    hfr_hair h;
    synthetic(&h, (float)alpha);
    char err[256];
    assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
    hfr_view v;
    flat_view(&v);
    pass(&v, 0, 1, geo);
    double kept = 0, covered = 0, sq = 0, var = 0;
    int pixels = 0;
    for (uint32_t seed = 1; seed <= 4; seed++) {
      pass(&v, seed, 0, st);
      for (int p = 0; p < W * H; p++) {
        int m = 0, k = 0;
        for (int s = 0; s < S; s++) {
          const float *g = geo + ((size_t)p * S + s) * 6, *f = st + ((size_t)p * S + s) * 6;
          if (f[2] > 0) {
            assert_true(g[2] > 0); /* never outside the geometry */
            assert_true(fabs(f[2] - alpha) < 1e-5);
            k++;
          }
          if (g[2] > 0) m++;
        }
        if (!m) continue;
        pixels++;
        kept += k, covered += m;
        sq += (k - m * alpha) * (k - m * alpha);
        var += m * alpha * (1 - alpha);
      }
    }
    double rate = kept / covered, sigma = sqrt(alpha * (1 - alpha) / covered);
    print_message("alpha %.2f: %d pixels, %.0f samples, kept %.4f (sigma %.4f), "
                  "variance ratio %.3f\n", alpha, pixels, covered, rate, sigma, sq / var);
    assert_true(covered > 2000);
    /* The mean within 5 sigma: hashed cells are about a pixel along a strand,
     * so neighbouring pixels are correlated and the effective count is lower. */
    assert_true(fabs(rate - alpha) < 5 * sigma * 2);
    assert_true(sq / var > 0.75 && sq / var < 1.3);
    hfr_hair_free(&h);
  }
  free(geo);
  free(st);
}

static void test_mask_deterministic(void **state) {
  (void)state;
  hfr_hair h;
  synthetic(&h, 0.5f);
  char err[256];
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
  hfr_view v;
  flat_view(&v);
  size_t n = (size_t)W * H * S * 6;
  float *a = malloc(sizeof(float) * n), *b = malloc(sizeof(float) * n),
        *c = malloc(sizeof(float) * n);
  assert_non_null(a);
  assert_non_null(b);
  assert_non_null(c);
  pass(&v, 7, 0, a);
  pass(&v, 7, 0, b);
  pass(&v, 8, 0, c);
  assert_memory_equal(a, b, sizeof(float) * n);
  size_t differ = 0, set = 0;
  for (size_t i = 0; i < n; i += 6) {
    set += a[i + 2] > 0;
    differ += (a[i + 2] > 0) != (c[i + 2] > 0);
  }
  print_message("seed 7: %zu samples kept; seed 8 differs in %zu\n", set, differ);
  assert_true(set > 500);
  /* Independent masks at alpha 0.5 differ in about half the covered samples. */
  assert_true(differ > set / 2);
  free(a);
  free(b);
  free(c);
  hfr_hair_free(&h);
}

/* Covered area at every strand width: a strand narrower than a pixel is a
 * one-pixel quad with its width in alpha, a wider one a quad as wide as
 * itself with alpha = opacity. The ground truth (subsample quads under the
 * same rule) and 64-sample stochastic transparency must then agree on the
 * frame's coverage, and the area must grow with the width beyond a pixel
 * (it stalled at one pixel, and at one subsample in the truth, before). */
/* Strands far wider than the frame (widths near float's largest, or a
 * thickness scale that overflows their product) cover what strands a few
 * frames wide cover; they were dropped or drawn in part. */
static void test_huge_widths_cover_the_frame(void **state) {
  (void)state;
  static const struct {
    float thickness, px;   /* model thickness, thickness scale in pixels per unit */
  } cases[] = {{1.0f, 4.0f * W}, {1.0f, 1e30f}, {1e30f, 1e30f}, {3.4e38f, 1.0f}};
  size_t first = 0;
  for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
    hfr_hair h;
    synthetic(&h, 1.0f);
    for (uint32_t p = 0; p < h.points; p++) h.thickness[p] = cases[c].thickness;
    char err[512] = "";
    assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
    hfr_view v;
    flat_view(&v);
    v.thickness_scale = scale_for_pixels(R, &v, cases[c].px);
    hfr_outputs o = {0};
    o.spp = 4, o.seed = 3;
    hf_image img;
    int rc = hfr_render(R, &v, &o, &img, NULL, err, sizeof err);
    if (rc != HF_OK) fail_msg("render: %s", err);
    int a = hf_image_channel(&img, "S0.alpha");
    assert_true(a >= 0);
    size_t covered = 0;
    for (size_t p = 0; p < (size_t)W * H; p++) covered += img.data[p * img.channels + a] > 0;
    print_message("thickness %g x scale for %g px: %zu of %d pixels covered\n",
                  (double)cases[c].thickness, (double)cases[c].px, covered, W * H);
    /* Every row, along the strands' length (the view frames them with a
     * margin at their ends): what the strands 4 frames wide cover. */
    if (c == 0) first = covered;
    assert_true(covered >= (size_t)W * H / 2);
    assert_int_equal(covered, first);
    hf_image_free(&img);
    hfr_hair_free(&h);
  }
}

static void test_wide_strands_area(void **state) {
  (void)state;
  hfr_hair h;
  synthetic(&h, 1.0f);
  /* Tilted, so that a strand crosses pixel and subsample rows at every
   * phase (a horizontal quad 1.2 subsamples wide covers one or two rows of
   * subsample centres along its whole length, whichever its height gives). */
  for (uint32_t p = 0; p < h.points; p++) h.pos[3 * p + 1] += 0.07f * h.pos[3 * p];
  char err[512] = "";
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
  const float widths[] = {0.3f, 0.8f, 1.6f, 3.0f};
  double area[4];
  for (int i = 0; i < 4; i++) {
    hfr_view v;
    flat_view(&v);
    v.thickness_scale = scale_for_pixels(R, &v, widths[i]);
    hfr_outputs o = {0};
    o.spp = 4, o.gt_supersample = 4, o.n_st = 1, o.st_spp[0] = 64, o.seed = 3;
    hf_image img;
    int rc = hfr_render(R, &v, &o, &img, NULL, err, sizeof err);
    if (rc != HF_OK) fail_msg("render: %s", err);
    int ga = hf_image_channel(&img, "gt.alpha"), sa = hf_image_channel(&img, "st64.alpha");
    assert_true(ga >= 0 && sa >= 0);
    double gt = 0, st = 0;
    for (size_t p = 0; p < (size_t)W * H; p++) {
      gt += img.data[p * img.channels + ga];
      st += img.data[p * img.channels + sa];
    }
    print_message("strand width %.1f px: coverage gt %.1f px, st64 %.1f px\n", widths[i], gt, st);
    assert_true(fabs(gt - st) < 0.03 * gt);
    area[i] = gt;
    hf_image_free(&img);
  }
  /* 12 strands across most of the frame: the area follows the width. */
  for (int i = 1; i < 4; i++) {
    double ratio = area[i] / area[0], want = widths[i] / widths[0];
    assert_true(ratio > 0.9 * want && ratio < 1.1 * want);
  }
  hfr_hair_free(&h);
}

static void style_scene(hfr_style s, int strands, hfr_view *v) {
  hfr_style_params p;
  hfr_style_defaults(s, &p);
  p.strands = strands;
  p.seed = 3;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  char err[256];
  assert_int_equal(hfr_renderer_set_hair(R, &h, 1, err, sizeof err), HF_OK);
  hfr_hair_free(&h);
  hfr_view_defaults(v);
  v->width = W, v->height = H;
  v->shadow_size = 256;
}

/* 600 curly strands in the default view, light and shadow map drawn. */
static void curly_scene_with_shadow(hfr_view *v, hr_camera *light) {
  style_scene(HFR_STYLE_CURLY, 600, v);
  hr_camera_light(R, v, light);
  char err[512] = "";
  if (hr_pass_shadow(R, v, light, 1, err, sizeof err) != HF_OK) fail_msg("shadow: %s", err);
}

static void test_gt_matches_cpu_blend(void **state) {
  (void)state;
  hfr_view v;
  hr_camera light;
  char err[512] = "";
  curly_scene_with_shadow(&v, &light);
  float *gpu = malloc(sizeof(float) * 3 * W * H), *cpu = malloc(sizeof(float) * 3 * W * H);
  assert_non_null(gpu);
  assert_non_null(cpu);
  hfr_stats st;
  memset(&st, 0, sizeof st);
  int rc = hr_pass_gt(R, &v, &light, 4, gpu, cpu, &st, err, sizeof err);
  if (rc != HF_OK) fail_msg("gt: %s", err);
  assert_int_equal(st.gt_truncated, 0); /* every list sorted in full */
  assert_true(st.gt_fragments > 1000);
  double maxd = 0;
  int hair_px = 0;
  for (int i = 0; i < W * H; i++) {
    const float *g = gpu + 3 * i, *c = cpu + 3 * i;
    hair_px += c[2] > 0;
    double d[3] = {fabs(g[0] * g[2] - c[0] * c[2]), fabs(g[1] * g[2] - c[1] * c[2]),
                   fabs(g[2] - c[2])};
    for (int k = 0; k < 3; k++) maxd = d[k] > maxd ? d[k] : maxd;
  }
  print_message("%llu fragments, deepest list %u, %d hair pixels, max |gpu - cpu| %.2e\n",
                (unsigned long long)st.gt_fragments, st.gt_max_depth, hair_px, maxd);
  assert_true(hair_px > 200);
  assert_true(maxd < 1e-4);
  free(gpu);
  free(cpu);
}

/* A window whose fragments do not fit one A-buffer is drawn in bands of
 * rows: the same ground truth as one large enough A-buffer, on the GPU and
 * on the host, the same fragment count, for the whole frame and for a crop;
 * a limit below one row's fragments fails and says so. */
static void test_gt_bands(void **state) {
  (void)state;
  hfr_view v;
  hr_camera light;
  char err[512] = "";
  curly_scene_with_shadow(&v, &light);
  const size_t n = (size_t)3 * W * H;
  float *whole = malloc(sizeof(float) * n), *gpu = malloc(sizeof(float) * n),
        *cpu = malloc(sizeof(float) * n);
  assert_true(whole && gpu && cpu);
  const uint32_t saved = R->max_fragments;
  uint64_t frame_fragments = 0;
  for (int crop = 0; crop < 2; crop++) {
    hfr_view cv = v;
    if (crop) cv.crop_x = W / 4, cv.crop_y = H / 3, cv.crop_w = W / 2, cv.crop_h = H / 2;
    int w, h;
    hr_view_target(&cv, &w, &h);
    hfr_stats one = {0}, banded = {0};
    R->max_fragments = 0;
    if (hr_pass_gt(R, &cv, &light, 4, whole, NULL, &one, err, sizeof err) != HF_OK)
      fail_msg("gt: %s", err);
    assert_true(one.gt_fragments > 1000);
    if (crop) assert_true(one.gt_fragments < frame_fragments); /* the crop's own fragments */
    frame_fragments = one.gt_fragments;
    R->max_fragments = (uint32_t)(one.gt_fragments / 5);
    if (hr_pass_gt(R, &cv, &light, 4, gpu, cpu, &banded, err, sizeof err) != HF_OK)
      fail_msg("banded gt: %s", err);
    double dg = 0, dc = 0;
    for (size_t i = 0; i < (size_t)w * h; i++) {
      const float *g = gpu + 3 * i, *c = cpu + 3 * i, *o = whole + 3 * i;
      for (int k = 0; k < 3; k++) dg = fmax(dg, fabs(g[k] - o[k]));
      /* The host blend, premultiplied as the GPU's is compared above. */
      dc = fmax(dc, fabs(c[2] - o[2]));
      for (int k = 0; k < 2; k++) dc = fmax(dc, fabs(c[k] * c[2] - o[k] * o[2]));
    }
    print_message("%s: %llu fragments, in bands of at most %u: max |banded - whole| %.2e, "
                  "host blend %.2e\n", crop ? "crop" : "frame",
                  (unsigned long long)one.gt_fragments, R->max_fragments, dg, dc);
    if (banded.gt_fragments != one.gt_fragments)
      fail_msg("%llu fragments in bands", (unsigned long long)banded.gt_fragments);
    assert_true(dg == 0);
    assert_true(dc < 1e-4);
  }
  R->max_fragments = 1;
  hfr_stats st = {0};
  assert_int_equal(hr_pass_gt(R, &v, &light, 4, gpu, NULL, &st, err, sizeof err), HF_ERANGE);
  assert_non_null(strstr(err, "in 1 row of"));
  R->max_fragments = saved;
  free(whole);
  free(gpu);
  free(cpu);
}

/* 12000 straight strands in the default view, no shadow map: lists
 * longer than one sort round of the resolve. */
static void dense_scene(hfr_view *v, hr_camera *light) {
  style_scene(HFR_STYLE_STRAIGHT, 12000, v);
  v->shadow_size = 0;
  hr_camera_light(R, v, light);
}

/* Dense hair: lists longer than one sort round, and more loop work per
 * pixel than llvmpipe allows one shader invocation. Still exact. */
static void test_gt_dense(void **state) {
  (void)state;
  hfr_view v;
  hr_camera light;
  dense_scene(&v, &light);
  float *gpu = malloc(sizeof(float) * 3 * W * H), *cpu = malloc(sizeof(float) * 3 * W * H);
  assert_non_null(gpu);
  assert_non_null(cpu);
  hfr_stats st;
  memset(&st, 0, sizeof st);
  char err[512] = "";
  int rc = hr_pass_gt(R, &v, &light, 4, gpu, cpu, &st, err, sizeof err);
  if (rc != HF_OK) fail_msg("gt: %s", err);
  assert_true(st.gt_max_depth > HR_ABUF_SORT);
  assert_true(st.gt_truncated > 0);
  double da = 0, dc = 0;
  for (int i = 0; i < W * H; i++) {
    const float *g = gpu + 3 * i, *c = cpu + 3 * i;
    da = fmax(da, fabs(g[2] - c[2]));
    dc = fmax(dc, fabs(g[0] * g[2] - c[0] * c[2]));
    dc = fmax(dc, fabs(g[1] * g[2] - c[1] * c[2]));
  }
  print_message("deepest list %u, %llu truncated lists: max |alpha| diff %.2e, "
                "max |colour| diff %.2e\n", st.gt_max_depth,
                (unsigned long long)st.gt_truncated, da, dc);
  assert_true(da < 1e-4);
  assert_true(dc < 1e-4);
  free(gpu);
  free(cpu);
}

/* max |a - b| over the premultiplied colour, highlight and alpha of n
 * pixels [n][3]. */
static double premultiplied_diff(const float *a, const float *b, size_t n) {
  double d = 0;
  for (size_t i = 0; i < n; i++) {
    const float *p = a + 3 * i, *q = b + 3 * i;
    d = fmax(d, fabs(p[2] - q[2]));
    for (int k = 0; k < 2; k++) d = fmax(d, fabs(p[k] * p[2] - q[k] * q[2]));
  }
  return d;
}

/* The transmittance cull (hr_gt_cull.c) on hair dense and wide enough that
 * most of each list lies behind a hundred strands: it keeps most fragments
 * out of the A-buffer and moves the truth by less than float rounding,
 * whether it draws the window from the start (HFR_GT_CULL_ON), turns on
 * when a window must be drawn again with deep lists (AUTO, here in bands
 * planned by its per-row bounds) or draws a crop; off, every fragment is
 * stored. */
static void test_gt_cull(void **state) {
  (void)state;
  hfr_view v;
  hr_camera light;
  hfr_style_params p;
  hfr_style_defaults(HFR_STYLE_PONYTAIL, &p);
  p.strands = 20000, p.seed = 3, p.opacity = 0.6f;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  char err[512] = "";
  assert_int_equal(hfr_renderer_set_hair(R, &h, 1, err, sizeof err), HF_OK);
  hfr_hair_free(&h);
  hfr_view_defaults(&v);
  v.width = W, v.height = H, v.shadow_size = 0;
  v.thickness_scale = 40; /* strands a few supersampled pixels wide */
  v.cam_yaw_deg = 90;     /* the tail's side: a hundred strands deep */
  hr_camera_light(R, &v, &light);
  const size_t n = (size_t)3 * W * H;
  float *off = malloc(sizeof(float) * n), *off_cpu = malloc(sizeof(float) * n),
        *on = malloc(sizeof(float) * n), *on_cpu = malloc(sizeof(float) * n),
        *aut = malloc(sizeof(float) * n);
  assert_true(off && off_cpu && on && on_cpu && aut);
  const uint32_t saved = R->max_fragments;
  const int saved_cull = R->gt_cull;
  R->max_fragments = 0;
  hfr_stats s_off = {0}, s_on = {0}, s_auto = {0};
  R->gt_cull = HFR_GT_CULL_OFF;
  if (hr_pass_gt(R, &v, &light, 4, off, off_cpu, &s_off, err, sizeof err) != HF_OK)
    fail_msg("gt, no cull: %s", err);
  R->gt_cull = HFR_GT_CULL_ON;
  if (hr_pass_gt(R, &v, &light, 4, on, on_cpu, &s_on, err, sizeof err) != HF_OK)
    fail_msg("gt, cull: %s", err);
  const double d_gpu = premultiplied_diff(on, off, (size_t)W * H),
               d_cpu = premultiplied_diff(on_cpu, off_cpu, (size_t)W * H);
  print_message("%llu fragments, %llu behind the cut (deepest list %u, then %u): max |cut - "
                "all| %.2e, host blend %.2e\n", (unsigned long long)s_off.gt_fragments,
                (unsigned long long)s_on.gt_fragments, s_off.gt_max_depth, s_on.gt_max_depth,
                d_gpu, d_cpu);
  assert_int_equal(s_off.gt_culled, 0);
  assert_int_equal(s_on.gt_culled, s_off.gt_fragments - s_on.gt_fragments);
  assert_true((double)s_off.gt_fragments / (4.0 * W * 4.0 * H) >= 8); /* deep lists */
  /* The estimate auto chooses by before a window's first draw: its quads,
   * the occluder left out, so at least what is drawn, and not far above. */
  hfr_view sv = v;
  sv.width *= 4, sv.height *= 4;
  hr_camera scam;
  hr_camera_from_view(R, &sv, &scam);
  double est = 0;
  assert_int_equal(hr_hair_window_fragments(R, &scam, v.thickness_scale, &est), HF_OK);
  print_message("estimated %.0f fragments before drawing\n", est);
  assert_true(est >= 0.9 * s_off.gt_fragments && est <= 3.0 * s_off.gt_fragments);
  assert_true(s_on.gt_fragments < s_off.gt_fragments / 2);
  assert_true(d_cpu < 1e-9);
  assert_true(d_gpu < 1e-5);
  /* AUTO with a pool too small for the window: counted, cut, banded. */
  R->gt_cull = HFR_GT_CULL_AUTO;
  R->max_fragments = (uint32_t)(s_on.gt_fragments / 3);
  if (hr_pass_gt(R, &v, &light, 4, aut, NULL, &s_auto, err, sizeof err) != HF_OK)
    fail_msg("gt, cull turned on, bands: %s", err);
  print_message("auto, in bands of at most %u: %llu fragments stored, %llu culled, max |auto "
                "- cut| %.2e\n", R->max_fragments, (unsigned long long)s_auto.gt_fragments,
                (unsigned long long)s_auto.gt_culled, premultiplied_diff(aut, on, (size_t)W * H));
  assert_int_equal(s_auto.gt_fragments, s_on.gt_fragments);
  assert_int_equal(s_auto.gt_culled, s_off.gt_fragments - s_on.gt_fragments);
  assert_true(premultiplied_diff(aut, on, (size_t)W * H) < 1e-5);
  /* A crop behind its own cut: the same as that window of the frame. */
  R->gt_cull = HFR_GT_CULL_ON;
  R->max_fragments = 0;
  hfr_view cv = v;
  cv.crop_x = 20, cv.crop_y = 12, cv.crop_w = 24, cv.crop_h = 30;
  hfr_stats s_crop = {0};
  if (hr_pass_gt(R, &cv, &light, 4, aut, NULL, &s_crop, err, sizeof err) != HF_OK)
    fail_msg("gt of a crop, cull: %s", err);
  double d_crop = 0;
  for (int y = 0; y < cv.crop_h; y++)
    d_crop = fmax(d_crop, premultiplied_diff(aut + (size_t)3 * y * cv.crop_w,
                                             on + 3 * ((size_t)(cv.crop_y + y) * W + cv.crop_x),
                                             (size_t)cv.crop_w));
  print_message("crop %dx%d: max |crop - frame| %.2e\n", cv.crop_w, cv.crop_h, d_crop);
  assert_true(d_crop < 1e-5);
  R->gt_cull = saved_cull;
  R->max_fragments = saved;
  free(off), free(off_cpu), free(on), free(on_cpu), free(aut);
}

/* The pool of A-buffer nodes is the renderer's, grown once and kept: a
 * second ground truth of the same window allocates nothing (llvmpipe
 * zero-fills every new buffer) and is the same to the bit, with the same
 * statistics; a window of fewer fragments keeps the pool as it is. */
static void test_gt_pool(void **state) {
  (void)state;
  hfr_view v;
  hr_camera light;
  dense_scene(&v, &light);
  const size_t n = (size_t)3 * W * H;
  float *a = malloc(sizeof(float) * n), *b = malloc(sizeof(float) * n);
  assert_true(a && b);
  char err[512] = "";
  hfr_stats s1 = {0}, s2 = {0}, s3 = {0};
  if (hr_pass_gt(R, &v, &light, 4, a, NULL, &s1, err, sizeof err) != HF_OK) fail_msg("%s", err);
  const uint32_t cap = R->abuf_nodes_cap;
  assert_true(cap >= s1.gt_fragments);
  if (hr_pass_gt(R, &v, &light, 4, b, NULL, &s2, err, sizeof err) != HF_OK) fail_msg("%s", err);
  assert_int_equal(R->abuf_nodes_cap, cap);
  assert_memory_equal(a, b, sizeof(float) * n);
  assert_int_equal(s1.gt_fragments, s2.gt_fragments);
  assert_int_equal(s1.gt_max_depth, s2.gt_max_depth);
  assert_int_equal(s1.gt_truncated, s2.gt_truncated);
  assert_int_equal(s1.gt_host_resolve, s2.gt_host_resolve);
  hfr_view cv = v;
  cv.crop_x = W / 4, cv.crop_y = H / 4, cv.crop_w = W / 4, cv.crop_h = H / 4;
  if (hr_pass_gt(R, &cv, &light, 4, b, NULL, &s3, err, sizeof err) != HF_OK) fail_msg("%s", err);
  assert_true(s3.gt_fragments < s1.gt_fragments);
  assert_int_equal(R->abuf_nodes_cap, cap);
  print_message("pool of %u nodes kept: %llu and %llu fragments, deepest list %u (%s)\n", cap,
                (unsigned long long)s1.gt_fragments, (unsigned long long)s3.gt_fragments,
                s1.gt_max_depth, s1.gt_host_resolve ? "blended on the host" : "on the GPU");
  free(a);
  free(b);
}

/* A strand whose width and opacity change along it, from a pixel and more
 * (alpha 1) to a fraction of one: with multisampling a pixel's fragment is
 * shaded at the pixel centre, which for a partly covered pixel can lie
 * outside the strand's quad, where the interpolated alpha runs past its
 * end values. Every sample's alpha and the ground truth's stay in [0, 1]
 * (protocol/FEATURES.md) whatever the strand's widths. */
/* Where the 4x MSAA samples sit, and the default ground truth off them:
 * the implementation's positions are inside the pixel and distinct, none is
 * a sub-pixel centre of the default truth, the standard pattern lies on the
 * 4x4 grid (and on no other up to 8), and a rendered frame reports how many
 * its truth shares. */
static void test_gt_grid(void **state) {
  (void)state;
  float pos[8];
  char err[512] = "";
  int rc = hfr_msaa_positions(R, pos, err, sizeof err);
  if (rc != HF_OK) fail_msg("positions: %s", err);
  for (int k = 0; k < 4; k++) {
    assert_true(pos[2 * k] >= 0 && pos[2 * k] < 1 && pos[2 * k + 1] >= 0 && pos[2 * k + 1] < 1);
    for (int j = 0; j < k; j++)
      assert_true(fabsf(pos[2 * k] - pos[2 * j]) + fabsf(pos[2 * k + 1] - pos[2 * j + 1]) > 0.01f);
  }
  assert_int_equal(hfr_gt_shared_positions(pos, HFR_GT_SUPERSAMPLE), 0);

  const float standard[8] = {0.375f, 0.125f, 0.875f, 0.375f, 0.125f, 0.625f, 0.625f, 0.875f};
  for (int ss = 1; ss <= 8; ss++)
    assert_int_equal(hfr_gt_shared_positions(standard, ss), ss == 4 ? 4 : 0);
  assert_int_equal(hfr_gt_shared_positions(standard, 12), 4);
  assert_int_equal(hfr_gt_shared_positions(standard, 0), 0);
  const float centre[8] = {0.5f, 0.5f, 0.1f, 0.5f, 0.5f, 0.9f, 0.3f, 0.7f};
  assert_int_equal(hfr_gt_shared_positions(centre, 1), 1);
  assert_int_equal(hfr_gt_shared_positions(centre, 5), 4);
  assert_int_equal(hfr_gt_shared_positions(centre, 2), 0);
  int is_standard = 1;
  for (int k = 0; k < 8; k++) is_standard &= fabsf(pos[k] - standard[k]) < 1e-6f;
  if (!strcmp(hfr_renderer_platform(R), "osmesa")) assert_true(is_standard);

  hfr_view v;
  flat_view(&v);
  hfr_outputs o = {0};
  o.spp = 4, o.seed = 2;
  hf_image img;
  hfr_stats st;
  const int ss[3] = {HFR_GT_SUPERSAMPLE, 4, 0};
  for (int i = 0; i < 3; i++) {
    o.gt_supersample = ss[i];
    rc = hfr_render(R, &v, &o, &img, &st, err, sizeof err);
    if (rc != HF_OK) fail_msg("render at gt %d: %s", ss[i], err);
    assert_int_equal(st.gt_shared_positions, hfr_gt_shared_positions(pos, ss[i]));
    hf_image_free(&img);
  }
  hfr_frame f;
  hfr_frame_defaults(&f, 16, 16);
  assert_int_equal(f.outputs.gt_supersample, HFR_GT_SUPERSAMPLE);
  hfr_dataset_opts d;
  hfr_dataset_defaults(&d);
  assert_int_equal(d.gt_supersample, HFR_GT_SUPERSAMPLE);
}

static void test_varying_width_alpha_range(void **state) {
  (void)state;
  hfr_hair h;
  synthetic(&h, 1.0f);
  for (uint32_t p = 0; p < h.points; p++) {
    h.pos[3 * p + 1] += 0.11f * h.pos[3 * p];    /* every row and phase crossed */
    h.thickness[p] = (p % 2) ? 3.0f : 0.25f;     /* x the view's 1.03 px */
    h.transparency[p] = (p % 3 == 0) ? 0.4f : 0.0f;
  }
  char err[512] = "";
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
  hfr_view v;
  flat_view(&v);
  hfr_outputs o = {0};
  o.spp = 4, o.gt_supersample = 4, o.n_st = 1, o.st_spp[0] = 16, o.seed = 9;
  hf_image img;
  int rc = hfr_render(R, &v, &o, &img, NULL, err, sizeof err);
  if (rc != HF_OK) fail_msg("render: %s", err);
  int ga = hf_image_channel(&img, "gt.alpha"), sa = hf_image_channel(&img, "st16.alpha");
  assert_true(ga >= 0 && sa >= 0);
  size_t covered = 0, opaque = 0;
  float amax = 0, amin = 1;
  for (size_t p = 0; p < (size_t)W * H; p++) {
    const float *px = img.data + p * img.channels;
    for (int k = 0; k < 4; k++) {
      float a = px[6 * k + 2];
      if (a == 0) continue;
      covered++;
      opaque += a > 0.95f;
      if (a > amax) amax = a;
      if (a < amin) amin = a;
    }
    /* The single-sampled and counted estimates: in range by construction,
     * kept so that a change there shows here. */
    assert_true(px[ga] >= 0 && px[ga] <= 1);
    assert_true(px[sa] >= 0 && px[sa] <= 1);
  }
  print_message("%zu covered samples, %zu of alpha > 0.95; sample alpha %.6f..%.6f\n", covered,
                opaque, amin, amax);
  assert_true(covered > 1000 && opaque > 100);
  assert_true(amin > 0 && amax <= 1.0f);
  hf_image_free(&img);
  hfr_hair_free(&h);
}

static void test_frame_ranges(void **state) {
  (void)state;
  hfr_view v;
  style_scene(HFR_STYLE_WAVY, 3000, &v);
  hfr_outputs o = {0};
  o.spp = 4;
  o.gt_supersample = 4;
  o.st_spp[0] = 16;
  o.n_st = 1;
  o.opaque_samples = 4;
  o.alpha_corrected = 1;
  o.seed = 5;
  hf_image img;
  hfr_stats st;
  char err[512] = "";
  int rc = hfr_render(R, &v, &o, &img, &st, err, sizeof err);
  if (rc != HF_OK) fail_msg("render: %s", err);
  assert_int_equal(img.channels, 4 * 6 + 3 + 3 + 3 + 3);
  assert_int_equal(hf_features_spp(&img), 4);
  assert_string_equal(img.names[0], "S0.color");
  assert_string_equal(img.names[5], "S0.tangent.y");
  assert_true(hf_image_channel(&img, "gt.alpha") >= 0);
  assert_true(hf_image_channel(&img, "st16.color") >= 0);
  assert_true(hf_image_channel(&img, "opaque.highlight") >= 0);
  assert_true(hf_image_channel(&img, "acst4.alpha") >= 0);
  const float cmax = 2 + v.ambient;
  size_t covered = 0;
  double gt_a = 0, st_a = 0;
  int c_gt = hf_image_channel(&img, "gt.alpha"), c_st = hf_image_channel(&img, "st16.alpha");
  for (int p = 0; p < W * H; p++) {
    const float *px = img.data + (size_t)p * img.channels;
    for (int c = 0; c < img.channels; c++) assert_true(isfinite(px[c]));
    for (int k = 0; k < 4; k++) {
      const float *f = px + 6 * k;
      if (f[2] == 0) { /* no fragment: every feature 0 */
        for (int j = 0; j < 6; j++) assert_true(f[j] == 0);
        continue;
      }
      covered++;
      assert_true(f[0] >= 0 && f[0] <= cmax);
      assert_true(f[1] >= 0 && f[1] <= 1);
      assert_true(f[2] > 0 && f[2] <= 1);
      assert_true(f[3] >= 0 && f[3] <= 1);
      assert_true(f[4] * f[4] + f[5] * f[5] <= 1.0001f);
    }
    for (int c = 24; c < img.channels; c += 3) {
      assert_true(px[c] >= 0 && px[c] <= cmax);
      assert_true(px[c + 1] >= 0 && px[c + 1] <= 1);
      assert_true(px[c + 2] >= 0 && px[c + 2] <= 1);
    }
    gt_a += px[c_gt];
    st_a += px[c_st];
  }
  print_message("%zu covered samples; mean alpha gt %.4f, st16 %.4f\n", covered,
                gt_a / (W * H), st_a / (W * H));
  assert_true(covered > 500);
  /* Stochastic transparency converges to the ground truth's coverage. */
  assert_true(fabs(gt_a - st_a) < 0.1 * gt_a);
  hf_image_free(&img);
}

/* Alpha-corrected stochastic transparency (acst4.*): its alpha is the
 * exact 1 - prod(1 - alpha) of the fragments over each of the pixel's 4
 * samples, averaged, whatever the samples' seed, and its premultiplied
 * result is closer to the ground truth than the 4 samples' mean it
 * corrects. */
static void test_alpha_corrected(void **state) {
  (void)state;
  char err[512] = "";
  /* One layer: strands that never overlap, opacity 0.6, so a pixel's
   * alpha is 0.6 times the share of its samples the geometry covers (the
   * opaque pass's coverage). */
  hfr_hair h;
  synthetic(&h, 0.6f);
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
  hfr_hair_free(&h);
  hfr_view v;
  flat_view(&v);
  hfr_outputs o = {0};
  o.spp = 4, o.alpha_corrected = 1, o.seed = 3;
  hf_image img;
  int rc = hfr_render(R, &v, &o, &img, NULL, err, sizeof err);
  if (rc != HF_OK) fail_msg("render: %s", err);
  float *geo = malloc(sizeof(float) * W * H * S * 6);
  assert_non_null(geo);
  pass(&v, 0, 1, geo);
  int ca = hf_image_channel(&img, "acst4.alpha");
  assert_true(ca >= 0);
  size_t lit = 0, partial = 0;
  for (size_t p = 0; p < (size_t)W * H; p++) {
    int covered = 0;
    for (int s = 0; s < S; s++) covered += geo[(p * S + s) * 6 + 2] > 0;
    float a = img.data[p * img.channels + ca];
    assert_float_equal(a, 0.6f * covered / S, 1e-5f);
    lit += covered > 0;
    partial += covered > 0 && covered < S;
  }
  print_message("one layer: %zu pixels with hair, %zu of them partly covered\n", lit, partial);
  assert_true(lit > 12 * 40);
  assert_true(partial > 0);
  free(geo);
  hf_image_free(&img);

  /* Overlapping wavy hair, two sample seeds. */
  style_scene(HFR_STYLE_WAVY, 3000, &v);
  hf_image im[2];
  o = (hfr_outputs){0};
  o.spp = 4, o.gt_supersample = 4, o.alpha_corrected = 1;
  for (int k = 0; k < 2; k++) {
    o.seed = 5 + k;
    rc = hfr_render(R, &v, &o, &im[k], NULL, err, sizeof err);
    if (rc != HF_OK) fail_msg("render: %s", err);
  }
  const int n = im[0].channels;
  ca = hf_image_channel(&im[0], "acst4.alpha");
  const int cc = hf_image_channel(&im[0], "acst4.color"), gc = hf_image_channel(&im[0], "gt.color");
  size_t hair = 0, seed_differs = 0;
  double err_ac = 0, err_st = 0;
  for (size_t p = 0; p < (size_t)W * H; p++) {
    const float *a = im[0].data + p * n, *b = im[1].data + p * n;
    /* The exact transmittance does not depend on the samples. */
    assert_float_equal(a[ca], b[ca], 1e-5f);
    for (int s = 0; s < 4; s++) seed_differs += a[6 * s + 2] != b[6 * s + 2];
    if (a[gc + 2] <= 0) continue;
    hair++;
    double st[3] = {0, 0, 0};
    for (int s = 0; s < 4; s++) {
      st[0] += a[6 * s] * a[6 * s + 2] / 4;
      st[1] += a[6 * s + 1] * a[6 * s + 2] / 4;
      st[2] += a[6 * s + 2] / 4;
    }
    const double ga = a[gc + 2], aa = a[ca];
    const double want[3] = {a[gc] * ga, a[gc + 1] * ga, ga};
    const double ac[3] = {a[cc] * aa, a[cc + 1] * aa, aa};
    for (int k = 0; k < 3; k++) {
      err_ac += (ac[k] - want[k]) * (ac[k] - want[k]);
      err_st += (st[k] - want[k]) * (st[k] - want[k]);
    }
  }
  print_message("%zu hair pixels: premultiplied squared error 4 samples %.3f, "
                "alpha-corrected %.3f; %zu sample alphas differ between seeds\n",
                hair, err_st, err_ac, seed_differs);
  assert_true(hair > 500);
  assert_true(seed_differs > 100);
  assert_true(err_ac < 0.5 * err_st);
  hf_image_free(&im[0]);
  hf_image_free(&im[1]);
}

/* Dataset mode: EXRs with features and targets, and a manifest that
 * records each frame's parameters. */
static void test_dataset_mode(void **state) {
  (void)state;
  char dir[256];
  snprintf(dir, sizeof dir, "/tmp/hf_test_dataset_%d", (int)getpid());
  hfr_dataset_opts o;
  hfr_dataset_defaults(&o);
  o.out_dir = dir;
  o.styles[0] = HFR_STYLE_CURLY;
  o.styles[1] = HFR_STYLE_PONYTAIL;
  o.n_styles = 2;
  o.count = 2;
  o.width = 32, o.height = 32;
  o.strands = 400;
  o.shadow_size = 128;
  o.st_spp[0] = 4;
  o.n_st = 1;
  o.progress = 0;
  o.platform = "osmesa";
  char err[512] = "";
  int rc = hfr_dataset_run(&o, err, sizeof err);
  if (rc != HF_OK) fail_msg("dataset: %s", err);
  assert_int_equal(hr_renderer_bind(R), HF_OK);

  char path[512];
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  char *text = slurp(path);
  assert_non_null(strstr(text, "\"format\":\t\"hairfilter-dataset\""));
  assert_non_null(strstr(text, "\"file\":\t\"ponytail_0001.exr\""));
  assert_non_null(strstr(text, "\"strand_count\":\t400"));
  assert_non_null(strstr(text, "\"camera\""));
  free(text);
  const char *files[] = {"curly_0000.exr", "curly_0001.exr", "ponytail_0000.exr",
                         "ponytail_0001.exr"};
  for (int i = 0; i < 4; i++) {
    snprintf(path, sizeof path, "%s/%s", dir, files[i]);
    hf_image img;
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_OK);
    assert_int_equal(img.width, 32);
    assert_int_equal(hf_features_spp(&img), 4);
    int a = hf_image_channel(&img, "gt.alpha");
    assert_true(a >= 0);
    assert_true(hf_image_channel(&img, "st4.color") >= 0);
    double sum = 0;
    for (int p = 0; p < 32 * 32; p++) sum += img.data[(size_t)p * img.channels + a];
    assert_true(sum > 0); /* some hair in every frame */
    hf_image_free(&img);
    remove(path);
  }
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  remove(path);
  rmdir(dir);
}

/* The sum of one channel (e.g. "gt.alpha") over an EXR's pixels. */
static double channel_sum(const char *path, const char *channel) {
  hf_image img;
  char err[256] = "";
  if (hf_exr_read(path, &img, err, sizeof err) != HF_OK) fail_msg("%s: %s", path, err);
  int c = hf_image_channel(&img, channel);
  assert_true(c >= 0);
  double sum = 0;
  for (size_t p = 0; p < (size_t)img.width * img.height; p++)
    sum += img.data[p * img.channels + c];
  hf_image_free(&img);
  return sum;
}

/* A frame whose fragments do not fit one A-buffer is drawn in bands: with
 * the limit lowered below the fragment counts of some of the run's own
 * frames, every frame is still made, with the same fragment count and the
 * same ground truth. A frame whose single rows do not fit is left out,
 * named in the manifest's "skipped" list, and the run goes on with the next
 * frame; a run that leaves out every frame fails. */
static void test_dataset_skips_dense_frames(void **state) {
  (void)state;
  char dir[256];
  snprintf(dir, sizeof dir, "/tmp/hf_test_dataset_skip_%d", (int)getpid());
  hfr_dataset_opts o;
  hfr_dataset_defaults(&o);
  o.out_dir = dir;
  o.styles[0] = HFR_STYLE_STRAIGHT;
  o.styles[1] = HFR_STYLE_CURLY;
  o.n_styles = 2;
  o.count = 2;
  o.width = 16, o.height = 16;
  o.strands = 1500;
  o.shadow_size = 0;
  o.progress = 0;
  o.platform = "osmesa";
  char err[512] = "", path[512];
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  assert_int_equal(hfr_dataset_run(&o, err, sizeof err), HF_OK);
  assert_int_equal(hr_renderer_bind(R), HF_OK);
  /* The four frames' fragment counts, in manifest order. */
  int counts[4], lo = 0x7fffffff, hi = 0;
  char *text = slurp(path);
  const char *k = text;
  for (int i = 0; i < 4; i++) {
    k = strstr(k, "\"gt_fragments\":");
    assert_non_null(k);
    k += strlen("\"gt_fragments\":");
    counts[i] = atoi(k);
    lo = counts[i] < lo ? counts[i] : lo;
    hi = counts[i] > hi ? counts[i] : hi;
  }
  free(text);
  print_message("fragments per frame: %d %d %d %d\n", counts[0], counts[1], counts[2], counts[3]);
  assert_true(lo < hi);
  const char *files[] = {"straight_0000.exr", "curly_0000.exr", "straight_0001.exr",
                         "curly_0001.exr"};
  double gt_sum[4];
  for (int i = 0; i < 4; i++) {
    char f[512];
    snprintf(f, sizeof f, "%s/%s", dir, files[i]);
    gt_sum[i] = channel_sum(f, "gt.color") + channel_sum(f, "gt.alpha");
  }
  o.max_fragments = (uint32_t)lo;
  assert_int_equal(hfr_dataset_run(&o, err, sizeof err), HF_OK);
  assert_int_equal(hr_renderer_bind(R), HF_OK);
  text = slurp(path);
  assert_null(strstr(text, "\"reason\""));   /* nothing left out */
  k = text;
  for (int i = 0; i < 4; i++) {
    k = strstr(k, "\"gt_fragments\":");
    assert_non_null(k);
    k += strlen("\"gt_fragments\":");
    assert_int_equal(atoi(k), counts[i]);
    char f[512];
    snprintf(f, sizeof f, "%s/%s", dir, files[i]);
    assert_true(channel_sum(f, "gt.color") + channel_sum(f, "gt.alpha") == gt_sum[i]);
  }
  free(text);
  o.max_fragments = 1;
  assert_int_equal(hfr_dataset_run(&o, err, sizeof err), HF_ERANGE);
  assert_int_equal(hr_renderer_bind(R), HF_OK);
  assert_non_null(strstr(err, "every frame was left out"));
  text = slurp(path);
  int skipped = 0;
  for (const char *q = text; (q = strstr(q, "\"reason\"")) != NULL; q++) skipped++;
  assert_int_equal(skipped, 4);   /* each frame tried in turn */
  free(text);
  for (int i = 0; i < 4; i++) {
    char f[512];
    snprintf(f, sizeof f, "%s/%s", dir, files[i]);
    remove(f);
  }
  remove(path);
  rmdir(dir);
}

static void test_dataset_extended(void **state) {
  (void)state;
  char dir[256];
  snprintf(dir, sizeof dir, "/tmp/hf_test_extended_%d", (int)getpid());
  hfr_dataset_opts o;
  hfr_dataset_defaults(&o);
  o.out_dir = dir;
  o.styles[0] = HFR_STYLE_WAVY;
  o.n_styles = 1;
  o.count = 4;
  o.width = o.height = 16;
  o.strands = 200;
  o.shadow_size = 64;
  o.gt_supersample = 1;
  o.extended = 1;
  o.progress = 0;
  o.platform = "osmesa";
  char path[512];
  cJSON *doc = run_dataset(&o, R);
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  assert_true(cJSON_IsTrue(cJSON_GetObjectItem(doc, "extended")));
  cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
  assert_int_equal(cJSON_GetArraySize(frames), 4);
  double first_period = -1;
  int differ = 0;
  cJSON_ArrayForEach(f, frames) {
    cJSON *h = cJSON_GetObjectItem(f, "hair");
    double period = cJSON_GetObjectItem(h, "curl_period")->valuedouble;
    double radius = cJSON_GetObjectItem(h, "curl_radius")->valuedouble;
    double length = cJSON_GetObjectItem(h, "length")->valuedouble;
    double opacity = cJSON_GetObjectItem(h, "opacity")->valuedouble;
    int segments = cJSON_GetObjectItem(h, "segments")->valueint;
    double dist = cJSON_GetObjectItem(cJSON_GetObjectItem(f, "camera"), "distance")->valuedouble;
    assert_true(period >= 0.07 && period <= 0.9);
    assert_true(radius >= 0.1 * period - 1e-6 && radius <= 0.45 * period + 1e-6);
    assert_true(length >= 0.7 - 1e-6 && length <= 3.0 + 1e-6);
    assert_true(length <= 128 * period / 6 + 1e-5);
    assert_true(opacity >= 0.3 - 1e-6 && opacity <= 1.0);
    assert_true(segments >= 24 && segments <= 128);
    assert_true(dist >= 1.8 - 1e-6 && dist <= 6.0 + 1e-6);
    assert_int_equal(cJSON_GetObjectItem(h, "strands")->valueint, 200);   /* --strands wins */
    if (first_period < 0) first_period = period;
    else differ |= period != first_period;
    char exr[600];
    snprintf(exr, sizeof exr, "%s/%s", dir, cJSON_GetObjectItem(f, "file")->valuestring);
    remove(exr);
  }
  assert_true(differ);
  cJSON_Delete(doc);
  remove(path);
  rmdir(dir);
}

/* The one-call API other commands use, on a model from a .hair file. */
static void test_render_frame_from_file(void **state) {
  (void)state;
  hfr_style_params p;
  hfr_style_defaults(HFR_STYLE_COILY, &p);
  p.strands = 500;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  char path[256];
  snprintf(path, sizeof path, "/tmp/hf_test_frame_%d.hair", (int)getpid());
  assert_int_equal(hfr_hair_save(path, &h), HF_OK);
  hfr_hair_free(&h);
  hfr_frame f;
  hfr_frame_defaults(&f, 48, 40);
  f.hair_path = path;
  f.platform = "osmesa";
  f.outputs.spp = 2;
  f.outputs.st_spp[0] = 8;
  f.outputs.n_st = 1;
  hf_image img;
  hfr_stats st;
  char err[512] = "";
  int rc = hfr_render_frame(&f, &img, &st, err, sizeof err);
  remove(path);
  if (rc != HF_OK) fail_msg("frame: %s", err);
  assert_int_equal(img.width, 48);
  assert_int_equal(img.height, 40);
  assert_int_equal(img.channels, 2 * 6 + 3 + 3);
  assert_int_equal(hf_features_spp(&img), 2);
  assert_true(st.gt_fragments > 0);
  float *rgb = malloc(sizeof(float) * 3 * 48 * 40);
  assert_non_null(rgb);
  assert_int_equal(hfr_composite_channels(&img, "gt", &f.view, rgb), HF_OK);
  assert_int_equal(hfr_composite_channels(&img, "st8", &f.view, rgb), HF_OK);
  assert_int_equal(hfr_composite_channels(&img, "opaque", &f.view, rgb), HF_ENOTFOUND);
  free(rgb);
  hf_image_free(&img);
  /* A missing file is reported, not rendered. */
  f.hair_path = "/nonexistent/model.hair";
  assert_int_equal(hfr_render_frame(&f, &img, NULL, err, sizeof err), HF_EIO);
  assert_int_equal(hr_renderer_bind(R), HF_OK);
}

/* A loaded model's stated rules, as drawn: --thickness at any width (it
 * was replaced by R / 2000 above 0.02 R), one header-transparency rule with
 * and without children, and a model float cannot frame refused instead of
 * rendered empty. */
static void frame_of(const char *path, const hfr_asset_opts *a, hfr_frame_stats *fs) {
  hfr_frame f;
  hfr_frame_defaults(&f, 48, 48);
  f.hair_path = path;
  f.platform = "osmesa";
  f.asset = *a;
  f.outputs.gt_supersample = 0;
  f.outputs.st_spp[0] = 4;
  f.outputs.n_st = 1;
  hf_image img;
  hfr_stats st;
  char err[512] = "";
  int rc = hfr_render_frame(&f, &img, &st, err, sizeof err);
  if (rc != HF_OK) fail_msg("frame of %s: %s", path, err);
  *fs = st.frame;
  hf_image_free(&img);
}

static void test_loaded_model_rules(void **state) {
  (void)state;
  hfr_style_params p;
  hfr_style_defaults(HFR_STYLE_STRAIGHT, &p);
  p.strands = 300;
  p.seed = 5;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  free(h.thickness), free(h.transparency);
  h.thickness = h.transparency = NULL;
  h.default_thickness = 0.0008f;
  float c[3], r;
  hfr_hair_bounds(&h, c, &r);
  char path[256];
  snprintf(path, sizeof path, "/tmp/hf_test_rules_%d.hair", (int)getpid());
  hfr_asset_opts a;
  hfr_asset_defaults(&a);
  a.occluder = "none";
  hfr_frame_stats fs[2];
  /* --thickness 0.01 R and 0.1 R: ten times as wide in pixels. */
  h.default_transparency = 0.2f;
  assert_int_equal(hfr_hair_save(path, &h), HF_OK);
  a.thickness = 0.01f * r;
  frame_of(path, &a, &fs[0]);
  a.thickness = 0.1f * r;
  frame_of(path, &a, &fs[1]);
  print_message("--thickness 0.01 R: %.4f px, 0.1 R: %.4f px\n", fs[0].width_px_p50,
                fs[1].width_px_p50);
  assert_true(fs[0].valid && fs[1].valid);
  assert_true(fabs(fs[1].width_px_p50 / fs[0].width_px_p50 - 10) < 0.1);
  /* Wide strands: a covered sample's alpha is the opacity. Invalid header
   * transparencies draw opaque (transparency 0) with children or without;
   * a header 1 draws nothing on either path, as a per-point 1 does. */
  const float bad[] = {NAN, -1, 2, INFINITY};
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    h.default_transparency = bad[i];
    assert_int_equal(hfr_hair_save(path, &h), HF_OK);
    for (int k = 0; k < 2; k++) {
      a.children.children = k ? 3 : 0;
      frame_of(path, &a, &fs[k]);
      print_message("header transparency %g, children %d: alpha p50 %.4f\n", bad[i],
                    a.children.children, fs[k].alpha_p50);
      assert_true(fs[k].hair_pixels > 0.05);
      assert_true(fs[k].alpha_p50 > 0.999 && fs[k].alpha_p10 > 0.999);
    }
  }
  h.default_transparency = 1;
  assert_int_equal(hfr_hair_save(path, &h), HF_OK);
  for (int k = 0; k < 2; k++) {
    a.children.children = k ? 3 : 0;
    frame_of(path, &a, &fs[k]);
    assert_true(fs[k].hair_pixels == 0);
  }
  a.children.children = 0;
  /* Coordinates scaled by 1e30: refused naming the radius and --units;
   * with --scale 1e-30 the same file renders as the original. */
  for (size_t k = 0; k < 3 * (size_t)h.points; k++) h.pos[k] *= 1e30f;
  h.default_transparency = 0.2f;
  assert_int_equal(hfr_hair_save(path, &h), HF_OK);
  hfr_frame f;
  hfr_frame_defaults(&f, 48, 48);
  f.hair_path = path;
  f.platform = "osmesa";
  hf_image img;
  char err[512] = "";
  assert_int_equal(hfr_render_frame(&f, &img, NULL, err, sizeof err), HF_ERANGE);
  print_message("1e30: %s\n", err);
  assert_non_null(strstr(err, "bounding radius"));
  assert_non_null(strstr(err, "--units"));
  a.scale = 1e-30f;
  a.thickness = 0.1f * r * 1e30f;
  frame_of(path, &a, &fs[0]);
  assert_true(fabs(fs[0].width_px_p50 / fs[1].width_px_p50 - 1) < 0.01);
  remove(path);
  /* The renderer refuses such a model itself (callers without the loader). */
  err[0] = 0;
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_ERANGE);
  assert_non_null(strstr(err, "bounding radius"));
  hfr_hair_free(&h);
}

/* The same GL code on EGL, where this build and machine have it. */
static void test_egl(void **state) {
  (void)state;
  hfr_renderer *r = NULL;
  char err[512] = "";
  int rc = hfr_renderer_create("egl", &r, err, sizeof err);
  if (rc != HF_OK) {
    print_message("EGL unavailable here: %s\n", err);
    skip();
  }
  hfr_hair h;
  synthetic(&h, 0.5f);
  assert_int_equal(hfr_renderer_set_hair(r, &h, 0, err, sizeof err), HF_OK);
  hfr_view v;
  flat_view_on(r, &v);
  hfr_outputs o = {0};
  o.spp = 4;
  o.seed = 1;
  hf_image img;
  rc = hfr_render(r, &v, &o, &img, NULL, err, sizeof err);
  if (rc != HF_OK) fail_msg("egl render: %s", err);
  size_t kept = 0;
  for (size_t i = 0; i < (size_t)W * H * 4; i++) kept += img.data[i * 6 + 2] > 0;
  assert_true(kept > 500);
  hf_image_free(&img);
  hfr_hair_free(&h);
  hfr_renderer_destroy(r);
  /* Put the suite's OSMesa context and entry points back. */
  assert_int_equal(hr_renderer_bind(R), HF_OK);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_hashed_alpha_binomial),
    cmocka_unit_test(test_mask_deterministic),
    cmocka_unit_test(test_wide_strands_area), cmocka_unit_test(test_huge_widths_cover_the_frame),
    cmocka_unit_test(test_gt_matches_cpu_blend),
    cmocka_unit_test(test_gt_dense),
    cmocka_unit_test(test_gt_bands),
    cmocka_unit_test(test_gt_cull),
    cmocka_unit_test(test_gt_pool),
    cmocka_unit_test(test_gt_grid),
    cmocka_unit_test(test_varying_width_alpha_range),
    cmocka_unit_test(test_frame_ranges),
    cmocka_unit_test(test_alpha_corrected),
    cmocka_unit_test(test_dataset_mode),
    cmocka_unit_test(test_dataset_skips_dense_frames),
    cmocka_unit_test(test_dataset_extended),
    cmocka_unit_test(test_render_frame_from_file),
    cmocka_unit_test(test_loaded_model_rules),
    cmocka_unit_test(test_egl),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
