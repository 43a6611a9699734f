/* hairfilterd and a frame's deadline (protocol version 4, PROTOCOL.md
 * "Version 4"): a frame still queued when its budget has passed is
 * answered EXPIRED and never computed; one within its budget is computed,
 * and the batcher does not hold it for partners past its budget; STATS
 * counts the expired frames (a fourth counter, version 4 only); the
 * frames queued behind one the batcher holds are answered as their budget
 * passes; before
 * version 4 the flag is UNSUPPORTED, and a budget of 0 is INVALID. Raw
 * frames, so that the daemon alone is tested. */
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

/* A frame alone waits 1.5 s in the batcher for partners: the queue behind
 * it is held that long, whatever the machine's speed. */
enum { HOLD_US = 1500000 };
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

/* A raw connection to the daemon's Unix socket that negotiated lo..hi. */
/* Sends a FILTER of Small, w x h, with budget_us (0: no DEADLINE flag). */
static void send_filter(int fd, uint32_t id, int w, int h, const float *in, uint32_t budget_us) {
  const ref_variant *v = harness_variant(&H, "Small");
  hfp_filter f;
  memset(&f, 0, sizeof f);
  strcpy(f.variant, "Small");
  f.width = (uint32_t)w;
  f.height = (uint32_t)h;
  f.spp = (uint16_t)v->cfg.spp;
  f.in_dtype = f.out_dtype = HFP_F32;
  f.data = in;
  assert_int_equal(hfp_features_bytes(f.width, f.height, f.spp, HFP_F32, &f.data_len), 0);
  if (budget_us) {
    f.flags = HFP_FILTER_DEADLINE;
    f.budget_us = budget_us;
  }
  uint8_t head[HFP_FILTER_HEAD_MAX];
  uint64_t total;
  int n = hfp_encode_filter_head(head, sizeof head, id, &f, &total);
  assert_true(n > 0);
  assert_int_equal(raw_send(fd, head, (size_t)n), 0);
  assert_int_equal(raw_send(fd, in, (size_t)f.data_len), 0);
}

/* Reads the next frame, a RESULT, into *r (its tensors copied to out,
 * when out is not NULL); returns its request id. */
static uint32_t read_result(int fd, hfp_result *r, float *out, size_t out_cap) {
  hfp_header h;
  uint8_t *p = NULL;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  if (h.type != HFP_RESULT) fail_msg("frame type %u, want RESULT", h.type);
  assert_int_equal(hfp_decode_result(p, h.length, r), 0);
  if (out && r->data_len) {
    assert_true(r->data_len <= out_cap);
    memcpy(out, r->data, (size_t)r->data_len);
  }
  r->data = r->rgba = NULL;
  free(p);
  return h.request_id;
}

/* A frame waits in the batcher (no partner comes) while two frames of other
 * sizes queue behind it: one whose 200 ms budget passes meanwhile is
 * answered EXPIRED, unrun (no backend run counted for it), and one with a
 * budget of 60 s is computed, to the reference's values. */
static void test_expired_while_queue_held(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int spp = v->cfg.spp;
  int fd = connect_versions_or_fail(S.unix_url, 1, 4);
  hfp_variant_stats before = variant_stats_or_fail(fd, "Small");
  float *a = make_features(16, 16, spp, 1), *b = make_features(24, 20, spp, 2),
        *c = make_features(20, 20, spp, 3);
  double t0 = now_ms();
  send_filter(fd, 1, 16, 16, a, 0);
  usleep(100000);   /* frame 1 is the batcher's before the others arrive */
  send_filter(fd, 2, 24, 20, b, 200000);
  send_filter(fd, 3, 20, 20, c, 60000000);
  static float got[20 * 20 * 3], want[20 * 20 * 3];
  int seen = 0;
  for (int k = 0; k < 3; k++) {
    hfp_result r;
    uint32_t id = read_result(fd, &r, got, sizeof got);
    seen |= 1 << id;
    if (id == 2) {
      assert_int_equal(r.status, HFP_E_EXPIRED);
      assert_int_equal(r.width, 0);
      assert_int_equal(r.batch, 0);
      assert_true(r.timing.infer_us == 0);
      /* it waited its budget at least, in the queue */
      assert_true(r.timing.queue_us >= 200000);
      assert_true(r.timing.queue_us <= r.timing.total_us);
    } else {
      assert_int_equal(r.status, HFP_OK);
      assert_int_equal(r.batch, 1);
      if (id == 3) {
        assert_int_equal(reference(v, 20, 20, c, HF_F32, want, HF_F32), 0);
        assert_memory_equal(got, want, sizeof want);
      }
    }
  }
  assert_int_equal(seen, (1 << 1) | (1 << 2) | (1 << 3));
  /* frame 1 held the queue for its partner wait */
  assert_true(now_ms() - t0 >= HOLD_US / 1000.0 - 50);
  hfp_variant_stats after = variant_stats_or_fail(fd, "Small");
  assert_true(after.expired - before.expired == 1);
  assert_true(after.requests_failed - before.requests_failed == 1);
  assert_true(after.requests_ok - before.requests_ok == 2);
  assert_true(after.batches - before.batches == 2);   /* frame 2 never ran */
  close(fd);
  free(a);
  free(b);
  free(c);
}

