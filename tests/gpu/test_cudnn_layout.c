/* The cudnn backend's device layout and weight packing, checked on the CPU:
 * buffer sizes and views, padding, and a host emulation that runs the
 * network exactly as the GPU graph does (FP16 packed filters in cuDNN's
 * [K][R][S][C] order, transposed convs as data gradients, strided skip
 * views) and must match cpu-ref. Needs no GPU. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "cudnn_layout.h"
#include "hfcore.h"

static void test_base_views(void **state) {
  (void)state;
  hf_net_config cfg;
  assert_int_equal(hf_variant_preset("Base", &cfg), HF_OK);
  hf_cl_layout lo;
  assert_int_equal(hf_cl_layout_init(&cfg, 2, 64, 48, HF_CL_DECONV_BWD_DATA, &lo), HF_OK);
  assert_int_equal(lo.nlayers, 6);
  assert_int_equal(lo.cin_pad, 24);
  assert_int_equal(lo.nbufs, HF_CL_BUF_SKIP0 + 2);
  assert_true(lo.buf_elems[HF_CL_BUF_IN] == (size_t)2 * 64 * 48 * 24);
  assert_true(lo.buf_elems[HF_CL_BUF_SKIP0] == (size_t)2 * 32 * 24 * 64);      /* 2*32 */
  assert_true(lo.buf_elems[HF_CL_BUF_SKIP0 + 1] == (size_t)2 * 16 * 12 * 128); /* 2*64 */
  assert_true(lo.buf_elems[HF_CL_BUF_DEEP] == (size_t)2 * 8 * 6 * 128);
  assert_true(lo.buf_elems[HF_CL_BUF_OUT] == (size_t)2 * 64 * 48 * HF_CL_OUT_CH);
  const hf_cl_layer *enc0 = &lo.layers[0], *enc1 = &lo.layers[1], *enc2 = &lo.layers[2];
  const hf_cl_layer *dec2 = &lo.layers[3], *dec1 = &lo.layers[4], *dec0 = &lo.layers[5];
  assert_string_equal(enc0->name, "enc0");
  assert_string_equal(dec0->name, "dec0");
  /* enc0 writes the second half of skip0; enc1 reads that same view. */
  assert_int_equal(enc0->out.buf, HF_CL_BUF_SKIP0);
  assert_int_equal(enc0->out.ch_off, 32);
  assert_int_equal(enc0->out.pix_stride, 64);
  assert_memory_equal(&enc1->in, &enc0->out, sizeof enc1->in);
  assert_int_equal(enc2->out.buf, HF_CL_BUF_DEEP);
  /* dec2 reads the bottleneck, writes the first half of skip1. */
  assert_int_equal(dec2->kind, HF_CL_CONV_BWD_DATA);
  assert_int_equal(dec2->in.buf, HF_CL_BUF_DEEP);
  assert_int_equal(dec2->out.buf, HF_CL_BUF_SKIP0 + 1);
  assert_int_equal(dec2->out.ch_off, 0);
  assert_int_equal(dec2->out.pix_stride, 128);
  assert_int_equal(dec2->k, 128);
  assert_int_equal(dec2->c, 64);
  /* dec1 reads all of skip1 (2*64), dec0 all of skip0 and writes OUT. */
  assert_int_equal(dec1->in.c, 128);
  assert_int_equal(dec1->in.pix_stride, 128);
  assert_int_equal(dec0->in.buf, HF_CL_BUF_SKIP0);
  assert_int_equal(dec0->out.buf, HF_CL_BUF_OUT);
  assert_int_equal(dec0->out.c, HF_CL_OUT_CH);
  assert_int_equal(dec0->relu, 0);
  assert_int_equal(dec1->relu, 1);
  assert_int_equal(dec0->out.h, 48);
  assert_int_equal(dec0->out.w, 64);
}

