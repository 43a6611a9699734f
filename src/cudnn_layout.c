/* Device memory layout and weight packing for the cudnn backend: see
 * cudnn_layout.h. */
#include <stdio.h>
#include <string.h>

#include "cudnn_layout.h"

/* Filter and bias blocks start on 256-byte boundaries, as cuDNN prefers. */
#define W_ALIGN 128   /* FP16 elements */
#define B_ALIGN 64

static size_t round_up_sz(size_t n, size_t a) { return (n + a - 1) / a * a; }

static hf_cl_view view(int buf, int ch_off, int pix_stride, int c, int h, int w) {
  hf_cl_view v = {buf, ch_off, pix_stride, c, h, w};
  return v;
}

int hf_cl_layout_init(const hf_net_config *cfg, int batch, int pw, int ph, int deconv,
                      hf_cl_layout *lo) {
  if (!cfg || !lo || batch < 1 || pw < 1 || ph < 1) return HF_EINVAL;
  if (deconv != HF_CL_DECONV_BWD_DATA && deconv != HF_CL_DECONV_SHUFFLE) return HF_EINVAL;
  int rc = hf_net_config_validate(cfg);
  if (rc) return rc;
  const int L = cfg->num_levels;
  const int align = hf_net_align(cfg);
  if (pw % align || ph % align) return HF_EINVAL;
  memset(lo, 0, sizeof *lo);
  lo->batch = batch;
  lo->pw = pw;
  lo->ph = ph;
  lo->cin_pad = hf_cl_pad8(cfg->in_channels);
  lo->nbufs = HF_CL_BUF_SKIP0 + (L - 1);

  int cp[HF_MAX_LEVELS];
  for (int i = 0; i < L; i++) cp[i] = hf_cl_pad8(cfg->levels[i]);

  /* Buffer sizes, overflow-checked: batch * h * w * channels. */
  const size_t frame = (size_t)pw * (size_t)ph;
  if ((size_t)batch > (size_t)-1 / frame) return HF_ERANGE;
  const size_t pix = (size_t)batch * frame;
  const size_t lim = ((size_t)1 << 62) / 2;   /* bytes stay < 2^62 */
#define SET_BUF(b, npix, ch)                                        \
  do {                                                              \
    if ((size_t)(ch) > lim / (npix)) return HF_ERANGE;              \
    lo->buf_elems[b] = (size_t)(npix) * (size_t)(ch);               \
  } while (0)
  SET_BUF(HF_CL_BUF_IN, pix, lo->cin_pad);
  SET_BUF(HF_CL_BUF_OUT, pix, HF_CL_OUT_CH);
  SET_BUF(HF_CL_BUF_DEEP, pix >> (2 * L), cp[L - 1]);
  for (int i = 0; i + 1 < L; i++) SET_BUF(HF_CL_BUF_SKIP0 + i, pix >> (2 * (i + 1)), 2 * cp[i]);
#undef SET_BUF

  size_t woff = 0, boff = 0;
  int n = 0;
  /* Encoders: enc{i} reads enc{i-1}'s view (or the input), writes the
   * second half of skip{i}, or the bottleneck for i = L-1. */
  hf_cl_view prev = view(HF_CL_BUF_IN, 0, lo->cin_pad, lo->cin_pad, ph, pw);
  for (int i = 0; i < L; i++) {
    hf_cl_layer *ly = &lo->layers[n++];
    snprintf(ly->name, sizeof ly->name, "enc%d", i);
    int h = ph >> (i + 1), w = pw >> (i + 1);
    ly->kind = HF_CL_CONV_FWD;
    ly->level = i;
    ly->relu = 1;
    ly->in = prev;
    ly->out = i + 1 < L ? view(HF_CL_BUF_SKIP0 + i, cp[i], 2 * cp[i], cp[i], h, w)
                        : view(HF_CL_BUF_DEEP, 0, cp[i], cp[i], h, w);
    ly->k = cp[i];
    ly->c = prev.c;
    ly->r = ly->s = 3;
    ly->stride = 2;
    ly->pad = 1;
    ly->in_real = hf_enc_in(cfg, i);
    ly->in_split = ly->in_split_pad = ly->in_real;
    ly->out_real = hf_enc_out(cfg, i);
    prev = ly->out;
  }
  /* Decoders: dec{i} reads the bottleneck (i = L-1) or the whole skip{i}
   * buffer, writes the first half of skip{i-1} or the output buffer. */
  for (int i = L - 1; i >= 0; i--) {
    hf_cl_layer *ly = &lo->layers[n++];
    snprintf(ly->name, sizeof ly->name, "dec%d", i);
    int hin = ph >> (i + 1), win = pw >> (i + 1);
    int hout = ph >> i, wout = pw >> i;
    ly->kind = HF_CL_CONV_BWD_DATA;
    ly->level = i;
    ly->relu = i > 0;
    if (i == L - 1) {
      ly->in = view(HF_CL_BUF_DEEP, 0, cp[i], cp[i], hin, win);
      ly->in_split = ly->in_split_pad = cfg->levels[i];
    } else {
      ly->in = view(HF_CL_BUF_SKIP0 + i, 0, 2 * cp[i], 2 * cp[i], hin, win);
      ly->in_split = cfg->levels[i];
      ly->in_split_pad = cp[i];
    }
    ly->out = i > 0 ? view(HF_CL_BUF_SKIP0 + i - 1, 0, 2 * cp[i - 1], cp[i - 1], hout, wout)
                    : view(HF_CL_BUF_OUT, 0, HF_CL_OUT_CH, HF_CL_OUT_CH, hout, wout);
    ly->k = ly->in.c;
    ly->c = ly->out.c;
    ly->r = ly->s = 4;
    ly->stride = 2;
    ly->pad = 1;
    ly->in_real = hf_dec_in(cfg, i);
    ly->out_real = hf_dec_out(cfg, i);
    if (deconv == HF_CL_DECONV_SHUFFLE) {
      ly->kind = HF_CL_CONV_SHUFFLE;
      ly->k = 4 * ly->out.c;
      ly->c = ly->in.c;
      ly->r = ly->s = 3;
      ly->stride = 1;
    }
  }
  lo->nlayers = n;

  for (int j = 0; j < n; j++) {
    hf_cl_layer *ly = &lo->layers[j];
    ly->w_elems = (size_t)ly->k * ly->r * ly->s * ly->c;
    ly->w_off = woff;
    woff = round_up_sz(woff + ly->w_elems, W_ALIGN);
    ly->b_elems = hf_cl_is_fwd(ly) ? ly->k : ly->c;
    ly->b_off = boff;
    boff = round_up_sz(boff + (size_t)ly->b_elems, B_ALIGN);
  }
  lo->w_elems = woff;
  lo->b_elems = boff;
  return HF_OK;
}

