/* Hostile and careless peers against a real hairfilterd (PROTOCOL.md,
 * "Handshake", "Errors", "Transport"; docs/SERVER.md, "Limits"): nothing is
 * served before the handshake, a HELLO that is not one is a PROTOCOL error,
 * a half-closed connection still gets every answer, replies that never left
 * are not counted as served, and peers that stall their handshake, trickle
 * a frame or crowd the server with unauthenticated connections lose their
 * slot. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "harness.h"

static harness H;
static server S;

/* Short deadlines so that the tests are quick; --max-handshakes small so
 * that the limit is reachable. */
static const char *const args[] = {"--handshake-timeout-ms", "500", "--stall-timeout-ms", "400",
                                   "--min-recv-rate", "64", "--max-handshakes", "4", NULL};

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  return server_start(&H, &S, args);
}

static int teardown(void **state) {
  (void)state;
  return harness_stop(&H, &S);
}

static void sleep_ms(int ms) { usleep((useconds_t)ms * 1000); }

static uint64_t ok_count(const char *variant) {
  hfc_client *c = NULL;
  hfc_options o = test_options("stats", NULL, 20000);
  assert_int_equal(hfc_connect(S.unix_url, &o, &c), 0);
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  hfc_close(c);
  for (int i = 0; i < st.num_variants; i++)
    if (!strcmp(st.variants[i].name, variant)) return st.variants[i].requests_ok;
  fail_msg("no variant %s in STATS", variant);
  return 0;
}

/* Sends bytes on a fresh connection to url and expects exactly one fatal
 * ERROR with code and request id 0, then the close. */
static void expect_refused(const char *url, const void *bytes, size_t n, int code,
                           const char *says) {
  int fd = raw_connect(url);
  assert_true(fd >= 0);
  assert_int_equal(raw_send(fd, bytes, n), 0);
  hfp_header h;
  hfp_error e;
  if (raw_read_error(fd, &h, &e)) fail_msg("%s: no ERROR", says);
  if ((int)e.code != code)
    fail_msg("%s: got %s (%s), want %s", says, hfp_code_name((int)e.code), e.message,
             hfp_code_name(code));
  assert_int_equal(h.request_id, 0);
  assert_int_equal(e.fatal, 1);
  assert_true(raw_closed(fd, 5000));
  close(fd);
}

/* Item: nothing but HELLO before the handshake, on the token-protected TCP
 * listener and on the Unix socket alike. */
