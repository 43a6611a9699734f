/* Fuzz target for every decoder. Built two ways:
 *   - as a libFuzzer target (tests/fuzz, clang -fsanitize=fuzzer), where
 *     LLVMFuzzerTestOneInput is the entry point;
 *   - as a ctest, where main() feeds it a few hundred thousand mutations of
 *     valid frames from a fixed seed, so every run is reproducible.
 * The property checked is the codec's contract: no decoder reads outside
 * its input, every result is 0 or a known negative code, and whatever
 * decodes re-encodes to a frame that decodes to the same thing. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfproto.h"

static int fail(const char *what, int rc) {
  fprintf(stderr, "fuzz_decode: %s returned %d\n", what, rc);
  abort();
}

static void check_rc(const char *what, int rc) {
  if (rc > 0 || rc <= -HFP_E_COUNT) fail(what, rc);
}

/* The text a server sends for a refused FILTER head: it reads only the
 * bytes that have arrived and is always a terminated, non-empty line. */
static void fault_text(const uint8_t *p, size_t avail, size_t len, int rc) {
  char why[200];
  memset(why, 'x', sizeof why);
  hfp_filter_fault(p, avail, len, rc, why, sizeof why);
  if (!memchr(why, 0, sizeof why) || !why[0]) fail("filter fault text", rc);
}

/* The head decoders a receiver uses while a frame arrives: every prefix
 * of the payload is either enough (0, or an error about the frame) or
 * asks for more (NOSPACE), and a prefix that decodes agrees with the whole. */
