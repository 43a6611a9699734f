/* hairfilterd and out-of-contract input (protocol/FEATURES.md): a frame with
 * non-finite samples gets status OK, RESULT flag bit 2 (protocol version 2)
 * and the result of the sanitised frame; clean frames do not get the flag,
 * also when batched with a bad one; STATS counts such frames
 * (frames_sanitised, version 2), and a version-1 client sees neither. A
 * fresh daemon, so the counts are exact. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "harness.h"

static harness H;
static server S;

static const char *const args[] = {"--max-batch", "4", "--max-queue-delay-us", "20000", NULL};

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  return server_start(&H, &S, args);
}

static int teardown(void **state) {
  (void)state;
  return harness_stop(&H, &S);
}

enum { W = 24, HH = 20 };

/* Frame `seed` of variant Small, with sample 1 of pixel (5, 7) made bad
 * (bad: 0 none, 1 +Inf highlight, 2 NaN colour). */
static float *frame(int spp, uint32_t seed, int bad) {
  float *f = make_features(W, HH, spp, seed);
  size_t at = ((size_t)7 * W + 5) * spp * 6 + 6;
  if (bad == 1) f[at + 1] = INFINITY;
  if (bad == 2) f[at + 0] = NAN;
  return f;
}

static void test_flag_and_result(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int spp = v->cfg.spp;
  hfc_client *c = client_connect(&S, "test-sanitised");
  assert_non_null(c);
  assert_int_equal(hfc_info(c)->version, HFP_VERSION);
  size_t nin = (size_t)W * HH * spp * 6, nout = (size_t)W * HH * 3;
  float got[W * HH * 3], want[W * HH * 3];
  for (int bad = 0; bad < 3; bad++) {
    float *in = frame(spp, 40 + bad, bad);
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = spp,
                     .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32, .result = got);
    hfc_timing t;
    assert_int_equal(hfc_filter(c, &r, &t), 0);
    assert_int_equal(t.input_sanitised, bad != 0);
    for (size_t i = 0; i < nout; i++) assert_true(isfinite(got[i]));
    /* The result of the same frame with the bad sample made uncovered. */
    if (bad) memset(in + ((size_t)7 * W + 5) * spp * 6 + 6, 0, 6 * sizeof(float));
    assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
    assert_memory_equal(got, want, sizeof got);
    free(in);
  }
  /* f16 in and out: an Inf is an Inf in binary16 too. */
  float *in = frame(spp, 50, 1);
  uint16_t *in16 = malloc(nin * 2), out16[W * HH * 3];
  for (size_t i = 0; i < nin; i++) in16[i] = hf_f32_to_f16(in[i]);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = spp,
                   .in_dtype = HFC_F16, .features = in16, .out_dtype = HFC_F16, .result = out16);
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(t.input_sanitised, 1);
  for (size_t i = 0; i < nout; i++) assert_true((out16[i] & 0x7c00u) != 0x7c00u);
  free(in);
  free(in16);
  hfc_close(c);
}

/* Pipelined, so the worker may run them in batches: only the bad frames
 * are flagged. */
static void test_batched(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int spp = v->cfg.spp;
  hfc_client *c = client_connect(&S, "test-sanitised");
  assert_non_null(c);
  enum { N = 8 };
  float *in[N], out[N][W * HH * 3];
  uint32_t id[N];
  for (int i = 0; i < N; i++) {
    in[i] = frame(spp, 60 + i, i % 3 == 1 ? 1 : 0);
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = spp,
                     .in_dtype = HFC_F32, .features = in[i], .out_dtype = HFC_F32,
                     .result = out[i], .user = (void *)(intptr_t)i);
    assert_int_equal(hfc_submit(c, &r, &id[i]), 0);
  }
  for (int k = 0; k < N; k++) {
    hfc_completion done;
    assert_int_equal(hfc_wait(c, 20000, &done), 0);
    assert_int_equal(done.status, 0);
    int i = (int)(intptr_t)done.user;
    assert_int_equal(done.timing.input_sanitised, i % 3 == 1);
  }
  for (int i = 0; i < N; i++) free(in[i]);
  hfc_close(c);
}

