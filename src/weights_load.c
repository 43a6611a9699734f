/* safetensors loader. The file is untrusted: every length, offset, dtype and
 * shape is checked against the file size and the metadata before any of it is
 * used, and every failure is a one-line reason, never a crash.
 *
 * Layout: u64 little-endian header length N, N bytes of JSON, raw tensor
 * data. The JSON maps tensor names to {dtype, shape, data_offsets} (offsets
 * relative to the data start) and may hold "__metadata__", a map of strings,
 * whose "hairfilter" entry is itself JSON describing the network, and whose
 * optional "input_range" entry is JSON giving the range of input statistics
 * the network was trained on (input_range.c). */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "json_check.h"
#include "weights.h"
#include "errors.h"

/* A header larger than this is certainly hostile: ours are a few KB. */
#define HEADER_MAX (16u << 20)
/* Largest weights file we agree to read (Large is ~3 MB). */
#define FILE_MAX ((size_t)1 << 31)

#define fail hf_fail_msg

static int json_int(const cJSON *obj, const char *key, int lo, int hi, int *out) {
  const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
  if (!cJSON_IsNumber(v)) return HF_EFORMAT;
  double d = v->valuedouble;
  /* The range first: converting a double outside int's range (1e100 in a
   * file) is undefined behaviour. */
  if (!(d >= lo && d <= hi) || d != (double)(int)d) return HF_ERANGE;
  *out = (int)d;
  return HF_OK;
}

