/* Real conditions on a headless context: crops of a larger frame, occluders
 * (fitted, meshes, the background layer), loaded models in other
 * conventions framed, frame statistics, and dataset regimes with .hair files
 * as styles. Small frames and few strands: seconds. */
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
#include "test_common.h"


static hfr_hair style(hfr_style s, int strands) {
  hfr_style_params p;
  hfr_style_defaults(s, &p);
  p.strands = strands;
  p.seed = 9;
  hfr_hair h;
  assert_int_equal(hfr_hair_generate(&p, &h), HF_OK);
  return h;
}

/* Gives the renderer strands of style s (with the head) and v the default
 * view. */
static void use_style(hfr_style s, int strands, hfr_view *v) {
  hfr_hair h = style(s, strands);
  char err[256];
  assert_int_equal(hfr_renderer_set_hair(R, &h, 1, err, sizeof err), HF_OK);
  hfr_hair_free(&h);
  hfr_view_defaults(v);
}

static void render(const hfr_view *v, const hfr_outputs *o, hf_image *img, hfr_stats *st) {
  char err[512] = "";
  int rc = hfr_render(R, v, o, img, st, err, sizeof err);
  if (rc != HF_OK) fail_msg("render: %s", err);
}

/* Renders each window of v on its own and checks that it holds the same
 * samples and ground truth as that window of the whole frame; returns the
 * share of the hair's instances the smallest window drew
 * (hr_hair_window_runs). */
static double crops_match(const hfr_view *v, const hfr_outputs *o, const int (*windows)[4],
                          int n) {
  hf_image full, crop;
  render(v, o, &full, NULL);
  double least = 1;
  for (int w = 0; w < n; w++) {
    hfr_view c = *v;
    c.crop_x = windows[w][0], c.crop_y = windows[w][1];
    c.crop_w = windows[w][2], c.crop_h = windows[w][3];
    render(&c, o, &crop, NULL);
    assert_int_equal(crop.width, c.crop_w);
    assert_int_equal(crop.height, c.crop_h);
    assert_int_equal(crop.channels, full.channels);
    double maxd = 0;
    size_t differ = 0, covered = 0;
    for (int y = 0; y < c.crop_h; y++)
      for (int x = 0; x < c.crop_w; x++) {
        const float *a = crop.data + ((size_t)y * crop.width + x) * crop.channels;
        const float *b = full.data + ((size_t)(y + c.crop_y) * full.width + x + c.crop_x) *
                                         full.channels;
        for (int k = 0; k < crop.channels; k++) {
          double d = fabs(a[k] - b[k]);
          maxd = d > maxd ? d : maxd;
          differ += d > 1e-6;
          if (d > 1e-6 && differ < 8)
            print_message("  (%d,%d) %s: crop %g full %g\n", x, y, crop.names[k], a[k], b[k]);
        }
        covered += a[2] > 0;
      }
    /* The instances the window drew. */
    hr_camera cam;
    hr_camera_from_view(R, &c, &cam);
    size_t runs = 0;
    assert_int_equal(hr_hair_window_runs(R, &cam, c.thickness_scale, &runs), HF_OK);
    uint64_t drawn = 0;
    for (size_t k = 0; k < runs; k++) drawn += R->runs[k].count;
    const double share = (double)drawn / (R->points - 1);
    least = share < least ? share : least;
    print_message("window %d,%d %dx%d: %zu covered first samples, max |crop - full| %.2e, "
                  "%zu values above 1e-6; %.1f%% of the instances drawn in %zu runs\n",
                  c.crop_x, c.crop_y, c.crop_w, c.crop_h, covered, maxd, differ,
                  100 * share, runs);
    assert_true(covered > 20);
    assert_true(maxd <= 1e-6);
    hf_image_free(&crop);
  }
  hf_image_free(&full);
  return least;
}

/* Three n x n windows of v's frame, on a grid of n-pixel steps, whose
 * first samples are covered at more than 20 pixels: the first, the middle
 * and the last such window in scan order. */
static void pick_windows(const hfr_view *v, const hfr_outputs *o, int n, int out[3][4]) {
  hf_image full;
  render(v, o, &full, NULL);
  int found[256][2], k = 0;
  for (int y = 0; y + n <= full.height; y += n)
    for (int x = 0; x + n <= full.width && k < 256; x += n) {
      int covered = 0;
      for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++)
          covered += full.data[((size_t)(y + j) * full.width + x + i) * full.channels + 2] > 0;
      if (covered > 20) found[k][0] = x, found[k][1] = y, k++;
    }
  hf_image_free(&full);
  assert_true(k >= 3);
  const int pick[3] = {0, k / 2, k - 1};
  for (int w = 0; w < 3; w++)
    out[w][0] = found[pick[w]][0], out[w][1] = found[pick[w]][1], out[w][2] = n, out[w][3] = n;
}

