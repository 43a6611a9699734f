/* Writes the fuzz targets' seed corpora (tests/fuzz/corpus/<target>/):
 * small valid inputs of every kind each parser reads, made by the project's
 * own writers so that they are valid by construction, from which libFuzzer
 * mutates. EXR files of layouts hf_exr_write does not make (tiled, other
 * compressions, several parts) come from tests/fuzz/make_exr_seeds.py.
 *
 *   build/tests/fuzz/fuzz_make_corpus tests/fuzz/corpus */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "hfcore.h"
#include "hfproto.h"
#include "hfrender.h"

static const char *root;

static void put(const char *target, const char *name, const void *b, size_t n) {
  char path[512];
  snprintf(path, sizeof path, "%s/%s", root, target);
  if (mkdir(path, 0755) && errno != EEXIST) exit(1);
  snprintf(path, sizeof path, "%s/%s/%s", root, target, name);
  FILE *f = fopen(path, "wb");
  if (!f || fwrite(b, 1, n, f) != n || fclose(f)) {
    fprintf(stderr, "make_corpus: cannot write %s\n", path);
    exit(1);
  }
}

static void frame(const char *name, int n, const uint8_t *b) {
  if (n <= 0) {
    fprintf(stderr, "make_corpus: cannot encode %s: %s\n", name, hfp_strerror(n));
    exit(1);
  }
  put("protocol", name, b, (size_t)n);
}

