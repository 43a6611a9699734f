/*
 * endpoints.c: the endpoint list of a client, connecting to one of them
 * (socket, HELLO handshake) and moving on to the next when one cannot be
 * used.
 *
 * Each address is parsed by hfp_url_parse, so a list accepts and refuses
 * exactly what the daemon's --listen does; the list itself is only commas
 * between addresses. A failed connect keeps the system's reason: errno is
 * left set for the caller, and the message names the endpoint, the reason
 * and, for the usual mistakes, what to check.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/timerfd.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "client_internal.h"

int hfci_parse_endpoints(const char *url, endpoint *eps, int *neps, char *why, size_t whylen) {
  *neps = 0;
  if (why && whylen) why[0] = 0;
  if (!url) {
    if (why && whylen) snprintf(why, whylen, "no URL");
    return HFC_E_URL;
  }
  const char *s = url;
  for (int i = 0;; i++) {
    const char *comma = strchr(s, ',');
    size_t n = comma ? (size_t)(comma - s) : strlen(s);
    if (i == MAX_ENDPOINTS) {
      if (why && whylen)
        snprintf(why, whylen, "bad URL list '%.120s': more than %d endpoints", url, MAX_ENDPOINTS);
      return HFC_E_URL;
    }
    if (n == 0 || n >= sizeof eps[i].url) {
      if (why && whylen)
        snprintf(why, whylen, "bad URL list '%.120s': endpoint %d is %s", url, i + 1,
                 n ? "too long" : "empty");
      return HFC_E_URL;
    }
    memcpy(eps[i].url, s, n);
    eps[i].url[n] = 0;
    if (hfp_url_parse(eps[i].url, 0, &eps[i].addr, why, whylen)) return HFC_E_URL;
    *neps = i + 1;
    if (!comma) return 0;
    s = comma + 1;
  }
}

int hfc_check_url(const char *url, char *why, size_t whylen) {
  hfci_begin(NULL);
  endpoint eps[MAX_ENDPOINTS];
  int n;
  char buf[MSG_MAX];
  int rc = hfci_parse_endpoints(url, eps, &n, buf, sizeof buf);
  /* Said in hfc_last_message(NULL) too, as every call that fails does. */
  if (rc) hfci_msg(NULL, "%s", buf);
  if (why && whylen) snprintf(why, whylen, "%s", rc ? buf : "");
  return rc;
}

/* ---- one connection ------------------------------------------------------- */

/* What to check after the usual connect failures. */
static const char *connect_hint(int kind, int err) {
  if (kind == HFP_URL_UNIX && (err == EACCES || err == EPERM))
    return " (the socket's permissions refuse this user: is it in the server's group, "
           "e.g. hairfilter?)";
  if (kind == HFP_URL_UNIX && err == ENOENT) return " (no socket there: is hairfilterd running?)";
  if (err == ECONNREFUSED) return " (nothing listens there: is hairfilterd running?)";
  if (kind == HFP_URL_UNIX && err == ETIMEDOUT)
    return " (the server accepted no connection within hfc_options.timeout_ms, its queue of "
           "connections full: is hairfilterd stopped or overloaded?)";
  return "";
}

static double mono_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

/* connect() of the non-blocking Unix socket fd within timeout_ms (< 0: no
 * limit). A listener whose queue of connections is full (a stopped or
 * overloaded server) makes a blocking connect wait for ever and a
 * non-blocking one fail at once with EAGAIN, so that is tried again a few
 * milliseconds apart until the timeout; a signal does not end it either.
 * 0, or -1 with errno (ETIMEDOUT once the time is up). */
static int connect_unix(int fd, const struct sockaddr_un *sun, int timeout_ms) {
  double deadline = mono_us() + (double)timeout_ms * 1e3;
  for (;;) {
    if (connect(fd, (const struct sockaddr *)sun, sizeof *sun) == 0) return 0;
    int e = errno;
    if (e == EISCONN) return 0;
    if (e == EINPROGRESS) {
      int so = 0;
      socklen_t sl = sizeof so;
      int w = hfci_wait_fd(fd, POLLOUT, hfci_ms_left(deadline, timeout_ms));
      if (w == 0 && getsockopt(fd, SOL_SOCKET, SO_ERROR, &so, &sl) == 0 && so == 0) return 0;
      errno = w == HFC_E_TIMEOUT ? ETIMEDOUT : so ? so : EIO;
      return -1;
    }
    if (e != EAGAIN && e != EINTR && e != EALREADY) {
      errno = e;
      return -1;
    }
    int left = hfci_ms_left(deadline, timeout_ms);
    if (left == 0) {
      errno = ETIMEDOUT;
      return -1;
    }
    if (e != EINTR) {
      struct timespec ts = {0, (long)((left < 0 || left > 10 ? 10 : left) * 1000000L)};
      nanosleep(&ts, NULL);
    }
  }
}