/* Removes dir/name, a frame or manifest of a test's set. */
static void remove_in(const char *dir, const char *name) {
  char path[600];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  remove(path);
}

/* The manifest doc records key as the range {lo, hi} (to float precision),
 * or, where lo and hi are both 0, not at all. */
static void assert_range_recorded(cJSON *doc, const char *key, double lo, double hi) {
  cJSON *r = cJSON_GetObjectItem(doc, key);
  if (lo == 0 && hi == 0) {
    assert_null(r);
    return;
  }
  assert_int_equal(cJSON_GetArraySize(r), 2);
  assert_float_equal(cJSON_GetArrayItem(r, 0)->valuedouble, lo, 1e-6);
  assert_float_equal(cJSON_GetArrayItem(r, 1)->valuedouble, hi, 1e-6);
}

/* A window of a frame, rendered on its own, holds the same samples and
 * ground truth as that window of the whole frame, though it draws only the
 * strands' segments that can reach it; strands many pixels wide reach
 * further than their centre lines. */
static void test_crop_equals_window(void **state) {
  (void)state;
  hfr_view v;
  use_style(HFR_STYLE_WAVY, 1500, &v);
  v.width = 96, v.height = 80;
  v.shadow_size = 128;
  v.cam_distance = 2.2f;
  v.thickness_scale = 6; /* denser coverage: more samples to compare */
  hfr_outputs o = {0};
  o.spp = 8; /* two passes: the second one jittered */
  o.gt_supersample = 2;
  o.background_layer = 1;
  o.alpha_corrected = 1; /* its pass blends additively: order matters */
  o.st_spp[0] = 4, o.st_spp[1] = 12, o.n_st = 2; /* a third pass, baselines only */
  o.seed = 3;
  const int windows[][4] = {{20, 12, 40, 48}, {27, 30, 33, 17}, {63, 50, 33, 30}};
  double least = crops_match(&v, &o, windows, 3);
  assert_true(least < 0.6); /* the windows are half the frame or less */
  /* Strands about 60 pixels wide (a close-up of thick hair) in windows
   * much narrower than that. */
  hfr_view wide = v;
  wide.thickness_scale = 400;
  int narrow[3][4];
  pick_windows(&wide, &o, 8, narrow);
  least = crops_match(&wide, &o, (const int (*)[4])narrow, 3);
  assert_true(least < 0.1); /* most segments are far from an 8-pixel window */
  /* Outside the frame: refused. */
  hfr_view bad = v;
  bad.crop_x = 80, bad.crop_y = 0, bad.crop_w = 32, bad.crop_h = 8;
  hf_image crop;
  char err[256];
  assert_int_equal(hfr_render(R, &bad, &o, &crop, NULL, err, sizeof err), HF_EINVAL);
}

/* Parallel strands in the plane z = -0.5 behind a quad occluder at z = 0
 * that covers x < 0: behind it no sample is covered and the ground truth is
 * empty; beside it the strands show. The layer has the occluder. */
