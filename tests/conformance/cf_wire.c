/*
 * Raw sockets for the conformance cases: the bytes a case chooses go out as
 * they are, and what comes back is read frame by frame with deadlines, so a
 * server that answers wrongly, late or not at all fails the case instead of
 * hanging the suite.
 */
#define _POSIX_C_SOURCE 200809L
#define _DEFAULT_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "cf_internal.h"

double cf_now_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec / 1e6;
}

void cf_sleep_ms(int ms) {
  struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
  while (nanosleep(&ts, &ts) && errno == EINTR) {
  }
}

int cf_fail(cf_test *t, const char *fmt, ...) {
  if (!t->why[0]) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(t->why, sizeof t->why, fmt, ap);
    va_end(ap);
  }
  return CF_FAIL;
}

int cf_skip(cf_test *t, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(t->why, sizeof t->why, fmt, ap);
  va_end(ap);
  return CF_SKIP;
}

void *cf_keep(cf_test *t, void *p) {
  if (!p) return NULL;
  if (t->nallocs == t->cap_allocs) {
    int cap = t->cap_allocs ? 2 * t->cap_allocs : 64;
    void **a = realloc(t->allocs, sizeof *a * (size_t)cap);
    if (!a) {
      free(p);
      return NULL;
    }
    t->allocs = a;
    t->cap_allocs = cap;
  }
  t->allocs[t->nallocs++] = p;
  return p;
}

void *cf_alloc(cf_test *t, size_t n) { return cf_keep(t, calloc(1, n ? n : 1)); }

int cf_keep_fd(cf_test *t, int fd) {
  if (fd < 0) return fd;
  if (t->nfds == (int)(sizeof t->fds / sizeof t->fds[0])) {
    close(fd);
    return -1;
  }
  t->fds[t->nfds++] = fd;
  return fd;
}

void cf_close(cf_test *t, int fd) {
  for (int i = 0; i < t->nfds; i++)
    if (t->fds[i] == fd) {
      t->fds[i] = t->fds[--t->nfds];
      break;
    }
  close(fd);
}

/* ---- connecting ---------------------------------------------------------- */

/* The first thing to check when a connect fails the usual ways, in the
 * words libhairfilter uses (client/lib/endpoints.c): the suite speaks the
 * wire itself, so it does not connect through the library. */
static const char *connect_hint(int err) {
  if (err == ENOENT || err == ECONNREFUSED) return " (is hairfilterd running?)";
  if (err == EACCES || err == EPERM) return " (is this user in the socket's group?)";
  return "";
}

static int open_url(const cf_options *o, const char *url, int timeout_ms, char *why,
                    size_t whylen) {
  hfp_url u;
  if (hfp_url_parse(url, 0, &u, why, whylen)) return -1;
  int fd = -1;
  if (u.kind == HFP_URL_UNIX) {
    struct sockaddr_un sun;
    memset(&sun, 0, sizeof sun);
    sun.sun_family = AF_UNIX;
    memcpy(sun.sun_path, u.path, sizeof u.path);
    fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0 || connect(fd, (struct sockaddr *)&sun, sizeof sun)) {
      snprintf(why, whylen, "cannot connect to %s: %s%s", url, strerror(errno),
               connect_hint(errno));
      if (fd >= 0) close(fd);
      return -1;
    }
  } else {
    char port[8];
    snprintf(port, sizeof port, "%u", (unsigned)u.port);
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_socktype = SOCK_STREAM;
    int gai = getaddrinfo(u.host, port, &hints, &res);
    if (gai || !res) {
      snprintf(why, whylen, "cannot resolve %s: %s", url, gai_strerror(gai));
      return -1;
    }
    for (struct addrinfo *ai = res; ai && fd < 0; ai = ai->ai_next) {
      fd = socket(ai->ai_family, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
      if (fd < 0) continue;
      int rc = connect(fd, ai->ai_addr, ai->ai_addrlen);
      if (rc && errno == EINPROGRESS) {
        struct pollfd p = {fd, POLLOUT, 0};
        int err = 0;
        socklen_t el = sizeof err;
        if (poll(&p, 1, timeout_ms) == 1 && !getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &el) &&
            !err)
          rc = 0;
        else
          errno = err ? err : ETIMEDOUT;
      }
      if (rc) {
        snprintf(why, whylen, "cannot connect to %s: %s%s", url, strerror(errno),
                 connect_hint(errno));
        close(fd);
        fd = -1;
      }
    }
    freeaddrinfo(res);
    if (fd < 0) return -1;
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (u.tls && (fd = cf_tls_wrap(o, &u, fd, why, whylen)) < 0) return -1;
  }
  /* Non-blocking: every wait is a poll with a deadline. */
  int fl = fcntl(fd, F_GETFL);
  if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
    snprintf(why, whylen, "fcntl: %s", strerror(errno));
    close(fd);
    return -1;
  }
  return fd;
}

