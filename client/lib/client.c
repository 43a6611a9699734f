/*
 * libhairfilter: one connection to hairfilterd, in protocol v2 (v1 with a
 * server that speaks only v1).
 *
 * The socket is non-blocking and every wait goes through poll() with the
 * client's timeout, so a dead or stuck server costs a timeout, never a hang.
 * Frames are read piece by piece straight into their destination: a RESULT
 * tensor lands in the caller's buffer with no intermediate copy, and a
 * request's features go out with one sendmsg() of [head, features].
 */
#define _POSIX_C_SOURCE 200809L
#include "hairfilter.h"

#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/mman.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "hfproto.h"

#define CTL_MAX (64 * 1024)   /* largest control reply (VARIANTS, STATS) */
#define MAX_SEGS 16

typedef struct segment {
  uint32_t id;
  uint8_t *addr;
  size_t size;
} segment;

typedef struct pending {
  int used, done;
  uint32_t id;
  uint64_t seq;               /* completion order */
  uint32_t width, height;
  int out_dtype;
  int shm;                    /* the server writes results in a segment */
  void *result, *rgba;
  double t_submit;
  hfc_completion comp;
} pending;

struct hfc_client {
  int fd;
  int timeout_ms;
  int broken;                 /* 0, or the error that ended the connection */
  hfc_server_info info;
  pending *p;
  int np;                     /* slots (= server's max_inflight) */
  int npending;               /* submitted, not yet returned by hfc_wait */
  uint32_t next_id;
  uint64_t next_seq;
  char msg[HFP_MESSAGE_MAX + 1];
  segment segs[MAX_SEGS];
  int nsegs;
  int rx_fd;                  /* a descriptor that came with a frame, or -1 */
  /* the control reply being waited for */
  int ctl_type, ctl_done, ctl_status;
  uint8_t *ctl;
  size_t ctl_len;
};

static const struct {
  int code;
  const char *msg;
} local_errors[] = {
  {HFC_E_ARG, "bad argument"},
  {HFC_E_URL, "bad server URL (want unix:PATH, tcp:HOST:PORT or tcp:PORT)"},
  {HFC_E_CONNECT, "cannot connect to the server"},
  {HFC_E_IO, "connection failed"},
  {HFC_E_TIMEOUT, "timed out waiting for the server"},
  {HFC_E_CLOSED, "server closed the connection"},
  {HFC_E_NOMEM, "out of memory"},
  {HFC_E_INFLIGHT, "too many requests in flight on this connection"},
  {HFC_E_NOPENDING, "no request in flight"},
};

const char *hfc_strerror(int err) {
  if (err == 0) return "ok";
  if (err < 0 && err > -HFP_E_COUNT) return hfp_strerror(err);
  for (size_t i = 0; i < sizeof local_errors / sizeof local_errors[0]; i++)
    if (local_errors[i].code == err) return local_errors[i].msg;
  return "unknown error";
}

static double now_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

/* ---- socket I/O with timeouts --------------------------------------------- */

static int wait_fd(int fd, short events, int timeout_ms) {
  struct pollfd pfd = {fd, events, 0};
  for (;;) {
    int n = poll(&pfd, 1, timeout_ms);
    if (n > 0) return 0;
    if (n == 0) return HFC_E_TIMEOUT;
    if (errno != EINTR) return HFC_E_IO;
  }
}

static void set_broken(hfc_client *c, int err);

/* Reads exactly n bytes. first_timeout_ms applies to the first byte; the
 * rest of a frame must follow within the client's timeout. */