static void test_nothing_before_hello(void **state) {
  (void)state;
  const char *urls[2] = {S.tcp_url, S.unix_url};
  for (int u = 0; u < 2; u++) {
    const char *url = urls[u];
    uint8_t b[1024];
    hfp_header h = {HFP_HELLO, 0, 0, 0};
    /* a zero-length HELLO, and STATS right behind it in the same send: one
     * ERROR, then the close; never a STATS_REPLY */
    hfp_header_encode(&h, b);
    hfp_header st = {HFP_STATS, 0, 0, 0};
    hfp_header_encode(&st, b + HFP_HEADER_SIZE);
    expect_refused(url, b, 2 * HFP_HEADER_SIZE, HFP_E_PROTOCOL, "zero-length HELLO");
    /* STATS, LIST_VARIANTS, SHM_CREATE, FILTER, a reply type: each first */
    int types[] = {HFP_STATS, HFP_LIST_VARIANTS, HFP_SHM_CREATE, HFP_FILTER, HFP_RESULT};
    for (size_t k = 0; k < sizeof types / sizeof types[0]; k++) {
      hfp_header x = {(uint16_t)types[k], 0, 5, types[k] == HFP_SHM_CREATE ? 8u : 0u};
      memset(b, 0, sizeof b);
      hfp_header_encode(&x, b);
      expect_refused(url, b, HFP_HEADER_SIZE + x.length, HFP_E_PROTOCOL, "request before HELLO");
    }
    /* HELLOs that are not one: too short, too long, a bad name, an empty
     * name, a byte too many: PROTOCOL, not LENGTH or INVALID */
    size_t n = raw_hello_frame(b, sizeof b, 1, 1, u == 0 ? TEST_TOKEN : NULL);
    assert_true(n > 0);
    uint8_t m[1024];
    for (uint32_t len = 1; len < 8; len += 3) {
      memcpy(m, b, n);
      hfp_put_u32(m + 12, len);
      expect_refused(url, m, HFP_HEADER_SIZE + len, HFP_E_PROTOCOL, "short HELLO");
    }
    memset(m, 'a', sizeof m);
    hfp_header big = {HFP_HELLO, 0, 0, 8 + HFP_NAME_MAX + HFP_TOKEN_MAX + 1};
    hfp_header_encode(&big, m);
    expect_refused(url, m, HFP_HEADER_SIZE + big.length, HFP_E_PROTOCOL, "long HELLO");
    memcpy(m, b, n);
    m[HFP_HEADER_SIZE + 8] = '\n';
    expect_refused(url, m, n, HFP_E_PROTOCOL, "HELLO with a control byte in the name");
    memcpy(m, b, n);
    hfp_put_u16(m + HFP_HEADER_SIZE + 4, 0);
    expect_refused(url, m, n, HFP_E_PROTOCOL, "HELLO with an empty name");
    memcpy(m, b, n);
    m[n] = 'x';
    hfp_put_u32(m + 12, hfp_get_u32(m + 12) + 1);
    expect_refused(url, m, n + 1, HFP_E_PROTOCOL, "HELLO with a trailing byte");
    /* A TLS ClientHello's first bytes (a handshake record, version 3.1) are
     * named as TLS on either kind of listener, not as a bad magic. */
    static const uint8_t client_hello[HFP_HEADER_SIZE] = {0x16, 0x03, 0x01, 0x02, 0x00, 0x01,
                                                          0x00, 0x01, 0xfc, 0x03, 0x03};
    int tfd = raw_connect(url);
    assert_true(tfd >= 0);
    assert_int_equal(raw_send(tfd, client_hello, sizeof client_hello), 0);
    hfp_header th;
    hfp_error te;
    if (raw_read_error(tfd, &th, &te)) fail_msg("TLS ClientHello on %s: no ERROR", url);
    assert_int_equal(te.code, HFP_E_PROTOCOL);
    if (!strstr(te.message, u == 0 ? "a TLS client on a plain tcp: listener"
                                   : "a TLS client on a Unix socket"))
      fail_msg("TLS ClientHello on %s: '%s'", url, te.message);
    close(tfd);
    /* and a correct one still works */
    int fd = raw_connect(url);
    assert_int_equal(raw_hello(fd, u == 0 ? TEST_TOKEN : NULL), 0);
    close(fd);
  }
  /* the token is checked on TCP */
  uint8_t b[512];
  size_t n = raw_hello_frame(b, sizeof b, 1, 1, "not-the-token");
  expect_refused(S.tcp_url, b, n, HFP_E_UNAUTHORIZED, "wrong token");
  n = raw_hello_frame(b, sizeof b, 1, 1, NULL);
  expect_refused(S.tcp_url, b, n, HFP_E_UNAUTHORIZED, "no token");
  assert_true(server_alive(&S));
}

/* Item: version ranges. The highest version in common: 0..1 holds 1,
 * 0..65535 the newest; ranges with none in common are VERSION. */
