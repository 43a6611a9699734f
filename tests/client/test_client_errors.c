/* libhairfilter's errors against a real hairfilterd: buffer sizes refused
 * before anything is read (run under AddressSanitizer in .ci/run, which
 * would report the over-read of a short features buffer), messages that name
 * the field and are cleared by every call, errno kept for connect failures,
 * unknown variants answered with the loaded names, names matched without
 * regard to case, versions. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

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

/* A Tiny (2 spp) request of w x h on exactly sized heap buffers. */
typedef struct frame {
  hfc_request r;
  float *in, *out;
} frame;

static void frame_make(frame *f, int w, int h, size_t in_bytes, size_t out_bytes) {
  f->in = make_features(w, h, 2, 7);
  assert_non_null(f->in);
  if (in_bytes < hfc_features_bytes(w, h, 2, HFC_F32)) {
    /* A buffer really this short, so that reading past it is an error
     * AddressSanitizer reports. */
    float *shortbuf = malloc(in_bytes);
    assert_non_null(shortbuf);
    memcpy(shortbuf, f->in, in_bytes);
    free(f->in);
    f->in = shortbuf;
  }
  f->out = malloc(out_bytes);
  assert_non_null(f->out);
  hfc_request_init(&f->r);
  f->r.variant = "Tiny";
  f->r.width = w;
  f->r.height = h;
  f->r.spp = 2;
  f->r.features = f->in;
  f->r.features_bytes = in_bytes;
  f->r.result = f->out;
  f->r.result_bytes = out_bytes;
}

static void frame_free(frame *f) {
  free(f->in);
  free(f->out);
}

static void expect_reference(const frame *f) {
  const ref_variant *v = harness_variant(&H, "Tiny");
  size_t n = (size_t)f->r.width * f->r.height * 3;
  float *want = malloc(n * sizeof *want);
  assert_non_null(want);
  assert_int_equal(reference(v, f->r.width, f->r.height, f->in, HFP_F32, want, HFP_F32), 0);
  assert_memory_equal(f->out, want, n * sizeof *want);
  free(want);
}

/* A features buffer one sample short of the frame is refused, naming the
 * field and both sizes, before a byte is read; the client stays usable. */
static void test_short_buffers_refused(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "short");
  assert_non_null(c);
  const int w = 16, h = 12;
  size_t need_in = hfc_features_bytes(w, h, 2, HFC_F32);
  size_t need_out = hfc_output_bytes(w, h, 3, HFC_F32);
  assert_int_equal(need_in, (size_t)w * h * 12 * 4);
  assert_int_equal(need_out, (size_t)w * h * 3 * 4);

  frame f;
  frame_make(&f, w, h, need_in - 6 * sizeof(float), need_out);
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_ARG);
  const char *m = hfc_last_message(c);
  assert_non_null(strstr(m, "hfc_request.features_bytes"));
  char want[64];
  snprintf(want, sizeof want, "needs %zu", need_in);
  assert_non_null(strstr(m, want));
  assert_int_equal(hfc_submit(c, &f.r, NULL), HFC_E_ARG);
  assert_int_equal(hfc_pending(c), 0);
  frame_free(&f);

  /* A result buffer one pixel short: refused, nothing written past it. */
  frame_make(&f, w, h, need_in, need_out - 3 * sizeof(float));
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "hfc_request.result_bytes"));
  /* and the composite's */
  f.r.result_bytes = need_out + 3 * sizeof(float);
  float rgba[4];
  f.r.rgba = rgba;
  f.r.rgba_bytes = sizeof rgba;
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "hfc_request.rgba_bytes"));
  frame_free(&f);

  /* Sizes at least as large work, and the connection was never touched. */
  frame_make(&f, w, h, need_in, need_out);
  f.r.features_bytes = need_in + 100;
  assert_int_equal(hfc_filter(c, &f.r, NULL), 0);
  assert_string_equal(hfc_last_message(c), "");
  expect_reference(&f);
  frame_free(&f);
  hfc_close(c);
}

