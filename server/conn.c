/*
 * Connections: the read state machine that turns bytes into requests, and
 * the writes that carry replies back.
 *
 * Reads go straight to where the bytes belong: libuv's alloc callback hands
 * out the unread rest of the current piece (header, control payload, FILTER
 * head, tensor, or a sink for a rejected frame), so a feature tensor is
 * never copied between the socket and the backend, and no read ever spans
 * two frames. A FILTER is validated from its head before its tensor buffer
 * is allocated, so a rejected request costs no memory however large it
 * claims to be.
 *
 * Error policy (PROTOCOL.md, "Errors"): a frame whose header is bad, or
 * whose payload exceeds max_frame_bytes, loses the framing or is not worth
 * reading, so the connection gets a fatal ERROR and is closed. Anything
 * wrong inside a well-framed FILTER gets a non-fatal ERROR with its request
 * id, the rest of the frame is skipped, and the connection goes on.
 *
 * Nothing but HELLO is read before the handshake is complete, and a HELLO
 * that is not one is a fatal PROTOCOL error: an unauthenticated peer gets
 * no STATS, no VARIANTS, no buffers. Memory is charged as it is used: a
 * FILTER's tensor as its bytes arrive, its result buffers and what running
 * it takes when it is admitted (docs/SERVER.md, "Memory").
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <hairfilter/hairfilter_version.h>

#include "server.h"

static void read_next(hfd_conn *c);
static void job_free(hfd_server *s, hfd_job *j);
static void conn_idle_check(hfd_conn *c);
static void on_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf);
static void on_read(uv_stream_t *stream, ssize_t nread, const uv_buf_t *buf);

/* A frame refused by a drain: what the server is doing, and what the
 * client does about it (the client library sends it on to another
 * endpoint of its list by itself; one endpoint alone must connect again). */
#define DRAINING_WHY                                                                   \
  "server is shutting down (draining before it stops): send the frame to another "     \
  "server, or connect again once this one has restarted"

/* Backpressure on replies: a peer that sends requests without reading the
 * answers would make us queue replies without bound (a flood of rejected
 * frames costs it nothing). Past HIGH unwritten replies we stop reading
 * from it; below LOW we resume. Results are already bounded by
 * --max-inflight, so this only bites on misbehaving peers. */
#define WRITES_HIGH 256
#define WRITES_LOW 64
/* The same in bytes, for the replies other than RESULT (ERROR, HELLO_OK,
 * VARIANTS, STATS_REPLY): they are charged to no budget, and a count alone
 * lets a STATS_REPLY of 64 variants (34 KiB) pile up to 8.5 MiB per
 * connection, gigabytes over --max-connections. HIGH still lets the
 * largest reply through alone; RESULTs are charged to --max-memory-mb
 * until written, and pausing for them would stall a client that writes
 * its next frame while it reads a large result. */
#define CTL_BYTES_HIGH ((uint64_t)64 << 10)
#define CTL_BYTES_LOW ((uint64_t)16 << 10)

/* A FILTER's tensor is read (and charged) in pieces of at most this many
 * bytes, so the memory received ahead of its charge is bounded. */
#define RECV_CHUNK ((size_t)1 << 20)

/* A connection before its HELLO counts against --max-handshakes; this ends
 * that, once. */
static void handshake_over(hfd_conn *c) {
  if (!c->handshaking) return;
  c->handshaking = 0;
  c->srv->num_handshaking--;
  if (c->listener->is_tcp && c->client) c->client->handshaking--;
}

static int mid_frame(const hfd_conn *c) { return c->rstate != RD_HEADER || c->got > 0; }

/* uv_read_stop cannot fail for a stream that is open (it returns 0), but
 * say so if that ever changes. */
static void read_stop(hfd_conn *c) {
  int rc = hfd_io_read_stop(c);
  if (rc < 0) hfd_err("conn %llu: read stop: %s", (unsigned long long)c->id, uv_strerror(rc));
}

/* Reading starts again once nothing holds it stopped: replies unread
 * (read_paused), a segment being pinned (pin_wait) or its descriptor not
 * yet passed (fd_sending), and the connection still reading at all. */
static void read_resume(hfd_conn *c) {
  if (c->read_paused || c->pin_wait || c->fd_sending || c->closing || c->fatal_sent || c->eof ||
      c->shutting)
    return;
  int rc = hfd_io_read_start(c, on_alloc, on_read);
  if (rc < 0) {
    hfd_err("conn %llu: read restart: %s", (unsigned long long)c->id, uv_strerror(rc));
    hfd_conn_close(c);
    return;
  }
  c->t_last_read = c->t_window = hfd_now_us();
  c->window_bytes = 0;
}

/* Written bytes of all the replies handed to libuv. */
static uint64_t bytes_written(const hfd_conn *c) {
  return c->bytes_queued - (uint64_t)hfd_io_write_queue_size(c);
}

/* A new reply-read-rate window starts (hfd_sweep_stalled): replies began
 * to wait, or the kernel took every byte that waited, which a peer that
 * keeps up with its replies does whatever their rate. */
static void read_window_start(hfd_conn *c, double now) {
  c->t_rwin = now;
  c->rwin_written = bytes_written(c);
}

static void wrote_one(hfd_conn *c) {
  c->writes_pending--;
  if (hfd_io_write_queue_size(c) == 0) read_window_start(c, hfd_now_us());
  if (c->read_paused && c->writes_pending <= WRITES_LOW && c->ctl_bytes <= CTL_BYTES_LOW) {
    c->read_paused = 0;
    read_resume(c);
  }
}

/* A reply of bytes was handed to libuv. */
static void writing_one(hfd_conn *c, uint64_t bytes) {
  int first = c->writes_pending == 0;
  if (first) {
    /* Nothing was waiting: the peer's reading is timed from now. */
    c->t_write = hfd_now_us();
    c->written_seen = c->bytes_queued;
  }
  c->bytes_queued += bytes;
  /* The rate's window starts with this reply counted: it is in libuv's
   * queue already, so counted before, the bytes of it still waiting would
   * have been taken for bytes read, and a reply larger than --min-recv-rate
   * times the window would have passed its first window, read or not. */
  if (first) read_window_start(c, c->t_write);
  c->writes_pending++;
  if (!c->read_paused && (c->writes_pending >= WRITES_HIGH || c->ctl_bytes >= CTL_BYTES_HIGH) &&
      !c->fatal_sent) {
    read_stop(c);
    c->read_paused = 1;
  }
}

/* " conn=N peer=P client=NAME" for a log line about c. */
static const char *conn_kv(const hfd_conn *c, char *buf, size_t cap) {
  char id[24];
  snprintf(id, sizeof id, "%llu", (unsigned long long)c->id);
  buf[0] = 0;
  hfd_kv(buf, cap, "conn", id);
  hfd_kv(buf, cap, "peer", c->peer);
  if (c->client_name[0]) hfd_kv(buf, cap, "client", c->client_name);
  return buf;
}

/* Error lines are rate-limited (a peer can make errors as fast as it can
 * send bytes); what is dropped is counted and reported with the next line.
 * The loop thread's own budget. */
static int log_allowed(void) {
  static hfd_rate lines;
  return hfd_rate_allow(&lines, 20, "error");
}

int hfd_conn_log_allowed(void) { return log_allowed(); }

/* ---- writes -------------------------------------------------------------- */

typedef struct ctl_write {
  uv_write_t req;
  hfd_conn *c;
  int close_after;
  size_t len;
  uint8_t data[];
} ctl_write;

static void conn_release(hfd_conn *c) {
  /* Freed only when libuv is done with the handle and nothing in flight
   * (queued jobs, pending writes) still points at it. */
  if (!c->handle_closed || c->inflight || c->writes_pending || c->pin_wait ||
      hfd_tls_stepping(c))
    return;
  hfd_server *s = c->srv;
  hfd_tls_conn_free(c);
  hfd_shm_client_leave(s, c);   /* its segments are freed: their jobs kept c */
  hfd_client_leave(s, c);
  free(c);
  hfd_maybe_finish(s);
}

void hfd_conn_release(hfd_conn *c) { conn_release(c); }

/* After a fatal ERROR over TCP the connection closes only once its peer
 * can have read it. Closing a TCP socket whose receive queue holds unread
 * bytes (the rest of the bad frame, requests pipelined behind it) makes the
 * kernel send a reset, and a reset throws away what is still on its way to
 * the peer: the ERROR and the results written before it. So the server
 * half-closes (the peer reads the ERROR, then the end of the stream), reads
 * and drops what the peer still sends, and closes at the peer's end of
 * stream, on a read error, or after HFD_LINGER_MS (hfd_sweep_stalled, which
 * runs at least once a second: 2 to 3 s), as
 * HTTP servers do in their "lingering close"; over TLS the half-close is
 * close_notify and the plaintext read is dropped. Unix sockets keep queued
 * data whatever the receiver left unread, a TLS connection whose
 * handshake did not complete has nothing to drain through, and one that
 * never completed its HELLO had nothing answered: they close at once. Without a sweep timer (every timeout disabled) nothing would bound
 * the wait, so they close at once too. */
#define HFD_LINGER_MS 2000

static void linger_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf) {
  hfd_conn *c = h->data;
  (void)suggested;
  *buf = uv_buf_init((char *)c->sink, sizeof c->sink);
}

static void linger_read(uv_stream_t *stream, ssize_t nread, const uv_buf_t *buf) {
  (void)buf;
  if (nread < 0) hfd_conn_close(stream->data); /* end of stream, or the peer is gone */
}

static void on_linger_shutdown(uv_shutdown_t *req, int status) {
  hfd_conn *c = req->data;
  free(req);
  c->writes_pending--;
  if (status < 0) hfd_conn_close(c);
  conn_release(c);
}

static void fatal_linger(hfd_conn *c) {
  if (c->closing) return;
  /* Before HELLO nothing was answered, and a lingering connection holds
   * its slot under --max-connections: peers that only connect would fill
   * the slots that --max-handshakes frees by closing the oldest of them. */
  if (!c->hello_done || (c->tls && !hfd_tls_established(c)) || c->is_pipe || c->eof ||
      !uv_is_active((uv_handle_t *)&c->srv->sweep_timer)) {
    hfd_conn_close(c);
    return;
  }
  uv_shutdown_t *req = malloc(sizeof *req);
  if (!req) {
    hfd_conn_close(c);
    return;
  }
  req->data = c;
  c->writes_pending++; /* before: over TLS the callback may run inside */
  if (hfd_io_shutdown(c, req, on_linger_shutdown) < 0) {
    c->writes_pending--;
    free(req);
    hfd_conn_close(c);
    return;
  }
  if (c->closing) return;
  c->lingering = c->shutting = 1;
  c->t_linger = hfd_now_us();
  if (c->job) {
    /* A FILTER half received when the error came: dropped. */
    job_free(c->srv, c->job);
    c->job = NULL;
  }
  int rc = hfd_io_read_start(c, linger_alloc, linger_read);
  if (rc < 0) {
    hfd_debug("conn %llu: read start: %s", (unsigned long long)c->id, uv_strerror(rc));
    hfd_conn_close(c);
  }
}

static void on_ctl_written(uv_write_t *req, int status) {
  ctl_write *w = (ctl_write *)req;
  hfd_conn *c = w->c;
  c->ctl_bytes -= w->len;
  wrote_one(c);
  if (status < 0 && status != UV_ECANCELED)
    hfd_debug("conn %llu: write failed: %s", (unsigned long long)c->id, uv_strerror(status));
  if (status < 0)
    hfd_conn_close(c);
  else if (w->close_after)
    fatal_linger(c);
  free(w);
  conn_release(c);
}

