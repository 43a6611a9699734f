/* cpu-ref: the network in plain C loops, written to be obviously correct
 * rather than fast. It is the oracle every other backend is tested against,
 * so it follows the wiring in hfcore.h line by line and shares nothing with
 * the optimised backends except the padding helpers. */
#include <stdlib.h>
#include <string.h>

#include "backend.h"

typedef struct ref_model {
  hf_weights *w; /* a private copy */
} ref_model;

static int ref_probe(char *why, size_t whylen) { return HF_OK; }

static int ref_model_create(void *dev, const hf_weights *w, void **out) {
  ref_model *m = calloc(1, sizeof *m);
  if (!m) return HF_ENOMEM;
  int rc = hf_weights_alloc(&w->cfg, &m->w);
  if (rc) {
    free(m);
    return rc;
  }
  memcpy(m->w->storage, w->storage, w->num_params * sizeof(float));
  /* hf_weights_alloc laid the arrays out in the same order as w's, so the
   * copy's pointers already address the copied values. */
  *out = m;
  return HF_OK;
}

static void ref_model_destroy(void *p) {
  ref_model *m = p;
  if (!m) return;
  hf_weights_free(m->w);
  free(m);
}

/* 3x3 convolution, stride 2, padding 1: in [h][w][cin] -> out [h/2][w/2][cout]. */
static void conv3x3_s2(const float *in, int h, int w, int cin, const float *wt,
                       const float *bias, int cout, int relu, float *out) {
  int oh = h / 2, ow = w / 2;
  for (int y = 0; y < oh; y++)
    for (int x = 0; x < ow; x++)
      for (int o = 0; o < cout; o++) {
        float acc = bias[o];
        for (int ky = 0; ky < 3; ky++) {
          int iy = 2 * y + ky - 1;
          if (iy < 0 || iy >= h) continue;
          for (int kx = 0; kx < 3; kx++) {
            int ix = 2 * x + kx - 1;
            if (ix < 0 || ix >= w) continue;
            const float *px = in + ((size_t)iy * w + ix) * cin;
            for (int i = 0; i < cin; i++)
              acc += px[i] * wt[(((size_t)o * cin + i) * 3 + ky) * 3 + kx];
          }
        }
        out[((size_t)y * ow + x) * cout + o] = relu && acc < 0 ? 0 : acc;
      }
}

/* 4x4 transposed convolution, stride 2, padding 1: in [h][w][cin] ->
 * out [2h][2w][cout]. Output pixel (Y, X) receives input pixel (y, x)
 * through tap (ky, kx) when Y = 2y - 1 + ky and X = 2x - 1 + kx. */
static void deconv4x4_s2(const float *in, int h, int w, int cin, const float *wt,
                         const float *bias, int cout, int relu, float *out) {
  int oh = 2 * h, ow = 2 * w;
  for (int Y = 0; Y < oh; Y++)
    for (int X = 0; X < ow; X++)
      for (int o = 0; o < cout; o++) {
        float acc = bias[o];
        for (int ky = 0; ky < 4; ky++) {
          int ty = Y + 1 - ky;
          if (ty < 0 || ty % 2 || ty / 2 >= h) continue;
          for (int kx = 0; kx < 4; kx++) {
            int tx = X + 1 - kx;
            if (tx < 0 || tx % 2 || tx / 2 >= w) continue;
            const float *px = in + ((size_t)(ty / 2) * w + tx / 2) * cin;
            for (int i = 0; i < cin; i++)
              acc += px[i] * wt[(((size_t)i * cout + o) * 4 + ky) * 4 + kx];
          }
        }
        out[((size_t)Y * ow + X) * cout + o] = relu && acc < 0 ? 0 : acc;
      }
}

/* 1x1 convolution: in [n][cin] -> out [n][cout], weights [cout][cin]. */
static void conv1x1(const float *in, size_t n, int cin, const float *wt, const float *bias,
                    int cout, float *out) {
  for (size_t p = 0; p < n; p++)
    for (int o = 0; o < cout; o++) {
      float acc = bias[o];
      for (int i = 0; i < cin; i++) acc += in[p * cin + i] * wt[(size_t)o * cin + i];
      out[p * cout + o] = acc;
    }
}

/* Concatenates a [n][ca] and b [n][cb] along channels into out [n][ca+cb]. */
static void concat(const float *a, int ca, const float *b, int cb, size_t n, float *out) {
  for (size_t p = 0; p < n; p++) {
    memcpy(out + p * (ca + cb), a + p * ca, ca * sizeof(float));
    memcpy(out + p * (ca + cb) + ca, b + p * cb, cb * sizeof(float));
  }
}

