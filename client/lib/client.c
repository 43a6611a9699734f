/*
 * client.c: frames in and out of a client's connections, and what happens
 * to its requests when a connection fails.
 *
 * Sockets are non-blocking and every wait goes through poll() with the
 * client's timeout, so a dead or stuck server costs a timeout, never a hang.
 * Frames are read piece by piece straight into their destination: a RESULT
 * tensor lands in the caller's buffer with no intermediate copy, and a
 * request's features go out with one sendmsg() of [head, features] (and
 * the estimate, when it is in a buffer of its own).
 *
 * Failover (a URL listing several endpoints): a lost connection's requests
 * are queued and sent again on the next endpoint that answers; a request
 * answered BUSY or SHUTTING_DOWN moves the client to the next endpoint, and
 * the connection it leaves is half-closed and read until its last reply
 * (the server answers every FILTER it admitted, PROTOCOL.md "Transport").
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>

#include "client_internal.h"

static double now_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

int hfci_ms_left(double deadline_us, int timeout_ms) {
  if (timeout_ms < 0) return -1;
  double left = deadline_us - now_us();
  return left <= 0 ? 0 : (int)((left + 999.0) / 1e3);
}

int hfci_wait_fd(int fd, short events, int timeout_ms) {
  struct pollfd pfd = {fd, events, 0};
  /* A signal (an engine's interval timer, a profiler's) ends poll early:
   * it waits again for what is left, not the whole timeout, or signals
   * more frequent than the timeout would keep it from ever running out. */
  double deadline = now_us() + (double)timeout_ms * 1e3;
  for (int wait = timeout_ms;; wait = hfci_ms_left(deadline, timeout_ms)) {
    int n = poll(&pfd, 1, wait);
    if (n > 0) return 0;
    if (n == 0) return HFC_E_TIMEOUT;
    if (errno != EINTR) return HFC_E_IO;
  }
}