static void test_padding_and_limits(void **state) {
  (void)state;
  static const struct { const char *name; int cin_pad; } want[] = {
      {"Base@1spp", 8}, {"Base@2spp", 16}, {"Base", 24}};
  hf_net_config cfg;
  hf_cl_layout lo;
  for (size_t i = 0; i < sizeof want / sizeof want[0]; i++) {
    assert_int_equal(hf_variant_preset(want[i].name, &cfg), HF_OK);
    assert_int_equal(hf_cl_layout_init(&cfg, 1, 8, 8, HF_CL_DECONV_BWD_DATA, &lo), HF_OK);
    assert_int_equal(lo.cin_pad, want[i].cin_pad);
    assert_int_equal(lo.layers[0].c, want[i].cin_pad);
  }
  assert_int_equal(hf_variant_preset("Deep", &cfg), HF_OK);
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 24, 16, HF_CL_DECONV_BWD_DATA, &lo), HF_EINVAL); /* 24 % 16 */
  assert_int_equal(hf_cl_layout_init(&cfg, 0, 16, 16, HF_CL_DECONV_BWD_DATA, &lo), HF_EINVAL);
  assert_int_equal(hf_cl_layout_init(&cfg, 1 << 30, 1 << 16, 1 << 16, HF_CL_DECONV_BWD_DATA, &lo), HF_ERANGE);
  /* Every filter block starts 256-byte aligned. */
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 16, 16, 7, &lo), HF_EINVAL); /* deconv mode */
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 16, 16, HF_CL_DECONV_BWD_DATA, &lo), HF_OK);
  for (int j = 0; j < lo.nlayers; j++) {
    assert_int_equal(lo.layers[j].w_off % 128, 0);
    assert_true(lo.layers[j].w_off + lo.layers[j].w_elems <= lo.w_elems);
  }
}

/* Channel counts that are not multiples of 8 exercise every padding path,
 * including the split of a decoder input into two padded halves. */
static hf_net_config odd_config(void) {
  hf_net_config cfg;
  memset(&cfg, 0, sizeof cfg);
  snprintf(cfg.name, sizeof cfg.name, "odd");
  cfg.spp = 1;
  cfg.in_channels = 6;
  cfg.out_channels = 3;
  cfg.num_levels = 2;
  cfg.levels[0] = 12;
  cfg.levels[1] = 20;
  return cfg;
}

static void test_pack_odd_channels(void **state) {
  (void)state;
  hf_net_config cfg = odd_config();
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(&cfg, 7, &w), HF_OK);
  hf_cl_layout lo;
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 4, 4, HF_CL_DECONV_BWD_DATA, &lo), HF_OK);
  uint16_t *w16 = malloc(lo.w_elems * 2), *b16 = malloc(lo.b_elems * 2);
  float *b32 = malloc(lo.b_elems * 4);
  assert_non_null(w16);
  assert_non_null(b16);
  assert_non_null(b32);
  assert_int_equal(hf_cl_pack_weights(&lo, w, w16, b16, b32), HF_OK);
  /* dec0: input 2*12 real channels -> 2*16 padded; real j >= 12 sits at
   * 16 + (j - 12); K = 32, C = 8 (3 real outputs). */
  const hf_cl_layer *dec0 = &lo.layers[3];
  assert_string_equal(dec0->name, "dec0");
  assert_int_equal(dec0->k, 32);
  assert_int_equal(dec0->c, 8);
  size_t nonzero = 0;
  for (int k = 0; k < 32; k++)
    for (int r = 0; r < 4; r++)
      for (int s = 0; s < 4; s++)
        for (int c = 0; c < 8; c++) {
          uint16_t got = w16[dec0->w_off + ((size_t)(k * 4 + r) * 4 + s) * 8 + c];
          int j = k < 16 ? (k < 12 ? k : -1) : (k - 16 < 12 ? 12 + k - 16 : -1);
          if (j < 0 || c >= 3) {
            assert_int_equal(got, 0);
          } else {
            float want = w->dec_w[0][((size_t)(j * 3 + c) * 4 + r) * 4 + s];
            assert_int_equal(got, hf_f32_to_f16(want));
            nonzero += got != 0;
          }
        }
  assert_true(nonzero > 0);
  /* enc1: K = 24 (20 real), C = 16 (12 real). */
  const hf_cl_layer *enc1 = &lo.layers[1];
  assert_int_equal(enc1->k, 24);
  assert_int_equal(enc1->c, 16);
  for (int k = 0; k < 24; k++)
    for (int c = 0; c < 16; c++) {
      uint16_t got = w16[enc1->w_off + ((size_t)(k * 3 + 1) * 3 + 2) * 16 + c];
      if (k >= 20 || c >= 12)
        assert_int_equal(got, 0);
      else
        assert_int_equal(got, hf_f32_to_f16(w->enc_w[1][((size_t)(k * 12 + c) * 3 + 1) * 3 + 2]));
    }
  for (int k = 0; k < 24; k++) {
    assert_true(b32[enc1->b_off + k] == (k < 20 ? w->enc_b[1][k] : 0.0f));
    assert_int_equal(b16[enc1->b_off + k], k < 20 ? hf_f32_to_f16(w->enc_b[1][k]) : 0);
  }
  free(w16);
  free(b16);
  free(b32);
  hf_weights_free(w);
}

/* ---- host emulation of the GPU pipeline ---------------------------------- */