/* Every bad field is named in the message. */
static void test_fields_named(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "fields");
  assert_non_null(c);
  frame f;
  frame_make(&f, 4, 4, hfc_features_bytes(4, 4, 2, HFC_F32), hfc_output_bytes(4, 4, 3, HFC_F32));
  struct {
    const char *field;
    hfc_request r;
  } bad[16];
  int n = 0;
  bad[n].field = "hfc_request.struct_size";
  bad[n].r = f.r;
  bad[n++].r.struct_size = 0;
  bad[n].field = "hfc_request.variant";
  bad[n].r = f.r;
  bad[n++].r.variant = NULL;
  bad[n].field = "hfc_request.width";
  bad[n].r = f.r;
  bad[n++].r.width = 0;
  bad[n].field = "hfc_request.height";
  bad[n].r = f.r;
  bad[n++].r.height = 70000;
  bad[n].field = "hfc_request.spp";
  bad[n].r = f.r;
  bad[n++].r.spp = 17;
  bad[n].field = "hfc_request.in_dtype";
  bad[n].r = f.r;
  bad[n++].r.in_dtype = (hfc_dtype)5;
  bad[n].field = "hfc_request.features is NULL: give";   /* and what to do */
  bad[n].r = f.r;
  bad[n++].r.features = NULL;
  bad[n].field = "hfc_request.result is NULL: give";
  bad[n].r = f.r;
  bad[n++].r.result = NULL;
  bad[n].field = "hfc_request.light has a value that is not finite: want";
  bad[n].r = f.r;
  bad[n++].r.light[1] = INFINITY;
  /* A composite under a light left at 0 would draw the hair black. */
  float rgba[4 * 4 * 4];
  bad[n].field = "hfc_request.light is 0,0,0";
  bad[n].r = f.r;
  bad[n].r.rgba = rgba;
  bad[n++].r.rgba_bytes = sizeof rgba;
  /* A dtype that does not fit its buffer: the dtype's field is named
   * beside the size's, since either may be the mistake. */
  bad[n].field = "in f32 (hfc_request.in_dtype) needs";
  bad[n].r = f.r;
  bad[n++].r.features_bytes = hfc_features_bytes(4, 4, 2, HFC_F16);
  bad[n].field = "in f32 (hfc_request.out_dtype) needs";
  bad[n].r = f.r;
  bad[n++].r.result_bytes = hfc_output_bytes(4, 4, 3, HFC_F16);
  bad[n].field = "hfc_output_bytes(width, height, 4, out_dtype)";
  bad[n].r = f.r;
  bad[n].r.rgba = rgba;
  bad[n].r.light[0] = 1;
  bad[n++].r.rgba_bytes = hfc_output_bytes(4, 4, 4, HFC_F16);
  for (int i = 0; i < n; i++) {
    assert_int_equal(hfc_filter(c, &bad[i].r, NULL), HFC_E_ARG);
    if (!strstr(hfc_last_message(c), bad[i].field))
      fail_msg("case %d: '%s' does not name %s", i, hfc_last_message(c), bad[i].field);
  }
  void *mem = NULL;
  assert_int_equal(hfc_shm_alloc(c, 0, &mem), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "bytes is 0: want"));
  /* Options too, with the message in this thread since there is no client. */
  hfc_options o;
  hfc_options_init(&o);
  o.client_name = "has space";
  hfc_client *d = NULL;
  assert_int_equal(hfc_connect(S.unix_url, &o, &d), HFC_E_ARG);
  assert_null(d);
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_options.client_name"));
  o.client_name = NULL;
  o.struct_size = 0;
  assert_int_equal(hfc_connect(S.unix_url, &o, &d), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_options.struct_size"));
  o.struct_size = offsetof(hfc_options, tls_ca_file) + 4;   /* inside a pointer */
  assert_int_equal(hfc_connect(S.unix_url, &o, &d), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(NULL), "not the size of any version"));
  o.struct_size = offsetof(hfc_options, tls_ca_file);       /* 0.1.0's */
  assert_int_equal(hfc_connect(S.unix_url, &o, &d), 0);
  hfc_close(d);
  frame_free(&f);
  hfc_close(c);
}