/* Parses the "hairfilter" metadata string into w->cfg and w->features. */
static int parse_metadata(const char *text, hf_weights *w, char *err, size_t errlen) {
  size_t at = 0;
  const char *fault = hf_json_text_fault(text, strlen(text), &at);
  if (fault)
    return fail(err, errlen, HF_EFORMAT, "metadata 'hairfilter' holds %s at byte %zu of its "
                "JSON; write the file again (weights/train.py --export)", fault, at);
  cJSON *m = hf_json_one_value(text, strlen(text));
  if (!m || !cJSON_IsObject(m)) {
    cJSON_Delete(m);
    return fail(err, errlen, HF_EFORMAT, "metadata 'hairfilter' is not one JSON object, or not "
                "valid JSON (NaN and Infinity are not JSON numbers; nothing may come before "
                "it, a byte order mark included, or follow it)");
  }
  int rc = HF_OK;
  /* 4.0 is 4 to cJSON, but no count to Python's json (hfnet.py refuses
   * it): refused here too, so no reader takes a file the other refuses. */
  static const char *const counts[] = {"spp", "in_channels", "out_channels", "levels",
                                       "kernel_radius", "kernel_hidden"};
  const char *which = "";
  size_t tok = 0;
  long nonint = hf_json_nonint_field(text, strlen(text), counts, 6, &which, &tok);
  if (nonint >= 0) {
    rc = fail(err, errlen, HF_EFORMAT, "metadata 'hairfilter': '%s' holds %.*s, not an "
              "integer: counts are written without a fraction or exponent; write the file "
              "again (weights/train.py --export)", which, (int)(tok < 32 ? tok : 32),
              text + nonint);
    goto out;
  }
  const char *where = "", *dup = hf_json_duplicate(m, &where);
  if (dup) {
    rc = fail(err, errlen, HF_EFORMAT, "metadata 'hairfilter': duplicate key '%.64s'%s%.64s%s: "
              "each name may appear once", dup, where[0] ? " in '" : "", where,
              where[0] ? "'" : "");
    goto out;
  }
  hf_net_config *c = &w->cfg;
  memset(c, 0, sizeof *c);
  const cJSON *name = cJSON_GetObjectItemCaseSensitive(m, "name");
  const cJSON *levels = cJSON_GetObjectItemCaseSensitive(m, "levels");
  const cJSON *features = cJSON_GetObjectItemCaseSensitive(m, "features");
  const cJSON *arch = cJSON_GetObjectItemCaseSensitive(m, "arch");
  if (!cJSON_IsString(name) || strlen(name->valuestring) == 0 ||
      strlen(name->valuestring) >= sizeof c->name) {
    rc = fail(err, errlen, HF_EFORMAT, "metadata: 'name' missing or longer than %d bytes",
              (int)sizeof c->name - 1);
    goto out;
  }
  strcpy(c->name, name->valuestring);
  c->arch = HF_ARCH_UNET; /* files from before 'arch' existed */
  if (arch) {
    int a = cJSON_IsString(arch) ? hf_arch_from_name(arch->valuestring) : HF_ENOTFOUND;
    if (a < 0) {
      rc = fail(err, errlen, HF_EUNSUPPORTED, "metadata: unsupported 'arch' (want unet, residual or kernel)");
      goto out;
    }
    c->arch = a;
  }
  const struct {
    const char *key;
    int hi;
    int *to;
    const char *why;
  } sizes[] = {
      {"spp", HF_MAX_SPP, &c->spp, ""},
      {"in_channels", HF_MAX_SPP * HF_FEATURES_PER_SAMPLE + HF_ESTIMATE_CHANNELS, &c->in_channels,
       ""},
      {"out_channels", HF_MAX_RAW_CHANNELS, &c->out_channels,
       " (a kernel variant's taps and 3, so a kernel_radius of at most 4)"},
  };
  _Static_assert(HF_KERNEL_MAX_RADIUS == 4, "the out_channels message names the radius");
  for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++)
    if (json_int(m, sizes[i].key, 1, sizes[i].hi, sizes[i].to)) {
      rc = fail(err, errlen, HF_EFORMAT, "metadata: '%s' missing or not an integer in 1..%d%s",
                sizes[i].key, sizes[i].hi, sizes[i].why);
      goto out;
    }
  /* Optional: files without it read the samples alone. */
  const cJSON *estimate = cJSON_GetObjectItemCaseSensitive(m, "estimate");
  if (estimate) {
    int e = cJSON_IsString(estimate) ? hf_estimate_from_name(estimate->valuestring) : HF_ENOTFOUND;
    if (e < 0) {
      rc = fail(err, errlen, HF_EUNSUPPORTED,
                "metadata: unsupported 'estimate' (want \"none\" or \"alpha_corrected\")");
      goto out;
    }
    if (e && c->arch != HF_ARCH_KERNEL) {
      rc = fail(err, errlen, HF_EUNSUPPORTED,
                "metadata: 'estimate' %s is for arch kernel only, not %s", hf_estimate_name(e),
                hf_arch_name(c->arch));
      goto out;
    }
    c->estimate = e;
  }
  if (c->in_channels != hf_net_in_channels(c->spp, c->estimate)) {
    if (c->estimate)
      rc = fail(err, errlen, HF_EFORMAT,
                "metadata: in_channels %d != spp %d x %d features + %d of the estimate",
                c->in_channels, c->spp, HF_FEATURES_PER_SAMPLE, HF_ESTIMATE_CHANNELS);
    else
      rc = fail(err, errlen, HF_EFORMAT, "metadata: in_channels %d != spp %d x %d features",
                c->in_channels, c->spp, HF_FEATURES_PER_SAMPLE);
    goto out;
  }
  const cJSON *radius = cJSON_GetObjectItemCaseSensitive(m, "kernel_radius");
  const cJSON *hidden = cJSON_GetObjectItemCaseSensitive(m, "kernel_hidden");
  const cJSON *mix = cJSON_GetObjectItemCaseSensitive(m, "kernel_mix");
  if (c->arch != HF_ARCH_KERNEL && (radius || hidden || mix)) {
    rc = fail(err, errlen, HF_EFORMAT,
              "metadata: 'kernel_radius', 'kernel_hidden' and 'kernel_mix' are for arch kernel "
              "only, not %s",
              hf_arch_name(c->arch));
    goto out;
  }
  if (c->arch == HF_ARCH_KERNEL) {
    if (json_int(m, "kernel_radius", 1, HF_KERNEL_MAX_RADIUS, &c->kernel_radius)) {
      rc = fail(err, errlen, HF_EFORMAT,
                "metadata: 'kernel_radius' missing or not an integer in 1..%d (arch kernel)",
                HF_KERNEL_MAX_RADIUS);
      goto out;
    }
    /* Optional, as in weights/hfnet.py: 0, no head. */
    if (hidden && json_int(m, "kernel_hidden", 0, HF_KERNEL_MAX_HIDDEN, &c->kernel_hidden)) {
      rc = fail(err, errlen, HF_EFORMAT, "metadata: 'kernel_hidden' is not an integer in 0..%d",
                HF_KERNEL_MAX_HIDDEN);
      goto out;
    }
    /* Optional: 0, the kernel weighs the estimate alone (or the samples). */
    if (mix && json_int(m, "kernel_mix", 0, 1, &c->kernel_mix)) {
      rc = fail(err, errlen, HF_EFORMAT, "metadata: 'kernel_mix' is not 0 or 1");
      goto out;
    }
    if (c->kernel_mix && !c->estimate) {
      rc = fail(err, errlen, HF_EFORMAT,
                "metadata: 'kernel_mix' 1 mixes the samples' sums with the estimate's: it needs "
                "'estimate' \"alpha_corrected\"");
      goto out;
    }
    int want = hf_kernel_taps(c->kernel_radius) + HF_OUT_CHANNELS + c->kernel_mix;
    if (c->out_channels != want) {
      rc = fail(err, errlen, HF_EFORMAT,
                "metadata: out_channels must be %d (kernel_radius %d: %d taps + %d%s)", want,
                c->kernel_radius, hf_kernel_taps(c->kernel_radius), HF_OUT_CHANNELS,
                c->kernel_mix ? " + 1 for kernel_mix" : "");
      goto out;
    }
  } else if (c->out_channels != HF_OUT_CHANNELS) {
    rc = fail(err, errlen, HF_EFORMAT, "metadata: out_channels must be %d", HF_OUT_CHANNELS);
    goto out;
  }
  int nl = cJSON_IsArray(levels) ? cJSON_GetArraySize(levels) : -1;
  if (nl < 1 || nl > HF_MAX_LEVELS) {
    rc = fail(err, errlen, HF_EFORMAT, "metadata: 'levels' must be an array of 1..%d counts",
              HF_MAX_LEVELS);
    goto out;
  }
  c->num_levels = nl;
  for (int i = 0; i < nl; i++) {
    const cJSON *v = cJSON_GetArrayItem(levels, i);
    if (!cJSON_IsNumber(v) || v->valuedouble < 1 || v->valuedouble > HF_MAX_CHANNELS ||
        v->valuedouble != (double)(int)v->valuedouble) {
      rc = fail(err, errlen, HF_EFORMAT, "metadata: levels[%d] is not a count in 1..%d", i,
                HF_MAX_CHANNELS);
      goto out;
    }
    c->levels[i] = (int)v->valuedouble;
  }
  /* Every backend assumes the canonical feature order: refuse anything else
   * rather than silently filter the wrong channels. */
  if (!cJSON_IsArray(features) || cJSON_GetArraySize(features) != HF_FEATURES_PER_SAMPLE) {
    rc = fail(err, errlen, HF_EFORMAT, "metadata: 'features' must list %d names",
              HF_FEATURES_PER_SAMPLE);
    goto out;
  }
  for (int k = 0; k < HF_FEATURES_PER_SAMPLE; k++) {
    const cJSON *v = cJSON_GetArrayItem(features, k);
    if (!cJSON_IsString(v) || strcmp(v->valuestring, HF_FEATURE_NAMES[k])) {
      rc = fail(err, errlen, HF_EFORMAT, "metadata: features[%d] must be \"%s\"", k,
                HF_FEATURE_NAMES[k]);
      goto out;
    }
    snprintf(w->features[k], sizeof w->features[k], "%s", v->valuestring);
  }
  rc = hf_net_config_validate(c);
  if (rc) fail(err, errlen, rc, "metadata: invalid network configuration");
