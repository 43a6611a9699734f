/* hairfilterd serves the Kernel architecture with no change of its own: it
 * loads any weights file through the core. A Kernel weights file (the
 * preset's shape, random weights) beside the harness's variants is listed
 * and filters frames, f32 and f16, over the socket and shared memory,
 * to exactly the bytes in-process cpu-ref gives. So does a KernelAC one,
 * which reads the alpha-corrected estimate (protocol version 3): VARIANTS
 * says so, its frames carry the estimate after the features or from a
 * buffer of its own, and a frame without it (or one with it for Kernel) is
 * refused, naming the flag. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "harness.h"

static harness H;
static server S;
static hf_model *kernel_ref;   /* cpu-ref, in process, on the same weights */
static hf_model *ac_ref;       /* the same for KernelAC */

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  /* Kept out of the harness's weights directory so the other suites'
   * servers do not see it. */
  char dir[256], path[300];
  snprintf(dir, sizeof dir, "%s/kernel", H.dir);
  if (mkdir(dir, 0700)) return -1;
  snprintf(path, sizeof path, "%s/Kernel.safetensors", dir);
  hf_net_config cfg;
  hf_weights *w = NULL;
  if (hf_variant_preset("Kernel", &cfg) || hf_weights_init_random(&cfg, 31, &w)) return -1;
  int rc = hf_weights_save(path, w) || hf_model_create(H.backend, w, &kernel_ref);
  hf_weights_free(w);
  if (rc) return -1;
  char ac_path[300];
  snprintf(ac_path, sizeof ac_path, "%s/KernelAC.safetensors", dir);
  if (hf_variant_preset("KernelAC", &cfg) || hf_weights_init_random(&cfg, 32, &w)) return -1;
  rc = hf_weights_save(ac_path, w) || hf_model_create(H.backend, w, &ac_ref);
  hf_weights_free(w);
  if (rc) return -1;
  const char *const extra[] = {"--weights", path, "--weights", ac_path, NULL};
  return server_start(&H, &S, extra);
}

static int teardown(void **state) {
  (void)state;
  hf_model_destroy(kernel_ref);
  hf_model_destroy(ac_ref);
  return harness_stop(&H, &S);
}

/* Features with hair-free stretches: the make_features frame with every
 * sample of the left 8 columns and every third sample elsewhere uncovered. */
static float *kernel_frame(int w, int h, uint32_t seed) {
  float *in = make_features(w, h, 4, seed);
  assert_non_null(in);
  for (int p = 0; p < w * h; p++)
    for (int k = 0; k < 4; k++)
      if (p % w < 8 || (p + k) % 3 == 0) memset(in + ((size_t)p * 4 + k) * 6, 0, 6 * sizeof(float));
  return in;
}

/* KernelAC's frame: kernel_frame's samples, then an estimate ([h][w][3]) with
 * no hair in the left 8 columns. */
static float *ac_frame(int w, int h, uint32_t seed) {
  float *s = kernel_frame(w, h, seed), *in = malloc((size_t)w * h * 27 * sizeof(float));
  assert_non_null(in);
  memcpy(in, s, (size_t)w * h * 24 * sizeof(float));
  float *e = in + (size_t)w * h * 24;
  for (int p = 0; p < w * h; p++) {
    int hair = p % w >= 8;
    e[p * 3] = hair ? 0.3f + 0.5f * (float)((p * 7) % 11) / 11 : 0;
    e[p * 3 + 1] = hair ? 0.2f * (float)((p * 5) % 7) / 7 : 0;
    e[p * 3 + 2] = hair ? 0.1f + 0.9f * (float)((p * 3) % 13) / 13 : 0;
  }
  free(s);
  return in;
}

/* One frame through the daemon as variant (into shm when not NULL) against
 * cpu-ref's ref on the same weights: kernel_frame's, and for a variant
 * that reads the estimate ac_frame's with the estimate sent. */
