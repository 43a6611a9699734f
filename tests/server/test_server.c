/* Integration tests: a real hairfilterd on a temporary Unix socket and a
 * loopback TCP port, driven through libhairfilter and through raw sockets,
 * with every result compared bit for bit to in-process cpu-ref inference. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include "harness.h"

static harness H;
static server S;   /* the shared server: max-size 512x512, batching on */

static const char *const shared_args[] = {"--max-size", "512x512", "--max-batch", "4",
                                          "--max-queue-delay-us", "2000",
                                          "--max-frame-mb", "64", NULL};

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  return server_start(&H, &S, shared_args);
}

static int teardown(void **state) {
  (void)state;
  int rc = server_stop(&S, 20000);
  if (rc != 0) server_dump_log(&S);
  harness_free(&H);
  return rc == 0 ? 0 : -1;
}

static hfc_client *connect_unix(void);

/* STATS' protocol_errors now. */
static uint64_t protocol_errors(void) {
  hfc_client *c = connect_unix();
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  hfc_close(c);
  return st.protocol_errors;
}

static hfc_client *connect_unix(void) {
  hfc_client *c = NULL;
  hfc_options o = test_options("test", NULL, 20000);
  int rc = hfc_connect(S.unix_url, &o, &c);
  if (rc) fprintf(stderr, "connect %s: %s\n", S.unix_url, hfc_strerror(rc));
  assert_int_equal(rc, 0);
  return c;
}

static void check_timing(const hfc_timing *t) {
  assert_true(t->queue_us >= 0 && t->input_us >= 0 && t->infer_us >= 0 && t->output_us >= 0);
  assert_true(t->server_us > 0);
  assert_true(t->queue_us + t->input_us + t->infer_us + t->output_us <= t->server_us);
  assert_true(t->infer_us > 0);
  assert_true(t->server_us <= t->total_us);
  assert_true(t->batch >= 1);
}

/* Filters one frame through c and compares with in-process inference. */
static void filter_and_compare(hfc_client *c, const char *variant, int w, int h, int f16,
                               uint32_t seed) {
  const ref_variant *v = harness_variant(&H, variant);
  assert_non_null(v);
  int spp = v->cfg.spp;
  size_t n_in = (size_t)w * h * spp * HF_FEATURES_PER_SAMPLE, n_out = (size_t)w * h * 3;
  float *in = make_features(w, h, spp, seed);
  assert_non_null(in);
  void *send = in;
  uint16_t *in16 = NULL;
  if (f16) {
    in16 = malloc(n_in * 2);
    assert_non_null(in16);
    for (size_t i = 0; i < n_in; i++) in16[i] = hf_f32_to_f16(in[i]);
    send = in16;
  }
  size_t es = f16 ? 2 : 4;
  void *got = malloc(n_out * es), *want = malloc(n_out * es);
  assert_non_null(got);
  assert_non_null(want);
  memset(got, 0xcd, n_out * es);
  hfc_request r = TEST_REQUEST(.variant = variant, .width = w, .height = h, .spp = spp,
                   .in_dtype = f16 ? HFC_F16 : HFC_F32, .features = send,
                   .out_dtype = f16 ? HFC_F16 : HFC_F32, .result = got);
  hfc_timing t;
  int rc = hfc_filter(c, &r, &t);
  if (rc) fprintf(stderr, "filter %s %dx%d: %s (%s)\n", variant, w, h, hfc_strerror(rc),
                  hfc_last_message(c));
  assert_int_equal(rc, 0);
  check_timing(&t);
  assert_int_equal(reference(v, w, h, send, f16 ? HF_F16 : HF_F32, want, f16 ? HF_F16 : HF_F32), 0);
  assert_memory_equal(got, want, n_out * es);
  free(in);
  free(in16);
  free(got);
  free(want);
}

static void test_variants(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  const hfc_server_info *i = hfc_info(c);
  assert_int_equal(i->version, HFP_VERSION);
  assert_int_equal(i->max_width, 512);
  assert_int_equal(i->max_height, 512);
  assert_int_equal(i->max_spp, 4);
  assert_int_equal(i->max_batch, 4);
  assert_int_equal(i->auth_required, 0);
  assert_true(i->f16 && i->f32);
  hfc_variant v[8];
  int n = 0;
  assert_int_equal(hfc_list_variants(c, v, 8, &n), 0);
  assert_int_equal(n, 3);
  /* sorted by file name */
  assert_string_equal(v[0].name, "Mono");
  assert_string_equal(v[1].name, "Small");
  assert_string_equal(v[2].name, "Tiny");
  for (int k = 0; k < 3; k++) {
    const ref_variant *r = harness_variant(&H, v[k].name);
    assert_non_null(r);
    assert_int_equal(v[k].spp, r->cfg.spp);
    assert_int_equal(v[k].num_levels, r->cfg.num_levels);
    for (int l = 0; l < r->cfg.num_levels; l++) assert_int_equal(v[k].levels[l], r->cfg.levels[l]);
    assert_string_equal(v[k].backend, "cpu-ref");
    assert_string_equal(v[k].precision, "fp32");
  }
  hfc_close(c);
}

static void test_filter_sizes_unix(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  static const int sizes[][2] = {{1, 1}, {7, 5}, {64, 48}, {130, 66}};
  const char *names[] = {"Tiny", "Small", "Mono"};
  uint32_t seed = 1;
  for (int v = 0; v < 3; v++)
    for (int s = 0; s < 4; s++) filter_and_compare(c, names[v], sizes[s][0], sizes[s][1], 0, seed++);
  filter_and_compare(c, "Small", 33, 17, 1, 99);   /* f16 both ways */
  hfc_close(c);
}

static void test_filter_tcp_auth(void **state) {
  (void)state;
  hfc_client *c = NULL;
  hfc_options o = test_options("test-tcp", TEST_TOKEN, 20000);
  assert_int_equal(hfc_connect(S.tcp_url, &o, &c), 0);
  assert_int_equal(hfc_info(c)->auth_required, 1);
  filter_and_compare(c, "Tiny", 40, 24, 0, 7);
  filter_and_compare(c, "Mono", 96, 80, 0, 8);
  filter_and_compare(c, "Small", 17, 3, 1, 9);
  hfc_close(c);
  /* wrong token, and none */
  hfc_options bad = test_options("test-tcp", "wrong", 20000);
  assert_int_equal(hfc_connect(S.tcp_url, &bad, &c), HFC_E_UNAUTHORIZED);
  hfc_options none = test_options("test-tcp", NULL, 20000);
  assert_int_equal(hfc_connect(S.tcp_url, &none, &c), HFC_E_UNAUTHORIZED);
  assert_true(server_alive(&S));
}

static void test_composite(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  const ref_variant *v = harness_variant(&H, "Tiny");
  enum { W = 24, HH = 20 };
  float *in = make_features(W, HH, v->cfg.spp, 5);
  float got[W * HH * 3], rgba[W * HH * 4], want[W * HH * 3], rgb[W * HH * 3];
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HH, .spp = v->cfg.spp,
                   .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32, .result = got,
                   .rgba = rgba, .hair = {0.3f, 0.2f, 0.1f}, .light = {1, 0.9f, 0.8f},
                   .background = {0.1f, 0.2f, 0.4f});
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
  assert_memory_equal(got, want, sizeof want);
  hf_composite(want, W, HH, r.hair, r.light, r.background, rgb);
  for (int p = 0; p < W * HH; p++) {
    for (int k = 0; k < 3; k++) assert_true(rgba[p * 4 + k] == rgb[p * 3 + k]);
    assert_true(rgba[p * 4 + 3] == want[p * 3 + 2]);
  }
  free(in);
  hfc_close(c);
}