/* Opens a socket connected to e: the descriptor, or HFC_E_CONNECT with
 * *err the system's reason (0 when it is in why: a name that does not
 * resolve) and why filled. */
static int open_socket(const endpoint *e, int timeout_ms, int *err, char *why, size_t whylen) {
  const hfp_url *u = &e->addr;
  *err = 0;
  if (u->kind == HFP_URL_UNIX) {
    struct sockaddr_un sun;
    memset(&sun, 0, sizeof sun);
    sun.sun_family = AF_UNIX;
    _Static_assert(sizeof u->path <= sizeof sun.sun_path, "hfp_url path fits sun_path");
    memcpy(sun.sun_path, u->path, sizeof u->path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (fd >= 0 && connect_unix(fd, &sun, timeout_ms) == 0) return fd;
    *err = errno;
    if (fd >= 0) close(fd);
    struct stat st;
    if (*err == ECONNREFUSED && stat(u->path, &st) == 0 && !S_ISSOCK(st.st_mode)) {
      /* connect() says "refused" for a file that is no socket at all: the
       * path is wrong, not the server down. */
      snprintf(why, whylen, "connect: %s is not a socket but a %s: is the path right? "
               "(hairfilterd's --listen unix:PATH)", u->path,
               S_ISDIR(st.st_mode) ? "directory" : S_ISFIFO(st.st_mode) ? "FIFO" : "regular file");
      return HFC_E_CONNECT;
    }
    snprintf(why, whylen, "connect: %s%s", strerror(*err), connect_hint(u->kind, *err));
    return HFC_E_CONNECT;
  }
  char port[8];
  snprintf(port, sizeof port, "%u", (unsigned)u->port);
  struct addrinfo hints, *res = NULL;
  memset(&hints, 0, sizeof hints);
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICSERV;
  int gai = getaddrinfo(u->host, port, &hints, &res);
  if (gai != 0 || !res) {
    *err = gai == EAI_SYSTEM ? errno : 0;
    snprintf(why, whylen, "cannot resolve '%s': %s", u->host,
             gai == EAI_SYSTEM ? strerror(*err) : gai_strerror(gai));
    return HFC_E_CONNECT;
  }
  int fd = -1;
  for (struct addrinfo *ai = res; ai; ai = ai->ai_next) {
    fd = socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) {
      *err = errno;
      continue;
    }
    int rc = connect(fd, ai->ai_addr, ai->ai_addrlen);
    /* A signal leaves a non-blocking connect going on, as EINPROGRESS does. */
    if (rc != 0 && (errno == EINPROGRESS || errno == EINTR)) {
      int so = 0;
      socklen_t sl = sizeof so;
      int w = hfci_wait_fd(fd, POLLOUT, timeout_ms);
      if (w == 0 && getsockopt(fd, SOL_SOCKET, SO_ERROR, &so, &sl) == 0 && so == 0)
        rc = 0;
      else
        errno = w == HFC_E_TIMEOUT ? ETIMEDOUT : so ? so : errno;
    }
    if (rc == 0) {
      int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      break;
    }
    *err = errno;
    close(fd);
    fd = -1;
  }
  freeaddrinfo(res);
  if (fd >= 0) return fd;
  snprintf(why, whylen, "connect: %s%s", strerror(*err), connect_hint(u->kind, *err));
  return HFC_E_CONNECT;
}

/* HELLO on a fresh socket and its answer: 0 with ok filled, or the error
 * with why filled. */