/* Queues one encoded control frame (at most a few tens of KiB). */
static void send_ctl(hfd_conn *c, const uint8_t *frame, size_t len, int close_after) {
  if (c->closing) return;
  ctl_write *w = malloc(sizeof *w + len);
  if (!w) {
    hfd_err("conn %llu: out of memory for a reply; closing it",
            (unsigned long long)c->id);
    hfd_conn_close(c);
    return;
  }
  w->c = c;
  w->close_after = close_after;
  w->len = len;
  memcpy(w->data, frame, len);
  uv_buf_t b = uv_buf_init((char *)w->data, (unsigned)len);
  c->ctl_bytes += len;   /* before: the write may complete inside (TLS) */
  int rc = hfd_io_write(c, &w->req, &b, 1, on_ctl_written);
  if (rc < 0) {
    hfd_debug("conn %llu: uv_write: %s", (unsigned long long)c->id, uv_strerror(rc));
    c->ctl_bytes -= len;
    free(w);
    hfd_conn_close(c);
    return;
  }
  writing_one(c, len);
}

/* Sends an ERROR. Fatal errors stop reading; the connection closes once
 * the ERROR has been written, so the peer gets to see why. */
static void send_error(hfd_conn *c, uint32_t request_id, int code, int fatal,
                       const char *fmt, ...) __attribute__((format(printf, 5, 6)));
static void send_error(hfd_conn *c, uint32_t request_id, int code, int fatal,
                       const char *fmt, ...) {
  hfp_error e;
  memset(&e, 0, sizeof e);
  e.code = (uint32_t)code;
  e.fatal = (uint8_t)(fatal != 0);
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(e.message, sizeof e.message, fmt, ap);
  va_end(ap);
  /* Keep the message printable whatever went into it (variant names from
   * the wire are already checked, but be sure). */
  for (char *p = e.message; *p; p++)
    if (*p < 0x20 || *p > 0x7e) *p = '?';
  /* BUSY is overload, not an error, and is not logged. Neither is a frame
   * refused with SHUTTING_DOWN an error: a drain refuses every frame sent
   * after SIGTERM, on every rolling restart; they are counted for the stop
   * line and logged at debug level. */
  int refused_draining = code == HFP_E_SHUTTING_DOWN && !fatal;
  if (refused_draining) c->srv->refused_draining++;
  if (refused_draining ? hfd_log_level >= HFD_LOG_DEBUG
                       : code != HFP_E_BUSY && log_allowed()) {
    char kv[300];
    hfd_logl(refused_draining ? HFD_LOG_DEBUG : HFD_LOG_ERR, "%s: %s%s%s request=%u code=%s",
             hfp_code_name(code), e.message, fatal ? "; closing the connection" : "",
             conn_kv(c, kv, sizeof kv), request_id, hfp_code_name(code));
  }
  uint8_t frame[HFP_HEADER_SIZE + 8 + HFP_MESSAGE_MAX];
  int n = hfp_encode_error(frame, sizeof frame, request_id, &e);
  if (n < 0) {
    hfd_err("cannot encode an ERROR: %s", hfp_strerror(n));
    hfd_conn_close(c);
    return;
  }
  if (fatal) {
    c->fatal_sent = 1;
    c->t_fatal = hfd_now_us();
    handshake_over(c);
    read_stop(c);
  }
  send_ctl(c, frame, (size_t)n, fatal);
}

/* ---- jobs ---------------------------------------------------------------- */

static void job_free(hfd_server *s, hfd_job *j) {
  s->mem_held -= j->bytes_held;
  if (j->model) hfd_model_unref(s, j->model);
  if (j->seg) {
    /* The tensors are the client's, in the segment. */
    hfd_seg_unref(s, j->seg);
  } else {
    hfd_rbuf_release(s, j->input);
    hfd_rbuf_release(s, j->out);
    hfd_rbuf_release(s, j->rgba);
  }
  free(j);
}

/* j's input tensor is no longer needed: its buffer and its charge go back
 * (a shared segment's tensors are the client's, charged to no frame). */
static void release_input(hfd_server *s, hfd_job *j) {
  if (j->seg || !j->input) return;
  hfd_rbuf_release(s, j->input);
  j->input = NULL;
  s->mem_held -= j->req.data_len;
  j->bytes_held -= j->req.data_len;
}

/* j will send no tensor: its input and result buffers and their charges go
 * back at once, so that --max-memory-mb is free for other frames. */
static void release_buffers(hfd_server *s, hfd_job *j) {
  release_input(s, j);
  if (j->seg) return;
  uint64_t results = (j->out ? j->out_len : 0) + (j->rgba ? j->rgba_len : 0);
  hfd_rbuf_release(s, j->out);
  hfd_rbuf_release(s, j->rgba);
  j->out = j->rgba = NULL;
  s->mem_held -= results;
  j->bytes_held -= results;
}

static void account(hfd_server *s, hfd_job *j);

/* Statistics count a reply once it is written: a frame whose peer left
 * before its RESULT went out was computed, not served. */
static void on_result_written(uv_write_t *req, int status) {
  hfd_job *j = req->data;
  hfd_conn *c = j->conn;
  hfd_server *s = c->srv;
  wrote_one(c);
  if (status < 0 && status != UV_ECANCELED)
    hfd_debug("conn %llu: result write failed: %s", (unsigned long long)c->id,
              uv_strerror(status));
  if (status < 0) {
    s->replies_lost++;
    hfd_conn_close(c);
  } else {
    account(s, j);
  }
  job_free(s, j);
  conn_release(c);
}

static void account(hfd_server *s, hfd_job *j) {
  hfp_variant_stats *st = &s->variants[j->variant].stats;
  hfd_metrics_count(s, j->variant, j->status);
  if (j->status == HFP_OK) hfd_metrics_observe(s, j);
  if (j->status != HFP_OK) {
    st->requests_failed++;
    /* Both also in requests_failed: its meaning (status != 0) is the
     * same for every protocol version (docs/SERVER.md, "Deadlines"). */
    st->expired += j->status == HFP_E_EXPIRED;
    st->cancelled += j->status == HFP_E_CANCELLED;
    /* Counted apart for the stop line and /metrics: overload, not a
     * failure to run. Only BUSY RESULTs are pushed-out frames. */
    if (j->status == HFP_E_BUSY)
      s->pushed_out_answered++;
    else
      s->failed_answered++;
    return;
  }
  s->served_answered++;
  st->requests_ok++;
  st->out_of_range += j->out_of_range != 0;
  st->frames_sanitised += j->sanitised != 0;
  st->sum_queue_us += j->timing.queue_us;
  st->sum_infer_us += j->timing.infer_us;
  st->sum_total_us += j->timing.total_us;
  st->hist_total[hfp_hist_bucket(j->timing.total_us)]++;
  st->hist_infer[hfp_hist_bucket(j->timing.infer_us)]++;
}

/* A job came back from the worker: reply on its connection, if that is
 * still open. */
static void deliver(hfd_server *s, hfd_job *j) {
  hfd_conn *c = j->conn;
  c->inflight--;
  if (--c->share->inflight == 0) s->sharers_with_frames--;
  s->jobs_outstanding--;
  /* The worker is done with the model: a replaced one may go now. */
  hfd_model_unref(s, j->model);
  j->model = NULL;
  double now = hfd_now_us();
  j->timing.queue_us = j->t_started > j->t_received ? (uint64_t)(j->t_started - j->t_received) : 0;
  j->timing.total_us = now > j->t_received ? (uint64_t)(now - j->t_received) : 0;
  if (j->status != HFP_OK) j->timing.input_us = j->timing.infer_us = j->timing.output_us = 0;
  /* What running it took is no longer needed. */
  s->mem_held -= j->infer_bytes;
  j->bytes_held -= j->infer_bytes;
  j->infer_bytes = 0;
  /* A frame answered unrun (EXPIRED, CANCELLED, BUSY, SHUTTING_DOWN) or
   * failed sends no tensor: its buffers go back now, not once a slow
   * client has read the 56 bytes of its RESULT. */
  if (j->status != HFP_OK) release_buffers(s, j);
  /* Nothing follows a fatal ERROR (PROTOCOL.md, "Errors"). */
  if (c->closing || c->fatal_sent) {
    s->replies_lost++;
    job_free(s, j);
    conn_release(c);
    return;
  }
  hfp_result r;
  memset(&r, 0, sizeof r);
  r.status = (uint16_t)j->status;
  r.timing = j->timing;
  r.dtype = j->req.out_dtype;   /* echoed whatever the status (PROTOCOL.md, RESULT) */
  if (j->status == HFP_OK) {
    r.flags = j->rgba ? HFP_FILTER_COMPOSITE : 0;
    r.width = j->req.width;
    r.height = j->req.height;
    r.batch = j->batch;
    r.data = j->out;
    r.data_len = j->out_len;
    r.rgba = j->rgba;
    r.rgba_len = j->rgba_len;
    if (j->seg) {
      r.flags |= HFP_FILTER_SHM;
      r.data_len = r.rgba_len = 0;
    }
    /* A version-1 peer knows no such flags: they are only counted for it. */
    if (j->out_of_range && c->version >= 2) r.flags |= HFP_RESULT_OUT_OF_RANGE;
    if (j->sanitised && c->version >= 2) r.flags |= HFP_RESULT_INPUT_SANITISED;
  }
  uint64_t total;
  int n = hfp_encode_result_head(j->head, sizeof j->head, j->request_id, &r, &total);
  if (n < 0) {
    hfd_err("conn %llu request %u: cannot encode RESULT: %s", (unsigned long long)c->id,
            j->request_id, hfp_strerror(n));
    s->replies_lost++;
    job_free(s, j);
    hfd_conn_close(c);
    conn_release(c);
    return;
  }
  uv_buf_t bufs[3];
  unsigned nbufs = 0;
  uint64_t bytes = (uint64_t)n + r.data_len + r.rgba_len;
  bufs[nbufs++] = uv_buf_init((char *)j->head, (unsigned)n);
  if (r.data_len) bufs[nbufs++] = uv_buf_init(j->out, (unsigned)r.data_len);
  if (r.rgba_len) bufs[nbufs++] = uv_buf_init(j->rgba, (unsigned)r.rgba_len);
  /* The input tensor is no longer needed; give its memory back now rather
   * than when the (possibly slow) client has read the reply. */
  release_input(s, j);
  j->wreq.data = j;
  int rc = hfd_io_write(c, &j->wreq, bufs, nbufs, on_result_written);
  if (rc < 0) {
    hfd_debug("conn %llu: uv_write: %s", (unsigned long long)c->id, uv_strerror(rc));
    s->replies_lost++;
    job_free(s, j);
    hfd_conn_close(c);
    conn_release(c);
    return;
  }
  writing_one(c, bytes);
  /* A peer that has shut down its side is closed once its last reply is
   * out (PROTOCOL.md, "Transport"). */
  conn_idle_check(c);
}

void hfd_on_async(uv_async_t *a) {
  hfd_server *s = a->data;
  /* Loads a reload waits for, then answers. */
  for (hfd_ctl *c = hfd_worker_take_ctl(&s->worker, 0), *next; c; c = next) {
    next = c->next;
    hfd_models_on_loaded(s, c);
  }
  hfd_job *j = hfd_worker_take_done(&s->worker);
  while (j) {
    hfd_job *next = j->next;
    deliver(s, j);
    j = next;
  }
  hfd_maybe_finish(s);
}

/* ---- requests ------------------------------------------------------------ */

