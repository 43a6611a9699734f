/* A server that stops answering (SIGSTOP: its socket stays open, so no
 * error ever comes) while an engine collects its frames with hfc_wait, in
 * one long wait or a loop of polls: after hfc_options.timeout_ms of
 * silence the frames complete with HFC_E_TIMEOUT (one endpoint), or are
 * sent to the next endpoint (a list), as hfc_filter's do. They stayed
 * pending for as long as the server was stopped, and a list never failed
 * over. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "harness.h"

#define TIMEOUT_MS 2000
#define W 8
#define HT 8

static harness H;
static server A, B;
static float *in, *out;

static int setup(void **state) {
  (void)state;
  if (harness_init(&H) || server_start(&H, &A, NULL) || server_start(&H, &B, NULL)) return -1;
  in = make_features(W, HT, 2, 21);
  out = malloc(hfc_output_bytes(W, HT, 3, HFC_F32));
  return in && out ? 0 : -1;
}

static int teardown(void **state) {
  (void)state;
  free(in);
  free(out);
  int bad = server_stop(&B, 20000) != 0;
  return harness_stop(&H, &A) || bad;
}

static hfc_client *connect_url(const char *url) {
  hfc_options o = test_options("silent", NULL, TIMEOUT_MS);
  hfc_client *c = NULL;
  int rc = hfc_connect(url, &o, &c);
  if (rc) fail_msg("connect %s: %s (%s)", url, hfc_strerror(rc), hfc_last_message(NULL));
  return c;
}

/* A frame filtered (the variants listed), A stopped, one more submitted:
 * its completion, collected with one wait of 20 s (poll 0: a loop of
 * hfc_wait(c, 0) 20 ms apart), within that time. */
static hfc_completion stopped_frame(hfc_client *c, int poll, double *took_ms) {
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  assert_int_equal(server_pause(&A), 0);
  assert_int_equal(hfc_submit(c, &r, NULL), HFC_OK);
  double t0 = now_ms();
  hfc_completion d;
  int rc;
  if (poll) {
    while ((rc = hfc_wait(c, 0, &d)) == HFC_E_TIMEOUT && now_ms() - t0 < 20000) {
      /* Nothing yet: said so, with the frame still pending (the message
       * was empty, like a lost connection's). */
      if (!strstr(hfc_last_message(c), "1 request(s) still pending") && !kill(A.pid, SIGCONT))
        fail_msg("hfc_wait(c, 0) with a frame in flight: '%s', want it to say the frame is "
                 "still pending", hfc_last_message(c));
      struct timespec ts = {0, 20 * 1000000L};
      nanosleep(&ts, NULL);
    }
  } else {
    rc = hfc_wait(c, 20000, &d);
  }
  *took_ms = now_ms() - t0;
  kill(A.pid, SIGCONT);
  if (rc)
    fail_msg("hfc_wait on a stopped server: %s after %.0f ms (%s), want the frame's completion "
             "after about %d ms", hfc_strerror(rc), *took_ms, hfc_last_message(c), TIMEOUT_MS);
  return d;
}

static void test_one_endpoint(void **state) {
  (void)state;
  for (int poll = 0; poll < 2; poll++) {
    hfc_client *c = connect_url(A.unix_url);
    double took;
    hfc_completion d = stopped_frame(c, poll, &took);
    assert_int_equal(d.status, HFC_E_TIMEOUT);
    assert_non_null(strstr(hfc_last_message(c), "no reply for"));
    assert_true(took >= TIMEOUT_MS - 50 && took < 10000);
    /* Nothing pending on a connection given up: the loss's error, and a
     * message that says so (it was empty, leaving an engine that takes
     * HFC_E_TIMEOUT for "nothing yet" polling a dead connection blind). */
    assert_int_equal(hfc_pending(c), 0);
    assert_int_equal(hfc_wait(c, 0, &d), HFC_E_TIMEOUT);
    if (!strstr(hfc_last_message(c), "no request is pending") ||
        !strstr(hfc_last_message(c), "hfc_connect again"))
      fail_msg("hfc_wait after the loss: message '%s', want it to say nothing is pending and "
               "to connect again", hfc_last_message(c));
    hfc_close(c);
  }
}

