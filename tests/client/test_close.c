/* hfc_close with frames in flight, as an engine does at shutdown: what the
 * client still holds for them is freed (completions read but never
 * collected keep their error message until hfc_wait returns them), shared
 * segments with frames on them are unmapped, and the daemon serves the
 * next client as before. Heap growth over many rounds is measured with
 * mallinfo2 (LeakSanitizer reports the same in sanitizer builds, where
 * mallinfo2 says nothing). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <malloc.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "harness.h"

static harness H;
static server S;

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  return server_start(&H, &S, NULL);
}

static int teardown(void **state) {
  (void)state;
  return harness_stop(&H, &S);
}

#define W 16
#define HT 16

/* One round: `bad` frames naming a variant the server lacks, then a good
 * frame filtered synchronously (which reads their UNKNOWN_VARIANT
 * answers on the way: they complete, uncollected), `inflight` more good
 * frames submitted, and the client closed. */
static void round_trip(const float *in, float *out, int bad, int inflight, int shm) {
  hfc_client *c = client_connect(&S, "close");
  assert_non_null(c);
  size_t in_bytes = hfc_features_bytes(W, HT, 2, HFC_F32);
  size_t out_bytes = hfc_output_bytes(W, HT, 3, HFC_F32);
  uint8_t *seg = NULL;
  if (shm) {
    assert_int_equal(hfc_shm_alloc(c, in_bytes + out_bytes, (void **)&seg), 0);
    memcpy(seg, in, in_bytes);
  }
  hfc_request r = TEST_REQUEST(.variant = "Nope", .width = W, .height = HT, .spp = 2,
                               .features = seg ? (const void *)seg : (const void *)in,
                               .result = seg ? (void *)(seg + in_bytes) : (void *)out);
  for (int i = 0; i < bad; i++) assert_int_equal(hfc_submit(c, &r, NULL), 0);
  r.variant = "Tiny";
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  assert_int_equal(hfc_pending(c), bad);
  for (int i = 0; i < inflight; i++) assert_int_equal(hfc_submit(c, &r, NULL), 0);
  hfc_close(c);
}

static void test_close_frees_uncollected(void **state) {
  (void)state;
  float *in = make_features(W, HT, 2, 5);
  float *out = malloc(hfc_output_bytes(W, HT, 3, HFC_F32));
  assert_non_null(in);
  assert_non_null(out);
  /* Warm-up rounds: whatever the first calls allocate for good
   * (OpenSSL's and libc's own tables) is not counted. */
  for (int i = 0; i < 3; i++) round_trip(in, out, 4, 2, i & 1);
  struct mallinfo2 before = mallinfo2();
  const int rounds = 40;
  for (int i = 0; i < rounds; i++) round_trip(in, out, 4, 2, i & 1);
  struct mallinfo2 after = mallinfo2();
  long grown = (long)after.uordblks - (long)before.uordblks;
  /* Each round leaked 4 messages of some 60 bytes before the fix: about
   * 10 KB over the rounds. */
  if (grown > 2048)
    fail_msg("the heap grew by %ld bytes over %d rounds of hfc_close with frames in flight",
             grown, rounds);
  /* The daemon serves on. */
  hfc_client *c = client_connect(&S, "after");
  assert_non_null(c);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HT, .spp = 2,
                               .features = in, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), HFC_OK);
  hfc_close(c);
  free(in);
  free(out);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_close_frees_uncollected),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