static int handshake(hfc_client *c, int fd, void *ssl, hfp_hello_ok *ok, char *why,
                     size_t whylen) {
  hfp_hello hello;
  memset(&hello, 0, sizeof hello);
  hello.min_version = HFP_VERSION_MIN;
  hello.max_version = HFP_VERSION;
  strcpy(hello.client_name, c->client_name);
  strcpy(hello.token, c->token);
  uint8_t frame[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  int n = hfp_encode_hello(frame, sizeof frame, &hello);
  if (n < 0) {
    snprintf(why, whylen, "cannot encode HELLO");
    return HFC_E_ARG;
  }
  int rc = hfci_send_io(fd, ssl, c->timeout_ms, frame, (size_t)n);
  uint8_t hb[HFP_HEADER_SIZE];
  /* A server that refuses the connection outright (a fatal BUSY at
   * --max-connections) writes its ERROR and closes before reading the
   * HELLO, so the send may fail (EPIPE) with the reason waiting unread:
   * read it, and report the send's failure only when there is none. */
  if (!rc || (!ssl && (rc == HFC_E_CLOSED || rc == HFC_E_IO))) {
    int sent = rc;
    rc = hfci_recv_io(fd, ssl, NULL, hb, sizeof hb, c->timeout_ms);
    if (rc && sent) rc = sent;
  }
  if (rc == HFC_E_TIMEOUT) {
    /* The socket connected (the kernel's backlog takes it) but nothing
     * answered: say how long, and what holds a server up there. */
    snprintf(why, whylen, "handshake: no answer to HELLO within %d ms (hfc_options.timeout_ms): "
             "is the server stopped or stuck, or are its --max-handshakes taken?", c->timeout_ms);
    return rc;
  }
  if (rc) {
    /* Under TLS 1.3 a server refuses a client certificate after the
     * client's side of the handshake is done: its alert comes here. */
    snprintf(why, whylen, "handshake: %s", rc == HFC_E_TLS ? hfci_tls_why() : hfc_strerror(rc));
    return rc;
  }
  hfp_header h;
  if (hfp_header_decode(hb, CTL_MAX, &h) ||
      (h.type != HFP_HELLO_OK && h.type != HFP_ERROR)) {
    snprintf(why, whylen, "handshake: not a hairfilterd reply");
    return HFC_E_PROTOCOL;
  }
  uint8_t *payload = malloc(h.length ? h.length : 1);
  if (!payload) return HFC_E_NOMEM;
  rc = hfci_recv_io(fd, ssl, NULL, payload, h.length, c->timeout_ms);
  if (rc) {
    free(payload);
    snprintf(why, whylen, "handshake: %s", rc == HFC_E_TLS ? hfci_tls_why() : hfc_strerror(rc));
    return rc;
  }
  if (h.type == HFP_ERROR) {
    hfp_error e;
    rc = hfp_decode_error(payload, h.length, &e);
    free(payload);
    if (rc) {
      snprintf(why, whylen, "handshake: malformed ERROR");
      return HFC_E_PROTOCOL;
    }
    /* The server's words say what is wrong; what the engine changes is
     * the option, which only the client can name. */
    const char *hint = "";
    if (e.code == HFP_E_UNAUTHORIZED)
      hint = c->token[0] ? "; hfc_options.token (--token) is not the server's token (its "
                           "--auth-token-file or $HAIRFILTERD_TOKEN)"
                         : "; set hfc_options.token (--token) to the server's token (its "
                           "--auth-token-file or $HAIRFILTERD_TOKEN)";
    snprintf(why, whylen, "%s: %s%s", hfp_code_name((int)e.code), e.message, hint);
    return e.code < HFP_E_COUNT ? -(int)e.code : HFC_E_INTERNAL;
  }
  rc = hfp_decode_hello_ok(payload, h.length, ok);
  free(payload);
  if (rc) {
    snprintf(why, whylen, "handshake: malformed HELLO_OK (%s)", hfp_strerror(rc));
    return rc == -HFP_E_VERSION ? HFC_E_VERSION : HFC_E_PROTOCOL;
  }
  return 0;
}

static void fill_info(hfc_server_info *i, const hfp_hello_ok *ok) {
  memset(i, 0, sizeof *i);
  snprintf(i->name, sizeof i->name, "%s", ok->server_name);
  snprintf(i->software_version, sizeof i->software_version, "%s", ok->software_version);
  i->version = ok->version;
  i->max_width = (int)ok->max_width;
  i->max_height = (int)ok->max_height;
  i->max_spp = ok->max_spp;
  i->max_inflight = ok->max_inflight;
  i->max_batch = (int)ok->max_batch;
  i->queue_size = (int)ok->queue_size;
  i->auth_required = (ok->server_flags & HFP_SERVER_AUTH_REQUIRED) != 0;
  i->f32 = (ok->dtypes >> HFP_F32) & 1;
  i->f16 = (ok->dtypes >> HFP_F16) & 1;
  i->shm = (ok->server_flags & HFP_SERVER_SHM) != 0;
  i->max_frame_bytes = ok->max_frame_bytes;
}

/* Connects to endpoint e and handshakes: the index of its connection slot,
 * or an error with why and *err (errno of a failed connect) filled. */
static int open_conn(hfc_client *c, int e, int *err, char *why, size_t whylen) {
  int k = -1;
  for (int i = 0; i < MAX_CONNS && k < 0; i++)
    if (c->conns[i].fd < 0) k = i;
  *err = 0;
  if (k < 0) {
    snprintf(why, whylen, "%d connections still draining", MAX_CONNS);
    return HFC_E_BUSY;
  }
  int fd = open_socket(&c->eps[e], c->timeout_ms, err, why, whylen);
  if (fd < 0) return fd;
  int fl = fcntl(fd, F_GETFL);
  if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
    *err = errno;
    close(fd);
    snprintf(why, whylen, "fcntl: %s", strerror(*err));
    return HFC_E_IO;
  }
  void *ssl = NULL;
  if (c->eps[e].addr.tls) {
    int rc = hfci_tls_connect(c, fd, &c->eps[e].addr, &ssl);
    if (rc) {
      close(fd);
      snprintf(why, whylen, "%s", hfci_tls_why());
      return rc;
    }
  }
  hfp_hello_ok ok;
  int rc = handshake(c, fd, ssl, &ok, why, whylen);
  if (rc) {
    if (ssl) hfci_tls_close(ssl);
    close(fd);
    return rc;
  }
  struct epoll_event ev;
  memset(&ev, 0, sizeof ev);
  ev.events = EPOLLIN;
  ev.data.fd = fd;
  if (epoll_ctl(c->epfd, EPOLL_CTL_ADD, fd, &ev) != 0) {
    *err = errno;
    if (ssl) hfci_tls_close(ssl);
    close(fd);
    snprintf(why, whylen, "epoll_ctl: %s", strerror(*err));
    return HFC_E_IO;
  }
  conn *x = &c->conns[k];
  memset(x, 0, sizeof *x);
  x->fd = fd;
  x->ssl = ssl;
  x->rx_fd = -1;
  x->endpoint = e;
  x->serial = ++c->next_serial;
  fill_info(&x->info, &ok);
  return k;
}

