/* The cudnn backend's device layout, layer forms and weight packing,
 * checked on the CPU: buffer sizes and views, padding, the geometry of each
 * decoder form, and a host emulation that runs the network exactly as the
 * GPU does (FP16 packed filters in cuDNN's [K][R][S][C] order, transposed
 * convs as data gradients or as the 2x2 D2S / PHASE rewrites or the 3x3
 * SHUFFLE one, asymmetric paddings, strided and step-2 views, the output
 * stage reading D2S phases directly) and must match cpu-ref. Needs no GPU. */
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
  assert_int_equal(hf_cl_layout_init(&cfg, 2, 64, 48, &lo), HF_OK);
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
  assert_int_equal(dec2->dec, 1);
  assert_int_equal(dec2->in.buf, HF_CL_BUF_DEEP);
  assert_int_equal(dec2->out.buf, HF_CL_BUF_SKIP0 + 1);
  assert_int_equal(dec2->out.ch_off, 0);
  assert_int_equal(dec2->out.pix_stride, 128);
  hf_cl_form f;
  assert_int_equal(hf_cl_layer_form(&lo, dec2, HF_CL_FORM_BWD_DATA, &f), HF_OK);
  assert_int_equal(f.nconv, 1);
  assert_int_equal(f.conv[0].bwd_data, 1);
  assert_int_equal(f.conv[0].k, 128);
  assert_int_equal(f.conv[0].c, 64);
  assert_int_equal(f.conv[0].r, 4);
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
  /* Forms that do not apply are refused. */
  assert_int_equal(hf_cl_layer_form(&lo, enc0, HF_CL_FORM_D2S, &f), HF_EINVAL);
  assert_int_equal(hf_cl_layer_form(&lo, dec0, HF_CL_FORM_FWD, &f), HF_EINVAL);
  assert_int_equal(hf_cl_layer_form(&lo, dec0, 99, &f), HF_EINVAL);
  for (int form = 0; form < HF_CL_NFORMS; form++)
    assert_int_equal(hf_cl_form_from_name(hf_cl_form_name(form)), form);
  assert_int_equal(hf_cl_form_from_name("nope"), HF_ENOTFOUND);
}

/* The geometry of the 2x2 rewrites: D2S computes (h+1) x (w+1) conv pixels
 * of 4*co channels; PHASE writes step-2 views with the phase's paddings;
 * dec0 in D2S leaves its output in the scratch for the output stage. */