static void test_list_fails_over(void **state) {
  (void)state;
  char url[600];
  snprintf(url, sizeof url, "%s,%s", A.unix_url, B.unix_url);
  for (int poll = 0; poll < 2; poll++) {
    hfc_client *c = connect_url(url);
    assert_string_equal(hfc_endpoint(c), A.unix_url);
    double took;
    hfc_completion d = stopped_frame(c, poll, &took);
    if (d.status != HFC_OK)
      fail_msg("the frame on the stopped server: %s (%s), want it filtered by the next",
               hfc_strerror(d.status), hfc_last_message(c));
    assert_int_equal(d.timing.resends, 1);
    assert_string_equal(hfc_endpoint(c), B.unix_url);
    hfc_close(c);
  }
}

/* No silence where replies wait: an engine that submits, then does not
 * collect for longer than the timeout (a loading screen), finds its
 * results, by one wait or by polls. */
static void test_pause_then_collect(void **state) {
  (void)state;
  hfc_client *c = connect_url(A.unix_url);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  for (int i = 0; i < 3; i++) assert_int_equal(hfc_submit(c, &r, NULL), HFC_OK);
  struct timespec ts = {(TIMEOUT_MS + 500) / 1000, (long)((TIMEOUT_MS + 500) % 1000) * 1000000L};
  nanosleep(&ts, NULL);
  for (int i = 0; i < 3; i++) {
    hfc_completion d;
    int rc = hfc_wait(c, i == 0 ? 0 : 20000, &d);
    if (rc || d.status)
      fail_msg("frame %d after a pause: %s / %s (%s)", i, hfc_strerror(rc), hfc_strerror(d.status),
               hfc_last_message(c));
  }
  hfc_completion none;
  assert_int_equal(hfc_wait(c, 0, &none), HFC_E_NOPENDING);
  assert_non_null(strstr(hfc_last_message(c), "no request is pending"));
  hfc_close(c);
}

/* hfc_filter on a stopped server gives the connection up after the
 * timeout as hfc_wait does, and says why in the same words, naming
 * hfc_options.timeout_ms (it said only "timed out waiting for the
 * server", which an engine that set timeout_ms to a frame budget could
 * not tell from a dead server). */
static void test_filter_names_the_timeout(void **state) {
  (void)state;
  hfc_client *c = connect_url(A.unix_url);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  assert_int_equal(server_pause(&A), 0);
  int rc = hfc_filter(c, &r, NULL);
  char msg[1024];
  snprintf(msg, sizeof msg, "%s", hfc_last_message(c));
  kill(A.pid, SIGCONT);
  assert_int_equal(rc, HFC_E_TIMEOUT);
  if (!strstr(msg, "no reply for") || !strstr(msg, "hfc_options.timeout_ms") ||
      !strstr(msg, "hfc_wait's timeout"))
    fail_msg("hfc_filter on a stopped server: '%s', want it to name hfc_options.timeout_ms and "
             "what a frame's deadline is", msg);
  hfc_close(c);
}

/* hfc_connect to a stopped server: the kernel accepts the connection, and
 * the HELLO goes unanswered; the error says how long it waited and what to
 * check (it said only "handshake: timed out waiting for the server"). */
static void test_connect_to_stopped(void **state) {
  (void)state;
  assert_int_equal(server_pause(&A), 0);
  hfc_options o = test_options("silent", NULL, 500);
  hfc_client *c = NULL;
  int rc = hfc_connect(A.unix_url, &o, &c);
  char msg[1024];
  snprintf(msg, sizeof msg, "%s", hfc_last_message(NULL));
  kill(A.pid, SIGCONT);
  hfc_close(c);
  assert_int_equal(rc, HFC_E_TIMEOUT);
  if (!strstr(msg, "no answer to HELLO within 500 ms") || !strstr(msg, "hfc_options.timeout_ms"))
    fail_msg("connect to a stopped server: '%s', want how long it waited and the option", msg);
}

/* An engine that waits for hfc_fd in its own event loop (poll without a
 * timeout: it has nothing else to do) and then collects with
 * hfc_wait(c, 0). The fd polls readable when the stopped server is due to
 * be given up, so the frame completes; it polled readable only for bytes
 * on a socket, and the engine waited for as long as the server was
 * stopped. */
