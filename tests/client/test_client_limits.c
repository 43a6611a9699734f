/* A frame over the limits the server announced in HELLO_OK (max_width x
 * max_height, max_frame_bytes, its dtypes) is refused by libhairfilter
 * before a byte of it is written, with the limit and the frame's size in
 * hfc_last_message, and the connection stays usable. It was written whole
 * and only then refused (a frame over max_frame_bytes also lost the
 * connection). A fake server on a Unix socket counts what it receives;
 * a real one, started with a small --max-size, checks the same for a
 * frame in shared memory and after a failover to a server of smaller
 * limits. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "harness.h"

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

/* ---- a fake server announcing small limits -------------------------------- */

typedef struct fake {
  char path[104];   /* a sockaddr_un path */
  int lfd;
  uint32_t max_side;
  uint64_t max_frame_bytes;
  uint32_t dtypes;
  int version;           /* HELLO_OK's protocol version (fake_start: HFP_VERSION) */
  int estimate;          /* 1: its variant "Tiny" reads the estimate (version 3) */
  int close_on_filter;   /* 1: close when a FILTER's header arrives, answering nothing */
  pthread_t thread;
  /* what it received after the handshake, read once the thread ended */
  int filters;
  uint64_t filter_bytes;
} fake;

static int read_all(int fd, void *buf, size_t n) {
  uint8_t *p = buf;
  while (n) {
    ssize_t r = read(fd, p, n);
    if (r <= 0) return -1;
    p += r;
    n -= (size_t)r;
  }
  return 0;
}

static int write_all(int fd, const void *buf, size_t n) {
  const uint8_t *p = buf;
  while (n) {
    ssize_t r = write(fd, p, n);
    if (r <= 0) return -1;
    p += r;
    n -= (size_t)r;
  }
  return 0;
}

/* One connection: HELLO answered with the limits, LIST_VARIANTS with one
 * variant "Tiny" of 2 spp, a FILTER read whole and answered with a
 * non-fatal INTERNAL (or the connection closed at its header), until the
 * client closes. */
static void *fake_main(void *arg) {
  fake *f = arg;
  int fd = accept(f->lfd, NULL, NULL);
  if (fd < 0) return NULL;
  for (;;) {
    uint8_t hb[HFP_HEADER_SIZE];
    hfp_header h;
    if (read_all(fd, hb, sizeof hb) || hfp_header_decode(hb, UINT32_MAX, &h)) break;
    if (h.type == HFP_FILTER) {
      f->filters++;
      f->filter_bytes += h.length;
      if (f->close_on_filter) break;
    }
    uint8_t *payload = malloc(h.length ? h.length : 1);
    if (!payload || read_all(fd, payload, h.length)) {
      free(payload);
      break;
    }
    free(payload);
    uint8_t out[4096];
    int n = -1;
    if (h.type == HFP_HELLO) {
      hfp_hello_ok ok;
      memset(&ok, 0, sizeof ok);
      ok.version = (uint16_t)f->version;
      ok.max_width = ok.max_height = f->max_side;
      ok.max_spp = 2;
      ok.max_inflight = 4;
      ok.dtypes = f->dtypes;
      ok.max_batch = 1;
      ok.queue_size = 4;
      ok.max_frame_bytes = f->max_frame_bytes;
      snprintf(ok.server_name, sizeof ok.server_name, "fake");
      snprintf(ok.software_version, sizeof ok.software_version, "0.0.0");
      n = hfp_encode_hello_ok(out, sizeof out, &ok);
    } else if (h.type == HFP_LIST_VARIANTS) {
      hfp_variant v;
      memset(&v, 0, sizeof v);
      snprintf(v.name, sizeof v.name, "Tiny");
      snprintf(v.backend, sizeof v.backend, "cpu-ref");
      snprintf(v.precision, sizeof v.precision, "fp32");
      v.spp = 2;
      v.num_levels = 1;
      v.levels[0] = 4;
      v.estimate = f->estimate ? HFP_ESTIMATE_ALPHA_CORRECTED : HFP_ESTIMATE_NONE;
      n = hfp_encode_variants_v(out, sizeof out, &v, 1, f->version);
    } else if (h.type == HFP_FILTER) {
      hfp_error e;
      memset(&e, 0, sizeof e);
      e.code = HFP_E_INTERNAL;
      snprintf(e.message, sizeof e.message, "fake answer");
      n = hfp_encode_error(out, sizeof out, h.request_id, &e);
    }
    if (n <= 0 || write_all(fd, out, (size_t)n)) break;
  }
  close(fd);
  return NULL;
}

