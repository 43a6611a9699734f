#include <ctype.h>
#include <errno.h>
#include <inttypes.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cli_common.h"
#include <hairfilter/hairfilter.h>
#ifdef HF_HAVE_RENDERER
#include "hfrender.h"
#endif

const float CLI_HAIR_DEFAULT[3] = {0.45f, 0.25f, 0.12f};
const float CLI_LIGHT_DEFAULT[3] = {1.0f, 1.0f, 1.0f};
const float CLI_BG_DEFAULT[3] = {0.18f, 0.2f, 0.24f};

int cli_parse_rgb(const char *cmd, const char *opt, const char *s, float rgb[3]) {
  float v[3];
  const char *p = s;
  for (int i = 0; i < 3; i++) {
    char *end;
    errno = 0;
    v[i] = strtof(p, &end);
    /* Each number whole and finite, separated by single commas: "1,2"
     * or "nan,0,0" would composite with a colour nobody asked for. */
    if (end == p || errno || !isfinite(v[i]) || *end != (i < 2 ? ',' : '\0')) {
      fprintf(stderr, "%s: %s: '%s' is not R,G,B (three finite numbers, e.g. "
                      "0.45,0.25,0.12)\n", cmd, opt, s);
      return -1;
    }
    p = end + 1;
  }
  memcpy(rgb, v, sizeof v);
  return 0;
}

/* cli_check_output and cli_check_output_dir: path names a file (a trailing
 * '/' is refused) or, with is_dir, a directory to create (trailing '/'s
 * ignored); either way the directory it goes in must exist and be
 * writable. */
static int check_output(const char *prog, const char *path, int is_dir) {
  if (!path) return 0;
  size_t len = strlen(path);
  if (is_dir)
    while (len > 1 && path[len - 1] == '/') len--;
  else if (len && path[len - 1] == '/') {
    fprintf(stderr, "%s: %s: names a directory; give a file name\n", prog, path);
    return HF_EIO;
  }
  const char *slash = NULL;   /* the last '/' of path[0, len) */
  for (size_t i = len; i > 0 && !slash; i--)
    if (path[i - 1] == '/') slash = path + i - 1;
  char dir[4096];
  if (!slash) {
    snprintf(dir, sizeof dir, ".");
  } else if (slash == path) {
    snprintf(dir, sizeof dir, "/");
  } else {
    size_t n = (size_t)(slash - path);
    if (n >= sizeof dir) {
      fprintf(stderr, "%s: %s: path too long\n", prog, path);
      return HF_EIO;
    }
    memcpy(dir, path, n);
    dir[n] = 0;
  }
  struct stat sb;
  if (stat(dir, &sb) == 0 && !S_ISDIR(sb.st_mode)) {
    fprintf(stderr, "%s: %.*s: %s is a file, not a directory\n", prog, (int)len, path, dir);
    return HF_EIO;
  }
  if (access(dir, W_OK) != 0) {
    int e = errno;
    if (e == ENOENT || e == ENOTDIR)
      fprintf(stderr, "%s: %.*s: the directory %s does not exist; create it first (mkdir -p %s)\n",
              prog, (int)len, path, dir, dir);
    else
      fprintf(stderr, "%s: %.*s: cannot write in %s: %s\n", prog, (int)len, path, dir, strerror(e));
    return HF_EIO;
  }
  return 0;
}

int cli_check_output(const char *prog, const char *path) { return check_output(prog, path, 0); }

int cli_check_output_dir(const char *prog, const char *dir) { return check_output(prog, dir, 1); }

int cli_parse_size(const char *s, int *w, int *h) {
  char tail;
  if (sscanf(s, "%dx%d%c", w, h, &tail) != 2 || *w < 1 || *h < 1) return -1;
  return 0;
}

/* A directory holds the bundled data when it has the network's Python
 * definition beside the weights (what bench --torch and demo read). */