/* A frame queued behind the one the batcher holds for partners is answered
 * EXPIRED as its budget passes, not once the batcher has waited its 1.5 s
 * and run: its reply comes first, long before the held frame's. */
static void test_expired_while_batcher_waits(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int spp = v->cfg.spp;
  int fd = connect_versions_or_fail(S.unix_url, 4, 4);
  float *a = make_features(16, 16, spp, 11), *b = make_features(24, 20, spp, 12);
  send_filter(fd, 1, 16, 16, a, 0);
  usleep(100000);   /* frame 1 is the batcher's before frame 2 arrives */
  send_filter(fd, 2, 24, 20, b, 200000);
  hfp_result r;
  uint32_t id = read_result(fd, &r, NULL, 0);
  if (id != 2)
    fail_msg("frame %u answered first (status %u, %.3f s); want frame 2's EXPIRED as its "
             "200 ms budget passed, before the batcher's 1.5 s wait for frame 1 ended",
             id, r.status, r.timing.total_us / 1e6);
  assert_int_equal(r.status, HFP_E_EXPIRED);
  assert_true(r.timing.queue_us >= 200000);
  assert_true(r.timing.total_us < HOLD_US);
  assert_int_equal(read_result(fd, &r, NULL, 0), 1);
  assert_int_equal(r.status, HFP_OK);
  assert_int_equal(r.batch, 1);
  close(fd);
  free(a);
  free(b);
}

/* A frame alone with a budget of 300 ms is not held for partners for the
 * 1.5 s the batcher would wait: it runs within its budget and is served. */
static void test_within_budget_not_held(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int fd = connect_versions_or_fail(S.unix_url, 4, 4);
  float *a = make_features(16, 16, v->cfg.spp, 4);
  send_filter(fd, 7, 16, 16, a, 300000);
  static float got[16 * 16 * 3], want[16 * 16 * 3];
  hfp_result r;
  assert_int_equal(read_result(fd, &r, got, sizeof got), 7);
  assert_int_equal(r.status, HFP_OK);
  assert_true(r.timing.queue_us < HOLD_US / 2);
  assert_int_equal(reference(v, 16, 16, a, HF_F32, want, HF_F32), 0);
  assert_memory_equal(got, want, sizeof want);
  close(fd);
  free(a);
}

/* Version 3 knows no DEADLINE flag: UNSUPPORTED, not fatal, and its STATS
 * carry three counters (expired reads 0 there, counted all the same). A
 * budget of 0 on version 4 is INVALID, not fatal. */
static void test_version_rules(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  float *a = make_features(8, 8, v->cfg.spp, 5);
  int fd = connect_versions_or_fail(S.unix_url, 1, 3);
  send_filter(fd, 9, 8, 8, a, 1000000);
  hfp_header h;
  hfp_error e;
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_UNSUPPORTED);
  assert_int_equal(e.fatal, 0);
  assert_int_equal(h.request_id, 9);
  assert_non_null(strstr(e.message, "version 4"));
  /* and what to do: offer version 4, or send the frame without the flag */
  assert_non_null(strstr(e.message, "HELLO"));
  assert_non_null(strstr(e.message, "without"));
  send_filter(fd, 10, 8, 8, a, 0);   /* still served */
  hfp_result r;
  assert_int_equal(read_result(fd, &r, NULL, 0), 10);
  assert_int_equal(r.status, HFP_OK);
  hfp_variant_stats st = variant_stats_or_fail(fd, "Small");
  assert_true(st.expired == 0);
  close(fd);

  fd = connect_versions_or_fail(S.unix_url, 4, 4);
  assert_true(variant_stats_or_fail(fd, "Small").expired >= 1);   /* test_expired_while_queue_held's */
  const ref_variant *sv = v;
  hfp_filter f;
  memset(&f, 0, sizeof f);
  strcpy(f.variant, "Small");
  f.width = f.height = 8;
  f.spp = (uint16_t)sv->cfg.spp;
  f.flags = HFP_FILTER_DEADLINE;
  f.budget_us = 1;
  f.data = a;
  assert_int_equal(hfp_features_bytes(8, 8, f.spp, HFP_F32, &f.data_len), 0);
  uint8_t head[HFP_FILTER_HEAD_MAX];
  uint64_t total;
  int n = hfp_encode_filter_head(head, sizeof head, 11, &f, &total);
  assert_true(n > 0);
  hfp_put_u32(head + HFP_HEADER_SIZE + HFP_FILTER_FIXED + 5, 0);   /* after "Small" */
  assert_int_equal(raw_send(fd, head, (size_t)n), 0);
  assert_int_equal(raw_send(fd, a, (size_t)f.data_len), 0);
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_INVALID);
  assert_int_equal(e.fatal, 0);
  assert_int_equal(h.request_id, 11);
  send_filter(fd, 12, 8, 8, a, 0);
  assert_int_equal(read_result(fd, &r, NULL, 0), 12);
  assert_int_equal(r.status, HFP_OK);
  close(fd);
  free(a);
}

