/* Network variants (the paper's Table 1) and the channel arithmetic every
 * backend shares. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

#include "hfcore.h"

const char *const HF_FEATURE_NAMES[HF_FEATURES_PER_SAMPLE] = {
  "color", "highlight", "alpha", "depth", "tangent.x", "tangent.y"
};
const char *const HF_OUTPUT_NAMES[HF_OUT_CHANNELS] = {"color", "highlight", "alpha"};

static const struct {
  const char *name;
  int spp;
  int num_levels;
  int levels[HF_MAX_LEVELS];
  int arch;
  int kernel_radius, kernel_hidden;
  int estimate;
  int kernel_mix;
} presets[] = {
  {"Base",      4, 3, {32, 64, 128}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  {"Base@1spp", 1, 3, {32, 64, 128}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  {"Base@2spp", 2, 3, {32, 64, 128}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  {"Large",     4, 3, {64, 128, 256}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  {"Small",     4, 3, {16, 32, 64}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  {"Shallow",   4, 2, {32, 64}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  {"Deep",      4, 4, {32, 64, 128, 256}, HF_ARCH_UNET, 0, 0, HF_ESTIMATE_NONE, 0},
  /* Beyond the paper: Base's cost, residual on the samples' own estimate. */
  {"Residual",  4, 3, {32, 64, 128}, HF_ARCH_RESIDUAL, 0, 0, HF_ESTIMATE_NONE, 0},
  /* Beyond the paper: Base's U-Net, the output read off the samples of the
   * 7x7 pixels around each pixel with a learned kernel; a 32-channel dec0
   * and the head over it and the input (weights/kernel.md: 16 channels
   * until 2026-12-02). */
  {"Kernel",    4, 3, {32, 64, 128}, HF_ARCH_KERNEL, 3, 32, HF_ESTIMATE_NONE, 0},
  /* Kernel reading stochastic transparency's alpha-corrected estimate too,
   * and filtering it instead of the samples' own (weights/kernel.md). */
  {"KernelAC",  4, 3, {32, 64, 128}, HF_ARCH_KERNEL, 3, 32, HF_ESTIMATE_ALPHA_CORRECTED, 0},
  /* KernelAC whose kernel weighs the samples' own sums too, mixed per pixel:
   * the estimate leaks hidden strands' colour where opaque strands a pixel
   * wide overlap, the samples do not (weights/kernel_mix.md). */
  {"KernelMix", 4, 3, {32, 64, 128}, HF_ARCH_KERNEL, 3, 32, HF_ESTIMATE_ALPHA_CORRECTED, 1},
};
#define NPRESETS ((int)(sizeof presets / sizeof presets[0]))

int hf_variant_preset_count(void) { return NPRESETS; }

const char *hf_variant_preset_name(int i) {
  return (i >= 0 && i < NPRESETS) ? presets[i].name : NULL;
}

int hf_variant_preset(const char *name, hf_net_config *out) {
  if (!name || !out) return HF_EINVAL;
  for (int i = 0; i < NPRESETS; i++) {
    if (strcasecmp(name, presets[i].name)) continue;
    memset(out, 0, sizeof *out);
    snprintf(out->name, sizeof out->name, "%s", presets[i].name);
    out->spp = presets[i].spp;
    out->estimate = presets[i].estimate;
    out->in_channels = hf_net_in_channels(presets[i].spp, presets[i].estimate);
    out->out_channels = HF_OUT_CHANNELS;
    out->num_levels = presets[i].num_levels;
    memcpy(out->levels, presets[i].levels, sizeof out->levels);
    out->arch = presets[i].arch;
    out->kernel_radius = presets[i].kernel_radius;
    out->kernel_hidden = presets[i].kernel_hidden;
    out->kernel_mix = presets[i].kernel_mix;
    if (out->arch == HF_ARCH_KERNEL)
      out->out_channels += hf_kernel_taps(out->kernel_radius) + out->kernel_mix;
    return HF_OK;
  }
  return HF_ENOTFOUND;
}