static void test_pipelined_32(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  assert_true(hfc_info(c)->max_inflight >= 32);
  enum { N = 32, W = 20, HH = 12 };
  const ref_variant *v = harness_variant(&H, "Tiny");
  float *in[N];
  float out[N][W * HH * 3];
  uint32_t ids[N];
  int seen[N] = {0};
  for (int i = 0; i < N; i++) {
    in[i] = make_features(W, HH, v->cfg.spp, 100 + (uint32_t)i);
    hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = W, .height = HH, .spp = v->cfg.spp,
                     .in_dtype = HFC_F32, .features = in[i], .out_dtype = HFC_F32,
                     .result = out[i], .user = (void *)(intptr_t)i);
    assert_int_equal(hfc_submit(c, &r, &ids[i]), 0);
  }
  assert_int_equal(hfc_pending(c), N);
  int max_batch = 0;
  for (int k = 0; k < N; k++) {
    hfc_completion done;
    assert_int_equal(hfc_wait(c, 20000, &done), 0);
    assert_int_equal(done.status, 0);
    int i = (int)(intptr_t)done.user;
    assert_true(i >= 0 && i < N);
    assert_int_equal(done.id, ids[i]);
    assert_int_equal(seen[i], 0);
    seen[i] = 1;
    check_timing(&done.timing);
    if (done.timing.batch > max_batch) max_batch = done.timing.batch;
  }
  hfc_completion none;
  assert_int_equal(hfc_wait(c, 0, &none), HFC_E_NOPENDING);
  /* Answers are right whatever batch they were computed in. */
  float want[W * HH * 3];
  for (int i = 0; i < N; i++) {
    assert_int_equal(reference(v, W, HH, in[i], HF_F32, want, HF_F32), 0);
    assert_memory_equal(out[i], want, sizeof want);
    free(in[i]);
  }
  /* 32 frames of one size queued at once on a max-batch-4 server. */
  assert_true(max_batch > 1 && max_batch <= 4);
  hfc_close(c);
}

/* A second connection is served while the first is half-way through
 * uploading a frame; then the first completes and is answered too. */
