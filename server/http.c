/*
 * The operator's HTTP endpoint (--http tcp:HOST:PORT), on libmicrohttpd
 * (Debian's libmicrohttpd-dev): HTTP parsing is that library's, and it runs
 * on a thread of its own (MHD_USE_INTERNAL_POLLING_THREAD), so a slow
 * scraper never delays a frame.
 *
 *   GET /metrics   Prometheus text format (metrics.c)
 *   GET /healthz   200 while the event loop and the inference worker make
 *                  progress, else 503 naming which one stalled and for how
 *                  long (--watchdog-ms): the liveness probe
 *   GET /readyz    200 while serving: the backend up, every configured
 *                  weights file serving a variant, not draining; else 503
 *                  with why: the readiness probe
 *
 * Slots: the endpoint keeps HTTP_SLOTS connections. A crowd of silent,
 * trickling or slowly reading peers must not shut the liveness probe out
 * (libmicrohttpd's own limit refuses the newest connection, and a byte a
 * second keeps its idle timeout from firing), so when one more arrives the
 * oldest is shut down, as the protocol port does with handshakes (conn.c).
 * Every reply closes its connection ("Connection: close"), so the oldest is
 * the one that has waited longest for its answer. libmicrohttpd's limit
 * stays above ours, room to accept while the evicted ones close.
 *
 * Threads: everything a request is about belongs to the loop thread. The
 * HTTP thread never reads it; it asks the loop for an answer (uv_async_send,
 * the one libuv call safe from another thread) and waits on a condition
 * variable, at most a few seconds, for the loop to render it. The request,
 * the answer and whether the loop still takes requests are guarded by one
 * mutex. /healthz needs no answer from the loop, so that a wedged loop is
 * reported rather than waited for: it reads two atomics, the loop's
 * heartbeat (hairfilterd.c) and the worker's progress (worker.c).
 */
#define _GNU_SOURCE
#include <microhttpd.h>
#include <errno.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "server.h"

#define ANSWER_TIMEOUT_MS 5000
#define HTTP_SLOTS 32            /* connections kept */
#define HTTP_MHD_LIMIT HFD_HTTP_CONN_LIMIT /* libmicrohttpd's hard limit: room for those closing */
#define HTTP_IDLE_TIMEOUT_S 10   /* libmicrohttpd's idle timeout */

typedef struct hfd_http hfd_http;

/* One open connection, in hfd_http's list (HTTP thread only). */
typedef struct http_conn {
  struct http_conn *prev, *next;
  int fd;
  double since;                  /* hfd_now_us when accepted */
  int evicted;                   /* shut down, not yet closed by libmicrohttpd */
  int stuck;                     /* its shutdown failed: not chosen again */
} http_conn;

struct hfd_http {
  hfd_server *s;
  struct MHD_Daemon *d;
  uv_async_t async;
  pthread_mutex_t mu;
  pthread_cond_t cv;
  /* under mu */
  uint64_t asked, answered;      /* generations of requests to the loop */
  int want_metrics;              /* the pending request needs the text */
  int loop_open;                 /* the loop still answers */
  char *text;                    /* the last rendered /metrics */
  size_t len;
  int ready;
  char why[300];
  /* HTTP thread only */
  http_conn *conns;              /* newest first */
  int live;                      /* in conns and not evicted */
  hfd_rate log_lines;            /* libmicrohttpd's warnings */
};

/* Loop thread: answers what the HTTP thread asked for. */
static void on_async(uv_async_t *a) {
  hfd_http *h = a->data;
  pthread_mutex_lock(&h->mu);
  uint64_t target = h->asked;
  int want = h->want_metrics;
  h->want_metrics = 0;
  pthread_mutex_unlock(&h->mu);
  char *text = NULL, why[300] = "";
  size_t len = 0;
  if (want && hfd_metrics_render(h->s, &text, &len)) text = NULL;
  int ready = hfd_ready(h->s, why, sizeof why);
  pthread_mutex_lock(&h->mu);
  if (want) {
    free(h->text);
    h->text = text;
    h->len = text ? len : 0;
  }
  h->ready = ready;
  snprintf(h->why, sizeof h->why, "%s", why);
  h->answered = target;
  pthread_cond_broadcast(&h->cv);
  pthread_mutex_unlock(&h->mu);
}

/* HTTP thread: asks the loop and waits for its answer (mu held). 0 when
 * answered, -1 when the loop is stopping or did not answer in time. */
