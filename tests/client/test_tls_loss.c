/* libhairfilter over tls: when the server dies (SIGKILL: no close_notify,
 * the socket just closes): the engine's process survives a frame written to
 * the dead connection (OpenSSL's write(2) would raise SIGPIPE, whose
 * default action ends the process), the loss is HFC_E_CLOSED like on a
 * plain socket (OpenSSL 3 reports the missing close_notify as an error of
 * its own, which read as a TLS handshake failure), and with a list the
 * frame goes to the next endpoint as it does on plain sockets. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <netinet/in.h>
#include <openssl/ssl.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "harness.h"
#include "test_certs.h"

static harness H;
static char cert_dir[200], cert[256], key[256], ca[256];

static int setup(void **state) {
  (void)state;
  /* The default action: what an engine that never touched SIGPIPE has. */
  signal(SIGPIPE, SIG_DFL);
  if (harness_init(&H)) return -1;
  snprintf(cert_dir, sizeof cert_dir, "%s/certs", H.dir);
  if (mkdir(cert_dir, 0700) || test_certs_make(cert_dir)) return -1;
  snprintf(cert, sizeof cert, "%s/server.pem", cert_dir);
  snprintf(key, sizeof key, "%s/server.key", cert_dir);
  snprintf(ca, sizeof ca, "%s/ca.pem", cert_dir);
  return 0;
}

static int teardown(void **state) {
  (void)state;
  harness_free(&H);
  return 0;
}

static void start_tls(server *s) {
  const char *extra[] = {"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", key,
                         NULL};
  assert_int_equal(server_start_ex(&H, s, extra, NULL, TEST_TOKEN), 0);
  assert_true(s->tls_url[0] != 0);
}

/* "tls:localhost:PORT" (the certificate names localhost). */
static void url_of(const server *s, char *buf, size_t cap) {
  snprintf(buf, cap, "tls:localhost%s", strrchr(s->tls_url, ':'));
}

/* SIGKILL and reaped: the socket closes without close_notify. */
static void kill_server(server *s) {
  int st;
  kill(s->pid, SIGKILL);
  assert_int_equal(waitpid(s->pid, &st, 0), s->pid);
  s->pid = 0;
}

typedef struct frame {
  hfc_request r;
  float *in, *out;
} frame;

/* A Tiny (2 spp) frame of w x h. */
static void frame_make(frame *f, int w, int h) {
  f->in = make_features(w, h, 2, 11);
  f->out = malloc(hfc_output_bytes(w, h, 3, HFC_F32));
  assert_non_null(f->in);
  assert_non_null(f->out);
  hfc_request_init(&f->r);
  f->r.variant = "Tiny";
  f->r.width = w;
  f->r.height = h;
  f->r.spp = 2;
  f->r.features = f->in;
  f->r.features_bytes = hfc_features_bytes(w, h, 2, HFC_F32);
  f->r.result = f->out;
  f->r.result_bytes = hfc_output_bytes(w, h, 3, HFC_F32);
}

static void frame_free(frame *f) {
  free(f->in);
  free(f->out);
}

static hfc_client *connect_url(const char *url) {
  hfc_options o = test_options("tls-loss", TEST_TOKEN, 20000);
  o.tls_ca_file = ca;
  hfc_client *c = NULL;
  int rc = hfc_connect(url, &o, &c);
  if (rc) fail_msg("connect %s: %s (%s)", url, hfc_strerror(rc), hfc_last_message(NULL));
  return c;
}

/* A frame of several megabytes written to a server killed since the last
 * one: the writes after the peer's reset fail with EPIPE, and the process
 * must live to see HFC_E_CLOSED. Then a small frame on a new client. */