static void heads(const uint8_t *p, size_t len) {
  hfp_filter whole, part;
  size_t head_whole = 0, head_part = 0;
  int rw = hfp_decode_filter_head(p, len, len, &whole, &head_whole);
  check_rc("filter head", rw);
  if (rw && rw != -HFP_E_NOSPACE) fault_text(p, len, len, rw);
  for (size_t avail = 0; avail <= len && avail <= HFP_FILTER_HEAD_MAX - HFP_HEADER_SIZE;
       avail++) {
    int rp = hfp_decode_filter_head(p, avail, len, &part, &head_part);
    check_rc("filter head prefix", rp);
    if (rp && rp != -HFP_E_NOSPACE) fault_text(p, avail, len, rp);
    if (rp == 0 && (rw != 0 || head_part != head_whole || part.data_len != whole.data_len))
      fail("filter head prefix disagrees with the whole", rp);
    if (rp == 0) break;
  }
  hfp_result rwh, rph;
  rw = hfp_decode_result_head(p, len, len, &rwh);
  check_rc("result head", rw);
  if (len >= HFP_RESULT_FIXED) {
    int rp = hfp_decode_result_head(p, HFP_RESULT_FIXED, len, &rph);
    check_rc("result head prefix", rp);
    if ((rp == 0) != (rw == 0)) fail("result head prefix disagrees with the whole", rp);
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static hfp_stats st;
  static hfp_variant vs[HFP_MAX_VARIANTS];
  static uint8_t out[1 << 16];
  if (size < HFP_HEADER_SIZE) return 0;
  hfp_header h;
  int rc = hfp_header_decode(data, UINT32_MAX, &h);
  check_rc("header", rc);
  /* The payload is whatever follows; its length is the input's, so
   * length-mismatch paths get exercised too. Each type goes to its own
   * decoder; types no decoder knows still try them all. */
  const uint8_t *p = data + HFP_HEADER_SIZE;
  size_t len = size - HFP_HEADER_SIZE;
  int count;
  hfp_hello hello;
  hfp_hello_ok ok;
  hfp_filter f;
  hfp_result r;
  hfp_error e;
  uint64_t bytes;
  uint32_t seg;
  int all = h.type < 1 || h.type > HFP_TYPE_MAX;
  if (all || h.type == HFP_HELLO) {
    rc = hfp_decode_hello(p, len, &hello);
    check_rc("hello", rc);
    if (rc && rc != -HFP_E_VERSION) {
      char why[192];
      memset(why, 'x', sizeof why);
      hfp_hello_fault(p, len, rc, why, sizeof why);
      if (!memchr(why, 0, sizeof why) || !why[0]) fail("hello fault text", rc);
    }
    if (!rc && hfp_encode_hello(out, sizeof out, &hello) != (int)(HFP_HEADER_SIZE + len))
      fail("hello re-encode", 0);
  }
  if (all || h.type == HFP_HELLO_OK) {
    rc = hfp_decode_hello_ok(p, len, &ok);
    check_rc("hello_ok", rc);
    /* A version-2 HELLO_OK without its software block re-encodes with an
     * empty one, a byte longer. */
    if (!rc) {
      int n = hfp_encode_hello_ok(out, sizeof out, &ok);
      if (n != (int)(HFP_HEADER_SIZE + len) && !(ok.version >= 2 && n == (int)(HFP_HEADER_SIZE + len) + 1))
        fail("hello_ok re-encode", 0);
    }
  }
  if (all || h.type == HFP_VARIANTS) {
    rc = hfp_decode_variants(p, len, vs, HFP_MAX_VARIANTS, &count);
    check_rc("variants", rc);
    /* as version 1, or version 2 when ranges followed the entries, or
     * version 3 when the estimates followed those */
    if (!rc && hfp_encode_variants_v(out, sizeof out, vs, count, 1) != (int)(HFP_HEADER_SIZE + len) &&
        hfp_encode_variants_v(out, sizeof out, vs, count, 2) != (int)(HFP_HEADER_SIZE + len) &&
        hfp_encode_variants_v(out, sizeof out, vs, count, 3) != (int)(HFP_HEADER_SIZE + len))
      fail("variants re-encode", 0);
  }
  if (all || h.type == HFP_FILTER) {
    rc = hfp_decode_filter(p, len, &f);
    check_rc("filter", rc);
    /* The fields between the variant name and the data: the budget (flag
     * DEADLINE), then the shared-memory reference (flag SHM). */
    size_t head = HFP_FILTER_FIXED + strlen(f.variant) +
                  ((f.flags & HFP_FILTER_DEADLINE) ? HFP_DEADLINE_SIZE : 0);
    if (!rc && !(f.flags & HFP_FILTER_SHM) &&
        (f.data_len != len - head || (const uint8_t *)f.data + f.data_len != p + len))
      fail("filter data bounds", 0);
    if (!rc && (f.flags & HFP_FILTER_SHM)) {
      if (len != head + HFP_SHM_REF_SIZE) fail("shm filter bounds", 0);
      check_rc("shm_check", hfp_shm_check(&f, UINT64_MAX));
      check_rc("shm_check small", hfp_shm_check(&f, 4096));
    }
    heads(p, len);
  }
  if (all || h.type == HFP_RESULT) {
    rc = hfp_decode_result(p, len, &r);
    check_rc("result", rc);
    if (!rc && HFP_RESULT_FIXED + r.data_len + r.rgba_len != len) fail("result bounds", 0);
    heads(p, len);
  }
  if (all || h.type == HFP_ERROR) {
    rc = hfp_decode_error(p, len, &e);
    check_rc("error", rc);
  }
  if (all || h.type == HFP_STATS_REPLY) {
    rc = hfp_decode_stats(p, len, &st);
    check_rc("stats", rc);
    /* as version 1, or shorter than what came when counters followed (a
     * peer may send fewer or more counters than we keep) */
    if (!rc) {
      int e1 = hfp_encode_stats_v(out, sizeof out, &st, 1);
      int e2 = hfp_encode_stats_v(out, sizeof out, &st, 2);
      if (e1 != (int)(HFP_HEADER_SIZE + len) && !(e1 > 0 && e1 < (int)(HFP_HEADER_SIZE + len) && e2 > 0))
        fail("stats re-encode", 0);
    }
  }
  if (all || h.type == HFP_SHM_CREATE) check_rc("shm_create", hfp_decode_shm_create(p, len, &bytes));
  if (all || h.type == HFP_SHM_CREATED)
    check_rc("shm_created", hfp_decode_shm_created(p, len, &seg, &bytes));
  if (all || h.type == HFP_SHM_DESTROY) check_rc("shm_destroy", hfp_decode_shm_destroy(p, len, &seg));
  return 0;
}

#ifndef HF_LIBFUZZER
/* xorshift64*: deterministic across platforms. */
static uint64_t rng = 0x9e3779b97f4a7c15ull;
static uint64_t next(void) {
  rng ^= rng >> 12;
  rng ^= rng << 25;
  rng ^= rng >> 27;
  return rng * 2685821657736338717ull;
}

/* Builds a valid frame of each kind. */
enum { KINDS = 11 };
/* A whole FILTER of m with its inline tensors (m->data, m->data_len bytes)
 * after the head; the frame's length, or the encoder's error. */
static int filter_frame(uint8_t *b, size_t cap, uint32_t id, const hfp_filter *m) {
  uint64_t total;
  int n = hfp_encode_filter_head(b, cap, id, m, &total);
  if (n <= 0) return n;
  memcpy(b + n, m->data, m->data_len);
  return (int)total;
}

static size_t seed_frame(int kind, uint8_t *b, size_t cap) {
  int n = 0;
  switch (kind) {
    case 0: {
      hfp_hello m = {1, 2, "fuzz", "tok"};
      n = hfp_encode_hello(b, cap, &m);
      break;
    }
    case 1: {
      hfp_hello_ok m = {2, 3, 64, 64, 4, 8, 3, 2, 16, 1 << 20, "srv", "0.1.0"};
      n = hfp_encode_hello_ok(b, cap, &m);
      break;
    }
    case 2: {
      /* version 2: with a range block after the entry */
      hfp_variant v = {"Base", "cpu", "fp32", 4, 2, {16, 32}, 1, {{0, 0.015, 0.02}}, 0};
      n = hfp_encode_variants_v(b, cap, &v, 1, 2);
      break;
    }
    case 3: {
      static float d[2 * 2 * 6];
      hfp_filter m = {"Base", HFP_FILTER_COMPOSITE, 2, 2, 1, HFP_F32, HFP_F16, {0}, {0}, {0}, d,
                      sizeof d, 0, 0, 0, 0, 0};
      n = filter_frame(b, cap, 1, &m);
      break;
    }
    case 4: {
      static float d[2 * 1 * 3];
      hfp_result m = {0, HFP_F32, HFP_RESULT_OUT_OF_RANGE, 2, 1, 1, {1, 2, 3, 4, 10},
                      d, sizeof d, NULL, 0};
      uint64_t total;
      n = hfp_encode_result_head(b, cap, 1, &m, &total);
      if (n > 0) {
        memcpy(b + n, d, sizeof d);
        n = (int)total;
      }
      break;
    }
    case 5: {
      static hfp_stats s;
      s.num_variants = 1;
      strcpy(s.variants[0].name, "Base");
      s.variants[0].out_of_range = 3;
      n = hfp_encode_stats_v(b, cap, &s, 2);
      break;
    }
    case 6: {
      hfp_error m = {HFP_E_BUSY, 0, "queue full"};
      n = hfp_encode_error(b, cap, 7, &m);
      break;
    }
    case 7: {
      /* a FILTER by reference into a shared segment */
      hfp_filter m = {"Base", HFP_FILTER_SHM | HFP_FILTER_COMPOSITE, 3, 2, 1, HFP_F16, HFP_F16,
                      {0}, {0}, {0}, NULL, 3 * 2 * 6 * 2, 5, 0, 512, 1024, 0};
      n = hfp_encode_filter_head(b, cap, 2, &m, NULL);
      break;
    }
    case 8: n = hfp_encode_shm_created(b, cap, 3, 65536); break;
    case 9: {
      /* version 4: a budget, then the inline tensors */
      static float d[2 * 2 * 6];
      hfp_filter m = {"Base", HFP_FILTER_DEADLINE, 2, 2, 1, HFP_F32, HFP_F32, {0}, {0}, {0}, d,
                      sizeof d, 0, 0, 0, 0, 16000};
      n = filter_frame(b, cap, 3, &m);
      break;
    }
    case 10: {
      /* version 4: a budget, then a shared-memory reference */
      hfp_filter m = {"Base", HFP_FILTER_SHM | HFP_FILTER_DEADLINE, 3, 2, 1, HFP_F16, HFP_F16,
                      {0}, {0}, {0}, NULL, 3 * 2 * 6 * 2, 5, 0, 512, 0, 40000};
      n = hfp_encode_filter_head(b, cap, 4, &m, NULL);
      break;
    }
  }
  if (n <= 0) fail("seed", n);
  return (size_t)n;
}

int main(int argc, char **argv) {
  long iterations = argc > 1 ? atol(argv[1]) : 200000;
  static uint8_t frame[4096], mutated[4096];
  for (long it = 0; it < iterations; it++) {
    size_t n = seed_frame((int)(it % KINDS), frame, sizeof frame);
    memcpy(mutated, frame, n);
    size_t len = n;
    int edits = 1 + (int)(next() % 4);
    for (int e = 0; e < edits; e++) {
      uint64_t r = next();
      switch (r % 4) {
        case 0: mutated[HFP_HEADER_SIZE + (r >> 8) % (len - HFP_HEADER_SIZE + 1 > 1 ? len - HFP_HEADER_SIZE : 1)] ^= (uint8_t)(r >> 40); break;
        case 1: len = HFP_HEADER_SIZE + (r >> 8) % (n - HFP_HEADER_SIZE + 1); break;
        case 2: if (len < sizeof mutated) mutated[len++] = (uint8_t)(r >> 16); break;
        case 3: { size_t at = HFP_HEADER_SIZE + (r >> 8) % (n - HFP_HEADER_SIZE + 1);
                  if (at + 2 <= len) hfp_put_u16(mutated + at, (uint16_t)(r >> 32)); } break;
      }
    }
    LLVMFuzzerTestOneInput(mutated, len);
    /* pure random bytes too */
    if (it % 16 == 0) {
      size_t rl = HFP_HEADER_SIZE + next() % 200;
      for (size_t i = 0; i < rl; i++) mutated[i] = (uint8_t)next();
      hfp_put_u32(mutated, HFP_MAGIC);
      LLVMFuzzerTestOneInput(mutated, rl);
    }
  }
  printf("fuzz_decode: %ld iterations, no contract violation\n", iterations);
  return 0;
}
#endif
