/* Device memory layout, layer forms and weight packing for the cudnn
 * backend: see cudnn_layout.h. */
#include <stdio.h>
#include <string.h>
#include <strings.h>

#include "cudnn_layout.h"

/* Filter and bias blocks start on 256-byte boundaries, as cuDNN prefers. */
#define W_ALIGN 128   /* FP16 elements */
#define B_ALIGN 64

static const char *const form_names[HF_CL_NFORMS] = {"fwd", "bwd-data", "d2s", "phase",
                                                     "shuffle"};

const char *hf_cl_form_name(int form) {
  return form >= 0 && form < HF_CL_NFORMS ? form_names[form] : "?";
}

int hf_cl_form_from_name(const char *name) {
  for (int f = 0; f < HF_CL_NFORMS; f++)
    if (!strcasecmp(name, form_names[f])) return f;
  return HF_ENOTFOUND;
}

static size_t round_up_sz(size_t n, size_t a) { return (n + a - 1) / a * a; }

static hf_cl_view view(int buf, int ch_off, int pix_stride, int c, int h, int w) {
  hf_cl_view v = {buf, ch_off, pix_stride, c, h, w, h, w, 0, 0, 1};
  return v;
}

hf_cl_view hf_cl_view_packed(int buf, int c, int h, int w) { return view(buf, 0, c, c, h, w); }

size_t hf_cl_view_offset(const hf_cl_view *v) {
  return (size_t)v->ch_off + ((size_t)v->y0 * v->bw + v->x0) * v->pix_stride;
}

void hf_cl_view_strides(const hf_cl_view *v, int64_t strides[4]) {
  strides[0] = (int64_t)v->bh * v->bw * v->pix_stride;
  strides[1] = 1;
  strides[2] = (int64_t)v->step * v->bw * v->pix_stride;
  strides[3] = (int64_t)v->step * v->pix_stride;
}

int hf_cl_view_dense(const hf_cl_view *v) {
  return v->ch_off == 0 && v->pix_stride == v->c && v->step == 1 && v->y0 == 0 && v->x0 == 0 &&
         v->bh == v->h && v->bw == v->w;
}

/* Output channels per phase of a decoder in each form (dec0 of 3 real
 * channels: as few as each form allows; more, as every other decoder). */
static int dec_co(const hf_cl_layer *ly, int form) {
  if (ly->level > 0 || ly->out_real > HF_OUT_CHANNELS) return ly->out.c;
  switch (form) {
  case HF_CL_FORM_D2S: return 3;
  case HF_CL_FORM_PHASE: return 4;
  default: return HF_CL_OUT_CH;
  }
}