static int recv_all(hfc_client *c, void *buf, size_t n, int first_timeout_ms) {
  uint8_t *p = buf;
  int timeout = first_timeout_ms;
  while (n) {
    /* recvmsg, not recv: a segment's descriptor rides with SHM_CREATED,
     * and any other that arrives must be closed, not leaked. */
    struct iovec iov = {p, n};
    union {
      struct cmsghdr align;
      char buf[CMSG_SPACE(sizeof(int) * 4)];
    } cm;
    struct msghdr mh;
    memset(&mh, 0, sizeof mh);
    mh.msg_iov = &iov;
    mh.msg_iovlen = 1;
    mh.msg_control = cm.buf;
    mh.msg_controllen = sizeof cm.buf;
    ssize_t r = recvmsg(c->fd, &mh, MSG_CMSG_CLOEXEC);
    if (r >= 0 && mh.msg_controllen) {
      for (struct cmsghdr *h = CMSG_FIRSTHDR(&mh); h; h = CMSG_NXTHDR(&mh, h)) {
        if (h->cmsg_level != SOL_SOCKET || h->cmsg_type != SCM_RIGHTS) continue;
        size_t nfd = (h->cmsg_len - CMSG_LEN(0)) / sizeof(int);
        for (size_t k = 0; k < nfd; k++) {
          int fd;
          memcpy(&fd, CMSG_DATA(h) + k * sizeof(int), sizeof fd);
          if (c->rx_fd < 0)
            c->rx_fd = fd;
          else
            close(fd);
        }
      }
    }
    if (r > 0) {
      p += r;
      n -= (size_t)r;
      timeout = c->timeout_ms;
      continue;
    }
    if (r == 0) return HFC_E_CLOSED;
    if (errno == EINTR) continue;
    if (errno != EAGAIN && errno != EWOULDBLOCK) return errno == ECONNRESET ? HFC_E_CLOSED : HFC_E_IO;
    int rc = wait_fd(c->fd, POLLIN, timeout);
    if (rc) return rc;
  }
  return 0;
}

static int send_all(hfc_client *c, struct iovec *iov, int iovcnt) {
  while (iovcnt) {
    struct msghdr mh;
    memset(&mh, 0, sizeof mh);
    mh.msg_iov = iov;
    mh.msg_iovlen = (size_t)iovcnt;
    ssize_t w = sendmsg(c->fd, &mh, MSG_NOSIGNAL);
    if (w < 0) {
      if (errno == EINTR) continue;
      if (errno != EAGAIN && errno != EWOULDBLOCK)
        return errno == EPIPE || errno == ECONNRESET ? HFC_E_CLOSED : HFC_E_IO;
      int rc = wait_fd(c->fd, POLLOUT, c->timeout_ms);
      if (rc) return rc;
      continue;
    }
    size_t left = (size_t)w;
    while (iovcnt && left >= iov->iov_len) {
      left -= iov->iov_len;
      iov++;
      iovcnt--;
    }
    if (iovcnt) {
      iov->iov_base = (uint8_t *)iov->iov_base + left;
      iov->iov_len -= left;
    }
  }
  return 0;
}

/* ---- pending requests ----------------------------------------------------- */

static pending *find_pending(hfc_client *c, uint32_t id) {
  for (int i = 0; i < c->np; i++)
    if (c->p[i].used && !c->p[i].done && c->p[i].id == id) return &c->p[i];
  return NULL;
}

static void finish(hfc_client *c, pending *p, int status) {
  p->done = 1;
  p->seq = c->next_seq++;
  p->comp.id = p->id;
  p->comp.status = status;
  p->comp.timing.total_us = now_us() - p->t_submit;
}

/* The connection is unusable: everything pending fails with err. */
static void set_broken(hfc_client *c, int err) {
  if (c->broken) return;
  c->broken = err;
  for (int i = 0; i < c->np; i++)
    if (c->p[i].used && !c->p[i].done) finish(c, &c->p[i], err);
  if (c->ctl_type && !c->ctl_done) {
    c->ctl_done = 1;
    c->ctl_status = err;
  }
}