static int is_data_dir(const char *dir) {
  char path[PATH_MAX];
  int n = snprintf(path, sizeof path, "%s/weights/hfnet.py", dir);
  return n > 0 && (size_t)n < sizeof path && access(path, R_OK) == 0;
}

const char *cli_data_dir(void) {
  static char found[PATH_MAX];
  const char *env = getenv("HAIRFILTER_DATA");
  if (env && *env) return env;
  if (found[0]) return found;
  /* Beside the executable: build/hairfilter in a checkout, bin/hairfilter
   * in a copy of the tree carried to another machine, or an installed
   * bin/ with ../share/hairfilter. The source tree this was built from
   * comes last: on another machine it does not exist. */
  char exe[PATH_MAX];
  ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
  if (n > 0) {
    exe[n] = 0;
    char *slash;
    for (int up = 0; up < 4 && (slash = strrchr(exe, '/')) != NULL; up++) {
      *slash = 0;
      if (!exe[0]) break;
      if (is_data_dir(exe)) {
        snprintf(found, sizeof found, "%s", exe);
        return found;
      }
      char share[PATH_MAX];
      if (snprintf(share, sizeof share, "%s/share/hairfilter", exe) < (int)sizeof share &&
          is_data_dir(share)) {
        snprintf(found, sizeof found, "%s", share);
        return found;
      }
    }
  }
  return HF_SOURCE_DIR;
}

int cli_open_backend(const char *name, hf_backend **out) {
  char why[512];
  int rc = hf_backend_create(name, out, why, sizeof why);
  if (rc) {
    fprintf(stderr, "hairfilter: backend '%s': %s (%s)\n", name, why, hf_strerror(rc));
    return rc;
  }
  fprintf(stderr, "hairfilter: using %s\n", why[0] ? why : hf_backend_name(*out));
  return 0;
}

int cli_write_preview(const char *path, const float *result, int w, int h,
                      const hf_image *layer, const float hair[3], const float light[3],
                      const float bg[3]) {
  float *rgb = malloc((size_t)w * h * 3 * sizeof(float));
  if (!rgb) return HF_ENOMEM;
#ifdef HF_HAVE_RENDERER
  hfr_composite_result(result, w, h, layer, hair, light, bg, rgb);
#else
  (void)layer;  /* built without the renderer: over bg alone */
  hf_composite(result, w, h, hair, light, bg, rgb);
#endif
  int rc = hf_png_write_rgb(path, rgb, w, h);
  free(rgb);
  return rc;
}

int cli_input_range_check(const hf_input_range *r, const void *in, hf_dtype dtype, int w, int h,
                          int spp, hf_input_stats *st) {
  memset(st, 0, sizeof *st);
  if (!r->present) return 0;
  int rc = hf_input_stats_compute(in, dtype, w, h, spp, st);
  return rc ? rc : (int)hf_input_range_check(r, st);
}

void cli_warn_lossy(const char *prog, const char *path, const hf_image *img) {
  if (img->lossy)
    fprintf(stderr, "%s: warning: %s is compressed with %s, which is lossy: its samples (alpha, "
            "depth, tangents) are not those the renderer wrote; write feature files with ZIP "
            "or PIZ, e.g. oiiotool %s --compression zip -o lossless.exr\n", prog, path,
            img->lossy, path);
}

void cli_warn_input_range(const char *prog, const char *frame, const char *variant,
                          const hf_input_range *r, const hf_input_stats *st, unsigned mask) {
  char why[512];
  hf_input_range_describe(r, st, mask, why, sizeof why);
  fprintf(stderr, "%s: warning: %s is outside the input range %s was trained on: %s\n", prog,
          frame, variant, why);
}

/* The four background.R/G/B/A channels of img (values in data, of dtype) as
 * a float32 image of their own; layer stays zeroed when one is missing. */