static void test_second_connection_mid_upload(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  enum { W = 64, HH = 64 };
  float *in = make_features(W, HH, v->cfg.spp, 77);
  size_t len;
  uint8_t *frame = raw_filter(41, "Small", W, HH, v->cfg.spp, in, &len);
  assert_non_null(frame);
  int fd = raw_connect(S.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);
  assert_int_equal(raw_send(fd, frame, len / 2), 0);

  hfc_client *c = connect_unix();
  filter_and_compare(c, "Tiny", 32, 32, 0, 78);
  hfc_close(c);

  assert_int_equal(raw_send(fd, frame + len / 2, len - len / 2), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  assert_int_equal(h.request_id, 41);
  hfp_result r;
  assert_int_equal(hfp_decode_result(p, h.length, &r), 0);
  assert_int_equal(r.status, 0);
  float want[W * HH * 3];
  assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
  assert_int_equal(r.data_len, sizeof want);
  assert_memory_equal(r.data, want, sizeof want);
  free(p);
  free(frame);
  free(in);
  close(fd);
}

static void test_disconnect_mid_frame(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Mono");
  float *in = make_features(100, 50, v->cfg.spp, 3);
  size_t len;
  uint8_t *frame = raw_filter(5, "Mono", 100, 50, v->cfg.spp, in, &len);
  assert_non_null(frame);
  for (int k = 0; k < 3; k++) {
    int fd = raw_connect(k == 1 ? S.tcp_url : S.unix_url);
    assert_true(fd >= 0);
    assert_int_equal(raw_hello(fd, TEST_TOKEN), 0);
    /* stop inside the header, inside the head, inside the tensor */
    size_t cut = k == 0 ? 7 : k == 1 ? HFP_HEADER_SIZE + 20 : len - 100;
    assert_int_equal(raw_send(fd, frame, cut), 0);
    close(fd);
  }
  free(frame);
  free(in);
  usleep(100000);
  assert_true(server_alive(&S));
  assert_true(server_log_has(&S, "peer left in the middle of a frame"));
  hfc_client *c = connect_unix();
  filter_and_compare(c, "Mono", 16, 16, 0, 4);
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  /* only this connection remains (the closes have been processed) */
  assert_int_equal(st.connections_open, 1);
  hfc_close(c);
}

/* Sends frame, expects ERROR code (non-fatal: the same connection then
 * serves a good request). */
static void expect_error(int fd, const uint8_t *frame, size_t len, uint32_t id, int code) {
  assert_int_equal(raw_send(fd, frame, len), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_ERROR);
  assert_int_equal(h.request_id, id);
  hfp_error e;
  assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
  assert_int_equal(e.code, code);
  assert_int_equal(e.fatal, 0);
  assert_true(strlen(e.message) > 0);
  free(p);
}

static void expect_result(int fd, const uint8_t *frame, size_t len, uint32_t id) {
  assert_int_equal(raw_send(fd, frame, len), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  assert_int_equal(h.request_id, id);
  free(p);
}

static void expect_fatal(int fd, const uint8_t *frame, size_t len, int code) {
  assert_int_equal(raw_send(fd, frame, len), 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_ERROR);
  hfp_error e;
  assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
  assert_int_equal(e.code, code);
  assert_int_equal(e.fatal, 1);
  free(p);
  assert_true(raw_closed(fd, 5000));
}

static void test_bad_requests_keep_connection(void **state) {
  (void)state;
  float *in = make_features(600, 8, 4, 1);
  int fd = raw_connect(S.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);
  size_t len;
  uint8_t *good = raw_filter(1, "Tiny", 8, 8, 2, in, &len);
  size_t glen = len;
  expect_result(fd, good, glen, 1);

  uint8_t *f = raw_filter(2, "Nope", 8, 8, 2, in, &len);
  expect_error(fd, f, len, 2, HFP_E_UNKNOWN_VARIANT);
  free(f);
  f = raw_filter(3, "Tiny", 600, 8, 2, in, &len);   /* over --max-size 512x512 */
  expect_error(fd, f, len, 3, HFP_E_TOO_LARGE);
  free(f);
  f = raw_filter(4, "Tiny", 8, 8, 4, in, &len);     /* Tiny takes 2 spp */
  expect_error(fd, f, len, 4, HFP_E_INVALID);
  free(f);
  /* payload 4 bytes short of what the dimensions say */
  f = raw_filter(5, "Tiny", 8, 8, 2, in, &len);
  hfp_put_u32(f + 12, hfp_get_u32(f + 12) - 4);
  expect_error(fd, f, len - 4, 5, HFP_E_LENGTH);
  free(f);
  /* unknown flag, bad dtype */
  f = raw_filter(6, "Tiny", 8, 8, 2, in, &len);
  hfp_put_u16(f + HFP_HEADER_SIZE + 2, 0x40);
  expect_error(fd, f, len, 6, HFP_E_UNSUPPORTED);
  free(f);
  f = raw_filter(7, "Tiny", 8, 8, 2, in, &len);
  f[HFP_HEADER_SIZE + 14] = 9;
  expect_error(fd, f, len, 7, HFP_E_UNSUPPORTED);
  free(f);
  /* the shared-memory flag on a frame that carries its tensor */
  f = raw_filter(8, "Tiny", 8, 8, 2, in, &len);
  hfp_put_u16(f + HFP_HEADER_SIZE + 2, HFP_FILTER_SHM);
  expect_error(fd, f, len, 8, HFP_E_LENGTH);
  free(f);
  /* request id 0 is reserved */
  f = raw_filter(9, "Tiny", 8, 8, 2, in, &len);
  hfp_put_u32(f + 8, 0);
  expect_error(fd, f, len, 0, HFP_E_INVALID);
  free(f);
  /* after all that, the connection still works */
  hfp_put_u32(good + 8, 10);
  expect_result(fd, good, glen, 10);

  /* a frame larger than --max-frame-mb: fatal, the connection closes */
  uint8_t hb[HFP_HEADER_SIZE];
  hfp_header big = {HFP_FILTER, 0, 11, 65u << 20};
  hfp_header_encode(&big, hb);
  expect_fatal(fd, hb, sizeof hb, HFP_E_TOO_LARGE);
  close(fd);

  /* bad magic: fatal */
  fd = raw_connect(S.unix_url);
  assert_int_equal(raw_hello(fd, NULL), 0);
  memcpy(hb, "GET / HTTP/1.1\r\n", 16);
  expect_fatal(fd, hb, sizeof hb, HFP_E_PROTOCOL);
  close(fd);
  /* FILTER before HELLO: fatal */
  fd = raw_connect(S.unix_url);
  expect_fatal(fd, good, glen, HFP_E_PROTOCOL);
  close(fd);
  /* a version the server does not speak: fatal */
  fd = raw_connect(S.unix_url);
  uint8_t hello[64];
  hfp_hello m = {1, 1, "future", ""};
  int n = hfp_encode_hello(hello, sizeof hello, &m);
  hfp_put_u16(hello + HFP_HEADER_SIZE, HFP_VERSION + 1);
  hfp_put_u16(hello + HFP_HEADER_SIZE + 2, HFP_VERSION + 2);
  expect_fatal(fd, hello, (size_t)n, HFP_E_VERSION);
  close(fd);
  /* a response type sent as a request: fatal */
  fd = raw_connect(S.unix_url);
  assert_int_equal(raw_hello(fd, NULL), 0);
  hfp_header res = {HFP_RESULT, 0, 1, 0};
  hfp_header_encode(&res, hb);
  expect_fatal(fd, hb, sizeof hb, HFP_E_PROTOCOL);
  close(fd);
  /* every server -> client type, also when it claims more than
   * --max-frame-mb: the type is checked before the length */
  static const uint16_t responses[] = {HFP_HELLO_OK, HFP_VARIANTS, HFP_RESULT, HFP_ERROR,
                                       HFP_STATS_REPLY, HFP_SHM_CREATED};
  for (size_t k = 0; k < sizeof responses / sizeof responses[0]; k++) {
    fd = raw_connect(S.unix_url);
    assert_int_equal(raw_hello(fd, NULL), 0);
    hfp_header r = {responses[k], 0, 0, (1u << 30) + 1};
    hfp_header_encode(&r, hb);
    expect_fatal(fd, hb, sizeof hb, HFP_E_PROTOCOL);
    close(fd);
  }

  free(good);
  free(in);
  assert_true(server_alive(&S));
  hfc_client *c = connect_unix();
  filter_and_compare(c, "Tiny", 8, 8, 0, 1);
  hfc_close(c);
}

static void test_stats(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  assert_int_equal(st.num_variants, 3);
  assert_int_equal(st.queue_capacity, 64);
  assert_true(st.uptime_us > 0);
  assert_true(st.connections_total >= 2);
  uint64_t ok = 0;
  for (int i = 0; i < st.num_variants; i++) {
    const hfc_variant_stats *v = &st.variants[i];
    uint64_t ht = 0, hi = 0;
    for (int b = 0; b < HFC_HIST_BUCKETS; b++) {
      ht += v->hist_total[b];
      hi += v->hist_infer[b];
    }
    assert_int_equal(ht, v->requests_ok);
    assert_int_equal(hi, v->requests_ok);
    assert_true(v->batches <= v->requests_ok);
    assert_true(v->sum_queue_us + v->sum_infer_us <= v->sum_total_us);
    ok += v->requests_ok;
    /* too large, wrong spp, id 0 (the rest fail before a variant is known) */
    if (!strcmp(v->name, "Tiny")) assert_true(v->rejected >= 3);
  }
  /* the earlier tests in this group filtered well over 40 frames */
  assert_true(ok >= 40);
  assert_true(st.protocol_errors >= 4);
  hfc_close(c);
}

/* A queue of one and a slow variant: a burst of pipelined frames must get
 * BUSY for some, at once, and correct results for the rest. */
static void test_busy_when_queue_full(void **state) {
  (void)state;
  server b;
  const char *args[] = {"--queue-size", "1", "--max-batch", "1", NULL};
  assert_int_equal(server_start(&H, &b, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("busy", NULL, 20000);
  assert_int_equal(hfc_connect(b.unix_url, &o, &c), 0);
  enum { N = 8, W = 160, HH = 160 };
  const ref_variant *v = harness_variant(&H, "Small");
  float *in = make_features(W, HH, v->cfg.spp, 11);
  static float out[N][W * HH * 3];
  for (int i = 0; i < N; i++) {
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = v->cfg.spp,
                     .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32,
                     .result = out[i], .user = (void *)(intptr_t)i);
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  int ok = 0, busy = 0;
  for (int k = 0; k < N; k++) {
    hfc_completion d;
    assert_int_equal(hfc_wait(c, 20000, &d), 0);
    if (d.status == HFC_E_BUSY) {
      busy++;
      /* rejected before admission: no server-side time was spent */
      assert_true(d.timing.server_us == 0);
    } else {
      assert_int_equal(d.status, 0);
      ok++;
    }
  }
  assert_true(busy >= 1);
  assert_true(ok >= 1);
  float *want = malloc(sizeof out[0]);
  assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
  /* every frame was the same, so any answered slot must equal the reference */
  int matched = 0;
  for (int i = 0; i < N; i++) matched += !memcmp(out[i], want, sizeof out[0]);
  assert_int_equal(matched, ok);
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  uint64_t rejected = 0;
  for (int i = 0; i < st.num_variants; i++) rejected += st.variants[i].rejected;
  assert_int_equal(rejected, (uint64_t)busy);
  free(want);
  free(in);
  hfc_close(c);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* A metric's value for variant="Small" in a /metrics body; fails when
 * absent. */
static double small_metric(const char *body, const char *name) {
  char key[160];
  snprintf(key, sizeof key, "\n%s{variant=\"Small\"} ", name);
  const char *at = strstr(body, key);
  if (!at) fail_msg("/metrics has no %s for Small", name);
  return strtod(at + strlen(key), NULL);
}

/* STATS' batches of Small, asked on c. */
static uint64_t small_batches(hfc_client *c) {
  static hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), 0);
  for (int i = 0; i < st.num_variants; i++)
    if (!strcmp(st.variants[i].name, "Small")) return st.variants[i].batches;
  fail_msg("STATS has no Small");
  return 0;
}

/* Item: every backend run counts as a batch, in STATS' batches and in
 * /metrics' hairfilterd_batch_size, whoever is still there to receive its
 * result (docs/SERVER.md, "Statistics"). A frame whose client closes while
 * it waits behind a long one still runs; its run is counted beside the
 * other two. */
static void test_batches_counted_when_client_gone(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-batch", "1", "--http", "tcp:127.0.0.1:0", NULL};
  hfc_client *c;
  assert_int_equal(server_start_connected(&H, &d, args, "stats", &c), 0);
  uint64_t batches0 = small_batches(c);
  char *m0 = http_get(&d, "/metrics");
  assert_non_null(m0);
  double count0 = small_metric(m0, "hairfilterd_batch_size_count");
  double sum0 = small_metric(m0, "hairfilterd_batch_size_sum");
  free(m0);
  /* A frame long enough (cpu-ref) that the next one waits behind it. */
  const int sizes[3] = {384, 32, 16};
  uint8_t *frames[3];
  size_t lens[3];
  for (int k = 0; k < 3; k++) {
    float *in = make_features(sizes[k], sizes[k], 4, (uint32_t)k + 1);
    frames[k] = raw_filter((uint32_t)k + 1, "Small", sizes[k], sizes[k], 4, in, &lens[k]);
    assert_non_null(frames[k]);
    free(in);
  }
  int stay = raw_connect(d.unix_url), gone = raw_connect(d.unix_url);
  assert_true(stay >= 0 && gone >= 0);
  assert_int_equal(raw_hello(stay, NULL), 0);
  assert_int_equal(raw_hello(gone, NULL), 0);
  assert_int_equal(raw_send(stay, frames[0], lens[0]), 0);
  usleep(20000);
  /* Admitted whole, then its client leaves before it has run. */
  assert_int_equal(raw_send(gone, frames[1], lens[1]), 0);
  close(gone);
  usleep(50000);
  assert_int_equal(raw_send(stay, frames[2], lens[2]), 0);
  for (uint32_t id = 1; id <= 3; id += 2) {
    hfp_header h;
    uint8_t *p;
    assert_int_equal(raw_read(stay, &h, &p), 0);
    assert_int_equal(h.type, HFP_RESULT);
    assert_int_equal(h.request_id, id);
    free(p);
  }
  /* The queue runs in order, so the frame whose client went ran before the
   * last one answered; its jobs may come back to the loop a moment later. */
  uint64_t batches = 0;
  for (int waited = 0; waited < 2000 && (batches = small_batches(c) - batches0) < 3;
       waited += 20)
    usleep(20000);
  char *m1 = http_get(&d, "/metrics");
  assert_non_null(m1);
  double count = small_metric(m1, "hairfilterd_batch_size_count") - count0;
  double sum = small_metric(m1, "hairfilterd_batch_size_sum") - sum0;
  free(m1);
  printf("3 backend runs, one whose client had gone: STATS batches +%llu, batch_size count "
         "+%g, sum +%g\n", (unsigned long long)batches, count, sum);
  assert_int_equal(batches, 3);
  assert_true(count == 3 && sum == 3);
  for (int k = 0; k < 3; k++) free(frames[k]);
  close(stay);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* SIGTERM with requests queued: they are finished (drain), new ones are
 * refused, the socket file is removed and the exit status is 0. */
static void test_sigterm_drains(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-batch", "1", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("drain", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  enum { N = 6, W = 96, HH = 96 };
  const ref_variant *v = harness_variant(&H, "Small");
  float *in = make_features(W, HH, v->cfg.spp, 21);
  static float out[N][W * HH * 3];
  for (int i = 0; i < N; i++) {
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = v->cfg.spp,
                     .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32,
                     .result = out[i]);
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  /* Wait until the first answer is in, so every frame has been received. */
  hfc_completion first;
  assert_int_equal(hfc_wait(c, 20000, &first), 0);
  assert_int_equal(first.status, 0);
  kill(d.pid, SIGTERM);
  int ok = 1;
  for (int k = 1; k < N; k++) {
    hfc_completion x;
    assert_int_equal(hfc_wait(c, 20000, &x), 0);
    assert_int_equal(x.status, 0);
    ok++;
  }
  assert_int_equal(ok, N);
  hfc_close(c);
  int st = server_stop(&d, 20000);
  assert_int_equal(st, 0);
  assert_true(server_log_has(&d, "SIGTERM: draining"));
  assert_true(server_log_has(&d, "stopped: "));
  assert_int_equal(access(d.unix_url + 5, F_OK), -1);
  free(in);
}

/* Frames sent while draining are refused with SHUTTING_DOWN: that is the
 * drain working, not an error, so no "error:" line is logged for them
 * (a rolling restart would trip error alerts); the stop line counts them
 * apart from the admitted requests. One frame waits in the batcher (a 2 s
 * delay for partners) while SIGTERM arrives; three sent after it are
 * refused; the waiting one is served. */
static void test_drain_refusals_counted(void **state) {
  (void)state;
  server d;
  /* Frame 0 waits for batch partners for 6 s, which the drain does not cut
   * short: the STATS polling, the SIGTERM and the log polling below must
   * end within it, with room on a loaded machine under a sanitizer. */
  const char *args[] = {"--max-batch", "16", "--max-queue-delay-us", "6000000", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL, *stats = NULL;
  hfc_options o = test_options("drain-refused", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  assert_int_equal(hfc_connect(d.unix_url, &o, &stats), 0);
  enum { W = 16, N = 4 };
  const ref_variant *v = harness_variant(&H, "Small");
  float *in = make_features(W, W, v->cfg.spp, 5);
  static float out[N][W * W * 3];
  hfc_request r[N];
  for (int i = 0; i < N; i++)
    r[i] = TEST_REQUEST(.variant = "Small", .width = W, .height = W, .spp = v->cfg.spp,
                        .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32,
                        .result = out[i]);
  assert_int_equal(hfc_submit(c, &r[0], NULL), 0);
  hfc_stats st;
  int queued = 0;
  for (int waited = 0; waited < 5000 && !queued; waited += 10) {
    assert_int_equal(hfc_get_stats(stats, &st), 0);
    if (!(queued = st.queue_depth == 1)) usleep(10000);
  }
  assert_true(queued);
  hfc_close(stats);
  kill(d.pid, SIGTERM);
  for (int waited = 0; waited < 5000 && !server_log_has(&d, "SIGTERM: draining"); waited += 10)
    usleep(10000);
  assert_true(server_log_has(&d, "SIGTERM: draining"));
  for (int i = 1; i < N; i++) assert_int_equal(hfc_submit(c, &r[i], NULL), 0);
  int served = 0, refused = 0;
  for (int k = 0; k < N; k++) {
    hfc_completion x;
    assert_int_equal(hfc_wait(c, 20000, &x), 0);
    served += x.status == 0;
    refused += x.status == HFC_E_SHUTTING_DOWN;
    /* The refusal says what the engine does next (it said only "server
     * is shutting down"). */
    if (x.status == HFC_E_SHUTTING_DOWN && !strstr(hfc_last_message(c), "connect again"))
      fail_msg("a frame refused while draining: '%s', want it to say what to do",
               hfc_last_message(c));
  }
  assert_int_equal(served, 1);
  assert_int_equal(refused, N - 1);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
  if (server_log_count(&d, "SHUTTING_DOWN: server is shutting down") != 0 ||
      !server_log_has(&d, "stopped: 1 request(s) served, 0 failed, 0 pushed out of the queue "
                          "(BUSY), 3 refused while draining (SHUTTING_DOWN)")) {
    server_dump_log(&d);
    fail_msg("refusals while draining logged as errors, or not in the stop line");
  }
  free(in);
}

/* --warm prepares every variant for the given shapes before the server
 * says it is ready (cpu-ref prepares nothing, but the path and the log are
 * the daemon's); --pipeline-depth 1 serves one run at a time; shapes
 * beyond --max-size or --max-batch are refused at startup. */
static void test_warm_and_pipeline_depth(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-batch", "2", "--warm", "64x48,32x32x2", "--pipeline-depth", "1",
                        NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("warm", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  const ref_variant *v = harness_variant(&H, "Small");
  float *in = make_features(64, 48, v->cfg.spp, 5);
  static float got[64 * 48 * 3], want[64 * 48 * 3];
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = 64, .height = 48, .spp = v->cfg.spp,
                   .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32, .result = got);
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(reference(v, 64, 48, in, HF_F32, want, HF_F32), 0);
  assert_memory_equal(got, want, sizeof got);
  hfc_close(c);
  free(in);
  assert_int_equal(server_stop(&d, 20000), 0);
  assert_true(server_log_has(&d, "variant Small: 64x48 batch 1 prepared in"));
  assert_true(server_log_has(&d, "variant Small: 32x32 batch 2 prepared in"));
  static const char *const bad[][2] = {{"--warm", "64x48x3"},        /* > --max-batch 2 */
                                       {"--warm", "9000x10"},        /* > --max-size */
                                       {"--warm", "64x"},
                                       {"--pipeline-depth", "3"}};
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    const char *a[] = {"--max-batch", "2", "--max-size", "4096x4096", bad[i][0], bad[i][1], NULL};
    assert_int_not_equal(server_start(&H, &d, a), 0);
  }
}

/* With no drain time, queued requests are failed with SHUTTING_DOWN (a
 * RESULT status), never dropped, and the exit status is still 0. */
static void test_sigterm_no_drain_time(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-batch", "1", "--drain-timeout-ms", "0", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  hfc_client *c = NULL;
  hfc_options o = test_options("drain0", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  enum { N = 6, W = 128, HH = 128 };
  const ref_variant *v = harness_variant(&H, "Small");
  float *in = make_features(W, HH, v->cfg.spp, 22);
  static float out[N][W * HH * 3];
  for (int i = 0; i < N; i++) {
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = v->cfg.spp,
                     .in_dtype = HFC_F32, .features = in, .out_dtype = HFC_F32,
                     .result = out[i]);
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  hfc_completion first;
  assert_int_equal(hfc_wait(c, 20000, &first), 0);
  assert_int_equal(first.status, 0);
  kill(d.pid, SIGTERM);
  int ok = 1, down = 0;
  for (int k = 1; k < N; k++) {
    hfc_completion x;
    assert_int_equal(hfc_wait(c, 20000, &x), 0);
    if (x.status == HFC_E_SHUTTING_DOWN)
      down++;
    else {
      assert_int_equal(x.status, 0);
      ok++;
    }
  }
  assert_int_equal(ok + down, N);
  assert_true(down >= 1);
  hfc_close(c);
  assert_int_equal(server_stop(&d, 20000), 0);
  free(in);
}

/* A RESULT with an error status echoes the FILTER's out_dtype (PROTOCOL.md,
 * RESULT `dtype`), as a successful one does: f16 out, then SIGTERM with
 * no drain time, so the queued frames get SHUTTING_DOWN. */
static void test_error_result_echoes_dtype(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--max-batch", "1", "--drain-timeout-ms", "0", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  enum { N = 6, W = 128, HH = 128 };
  const ref_variant *v = harness_variant(&H, "Small");
  float *in = make_features(W, HH, v->cfg.spp, 23);
  int fd = raw_connect(d.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);
  for (uint32_t id = 1; id <= N; id++) {
    size_t len;
    uint8_t *f = raw_filter(id, "Small", W, HH, v->cfg.spp, in, &len);
    assert_non_null(f);
    f[HFP_HEADER_SIZE + 15] = HFP_F16;   /* out_dtype */
    assert_int_equal(raw_send(fd, f, len), 0);
    free(f);
  }
  int ok = 0, failed = 0;
  for (int k = 0; k < N; k++) {
    hfp_header h;
    uint8_t *p;
    if (raw_read(fd, &h, &p)) break;
    assert_int_equal(h.type, HFP_RESULT);
    assert_true(h.length >= 4);
    const int status = p[0] | p[1] << 8;
    if (status == 0) ok++;
    else failed++;
    if (p[2] != HFP_F16)
      fail_msg("RESULT %u, status %d: dtype %u, the FILTER asked for %u", h.request_id, status,
               p[2], HFP_F16);
    free(p);
    if (k == 0) kill(d.pid, SIGTERM);
  }
  close(fd);
  assert_int_equal(server_stop(&d, 20000), 0);
  assert_true(ok >= 1);
  assert_true(failed >= 1);
  free(in);
}

/* A peer that stops in the middle of a frame is cut off after the stall
 * timeout, and one that never says HELLO after the handshake timeout,
 * instead of holding their buffers and slots forever. */
static void test_stalled_peer_is_closed(void **state) {
  (void)state;
  server d;
  const char *args[] = {"--stall-timeout-ms", "300", "--handshake-timeout-ms", "300", NULL};
  assert_int_equal(server_start(&H, &d, args), 0);
  float *in = make_features(32, 32, 2, 1);
  size_t len;
  uint8_t *f = raw_filter(17, "Tiny", 32, 32, 2, in, &len);
  int fd = raw_connect(d.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);
  assert_int_equal(raw_send(fd, f, len / 3), 0);
  int silent = raw_connect(d.unix_url);
  assert_true(silent >= 0);
  hfp_header h;
  uint8_t *p;
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_ERROR);
  assert_int_equal(h.request_id, 17);
  hfp_error e;
  assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
  assert_int_equal(e.code, HFP_E_PROTOCOL);
  assert_int_equal(e.fatal, 1);
  free(p);
  assert_true(raw_closed(fd, 5000));
  assert_int_equal(raw_read_error(silent, &h, &e), 0);
  assert_int_equal(e.code, HFP_E_PROTOCOL);
  assert_non_null(strstr(e.message, "no complete HELLO within 300 ms"));
  assert_true(raw_closed(silent, 5000));
  close(fd);
  close(silent);
  /* an idle connection between frames is left alone */
  hfc_client *c = NULL;
  hfc_options o = test_options("idle", NULL, 20000);
  assert_int_equal(hfc_connect(d.unix_url, &o, &c), 0);
  usleep(700000);
  float out[32 * 32 * 3];
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 32, .height = 32, .spp = 2, .in_dtype = HFC_F32,
                   .features = in, .out_dtype = HFC_F32, .result = out);
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  hfc_close(c);
  free(f);
  free(in);
  assert_int_equal(server_stop(&d, 20000), 0);
}

/* The CLI end to end: feature EXR in, result EXR and server-composited
 * PNG out, timing printed; the EXR holds exactly the reference result. */
static void test_cli_filter(void **state) {
  (void)state;
  const ref_variant *v = harness_variant(&H, "Small");
  enum { W = 40, HH = 28 };
  float *in = make_features(W, HH, v->cfg.spp, 55);
  hf_image img = {0};
  assert_int_equal(hf_features_to_image(in, W, HH, v->cfg.spp, &img), 0);
  char feat[300], res[300], png[300], outtxt[300], cmd[2000];
  snprintf(feat, sizeof feat, "%s/cli_features.exr", H.dir);
  snprintf(res, sizeof res, "%s/cli_result.exr", H.dir);
  snprintf(png, sizeof png, "%s/cli_preview.png", H.dir);
  snprintf(outtxt, sizeof outtxt, "%s/cli_out.txt", H.dir);
  assert_int_equal(hf_exr_write(feat, &img, 0), 0);
  hf_image_free(&img);
  snprintf(cmd, sizeof cmd, "'%s' filter --server '%s' --variant Small --in '%s' --out '%s' "
           "--png '%s' > '%s' 2>&1", HAIRFILTER_CLI_PATH, S.unix_url, feat, res, png, outtxt);
  int rc = system(cmd);
  if (rc != 0) {
    snprintf(cmd, sizeof cmd, "cat '%s' >&2", outtxt);
    if (system(cmd)) {}
  }
  assert_int_equal(rc, 0);
  FILE *f = fopen(outtxt, "r");
  assert_non_null(f);
  char text[4096];
  size_t n = fread(text, 1, sizeof text - 1, f);
  fclose(f);
  text[n] = 0;
  assert_non_null(strstr(text, "infer"));
  assert_non_null(strstr(text, "server"));
  assert_non_null(strstr(text, "network"));
  char err[256];
  hf_image out = {0};
  assert_int_equal(hf_exr_read(res, &out, err, sizeof err), 0);
  assert_int_equal(out.width, W);
  assert_int_equal(out.height, HH);
  float want[W * HH * 3];
  assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
  const char *names[3] = {"color", "highlight", "alpha"};
  for (int k = 0; k < 3; k++) {
    int ch = hf_image_channel(&out, names[k]);
    assert_true(ch >= 0);
    for (int p = 0; p < W * HH; p++) assert_true(out.data[p * out.channels + ch] == want[p * 3 + k]);
  }
  hf_image_free(&out);
  assert_int_equal(access(png, F_OK), 0);
  /* A frame with a background layer (an opaque red one): the PNG is
   * composited over it on the client, byte for byte the preview of
   * hairfilter infer on the same weights and backend, and not the server's
   * composite over the flat background. */
  hf_image plain = {0}, layered = {0};
  assert_int_equal(hf_features_to_image(in, W, HH, v->cfg.spp, &plain), 0);
  assert_int_equal(hf_image_alloc(&layered, W, HH, plain.channels + 4), 0);
  for (int ch = 0; ch < plain.channels; ch++) memcpy(layered.names[ch], plain.names[ch], 32);
  for (int k = 0; k < 4; k++)
    snprintf(layered.names[plain.channels + k], 32, "background.%c", "RGBA"[k]);
  for (int p = 0; p < W * HH; p++) {
    memcpy(layered.data + (size_t)p * layered.channels, plain.data + (size_t)p * plain.channels,
           (size_t)plain.channels * sizeof(float));
    for (int k = 0; k < 4; k++) layered.data[(size_t)p * layered.channels + plain.channels + k] =
                                    k == 1 || k == 2 ? 0.0f : 1.0f;
  }
  char lfeat[300], lpng[300], ipng[300], ires[300];
  snprintf(lfeat, sizeof lfeat, "%s/cli_layered.exr", H.dir);
  snprintf(lpng, sizeof lpng, "%s/cli_layered.png", H.dir);
  snprintf(ipng, sizeof ipng, "%s/cli_layered_infer.png", H.dir);
  snprintf(ires, sizeof ires, "%s/cli_layered_infer.exr", H.dir);
  assert_int_equal(hf_exr_write(lfeat, &layered, 0), 0);
  hf_image_free(&plain);
  hf_image_free(&layered);
  char both[4000];
  snprintf(both, sizeof both, "'%s' filter --server '%s' --variant Small --in '%s' --out '%s' "
           "--png '%s' > '%s' 2>&1 && '%s' infer --backend cpu-ref --weights '%s/Small.safetensors' "
           "--in '%s' --out '%s' --png '%s' >> '%s' 2>&1", HAIRFILTER_CLI_PATH, S.unix_url, lfeat,
           res, lpng, outtxt, HAIRFILTER_CLI_PATH, H.weights_dir, lfeat, ires, ipng, outtxt);
  rc = system(both);
  if (rc != 0) {
    snprintf(cmd, sizeof cmd, "cat '%s' >&2", outtxt);
    if (system(cmd)) {}
  }
  assert_int_equal(rc, 0);
  snprintf(cmd, sizeof cmd, "cmp -s '%s' '%s'", lpng, ipng);
  assert_int_equal(system(cmd), 0);
  snprintf(cmd, sizeof cmd, "cmp -s '%s' '%s'", lpng, png);
  assert_int_not_equal(system(cmd), 0);
  /* an unknown variant fails with a message and status 1 */
  snprintf(cmd, sizeof cmd, "'%s' filter --server '%s' --variant Nope --in '%s' --out '%s' "
           "> '%s' 2>&1", HAIRFILTER_CLI_PATH, S.unix_url, feat, res, outtxt);
  rc = system(cmd);
  assert_true(WIFEXITED(rc) && WEXITSTATUS(rc) == 1);
  f = fopen(outtxt, "r");
  assert_non_null(f);
  n = fread(text, 1, sizeof text - 1, f);
  fclose(f);
  text[n] = 0;
  if (!strstr(text, "no such variant \"Nope\"; the server has:") || !strstr(text, "Small"))
    fail_msg("an unknown variant: %s", text);
  /* a bad URL is a usage error (status 2) that names it */
  snprintf(cmd, sizeof cmd, "'%s' filter --server tcp:127.0.0.1:70000 --list > '%s' 2>&1",
           HAIRFILTER_CLI_PATH, outtxt);
  rc = system(cmd);
  assert_true(WIFEXITED(rc) && WEXITSTATUS(rc) == 2);
  f = fopen(outtxt, "r");
  assert_non_null(f);
  n = fread(text, 1, sizeof text - 1, f);
  fclose(f);
  text[n] = 0;
  assert_non_null(strstr(text, "port 70000 is outside 1..65535"));
  free(in);
}

/* Local failures of the client library: bad URLs, nothing listening, a
 * server that never answers, bad arguments, the in-flight window. */
static void test_client_errors(void **state) {
  (void)state;
  hfc_client *c = NULL;
  assert_int_equal(hfc_connect("http://x", NULL, &c), HFC_E_URL);
  /* the messages name every URL form, and UNSUPPORTED's covers shared
   * memory where the connection cannot have it */
  assert_non_null(strstr(hfc_strerror(HFC_E_URL), "tls:HOST:PORT"));
  assert_non_null(strstr(hfc_strerror(HFC_E_UNSUPPORTED), "shared memory"));
  assert_int_equal(hfc_connect("tcp:nohostport", NULL, &c), HFC_E_URL);
  assert_int_equal(hfc_connect("unix:", NULL, &c), HFC_E_URL);
  /* a port outside 1..65535 or with trailing junk is a bad URL, never
   * another port (70000 would be 4464 in 16 bits) */
  assert_int_equal(hfc_connect("tcp:127.0.0.1:70000", NULL, &c), HFC_E_URL);
  assert_int_equal(hfc_connect("tcp:127.0.0.1:0", NULL, &c), HFC_E_URL);
  assert_int_equal(hfc_connect("tcp:127.0.0.1:80x", NULL, &c), HFC_E_URL);
  char why[300];
  assert_int_equal(hfc_check_url("tcp:127.0.0.1:70000", why, sizeof why), HFC_E_URL);
  assert_string_equal(why, "bad URL 'tcp:127.0.0.1:70000': port 70000 is outside 1..65535");
  assert_int_equal(hfc_check_url(S.tcp_url, why, sizeof why), 0);
  assert_int_equal(hfc_check_url("tcp:[::1]:7070", why, sizeof why), 0);
  char path[300];
  snprintf(path, sizeof path, "unix:%s/nobody.sock", H.dir);
  assert_int_equal(hfc_connect(path, NULL, &c), HFC_E_CONNECT);
  assert_null(c);
  /* a socket that accepts (in the backlog) but never speaks */
  snprintf(path, sizeof path, "%s/mute.sock", H.dir);
  int lfd = socket(AF_UNIX, SOCK_STREAM, 0);
  struct sockaddr_un sun;
  memset(&sun, 0, sizeof sun);
  sun.sun_family = AF_UNIX;
  assert_true(strlen(path) < sizeof sun.sun_path);
  memcpy(sun.sun_path, path, strlen(path) + 1);
  assert_int_equal(bind(lfd, (struct sockaddr *)&sun, sizeof sun), 0);
  assert_int_equal(listen(lfd, 4), 0);
  char url[320];
  snprintf(url, sizeof url, "unix:%s", path);
  hfc_options quick = test_options("mute", NULL, 200);
  assert_int_equal(hfc_connect(url, &quick, &c), HFC_E_TIMEOUT);
  close(lfd);
  for (int e = -11; e <= 0; e++) assert_non_null(hfc_strerror(e));
  assert_string_equal(hfc_strerror(HFC_E_BUSY), hfp_strerror(HFP_E_BUSY));
  assert_string_equal(hfc_strerror(HFC_E_TIMEOUT), "timed out waiting for the server");

  c = connect_unix();
  float in[4 * 4 * 12], out[4 * 4 * 3];
  memset(in, 0, sizeof in);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 4, .height = 4, .spp = 2, .in_dtype = HFC_F32,
                   .features = in, .out_dtype = HFC_F32, .result = out);
  hfc_request bad = r;
  bad.width = 0;
  assert_int_equal(hfc_submit(c, &bad, NULL), HFC_E_ARG);
  bad = r;
  bad.result = NULL;
  assert_int_equal(hfc_submit(c, &bad, NULL), HFC_E_ARG);
  bad = r;
  bad.in_dtype = (hfc_dtype)5;
  assert_int_equal(hfc_submit(c, &bad, NULL), HFC_E_ARG);
  /* the server's verdicts come back as the protocol's codes */
  bad = r;
  bad.variant = "Nope";
  assert_int_equal(hfc_filter(c, &bad, NULL), HFC_E_UNKNOWN_VARIANT);
  assert_non_null(strstr(hfc_last_message(c), "Nope"));
  /* the window is the server's max_inflight; one more is refused locally */
  int win = hfc_info(c)->max_inflight;
  static float outs[64][4 * 4 * 3];
  assert_true(win <= 64);
  for (int i = 0; i < win; i++) {
    r.result = outs[i];
    assert_int_equal(hfc_submit(c, &r, NULL), 0);
  }
  assert_int_equal(hfc_submit(c, &r, NULL), HFC_E_INFLIGHT);
  for (int i = 0; i < win; i++) {
    hfc_completion d;
    assert_int_equal(hfc_wait(c, 20000, &d), 0);
    assert_int_equal(d.status, 0);
  }
  assert_int_equal(hfc_pending(c), 0);
  hfc_close(c);
}

/* Garbage at the server: mutated HELLOs and FILTERs, random bytes and
 * truncations over many connections. It must survive all of it, keep its
 * memory accounting straight and serve the next good request. */
static void test_garbage_survived(void **state) {
  (void)state;
  float *in = make_features(6, 4, 2, 9);
  size_t len;
  uint8_t *good = raw_filter(1, "Tiny", 6, 4, 2, in, &len);
  uint8_t hello[128];
  hfp_hello m = {1, 1, "fuzz", ""};
  int hn = hfp_encode_hello(hello, sizeof hello, &m);
  uint8_t buf[4096];
  uint32_t x = 2024;
  for (int it = 0; it < 300; it++) {
    int fd = raw_connect(it % 3 ? S.unix_url : S.tcp_url);
    assert_true(fd >= 0);
    size_t n = 0;
    if (it % 3 == 0) {
      /* TCP needs the token: send a correct HELLO with it, then garbage */
      hfp_hello t = {1, 1, "fuzz", TEST_TOKEN};
      n = (size_t)hfp_encode_hello(buf, sizeof buf, &t);
    } else if (it % 5 != 1) {
      memcpy(buf, hello, (size_t)hn);
      n = (size_t)hn;
    }
    memcpy(buf + n, good, len);
    size_t total = n + len;
    int edits = 1 + it % 6;
    for (int e = 0; e < edits; e++) {
      x = x * 1664525u + 1013904223u;
      size_t at = (x >> 8) % total;
      if ((x & 3) == 0)
        total = at + 1;                    /* truncate */
      else
        buf[at] ^= (uint8_t)(1u << ((x >> 4) & 7));
    }
    raw_send(fd, buf, total);              /* may fail once the server hung up */
    close(fd);
  }
  free(good);
  free(in);
  usleep(200000);
  assert_true(server_alive(&S));
  /* Peers that sent no HELLO still count against --max-handshakes until
   * the server closes them (their deadline), and until then a new
   * connection is rightly refused BUSY: wait that out, on a loaded
   * machine too, before asking for service. */
  hfc_client *c = NULL;
  hfc_options o = test_options("test", NULL, 20000);
  int rc = HFC_E_BUSY;
  for (int i = 0; i < 150 && rc == HFC_E_BUSY; i++) {
    rc = hfc_connect(S.unix_url, &o, &c);
    if (rc == HFC_E_BUSY) usleep(100000);
  }
  if (rc) fprintf(stderr, "connect %s: %s\n", S.unix_url, hfc_strerror(rc));
  assert_int_equal(rc, 0);
  filter_and_compare(c, "Tiny", 6, 4, 0, 9);
  hfc_stats st;
  for (int i = 0; i < 50; i++) {
    assert_int_equal(hfc_get_stats(c, &st), 0);
    if (st.connections_open == 1) break;
    usleep(100000);
  }
  assert_int_equal(st.connections_open, 1);
  assert_int_equal(st.queue_depth, 0);
  hfc_close(c);
}

/* A peer that floods requests and reads nothing: the server stops reading
 * from it once enough replies are waiting (so its memory stays bounded),
 * and resumes when the peer reads; every request is still answered. */
static void test_backpressure_on_unread_replies(void **state) {
  (void)state;
  enum { N = 40000 };
  float in[1 * 1 * 12] = {0};
  size_t len;
  uint8_t *one = raw_filter(1, "Nope", 1, 1, 2, in, &len);
  uint8_t *all = malloc(len * N);
  assert_non_null(all);
  for (int i = 0; i < N; i++) {
    memcpy(all + len * i, one, len);
    hfp_put_u32(all + len * i + 8, (uint32_t)i + 1);
  }
  int fd = raw_connect(S.unix_url);
  assert_int_equal(raw_hello(fd, NULL), 0);
  size_t total = len * N, sent = 0;
  /* Send without reading until the socket refuses more. */
  while (sent < total) {
    ssize_t w = send(fd, all + sent, total - sent, MSG_DONTWAIT | MSG_NOSIGNAL);
    if (w > 0) {
      sent += (size_t)w;
      continue;
    }
    assert_true(w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK));
    /* give the server time to read whatever it is still willing to */
    struct pollfd p = {fd, POLLOUT, 0};
    if (poll(&p, 1, 300) == 0) break;
  }
  assert_true(sent < total);
  /* Now read and send together until every request has its ERROR. */
  int got = 0;
  uint8_t hb[HFP_HEADER_SIZE], body[512];
  size_t hfill = 0, bfill = 0, blen = 0;
  int in_body = 0;
  while (got < N) {
    struct pollfd p = {fd, POLLIN | (sent < total ? POLLOUT : 0), 0};
    assert_true(poll(&p, 1, 10000) > 0);
    if ((p.revents & POLLOUT) && sent < total) {
      ssize_t w = send(fd, all + sent, total - sent, MSG_DONTWAIT | MSG_NOSIGNAL);
      if (w > 0) sent += (size_t)w;
    }
    if (!(p.revents & POLLIN)) continue;
    if (!in_body) {
      ssize_t r = recv(fd, hb + hfill, sizeof hb - hfill, MSG_DONTWAIT);
      assert_true(r > 0 || (r < 0 && errno == EAGAIN));
      if (r > 0) hfill += (size_t)r;
      if (hfill == sizeof hb) {
        hfp_header h;
        assert_int_equal(hfp_header_decode(hb, sizeof body, &h), 0);
        assert_int_equal(h.type, HFP_ERROR);
        assert_int_equal(h.request_id, (uint32_t)got + 1);
        blen = h.length;
        bfill = 0;
        in_body = 1;
        hfill = 0;
      }
    } else {
      ssize_t r = recv(fd, body + bfill, blen - bfill, MSG_DONTWAIT);
      assert_true(r > 0 || (r < 0 && errno == EAGAIN));
      if (r > 0) bfill += (size_t)r;
    }
    if (in_body && bfill == blen) {
      hfp_error e;
      assert_int_equal(hfp_decode_error(body, blen, &e), 0);
      assert_int_equal(e.code, HFP_E_UNKNOWN_VARIANT);
      in_body = 0;
      got++;
    }
  }
  assert_int_equal(sent, total);
  close(fd);
  free(all);
  free(one);
  assert_true(server_alive(&S));
}

/* Frames through shared memory: features read and results written in
 * place, bit for bit what the socket path and in-process inference give;
 * pipelined; refused where the protocol says so. */
static void test_shared_memory(void **state) {
  (void)state;
  hfc_client *c = connect_unix();
  assert_int_equal(hfc_info(c)->shm, 1);
  const ref_variant *v = harness_variant(&H, "Small");
  enum { W = 64, HH = 48, N = 6 };
  size_t in_b = (size_t)W * HH * v->cfg.spp * 6 * 4, out_b = (size_t)W * HH * 3 * 4,
         rgba_b = (size_t)W * HH * 4 * 4, per = in_b + out_b + rgba_b;
  uint8_t *mem;
  assert_int_equal(hfc_shm_alloc(c, per * N, (void **)&mem), 0);
  assert_non_null(mem);
  float *want = malloc(out_b), *rgb = malloc((size_t)W * HH * 3 * 4);
  assert_non_null(want);
  assert_non_null(rgb);
  /* one synchronous frame with a composite */
  float *in = make_features(W, HH, v->cfg.spp, 31);
  memcpy(mem, in, in_b);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = v->cfg.spp,
                   .in_dtype = HFC_F32, .features = mem, .out_dtype = HFC_F32,
                   .result = mem + in_b, .rgba = mem + in_b + out_b,
                   .hair = {0.4f, 0.3f, 0.2f}, .light = {1, 1, 1}, .background = {0, 0, 0.5f});
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(t.via_shm, 1);
  check_timing(&t);
  assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
  assert_memory_equal(mem + in_b, want, out_b);
  hf_composite(want, W, HH, r.hair, r.light, r.background, rgb);
  const float *rgba = (const float *)(mem + in_b + out_b);
  for (int p = 0; p < W * HH; p++) {
    for (int k = 0; k < 3; k++) assert_true(rgba[p * 4 + k] == rgb[p * 3 + k]);
    assert_true(rgba[p * 4 + 3] == want[p * 3 + 2]);
  }
  free(in);
  /* N pipelined frames, each in its own slice of the segment */
  for (int i = 0; i < N; i++) {
    float *fi = make_features(W, HH, v->cfg.spp, 40 + (uint32_t)i);
    memcpy(mem + per * i, fi, in_b);
    free(fi);
    hfc_request ri = TEST_REQUEST(.variant = "Small", .width = W, .height = HH, .spp = v->cfg.spp,
                      .in_dtype = HFC_F32, .features = mem + per * i, .out_dtype = HFC_F32,
                      .result = mem + per * i + in_b, .user = (void *)(intptr_t)i);
    assert_int_equal(hfc_submit(c, &ri, NULL), 0);
  }
  /* a segment in use cannot be freed */
  assert_int_equal(hfc_shm_free(c, mem), HFC_E_ARG);
  for (int k = 0; k < N; k++) {
    hfc_completion d;
    assert_int_equal(hfc_wait(c, 20000, &d), 0);
    assert_int_equal(d.status, 0);
    assert_int_equal(d.timing.via_shm, 1);
  }
  for (int i = 0; i < N; i++) {
    float *fi = make_features(W, HH, v->cfg.spp, 40 + (uint32_t)i);
    assert_int_equal(reference(v, W, HH, fi, HF_F32, want, HF_F32), 0);
    assert_memory_equal(mem + per * i + in_b, want, out_b);
    free(fi);
  }
  /* features in the segment but the result elsewhere: the socket path */
  float *out = malloc(out_b);
  r.result = out;
  r.rgba = NULL;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(t.via_shm, 0);
  free(out);
  /* the result over its own features (regions overlap, which PROTOCOL.md
   * refuses): the socket path, and the result is still the features' */
  in = make_features(W, HH, v->cfg.spp, 32);
  memcpy(mem, in, in_b);
  r.features = mem;
  r.result = mem;
  assert_int_equal(hfc_filter(c, &r, &t), 0);
  assert_int_equal(t.via_shm, 0);
  assert_int_equal(reference(v, W, HH, in, HF_F32, want, HF_F32), 0);
  assert_memory_equal(mem, want, out_b);
  free(in);
  assert_int_equal(hfc_shm_free(c, mem), 0);
  assert_int_equal(hfc_shm_free(c, mem), HFC_E_ARG);
  /* more than the server's whole shared-memory budget: no retry can help */
  void *huge;
  assert_int_equal(hfc_shm_alloc(c, (size_t)2048 << 20, &huge), HFC_E_TOO_LARGE);
  assert_null(huge);
  assert_non_null(strstr(hfc_last_message(c), "--max-shm-mb 1024"));
  filter_and_compare(c, "Tiny", 8, 8, 0, 3);   /* and the connection is fine */
  hfc_close(c);
  free(want);
  free(rgb);

  /* TCP cannot pass descriptors */
  hfc_options o = test_options("tcp-shm", TEST_TOKEN, 20000);
  assert_int_equal(hfc_connect(S.tcp_url, &o, &c), 0);
  assert_int_equal(hfc_info(c)->shm, 0);
  void *m2;
  assert_int_equal(hfc_shm_alloc(c, 4096, &m2), HFC_E_UNSUPPORTED);
  hfc_close(c);
}

/* A segment is pinned off the event loop (server/conn.c, pin_req) while
 * its connection reads nothing more: requests sent right behind
 * SHM_CREATE are answered after SHM_CREATED, in order; and segments of
 * connections that leave at once come back to the budget. */
static void test_segment_then_pipelined_requests(void **state) {
  (void)state;
  int fd = raw_connect(S.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);
  uint8_t b[256];
  int n = hfp_encode_shm_create(b, sizeof b, 1 << 20);
  hfp_header lv = {HFP_LIST_VARIANTS, 0, 0, 0}, st = {HFP_STATS, 0, 0, 0};
  hfp_header_encode(&lv, b + n);
  hfp_header_encode(&st, b + n + HFP_HEADER_SIZE);
  n += 2 * HFP_HEADER_SIZE;
  n += hfp_encode_shm_create(b + n, sizeof b - (size_t)n, 4096);
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  static const uint16_t order[] = {HFP_SHM_CREATED, HFP_VARIANTS, HFP_STATS_REPLY,
                                   HFP_SHM_CREATED};
  for (size_t k = 0; k < sizeof order / sizeof order[0]; k++) {
    hfp_header h;
    uint8_t *p;
    int seg_fd = -1;
    assert_int_equal(raw_read_fd(fd, &h, &p, &seg_fd), 0);
    if (h.type != order[k]) fail_msg("reply %zu: type %u, wanted %u", k, h.type, order[k]);
    assert_true((seg_fd >= 0) == (h.type == HFP_SHM_CREATED));
    if (seg_fd >= 0) close(seg_fd);
    free(p);
  }
  close(fd);
  /* 16 clients (processes: one client's connections share its part,
   * --max-shm-mb-per-client) each make a 60 MiB segment and leave without
   * a word, 960 MiB of the 1024 MiB budget; then 250 MiB, a client's
   * part, can be had again on one connection, and a second connection of
   * the same client is held to that part. */
  for (int k = 0; k < 16; k++) {
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
      int f = raw_connect(S.unix_url);
      if (f < 0 || raw_hello(f, NULL) != 0) _exit(1);
      n = hfp_encode_shm_create(b, sizeof b, (uint64_t)60 << 20);
      _exit(raw_send(f, b, (size_t)n) != 0);
    }
    int st = 0;
    assert_int_equal(waitpid(pid, &st, 0), pid);
    assert_true(WIFEXITED(st) && WEXITSTATUS(st) == 0);
  }
  hfc_client *cs[2];
  void *big[2];
  cs[0] = connect_unix();
  int rc = HFC_E_BUSY;
  for (int tries = 0; tries < 100 && rc == HFC_E_BUSY; tries++) {
    rc = hfc_shm_alloc(cs[0], (size_t)250 << 20, &big[0]);
    if (rc == HFC_E_BUSY) usleep(50000);
  }
  if (rc)
    fail_msg("250 MiB after the 16 left: %s (%s)", hfc_strerror(rc), hfc_last_message(cs[0]));
  cs[1] = connect_unix();
  rc = hfc_shm_alloc(cs[1], (size_t)250 << 20, &big[1]);
  if (rc != HFC_E_BUSY || !strstr(hfc_last_message(cs[1]), "--max-shm-mb-per-client"))
    fail_msg("250 MiB more on a second connection of this client: %s (%s), wanted BUSY naming "
             "--max-shm-mb-per-client", hfc_strerror(rc), hfc_last_message(cs[1]));
  assert_int_equal(hfc_shm_free(cs[0], big[0]), 0);
  filter_and_compare(cs[0], "Tiny", 8, 8, 0, 4);
  for (int k = 0; k < 2; k++) hfc_close(cs[k]);
  assert_true(server_alive(&S));
}