out:
  cJSON_Delete(m);
  return rc;
}

static uint64_t read_le64(const unsigned char *p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; i--) v = (v << 8) | p[i];
  return v;
}

/* Copies one tensor's bytes into dst as float32. */
static void convert(const unsigned char *src, int is_f16, size_t numel, float *dst) {
  if (!is_f16) {
    memcpy(dst, src, numel * 4); /* little-endian hosts only (x86, arm) */
    return;
  }
  for (size_t i = 0; i < numel; i++)
    dst[i] = hf_f16_to_f32((uint16_t)(src[2 * i] | (src[2 * i + 1] << 8)));
}

/* Index of the first NaN or infinity among a tensor's numel stored values,
 * or -1. Read off the bits: an exponent of all ones (F32 0x7f800000, F16
 * 0x7c00) is an infinity or a NaN. */
static long long first_nonfinite(const unsigned char *src, int is_f16, size_t numel) {
  for (size_t i = 0; i < numel; i++) {
    int bad = is_f16 ? (src[2 * i + 1] & 0x7c) == 0x7c
                     : (src[4 * i + 3] & 0x7f) == 0x7f && (src[4 * i + 2] & 0x80);
    if (bad) return (long long)i;
  }
  return -1;
}

static int check_tensor(const cJSON *t, const hf_tensor_spec *s, size_t data_len,
                        int *is_f16, size_t *begin, size_t *end, char *err, size_t errlen) {
  if (!cJSON_IsObject(t)) return fail(err, errlen, HF_EFORMAT, "tensor '%s' missing", s->name);
  const cJSON *dtype = cJSON_GetObjectItemCaseSensitive(t, "dtype");
  const cJSON *shape = cJSON_GetObjectItemCaseSensitive(t, "shape");
  const cJSON *offs = cJSON_GetObjectItemCaseSensitive(t, "data_offsets");
  if (!cJSON_IsString(dtype))
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': no dtype", s->name);
  if (!strcmp(dtype->valuestring, "F32")) *is_f16 = 0;
  else if (!strcmp(dtype->valuestring, "F16")) *is_f16 = 1;
  else
    return fail(err, errlen, HF_EUNSUPPORTED, "tensor '%s': dtype %.16s (want F32 or F16)",
                s->name, dtype->valuestring);
  if (!cJSON_IsArray(shape) || cJSON_GetArraySize(shape) != s->ndim)
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': expected %d dimensions", s->name,
                s->ndim);
  for (int d = 0; d < s->ndim; d++) {
    const cJSON *v = cJSON_GetArrayItem(shape, d);
    /* true is 1 to Python's ==: said as what it is, in hfnet.py's words. */
    if (cJSON_IsBool(v))
      return fail(err, errlen, HF_EFORMAT, "tensor '%s': shape holds %s, not an integer: "
                  "safetensors shapes and offsets are integers; write the file again with a "
                  "safetensors writer", s->name, cJSON_IsTrue(v) ? "true" : "false");
    if (!cJSON_IsNumber(v) || v->valuedouble != (double)s->shape[d])
      return fail(err, errlen, HF_EFORMAT,
                  "tensor '%s': shape[%d] should be %lld for this configuration", s->name, d,
                  (long long)s->shape[d]);
  }
  if (!cJSON_IsArray(offs) || cJSON_GetArraySize(offs) != 2)
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': bad data_offsets", s->name);
  const cJSON *ob = cJSON_GetArrayItem(offs, 0), *oe = cJSON_GetArrayItem(offs, 1);
  if (!cJSON_IsNumber(ob) || !cJSON_IsNumber(oe))
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': data_offsets holds %s, not two integers",
                s->name, hf_json_kind(cJSON_IsNumber(ob) ? oe : ob));
  double b = ob->valuedouble, e = oe->valuedouble;
  if (b < 0 || e < 0 || b != (double)(size_t)b || e != (double)(size_t)e)
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': data_offsets [%.17g, %.17g] are not two "
                "byte offsets (integers from 0)", s->name, b, e);
  if (e < b)
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': data_offsets [%.0f, %.0f] end before "
                "they begin", s->name, b, e);
  if (e > (double)data_len)
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': data_offsets [%.0f, %.0f] end past the "
                "%zu bytes of data after the header (a truncated file?)", s->name, b, e,
                (size_t)data_len);
  size_t bytes = s->numel * (*is_f16 ? 2 : 4);
  if ((size_t)e - (size_t)b != bytes)
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': %zu bytes of data, shape needs %zu",
                s->name, (size_t)e - (size_t)b, bytes);
  *begin = (size_t)b;
  *end = (size_t)e;
  return HF_OK;
}