static void reply_hello(hfd_conn *c, const uint8_t *p, size_t len) {
  hfd_server *s = c->srv;
  hfp_hello h;
  int rc = hfp_decode_hello(p, len, &h);
  if (rc && rc != -HFP_E_VERSION) {
    /* Whatever the codec found (a length that disagrees with its fields,
     * a bad name), a HELLO that is not one is a PROTOCOL error. */
    char why[192];
    hfp_hello_fault(p, len, rc, why, sizeof why);
    s->protocol_errors++;
    send_error(c, 0, HFP_E_PROTOCOL, 1, "malformed HELLO: %s", why);
    return;
  }
  /* The token before the version: a peer without the token learns nothing
   * of this server, not even which versions it speaks. */
  if (c->listener->auth_required) {
    /* Constant-time comparison: the time taken says nothing about how much
     * of a guessed token was right. */
    const char *want = s->cfg->token;
    size_t wl = strlen(want), gl = strlen(h.token);
    unsigned diff = (unsigned)(wl ^ gl);
    for (size_t i = 0; i < HFP_TOKEN_MAX; i++)
      diff |= (unsigned)((i < wl ? want[i] : 0) ^ (i < gl ? h.token[i] : 0));
    if (diff || !wl) {
      s->protocol_errors++;
      send_error(c, 0, HFP_E_UNAUTHORIZED, 1, "%s", gl ? "wrong token" : "this listener needs a token");
      return;
    }
  }
  int version = rc ? -HFP_E_VERSION : hfp_negotiate(h.min_version, h.max_version);
  if (version < 0) {
    s->protocol_errors++;
    send_error(c, 0, HFP_E_VERSION, 1, "client speaks versions %u..%u, server speaks %d..%d",
               h.min_version, h.max_version, HFP_VERSION_MIN, HFP_VERSION);
    return;
  }
  snprintf(c->client_name, sizeof c->client_name, "%s", h.client_name);
  c->hello_done = 1;
  c->version = version;
  handshake_over(c);
  hfp_hello_ok ok;
  memset(&ok, 0, sizeof ok);
  ok.version = (uint16_t)version;
  ok.server_flags = (c->listener->auth_required ? HFP_SERVER_AUTH_REQUIRED : 0) |
                    (c->is_ipc ? HFP_SERVER_SHM : 0);
  /* The largest frame every limit lets through (limits.c), not just
   * --max-size. */
  ok.max_width = (uint32_t)s->max_width;
  ok.max_height = (uint32_t)s->max_height;
  int max_spp = 1;
  for (int i = 0; i < s->num_variants; i++)
    if (s->variants[i].model && s->variants[i].model->cfg.spp > max_spp)
      max_spp = s->variants[i].model->cfg.spp;
  ok.max_spp = (uint16_t)max_spp;
  ok.max_inflight = (uint16_t)s->cfg->max_inflight;
  ok.dtypes = HFP_DTYPE_MASK_ALL;
  ok.max_batch = (uint32_t)s->cfg->max_batch;
  ok.queue_size = (uint32_t)s->cfg->queue_size;
  ok.max_frame_bytes = s->cfg->max_frame_bytes;
  snprintf(ok.server_name, sizeof ok.server_name, "%s", s->cfg->name);
  /* Version 2 peers learn the server's release (version 1 ones never see it). */
  snprintf(ok.software_version, sizeof ok.software_version, "%s", HAIRFILTER_VERSION_STRING);
  uint8_t frame[HFP_HELLO_OK_MAX];
  int n = hfp_encode_hello_ok(frame, sizeof frame, &ok);
  if (n < 0) {
    send_error(c, 0, HFP_E_INTERNAL, 1, "cannot encode HELLO_OK");
    return;
  }
  char kv[300];
  hfd_debug("hello%s version=%d", conn_kv(c, kv, sizeof kv), version);
  send_ctl(c, frame, (size_t)n, 0);
}

static void reply_variants(hfd_conn *c) {
  hfd_server *s = c->srv;
  hfp_variant v[HFD_MAX_VARIANTS];
  memset(v, 0, sizeof v);
  int n = 0;
  for (int k = 0; k < s->num_variants; k++) {
    const hfd_model *sv = s->variants[k].model;
    if (!sv) continue;  /* removed */
    int i = n++;
    snprintf(v[i].name, sizeof v[i].name, "%s", sv->name);
    snprintf(v[i].backend, sizeof v[i].backend, "%s", hf_backend_name(s->worker.backend));
    snprintf(v[i].precision, sizeof v[i].precision, "%s", sv->precision);
    v[i].spp = (uint16_t)sv->cfg.spp;
    v[i].num_levels = (uint16_t)sv->cfg.num_levels;
    for (int l = 0; l < sv->cfg.num_levels; l++) v[i].levels[l] = (uint32_t)sv->cfg.levels[l];
    for (int k = 0; sv->range.present && k < HF_STAT_COUNT && k < HFP_MAX_STATS; k++) {
      if (!(sv->range.has & (1u << k))) continue;
      v[i].ranges[v[i].num_ranges].stat = (uint8_t)k;
      v[i].ranges[v[i].num_ranges].lo = sv->range.lo[k];
      v[i].ranges[v[i].num_ranges++].hi = sv->range.hi[k];
    }
    /* Sent to version-3 peers only (the codec leaves it out before). */
    v[i].estimate = sv->cfg.estimate ? HFP_ESTIMATE_ALPHA_CORRECTED : HFP_ESTIMATE_NONE;
  }
  size_t need = hfp_frame_size_variants_v(v, n, c->version);
  uint8_t *frame = malloc(need);
  if (!frame) {
    send_error(c, 0, HFP_E_INTERNAL, 0, "out of memory");
    return;
  }
  int len = hfp_encode_variants_v(frame, need, v, n, c->version);
  if (len < 0)
    send_error(c, 0, HFP_E_INTERNAL, 0, "cannot encode VARIANTS: %s", hfp_strerror(len));
  else
    send_ctl(c, frame, (size_t)len, 0);
  free(frame);
}

static void reply_stats(hfd_conn *c) {
  static hfp_stats st;  /* 30 KiB; the loop is single-threaded */
  hfd_fill_stats(c->srv, &st);
  size_t need = hfp_frame_size_stats_v(&st, c->version);
  uint8_t *frame = malloc(need);
  if (!frame) {
    send_error(c, 0, HFP_E_INTERNAL, 0, "out of memory");
    return;
  }
  int n = hfp_encode_stats_v(frame, need, &st, c->version);
  if (n < 0)
    send_error(c, 0, HFP_E_INTERNAL, 0, "cannot encode STATS_REPLY: %s", hfp_strerror(n));
  else
    send_ctl(c, frame, (size_t)n, 0);
  free(frame);
}

/* Skips what is left of the current frame after a non-fatal rejection. */
static void discard_rest(hfd_conn *c, uint64_t left) {
  if (left == 0) {
    read_next(c);
    return;
  }
  c->rstate = RD_DISCARD;
  c->discard_left = left;
}