static void sleep_ms(int ms) {
  struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
  while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
  }
}

static int connect_from(hfc_client *c, int start, int skip) {
  char all[MSG_MAX] = "", why[400];
  size_t used = 0;
  int rc = HFC_E_CONNECT, err = 0;
  for (int round = 0; round < c->connect_rounds; round++) {
    if (round) sleep_ms(c->retry_delay_ms);
    for (int i = 0; i < c->neps; i++) {
      int e = (start + i) % c->neps;
      if (e == skip) continue;
      why[0] = 0;
      int k = open_conn(c, e, &err, why, sizeof why);
      if (k >= 0) {
        c->active = k;
        c->broken = 0;
        c->info_last = c->conns[k].info;
        return 0;
      }
      rc = k;
      /* Every endpoint's reason, each once: the rounds repeat them. */
      if (round == 0 && used < sizeof all) {
        int n = snprintf(all + used, sizeof all - used, "%s%s: %s", used ? "; " : "",
                         c->eps[e].url, why);
        if (n > 0) used += (size_t)n;
      }
    }
  }
  if (!used) snprintf(all, sizeof all, "no other endpoint to try");
  else if (c->connect_rounds > 1 && used < sizeof all)
    snprintf(all + used, sizeof all - used, " (%d rounds, %d ms apart)", c->connect_rounds,
             c->retry_delay_ms);
  hfci_msg(c, "%s", all);
  /* errno is what the last connect failed with (0: it did not get that far). */
  errno = err;
  return rc;
}

int hfci_connect_next(hfc_client *c, int start) { return connect_from(c, start, -1); }

int hfci_connect_other(hfc_client *c, int leave) { return connect_from(c, leave + 1, leave); }