/* A request of an older header (0.1.0's ended at user) is filtered as one
 * of this header with the fields it lacks at their hfc_request_init()
 * values, whatever lies in memory beyond it; a newer header's larger
 * request is filtered when the fields past ours are zero and refused when
 * one is set; a size no version had (ending inside a field) is refused. */
static void test_request_sizes(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "older");
  assert_non_null(c);
  frame f;
  frame_make(&f, 8, 6, hfc_features_bytes(8, 6, 2, HFC_F32), hfc_output_bytes(8, 6, 3, HFC_F32));
  hfc_request r = f.r;
  r.struct_size = offsetof(hfc_request, estimate);
  /* What an older caller's memory may hold past its struct. */
  r.estimate = 7;
  r.estimate_buffer = f.in;
  r.estimate_bytes = 3;
  memset(f.out, 0xff, hfc_output_bytes(8, 6, 3, HFC_F32));
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  expect_reference(&f);

  /* 0.2.0's request ended at estimate_bytes: a budget in the memory past
   * it is not read (a frame of 1 us would expire). */
  r = f.r;
  r.struct_size = offsetof(hfc_request, deadline_us);
  r.deadline_us = 1;
  memset(f.out, 0xff, hfc_output_bytes(8, 6, 3, HFC_F32));
  assert_int_equal(hfc_filter(c, &r, NULL), 0);
  expect_reference(&f);

  struct {
    hfc_request r;
    unsigned char newer[16];
  } big;
  memset(&big, 0, sizeof big);
  big.r = f.r;
  big.r.struct_size = sizeof big;
  memset(f.out, 0xff, hfc_output_bytes(8, 6, 3, HFC_F32));
  assert_int_equal(hfc_filter(c, &big.r, NULL), 0);
  expect_reference(&f);
  big.newer[5] = 1;
  assert_int_equal(hfc_filter(c, &big.r, NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(c), "from a newer hairfilter.h"));
  char want[32];
  snprintf(want, sizeof want, "byte %zu", sizeof(hfc_request) + 5);
  assert_non_null(strstr(hfc_last_message(c), want));

  size_t bad[] = {offsetof(hfc_request, estimate) - 1, offsetof(hfc_request, estimate) + 2,
                  offsetof(hfc_request, estimate_buffer),
                  offsetof(hfc_request, estimate_buffer) + 4,
                  offsetof(hfc_request, deadline_us) + 2, sizeof(hfc_request) - 1};
  for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
    r = f.r;
    r.struct_size = bad[i];
    assert_int_equal(hfc_filter(c, &r, NULL), HFC_E_ARG);
    assert_non_null(strstr(hfc_last_message(c), "not the size of any version"));
    assert_non_null(strstr(hfc_last_message(c), "hfc_request.struct_size"));
  }
  frame_free(&f);
  hfc_close(c);
}

/* A result buffer that is not writable for its result_bytes (a caller's
 * mistake the library cannot see): the reply cannot be read, the
 * connection is lost, and the message names the buffer (it said
 * "connection failed: connect again" alone). */
