/* safetensors writer (float32), the inverse of weights_load.c. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "weights.h"

/* The metadata JSON the loader expects; caller frees. */
static char *metadata_json(const hf_weights *w) {
  const hf_net_config *c = &w->cfg;
  cJSON *m = cJSON_CreateObject();
  if (!m) return NULL;
  cJSON_AddStringToObject(m, "name", c->name);
  cJSON_AddStringToObject(m, "arch", hf_arch_name(c->arch));
  cJSON_AddNumberToObject(m, "spp", c->spp);
  cJSON_AddNumberToObject(m, "in_channels", c->in_channels);
  cJSON_AddItemToObject(m, "levels", cJSON_CreateIntArray(c->levels, c->num_levels));
  cJSON_AddNumberToObject(m, "out_channels", c->out_channels);
  if (c->arch == HF_ARCH_KERNEL) {
    cJSON_AddNumberToObject(m, "kernel_radius", c->kernel_radius);
    cJSON_AddNumberToObject(m, "kernel_hidden", c->kernel_hidden);
    if (c->kernel_mix) cJSON_AddNumberToObject(m, "kernel_mix", c->kernel_mix);
  }
  if (c->estimate) cJSON_AddStringToObject(m, "estimate", hf_estimate_name(c->estimate));
  cJSON_AddItemToObject(m, "features",
                        cJSON_CreateStringArray(HF_FEATURE_NAMES, HF_FEATURES_PER_SAMPLE));
  char *s = cJSON_PrintUnformatted(m);
  cJSON_Delete(m);
  return s;
}

int hf_weights_save(const char *path, const hf_weights *w) {
  if (!path || !w || hf_net_config_validate(&w->cfg)) return HF_EINVAL;
  hf_weights copy = *w; /* specs point into the copy's slots, same arrays */
  hf_tensor_spec specs[HF_TENSORS_MAX];
  int n = hf_weights_specs(&copy, specs);
  int rc = HF_ENOMEM;
  char *header = NULL, *meta = metadata_json(w), *range = NULL, *tmp = NULL;
  cJSON *root = cJSON_CreateObject();
  if (!meta || !root) goto out;
  cJSON *md = cJSON_AddObjectToObject(root, "__metadata__");
  cJSON_AddStringToObject(md, "hairfilter", meta);
  if (w->input_range.present) {
    if (!(range = hf_input_range_to_json(&w->input_range))) goto out;
    cJSON_AddStringToObject(md, "input_range", range);
  }
  size_t off = 0;
  for (int k = 0; k < n; k++) {
    cJSON *t = cJSON_AddObjectToObject(root, specs[k].name);
    cJSON_AddStringToObject(t, "dtype", "F32");
    cJSON *shape = cJSON_AddArrayToObject(t, "shape");
    for (int d = 0; d < specs[k].ndim; d++)
      cJSON_AddItemToArray(shape, cJSON_CreateNumber((double)specs[k].shape[d]));
    cJSON *o = cJSON_AddArrayToObject(t, "data_offsets");
    cJSON_AddItemToArray(o, cJSON_CreateNumber((double)off));
    off += specs[k].numel * 4;
    cJSON_AddItemToArray(o, cJSON_CreateNumber((double)off));
  }
  header = cJSON_PrintUnformatted(root);
  if (!header) goto out;
  /* Pad the header with spaces so tensor data starts 8-byte aligned. */
  size_t hlen = strlen(header), padded = (hlen + 7) & ~(size_t)7;
  unsigned char lenbuf[8];
  for (int i = 0; i < 8; i++) lenbuf[i] = (unsigned char)((uint64_t)padded >> (8 * i));
  /* Into path.tmp renamed over path once complete (as hf_exr_write, and
   * hfnet.save_safetensors): a reader of path (a server reloading it) never
   * meets half a file, and an earlier file there survives a failed write. */
  size_t plen = strlen(path);
  rc = HF_ENOMEM;
  if (!(tmp = malloc(plen + 5))) goto out;
  memcpy(tmp, path, plen);
  memcpy(tmp + plen, ".tmp", 5);
  FILE *f = fopen(tmp, "wb");
  rc = HF_EIO;
  if (!f) goto out;
  int ok = fwrite(lenbuf, 1, 8, f) == 8 && fwrite(header, 1, hlen, f) == hlen;
  for (size_t i = hlen; ok && i < padded; i++) ok = fputc(' ', f) != EOF;
  for (int k = 0; ok && k < n; k++)
    ok = fwrite(*specs[k].slot, 4, specs[k].numel, f) == specs[k].numel;
  if (fclose(f) != 0) ok = 0;
  if (ok && rename(tmp, path) != 0) ok = 0;
  if (!ok) remove(tmp);   /* nothing half-written left behind */
  rc = ok ? HF_OK : HF_EIO;
out:
  free(tmp);
  free(header);
  free(meta);
  free(range);
  cJSON_Delete(root);
  return rc;
}
