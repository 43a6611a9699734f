/* hairfilterd's TLS listeners with libhairfilter's tls: URLs (docs/SERVER.md,
 * "TLS"), certificates made in the test (test_certs.h): a frame filtered
 * over TLS is byte for byte the one filtered over plain TCP; a wrong CA, an
 * expired certificate (swapped in by SIGHUP), a wrong host name, a missing
 * or foreign client certificate under mutual TLS, a plain-text client on a
 * TLS port and a TLS client on a plain port each get an error naming the
 * problem, and the daemon serves the next client all the same. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <openssl/err.h>
#include <openssl/ssl.h>
#include <poll.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "harness.h"
#include "test_certs.h"

static harness H;
static server S;      /* tls: listener with a token, and the harness's plain ones */
static server M;      /* mutual TLS: the client certificate replaces the token */
static char cert_dir[200];

static void path_of(char *buf, size_t cap, const char *file) {
  snprintf(buf, cap, "%s/%s", cert_dir, file);
}

static int setup(void **state) {
  (void)state;
  if (harness_init(&H)) return -1;
  snprintf(cert_dir, sizeof cert_dir, "%s/certs", H.dir);
  if (mkdir(cert_dir, 0700) || test_certs_make(cert_dir)) return -1;
  /* The served certificate is a copy, so the expired one can be put in
   * its place for a reload. */
  char cert[256], key[256], ca[256];
  path_of(cert, sizeof cert, "served.pem");
  path_of(key, sizeof key, "served.key");
  path_of(ca, sizeof ca, "ca.pem");
  char cmd[1024];
  snprintf(cmd, sizeof cmd, "cp %s/server.pem %s && cp %s/server.key %s", cert_dir, cert,
           cert_dir, key);
  if (system(cmd) != 0) return -1;
  char est[300];
  if (harness_estimate_weights(&H, est, sizeof est)) return -1;
  const char *extra[] = {"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", key,
                         "--listen", "tcp:0.0.0.0:0", "--verbose", "--weights", est, NULL};
  if (server_start(&H, &S, extra) || !S.tls_url[0]) return -1;
  const char *mextra[] = {"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", key,
                          "--tls-client-ca", ca, "--tls-client-cert-auth", NULL};
  return server_start(&H, &M, mextra) || !M.tls_url[0] ? -1 : 0;
}

static int teardown(void **state) {
  (void)state;
  int bad = server_stop(&M, 20000) != 0;
  return harness_stop(&H, &S) || bad;
}

/* "tls:localhost:PORT" for a server's tls: listener (its certificate names
 * localhost only); with numeric, "tls:127.0.0.1:PORT". */
static void tls_url(const server *s, int numeric, char *buf, size_t cap) {
  const char *port = strrchr(s->tls_url, ':');
  snprintf(buf, cap, "tls:%s%s", numeric ? "127.0.0.1" : "localhost", port);
}

typedef struct tls_opts {
  const char *ca, *cert, *key, *token, *server_name;
} tls_opts;

/* Connects with the certificate files of cert_dir named in t; the return
 * code, the message in msg. */
static int tls_connect(const char *url, const tls_opts *t, hfc_client **c, char *msg,
                       size_t cap) {
  char ca[256], cert[256], key[256];
  hfc_options o = test_options("tls-test", t->token, 10000);
  if (t->ca) path_of(ca, sizeof ca, t->ca), o.tls_ca_file = ca;
  if (t->cert) path_of(cert, sizeof cert, t->cert), o.tls_cert_file = cert;
  if (t->key) path_of(key, sizeof key, t->key), o.tls_key_file = key;
  o.tls_server_name = t->server_name;
  *c = NULL;
  int rc = hfc_connect(url, &o, c);
  snprintf(msg, cap, "%s", hfc_last_message(NULL));
  return rc;
}

/* Filters the harness's frame (Small, 64x48, 4 spp) on c into out. */
static int filter_frame(hfc_client *c, float *out) {
  int w = 64, h = 48, spp = 4;
  float *in = make_features(w, h, spp, 17);
  hfc_request r = TEST_REQUEST(.variant = "Small", .width = w, .height = h, .spp = spp,
                               .features = in, .result = out);
  hfc_timing t;
  int rc = hfc_filter(c, &r, &t);
  free(in);
  return rc;
}

/* The server still filters for a good TLS client after what came before. */
static void still_serves(const server *s, const tls_opts *good) {
  char url[300], msg[600];
  tls_url(s, 0, url, sizeof url);
  hfc_client *c;
  int rc = tls_connect(url, good, &c, msg, sizeof msg);
  if (rc) fail_msg("a good client after that: %s (%s)", hfc_strerror(rc), msg);
  float *out = malloc(64 * 48 * 3 * sizeof(float));
  assert_int_equal(filter_frame(c, out), 0);
  free(out);
  hfc_close(c);
}