static void test_result_not_writable(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "efault");
  assert_non_null(c);
  frame f;
  size_t out = hfc_output_bytes(8, 6, 3, HFC_F32);
  frame_make(&f, 8, 6, hfc_features_bytes(8, 6, 2, HFC_F32), out);
  long page = sysconf(_SC_PAGESIZE);
  size_t span = ((out + (size_t)page - 1) / (size_t)page + 1) * (size_t)page;
  unsigned char *m = mmap(NULL, span, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  assert_true(m != MAP_FAILED);
  /* Its last page read-only: a result starting 16 bytes before it. */
  assert_int_equal(mprotect(m + span - (size_t)page, (size_t)page, PROT_READ), 0);
  hfc_request r = f.r;
  r.result = m + span - (size_t)page - 16;
  int rc = hfc_filter(c, &r, NULL);
  assert_int_equal(rc, HFC_E_IO);
  assert_non_null(strstr(hfc_last_message(c), "result or rgba buffer is not writable"));
  munmap(m, span);
  frame_free(&f);
  hfc_close(c);
}

/* The message of one call never survives into the next. */
static void test_message_cleared(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "cleared");
  assert_non_null(c);
  frame f;
  frame_make(&f, 4, 4, hfc_features_bytes(4, 4, 2, HFC_F32), hfc_output_bytes(4, 4, 3, HFC_F32));
  f.r.variant = "Nope";
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_UNKNOWN_VARIANT);
  assert_non_null(strstr(hfc_last_message(c), "Nope"));
  /* A bad argument next: its own message, not the server's last words. */
  f.r.variant = "Tiny";
  f.r.width = 0;
  assert_int_equal(hfc_submit(c, &f.r, NULL), HFC_E_ARG);
  assert_null(strstr(hfc_last_message(c), "Nope"));
  assert_non_null(strstr(hfc_last_message(c), "hfc_request.width"));
  /* Then a call that succeeds leaves none, here and in the thread's copy. */
  f.r.width = 4;
  assert_int_equal(hfc_filter(c, &f.r, NULL), 0);
  assert_string_equal(hfc_last_message(c), "");
  assert_string_equal(hfc_last_message(NULL), "");
  hfc_variant vs[8];
  int nv;
  f.r.variant = "Nope";
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_UNKNOWN_VARIANT);
  assert_int_equal(hfc_list_variants(c, vs, 8, &nv), 0);
  assert_string_equal(hfc_last_message(c), "");
  frame_free(&f);
  hfc_close(c);
}

/* An unknown variant is answered with the names the server has; a name
 * that differs only in case is that variant. */
static void test_variant_names(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "names");
  assert_non_null(c);
  frame f;
  frame_make(&f, 8, 6, hfc_features_bytes(8, 6, 2, HFC_F32), hfc_output_bytes(8, 6, 3, HFC_F32));
  f.r.variant = "Tinny";
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_UNKNOWN_VARIANT);
  const char *m = hfc_last_message(c);
  assert_non_null(strstr(m, "Tinny"));
  assert_non_null(strstr(m, "Tiny"));
  assert_non_null(strstr(m, "Small"));
  assert_non_null(strstr(m, "Mono"));
  const char *names[] = {"tiny", "TINY", "tInY"};
  for (int i = 0; i < 3; i++) {
    f.r.variant = names[i];
    memset(f.out, 0, hfc_output_bytes(8, 6, 3, HFC_F32));
    assert_int_equal(hfc_filter(c, &f.r, NULL), 0);
    expect_reference(&f);
  }
  frame_free(&f);
  hfc_close(c);
}

/* The errors a Tiny frame counts in the server's statistics. */
static uint64_t tiny_failed(hfc_client *c) {
  hfc_stats *st = malloc(sizeof *st);
  assert_non_null(st);
  assert_int_equal(hfc_get_stats(c, st), 0);
  uint64_t n = UINT64_MAX;
  for (int i = 0; i < st->num_variants; i++)
    if (!strcmp(st->variants[i].name, "Tiny"))
      n = st->variants[i].requests_failed + st->variants[i].rejected;
  free(st);
  assert_true(n != UINT64_MAX);
  return n;
}

/* A request with other samples per pixel than its variant is HFC_E_ARG
 * naming hfc_request.spp and the variant's, before the frame goes out
 * (the server would have read all of it to answer INVALID). */