/* The tensors' byte ranges must tile the data: sorted by start, each
 * begins where the one before ends, the first at 0, the last at the end of
 * the file (the safetensors reference reader's rule; a range two tensors
 * share, or bytes no tensor owns, would be read differently by readers that
 * do not check). begin and end are indexed like specs. */
static int check_tiling(const hf_tensor_spec *specs, const size_t *begin, const size_t *end,
                        int n, size_t data_len, char *err, size_t errlen) {
  int order[HF_TENSORS_MAX];
  for (int k = 0; k < n; k++) {
    int j = k;
    for (; j > 0 && begin[order[j - 1]] > begin[k]; j--) order[j] = order[j - 1];
    order[j] = k;
  }
  size_t at = 0;
  for (int i = 0; i < n; i++) {
    int k = order[i];
    if (begin[k] < at)
      return fail(err, errlen, HF_EFORMAT, "tensor '%s': data_offsets [%zu, %zu) overlap "
                  "tensor '%s' [%zu, %zu): in safetensors each tensor owns its bytes",
                  specs[k].name, begin[k], end[k], specs[order[i - 1]].name,
                  begin[order[i - 1]], end[order[i - 1]]);
    if (begin[k] > at)
      return fail(err, errlen, HF_EFORMAT, "bytes [%zu, %zu) of the data belong to no tensor: "
                  "safetensors tensors follow one another with no gap", at, begin[k]);
    at = end[k];
  }
  if (at != data_len)
    return fail(err, errlen, HF_EFORMAT, "%zu bytes after the last tensor: safetensors data "
                "ends with its last tensor", data_len - at);
  return HF_OK;
}

