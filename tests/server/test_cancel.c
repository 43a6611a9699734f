/* hairfilterd and CANCEL (protocol version 4, PROTOCOL.md "Version 4"): a
 * queued frame is taken off the queue and answered CANCELLED, unrun, at
 * once; one the batcher holds runs and is answered as usual; a CANCEL of
 * an id not in flight gets no reply; before version 4 a CANCEL is a fatal
 * PROTOCOL. STATS counts the cancelled frames (a fifth counter, version 4
 * only), and so do /metrics, the SIGUSR1 statistics line and `hairfilter
 * filter --stats`. Raw frames, so that the daemon alone is tested. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "harness.h"
#include "harness_cmocka.h"

static harness H;
static server S;

/* A frame alone waits 1.5 s in the batcher for partners, holding the
 * queue behind it. */
static const char *const args[] = {"--max-batch", "16", "--max-queue-delay-us", "1500000",
                                   "--http", "tcp:127.0.0.1:0", NULL};

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  return server_start(&H, &S, args);
}

static int teardown(void **state) {
  (void)state;
  return harness_stop(&H, &S);
}

static void send_filter(int fd, uint32_t id, int w, int h, const float *in) {
  size_t len;
  uint8_t *b = raw_filter(id, "Small", w, h, harness_variant(&H, "Small")->cfg.spp, in, &len);
  assert_non_null(b);
  assert_int_equal(raw_send(fd, b, len), 0);
  free(b);
}

static void send_cancel(int fd, uint32_t id) {
  uint8_t b[HFP_HEADER_SIZE];
  assert_int_equal(hfp_encode_empty(b, sizeof b, HFP_CANCEL, id), HFP_HEADER_SIZE);
  assert_int_equal(raw_send(fd, b, sizeof b), 0);
}

/* The next frame, a RESULT, into *r; its request id. */
static uint32_t read_result(int fd, hfp_result *r) {
  hfp_header h;
  uint8_t *p = NULL;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  if (h.type != HFP_RESULT) fail_msg("frame type %u, want RESULT", h.type);
  assert_int_equal(hfp_decode_result(p, h.length, r), 0);
  r->data = r->rgba = NULL;
  free(p);
  return h.request_id;
}

/* Frame 1 waits in the batcher; frame 2 (another size) is queued behind
 * it. Cancelled, frame 2 is answered CANCELLED at once, before frame 1's
 * result, and never runs; frame 1, already the batcher's, is not
 * cancelled: its result comes as usual. A CANCEL of an answered id, and
 * of one never sent, gets nothing. */
static void test_queued_and_held(void **state) {
  (void)state;
  int spp = harness_variant(&H, "Small")->cfg.spp;
  int fd = connect_versions_or_fail(S.unix_url, 1, 4);
  hfp_variant_stats before = variant_stats_or_fail(fd, "Small");
  float *a = make_features(16, 16, spp, 1), *b = make_features(24, 20, spp, 2);
  send_filter(fd, 1, 16, 16, a);
  usleep(100000);   /* frame 1 is the batcher's before the others arrive */
  send_filter(fd, 2, 24, 20, b);
  double t0 = now_ms();
  send_cancel(fd, 2);
  send_cancel(fd, 1);
  hfp_result r;
  assert_int_equal(read_result(fd, &r), 2);
  assert_int_equal(r.status, HFP_E_CANCELLED);
  assert_int_equal(r.batch, 0);
  assert_int_equal(r.width, 0);
  assert_true(now_ms() - t0 < 1000);   /* not after frame 1's 1.5 s wait */
  assert_int_equal(read_result(fd, &r), 1);
  assert_int_equal(r.status, HFP_OK);
  send_cancel(fd, 1);    /* answered */
  send_cancel(fd, 99);   /* never sent */
  hfp_variant_stats after = variant_stats_or_fail(fd, "Small");   /* the next reply is STATS' */
  assert_true(after.requests_failed - before.requests_failed == 1);
  assert_true(after.requests_ok - before.requests_ok == 1);
  assert_true(after.batches - before.batches == 1);   /* frame 2 never ran */
  assert_true(after.expired == before.expired);
  /* counted apart, as well as among the failed ones */
  assert_true(after.cancelled - before.cancelled == 1);
  close(fd);
  /* Version 3 knows no such counter: read as 0, counted all the same. */
  fd = connect_versions_or_fail(S.unix_url, 1, 3);
  hfp_variant_stats v3 = variant_stats_or_fail(fd, "Small");
  assert_true(v3.cancelled == 0 && v3.expired == 0);
  assert_true(v3.requests_failed == after.requests_failed);
  close(fd);
  free(a);
  free(b);
}

/* Before version 4 a CANCEL is no request: a fatal PROTOCOL with id 0.
 * With a payload it is a fatal LENGTH. */