static void filter_and_compare(hfc_client *c, const char *variant, hf_model *ref, int w, int h,
                               int f16, uint8_t *shm) {
  const int estimate = hf_model_config(ref)->estimate != HF_ESTIMATE_NONE;
  size_t n_in = (size_t)w * h * hf_model_config(ref)->in_channels, n_out = (size_t)w * h * 3;
  size_t es = f16 ? 2 : 4;
  uint32_t seed = (uint32_t)(w * 31 + h + f16);
  float *in = estimate ? ac_frame(w, h, seed) : kernel_frame(w, h, seed);
  uint8_t *send = shm ? shm : malloc(n_in * es);
  uint8_t *got = shm ? shm + n_in * es : malloc(n_out * es), *want = malloc(n_out * es);
  assert_non_null(send);
  assert_non_null(got);
  assert_non_null(want);
  for (size_t i = 0; i < n_in; i++) {
    if (f16) ((uint16_t *)send)[i] = hf_f32_to_f16(in[i]);
    else ((float *)send)[i] = in[i];
  }
  memset(got, 0xcd, n_out * es);
  hfc_request r = TEST_REQUEST(.variant = variant, .width = w, .height = h, .spp = 4,
                                .in_dtype = f16 ? HFC_F16 : HFC_F32, .features = send,
                                .out_dtype = f16 ? HFC_F16 : HFC_F32, .result = got,
                                .estimate = estimate);
  assert_int_equal(r.features_bytes, n_in * es);
  hfc_timing t;
  int rc = hfc_filter(c, &r, &t);
  if (rc) fprintf(stderr, "filter %s %dx%d: %s (%s)\n", variant, w, h, hfc_strerror(rc),
                  hfc_last_message(c));
  assert_int_equal(rc, 0);
  assert_int_equal(t.via_shm, shm != NULL);
  hf_io io = {1, w, h, send, f16 ? HF_F16 : HF_F32, want, f16 ? HF_F16 : HF_F32};
  assert_int_equal(hf_model_run(ref, &io, NULL), HF_OK);
  assert_memory_equal(got, want, n_out * es);
  free(in);
  if (!shm) free(send), free(got);
  free(want);
}

static void test_kernel_listed_and_filtered(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "test-kernel");
  assert_non_null(c);
  hfc_variant v;
  assert_int_equal(listed_variant(c, "Kernel", &v), 0);
  assert_int_equal(v.spp, 4);
  assert_string_equal(v.backend, "cpu-ref");
  filter_and_compare(c, "Kernel", kernel_ref, 37, 23, 0, NULL);
  filter_and_compare(c, "Kernel", kernel_ref, 64, 48, 1, NULL);
  filter_and_compare(c, "Kernel", kernel_ref, 9, 5, 0, NULL); /* smaller than the 7x7 kernel's reach */
  assert_int_equal(hfc_info(c)->shm, 1); /* a Unix socket */
  uint8_t *mem;
  assert_int_equal(hfc_shm_alloc(c, (size_t)40 * 30 * (24 + 3) * 4, (void **)&mem), 0);
  filter_and_compare(c, "Kernel", kernel_ref, 40, 30, 0, mem);
  assert_int_equal(hfc_shm_free(c, mem), 0);
  hfc_close(c);
}