int cf_connect(cf_test *t, int *fd) {
  char why[300];
  int s = open_url(t->o, t->o->server, t->o->timeout_ms, why, sizeof why);
  if (s < 0) return cf_fail(t, "%s", why);
  if (cf_keep_fd(t, s) < 0) return cf_fail(t, "too many sockets in one case");
  *fd = s;
  return 0;
}

size_t cf_hello_frame(uint8_t *buf, size_t cap, int lo, int hi, const char *name,
                      const char *token) {
  hfp_hello m;
  memset(&m, 0, sizeof m);
  m.min_version = 1;
  m.max_version = 1;
  snprintf(m.client_name, sizeof m.client_name, "%s", name ? name : "conformance");
  if (token) snprintf(m.token, sizeof m.token, "%s", token);
  int n = hfp_encode_hello(buf, cap, &m);
  if (n < 0) return 0;
  /* The versions are written as given, whatever the encoder allows. */
  hfp_put_u16(buf + HFP_HEADER_SIZE, (uint16_t)lo);
  hfp_put_u16(buf + HFP_HEADER_SIZE + 2, (uint16_t)hi);
  return (size_t)n;
}

int cf_connect_hello(cf_test *t, int lo, int hi, int *fd, hfp_hello_ok *ok) {
  CF_TRY(cf_connect(t, fd));
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, lo, hi, "conformance", t->o->token);
  CF_CHECK(t, n > 0, "cannot encode a HELLO");
  CF_TRY(cf_send(t, *fd, b, n));
  cf_frame f;
  CF_TRY(cf_expect(t, *fd, HFP_HELLO_OK, &f));
  hfp_hello_ok m;
  int rc = hfp_decode_hello_ok(f.p, f.h.length, &m);
  CF_CHECK(t, rc == 0, "HELLO_OK does not decode: %s", hfp_strerror(rc));
  CF_CHECK(t, f.h.request_id == 0, "HELLO_OK carries request id %u, not 0", f.h.request_id);
  CF_CHECK(t, m.version >= lo && m.version <= hi, "HELLO_OK chose version %u outside %d..%d",
           m.version, lo, hi);
  if (ok) *ok = m;
  return 0;
}

/* ---- sending --------------------------------------------------------------- */

int cf_send_raw(int fd, const void *buf, size_t n, int passed, int timeout_ms) {
  const uint8_t *p = buf;
  double deadline = cf_now_ms() + timeout_ms;
  while (n) {
    struct iovec iov = {(void *)p, n};
    struct msghdr mh;
    union {
      struct cmsghdr align;
      char b[CMSG_SPACE(sizeof(int))];
    } cm;
    memset(&mh, 0, sizeof mh);
    mh.msg_iov = &iov;
    mh.msg_iovlen = 1;
    if (passed >= 0) {
      memset(&cm, 0, sizeof cm);
      mh.msg_control = cm.b;
      mh.msg_controllen = sizeof cm.b;
      struct cmsghdr *c = CMSG_FIRSTHDR(&mh);
      c->cmsg_level = SOL_SOCKET;
      c->cmsg_type = SCM_RIGHTS;
      c->cmsg_len = CMSG_LEN(sizeof(int));
      memcpy(CMSG_DATA(c), &passed, sizeof(int));
    }
    ssize_t w = sendmsg(fd, &mh, MSG_NOSIGNAL);
    if (w > 0) {
      p += w;
      n -= (size_t)w;
      passed = -1;
      continue;
    }
    if (w < 0 && errno == EINTR) continue;
    if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      int left = (int)(deadline - cf_now_ms());
      struct pollfd pf = {fd, POLLOUT, 0};
      if (left <= 0 || poll(&pf, 1, left) <= 0) {
        errno = ETIMEDOUT;
        return (int)(n < INT32_MAX ? n : INT32_MAX);
      }
      continue;
    }
    return -1;
  }
  return 0;
}