int hf_net_config_validate(const hf_net_config *cfg) {
  if (!cfg) return HF_EINVAL;
  if (cfg->spp < 1 || cfg->spp > HF_MAX_SPP) return HF_ERANGE;
  if (cfg->estimate != HF_ESTIMATE_NONE && cfg->estimate != HF_ESTIMATE_ALPHA_CORRECTED)
    return HF_EUNSUPPORTED;
  /* Only the Kernel output stage knows what to do with an estimate. */
  if (cfg->estimate && cfg->arch != HF_ARCH_KERNEL) return HF_EUNSUPPORTED;
  if (cfg->in_channels != hf_net_in_channels(cfg->spp, cfg->estimate)) return HF_EFORMAT;
  if (cfg->num_levels < 1 || cfg->num_levels > HF_MAX_LEVELS) return HF_ERANGE;
  for (int i = 0; i < cfg->num_levels; i++)
    if (cfg->levels[i] < 1 || cfg->levels[i] > HF_MAX_CHANNELS) return HF_ERANGE;
  if (memchr(cfg->name, 0, sizeof cfg->name) == NULL) return HF_EFORMAT;
  if (cfg->arch != HF_ARCH_UNET && cfg->arch != HF_ARCH_RESIDUAL && cfg->arch != HF_ARCH_KERNEL)
    return HF_EUNSUPPORTED;
  if (cfg->arch != HF_ARCH_KERNEL) {
    /* The kernel's fields describe nothing here: set, they are a mistake. */
    if (cfg->kernel_radius || cfg->kernel_hidden || cfg->kernel_mix) return HF_EFORMAT;
    return cfg->out_channels == HF_OUT_CHANNELS ? HF_OK : HF_EFORMAT;
  }
  if (cfg->kernel_radius < 1 || cfg->kernel_radius > HF_KERNEL_MAX_RADIUS) return HF_ERANGE;
  if (cfg->kernel_hidden < 0 || cfg->kernel_hidden > HF_KERNEL_MAX_HIDDEN) return HF_ERANGE;
  /* Mixing needs the estimate: without it there is one kind of sums. */
  if (cfg->kernel_mix < 0 || cfg->kernel_mix > 1 || (cfg->kernel_mix && !cfg->estimate))
    return HF_EFORMAT;
  if (cfg->out_channels != hf_kernel_taps(cfg->kernel_radius) + HF_OUT_CHANNELS + cfg->kernel_mix)
    return HF_EFORMAT;
  return HF_OK;
}

int hf_net_in_channels(int spp, int estimate) {
  return spp * HF_FEATURES_PER_SAMPLE + (estimate ? HF_ESTIMATE_CHANNELS : 0);
}

int hf_kernel_sums_of(const hf_net_config *cfg) {
  return cfg->kernel_mix ? HF_KSUMS_MIXED : cfg->estimate;
}

int hf_kernel_sums_floats(int ksums) { return ksums == HF_KSUMS_MIXED ? 6 : 3; }

const char *hf_estimate_name(int estimate) {
  return estimate == HF_ESTIMATE_NONE              ? "none"
         : estimate == HF_ESTIMATE_ALPHA_CORRECTED ? "alpha_corrected"
                                                   : "unknown";
}

int hf_estimate_from_name(const char *name) {
  if (name && !strcmp(name, "none")) return HF_ESTIMATE_NONE;
  if (name && !strcmp(name, "alpha_corrected")) return HF_ESTIMATE_ALPHA_CORRECTED;
  return HF_ENOTFOUND;
}

int hf_net_align(const hf_net_config *cfg) { return 1 << cfg->num_levels; }

int hf_enc_in(const hf_net_config *cfg, int i) {
  return i == 0 ? cfg->in_channels : cfg->levels[i - 1];
}

int hf_enc_out(const hf_net_config *cfg, int i) { return cfg->levels[i]; }