static void test_occluder_hides(void **state) {
  (void)state;
  const int strands = 40, seg = 8;
  hfr_hair h = {0};
  h.strands = strands;
  h.points = strands * (seg + 1);
  h.default_segments = seg;
  h.default_thickness = 0.01f;
  h.pos = malloc(12 * (size_t)h.points);
  assert_non_null(h.pos);
  for (int s = 0; s < strands; s++)
    for (int i = 0; i <= seg; i++) {
      float *p = h.pos + 3 * ((size_t)s * (seg + 1) + i);
      p[0] = -1 + 2.0f * i / seg, p[1] = -1 + 2.0f * s / (strands - 1), p[2] = -0.5f;
    }
  char err[256];
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
  float quad[6][6] = {{-3, -3, 0, 0, 0, 1}, {0, -3, 0, 0, 0, 1}, {0, 3, 0, 0, 0, 1},
                      {-3, -3, 0, 0, 0, 1}, {0, 3, 0, 0, 0, 1}, {-3, 3, 0, 0, 0, 1}};
  hfr_mesh m = {6, &quad[0][0]};
  assert_int_equal(hfr_renderer_set_occluder(R, &m, 0, err, sizeof err), HF_OK);
  hfr_view v;
  hfr_view_defaults(&v);
  v.width = v.height = 64;
  v.cam_yaw_deg = 0, v.cam_pitch_deg = 0;
  v.light_yaw_deg = 0, v.light_pitch_deg = 0;
  v.shadow_size = 0;
  hfr_outputs o = {0};
  o.spp = 4, o.gt_supersample = 2, o.background_layer = 1, o.seed = 1;
  hf_image img;
  render(&v, &o, &img, NULL);
  int ga = hf_image_channel(&img, "gt.alpha"), la = hf_image_channel(&img, "background.A");
  assert_true(ga >= 0 && la >= 0);
  double left = 0, right = 0, left_bg = 0, right_bg = 0;
  size_t left_s = 0, right_s = 0;
  for (int y = 8; y < 56; y++)
    for (int x = 4; x < 60; x++) {
      if (x >= 29 && x <= 34) continue; /* the occluder's edge */
      const float *p = img.data + ((size_t)y * 64 + x) * img.channels;
      size_t k = 0;
      for (int s = 0; s < 4; s++) k += p[6 * s + 2] > 0;
      if (x < 32) left += p[ga], left_s += k, left_bg += p[la];
      else right += p[ga], right_s += k, right_bg += p[la];
    }
  print_message("gt alpha behind the occluder %.3f, beside %.3f; samples %zu / %zu\n", left,
                right, left_s, right_s);
  assert_true(left == 0 && left_s == 0);
  assert_true(right > 10 && right_s > 100);
  assert_true(left_bg > 0.99 * 48 * 25 && right_bg == 0);
  /* The composite shows the occluder where the hair does not cover it. */
  float *rgb = malloc(sizeof(float) * 3 * 64 * 64), *plain = malloc(sizeof(float) * 3 * 64 * 64);
  assert_non_null(rgb);
  assert_non_null(plain);
  assert_int_equal(hfr_composite_channels(&img, "gt", &v, rgb), HF_OK);
  float *res = calloc(3 * 64 * 64, sizeof(float));
  assert_non_null(res);
  hf_composite(res, 64, 64, v.hair_color, v.light_color, v.background, plain);
  const float *l = img.data + ((size_t)32 * 64 + 10) * img.channels;
  assert_true(fabsf(rgb[3 * (32 * 64 + 10)] - l[la - 3]) < 1e-5f); /* R of the layer */
  assert_true(fabsf(rgb[3 * (32 * 64 + 10)] - plain[3 * (32 * 64 + 10)]) > 1e-3f);
  free(res);
  free(rgb);
  free(plain);
  hf_image_free(&img);
  hfr_hair_free(&h);
}

/* A style saved z-up in centimetres and loaded back with --up z --units cm
 * is framed like the original: same bounding sphere, all of it in view. */
static void test_conventions_framing(void **state) {
  (void)state;
  hfr_hair h = style(HFR_STYLE_STRAIGHT, 800);
  float c0[3], r0;
  hfr_hair_bounds(&h, c0, &r0);
  /* To z-up centimetres: y-up (x, y, z) -> z-up (x, -z, y), x10. */
  for (uint32_t i = 0; i < h.points; i++) {
    float *p = h.pos + 3 * (size_t)i, y = p[1], z = p[2];
    p[0] *= 10, p[1] = -10 * z, p[2] = 10 * y;
  }
  for (uint32_t i = 0; i < h.points; i++) h.thickness[i] *= 10;
  h.default_thickness *= 10;
  char path[256];
  snprintf(path, sizeof path, "/tmp/hf_test_views_%d.hair", (int)getpid());
  assert_int_equal(hfr_hair_save(path, &h), HF_OK);
  hfr_hair_free(&h);
  hfr_asset_opts ao;
  hfr_asset_defaults(&ao);
  assert_int_equal(hfr_axis_from_name("z", &ao.up), HF_OK);
  assert_int_equal(hfr_units_scale("cm", &ao.scale), HF_OK);
  hfr_mesh occ;
  char err[256] = "", warn[256] = "";
  assert_int_equal(hfr_asset_load(path, &ao, &h, &occ, warn, sizeof warn, err, sizeof err), HF_OK);
  remove(path);
  assert_string_equal(warn, "");
  float c1[3], r1;
  hfr_hair_bounds(&h, c1, &r1);
  for (int k = 0; k < 3; k++) assert_true(fabsf(c1[k] - c0[k]) < 1e-4f * r0);
  assert_true(fabsf(r1 - r0) < 1e-4f * r0);
  assert_true(occ.vertices > 0);
  assert_int_equal(hfr_renderer_set_hair(R, &h, 0, err, sizeof err), HF_OK);
  assert_int_equal(hfr_renderer_set_occluder(R, &occ, 1, err, sizeof err), HF_OK);
  hfr_view v;
  hfr_view_defaults(&v);
  v.width = v.height = 64;
  v.shadow_size = 0;
  /* The whole bounding sphere (points all over it, its silhouette among
   * them) projects inside the frame, in a square, a landscape and a
   * portrait frame alike. */
  float centre[3], radius;
  hfr_renderer_bounds(R, centre, &radius);
  const int sizes[3][2] = {{64, 64}, {96, 48}, {48, 96}};
  for (int sz = 0; sz < 3; sz++) {
    hfr_view a = v;
    a.width = sizes[sz][0], a.height = sizes[sz][1];
    hr_camera cam;
    hr_camera_from_view(R, &a, &cam);
    float most = 0;
    for (int t = 0; t < 64; t++)
      for (int q = 0; q < 128; q++) {
        float th = (float)M_PI * (t + 0.5f) / 64, ph = 2 * (float)M_PI * q / 128;
        float p[4] = {centre[0] + radius * sinf(th) * cosf(ph),
                      centre[1] + radius * cosf(th),
                      centre[2] + radius * sinf(th) * sinf(ph), 1};
        float e[4] = {0}, c[4] = {0};
        for (int i = 0; i < 4; i++)
          for (int j = 0; j < 4; j++) e[i] += cam.view[4 * j + i] * p[j];
        for (int i = 0; i < 4; i++)
          for (int j = 0; j < 4; j++) c[i] += cam.proj[4 * j + i] * e[j];
        assert_true(c[3] > 0);
        most = fmaxf(most, fmaxf(fabsf(c[0] / c[3]), fabsf(c[1] / c[3])));
      }
    print_message("%dx%d: the bounding sphere reaches %.3f of the half-frame\n", a.width,
                  a.height, most);
    assert_true(most < 1);
  }
  hfr_outputs o = {0};
  o.spp = 4, o.seed = 2;
  hf_image img;
  hfr_stats st;
  render(&v, &o, &img, &st);
  print_message("z-up cm model: %.3f of the pixels hair\n", st.frame.hair_pixels);
  assert_true(st.frame.hair_pixels > 0.03);
  hf_image_free(&img);
  hfr_mesh_free(&occ);
  hfr_hair_free(&h);
}

