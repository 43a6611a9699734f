/* Feature and result images <-> network tensors. Channel names are the
 * contract of protocol/FEATURES.md: S{k}.<feature> per sample k, and
 * color/highlight/alpha for results. */
#include <stdio.h>
#include <string.h>

#include "hfcore.h"

int hf_features_spp(const hf_image *img) {
  if (!img) return HF_EINVAL;
  /* No upper limit here: a file with more samples than any network reads
   * is filtered on its first spp (protocol/FEATURES.md); a channel per
   * feature bounds the count by the image's channels. */
  int spp = 0;
  char name[32];
  for (;;) {
    snprintf(name, sizeof name, "S%d.%s", spp, HF_FEATURE_NAMES[0]);
    if (hf_image_channel(img, name) < 0) break;
    spp++;
  }
  return spp ? spp : HF_ENOTFOUND;
}

int hf_features_from_image(const hf_image *img, int spp, float *in) {
  if (!img) return HF_EINVAL;
  return hf_features_from_data(img, img->data, HF_F32, spp, in);
}

int hf_features_from_data(const hf_image *img, const void *data, hf_dtype dtype, int spp,
                          void *in) {
  if (!img || !data || !in || spp < 1 || spp > HF_MAX_SPP || (dtype != HF_F32 && dtype != HF_F16))
    return HF_EINVAL;
  int src[HF_MAX_SPP * HF_FEATURES_PER_SAMPLE];
  int cin = spp * HF_FEATURES_PER_SAMPLE;
  for (int k = 0; k < spp; k++)
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++) {
      char name[32];
      snprintf(name, sizeof name, "S%d.%s", k, HF_FEATURE_NAMES[f]);
      if ((src[k * HF_FEATURES_PER_SAMPLE + f] = hf_image_channel(img, name)) < 0)
        return HF_ENOTFOUND;
    }
  size_t n = (size_t)img->width * img->height, nch = (size_t)img->channels;
  /* A gather of bits: values are copied, never converted. */
  if (dtype == HF_F16) {
    const uint16_t *d = data;
    uint16_t *o = in;
    for (size_t p = 0; p < n; p++)
      for (int c = 0; c < cin; c++) o[p * cin + c] = d[p * nch + src[c]];
  } else {
    const float *d = data;
    float *o = in;
    for (size_t p = 0; p < n; p++)
      for (int c = 0; c < cin; c++) o[p * cin + c] = d[p * nch + src[c]];
  }
  return spp;
}

int hf_estimate_from_data(const hf_image *img, const void *data, hf_dtype dtype, void *est) {
  if (!img || !data || !est || (dtype != HF_F32 && dtype != HF_F16)) return HF_EINVAL;
  int src[HF_ESTIMATE_CHANNELS];
  for (int c = 0; c < HF_ESTIMATE_CHANNELS; c++) {
    char name[32];
    snprintf(name, sizeof name, "%s.%s", HF_ESTIMATE_PREFIX, HF_OUTPUT_NAMES[c]);
    if ((src[c] = hf_image_channel(img, name)) < 0) return HF_ENOTFOUND;
  }
  size_t n = (size_t)img->width * img->height, nch = (size_t)img->channels;
  for (size_t p = 0; p < n; p++)
    for (int c = 0; c < HF_ESTIMATE_CHANNELS; c++) {
      if (dtype == HF_F16)
        ((uint16_t *)est)[p * HF_ESTIMATE_CHANNELS + c] = ((const uint16_t *)data)[p * nch + src[c]];
      else
        ((float *)est)[p * HF_ESTIMATE_CHANNELS + c] = ((const float *)data)[p * nch + src[c]];
    }
  return HF_OK;
}

int hf_features_to_image(const float *in, int width, int height, int spp, hf_image *img) {
  if (!in || !img || spp < 1 || spp > HF_MAX_SPP) return HF_EINVAL;
  int cin = spp * HF_FEATURES_PER_SAMPLE;
  int rc = hf_image_alloc(img, width, height, cin);
  if (rc) return rc;
  for (int k = 0; k < spp; k++)
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++)
      snprintf(img->names[k * HF_FEATURES_PER_SAMPLE + f], sizeof img->names[0], "S%d.%s", k,
               HF_FEATURE_NAMES[f]);
  memcpy(img->data, in, (size_t)width * height * cin * sizeof(float));
  return HF_OK;
}

int hf_result_to_image(const float *out, int width, int height, hf_image *img) {
  if (!out || !img) return HF_EINVAL;
  int rc = hf_image_alloc(img, width, height, HF_OUT_CHANNELS);
  if (rc) return rc;
  for (int c = 0; c < HF_OUT_CHANNELS; c++)
    snprintf(img->names[c], sizeof img->names[c], "%s", HF_OUTPUT_NAMES[c]);
  memcpy(img->data, out, (size_t)width * height * HF_OUT_CHANNELS * sizeof(float));
  return HF_OK;
}