/* A raw FILTER of frame(seed, bad) on fd: the RESULT's flags byte. */
static int raw_flags(int fd, int spp, uint32_t seed, int bad) {
  float *in = frame(spp, seed, bad);
  size_t len;
  uint8_t *f = raw_filter(5 + (uint32_t)bad, "Small", W, HH, spp, in, &len);
  assert_non_null(f);
  assert_int_equal(raw_send(fd, f, len), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  hfp_result r;
  assert_int_equal(hfp_decode_result(p, h.length, &r), 0);
  assert_int_equal(r.status, 0);
  int flags = p[3];
  free(p);
  free(f);
  free(in);
  return flags;
}

/* A version-1 client: no flag (its decoder would refuse the bit), no
 * counters after STATS_REPLY; the frames are sanitised and counted all the
 * same. A version-2 one: the flag and the counters. */
static void test_versions(void **state) {
  (void)state;
  int spp = harness_variant(&H, "Small")->cfg.spp;
  for (int version = 1; version <= 2; version++) {
    int fd = raw_connect(S.unix_url);
    assert_true(fd >= 0);
    assert_int_equal(raw_hello_versions(fd, NULL, 1, version), 0);
    assert_int_equal(raw_flags(fd, spp, 80, 0), 0);
    assert_int_equal(raw_flags(fd, spp, 80, 2), version >= 2 ? HFP_RESULT_INPUT_SANITISED : 0);
    uint8_t b[64];
    int n = hfp_encode_empty(b, sizeof b, HFP_STATS, 0);
    assert_int_equal(raw_send(fd, b, (size_t)n), 0);
    hfp_header h;
    uint8_t *p;
    static hfp_stats s1;
    assert_int_equal(raw_read(fd, &h, &p), 0);
    assert_int_equal(h.type, HFP_STATS_REPLY);
    assert_int_equal(hfp_decode_stats(p, h.length, &s1), 0);
    assert_int_equal((size_t)h.length + HFP_HEADER_SIZE, hfp_frame_size_stats_v(&s1, version));
    free(p);
    close(fd);
  }
}

/* frames_sanitised: 2 + 1 (f16) in test_flag_and_result, 3 in test_batched
 * and 2 in test_versions (the version-1 one counted too); 16 frames in all. */
static void test_stats(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "test-sanitised");
  assert_non_null(c);
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  int found = 0;
  for (int i = 0; i < st.num_variants; i++) {
    if (strcmp(st.variants[i].name, "Small")) {
      assert_int_equal(st.variants[i].frames_sanitised, 0);
      continue;
    }
    found = 1;
    assert_int_equal(st.variants[i].frames_sanitised, 8);
    assert_int_equal(st.variants[i].requests_ok, 16);
    /* It ran, and keeps what its sizes need (a gauge; version 2). */
    assert_true(st.variants[i].cache_bytes > 0);
  }
  assert_true(found);
  hfc_close(c);
}

/* hairfilter filter on a cropped feature file with a NaN sample: one
 * warning naming the pixel in the file's coordinates, and a result with the
 * file's data window and display window. */