static void test_fd_wakes_for_silence(void **state) {
  (void)state;
  hfc_client *c = connect_url(A.unix_url);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  assert_int_equal(server_pause(&A), 0);
  assert_int_equal(hfc_submit(c, &r, NULL), HFC_OK);
  double t0 = now_ms();
  hfc_completion d;
  int rc = HFC_E_TIMEOUT;
  /* The engine's loop; 20 s stands in for "for ever". */
  while (rc == HFC_E_TIMEOUT && now_ms() - t0 < 20000) {
    struct pollfd p = {hfc_fd(c), POLLIN, 0};
    if (poll(&p, 1, 20000 - (int)(now_ms() - t0)) <= 0) break;
    rc = hfc_wait(c, 0, &d);
  }
  double took = now_ms() - t0;
  kill(A.pid, SIGCONT);
  if (rc)
    fail_msg("poll(hfc_fd) then hfc_wait(c, 0) on a stopped server: %s after %.0f ms, want the "
             "frame's completion after about %d ms", hfc_strerror(rc), took, TIMEOUT_MS);
  assert_int_equal(d.status, HFC_E_TIMEOUT);
  assert_true(took >= TIMEOUT_MS - 50 && took < 10000);
  /* Nothing is owed any more: the fd is quiet again. */
  struct pollfd p = {hfc_fd(c), POLLIN, 0};
  assert_int_equal(poll(&p, 1, 100), 0);
  hfc_close(c);
}

/* A server killed before a frame is submitted: the send fails inside
 * hfc_submit, which returns 0 and leaves the frame's HFC_E_CLOSED as its
 * completion. No socket is left to poll readable, so hfc_fd must say a
 * completion waits, or an engine polling it waits for ever. */
static void test_fd_wakes_for_local_completion(void **state) {
  (void)state;
  server C;
  if (server_start(&H, &C, NULL)) fail_msg("a third server did not start");
  hfc_client *c = connect_url(C.unix_url);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  assert_int_equal(kill(C.pid, SIGKILL), 0);
  server_stop(&C, 20000);
  /* The send fails inside (the socket is still open on this side), and
   * the failure is the frame's completion: hfc_submit itself succeeds. */
  assert_int_equal(hfc_submit(c, &r, NULL), HFC_OK);
  struct pollfd p = {hfc_fd(c), POLLIN, 0};
  if (poll(&p, 1, 5000) != 1)
    fail_msg("hfc_submit took a frame whose send failed, and hfc_fd did not poll readable "
             "for its completion within 5 s");
  hfc_completion d;
  assert_int_equal(hfc_wait(c, 0, &d), HFC_OK);
  assert_int_not_equal(d.status, HFC_OK);
  hfc_close(c);
}

/* The same through hfc_shm_free: its SHM_DESTROY to a server killed with
 * a frame in flight fails, and the frame completes with the lost
 * connection. hfc_fd must poll readable for that completion; it stayed
 * quiet until the silence timeout (30 s here), as hfc_shm_free left the
 * descriptor's timer as hfc_submit had set it. */
static void test_fd_wakes_after_shm_free(void **state) {
  (void)state;
  server C;
  if (server_start(&H, &C, NULL)) fail_msg("a third server did not start");
  hfc_options o = test_options("silent", NULL, 30000);
  hfc_client *c = NULL;
  if (hfc_connect(C.unix_url, &o, &c))
    fail_msg("connect %s: %s", C.unix_url, hfc_last_message(NULL));
  void *seg = NULL;
  assert_int_equal(hfc_shm_alloc(c, 4096, &seg), HFC_OK);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_submit(c, &r, NULL), HFC_OK);
  assert_int_equal(kill(C.pid, SIGKILL), 0);
  server_stop(&C, 20000);
  assert_int_not_equal(hfc_shm_free(c, seg), HFC_OK);
  struct pollfd p = {hfc_fd(c), POLLIN, 0};
  if (poll(&p, 1, 5000) != 1)
    fail_msg("hfc_shm_free lost the connection with a frame in flight, and hfc_fd did not poll "
             "readable for the frame's completion within 5 s");
  hfc_completion d;
  assert_int_equal(hfc_wait(c, 0, &d), HFC_OK);
  assert_int_not_equal(d.status, HFC_OK);
  hfc_close(c);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_one_endpoint),
    cmocka_unit_test(test_list_fails_over),
    cmocka_unit_test(test_pause_then_collect),
    cmocka_unit_test(test_filter_names_the_timeout),
    cmocka_unit_test(test_connect_to_stopped),
    cmocka_unit_test(test_fd_wakes_for_silence),
    cmocka_unit_test(test_fd_wakes_for_local_completion),
    cmocka_unit_test(test_fd_wakes_after_shm_free),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