static int send_msg(cf_test *t, int fd, const void *buf, size_t n, int passed) {
  int left = cf_send_raw(fd, buf, n, passed, t->o->timeout_ms);
  if (left > 0)
    return cf_fail(t, "the server read nothing for %d ms (%d bytes not sent)", t->o->timeout_ms, left);
  if (left < 0) return cf_fail(t, "send: %s", strerror(errno));
  return 0;
}

int cf_send(cf_test *t, int fd, const void *buf, size_t n) { return send_msg(t, fd, buf, n, -1); }

int cf_send_with_fd(cf_test *t, int fd, const void *buf, size_t n, int passed) {
  return send_msg(t, fd, buf, n, passed);
}

void cf_shutdown_wr(int fd) { shutdown(fd, SHUT_WR); }

/* ---- receiving ------------------------------------------------------------- */

/* Reads up to n bytes before deadline: the count read (n unless EOF came
 * first), or -1 on timeout with *got bytes read, -2 on a socket error. */
static ssize_t recv_until(int fd, uint8_t *p, size_t n, double deadline, int *passed, int *err) {
  size_t got = 0;
  while (got < n) {
    struct iovec iov = {p + got, n - got};
    union {
      struct cmsghdr align;
      char b[CMSG_SPACE(sizeof(int) * 4)];
    } cm;
    struct msghdr mh;
    memset(&mh, 0, sizeof mh);
    mh.msg_iov = &iov;
    mh.msg_iovlen = 1;
    mh.msg_control = cm.b;
    mh.msg_controllen = sizeof cm.b;
    ssize_t r = recvmsg(fd, &mh, MSG_CMSG_CLOEXEC);
    if (r >= 0 && mh.msg_controllen) {
      for (struct cmsghdr *c = CMSG_FIRSTHDR(&mh); c; c = CMSG_NXTHDR(&mh, c)) {
        if (c->cmsg_level != SOL_SOCKET || c->cmsg_type != SCM_RIGHTS) continue;
        size_t k = (c->cmsg_len - CMSG_LEN(0)) / sizeof(int);
        for (size_t i = 0; i < k; i++) {
          int d;
          memcpy(&d, CMSG_DATA(c) + i * sizeof(int), sizeof d);
          if (passed && *passed < 0)
            *passed = d;
          else
            close(d);
        }
      }
    }
    if (r > 0) {
      got += (size_t)r;
      continue;
    }
    if (r == 0) return (ssize_t)got;
    if (errno == EINTR) continue;
    if (errno == ECONNRESET) return (ssize_t)got;   /* closed with our bytes unread */
    if (errno != EAGAIN && errno != EWOULDBLOCK) {
      *err = errno;
      return -2;
    }
    int left = (int)(deadline - cf_now_ms());
    struct pollfd pf = {fd, POLLIN, 0};
    if (left <= 0 || poll(&pf, 1, left) == 0) {
      *err = (int)got;
      return -1;
    }
  }
  return (ssize_t)got;
}

/* PROTOCOL.md's name of a message type, "type N" for one it does not name. */
const char *cf_type_name(int type, char buf[16]) {
  static const char *const n[] = {"?", "HELLO", "HELLO_OK", "LIST_VARIANTS", "VARIANTS",
                                  "FILTER", "RESULT", "ERROR", "STATS", "STATS_REPLY",
                                  "SHM_CREATE", "SHM_CREATED", "SHM_DESTROY"};
  if (type >= 1 && type <= HFP_TYPE_MAX && type < (int)(sizeof n / sizeof n[0])) return n[type];
  snprintf(buf, 16, "type %d", type);
  return buf;
}

static const char *type_name(int type) {
  static __thread char b[16];
  return cf_type_name(type, b);
}