void hfci_conn_close(hfc_client *c, int k) {
  conn *x = &c->conns[k];
  if (x->fd < 0) return;
  epoll_ctl(c->epfd, EPOLL_CTL_DEL, x->fd, NULL);
  if (x->ssl) hfci_tls_close(x->ssl);
  close(x->fd);
  if (x->rx_fd >= 0) close(x->rx_fd);
  free(x->variants);
  hfci_shm_orphan(c, x->serial);
  memset(x, 0, sizeof *x);
  x->fd = -1;
  x->rx_fd = -1;
  if (c->active == k) c->active = -1;
}

int hfci_follows_list(const hfc_client *c) {
  return c->neps > 1 && !(c->failover & HFC_FAILOVER_NEVER) && (c->failover & HFC_FAILOVER_LOST);
}

int hfci_can_failover(const hfc_client *c, int err, int lost) {
  if (c->neps < 2 || (c->failover & HFC_FAILOVER_NEVER)) return 0;
  if (!lost) {
    /* A request's own answer: the server is full, or leaving. */
    if (err == HFC_E_BUSY) return (c->failover & HFC_FAILOVER_BUSY) != 0;
    return err == HFC_E_SHUTTING_DOWN && (c->failover & HFC_FAILOVER_LOST);
  }
  if (!(c->failover & HFC_FAILOVER_LOST)) return 0;
  /* The connection went away, or the server is leaving or full; errors
   * about what this client sent (a token, a version, a frame too long)
   * would meet the next server too. */
  switch (err) {
    case HFC_E_CLOSED: case HFC_E_IO: case HFC_E_TIMEOUT: case HFC_E_PROTOCOL:
    case HFC_E_SHUTTING_DOWN: case HFC_E_BUSY: case HFC_E_INTERNAL:
      return 1;
    default:
      return 0;
  }
}

/* ---- the public side -------------------------------------------------------- */

static int set_options(hfc_client *c, const hfc_options *opt) {
  hfc_options o;
  hfc_options_init(&o);
  /* Options of an older header (0.1.0's ended before the TLS fields) keep
   * the defaults of the rest. */
  static const size_t released[] = {offsetof(hfc_options, tls_ca_file)};   /* 0.1.0 */
  int rc;
  if (opt && (rc = hfci_take_struct(c, "hfc_options", opt, &o, sizeof o, released, 1,
                                    "hfc_options_init")))
    return rc;
  const char *name = o.client_name ? o.client_name : "libhairfilter";
  size_t nl = strlen(name), tl = o.token ? strlen(o.token) : 0;
  if (nl < 1 || nl > HFP_NAME_MAX)
    return hfci_arg(c, "hfc_options.client_name is %zu bytes: want 1..%d", nl, HFP_NAME_MAX);
  for (size_t i = 0; i < nl; i++)
    if (name[i] <= 0x20 || name[i] > 0x7e)
      return hfci_arg(c, "hfc_options.client_name has byte 0x%02x at %zu: want printable "
                         "ASCII without spaces", (unsigned char)name[i], i);
  if (tl > HFP_TOKEN_MAX)
    return hfci_arg(c, "hfc_options.token is %zu bytes: at most %d", tl, HFP_TOKEN_MAX);
  for (size_t i = 0; i < tl; i++)
    if (o.token[i] <= 0x20 || o.token[i] > 0x7e)
      return hfci_arg(c, "hfc_options.token has a byte outside printable ASCII without "
                         "spaces at %zu", i);
  if (o.connect_rounds < 0 || o.retry_delay_ms < 0)
    return hfci_arg(c, "hfc_options.%s is negative", o.connect_rounds < 0 ? "connect_rounds"
                                                                          : "retry_delay_ms");
  /* A bit this library does not know is a typo or a newer header's option
   * it cannot honour: said, not ignored. */
  unsigned known = HFC_FAILOVER_LOST | HFC_FAILOVER_BUSY | HFC_FAILOVER_NEVER;
  if (o.failover & ~known)
    return hfci_arg(c, "hfc_options.failover has bits 0x%x this library does not know: use "
                       "HFC_FAILOVER_LOST, HFC_FAILOVER_BUSY or HFC_FAILOVER_NEVER",
                    o.failover & ~known);
  memcpy(c->client_name, name, nl + 1);
  if (tl) memcpy(c->token, o.token, tl + 1);
  c->timeout_ms = o.timeout_ms == 0 ? 30000 : o.timeout_ms;
  c->connect_rounds = o.connect_rounds ? o.connect_rounds : 1;
  c->retry_delay_ms = o.retry_delay_ms ? o.retry_delay_ms : 100;
  c->max_resends = o.max_resends == 0 ? 2 : o.max_resends < 0 ? 0 : o.max_resends;
  c->failover = o.failover ? o.failover : HFC_FAILOVER_LOST | HFC_FAILOVER_BUSY;
  return 0;
}