static void test_killed_server_single_url(void **state) {
  (void)state;
  server s;
  start_tls(&s);
  char url[300];
  url_of(&s, url, sizeof url);
  hfc_client *c = connect_url(url);
  frame small, big;
  frame_make(&small, 16, 16);
  frame_make(&big, 512, 512);   /* 12 MiB of features: many TLS records */
  assert_int_equal(hfc_filter(c, &small.r, NULL), HFC_OK);
  kill_server(&s);
  int rc = hfc_filter(c, &big.r, NULL);
  /* Reaching here is half the test: SIGPIPE would have ended the process. */
  if (rc != HFC_E_CLOSED)
    fail_msg("a frame to a killed server: %s (%s), want HFC_E_CLOSED", hfc_strerror(rc),
             hfc_last_message(c));
  /* One endpoint: the frame's error says to connect again (it said only
   * "server closed the connection"). */
  if (!strstr(hfc_last_message(c), "connect again"))
    fail_msg("a frame lost with the only endpoint: '%s', want it to say to connect again",
             hfc_last_message(c));
  hfc_close(c);

  /* A frame whose request went out whole before the loss: its reply is
   * the peer's close without close_notify. */
  start_tls(&s);
  url_of(&s, url, sizeof url);
  c = connect_url(url);
  assert_int_equal(hfc_filter(c, &small.r, NULL), HFC_OK);
  kill_server(&s);
  rc = hfc_filter(c, &small.r, NULL);
  if (rc != HFC_E_CLOSED)
    fail_msg("a small frame to a killed server: %s (%s), want HFC_E_CLOSED", hfc_strerror(rc),
             hfc_last_message(c));
  assert_non_null(strstr(hfc_last_message(c), "connect again"));
  assert_null(strstr(hfc_last_message(c), "handshake"));
  hfc_close(c);
  frame_free(&small);
  frame_free(&big);
}

/* tls:A,tls:B with A killed: the frame is sent again to B, as on plain
 * sockets (HFC_FAILOVER_LOST), whether it was small or large. */
static void test_killed_server_fails_over(void **state) {
  (void)state;
  server a, b;
  start_tls(&a);
  start_tls(&b);
  char ua[300], ub[300], list[620];
  url_of(&a, ua, sizeof ua);
  url_of(&b, ub, sizeof ub);
  snprintf(list, sizeof list, "%s,%s", ua, ub);
  frame small, big;
  frame_make(&small, 16, 16);
  frame_make(&big, 512, 512);
  frame *fs[2] = {&small, &big};
  for (int i = 0; i < 2; i++) {
    hfc_client *c = connect_url(list);
    assert_string_equal(hfc_endpoint(c), ua);
    assert_int_equal(hfc_filter(c, &small.r, NULL), HFC_OK);
    kill_server(&a);
    hfc_timing t;
    int rc = hfc_filter(c, &fs[i]->r, &t);
    if (rc != HFC_OK)
      fail_msg("%s frame after A was killed: %s (%s), want it filtered by B",
               i ? "a large" : "a small", hfc_strerror(rc), hfc_last_message(c));
    assert_string_equal(hfc_endpoint(c), ub);
    hfc_close(c);
    start_tls(&a);
    url_of(&a, ua, sizeof ua);
    snprintf(list, sizeof list, "%s,%s", ua, ub);
  }
  frame_free(&small);
  frame_free(&big);
  assert_int_equal(server_stop(&a, 20000), 0);
  assert_int_equal(server_stop(&b, 20000), 0);
}

/* ---- a server that closes without close_notify while a reply is awaited ---- */

typedef struct fake {
  int lfd, port;
  pthread_t thread;
} fake;

static int read_n(SSL *ssl, uint8_t *p, size_t n) {
  while (n) {
    int r = SSL_read(ssl, p, (int)n);
    if (r <= 0) return -1;
    p += r;
    n -= (size_t)r;
  }
  return 0;
}

/* One frame from ssl, its payload dropped: 0, or -1. */
static int read_frame(SSL *ssl, hfp_header *h) {
  uint8_t hb[HFP_HEADER_SIZE];
  if (read_n(ssl, hb, sizeof hb) || hfp_header_decode(hb, UINT32_MAX, h)) return -1;
  for (uint32_t left = h->length; left;) {
    uint8_t buf[4096];
    uint32_t n = left < sizeof buf ? left : (uint32_t)sizeof buf;
    if (read_n(ssl, buf, n)) return -1;
    left -= n;
  }
  return 0;
}

/* Accepts one connection: TLS, HELLO answered, then the first request
 * after it (LIST_VARIANTS, before the first frame naming a variant) read
 * whole, and the socket closed with no close_notify and nothing unread, as
 * the kernel closes the sockets of a server that is killed. */