static void protocol(void) {
  static uint8_t b[1 << 16];
  hfp_hello hello = {1, 2, "engine", "s3cret"};
  frame("hello", hfp_encode_hello(b, sizeof b, &hello), b);
  hfp_hello hello1 = {1, 1, "old-engine", ""};
  frame("hello_v1", hfp_encode_hello(b, sizeof b, &hello1), b);
  hfp_hello_ok ok = {2, 3, 1768, 1768, 4, 32, 3, 4, 64, 1u << 30, "hairfilterd", "0.1.0"};
  frame("hello_ok", hfp_encode_hello_ok(b, sizeof b, &ok), b);
  frame("list_variants", hfp_encode_empty(b, sizeof b, HFP_LIST_VARIANTS, 0), b);
  frame("stats", hfp_encode_empty(b, sizeof b, HFP_STATS, 0), b);
  hfp_variant v[2] = {
    {"Base", "cpu", "fp32", 4, 3, {32, 64, 128}, 2, {{0, 0.01, 0.3}, {4, 16, 2048}}, 0},
    {"KernelAC", "cudnn", "fp16", 4, 3, {32, 64, 128}, 0, {{0, 0, 0}},
     HFP_ESTIMATE_ALPHA_CORRECTED},
  };
  frame("variants_v1", hfp_encode_variants_v(b, sizeof b, v, 2, 1), b);
  frame("variants_v2", hfp_encode_variants_v(b, sizeof b, v, 2, 2), b);
  frame("variants_v3", hfp_encode_variants_v(b, sizeof b, v, 2, 3), b);
  static float feat[3 * 2 * 4 * 6];
  for (size_t i = 0; i < sizeof feat / sizeof feat[0]; i++) feat[i] = (float)(i % 7) / 7;
  hfp_filter f = {"Base", 0, 3, 2, 4, HFP_F32, HFP_F32, {0.5f, 0.4f, 0.3f}, {1, 1, 1},
                  {0.1f, 0.1f, 0.1f}, feat, sizeof feat, 0, 0, 0, 0, 0};
  uint64_t total;
  int n = hfp_encode_filter_head(b, sizeof b, 9, &f, &total);
  if (n > 0) memcpy(b + n, feat, sizeof feat), n = (int)total;
  frame("filter", n, b);
  f.flags = HFP_FILTER_COMPOSITE;
  f.in_dtype = HFP_F16;
  f.out_dtype = HFP_F16;
  f.data_len = sizeof feat / 2;
  n = hfp_encode_filter_head(b, sizeof b, 10, &f, &total);
  if (n > 0) memcpy(b + n, feat, sizeof feat / 2), n = (int)total;
  frame("filter_f16_composite", n, b);
  f.flags = HFP_FILTER_SHM | HFP_FILTER_COMPOSITE;
  f.shm_segment = 1, f.shm_in = 0, f.shm_out = 4096, f.shm_rgba = 8192;
  frame("filter_shm", hfp_encode_filter_head(b, sizeof b, 11, &f, NULL), b);
  /* Version 4: a budget after the variant name, before a shared-memory
   * reference or the inline tensors. */
  f.flags |= HFP_FILTER_DEADLINE;
  f.budget_us = 16000;
  frame("filter_shm_deadline", hfp_encode_filter_head(b, sizeof b, 14, &f, NULL), b);
  f.flags = HFP_FILTER_DEADLINE;
  f.in_dtype = f.out_dtype = HFP_F32;
  f.data_len = sizeof feat;
  f.shm_segment = 0, f.shm_out = 0, f.shm_rgba = 0;
  n = hfp_encode_filter_head(b, sizeof b, 15, &f, &total);
  if (n > 0) memcpy(b + n, feat, sizeof feat), n = (int)total;
  frame("filter_deadline", n, b);
  frame("cancel", hfp_encode_empty(b, sizeof b, HFP_CANCEL, 15), b);
  /* Version 3: the estimate after the features (3 x 2 pixels, 3 values). */
  static float feat_est[3 * 2 * (4 * 6 + 3)];
  for (size_t i = 0; i < sizeof feat_est / sizeof feat_est[0]; i++) feat_est[i] = (float)(i % 5) / 5;
  hfp_filter fe = {"KernelAC", HFP_FILTER_ESTIMATE, 3, 2, 4, HFP_F32, HFP_F32, {0.5f, 0.4f, 0.3f},
                   {1, 1, 1}, {0.1f, 0.1f, 0.1f}, feat_est, sizeof feat_est, 0, 0, 0, 0, 0};
  n = hfp_encode_filter_head(b, sizeof b, 13, &fe, &total);
  if (n > 0) memcpy(b + n, feat_est, sizeof feat_est), n = (int)total;
  frame("filter_estimate", n, b);
  static float res[3 * 2 * 4];
  hfp_result r = {0, HFP_F32, HFP_FILTER_COMPOSITE | HFP_RESULT_INPUT_SANITISED, 3, 2, 2,
                  {10, 20, 3000, 40, 3200}, res, 3 * 2 * 3 * 4, res, 3 * 2 * 4 * 4};
  n = hfp_encode_result_head(b, sizeof b, 9, &r, &total);
  if (n > 0) memcpy(b + n, res, (size_t)(total - (uint64_t)n)), n = (int)total;
  frame("result_composite", n, b);
  hfp_result rs = {0, HFP_F16, HFP_FILTER_SHM, 3, 2, 1, {1, 2, 3, 4, 12}, NULL, 0, NULL, 0};
  frame("result_shm", hfp_encode_result_head(b, sizeof b, 11, &rs, NULL), b);
  hfp_result rf = {HFP_E_SHUTTING_DOWN, 0, 0, 0, 0, 0, {0, 0, 0, 0, 5}, NULL, 0, NULL, 0};
  frame("result_status", hfp_encode_result_head(b, sizeof b, 12, &rf, NULL), b);
  hfp_error e = {HFP_E_PROTOCOL, 1, "no complete HELLO within 10000 ms"};
  frame("error_fatal", hfp_encode_error(b, sizeof b, 0, &e), b);
  static hfp_stats st;
  st.uptime_us = 123456789;
  st.connections_total = 40;
  st.connections_open = 2;
  st.queue_capacity = 64;
  st.num_variants = 2;
  strcpy(st.variants[0].name, "Base");
  strcpy(st.variants[1].name, "Small");
  st.variants[0].requests_ok = 7;
  st.variants[0].hist_total[9] = 7;
  st.variants[0].frames_sanitised = 1;
  frame("stats_reply_v1", hfp_encode_stats_v(b, sizeof b, &st, 1), b);
  frame("stats_reply_v2", hfp_encode_stats_v(b, sizeof b, &st, 2), b);
  st.variants[0].cancelled = 2;
  frame("stats_reply_v4", hfp_encode_stats_v(b, sizeof b, &st, 4), b);
  frame("shm_create", hfp_encode_shm_create(b, sizeof b, 1 << 20), b);
  frame("shm_created", hfp_encode_shm_created(b, sizeof b, 1, 1 << 20), b);
  frame("shm_destroy", hfp_encode_shm_destroy(b, sizeof b, 1), b);
}