static float *view_at(float **bufs, const hf_cl_view *v, size_t pixel) {
  return bufs[v->buf] + v->ch_off + pixel * v->pix_stride;
}

/* cuDNN's definitions: forward cross-correlation y[k] += x[c] * W[k][r][s][c]
 * at input (oy*stride - pad + r); data gradient dx[c] += dy[k] * W[k][r][s][c]
 * wherever the forward conv would have read dx at that tap. */
static void emu_layer(float **bufs, int batch, const hf_cl_layer *ly, const uint16_t *w16,
                      const float *b32) {
  const int R = ly->r, S = ly->s, K = ly->k, C = ly->c, st = ly->stride, pd = ly->pad;
  const float *bias = b32 + ly->b_off;
  const hf_cl_view *in = &ly->in, *out = &ly->out;
  /* SHUFFLE: the conv writes a dense 4*C scratch at the input resolution,
   * then depth-to-space moves it into the layer's output view. */
  const int shuffle = ly->kind == HF_CL_CONV_SHUFFLE;
  hf_cl_view sv = {HF_CL_MAX_BUFS, 0, K, K, in->h, in->w};   /* the spare slot */
  if (shuffle) {
    assert_int_equal(K, 4 * out->c);
    bufs[sv.buf] = malloc((size_t)batch * in->h * in->w * K * sizeof(float));
    assert_non_null(bufs[sv.buf]);
    out = &sv;
  }
  float *wf = malloc(ly->w_elems * sizeof *wf);
  float *acc = malloc(out->c * sizeof *acc);
  assert_non_null(wf);
  assert_non_null(acc);
  for (size_t i = 0; i < ly->w_elems; i++) wf[i] = hf_f16_to_f32(w16[ly->w_off + i]);
  for (int n = 0; n < batch; n++)
    for (int y = 0; y < out->h; y++)
      for (int x = 0; x < out->w; x++) {
        for (int o = 0; o < out->c; o++) acc[o] = bias[o];
        for (int r = 0; r < R; r++)
          for (int s = 0; s < S; s++) {
            int iy, ix;
            if (ly->kind != HF_CL_CONV_BWD_DATA) {
              iy = y * st - pd + r;
              ix = x * st - pd + s;
            } else {
              int ty = y + pd - r, tx = x + pd - s;
              if (ty < 0 || tx < 0 || ty % st || tx % st) continue;
              iy = ty / st;
              ix = tx / st;
            }
            if (iy < 0 || ix < 0 || iy >= in->h || ix >= in->w) continue;
            const float *xp = view_at(bufs, in, ((size_t)n * in->h + iy) * in->w + ix);
            if (ly->kind != HF_CL_CONV_BWD_DATA) {
              for (int k = 0; k < K; k++)
                for (int c = 0; c < C; c++) acc[k] += xp[c] * wf[((size_t)(k * R + r) * S + s) * C + c];
            } else {
              for (int k = 0; k < K; k++)
                for (int c = 0; c < C; c++) acc[c] += xp[k] * wf[((size_t)(k * R + r) * S + s) * C + c];
            }
          }
        float *yp = view_at(bufs, out, ((size_t)n * out->h + y) * out->w + x);
        for (int o = 0; o < out->c; o++) yp[o] = ly->relu && acc[o] < 0 ? 0 : acc[o];
      }
  if (shuffle) {
    const int co = K / 4;
    for (int n = 0; n < batch; n++)
      for (int y = 0; y < in->h; y++)
        for (int x = 0; x < in->w; x++)
          for (int q = 0; q < 4; q++) {
            const float *src = view_at(bufs, &sv, ((size_t)n * in->h + y) * in->w + x) + q * co;
            float *dst = view_at(bufs, &ly->out,
                                 ((size_t)n * ly->out.h + 2 * y + q / 2) * ly->out.w + 2 * x + q % 2);
            memcpy(dst, src, co * sizeof(float));
          }
    free(bufs[sv.buf]);
    bufs[sv.buf] = NULL;
  }
  free(wf);
  free(acc);
}

static uint64_t rng = 88172645463325252ull;
static float frand(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (float)(rng >> 40) / (float)(1 << 24);
}