static void test_cli_filter(void **state) {
  (void)state;
  int spp = harness_variant(&H, "Small")->cfg.spp;
  float *in = frame(spp, 90, 2);
  hf_image img = {0};
  assert_int_equal(hf_features_to_image(in, W, HH, spp, &img), 0);
  img.origin_x = 300;
  img.origin_y = 100;
  img.display_width = 1920;
  img.display_height = 1080;
  char feat[300], res[300], outtxt[300], cmd[2000];
  snprintf(feat, sizeof feat, "%s/nan_features.exr", H.dir);
  snprintf(res, sizeof res, "%s/nan_result.exr", H.dir);
  snprintf(outtxt, sizeof outtxt, "%s/nan_out.txt", H.dir);
  assert_int_equal(hf_exr_write(feat, &img, 0), 0);
  hf_image_free(&img);
  for (int f16 = 0; f16 < 2; f16++) {
    snprintf(cmd, sizeof cmd, "'%s' filter --server '%s' --variant Small --in '%s' --out '%s' %s"
             "> '%s' 2>&1", HAIRFILTER_CLI_PATH, S.unix_url, feat, res, f16 ? "--f16 " : "",
             outtxt);
    assert_int_equal(system(cmd), 0);
    char text[4096];
    assert_int_equal(read_text_file(outtxt, text, sizeof text), 0);
    if (!strstr(text, "nan_features.exr: 1 sample sanitised") ||
        !strstr(text, "the first at pixel (305, 107): S1.color = nan is not finite"))
      fail_msg("unexpected output:\n%s", text);
    char err[256];
    hf_image out = {0};
    assert_int_equal(hf_exr_read(res, &out, err, sizeof err), 0);
    assert_int_equal(out.origin_x, 300);
    assert_int_equal(out.origin_y, 100);
    assert_int_equal(out.display_width, 1920);
    assert_int_equal(out.display_height, 1080);
    for (int i = 0; i < W * HH * 3; i++) assert_true(isfinite(out.data[i]));
    hf_image_free(&out);
  }
  free(in);
}

/* hairfilter filter --f16 on a HALF feature file (sent as stored) and on
 * a FLOAT file of the same values (read as float32, converted once): the
 * same request, so the same result file, byte for byte, and the same
 * warning for the NaN sample. */
static int file_bytes(const char *path, char **buf, long *len) {
  FILE *f = fopen(path, "rb");
  if (!f) return -1;
  fseek(f, 0, SEEK_END);
  *len = ftell(f);
  fseek(f, 0, SEEK_SET);
  *buf = malloc((size_t)*len + 1);
  int ok = *buf && fread(*buf, 1, (size_t)*len, f) == (size_t)*len;
  fclose(f);
  return ok ? 0 : -1;
}

static void test_cli_filter_half_file(void **state) {
  (void)state;
  int spp = harness_variant(&H, "Small")->cfg.spp;
  float *in = frame(spp, 91, 2);
  hf_image img = {0}, widened = {0};
  assert_int_equal(hf_features_to_image(in, W, HH, spp, &img), 0);
  char half[300], flt[300], res[2][300], outtxt[300], cmd[2000], err[256];
  snprintf(half, sizeof half, "%s/half_features.exr", H.dir);
  snprintf(flt, sizeof flt, "%s/float_features.exr", H.dir);
  assert_int_equal(hf_exr_write(half, &img, 1), 0);
  assert_int_equal(hf_exr_read(half, &widened, err, sizeof err), 0);
  assert_int_equal(hf_exr_write(flt, &widened, 0), 0);
  for (int k = 0; k < 2; k++) {
    snprintf(res[k], sizeof res[k], "%s/half_result%d.exr", H.dir, k);
    snprintf(outtxt, sizeof outtxt, "%s/half_out%d.txt", H.dir, k);
    snprintf(cmd, sizeof cmd, "'%s' filter --server '%s' --variant Small --in '%s' --out '%s' "
             "--f16 > '%s' 2>&1", HAIRFILTER_CLI_PATH, S.unix_url, k ? flt : half, res[k],
             outtxt);
    assert_int_equal(system(cmd), 0);
    char text[4096];
    assert_int_equal(read_text_file(outtxt, text, sizeof text), 0);
    if (!strstr(text, "1 sample sanitised") || !strstr(text, "read ") ||
        !strstr(text, "into the request's f16"))
      fail_msg("unexpected output:\n%s", text);
  }
  char *a = NULL, *b = NULL;
  long na = 0, nb = 0;
  assert_int_equal(file_bytes(res[0], &a, &na), 0);
  assert_int_equal(file_bytes(res[1], &b, &nb), 0);
  assert_true(na > 0);
  assert_int_equal(na, nb);
  assert_memory_equal(a, b, (size_t)na);
  free(a);
  free(b);
  hf_image_free(&img);
  hf_image_free(&widened);
  free(in);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_flag_and_result), cmocka_unit_test(test_batched),
    cmocka_unit_test(test_versions),        cmocka_unit_test(test_stats),
    cmocka_unit_test(test_cli_filter),      cmocka_unit_test(test_cli_filter_half_file),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