static const tls_opts GOOD = {.ca = "ca.pem", .token = TEST_TOKEN};
static const tls_opts MUTUAL = {.ca = "ca.pem", .cert = "client.pem", .key = "client.key"};

/* Item: the same frame over TLS and over plain TCP gives the same bytes. */
static void test_tls_equals_tcp(void **state) {
  (void)state;
  size_t n = 64 * 48 * 3;
  float *plain = malloc(n * sizeof(float)), *tls = malloc(n * sizeof(float));
  hfc_options o = test_options("tcp-test", TEST_TOKEN, 10000);
  hfc_client *c;
  assert_int_equal(hfc_connect(S.tcp_url, &o, &c), 0);
  assert_int_equal(filter_frame(c, plain), 0);
  hfc_close(c);
  char url[300], msg[600];
  tls_url(&S, 0, url, sizeof url);
  int rc = tls_connect(url, &GOOD, &c, msg, sizeof msg);
  if (rc) fail_msg("%s: %s (%s)", url, hfc_strerror(rc), msg);
  assert_int_equal(hfc_info(c)->auth_required, 1);
  memset(tls, 0xff, n * sizeof(float));
  assert_int_equal(filter_frame(c, tls), 0);
  /* Several in flight at once: replies arrive in records of their own. */
  for (int k = 0; k < 3; k++) {
    memset(tls, 0xff, n * sizeof(float));
    assert_int_equal(filter_frame(c, tls), 0);
    assert_memory_equal(plain, tls, n * sizeof(float));
  }
  /* hfc_fd polls readable for replies over TLS, and then each is had
   * without waiting. */
  float *outs = malloc(3 * n * sizeof(float));
  float *in = make_features(64, 48, 4, 17);
  for (int k = 0; k < 3; k++) {
    hfc_request r = TEST_REQUEST(.variant = "Small", .width = 64, .height = 48, .spp = 4,
                                 .features = in, .result = outs + k * n);
    uint32_t id;
    assert_int_equal(hfc_submit(c, &r, &id), 0);
  }
  for (int got = 0; got < 3;) {
    struct pollfd p = {hfc_fd(c), POLLIN, 0};
    assert_int_equal(poll(&p, 1, 10000), 1);
    hfc_completion d;
    while (got < 3 && (rc = hfc_wait(c, 0, &d)) == 0) {
      assert_int_equal(d.status, 0);
      got++;
    }
    if (got < 3) assert_int_equal(rc, HFC_E_TIMEOUT);
  }
  for (int k = 0; k < 3; k++) assert_memory_equal(plain, outs + k * n, n * sizeof(float));
  free(in);
  free(outs);
  hfc_close(c);
  /* And the mutual-TLS server, without a token. */
  tls_url(&M, 0, url, sizeof url);
  rc = tls_connect(url, &MUTUAL, &c, msg, sizeof msg);
  if (rc) fail_msg("%s with a client certificate: %s (%s)", url, hfc_strerror(rc), msg);
  assert_int_equal(hfc_info(c)->auth_required, 0);
  memset(tls, 0xff, n * sizeof(float));
  assert_int_equal(filter_frame(c, tls), 0);
  assert_memory_equal(plain, tls, n * sizeof(float));
  hfc_close(c);
  free(plain);
  free(tls);
  /* The loud warning about plain TCP on a non-loopback address. */
  assert_true(server_log_has(&S, "plain TCP on a non-loopback address"));
}

/* A frame of a variant that reads the estimate, sent with the estimate in a
 * buffer of its own (three parts through TLS records) gives the bytes of the
 * same frame sent in one buffer over plain TCP. */