/* The deepest decoder reads the bottleneck alone; the others read their
 * upper neighbour's output concatenated with the encoder skip. */
int hf_dec_in(const hf_net_config *cfg, int i) {
  return i == cfg->num_levels - 1 ? cfg->levels[i] : 2 * cfg->levels[i];
}

int hf_dec_out(const hf_net_config *cfg, int i) {
  if (i > 0) return cfg->levels[i - 1];
  return hf_head_in(cfg) ? cfg->kernel_hidden : cfg->out_channels;
}

int hf_kernel_taps(int radius) { return (2 * radius + 1) * (2 * radius + 1); }

int hf_head_in(const hf_net_config *cfg) {
  return cfg->arch == HF_ARCH_KERNEL && cfg->kernel_hidden > 0
             ? cfg->kernel_hidden + cfg->in_channels : 0;
}

double hf_net_macs(const hf_net_config *cfg, int w, int h) {
  double macs = 0;
  for (int i = 0; i < cfg->num_levels; i++) {
    double lo = (double)(w >> (i + 1)) * (h >> (i + 1)); /* low-res pixels */
    /* conv: each output pixel (low res) reads 3x3xin */
    macs += lo * 9.0 * hf_enc_in(cfg, i) * hf_enc_out(cfg, i);
    /* transposed conv 4x4 stride 2: each input pixel (low res) scatters
     * 4x4xout, i.e. 4 taps per output pixel at high res */
    macs += lo * 16.0 * hf_dec_in(cfg, i) * hf_dec_out(cfg, i);
  }
  double px = (double)w * h;
  macs += px * hf_head_in(cfg) * (hf_head_in(cfg) ? cfg->out_channels : 0);
  /* the output stage: per tap the weight, then 3 weighted sums (6 mixing) */
  if (cfg->arch == HF_ARCH_KERNEL)
    macs += px * (cfg->kernel_mix ? 7.0 : 4.0) * hf_kernel_taps(cfg->kernel_radius);
  return macs;
}

const char *hf_arch_name(int arch) {
  return arch == HF_ARCH_UNET       ? "unet"
         : arch == HF_ARCH_RESIDUAL ? "residual"
         : arch == HF_ARCH_KERNEL   ? "kernel"
                                    : "unknown";
}

int hf_arch_from_name(const char *name) {
  if (name && !strcmp(name, "unet")) return HF_ARCH_UNET;
  if (name && !strcmp(name, "residual")) return HF_ARCH_RESIDUAL;
  if (name && !strcmp(name, "kernel")) return HF_ARCH_KERNEL;
  return HF_ENOTFOUND;
}

/* A sample is covered when its fragment was kept: uncovered samples carry
 * all-zero features, and a kept fragment always has alpha > 0. With
 * coverage drawn with probability alpha, the covered fraction estimates the
 * blended alpha and the covered samples' mean estimates the blended colour
 * (Enderton et al. 2011). A pixel with no covered sample gets colour 1, the
 * neutral value of the paper's colour transform. */
void hf_pixel_sums(const float *px, int spp, float sums[3]) {
  float n = 0, col = 0, hl = 0;
  for (int k = 0; k < spp; k++) {
    const float *s = px + k * HF_FEATURES_PER_SAMPLE;
    if (s[2] > 0.0f) {
      n += 1.0f;
      col += s[0];
      hl += s[1];
    }
  }
  sums[0] = n, sums[1] = col, sums[2] = hl;
}

/* The estimate as spp samples that all show it (weights/hfnet.py
 * estimate_sums is its twin: the products in the same order). */
void hf_estimate_sums(const float *px, int spp, float sums[3]) {
  const float *e = px + spp * HF_FEATURES_PER_SAMPLE;
  const float n = (float)spp * e[2];
  sums[0] = n, sums[1] = n * e[0], sums[2] = n * e[1];
}