static void test_hello_versions(void **state) {
  (void)state;
  static const struct {
    uint16_t lo, hi;
    int code, version;
  } cases[] = {{0, 1, 0, 1},
               {1, 1, 0, 1},
               {1, 65535, 0, HFP_VERSION},
               {0, 65535, 0, HFP_VERSION},
               {HFP_VERSION + 1, HFP_VERSION + 2, HFP_E_VERSION, 0},
               {3, 2, HFP_E_VERSION, 0},
               {0, 0, HFP_E_VERSION, 0}};
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
    uint8_t b[512];
    size_t n = raw_hello_frame(b, sizeof b, cases[k].lo, cases[k].hi, TEST_TOKEN);
    if (cases[k].code) {
      expect_refused(S.tcp_url, b, n, cases[k].code, "version range");
      continue;
    }
    int fd = raw_connect(S.tcp_url);
    assert_int_equal(raw_send(fd, b, n), 0);
    hfp_header h;
    uint8_t *p;
    assert_int_equal(raw_read(fd, &h, &p), 0);
    if (h.type != HFP_HELLO_OK) fail_msg("%u..%u: no HELLO_OK", cases[k].lo, cases[k].hi);
    hfp_hello_ok ok;
    assert_int_equal(hfp_decode_hello_ok(p, h.length, &ok), 0);
    assert_int_equal(ok.version, cases[k].version);
    free(p);
    close(fd);
  }
}

/* Item: errors about the connection or a control request carry request id
 * 0, whatever id the request had; SHM_* on TCP is UNSUPPORTED, non-fatal. */
static void test_control_errors_carry_id_0(void **state) {
  (void)state;
  int fd = raw_connect(S.tcp_url);
  assert_int_equal(raw_hello(fd, TEST_TOKEN), 0);
  uint8_t b[64];
  int n = hfp_encode_shm_create(b, sizeof b, 4096);
  hfp_put_u32(b + 8, 55);
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  hfp_header h;
  hfp_error e;
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_UNSUPPORTED);
  assert_int_equal(h.request_id, 0);
  assert_int_equal(e.fatal, 0);
  n = hfp_encode_shm_destroy(b, sizeof b, 3);
  hfp_put_u32(b + 8, 9);
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_UNSUPPORTED);
  assert_int_equal(h.request_id, 0);
  /* the connection goes on */
  float *in = make_features(8, 8, 2, 3);
  size_t len;
  uint8_t *f = raw_filter(12, "Tiny", 8, 8, 2, in, &len);
  assert_int_equal(raw_send(fd, f, len), 0);
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  assert_int_equal(h.request_id, 12);
  free(p);
  /* a control request with a payload: fatal LENGTH, id 0 */
  hfp_header st = {HFP_STATS, 0, 31, 4};
  memset(b, 0, sizeof b);
  hfp_header_encode(&st, b);
  assert_int_equal(raw_send(fd, b, HFP_HEADER_SIZE + 4), 0);
  assert_int_equal(raw_read_error(fd, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_LENGTH);
  assert_int_equal(h.request_id, 0);
  assert_int_equal(e.fatal, 1);
  close(fd);
  free(f);
  free(in);
}

/* Item: a client that sends N FILTERs and shuts down its sending side gets
 * all N results (bit for bit the reference), then the close; STATS counts
 * exactly those N. Also when it stops in the middle of a frame: the frames
 * before it are answered. */
static void test_half_close_gets_every_answer(void **state) {
  (void)state;
  enum { N = 16, W = 16, HH = 12 };
  const ref_variant *v = harness_variant(&H, "Tiny");
  float *in[N];
  size_t len[N];
  uint8_t *fr[N];
  for (int i = 0; i < N; i++) {
    in[i] = make_features(W, HH, 2, 300 + (uint32_t)i);
    fr[i] = raw_filter((uint32_t)i + 1, "Tiny", W, HH, 2, in[i], &len[i]);
  }
  const char *urls[2] = {S.unix_url, S.tcp_url};
  for (int u = 0; u < 2; u++) {
    for (int cut = 0; cut < 2; cut++) {
      uint64_t before = ok_count("Tiny");
      int fd = raw_connect(urls[u]);
      assert_int_equal(raw_hello(fd, TEST_TOKEN), 0);
      /* cut: the last frame is sent only in part */
      int whole = cut ? N - 1 : N;
      for (int i = 0; i < whole; i++) assert_int_equal(raw_send(fd, fr[i], len[i]), 0);
      if (cut) assert_int_equal(raw_send(fd, fr[N - 1], len[N - 1] / 2), 0);
      assert_int_equal(shutdown(fd, SHUT_WR), 0);
      int seen[N] = {0};
      float want[W * HH * 3];
      for (int k = 0; k < whole; k++) {
        hfp_header h;
        uint8_t *p;
        if (raw_read(fd, &h, &p)) fail_msg("answer %d of %d missing after half-close", k, whole);
        assert_int_equal(h.type, HFP_RESULT);
        assert_true(h.request_id >= 1 && h.request_id <= (uint32_t)whole);
        int i = (int)h.request_id - 1;
        assert_int_equal(seen[i], 0);
        seen[i] = 1;
        hfp_result r;
        assert_int_equal(hfp_decode_result(p, h.length, &r), 0);
        assert_int_equal(r.status, 0);
        assert_int_equal(reference(v, W, HH, in[i], HF_F32, want, HF_F32), 0);
        assert_memory_equal(r.data, want, sizeof want);
        free(p);
      }
      assert_true(raw_closed(fd, 5000));
      close(fd);
      /* STATS counts exactly what was answered. */
      uint64_t after = ok_count("Tiny");
      assert_int_equal(after - before, (uint64_t)whole);
    }
  }
  for (int i = 0; i < N; i++) {
    free(in[i]);
    free(fr[i]);
  }
  assert_true(server_alive(&S));
}