int cf_read(cf_test *t, int fd, int timeout_ms, cf_frame *f) {
  memset(f, 0, sizeof *f);
  f->passed_fd = -1;
  double deadline = cf_now_ms() + timeout_ms;
  uint8_t hb[HFP_HEADER_SIZE];
  int err = 0;
  ssize_t r = recv_until(fd, hb, sizeof hb, deadline, &f->passed_fd, &err);
  if (f->passed_fd >= 0) cf_keep_fd(t, f->passed_fd);
  if (r == -1 && err == 0) return CF_TIMEOUT;
  if (r == -1) return cf_fail(t, "a frame header stopped after %d of 16 bytes", err);
  if (r == -2) return cf_fail(t, "recv: %s", strerror(err));
  if (r == 0) return CF_EOF;
  if (r < (ssize_t)sizeof hb)
    return cf_fail(t, "the connection closed %zd bytes into a frame header", r);
  int rc = hfp_header_decode(hb, UINT32_MAX, &f->h);
  if (rc)
    return cf_fail(t, "the server sent a bad frame header (%s): %02x %02x %02x %02x %s flags %u",
                   hfp_strerror(rc), hb[0], hb[1], hb[2], hb[3], type_name(hfp_get_u16(hb + 4)),
                   hfp_get_u16(hb + 6));
  /* Replies are bounded by what was asked; 1 GiB is far past any of ours. */
  if (f->h.length > (1u << 30))
    return cf_fail(t, "a %s frame announces %u payload bytes", type_name(f->h.type), f->h.length);
  f->p = cf_alloc(t, f->h.length);
  if (!f->p) return cf_fail(t, "out of memory for a %u-byte frame", f->h.length);
  /* The rest of a frame must follow promptly. */
  deadline = cf_now_ms() + t->o->timeout_ms;
  r = recv_until(fd, f->p, f->h.length, deadline, &f->passed_fd, &err);
  if (r == -1) return cf_fail(t, "a %s frame (id %u) stopped after %d of its %u payload bytes",
                              type_name(f->h.type), f->h.request_id, err, f->h.length);
  if (r == -2) return cf_fail(t, "recv: %s", strerror(err));
  if (r < (ssize_t)f->h.length)
    return cf_fail(t, "the connection closed %zd bytes into the %u-byte payload of a %s (id %u)", r,
                   f->h.length, type_name(f->h.type), f->h.request_id);
  return CF_GOT;
}

const char *cf_describe(const cf_frame *f, char *buf, size_t cap) {
  if (f->h.type == HFP_ERROR) {
    hfp_error e;
    if (hfp_decode_error(f->p, f->h.length, &e) == 0) {
      snprintf(buf, cap, "ERROR %s%s id %u: \"%s\"", hfp_code_name((int)e.code),
               e.fatal ? " (fatal)" : "", f->h.request_id, e.message);
      return buf;
    }
  }
  if (f->h.type == HFP_RESULT && f->h.length >= 2) {
    snprintf(buf, cap, "RESULT id %u status %s, %u bytes", f->h.request_id,
             hfp_code_name(hfp_get_u16(f->p)), f->h.length);
    return buf;
  }
  snprintf(buf, cap, "%s id %u, %u bytes", type_name(f->h.type), f->h.request_id, f->h.length);
  return buf;
}

static int what_came(cf_test *t, int rc, const cf_frame *f, const char *wanted) {
  char d[400];
  if (rc == CF_EOF) return cf_fail(t, "wanted %s, the server closed the connection", wanted);
  if (rc == CF_TIMEOUT) return cf_fail(t, "wanted %s, nothing came in %d ms", wanted, t->o->timeout_ms);
  if (rc == CF_FAIL) return CF_FAIL;
  return cf_fail(t, "wanted %s, got %s", wanted, cf_describe(f, d, sizeof d));
}

int cf_expect(cf_test *t, int fd, int type, cf_frame *f) {
  int rc = cf_read(t, fd, t->o->timeout_ms, f);
  if (rc == CF_GOT && f->h.type == type) return 0;
  return what_came(t, rc, f, type_name(type));
}