static void test_tls_estimate_apart(void **state) {
  (void)state;
  const int w = 48, h = 40;
  const size_t n_feat = (size_t)w * h * 24, n_est = (size_t)w * h * 3, n_out = (size_t)w * h * 3;
  float *in = make_features(w, h, 4, 23), *est = malloc(n_est * sizeof(float));
  float *plain = malloc(n_out * sizeof(float)), *tls = malloc(n_out * sizeof(float));
  float *one = malloc((n_feat + n_est) * sizeof(float));
  for (size_t i = 0; i < n_est; i++) est[i] = (float)((i * 7) % 13) / 13.0f;
  memcpy(one, in, n_feat * sizeof(float));
  memcpy(one + n_feat, est, n_est * sizeof(float));
  hfc_options o = test_options("tcp-estimate", TEST_TOKEN, 10000);
  hfc_client *c;
  assert_int_equal(hfc_connect(S.tcp_url, &o, &c), 0);
  hfc_request r = TEST_REQUEST(.variant = "Estimate", .width = w, .height = h, .spp = 4,
                               .features = one, .result = plain, .estimate = 1);
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  hfc_close(c);
  char url[300], msg[600];
  tls_url(&S, 0, url, sizeof url);
  int rc = tls_connect(url, &GOOD, &c, msg, sizeof msg);
  if (rc) fail_msg("%s: %s (%s)", url, hfc_strerror(rc), msg);
  memset(tls, 0xff, n_out * sizeof(float));
  r = TEST_REQUEST(.variant = "Estimate", .width = w, .height = h, .spp = 4, .features = in,
                   .result = tls, .estimate = 1, .estimate_buffer = est);
  rc = hfc_filter(c, &r, NULL);
  if (rc) fail_msg("over TLS with the estimate apart: %s (%s)", hfc_strerror(rc),
                   hfc_last_message(c));
  assert_memory_equal(plain, tls, n_out * sizeof(float));
  hfc_close(c);
  free(in), free(est), free(one), free(plain), free(tls);
}

/* One refused client: rc and words of its message, then the server goes on. */
static void refused(const server *s, const char *url, const tls_opts *t, int want_rc,
                    const char *says, const char *also, const tls_opts *good) {
  char msg[600];
  hfc_client *c;
  int rc = tls_connect(url, t, &c, msg, sizeof msg);
  if (rc != want_rc || !strstr(msg, says) || (also && !strstr(msg, also)))
    fail_msg("%s: got %s '%s', wanted %s with '%s'", url, hfc_strerror(rc), msg,
             hfc_strerror(want_rc), says);
  hfc_close(c);
  assert_true(server_alive(s));
  still_serves(s, good);
}

/* Item: a server certificate from another CA, one for another host name,
 * a wrong token over TLS. */
static void test_server_certificate_refused(void **state) {
  (void)state;
  char url[300], num[300];
  tls_url(&S, 0, url, sizeof url);
  tls_url(&S, 1, num, sizeof num);
  tls_opts other = GOOD;
  other.ca = "other-ca.pem";
  refused(&S, url, &other, HFC_E_TLS, "unable to get local issuer certificate",
          "--tls-ca", &GOOD);
  /* The server hears the client's alert, and says whose refusal it was. */
  assert_true(server_log_has(&S, "the client refused this server's certificate: unknown CA"));
  /* No CA file: the system's store was used, and the hint says so. */
  tls_opts system = GOOD;
  system.ca = NULL;
  refused(&S, url, &system, HFC_E_TLS, "the system's CA store", "--tls-ca FILE", &GOOD);
  /* 127.0.0.1 is not in the certificate (DNS:localhost only): the names it
   * has are listed, and the handshake is named once. */
  refused(&S, num, &GOOD, HFC_E_TLS, "IP address mismatch", "the certificate names DNS:localhost",
          &GOOD);
  tls_opts name = GOOD;
  name.server_name = "render-99.farm";
  refused(&S, url, &name, HFC_E_TLS, "hostname mismatch", "--tls-server-name", &GOOD);
  char msg[600];
  hfc_client *c;
  tls_connect(url, &name, &c, msg, sizeof msg);
  char *first = strstr(msg, "TLS handshake");
  if (!first || strstr(first + 1, "TLS handshake") || strstr(strstr(msg, url) + 1, url))
    fail_msg("the URL and 'TLS handshake' once each: '%s'", msg);
  /* The token still applies over TLS. */
  tls_opts token = GOOD;
  token.token = "not-the-token";
  refused(&S, url, &token, HFC_E_UNAUTHORIZED, "wrong token", NULL, &GOOD);
  /* A host name the certificate does have, given for a numeric URL. */
  name.server_name = "localhost";
  int rc = tls_connect(num, &name, &c, msg, sizeof msg);
  if (rc) fail_msg("%s as localhost: %s (%s)", num, hfc_strerror(rc), msg);
  hfc_close(c);
}