/* Item: a peer that closes before its answers are written is not counted
 * as served (a Unix socket reports the failed write). */
static void test_unsent_answers_not_counted(void **state) {
  (void)state;
  enum { N = 3, W = 160, HH = 120 };
  float *in = make_features(W, HH, 4, 41);
  size_t len;
  uint8_t *f = raw_filter(1, "Small", W, HH, 4, in, &len);
  uint64_t before = ok_count("Small");
  int fd = raw_connect(S.unix_url);
  assert_int_equal(raw_hello(fd, NULL), 0);
  for (int i = 0; i < N; i++) {
    hfp_put_u32(f + 8, (uint32_t)i + 1);
    assert_int_equal(raw_send(fd, f, len), 0);
  }
  close(fd);
  /* A frame of another size is not batched with them and, the worker
   * being first in first out, is answered after they were computed. */
  hfc_client *c = NULL;
  hfc_options o = test_options("probe", NULL, 30000);
  assert_int_equal(hfc_connect(S.unix_url, &o, &c), 0);
  float out[8 * 4 * 3], *pin = make_features(8, 4, 4, 2);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = 8, .height = 4, .spp = 4, .in_dtype = HFC_F32,
                   .features = pin, .out_dtype = HFC_F32, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  hfc_close(c);
  assert_int_equal(ok_count("Small") - before, 1);
  free(pin);
  free(f);
  free(in);
}

/* Item: connections that never send a HELLO cannot fill --max-connections:
 * those --max-handshakes pushes out give their slot back at once (they are
 * not kept open to drain, as a connection closed after its HELLO is). */
static void test_bare_connections_leave_room(void **state) {
  (void)state;
  enum { M = 24 };
  server L;
  const char *largs[] = {"--max-connections", "8", "--max-handshakes", "2",
                         "--handshake-timeout-ms", "60000", NULL};
  assert_int_equal(server_start(&H, &L, largs), 0);
  int fd[M];
  for (int i = 0; i < M; i++) {
    fd[i] = raw_connect(L.tcp_url);
    assert_true(fd[i] >= 0);
    assert_int_equal(raw_send(fd[i], "x", 1), 0); /* input the server never reads */
  }
  sleep_ms(100);
  hfc_client *c = NULL;
  hfc_options o = test_options("legit", TEST_TOKEN, 20000);
  int rc = hfc_connect(L.tcp_url, &o, &c);
  if (rc) fail_msg("a client beside %d bare connections: %s (%s)", M, hfc_strerror(rc),
                   c ? hfc_last_message(c) : "");
  hfc_close(c);
  for (int i = 0; i < M; i++) close(fd[i]);
  assert_int_equal(server_stop(&L, 20000), 0);
}