static void test_decoder_forms(void **state) {
  (void)state;
  hf_net_config cfg;
  assert_int_equal(hf_variant_preset("Base", &cfg), HF_OK);
  hf_cl_layout lo;
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 64, 48, &lo), HF_OK);
  const hf_cl_layer *dec1 = &lo.layers[4], *dec0 = &lo.layers[5];
  hf_cl_form f;
  assert_int_equal(hf_cl_layer_form(&lo, dec1, HF_CL_FORM_D2S, &f), HF_OK);
  assert_int_equal(f.nconv, 1);
  assert_int_equal(f.d2s, HF_CL_D2S_OFFSET);
  assert_int_equal(f.out_in_scratch, 0);
  assert_int_equal(f.conv[0].k, 4 * 32);
  assert_int_equal(f.conv[0].r, 2);
  assert_int_equal(f.conv[0].stride, 1);
  assert_int_equal(f.conv[0].pad_pre[0], 1);
  assert_int_equal(f.conv[0].pad_post[1], 1);
  assert_int_equal(f.scratch.h, 12 + 1);
  assert_int_equal(f.scratch.w, 16 + 1);
  assert_int_equal(f.scratch.c, 128);
  assert_true(hf_cl_view_dense(&f.scratch));
  assert_memory_equal(&f.out, &dec1->out, sizeof f.out);

  assert_int_equal(hf_cl_layer_form(&lo, dec1, HF_CL_FORM_PHASE, &f), HF_OK);
  assert_int_equal(f.nconv, 4);
  for (int q = 0; q < 4; q++) {
    const hf_cl_conv *cv = &f.conv[q];
    const int dy = q >> 1, dx = q & 1;
    assert_int_equal(cv->k, 32);
    assert_int_equal(cv->pad_pre[0], 1 - dy);
    assert_int_equal(cv->pad_pre[1], 1 - dx);
    assert_int_equal(cv->pad_post[0], dy);
    assert_int_equal(cv->pad_post[1], dx);
    assert_int_equal(cv->y.step, 2);
    assert_int_equal(cv->y.h, 12);
    assert_int_equal(cv->y.w, 16);
    /* Pixel (m, n) of phase (dy, dx) is output pixel (2m+dy, 2n+dx). */
    assert_true(hf_cl_view_offset(&cv->y) == (size_t)(dy * 32 + dx) * 64);
    int64_t s[4];
    hf_cl_view_strides(&cv->y, s);
    assert_true(s[0] == 24 * 32 * 64 && s[1] == 1 && s[2] == 2 * 32 * 64 && s[3] == 2 * 64);
    assert_true(cv->w_off == dec1->w_off[HF_CL_FORM_PHASE] + (size_t)q * 32 * 4 * 128);  /* C = 2*64 */
    assert_true(cv->b_off == dec1->b_off[HF_CL_FORM_PHASE] + (size_t)q * 32);
  }

  assert_int_equal(hf_cl_layer_form(&lo, dec0, HF_CL_FORM_D2S, &f), HF_OK);
  assert_int_equal(f.co, 3);
  assert_int_equal(f.conv[0].k, 12);
  assert_int_equal(f.out_in_scratch, 1);
  hf_cl_raw r = hf_cl_raw_output(&f);
  assert_int_equal(r.buf, HF_CL_BUF_SCRATCH);
  assert_int_equal(r.div, 2);
  assert_int_equal(r.offset, 1);
  assert_int_equal(r.pix_stride, 12);
  assert_int_equal(r.rows, 24 + 1);
  assert_int_equal(hf_cl_layer_form(&lo, dec0, HF_CL_FORM_PHASE, &f), HF_OK);
  assert_int_equal(f.co, 4);
  assert_int_equal(f.out.pix_stride, 4);
  r = hf_cl_raw_output(&f);
  assert_int_equal(r.buf, HF_CL_BUF_OUT);
  assert_int_equal(r.div, 1);
  assert_int_equal(r.pix_stride, 4);
  assert_int_equal(hf_cl_layer_form(&lo, dec0, HF_CL_FORM_BWD_DATA, &f), HF_OK);
  r = hf_cl_raw_output(&f);
  assert_int_equal(r.pix_stride, HF_CL_OUT_CH);
}