static int forward(const hf_weights *w, const float *input, int pw, int ph, float *result) {
  const hf_net_config *c = &w->cfg;
  int L = c->num_levels, rc = HF_ENOMEM;
  float *enc[HF_MAX_LEVELS] = {0};
  float *cur = NULL, *cat = NULL;
  /* With a head, dec0 writes its hidden channels (ReLU) and the head, a 1x1
   * convolution over them and the input, writes the result. */
  const int head = hf_head_in(c);
  for (int i = 0; i < L; i++) {
    size_t n = (size_t)(pw >> (i + 1)) * (ph >> (i + 1)) * hf_enc_out(c, i);
    if (!(enc[i] = malloc(n * sizeof(float) + 1))) goto out;
    conv3x3_s2(i ? enc[i - 1] : input, ph >> i, pw >> i, hf_enc_in(c, i), w->enc_w[i],
               w->enc_b[i], hf_enc_out(c, i), 1, enc[i]);
  }
  for (int i = L - 1; i >= 0; i--) {
    int h = ph >> (i + 1), wd = pw >> (i + 1);
    const float *din = enc[L - 1];
    if (i < L - 1) {
      free(cat);
      if (!(cat = malloc((size_t)h * wd * hf_dec_in(c, i) * sizeof(float)))) goto out;
      concat(cur, c->levels[i], enc[i], c->levels[i], (size_t)h * wd, cat);
      din = cat;
    }
    float *o = i || head ? malloc((size_t)(2 * h) * (2 * wd) * hf_dec_out(c, i) * sizeof(float))
                         : result;
    if (!o) goto out;
    deconv4x4_s2(din, h, wd, hf_dec_in(c, i), w->dec_w[i], w->dec_b[i], hf_dec_out(c, i),
                 i != 0 || head, o);
    free(cur);
    cur = o != result ? o : NULL;
  }
  if (head) {
    size_t npx = (size_t)pw * ph;
    free(cat);
    if (!(cat = malloc(npx * head * sizeof(float)))) goto out;
    concat(cur, c->kernel_hidden, input, c->in_channels, npx, cat);
    conv1x1(cat, npx, head, w->head_w, w->head_b, c->out_channels, result);
  }
  rc = HF_OK;
out:
  for (int i = 0; i < L; i++) free(enc[i]);
  free(cat);
  free(cur);
  return rc;
}

static int ref_model_run(void *p, const hf_io *io, hf_timing *t) {
  ref_model *m = p;
  const hf_net_config *c = &m->w->cfg;
  int a = hf_net_align(c);
  int pw = hf_round_up(io->width, a), ph = hf_round_up(io->height, a);
  size_t in_frame = (size_t)pw * ph * c->in_channels;
  size_t out_frame = (size_t)pw * ph * c->out_channels;
  double t0 = hf_now_us();
  float *in = malloc(in_frame * io->batch * sizeof(float));
  float *out = malloc(out_frame * io->batch * sizeof(float));
  int rc = HF_ENOMEM;
  if (!in || !out) goto out;
  hf_input_to_padded_f32(io, c->in_channels, pw, ph, in);
  double t1 = hf_now_us();
  for (int n = 0; n < io->batch; n++)
    if ((rc = forward(m->w, in + n * in_frame, pw, ph, out + n * out_frame)) != 0) goto out;
  double t2 = hf_now_us();
  hf_output_from_padded_f32(c, in, out, pw, ph, io);
  t->input_us = t1 - t0;
  t->infer_us = t2 - t1;
  t->output_us = hf_now_us() - t2;
  rc = HF_OK;
out:
  free(in);
  free(out);
  return rc;
}

/* What ref_model_run allocates, from the same sizes: the padded input and
 * output of the batch, every encoder output, every decoder's concat input
 * and output, the head's concatenation, and the output stage's buffers. That is the sum of every
 * allocation of a run, not the most alive at once: the heap may not reuse
 * a freed block for a larger one, so resident memory can exceed the live
 * peak, never the sum (the frames of a batch run one after another in the
 * same blocks). Each block costs at most a page more, and 64 KiB cover the
 * allocator's own bookkeeping. Nothing is kept between runs. */
static size_t ref_run_bytes(const hf_net_config *c, int batch, int pw, int ph) {
  const size_t f = sizeof(float), page = 4096;
  const size_t px = (size_t)pw * ph;
  size_t total = (px * c->in_channels + px * c->out_channels) * f * batch + 2 * page;
  for (int i = 0; i < c->num_levels; i++) {
    size_t hw = (size_t)(pw >> (i + 1)) * (ph >> (i + 1));
    total += hw * hf_enc_out(c, i) * f + 1 + page;
    if (i < c->num_levels - 1) total += hw * hf_dec_in(c, i) * f + page;
    if (i > 0 || hf_head_in(c)) total += 4 * hw * hf_dec_out(c, i) * f + page;
  }
  if (hf_head_in(c)) total += px * hf_head_in(c) * f + page; /* the head's concatenation */
  return total + hf_output_extra_bytes(c, pw, ph) + 2 * page + ((size_t)64 << 10);
}

const hf_backend_ops hf_backend_cpu_ref = {
  .name = "cpu-ref",
  .priority = 10,
  .archs = 1u << HF_ARCH_UNET | 1u << HF_ARCH_RESIDUAL | 1u << HF_ARCH_KERNEL,
  .probe = ref_probe,
  .model_create = ref_model_create,
  .model_destroy = ref_model_destroy,
  .model_run = ref_model_run,
  .run_bytes = ref_run_bytes,
};
