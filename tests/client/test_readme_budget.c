/* client/lib/README.md's hair_filter_budget, run against a daemon: a frame
 * an earlier call left in flight completes before the next call's own, and
 * must not be taken for it. The README's C blocks come in as one file
 * (snippets.cmake -DBODY), with its `hf`. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "readme_snippets.c"

#define W 32
#define HH 16

static void test_budget_reports_its_own_frame(void **state) {
  (void)state;
  harness H;
  assert_int_equal(harness_init(&H), 0);
  /* The batcher holds a frame half a second for partners: frame 1 is still
   * in flight when frame 2 is sent. */
  static const char *const holding[] = {"--max-batch", "4", "--max-queue-delay-us", "500000",
                                        NULL};
  server s;
  assert_int_equal(server_start(&H, &s, holding), 0);
  hfc_options o = test_options("readme-budget", NULL, 20000);
  assert_int_equal(hfc_connect(s.unix_url, &o, &hf), 0);
  size_t out_bytes = hfc_output_bytes(W, HH, 3, HFC_F32);
  float *f1 = make_features(W, HH, 4, 1), *f2 = make_features(W, HH, 4, 2);
  float *o1 = malloc(out_bytes), *o2 = malloc(out_bytes);
  assert_non_null(f1);
  assert_non_null(f2);
  assert_non_null(o1);
  assert_non_null(o2);
  hfc_request r1 = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                                .features = f1, .result = o1);
  hfc_request r2 = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = 4,
                                .features = f2, .result = o2);
  /* Frame 1, a budget of 10 s, not waited for: left in flight, and its
   * result let arrive (the batcher holds it half a second), so that it is
   * the first completion the next call meets whatever becomes of frame 2. */
  assert_int_equal(hair_filter_budget(&r1, 10000000, 0), 0);
  assert_int_equal(hfc_pending(hf), 1);
  struct pollfd pfd = {.fd = hfc_fd(hf), .events = POLLIN};
  assert_int_equal(poll(&pfd, 1, 20000), 1);
  /* Frame 2, a budget of 1 us: it passes before the batcher takes the
   * frame (almost always: it is answered EXPIRED, unrun), or the frame
   * runs. Either way hair_filter_budget must report frame 2's own fate,
   * not frame 1's OK, which comes first: 0 when the server's STATS count
   * one expired frame, 1 when none. */
  int got = hair_filter_budget(&r2, 1, 10000);
  hfc_completion done;
  while (hfc_pending(hf) > 0) assert_int_equal(hfc_wait(hf, 20000, &done), HFC_OK);
  hfc_stats *st = calloc(1, sizeof *st);
  assert_non_null(st);
  assert_int_equal(hfc_get_stats(hf, st), HFC_OK);
  uint64_t expired = 0;
  for (int i = 0; i < st->num_variants; i++)
    if (!strcmp(st->variants[i].name, "Small")) expired = st->variants[i].expired;
  free(st);
  assert_true(expired <= 1);
  if (got != (expired == 0))
    fail_msg("hair_filter_budget returned %d for frame 2, which the server %s: frame 1's "
             "result taken for frame 2's", got, expired ? "answered EXPIRED" : "computed");
  hfc_close(hf);
  hf = NULL;
  free(f1);
  free(f2);
  free(o1);
  free(o2);
  assert_int_equal(server_stop(&s, 20000), 0);
  harness_free(&H);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_budget_reports_its_own_frame),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
