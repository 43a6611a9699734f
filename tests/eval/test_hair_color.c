/* One set of trained weights serves any uniform hair colour (paper, Fig. 11).
 *
 * The network predicts the colour factor and the highlight, not RGB; the
 * hair colour only enters at compositing time. So a frame is rendered and
 * filtered once, then composited with very different hair colours, each
 * against the ground truth composited with the same colour. For every colour
 * the filtered frame must beat the input's own 4-sample average by a clear
 * margin in MSE and SSIM; a network that had learned one colour (or a
 * composite that baked one in) would fail for the others.
 *
 *   test_hair_color WEIGHTS.safetensors [FIGURE.png]
 *
 * With FIGURE.png it also draws one row per colour: the 4-sample average,
 * the network, the ground truth (docs/quality_hair_colors.png). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "eval_metrics.h"
#include "hfcore.h"
#include "hfrender.h"

#define W 128
#define H 128

static const char *weights_path, *figure_path;

#define GAP 4
#define FIG_W (3 * W + 4 * GAP)

/* Tile col of row in the figure (white gaps between tiles). */
static void put_tile(float *fig, int row, int col, const float *rgb) {
  for (int y = 0; y < H; y++)
    memcpy(fig + ((size_t)(GAP + row * (H + GAP) + y) * FIG_W + GAP + col * (W + GAP)) * 3,
           rgb + (size_t)y * W * 3, (size_t)W * 3 * sizeof(float));
}

static const struct {
  const char *name;
  float rgb[3];
} COLORS[] = {
    {"black", {0.02f, 0.015f, 0.01f}},
    {"brown", {0.45f, 0.25f, 0.12f}},
    {"blonde", {0.9f, 0.75f, 0.45f}},
    {"red", {0.7f, 0.18f, 0.06f}},
    {"white", {0.95f, 0.95f, 0.95f}},
};

static void clamp01(float *v, size_t n) {
  for (size_t i = 0; i < n; i++) v[i] = fminf(1.f, fmaxf(0.f, v[i]));
}