static void *fake_main(void *arg) {
  fake *f = arg;
  SSL_CTX *ctx = SSL_CTX_new(TLS_server_method());
  int fd = accept(f->lfd, NULL, NULL);
  if (!ctx || fd < 0 || SSL_CTX_use_certificate_chain_file(ctx, cert) != 1 ||
      SSL_CTX_use_PrivateKey_file(ctx, key, SSL_FILETYPE_PEM) != 1) {
    fprintf(stderr, "fake server: setup failed\n");
    if (fd >= 0) close(fd);
    SSL_CTX_free(ctx);
    return NULL;
  }
  SSL *ssl = SSL_new(ctx);
  SSL_set_fd(ssl, fd);
  hfp_header h;
  if (SSL_accept(ssl) == 1 && read_frame(ssl, &h) == 0 && h.type == HFP_HELLO) {
    hfp_hello_ok ok;
    memset(&ok, 0, sizeof ok);
    ok.version = HFP_VERSION;
    ok.max_width = ok.max_height = 4096;
    ok.max_spp = 16;
    ok.max_inflight = 8;
    ok.dtypes = HFP_DTYPE_MASK_ALL;
    ok.max_batch = 1;
    ok.queue_size = 8;
    ok.max_frame_bytes = 1u << 30;
    snprintf(ok.server_name, sizeof ok.server_name, "fake");
    snprintf(ok.software_version, sizeof ok.software_version, "0.0.0");
    uint8_t frame[HFP_HELLO_OK_MAX];
    int n = hfp_encode_hello_ok(frame, sizeof frame, &ok);
    if (n > 0 && SSL_write(ssl, frame, n) == n) read_frame(ssl, &h);
  }
  SSL_free(ssl);   /* no SSL_shutdown: no close_notify */
  close(fd);
  SSL_CTX_free(ctx);
  return NULL;
}

static void fake_start(fake *f) {
  struct sockaddr_in a;
  memset(&a, 0, sizeof a);
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t al = sizeof a;
  f->lfd = socket(AF_INET, SOCK_STREAM, 0);
  assert_true(f->lfd >= 0);
  assert_int_equal(bind(f->lfd, (struct sockaddr *)&a, sizeof a), 0);
  assert_int_equal(listen(f->lfd, 4), 0);
  assert_int_equal(getsockname(f->lfd, (struct sockaddr *)&a, &al), 0);
  f->port = ntohs(a.sin_port);
  assert_int_equal(pthread_create(&f->thread, NULL, fake_main, f), 0);
}

static void fake_join(fake *f) {
  pthread_join(f->thread, NULL);
  close(f->lfd);
}

/* The reply awaited ends in the peer's close without close_notify: that
 * is HFC_E_CLOSED, not a TLS handshake failure, alone; and in a list the
 * request goes on to the next endpoint. */
static void test_close_without_close_notify(void **state) {
  (void)state;
  frame small;
  frame_make(&small, 16, 16);
  fake f;
  fake_start(&f);
  char url[300];
  snprintf(url, sizeof url, "tls:localhost:%d", f.port);
  hfc_client *c = connect_url(url);
  int rc = hfc_filter(c, &small.r, NULL);
  fake_join(&f);
  if (rc != HFC_E_CLOSED)
    fail_msg("a server gone without close_notify: %s (%s), want HFC_E_CLOSED", hfc_strerror(rc),
             hfc_last_message(c));
  hfc_close(c);

  server b;
  start_tls(&b);
  char ub[300], list[620];
  url_of(&b, ub, sizeof ub);
  fake_start(&f);
  snprintf(list, sizeof list, "tls:localhost:%d,%s", f.port, ub);
  c = connect_url(list);
  rc = hfc_filter(c, &small.r, NULL);
  fake_join(&f);
  if (rc != HFC_OK)
    fail_msg("failover from a server gone without close_notify: %s (%s), want the frame "
             "filtered by the next endpoint", hfc_strerror(rc), hfc_last_message(c));
  assert_string_equal(hfc_endpoint(c), ub);
  hfc_close(c);
  frame_free(&small);
  assert_int_equal(server_stop(&b, 20000), 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_killed_server_single_url),
    cmocka_unit_test(test_killed_server_fails_over),
    cmocka_unit_test(test_close_without_close_notify),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
