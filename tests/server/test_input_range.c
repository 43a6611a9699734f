/* The input-range report through a real hairfilterd (PROTOCOL.md, "Version
 * 2"): a variant whose weights record a narrow trained range beside the
 * harness's variants, which record none. Frames outside the range come back
 * flagged to a version-2 client (socket and shared memory, f32 and f16) and
 * unflagged but counted for a version-1 one; frames inside, and every frame
 * of a variant without a range, are never flagged; VARIANTS carries the
 * range, STATS the count; `hairfilter filter` names the statistic. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "harness.h"

static harness H;
static server S;
static char narrow_path[300];

enum { W = 24, HH = 16, SPP = 4 };

/* Every pixel hair with two of four samples covered, of alpha a: the
 * strand_alpha_p50 of the frame is a (0.25 and 0.5 are exact bin edges). */
static float *frame_of_alpha(float a) {
  float *in = calloc((size_t)W * HH * SPP * 6, sizeof(float));
  for (int p = 0; p < W * HH; p++)
    for (int k = 0; k < 2; k++) {
      float *s = in + ((size_t)p * SPP + k) * 6;
      s[0] = 0.8f, s[1] = 0.1f, s[2] = a, s[3] = 0.5f, s[4] = 0.6f, s[5] = -0.8f;
    }
  return in;
}

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  /* Trained (so its metadata says) on frames whose median strand alpha was
   * 0.2..0.3. */
  if (harness_narrow_weights(&H,
                             "{\"definition\": 1, \"spp\": 4, \"frames\": 20, "
                             "\"strand_alpha_p50\": [0.2, 0.3], \"hair_fraction\": [0.5, 1]}",
                             narrow_path, sizeof narrow_path))
    return -1;
  const char *const extra[] = {"--weights", narrow_path, "--max-batch", "4",
                               "--max-queue-delay-us", "2000", NULL};
  return server_start(&H, &S, extra);
}

static int teardown(void **state) {
  (void)state;
  return harness_stop(&H, &S);
}

static hfc_client *connect_unix(void) {
  hfc_client *c = client_connect(&S, "test-range");
  assert_non_null(c);
  assert_int_equal(hfc_info(c)->version, HFP_VERSION);
  return c;
}

/* One frame through c; returns hfc_timing.out_of_range. */
static int filter_flag(hfc_client *c, const char *variant, const float *in, int f16, void *shm) {
  size_t n_in = (size_t)W * HH * SPP * 6;
  size_t es = f16 ? 2 : 4;
  void *feat = shm, *out = shm ? (uint8_t *)shm + n_in * es : malloc((size_t)W * HH * 3 * es);
  if (!shm) feat = malloc(n_in * es);
  for (size_t i = 0; i < n_in; i++) {
    if (f16) ((uint16_t *)feat)[i] = hf_f32_to_f16(in[i]);
    else ((float *)feat)[i] = in[i];
  }
  hfc_request r = TEST_REQUEST(.variant = variant, .width = W, .height = HH, .spp = SPP,
                   .in_dtype = f16 ? HFC_F16 : HFC_F32, .features = feat,
                   .out_dtype = f16 ? HFC_F16 : HFC_F32, .result = out);
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(t.via_shm, shm != NULL);
  if (!shm) {
    free(feat);
    free(out);
  }
  return t.out_of_range;
}

static const hfc_variant_stats *find_stats(const hfc_stats *st, const char *name) {
  for (int i = 0; i < st->num_variants; i++)
    if (!strcmp(st->variants[i].name, name)) return &st->variants[i];
  return NULL;
}

static void test_variants_carry_the_range(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  hfc_variant vs[8];
  int n = 0;
  assert_int_equal(hfc_list_variants(c, vs, 8, &n), 0);
  assert_int_equal(n, 4);
  int seen = 0;
  for (int i = 0; i < n; i++) {
    if (strcmp(vs[i].name, "Narrow")) {
      assert_int_equal(vs[i].range_mask, 0);   /* harness weights: no range */
      continue;
    }
    seen = 1;
    assert_int_equal(vs[i].range_mask,
                     (1u << HF_STAT_STRAND_ALPHA_P50) | (1u << HF_STAT_HAIR_FRACTION));
    assert_true(vs[i].range_lo[HF_STAT_STRAND_ALPHA_P50] == 0.2);
    assert_true(vs[i].range_hi[HF_STAT_STRAND_ALPHA_P50] == 0.3);
    assert_true(vs[i].range_lo[HF_STAT_HAIR_FRACTION] == 0.5);
  }
  assert_true(seen);
  hfc_close(c);
}