static void test_estimate_listed_and_filtered(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "test-kernel-ac");
  assert_non_null(c);
  /* The estimate needs version 3 or later; the server speaks the newest. */
  assert_int_equal(hfc_info(c)->version, HFP_VERSION);
  assert_true(HFP_VERSION >= 3);
  hfc_variant v[8];
  int n = 0, found = 0;
  assert_int_equal(hfc_list_variants(c, v, 8, &n), 0);
  for (int i = 0; i < n && i < 8; i++) {
    assert_int_equal(v[i].estimate, !strcmp(v[i].name, "KernelAC"));
    found += !strcmp(v[i].name, "KernelAC");
  }
  assert_int_equal(found, 1);
  filter_and_compare(c, "KernelAC", ac_ref, 37, 23, 0, NULL);
  filter_and_compare(c, "KernelAC", ac_ref, 64, 48, 1, NULL);
  uint8_t *mem;
  assert_int_equal(hfc_shm_alloc(c, (size_t)40 * 30 * (27 + 3) * 4, (void **)&mem), 0);
  filter_and_compare(c, "KernelAC", ac_ref, 40, 30, 0, mem);
  assert_int_equal(hfc_shm_free(c, mem), 0);
  /* Without the estimate KernelAC's frame is refused, with it Kernel's:
   * by libhairfilter, before anything is sent, in the API's words (the
   * server's own refusal, INVALID naming the FILTER flag, is the
   * conformance suite's filter.estimate.* cases). */
  const int w = 16, h = 8;
  float *in = ac_frame(w, h, 5), out[16 * 8 * 3];
  hfc_request r = TEST_REQUEST(.variant = "KernelAC", .width = w, .height = h, .spp = 4,
                                .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "set hfc_request.estimate to 1"));
  r = TEST_REQUEST(.variant = "Kernel", .width = w, .height = h, .spp = 4, .features = in,
                   .result = out, .estimate = 1);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "Kernel reads no estimate"));
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), HFC_OK);
  for (int i = 0; i < st.num_variants; i++) {
    assert_int_equal(st.variants[i].rejected, 0);
    assert_int_equal(st.variants[i].requests_failed, 0);
  }
  /* The connection goes on. */
  filter_and_compare(c, "KernelAC", ac_ref, 9, 5, 0, NULL);
  free(in);
  hfc_close(c);
}

/* KernelAC's frame with the estimate in a buffer of its own
 * (hfc_request.estimate_buffer) gives the bytes of the same frame sent in
 * one buffer: f32 and f16, over the Unix socket and TCP, and in shared
 * memory, by reference when the estimate directly follows the features in
 * the segment and through the socket when it lies elsewhere. */
static void split_and_compare(hfc_client *c, int w, int h, int f16, uint8_t *shm, int adjacent,
                              int want_shm) {
  const size_t es = f16 ? 2 : 4, n_feat = (size_t)w * h * 24, n_est = (size_t)w * h * 3;
  const size_t n_out = (size_t)w * h * 3;
  float *in = ac_frame(w, h, (uint32_t)(w + h * 3 + f16));
  uint8_t *one = malloc((n_feat + n_est) * es), *want = malloc(n_out * es);
  assert_non_null(one);
  assert_non_null(want);
  for (size_t i = 0; i < n_feat + n_est; i++) {
    if (f16) ((uint16_t *)one)[i] = hf_f32_to_f16(in[i]);
    else ((float *)one)[i] = in[i];
  }
  /* The layout: features, then (adjacent) the estimate, result; or
   * features, result, estimate. */
  uint8_t *feat = shm ? shm : malloc(n_feat * es);
  uint8_t *est = shm ? shm + (adjacent ? n_feat * es : (n_feat + n_out) * es) : malloc(n_est * es);
  uint8_t *got = shm ? shm + (adjacent ? (n_feat + n_est) * es : n_feat * es) : malloc(n_out * es);
  assert_non_null(feat);
  assert_non_null(est);
  assert_non_null(got);
  memcpy(feat, one, n_feat * es);
  memcpy(est, one + n_feat * es, n_est * es);
  memset(got, 0xcd, n_out * es);
  hfc_request r = TEST_REQUEST(.variant = "KernelAC", .width = w, .height = h, .spp = 4,
                                .in_dtype = f16 ? HFC_F16 : HFC_F32, .features = feat,
                                .out_dtype = f16 ? HFC_F16 : HFC_F32, .result = got,
                                .estimate = 1, .estimate_buffer = est);
  assert_int_equal(r.features_bytes, n_feat * es);   /* the samples alone */
  hfc_timing t;
  int rc = hfc_filter(c, &r, &t);
  if (rc) fail_msg("filter %dx%d with the estimate apart: %s (%s)", w, h, hfc_strerror(rc),
                   hfc_last_message(c));
  assert_int_equal(t.via_shm, want_shm);
  hf_io io = {1, w, h, one, f16 ? HF_F16 : HF_F32, want, f16 ? HF_F16 : HF_F32};
  assert_int_equal(hf_model_run(ac_ref, &io, NULL), HF_OK);
  assert_memory_equal(got, want, n_out * es);
  if (!shm) free(feat), free(est), free(got);
  free(one);
  free(want);
  free(in);
}