int hf_weights_load_mem(const void *buf, size_t len, hf_weights **out, char *err,
                        size_t errlen) {
  if (!buf || !out) return fail(err, errlen, HF_EINVAL, "null argument");
  *out = NULL;
  const unsigned char *p = buf;
  if (len < 8) return fail(err, errlen, HF_EFORMAT, "file too short (%zu bytes)", len);
  uint64_t hlen = read_le64(p);
  if (hlen < 2 || hlen > HEADER_MAX || hlen > len - 8) {
    /* Files given for weights by mistake are named for what they are: a
     * header length read off a zip's or an EXR's first bytes says nothing. */
    if (!memcmp(p, "PK\3\4", 4))
      return fail(err, errlen, HF_EFORMAT, "a zip archive, not a safetensors file: a PyTorch "
                  "checkpoint (train.py's RUN/checkpoint.pt)? Export its weights with "
                  "weights/train.py --out RUN --resume --export W.safetensors");
    if (p[0] == 0x76 && p[1] == 0x2f && p[2] == 0x31 && p[3] == 0x01)
      return fail(err, errlen, HF_EFORMAT, "an OpenEXR image, not a safetensors weights file");
    return fail(err, errlen, HF_EFORMAT, "header length %llu does not fit a %zu-byte file "
                "(not a safetensors file, or one cut short)", (unsigned long long)hlen, len);
  }
  if (p[8] != '{')
    return fail(err, errlen, HF_EFORMAT, "header does not start with '{' (a byte order mark "
                "or other bytes come before the JSON): write the file again with a "
                "safetensors writer");
  /* Before cJSON, which takes other bytes and cuts names at \u0000. */
  size_t at = 0;
  const char *fault = hf_json_text_fault((const char *)p + 8, (size_t)hlen, &at);
  if (fault)
    return fail(err, errlen, HF_EFORMAT, "header holds %s at byte %zu of its JSON (byte %zu of "
                "the file): a safetensors header is UTF-8 JSON whose names other readers must "
                "read alike; write the file again with a safetensors writer", fault, at, at + 8);
  char *text = malloc(hlen + 1);
  if (!text) return fail(err, errlen, HF_ENOMEM, "out of memory");
  memcpy(text, p + 8, hlen);
  text[hlen] = 0;
  /* One JSON value and nothing after it but JSON's whitespace (the spaces
   * safetensors pads with): what safetensors' own reader and Python's json
   * take. */
  cJSON *root = hf_json_one_value(text, (size_t)hlen);
  free(text);
  if (!root || !cJSON_IsObject(root)) {
    cJSON_Delete(root);
    return fail(err, errlen, HF_EFORMAT, "header is not valid JSON (one object, nothing after "
                "it; the padding spaces safetensors allows excepted)");
  }
  /* "shape": [32.0, ...] is 32 to cJSON, but no integer to safetensors'
   * reference reader (nor are offsets so written): refused, so no reader
   * takes a file another refuses. */
  static const char *const int_keys[] = {"shape", "data_offsets"};
  char tensor[80] = "";
  const char *which = "";
  size_t tok = 0;
  long nonint = hf_json_nonint_member((const char *)p + 8, (size_t)hlen, int_keys, 2, tensor,
                                      sizeof tensor, &which, &tok);
  if (nonint >= 0) {
    cJSON_Delete(root);
    return fail(err, errlen, HF_EFORMAT, "tensor '%s': %s holds %.*s, not an integer (byte %ld "
                "of the header's JSON): safetensors shapes and offsets are integers, written "
                "without a fraction or exponent; write the file again with a safetensors writer",
                tensor, which, (int)(tok < 32 ? tok : 32), (const char *)p + 8 + nonint, nonint);
  }
  const unsigned char *data = p + 8 + hlen;
  size_t data_len = len - 8 - (size_t)hlen;
  int rc;
  hf_weights tmp;
  memset(&tmp, 0, sizeof tmp);
  const char *where = "", *dup = hf_json_duplicate(root, &where);
  if (dup) {
    rc = fail(err, errlen, HF_EFORMAT, "header: duplicate key '%.64s'%s%.64s%s: each name may "
              "appear once (readers disagree on which one counts)", dup,
              where[0] ? " in '" : "", where, where[0] ? "'" : "");
    goto out;
  }
  /* safetensors: "__metadata__" is optional and, when present, an object
   * whose values are all strings. */
  const cJSON *meta = cJSON_GetObjectItemCaseSensitive(root, "__metadata__");
  if (meta && !cJSON_IsObject(meta)) {
    rc = fail(err, errlen, HF_EFORMAT, "header: '__metadata__' is %s, but safetensors wants an "
              "object of string values", hf_json_kind(meta));
    goto out;
  }
  for (const cJSON *it = meta ? meta->child : NULL; it; it = it->next)
    if (!cJSON_IsString(it)) {
      rc = fail(err, errlen, HF_EFORMAT, "header: '__metadata__.%.64s' is %s, but safetensors "
                "metadata values are strings", it->string, hf_json_kind(it));
      goto out;
    }
  const cJSON *hf = meta ? cJSON_GetObjectItemCaseSensitive(meta, "hairfilter") : NULL;
  if (!cJSON_IsString(hf)) {
    rc = fail(err, errlen, HF_EFORMAT, "no '__metadata__.hairfilter' entry");
    goto out;
  }
  rc = parse_metadata(hf->valuestring, &tmp, err, errlen);
  if (rc) goto out;
  /* Optional: the input statistics the variant was trained on. */
  const cJSON *range = cJSON_GetObjectItemCaseSensitive(meta, "input_range");
  if (range) {
    char why[160] = "";
    if (!cJSON_IsString(range))
      rc = fail(err, errlen, HF_EFORMAT, "metadata 'input_range' must be a JSON string");
    else if ((rc = hf_input_range_parse(range->valuestring, tmp.cfg.spp, &tmp.input_range, why,
                                        sizeof why)) != 0)
      fail(err, errlen, rc, "metadata: %s", why);
    if (rc) goto out;
  }
  /* Every tensor is checked against the file before the network is
   * allocated: metadata that claims huge levels must not cost their memory
   * when the file holds a fraction of it. (parse_metadata validated the
   * configuration, which hf_weights_specs needs.) */
  hf_tensor_spec specs[HF_TENSORS_MAX];
  int n = hf_weights_specs(&tmp, specs);
  /* Unknown tensors mean the file describes another network. */
  int entries = 0;
  for (const cJSON *it = root->child; it; it = it->next)
    if (strcmp(it->string, "__metadata__")) entries++;
  if (entries != n) {
    rc = fail(err, errlen, HF_EFORMAT, "file has %d tensors, configuration needs %d", entries, n);
    goto out;
  }
  size_t begin[HF_TENSORS_MAX], end[HF_TENSORS_MAX];
  int f16[HF_TENSORS_MAX];
  for (int k = 0; k < n; k++) {
    f16[k] = 0;
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, specs[k].name);
    rc = check_tensor(t, &specs[k], data_len, &f16[k], &begin[k], &end[k], err, errlen);
    if (rc) goto out;
  }
  if ((rc = check_tiling(specs, begin, end, n, data_len, err, errlen)) != HF_OK) goto out;
  /* A network with a NaN or infinite weight gives NaN for every pixel its
   * receptive field reaches, which the output guard would turn into neutral
   * values frame after frame, blamed on the frames. */
  for (int k = 0; k < n; k++) {
    long long bad = first_nonfinite(data + begin[k], f16[k], specs[k].numel);
    if (bad >= 0) {
      rc = fail(err, errlen, HF_EFORMAT, "tensor '%s': value %lld of %zu is not finite (NaN or "
                "infinite): the weights are damaged (a training run that diverged?); export "
                "them again from a good checkpoint", specs[k].name, bad, specs[k].numel);
      goto out;
    }
  }
  hf_weights *w;
  rc = hf_weights_alloc(&tmp.cfg, &w);
  if (rc) {
    fail(err, errlen, rc, "cannot allocate weights: %s", hf_strerror(rc));
    goto out;
  }
  memcpy(w->features, tmp.features, sizeof w->features);
  w->input_range = tmp.input_range;
  /* The same specs in the same order, their slots now w's arrays. */
  hf_weights_specs(w, specs);
  for (int k = 0; k < n; k++) convert(data + begin[k], f16[k], specs[k].numel, *specs[k].slot);
  *out = w;
