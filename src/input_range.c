/* The range of input statistics a variant was trained on: the weights'
 * `input_range` metadata (weights/FORMAT.md), read and written as JSON text,
 * and the check of a frame's statistics (input_stats.c) against it. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "errors.h"
#include "json_check.h"
#include "hfcore.h"

#define fail hf_fail_msg

int hf_input_range_parse(const char *json, int spp, hf_input_range *out, char *err,
                         size_t errlen) {
  if (!json || !out) return fail(err, errlen, HF_EINVAL, "null argument");
  memset(out, 0, sizeof *out);
  size_t at = 0;
  const char *fault = hf_json_text_fault(json, strlen(json), &at);
  if (fault)
    return fail(err, errlen, HF_EFORMAT, "input_range holds %s at byte %zu of its JSON", fault,
                at);
  cJSON *m = hf_json_one_value(json, strlen(json));   /* nothing may follow the object */
  int rc = HF_OK;
  if (!cJSON_IsObject(m)) {
    rc = fail(err, errlen, HF_EFORMAT, "input_range is not a JSON object");
    goto out;
  }
  const char *where = "", *dup = hf_json_duplicate(m, &where);
  if (dup) {
    rc = fail(err, errlen, HF_EFORMAT, "input_range: duplicate key '%.64s'%s%.64s%s: each name "
              "may appear once", dup, where[0] ? " in '" : "", where, where[0] ? "'" : "");
    goto out;
  }
  const cJSON *def = cJSON_GetObjectItemCaseSensitive(m, "definition");
  if (!cJSON_IsNumber(def)) {
    rc = fail(err, errlen, HF_EFORMAT, "input_range: no 'definition' number");
    goto out;
  }
  /* Statistics of another definition are not comparable with ours: such a
   * range is left unused, as if there were none. */
  if (def->valuedouble != HF_INPUT_STATS_DEFINITION) goto out;
  const cJSON *s = cJSON_GetObjectItemCaseSensitive(m, "spp");
  const cJSON *f = cJSON_GetObjectItemCaseSensitive(m, "frames");
  if (!cJSON_IsNumber(s) || s->valuedouble != spp) {
    rc = fail(err, errlen, HF_EFORMAT, "input_range: 'spp' must be the variant's %d", spp);
    goto out;
  }
  if (!cJSON_IsNumber(f) || f->valuedouble < 1 || f->valuedouble > 1e9 ||
      f->valuedouble != (double)(int)f->valuedouble) {
    rc = fail(err, errlen, HF_EFORMAT, "input_range: 'frames' must be a count >= 1");
    goto out;
  }
  out->spp = spp;
  out->frames = (int)f->valuedouble;
  for (int k = 0; k < HF_STAT_COUNT; k++) {
    const cJSON *r = cJSON_GetObjectItemCaseSensitive(m, hf_input_stat_name(k));
    if (!r) continue;   /* not recorded: not checked */
    const cJSON *lo = cJSON_GetArrayItem(r, 0), *hi = cJSON_GetArrayItem(r, 1);
    if (!cJSON_IsArray(r) || cJSON_GetArraySize(r) != 2 || !cJSON_IsNumber(lo) ||
        !cJSON_IsNumber(hi) || !isfinite(lo->valuedouble) || !isfinite(hi->valuedouble) ||
        lo->valuedouble > hi->valuedouble) {
      rc = fail(err, errlen, HF_EFORMAT, "input_range: '%s' must be [low, high] with low <= high",
                hf_input_stat_name(k));
      goto out;
    }
    out->has |= 1u << k;
    out->lo[k] = lo->valuedouble;
    out->hi[k] = hi->valuedouble;
  }
  if (!out->has) {
    rc = fail(err, errlen, HF_EFORMAT, "input_range: no statistic has a range");
    goto out;
  }
  out->present = 1;
out:
  if (rc) memset(out, 0, sizeof *out);
  cJSON_Delete(m);
  return rc;
}

char *hf_input_range_to_json(const hf_input_range *r) {
  if (!r || !r->present) return NULL;
  cJSON *m = cJSON_CreateObject();
  if (!m) return NULL;
  cJSON_AddNumberToObject(m, "definition", HF_INPUT_STATS_DEFINITION);
  cJSON_AddNumberToObject(m, "spp", r->spp);
  cJSON_AddNumberToObject(m, "frames", r->frames);
  for (int k = 0; k < HF_STAT_COUNT; k++) {
    if (!(r->has & (1u << k))) continue;
    /* cJSON prints 15 significant digits unless they read back within
     * DBL_EPSILON, which loses the last bit: 17 digits round-trip exactly. */
    char raw[64];
    snprintf(raw, sizeof raw, "[%.17g, %.17g]", r->lo[k], r->hi[k]);
    cJSON_AddRawToObject(m, hf_input_stat_name(k), raw);
  }
  char *s = cJSON_PrintUnformatted(m);
  cJSON_Delete(m);
  return s;
}

unsigned hf_input_range_check(const hf_input_range *r, const hf_input_stats *s) {
  if (!r || !s || !r->present || s->hair_pixels == 0) return 0;
  unsigned out = 0;
  for (int k = 0; k < HF_STAT_COUNT; k++) {
    double v = s->value[k];
    if ((r->has & (1u << k)) && !isnan(v) && (v < r->lo[k] || v > r->hi[k])) out |= 1u << k;
  }
  return out;
}

int hf_input_range_describe(const hf_input_range *r, const hf_input_stats *s, unsigned mask,
                            char *buf, size_t len) {
  if (!buf || !len) return HF_EINVAL;
  buf[0] = 0;
  if (!r || !s) return HF_EINVAL;
  size_t used = 0;
  for (int k = 0; k < HF_STAT_COUNT; k++) {
    if (!(mask & (1u << k))) continue;
    int n = snprintf(buf + used, len - used, "%s%s %.4g (trained %.4g..%.4g)", used ? ", " : "",
                     hf_input_stat_name(k), s->value[k], r->lo[k], r->hi[k]);
    if (n < 0 || (size_t)n >= len - used) return HF_ERANGE;   /* cut, still terminated */
    used += (size_t)n;
  }
  return HF_OK;
}