/* Reads one frame and dispatches it. */
static int pump(hfc_client *c, int first_timeout_ms) {
  if (c->broken) return c->broken;
  uint8_t hb[HFP_HEADER_SIZE];
  int rc = recv_all(c, hb, sizeof hb, first_timeout_ms);
  if (rc == HFC_E_TIMEOUT) {
    /* A timeout before any byte of a frame leaves the stream intact. */
    return rc;
  }
  if (rc) goto fail;
  hfp_header h;
  rc = hfp_header_decode(hb, UINT32_MAX, &h);
  if (rc) {
    rc = HFC_E_PROTOCOL;
    goto fail;
  }
  if (h.type == HFP_RESULT) {
    uint8_t head[HFP_RESULT_FIXED];
    if (h.length < HFP_RESULT_FIXED) {
      rc = HFC_E_PROTOCOL;
      goto fail;
    }
    if ((rc = recv_all(c, head, sizeof head, c->timeout_ms))) goto fail;
    hfp_result r;
    pending *p = find_pending(c, h.request_id);
    if (!p || hfp_decode_result_head(head, sizeof head, h.length, &r)) {
      snprintf(c->msg, sizeof c->msg, "malformed RESULT or unknown request id %u", h.request_id);
      rc = HFC_E_PROTOCOL;
      goto fail;
    }
    hfc_timing *t = &p->comp.timing;
    t->queue_us = (double)r.timing.queue_us;
    t->input_us = (double)r.timing.input_us;
    t->infer_us = (double)r.timing.infer_us;
    t->output_us = (double)r.timing.output_us;
    t->server_us = (double)r.timing.total_us;
    t->batch = (int)r.batch;
    t->via_shm = p->shm;
    t->out_of_range = (r.flags & HFP_RESULT_OUT_OF_RANGE) != 0;
    t->input_sanitised = (r.flags & HFP_RESULT_INPUT_SANITISED) != 0;
    if (r.status != HFP_OK) {
      finish(c, p, -(int)r.status);
      return 0;
    }
    int shm = (r.flags & HFP_FILTER_SHM) != 0;
    int has_rgba = (r.flags & HFP_FILTER_COMPOSITE) != 0;
    if (r.width != p->width || r.height != p->height || r.dtype != p->out_dtype ||
        has_rgba != (p->rgba != NULL) || shm != p->shm) {
      snprintf(c->msg, sizeof c->msg, "RESULT for request %u does not match it", h.request_id);
      rc = HFC_E_PROTOCOL;
      goto fail;
    }
    if ((rc = recv_all(c, p->result, (size_t)r.data_len, c->timeout_ms))) goto fail;
    if (r.rgba_len && (rc = recv_all(c, p->rgba, (size_t)r.rgba_len, c->timeout_ms))) goto fail;
    finish(c, p, HFC_OK);
    return 0;
  }
  if (h.length > CTL_MAX) {
    rc = HFC_E_PROTOCOL;
    goto fail;
  }
  uint8_t *buf = malloc(h.length ? h.length : 1);
  if (!buf) {
    rc = HFC_E_NOMEM;
    goto fail;
  }
  if ((rc = recv_all(c, buf, h.length, c->timeout_ms))) {
    free(buf);
    goto fail;
  }
  if (h.type == HFP_ERROR) {
    hfp_error e;
    rc = hfp_decode_error(buf, h.length, &e);
    free(buf);
    if (rc) {
      rc = HFC_E_PROTOCOL;
      goto fail;
    }
    snprintf(c->msg, sizeof c->msg, "%s", e.message);
    /* Codes a newer server may add still read as errors here. */
    int code = e.code < HFP_E_COUNT ? -(int)e.code : HFC_E_INTERNAL;
    pending *p = h.request_id ? find_pending(c, h.request_id) : NULL;
    if (p) {
      finish(c, p, code);
    } else if (h.request_id == 0 && c->ctl_type && !c->ctl_done) {
      c->ctl_done = 1;
      c->ctl_status = code;
    } else if (h.request_id != 0 && !e.fatal) {
      rc = HFC_E_PROTOCOL;  /* about a request we never sent */
      goto fail;
    }
    /* else: about a message that has no reply (SHM_DESTROY); the message
     * is kept for hfc_last_message. */
    if (e.fatal) set_broken(c, code);
    return 0;
  }
  if (c->ctl_type && !c->ctl_done && h.type == c->ctl_type) {
    c->ctl = buf;
    c->ctl_len = h.length;
    c->ctl_done = 1;
    c->ctl_status = 0;
    return 0;
  }
  free(buf);
  snprintf(c->msg, sizeof c->msg, "unexpected message type %u", h.type);
  rc = HFC_E_PROTOCOL;
fail:
  set_broken(c, rc);
  return rc;
}