/* libhairfilter: hfc_request.deadline_us goes to the daemon, a frame whose
 * budget passes while the batcher holds the queue completes with
 * HFC_E_EXPIRED and a message that names the budget, the next frame with
 * one is served; hfc_get_stats counts it. */
static void test_client_library(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  int spp = v->cfg.spp;
  hfc_client *c = client_connect(&S, "deadline-client");
  assert_non_null(c);
  assert_int_equal(hfc_info(c)->version, 4);
  hfc_stats st0;
  assert_int_equal(hfc_get_stats(c, &st0), 0);
  float *a = make_features(16, 16, spp, 6), *b = make_features(24, 20, spp, 7);
  static float out_a[16 * 16 * 3], out_b[24 * 20 * 3], want[24 * 20 * 3];
  hfc_request ra = TEST_REQUEST(.variant = "Small", .width = 16, .height = 16, .spp = spp,
                                .in_dtype = HFC_F32, .features = a, .out_dtype = HFC_F32,
                                .result = out_a, .user = (void *)1);
  hfc_request rb = TEST_REQUEST(.variant = "Small", .width = 24, .height = 20, .spp = spp,
                                .in_dtype = HFC_F32, .features = b, .out_dtype = HFC_F32,
                                .result = out_b, .user = (void *)2, .deadline_us = 150000);
  assert_int_equal(hfc_submit(c, &ra, NULL), 0);
  usleep(100000);
  assert_int_equal(hfc_submit(c, &rb, NULL), 0);
  for (int k = 0; k < 2; k++) {
    hfc_completion d;
    assert_int_equal(hfc_wait(c, 20000, &d), 0);
    if (d.user == (void *)2) {
      assert_int_equal(d.status, HFC_E_EXPIRED);
      assert_non_null(strstr(hfc_last_message(c), "deadline_us"));
      /* the budget's value, to tell by how much the server was behind */
      assert_non_null(strstr(hfc_last_message(c), "budget of 150000 us"));
      assert_true(d.timing.queue_us >= 150000);
    } else {
      assert_int_equal(d.status, 0);
    }
  }
  assert_non_null(strstr(hfc_strerror(HFC_E_EXPIRED), "deadline"));
  /* within its budget: served */
  rb.deadline_us = 30000000;
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &rb, &t), 0);
  assert_int_equal(reference(v, 24, 20, b, HF_F32, want, HF_F32), 0);
  assert_memory_equal(out_b, want, sizeof want);
  hfc_stats st1;
  assert_int_equal(hfc_get_stats(c, &st1), 0);
  uint64_t e0 = 0, e1 = 0;
  for (int i = 0; i < st0.num_variants; i++)
    if (!strcmp(st0.variants[i].name, "Small")) e0 = st0.variants[i].expired;
  for (int i = 0; i < st1.num_variants; i++)
    if (!strcmp(st1.variants[i].name, "Small")) e1 = st1.variants[i].expired;
  assert_true(e1 - e0 == 1);
  hfc_close(c);
  free(a);
  free(b);
}

/* The frames expired so far (three: test_expired_while_queue_held's,
 * test_expired_while_batcher_waits' and test_client_library's) in the operator's views: /metrics'
 * requests_total{status="expired",class="overload"}, the SIGUSR1
 * statistics line's expired=, and `hairfilter filter --stats`. */
static void test_reports(void **state) {
  (void)state;
  char *m = http_get(&S, "/metrics");
  assert_non_null(m);
  if (!strstr(m, "hairfilterd_requests_total{variant=\"Small\",status=\"expired\","
                 "class=\"overload\"} 3\n"))
    fail_msg("no expired count of 3 for Small in /metrics:\n%s", m);
  /* shown at zero too, for rate() and alerts */
  if (!strstr(m, "hairfilterd_requests_total{variant=\"Tiny\",status=\"expired\","
                 "class=\"overload\"} 0\n"))
    fail_msg("no expired series at 0 for Tiny in /metrics");
  /* The HELP line names the class of every status the samples carry. */
  if (!strstr(m, "overload (BUSY, EXPIRED)") || !strstr(m, "cancelled (CANCELLED)"))
    fail_msg("the HELP of hairfilterd_requests_total does not name EXPIRED's class and "
             "CANCELLED's:\n%s", m);
  free(m);
  usr1_line_or_fail(&S, "sanitised=0 expired=3");
  char text[8192];
  cli_stats_or_fail(&H, &S, text, sizeof text);
  /* failed counts EXPIRED and CANCELLED too (each also counted apart
   * below the table): the legend says so */
  if (!strstr(text, "EXPIRED and CANCELLED included"))
    fail_msg("the --stats legend does not say what failed counts:\n%s", text);
  if (!strstr(text, "  Small: 3 frame(s) expired in the queue, not computed"))
    fail_msg("no expired line in hairfilter filter --stats:\n%s", text);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_expired_while_queue_held),
      cmocka_unit_test(test_expired_while_batcher_waits),
      cmocka_unit_test(test_within_budget_not_held),
      cmocka_unit_test(test_version_rules),
      cmocka_unit_test(test_client_library),
      cmocka_unit_test(test_reports),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