/* Item: mutual TLS: no client certificate, one from another CA. */
static void test_client_certificate_refused(void **state) {
  (void)state;
  char url[300];
  tls_url(&M, 0, url, sizeof url);
  tls_opts none = {.ca = "ca.pem", .token = TEST_TOKEN};
  refused(&M, url, &none, HFC_E_TLS, "certificate required", "requires a client certificate",
          &MUTUAL);
  tls_opts foreign = {.ca = "ca.pem", .cert = "client-other.pem", .key = "client-other.key"};
  refused(&M, url, &foreign, HFC_E_TLS, "unknown ca", "does not trust this client certificate",
          &MUTUAL);
  /* The server's own certificate (extendedKeyUsage serverAuth) as a
   * client's: the purpose is named, and what a client certificate needs. */
  tls_opts purpose = {.ca = "ca.pem", .cert = "server.pem", .key = "server.key"};
  refused(&M, url, &purpose, HFC_E_TLS, "unsupported certificate", "extendedKeyUsage=clientAuth",
          &MUTUAL);
  assert_true(server_log_has(&M, "TLS handshake failed"));
  assert_true(server_log_has(&M, "this server refused the client's certificate: the client sent "
                                 "no certificate"));
  assert_true(server_log_has(&M, "this server refused the client's certificate: unable to get "
                                 "local issuer certificate"));
  /* A key that is not the certificate's is the caller's mistake, said so. */
  tls_opts wrong_key = {.ca = "ca.pem", .cert = "client.pem", .key = "client-other.key"};
  char msg[600];
  hfc_client *c;
  assert_int_equal(tls_connect(url, &wrong_key, &c, msg, sizeof msg), HFC_E_ARG);
  assert_non_null(strstr(msg, "tls_key_file"));
  /* A certificate without its key, or the reverse, is refused before
   * connecting, naming both. */
  tls_opts halves[] = {{.ca = "ca.pem", .cert = "client.pem"}, {.ca = "ca.pem", .key = "client.key"}};
  for (int k = 0; k < 2; k++) {
    assert_int_equal(tls_connect(url, &halves[k], &c, msg, sizeof msg), HFC_E_ARG);
    if (!strstr(msg, "tls_cert_file and tls_key_file")) fail_msg("half a pair: '%s'", msg);
  }
  /* TLS options with no tls: endpoint would leave the connection plain,
   * the token unencrypted: refused before connecting. */
  char plain[400];
  snprintf(plain, sizeof plain, "tcp:%s,unix:/nonexistent.sock", url + 4);
  tls_opts ca_only = {.ca = "ca.pem"}, name_only = {.server_name = "localhost"};
  const tls_opts *plain_opts[] = {&ca_only, &name_only};
  for (int k = 0; k < 2; k++) {
    assert_int_equal(tls_connect(plain, plain_opts[k], &c, msg, sizeof msg), HFC_E_ARG);
    if (!strstr(msg, "are for tls: endpoints") || !strstr(msg, "unencrypted"))
      fail_msg("TLS options with plain endpoints: '%s'", msg);
  }
}

/* Item: the wrong protocol on either port. */
static void test_wrong_protocol(void **state) {
  (void)state;
  /* A plain client on the TLS port hears why, in its own protocol. */
  char plain[800], msg[600];
  snprintf(plain, sizeof plain, "tcp:%s", S.tls_url + 4);
  hfc_options o = test_options("plain", TEST_TOKEN, 10000);
  hfc_client *c = NULL;
  int rc = hfc_connect(plain, &o, &c);
  snprintf(msg, sizeof msg, "%s", hfc_last_message(NULL));
  if (rc != HFC_E_PROTOCOL || !strstr(msg, "this listener speaks TLS"))
    fail_msg("%s: %s '%s'", plain, hfc_strerror(rc), msg);
  assert_true(server_log_has(&S, "plain-text HELLO on TLS listener"));
  still_serves(&S, &GOOD);
  /* Raw bytes that are neither: the handshake fails, the daemon goes on. */
  int fd = raw_connect(plain);
  assert_true(fd >= 0);
  raw_send(fd, "GET / HTTP/1.0\r\n\r\n", 18);
  assert_true(raw_closed(fd, 5000));
  close(fd);
  still_serves(&S, &GOOD);
  /* A TLS client on the plain port. */
  char tls[800];
  snprintf(tls, sizeof tls, "tls:%s", S.tcp_url + 4);
  tls_opts t = GOOD;
  t.server_name = "localhost";
  rc = tls_connect(tls, &t, &c, msg, sizeof msg);
  if (rc != HFC_E_TLS || !strstr(msg, "plain tcp: listener"))
    fail_msg("%s: %s '%s'", tls, hfc_strerror(rc), msg);
  assert_true(server_log_has(&S, "a TLS client on a plain tcp: listener"));
  still_serves(&S, &GOOD);
}

/* Item: SIGHUP reads the certificate again: an expired one put in its place
 * is refused by clients (the daemon's log says it is expired), the renewed
 * one serves again, and a connection made before keeps working. */