/* Sends a control request and waits for its reply (payload in c->ctl, to
 * be freed by the caller). Results arriving meanwhile are kept. */
static int control(hfc_client *c, const uint8_t *frame, size_t len, int reply_type) {
  if (c->broken) return c->broken;
  c->msg[0] = 0;
  c->ctl_type = reply_type;
  c->ctl_done = 0;
  c->ctl = NULL;
  struct iovec iov = {(void *)frame, len};
  int rc = send_all(c, &iov, 1);
  if (rc) {
    set_broken(c, rc);
    c->ctl_type = 0;
    return rc;
  }
  while (!c->ctl_done) {
    rc = pump(c, c->timeout_ms);
    if (rc == HFC_E_TIMEOUT) set_broken(c, rc);
    if (rc && !c->ctl_done) break;
  }
  c->ctl_type = 0;
  if (!c->ctl_done) return rc;
  if (c->ctl_status) {
    free(c->ctl);
    c->ctl = NULL;
  }
  return c->ctl_status;
}

/* ---- connect -------------------------------------------------------------- */

static int open_socket(const char *url, int timeout_ms) {
  hfp_url u;
  if (hfp_url_parse(url, 0, &u, NULL, 0)) return HFC_E_URL;
  if (u.kind == HFP_URL_UNIX) {
    struct sockaddr_un sun;
    memset(&sun, 0, sizeof sun);
    sun.sun_family = AF_UNIX;
    _Static_assert(sizeof u.path <= sizeof sun.sun_path, "hfp_url path fits sun_path");
    memcpy(sun.sun_path, u.path, sizeof u.path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return HFC_E_CONNECT;
    if (connect(fd, (struct sockaddr *)&sun, sizeof sun) != 0) {
      close(fd);
      return HFC_E_CONNECT;
    }
    return fd;
  }
  char port[8];
  snprintf(port, sizeof port, "%u", (unsigned)u.port);
  const char *host = u.host;
  struct addrinfo hints, *res = NULL;
  memset(&hints, 0, sizeof hints);
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICSERV;
  if (getaddrinfo(host, port, &hints, &res) != 0 || !res) return HFC_E_CONNECT;
  int fd = -1;
  for (struct addrinfo *ai = res; ai; ai = ai->ai_next) {
    fd = socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) continue;
    int rc = connect(fd, ai->ai_addr, ai->ai_addrlen);
    if (rc != 0 && errno == EINPROGRESS) {
      int err = 0;
      socklen_t el = sizeof err;
      if (wait_fd(fd, POLLOUT, timeout_ms) == 0 &&
          getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &el) == 0 && err == 0)
        rc = 0;
    }
    if (rc == 0) {
      int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      break;
    }
    close(fd);
    fd = -1;
  }
  freeaddrinfo(res);
  return fd >= 0 ? fd : HFC_E_CONNECT;
}

int hfc_check_url(const char *url, char *why, size_t whylen) {
  hfp_url u;
  return hfp_url_parse(url, 0, &u, why, whylen) ? HFC_E_URL : 0;
}