static void test_spp_mismatch(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "spp");
  assert_non_null(c);
  frame f;
  frame_make(&f, 8, 6, hfc_features_bytes(8, 6, 4, HFC_F32), hfc_output_bytes(8, 6, 3, HFC_F32));
  uint64_t before = tiny_failed(c);
  f.r.spp = 4;   /* Tiny takes 2 */
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_E_ARG);
  const char *m = hfc_last_message(c);
  if (!strstr(m, "hfc_request.spp is 4") || !strstr(m, "Tiny takes 2"))
    fail_msg("the message does not name hfc_request.spp and Tiny's 2: %s", m);
  f.r.variant = "tiny";   /* matched without regard to case, then checked */
  assert_int_equal(hfc_submit(c, &f.r, NULL), HFC_E_ARG);
  assert_int_equal(hfc_pending(c), 0);
  assert_int_equal(tiny_failed(c), before);
  f.r.spp = 2;
  assert_int_equal(hfc_filter(c, &f.r, NULL), HFC_OK);
  frame_free(&f);
  hfc_close(c);
}

/* A failed connect leaves errno and a message naming the endpoint and the
 * reason: a missing socket and a refused one read differently, and both
 * differently from a socket this user may not open. */
static void test_connect_errno(void **state) {
  (void)state;
  char url[300];
  hfc_client *c = NULL;
  snprintf(url, sizeof url, "unix:%s/none.sock", H.dir);
  errno = 0;
  assert_int_equal(hfc_connect(url, NULL, &c), HFC_E_CONNECT);
  assert_int_equal(errno, ENOENT);
  assert_null(c);
  assert_non_null(strstr(hfc_last_message(NULL), url));
  assert_non_null(strstr(hfc_last_message(NULL), strerror(ENOENT)));

  /* A socket file nobody listens on. */
  char path[256];
  snprintf(path, sizeof path, "%s/dead.sock", H.dir);
  int lfd = socket(AF_UNIX, SOCK_STREAM, 0);
  struct sockaddr_un sun;
  memset(&sun, 0, sizeof sun);
  sun.sun_family = AF_UNIX;
  assert_true(strlen(path) < sizeof sun.sun_path);
  memcpy(sun.sun_path, path, strlen(path) + 1);
  assert_int_equal(bind(lfd, (struct sockaddr *)&sun, sizeof sun), 0);
  close(lfd);
  snprintf(url, sizeof url, "unix:%s", path);
  assert_int_equal(hfc_connect(url, NULL, &c), HFC_E_CONNECT);
  assert_int_equal(errno, ECONNREFUSED);
  assert_non_null(strstr(hfc_last_message(NULL), strerror(ECONNREFUSED)));
  unlink(path);

  /* The daemon's own socket, for a user who may not open it. As root (who
   * may open anything) the check runs in a child that becomes nobody; the
   * harness folder is private to its owner. */
  pid_t pid = fork();
  assert_true(pid >= 0);
  if (pid == 0) {
    if (geteuid() == 0) {
      if (setgid(65534) || setuid(65534)) _exit(3);
    } else {
      const char *p = S.unix_url + 5;
      if (chmod(p, 0)) _exit(3);
    }
    hfc_client *d = NULL;
    int rc = hfc_connect(S.unix_url, NULL, &d);
    int e = errno;
    const char *msg = hfc_last_message(NULL);
    if (geteuid() != 0) chmod(S.unix_url + 5, 0660);
    if (rc != HFC_E_CONNECT) _exit(4);
    if (e != EACCES) _exit(5);
    if (!strstr(msg, strerror(EACCES)) || !strstr(msg, "group")) _exit(6);
    _exit(0);
  }
  int st;
  assert_int_equal(waitpid(pid, &st, 0), pid);
  assert_true(WIFEXITED(st));
  assert_int_equal(WEXITSTATUS(st), 0);

  /* A list: every endpoint named, with its reason. */
  snprintf(url, sizeof url, "unix:%s/a.sock,tcp:127.0.0.1:1", H.dir);
  assert_int_equal(hfc_connect(url, NULL, &c), HFC_E_CONNECT);
  assert_non_null(strstr(hfc_last_message(NULL), "a.sock: connect: "));
  assert_non_null(strstr(hfc_last_message(NULL), "tcp:127.0.0.1:1: connect: "));
  assert_int_equal(errno, ECONNREFUSED);   /* the last endpoint's */
  assert_int_equal(hfc_check_url("unix:/a,,tcp:1", NULL, 0), HFC_E_URL);
  /* hfc_last_message(NULL) says why, as after any call that fails (it was
   * left empty). */
  assert_true(hfc_last_message(NULL)[0] != 0);
  char why[200];
  assert_int_equal(hfc_check_url("unix:/a,tcp:h:99999", why, sizeof why), HFC_E_URL);
  assert_non_null(strstr(why, "99999"));
  assert_non_null(strstr(hfc_last_message(NULL), "99999"));
  assert_int_equal(hfc_check_url("unix:/a", why, sizeof why), 0);
  assert_string_equal(hfc_last_message(NULL), "");

  /* A path that is a file, not a socket: connect() says refused; the
   * message says what is there (it said "nothing listens there: is
   * hairfilterd running?"). */
  snprintf(path, sizeof path, "%s/plain", H.dir);
  FILE *f = fopen(path, "w");
  assert_non_null(f);
  fclose(f);
  snprintf(url, sizeof url, "unix:%s", path);
  assert_int_equal(hfc_connect(url, NULL, &c), HFC_E_CONNECT);
  assert_non_null(strstr(hfc_last_message(NULL), "is not a socket but a regular file"));
  assert_null(strstr(hfc_last_message(NULL), "is hairfilterd running"));
  unlink(path);

  /* A failover bit the library does not know is refused, naming it. */
  hfc_options o;
  hfc_options_init(&o);
  o.failover = 0x40;
  assert_int_equal(hfc_connect(S.unix_url, &o, &c), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_options.failover has bits 0x40"));
  assert_null(c);
}

/* A server at --max-connections answers the next connection with a fatal
 * BUSY and closes it at once; the client, writing its HELLO after that
 * close, saw EPIPE and reported "handshake: server closed the connection"
 * (HFC_E_CLOSED) without reading the ERROR waiting for it. Every try is
 * HFC_E_BUSY naming the limit. */
static void test_connection_limit(void **state) {
  (void)state;
  static const char *const extra[] = {"--max-connections", "1", NULL};
  server L;
  hfc_client *held = NULL;
  assert_int_equal(server_start_connected(&H, &L, extra, "held", &held), 0);
  const char *urls[] = {L.unix_url, L.tcp_url};
  for (int u = 0; u < 2; u++)
    for (int i = 0; i < 100; i++) {
      hfc_options o = test_options("over", NULL, 5000);
      hfc_client *c = NULL;
      int rc = hfc_connect(urls[u], &o, &c);
      if (rc != HFC_E_BUSY || !strstr(hfc_last_message(NULL), "connection limit (1)"))
        fail_msg("connect %d to %s over --max-connections 1: %s (%s), want BUSY naming the "
                 "limit", i, urls[u], hfc_strerror(rc), hfc_last_message(NULL));
      hfc_close(c);
    }
  hfc_close(held);
  assert_int_equal(server_stop(&L, 20000), 0);
}

/* The 17th segment of a client is HFC_E_INFLIGHT, as the header says,
 * saying what to do; one freed makes room again. */
static void test_segment_limit(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "segments");
  assert_non_null(c);
  void *m[16], *more = NULL;
  for (int i = 0; i < 16; i++) assert_int_equal(hfc_shm_alloc(c, 4096, &m[i]), 0);
  assert_int_equal(hfc_shm_alloc(c, 4096, &more), HFC_E_INFLIGHT);
  assert_non_null(strstr(hfc_last_message(c), "free one with hfc_shm_free"));
  assert_int_equal(hfc_shm_free(c, m[0]), 0);
  assert_int_equal(hfc_shm_alloc(c, 4096, &m[0]), 0);
  for (int i = 0; i < 16; i++) assert_int_equal(hfc_shm_free(c, m[i]), 0);
  hfc_close(c);
}

