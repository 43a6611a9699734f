/* An engine's variant removed by a reload (SIGHUP) and added back, while
 * the engine keeps its connection: frames for it are UNKNOWN_VARIANT with
 * a message that agrees with the server (the names this connection listed
 * before the reload still held the variant), and once it is back, frames
 * for it are filtered again on the same connection. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "harness.h"

static harness H;
static server S;
static char cfg[256], narrow[300];

static int write_cfg(int with_narrow) {
  FILE *f = fopen(cfg, "w");
  if (!f) return -1;
  if (with_narrow) fprintf(f, "weights = %s\n", narrow);
  return fclose(f);
}

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  /* Narrow: Small's shape, from a file of its own that the config names. */
  if (harness_narrow_weights(&H, NULL, narrow, sizeof narrow)) return -1;
  snprintf(cfg, sizeof cfg, "%s/reload.conf", H.dir);
  if (write_cfg(1)) return -1;
  const char *extra[] = {"--config", cfg, NULL};
  return server_start(&H, &S, extra);
}

static int teardown(void **state) {
  (void)state;
  return harness_stop(&H, &S);
}

/* Rewrites the config, sends SIGHUP and waits for the reload's end. */
static void reload(int with_narrow) {
  int before = server_log_count(&S, "reload done");
  assert_int_equal(write_cfg(with_narrow), 0);
  assert_int_equal(kill(S.pid, SIGHUP), 0);
  double deadline = now_ms() + 30000;
  while (server_log_count(&S, "reload done") == before) {
    if (now_ms() > deadline) {
      server_dump_log(&S);
      fail_msg("no 'reload done' within 30 s");
    }
    struct timespec ts = {0, 20 * 1000000L};
    nanosleep(&ts, NULL);
  }
}

static void test_variant_removed_and_back(void **state) {
  (void)state;
  const int w = 16, h = 16;
  float *in = make_features(w, h, 4, 9);
  float *out = malloc(hfc_output_bytes(w, h, 3, HFC_F32));
  assert_non_null(in);
  assert_non_null(out);
  hfc_client *c = client_connect(&S, "reload");
  assert_non_null(c);
  hfc_request r = TEST_REQUEST(.variant = "Narrow", .width = w, .height = h, .spp = 4,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);

  reload(0);
  /* The first frame after the removal: this connection's list, made
   * before the reload, still holds Narrow. */
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_E_UNKNOWN_VARIANT);
  const char *m = hfc_last_message(c);
  if (strstr(m, "has ") && strstr(strstr(m, "has "), "Narrow"))
    fail_msg("the message lists Narrow among the variants the server has: %s", m);
  assert_non_null(strstr(m, "reload has removed it"));
  /* The next: listed again, without Narrow. */
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_E_UNKNOWN_VARIANT);
  m = hfc_last_message(c);
  assert_non_null(strstr(m, "this server has "));
  if (strstr(strstr(m, "this server has "), "Narrow"))
    fail_msg("the message lists Narrow among the variants the server has: %s", m);

  reload(1);
  /* Back: the same connection filters it again. */
  int rc = hfc_filter(c, &r, NULL);
  if (rc) fail_msg("Narrow after it was added back: %s (%s)", hfc_strerror(rc), hfc_last_message(c));
  hfc_close(c);
  free(in);
  free(out);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_variant_removed_and_back),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