static void test_padding_and_limits(void **state) {
  (void)state;
  static const struct { const char *name; int cin_pad; } want[] = {
      {"Base@1spp", 8}, {"Base@2spp", 16}, {"Base", 24}};
  hf_net_config cfg;
  hf_cl_layout lo;
  for (size_t i = 0; i < sizeof want / sizeof want[0]; i++) {
    assert_int_equal(hf_variant_preset(want[i].name, &cfg), HF_OK);
    assert_int_equal(hf_cl_layout_init(&cfg, 1, 8, 8, &lo), HF_OK);
    assert_int_equal(lo.cin_pad, want[i].cin_pad);
    assert_int_equal(lo.layers[0].in.c, want[i].cin_pad);
  }
  assert_int_equal(hf_variant_preset("Deep", &cfg), HF_OK);
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 24, 16, &lo), HF_EINVAL); /* 24 % 16 */
  assert_int_equal(hf_cl_layout_init(&cfg, 0, 16, 16, &lo), HF_EINVAL);
  assert_int_equal(hf_cl_layout_init(&cfg, 1 << 30, 1 << 16, 1 << 16, &lo), HF_ERANGE);
  /* Every filter block of every form starts 256-byte aligned. */
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 16, 16, &lo), HF_OK);
  for (int j = 0; j < lo.nlayers; j++)
    for (int form = 0; form < HF_CL_NFORMS; form++) {
      const hf_cl_layer *ly = &lo.layers[j];
      assert_int_equal((ly->w_elems[form] > 0), (form == HF_CL_FORM_FWD) != ly->dec);
      if (!ly->w_elems[form]) continue;
      assert_int_equal(ly->w_off[form] % 128, 0);
      assert_true(ly->w_off[form] + ly->w_elems[form] <= lo.w_elems);
      assert_true(ly->b_off[form] + ly->b_elems[form] <= lo.b_elems);
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
  assert_int_equal(hf_cl_layout_init(&cfg, 1, 4, 4, &lo), HF_OK);
  uint16_t *w16 = malloc(lo.w_elems * 2), *b16 = malloc(lo.b_elems * 2);
  float *b32 = malloc(lo.b_elems * 4);
  assert_non_null(w16);
  assert_non_null(b16);
  assert_non_null(b32);
  assert_int_equal(hf_cl_pack_weights(&lo, w, w16, b16, b32), HF_OK);
  /* dec0 as data gradient: input 2*12 real channels -> 2*16 padded; real
   * j >= 12 sits at 16 + (j - 12); K = 32, C = 8 (3 real outputs). */
  const hf_cl_layer *dec0 = &lo.layers[3];
  assert_string_equal(dec0->name, "dec0");
  assert_int_equal(dec0->in.c, 32);
  const uint16_t *f = w16 + dec0->w_off[HF_CL_FORM_BWD_DATA];
  size_t nonzero = 0;
  for (int k = 0; k < 32; k++)
    for (int r = 0; r < 4; r++)
      for (int s = 0; s < 4; s++)
        for (int c = 0; c < 8; c++) {
          uint16_t got = f[((size_t)(k * 4 + r) * 4 + s) * 8 + c];
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
  /* dec0 as D2S: [K = (2dy+dx)*3 + o][ty][tx][C = 32], kernel tap
   * (hf_cl_tap2(dy, ty), hf_cl_tap2(dx, tx)); biases repeated per phase. */
  f = w16 + dec0->w_off[HF_CL_FORM_D2S];
  for (int q = 0; q < 4; q++)
    for (int o = 0; o < 3; o++)
      for (int ty = 0; ty < 2; ty++)
        for (int tx = 0; tx < 2; tx++)
          for (int k = 0; k < 32; k++) {
            uint16_t got = f[((size_t)((q * 3 + o) * 2 + ty) * 2 + tx) * 32 + k];
            int j = k < 16 ? (k < 12 ? k : -1) : (k - 16 < 12 ? 12 + k - 16 : -1);
            const int r4 = hf_cl_tap2(q >> 1, ty), s4 = hf_cl_tap2(q & 1, tx);
            assert_int_equal(got, j < 0 ? 0
                                        : hf_f32_to_f16(w->dec_w[0][((size_t)(j * 3 + o) * 4 + r4) * 4 + s4]));
          }
  for (int q = 0; q < 4; q++)
    for (int o = 0; o < 3; o++)
      assert_true(b32[dec0->b_off[HF_CL_FORM_D2S] + q * 3 + o] == w->dec_b[0][o]);
  /* enc1: K = 24 (20 real), C = 16 (12 real). */
  const hf_cl_layer *enc1 = &lo.layers[1];
  assert_int_equal(enc1->out.c, 24);
  assert_int_equal(enc1->in.c, 16);
  f = w16 + enc1->w_off[HF_CL_FORM_FWD];
  for (int k = 0; k < 24; k++)
    for (int c = 0; c < 16; c++) {
      uint16_t got = f[((size_t)(k * 3 + 1) * 3 + 2) * 16 + c];
      if (k >= 20 || c >= 12)
        assert_int_equal(got, 0);
      else
        assert_int_equal(got, hf_f32_to_f16(w->enc_w[1][((size_t)(k * 12 + c) * 3 + 1) * 3 + 2]));
    }
  const size_t bo = enc1->b_off[HF_CL_FORM_FWD];
  for (int k = 0; k < 24; k++) {
    assert_true(b32[bo + k] == (k < 20 ? w->enc_b[1][k] : 0.0f));
    assert_int_equal(b16[bo + k], k < 20 ? hf_f32_to_f16(w->enc_b[1][k]) : 0);
  }
  free(w16);
  free(b16);
  free(b32);
  hf_weights_free(w);
}

/* ---- host emulation of the GPU pipeline ---------------------------------- */

static float *view_px(float **bufs, const hf_cl_view *v, int n, int y, int x) {
  return bufs[v->buf] + v->ch_off +
         (((size_t)n * v->bh + v->y0 + (size_t)v->step * y) * v->bw + v->x0 +
          (size_t)v->step * x) * v->pix_stride;
}

/* cuDNN's definitions: forward cross-correlation y[k] += x[c] * W[k][r][s][c]
 * at input (oy*stride - pad_pre + r); data gradient dx[c] += dy[k] *
 * W[k][r][s][c] wherever the forward conv would have read dx at that tap.
 * Then bias and ReLU, as the fused epilogue or the bias kernel does. */
static void emu_conv(float **bufs, int batch, const hf_cl_conv *cv, const uint16_t *w16,
                     const float *b32) {
  const int R = cv->r, S = cv->s, K = cv->k, C = cv->c, st = cv->stride;
  const hf_cl_view *in = &cv->x, *out = &cv->y;
  const size_t welems = (size_t)K * R * S * C;
  float *wf = malloc(welems * sizeof *wf);
  float *acc = malloc(out->c * sizeof *acc);
  assert_non_null(wf);
  assert_non_null(acc);
  for (size_t i = 0; i < welems; i++) wf[i] = hf_f16_to_f32(w16[cv->w_off + i]);
  for (int n = 0; n < batch; n++)
    for (int y = 0; y < out->h; y++)
      for (int x = 0; x < out->w; x++) {
        for (int o = 0; o < out->c; o++) acc[o] = b32[cv->b_off + o];
        for (int r = 0; r < R; r++)
          for (int s = 0; s < S; s++) {
            int iy, ix;
            if (!cv->bwd_data) {
              iy = y * st - cv->pad_pre[0] + r;
              ix = x * st - cv->pad_pre[1] + s;
            } else {
              int ty = y + cv->pad_pre[0] - r, tx = x + cv->pad_pre[1] - s;
              if (ty < 0 || tx < 0 || ty % st || tx % st) continue;
              iy = ty / st;
              ix = tx / st;
            }
            if (iy < 0 || ix < 0 || iy >= in->h || ix >= in->w) continue;
            const float *xp = view_px(bufs, in, n, iy, ix);
            for (int k = 0; k < K; k++)
              for (int c = 0; c < C; c++) {
                const float wv = wf[((size_t)(k * R + r) * S + s) * C + c];
                if (!cv->bwd_data) acc[k] += xp[c] * wv;
                else acc[c] += xp[k] * wv;
              }
          }
        float *yp = view_px(bufs, out, n, y, x);
        for (int o = 0; o < out->c; o++) yp[o] = cv->relu && acc[o] < 0 ? 0 : acc[o];
      }
  free(wf);
  free(acc);
}

/* One layer in one form: its convs, then the depth-to-space (what
 * hf_cuk_depth_to_space computes) unless the output stage reads the
 * scratch. bufs[HF_CL_BUF_SCRATCH] holds the form's scratch; the caller
 * frees it after the output stage when it is dec0's. */
static void emu_layer(float **bufs, int batch, const hf_cl_form *f, const uint16_t *w16,
                      const float *b32) {
  if (f->d2s) {
    free(bufs[HF_CL_BUF_SCRATCH]);
    bufs[HF_CL_BUF_SCRATCH] =
        calloc((size_t)batch * f->scratch.h * f->scratch.w * f->scratch.c, sizeof(float));
    assert_non_null(bufs[HF_CL_BUF_SCRATCH]);
  }
  for (int c = 0; c < f->nconv; c++) emu_conv(bufs, batch, &f->conv[c], w16, b32);
  if (!f->d2s || f->out_in_scratch) return;
  const int off = f->d2s == HF_CL_D2S_OFFSET, co = f->co;
  for (int n = 0; n < batch; n++)
    for (int Y = 0; Y < f->out.h; Y++)
      for (int X = 0; X < f->out.w; X++) {
        const int dy = Y & 1, dx = X & 1;
        const float *s = view_px(bufs, &f->scratch, n, Y / 2 + dy * off, X / 2 + dx * off) +
                         (2 * dy + dx) * co;
        memcpy(view_px(bufs, &f->out, n, Y, X), s, co * sizeof(float));
      }
}

/* The raw output of frame pixel (x, y) as the output stage reads it. */
static const float *raw_px(float **bufs, const hf_cl_raw *r, int n, int y, int x) {
  const float *base = bufs[r->buf];
  if (r->div == 1) return base + (((size_t)n * r->rows + y) * r->cols + x) * r->pix_stride;
  const int dy = y & 1, dx = x & 1;
  return base + (((size_t)n * r->rows + y / 2 + dy * r->offset) * r->cols + x / 2 + dx * r->offset) *
                    r->pix_stride +
         (2 * dy + dx) * r->co;
}

static uint64_t rng = 88172645463325252ull;
static float frand(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (float)(rng >> 40) / (float)(1 << 24);
}

#define MIXED (-1)   /* decoders cycle through the forms */

static void emulate_vs_cpu_ref(const hf_net_config *cfg, int dec_form, int batch, int width,
                               int height) {
  hf_weights *w;
  assert_int_equal(hf_weights_init_random(cfg, 1234, &w), HF_OK);
  const int a = hf_net_align(cfg);
  const int pw = (width + a - 1) / a * a, ph = (height + a - 1) / a * a;
  hf_cl_layout lo;
  assert_int_equal(hf_cl_layout_init(cfg, batch, pw, ph, &lo), HF_OK);
  uint16_t *w16 = malloc(lo.w_elems * 2), *b16 = malloc(lo.b_elems * 2);
  float *b32 = malloc(lo.b_elems * 4);
  assert_int_equal(hf_cl_pack_weights(&lo, w, w16, b16, b32), HF_OK);

  const size_t npx = (size_t)batch * width * height;
  float *in = malloc(npx * cfg->in_channels * 4), *want = malloc(npx * 12), *got = malloc(npx * 12);
  assert_non_null(in);
  for (size_t i = 0; i < npx * cfg->in_channels; i++) in[i] = frand();

  float *bufs[HF_CL_MAX_BUFS + 1] = {0};   /* + the form scratch */
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
  static const int cycle[] = {HF_CL_FORM_D2S, HF_CL_FORM_PHASE, HF_CL_FORM_BWD_DATA,
                              HF_CL_FORM_SHUFFLE};
  hf_cl_form f;
  for (int j = 0; j < lo.nlayers; j++) {
    const hf_cl_layer *ly = &lo.layers[j];
    const int form = !ly->dec ? HF_CL_FORM_FWD : dec_form != MIXED ? dec_form : cycle[j % 4];
    assert_int_equal(hf_cl_layer_form(&lo, ly, form, &f), HF_OK);
    emu_layer(bufs, batch, &f, w16, b32);
  }
  /* The output stage: f is dec0's form. The Kernel architecture's head is
   * part of it (hf_cuk_output_kernel): the FP32 1x1 convolution over dec0's
   * hidden channels, already through the layer's ReLU, and the input. */
  const hf_cl_raw raw = hf_cl_raw_output(&f);
  const int head = hf_head_in(cfg), hidden = cfg->kernel_hidden;
  for (int n = 0; n < batch; n++) {
    hf_input_view view = {bufs[HF_CL_BUF_IN] + (size_t)n * ph * pw * lo.cin_pad, width, height,
                          pw, lo.cin_pad};
    for (int y = 0; y < height; y++)
      for (int x = 0; x < width; x++) {
        float v[HF_MAX_RAW_CHANNELS];
        const float *rp = raw_px(bufs, &raw, n, y, x);
        const float *ip = view.data + ((size_t)y * pw + x) * lo.cin_pad;
        for (int o = 0; o < cfg->out_channels; o++) {
          if (!head) {
            v[o] = rp[o];
            continue;
          }
          const float *wr = w->head_w + (size_t)o * head;
          v[o] = w->head_b[o];
          for (int j = 0; j < head; j++) v[o] += wr[j] * (j < hidden ? rp[j] : ip[j - hidden]);
        }
        hf_output_finish(cfg, &view, x, y, v);
        memcpy(got + (((size_t)n * height + y) * width + x) * 3, v, 12);
      }
  }

  hf_backend *b;
  char why[256];
  assert_int_equal(hf_backend_create("cpu-ref", &b, why, sizeof why), HF_OK);
  hf_model *m;
  assert_int_equal(hf_model_create(b, w, &m), HF_OK);
  /* hf_model_run takes a frame with an estimate planar: each frame's
   * samples, then its estimate (the emulation read them interleaved). */
  float *planar = in;
  if (cfg->estimate) {
    const int ns = cfg->spp * HF_FEATURES_PER_SAMPLE, cin = cfg->in_channels;
    const size_t fpx = (size_t)width * height;
    assert_non_null(planar = malloc(npx * cin * sizeof(float)));
    for (int n = 0; n < batch; n++)
      for (size_t p = 0; p < fpx; p++) {
        const float *src = in + ((size_t)n * fpx + p) * cin;
        float *frame = planar + (size_t)n * fpx * cin;
        memcpy(frame + p * ns, src, ns * sizeof(float));
        memcpy(frame + fpx * ns + p * HF_ESTIMATE_CHANNELS, src + ns,
               HF_ESTIMATE_CHANNELS * sizeof(float));
      }
  }
  hf_io io = {batch, width, height, planar, HF_F32, want, HF_F32};
  assert_int_equal(hf_model_run(m, &io, NULL), HF_OK);
  if (planar != in) free(planar);
  double num = 0, den = 0;
  for (size_t i = 0; i < npx * 3; i++) {
    assert_false(isnan(got[i]));
    num += (got[i] - want[i]) * (double)(got[i] - want[i]);
    den += (double)want[i] * want[i];
  }
  double rel = sqrt(num / den);
  printf("  %-10s %-9s batch %d %dx%d: relative L2 %.2e\n", cfg->name,
         dec_form == MIXED ? "mixed" : hf_cl_form_name(dec_form), batch, width, height, rel);
  /* FP16 filters alone: ~1e-3. A wrong channel map or tap order: ~1. */
  assert_true(rel < 5e-3);

  hf_model_destroy(m);
  hf_backend_destroy(b);
  for (int k = 0; k <= HF_CL_MAX_BUFS; k++) free(bufs[k]);
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
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_BWD_DATA, 2, 21, 13);
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_D2S, 2, 21, 13);
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_PHASE, 1, 21, 13);
    emulate_vs_cpu_ref(&cfg, MIXED, 1, 19, 11);
  }
}