int hfc_connect(const char *url, const hfc_options *opt, hfc_client **out) {
  if (!url || !out) return HFC_E_ARG;
  *out = NULL;
  hfc_options o = {0};
  if (opt) o = *opt;
  if (!o.client_name) o.client_name = "libhairfilter";
  if (o.timeout_ms == 0) o.timeout_ms = 30000;
  hfp_hello hello;
  memset(&hello, 0, sizeof hello);
  hello.min_version = HFP_VERSION_MIN;
  hello.max_version = HFP_VERSION;
  if (strlen(o.client_name) > HFP_NAME_MAX || (o.token && strlen(o.token) > HFP_TOKEN_MAX))
    return HFC_E_ARG;
  strcpy(hello.client_name, o.client_name);
  if (o.token) strcpy(hello.token, o.token);
  uint8_t frame[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  int n = hfp_encode_hello(frame, sizeof frame, &hello);
  if (n < 0) return HFC_E_ARG;

  hfc_client *c = calloc(1, sizeof *c);
  if (!c) return HFC_E_NOMEM;
  c->fd = -1;
  c->rx_fd = -1;
  c->timeout_ms = o.timeout_ms;
  c->next_id = 1;
  int fd = open_socket(url, o.timeout_ms);
  if (fd < 0) {
    free(c);
    return fd;
  }
  c->fd = fd;
  int fl = fcntl(fd, F_GETFL);
  if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
    hfc_close(c);
    return HFC_E_IO;
  }
  int rc = control(c, frame, (size_t)n, HFP_HELLO_OK);
  if (rc) {
    hfc_close(c);
    return rc;
  }
  hfp_hello_ok ok;
  rc = hfp_decode_hello_ok(c->ctl, c->ctl_len, &ok);
  free(c->ctl);
  c->ctl = NULL;
  if (rc) {
    hfc_close(c);
    return rc == -HFP_E_VERSION ? HFC_E_VERSION : HFC_E_PROTOCOL;
  }
  hfc_server_info *i = &c->info;
  snprintf(i->name, sizeof i->name, "%s", ok.server_name);
  i->version = ok.version;
  i->max_width = (int)ok.max_width;
  i->max_height = (int)ok.max_height;
  i->max_spp = ok.max_spp;
  i->max_inflight = ok.max_inflight;
  i->max_batch = (int)ok.max_batch;
  i->queue_size = (int)ok.queue_size;
  i->auth_required = (ok.server_flags & HFP_SERVER_AUTH_REQUIRED) != 0;
  i->f32 = (ok.dtypes >> HFP_F32) & 1;
  i->f16 = (ok.dtypes >> HFP_F16) & 1;
  i->shm = (ok.server_flags & HFP_SERVER_SHM) != 0;
  i->max_frame_bytes = ok.max_frame_bytes;
  /* max_inflight is a u16 on the wire: at most 65535 small slots. */
  c->np = ok.max_inflight;
  c->p = calloc((size_t)c->np, sizeof *c->p);
  if (!c->p) {
    hfc_close(c);
    return HFC_E_NOMEM;
  }
  *out = c;
  return 0;
}

void hfc_close(hfc_client *c) {
  if (!c) return;
  if (c->fd >= 0) close(c->fd);
  if (c->rx_fd >= 0) close(c->rx_fd);
  for (int i = 0; i < c->nsegs; i++) munmap(c->segs[i].addr, c->segs[i].size);
  free(c->ctl);
  free(c->p);
  free(c);
}

const hfc_server_info *hfc_info(const hfc_client *c) { return &c->info; }
const char *hfc_last_message(const hfc_client *c) { return c->msg; }
int hfc_fd(const hfc_client *c) { return c->fd; }
int hfc_pending(const hfc_client *c) { return c->npending; }

/* ---- variants and stats ------------------------------------------------ */

int hfc_list_variants(hfc_client *c, hfc_variant *out, int max, int *count) {
  if (!c || (!out && max > 0) || max < 0 || !count) return HFC_E_ARG;
  uint8_t frame[HFP_HEADER_SIZE];
  int n = hfp_encode_empty(frame, sizeof frame, HFP_LIST_VARIANTS, 0);
  if (n < 0) return HFC_E_ARG;
  int rc = control(c, frame, (size_t)n, HFP_VARIANTS);
  if (rc) return rc;
  hfp_variant *v = malloc(sizeof *v * HFP_MAX_VARIANTS);
  if (!v) {
    free(c->ctl);
    c->ctl = NULL;
    return HFC_E_NOMEM;
  }
  int got = 0;
  rc = hfp_decode_variants(c->ctl, c->ctl_len, v, HFP_MAX_VARIANTS, &got);
  free(c->ctl);
  c->ctl = NULL;
  if (rc) {
    free(v);
    return HFC_E_PROTOCOL;
  }
  *count = got;
  for (int i = 0; i < got && i < max; i++) {
    memset(&out[i], 0, sizeof out[i]);
    memcpy(out[i].name, v[i].name, sizeof out[i].name);
    memcpy(out[i].backend, v[i].backend, sizeof out[i].backend);
    memcpy(out[i].precision, v[i].precision, sizeof out[i].precision);
    out[i].spp = v[i].spp;
    out[i].num_levels = v[i].num_levels;
    for (int l = 0; l < v[i].num_levels; l++) out[i].levels[l] = (int)v[i].levels[l];
    for (int k = 0; k < v[i].num_ranges; k++) {
      int stat = v[i].ranges[k].stat;
      if (stat >= HFC_MAX_STATS) continue;   /* one this library does not know */
      out[i].range_mask |= 1u << stat;
      out[i].range_lo[stat] = v[i].ranges[k].lo;
      out[i].range_hi[stat] = v[i].ranges[k].hi;
    }
  }
  free(v);
  return 0;
}