int hf_cl_layout_init(const hf_net_config *cfg, int batch, int pw, int ph, hf_cl_layout *lo) {
  if (!cfg || !lo || batch < 1 || pw < 1 || ph < 1) return HF_EINVAL;
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
  lo->out_ch = hf_dec_out(cfg, 0) > HF_OUT_CHANNELS ? hf_cl_pad8(hf_dec_out(cfg, 0)) : HF_CL_OUT_CH;
  lo->nbufs = HF_CL_BUF_SKIP0 + (L - 1);

  int cp[HF_MAX_LEVELS];
  for (int i = 0; i < L; i++) cp[i] = hf_cl_pad8(cfg->levels[i]);

  /* Buffer sizes, overflow-checked: batch * h * w * channels. The largest
   * form scratch, 4 * (h+1) * (w+1) * co elements for a D2S decoder, stays
   * under 5x the OUT buffer, so the same bound covers it. */
  const size_t frame = (size_t)pw * (size_t)ph;
  if ((size_t)batch > (size_t)-1 / frame) return HF_ERANGE;
  const size_t pix = (size_t)batch * frame;
  const size_t lim = ((size_t)1 << 62) / 2 / 8;   /* bytes of any tensor stay < 2^62 */
#define SET_BUF(b, npix, ch)                                        \
  do {                                                              \
    if ((size_t)(ch) > lim / (npix)) return HF_ERANGE;              \
    lo->buf_elems[b] = (size_t)(npix) * (size_t)(ch);               \
  } while (0)
  SET_BUF(HF_CL_BUF_IN, pix, lo->cin_pad);
  SET_BUF(HF_CL_BUF_OUT, pix, lo->out_ch);
  SET_BUF(HF_CL_BUF_DEEP, pix >> (2 * L), cp[L - 1]);
  for (int i = 0; i + 1 < L; i++) SET_BUF(HF_CL_BUF_SKIP0 + i, pix >> (2 * (i + 1)), 2 * cp[i]);
#undef SET_BUF

  int n = 0;
  /* Encoders: enc{i} reads enc{i-1}'s view (or the input), writes the
   * second half of skip{i}, or the bottleneck for i = L-1. */
  hf_cl_view prev = view(HF_CL_BUF_IN, 0, lo->cin_pad, lo->cin_pad, ph, pw);
  for (int i = 0; i < L; i++) {
    hf_cl_layer *ly = &lo->layers[n++];
    snprintf(ly->name, sizeof ly->name, "enc%d", i);
    int h = ph >> (i + 1), w = pw >> (i + 1);
    ly->level = i;
    ly->relu = 1;
    ly->in = prev;
    ly->out = i + 1 < L ? view(HF_CL_BUF_SKIP0 + i, cp[i], 2 * cp[i], cp[i], h, w)
                        : view(HF_CL_BUF_DEEP, 0, cp[i], cp[i], h, w);
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
    ly->dec = 1;
    ly->level = i;
    ly->relu = i > 0 || hf_head_in(cfg) > 0;   /* the head reads ReLU(dec0) */
    if (i == L - 1) {
      ly->in = view(HF_CL_BUF_DEEP, 0, cp[i], cp[i], hin, win);
      ly->in_split = ly->in_split_pad = cfg->levels[i];
    } else {
      ly->in = view(HF_CL_BUF_SKIP0 + i, 0, 2 * cp[i], 2 * cp[i], hin, win);
      ly->in_split = cfg->levels[i];
      ly->in_split_pad = cp[i];
    }
    ly->out = i > 0 ? view(HF_CL_BUF_SKIP0 + i - 1, 0, 2 * cp[i - 1], cp[i - 1], hout, wout)
                    : view(HF_CL_BUF_OUT, 0, lo->out_ch, lo->out_ch, hout, wout);
    ly->in_real = hf_dec_in(cfg, i);
    ly->out_real = hf_dec_out(cfg, i);
  }
  lo->nlayers = n;

  /* Packed weights: one block per layer and form. */
  size_t woff = 0, boff = 0;
  for (int j = 0; j < n; j++) {
    hf_cl_layer *ly = &lo->layers[j];
    for (int form = 0; form < HF_CL_NFORMS; form++) {
      if ((form == HF_CL_FORM_FWD) == ly->dec) continue;
      size_t we, be;
      if (form == HF_CL_FORM_FWD) {
        we = (size_t)ly->out.c * 9 * ly->in.c;
        be = ly->out.c;
      } else if (form == HF_CL_FORM_BWD_DATA) {
        we = (size_t)ly->in.c * 16 * dec_co(ly, form);
        be = dec_co(ly, form);
      } else {
        const int taps = form == HF_CL_FORM_SHUFFLE ? 9 : 4;
        we = (size_t)4 * dec_co(ly, form) * taps * ly->in.c;
        be = (size_t)4 * dec_co(ly, form);
      }
      ly->w_off[form] = woff;
      ly->w_elems[form] = we;
      woff = round_up_sz(woff + we, W_ALIGN);
      ly->b_off[form] = boff;
      ly->b_elems[form] = be;
      boff = round_up_sz(boff + be, B_ALIGN);
    }
  }
  lo->w_elems = woff;
  lo->b_elems = boff;
  return HF_OK;
}

static hf_cl_conv conv_base(int bwd_data, int k, int c, int r, int stride, int pad, int relu) {
  hf_cl_conv cv;
  memset(&cv, 0, sizeof cv);
  cv.bwd_data = bwd_data;
  cv.k = k;
  cv.c = c;
  cv.r = cv.s = r;
  cv.stride = stride;
  cv.pad_pre[0] = cv.pad_pre[1] = cv.pad_post[0] = cv.pad_post[1] = pad;
  cv.relu = relu;
  return cv;
}