static void test_every_color(void **state) {
  (void)state;
  hfr_frame f;
  hfr_frame_defaults(&f, W, H);
  hfr_style_defaults(HFR_STYLE_WAVY, &f.style);
  f.style.strands = 20000;
  f.style.seed = 11;
  f.view.shadow_size = 512;
  f.view.cam_yaw_deg = 150;
  f.view.cam_distance = 2.6f;
  f.platform = "osmesa";
  hf_image img;
  char err[512] = "";
  int rc = hfr_render_frame(&f, &img, NULL, err, sizeof err);
  if (rc != HF_OK) fail_msg("render: %s", err);

  hf_weights *wts = NULL;
  if (hf_weights_load(weights_path, &wts, err, sizeof err)) fail_msg("%s", err);
  hf_backend *be = NULL;
  assert_int_equal(hf_backend_create("cpu-ref", &be, err, sizeof err), HF_OK);
  hf_model *m = NULL;
  assert_int_equal(hf_model_create(be, wts, &m), HF_OK);
  const int spp = wts->cfg.spp;
  hf_weights_free(wts);

  const size_t npx = (size_t)W * H;
  float *in = malloc(npx * spp * HF_FEATURES_PER_SAMPLE * sizeof(float));
  float *net = malloc(npx * 3 * sizeof(float)), *avg = malloc(npx * 3 * sizeof(float));
  float *gt = malloc(npx * 3 * sizeof(float));
  float *rgb_net = malloc(npx * 3 * sizeof(float)), *rgb_avg = malloc(npx * 3 * sizeof(float));
  float *rgb_gt = malloc(npx * 3 * sizeof(float));
  uint8_t *mask = malloc(npx);
  assert_true(in && net && avg && gt && rgb_net && rgb_avg && rgb_gt && mask);
  assert_true(hf_features_from_image(&img, spp, in) >= 0);
  hf_io io = {.batch = 1, .width = W, .height = H, .in = in, .in_dtype = HF_F32,
              .out = net, .out_dtype = HF_F32};
  assert_int_equal(hf_model_run(m, &io, NULL), HF_OK);
  /* The input's own estimate, as `hairfilter eval` defines it. */
  for (size_t p = 0; p < npx; p++)
    hf_st_estimate(in + p * spp * HF_FEATURES_PER_SAMPLE, spp, avg + 3 * p);
  int gi[3];
  for (int c = 0; c < 3; c++) {
    char name[32];
    snprintf(name, sizeof name, "gt.%s", HF_OUTPUT_NAMES[c]);
    gi[c] = hf_image_channel(&img, name);
    assert_true(gi[c] >= 0);
  }
  size_t hair = 0;
  for (size_t p = 0; p < npx; p++) {
    for (int c = 0; c < 3; c++) gt[3 * p + c] = img.data[p * img.channels + gi[c]];
    hair += (mask[p] = gt[3 * p + 2] > 0);
  }
  assert_true(hair > npx / 10);   /* the view shows plenty of hair */

  const float light[3] = {1, 1, 1}, bg[3] = {0.18f, 0.2f, 0.24f};
  const int ncol = (int)(sizeof COLORS / sizeof COLORS[0]);
  const size_t fig_h = (size_t)ncol * (H + GAP) + GAP;
  float *fig = NULL;
  if (figure_path) {
    fig = malloc(fig_h * FIG_W * 3 * sizeof(float));
    assert_non_null(fig);
    for (size_t i = 0; i < fig_h * FIG_W * 3; i++) fig[i] = 1.f;
  }
  for (int i = 0; i < ncol; i++) {
    hf_composite(net, W, H, COLORS[i].rgb, light, bg, rgb_net);
    hf_composite(avg, W, H, COLORS[i].rgb, light, bg, rgb_avg);
    hf_composite(gt, W, H, COLORS[i].rgb, light, bg, rgb_gt);
    clamp01(rgb_net, npx * 3), clamp01(rgb_avg, npx * 3), clamp01(rgb_gt, npx * 3);
    double mse_net = eval_mse(rgb_net, rgb_gt, W, H, 3, mask, NULL);
    double mse_avg = eval_mse(rgb_avg, rgb_gt, W, H, 3, mask, NULL);
    double ssim_net = eval_ssim(rgb_net, rgb_gt, W, H, 3, mask);
    double ssim_avg = eval_ssim(rgb_avg, rgb_gt, W, H, 3, mask);
    print_message("%-6s  network %.2f dB SSIM %.4f | 4-sample average %.2f dB SSIM %.4f\n",
                  COLORS[i].name, eval_psnr(mse_net, 1), ssim_net, eval_psnr(mse_avg, 1),
                  ssim_avg);
    /* At least 1 dB better and a higher SSIM, for every colour. */
    assert_true(mse_net < mse_avg * 0.79);
    assert_true(ssim_net > ssim_avg);
    if (fig) {
      put_tile(fig, i, 0, rgb_avg);
      put_tile(fig, i, 1, rgb_net);
      put_tile(fig, i, 2, rgb_gt);
    }
  }
  if (fig) {
    assert_int_equal(hf_png_write_rgb(figure_path, fig, FIG_W, (int)fig_h), HF_OK);
    print_message("figure %s: rows %d colours; columns 4-sample average, network, truth\n",
                  figure_path, ncol);
    free(fig);
  }
  free(in), free(net), free(avg), free(gt), free(rgb_net), free(rgb_avg), free(rgb_gt);
  free(mask);
  hf_model_destroy(m);
  hf_backend_destroy(be);
  hf_image_free(&img);
}

int main(int argc, char **argv) {
  if (argc != 2 && argc != 3) {
    fprintf(stderr, "usage: test_hair_color WEIGHTS.safetensors [FIGURE.png]\n");
    return 2;
  }
  weights_path = argv[1];
  figure_path = argc == 3 ? argv[2] : NULL;
  const struct CMUnitTest tests[] = {cmocka_unit_test(test_every_color)};
  return cmocka_run_group_tests(tests, NULL, NULL);
}