static void weights(void) {
  /* Tiny networks of each architecture (Kernel with and without its head),
   * with and without a trained range. */
  static const struct {
    const char *file;
    int spp, arch, L, levels[3];
    const char *range;
    int kernel_radius, kernel_hidden;
  } w[] = {
    {"unet_1level", 1, HF_ARCH_UNET, 1, {4}, NULL, 0, 0},
    {"unet_2level", 2, HF_ARCH_UNET, 2, {4, 8}, NULL, 0, 0},
    {"residual", 1, HF_ARCH_RESIDUAL, 2, {4, 4}, NULL, 0, 0},
    {"with_range", 4, HF_ARCH_UNET, 1, {2},
     "{\"definition\": 1, \"spp\": 4, \"frames\": 3, \"strand_alpha_p50\": [0.1, 0.2]}",
     0, 0},
    {"kernel_head", 1, HF_ARCH_KERNEL, 1, {4}, NULL, 1, 4},
    {"kernel_no_head", 1, HF_ARCH_KERNEL, 1, {4}, NULL, 1, 0},
  };
  char tmp[] = "/tmp/make_corpus_XXXXXX";
  int fd = mkstemp(tmp);
  if (fd < 0) exit(1);
  for (size_t i = 0; i < sizeof w / sizeof w[0]; i++) {
    hf_net_config c;
    memset(&c, 0, sizeof c);
    snprintf(c.name, sizeof c.name, "Fuzz%zu", i);
    c.spp = w[i].spp;
    c.in_channels = c.spp * HF_FEATURES_PER_SAMPLE;
    c.num_levels = w[i].L;
    c.arch = w[i].arch;
    c.kernel_radius = w[i].kernel_radius;
    c.kernel_hidden = w[i].kernel_hidden;
    c.out_channels = HF_OUT_CHANNELS + (c.arch == HF_ARCH_KERNEL ? hf_kernel_taps(c.kernel_radius) : 0);
    for (int l = 0; l < c.num_levels; l++) c.levels[l] = w[i].levels[l];
    hf_weights *wt;
    if (hf_net_config_validate(&c) || hf_weights_init_random(&c, 7 + i, &wt)) exit(1);
    if (w[i].range && hf_input_range_parse(w[i].range, c.spp, &wt->input_range, NULL, 0)) exit(1);
    if (hf_weights_save(tmp, wt)) exit(1);
    hf_weights_free(wt);
    FILE *f = fopen(tmp, "rb");
    static uint8_t buf[1 << 20];
    size_t n = f ? fread(buf, 1, sizeof buf, f) : 0;
    if (f) fclose(f);
    put("weights", w[i].file, buf, n);
  }
  remove(tmp);
}

static void hair(void) {
  char tmp[] = "/tmp/make_corpus_XXXXXX";
  int fd = mkstemp(tmp);
  if (fd < 0) exit(1);
  static float pos[3 * 9], thick[9], trans[9], col[3 * 9];
  static uint16_t seg[3] = {2, 3, 1};
  for (int i = 0; i < 27; i++) pos[i] = (float)i * 0.1f, col[i] = 0.5f;
  for (int i = 0; i < 9; i++) thick[i] = 0.01f, trans[i] = 0.2f;
  hfr_hair all = {.strands = 3, .points = 9, .segments = seg, .pos = pos, .thickness = thick,
                  .transparency = trans, .color = col, .default_thickness = 0.02f,
                  .default_transparency = 0.1f, .default_color = {0.3f, 0.2f, 0.1f},
                  .info = "all arrays"};
  hfr_hair plain = {.strands = 3, .points = 9, .pos = pos, .default_segments = 2,
                    .default_thickness = 0.02f, .info = "default segments"};
  const struct {
    const char *name;
    const hfr_hair *h;
  } m[] = {{"all_arrays", &all}, {"points_only", &plain}};
  for (size_t i = 0; i < 2; i++) {
    if (hfr_hair_save(tmp, m[i].h)) exit(1);
    FILE *f = fopen(tmp, "rb");
    static uint8_t buf[4096];
    size_t n = f ? fread(buf, 1, sizeof buf, f) : 0;
    if (f) fclose(f);
    put("hair", m[i].name, buf, n);
  }
  remove(tmp);
}

static void exr(void) {
  /* A 3x2 feature frame of 2 samples, float and half (ZIP, scanlines). */
  hf_image img;
  static float in[3 * 2 * 2 * 6];
  for (size_t i = 0; i < sizeof in / sizeof in[0]; i++) in[i] = (float)(i % 9) / 9;
  if (hf_features_to_image(in, 3, 2, 2, &img)) exit(1);
  char tmp[64];
  snprintf(tmp, sizeof tmp, "/tmp/make_corpus_%d.exr", (int)getpid());
  for (int half = 0; half < 2; half++) {
    if (hf_exr_write(tmp, &img, half)) exit(1);
    FILE *f = fopen(tmp, "rb");
    static uint8_t buf[1 << 16];
    size_t n = f ? fread(buf, 1, sizeof buf, f) : 0;
    if (f) fclose(f);
    put("exr", half ? "features_half_zip" : "features_float_zip", buf, n);
  }
  remove(tmp);
  hf_image_free(&img);
}

int main(int argc, char **argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: fuzz_make_corpus CORPUS_DIR\n");
    return 2;
  }
  root = argv[1];
  mkdir(root, 0755);
  protocol();
  weights();
  hair();
  exr();
  return 0;
}