static void fake_start(fake *f, const char *name, uint32_t max_side, uint64_t max_frame_bytes,
                       uint32_t dtypes) {
  memset(f, 0, sizeof *f);
  int len = snprintf(f->path, sizeof f->path, "%s/%s.sock", H.dir, name);
  assert_true(len > 0 && (size_t)len < sizeof f->path);
  f->max_side = max_side;
  f->max_frame_bytes = max_frame_bytes;
  f->dtypes = dtypes;
  f->version = HFP_VERSION;
  struct sockaddr_un a;
  memset(&a, 0, sizeof a);
  a.sun_family = AF_UNIX;
  snprintf(a.sun_path, sizeof a.sun_path, "%s", f->path);
  f->lfd = socket(AF_UNIX, SOCK_STREAM, 0);
  assert_true(f->lfd >= 0);
  assert_int_equal(bind(f->lfd, (struct sockaddr *)&a, sizeof a), 0);
  assert_int_equal(listen(f->lfd, 4), 0);
  assert_int_equal(pthread_create(&f->thread, NULL, fake_main, f), 0);
}

static void fake_join(fake *f) {
  pthread_join(f->thread, NULL);
  close(f->lfd);
  unlink(f->path);
}

static hfc_client *connect_url(const char *url) {
  hfc_options o = test_options("limits", NULL, 10000);
  hfc_client *c = NULL;
  int rc = hfc_connect(url, &o, &c);
  if (rc) fail_msg("connect %s: %s (%s)", url, hfc_strerror(rc), hfc_last_message(NULL));
  return c;
}

static void expect(hfc_client *c, int rc, int want, const char *const *needles) {
  const char *m = hfc_last_message(c);
  if (rc != want) fail_msg("got %s (%s), want %s", hfc_strerror(rc), m, hfc_strerror(want));
  for (; *needles; needles++)
    if (!strstr(m, *needles)) fail_msg("message '%s' does not say '%s'", m, *needles);
}

/* Over the size, over max_frame_bytes, in a dtype not offered: each refused
 * with nothing sent, by hfc_filter and hfc_submit alike; then a frame
 * within the limits goes out and is answered on the same connection. */
static void test_socket_limits(void **state) {
  (void)state;
  fake f;
  /* 16x16 frames, 4 KiB payloads: a 16x16 frame of 2 spp in f32 is 12 KiB. */
  fake_start(&f, "small", 16, 4096, 1u << HFP_F32);
  char url[256];
  snprintf(url, sizeof url, "unix:%s", f.path);
  hfc_client *c = connect_url(url);
  float *in = calloc(1, hfc_features_bytes(32, 32, 2, HFC_F32));
  float *out = calloc(1, hfc_output_bytes(32, 32, 3, HFC_F32));
  assert_non_null(in);
  assert_non_null(out);

  hfc_request r = TEST_REQUEST(.variant = "tiny", .width = 32, .height = 8, .spp = 2,
                               .features = in, .result = out);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_TOO_LARGE,
         (const char *[]){"32x8", "16x16", "max_width", "nothing was sent", "--max-size",
                          "--max-memory-mb", "--max-frame-mb", NULL});
  uint32_t id = 77;
  expect(c, hfc_submit(c, &r, &id), HFC_E_TOO_LARGE, (const char *[]){"32x8", NULL});
  assert_int_equal(id, 77);
  assert_int_equal(hfc_pending(c), 0);

  r = TEST_REQUEST(.variant = "Tiny", .width = 16, .height = 16, .spp = 2, .features = in,
                   .result = out);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_TOO_LARGE,
         (const char *[]){"16x16 frame of 2 spp", "4096", "max_frame_bytes", "nothing was sent",
                          NULL});

  r = TEST_REQUEST(.variant = "Tiny", .width = 8, .height = 8, .spp = 2, .in_dtype = HFC_F16,
                   .features = in, .result = out);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_UNSUPPORTED,
         (const char *[]){"f32", "in_dtype", NULL});

  /* Within the limits: sent, and the fake's answer comes back. */
  r = TEST_REQUEST(.variant = "Tiny", .width = 8, .height = 8, .spp = 2, .features = in,
                   .result = out);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_INTERNAL, (const char *[]){"fake answer", NULL});
  hfc_close(c);
  fake_join(&f);
  if (f.filters != 1)
    fail_msg("the fake server received %d FILTER frames (%llu bytes), want only the one "
             "within its limits", f.filters, (unsigned long long)f.filter_bytes);
  free(in);
  free(out);
}

/* A frame queued for a server of larger limits that is lost goes to the
 * next endpoint of the list, whose limits it exceeds: it completes with
 * HFC_E_TOO_LARGE there without being sent. */