static void test_flag_and_count(void **state) {
  (void)state;
  float *inside = frame_of_alpha(0.25f), *outside = frame_of_alpha(0.5f);
  float *empty = calloc((size_t)W * HH * SPP * 6, sizeof(float));
  hfc_client *c = connect_unix();
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  uint64_t before = find_stats(&st, "Narrow")->out_of_range;

  assert_int_equal(filter_flag(c, "Narrow", inside, 0, NULL), 0);
  assert_int_equal(filter_flag(c, "Narrow", outside, 0, NULL), 1);
  assert_int_equal(filter_flag(c, "Narrow", outside, 1, NULL), 1);     /* f16 */
  assert_int_equal(filter_flag(c, "Narrow", inside, 1, NULL), 0);
  /* No hair at all: nothing to filter, never out of range. */
  assert_int_equal(filter_flag(c, "Narrow", empty, 0, NULL), 0);
  /* Shared memory: the same judgement on the segment's input. */
  void *shm = NULL;
  size_t bytes = (size_t)W * HH * (SPP * 6 + 3) * 4;
  assert_int_equal(hfc_shm_alloc(c, bytes, &shm), 0);
  assert_int_equal(filter_flag(c, "Narrow", outside, 0, shm), 1);
  assert_int_equal(filter_flag(c, "Narrow", inside, 0, shm), 0);
  assert_int_equal(hfc_shm_free(c, shm), 0);
  /* A variant whose weights record no range: never flagged. */
  assert_int_equal(filter_flag(c, "Small", outside, 0, NULL), 0);

  /* Frames batched together are judged one by one. */
  void *outs[4];
  uint32_t ids[4];
  for (int i = 0; i < 4; i++) {
    outs[i] = malloc((size_t)W * HH * 3 * 4);
    hfc_request r = TEST_REQUEST(.variant = "Narrow", .width = W, .height = HH, .spp = SPP,
                     .in_dtype = HFC_F32, .features = i % 2 ? outside : inside,
                     .out_dtype = HFC_F32, .result = outs[i]);
    assert_int_equal(hfc_submit(c, &r, &ids[i]), 0);
  }
  for (int i = 0; i < 4; i++) {
    hfc_completion done;
    assert_int_equal(hfc_wait(c, -1, &done), 0);
    assert_int_equal(done.status, 0);
    int k = 0;
    while (ids[k] != done.id) k++;
    assert_int_equal(done.timing.out_of_range, k % 2);
  }
  for (int i = 0; i < 4; i++) free(outs[i]);

  /* A version-1 peer gets the same result without the flag it does not
   * know; the frame is still counted. */
  int fd = raw_connect(S.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);   /* offers version 1 only */
  size_t len;
  uint8_t *frame = raw_filter(5, "Narrow", W, HH, SPP, outside, &len);
  assert_int_equal(raw_send(fd, frame, len), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  hfp_result res;
  assert_int_equal(hfp_decode_result(p, h.length, &res), 0);
  assert_int_equal(res.status, 0);
  assert_int_equal(res.flags, 0);
  free(p);
  free(frame);
  /* ...and its STATS_REPLY is version 1's, byte for byte in length. */
  uint8_t sreq[HFP_HEADER_SIZE];
  assert_int_equal(hfp_encode_empty(sreq, sizeof sreq, HFP_STATS, 0), HFP_HEADER_SIZE);
  assert_int_equal(raw_send(fd, sreq, sizeof sreq), 0);
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_STATS_REPLY);
  static hfp_stats v1;
  assert_int_equal(hfp_decode_stats(p, h.length, &v1), 0);
  assert_int_equal(h.length + HFP_HEADER_SIZE, hfp_frame_size_stats(&v1));
  free(p);
  close(fd);

  /* Flagged: 2 + 1 (shm) + 2 (batch) + 1 (version 1) = 6. */
  assert_int_equal(hfc_get_stats(c, &st), 0);
  assert_int_equal(find_stats(&st, "Narrow")->out_of_range - before, 6);
  assert_int_equal(find_stats(&st, "Small")->out_of_range, 0);
  hfc_close(c);
  free(inside);
  free(outside);
  free(empty);
}

/* `hairfilter filter` names the statistic, its value and the trained range
 * for a flagged frame, and says nothing for one inside. */
static void test_cli_warning(void **state) {
  (void)state;
  float *outside = frame_of_alpha(0.5f), *inside = frame_of_alpha(0.25f);
  const float *frames[2] = {outside, inside};
  for (int f = 0; f < 2; f++) {
    hf_image img = {0};
    assert_int_equal(hf_features_to_image(frames[f], W, HH, SPP, &img), 0);
    char feat[320], res[320], txt[320], cmd[2048];
    snprintf(feat, sizeof feat, "%s/range_in%d.exr", H.dir, f);
    snprintf(res, sizeof res, "%s/range_out%d.exr", H.dir, f);
    snprintf(txt, sizeof txt, "%s/range_cli%d.txt", H.dir, f);
    assert_int_equal(hf_exr_write(feat, &img, 0), 0);
    hf_image_free(&img);
    snprintf(cmd, sizeof cmd, "'%s' filter --server '%s' --variant Narrow --in '%s' --out '%s' "
             "%s > '%s' 2>&1", HAIRFILTER_CLI_PATH, S.unix_url, feat, res, f ? "" : "--f16", txt);
    assert_int_equal(system(cmd), 0);
    char text[4096];
    assert_int_equal(read_text_file(txt, text, sizeof text), 0);
    const char *want = "is outside the input range Narrow was trained on: strand_alpha_p50 0.5 "
                       "(trained 0.2..0.3)";
    if (f == 0 && !strstr(text, want)) fail_msg("no warning in:\n%s", text);
    if (f == 1 && strstr(text, "warning")) fail_msg("unexpected warning in:\n%s", text);
  }
  /* --list shows the range, --stats the count. */
  char txt[320], cmd[1024];
  snprintf(txt, sizeof txt, "%s/range_list.txt", H.dir);
  snprintf(cmd, sizeof cmd, "'%s' filter --server '%s' --list --stats > '%s' 2>&1",
           HAIRFILTER_CLI_PATH, S.unix_url, txt);
  assert_int_equal(system(cmd), 0);
  char text[8192];
  assert_int_equal(read_text_file(txt, text, sizeof text), 0);
  if (!strstr(text, "trained on strand_alpha_p50 0.2..0.3, hair_fraction 0.5..1"))
    fail_msg("no range in --list:\n%s", text);
  if (!strstr(text, "outside")) fail_msg("no out-of-range column in --stats:\n%s", text);
  free(outside);
  free(inside);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_variants_carry_the_range),
    cmocka_unit_test(test_flag_and_count),
    cmocka_unit_test(test_cli_warning),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