static void reject(hfd_conn *c, int variant, int code, uint64_t left, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void reject(hfd_conn *c, int variant, int code, uint64_t left, const char *fmt, ...) {
  char msg[HFP_MESSAGE_MAX + 1];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  if (variant >= 0)
    c->srv->variants[variant].stats.rejected++;
  else
    c->srv->protocol_errors++;
  if (variant >= 0 || c->hdr.type == HFP_FILTER) hfd_metrics_count(c->srv, variant, code);
  send_error(c, c->hdr.type == HFP_FILTER ? c->hdr.request_id : 0, code, 0, "%s", msg);
  discard_rest(c, left);
}

static void filter_admit(hfd_conn *c);
static void on_control(hfd_conn *c);

static hfd_seg *find_seg(hfd_conn *c, uint32_t id) {
  for (hfd_seg *g = c->segs; g; g = g->next)
    if (g->id == id) return g;
  return NULL;
}

/* A FILTER whose tensors are in a segment: nothing more to read; point the
 * job at the segment and admit it. */
static void filter_shm(hfd_conn *c, int v, const hfp_filter *f) {
  hfd_seg *g = find_seg(c, f->shm_segment);
  if (!g) {
    reject(c, v, HFP_E_INVALID, 0, "no segment %u on this connection", f->shm_segment);
    return;
  }
  char why[200];
  int rc = hfp_shm_check_why(f, g->size, why, sizeof why);
  if (rc) {
    reject(c, v, -rc, 0, "segment %u: %s", f->shm_segment, why);
    return;
  }
  hfd_job *j = calloc(1, sizeof *j);
  if (!j) {
    reject(c, v, HFP_E_BUSY, 0, "out of memory");
    return;
  }
  j->conn = c;
  j->request_id = c->hdr.request_id;
  j->variant = v;
  j->model = c->srv->variants[v].model;
  j->model->refs++;
  j->req = *f;
  j->seg = g;
  g->refs++;
  j->input = g->addr + f->shm_in;
  j->req.data = j->input;
  j->out = g->addr + f->shm_out;
  j->rgba = (f->flags & HFP_FILTER_COMPOSITE) ? g->addr + f->shm_rgba : NULL;
  c->job = j;
  filter_admit(c);
}

static uint64_t mem_committed(hfd_server *s) {
  return s->mem_held + atomic_load(&s->worker.cached_bytes) + hfd_rpool_reserve(&s->rpool);
}

/* 1 when more bytes can be charged within --max-memory-mb; idle receive
 * buffers make way first. */
static int mem_fits(hfd_server *s, uint64_t more) {
  uint64_t used = mem_committed(s), cap = s->cfg->max_memory_bytes;
  if (used > cap || more > cap - used) {
    hfd_rpool_shrink(&s->rpool, used + more - cap);
    used = mem_committed(s);
  }
  return used <= cap && more <= cap - used;
}

static void answer_expired(hfd_server *s);

/* mem_fits for c's frame, after the frames past their budget have given
 * their memory back when it does not fit otherwise (docs/SERVER.md,
 * "Deadlines"): 1 or 0; -1 when answering them closed c (a reply of its
 * own that could not be written; the frame c was receiving is dropped). */
static int mem_fits_for(hfd_conn *c, uint64_t more) {
  hfd_server *s = c->srv;
  if (mem_fits(s, more)) return 1;
  if (s->draining) return 0;
  answer_expired(s);
  if (c->closing) return -1;
  return mem_fits(s, more);
}

/* The FILTER head is in ctl[]: check it against the server and, when it
 * passes, make the job that the tensor will be read into. Nothing is charged
 * yet but what has arrived: a peer that announces a large frame and sends
 * it slowly holds only what it sent (docs/SERVER.md, "Memory"). */
static void filter_head(hfd_conn *c, size_t have) {
  hfd_server *s = c->srv;
  uint32_t len = c->hdr.length;
  hfp_filter f;
  size_t head_len = 0;
  int rc = hfp_decode_filter_head(c->ctl, have, len, &f, &head_len);
  if (rc == -HFP_E_NOSPACE) {
    /* The fixed fields are in; the variant name (and, for SHM, the segment
     * reference) is still to come. The codec has checked that it fits. */
    unsigned flags = hfp_get_u16(c->ctl + 2);
    size_t need = HFP_FILTER_FIXED + hfp_get_u16(c->ctl) +
                  ((flags & HFP_FILTER_DEADLINE) ? HFP_DEADLINE_SIZE : 0) +
                  ((flags & HFP_FILTER_SHM) ? HFP_SHM_REF_SIZE : 0);
    c->want = need;
    return;
  }
  uint64_t left = len - have;
  /* A refusal counts in the `rejected` of the variant the FILTER names
   * whenever the codec read its name, the faults after the name included;
   * one refused before (or naming no served variant) is a protocol error
   * (PROTOCOL.md, "Statistics"). The codec leaves the name empty unless it
   * read it. */
  int v = f.variant[0] ? hfd_variant_find(s, f.variant) : -1;
  /* SHM where the connection cannot have a segment is refused before
   * anything else the frame holds: its reference means nothing here
   * (PROTOCOL.md, "Which error a FILTER gets"). The fixed fields are in
   * ctl[] (on_header asked for them), whatever the codec made of them. */
  if ((hfp_get_u16(c->ctl + 2) & HFP_FILTER_SHM) && !c->is_ipc) {
    reject(c, v, HFP_E_UNSUPPORTED, left, "%s",
           c->is_pipe ? "shared memory is disabled on this server (--max-shm-mb 0)"
                      : "shared memory needs a Unix socket");
    return;
  }
  /* Before version 3, bit 2 (ESTIMATE) is a flag no FILTER may set: an
   * unknown flag, whatever the length says (PROTOCOL.md, "Version 3"). */
  if ((hfp_get_u16(c->ctl + 2) & HFP_FILTER_ESTIMATE) && c->version < 3) {
    reject(c, v, HFP_E_UNSUPPORTED, left,
           "FILTER flag ESTIMATE (bit 2) needs protocol version 3; this connection speaks %d: "
           "offer version 3 or later in HELLO (a newer client), or send the frame without the "
           "flag", c->version);
    return;
  }
  /* Likewise bit 3 (DEADLINE) before version 4 (PROTOCOL.md, "Version 4"). */
  if ((hfp_get_u16(c->ctl + 2) & HFP_FILTER_DEADLINE) && c->version < 4) {
    reject(c, v, HFP_E_UNSUPPORTED, left,
           "FILTER flag DEADLINE (bit 3) needs protocol version 4; this connection speaks %d: "
           "offer version 4 in HELLO (a newer client), or send the frame without the flag",
           c->version);
    return;
  }
  if (rc) {
    /* The field and what it must be, so the client knows what to fix. */
    char why[200];
    hfp_filter_fault(c->ctl, have, len, rc, why, sizeof why);
    reject(c, v, -rc, left, "malformed FILTER: %s", why);
    return;
  }
  uint64_t need = 0;
  int fits;
  if (c->hdr.request_id == 0) {
    reject(c, v, HFP_E_INVALID, left, "request id 0 is reserved");
  } else if (v < 0) {
    reject(c, -1, HFP_E_UNKNOWN_VARIANT, left, "unknown variant '%s'", f.variant);
  } else if (f.spp != s->variants[v].model->cfg.spp) {
    reject(c, v, HFP_E_INVALID, left, "variant %s takes %d spp, request has %u", f.variant,
           s->variants[v].model->cfg.spp, f.spp);
  } else if (s->variants[v].model->cfg.estimate && !(f.flags & HFP_FILTER_ESTIMATE)) {
    reject(c, v, HFP_E_INVALID, left,
           "variant %s reads stochastic transparency's alpha-corrected estimate: set FILTER "
           "flag ESTIMATE and send the estimate after the features (protocol version 3%s)",
           f.variant, c->version < 3 ? "; this connection speaks an older one" : "");
  } else if (!s->variants[v].model->cfg.estimate && (f.flags & HFP_FILTER_ESTIMATE)) {
    reject(c, v, HFP_E_INVALID, left,
           "variant %s reads no estimate: clear FILTER flag ESTIMATE and send the features "
           "alone", f.variant);
  } else if (f.width > (uint32_t)s->max_width || f.height > (uint32_t)s->max_height) {
    reject(c, v, HFP_E_TOO_LARGE, left,
           "%ux%u is over the limit of %dx%d (HELLO_OK's max size; hairfilterd's --max-size, "
           "lowered at start to fit --max-memory-mb: docs/SERVER.md)", f.width, f.height,
           s->max_width, s->max_height);
  } else if ((need = hfd_frame_bytes(s, v, &f)) > s->frame_budget) {
    /* Within the announced size this cannot happen (limits.c); kept so
     * that no frame is ever admitted that the budget cannot hold. */
    reject(c, v, HFP_E_TOO_LARGE, left, "%ux%u needs %llu MiB, over the %llu MiB one frame may use",
           f.width, f.height, (unsigned long long)(need >> 20),
           (unsigned long long)(s->frame_budget >> 20));
  } else if (s->draining) {
    reject(c, v, HFP_E_SHUTTING_DOWN, left, "%s", DRAINING_WHY);
  } else if ((fits = mem_fits_for(c, need)) <= 0) {
    if (fits < 0) return;
    /* Refused now rather than after the upload: it would not fit. */
    reject(c, v, HFP_E_BUSY, left,
           "request memory full: the frame needs %llu MiB, %llu of %llu MiB are in use "
           "(--max-memory-mb); retry later", (unsigned long long)(need >> 20),
           (unsigned long long)(mem_committed(s) >> 20),
           (unsigned long long)(s->cfg->max_memory_bytes >> 20));
  } else if (f.flags & HFP_FILTER_SHM) {
    filter_shm(c, v, &f);
  } else {
    uint64_t out_len = 0, rgba_len = 0;
    hfp_output_bytes(f.width, f.height, HFP_OUTPUTS, f.out_dtype, &out_len);
    if (f.flags & HFP_FILTER_COMPOSITE) hfp_output_bytes(f.width, f.height, 4, f.out_dtype, &rgba_len);
    hfd_job *j = calloc(1, sizeof *j);
    /* A kept buffer (recv_pool.c) or address space only: either way it is
     * charged as the tensor lands in it (on_read). */
    void *in = j ? hfd_rpool_take(&s->rpool, (size_t)f.data_len) : NULL;
    if (!in) {
      free(j);
      reject(c, v, HFP_E_BUSY, left, "out of memory for a %llu-byte frame",
             (unsigned long long)f.data_len);
      return;
    }
    j->conn = c;
    j->request_id = c->hdr.request_id;
    j->variant = v;
    /* The version that checked the frame runs it, whatever a reload does
     * meanwhile. */
    j->model = s->variants[v].model;
    j->model->refs++;
    j->req = f;
    j->req.data = in;
    j->input = in;
    j->out_len = out_len;
    j->rgba_len = rgba_len;
    c->job = j;
    c->rstate = RD_FILTER_DATA;
    c->want = (size_t)f.data_len;
    c->got = 0;
  }
}

/* The queue places c's client may hold on all its connections together
 * (c->share: the connection itself with --queue-share-by connection),
 * queue_size / n with n the clients holding frames (admitted, not yet
 * answered), c's counted, at least 1. Per connection, a client that opened
 * many connections held as many shares and kept the others' frames out. */
static int queue_share(const hfd_server *s, const hfd_conn *c) {
  int q = s->cfg->queue_size, n = s->sharers_with_frames + (c->share->inflight == 0);
  return q / n > 0 ? q / n : 1;
}

/* Whether c must wait for its share of the queue: the last quarter of the
 * queue (at least one place) goes only to connections holding fewer frames
 * than their share (queue_share). So clients that resend the moment a slot
 * frees (after every BUSY) fill the queue up to its last quarter only, and
 * one that sends a frame at a time, holding none, finds room there; where a
 * connection under its share took that room, filter_admit makes room by
 * pushing out a frame of one over its share. The queue is shared, not
 * first come first served. The rule refuses nothing that is within its
 * share: a connection alone may hold as many frames as the queue has
 * places, those running or being answered counted (so with one running it
 * fills all but one place), and connections that each stay within
 * queue_size / n never meet it (the defaults: queue 64, 32 in flight per
 * connection). */
static int over_queue_share(hfd_server *s, const hfd_conn *c, int share) {
  int q = s->cfg->queue_size, reserve = q / 4 > 0 ? q / 4 : 1;
  /* Within its share nothing is refused: only then is the worker's queue
   * (and its mutex) asked how full it is. */
  return c->share->inflight >= share && hfd_worker_queue_depth(&s->worker) + 1 > q - reserve;
}

/* Answers j, which a client under its share pushed out of the queue
 * (hfd_worker_push_out), with a RESULT of status BUSY: it was admitted, so
 * its reply is a RESULT (PROTOCOL.md, "Flow control"). */
static void answer_pushed_out(hfd_server *s, hfd_job *j) {
  j->status = HFP_E_BUSY;
  j->t_started = j->t_done = hfd_now_us();
  j->batch = 0;
  deliver(s, j);
}

/* Queues j of c, whose share is share: 0, or HFP_E_BUSY for a full queue.
 * A connection under its share takes, in a full queue, the place of a
 * frame of one over its share (hfd_worker_push_out), which *pushed then
 * returns. */
static int queue_frame(hfd_server *s, const hfd_conn *c, int share, hfd_job *j,
                       hfd_job **pushed) {
  if (c->share->inflight < share) return hfd_worker_push_out(&s->worker, j, share, pushed);
  return hfd_worker_submit(&s->worker, j);
}

/* Answers now the queued frames whose budget has passed (EXPIRED): they
 * count in their connections' in-flight frames and shares of the queue,
 * and hold their memory, until answered, and the worker, busy with a run,
 * would answer them only after it. */
static void answer_expired(hfd_server *s) {
  for (hfd_job *j = hfd_worker_take_expired(&s->worker), *next; j; j = next) {
    next = j->next;
    j->next = NULL;
    deliver(s, j);
  }
}

/* The FILTER's tensor is in: charge its result buffers and what running it
 * takes, and admit it to the queue, or say why not. */
static void filter_admit(hfd_conn *c) {
  hfd_server *s = c->srv;
  hfd_job *j = c->job;
  c->job = NULL;
  j->t_received = hfd_now_us();
  int code = 0;
  const char *why = NULL;
  char share_why[400];
  hfd_job *pushed = NULL;
  int share = queue_share(s, c);
  uint64_t run = hfd_worker_run_bytes(&s->worker, &j->model->cfg, j->req.width, j->req.height,
                                      1, j->req.data_len);
  uint64_t more = run + (j->seg ? 0 : j->out_len + j->rgba_len);
  /* A frame that can still make it is not refused for places or memory
   * that frames past their budget hold, the connection's own included
   * (docs/SERVER.md, "Deadlines"). */
  if (!s->draining && (c->inflight >= s->cfg->max_inflight || over_queue_share(s, c, share))) {
    answer_expired(s);
    /* A reply of c's own that could not be written closed c. */
    if (c->closing) {
      job_free(s, j);
      return;
    }
    share = queue_share(s, c);
  }
  if (run != UINT64_MAX && !s->draining) {
    if (mem_fits_for(c, more) < 0) {
      job_free(s, j);
      return;
    }
    share = queue_share(s, c);
  }
  /* c's count cannot change from here until it is queued. */
  if (s->draining) {
    code = HFP_E_SHUTTING_DOWN;
    why = DRAINING_WHY;
  } else if (c->inflight >= s->cfg->max_inflight) {
    code = HFP_E_BUSY;
    /* The client's own doing: the limit it was told in HELLO_OK. */
    snprintf(share_why, sizeof share_why,
             "too many requests in flight on this connection: %d, HELLO_OK's max_inflight "
             "(--max-inflight); read a reply before sending more", c->inflight);
    why = share_why;
  } else if (over_queue_share(s, c, share)) {
    code = HFP_E_BUSY;
    /* Where the share comes from, and the operator's knob: a single
     * connection meets this too, with a queue smaller than its window. */
    const int by_conn = c->share == &c->own;
    char who[128];
    if (by_conn)
      snprintf(who, sizeof who, "this connection");
    else
      snprintf(who, sizeof who, "this client (%s, %d connection(s) together)", c->share->name,
               c->share->conns);
    snprintf(share_why, sizeof share_why,
             "%s holds its share of the queue (%d frame(s) of --queue-size %d, shared by %d "
             "%s(s) holding frames; the server's operator can raise --queue-size)", who, share,
             s->cfg->queue_size, s->sharers_with_frames + (c->share->inflight == 0),
             by_conn ? "connection" : "client");
    why = share_why;
  } else if (run == UINT64_MAX || !mem_fits(s, more)) {
    code = HFP_E_BUSY;
    /* How much it needed and what is left, as the refusal at the head says. */
    snprintf(share_why, sizeof share_why,
             "request memory full: running the frame needs %llu MiB, %llu of %llu MiB are in use "
             "(--max-memory-mb); retry later", (unsigned long long)(more >> 20),
             (unsigned long long)(mem_committed(s) >> 20),
             (unsigned long long)(s->cfg->max_memory_bytes >> 20));
    why = share_why;
  } else {
    s->mem_held += more;
    j->bytes_held += more;
    j->infer_bytes = run;
    if (!j->seg) {
      j->out = hfd_rbuf_result(s, j->out_len);
      j->rgba = j->rgba_len ? hfd_rbuf_result(s, j->rgba_len) : NULL;
    }
    if (!j->out || (j->rgba_len && !j->rgba)) {
      code = HFP_E_BUSY;
      why = "out of memory for the result";
    } else if (queue_frame(s, c, share, j, &pushed)) {
      code = HFP_E_BUSY;
      snprintf(share_why, sizeof share_why,
               "queue full (--queue-size %d frames waiting to run); retry later",
               s->cfg->queue_size);
      why = share_why;
    }
  }
  if (code) {
    s->variants[j->variant].stats.rejected++;
    hfd_metrics_count(s, j->variant, code);
    send_error(c, j->request_id, code, 0, "%s", why);
    job_free(s, j);
  } else {
    c->inflight++;
    if (c->share->inflight++ == 0) s->sharers_with_frames++;
    s->jobs_outstanding++;
  }
  /* Answered once c's frame is counted (it is never one of c's: c holds
   * fewer than its share). */
  if (pushed) answer_pushed_out(s, pushed);
  read_next(c);
}

/* The types a client sends (PROTOCOL.md, "Frames"); the others go only
 * from server to client. */
static int is_client_type(const hfd_conn *c, uint16_t type) {
  return type == HFP_HELLO || type == HFP_LIST_VARIANTS || type == HFP_FILTER ||
         type == HFP_STATS || type == HFP_SHM_CREATE || type == HFP_SHM_DESTROY ||
         (type == HFP_CANCEL && c->version >= 4);
}

/* A whole header is in hbuf. Request ids in ERRORs (PROTOCOL.md,
 * "Errors"): a FILTER's own for errors about it, 0 for everything else. */
static void on_header(hfd_conn *c) {
  hfd_server *s = c->srv;
  uint32_t max = s->cfg->max_frame_bytes > UINT32_MAX ? UINT32_MAX
                                                       : (uint32_t)s->cfg->max_frame_bytes;
  int rc = hfp_header_decode(c->hbuf, max, &c->hdr);
  const hfp_header *h = &c->hdr;
  /* The type is the header's before its length: a server -> client type
   * claiming too much goes on to the switch below, which refuses it as
   * PROTOCOL whatever its length, and so does a second HELLO, which is no
   * request once the handshake is done. */
  if (rc == -HFP_E_TOO_LARGE && c->hello_done && is_client_type(c, h->type) &&
      h->type != HFP_HELLO) {
    s->protocol_errors++;
    send_error(c, h->type == HFP_FILTER ? h->request_id : 0, HFP_E_TOO_LARGE, 1,
               "frame of %u bytes is over the limit of %llu", h->length,
               (unsigned long long)s->cfg->max_frame_bytes);
    return;
  }
  if (rc && rc != -HFP_E_TOO_LARGE) {
    s->protocol_errors++;
    /* A TLS record (handshake type 0x16, version 3.x: RFC 8446, 5.1) opens
     * a ClientHello. The ERROR below is no text to that client, but its
     * bytes make the client's TLS library report a wrong record version,
     * which libhairfilter explains as a plain listener. */
    if (!c->hello_done && c->hbuf[0] == 0x16 && c->hbuf[1] == 0x03 && c->hbuf[2] <= 0x04) {
      if (c->listener->is_tcp)
        send_error(c, 0, HFP_E_PROTOCOL, 1,
                   "a TLS client on a plain tcp: listener (%s): the client must use a tcp: URL, "
                   "or the server listen on tls:HOST:PORT", c->listener->url);
      else
        send_error(c, 0, HFP_E_PROTOCOL, 1,
                   "a TLS client on a Unix socket (%s): TLS is for tls:HOST:PORT listeners; "
                   "over the socket the client must speak plain (a unix: URL)", c->listener->url);
      return;
    }
    /* The field at fault, in hfp_header_decode's order. */
    uint32_t magic = hfp_get_u32(c->hbuf);
    unsigned type = hfp_get_u16(c->hbuf + 4), flags = hfp_get_u16(c->hbuf + 6);
    if (magic != HFP_MAGIC)
      send_error(c, 0, HFP_E_PROTOCOL, 1,
                 "bad frame header: magic 0x%08x, not 0x%08x (the bytes HFP1): not a "
                 "hairfilter client, or a frame's length that disagrees with its payload",
                 magic, HFP_MAGIC);
    else if (type < 1 || type > HFP_TYPE_MAX)
      send_error(c, 0, HFP_E_PROTOCOL, 1,
                 "bad frame header: message type %u is none of 1..%d", type, HFP_TYPE_MAX);
    else
      send_error(c, 0, HFP_E_PROTOCOL, 1,
                 "bad frame header: flags 0x%04x in a %s header; they are reserved and must "
                 "be 0", flags, hfp_type_name(type));
    return;
  }
  /* Before the handshake, the only frame read is a HELLO of a HELLO's
   * size: nothing else is served, decoded or buffered. */
  if (!c->hello_done) {
    if (h->type != HFP_HELLO) {
      s->protocol_errors++;
      send_error(c, 0, HFP_E_PROTOCOL, 1, "HELLO must come first, not %s (type %u)",
                 hfp_type_name(h->type), h->type);
      return;
    }
    if (h->length < HFP_HELLO_FIXED || h->length > HFP_HELLO_FIXED + HFP_NAME_MAX + HFP_TOKEN_MAX) {
      s->protocol_errors++;
      send_error(c, 0, HFP_E_PROTOCOL, 1, "malformed HELLO: its payload is %u bytes; a HELLO's "
                 "is %d to %d (the fixed fields, a name of 1..%d, a token of 0..%d)", h->length,
                 HFP_HELLO_FIXED + 1, HFP_HELLO_FIXED + HFP_NAME_MAX + HFP_TOKEN_MAX,
                 HFP_NAME_MAX, HFP_TOKEN_MAX);
      return;
    }
  }
  switch (h->type) {
    case HFP_HELLO:
      if (c->hello_done) {
        s->protocol_errors++;
        send_error(c, 0, HFP_E_PROTOCOL, 1, "second HELLO");
        return;
      }
      break;
    case HFP_SHM_CREATE:
    case HFP_SHM_DESTROY:
      /* A malformed control message is fatal wherever it arrives; only a
       * well-formed one is refused for the transport (PROTOCOL.md, "Errors"). */
      if (h->length != (h->type == HFP_SHM_CREATE ? 8u : 4u)) {
        s->protocol_errors++;
        send_error(c, 0, HFP_E_LENGTH, 1, "malformed %s: its payload is %u bytes; it must be %u",
                   hfp_type_name(h->type), h->length, h->type == HFP_SHM_CREATE ? 8u : 4u);
        return;
      }
      if (!c->is_ipc) {
        reject(c, -1, HFP_E_UNSUPPORTED, h->length, "%s",
               c->is_pipe ? "shared memory is disabled on this server (--max-shm-mb 0)"
                          : "shared memory needs a Unix socket");
        return;
      }
      break;
    case HFP_CANCEL:
      /* Before version 4 no such request exists (PROTOCOL.md, "Version 4"). */
      if (c->version < 4) {
        s->protocol_errors++;
        send_error(c, 0, HFP_E_PROTOCOL, 1,
                   "message type 13 (CANCEL) needs protocol version 4; this connection speaks "
                   "%d: offer version 4 in HELLO (a newer client) to cancel frames",
                   c->version);
        return;
      }
      /* An empty payload, as LIST_VARIANTS and STATS have. */
      /* fall through */
    case HFP_LIST_VARIANTS:
    case HFP_STATS:
      if (h->length != 0) {
        s->protocol_errors++;
        send_error(c, 0, HFP_E_LENGTH, 1, "%s has an empty payload; this one has %u bytes",
                   hfp_type_name(h->type), h->length);
        return;
      }
      break;
    case HFP_FILTER:
      if (h->length < HFP_FILTER_FIXED) {
        reject(c, -1, HFP_E_LENGTH, h->length, "FILTER shorter than its fixed fields");
        return;
      }
      c->rstate = RD_FILTER_HEAD;
      c->want = HFP_FILTER_FIXED;
      c->got = 0;
      return;
    default:
      s->protocol_errors++;
      send_error(c, 0, HFP_E_PROTOCOL, 1, "message type %u is not a request", h->type);
      return;
  }
  c->rstate = RD_CONTROL;
  c->want = h->length;
  c->got = 0;
  if (c->want == 0) on_control(c);   /* complete already */
}

typedef struct fd_write {
  uv_write_t req;
  hfd_conn *c;
  uv_pipe_t fdpipe;              /* wraps the memfd so libuv can send it */
  uint8_t data[HFP_HEADER_SIZE + 12];
} fd_write;

static void on_fdpipe_closed(uv_handle_t *h) { free(h->data); }

static void on_fd_written(uv_write_t *req, int status) {
  fd_write *w = (fd_write *)req;
  hfd_conn *c = w->c;
  /* The descriptor is out (or never will be): the connection may ask for
   * the next segment. wrote_one resumes reading when replies held it too. */
  c->fd_sending = 0;
  int paused = c->read_paused;
  wrote_one(c);
  if (status < 0 && status != UV_ECANCELED)
    hfd_debug("conn %llu: segment send failed: %s", (unsigned long long)c->id, uv_strerror(status));
  if (status < 0)
    hfd_conn_close(c);
  else if (!paused)
    read_resume(c);
  /* Our copy of the fd goes; the mapping and the client's copy stay. */
  w->fdpipe.data = w;
  uv_close((uv_handle_t *)&w->fdpipe, on_fdpipe_closed);
  conn_release(c);
}

/* Passes the new segment g (its memfd fd, which this closes) to the peer
 * in SHM_CREATED and adds it to the connection's. */
static void shm_created(hfd_conn *c, hfd_seg *g, int fd, uint64_t bytes) {
  hfd_server *s = c->srv;
  do g->id = ++c->next_seg_id; while (g->id == 0 || find_seg(c, g->id));
  fd_write *w = calloc(1, sizeof *w);
  int rc = w ? uv_pipe_init(s->loop, &w->fdpipe, 0) : UV_ENOMEM;
  if (rc == 0 && (rc = uv_pipe_open(&w->fdpipe, fd)) < 0) {
    /* not open: close the handle (it owns nothing yet) and the fd ourselves */
    w->fdpipe.data = w;
    uv_close((uv_handle_t *)&w->fdpipe, on_fdpipe_closed);
    w = NULL;
    close(fd);
    fd = -1;
  }
  if (rc < 0) {
    if (fd >= 0) close(fd);
    free(w);
    hfd_seg_drop(s, g);
    s->protocol_errors++; /* no variant to count it against */
    send_error(c, 0, HFP_E_INTERNAL, 0, "cannot pass the segment: %s", uv_strerror(rc));
    return;
  }
  int n = hfp_encode_shm_created(w->data, sizeof w->data, g->id, bytes);
  w->c = c;
  uv_buf_t b = uv_buf_init((char *)w->data, (unsigned)(n > 0 ? n : 0));
  rc = n > 0 ? uv_write2(&w->req, &c->h.stream, &b, 1, (uv_stream_t *)&w->fdpipe, on_fd_written)
             : UV_EINVAL;
  if (rc < 0) {
    w->fdpipe.data = w;
    uv_close((uv_handle_t *)&w->fdpipe, on_fdpipe_closed);
    hfd_seg_drop(s, g);
    s->protocol_errors++; /* no variant to count it against */
    send_error(c, 0, HFP_E_INTERNAL, 0, "cannot pass the segment: %s", uv_strerror(rc));
    return;
  }
  writing_one(c, (uint64_t)n);
  /* Until this SHM_CREATED is written the connection reads nothing more:
   * its descriptor stays open in the daemon as long as the write waits, and
   * a client that asked for segment after segment without reading the
   * answers would otherwise hold 16 descriptors per connection, enough to
   * exhaust the daemon's open-file limit (every new connection then
   * refused unseen, every memfd_create failing). One at a time bounds it to
   * two per connection, its socket and one segment's; a client that never
   * reads is closed by the sweep, its replies unread. */
  c->fd_sending = 1;
  read_stop(c);
  g->next = c->segs;
  c->segs = g;
  c->num_segs++;
  hfd_debug("conn %llu: segment %u of %llu bytes", (unsigned long long)c->id, g->id,
            (unsigned long long)bytes);
}

/* Pinning a segment takes milliseconds (hfd_seg_pin), which on the loop
 * thread every other connection would wait, and a client creating and
 * destroying segments in a loop could make the loop do little else. So
 * it runs on libuv's thread pool; meanwhile the connection reads nothing
 * more (its later requests, and their replies, stay behind SHM_CREATED),
 * and it is not freed (conn_release waits for pin_wait). */
typedef struct pin_req {
  uv_work_t req;
  hfd_conn *c;
  hfd_seg *g;
  int fd;
  uint64_t bytes;
  int rc;
} pin_req;

static void pin_work(uv_work_t *req) {
  pin_req *p = req->data;
  p->rc = hfd_seg_pin(p->c->srv, p->g);
}

static void pin_done(uv_work_t *req, int status) {
  pin_req *p = req->data;
  hfd_conn *c = p->c;
  hfd_server *s = c->srv;
  c->pin_wait = 0;
  s->pins_outstanding--;
  /* UV_ECANCELED (never asked for here): it never ran, nothing is pinned. */
  if (status < 0)
    p->g->registered = 0;
  else
    hfd_seg_pinned(s, p->g, p->rc);
  if (c->closing || c->fatal_sent) {
    close(p->fd);
    hfd_seg_drop(s, p->g);
    free(p);
    conn_release(c);
  } else {
    shm_created(c, p->g, p->fd, p->bytes);
    free(p);
    /* Not while replies are unread (wrote_one restarts it then), nor while
     * the descriptor waits to be written (on_fd_written does). */
    read_resume(c);
  }
  /* A drain that waited for this pin may finish now. */
  hfd_maybe_finish(s);
}

static void shm_create(hfd_conn *c) {
  hfd_server *s = c->srv;
  uint64_t bytes;
  if (hfp_decode_shm_create(c->ctl, c->want, &bytes)) {
    s->protocol_errors++; /* no variant to count it against */
    send_error(c, 0, HFP_E_INVALID, 0, "segment size must be at least 1 byte");
    return;
  }
  /* The size before the count: a segment over the whole budget, or over
   * a connection's, is TOO_LARGE (hfd_seg_create) also on a connection
   * holding 16, since no release can make it fit, where BUSY would ask
   * for a retry. */
  if (c->num_segs >= HFD_MAX_SEGMENTS && bytes <= hfd_shm_segment_max(s)) {
    s->protocol_errors++; /* no variant to count it against */
    send_error(c, 0, HFP_E_BUSY, 0, "at most %d segments per connection", HFD_MAX_SEGMENTS);
    return;
  }
  char why[HFP_MESSAGE_MAX + 1];
  hfd_seg *g;
  int fd;
  int code = hfd_seg_create(s, c, bytes, &g, &fd, why, sizeof why);
  if (code) {
    s->protocol_errors++; /* no variant to count it against */
    send_error(c, 0, code, 0, "%s", why);
    return;
  }
  if (s->worker.backend) {
    pin_req *p = calloc(1, sizeof *p);
    if (p) {
      *p = (pin_req){.c = c, .g = g, .fd = fd, .bytes = bytes};
      p->req.data = p;
      if (uv_queue_work(s->loop, &p->req, pin_work, pin_done) == 0) {
        read_stop(c);
        c->pin_wait = 1;
        s->pins_outstanding++;
        return;
      }
      free(p);
    }
    /* No thread to hand it to: pinned here, as it was always safe to. */
    hfd_seg_pinned(s, g, hfd_seg_pin(s, g));
  }
  shm_created(c, g, fd, bytes);
}

static void shm_destroy(hfd_conn *c) {
  hfd_server *s = c->srv;
  uint32_t id = 0;
  hfd_seg **pp = &c->segs;
  if (hfp_decode_shm_destroy(c->ctl, c->want, &id) == 0)
    for (; *pp; pp = &(*pp)->next)
      if ((*pp)->id == id) break;
  if (!id || !*pp) {
    s->protocol_errors++; /* no variant to count it against */
    send_error(c, 0, HFP_E_INVALID, 0, "no segment %u on this connection", id);
    return;
  }
  hfd_seg *g = *pp;
  *pp = g->next;
  c->num_segs--;
  /* Frames still running on it keep it mapped until they are answered. */
  hfd_seg_drop(c->srv, g);
}

static void on_control(hfd_conn *c) {
  if (!c->hello_done && c->hdr.type != HFP_HELLO) {
    /* on_header lets nothing else through; this says so once more where
     * the replies are made. */
    c->srv->protocol_errors++;
    send_error(c, 0, HFP_E_PROTOCOL, 1, "HELLO must come first");
    return;
  }
  switch (c->hdr.type) {
    case HFP_HELLO: reply_hello(c, c->ctl, c->want); break;
    case HFP_LIST_VARIANTS: reply_variants(c); break;
    case HFP_STATS: reply_stats(c); break;
    case HFP_SHM_CREATE: shm_create(c); break;
    case HFP_SHM_DESTROY: shm_destroy(c); break;
    case HFP_CANCEL:
      /* A frame queued is answered CANCELLED through the worker's
       * completions, as any frame; one running, answered or unknown is
       * left as it is: a CANCEL has no reply of its own. */
      if (hfd_worker_cancel_frame(&c->srv->worker, c, c->hdr.request_id))
        hfd_debug("conn %llu request %u: cancelled in the queue", (unsigned long long)c->id,
                  c->hdr.request_id);
      break;
  }
  if (!c->fatal_sent && !c->closing) read_next(c);
}

static void read_next(hfd_conn *c) {
  c->rstate = RD_HEADER;
  c->want = HFP_HEADER_SIZE;
  c->got = 0;
}

/* ---- libuv callbacks -------------------------------------------------- */

static void on_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf) {
  hfd_conn *c = h->data;
  (void)suggested;
  size_t left;
  switch (c->rstate) {
    case RD_HEADER:
      *buf = uv_buf_init((char *)c->hbuf + c->got, (unsigned)(c->want - c->got));
      return;
    case RD_CONTROL:
    case RD_FILTER_HEAD:
      *buf = uv_buf_init((char *)c->ctl + c->got, (unsigned)(c->want - c->got));
      return;
    case RD_FILTER_DATA:
      left = c->want - c->got;
      if (left > RECV_CHUNK) left = RECV_CHUNK;
      *buf = uv_buf_init((char *)c->job->input + c->got, (unsigned)left);
      return;
    case RD_DISCARD:
      left = c->discard_left < sizeof c->sink ? (size_t)c->discard_left : sizeof c->sink;
      *buf = uv_buf_init((char *)c->sink, (unsigned)left);
      return;
  }
}