int hfc_get_stats(hfc_client *c, hfc_stats *out) {
  if (!c || !out) return HFC_E_ARG;
  uint8_t frame[HFP_HEADER_SIZE];
  int n = hfp_encode_empty(frame, sizeof frame, HFP_STATS, 0);
  if (n < 0) return HFC_E_ARG;
  int rc = control(c, frame, (size_t)n, HFP_STATS_REPLY);
  if (rc) return rc;
  hfp_stats *st = malloc(sizeof *st);
  if (!st) {
    free(c->ctl);
    c->ctl = NULL;
    return HFC_E_NOMEM;
  }
  rc = hfp_decode_stats(c->ctl, c->ctl_len, st);
  free(c->ctl);
  c->ctl = NULL;
  if (rc) {
    free(st);
    return HFC_E_PROTOCOL;
  }
  memset(out, 0, sizeof *out);
  out->uptime_us = st->uptime_us;
  out->connections_total = st->connections_total;
  out->protocol_errors = st->protocol_errors;
  out->connections_open = (int)st->connections_open;
  out->queue_depth = (int)st->queue_depth;
  out->queue_capacity = (int)st->queue_capacity;
  out->num_variants = st->num_variants;
  for (int i = 0; i < st->num_variants; i++) {
    const hfp_variant_stats *s = &st->variants[i];
    hfc_variant_stats *d = &out->variants[i];
    memcpy(d->name, s->name, sizeof d->name);
    d->requests_ok = s->requests_ok;
    d->requests_failed = s->requests_failed;
    d->rejected = s->rejected;
    d->batches = s->batches;
    d->sum_queue_us = s->sum_queue_us;
    d->sum_infer_us = s->sum_infer_us;
    d->sum_total_us = s->sum_total_us;
    memcpy(d->hist_total, s->hist_total, sizeof d->hist_total);
    memcpy(d->hist_infer, s->hist_infer, sizeof d->hist_infer);
    d->out_of_range = s->out_of_range;
    d->frames_sanitised = s->frames_sanitised;
  }
  free(st);
  return 0;
}

/* ---- filtering ------------------------------------------------------------ */

/* The segment holding a tensor of n bytes at p, or NULL. */
static const segment *seg_of(const hfc_client *c, const void *p, uint64_t n) {
  const uint8_t *b = p;
  for (int i = 0; i < c->nsegs; i++) {
    const segment *g = &c->segs[i];
    if (b >= g->addr && b < g->addr + g->size && n <= (uint64_t)(g->addr + g->size - b)) return g;
  }
  return NULL;
}

/* When every tensor of r lies in one segment, fills f's references and
 * returns that segment; the server checks the same bounds again. */
static const segment *shm_place(const hfc_client *c, hfp_filter *f, const hfc_request *r) {
  uint64_t out_len, rgba_len = 0;
  if (!c->nsegs || hfp_output_bytes(f->width, f->height, HFP_OUTPUTS, f->out_dtype, &out_len))
    return NULL;
  if (r->rgba && hfp_output_bytes(f->width, f->height, 4, f->out_dtype, &rgba_len)) return NULL;
  const segment *g = seg_of(c, r->features, f->data_len);
  if (!g || seg_of(c, r->result, out_len) != g || (r->rgba && seg_of(c, r->rgba, rgba_len) != g))
    return NULL;
  f->shm_in = (uint64_t)((const uint8_t *)r->features - g->addr);
  f->shm_out = (uint64_t)((const uint8_t *)r->result - g->addr);
  f->shm_rgba = r->rgba ? (uint64_t)((const uint8_t *)r->rgba - g->addr) : 0;
  if (hfp_shm_check(f, g->size)) return NULL;  /* misaligned: use the socket */
  return g;
}

