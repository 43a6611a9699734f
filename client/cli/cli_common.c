#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli_common.h"

const float CLI_HAIR_DEFAULT[3] = {0.45f, 0.25f, 0.12f};
const float CLI_LIGHT_DEFAULT[3] = {1.0f, 1.0f, 1.0f};
const float CLI_BG_DEFAULT[3] = {0.18f, 0.2f, 0.24f};

int cli_parse_rgb(const char *s, float rgb[3]) {
  char tail;
  return sscanf(s, "%f,%f,%f%c", &rgb[0], &rgb[1], &rgb[2], &tail) == 3 ? 0 : -1;
}

int cli_parse_size(const char *s, int *w, int *h) {
  char tail;
  if (sscanf(s, "%dx%d%c", w, h, &tail) != 2 || *w < 1 || *h < 1) return -1;
  return 0;
}

const char *cli_data_dir(void) {
  const char *env = getenv("HAIRFILTER_DATA");
  return env && *env ? env : HF_SOURCE_DIR;
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

int cli_write_preview(const char *path, const float *result, int w, int h, const float hair[3],
                      const float light[3], const float bg[3]) {
  float *rgb = malloc((size_t)w * h * 3 * sizeof(float));
  if (!rgb) return HF_ENOMEM;
  hf_composite(result, w, h, hair, light, bg, rgb);
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

void cli_warn_input_range(const char *prog, const char *frame, const char *variant,
                          const hf_input_range *r, const hf_input_stats *st, unsigned mask) {
  char why[512];
  hf_input_range_describe(r, st, mask, why, sizeof why);
  fprintf(stderr, "%s: warning: %s is outside the input range %s was trained on: %s\n", prog,
          frame, variant, why);
}