void hf_st_estimate(const float *px, int spp, float est[3]) {
  float s[3];
  hf_pixel_sums(px, spp, s);
  const float n = s[0];
  est[HF_OUT_COLOR] = n > 0 ? s[1] / n : 1.0f;
  est[HF_OUT_HIGHLIGHT] = n > 0 ? s[2] / n : 0.0f;
  est[HF_OUT_ALPHA] = n / (float)spp;
}

void hf_residual_base(const hf_input_view *in, int spp, int x, int y, float base[3]) {
  const int r = HF_RESIDUAL_RADIUS;
  int y0 = y - r < 0 ? 0 : y - r, y1 = y + r >= in->height ? in->height - 1 : y + r;
  int x0 = x - r < 0 ? 0 : x - r, x1 = x + r >= in->width ? in->width - 1 : x + r;
  float n = 0, col = 0, hl = 0;
  for (int yy = y0; yy <= y1; yy++)
    for (int xx = x0; xx <= x1; xx++) {
      const float *s = in->data + ((size_t)yy * in->pitch + xx) * in->stride;
      for (int k = 0; k < spp; k++, s += HF_FEATURES_PER_SAMPLE)
        if (s[2] > 0.0f) {
          n += 1.0f;
          col += s[0];
          hl += s[1];
        }
    }
  int samples = (y1 - y0 + 1) * (x1 - x0 + 1) * spp;
  base[HF_OUT_COLOR] = n > 0 ? col / n : 1.0f;
  base[HF_OUT_HIGHLIGHT] = n > 0 ? hl / n : 0.0f;
  base[HF_OUT_ALPHA] = n / (float)samples;
}

void hf_pixel_sums_rows(const hf_input_view *in, int spp, int ksums, int y0, int y1,
                        float *sums) {
  const int k = hf_kernel_sums_floats(ksums);
  for (int y = y0; y < y1; y++)
    for (int x = 0; x < in->width; x++) {
      const float *px = in->data + ((size_t)y * in->pitch + x) * in->stride;
      float *s = sums + ((size_t)y * in->width + x) * k;
      if (ksums == HF_KSUMS_ESTIMATE) {
        hf_estimate_sums(px, spp, s);
      } else {
        hf_pixel_sums(px, spp, s);
        if (ksums == HF_KSUMS_MIXED) hf_estimate_sums(px, spp, s + 3);
      }
    }
}

int hf_pooled_estimate_frame(const hf_input_view *in, int spp, int radius, float *base,
                             float *tmp) {
  if (in->width < 1 || in->height < 1 || spp < 1 || radius < 0) return HF_EINVAL;
  /* Per-pixel sums (covered count, colour, highlight) into base... */
  hf_pixel_sums_rows(in, spp, HF_ESTIMATE_NONE, 0, in->height, base);
  return hf_pooled_estimate_sums(in->width, in->height, spp, radius, base, tmp);
}

int hf_pooled_estimate_sums(int width, int height, int spp, int radius, float *base,
                            float *tmp) {
  const int w = width, h = height, r = radius;
  if (w < 1 || h < 1 || spp < 1 || r < 0) return HF_EINVAL;
  /* The per-pixel sums summed along rows into tmp, then along columns back
   * into base: the window sums with 2 (2r+1) additions per pixel instead of
   * (2r+1)^2. */
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int x0 = x - r < 0 ? 0 : x - r, x1 = x + r >= w ? w - 1 : x + r;
      float acc[3] = {0, 0, 0};
      for (int xx = x0; xx <= x1; xx++)
        for (int c = 0; c < 3; c++) acc[c] += base[((size_t)y * w + xx) * 3 + c];
      memcpy(tmp + ((size_t)y * w + x) * 3, acc, sizeof acc);
    }
  for (int y = 0; y < h; y++) {
    int y0 = y - r < 0 ? 0 : y - r, y1 = y + r >= h ? h - 1 : y + r;
    for (int x = 0; x < w; x++) {
      int x0 = x - r < 0 ? 0 : x - r, x1 = x + r >= w ? w - 1 : x + r;
      float acc[3] = {0, 0, 0};
      for (int yy = y0; yy <= y1; yy++)
        for (int c = 0; c < 3; c++) acc[c] += tmp[((size_t)yy * w + x) * 3 + c];
      float samples = (float)((y1 - y0 + 1) * (x1 - x0 + 1) * spp);
      float *o = base + ((size_t)y * w + x) * 3;
      o[HF_OUT_COLOR] = acc[0] > 0 ? acc[1] / acc[0] : 1.0f;
      o[HF_OUT_HIGHLIGHT] = acc[0] > 0 ? acc[2] / acc[0] : 0.0f;
      o[HF_OUT_ALPHA] = acc[0] / samples;
    }
  }
  return HF_OK;
}