int hfci_send_fd(int fd, int timeout_ms, const struct iovec *in, int n) {
  struct iovec vec[HFCI_MAX_IOV];
  int iovcnt = 0;
  for (int i = 0; i < n && i < HFCI_MAX_IOV; i++)
    if (in[i].iov_len) vec[iovcnt++] = in[i];
  struct iovec *iov = vec;
  while (iovcnt) {
    struct msghdr mh;
    memset(&mh, 0, sizeof mh);
    mh.msg_iov = iov;
    mh.msg_iovlen = (size_t)iovcnt;
    ssize_t w = sendmsg(fd, &mh, MSG_NOSIGNAL);
    if (w < 0) {
      if (errno == EINTR) continue;
      if (errno != EAGAIN && errno != EWOULDBLOCK)
        return errno == EPIPE || errno == ECONNRESET ? HFC_E_CLOSED : HFC_E_IO;
      int rc = hfci_wait_fd(fd, POLLOUT, timeout_ms);
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

int hfci_recv_fd(int fd, int *rx_fd, void *buf, size_t n, int timeout_ms) {
  uint8_t *p = buf;
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
    ssize_t r = recvmsg(fd, &mh, MSG_CMSG_CLOEXEC);
    if (r >= 0 && mh.msg_controllen) {
      for (struct cmsghdr *h = CMSG_FIRSTHDR(&mh); h; h = CMSG_NXTHDR(&mh, h)) {
        if (h->cmsg_level != SOL_SOCKET || h->cmsg_type != SCM_RIGHTS) continue;
        size_t nfd = (h->cmsg_len - CMSG_LEN(0)) / sizeof(int);
        for (size_t k = 0; k < nfd; k++) {
          int got;
          memcpy(&got, CMSG_DATA(h) + k * sizeof(int), sizeof got);
          if (rx_fd && *rx_fd < 0)
            *rx_fd = got;
          else
            close(got);
        }
      }
    }
    if (r > 0) {
      p += r;
      n -= (size_t)r;
      continue;
    }
    if (r == 0) return HFC_E_CLOSED;
    if (errno == EINTR) continue;
    if (errno != EAGAIN && errno != EWOULDBLOCK) return errno == ECONNRESET ? HFC_E_CLOSED : HFC_E_IO;
    int rc = hfci_wait_fd(fd, POLLIN, timeout_ms);
    if (rc) return rc;
  }
  return 0;
}

int hfci_send_iov(int fd, void *ssl, int timeout_ms, const struct iovec *iov, int n) {
  return ssl ? hfci_tls_send(ssl, fd, timeout_ms, iov, n) : hfci_send_fd(fd, timeout_ms, iov, n);
}

int hfci_send_io(int fd, void *ssl, int timeout_ms, const void *buf, size_t n) {
  struct iovec iov = {(void *)buf, n};
  return hfci_send_iov(fd, ssl, timeout_ms, &iov, 1);
}

int hfci_recv_io(int fd, void *ssl, int *rx_fd, void *buf, size_t n, int timeout_ms) {
  return ssl ? hfci_tls_recv(ssl, fd, buf, n, timeout_ms)
             : hfci_recv_fd(fd, rx_fd, buf, n, timeout_ms);
}

static int recv_all(hfc_client *c, conn *x, void *buf, size_t n) {
  errno = 0;
  int rc = hfci_recv_io(x->fd, x->ssl, &x->rx_fd, buf, n, c->timeout_ms);
  if (rc == HFC_E_TLS) snprintf(x->why, sizeof x->why, "%s", hfci_tls_why());
  /* The kernel could not write where the reply goes: a result or rgba
   * buffer smaller than its _bytes says (or freed, or read-only). The
   * connection is lost either way (the reply is half read); the message
   * points at the caller's buffer, not the network. */
  if (rc == HFC_E_IO && errno == EFAULT)
    snprintf(x->why, sizeof x->why, "reading the reply: %s: the request's result or rgba buffer "
             "is not writable for its result_bytes or rgba_bytes (too small, freed, read-only, "
             "or past the end of its shared segment)", strerror(EFAULT));
  return rc;
}

/* ---- requests --------------------------------------------------------------- */

void hfci_finish(hfc_client *c, pending *p, int status, const char *why) {
  p->state = P_DONE;
  p->seq = c->next_seq++;
  p->comp.id = p->id;
  p->comp.status = status;
  p->comp.timing.total_us = now_us() - p->t_submit;
  p->comp.timing.resends = p->resends;
  free(p->msg);
  p->msg = status && why && why[0] ? strdup(why) : NULL;
}

void hfci_release(hfc_client *c, pending *p, hfc_completion *done) {
  hfci_begin(c);
  if (p->msg) hfci_msg(c, "%s", p->msg);
  free(p->msg);
  p->msg = NULL;
  if (done) *done = p->comp;
  p->state = P_FREE;
  c->npending--;
}

/* Queues p to be sent again on the next connection. */
static void requeue(pending *p) {
  p->state = P_QUEUED;
  p->resends++;
  memset(&p->comp.timing, 0, sizeof p->comp.timing);
}

static pending *find_sent(hfc_client *c, int k, uint32_t wire_id) {
  for (int i = 0; i < c->np; i++) {
    pending *p = &c->p[i];
    if (p->state == P_SENT && p->conn == k && p->wire_id == wire_id) return p;
  }
  return NULL;
}

/* Leaves connection k, which answered BUSY or SHUTTING_DOWN, for another
 * endpoint: 0 once another is active (k is then half-closed and drained),
 * or the error of the endpoints tried. */
static int switch_away(hfc_client *c, int k) {
  conn *x = &c->conns[k];
  int rc = hfci_connect_other(c, x->endpoint);
  if (rc) return rc;
  /* Nothing more goes to k: its segments serve the socket path from now on,
   * and its half-close tells the server to answer what it has and close. */
  hfci_shm_orphan(c, x->serial);
  x->draining = 1;
  if (x->ssl ? hfci_tls_shutdown_wr(x->ssl) != 0 : shutdown(x->fd, SHUT_WR) != 0)
    hfci_conn_lost(c, k, HFC_E_IO);
  return 0;
}

/* A request's own answer was a failover code (BUSY, SHUTTING_DOWN): when
 * the policy allows, the request goes to another endpoint, or completes
 * with err if none takes it. 1 when dealt with here, 0 when the caller
 * completes it with err. */
static int fail_over_request(hfc_client *c, int k, pending *p, int err) {
  if (!hfci_can_resend(c, p, err, 0)) return 0;
  requeue(p);
  if (k != c->active) return 1;     /* a draining connection: the active one takes it */
  int e = c->conns[k].endpoint;
  if (switch_away(c, k) == 0) return 1;
  char why[MSG_MAX + 100];
  snprintf(why, sizeof why, "%s from %s, and no other endpoint took the frame: %s",
           hfp_code_name(err), c->eps[e].url, c->msg);
  p->resends--;
  hfci_finish(c, p, err, why);
  return 1;
}

/* The server's words about a variant it does not know, with the names it
 * has (as last listed on this connection), into why. When that list holds
 * the very name refused, it is out of date: a reload removed the variant
 * since, and listing the names would contradict the server's answer. */
static void unknown_variant_msg(conn *x, const char *name, const char *server_msg, char *why,
                                size_t whylen) {
  for (int i = 0; i < x->nvariants; i++)
    if (!strcmp(x->variants[i].name, name)) {
      snprintf(why, whylen, "%s: the server served it when this connection listed its "
               "variants, and a reload has removed it since (hfc_list_variants says what it "
               "serves now)", server_msg);
      x->variants_known = 0;
      return;
    }
  int n = snprintf(why, whylen, "%s", server_msg);
  for (int i = 0; i < x->nvariants && n > 0 && (size_t)n < whylen; i++) {
    int m = snprintf(why + n, whylen - (size_t)n, "%s%s", i ? ", " : ": this server has ",
                     x->variants[i].name);
    if (m < 0) break;
    n += m;
  }
  x->variants_known = 0;   /* the server's set has changed: list again next time */
}

/* Reads one frame from connection k and dispatches it. 0, or an error that
 * ends the connection. */
static int read_frame(hfc_client *c, int k) {
  conn *x = &c->conns[k];
  x->why[0] = 0;
  uint8_t hb[HFP_HEADER_SIZE];
  int rc = recv_all(c, x, hb, sizeof hb);
  if (rc) return rc;
  /* A frame has begun: the server is alive (hfci_check_silent). */
  x->quiet_since_us = now_us();
  hfp_header h;
  if (hfp_header_decode(hb, UINT32_MAX, &h)) {
    snprintf(x->why, sizeof x->why, "a malformed frame header");
    return HFC_E_PROTOCOL;
  }
  if (h.type == HFP_RESULT) {
    uint8_t head[HFP_RESULT_FIXED];
    if (h.length < HFP_RESULT_FIXED) return HFC_E_PROTOCOL;
    if ((rc = recv_all(c, x, head, sizeof head))) return rc;
    hfp_result r;
    pending *p = find_sent(c, k, h.request_id);
    if (!p || hfp_decode_result_head(head, sizeof head, h.length, &r)) {
      snprintf(x->why, sizeof x->why, "a malformed RESULT or one for no request (id %u)",
               h.request_id);
      return HFC_E_PROTOCOL;
    }
    x->inflight--;
    /* Version 1 has no flag bits 2 and 3 (PROTOCOL.md, "Version 2"). */
    if (x->info.version < 2 &&
        (r.flags & (HFP_RESULT_INPUT_SANITISED | HFP_RESULT_OUT_OF_RANGE))) {
      snprintf(x->why, sizeof x->why, "RESULT flags 0x%02x on a version-1 connection", r.flags);
      x->inflight++;   /* not this request's fault: it may be sent again elsewhere */
      return HFC_E_PROTOCOL;
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
      int err = r.status < HFP_E_COUNT ? -(int)r.status : HFC_E_INTERNAL;
      /* Admitted, then not run: a server that stopped (SHUTTING_DOWN),
       * failed (INTERNAL) or gave the frame's queue place to a client
       * under its share (BUSY) may leave the frame to another. */
      if (!fail_over_request(c, k, p, err)) {
        char why[MSG_MAX], budget[256] = "";
        /* The budget and the wait, so that a log line says by how much the
         * server was behind. */
        if (err == HFC_E_EXPIRED && p->budget_sent != p->deadline_us)
          snprintf(budget, sizeof budget, " (its budget of %u us, what remained of "
                   "hfc_request.deadline_us's %u us when it was sent again after a failover, "
                   "passed while it was queued: it waited %.0f us; the server is not keeping "
                   "up)", p->budget_sent, p->deadline_us, t->queue_us);
        else if (err == HFC_E_EXPIRED)
          snprintf(budget, sizeof budget, " (its budget of %u us, hfc_request.deadline_us, "
                   "passed while it was queued: it waited %.0f us; the server is not keeping "
                   "up)", p->deadline_us, t->queue_us);
        snprintf(why, sizeof why, "%s admitted the frame, then did not run it: %s%s",
                 c->eps[x->endpoint].url, hfp_code_name(err),
                 err == HFC_E_BUSY ? " (its queue place went to a client holding less than "
                                     "its share; retry later)"
                 : err == HFC_E_EXPIRED ? budget
                 : err == HFC_E_CANCELLED ? " (hfc_cancel took it off the queue)"
                                          : "");
        hfci_finish(c, p, err, why);
      }
      return 0;
    }
    int shm = (r.flags & HFP_FILTER_SHM) != 0;
    int has_rgba = (r.flags & HFP_FILTER_COMPOSITE) != 0;
    if (r.width != p->width || r.height != p->height || r.dtype != p->out_dtype ||
        has_rgba != (p->rgba != NULL) || shm != p->shm) {
      snprintf(x->why, sizeof x->why, "a RESULT that does not match its request");
      /* Not this request's fault: it may be sent again elsewhere. */
      x->inflight++;
      return HFC_E_PROTOCOL;
    }
    /* A frame lost mid-way leaves the request SENT on k, and the
     * connection's loss then decides its fate. */
    if ((rc = recv_all(c, x, p->result, (size_t)r.data_len)) ||
        (r.rgba_len && (rc = recv_all(c, x, p->rgba, (size_t)r.rgba_len)))) {
      x->inflight++;
      return rc;
    }
    hfci_finish(c, p, HFC_OK, NULL);
    return 0;
  }
  if (h.length > CTL_MAX) {
    snprintf(x->why, sizeof x->why, "a reply of %u bytes, over %d", h.length, CTL_MAX);
    return HFC_E_PROTOCOL;
  }
  uint8_t *buf = malloc(h.length ? h.length : 1);
  if (!buf) return HFC_E_NOMEM;
  if ((rc = recv_all(c, x, buf, h.length))) {
    free(buf);
    return rc;
  }
  if (h.type == HFP_ERROR) {
    hfp_error e;
    rc = hfp_decode_error(buf, h.length, &e);
    free(buf);
    if (rc) return HFC_E_PROTOCOL;
    /* Codes a newer server may add still read as errors here. */
    int code = e.code < HFP_E_COUNT ? -(int)e.code : HFC_E_INTERNAL;
    pending *p = h.request_id ? find_sent(c, k, h.request_id) : NULL;
    int ctl_here = h.request_id == 0 && c->ctl_type && !c->ctl_done && c->ctl_conn == k;
    if (e.fatal) snprintf(x->why, sizeof x->why, "%s", e.message);
    if (p) {
      x->inflight--;
      if (fail_over_request(c, k, p, code)) return e.fatal ? code : 0;
      char why[900];
      if (code == HFC_E_UNKNOWN_VARIANT)
        unknown_variant_msg(x, p->variant, e.message, why, sizeof why);
      else
        snprintf(why, sizeof why, "%s", e.message);
      hfci_finish(c, p, code, why);
    } else if (ctl_here) {
      hfci_msg(c, "%s", e.message);
      c->ctl_done = 1;
      c->ctl_status = code;
    } else if (h.request_id != 0 && !e.fatal) {
      return HFC_E_PROTOCOL;   /* about a request we never sent */
    } else {
      /* About a message that has no reply (SHM_DESTROY), or the connection:
       * the message is kept for hfc_last_message. */
      hfci_msg(c, "%s", e.message);
    }
    return e.fatal ? code : 0;
  }
  if (c->ctl_type && !c->ctl_done && c->ctl_conn == k && h.type == c->ctl_type) {
    c->ctl = buf;
    c->ctl_len = h.length;
    c->ctl_done = 1;
    c->ctl_status = 0;
    return 0;
  }
  free(buf);
  snprintf(x->why, sizeof x->why, "an unexpected message (type %u)", h.type);
  return HFC_E_PROTOCOL;
}

/* A send on connection k failed with err. A server answers a frame from
 * its header and may close while the client is still writing it: after a
 * fatal ERROR for it (TOO_LARGE over max_frame_bytes), or at the end of a
 * drain, whose last reply may be the SHUTTING_DOWN of that very frame
 * (PROTOCOL.md, "Fatal or not"). Those replies are still on a plain socket
 * (a Unix socket keeps them; over TCP they are there unless a reset threw
 * them away) and are read first, so each frame completes as the server
 * answered it; then the connection ends, with a fatal ERROR's code when
 * one came. Over TLS the session is gone with the failed write. */
void hfci_send_failed(hfc_client *c, int k, int err) {
  conn *x = &c->conns[k];
  while (err == HFC_E_CLOSED && x->fd >= 0 && !x->ssl) {
    struct pollfd pf = {x->fd, POLLIN, 0};
    int r;
    do {
      r = poll(&pf, 1, 0);
    } while (r < 0 && errno == EINTR);
    if (r <= 0) break;
    int rc = read_frame(c, k);
    if (rc == HFC_E_CLOSED) break;   /* the end of what the server wrote */
    if (rc) err = rc;                /* its fatal ERROR, or a broken frame */
  }
  hfci_conn_lost(c, k, err);
}

static int pump_once(hfc_client *c, int timeout_ms);

int hfci_pump(hfc_client *c, int timeout_ms) {
  int rc = pump_once(c, timeout_ms);
  hfci_tls_signal(c);
  hfci_due_update(c);
  return rc;
}

static int pump_once(hfc_client *c, int timeout_ms) {
  struct pollfd pf[MAX_CONNS];
  int idx[MAX_CONNS], n = 0;
  for (int k = 0; k < MAX_CONNS; k++)
    if (c->conns[k].fd >= 0) {
      pf[n].fd = c->conns[k].fd;
      pf[n].events = POLLIN;
      pf[n].revents = 0;
      idx[n++] = k;
    }
  if (!n) return c->broken ? c->broken : HFC_E_CLOSED;
  /* A frame OpenSSL has already decrypted is not on the socket. */
  for (int i = 0; i < n; i++)
    if (hfci_tls_pending(c->conns[idx[i]].ssl)) {
      int rc = read_frame(c, idx[i]);
      if (rc) hfci_conn_lost(c, idx[i], rc);
      return 0;
    }
  int r;
  /* As hfci_wait_fd: a signal leaves only the rest of the timeout. */
  double deadline = now_us() + (double)timeout_ms * 1e3;
  for (int wait = timeout_ms;; wait = hfci_ms_left(deadline, timeout_ms)) {
    r = poll(pf, (nfds_t)n, wait);
    if (!(r < 0 && errno == EINTR)) break;
  }
  if (r == 0) return HFC_E_TIMEOUT;
  if (r < 0) return HFC_E_IO;
  for (int i = 0; i < n; i++)
    if (pf[i].revents) {
      int rc = read_frame(c, idx[i]);
      if (rc) hfci_conn_lost(c, idx[i], rc);
      return 0;
    }
  return 0;
}

static int any_queued(const hfc_client *c) {
  for (int i = 0; i < c->np; i++)
    if (c->p[i].state == P_QUEUED) return 1;
  return 0;
}

static void fail_queued(hfc_client *c, int err, const char *why) {
  for (int i = 0; i < c->np; i++)
    if (c->p[i].state == P_QUEUED) hfci_finish(c, &c->p[i], err, why);
}

void hfci_conn_lost(hfc_client *c, int k, int err) {
  conn *x = &c->conns[k];
  if (x->fd < 0) return;
  int e = x->endpoint;
  int move = hfci_can_failover(c, err, 1);
  char why[MSG_MAX];
  if (x->why[0])
    snprintf(why, sizeof why, "%s: %s: %s", c->eps[e].url,
             err > -HFP_E_COUNT ? hfp_code_name(err) : hfc_strerror(err), x->why);
  else
    snprintf(why, sizeof why, "%s: %s", c->eps[e].url, hfc_strerror(err));
  /* The client's only way on is gone and it moves nowhere by itself (a
   * single URL, or a list without HFC_FAILOVER_LOST): the frames' errors
   * say what the engine does. Not on a list that the next call follows,
   * whether or not this error moves these frames (hfci_need_conn). */
  if (!hfci_follows_list(c) && k == c->active) {
    size_t n = strlen(why);
    snprintf(why + n, sizeof why - n, ": connect again (hfc_close, then hfc_connect)");
  }
  /* Requests first, while k still names this connection: a new one may
   * take its slot below. */
  for (int i = 0; i < c->np; i++) {
    pending *p = &c->p[i];
    if (p->state != P_SENT || p->conn != k) continue;
    if (move && p->resends < c->max_resends && !p->in_place) {
      requeue(p);
    } else if (move && p->in_place) {
      char in_place[MSG_MAX + 96];
      snprintf(in_place, sizeof in_place,
               "%s (not resent: its result may already have overwritten its features)", why);
      hfci_finish(c, p, err, in_place);
    } else {
      hfci_finish(c, p, err, why);
    }
  }
  if (c->ctl_type && !c->ctl_done && c->ctl_conn == k) {
    c->ctl_done = 1;
    c->ctl_status = err;   /* hfci_control sends it again when it may */
    hfci_msg(c, "%s", why);
  }
  hfci_conn_close(c, k);
  if (c->active >= 0) return;     /* a draining connection: the active one goes on */
  c->last_ep = e;
  c->broken = err;
  /* With nothing waiting to be sent, the next call connects (hfci_need_conn). */
  if (!any_queued(c)) return;
  if (move && hfci_connect_next(c, e + 1) == 0) return;
  char all[2 * MSG_MAX + 40];
  snprintf(all, sizeof all, "%s; no other endpoint answers: %s", why, move ? c->msg : "");
  fail_queued(c, err, move ? all : why);
}

int hfci_silence_left_ms(const hfc_client *c) {
  if (c->timeout_ms < 0) return -1;
  double now = now_us(), least = -1;
  for (int k = 0; k < MAX_CONNS; k++) {
    const conn *x = &c->conns[k];
    if (x->fd < 0 || x->inflight <= 0) continue;
    double left = x->quiet_since_us + (double)c->timeout_ms * 1e3 - now;
    if (left < 0) left = 0;
    if (least < 0 || left < least) least = left;
  }
  return least < 0 ? -1 : (int)(least / 1e3 + 0.999);
}

void hfci_due_update(hfc_client *c) {
  if (c->due_fd < 0) return;
  struct itimerspec its;
  memset(&its, 0, sizeof its);
  int done = 0;
  for (int i = 0; i < c->np && !done; i++) done = c->p[i].state == P_DONE;
  int silent = done ? 0 : hfci_silence_left_ms(c);
  if (done) {
    its.it_value.tv_nsec = 1;   /* all zero would disarm it */
  } else if (silent >= 0) {
    /* One millisecond late rather than early: hfci_check_silent gives a
     * connection up only once the whole timeout has passed. */
    long long ms = (long long)silent + 1;   /* timeout_ms may be INT_MAX */
    its.it_value.tv_sec = (time_t)(ms / 1000);
    its.it_value.tv_nsec = (long)(ms % 1000) * 1000000L;
  }
  /* Setting it also clears the expirations counted so far, so the fd is
   * quiet again once nothing is due. It fails only for a descriptor that
   * is no timerfd or a time out of range, neither of which this makes; the
   * message is kept so that an engine whose poll never wakes can see why. */
  if (timerfd_settime(c->due_fd, 0, &its, NULL) != 0)
    hfci_msg(c, "timerfd_settime for hfc_fd: %s (hfc_fd may not wake: poll it with a timeout)",
             strerror(errno));
}

void hfci_check_silent(hfc_client *c) {
  if (c->timeout_ms < 0) return;
  double now = now_us();
  for (int k = 0; k < MAX_CONNS; k++) {
    conn *x = &c->conns[k];
    if (x->fd < 0 || x->inflight <= 0 ||
        now - x->quiet_since_us < (double)c->timeout_ms * 1e3)
      continue;
    /* Bytes (or its close) already waiting are not silence: an engine that
     * did not collect for a while finds its replies there, and a pump reads
     * one connection's frame at a time. */
    struct pollfd pfd = {x->fd, POLLIN, 0};
    if (hfci_tls_pending(x->ssl) || poll(&pfd, 1, 0) > 0) continue;
    hfci_give_up_silent(c, k);
  }
}

void hfci_give_up_silent(hfc_client *c, int k) {
  conn *x = &c->conns[k];
  /* timeout_ms reads as a deadline, and an engine that set it to a frame
   * budget finds its connection given up: the message says what it is. */
  if (x->inflight > 0)
    snprintf(x->why, sizeof x->why,
             "no reply for %d ms (hfc_options.timeout_ms) with %d frame(s) in flight: is the "
             "server stopped or stuck? A server slower than that needs a larger timeout_ms (a "
             "frame's own deadline is hfc_wait's timeout, which leaves the frame pending)",
             c->timeout_ms, x->inflight);
  else
    snprintf(x->why, sizeof x->why,
             "no reply for %d ms (hfc_options.timeout_ms) to a variant list, statistics or "
             "shared-memory request: is the server stopped or stuck?", c->timeout_ms);
  hfci_conn_lost(c, k, HFC_E_TIMEOUT);
}

void hfci_progress(hfc_client *c) {
  /* Draining connections that have answered everything are done. */
  for (int k = 0; k < MAX_CONNS; k++) {
    conn *x = &c->conns[k];
    if (x->fd >= 0 && k != c->active && x->inflight == 0 &&
        !(c->ctl_type && !c->ctl_done && c->ctl_conn == k))
      hfci_conn_close(c, k);
  }
  /* Queued requests, oldest first, while the active connection has room. */
  for (;;) {
    if (c->active < 0) {
      if (!any_queued(c)) return;
      /* Requests moved off a draining connection that was lost after the
       * active one: the next endpoint, when the policy allows. */
      if (hfci_need_conn(c) < 0) {
        fail_queued(c, c->broken ? c->broken : HFC_E_CLOSED, c->msg);
        return;
      }
      continue;
    }
    conn *x = &c->conns[c->active];
    if (x->inflight >= x->info.max_inflight) return;
    pending *p = NULL;
    for (int i = 0; i < c->np; i++)
      if (c->p[i].state == P_QUEUED && (!p || c->p[i].order < p->order)) p = &c->p[i];
    if (!p) return;
    int k = c->active;
    int rc = hfci_send_request(c, p);
    if (rc) hfci_send_failed(c, k, rc);
  }
}

int hfci_need_conn(hfc_client *c) {
  if (c->active >= 0) return c->active;
  if (!hfci_follows_list(c)) {
    int err = c->broken ? c->broken : HFC_E_CLOSED;
    if (!c->msg[0]) hfci_msg(c, "the connection was lost earlier (%s): connect again", hfc_strerror(err));
    return err;
  }
  int rc = hfci_connect_next(c, c->last_ep + 1);
  return rc ? rc : c->active;
}

int hfci_control(hfc_client *c, const uint8_t *frame, size_t len, int reply_type) {
  for (int attempt = 0;; attempt++) {
    int k = hfci_need_conn(c);
    if (k < 0) return k;
    uint64_t serial = c->conns[k].serial;
    c->ctl_type = reply_type;
    c->ctl_conn = k;
    c->ctl_done = 0;
    c->ctl_status = 0;
    c->ctl = NULL;
    int rc = hfci_send_io(c->conns[k].fd, c->conns[k].ssl, c->timeout_ms, frame, len);
    if (rc) hfci_send_failed(c, k, rc);   /* marks the control request done with rc */
    while (!c->ctl_done) {
      rc = hfci_pump(c, c->timeout_ms);
      if (rc == HFC_E_TIMEOUT)
        hfci_give_up_silent(c, c->ctl_conn);
      else if (rc && !c->ctl_done) {
        c->ctl_done = 1;
        c->ctl_status = rc;
      }
      hfci_progress(c);
    }
    c->ctl_type = 0;
    hfci_due_update(c);   /* hfci_progress may have sent or failed frames since the pump */
    rc = c->ctl_status;
    if (rc && c->ctl) {
      free(c->ctl);
      c->ctl = NULL;
    }
    /* Lost with its connection: once more on the next, as for frames. */
    int lost = c->conns[k].fd < 0 || c->conns[k].serial != serial;
    if (rc && lost && attempt < c->max_resends && hfci_can_failover(c, rc, 1)) continue;
    return rc;
  }
}