/* Item: a fatal ERROR over TCP reaches a peer that sent more after the bad
 * frame and is slow to read: after every RESULT queued before it, and then
 * the end of the stream, not a reset. Closing a socket with unread input
 * makes the kernel reset the connection and drop what is still on its way
 * to the peer (PROTOCOL.md, "Errors": the client reads the ERROR before it
 * sees the connection broken). */
static void test_fatal_error_reaches_a_slow_reader(void **state) {
  (void)state;
  enum { N = 24, W = 64, HH = 64 };
  float *in = make_features(W, HH, 2, 17);
  size_t len;
  uint8_t *f = raw_filter(1, "Tiny", W, HH, 2, in, &len);
  int fd = raw_connect_rcvbuf(S.tcp_url, 4096);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, TEST_TOKEN), 0);
  for (int i = 0; i < N; i++) {
    hfp_put_u32(f + 8, (uint32_t)i + 1);
    assert_int_equal(raw_send(fd, f, len), 0);
  }
  /* Every frame computed, its RESULT queued behind the small window. */
  hfc_client *c = NULL;
  hfc_options o = test_options("queue", NULL, 20000);
  assert_int_equal(hfc_connect(S.unix_url, &o, &c), 0);
  double t0 = now_ms();
  for (;;) {
    hfc_stats st;
    assert_int_equal(hfc_get_stats(c, &st), 0);
    if (st.queue_depth == 0) break;
    assert_true(now_ms() - t0 < 20000);
    sleep_ms(50);
  }
  hfc_close(c);
  sleep_ms(300);
  /* A frame whose header is not one, and bytes the server never reads. */
  uint8_t bad[HFP_HEADER_SIZE + 1000];
  memset(bad, 'j', sizeof bad);
  memset(bad, 0xee, 4);
  assert_int_equal(raw_send(fd, bad, sizeof bad), 0);
  sleep_ms(300);
  for (int i = 0; i < N; i++) {
    hfp_header h;
    uint8_t *p;
    if (raw_read(fd, &h, &p)) fail_msg("RESULT %d of %d lost to the close", i + 1, N);
    assert_int_equal(h.type, HFP_RESULT);
    assert_int_equal(h.request_id, (uint32_t)i + 1);
    free(p);
  }
  hfp_header h;
  hfp_error e;
  if (raw_read_error(fd, &h, &e)) fail_msg("the fatal ERROR was lost to the close");
  assert_int_equal(e.code, HFP_E_PROTOCOL);
  assert_int_equal(e.fatal, 1);
  char byte;
  ssize_t r = recv(fd, &byte, 1, 0);
  if (r != 0) fail_msg("after the ERROR: %zd (%s), want the end of the stream", r,
                       r < 0 ? strerror(errno) : "data");
  close(fd);
  free(f);
  free(in);
  assert_true(server_alive(&S));
}

/* Item: the handshake has a deadline that trickled bytes do not extend. */
static void test_handshake_deadline(void **state) {
  (void)state;
  for (int trickle = 0; trickle < 2; trickle++) {
    uint8_t b[512];
    size_t n = raw_hello_frame(b, sizeof b, 1, 1, TEST_TOKEN);
    int fd = raw_connect(S.tcp_url);
    assert_true(fd >= 0);
    double t0 = now_ms();
    size_t sent = 0;
    hfp_header h;
    hfp_error e;
    for (;;) {
      if (trickle && sent < n - 1) assert_int_equal(raw_send(fd, b + sent++, 1), 0);
      struct timeval tv = {0, 100000};
      setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
      if (raw_read_error(fd, &h, &e) == 0) break;
      assert_true(now_ms() - t0 < 5000);
    }
    double took = now_ms() - t0;
    assert_int_equal(e.code, HFP_E_PROTOCOL);
    assert_int_equal(e.fatal, 1);
    assert_non_null(strstr(e.message, "no complete HELLO within 500 ms"));
    /* 500 ms, checked every 100: cut off between 0.5 and ~1 s. */
    assert_true(took >= 450 && took < 2500);
    close(fd);
  }
}