/* The peer shut down its sending side (PROTOCOL.md, "Transport"): what it
 * was in the middle of sending is dropped, what was admitted is still
 * answered, and the connection closes once the last reply is out. */
static void on_eof(hfd_conn *c) {
  if (mid_frame(c) && !c->fatal_sent) {
    if (log_allowed())
      {
        char kv[300];
        hfd_log("peer left in the middle of a frame%s", conn_kv(c, kv, sizeof kv));
      }
    if (c->job) {
      job_free(c->srv, c->job);
      c->job = NULL;
    }
  }
  c->eof = 1;
  handshake_over(c);
  read_next(c);
  if (c->fatal_sent) return;   /* closing after its ERROR anyway */
  conn_idle_check(c);
}

static void conn_idle_check(hfd_conn *c) {
  if (c->eof && c->inflight == 0 && !c->closing && !c->shutting) hfd_conn_shutdown(c);
}

static void on_read(uv_stream_t *stream, ssize_t nread, const uv_buf_t *buf) {
  hfd_conn *c = stream->data;
  hfd_server *s = c->srv;
  (void)buf;
  if (nread == 0) return;
  if (nread == UV_EOF) {
    on_eof(c);
    return;
  }
  if (nread < 0) {
    hfd_debug("conn %llu: read: %s", (unsigned long long)c->id, uv_strerror((int)nread));
    if (mid_frame(c) && log_allowed())
      {
        char kv[300];
        hfd_log("peer left in the middle of a frame%s", conn_kv(c, kv, sizeof kv));
      }
    hfd_conn_close(c);
    return;
  }
  if (c->fatal_sent || c->closing) return;
  if (c->is_pipe && uv_pipe_pending_count(&c->h.pipe) > 0) {
    /* Descriptors only go from server to client; libuv closes the queued
     * ones with the connection. Every Unix connection is read as an IPC
     * pipe for this, also with shared memory disabled: otherwise the
     * kernel would drop the descriptor unseen and the rule would hold only
     * where segments are offered. */
    s->protocol_errors++;
    send_error(c, 0, HFP_E_PROTOCOL, 1, "clients may not send file descriptors");
    return;
  }
  double now = hfd_now_us();
  size_t n = (size_t)nread;
  if (!mid_frame(c)) {
    /* A frame starts: its receive rate is measured from here. */
    c->t_window = now;
    c->window_bytes = 0;
  }
  c->t_last_read = now;
  c->window_bytes += n;
  if (c->rstate == RD_DISCARD) {
    c->discard_left -= n;
    if (c->discard_left == 0) read_next(c);
    return;
  }
  c->got += n;
  if (c->rstate == RD_FILTER_DATA) {
    /* The tensor is charged as it arrives. Past the budget, the frame is
     * refused here, before more of it comes. */
    hfd_job *j = c->job;
    s->mem_held += n;
    j->bytes_held += n;
    hfd_rpool_charge(&s->rpool, j->input, n);
    int fits = mem_fits_for(c, 0);
    if (fits < 0) return;
    if (!fits) {
      int v = j->variant;
      uint64_t left = (uint64_t)c->want - c->got;
      c->job = NULL;
      job_free(s, j);
      reject(c, v, HFP_E_BUSY, left,
             "request memory full while receiving the frame (%llu of %llu MiB in use, "
             "--max-memory-mb); retry later", (unsigned long long)(mem_committed(s) >> 20),
             (unsigned long long)(s->cfg->max_memory_bytes >> 20));
      return;
    }
  }
  if (c->got < c->want) return;
  switch (c->rstate) {
    case RD_HEADER: on_header(c); break;
    case RD_CONTROL: on_control(c); break;
    case RD_FILTER_HEAD: filter_head(c, c->got); break;
    case RD_FILTER_DATA: filter_admit(c); break;
    case RD_DISCARD: break;
  }
}

