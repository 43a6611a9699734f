/* libhairfilter with several endpoints (hfc_connect "A,B"): endpoints that
 * cannot be reached are passed over, with the retry policy of hfc_options;
 * a daemon stopped in the middle of a stream (killed, or draining after
 * SIGTERM) or answering BUSY hands its frames to the other, and every frame
 * still comes back equal to in-process cpu-ref inference. */
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
#include <time.h>
#include <unistd.h>

#include "harness.h"

#define W 96
#define HH 64
#define NSEEDS 3

static harness H;
static float *feat[NSEEDS], *want[NSEEDS];
static size_t in_bytes, out_bytes;

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  const ref_variant *v = harness_variant(&H, "Small");
  in_bytes = hfc_features_bytes(W, HH, v->cfg.spp, HFC_F32);
  out_bytes = hfc_output_bytes(W, HH, 3, HFC_F32);
  for (int i = 0; i < NSEEDS; i++) {
    feat[i] = make_features(W, HH, v->cfg.spp, 100 + (uint32_t)i);
    want[i] = malloc(out_bytes);
    if (!feat[i] || !want[i] || reference(v, W, HH, feat[i], HFP_F32, want[i], HFP_F32)) return -1;
  }
  return 0;
}

static int teardown(void **state) {
  (void)state;
  for (int i = 0; i < NSEEDS; i++) {
    free(feat[i]);
    free(want[i]);
  }
  harness_free(&H);
  return 0;
}

/* Waits for a daemon signalled outside server_stop; its exit status. */
static int reap(server *s) {
  int st;
  if (waitpid(s->pid, &st, 0) != s->pid) return -1;
  s->pid = 0;
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

static hfc_client *connect_list(const char *a, const char *b, unsigned failover) {
  char url[600];
  snprintf(url, sizeof url, "%s,%s", a, b);
  hfc_options o = test_options("failover", NULL, 20000);
  o.failover = failover;
  hfc_client *c = NULL;
  int rc = hfc_connect(url, &o, &c);
  if (rc) fail_msg("connect %s: %s (%s)", url, hfc_strerror(rc), hfc_last_message(NULL));
  return c;
}

typedef struct stream {
  int ok, failed, busy, resent, via_shm;
  int last_failure;
} stream;

/* Sends `total` Small frames through c, `window` in flight, checking each
 * result; after `at` completions, calls event(arg) once. Frames whose
 * buffers lie in shm (when not NULL, room for `window` slots) go by
 * reference while they can. */
static stream run_stream(hfc_client *c, int total, int window, int at, void (*event)(void *),
                         void *arg, uint8_t *shm) {
  stream st = {0};
  float *outs[16];
  int seed_of[16];
  assert_true(window <= 16);
  for (int i = 0; i < window; i++) {
    outs[i] = shm ? (float *)(shm + (in_bytes + out_bytes) * (size_t)i + in_bytes)
                  : malloc(out_bytes);
    assert_non_null(outs[i]);
  }
  int sent = 0, done = 0;
  for (; sent < window && sent < total; sent++) {
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                                 .features = feat[sent % NSEEDS], .result = outs[sent],
                                 .user = (void *)(intptr_t)sent);
    if (shm) {
      uint8_t *in = shm + (in_bytes + out_bytes) * (size_t)sent;
      memcpy(in, feat[sent % NSEEDS], in_bytes);
      r.features = in;
    }
    seed_of[sent] = sent % NSEEDS;
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  while (done < total) {
    hfc_completion d;
    int rc = hfc_wait(c, 30000, &d);
    if (rc) fail_msg("wait: %s (%s)", hfc_strerror(rc), hfc_last_message(c));
    int slot = (int)(intptr_t)d.user;
    done++;
    if (d.status == HFC_OK) {
      st.ok++;
      assert_memory_equal(outs[slot], want[seed_of[slot]], out_bytes);
    } else {
      st.failed++;
      st.last_failure = d.status;
      if (d.status == HFC_E_BUSY) st.busy++;
    }
    st.resent += d.timing.resends > 0;
    st.via_shm += d.timing.via_shm;
    if (done == at && event) event(arg);
    if (sent < total) {
      int seed = sent % NSEEDS;
      hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                                   .features = feat[seed], .result = outs[slot],
                                   .user = (void *)(intptr_t)slot);
      if (shm) {
        uint8_t *in = shm + (in_bytes + out_bytes) * (size_t)slot;
        memcpy(in, feat[seed], in_bytes);
        r.features = in;
      }
      seed_of[slot] = seed;
      memset(outs[slot], 0, out_bytes);
      rc = hfc_submit(c, &r, NULL);
      if (rc) fail_msg("submit: %s (%s)", hfc_strerror(rc), hfc_last_message(c));
      sent++;
    }
  }
  if (!shm)
    for (int i = 0; i < window; i++) free(outs[i]);
  return st;
}