static int read_layer(const char *path, const hf_image *img, const void *data, hf_dtype dtype,
                      hf_image *layer) {
  int ch[4];
  for (int k = 0; k < 4; k++) {
    char name[32];
    snprintf(name, sizeof name, "background.%c", "RGBA"[k]);
    if ((ch[k] = hf_image_channel(img, name)) < 0) return HF_OK;
  }
  int rc = hf_image_alloc(layer, img->width, img->height, 4);
  if (rc) return rc;
  for (int k = 0; k < 4; k++) snprintf(layer->names[k], sizeof layer->names[k], "background.%c",
                                       "RGBA"[k]);
  size_t px = (size_t)img->width * img->height, bad = 0, first = 0;
  int first_k = 0;
  float first_v = 0;
  for (size_t i = 0; i < px; i++) {
    int ok = 1;
    for (int k = 0; k < 4; k++) {
      size_t at = i * (size_t)img->channels + (size_t)ch[k];
      float v = dtype == HF_F16 ? hf_f16_to_f32(((const uint16_t *)data)[at])
                                : ((const float *)data)[at];
      layer->data[i * 4 + k] = v;
      if (ok && !isfinite(v)) {
        ok = 0;
        if (!bad) first = i, first_k = k, first_v = v;
      }
    }
    /* A damaged layer pixel would composite to NaN, which a PNG shows as
     * black: it is left out (transparent), so the background colour shows,
     * and said. */
    if (!ok) {
      bad++;
      for (int k = 0; k < 4; k++) layer->data[i * 4 + k] = 0;
    }
  }
  if (bad)
    fprintf(stderr, "hairfilter: warning: %s: its background layer has %zu pixel%s with a "
            "value that is not finite, the first at pixel (%lld, %lld): background.%c = %g; "
            "a preview (--png) shows the background colour there\n", path, bad, bad == 1 ? "" : "s",
            (long long)img->origin_x + (long long)(first % (size_t)img->width),
            (long long)img->origin_y + (long long)(first / (size_t)img->width), "RGBA"[first_k],
            (double)first_v);
  return HF_OK;
}