static void on_closed(uv_handle_t *h) {
  hfd_conn *c = h->data;
  hfd_server *s = c->srv;
  if (c->prev)
    c->prev->next = c->next;
  else
    s->conns = c->next;
  if (c->next)
    c->next->prev = c->prev;
  else
    s->conns_tail = c->prev;
  s->num_conns--;
  /* Writes TLS still held complete now, before the release below. */
  hfd_tls_conn_closing(c);
  c->handle_closed = 1;
  char kv[300];
  hfd_debug("connection closed%s", conn_kv(c, kv, sizeof kv));
  conn_release(c);
  hfd_maybe_finish(s);
}

void hfd_conn_close(hfd_conn *c) {
  if (c->closing) return;
  c->closing = 1;
  handshake_over(c);
  if (c->job) {
    /* A FILTER was half received: drop it, nothing else is affected. */
    job_free(c->srv, c->job);
    c->job = NULL;
  }
  while (c->segs) {
    hfd_seg *g = c->segs;
    c->segs = g->next;
    hfd_seg_drop(c->srv, g);
  }
  c->num_segs = 0;
  /* Its frames still queued would run for no one (deliver drops their
   * results) while other clients are refused BUSY for the places. */
  if (c->inflight > 0) {
    int n = hfd_worker_drop_conn(&c->srv->worker, c);
    char kv[300];
    if (n > 0 && log_allowed())
      hfd_log("%d queued frame%s dropped unrun, the connection gone%s", n, n == 1 ? "" : "s",
              conn_kv(c, kv, sizeof kv));
  }
  uv_close(&c->h.handle, on_closed);
}