/* Frame statistics: inside their ranges, and they follow the strand width. */
static void test_frame_stats(void **state) {
  (void)state;
  hfr_view v;
  use_style(HFR_STYLE_STRAIGHT, 2000, &v);
  v.width = v.height = 64;
  v.shadow_size = 0;
  hfr_outputs o = {0};
  o.spp = 4, o.gt_supersample = 2, o.seed = 4;
  hfr_frame_stats fs[3];
  const float scales[3] = {1, 8, 200};
  for (int i = 0; i < 3; i++) {
    v.thickness_scale = scales[i];
    hf_image img;
    hfr_stats st;
    render(&v, &o, &img, &st);
    fs[i] = st.frame;
    char line[512];
    hfr_frame_stats_format(&fs[i], line, sizeof line);
    print_message("scale %g: %s\n", scales[i], line);
    assert_true(fs[i].valid);
    assert_true(fs[i].alpha_p10 > 0 && fs[i].alpha_p10 <= fs[i].alpha_p50 &&
                fs[i].alpha_p50 <= fs[i].alpha_p90 && fs[i].alpha_p90 <= 1);
    assert_true(fs[i].hair_pixels > 0 && fs[i].hair_pixels <= 1);
    assert_true(fs[i].full_pixels >= 0 && fs[i].full_pixels <= 1);
    assert_true(fs[i].gt_opaque >= 0 && fs[i].gt_opaque <= 1);
    assert_true(fs[i].points_in_view > 1000);
    hf_image_free(&img);
  }
  /* Width in pixels scales with the thickness; alpha follows it below a
   * pixel and is the opacity (<= 0.8 here) above. */
  assert_true(fabs(fs[1].width_px_p50 / fs[0].width_px_p50 - 8) < 0.01 * 8);
  assert_true(fs[1].alpha_p50 > 4 * fs[0].alpha_p50);
  assert_true(fs[2].alpha_p50 > 0.7 && fs[2].alpha_p90 <= 0.8 + 1e-6);
  assert_true(fs[2].full_pixels > fs[0].full_pixels);
  assert_true(fs[2].gt_opaque > fs[0].gt_opaque);
}

/* Regimes over two styles and a .hair file (z-up, cm, guides grown into
 * children): every frame's draws inside their ranges and varied, the crop in
 * its frame, statistics and the layer recorded, the file's conventions too. */