static void test_refused(void **state) {
  (void)state;
  int fd = connect_versions_or_fail(S.unix_url, 1, 3);
  send_cancel(fd, 5);
  hfp_header h;
  hfp_error e;
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_PROTOCOL);
  assert_int_equal(e.fatal, 1);
  assert_int_equal(h.request_id, 0);
  assert_non_null(strstr(e.message, "version 4"));
  assert_non_null(strstr(e.message, "HELLO"));   /* what to do: offer version 4 */
  assert_true(raw_closed(fd, 5000));
  close(fd);
  fd = connect_versions_or_fail(S.unix_url, 4, 4);
  uint8_t b[HFP_HEADER_SIZE + 4] = {0};
  assert_int_equal(hfp_encode_empty(b, sizeof b, HFP_CANCEL, 5), HFP_HEADER_SIZE);
  hfp_put_u32(b + 12, 4);
  assert_int_equal(raw_send(fd, b, sizeof b), 0);
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_LENGTH);
  assert_int_equal(e.fatal, 1);
  close(fd);
}

/* libhairfilter: hfc_cancel of a frame queued behind one the batcher
 * holds completes HFC_E_CANCELLED, with a message naming hfc_cancel,
 * before the held one; hfc_cancel of the held one changes nothing (it
 * completes OK); an id not pending is HFC_E_ARG naming it. */
static void test_client_library(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int spp = v->cfg.spp;
  hfc_client *c = client_connect(&S, "cancel-client");
  assert_non_null(c);
  static hfc_stats st0, st1;
  assert_int_equal(hfc_get_stats(c, &st0), 0);
  float *a = make_features(16, 16, spp, 3), *b = make_features(24, 20, spp, 4);
  static float out_a[16 * 16 * 3], out_b[24 * 20 * 3], want[16 * 16 * 3];
  hfc_request ra = TEST_REQUEST(.variant = "Small", .width = 16, .height = 16, .spp = spp,
                                .in_dtype = HFC_F32, .features = a, .out_dtype = HFC_F32,
                                .result = out_a, .user = (void *)1);
  hfc_request rb = TEST_REQUEST(.variant = "Small", .width = 24, .height = 20, .spp = spp,
                                .in_dtype = HFC_F32, .features = b, .out_dtype = HFC_F32,
                                .result = out_b, .user = (void *)2);
  uint32_t ida, idb;
  assert_int_equal(hfc_submit(c, &ra, &ida), 0);
  usleep(100000);
  assert_int_equal(hfc_submit(c, &rb, &idb), 0);
  assert_int_equal(hfc_cancel(c, idb), 0);
  assert_int_equal(hfc_cancel(c, ida), 0);
  hfc_completion d;
  assert_int_equal(hfc_wait(c, 20000, &d), 0);
  assert_int_equal(d.id, idb);
  assert_int_equal(d.status, HFC_E_CANCELLED);
  assert_non_null(strstr(hfc_last_message(c), "hfc_cancel"));
  assert_int_equal(hfc_wait(c, 20000, &d), 0);
  assert_int_equal(d.id, ida);
  assert_int_equal(d.status, 0);
  assert_int_equal(reference(v, 16, 16, a, HF_F32, want, HF_F32), 0);
  assert_memory_equal(out_a, want, sizeof want);
  assert_int_equal(hfc_cancel(c, ida), HFC_E_ARG);   /* returned by hfc_wait: done */
  char id_text[32];
  snprintf(id_text, sizeof id_text, "request %u", ida);
  assert_non_null(strstr(hfc_last_message(c), id_text));
  assert_int_equal(hfc_cancel(NULL, 1), HFC_E_ARG);
  assert_non_null(strstr(hfc_strerror(HFC_E_CANCELLED), "cancelled"));
  /* hfc_get_stats counts it */
  assert_int_equal(hfc_get_stats(c, &st1), 0);
  uint64_t c0 = 0, c1 = 0;
  for (int i = 0; i < st0.num_variants; i++)
    if (!strcmp(st0.variants[i].name, "Small")) c0 = st0.variants[i].cancelled;
  for (int i = 0; i < st1.num_variants; i++)
    if (!strcmp(st1.variants[i].name, "Small")) c1 = st1.variants[i].cancelled;
  assert_true(c1 - c0 == 1);
  hfc_close(c);
  free(a);
  free(b);
}

/* The frames cancelled so far (two: test_queued_and_held's and
 * test_client_library's) in the operator's views: /metrics'
 * requests_total{status="cancelled",class="cancelled"}, the SIGUSR1
 * statistics line's cancelled=, and `hairfilter filter --stats`. */
static void test_reports(void **state) {
  (void)state;
  char *m = http_get(&S, "/metrics");
  assert_non_null(m);
  if (!strstr(m, "hairfilterd_requests_total{variant=\"Small\",status=\"cancelled\","
                 "class=\"cancelled\"} 2\n"))
    fail_msg("no cancelled count of 2 for Small in /metrics:\n%s", m);
  free(m);
  usr1_line_or_fail(&S, "expired=0 cancelled=2");
  char text[8192];
  cli_stats_or_fail(&H, &S, text, sizeof text);
  if (!strstr(text, "  Small: 2 frame(s) cancelled in the queue, not computed"))
    fail_msg("no cancelled line in hairfilter filter --stats:\n%s", text);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_queued_and_held),
      cmocka_unit_test(test_refused),
      cmocka_unit_test(test_client_library),
      cmocka_unit_test(test_reports),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