/* A TCP listener's token refused: the message names the option to set
 * (it was the server's "this listener needs a token" or "wrong token"
 * alone, with nothing naming hfc_options.token). */
static void test_unauthorized_names_the_option(void **state) {
  (void)state;
  const char *tokens[] = {NULL, "wrong"};
  const char *want[] = {"set hfc_options.token", "is not the server's token"};
  for (int i = 0; i < 2; i++) {
    hfc_options o = test_options("auth", tokens[i], 5000);
    hfc_client *c = NULL;
    assert_int_equal(hfc_connect(S.tcp_url, &o, &c), HFC_E_UNAUTHORIZED);
    if (!strstr(hfc_last_message(NULL), want[i]))
      fail_msg("token %s refused: '%s', want '%s'", tokens[i] ? tokens[i] : "none",
               hfc_last_message(NULL), want[i]);
  }
}

/* Versions: the library's, the headers', and the server's in HELLO_OK (to
 * version-2 peers; a version-1 peer gets the version-1 frame). */
static void test_versions(void **state) {
  (void)state;
  assert_string_equal(hfc_version(), HAIRFILTER_VERSION_STRING);
  char v[32];
  snprintf(v, sizeof v, "%d.%d.%d", HAIRFILTER_VERSION_MAJOR, HAIRFILTER_VERSION_MINOR,
           HAIRFILTER_VERSION_PATCH);
  assert_string_equal(v, HAIRFILTER_VERSION_STRING);
  assert_int_equal(HAIRFILTER_VERSION, HAIRFILTER_VERSION_OF(HAIRFILTER_VERSION_MAJOR,
                                                            HAIRFILTER_VERSION_MINOR,
                                                            HAIRFILTER_VERSION_PATCH));
  hfc_client *c = client_connect(&S, "versions");
  assert_non_null(c);
  assert_int_equal(hfc_info(c)->version, HFP_VERSION);
  assert_string_equal(hfc_info(c)->software_version, HAIRFILTER_VERSION_STRING);
  assert_string_equal(hfc_endpoint(c), S.unix_url);
  hfc_close(c);

  for (int version = 1; version <= 2; version++) {
    int fd = raw_connect(S.unix_url);
    assert_true(fd >= 0);
    uint8_t b[512];
    size_t n = raw_hello_frame(b, sizeof b, (uint16_t)version, (uint16_t)version, NULL);
    assert_int_equal(raw_send(fd, b, n), 0);
    hfp_header h;
    uint8_t *p;
    assert_int_equal(raw_read(fd, &h, &p), 0);
    assert_int_equal(h.type, HFP_HELLO_OK);
    hfp_hello_ok ok;
    assert_int_equal(hfp_decode_hello_ok(p, h.length, &ok), 0);
    size_t v1_len = 38 + strlen(ok.server_name);
    if (version == 1) {
      assert_int_equal(h.length, v1_len);
      assert_string_equal(ok.software_version, "");
    } else {
      assert_int_equal(h.length, v1_len + 1 + strlen(HAIRFILTER_VERSION_STRING));
      assert_string_equal(ok.software_version, HAIRFILTER_VERSION_STRING);
    }
    free(p);
    close(fd);
  }
}