int hf_cl_layer_form(const hf_cl_layout *lo, const hf_cl_layer *ly, int form, hf_cl_form *f) {
  if (!lo || !ly || !f || form < 0 || form >= HF_CL_NFORMS) return HF_EINVAL;
  if ((form == HF_CL_FORM_FWD) == ly->dec) return HF_EINVAL;
  memset(f, 0, sizeof *f);
  f->form = form;
  f->out = ly->out;
  const int cin = ly->in.c;
  if (form == HF_CL_FORM_FWD) {
    hf_cl_conv *cv = &f->conv[f->nconv++];
    *cv = conv_base(0, ly->out.c, cin, 3, 2, 1, ly->relu);
    cv->x = ly->in;
    cv->y = ly->out;
    cv->w_off = ly->w_off[form];
    cv->b_off = ly->b_off[form];
    f->co = ly->out.c;
    return HF_OK;
  }
  const int co = dec_co(ly, form);
  const int hin = ly->in.h, win = ly->in.w;
  f->co = co;
  if (ly->level == 0 && co != ly->out.c)   /* dec0 with fewer channels per phase */
    f->out = hf_cl_view_packed(HF_CL_BUF_OUT, co, ly->out.h, ly->out.w);
  switch (form) {
  case HF_CL_FORM_BWD_DATA: {
    /* The data gradient of the forward conv (K = the decoder's input). */
    hf_cl_conv *cv = &f->conv[f->nconv++];
    *cv = conv_base(1, cin, co, 4, 2, 1, ly->relu);
    cv->x = ly->in;
    cv->y = f->out;
    break;
  }
  case HF_CL_FORM_D2S:
  case HF_CL_FORM_SHUFFLE: {
    const int d2s = form == HF_CL_FORM_D2S;
    hf_cl_conv *cv = &f->conv[f->nconv++];
    *cv = conv_base(0, 4 * co, cin, d2s ? 2 : 3, 1, 1, ly->relu);
    f->scratch = hf_cl_view_packed(HF_CL_BUF_SCRATCH, 4 * co, hin + d2s, win + d2s);
    cv->x = ly->in;
    cv->y = f->scratch;
    f->d2s = d2s ? HF_CL_D2S_OFFSET : HF_CL_D2S_SHUFFLE;
    if (d2s && ly->level == 0) {
      f->out_in_scratch = 1;
      f->out = f->scratch;
    }
    break;
  }
  case HF_CL_FORM_PHASE:
    for (int q = 0; q < 4; q++) {
      const int dy = q >> 1, dx = q & 1;
      hf_cl_conv *cv = &f->conv[f->nconv++];
      *cv = conv_base(0, co, cin, 2, 1, 0, ly->relu);
      cv->pad_pre[0] = 1 - dy;
      cv->pad_pre[1] = 1 - dx;
      cv->pad_post[0] = dy;
      cv->pad_post[1] = dx;
      cv->x = ly->in;
      cv->y = f->out;
      cv->y.y0 = dy;
      cv->y.x0 = dx;
      cv->y.step = 2;
      cv->y.h = hin;
      cv->y.w = win;
      cv->w_off = ly->w_off[form] + (size_t)q * co * 4 * cin;
      cv->b_off = ly->b_off[form] + (size_t)q * co;
    }
    return HF_OK;
  }
  f->conv[0].w_off = ly->w_off[form];
  f->conv[0].b_off = ly->b_off[form];
  return HF_OK;
}

hf_cl_raw hf_cl_raw_output(const hf_cl_form *f) {
  hf_cl_raw r;
  memset(&r, 0, sizeof r);
  if (f->out_in_scratch) {
    r.buf = HF_CL_BUF_SCRATCH;
    r.pix_stride = f->scratch.pix_stride;
    r.rows = f->scratch.h;
    r.cols = f->scratch.w;
    r.div = 2;
    r.offset = 1;
    r.co = f->co;
  } else {
    r.buf = f->out.buf;
    r.pix_stride = f->out.pix_stride;
    r.rows = f->out.bh;
    r.cols = f->out.bw;
    r.div = 1;
    r.co = f->co;
  }
  return r;
}

static int map_in(const hf_cl_layer *ly, int j) {
  return j < ly->in_split ? j : ly->in_split_pad + (j - ly->in_split);
}