int hf_residual_base_frame(const hf_input_view *in, int spp, float *base, float *tmp) {
  return hf_pooled_estimate_frame(in, spp, HF_RESIDUAL_RADIUS, base, tmp);
}

void hf_residual_apply(const float base[3], float *v) {
  const float *b = base;
  v[HF_OUT_COLOR] += b[HF_OUT_COLOR];
  float h = v[HF_OUT_HIGHLIGHT] + b[HF_OUT_HIGHLIGHT];
  v[HF_OUT_HIGHLIGHT] = h > 0.0f ? h : 0.0f;
  float a = v[HF_OUT_ALPHA] + b[HF_OUT_ALPHA];
  v[HF_OUT_ALPHA] = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}

/* The Kernel architecture's output of one pixel. raw: its taps + 3 raw
 * channels (+ 1, m, when mix); sums: the per-pixel sums of the pixel itself,
 * pitch floats per row, 3 per pixel (6 when mix: the samples', then the
 * estimate's); the taps inside the frame are dy in dy0..dy1, dx in dx0..dx1
 * (-r..r cut to the frame). Follows weights/hfnet.py kernel_weights,
 * kernel_aggregate and kernel_normalise step by step: the softmax's weights
 * e_t / den, then the weighted sums in tap order, then (mix) the estimate's
 * plus beta times the samples' less the estimate's. */
static void kernel_pixel(const float *raw, int spp, int r, int mix, const float *sums,
                         ptrdiff_t pitch, int dy0, int dy1, int dx0, int dx1, float out[3]) {
  const int side = 2 * r + 1, taps = side * side;
  /* The maximum over the taps inside the frame keeps every exponent <= 0
   * and the largest 1, so den >= 1: no overflow, no division by 0. */
  float m = -INFINITY;
  for (int dy = dy0; dy <= dy1; dy++)
    for (int dx = dx0; dx <= dx1; dx++) m = fmaxf(m, raw[(dy + r) * side + dx + r]);
  float e[HF_MAX_RAW_CHANNELS], den = 0;
  for (int dy = dy0; dy <= dy1; dy++)
    for (int dx = dx0; dx <= dx1; dx++) {
      int t = (dy + r) * side + dx + r;
      e[t] = expf(raw[t] - m);
      den += e[t];
    }
  const int k = mix ? 6 : 3;
  float n = 0, col = 0, hl = 0, en = 0, ecol = 0, ehl = 0;
  for (int dy = dy0; dy <= dy1; dy++)
    for (int dx = dx0; dx <= dx1; dx++) {
      float wt = e[(dy + r) * side + dx + r] / den;
      const float *q = sums + dy * pitch + dx * k;
      n += wt * q[0];
      col += wt * q[1];
      hl += wt * q[2];
      if (mix) {
        en += wt * q[3];
        ecol += wt * q[4];
        ehl += wt * q[5];
      }
    }
  if (mix) {
    const float beta = 1.0f / (1.0f + expf(-HF_KERNEL_MIX_GAIN * raw[taps + 3]));
    n = en + beta * (n - en);
    col = ecol + beta * (col - ecol);
    hl = ehl + beta * (hl - ehl);
  }
  const float *c = raw + taps;
  int ok = n > 1e-12f;
  float h = (ok ? hl / n : 0.0f) + c[1], a = n / (float)spp + c[2];
  out[HF_OUT_COLOR] = (ok ? col / n : 1.0f) + c[0];
  out[HF_OUT_HIGHLIGHT] = h > 0.0f ? h : 0.0f;
  out[HF_OUT_ALPHA] = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}