static int ask_loop(hfd_http *h, int metrics) {
  if (!h->loop_open) return -1;
  uint64_t mine = ++h->asked;
  h->want_metrics |= metrics;
  /* Sent under mu: the loop closes the handle only after loop_open is 0,
   * which it sets under mu too, so the handle is open here. */
  if (uv_async_send(&h->async) < 0) return -1;
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  ts.tv_sec += ANSWER_TIMEOUT_MS / 1000;
  while (h->answered < mine && h->loop_open)
    if (pthread_cond_timedwait(&h->cv, &h->mu, &ts) != 0) break;
  return h->answered >= mine ? 0 : -1;
}

static enum MHD_Result reply(struct MHD_Connection *conn, unsigned status, const char *type,
                             char *body, size_t len) {
  struct MHD_Response *r = MHD_create_response_from_buffer(len, body, MHD_RESPMEM_MUST_FREE);
  if (!r) {
    free(body);
    return MHD_NO;
  }
  MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, type);
  MHD_add_response_header(r, MHD_HTTP_HEADER_CACHE_CONTROL, "no-store");
  /* RFC 9110, 15.5.6: a 405 says which methods the resource takes. */
  if (status == MHD_HTTP_METHOD_NOT_ALLOWED) MHD_add_response_header(r, "Allow", "GET, HEAD");
  enum MHD_Result rc = MHD_queue_response(conn, status, r);
  MHD_destroy_response(r);
  return rc;
}

