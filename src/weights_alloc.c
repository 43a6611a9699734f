/* Allocation and random initialisation of network weights. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "weights.h"

int hf_weights_specs(hf_weights *w, hf_tensor_spec *s) {
  const hf_net_config *c = &w->cfg;
  int n = 0;
  for (int i = 0; i < c->num_levels; i++) {
    int ei = hf_enc_in(c, i), eo = hf_enc_out(c, i);
    int di = hf_dec_in(c, i), dout = hf_dec_out(c, i);
    s[n] = (hf_tensor_spec){.ndim = 4, .shape = {eo, ei, 3, 3}, .slot = &w->enc_w[i]};
    snprintf(s[n++].name, sizeof s[0].name, "enc%d.weight", i);
    s[n] = (hf_tensor_spec){.ndim = 1, .shape = {eo}, .slot = &w->enc_b[i]};
    snprintf(s[n++].name, sizeof s[0].name, "enc%d.bias", i);
    /* ConvTranspose2d stores [in][out][kh][kw] */
    s[n] = (hf_tensor_spec){.ndim = 4, .shape = {di, dout, 4, 4}, .slot = &w->dec_w[i]};
    snprintf(s[n++].name, sizeof s[0].name, "dec%d.weight", i);
    s[n] = (hf_tensor_spec){.ndim = 1, .shape = {dout}, .slot = &w->dec_b[i]};
    snprintf(s[n++].name, sizeof s[0].name, "dec%d.bias", i);
  }
  if (hf_head_in(c)) {
    s[n] = (hf_tensor_spec){.ndim = 4, .shape = {c->out_channels, hf_head_in(c), 1, 1},
                            .slot = &w->head_w};
    snprintf(s[n++].name, sizeof s[0].name, "head.weight");
    s[n] = (hf_tensor_spec){.ndim = 1, .shape = {c->out_channels}, .slot = &w->head_b};
    snprintf(s[n++].name, sizeof s[0].name, "head.bias");
  }
  for (int k = 0; k < n; k++) {
    s[k].numel = 1;
    for (int d = 0; d < s[k].ndim; d++) s[k].numel *= (size_t)s[k].shape[d];
  }
  return n;
}

int hf_weights_alloc(const hf_net_config *cfg, hf_weights **out) {
  if (!out) return HF_EINVAL;
  *out = NULL;
  int rc = hf_net_config_validate(cfg);
  if (rc) return rc;
  hf_weights *w = calloc(1, sizeof *w);
  if (!w) return HF_ENOMEM;
  w->cfg = *cfg;
  for (int k = 0; k < HF_FEATURES_PER_SAMPLE; k++)
    snprintf(w->features[k], sizeof w->features[k], "%s", HF_FEATURE_NAMES[k]);
  hf_tensor_spec specs[HF_TENSORS_MAX];
  int n = hf_weights_specs(w, specs);
  size_t total = 0;
  for (int k = 0; k < n; k++) total += specs[k].numel;
  float *storage = calloc(total, sizeof(float));
  if (!storage) {
    free(w);
    return HF_ENOMEM;
  }
  size_t off = 0;
  for (int k = 0; k < n; k++) {
    *specs[k].slot = storage + off;
    off += specs[k].numel;
  }
  w->storage = storage;
  w->num_params = total;
  *out = w;
  return HF_OK;
}

void hf_weights_free(hf_weights *w) {
  if (!w) return;
  free(w->storage);
  free(w);
}

/* splitmix64: tiny, seedable, good enough for test weights. */
static uint64_t next_u64(uint64_t *s) {
  uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

static float uniform(uint64_t *s, float bound) {
  double u = (double)(next_u64(s) >> 11) / 9007199254740992.0; /* [0,1) */
  return (float)((2.0 * u - 1.0) * bound);
}

/* Uniform(-1/sqrt(fan_in), 1/sqrt(fan_in)) like PyTorch's default for both
 * weights and biases, so activations stay in a sane range. */
int hf_weights_init_random(const hf_net_config *cfg, uint64_t seed, hf_weights **out) {
  int rc = hf_weights_alloc(cfg, out);
  if (rc) return rc;
  hf_weights *w = *out;
  uint64_t s = seed;
  for (int i = 0; i < cfg->num_levels; i++) {
    int ei = hf_enc_in(cfg, i), eo = hf_enc_out(cfg, i);
    int di = hf_dec_in(cfg, i), dout = hf_dec_out(cfg, i);
    float be = 1.0f / sqrtf((float)(ei * 9));
    for (size_t k = 0; k < (size_t)eo * ei * 9; k++) w->enc_w[i][k] = uniform(&s, be);
    for (int k = 0; k < eo; k++) w->enc_b[i][k] = uniform(&s, be);
    /* ConvTranspose2d's fan_in is computed from weight dim 1 (out) * k*k */
    float bd = 1.0f / sqrtf((float)(dout * 16));
    for (size_t k = 0; k < (size_t)di * dout * 16; k++) w->dec_w[i][k] = uniform(&s, bd);
    for (int k = 0; k < dout; k++) w->dec_b[i][k] = uniform(&s, bd);
  }
  if (hf_head_in(cfg)) {
    int hi = hf_head_in(cfg), ho = cfg->out_channels;
    float bh = 1.0f / sqrtf((float)hi);
    for (size_t k = 0; k < (size_t)ho * hi; k++) w->head_w[k] = uniform(&s, bh);
    for (int k = 0; k < ho; k++) w->head_b[k] = uniform(&s, bh);
  }
  return HF_OK;
}