static void test_dataset_regimes(void **state) {
  (void)state;
  char dir[256], hair[300];
  snprintf(dir, sizeof dir, "/tmp/hf_test_regimes_%d", (int)getpid());
  snprintf(hair, sizeof hair, "%s.hair", dir);
  hfr_hair g = style(HFR_STYLE_SPIKY, 1600);
  /* Its guides only, z-up centimetres. */
  hfr_style_params p;
  hfr_style_defaults(HFR_STYLE_SPIKY, &p);
  p.strands = 40, p.children = 0, p.seed = 5;
  hfr_hair_free(&g);
  assert_int_equal(hfr_hair_generate(&p, &g), HF_OK);
  for (uint32_t i = 0; i < g.points; i++) {
    float *q = g.pos + 3 * (size_t)i, y = q[1], z = q[2];
    q[0] *= 10, q[1] = -10 * z, q[2] = 10 * y;
  }
  free(g.thickness);
  g.thickness = NULL;
  g.default_thickness = HFR_HAIR_UNSET_THICKNESS; /* as the reference writer leaves it */
  assert_int_equal(hfr_hair_save(hair, &g), HF_OK);
  hfr_hair_free(&g);

  hfr_dataset_opts o;
  hfr_dataset_defaults(&o);
  o.out_dir = dir;
  o.styles[0] = HFR_STYLE_FUR, o.styles[1] = HFR_STYLE_PONYTAIL, o.styles[2] = HFR_STYLE_BRAIDED;
  o.n_styles = 3;
  const char *files[] = {hair};
  o.hair_files = files, o.n_hair_files = 1;
  o.asset.up = HFR_AXIS_Z, o.asset.scale = 0.1f, o.asset.children.children = 5;
  o.count = 2;
  o.width = o.height = 24;
  o.strands = 300;
  o.regimes = 1, o.frame_min = 32, o.frame_max = 64;
  o.gt_supersample = 1;
  o.background_layer = 1;
  o.progress = 0;
  o.platform = "osmesa";
  char err[512] = "", path[600];
  cJSON *doc = run_dataset(&o, R);
  assert_true(cJSON_IsTrue(cJSON_GetObjectItem(doc, "regimes")));
  cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
  assert_int_equal(cJSON_GetArraySize(frames), 8);
  double wmin = 1e9, wmax = 0;
  int files_seen = 0, braided_seen = 0;
  cJSON_ArrayForEach(f, frames) {
    cJSON *fr = cJSON_GetObjectItem(f, "frame"), *rg = cJSON_GetObjectItem(f, "regime");
    cJSON *st = cJSON_GetObjectItem(f, "stats"), *h = cJSON_GetObjectItem(f, "hair");
    assert_non_null(fr);
    assert_non_null(rg);
    assert_non_null(st);
    int fw = cJSON_GetObjectItem(fr, "width")->valueint;
    cJSON *crop = cJSON_GetObjectItem(fr, "crop_x_y_w_h");
    int cx = cJSON_GetArrayItem(crop, 0)->valueint, cy = cJSON_GetArrayItem(crop, 1)->valueint;
    assert_true(fw >= 32 && fw <= 64);
    assert_int_equal(cJSON_GetObjectItem(f, "full_width")->valueint, fw);
    assert_int_equal(cJSON_GetObjectItem(f, "full_height")->valueint, fw);
    assert_int_equal(cJSON_GetArrayItem(crop, 2)->valueint, 24);
    assert_true(cx >= 0 && cy >= 0 && cx + 24 <= fw && cy + 24 <= fw);
    double tw = cJSON_GetObjectItem(rg, "target_width_px")->valuedouble;
    assert_true(tw >= 0.004 - 1e-6 && tw <= 4 + 1e-6);
    wmin = fmin(wmin, tw), wmax = fmax(wmax, tw);
    cJSON *wpx = cJSON_GetObjectItem(st, "width_px_p10_p50_p90");
    assert_true(cJSON_GetArrayItem(wpx, 1)->valuedouble > 0);
    assert_non_null(cJSON_GetObjectItem(cJSON_GetObjectItem(f, "light"), "shadow_bias"));
    if (cJSON_GetObjectItem(h, "file")) {
      files_seen++;
      assert_string_equal(cJSON_GetObjectItem(h, "up")->valuestring, "z");
      assert_int_equal(cJSON_GetObjectItem(h, "children")->valueint, 5);
      assert_int_equal(cJSON_GetObjectItem(f, "strand_count")->valueint, 40 * 6);
      assert_string_equal(cJSON_GetObjectItem(f, "occluder")->valuestring, "fit");
    } else {
      assert_true(cJSON_GetObjectItem(h, "width_spread")->valuedouble >= 1);
    }
    /* Braided: a length and plait that leave a plait, and how many. */
    if (!strcmp(cJSON_GetObjectItem(f, "style")->valuestring, "braided")) {
      braided_seen++;
      int plaits = cJSON_GetObjectItem(h, "plaits")->valueint;
      double len = cJSON_GetObjectItem(h, "length")->valuedouble;
      double per = cJSON_GetObjectItem(h, "curl_period")->valuedouble;
      double swing = cJSON_GetObjectItem(h, "curl_radius")->valuedouble / per;
      if (plaits < 1 || plaits > 2 || len < 2.2 - 1e-6 || len > 4.5 + 1e-6 || per < 0.15 - 1e-6 ||
          per > 0.6 + 1e-6 || swing < 0.15 - 1e-5 || swing > 0.35 + 1e-5)
        fail_msg("braided: %d plaits, length %g, period %g, swing %g of it", plaits, len, per,
                 swing);
    } else {
      assert_null(cJSON_GetObjectItem(h, "plaits"));
    }
    snprintf(path, sizeof path, "%s/%s", dir, cJSON_GetObjectItem(f, "file")->valuestring);
    hf_image img;
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_OK);
    assert_int_equal(img.width, 24);
    assert_true(hf_image_channel(&img, "background.A") >= 0);
    hf_image_free(&img);
    remove(path);
  }
  assert_int_equal(files_seen, 2);
  assert_int_equal(braided_seen, 2);
  assert_true(wmax > wmin);
  cJSON_Delete(doc);
  remove_in(dir, "manifest.json");
  rmdir(dir);
  remove(hair);
}