/* hfc_fd polls readable once a reply waits. */
static void test_fd_polls(void **state) {
  (void)state;
  hfc_client *c = client_connect(&S, "poll");
  assert_non_null(c);
  frame f;
  frame_make(&f, 8, 8, hfc_features_bytes(8, 8, 2, HFC_F32), hfc_output_bytes(8, 8, 3, HFC_F32));
  assert_int_equal(hfc_submit(c, &f.r, NULL), 0);
  struct pollfd p = {hfc_fd(c), POLLIN, 0};
  assert_int_equal(poll(&p, 1, 20000), 1);
  hfc_completion d;
  assert_int_equal(hfc_wait(c, 0, &d), 0);
  assert_int_equal(d.status, 0);
  expect_reference(&f);
  /* Replies a statistics call read on its way to its own answer are
   * completions no socket shows any more: hfc_fd still polls readable for
   * them (it did not, and an engine waiting on it waited for ever). */
  assert_int_equal(hfc_submit(c, &f.r, NULL), 0);
  assert_int_equal(hfc_submit(c, &f.r, NULL), 0);
  struct timespec ts = {0, 300 * 1000000L};
  nanosleep(&ts, NULL);
  hfc_stats *st = malloc(sizeof *st);
  assert_int_equal(hfc_get_stats(c, st), 0);
  free(st);
  for (int got = 0; got < 2;) {
    if (poll(&p, 1, 5000) != 1)
      fail_msg("hfc_fd not readable with %d completion(s) read ahead by hfc_get_stats",
               2 - got);
    while (got < 2 && hfc_wait(c, 0, &d) == 0) got++;
  }
  frame_free(&f);
  hfc_close(c);
}

