/* Every blocking step of libhairfilter gives up after hfc_options.timeout_ms
 * (hairfilter.h), also in an engine whose threads take signals (an
 * interval timer, a profiler) and against a server that accepts no more
 * connections. A poll() interrupted by a signal waited the whole timeout
 * again, so a timer more frequent than the timeout kept hfc_filter on a
 * stopped server waiting for ever; and hfc_connect on a Unix socket whose
 * listener's queue is full blocked in connect() for ever. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/un.h>
#include <unistd.h>

#include "harness.h"

#define TIMEOUT_MS 1000

static harness H;

static int setup(void **state) {
  (void)state;
  return harness_init(&H);
}

static int teardown(void **state) {
  (void)state;
  harness_free(&H);
  return 0;
}

static void tick(int sig) { (void)sig; }

/* SIGALRM every 5 ms, its handler doing nothing (not SA_RESTART: poll()
 * is never restarted anyway). */
static void timer_on(int on) {
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on ? tick : SIG_DFL;
  sigaction(SIGALRM, &sa, NULL);
  struct itimerval it;
  memset(&it, 0, sizeof it);
  if (on) it.it_interval.tv_usec = it.it_value.tv_usec = 5000;
  setitimer(ITIMER_REAL, &it, NULL);
}

/* A frame to a stopped server while a 5 ms timer fires: HFC_E_TIMEOUT after
 * about the timeout, not never. */
static void test_timeout_under_timer(void **state) {
  (void)state;
  server s;
  assert_int_equal(server_start(&H, &s, NULL), 0);
  hfc_options o = test_options("signals", NULL, TIMEOUT_MS);
  hfc_client *c = NULL;
  assert_int_equal(hfc_connect(s.unix_url, &o, &c), HFC_OK);
  float *in = make_features(8, 8, 2, 5);
  float *out = malloc(hfc_output_bytes(8, 8, 3, HFC_F32));
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 8, .height = 8, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  assert_int_equal(server_pause(&s), 0);
  timer_on(1);
  double t0 = now_ms();
  /* Should the client never give up, a child wakes the server after 20 s. */
  pid_t guard = fork();
  if (guard == 0) {
    sleep(20);
    kill(s.pid, SIGCONT);
    _exit(0);
  }
  int rc = hfc_filter(c, &r, NULL);
  double took = now_ms() - t0;
  timer_on(0);
  kill(guard, SIGKILL);
  kill(s.pid, SIGCONT);
  if (rc != HFC_E_TIMEOUT || took > 5 * TIMEOUT_MS)
    fail_msg("hfc_filter on a stopped server under a 5 ms timer: %s after %.0f ms, want "
             "HFC_E_TIMEOUT after about %d ms (%s)", hfc_strerror(rc), took, TIMEOUT_MS,
             hfc_last_message(c));
  hfc_close(c);
  free(in);
  free(out);
  assert_int_equal(server_stop(&s, 20000), 0);
}

/* A Unix listener that accepts nothing and whose queue is full: hfc_connect
 * is HFC_E_CONNECT with ETIMEDOUT and a message saying what to check,
 * after about the timeout, whether or not a timer fires meanwhile. */
static void test_connect_queue_full(void **state) {
  (void)state;
  char path[104];
  int len = snprintf(path, sizeof path, "%s/full.sock", H.dir);
  assert_true(len > 0 && (size_t)len < sizeof path);
  struct sockaddr_un a;
  memset(&a, 0, sizeof a);
  a.sun_family = AF_UNIX;
  memcpy(a.sun_path, path, (size_t)len + 1);
  int l = socket(AF_UNIX, SOCK_STREAM, 0);
  assert_true(l >= 0);
  assert_int_equal(bind(l, (struct sockaddr *)&a, sizeof a), 0);
  assert_int_equal(listen(l, 0), 0);
  /* Fill its queue: non-blocking connects until one is refused. */
  int fill[8], nfill = 0;
  for (; nfill < 8; nfill++) {
    fill[nfill] = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0);
    if (connect(fill[nfill], (struct sockaddr *)&a, sizeof a) != 0) {
      assert_int_equal(errno, EAGAIN);
      break;
    }
  }
  assert_true(nfill < 8);
  char url[128];
  snprintf(url, sizeof url, "unix:%s", path);
  for (int timer = 0; timer < 2; timer++) {
    hfc_options o = test_options("signals", NULL, TIMEOUT_MS);
    hfc_client *c = NULL;
    /* Without the timer, one SIGALRM after 5 timeouts ends a connect that
     * would block for ever (it then fails with EINTR). */
    if (timer) {
      timer_on(1);
    } else {
      struct sigaction sa;
      memset(&sa, 0, sizeof sa);
      sa.sa_handler = tick;
      sigaction(SIGALRM, &sa, NULL);
      alarm(5 * TIMEOUT_MS / 1000);
    }
    double t0 = now_ms();
    int rc = hfc_connect(url, &o, &c);
    double took = now_ms() - t0;
    int err = errno;
    alarm(0);
    timer_on(0);
    if (rc != HFC_E_CONNECT || err != ETIMEDOUT || took > 5 * TIMEOUT_MS ||
        took < TIMEOUT_MS / 2)
      fail_msg("hfc_connect to a full queue%s: %s, errno %d, after %.0f ms; want "
               "HFC_E_CONNECT, ETIMEDOUT, after about %d ms (%s)", timer ? " under a timer" : "",
               hfc_strerror(rc), err, took, TIMEOUT_MS, hfc_last_message(NULL));
    assert_non_null(strstr(hfc_last_message(NULL), "is hairfilterd stopped or overloaded"));
    hfc_close(c);
  }
  for (int i = 0; i <= nfill; i++) close(fill[i]);
  close(l);
  unlink(path);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_timeout_under_timer),
      cmocka_unit_test(test_connect_queue_full),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