/* Every reply is handed to the kernel and the end of stream sent. A TCP
 * peer of a stopping server that was still sending then may have bytes on
 * their way, and closing with received bytes unread sends a reset, which
 * throws away the replies the peer has not read yet (see HFD_LINGER_MS):
 * such a connection stays open, dropping what arrives, until the peer
 * closes its side, or until --flush-timeout-ms closes every connection. */
static void on_shutdown(uv_shutdown_t *req, int status) {
  hfd_conn *c = req->data;
  free(req);
  c->writes_pending--;
  if (status == 0 && c->srv->stopped && c->flush_sending && !c->eof && !c->is_pipe &&
      !c->closing)
    c->flushed = 1;
  else
    hfd_conn_close(c);
  conn_release(c);
}

/* What a peer sends while the stopping server flushes its replies: dropped
 * unread, so that a peer blocked writing a frame (a client that reads only
 * between frames, as libhairfilter does) gets it out and goes on to read
 * its replies. With reading stopped the two would wait on each other
 * until --flush-timeout-ms and the replies would be lost. The peer's end
 * of stream ends the reading only, until the replies are out. */
static void flush_read(uv_stream_t *stream, ssize_t nread, const uv_buf_t *buf) {
  hfd_conn *c = stream->data;
  (void)buf;
  if (nread > 0) {
    c->flush_sending = 1;
  } else if (nread == UV_EOF) {
    c->eof = 1;
    if (c->flushed)
      hfd_conn_close(c);
    else
      read_stop(c);
  } else if (nread < 0) {
    hfd_conn_close(c); /* the peer is gone: nothing more can reach it */
  }
}

/* Flushes what is written, then closes. */
void hfd_conn_shutdown(hfd_conn *c) {
  if (c->lingering) {
    hfd_conn_close(c); /* its ERROR is out; the server is stopping */
    return;
  }
  if (c->closing || c->shutting) return;
  c->shutting = 1;
  if (c->srv->stopped && !c->eof) {
    c->flush_sending = mid_frame(c);
    if (c->job) {
      /* A FILTER half received: never to be answered (SERVER.md, "Shutdown"). */
      job_free(c->srv, c->job);
      c->job = NULL;
    }
    read_stop(c); /* uv_read_start refuses a stream that is reading */
    int rc = hfd_io_read_start(c, linger_alloc, flush_read);
    if (rc < 0)
      hfd_debug("conn %llu: read start: %s", (unsigned long long)c->id, uv_strerror(rc));
  } else {
    read_stop(c);
  }
  handshake_over(c);
  uv_shutdown_t *req = malloc(sizeof *req);
  if (!req) {
    hfd_conn_close(c);
    return;
  }
  req->data = c;
  if (hfd_io_shutdown(c, req, on_shutdown) < 0) {
    free(req);
    hfd_conn_close(c);
    return;
  }
  c->writes_pending++;
}

/* Deadlines, checked a few times per timeout (hairfilterd.c starts the
 * timer): a peer that has not completed its HELLO within the handshake
 * timeout, one silent for the stall timeout in the middle of a frame, one
 * whose frame arrives slower than the minimum rate over a stall-timeout
 * window, and one that has not read any of its waiting replies for the
 * stall timeout. Trickling a byte now and then holds a slot no longer than
 * these allow. */
void hfd_sweep_stalled(hfd_server *s) {
  const hfd_config *cfg = s->cfg;
  double now = hfd_now_us(), stall_us = cfg->stall_timeout_ms * 1e3;
  for (hfd_conn *c = s->conns, *next; c; c = next) {
    next = c->next;
    if (c->closing) continue;
    if (c->lingering) {
      if (now - c->t_linger > HFD_LINGER_MS * 1e3) hfd_conn_close(c);
      continue;
    }
    /* Replies waiting: has the peer read any of them lately? */
    if (c->writes_pending && stall_us > 0) {
      uint64_t written = bytes_written(c);
      if (written != c->written_seen) {
        c->written_seen = written;
        c->t_write = now;
      } else if (now - c->t_write > stall_us) {
        if (log_allowed())
          {
          char kv[300];
          hfd_log("replies unread for %d ms; closing%s", cfg->stall_timeout_ms,
                  conn_kv(c, kv, sizeof kv));
        }
        hfd_conn_close(c);
        continue;
      }
      /* And fast enough? A peer that reads a few bytes now and then would
       * otherwise hold its unread RESULTs, charged to --max-memory-mb,
       * for as long as it likes, and every other client would get BUSY:
       * the reading side of --min-recv-rate's trickle. Measured over each
       * --stall-timeout-ms window in which bytes stayed queued in the
       * daemon (the kernel's socket buffer full); a window starts afresh
       * whenever the kernel has taken every byte (read_window_start). */
      if (hfd_io_write_queue_size(c) == 0) {
        read_window_start(c, now);
      } else if (now - c->t_rwin >= stall_us) {
        double rate = (double)(written - c->rwin_written) / ((now - c->t_rwin) / 1e6);
        if (cfg->min_recv_rate && rate < (double)cfg->min_recv_rate) {
          if (log_allowed()) {
            char kv[300];
            hfd_log("replies read at %.3g bytes/s, under the minimum of %llu KiB/s "
                    "(--min-recv-rate); closing%s", rate,
                    (unsigned long long)(cfg->min_recv_rate >> 10), conn_kv(c, kv, sizeof kv));
          }
          hfd_conn_close(c);
          continue;
        }
        read_window_start(c, now);
      }
    }
    if (hfd_tls_overdue(c, now)) {
      hfd_conn_close(c);
      continue;
    }
    if (c->fatal_sent || c->shutting || c->eof) continue;
    if (!c->hello_done && cfg->handshake_timeout_ms > 0 &&
        now - c->t_accept > cfg->handshake_timeout_ms * 1e3) {
      s->protocol_errors++;
      send_error(c, 0, HFP_E_PROTOCOL, 1, "no complete HELLO within %d ms",
                 cfg->handshake_timeout_ms);
      continue;
    }
    /* While reading is paused for unread replies, the peer is not late.
     * Before HELLO the handshake deadline is the bound, when there is one. */
    if (!mid_frame(c) || c->read_paused || stall_us <= 0) continue;
    if (!c->hello_done && cfg->handshake_timeout_ms > 0) continue;
    uint32_t id = c->rstate != RD_HEADER && c->hdr.type == HFP_FILTER ? c->hdr.request_id : 0;
    if (now - c->t_last_read > stall_us) {
      s->protocol_errors++;
      send_error(c, id, HFP_E_PROTOCOL, 1, "no data for %d ms in the middle of a frame",
                 cfg->stall_timeout_ms);
    } else if (now - c->t_window >= stall_us) {
      double rate = c->window_bytes / ((now - c->t_window) / 1e6);
      if (cfg->min_recv_rate && rate < (double)cfg->min_recv_rate) {
        s->protocol_errors++;
        send_error(c, id, HFP_E_PROTOCOL, 1,
                   "frame arriving at %.3g bytes/s, under the minimum of %llu KiB/s", rate,
                   (unsigned long long)(cfg->min_recv_rate >> 10));
      } else {
        c->t_window = now;
        c->window_bytes = 0;
      }
    }
  }
}

/* Whether c's socket already holds its whole HELLO, none of it read yet.
 * The connections waiting in the backlog are accepted in one turn of the
 * loop (up to HFD_ACCEPTS_PER_TURN, below), before any of them is read
 * from: in a burst of connections a client that sent its HELLO at once is
 * among the oldest before the server has read a byte of it. A peek tells
 * it from the silent ones. Not over TLS, whose bytes are records. */
static int hello_waiting(hfd_conn *c) {
  if (c->tls || c->rstate != RD_HEADER || c->got) return 0;
  uv_os_fd_t fd;
  if (uv_fileno(&c->h.handle, &fd) != 0) return 0;
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  ssize_t n = recv(fd, b, sizeof b, MSG_PEEK | MSG_DONTWAIT);
  if (n < HFP_HEADER_SIZE) return 0;   /* nothing, part of a header, or an error */
  hfp_header h;
  if (hfp_header_decode(b, 8 + HFP_NAME_MAX + HFP_TOKEN_MAX, &h) != 0 || h.type != HFP_HELLO)
    return 0;
  return (size_t)n >= HFP_HEADER_SIZE + (size_t)h.length;
}

/* Whether c's peer has closed (or reset) its end with nothing unread: in a
 * storm of connect-and-close peers, the loop accepts a burst before it
 * reads the closes, and the one --max-handshakes would push out is often
 * gone already. Such a one is closed without an ERROR (nobody would read
 * it) and is not counted in protocol_errors: no client did anything wrong.
 * Looked at for the chosen connection only. */
static int hung_up(hfd_conn *c) {
  uv_os_fd_t fd;
  if (uv_fileno(&c->h.handle, &fd) != 0) return 0;
  uint8_t b;
  ssize_t n = recv(fd, &b, 1, MSG_PEEK | MSG_DONTWAIT);
  return n == 0 || (n < 0 && (errno == ECONNRESET || errno == EPIPE || errno == ENOTCONN));
}

/* A connection before its HELLO that --max-handshakes may refuse. */
static int refusable(const hfd_conn *c) {
  return c->handshaking && !c->closing && !c->fatal_sent;
}

/* The connection to refuse at --max-handshakes: the oldest still before
 * its HELLO whose HELLO has not arrived whole, so that a crowd arriving in
 * one burst does not push out a client whose HELLO is waiting to be read.
 * NULL when every one's has: none is refused, as each leaves the count
 * when its HELLO is read, on the loop's next turn (a HELLO that is not
 * accepted closes its connection at once), so the excess lasts a turn and
 * --max-connections still bounds it; refusing the oldest instead would let
 * a crowd sending bogus HELLOs push out a real one. Once seen, a waiting
 * HELLO is remembered: it is read before anything else arrives.
 *
 * Over TLS a HELLO is not seen before the handshake, which takes the
 * client round trips: a crowd of bare TCP connections, each cheaper than a
 * real client's, would push it out in the middle. So on a TLS listener a
 * peer the server has not answered goes first (nothing sent, or less than
 * a ClientHello: a byte costs a peer no more than silence), the oldest of
 * them (not the newest connection, fresh, just accepted, which has had no
 * time to send one); then the
 * oldest of the rest, passing over one whose socket holds a whole TLS
 * record not read yet (its ClientHello in a burst, or the flight that
 * ends its handshake). That is forgotten once the record is read: it
 * moves the handshake on but need not end it. */
static hfd_conn *oldest_handshake(hfd_server *s, const hfd_conn *fresh) {
  /* Oldest first (s->conns is newest first, in the order of accepting),
   * so that the first that qualifies is the one, and a crowd of
   * connections costs a walk of flags, not a look into every socket for
   * each connection accepted: that was the loop's main work under a flood
   * of connections (the socket is looked into once, for the oldest
   * candidates only, and a whole record or HELLO seen there is
   * remembered until it is read). */
  for (hfd_conn *c = s->conns_tail; c; c = c->prev)
    if (refusable(c) && c->tls && c != fresh && hfd_tls_unanswered(c)) return c;
  for (hfd_conn *c = s->conns_tail; c; c = c->prev) {
    if (!refusable(c) || c->hello_waiting) continue;
    if (c->tls) {
      if (!hfd_tls_record_waiting(c)) return c;
    } else {
      if (!hello_waiting(c)) return c;
      c->hello_waiting = 1;
    }
  }
  return NULL;
}

/* The connection to refuse when k, an IP address, holds more connections
 * before their HELLO than --max-handshakes-per-address: the one
 * oldest_handshake would pick among k's own (older than fresh, the one
 * just accepted), else fresh itself. Per connection, a peer that replays a
 * ClientHello on new connections made them all answered and stalled, and
 * the oldest of those was another address's client in the middle of its
 * handshake; among its own it pushes out only itself, and when each of
 * its older ones has a record or HELLO waiting (a burst) its newest goes
 * at once, before it costs a handshake, so it holds no more slots than
 * its part and queues no more handshake steps than that. */
