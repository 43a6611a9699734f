/* Network variants (the paper's Table 1) and the channel arithmetic every
 * backend shares. */
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
} presets[] = {
  {"Base",      4, 3, {32, 64, 128}, HF_ARCH_UNET},
  {"Base@1spp", 1, 3, {32, 64, 128}, HF_ARCH_UNET},
  {"Base@2spp", 2, 3, {32, 64, 128}, HF_ARCH_UNET},
  {"Large",     4, 3, {64, 128, 256}, HF_ARCH_UNET},
  {"Small",     4, 3, {16, 32, 64}, HF_ARCH_UNET},
  {"Shallow",   4, 2, {32, 64}, HF_ARCH_UNET},
  {"Deep",      4, 4, {32, 64, 128, 256}, HF_ARCH_UNET},
  /* Beyond the paper: Base's cost, residual on the samples' own estimate. */
  {"Residual",  4, 3, {32, 64, 128}, HF_ARCH_RESIDUAL},
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
    out->in_channels = presets[i].spp * HF_FEATURES_PER_SAMPLE;
    out->out_channels = HF_OUT_CHANNELS;
    out->num_levels = presets[i].num_levels;
    memcpy(out->levels, presets[i].levels, sizeof out->levels);
    out->arch = presets[i].arch;
    return HF_OK;
  }
  return HF_ENOTFOUND;
}

int hf_net_config_validate(const hf_net_config *cfg) {
  if (!cfg) return HF_EINVAL;
  if (cfg->spp < 1 || cfg->spp > HF_MAX_SPP) return HF_ERANGE;
  if (cfg->in_channels != cfg->spp * HF_FEATURES_PER_SAMPLE) return HF_EFORMAT;
  if (cfg->out_channels != HF_OUT_CHANNELS) return HF_EFORMAT;
  if (cfg->num_levels < 1 || cfg->num_levels > HF_MAX_LEVELS) return HF_ERANGE;
  for (int i = 0; i < cfg->num_levels; i++)
    if (cfg->levels[i] < 1 || cfg->levels[i] > HF_MAX_CHANNELS) return HF_ERANGE;
  if (memchr(cfg->name, 0, sizeof cfg->name) == NULL) return HF_EFORMAT;
  if (cfg->arch != HF_ARCH_UNET && cfg->arch != HF_ARCH_RESIDUAL) return HF_EUNSUPPORTED;
  return HF_OK;
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
  return i == 0 ? cfg->out_channels : cfg->levels[i - 1];
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
  return macs;
}

void hf_output_transform(float *v) {
  float c = v[HF_OUT_COLOR];
  v[HF_OUT_COLOR] = c * c * c / 32.0f + c / 5.0f + 1.0f;
  v[HF_OUT_HIGHLIGHT] = v[HF_OUT_HIGHLIGHT] > 0.0f ? v[HF_OUT_HIGHLIGHT] : 0.0f;
  float a = v[HF_OUT_ALPHA];
  v[HF_OUT_ALPHA] = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}

const char *hf_arch_name(int arch) {
  return arch == HF_ARCH_UNET ? "unet" : arch == HF_ARCH_RESIDUAL ? "residual" : "unknown";
}

int hf_arch_from_name(const char *name) {
  if (name && !strcmp(name, "unet")) return HF_ARCH_UNET;
  if (name && !strcmp(name, "residual")) return HF_ARCH_RESIDUAL;
  return HF_ENOTFOUND;
}

/* A sample is covered when its fragment was kept: uncovered samples carry
 * all-zero features, and a kept fragment always has alpha > 0. With
 * coverage drawn with probability alpha, the covered fraction estimates the
 * blended alpha and the covered samples' mean estimates the blended colour
 * (Enderton et al. 2011). A pixel with no covered sample gets colour 1, the
 * neutral value of the paper's colour transform. */
void hf_st_estimate(const float *px, int spp, float est[3]) {
  float n = 0, col = 0, hl = 0;
  for (int k = 0; k < spp; k++) {
    const float *s = px + k * HF_FEATURES_PER_SAMPLE;
    if (s[2] > 0.0f) {
      n += 1.0f;
      col += s[0];
      hl += s[1];
    }
  }
  est[HF_OUT_COLOR] = n > 0 ? col / n : 1.0f;
  est[HF_OUT_HIGHLIGHT] = n > 0 ? hl / n : 0.0f;
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

int hf_pooled_estimate_frame(const hf_input_view *in, int spp, int radius, float *base,
                             float *tmp) {
  const int w = in->width, h = in->height, r = radius;
  if (w < 1 || h < 1 || spp < 1 || r < 0) return HF_EINVAL;
  /* Per-pixel sums (covered count, colour, highlight) into base... */
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      const float *s = in->data + ((size_t)y * in->pitch + x) * in->stride;
      float n = 0, col = 0, hl = 0;
      for (int k = 0; k < spp; k++, s += HF_FEATURES_PER_SAMPLE)
        if (s[2] > 0.0f) {
          n += 1.0f;
          col += s[0];
          hl += s[1];
        }
      float *o = base + ((size_t)y * w + x) * 3;
      o[0] = n, o[1] = col, o[2] = hl;
    }
  /* ...summed along rows into tmp, then along columns back into base: the
   * window sums with 2 (2r+1) additions per pixel instead of (2r+1)^2. */
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

void hf_output_finish(const hf_net_config *cfg, const hf_input_view *in, int x, int y, float *v) {
  if (cfg->arch != HF_ARCH_RESIDUAL) {
    hf_output_transform(v);
    return;
  }
  float b[3];
  hf_residual_base(in, cfg->spp, x, y, b);
  hf_residual_apply(b, v);
}