static int map_in(const hf_cl_layer *ly, int j) {
  return j < ly->in_split ? j : ly->in_split_pad + (j - ly->in_split);
}

int hf_cl_pack_weights(const hf_cl_layout *lo, const hf_weights *w, uint16_t *w16,
                       uint16_t *b16, float *b32) {
  if (!lo || !w || !w16 || !b16 || !b32) return HF_EINVAL;
  memset(w16, 0, lo->w_elems * sizeof *w16);   /* f16 +0 is all-zero bits */
  memset(b16, 0, lo->b_elems * sizeof *b16);
  memset(b32, 0, lo->b_elems * sizeof *b32);
  for (int j = 0; j < lo->nlayers; j++) {
    const hf_cl_layer *ly = &lo->layers[j];
    const int R = ly->r, S = ly->s, in_real = ly->in_real, out_real = ly->out_real;
    if (map_in(ly, in_real - 1) >= (hf_cl_is_fwd(ly) ? ly->c : ly->k)) return HF_EINVAL;
    uint16_t *f = w16 + ly->w_off;
    const float *src, *bias;
    if (ly->kind == HF_CL_CONV_FWD) {
      /* Conv2d [out][in][R][S] -> [K=out][R][S][C=in]. */
      src = w->enc_w[ly->level];
      bias = w->enc_b[ly->level];
      for (int o = 0; o < out_real; o++)
        for (int i = 0; i < in_real; i++)
          for (int r = 0; r < R; r++)
            for (int s = 0; s < S; s++)
              f[(((size_t)o * R + r) * S + s) * ly->c + map_in(ly, i)] =
                  hf_f32_to_f16(src[(((size_t)o * in_real + i) * R + r) * S + s]);
    } else if (ly->kind == HF_CL_CONV_SHUFFLE) {
      /* ConvTranspose2d [in][out][4][4] -> 3x3 conv [K=(2dy+dx)*Cout+o][ty][tx][C=in]:
       * tap t (input row y-1+t) feeds output phase d through kernel row
       * tap4[d][t] (-1: not at all). */
      static const int tap4[2][3] = {{3, 1, -1}, {-1, 2, 0}};
      const int co = ly->k / 4, T = 4;
      src = w->dec_w[ly->level];
      bias = w->dec_b[ly->level];
      for (int dy = 0; dy < 2; dy++)
        for (int dx = 0; dx < 2; dx++)
          for (int ty = 0; ty < 3; ty++)
            for (int tx = 0; tx < 3; tx++) {
              const int r4 = tap4[dy][ty], s4 = tap4[dx][tx];
              if (r4 < 0 || s4 < 0) continue;
              for (int o = 0; o < out_real; o++)
                for (int i = 0; i < in_real; i++)
                  f[(((size_t)((dy * 2 + dx) * co + o) * R + ty) * S + tx) * ly->c + map_in(ly, i)] =
                      hf_f32_to_f16(src[(((size_t)i * out_real + o) * T + r4) * T + s4]);
            }
      for (int q = 0; q < 4; q++)
        for (int o = 0; o < out_real; o++) {
          b16[ly->b_off + q * co + o] = hf_f32_to_f16(bias[o]);
          b32[ly->b_off + q * co + o] = bias[o];
        }
      continue;
    } else {
      /* ConvTranspose2d [in][out][R][S] -> [K=in][R][S][C=out]. */
      src = w->dec_w[ly->level];
      bias = w->dec_b[ly->level];
      for (int i = 0; i < in_real; i++)
        for (int o = 0; o < out_real; o++)
          for (int r = 0; r < R; r++)
            for (int s = 0; s < S; s++)
              f[(((size_t)map_in(ly, i) * R + r) * S + s) * ly->c + o] =
                  hf_f32_to_f16(src[(((size_t)i * out_real + o) * R + r) * S + s]);
    }
    for (int o = 0; o < out_real; o++) {
      b16[ly->b_off + o] = hf_f32_to_f16(bias[o]);
      b32[ly->b_off + o] = bias[o];
    }
  }
  return HF_OK;
}