static void test_emulation_odd_channels(void **state) {
  (void)state;
  hf_net_config cfg = odd_config();
  emulate_vs_cpu_ref(&cfg, HF_CL_FORM_BWD_DATA, 1, 37, 23);
  emulate_vs_cpu_ref(&cfg, HF_CL_FORM_D2S, 1, 37, 23);
  emulate_vs_cpu_ref(&cfg, HF_CL_FORM_PHASE, 1, 37, 23);
  emulate_vs_cpu_ref(&cfg, HF_CL_FORM_SHUFFLE, 1, 37, 23);
  emulate_vs_cpu_ref(&cfg, MIXED, 2, 5, 3);
}

/* The Kernel architecture's dec0 has more than 3 channels: padded to 8 in
 * every form, with the head's ReLU when it has one. A 5x5 kernel without a
 * head (28 raw channels), an odd hidden count and the largest kernel, on
 * the odd-channel network. */
static void test_emulation_kernel(void **state) {
  (void)state;
  static const struct { int r, hidden; } k[] = {{2, 0}, {1, 5}, {4, 64}};
  for (size_t i = 0; i < sizeof k / sizeof k[0]; i++) {
    hf_net_config cfg = odd_config();
    cfg.arch = HF_ARCH_KERNEL;
    cfg.kernel_radius = k[i].r;
    cfg.kernel_hidden = k[i].hidden;
    cfg.out_channels = hf_kernel_taps(k[i].r) + 3;
    snprintf(cfg.name, sizeof cfg.name, "odd r%d h%d", k[i].r, k[i].hidden);
    hf_cl_layout lo;
    assert_int_equal(hf_cl_layout_init(&cfg, 1, 8, 8, &lo), HF_OK);
    const hf_cl_layer *dec0 = &lo.layers[lo.nlayers - 1];
    assert_int_equal(lo.out_ch, hf_cl_pad8(hf_dec_out(&cfg, 0)));
    assert_int_equal(dec0->out.c, lo.out_ch);
    assert_int_equal(dec0->out_real, k[i].hidden ? k[i].hidden : hf_kernel_taps(k[i].r) + 3);
    assert_int_equal(dec0->relu, k[i].hidden > 0);
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_BWD_DATA, 1, 13, 9);
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_D2S, 2, 13, 9);
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_PHASE, 1, 13, 9);
    emulate_vs_cpu_ref(&cfg, HF_CL_FORM_SHUFFLE, 1, 13, 9);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_base_views),
      cmocka_unit_test(test_decoder_forms),
      cmocka_unit_test(test_padding_and_limits),
      cmocka_unit_test(test_pack_odd_channels),
      cmocka_unit_test(test_emulation_presets),
      cmocka_unit_test(test_emulation_odd_channels),
      cmocka_unit_test(test_emulation_kernel),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