/* Every call takes a NULL client (an engine whose hfc_connect failed, a
 * default-constructed or moved-from hairfilter::Client): the getters too,
 * which crashed, each naming the function in hfc_last_message(NULL). */
static void test_null_client(void **state) {
  (void)state;
  assert_int_equal(hfc_pending(NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_pending: the client is NULL"));
  assert_int_equal(hfc_fd(NULL), HFC_E_ARG);
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_fd: the client is NULL"));
  const hfc_server_info *i = hfc_info(NULL);
  assert_non_null(i);
  assert_int_equal(i->max_inflight, 0);
  assert_string_equal(i->name, "");
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_info: the client is NULL"));
  assert_string_equal(hfc_endpoint(NULL), "");
  assert_non_null(strstr(hfc_last_message(NULL), "hfc_endpoint: the client is NULL"));
  frame f;
  frame_make(&f, 8, 8, hfc_features_bytes(8, 8, 2, HFC_F32), hfc_output_bytes(8, 8, 3, HFC_F32));
  assert_int_equal(hfc_filter(NULL, &f.r, NULL), HFC_E_ARG);
  assert_string_equal(hfc_last_message(NULL), "hfc_filter: the client is NULL");
  assert_int_equal(hfc_submit(NULL, &f.r, NULL), HFC_E_ARG);
  assert_string_equal(hfc_last_message(NULL), "hfc_submit: the client is NULL");
  hfc_completion d;
  assert_int_equal(hfc_wait(NULL, 0, &d), HFC_E_ARG);
  hfc_close(NULL);
  frame_free(&f);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_null_client),
    cmocka_unit_test(test_short_buffers_refused),
    cmocka_unit_test(test_fields_named),
    cmocka_unit_test(test_request_sizes),
    cmocka_unit_test(test_result_not_writable),
    cmocka_unit_test(test_message_cleared),
    cmocka_unit_test(test_variant_names),
    cmocka_unit_test(test_spp_mismatch),
    cmocka_unit_test(test_connect_errno),
    cmocka_unit_test(test_versions),
    cmocka_unit_test(test_fd_polls),
    cmocka_unit_test(test_connection_limit),
    cmocka_unit_test(test_unauthorized_names_the_option),
    cmocka_unit_test(test_segment_limit),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