int cli_read_features(const char *path, const char *part, int spp, int estimate,
                      const char *variant, hf_dtype dtype, hf_image *img, void **in,
                      hf_image *layer) {
  char err[512];
  void *data = NULL;
  *in = NULL;
  if (layer) memset(layer, 0, sizeof *layer);
  int rc = hf_exr_read_part_as(path, part, "S0.color", dtype, img, &data, err, sizeof err);
  if (rc) {
    fprintf(stderr, "hairfilter: %s\n", err);
    return rc;
  }
  cli_warn_lossy("hairfilter", path, img);
  if (cli_refuse_uint("hairfilter", path, img)) {
    rc = HF_EFORMAT;
    goto fail;
  }
  int have = hf_features_spp(img);
  if (have < 0) {
    /* Compositing tools put a file's channels under a layer
     * ("beauty.S0.color"): said as such, not as another kind of file. */
    static const char tail[] = ".S0.color";
    const size_t nt = sizeof tail - 1;
    for (int c = 0; c < img->channels; c++) {
      size_t n = strlen(img->names[c]);
      if (n > nt && !strcmp(img->names[c] + n - nt, tail)) {
        fprintf(stderr, "hairfilter: %s: no channel S0.color, but %s: the features are under "
                "layer \"%.*s\", and are read only without one (S0.color, S0.highlight, ..., "
                "protocol/FEATURES.md); write or rename the channels without the layer\n", path,
                img->names[c], (int)(n - nt), img->names[c]);
        rc = HF_EFORMAT;
        goto fail;
      }
    }
    fprintf(stderr, "hairfilter: %s: no channel S0.color: not a feature file "
            "(protocol/FEATURES.md names the channels)\n", path);
    rc = HF_EFORMAT;
    goto fail;
  }
  if (have < spp) {
    /* Sample `have` lacks its colour but has other features: a channel
     * missing, not a frame of fewer samples. */
    char next[16];
    snprintf(next, sizeof next, "S%d.", have);
    for (int c = 0; c < img->channels; c++)
      if (!strncmp(img->names[c], next, strlen(next))) {
        fprintf(stderr, "hairfilter: %s: no channel S%d.color, though it has %s: sample %d lacks "
                "its color feature (protocol/FEATURES.md; the sample count is the number of "
                "consecutive S{k}.color channels from S0)\n", path, have, img->names[c], have);
        rc = HF_EFORMAT;
        goto fail;
      }
    fprintf(stderr, "hairfilter: %s has %d sample%s per pixel (S0.color..S%d.color), "
            "variant %s needs %d: render the frame with --spp %d (or more), or filter it "
            "with %s\n", path, have, have == 1 ? "" : "s", have - 1, variant, spp, spp,
            have >= 2 ? "Base@2spp, which reads 2 (--variant Base@2spp from a server, "
                        "--weights weights/base_2spp.safetensors for infer)"
                      : "Base@1spp, which reads 1 (--variant Base@1spp from a server, "
                        "--weights weights/base_1spp.safetensors for infer)");
    rc = HF_EFORMAT;
    goto fail;
  }
  for (int k = 0; k < spp; k++)
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++) {
      char name[32];
      snprintf(name, sizeof name, "S%d.%s", k, HF_FEATURE_NAMES[f]);
      if (hf_image_channel(img, name) < 0) {
        fprintf(stderr, "hairfilter: %s: no channel %s: sample %d lacks its %s feature "
                "(protocol/FEATURES.md)\n", path, name, k, HF_FEATURE_NAMES[f]);
        rc = HF_EFORMAT;
        goto fail;
      }
    }
  for (int c = 0; estimate && c < HF_ESTIMATE_CHANNELS; c++) {
    char name[32];
    snprintf(name, sizeof name, "%s.%s", HF_ESTIMATE_PREFIX, HF_OUTPUT_NAMES[c]);
    if (hf_image_channel(img, name) < 0) {
      fprintf(stderr, "hairfilter: %s: no channel %s: variant %s reads stochastic "
              "transparency's alpha-corrected estimate beside the samples; `hairfilter render` "
              "writes it unless given --no-alpha-corrected (protocol/FEATURES.md, \"The "
              "alpha-corrected estimate\"), or filter the frame with a variant that reads the "
              "samples alone (Kernel: --variant Kernel from a server, --weights "
              "weights/kernel.safetensors for infer)\n", path, name, variant);
      rc = HF_EFORMAT;
      goto fail;
    }
  }
  const size_t px = (size_t)img->width * img->height;
  const size_t esz = dtype == HF_F16 ? sizeof(uint16_t) : sizeof(float);
  if (!(*in = malloc(px * hf_net_in_channels(spp, estimate) * esz))) {
    fprintf(stderr, "hairfilter: %s: out of memory for a %dx%d frame\n", path, img->width,
            img->height);
    rc = HF_ENOMEM;
    goto fail;
  }
  hf_features_from_data(img, data, dtype, spp, *in);
  /* A frame with an estimate is planar: the samples, then the estimate. */
  if (estimate)
    hf_estimate_from_data(img, data, dtype, (uint8_t *)*in + px * spp * HF_FEATURES_PER_SAMPLE * esz);
  if (layer && (rc = read_layer(path, img, data, dtype, layer)) != 0) {
    fprintf(stderr, "hairfilter: %s: its background layer: %s\n", path, hf_strerror(rc));
    free(*in);
    *in = NULL;
    goto fail;
  }
  free(data);
  return HF_OK;
fail:
  free(data);
  hf_image_free(img);
  return rc;
}

/* Whether name is "<letters><digits>." + something, letters being prefix. */
static int numbered(const char *name, const char *prefix) {
  size_t n = strlen(prefix);
  if (strncmp(name, prefix, n) || !isdigit((unsigned char)name[n])) return 0;
  for (name += n; isdigit((unsigned char)*name);) name++;
  return *name == '.';
}