static void test_failover_limits(void **state) {
  (void)state;
  fake big, small;
  fake_start(&big, "big", 64, 1u << 20, HFP_DTYPE_MASK_ALL);
  big.close_on_filter = 1;
  fake_start(&small, "smaller", 16, 1u << 20, HFP_DTYPE_MASK_ALL);
  char url[512];
  snprintf(url, sizeof url, "unix:%s,unix:%s", big.path, small.path);
  hfc_client *c = connect_url(url);
  float *in = calloc(1, hfc_features_bytes(32, 32, 2, HFC_F32));
  float *out = calloc(1, hfc_output_bytes(32, 32, 3, HFC_F32));
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 32, .height = 32, .spp = 2,
                               .features = in, .result = out);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_TOO_LARGE,
         (const char *[]){"32x32", "16x16", "nothing was sent", NULL});
  hfc_close(c);
  fake_join(&big);
  fake_join(&small);
  assert_int_equal(big.filters, 1);
  if (small.filters != 0)
    fail_msg("the server of smaller limits received %d FILTER frames, want none",
             small.filters);
  free(in);
  free(out);
}

/* A frame with an estimate (protocol version 3) queued for a server that
 * is lost goes to the next endpoint, an older server of version 2: it
 * completes there without being sent, HFC_E_UNSUPPORTED naming the
 * version, as hfc_submit refuses it on such a server. Sent, its flag and
 * estimate were what that server cannot read. */
static void test_failover_version(void **state) {
  (void)state;
  fake newer, older;
  fake_start(&newer, "newer", 64, 1u << 20, HFP_DTYPE_MASK_ALL);
  newer.estimate = 1;
  newer.close_on_filter = 1;
  fake_start(&older, "older", 64, 1u << 20, HFP_DTYPE_MASK_ALL);
  older.version = 2;
  char url[512];
  snprintf(url, sizeof url, "unix:%s,unix:%s", newer.path, older.path);
  hfc_client *c = connect_url(url);
  float *in = calloc(1, hfc_features_bytes(8, 8, 2, HFC_F32) + hfc_estimate_bytes(8, 8, HFC_F32));
  float *out = calloc(1, hfc_output_bytes(8, 8, 3, HFC_F32));
  assert_non_null(in);
  assert_non_null(out);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 8, .height = 8, .spp = 2,
                               .estimate = 1, .features = in, .result = out);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_UNSUPPORTED,
         (const char *[]){"estimate", "version 2", "nothing was sent", NULL});
  hfc_close(c);
  fake_join(&newer);
  fake_join(&older);
  assert_int_equal(newer.filters, 1);
  if (older.filters != 0)
    fail_msg("the version-2 server received %d FILTER frames with an estimate, want none",
             older.filters);
  free(in);
  free(out);
}

/* Shared memory on a real server of --max-size 16x16: a 32x32 frame in a
 * segment is refused before its reference goes out (the server counts no
 * request of the variant), and a 16x16 one then goes by reference on the
 * same connection. */
static void test_shm_limits(void **state) {
  (void)state;
  server s;
  hfc_client *c;
  const char *extra[] = {"--max-size", "16x16", NULL};
  assert_int_equal(server_start_connected(&H, &s, extra, "limits-shm", &c), 0);
  assert_true(hfc_info(c)->shm);
  assert_int_equal(hfc_info(c)->max_width, 16);
  size_t in_bytes = hfc_features_bytes(32, 32, 2, HFC_F32);
  size_t out_bytes = hfc_output_bytes(32, 32, 3, HFC_F32);
  unsigned char *mem;
  assert_int_equal(hfc_shm_alloc(c, in_bytes + out_bytes, (void **)&mem), HFC_OK);
  hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 32, .height = 32, .spp = 2,
                               .features = mem, .result = mem + in_bytes);
  expect(c, hfc_filter(c, &r, NULL), HFC_E_TOO_LARGE,
         (const char *[]){"32x32", "16x16", "nothing was sent", NULL});
  hfc_stats st;
  assert_int_equal(hfc_get_stats(c, &st), HFC_OK);
  for (int i = 0; i < st.num_variants; i++)
    if (!strcmp(st.variants[i].name, "Tiny"))
      assert_int_equal(st.variants[i].rejected + st.variants[i].requests_failed, 0);
  r = TEST_REQUEST(.variant = "Tiny", .width = 16, .height = 16, .spp = 2, .features = mem,
                   .result = mem + hfc_features_bytes(16, 16, 2, HFC_F32));
  hfc_timing t;
  assert_int_equal(hfc_filter(c, &r, &t), HFC_OK);
  assert_int_equal(t.via_shm, 1);
  hfc_close(c);
  assert_int_equal(server_stop(&s, 20000), 0);
  assert_false(server_log_has(&s, "TOO_LARGE"));
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_socket_limits),
      cmocka_unit_test(test_failover_limits),
      cmocka_unit_test(test_failover_version),
      cmocka_unit_test(test_shm_limits),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