static void codes_text(unsigned codes, char *buf, size_t cap) {
  buf[0] = 0;
  for (int c = 1; c < 32; c++)
    if (codes & (1u << c)) {
      size_t l = strlen(buf);
      snprintf(buf + l, cap - l, "%s%s", l ? " or " : "", hfp_code_name(c));
    }
}

int cf_expect_error_in(cf_test *t, int fd, unsigned codes, int fatal, uint32_t id) {
  char want[160], w2[220];
  codes_text(codes, want, sizeof want);
  snprintf(w2, sizeof w2, "ERROR %s%s with request id %u", want, fatal ? " (fatal)" : " (not fatal)",
           id);
  cf_frame f;
  int rc = cf_read(t, fd, t->o->timeout_ms, &f);
  if (rc != CF_GOT || f.h.type != HFP_ERROR) return what_came(t, rc, &f, w2);
  hfp_error e;
  rc = hfp_decode_error(f.p, f.h.length, &e);
  CF_CHECK(t, rc == 0, "wanted %s, got an ERROR that does not decode (%s)", w2, hfp_strerror(rc));
  char d[400];
  cf_describe(&f, d, sizeof d);
  CF_CHECK(t, e.code < 32 && (codes & (1u << e.code)), "wanted %s, got %s", w2, d);
  CF_CHECK(t, e.fatal == fatal, "wanted %s, got %s", w2, d);
  CF_CHECK(t, f.h.request_id == id, "wanted %s, got %s", w2, d);
  if (fatal) {
    rc = cf_read(t, fd, t->o->timeout_ms, &f);
    if (rc == CF_EOF) return 0;
    if (rc == CF_GOT)
      return cf_fail(t, "after a fatal ERROR (%s) the server sent %s instead of closing", d,
                     cf_describe(&f, w2, sizeof w2));
    if (rc == CF_TIMEOUT)
      return cf_fail(t, "after a fatal ERROR (%s) the connection stayed open for %d ms", d,
                     t->o->timeout_ms);
    return CF_FAIL;
  }
  return 0;
}

int cf_expect_error(cf_test *t, int fd, int code, int fatal, uint32_t id) {
  return cf_expect_error_in(t, fd, CF_CODE(code), fatal, id);
}

int cf_expect_eof(cf_test *t, int fd) {
  cf_frame f;
  int rc = cf_read(t, fd, t->o->timeout_ms, &f);
  if (rc == CF_EOF) return 0;
  return what_came(t, rc, &f, "the close and nothing else");
}

int cf_expect_quiet(cf_test *t, int fd) {
  cf_frame f;
  int rc = cf_read(t, fd, t->o->quiet_ms, &f);
  if (rc == CF_TIMEOUT) return 0;
  char d[400];
  if (rc == CF_EOF) return cf_fail(t, "wanted no reply, the server closed the connection");
  if (rc == CF_GOT) return cf_fail(t, "wanted no reply, got %s", cf_describe(&f, d, sizeof d));
  return CF_FAIL;
}

int cf_busy(cf_test *t, const cf_frame *r, hfp_error *e) {
  if (r->h.type != HFP_ERROR) return 0;
  hfp_error tmp;
  char d[400];
  if (!e) e = &tmp;
  if (hfp_decode_error(r->p, r->h.length, e) == 0 && e->code == HFP_E_BUSY && !e->fatal) return 1;
  return cf_fail(t, "wanted a RESULT or a non-fatal BUSY, got %s", cf_describe(r, d, sizeof d));
}

int cf_still_serves(cf_test *t, int fd) {
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, HFP_LIST_VARIANTS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  cf_frame f;
  int rc = cf_read(t, fd, t->o->timeout_ms, &f);
  if (rc == CF_GOT && f.h.type == HFP_VARIANTS) return 0;
  return what_came(t, rc, &f, "VARIANTS (the connection should still serve)");
}

void cf_header(uint8_t *buf, int type, uint16_t flags, uint32_t id, uint32_t length) {
  hfp_put_u32(buf, HFP_MAGIC);
  hfp_put_u16(buf + 4, (uint16_t)type);
  hfp_put_u16(buf + 6, flags);
  hfp_put_u32(buf + 8, id);
  hfp_put_u32(buf + 12, length);
}

void cf_set_length(uint8_t *frame, uint32_t length) { hfp_put_u32(frame + 12, length); }
