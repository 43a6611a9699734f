/* The C side of tests/train/test_input_stats.py: what src/ computes, printed
 * as JSON for the Python twin (weights/input_stats.py) to be compared with.
 *
 *   input_stats_dump stats FRAME.exr SPP     hf_input_stats of the first SPP samples
 *   input_stats_dump range W.safetensors     the weights' input_range ("null": none)
 *   input_stats_dump check W.safetensors FRAME.exr
 *                                            mask of statistics outside the range
 *   input_stats_dump weights OUT.safetensors random Small weights (seed 5)
 *   input_stats_dump sanitise FRAME.exr SPP OUT
 *                                            the first SPP samples as the network sees
 *                                            them (hf_features_sanitise), raw float32 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"

static int frame_stats(const char *path, int spp, hf_input_stats *st) {
  char err[512];
  hf_image img = {0};
  if (hf_exr_read(path, &img, err, sizeof err)) {
    fprintf(stderr, "input_stats_dump: %s\n", err);
    return 1;
  }
  float *in = malloc((size_t)img.width * img.height * spp * HF_FEATURES_PER_SAMPLE * sizeof(float));
  int rc = !in || hf_features_from_image(&img, spp, in) < 0 ||
           hf_input_stats_compute(in, HF_F32, img.width, img.height, spp, st);
  if (rc) fprintf(stderr, "input_stats_dump: %s: no %d-spp features\n", path, spp);
  free(in);
  hf_image_free(&img);
  return rc;
}

/* The first spp samples of the frame at path, sanitised, into the file out
 * as [height][width][spp][6] float32: what the network sees. */
static int sanitised(const char *path, int spp, const char *out) {
  char err[512];
  hf_image img = {0};
  if (spp < 1 || spp > HF_MAX_SPP || hf_exr_read(path, &img, err, sizeof err)) {
    fprintf(stderr, "input_stats_dump: %s: %s\n", path, spp < 1 || spp > HF_MAX_SPP ? "spp" : err);
    return 1;
  }
  size_t n = (size_t)img.width * img.height * spp * HF_FEATURES_PER_SAMPLE;
  float *in = malloc(n * sizeof(float));
  hf_input_report rep;
  FILE *f = NULL;
  int rc = !in || hf_features_from_image(&img, spp, in) < 0;
  if (!rc) {
    hf_features_sanitise(in, HF_F32, img.width, img.height, spp, &rep);
    rc = !(f = fopen(out, "wb")) || fwrite(in, sizeof(float), n, f) != n;
    if (f && fclose(f)) rc = 1;
  }
  if (rc) fprintf(stderr, "input_stats_dump: %s: cannot sanitise into %s\n", path, out);
  free(in);
  hf_image_free(&img);
  return rc;
}

static hf_weights *load(const char *path) {
  char err[512];
  hf_weights *w = NULL;
  if (hf_weights_load(path, &w, err, sizeof err)) fprintf(stderr, "input_stats_dump: %s\n", err);
  return w;
}

int main(int argc, char **argv) {
  if (argc == 4 && !strcmp(argv[1], "stats")) {
    hf_input_stats st;
    if (frame_stats(argv[2], atoi(argv[3]), &st)) return 1;
    printf("{\"hair_pixels\": %llu, \"full_pixels\": %llu", (unsigned long long)st.hair_pixels,
           (unsigned long long)st.full_pixels);
    for (int k = 0; k < HF_STAT_COUNT; k++) {
      if (isnan(st.value[k])) printf(", \"%s\": null", hf_input_stat_name(k));
      else printf(", \"%s\": %.17g", hf_input_stat_name(k), st.value[k]);
    }
    printf("}\n");
    return 0;
  }
  if (argc == 3 && !strcmp(argv[1], "range")) {
    hf_weights *w = load(argv[2]);
    if (!w) return 1;
    char *text = hf_input_range_to_json(&w->input_range);
    printf("%s\n", text ? text : "null");
    free(text);
    hf_weights_free(w);
    return 0;
  }
  if (argc == 4 && !strcmp(argv[1], "check")) {
    hf_weights *w = load(argv[2]);
    hf_input_stats st;
    if (!w || frame_stats(argv[3], w->cfg.spp, &st)) return 1;
    printf("%u\n", hf_input_range_check(&w->input_range, &st));
    hf_weights_free(w);
    return 0;
  }
  if (argc == 3 && !strcmp(argv[1], "weights")) {
    hf_net_config cfg;
    hf_weights *w = NULL;
    int rc = hf_variant_preset("Small", &cfg) || hf_weights_init_random(&cfg, 5, &w) ||
             hf_weights_save(argv[2], w);
    hf_weights_free(w);
    return rc ? 1 : 0;
  }
  if (argc == 5 && !strcmp(argv[1], "sanitise")) return sanitised(argv[2], atoi(argv[3]), argv[4]);
  fprintf(stderr, "usage: input_stats_dump stats FRAME.exr SPP | range W | check W FRAME.exr | "
                  "weights OUT | sanitise FRAME.exr SPP OUT\n");
  return 2;
}