static void kill_server(void *arg) { kill(((server *)arg)->pid, SIGKILL); }
static void term_server(void *arg) { kill(((server *)arg)->pid, SIGTERM); }

/* An endpoint that does not answer is passed over; with none answering,
 * the rounds of the retry policy are tried and every endpoint is named. */
static void test_unreachable_passed_over(void **state) {
  (void)state;
  server b;
  assert_int_equal(server_start(&H, &b, NULL), 0);
  char missing[300];
  snprintf(missing, sizeof missing, "unix:%s/missing.sock", H.dir);
  hfc_client *c = connect_list(missing, b.unix_url, 0);
  assert_string_equal(hfc_endpoint(c), b.unix_url);
  stream st = run_stream(c, 3, 1, 0, NULL, NULL, NULL);
  assert_int_equal(st.ok, 3);
  hfc_close(c);

  char url[700];
  snprintf(url, sizeof url, "%s,unix:%s/gone.sock", missing, H.dir);
  hfc_options o = test_options("rounds", NULL, 2000);
  o.connect_rounds = 3;
  o.retry_delay_ms = 60;
  double t0 = now_ms();
  assert_int_equal(hfc_connect(url, &o, &c), HFC_E_CONNECT);
  double took = now_ms() - t0;
  assert_true(took >= 2 * 60 - 5);
  const char *m = hfc_last_message(NULL);
  assert_non_null(strstr(m, "missing.sock: connect: "));
  assert_non_null(strstr(m, "gone.sock: connect: "));
  assert_non_null(strstr(m, "3 rounds"));
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* A killed daemon: the frames it had are sent to the other and every frame
 * of the stream comes back right. A single URL, as before, fails them. */
static void test_killed_mid_stream(void **state) {
  (void)state;
  server a, b;
  assert_int_equal(server_start(&H, &a, NULL), 0);
  assert_int_equal(server_start(&H, &b, NULL), 0);
  hfc_client *c = connect_list(a.unix_url, b.unix_url, 0);
  assert_string_equal(hfc_endpoint(c), a.unix_url);
  stream st = run_stream(c, 16, 4, 2, kill_server, &a, NULL);
  assert_int_equal(st.ok, 16);
  assert_int_equal(st.failed, 0);
  assert_true(st.resent >= 1);       /* frames in flight at the kill went to b */
  assert_string_equal(hfc_endpoint(c), b.unix_url);
  assert_int_equal(reap(&a), 128 + SIGKILL);
  hfc_close(c);

  /* One endpoint: no failover, the frames in flight fail with the loss. */
  server a2;
  assert_int_equal(server_start(&H, &a2, NULL), 0);
  c = client_connect(&a2, "single");
  assert_non_null(c);
  float *outs[4];
  for (int i = 0; i < 4; i++) {
    outs[i] = malloc(out_bytes);
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                                 .features = feat[0], .result = outs[i]);
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  kill(a2.pid, SIGKILL);
  int closed = 0;
  for (int i = 0; i < 4; i++) {
    hfc_completion d;
    assert_int_equal(hfc_wait(c, 20000, &d), 0);
    closed += d.status == HFC_E_CLOSED;
    assert_int_equal(d.timing.resends, 0);
    free(outs[i]);
  }
  assert_true(closed >= 1);
  assert_int_equal(reap(&a2), 128 + SIGKILL);
  hfc_close(c);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* Frames filtered in place (the result over the features) are not resent
 * when their daemon dies: the result may already have overwritten the
 * features. Frames beside them with their own result buffers are. */
static void test_in_place_not_resent(void **state) {
  (void)state;
  server a, b;
  assert_int_equal(server_start(&H, &a, NULL), 0);
  assert_int_equal(server_start(&H, &b, NULL), 0);
  hfc_client *c = connect_list(a.unix_url, b.unix_url, 0);
  enum { N = 6 };
  float *feats[N], *results[N];   /* results[i] == feats[i]: in place */
  for (int i = 0; i < N; i++) {
    int in_place = i % 2 == 0;
    feats[i] = malloc(in_bytes);
    results[i] = in_place ? feats[i] : malloc(out_bytes);
    assert_non_null(feats[i]);
    assert_non_null(results[i]);
    memcpy(feats[i], feat[i % NSEEDS], in_bytes);
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                                 .features = feats[i], .result = results[i],
                                 .user = (void *)(intptr_t)i);
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  kill(a.pid, SIGKILL);
  int resent = 0, failed_in_place = 0;
  for (int k = 0; k < N; k++) {
    hfc_completion d;
    assert_int_equal(hfc_wait(c, 20000, &d), 0);
    int i = (int)(intptr_t)d.user;
    if (i % 2 == 0) {
      assert_int_equal(d.timing.resends, 0);
      if (d.status == HFC_OK) assert_memory_equal(results[i], want[i % NSEEDS], out_bytes);
      else failed_in_place++;
    } else {
      assert_int_equal(d.status, HFC_OK);
      assert_memory_equal(results[i], want[i % NSEEDS], out_bytes);
      resent += d.timing.resends > 0;
    }
  }
  /* Some were in flight at the kill; the others came back before it. */
  assert_true(failed_in_place + resent >= 1);
  for (int i = 0; i < N; i++) {
    if (results[i] != feats[i]) free(results[i]);
    free(feats[i]);
  }
  assert_int_equal(reap(&a), 128 + SIGKILL);
  hfc_close(c);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* A daemon told to stop (SIGTERM) drains: what it admitted comes back from
 * it, and what it refuses (SHUTTING_DOWN) goes to the other. */
static void test_draining_mid_stream(void **state) {
  (void)state;
  server a, b;
  assert_int_equal(server_start(&H, &a, NULL), 0);
  assert_int_equal(server_start(&H, &b, NULL), 0);
  hfc_client *c = connect_list(a.unix_url, b.unix_url, 0);
  stream st = run_stream(c, 16, 4, 2, term_server, &a, NULL);
  assert_int_equal(st.ok, 16);
  assert_int_equal(st.failed, 0);
  assert_string_equal(hfc_endpoint(c), b.unix_url);
  assert_int_equal(reap(&a), 0);
  hfc_stats *s = malloc(sizeof *s);
  assert_int_equal(hfc_get_stats(c, s), 0);
  uint64_t on_b = 0;
  for (int i = 0; i < s->num_variants; i++) on_b += s->variants[i].requests_ok;
  assert_true(on_b >= 1 && on_b < 16);  /* both daemons served part of the stream */
  free(s);
  hfc_close(c);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* A daemon whose queue is full answers BUSY; with BUSY failover the frame
 * goes to the other and nothing is refused, without it the caller sees the
 * BUSY. */
static void test_busy_fails_over(void **state) {
  (void)state;
  static const char *const tight[] = {"--queue-size", "1", "--max-batch", "1", NULL};
  server a, b;
  assert_int_equal(server_start(&H, &a, tight), 0);
  assert_int_equal(server_start(&H, &b, NULL), 0);
  hfc_client *c = connect_list(a.unix_url, b.unix_url, 0);
  stream st = run_stream(c, 12, 6, 0, NULL, NULL, NULL);
  assert_int_equal(st.ok, 12);
  assert_int_equal(st.busy, 0);
  assert_true(st.resent >= 1);
  hfc_close(c);

  c = connect_list(a.unix_url, b.unix_url, HFC_FAILOVER_LOST);
  st = run_stream(c, 6, 6, 0, NULL, NULL, NULL);
  assert_true(st.busy >= 1);
  assert_int_equal(st.ok + st.busy, 6);
  assert_string_equal(hfc_endpoint(c), a.unix_url);
  hfc_close(c);
  assert_int_equal(server_stop(&a, 20000), 0);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* Frames in a shared segment of a daemon that is killed go to the other
 * through the socket, into the same memory. */
static void test_shared_memory_failover(void **state) {
  (void)state;
  server a, b;
  assert_int_equal(server_start(&H, &a, NULL), 0);
  assert_int_equal(server_start(&H, &b, NULL), 0);
  hfc_client *c = connect_list(a.unix_url, b.unix_url, 0);
  uint8_t *shm = NULL;
  assert_int_equal(hfc_shm_alloc(c, (in_bytes + out_bytes) * 4, (void **)&shm), 0);
  stream st = run_stream(c, 12, 4, 2, kill_server, &a, shm);
  assert_int_equal(st.ok, 12);
  assert_true(st.via_shm >= 1);      /* before the kill */
  assert_true(st.via_shm < 12);      /* after it, b has no part in a's segment */
  assert_int_equal(hfc_shm_free(c, shm), 0);
  assert_int_equal(reap(&a), 128 + SIGKILL);
  hfc_close(c);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* hfc_cancel whose CANCEL finds its connection gone: the frame that the
 * loss sends to the next endpoint is cancelled there (or before it is
 * sent), and completes once, CANCELLED, rather than computed. Both
 * daemons' batchers hold a frame for partners for seconds: on a, the
 * frame itself (so it is not answered before the kill); on b, a frame of
 * another size (so the frame sent again waits in b's queue). */
static void test_cancel_on_lost_connection(void **state) {
  (void)state;
  static const char *const holding[] = {"--max-batch", "4", "--max-queue-delay-us", "3000000",
                                        NULL};
  server a, b;
  assert_int_equal(server_start(&H, &a, holding), 0);
  assert_int_equal(server_start(&H, &b, holding), 0);
  hfc_options o = test_options("blocker", NULL, 20000);
  hfc_client *blk = NULL;
  assert_int_equal(hfc_connect(b.unix_url, &o, &blk), 0);
  float *blk_out = malloc(out_bytes), *out = malloc(out_bytes);
  assert_non_null(blk_out);
  assert_non_null(out);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = W / 2, .height = HH, .spp = 4,
                               .features = feat[0], .result = blk_out);
  assert_int_equal(hfc_submit(blk, &r, NULL), 0);

  hfc_client *c = connect_list(a.unix_url, b.unix_url, 0);
  r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                   .features = feat[1], .result = out);
  uint32_t id = 0;
  assert_int_equal(hfc_submit(c, &r, &id), 0);
  usleep(200000);   /* a's batcher holds it */
  kill(a.pid, SIGKILL);
  assert_int_equal(reap(&a), 128 + SIGKILL);
  int rc = hfc_cancel(c, id);
  assert_true(rc < 0);   /* the connection's error: the CANCEL did not go out on a */
  assert_non_null(strstr(hfc_last_message(c), "CANCEL of request"));
  hfc_completion d;
  rc = hfc_wait(c, 20000, &d);
  if (rc) fail_msg("wait: %s (%s)", hfc_strerror(rc), hfc_last_message(c));
  assert_int_equal(d.id, id);
  if (d.status != HFC_E_CANCELLED)
    fail_msg("the cancelled frame completed %s (%s), not CANCELLED", hfc_strerror(d.status),
             hfc_last_message(c));
  assert_int_equal(hfc_wait(c, 0, &d), HFC_E_NOPENDING);   /* exactly once */
  assert_int_equal(hfc_wait(blk, 20000, &d), 0);
  assert_int_equal(d.status, HFC_OK);
  hfc_close(c);
  hfc_close(blk);
  free(blk_out);
  free(out);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* Small's frames at b answered with a status other than OK or refused
 * (its blocker, served, counts in neither). */
static uint64_t small_frames_at(const server *b) {
  hfc_client *c = client_connect(b, "counter");
  assert_non_null(c);
  hfc_stats *s = malloc(sizeof *s);
  assert_non_null(s);
  assert_int_equal(hfc_get_stats(c, s), 0);
  uint64_t n = 0;
  for (int i = 0; i < s->num_variants; i++)
    if (!strcmp(s->variants[i].name, "Small"))
      n = s->variants[i].requests_failed + s->variants[i].rejected;
  free(s);
  hfc_close(c);
  return n;
}

/* hfc_last_message of resend_after_loss's completion. */
static char resend_msg[1024];

/* A frame with a budget that a's batcher holds when a is killed; the
 * client learns of the loss only at hfc_wait, wait_ms after the submit.
 * Returns its completion (its message in resend_msg), and b's frames not
 * served over it in *at_b. */
static hfc_completion resend_after_loss(server *a, server *b, uint32_t budget_us, int wait_ms,
                                        uint64_t *at_b) {
  uint64_t before = small_frames_at(b);
  hfc_client *c = connect_list(a->unix_url, b->unix_url, 0);
  float *out = malloc(out_bytes);
  assert_non_null(out);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                               .features = feat[2], .result = out, .deadline_us = budget_us);
  double t0 = now_ms();
  assert_int_equal(hfc_submit(c, &r, NULL), 0);
  usleep(200000);   /* a's batcher holds it */
  kill(a->pid, SIGKILL);
  assert_int_equal(reap(a), 128 + SIGKILL);
  double left = wait_ms - (now_ms() - t0);
  if (left > 0) usleep((useconds_t)(left * 1e3));
  hfc_completion d;
  int rc = hfc_wait(c, 20000, &d);
  if (rc) fail_msg("wait: %s (%s)", hfc_strerror(rc), hfc_last_message(c));
  snprintf(resend_msg, sizeof resend_msg, "%s", d.status ? hfc_last_message(c) : "");
  printf("budget %u us, loss seen after %d ms: %s, queued %.0f us (%s)\n", budget_us, wait_ms,
         d.status ? hfc_strerror(d.status) : "OK", d.timing.queue_us, resend_msg);
  hfc_completion again;
  assert_int_equal(hfc_wait(c, 0, &again), HFC_E_NOPENDING);   /* exactly once */
  hfc_close(c);
  free(out);
  *at_b = small_frames_at(b) - before;
  return d;
}

/* A frame sent again after a failover carries what remains of its budget,
 * not all of it again. Its budget is 2 s; a holds it and is killed, and
 * the client sends it to b 1.2 s after the submit, where the batcher holds
 * a frame of another size for 6 s: the frame waits in b's queue until
 * its budget passes and is answered EXPIRED, having waited there what
 * remained (under 0.8 s), not 2 s. Then a frame whose budget (1.5 s) has
 * passed when the loss is seen (1.8 s) is not sent at all: it completes
 * EXPIRED at once, and b gets nothing (which, with its full budget again,
 * would have expired there too); its hfc_timing.resends is 0. */
static void test_resend_remaining_budget(void **state) {
  (void)state;
  static const char *const holding[] = {"--max-batch", "4", "--max-queue-delay-us", "6000000",
                                        NULL};
  server a, b;
  assert_int_equal(server_start(&H, &a, holding), 0);
  assert_int_equal(server_start(&H, &b, holding), 0);
  hfc_options o = test_options("blocker", NULL, 30000);
  hfc_client *blk = NULL;
  assert_int_equal(hfc_connect(b.unix_url, &o, &blk), 0);
  float *blk_out = malloc(out_bytes);
  assert_non_null(blk_out);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = W / 2, .height = HH, .spp = 4,
                               .features = feat[0], .result = blk_out);
  assert_int_equal(hfc_submit(blk, &r, NULL), 0);

  uint64_t at_b;
  hfc_completion d = resend_after_loss(&a, &b, 2000000, 1200, &at_b);
  if (d.status != HFC_E_EXPIRED)
    fail_msg("the frame sent again completed %s, not EXPIRED", hfc_strerror(d.status));
  assert_int_equal(at_b, 1);
  assert_int_equal(d.timing.resends, 1);
  if (d.timing.queue_us >= 1500000)
    fail_msg("the frame sent again waited %.0f us at b: its whole budget of 2 s again, not what "
             "remained of it", d.timing.queue_us);
  assert_non_null(strstr(resend_msg, "what remained of hfc_request.deadline_us's 2000000 us"));

  assert_int_equal(server_start(&H, &a, holding), 0);
  d = resend_after_loss(&a, &b, 1500000, 1800, &at_b);
  if (d.status != HFC_E_EXPIRED)
    fail_msg("a frame whose budget had passed before it was sent again completed %s, not "
             "EXPIRED", hfc_strerror(d.status));
  assert_int_equal(at_b, 0);   /* not sent */
  assert_int_equal(d.timing.resends, 0);
  assert_non_null(strstr(resend_msg, "budget of 1500000 us"));
  assert_non_null(strstr(resend_msg, "not sent to"));

  assert_int_equal(hfc_wait(blk, 30000, &d), 0);
  assert_int_equal(d.status, HFC_OK);
  hfc_close(blk);
  free(blk_out);
  assert_int_equal(server_stop(&b, 20000), 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_unreachable_passed_over),
    cmocka_unit_test(test_killed_mid_stream),
    cmocka_unit_test(test_in_place_not_resent),
    cmocka_unit_test(test_draining_mid_stream),
    cmocka_unit_test(test_busy_fails_over),
    cmocka_unit_test(test_shared_memory_failover),
    cmocka_unit_test(test_cancel_on_lost_connection),
    cmocka_unit_test(test_resend_remaining_budget),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