static void test_reload_certificate(void **state) {
  (void)state;
  char url[300], msg[600];
  tls_url(&S, 0, url, sizeof url);
  hfc_client *before;
  assert_int_equal(tls_connect(url, &GOOD, &before, msg, sizeof msg), 0);
  char cmd[1024];
  snprintf(cmd, sizeof cmd, "cp %s/expired.pem %s/served.pem && cp %s/expired.key %s/served.key",
           cert_dir, cert_dir, cert_dir, cert_dir);
  assert_int_equal(system(cmd), 0);
  kill(S.pid, SIGHUP);
  for (int i = 0; i < 500 && !server_log_has(&S, "EXPIRED"); i++) usleep(10000);
  assert_true(server_log_has(&S, "reload: TLS: certificate"));
  hfc_client *c;
  int rc = tls_connect(url, &GOOD, &c, msg, sizeof msg);
  if (rc != HFC_E_TLS || !strstr(msg, "certificate has expired") || !strstr(msg, "renewed"))
    fail_msg("expired: %s '%s'", hfc_strerror(rc), msg);
  float *out = malloc(64 * 48 * 3 * sizeof(float));
  assert_int_equal(filter_frame(before, out), 0);
  hfc_close(before);
  /* A key that does not match keeps the one loaded before. */
  snprintf(cmd, sizeof cmd, "cp %s/server.pem %s/served.pem", cert_dir, cert_dir);
  assert_int_equal(system(cmd), 0);
  kill(S.pid, SIGHUP);
  for (int i = 0; i < 500 && !server_log_has(&S, "keeps serving"); i++) usleep(10000);
  assert_true(server_log_has(&S, "the certificate loaded before keeps serving"));
  snprintf(cmd, sizeof cmd, "cp %s/server.key %s/served.key", cert_dir, cert_dir);
  assert_int_equal(system(cmd), 0);
  kill(S.pid, SIGHUP);
  int ok = 0;
  for (int i = 0; i < 500 && !ok; i++) {
    usleep(10000);
    ok = tls_connect(url, &GOOD, &c, msg, sizeof msg) == 0;
    if (!ok) hfc_close(c);
  }
  if (!ok) fail_msg("the renewed certificate does not serve: %s", msg);
  assert_int_equal(filter_frame(c, out), 0);
  hfc_close(c);
  free(out);
}

/* Item: the TLS options are checked at start, naming what is wrong. */
static void test_start_options(void **state) {
  (void)state;
  char cert[256], key[256], other_key[256], out[4096];
  path_of(cert, sizeof cert, "server.pem");
  path_of(key, sizeof key, "server.key");
  path_of(other_key, sizeof other_key, "client.key");
  struct {
    const char *args[12];
    int status;
    const char *says;
  } cases[] = {
    {{"--listen", "tls:127.0.0.1:0", "--weights-dir", H.weights_dir, NULL}, 2,
     "needs --tls-cert FILE and --tls-key FILE"},
    {{"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--weights-dir", H.weights_dir, NULL},
     2, "needs --tls-cert FILE and --tls-key FILE"},
    {{"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", key,
      "--tls-client-cert-auth", "--weights-dir", H.weights_dir, NULL},
     2, "--tls-client-cert-auth needs --tls-client-ca"},
    {{"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", other_key,
      "--weights-dir", H.weights_dir, "--backend", "cpu-ref", "--no-auth", NULL},
     1, "is not the key of --tls-cert"},
    {{"--listen", "tls:127.0.0.1:0", "--tls-cert", "/nonexistent.pem", "--tls-key", key,
      "--weights-dir", H.weights_dir, "--backend", "cpu-ref", "--no-auth", NULL},
     1, "--tls-cert /nonexistent.pem"},
    {{"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", key, "--weights-dir",
      H.weights_dir, "--backend", "cpu-ref", NULL},
     2, "TCP needs a token"},
  };
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
    int st = daemon_run(cases[k].args, NULL, 20000, out, sizeof out);
    if (st != cases[k].status || !strstr(out, cases[k].says))
      fail_msg("case %zu: status %d, said: %s", k, st, out);
  }
}

/* Runs the hairfilter CLI with args (shell words) and the token in the
 * environment: its exit status, stdout and stderr in out. */