static void test_estimate_in_a_buffer_of_its_own(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "test-estimate-apart");
  assert_non_null(c);
  split_and_compare(c, 37, 23, 0, NULL, 0, 0);
  split_and_compare(c, 64, 48, 1, NULL, 0, 0);
  const size_t seg = (size_t)40 * 30 * (24 + 3 + 3) * 4;
  uint8_t *mem;
  assert_int_equal(hfc_shm_alloc(c, seg, (void **)&mem), 0);
  split_and_compare(c, 40, 30, 0, mem, 1, 1);
  split_and_compare(c, 40, 30, 0, mem, 0, 0);
  /* While a frame whose estimate is in the segment is pending, the segment
   * stays. */
  float *in = ac_frame(8, 8, 3);
  memcpy(mem + (size_t)8 * 8 * 27 * 4, in + 8 * 8 * 24, 8 * 8 * 3 * 4);
  float out[8 * 8 * 3];
  hfc_request r = TEST_REQUEST(.variant = "KernelAC", .width = 8, .height = 8, .spp = 4,
                                .features = in, .result = out, .estimate = 1,
                                .estimate_buffer = mem + (size_t)8 * 8 * 27 * 4);
  uint32_t id;
  assert_int_equal(hfc_submit(c, &r, &id), 0);
  assert_int_equal(hfc_shm_free(c, mem), HFC_E_ARG);
  hfc_completion done;
  assert_int_equal(hfc_wait(c, -1, &done), 0);
  assert_int_equal(done.status, 0);
  assert_int_equal(hfc_shm_free(c, mem), 0);
  /* Refused before anything is sent, naming the field; the timing is all 0. */
  r = TEST_REQUEST(.variant = "KernelAC", .width = 8, .height = 8, .spp = 4, .features = in,
                   .result = out, .estimate_buffer = in + 8 * 8 * 24);
  hfc_timing t;
  memset(&t, 0x5a, sizeof t);
  assert_int_equal(hfc_filter(c, &r, &t), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "hfc_request.estimate_buffer is set but"));
  assert_true(t.total_us == 0 && t.server_us == 0 && t.via_shm == 0 && t.batch == 0);
  r = TEST_REQUEST(.variant = "KernelAC", .width = 8, .height = 8, .spp = 4, .features = in,
                   .result = out, .estimate = 1, .estimate_buffer = in + 8 * 8 * 24,
                   .estimate_bytes = 8 * 8 * 3 * 4 - 1);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "hfc_request.estimate_bytes is 767"));
  free(in);
  hfc_close(c);
  /* Over TCP (no shared memory): the three parts in one gather write. */
  hfc_options o = test_options("test-estimate-apart-tcp", TEST_TOKEN, 20000);
  assert_int_equal(hfc_connect(S.tcp_url, &o, &c), 0);
  split_and_compare(c, 37, 23, 0, NULL, 0, 0);
  split_and_compare(c, 200, 150, 1, NULL, 0, 0);
  hfc_close(c);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_kernel_listed_and_filtered),
    cmocka_unit_test(test_estimate_listed_and_filtered),
    cmocka_unit_test(test_estimate_in_a_buffer_of_its_own),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