static enum MHD_Result text_reply(struct MHD_Connection *conn, unsigned status,
                                  const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static enum MHD_Result text_reply(struct MHD_Connection *conn, unsigned status,
                                  const char *fmt, ...) {
  char *body = NULL;
  va_list ap;
  va_start(ap, fmt);
  int n = vasprintf(&body, fmt, ap);
  va_end(ap);
  if (n < 0) return MHD_NO;
  return reply(conn, status, "text/plain; charset=utf-8", body, (size_t)n);
}

/* Why the daemon is not alive, or "" when it is (any thread). */
static void liveness(hfd_server *s, char *why, size_t cap) {
  double limit_us = s->cfg->watchdog_ms * 1e3, stalled;
  double beat = hfd_now_us() - (double)atomic_load(&s->loop_beat_us);
  why[0] = 0;
  if (beat > limit_us)
    snprintf(why, cap, "event loop made no progress for %.1f s (--watchdog-ms %d)", beat / 1e6,
             s->cfg->watchdog_ms);
  else if (hfd_worker_stalled(&s->worker, limit_us, &stalled))
    snprintf(why, cap, "inference worker made no progress for %.1f s (--watchdog-ms %d)",
             stalled / 1e6, s->cfg->watchdog_ms);
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *conn, const char *url,
                                  const char *method, const char *version,
                                  const char *upload_data, size_t *upload_data_size,
                                  void **req_cls) {
  hfd_http *h = cls;
  (void)version;
  (void)upload_data;
  (void)req_cls;
  if (strcmp(method, MHD_HTTP_METHOD_GET) && strcmp(method, MHD_HTTP_METHOD_HEAD))
    return text_reply(conn, MHD_HTTP_METHOD_NOT_ALLOWED, "only GET and HEAD\n");
  if (*upload_data_size) return text_reply(conn, MHD_HTTP_BAD_REQUEST, "no body expected\n");
  if (!strcmp(url, "/healthz")) {
    char why[300];
    liveness(h->s, why, sizeof why);
    return why[0] ? text_reply(conn, MHD_HTTP_SERVICE_UNAVAILABLE, "unhealthy: %s\n", why)
                  : text_reply(conn, MHD_HTTP_OK, "ok\n");
  }
  int metrics = !strcmp(url, "/metrics");
  if (!metrics && strcmp(url, "/readyz"))
    return text_reply(conn, MHD_HTTP_NOT_FOUND, "not found: try /metrics, /healthz, /readyz\n");
  pthread_mutex_lock(&h->mu);
  int rc = ask_loop(h, metrics);
  char *text = NULL, why[300];
  size_t len = 0;
  int ready = h->ready;
  snprintf(why, sizeof why, "%s", h->why);
  if (!rc && metrics && h->text) {
    text = malloc(h->len);
    if (text) memcpy(text, h->text, h->len);
    len = h->len;
  }
  int open = h->loop_open;
  pthread_mutex_unlock(&h->mu);
  if (rc)
    return text_reply(conn, MHD_HTTP_SERVICE_UNAVAILABLE, "%s\n",
                      open ? "event loop did not answer in time" : "stopping");
  if (!metrics)
    return ready ? text_reply(conn, MHD_HTTP_OK, "ready\n")
                 : text_reply(conn, MHD_HTTP_SERVICE_UNAVAILABLE, "not ready: %s\n", why);
  if (!text) return text_reply(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory\n");
  return reply(conn, MHD_HTTP_OK, "text/plain; version=0.0.4; charset=utf-8", text, len);
}

/* libmicrohttpd's warnings; a peer can cause one per connection (refused
 * at its limit, a malformed request), so they share a budget per second.
 * libmicrohttpd calls this on its own thread, and on the caller's only in
 * MHD_start_daemon before that thread exists or, rarely, in
 * MHD_stop_daemon while it stops: at worst a line more or less. */
static void on_mhd_log(void *cls, const char *fmt, va_list ap) {
  hfd_http *h = cls;
  if (!hfd_rate_allow(&h->log_lines, 20, "http warning")) return;
  char msg[512];
  vsnprintf(msg, sizeof msg, fmt, ap);
  msg[strcspn(msg, "\n")] = 0;
  hfd_warn("http: %s", msg);
}

/* Shuts down the oldest live connection other than keep; libmicrohttpd
 * then sees it end and closes it (its fd is never closed here, and every
 * callback runs on libmicrohttpd's one thread, so the fd cannot be reused
 * under it). */
static void evict_oldest(hfd_http *h, const http_conn *keep) {
  http_conn *victim = NULL;
  for (http_conn *c = h->conns; c; c = c->next)
    if (c != keep && !c->evicted && !c->stuck && (!victim || c->since <= victim->since))
      victim = c;
  if (!victim) return;
  if (shutdown(victim->fd, SHUT_RDWR) != 0 && errno != ENOTCONN) {
    int e = errno;
    victim->stuck = 1;
    if (hfd_rate_allow(&h->log_lines, 20, "http warning"))
      hfd_warn("http: shutdown of a connection over the limit: %s", strerror(e));
    return;
  }
  victim->evicted = 1;
  h->live--;
  if (hfd_rate_allow(&h->log_lines, 20, "http warning"))
    hfd_warn("http: %d connections, the limit: closed the oldest, open %.1f s", HTTP_SLOTS,
             (hfd_now_us() - victim->since) / 1e6);
}

/* Connections start and close (MHD_OPTION_NOTIFY_CONNECTION). */
static void on_connection(void *cls, struct MHD_Connection *conn, void **socket_context,
                          enum MHD_ConnectionNotificationCode toe) {
  hfd_http *h = cls;
  if (toe == MHD_CONNECTION_NOTIFY_STARTED) {
    const union MHD_ConnectionInfo *ci =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CONNECTION_FD);
    http_conn *c = ci ? calloc(1, sizeof *c) : NULL;
    *socket_context = c;
    if (!c) return;  /* untracked: never evicted, closed by the idle timeout */
    c->fd = ci->connect_fd;
    c->since = hfd_now_us();
    c->next = h->conns;
    if (h->conns) h->conns->prev = c;
    h->conns = c;
    if (++h->live > HTTP_SLOTS) evict_oldest(h, c);
    return;
  }
  http_conn *c = *socket_context;
  if (!c) return;
  if (c->prev) c->prev->next = c->next;
  else h->conns = c->next;
  if (c->next) c->next->prev = c->prev;
  if (!c->evicted) h->live--;
  free(c);
  *socket_context = NULL;
}

int hfd_http_start(hfd_server *s, char *url, size_t urlcap) {
  const hfp_url *u = &s->cfg->http_url;
  const char *host = strcmp(u->host, "localhost") ? u->host : "127.0.0.1";
  struct sockaddr_storage ss;
  memset(&ss, 0, sizeof ss);
  int v6 = 0;
  if (uv_ip4_addr(host, u->port, (struct sockaddr_in *)&ss) != 0) {
    if (uv_ip6_addr(host, u->port, (struct sockaddr_in6 *)&ss) != 0) {
      hfd_err("--http %s: host must be a numeric address or localhost", s->cfg->http);
      return -1;
    }
    v6 = 1;
  }
  /* The socket is bound here rather than by libmicrohttpd, which says only
   * "Failed to bind to port 0" (the port it was given beside the address)
   * and not why in a way the operator can act on. */
  int fd = socket(v6 ? AF_INET6 : AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (fd < 0) {
    hfd_err("--http %s: socket: %s", s->cfg->http, strerror(errno));
    return -1;
  }
  int one = 1;
  /* Neither is needed to serve (a restart may wait out TIME_WAIT, an IPv6
   * address may take IPv4 too): said, not fatal. */
  if (setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one) != 0)
    hfd_warn("--http %s: SO_REUSEADDR: %s", s->cfg->http, strerror(errno));
  if (v6 && setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &one, sizeof one) != 0)
    hfd_warn("--http %s: IPV6_V6ONLY: %s", s->cfg->http, strerror(errno));
  socklen_t slen = v6 ? sizeof(struct sockaddr_in6) : sizeof(struct sockaddr_in);
  if (bind(fd, (struct sockaddr *)&ss, slen) != 0 || listen(fd, HTTP_MHD_LIMIT) != 0) {
    hfd_bind_error("--http", s->cfg->http, host, u->port, errno);
    close(fd);
    return -1;
  }
  struct sockaddr_storage bound;
  socklen_t blen = sizeof bound;
  unsigned port = u->port;
  if (getsockname(fd, (struct sockaddr *)&bound, &blen) == 0)
    port = ntohs(v6 ? ((struct sockaddr_in6 *)&bound)->sin6_port
                    : ((struct sockaddr_in *)&bound)->sin_port);
  hfd_http *h = calloc(1, sizeof *h);
  if (!h) {
    close(fd);
    return -1;
  }
  h->s = s;
  pthread_condattr_t ca;
  if (pthread_mutex_init(&h->mu, NULL) || pthread_condattr_init(&ca) ||
      pthread_condattr_setclock(&ca, CLOCK_MONOTONIC) || pthread_cond_init(&h->cv, &ca)) {
    free(h);
    close(fd);
    return -1;
  }
  pthread_condattr_destroy(&ca);
  int rc = uv_async_init(s->loop, &h->async, on_async);
  if (rc < 0) {
    hfd_err("--http: uv_async_init: %s", uv_strerror(rc));
    free(h);
    close(fd);
    return -1;
  }
  h->async.data = h;
  h->loop_open = 1;
  s->http = h;
  unsigned flags = MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_ERROR_LOG |
                   (v6 ? MHD_USE_IPv6 : 0);
  h->d = MHD_start_daemon(flags, 0, NULL, NULL, on_request, h,
                          MHD_OPTION_EXTERNAL_LOGGER, on_mhd_log, h,
                          MHD_OPTION_LISTEN_SOCKET, (MHD_socket)fd,
                          MHD_OPTION_CONNECTION_LIMIT, (unsigned)HTTP_MHD_LIMIT,
                          MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)HTTP_IDLE_TIMEOUT_S,
                          MHD_OPTION_NOTIFY_CONNECTION, on_connection, h,
                          MHD_OPTION_END);
  if (!h->d) {
    /* Its reason went to the log as an http warning (on_mhd_log); the
     * socket is left to the exit that follows, as libmicrohttpd may have
     * closed it. */
    hfd_err("--http %s: libmicrohttpd could not start on the bound socket", s->cfg->http);
    return -1;
  }
  snprintf(url, urlcap, v6 ? "http://[%s]:%u" : "http://%s:%u", host, port);
  hfd_log("http on %s: /metrics /healthz /readyz", url);
  return 0;
}

void hfd_http_loop_closing(hfd_server *s) {
  hfd_http *h = s->http;
  if (!h || !h->loop_open) return;
  pthread_mutex_lock(&h->mu);
  h->loop_open = 0;
  pthread_cond_broadcast(&h->cv);
  pthread_mutex_unlock(&h->mu);
  uv_close((uv_handle_t *)&h->async, NULL);
}

void hfd_http_stop(hfd_server *s) {
  hfd_http *h = s->http;
  if (!h) return;
  if (h->d) MHD_stop_daemon(h->d);  /* reports every connection closed: h->conns is empty */
  free(h->text);
  pthread_cond_destroy(&h->cv);
  pthread_mutex_destroy(&h->mu);
  free(h);
  s->http = NULL;
}