/* Item: a frame must arrive at --min-recv-rate; a byte every 100 ms is
 * never silent for the stall timeout, and still loses the connection. */
static void test_trickled_frame_is_cut_off(void **state) {
  (void)state;
  float *in = make_features(128, 128, 2, 5);
  size_t len;
  uint8_t *f = raw_filter(77, "Tiny", 128, 128, 2, in, &len);
  int fd = raw_connect(S.unix_url);
  assert_int_equal(raw_hello(fd, NULL), 0);
  assert_int_equal(raw_send(fd, f, 200), 0);
  double t0 = now_ms();
  hfp_header h;
  hfp_error e;
  size_t sent = 200;
  struct timeval tv = {0, 100000};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  while (raw_read_error(fd, &h, &e) != 0) {
    assert_true(now_ms() - t0 < 5000);
    assert_int_equal(raw_send(fd, f + sent, 16), 0);
    sent += 16;
  }
  assert_int_equal(e.code, HFP_E_PROTOCOL);
  assert_int_equal(e.fatal, 1);
  assert_int_equal(h.request_id, 77);
  assert_non_null(strstr(e.message, "under the minimum of 64 KiB/s"));
  assert_true(now_ms() - t0 < 2500);
  close(fd);
  /* the same frame sent at once is served */
  hfc_client *c = NULL;
  hfc_options o = test_options("fast", NULL, 20000);
  assert_int_equal(hfc_connect(S.unix_url, &o, &c), 0);
  static float out[128 * 128 * 3];
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 128, .height = 128, .spp = 2,
                   .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  hfc_close(c);
  free(f);
  free(in);
}

/* Item: connections before their HELLO have their own small limit; the
 * oldest of them makes room for a new one, so a real client gets in at
 * once however many silent ones there are. */
static void test_handshake_limit(void **state) {
  (void)state;
  enum { M = 6 };
  server L;
  const char *largs[] = {"--max-handshakes", "4", "--handshake-timeout-ms", "60000", NULL};
  assert_int_equal(server_start(&H, &L, largs), 0);
  int fd[M];
  for (int i = 0; i < M; i++) {
    fd[i] = raw_connect(L.tcp_url);
    assert_true(fd[i] >= 0);
    sleep_ms(20);
  }
  /* --max-handshakes 4: the two oldest were told BUSY and closed */
  for (int i = 0; i < 2; i++) {
    hfp_header h;
    hfp_error e;
    assert_int_equal(raw_read_error(fd[i], &h, &e), 0);
    assert_int_equal(e.code, HFP_E_BUSY);
    assert_int_equal(e.fatal, 1);
    assert_true(raw_closed(fd[i], 5000));
  }
  hfc_client *c = NULL;
  hfc_options o = test_options("legit", TEST_TOKEN, 20000);
  assert_int_equal(hfc_connect(L.tcp_url, &o, &c), 0);
  float in[8 * 8 * 12] = {0}, out[8 * 8 * 3];
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 8, .height = 8, .spp = 2, .in_dtype = HFC_F32,
                   .features = in, .out_dtype = HFC_F32, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  hfc_close(c);
  /* ...which cost the next oldest its slot */
  hfp_header h;
  hfp_error e;
  assert_int_equal(raw_read_error(fd[2], &h, &e), 0);
  assert_int_equal(e.code, HFP_E_BUSY);
  for (int i = 0; i < M; i++) close(fd[i]);
  assert_int_equal(server_stop(&L, 20000), 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_nothing_before_hello),
    cmocka_unit_test(test_hello_versions),
    cmocka_unit_test(test_control_errors_carry_id_0),
    cmocka_unit_test(test_half_close_gets_every_answer),
    cmocka_unit_test(test_unsent_answers_not_counted),
    cmocka_unit_test(test_fatal_error_reaches_a_slow_reader),
    cmocka_unit_test(test_handshake_deadline),
    cmocka_unit_test(test_trickled_frame_is_cut_off),
    cmocka_unit_test(test_handshake_limit),
    cmocka_unit_test(test_bare_connections_leave_room),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