static void emulate_vs_cpu_ref(const hf_net_config *cfg, int deconv, int batch, int width,
                               int height) {
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(cfg, 1234, &w), HF_OK);
  const int a = hf_net_align(cfg);
  const int pw = (width + a - 1) / a * a, ph = (height + a - 1) / a * a;
  hf_cl_layout lo;
  assert_int_equal(hf_cl_layout_init(cfg, batch, pw, ph, deconv, &lo), HF_OK);
  uint16_t *w16 = malloc(lo.w_elems * 2), *b16 = malloc(lo.b_elems * 2);
  float *b32 = malloc(lo.b_elems * 4);
  assert_int_equal(hf_cl_pack_weights(&lo, w, w16, b16, b32), HF_OK);

  const size_t npx = (size_t)batch * width * height;
  float *in = malloc(npx * cfg->in_channels * 4), *want = malloc(npx * 12), *got = malloc(npx * 12);
  assert_non_null(in);
  for (size_t i = 0; i < npx * cfg->in_channels; i++) in[i] = frand();

  float *bufs[HF_CL_MAX_BUFS + 1] = {0};   /* + a spare for SHUFFLE scratch */
  for (int b = 0; b < lo.nbufs; b++) {
    bufs[b] = calloc(lo.buf_elems[b], sizeof(float));
    assert_non_null(bufs[b]);
  }
  /* The input kernel: zero-padded, channels padded. */
  for (int n = 0; n < batch; n++)
    for (int y = 0; y < height; y++)
      for (int x = 0; x < width; x++)
        memcpy(bufs[HF_CL_BUF_IN] + (((size_t)n * ph + y) * pw + x) * lo.cin_pad,
               in + (((size_t)n * height + y) * width + x) * cfg->in_channels,
               cfg->in_channels * sizeof(float));
  for (int j = 0; j < lo.nlayers; j++) emu_layer(bufs, batch, &lo.layers[j], w16, b32);
  /* The output kernel: transforms (or residual) + crop. */
  for (int n = 0; n < batch; n++) {
    hf_input_view view = {bufs[HF_CL_BUF_IN] + (size_t)n * ph * pw * lo.cin_pad, width, height,
                          pw, lo.cin_pad};
    for (int y = 0; y < height; y++)
      for (int x = 0; x < width; x++) {
        float *o = got + (((size_t)n * height + y) * width + x) * 3;
        size_t px = ((size_t)n * ph + y) * pw + x;
        memcpy(o, bufs[HF_CL_BUF_OUT] + px * HF_CL_OUT_CH, 12);
        hf_output_finish(cfg, &view, x, y, o);
      }
  }

  hf_backend *b;
  char why[256];
  assert_int_equal(hf_backend_create("cpu-ref", &b, why, sizeof why), HF_OK);
  hf_model *m;
  assert_int_equal(hf_model_create(b, w, &m), HF_OK);
  hf_io io = {batch, width, height, in, HF_F32, want, HF_F32};
  assert_int_equal(hf_model_run(m, &io, NULL), HF_OK);
  double num = 0, den = 0;
  for (size_t i = 0; i < npx * 3; i++) {
    assert_false(isnan(got[i]));
    num += (got[i] - want[i]) * (double)(got[i] - want[i]);
    den += (double)want[i] * want[i];
  }
  double rel = sqrt(num / den);
  printf("  %-10s %-9s batch %d %dx%d: relative L2 %.2e\n", cfg->name,
         deconv == HF_CL_DECONV_SHUFFLE ? "shuffle" : "bwd-data", batch, width, height, rel);
  /* FP16 filters alone: ~1e-3. A wrong channel map or tap order: ~1. */
  assert_true(rel < 5e-3);

  hf_model_destroy(m);
  hf_backend_destroy(b);
  for (int k = 0; k < lo.nbufs; k++) free(bufs[k]);
  free(in);
  free(want);
  free(got);
  free(w16);
  free(b16);
  free(b32);
  hf_weights_free(w);
}

static void test_emulation_presets(void **state) {
  (void)state;
  for (int i = 0; i < hf_variant_preset_count(); i++) {
    hf_net_config cfg;
    assert_int_equal(hf_variant_preset(hf_variant_preset_name(i), &cfg), HF_OK);
    emulate_vs_cpu_ref(&cfg, HF_CL_DECONV_BWD_DATA, 2, 21, 13);
    emulate_vs_cpu_ref(&cfg, HF_CL_DECONV_SHUFFLE, 2, 21, 13);
  }
}

static void test_emulation_odd_channels(void **state) {
  (void)state;
  hf_net_config cfg = odd_config();
  emulate_vs_cpu_ref(&cfg, HF_CL_DECONV_BWD_DATA, 1, 37, 23);
  emulate_vs_cpu_ref(&cfg, HF_CL_DECONV_SHUFFLE, 1, 37, 23);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_base_views),
      cmocka_unit_test(test_padding_and_limits),
      cmocka_unit_test(test_pack_odd_channels),
      cmocka_unit_test(test_emulation_presets),
      cmocka_unit_test(test_emulation_odd_channels),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