/* The 4*co x taps x taps x C filter of a D2S, PHASE or SHUFFLE decoder:
 * K index (2dy+dx)*co + o, each phase's taps from the 4x4 kernel. */
static void pack_phases(const hf_cl_layer *ly, int form, const float *src, uint16_t *f) {
  /* SHUFFLE's 3x3 tap t reads input row y-1+t; phase d uses kernel row
   * tap3[d][t] (-1: not at all). */
  static const int tap3[2][3] = {{3, 1, -1}, {-1, 2, 0}};
  const int T = form == HF_CL_FORM_SHUFFLE ? 3 : 2, C = ly->in.c, co = dec_co(ly, form);
  for (int dy = 0; dy < 2; dy++)
    for (int dx = 0; dx < 2; dx++)
      for (int ty = 0; ty < T; ty++)
        for (int tx = 0; tx < T; tx++) {
          const int r4 = T == 3 ? tap3[dy][ty] : hf_cl_tap2(dy, ty);
          const int s4 = T == 3 ? tap3[dx][tx] : hf_cl_tap2(dx, tx);
          if (r4 < 0 || s4 < 0) continue;
          for (int o = 0; o < ly->out_real; o++)
            for (int i = 0; i < ly->in_real; i++)
              f[(((size_t)((dy * 2 + dx) * co + o) * T + ty) * T + tx) * C + map_in(ly, i)] =
                  hf_f32_to_f16(src[(((size_t)i * ly->out_real + o) * 4 + r4) * 4 + s4]);
        }
}

int hf_cl_pack_weights(const hf_cl_layout *lo, const hf_weights *w, uint16_t *w16,
                       uint16_t *b16, float *b32) {
  if (!lo || !w || !w16 || !b16 || !b32) return HF_EINVAL;
  memset(w16, 0, lo->w_elems * sizeof *w16);   /* f16 +0 is all-zero bits */
  memset(b16, 0, lo->b_elems * sizeof *b16);
  memset(b32, 0, lo->b_elems * sizeof *b32);
  for (int j = 0; j < lo->nlayers; j++) {
    const hf_cl_layer *ly = &lo->layers[j];
    const int in_real = ly->in_real, out_real = ly->out_real;
    if (map_in(ly, in_real - 1) >= ly->in.c) return HF_EINVAL;
    const float *src = ly->dec ? w->dec_w[ly->level] : w->enc_w[ly->level];
    const float *bias = ly->dec ? w->dec_b[ly->level] : w->enc_b[ly->level];
    for (int form = 0; form < HF_CL_NFORMS; form++) {
      if (!ly->w_elems[form]) continue;
      uint16_t *f = w16 + ly->w_off[form];
      int copies = 1, co = ly->out.c;
      if (form == HF_CL_FORM_FWD) {
        /* Conv2d [out][in][3][3] -> [K=out][3][3][C=in]. */
        const int C = ly->in.c;
        for (int o = 0; o < out_real; o++)
          for (int i = 0; i < in_real; i++)
            for (int r = 0; r < 3; r++)
              for (int s = 0; s < 3; s++)
                f[(((size_t)o * 3 + r) * 3 + s) * C + map_in(ly, i)] =
                    hf_f32_to_f16(src[(((size_t)o * in_real + i) * 3 + r) * 3 + s]);
      } else if (form == HF_CL_FORM_BWD_DATA) {
        /* ConvTranspose2d [in][out][4][4] -> [K=in][4][4][C=out]. */
        co = dec_co(ly, form);
        for (int i = 0; i < in_real; i++)
          for (int o = 0; o < out_real; o++)
            for (int r = 0; r < 4; r++)
              for (int s = 0; s < 4; s++)
                f[(((size_t)map_in(ly, i) * 4 + r) * 4 + s) * co + o] =
                    hf_f32_to_f16(src[(((size_t)i * out_real + o) * 4 + r) * 4 + s]);
      } else {
        co = dec_co(ly, form);
        copies = 4;
        pack_phases(ly, form, src, f);
      }
      for (int q = 0; q < copies; q++)
        for (int o = 0; o < out_real; o++) {
          b16[ly->b_off[form] + (size_t)q * co + o] = hf_f32_to_f16(bias[o]);
          b32[ly->b_off[form] + (size_t)q * co + o] = bias[o];
        }
    }
  }
  return HF_OK;
}