/* Each of the n ranges bad[k] = {MIN, MAX}, set in o through *lo and *hi,
 * is refused with HF_EINVAL and an error naming option. */
static void assert_ranges_refused(hfr_dataset_opts *o, float *lo, float *hi, const float bad[][2],
                                  size_t n, const char *option) {
  for (size_t k = 0; k < n; k++) {
    char err[512] = "";
    *lo = bad[k][0], *hi = bad[k][1];
    assert_int_equal(hfr_dataset_run(o, err, sizeof err), HF_EINVAL);
    if (!strstr(err, option))
      fail_msg("range %g,%g: error '%s' does not name %s", bad[k][0], bad[k][1], err, option);
  }
}

/* A small regimes set for the range tests, into /tmp/hf_test_<name>_<pid>
 * (written to dir, 256 bytes): 16x16 crops of 32-48 frames, a 1x1 truth,
 * count frames per style, strands strands each. */
static void small_regimes_set(hfr_dataset_opts *o, char *dir, const char *name, int count,
                              int strands) {
  snprintf(dir, 256, "/tmp/hf_test_%s_%d", name, (int)getpid());
  hfr_dataset_defaults(o);
  o->out_dir = dir;
  o->count = count;
  o->width = o->height = 16;
  o->strands = strands;
  o->regimes = 1, o->frame_min = 32, o->frame_max = 48;
  o->gt_supersample = 1;
  o->progress = 0;
  o->platform = "osmesa";
}

/* --width-px narrows the regimes' strand width: every frame's drawn width
 * lies in the range asked for, the manifest records it, and a range that
 * is empty or not positive is refused with an error naming the option. */
static void test_dataset_width_range(void **state) {
  (void)state;
  char dir[256];
  hfr_dataset_opts o;
  small_regimes_set(&o, dir, "width_px", 3, 200);
  o.styles[0] = HFR_STYLE_WAVY, o.styles[1] = HFR_STYLE_FUR;
  o.n_styles = 2;
  o.width_px_min = 0.6f, o.width_px_max = 2.5f;
  cJSON *doc = run_dataset(&o, R);
  assert_range_recorded(doc, "width_px_range", 0.6, 2.5);
  cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
  assert_int_equal(cJSON_GetArraySize(frames), 6);
  cJSON_ArrayForEach(f, frames) {
    double tw = cJSON_GetObjectItem(cJSON_GetObjectItem(f, "regime"), "target_width_px")->valuedouble;
    if (!(tw >= 0.6 - 1e-6 && tw <= 2.5 + 1e-6)) fail_msg("drawn width %g px outside 0.6..2.5", tw);
    remove_in(dir, cJSON_GetObjectItem(f, "file")->valuestring);
  }
  cJSON_Delete(doc);
  remove_in(dir, "manifest.json");
  rmdir(dir);
  const float bad[][2] = {{2.0f, 1.0f}, {-1.0f, 1.0f}, {0.0f, 1.0f}, {1.0f, 100.0f}};
  assert_ranges_refused(&o, &o.width_px_min, &o.width_px_max, bad, 4, "--width-px");
}

/* --opacity-range sets the regimes' strand opacity: with 1,1 and strands
 * wider than a pixel every frame's covered samples have alpha 1 (at the
 * median) and its opacity is recorded as 1; the manifest records the range;
 * the other draws (widths, frame sizes) are those of the default range; a
 * range that is empty or outside (0, 1] is refused naming the option. */