out:
  cJSON_Delete(root);
  return rc;
}

int hf_weights_load(const char *path, hf_weights **out, char *err, size_t errlen) {
  if (!path || !out) return fail(err, errlen, HF_EINVAL, "null argument");
  *out = NULL;
  /* O_NONBLOCK: opening a FIFO (or a device that waits) would otherwise
   * block until a writer comes, holding the daemon's worker and its stop
   * forever; only a regular file is read. */
  int fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) {
    int e = errno;
    char to[512];
    ssize_t n;
    /* A link that points nowhere is there to `ls`: say where it points. */
    if (e == ENOENT && (n = readlink(path, to, sizeof to - 1)) > 0) {
      to[n] = 0;
      return fail(err, errlen, HF_EIO, "%s: is a symbolic link to %s, which does not exist",
                  path, to);
    }
    return fail(err, errlen, HF_EIO, "%s: %s", path, strerror(e));
  }
  struct stat st;
  if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    int dir = S_ISDIR(st.st_mode);
    close(fd);
    /* fopen reads a directory on Linux; its size was "not supported". */
    return fail(err, errlen, HF_EIO, "%s: is %s: give a .safetensors file", path,
                dir ? "a directory" : S_ISFIFO(st.st_mode) ? "a FIFO, not a regular file"
                : S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ? "a device, not a regular file"
                : "not a regular file");
  }
  FILE *f = fdopen(fd, "rb");
  if (!f) {
    close(fd);
    return fail(err, errlen, HF_EIO, "%s: %s", path, strerror(errno));
  }
  int rc = HF_OK;
  unsigned char *buf = NULL;
  if (fseek(f, 0, SEEK_END) != 0) {
    rc = fail(err, errlen, HF_EIO, "%s: cannot seek", path);
    goto out;
  }
  long size = ftell(f);
  if (size < 0 || (unsigned long)size > FILE_MAX) {
    rc = fail(err, errlen, HF_ERANGE, "%s: larger than the %zu bytes a weights file may have",
              path, FILE_MAX);
    goto out;
  }
  rewind(f);
  buf = malloc(size ? (size_t)size : 1);
  if (!buf) {
    rc = fail(err, errlen, HF_ENOMEM, "%s: out of memory", path);
    goto out;
  }
  if (fread(buf, 1, (size_t)size, f) != (size_t)size) {
    rc = fail(err, errlen, HF_EIO, "%s: short read", path);
    goto out;
  }
  char inner[400] = "";
  rc = hf_weights_load_mem(buf, (size_t)size, out, inner, sizeof inner);
  if (rc) fail(err, errlen, rc, "%s: %s", path, inner);
out:
  free(buf);
  fclose(f);
  return rc;
}