int hfc_connect(const char *url, const hfc_options *opt, hfc_client **out) {
  hfci_begin(NULL);
  if (!out) return hfci_arg(NULL, "hfc_connect: out is NULL");
  *out = NULL;
  if (!url) return hfci_arg(NULL, "hfc_connect: url is NULL");
  hfc_client *c = calloc(1, sizeof *c);
  if (!c) return HFC_E_NOMEM;
  c->epfd = -1;
  c->tls_evfd = -1;
  c->due_fd = -1;
  c->active = -1;
  for (int k = 0; k < MAX_CONNS; k++) c->conns[k].fd = c->conns[k].rx_fd = -1;
  char why[400];
  int rc = hfci_parse_endpoints(url, c->eps, &c->neps, why, sizeof why);
  if (rc) hfci_msg(NULL, "%s", why);
  if (!rc) rc = set_options(c, opt);
  if (!rc) {
    hfc_options o;
    hfc_options_init(&o);
    if (opt) memcpy(&o, opt, opt->struct_size < sizeof o ? opt->struct_size : sizeof o);
    o.struct_size = sizeof o;
    if ((rc = hfci_tls_setup(c, &o, why, sizeof why))) hfci_msg(NULL, "%s", why);
  }
  if (!rc && (c->epfd = epoll_create1(EPOLL_CLOEXEC)) < 0) {
    hfci_msg(NULL, "epoll_create1: %s", strerror(errno));
    rc = HFC_E_IO;
  }
  if (!rc && (rc = hfci_tls_poll_setup(c, why, sizeof why))) hfci_msg(NULL, "%s", why);
  if (!rc) {
    struct epoll_event ev;
    memset(&ev, 0, sizeof ev);
    ev.events = EPOLLIN;
    c->due_fd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    ev.data.fd = c->due_fd;
    if (c->due_fd < 0 || epoll_ctl(c->epfd, EPOLL_CTL_ADD, c->due_fd, &ev) != 0) {
      hfci_msg(NULL, "timerfd for hfc_fd: %s", strerror(errno));
      rc = HFC_E_IO;
    }
  }
  if (!rc) rc = hfci_connect_next(c, 0);
  if (rc) {
    /* The message (this thread's copy) and errno outlive the client. */
    hfc_close(c);
    return rc;
  }
  c->msg[0] = 0;
  c->next_id = 1;
  *out = c;
  return 0;
}

void hfc_close(hfc_client *c) {
  if (!c) return;
  int saved = errno;
  for (int k = 0; k < MAX_CONNS; k++) hfci_conn_close(c, k);
  hfci_shm_release_all(c);
  if (c->epfd >= 0) close(c->epfd);
  if (c->tls_evfd >= 0) close(c->tls_evfd);
  if (c->due_fd >= 0) close(c->due_fd);
  hfci_tls_free(c);
  free(c->ctl);
  /* Requests completed with an error and never collected by hfc_wait keep
   * their message until then: an engine closing with frames in flight
   * leaves them here. */
  for (int i = 0; i < c->np; i++) free(c->p[i].msg);
  free(c->p);
  free(c);
  errno = saved;
}

/* The getters take NULL too: an engine whose hfc_connect failed (or a
 * default-constructed or moved-from hairfilter::Client) asks them before
 * it asks whether it has a client, and a crash there says nothing. */
const hfc_server_info *hfc_info(const hfc_client *c) {
  static const hfc_server_info none;
  if (!c) {
    hfci_msg(NULL, "hfc_info: the client is NULL (hfc_connect failed or was not called)");
    return &none;
  }
  return c->active >= 0 ? &c->conns[c->active].info : &c->info_last;
}

const char *hfc_endpoint(const hfc_client *c) {
  if (!c) {
    hfci_msg(NULL, "hfc_endpoint: the client is NULL (hfc_connect failed or was not called)");
    return "";
  }
  return c->active >= 0 ? c->eps[c->conns[c->active].endpoint].url : "";
}

int hfc_fd(const hfc_client *c) {
  if (!c) return hfci_arg(NULL, "hfc_fd: the client is NULL (hfc_connect failed or was not called)");
  return c->epfd;
}