static int run_cli(const char *args, const char *token, char *out, size_t cap) {
  char log[300], cmd[2048];
  snprintf(log, sizeof log, "%s/cli.txt", H.dir);
  snprintf(cmd, sizeof cmd, "HAIRFILTER_TOKEN='%s' '%s' %s > '%s' 2>&1", token,
           HAIRFILTER_CLI_PATH, args, log);
  int rc = system(cmd);
  out[0] = 0;
  FILE *f = fopen(log, "r");
  if (f) {
    size_t n = fread(out, 1, cap - 1, f);
    out[n] = 0;
    fclose(f);
  }
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

/* Item: the CLI's TLS options: --tls-server-name, certificate and key
 * together, messages that name the options and say each thing once. */
static void test_cli(void **state) {
  (void)state;
  char num[300], args[1500], out[4096], ca[256], cert[256];
  tls_url(&S, 1, num, sizeof num);
  path_of(ca, sizeof ca, "ca.pem");
  path_of(cert, sizeof cert, "client.pem");
  snprintf(args, sizeof args, "filter --server %s --tls-ca '%s' --tls-server-name localhost --list",
           num, ca);
  int st = run_cli(args, TEST_TOKEN, out, sizeof out);
  if (st != 0 || !strstr(out, "Small")) fail_msg("--tls-server-name: status %d: %s", st, out);
  /* Without it: the names the certificate has, and the option to use. */
  snprintf(args, sizeof args, "filter --server %s --tls-ca '%s' --list", num, ca);
  st = run_cli(args, TEST_TOKEN, out, sizeof out);
  char *first = strstr(out, num), *tls = strstr(out, "TLS handshake");
  if (st != 1 || !strstr(out, "names DNS:localhost") || !strstr(out, "--tls-server-name NAME") ||
      !first || strstr(first + 1, num) || !tls || strstr(tls + 1, "TLS handshake"))
    fail_msg("name mismatch: status %d: %s", st, out);
  /* A wrong token: where the CLI takes it from. */
  snprintf(args, sizeof args, "filter --server %s --tls-ca '%s' --tls-server-name localhost --list",
           num, ca);
  st = run_cli(args, "not-the-token", out, sizeof out);
  if (st != 1 || !strstr(out, "UNAUTHORIZED") ||
      !strstr(out, "the token given is not the server's: compare --token or $HAIRFILTER_TOKEN"))
    fail_msg("wrong token: status %d: %s", st, out);
  /* Half a client certificate is refused before connecting. */
  const char *cmds[] = {"filter --list", "load --variant Small", "conformance"};
  for (int k = 0; k < 3; k++) {
    snprintf(args, sizeof args, "%s --server %s --tls-ca '%s' --tls-cert '%s'", cmds[k], num, ca,
             cert);
    st = run_cli(args, TEST_TOKEN, out, sizeof out);
    if (st != 2 || !strstr(out, "give --tls-cert and --tls-key together"))
      fail_msg("%s with --tls-cert alone: status %d: %s", cmds[k], st, out);
  }
}

/* Starts L with a TLS listener (the served certificate) and the limit
 * options in limits (NULL-terminated, at most 8), and writes the plain
 * tcp: URL of that listener to tcp, for peers that speak no TLS. */
static void start_tls_limited(server *L, const char *const *limits, char *tcp, size_t tcplen) {
  char cert[256], key[256], url[300];
  path_of(cert, sizeof cert, "served.pem");
  path_of(key, sizeof key, "served.key");
  const char *largs[16] = {"--listen", "tls:127.0.0.1:0", "--tls-cert", cert, "--tls-key", key};
  int n = 6;
  for (int i = 0; limits[i]; i++) {
    assert_true(n < 15);
    largs[n++] = limits[i];
  }
  largs[n] = NULL;
  assert_int_equal(server_start(&H, L, largs), 0);
  tls_url(L, 1, url, sizeof url);
  snprintf(tcp, tcplen, "tcp:%s", strchr(url, ':') + 1);
}

/* Item: TCP connections to a TLS listener that never start their TLS
 * handshake cannot fill --max-connections: those refused at the limit, or
 * pushed out by --max-handshakes, are closed at once (no TLS session could
 * carry their ERROR), and a real client gets in beside a hundred of them. */
static void test_bare_connections_leave_room(void **state) {
  (void)state;
  enum { N = 100 };
  server L;
  char url[300], msg[600], tcp[300];
  const char *limits[] = {"--max-connections", "8", "--max-handshakes", "2", NULL};
  start_tls_limited(&L, limits, tcp, sizeof tcp);
  int fd[N];
  for (int i = 0; i < N; i++) {
    fd[i] = raw_connect(tcp);
    assert_true(fd[i] >= 0);
    assert_int_equal(raw_send(fd[i], "\x16", 1), 0); /* the start of a ClientHello, no more */
  }
  usleep(100000);
  tls_url(&L, 0, url, sizeof url);
  hfc_client *c;
  int rc = tls_connect(url, &GOOD, &c, msg, sizeof msg);
  if (rc) fail_msg("a client beside %d bare connections: %s (%s)", N, hfc_strerror(rc), msg);
  hfc_close(c);
  for (int i = 0; i < N; i++) close(fd[i]);
  assert_int_equal(server_stop(&L, 20000), 0);
}

/* Item: TCP connections to a TLS listener that never start their TLS
 * handshake are held to --max-handshakes like any other peer before its
 * HELLO: those pushed out are closed once the grace for a racing handshake
 * (HFD_TLS_FATAL_GRACE_MS in server/server.h, 2 s) has passed without one
 * to carry their BUSY, long before the handshake deadline; the newest stay. */
static void test_silent_crowd_held_to_max_handshakes(void **state) {
  (void)state;
  enum { N = 6, KEEP = 2 };
  server L;
  char tcp[300];
  /* One address stands for many peers: its own part as large as the whole. */
  const char *limits[] = {"--max-handshakes", "2", "--max-handshakes-per-address", "2",
                          "--handshake-timeout-ms", "60000", NULL};
  start_tls_limited(&L, limits, tcp, sizeof tcp);
  int fd[N], open_[N];
  for (int i = 0; i < N; i++) {
    assert_true((fd[i] = raw_connect(tcp)) >= 0);
    open_[i] = 1;
    usleep(20000); /* accepted in this order */
  }
  /* The grace, then up to one sweep (at most a second), with room to spare. */
  int closed = 0;
  for (int waited = 0; closed < N - KEEP && waited < 2000 + 4000; waited += 50) {
    usleep(50000);
    for (int i = 0; i < N; i++) {
      struct pollfd p = {fd[i], POLLIN, 0};
      char b;
      if (open_[i] && poll(&p, 1, 0) == 1 && read(fd[i], &b, 1) <= 0) open_[i] = 0, closed++;
    }
  }
  for (int i = 0; i < N; i++) {
    if (i < N - KEEP && open_[i])
      fail_msg("silent connection %d of %d, pushed out by --max-handshakes 2, is still open", i, N);
    if (i >= N - KEEP && !open_[i])
      fail_msg("silent connection %d of %d, within --max-handshakes 2, was closed", i, N);
  }
  for (int i = 0; i < N; i++) close(fd[i]);
  assert_int_equal(server_stop(&L, 20000), 0);
}

/* Sends what the memory BIO holds to fd; 0 on success. */
static int flush_bio(BIO *w, int fd) {
  char buf[16384];
  int n;
  while ((n = BIO_read(w, buf, sizeof buf)) > 0)
    if (raw_send(fd, buf, (size_t)n)) return -1;
  return 0;
}

/* Feeds what fd has (waiting up to 5 s for the first byte) into r; 0 on
 * success, -1 on EOF, error or timeout. */
static int fill_bio(BIO *r, int fd) {
  struct pollfd p = {fd, POLLIN, 0};
  if (poll(&p, 1, 5000) != 1) return -1;
  char buf[16384];
  ssize_t n = read(fd, buf, sizeof buf);
  return n > 0 && BIO_write(r, buf, (int)n) == n ? 0 : -1;
}

/* Item: a client that offers only a finite-field group (ffdhe8192, which
 * cost the server 118 ms a handshake against 0.33 ms for X25519, its
 * choice before any token is checked) fails the handshake at once; one
 * offering X25519 or P-256 is served. */
static void test_expensive_groups_refused(void **state) {
  (void)state;
  char url[300], tcp[300];
  tls_url(&S, 1, url, sizeof url);
  snprintf(tcp, sizeof tcp, "tcp:%s", strchr(url, ':') + 1);
  const char *groups[] = {"ffdhe8192", "ffdhe2048", "X25519", "P-256"};
  for (int g = 0; g < 4; g++) {
    SSL_CTX *ctx = SSL_CTX_new(TLS_client_method());
    assert_non_null(ctx);
    SSL_CTX_set_verify(ctx, SSL_VERIFY_NONE, NULL);
    assert_int_equal(SSL_CTX_set1_groups_list(ctx, groups[g]), 1);
    SSL *ssl = SSL_new(ctx);
    BIO *rb = BIO_new(BIO_s_mem()), *wb = BIO_new(BIO_s_mem());
    assert_true(ssl && rb && wb);
    SSL_set_bio(ssl, rb, wb);
    SSL_set_connect_state(ssl);
    int fd = raw_connect(tcp);
    assert_true(fd >= 0);
    int r;
    while ((r = SSL_do_handshake(ssl)) != 1 && SSL_get_error(ssl, r) == SSL_ERROR_WANT_READ &&
           flush_bio(wb, fd) == 0 && fill_bio(rb, fd) == 0) {
    }
    ERR_clear_error();
    if (g < 2 && r == 1)
      fail_msg("a handshake offering only %s was completed; it should fail (no group in "
               "common)", groups[g]);
    if (g >= 2 && r != 1) fail_msg("a handshake offering %s failed", groups[g]);
    SSL_free(ssl);
    SSL_CTX_free(ctx);
    close(fd);
  }
}

/* Item: a TLS client that --max-handshakes pushes out while its handshake
 * is under way (its ClientHello answered, its Finished not yet read by the
 * server; from the client's side the handshake may be done) gets the fatal
 * BUSY as soon as its handshake completes, not a bare close. */
static void test_mid_handshake_eviction_says_busy(void **state) {
  (void)state;
  server L;
  char tcp[300];
  /* One address stands for many peers: its own part as large as the whole. */
  const char *limits[] = {"--max-handshakes", "2", "--max-handshakes-per-address", "2", NULL};
  start_tls_limited(&L, limits, tcp, sizeof tcp);
  SSL_CTX *ctx = SSL_CTX_new(TLS_client_method());
  assert_non_null(ctx);
  SSL_CTX_set_verify(ctx, SSL_VERIFY_NONE, NULL);
  SSL *ssl = SSL_new(ctx);
  BIO *rb = BIO_new(BIO_s_mem()), *wb = BIO_new(BIO_s_mem());
  assert_true(ssl && rb && wb);
  SSL_set_bio(ssl, rb, wb);
  SSL_set_connect_state(ssl);
  int fd = raw_connect(tcp);
  assert_true(fd >= 0);
  /* Run the client's side of the handshake, holding back its last flight
   * (the Finished) so that the server stays mid-handshake. */
  int r;
  while ((r = SSL_do_handshake(ssl)) != 1) {
    assert_int_equal(SSL_get_error(ssl, r), SSL_ERROR_WANT_READ);
    assert_int_equal(flush_bio(wb, fd), 0);
    assert_int_equal(fill_bio(rb, fd), 0);
  }
  /* Two more connections before their HELLO push the oldest out: the
   * first sends its ClientHello and is answered (a peer the server has
   * not answered, one that sent nothing or a byte, would go first); the
   * second, just accepted, is over the limit. */
  int other[2];
  SSL *mid = SSL_new(ctx);
  BIO *mrb = BIO_new(BIO_s_mem()), *mwb = BIO_new(BIO_s_mem());
  assert_true(mid && mrb && mwb);
  SSL_set_bio(mid, mrb, mwb);
  SSL_set_connect_state(mid);
  assert_true((other[0] = raw_connect(tcp)) >= 0);
  r = SSL_do_handshake(mid);
  assert_int_equal(SSL_get_error(mid, r), SSL_ERROR_WANT_READ);
  assert_int_equal(flush_bio(mwb, other[0]), 0);
  assert_int_equal(fill_bio(mrb, other[0]), 0);   /* the server's answer */
  assert_true((other[1] = raw_connect(tcp)) >= 0);
  usleep(200000);
  assert_int_equal(flush_bio(wb, fd), 0);
  uint8_t got[4096];
  size_t have = 0;
  hfp_header h = {0};
  while (have < HFP_HEADER_SIZE || have < HFP_HEADER_SIZE + (size_t)h.length) {
    int n = SSL_read(ssl, got + have, (int)(sizeof got - have));
    if (n > 0) {
      have += (size_t)n;
      if (have >= HFP_HEADER_SIZE) assert_int_equal(hfp_header_decode(got, 4096, &h), 0);
      continue;
    }
    if (SSL_get_error(ssl, n) != SSL_ERROR_WANT_READ || fill_bio(rb, fd))
      fail_msg("the evicted client got no ERROR (the connection closed without one)");
  }
  hfp_error e;
  assert_int_equal(h.type, HFP_ERROR);
  assert_int_equal(hfp_decode_error(got + HFP_HEADER_SIZE, h.length, &e), 0);
  assert_int_equal(e.code, HFP_E_BUSY);
  assert_true(e.fatal);
  SSL_free(ssl);
  SSL_free(mid);
  SSL_CTX_free(ctx);
  close(fd);
  for (int i = 0; i < 2; i++) close(other[i]);
  assert_int_equal(server_stop(&L, 20000), 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_tls_equals_tcp),
    cmocka_unit_test(test_tls_estimate_apart),
    cmocka_unit_test(test_server_certificate_refused),
    cmocka_unit_test(test_client_certificate_refused),
    cmocka_unit_test(test_wrong_protocol),
    cmocka_unit_test(test_reload_certificate),
    cmocka_unit_test(test_start_options),
    cmocka_unit_test(test_cli),
    cmocka_unit_test(test_bare_connections_leave_room),
    cmocka_unit_test(test_mid_handshake_eviction_says_busy),
    cmocka_unit_test(test_expensive_groups_refused),
    cmocka_unit_test(test_silent_crowd_held_to_max_handshakes),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