static void test_dataset_opacity_range(void **state) {
  (void)state;
  char dir[256];
  hfr_dataset_opts o;
  small_regimes_set(&o, dir, "opacity", 2, 300);
  o.styles[0] = HFR_STYLE_STRAIGHT;
  o.n_styles = 1;
  o.width_px_min = 6.0f, o.width_px_max = 8.0f; /* at least 1.5 px after the clump factor */
  double drawn[2][2]; /* [run][frame] target width */
  for (int run = 0; run < 2; run++) {
    o.opacity_min = o.opacity_max = run ? 1.0f : 0.0f;
    cJSON *doc = run_dataset(&o, R);
    assert_range_recorded(doc, "opacity_range", run ? 1.0 : 0.2, 1.0);
    cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
    assert_int_equal(cJSON_GetArraySize(frames), 2);
    int i = 0;
    cJSON_ArrayForEach(f, frames) {
      drawn[run][i++] =
          cJSON_GetObjectItem(cJSON_GetObjectItem(f, "regime"), "target_width_px")->valuedouble;
      double op = cJSON_GetObjectItem(cJSON_GetObjectItem(f, "hair"), "opacity")->valuedouble;
      cJSON *ca = cJSON_GetObjectItem(cJSON_GetObjectItem(f, "stats"), "covered_alpha_p10_p50_p90");
      double p50 = cJSON_GetArrayItem(ca, 1)->valuedouble;
      if (run) {
        assert_float_equal(op, 1.0, 1e-6);
        if (!(p50 > 0.999)) fail_msg("opaque strands 6-8 px wide: covered alpha p50 %g, not 1", p50);
      } else if (!(op >= 0.2 - 1e-6 && op < 1.0)) {
        fail_msg("default opacity %g outside [0.2, 1)", op);
      }
      remove_in(dir, cJSON_GetObjectItem(f, "file")->valuestring);
    }
    cJSON_Delete(doc);
  }
  assert_float_equal(drawn[0][0], drawn[1][0], 1e-9);
  assert_float_equal(drawn[0][1], drawn[1][1], 1e-9);
  remove_in(dir, "manifest.json");
  rmdir(dir);
  const float bad[][2] = {{0.8f, 0.5f}, {-0.1f, 1.0f}, {0.0f, 1.0f}, {0.5f, 1.5f}};
  assert_ranges_refused(&o, &o.opacity_min, &o.opacity_max, bad, 4, "--opacity-range");
  o.regimes = 0;
  assert_ranges_refused(&o, &o.opacity_min, &o.opacity_max, bad, 4, "--opacity-range");
}

/* Out of --regimes, --opacity-range draws each style frame's opacity in
 * it, per frame, from a stream of its own: the frames' other draws are
 * those of a run without it, which keeps the style's opacity and records
 * no range; the manifest records the range. */
static void test_dataset_opacity_range_styles(void **state) {
  (void)state;
  char dir[256];
  hfr_dataset_opts o;
  small_regimes_set(&o, dir, "opacity_st", 2, 200);
  o.regimes = 0;
  o.styles[0] = HFR_STYLE_BRAIDED, o.styles[1] = HFR_STYLE_WAVY;
  o.n_styles = 2;
  double length[2][4], opacity[2][4];
  for (int run = 0; run < 2; run++) {
    o.opacity_min = run ? 0.4f : 0, o.opacity_max = run ? 0.5f : 0;
    cJSON *doc = run_dataset(&o, R);
    assert_range_recorded(doc, "opacity_range", o.opacity_min, o.opacity_max);
    cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
    assert_int_equal(cJSON_GetArraySize(frames), 4);
    int i = 0;
    cJSON_ArrayForEach(f, frames) {
      cJSON *h = cJSON_GetObjectItem(f, "hair");
      length[run][i] = cJSON_GetObjectItem(h, "length")->valuedouble;
      opacity[run][i] = cJSON_GetObjectItem(h, "opacity")->valuedouble;
      if (run && !(opacity[run][i] >= 0.4 - 1e-6 && opacity[run][i] <= 0.5 + 1e-6))
        fail_msg("frame %d: opacity %g outside 0.4..0.5", i, opacity[run][i]);
      remove_in(dir, cJSON_GetObjectItem(f, "file")->valuestring);
      i++;
    }
    cJSON_Delete(doc);
    remove_in(dir, "manifest.json");
  }
  for (int i = 0; i < 4; i++) {
    assert_float_equal(length[0][i], length[1][i], 1e-9);
    /* The styles' own opacities (0.68 and more) are outside the range. */
    assert_true(opacity[0][i] > 0.6);
  }
  /* Drawn per frame, not one value for the set. */
  assert_true(opacity[1][0] != opacity[1][1]);
  rmdir(dir);
}

/* --gather-range draws each ponytail and braided frame's gather in it and
 * the manifest records it (the range in the options, the draw per frame);
 * the frame's other draws are those of a run without it; other styles'
 * frames record none; a range outside [0, 1] or empty is refused naming
 * the option. */