int cli_refuse_uint(const char *prog, const char *path, const hf_image *img) {
  for (int c = 0; img->uint_stored && c < img->channels; c++) {
    const char *n = img->names[c];
    if (img->uint_stored[c] && (numbered(n, "S") || numbered(n, "st") || !strncmp(n, "gt.", 3) ||
                                !strncmp(n, HF_ESTIMATE_PREFIX ".", strlen(HF_ESTIMATE_PREFIX) + 1))) {
      fprintf(stderr, "%s: %s: channel %s is stored as UINT (32-bit unsigned integers), which "
              "would be read as its integer values; the channels protocol/FEATURES.md names are "
              "HALF or FLOAT: write them as float, e.g. oiiotool %s -d float -o float.exr\n",
              prog, path, n, path);
      return 1;
    }
  }
  return 0;
}

void cli_warn_sanitised(const char *path, const hf_image *img, const hf_input_report *r) {
  if (r->samples) {
    char ch[40], what[160];
    /* The estimate has a rule of its own (protocol/FEATURES.md, "The
     * alpha-corrected estimate"): a fault makes the pixel's estimate 0. */
    const int est = r->sample == HF_REPORT_ESTIMATE;
    const char *gone = est ? "the pixel's estimate becomes 0 (no hair)"
                           : "the sample counts as uncovered";
    if (est)
      snprintf(ch, sizeof ch, "%s.%s", HF_ESTIMATE_PREFIX, HF_OUTPUT_NAMES[r->feature]);
    else
      snprintf(ch, sizeof ch, "S%d.%s", r->sample, HF_FEATURE_NAMES[r->feature]);
    if (r->kind == HF_SANITISED_NONFINITE)
      snprintf(what, sizeof what, "%s = %g is not finite: %s", ch, r->value, gone);
    else if (r->kind == HF_SANITISED_UNCOVERED)
      snprintf(what, sizeof what, "%s = %g is not above 0 in %s that is not all zero: %s", ch,
               r->value, est ? "an estimate" : "a sample", gone);
    else
      snprintf(what, sizeof what, "%s = %g is out of range: clamped", ch, r->value);
    /* "First" in the frame's memory order: every sample before any
     * estimate, which follows the samples (protocol/FEATURES.md). */
    fprintf(stderr, "hairfilter: warning: %s: %" PRIu64 " sample%s sanitised (protocol/"
            "FEATURES.md, \"Out-of-contract values\"), the first at pixel (%d, %d): %s\n",
            path, r->samples, r->samples == 1 ? "" : "s", img->origin_x + r->x,
            img->origin_y + r->y, what);
  }
  if (r->outputs)
    fprintf(stderr, "hairfilter: warning: %s: %" PRIu64 " result pixel%s out of range, "
            "clamped (protocol/FEATURES.md, \"Out-of-contract values\")\n", path, r->outputs,
            r->outputs == 1 ? "" : "s");
}

void cli_connect_failed(const char *prog, int rc) {
  const char *m = hfc_last_message(NULL);
  /* The message starts with the endpoint (or names the option); the code's
   * words would only repeat it. */
  fprintf(stderr, "%s: %s\n", prog, m[0] ? m : hfc_strerror(rc));
  /* The server says "wrong token" when one was given, "needs a token" when
   * none was. */
  if (rc == HFC_E_UNAUTHORIZED && strstr(m, "wrong token"))
    fprintf(stderr, "%s: the token given is not the server's: compare --token or "
            "$HAIRFILTER_TOKEN with the server's --auth-token-file\n", prog);
  else if (rc == HFC_E_UNAUTHORIZED)
    fprintf(stderr, "%s: give the server's token with --token TOKEN or $HAIRFILTER_TOKEN\n",
            prog);
}