int hfc_shm_alloc(hfc_client *c, size_t bytes, void **mem) {
  if (!c || !mem || bytes == 0) return HFC_E_ARG;
  *mem = NULL;
  if (!c->info.shm) return HFC_E_UNSUPPORTED;
  if (c->nsegs == MAX_SEGS) return HFC_E_INFLIGHT;
  uint8_t frame[HFP_HEADER_SIZE + 8];
  int n = hfp_encode_shm_create(frame, sizeof frame, (uint64_t)bytes);
  if (n < 0) return HFC_E_ARG;
  if (c->rx_fd >= 0) {
    close(c->rx_fd);
    c->rx_fd = -1;
  }
  int rc = control(c, frame, (size_t)n, HFP_SHM_CREATED);
  if (rc) return rc;
  uint32_t id;
  uint64_t size;
  rc = hfp_decode_shm_created(c->ctl, c->ctl_len, &id, &size);
  free(c->ctl);
  c->ctl = NULL;
  int fd = c->rx_fd;
  c->rx_fd = -1;
  if (rc || size != bytes || fd < 0) {
    if (fd >= 0) close(fd);
    set_broken(c, HFC_E_PROTOCOL);
    return HFC_E_PROTOCOL;
  }
  void *addr = mmap(NULL, bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  close(fd);
  if (addr == MAP_FAILED) {
    uint8_t d[HFP_HEADER_SIZE + 4];
    int dn = hfp_encode_shm_destroy(d, sizeof d, id);
    struct iovec iov = {d, (size_t)dn};
    if (dn > 0 && (rc = send_all(c, &iov, 1)) != 0) set_broken(c, rc);
    return HFC_E_NOMEM;
  }
  c->segs[c->nsegs++] = (segment){id, addr, bytes};
  *mem = addr;
  return 0;
}

int hfc_shm_free(hfc_client *c, void *mem) {
  if (!c || !mem) return HFC_E_ARG;
  for (int i = 0; i < c->nsegs; i++) {
    if (c->segs[i].addr != mem) continue;
    for (int k = 0; k < c->np; k++)
      if (c->p[k].used && !c->p[k].done && c->p[k].shm &&
          seg_of(c, c->p[k].result, 1) == &c->segs[i])
        return HFC_E_ARG;  /* a request still writes into it */
    uint8_t d[HFP_HEADER_SIZE + 4];
    int n = hfp_encode_shm_destroy(d, sizeof d, c->segs[i].id);
    munmap(c->segs[i].addr, c->segs[i].size);
    c->segs[i] = c->segs[--c->nsegs];
    if (n < 0) return HFC_E_ARG;
    if (c->broken) return 0;  /* the server has dropped it with the connection */
    struct iovec iov = {d, (size_t)n};
    int rc = send_all(c, &iov, 1);
    if (rc) set_broken(c, rc);
    return rc;
  }
  return HFC_E_ARG;
}

int hfc_submit(hfc_client *c, const hfc_request *r, uint32_t *id) {
  if (!c || !r || !r->variant || !r->features || !r->result || r->width < 1 ||
      r->height < 1 || r->spp < 1 || (r->in_dtype != HFC_F32 && r->in_dtype != HFC_F16) ||
      (r->out_dtype != HFC_F32 && r->out_dtype != HFC_F16))
    return HFC_E_ARG;
  if (c->broken) return c->broken;
  c->msg[0] = 0;
  pending *slot = NULL;
  for (int i = 0; i < c->np && !slot; i++)
    if (!c->p[i].used) slot = &c->p[i];
  if (!slot) return HFC_E_INFLIGHT;

  hfp_filter f;
  memset(&f, 0, sizeof f);
  if (strlen(r->variant) > HFP_NAME_MAX) return HFC_E_ARG;
  strcpy(f.variant, r->variant);
  f.flags = r->rgba ? HFP_FILTER_COMPOSITE : 0;
  f.width = (uint32_t)r->width;
  f.height = (uint32_t)r->height;
  f.spp = (uint16_t)(r->spp > 0xffff ? 0xffff : r->spp);
  f.in_dtype = (uint8_t)r->in_dtype;
  f.out_dtype = (uint8_t)r->out_dtype;
  memcpy(f.hair, r->hair, sizeof f.hair);
  memcpy(f.light, r->light, sizeof f.light);
  memcpy(f.bg, r->background, sizeof f.bg);
  f.data = r->features;
  if (hfp_features_bytes(f.width, f.height, f.spp, f.in_dtype, &f.data_len))
    return HFC_E_ARG;
  const segment *g = shm_place(c, &f, r);
  if (g) {
    f.flags |= HFP_FILTER_SHM;
    f.shm_segment = g->id;
  }
  /* Ids are never 0 (reserved) and never one still pending. */
  uint32_t rid;
  do {
    rid = c->next_id++;
  } while (rid == 0 || find_pending(c, rid));
  uint8_t head[HFP_FILTER_HEAD_MAX];
  uint64_t total;
  int n = hfp_encode_filter_head(head, sizeof head, rid, &f, &total);
  if (n < 0) return n == -HFP_E_TOO_LARGE ? HFC_E_TOO_LARGE : HFC_E_ARG;

  memset(slot, 0, sizeof *slot);
  slot->used = 1;
  slot->id = rid;
  slot->width = f.width;
  slot->height = f.height;
  slot->out_dtype = f.out_dtype;
  slot->shm = g != NULL;
  slot->result = r->result;
  slot->rgba = r->rgba;
  slot->comp.user = r->user;
  slot->t_submit = now_us();
  c->npending++;
  struct iovec iov[2] = {{head, (size_t)n}, {(void *)r->features, (size_t)f.data_len}};
  int rc = send_all(c, iov, g ? 1 : 2);
  if (rc) {
    /* Part of a frame may be out: the stream cannot be trusted any more. */
    set_broken(c, rc);
  }
  if (id) *id = rid;
  return 0;
}

static pending *first_done(hfc_client *c) {
  pending *best = NULL;
  for (int i = 0; i < c->np; i++)
    if (c->p[i].used && c->p[i].done && (!best || c->p[i].seq < best->seq)) best = &c->p[i];
  return best;
}

static void release(hfc_client *c, pending *p, hfc_completion *done) {
  if (done) *done = p->comp;
  p->used = 0;
  c->npending--;
}

int hfc_wait(hfc_client *c, int timeout_ms, hfc_completion *done) {
  if (!c || !done) return HFC_E_ARG;
  if (timeout_ms < 0) timeout_ms = c->timeout_ms;
  double deadline = now_us() + (double)timeout_ms * 1e3;
  for (;;) {
    pending *p = first_done(c);
    if (p) {
      release(c, p, done);
      return 0;
    }
    if (c->npending == 0) return c->broken ? c->broken : HFC_E_NOPENDING;
    int left = timeout_ms < 0 ? -1 : (int)((deadline - now_us()) / 1e3);
    if (left < 0 && timeout_ms >= 0) left = 0;
    int rc = pump(c, left);
    if (rc == HFC_E_TIMEOUT && !first_done(c)) return rc;
  }
}

int hfc_filter(hfc_client *c, const hfc_request *r, hfc_timing *timing) {
  uint32_t id;
  int rc = hfc_submit(c, r, &id);
  if (rc) return rc;
  pending *p = NULL;
  for (int i = 0; i < c->np; i++)
    if (c->p[i].used && c->p[i].id == id) p = &c->p[i];
  while (!p->done) {
    rc = pump(c, c->timeout_ms);
    if (rc == HFC_E_TIMEOUT) set_broken(c, rc);
  }
  hfc_completion comp;
  release(c, p, &comp);
  if (timing) *timing = comp.timing;
  return comp.status;
}