static void test_dataset_gather_range(void **state) {
  (void)state;
  char dir[256];
  hfr_dataset_opts o;
  small_regimes_set(&o, dir, "gather", 2, 200);
  o.styles[0] = HFR_STYLE_PONYTAIL, o.styles[1] = HFR_STYLE_BRAIDED, o.styles[2] = HFR_STYLE_WAVY;
  o.n_styles = 3;
  double drawn[2][6], gathers[6] = {0};
  for (int run = 0; run < 2; run++) {
    o.gather_min = run ? 0.6f : 0, o.gather_max = run ? 0.9f : 0;
    cJSON *doc = run_dataset(&o, R);
    assert_range_recorded(doc, "gather_range", o.gather_min, o.gather_max);
    cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
    assert_int_equal(cJSON_GetArraySize(frames), 6);
    int i = 0;
    cJSON_ArrayForEach(f, frames) {
      cJSON *h = cJSON_GetObjectItem(f, "hair");
      drawn[run][i] = cJSON_GetObjectItem(h, "length")->valuedouble +
                      cJSON_GetObjectItem(cJSON_GetObjectItem(f, "regime"), "target_width_px")->valuedouble;
      const char *style = cJSON_GetObjectItem(f, "style")->valuestring;
      cJSON *g = cJSON_GetObjectItem(h, "gather");
      if (run && strcmp(style, "wavy")) {
        assert_non_null(g);
        gathers[i] = g->valuedouble;
        if (!(gathers[i] >= 0.6 - 1e-6 && gathers[i] <= 0.9 + 1e-6))
          fail_msg("%s: gather %g outside 0.6..0.9", style, gathers[i]);
      } else {
        assert_null(g);
      }
      remove_in(dir, cJSON_GetObjectItem(f, "file")->valuestring);
      i++;
    }
    cJSON_Delete(doc);
    remove_in(dir, "manifest.json");
  }
  for (int i = 0; i < 6; i++) assert_float_equal(drawn[0][i], drawn[1][i], 1e-9);
  /* Drawn per frame, not one value for the set. */
  assert_true(gathers[0] != gathers[1]);
  rmdir(dir);
  const float bad[][2] = {{0.8f, 0.5f}, {-0.1f, 1.0f}, {0.5f, 1.5f}};
  assert_ranges_refused(&o, &o.gather_min, &o.gather_max, bad, 3, "--gather-range");
}

/* --smooth-share 1 draws every style frame as a smooth groom: frizz 0, and
 * clumping 0 but on spiky (its children's clumps kept), each frame's
 * manifest saying "smooth"; the frames' other draws are those of a run
 * without it; a share outside [0, 1] is refused naming the option. */
static void test_dataset_smooth_share(void **state) {
  (void)state;
  char dir[256];
  hfr_dataset_opts o;
  small_regimes_set(&o, dir, "smooth", 2, 200);
  o.styles[0] = HFR_STYLE_BRAIDED, o.styles[1] = HFR_STYLE_SPIKY, o.styles[2] = HFR_STYLE_WAVY;
  o.n_styles = 3;
  double drawn[2][6];
  for (int run = 0; run < 2; run++) {
    o.smooth_share = (float)run;
    cJSON *doc = run_dataset(&o, R);
    cJSON *share = cJSON_GetObjectItem(doc, "smooth_share");
    if (run) assert_float_equal(share->valuedouble, 1.0, 1e-9);
    else assert_null(share);
    cJSON *frames = cJSON_GetObjectItem(doc, "frames"), *f;
    assert_int_equal(cJSON_GetArraySize(frames), 6);
    int i = 0;
    cJSON_ArrayForEach(f, frames) {
      cJSON *h = cJSON_GetObjectItem(f, "hair");
      const char *style = cJSON_GetObjectItem(f, "style")->valuestring;
      double frizz = cJSON_GetObjectItem(h, "frizz")->valuedouble;
      double clumping = cJSON_GetObjectItem(h, "clumping")->valuedouble;
      drawn[run][i++] = cJSON_GetObjectItem(h, "length")->valuedouble +
                        cJSON_GetObjectItem(cJSON_GetObjectItem(f, "regime"), "target_width_px")->valuedouble;
      cJSON *smooth = cJSON_GetObjectItem(h, "smooth");
      if (run) {
        assert_true(cJSON_IsTrue(smooth));
        if (frizz != 0 || (clumping != 0) != !strcmp(style, "spiky"))
          fail_msg("%s, smooth: frizz %g, clumping %g", style, frizz, clumping);
      } else {
        assert_null(smooth);
        assert_true(frizz > 0);
      }
      remove_in(dir, cJSON_GetObjectItem(f, "file")->valuestring);
    }
    cJSON_Delete(doc);
    remove_in(dir, "manifest.json");
  }
  for (int i = 0; i < 6; i++) assert_float_equal(drawn[0][i], drawn[1][i], 1e-9);
  rmdir(dir);
  const float bad[] = {-0.5f, 1.5f};
  for (int k = 0; k < 2; k++) {
    char err[512] = "";
    o.smooth_share = bad[k];
    assert_int_equal(hfr_dataset_run(&o, err, sizeof err), HF_EINVAL);
    assert_non_null(strstr(err, "--smooth-share"));
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_dataset_smooth_share),
    cmocka_unit_test(test_dataset_gather_range),
    cmocka_unit_test(test_crop_equals_window),
    cmocka_unit_test(test_occluder_hides),
    cmocka_unit_test(test_conventions_framing),
    cmocka_unit_test(test_frame_stats),
    cmocka_unit_test(test_dataset_regimes),
    cmocka_unit_test(test_dataset_width_range),
    cmocka_unit_test(test_dataset_opacity_range),
    cmocka_unit_test(test_dataset_opacity_range_styles),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