static hfd_conn *address_handshake_victim(hfd_server *s, const hfd_client *k, hfd_conn *fresh) {
  for (hfd_conn *c = s->conns_tail; c; c = c->prev)
    if (c->client == k && c != fresh && refusable(c) && c->tls && hfd_tls_unanswered(c))
      return c;
  for (hfd_conn *c = s->conns_tail; c; c = c->prev) {
    if (c->client != k || c == fresh || !refusable(c) || c->hello_waiting) continue;
    if (c->tls) {
      if (!hfd_tls_record_waiting(c)) return c;
    } else {
      if (!hello_waiting(c)) return c;
      c->hello_waiting = 1;
    }
  }
  return fresh;
}

/* A connection refused before its HELLO (the connection limit, or pushed
 * out by --max-handshakes) closes now, not when its ERROR's write
 * completes on a later turn of the loop: in a burst of connections libuv
 * accepts one after another in a single turn, and refused ones that stayed
 * open until then would hold a slot and a descriptor each, refusing the
 * rest of the burst and running the daemon out of descriptors (a
 * connection libuv cannot get one for is dropped without a word). The
 * ERROR is in the kernel already when its write left nothing queued (a
 * fresh socket takes it whole); over TLS it waits for the handshake
 * (reclaim_slot). */
static void close_refused(hfd_conn *c) {
  if (!c->closing && !c->tls && hfd_io_write_queue_size(c) == 0) hfd_conn_close(c);
}

/* Makes room for one more connection at --max-connections, when it can:
 * connections already closing do not count, and a TLS connection holding a
 * fatal ERROR until its handshake is done (pushed out by --max-handshakes,
 * or past the handshake deadline) gives its slot up, the oldest first, and
 * is closed without the ERROR (no TLS session could carry it yet). Peers
 * that open TCP connections to a TLS listener and never finish a handshake
 * cannot fill the slots that way. 1 when the newest connection may stay. */
static int reclaim_slot(hfd_server *s) {
  int live = 0;
  for (hfd_conn *c = s->conns; c; c = c->next) live += !c->closing;
  while (live > s->max_connections) {
    hfd_conn *old = NULL;
    for (hfd_conn *c = s->conns; c; c = c->next)
      if (c->tls && c->fatal_sent && !c->closing && !hfd_tls_established(c) &&
          (!old || c->t_accept < old->t_accept))
        old = c;
    if (!old) return 0;
    hfd_conn_close(old);
    live--;
  }
  return 1;
}

/* At --max-connections, with no slot to reclaim: the oldest connection
 * still before its HELLO whose HELLO has not arrived (as --max-handshakes
 * picks, oldest_handshake) goes for fresh, the newest. Peers that connect
 * and say nothing could otherwise hold every slot wherever
 * --max-handshakes is not below --max-connections (its default 32 beside
 * --max-connections 6), and each client after them got BUSY for the
 * connection limit; a connection that has said HELLO, or whose HELLO is
 * waiting to be read, is never the one. 1 when fresh may stay. */
static int push_out_silent(hfd_server *s, hfd_conn *fresh) {
  hfd_conn *old = oldest_handshake(s, fresh);
  if (!old) return 0;
  if (!hung_up(old)) {
    s->protocol_errors++;
    char kv[300];
    if (hfd_conn_log_allowed())
      hfd_err("connection limit (%d) reached: closing the oldest connection that has not said "
              "HELLO for a new one%s", s->max_connections, conn_kv(old, kv, sizeof kv));
    if (!old->tls)
      send_error(old, 0, HFP_E_BUSY, 1,
                 "connection limit (%d) reached: the oldest connection without its HELLO is "
                 "closed for a newer one", s->max_connections);
  }
  /* Now, not once an ERROR is written: the slot is fresh's (over TLS
   * without a word, no session to carry one yet). */
  hfd_conn_close(old);
  return 1;
}

/* Connections accepted in one turn of the loop before the others get a
 * turn. libuv accepts from a listener until the backlog is empty, with no
 * other I/O between: peers that connect as fast as the daemon can accept
 * and refuse them (no HELLO, no token needed) would hold the loop in that
 * accept loop, and every other connection, its HELLO, its requests and its
 * results, would wait as long as they kept at it. Past this many, the next
 * connection is left pending (libuv stops watching the listener until it
 * is accepted) and taken at the end of the turn (hfd_on_accept_check),
 * after the rest of the turn's I/O. */
#define HFD_ACCEPTS_PER_TURN 64

void hfd_on_accept_check(uv_check_t *h) {
  hfd_server *s = h->data;
  s->accepts_in_turn = 0;
  int rc = uv_check_stop(h);
  if (rc < 0) hfd_err("accept check stop: %s", uv_strerror(rc));
  for (int i = 0; i < s->num_listeners; i++) {
    hfd_listener *l = &s->listeners[i];
    if (!l->accept_deferred) continue;
    l->accept_deferred = 0;
    /* A listener closed meanwhile (a drain) closes its pending connection. */
    if (!uv_is_closing(&l->h.handle)) hfd_on_connection(&l->h.stream, 0);
  }
}

void hfd_on_connection(uv_stream_t *server, int status) {
  hfd_listener *l = server->data;
  hfd_server *s = l->srv;
  if (status < 0) {
    hfd_err("accept on %s: %s", l->url, uv_strerror(status));
    return;
  }
  if (s->accepts_in_turn >= HFD_ACCEPTS_PER_TURN) {
    int rc = uv_check_start(&s->accept_check, hfd_on_accept_check);
    if (rc == 0) {
      l->accept_deferred = 1;   /* not accepted: libuv keeps it and stops listening */
      return;
    }
    hfd_err("accept check start: %s; accepting on", uv_strerror(rc));
  }
  s->accepts_in_turn++;
  hfd_conn *c = calloc(1, sizeof *c);
  if (!c) {
    hfd_err("out of memory for a connection on %s", l->url);
    return;
  }
  c->srv = s;
  c->listener = l;
  /* Unix connections are IPC pipes so that segment fds can be passed, and
   * so that a descriptor a client sends is seen and refused. */
  c->is_pipe = !l->is_tcp;
  c->is_ipc = c->is_pipe && s->cfg->max_shm_bytes > 0;
  int rc = l->is_tcp ? uv_tcp_init(s->loop, &c->h.tcp)
                     : uv_pipe_init(s->loop, &c->h.pipe, c->is_pipe);
  if (rc < 0) {
    hfd_err("%s: handle init: %s", l->url, uv_strerror(rc));
    free(c);
    return;
  }
  c->h.handle.data = c;
  c->id = ++s->next_conn_id;
  c->next = s->conns;
  if (s->conns)
    s->conns->prev = c;
  else
    s->conns_tail = c;
  s->conns = c;
  s->num_conns++;
  s->conns_total++;
  c->t_accept = c->t_last_read = c->t_window = hfd_now_us();
  rc = uv_accept(server, &c->h.stream);
  if (rc < 0) {
    hfd_err("accept on %s: %s", l->url, uv_strerror(rc));
    hfd_conn_close(c);
    return;
  }
  hfd_client_join(s, c);
  if (l->is_tls && (rc = hfd_tls_conn_start(c)) < 0) {
    hfd_err("conn %llu: TLS session: %s", (unsigned long long)c->id, uv_strerror(rc));
    hfd_conn_close(c);
    return;
  }
  if (l->is_tcp) {
    struct sockaddr_storage ss;
    int len = sizeof ss;
    char ip[48] = "?";  /* INET6_ADDRSTRLEN */
    if (uv_tcp_getpeername(&c->h.tcp, (struct sockaddr *)&ss, &len) == 0) {
      int v6 = ss.ss_family == AF_INET6;
      int nr = v6 ? uv_ip6_name((struct sockaddr_in6 *)&ss, ip, sizeof ip)
                  : uv_ip4_name((struct sockaddr_in *)&ss, ip, sizeof ip);
      if (nr == 0)
        snprintf(c->peer, sizeof c->peer, v6 ? "[%s]:%d" : "%s:%d", ip,
                 ntohs(v6 ? ((struct sockaddr_in6 *)&ss)->sin6_port
                          : ((struct sockaddr_in *)&ss)->sin_port));
    }
    if (!c->peer[0]) snprintf(c->peer, sizeof c->peer, "tcp");
    /* Replies are written whole; Nagle would only delay their last segment. */
    rc = uv_tcp_nodelay(&c->h.tcp, 1);
    if (rc < 0) hfd_err("conn %llu: TCP_NODELAY: %s", (unsigned long long)c->id, uv_strerror(rc));
  } else {
    snprintf(c->peer, sizeof c->peer, "unix");
    if (c->is_ipc) hfd_shm_client_join(s, c);   /* -1: its own client, logged */
  }
  char kv[300];
  conn_kv(c, kv, sizeof kv);
  hfd_kv(kv, sizeof kv, "listener", l->url);
  hfd_debug("connection accepted%s", kv);
  read_next(c);
  if (s->num_conns > s->max_connections && !reclaim_slot(s) && !push_out_silent(s, c)) {
    s->protocol_errors++;
    if (c->tls) {
      /* No TLS session yet to carry the ERROR; one queued for after the
       * handshake would hold the slot for the handshake's deadline. */
      hfd_conn_close(c);
      return;
    }
    send_error(c, 0, HFP_E_BUSY, 1, "connection limit (%d) reached", s->max_connections);
    close_refused(c);
    return;
  }
  c->handshaking = 1;
  s->num_handshaking++;
  if (l->is_tcp && ++c->client->handshaking > hfd_client_handshake_cap(s) &&
      hfd_client_handshake_cap(s) < s->cfg->max_handshakes) {
    /* One address may hold only its part of the slots, so that a flood
     * from it cannot push out the clients of others (address_handshake_victim).
     * A part as large as the whole is no part: --max-handshakes decides. */
    hfd_conn *old = address_handshake_victim(s, c->client, c);
    if (hung_up(old)) {
      hfd_conn_close(old);
      if (old == c) return;
    } else {
      s->protocol_errors++;
      char kv[300];
      if (hfd_conn_log_allowed())
        hfd_err("too many connections before their HELLO from %s (--max-handshakes-per-address "
                "%d); closing the %s%s", c->client->name, hfd_client_handshake_cap(s),
                old == c ? "newest" : "oldest", conn_kv(old, kv, sizeof kv));
      if (old->tls) {
        /* Closed without a word: an ERROR would wait for a handshake, which
         * is what the address has too many of. Its step, if queued, is
         * skipped. */
        hfd_conn_close(old);
      } else {
        send_error(old, 0, HFP_E_BUSY, 1,
                   "too many connections before their HELLO from %s "
                   "(--max-handshakes-per-address %d)", c->client->name,
                   hfd_client_handshake_cap(s));
        close_refused(old);
      }
      if (old == c) return;
    }
  }
  if (s->num_handshaking > s->cfg->max_handshakes) {
    /* Connections that have not said HELLO have their own small limit, so
     * that they cannot take every slot. A real client says HELLO at once;
     * the one that has waited longest is the likeliest not to, and goes. */
    hfd_conn *old = oldest_handshake(s, c);
    if (old && hung_up(old)) {
      hfd_conn_close(old);
      if (old == c) return;
    } else if (old) {
      s->protocol_errors++;
      /* Over TLS the ERROR waits for the handshake (a client racing its
       * handshake sees why it was refused); until then reclaim_slot may
       * take the connection's slot for a newcomer. */
      send_error(old, 0, HFP_E_BUSY, 1, "too many connections before their HELLO (%d)",
                 s->cfg->max_handshakes);
      close_refused(old);
      if (old == c) return;
    }
  }
  rc = hfd_io_read_start(c, on_alloc, on_read);
  if (rc < 0) {
    hfd_err("conn %llu: read start: %s", (unsigned long long)c->id, uv_strerror(rc));
    hfd_conn_close(c);
  }
}