void hf_kernel_output_rows(int width, int height, int spp, int radius, int ksums,
                           const float *sums, const float *raw, int raw_pitch, int raw_stride,
                           int y0, int y1, float *out) {
  const int r = radius, k = hf_kernel_sums_floats(ksums), mix = ksums == HF_KSUMS_MIXED;
  const ptrdiff_t pitch = (ptrdiff_t)width * k;
  for (int y = y0; y < y1; y++) {
    int dy0 = y - r < 0 ? -y : -r, dy1 = y + r >= height ? height - 1 - y : r;
    for (int x = 0; x < width; x++) {
      int dx0 = x - r < 0 ? -x : -r, dx1 = x + r >= width ? width - 1 - x : r;
      kernel_pixel(raw + ((size_t)y * raw_pitch + x) * raw_stride, spp, r, mix,
                   sums + (size_t)y * pitch + (size_t)x * k, pitch, dy0, dy1, dx0, dx1,
                   out + ((size_t)y * width + x) * 3);
    }
  }
}

int hf_kernel_output_frame(const hf_input_view *in, int spp, int ksums, int radius,
                           const float *raw, int raw_pitch, int raw_stride, float *out,
                           float *sums) {
  if (in->width < 1 || in->height < 1 || spp < 1 || radius < 0 ||
      radius > HF_KERNEL_MAX_RADIUS ||
      (ksums != HF_KSUMS_SAMPLES && ksums != HF_KSUMS_ESTIMATE && ksums != HF_KSUMS_MIXED))
    return HF_EINVAL;
  hf_pixel_sums_rows(in, spp, ksums, 0, in->height, sums);
  hf_kernel_output_rows(in->width, in->height, spp, radius, ksums, sums, raw, raw_pitch,
                        raw_stride, 0, in->height, out);
  return HF_OK;
}

void hf_output_finish(const hf_net_config *cfg, const hf_input_view *in, int x, int y, float *v) {
  if (cfg->arch == HF_ARCH_KERNEL) {
    /* The sums of the (2r+1)^2 pixels around (x, y) alone, in a window of
     * the same geometry as a frame's. */
    const int r = cfg->kernel_radius, side = 2 * r + 1, ksums = hf_kernel_sums_of(cfg);
    const int k = hf_kernel_sums_floats(ksums);
    float sums[(2 * HF_KERNEL_MAX_RADIUS + 1) * (2 * HF_KERNEL_MAX_RADIUS + 1) * 6];
    int dy0 = y - r < 0 ? -y : -r, dy1 = y + r >= in->height ? in->height - 1 - y : r;
    int dx0 = x - r < 0 ? -x : -r, dx1 = x + r >= in->width ? in->width - 1 - x : r;
    for (int dy = dy0; dy <= dy1; dy++) {
      hf_input_view row = {in->data + ((size_t)(y + dy) * in->pitch + x + dx0) * in->stride,
                           dx1 - dx0 + 1, 1, in->pitch, in->stride};
      hf_pixel_sums_rows(&row, cfg->spp, ksums, 0, 1, sums + ((dy + r) * side + dx0 + r) * k);
    }
    float o[3];
    kernel_pixel(v, cfg->spp, r, ksums == HF_KSUMS_MIXED, sums + (r * side + r) * k, side * k,
                 dy0, dy1, dx0, dx1, o);
    memcpy(v, o, sizeof o);
    return;
  }
  if (cfg->arch != HF_ARCH_RESIDUAL) {
    hf_output_transform(v);
    return;
  }
  float b[3];
  hf_residual_base(in, cfg->spp, x, y, b);
  hf_residual_apply(b, v);
}