/* The server's side of bad references, with a raw connection holding a
 * real segment. */
static void test_shared_memory_bad_references(void **state) {
  (void)state;
  int fd = raw_connect(S.unix_url);
  assert_true(fd >= 0);
  assert_int_equal(raw_hello(fd, NULL), 0);
  uint8_t b[64];
  int n = hfp_encode_shm_create(b, sizeof b, 4096);
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  hfp_header h;
  uint8_t *p;
  int seg_fd;
  assert_int_equal(raw_read_fd(fd, &h, &p, &seg_fd), 0);
  assert_int_equal(h.type, HFP_SHM_CREATED);
  assert_true(seg_fd >= 0);
  uint32_t seg;
  uint64_t bytes;
  assert_int_equal(hfp_decode_shm_created(p, h.length, &seg, &bytes), 0);
  assert_int_equal(bytes, 4096);
  free(p);
  /* sealed: the client can neither shrink nor grow it */
  struct stat st;
  assert_int_equal(fstat(seg_fd, &st), 0);
  assert_int_equal(st.st_size, 4096);
  assert_int_not_equal(ftruncate(seg_fd, 0), 0);
  assert_int_not_equal(ftruncate(seg_fd, 1 << 20), 0);
  close(seg_fd);

  hfp_filter f;
  memset(&f, 0, sizeof f);
  strcpy(f.variant, "Tiny");
  f.flags = HFP_FILTER_SHM;
  f.width = f.height = 4;
  f.spp = 2;
  f.data_len = 4 * 4 * 2 * 6 * 4;
  uint8_t fr[HFP_FILTER_HEAD_MAX + HFP_SHM_REF_SIZE];
  uint64_t total;
  struct { uint32_t id, seg; uint64_t in, out; int code; } cases[] = {
    {21, 99, 0, 1536, HFP_E_INVALID},        /* no such segment */
    {22, 0, 0, 4000, HFP_E_LENGTH},          /* result runs past the end */
    {23, 0, 2, 1536, HFP_E_LENGTH},          /* misaligned features */
  };
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
    f.shm_segment = cases[k].seg ? cases[k].seg : seg;
    f.shm_in = cases[k].in;
    f.shm_out = cases[k].out;
    n = hfp_encode_filter_head(fr, sizeof fr, cases[k].id, &f, &total);
    assert_true(n > 0);
    expect_error(fd, fr, (size_t)n, cases[k].id, cases[k].code);
  }
  /* a good reference on the same connection (zero features: any result) */
  f.shm_segment = seg;
  f.shm_in = 0;
  f.shm_out = 1536;
  n = hfp_encode_filter_head(fr, sizeof fr, 24, &f, &total);
  assert_int_equal(raw_send(fd, fr, (size_t)n), 0);
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_RESULT);
  assert_int_equal(h.request_id, 24);
  hfp_result res;
  assert_int_equal(hfp_decode_result(p, h.length, &res), 0);
  assert_int_equal(res.status, 0);
  assert_true(res.flags & HFP_FILTER_SHM);
  assert_int_equal(h.length, HFP_RESULT_FIXED);
  free(p);
  /* destroying an unknown segment and asking for an empty one: non-fatal
   * ERRORs, each counted in STATS' protocol_errors (no variant to count
   * them against) */
  uint64_t errors_before = protocol_errors();
  n = hfp_encode_shm_destroy(b, sizeof b, 77);
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_ERROR);
  hfp_error e;
  assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
  assert_int_equal(e.code, HFP_E_INVALID);
  assert_int_equal(e.fatal, 0);
  free(p);
  n = hfp_encode_shm_create(b, sizeof b, 4096);
  assert_true(n > 0);
  memset(b + HFP_HEADER_SIZE, 0, 8); /* size 0 */
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  assert_int_equal(raw_read(fd, &h, &p), 0);
  assert_int_equal(h.type, HFP_ERROR);
  assert_int_equal(hfp_decode_error(p, h.length, &e), 0);
  assert_int_equal(e.code, HFP_E_INVALID);
  assert_int_equal(e.fatal, 0);
  free(p);
  assert_int_equal(protocol_errors() - errors_before, 2);
  /* destroy the real one; a reference to it is then refused */
  n = hfp_encode_shm_destroy(b, sizeof b, seg);
  assert_int_equal(raw_send(fd, b, (size_t)n), 0);
  n = hfp_encode_filter_head(fr, sizeof fr, 25, &f, &total);
  expect_error(fd, fr, (size_t)n, 25, HFP_E_INVALID);
  close(fd);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_variants),
    cmocka_unit_test(test_filter_sizes_unix),
    cmocka_unit_test(test_filter_tcp_auth),
    cmocka_unit_test(test_composite),
    cmocka_unit_test(test_pipelined_32),
    cmocka_unit_test(test_second_connection_mid_upload),
    cmocka_unit_test(test_disconnect_mid_frame),
    cmocka_unit_test(test_bad_requests_keep_connection),
    cmocka_unit_test(test_cli_filter),
    cmocka_unit_test(test_client_errors),
    cmocka_unit_test(test_garbage_survived),
    cmocka_unit_test(test_shared_memory),
    cmocka_unit_test(test_shared_memory_bad_references),
    cmocka_unit_test(test_backpressure_on_unread_replies),
    cmocka_unit_test(test_stats),
    cmocka_unit_test(test_busy_when_queue_full),
    cmocka_unit_test(test_batches_counted_when_client_gone),
    cmocka_unit_test(test_sigterm_drains),
    cmocka_unit_test(test_drain_refusals_counted),
    cmocka_unit_test(test_warm_and_pipeline_depth),
    cmocka_unit_test(test_sigterm_no_drain_time),
    cmocka_unit_test(test_error_result_echoes_dtype),
    cmocka_unit_test(test_segment_then_pipelined_requests),
    cmocka_unit_test(test_stalled_peer_is_closed),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
