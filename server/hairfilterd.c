/*
 * hairfilterd: serves hair filtering over protocol v1 and v2 (protocol/PROTOCOL.md)
 * on Unix sockets and TCP. This file holds startup (options, listeners),
 * signals (drain on SIGINT/SIGTERM, reload on SIGHUP, statistics on
 * SIGUSR1), readiness and the loop's heartbeat, and the STATS snapshot;
 * conn.c reads and answers requests, worker.c runs the network, models.c
 * keeps the variants, http.c and metrics.c serve the operator's endpoint.
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <malloc.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <systemd/sd-daemon.h>
#include <time.h>
#include <unistd.h>

#include <hairfilter/hairfilter_version.h>

#include "server.h"

/* ---- listeners ----------------------------------------------------------- */

static void explain_socket_dir(const char *url, const char *path, int rc);

/* A socket file left by a server that died is removed; one that a live
 * server answers on is not, nor one the daemon cannot tell about: only a
 * connection refused says no server listens there. Each refusal says why
 * and what to do. */
static int clear_stale_socket(const char *path) {
  char url[220];
  snprintf(url, sizeof url, "unix:%s", path);
  struct stat st;
  if (lstat(path, &st) != 0) {
    if (errno == ENOENT) return 0;
    if (errno == EACCES) {
      /* The directory cannot be searched: the same fix as one that
       * cannot be written. */
      explain_socket_dir(url, path, UV_EACCES);
      return -1;
    }
    hfd_err("--listen %s: cannot look at %s: %s; give another path", url, path, strerror(errno));
    return -1;
  }
  if (!S_ISSOCK(st.st_mode)) {
    hfd_err("--listen unix:%s: %s exists and is not a socket; remove it, or give another path",
            path, path);
    return -1;
  }
  /* Non-blocking: a blocking connect to a listener that does not accept
   * (stopped, frozen, or its backlog full) waits for it without end, and
   * the start would hang; non-blocking, that is EAGAIN, a live server. */
  int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (fd < 0) {
    hfd_err("--listen %s: socket: %s", url, strerror(errno));
    return -1;
  }
  struct sockaddr_un sun;
  memset(&sun, 0, sizeof sun);
  sun.sun_family = AF_UNIX;
  snprintf(sun.sun_path, sizeof sun.sun_path, "%s", path);
  int rc = connect(fd, (struct sockaddr *)&sun, sizeof sun);
  int err = errno;
  close(fd);
  if (rc == 0 || err == EAGAIN) {
    /* EAGAIN: a listener whose backlog is full, so a live one. */
    hfd_err("--listen unix:%s: another server is listening there (another hairfilterd?); stop "
            "it, or give each daemon its own socket path", path);
    return -1;
  }
  if (err == ENOENT) return 0;   /* removed meanwhile */
  if (err != ECONNREFUSED) {
    /* Not allowed to connect (a socket of another user, mode 0700 or
     * 0770): a live server may be behind it, and removing its file
     * would cut it off from every new client. */
    hfd_err("--listen unix:%s: a socket file is there and hairfilterd (uid %ld) cannot tell "
            "whether a server listens on it: connect: %s (owner uid %ld gid %ld, mode %04o); if "
            "no server uses it, remove it (rm %s), else give each daemon its own socket path",
            path, (long)geteuid(), strerror(err), (long)st.st_uid, (long)st.st_gid,
            (unsigned)(st.st_mode & 07777), path);
    return -1;
  }
  if (unlink(path) != 0) {
    err = errno;
    hfd_err("--listen unix:%s: cannot remove the socket file left there by a server that is "
            "gone: %s; hairfilterd runs as uid %ld and the file's owner is uid %ld (in a "
            "directory with the sticky bit, such as /tmp, only the owner may remove it): remove "
            "it as its owner or root (rm %s), or give another path",
            path, strerror(err), (long)geteuid(), (long)st.st_uid, path);
    return -1;
  }
  return 0;
}

/* A Unix socket that cannot be made: name the directory, who owns it, who
 * we are, and the fix (the usual case: a directory made by root, or by the
 * kubelet for a hostPath, meeting a daemon that runs as its own user). */
static void explain_socket_dir(const char *url, const char *path, int rc) {
  char dir[200];
  snprintf(dir, sizeof dir, "%s", path);
  char *slash = strrchr(dir, '/');
  if (!slash)
    snprintf(dir, sizeof dir, ".");
  else if (slash == dir)
    dir[1] = 0;
  else
    *slash = 0;
  struct stat st;
  if (stat(dir, &st) != 0) {
    /* libuv's code here (often EACCES) would blame permissions for what
     * is a missing directory: name only what stat found. */
    hfd_err("--listen %s: the directory %s does not exist (%s); create it writable for "
            "uid %ld (docs/SERVER.md, \"Socket directory\")", url, dir, strerror(errno),
            (long)geteuid());
    return;
  }
  if (rc == UV_EROFS) {
    /* No owner or mode makes a read-only mount writable: a container run
     * with a read-only root file system needs a writable mount there. */
    hfd_err("--listen %s: %s is on a read-only file system, so hairfilterd (uid %ld gid %ld) "
            "cannot create its socket there; mount a writable directory there for it: docker run "
            "--tmpfs %s:uid=%ld,gid=%ld,mode=0750, a Kubernetes emptyDir, or systemd's "
            "RuntimeDirectory= (docs/SERVER.md, \"Socket directory\"). No listener is opened: "
            "the daemon stops rather than serve on some of its addresses", url, dir,
            (long)geteuid(), (long)getegid(), dir, (long)geteuid(), (long)getegid());
    return;
  }
  hfd_err("--listen %s: %s: hairfilterd runs as uid %ld gid %ld and cannot create a socket in "
          "%s (owner uid %ld gid %ld, mode %04o); make the directory writable for it, e.g. "
          "install -d -o %ld -g %ld -m 0750 %s, systemd's RuntimeDirectory=, or a Kubernetes "
          "emptyDir (docs/SERVER.md, \"Socket directory\"). No listener is opened: the daemon "
          "stops rather than serve on some of its addresses", url, uv_strerror(rc),
          (long)geteuid(), (long)getegid(), dir, (long)st.st_uid, (long)st.st_gid,
          (unsigned)(st.st_mode & 07777), (long)geteuid(), (long)getegid(), dir);
}

void hfd_bind_error(const char *option, const char *url, const char *host, int port, int err) {
  if (err == EADDRINUSE)
    hfd_err("%s %s: port %d is in use on %s: another process listens there (another "
            "hairfilterd? `ss -ltnp 'sport = :%d'` names it); stop it or give another port",
            option, url, port, host, port);
  else if (err == EADDRNOTAVAIL)
    hfd_err("%s %s: %s is not an address of this host (`ip -brief address` lists them); "
            "give one of them, 0.0.0.0 for all, or 127.0.0.1", option, url, host);
  else if (err == EACCES && port > 0 && port < 1024)
    hfd_err("%s %s: port %d is privileged (below 1024) and hairfilterd runs without "
            "CAP_NET_BIND_SERVICE; give a port of 1024 or more", option, url, port);
  else
    hfd_err("%s %s: %s", option, url, strerror(err));
}

/* Whether a Unix listener's path still names the socket it bound: a file
 * removed (a cleaner of /tmp, a runtime directory another unit removed)
 * or replaced leaves the daemon unreachable there. 1 for TCP listeners. */
static int listener_socket_present(const hfd_listener *l) {
  if (!l->unix_path[0]) return 1;
  struct stat st;
  return stat(l->unix_path, &st) == 0 && S_ISSOCK(st.st_mode) &&
         (unsigned long long)st.st_dev == l->sock_dev &&
         (unsigned long long)st.st_ino == l->sock_ino;
}

static int open_listener(hfd_server *s, const char *url, const hfp_url *u) {
  hfd_listener *l = &s->listeners[s->num_listeners];
  memset(l, 0, sizeof *l);
  l->srv = s;
  int rc;
  if (u->kind == HFP_URL_UNIX) {
    const char *path = u->path;
    if (strlen(path) >= sizeof l->unix_path) {
      hfd_err("--listen %s: socket path too long", url);
      return -1;
    }
    if (clear_stale_socket(path)) return -1;
    if ((rc = uv_pipe_init(s->loop, &l->h.pipe, 0)) < 0) {
      hfd_err("--listen %s: %s", url, uv_strerror(rc));
      return -1;
    }
    /* Bound here and handed to libuv, rather than by uv_pipe_bind: libuv
     * unlinks a path it bound when the handle closes, whatever the path
     * names by then, which may be the socket of a daemon started there
     * since this one's was removed. remove_files unlinks it only while it
     * is still this listener's. */
    int fd = -1;
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    if (strlen(path) >= sizeof sa.sun_path) {
      rc = UV_ENAMETOOLONG;
    } else {
      memcpy(sa.sun_path, path, strlen(path) + 1);
      fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
      if (fd < 0 || bind(fd, (struct sockaddr *)&sa, sizeof sa) != 0)
        rc = -errno;
      else if ((rc = uv_pipe_open(&l->h.pipe, fd)) < 0)
        unlink(path);
    }
    if (rc < 0) {
      if (rc == UV_EACCES || rc == UV_EPERM || rc == UV_ENOENT || rc == UV_EROFS)
        explain_socket_dir(url, path, rc);
      else
        hfd_err("--listen %s: %s", url, uv_strerror(rc));
      if (fd >= 0) close(fd);
      uv_close(&l->h.handle, NULL);
      return -1;
    }
    snprintf(l->unix_path, sizeof l->unix_path, "%s", path);
    snprintf(l->url, sizeof l->url, "unix:%s", path);
    /* The file as bound, which remove_files and /readyz compare with what
     * the path names later: without it the socket would be taken for lost
     * from the start, and left behind at the stop. */
    struct stat st;
    if (stat(path, &st) != 0) {
      hfd_err("--listen %s: the socket file cannot be looked at right after it was bound: %s; "
              "does another process remove files in its directory? give the socket a "
              "directory of its own (docs/SERVER.md, \"Socket directory\")", url, strerror(errno));
      uv_close(&l->h.handle, NULL);
      return -1;
    }
    l->sock_dev = (unsigned long long)st.st_dev;
    l->sock_ino = (unsigned long long)st.st_ino;
  } else {
    /* Numeric addresses only: a listener's address is not looked up. */
    const char *host = strcmp(u->host, "localhost") ? u->host : "127.0.0.1";
    struct sockaddr_storage ss;
    memset(&ss, 0, sizeof ss);
    if (uv_ip4_addr(host, u->port, (struct sockaddr_in *)&ss) != 0 &&
        uv_ip6_addr(host, u->port, (struct sockaddr_in6 *)&ss) != 0) {
      hfd_err("--listen %s: host must be a numeric address or localhost", url);
      return -1;
    }
    l->is_tcp = 1;
    l->is_tls = u->tls;
    /* Checked with the options already (config.c); again here for a
     * reload's configuration, by the same rule. */
    int loop_only;
    if (hfd_listener_auth(s->cfg, u, url, &loop_only, &l->auth_required)) return -1;
    if (!l->is_tls && !loop_only)
      hfd_warn("--listen %s: plain TCP on a non-loopback address: the token and every frame "
               "cross the network unencrypted; serve remote clients on tls:HOST:PORT "
               "(docs/SERVER.md, \"TLS\")", url);
    if ((rc = uv_tcp_init(s->loop, &l->h.tcp)) < 0) {
      hfd_err("--listen %s: %s", url, uv_strerror(rc));
      return -1;
    }
    if ((rc = uv_tcp_bind(&l->h.tcp, (struct sockaddr *)&ss, 0)) < 0) {
      hfd_bind_error("--listen", url, host, u->port, -rc);
      uv_close(&l->h.handle, NULL);
      return -1;
    }
  }
  l->h.handle.data = l;
  if ((rc = uv_listen(&l->h.stream, 511, hfd_on_connection)) < 0) {
    /* libuv reports a TCP bind's EADDRINUSE here, not at uv_tcp_bind. */
    if (l->is_tcp)
      hfd_bind_error("--listen", url, strcmp(u->host, "localhost") ? u->host : "127.0.0.1",
                     u->port, -rc);
    else
      hfd_err("--listen %s: %s", url, uv_strerror(rc));
    uv_close(&l->h.handle, NULL);
    if (l->unix_path[0]) unlink(l->unix_path);
    return -1;
  }
  if (l->is_tcp) {
    /* Resolve the real port (port 0 asks the kernel for a free one). */
    struct sockaddr_storage ss;
    int len = sizeof ss;
    char ip[64];
    if ((rc = uv_tcp_getsockname(&l->h.tcp, (struct sockaddr *)&ss, &len)) < 0) {
      hfd_err("--listen %s: getsockname: %s", url, uv_strerror(rc));
      uv_close(&l->h.handle, NULL);
      return -1;
    }
    int v6 = ss.ss_family == AF_INET6;
    rc = v6 ? uv_ip6_name((struct sockaddr_in6 *)&ss, ip, sizeof ip)
            : uv_ip4_name((struct sockaddr_in *)&ss, ip, sizeof ip);
    if (rc < 0) {
      hfd_err("--listen %s: address name: %s", url, uv_strerror(rc));
      uv_close(&l->h.handle, NULL);
      return -1;
    }
    snprintf(l->url, sizeof l->url, v6 ? "%s:[%s]:%d" : "%s:%s:%d", l->is_tls ? "tls" : "tcp", ip,
             ntohs(v6 ? ((struct sockaddr_in6 *)&ss)->sin6_port
                      : ((struct sockaddr_in *)&ss)->sin_port));
  }
  s->num_listeners++;
  /* One parenthesis: "(TLS, client certificate required, token required)". */
  hfd_log("listening on %s%s%s%s%s", l->url, l->is_tcp ? " (" : "",
          l->is_tls ? (s->cfg->tls_client_ca ? "TLS, client certificate required, " : "TLS, ")
                    : "",
          !l->is_tcp ? ""
          : l->auth_required ? "token required"
          : l->is_tls && s->cfg->tls_client_cert_auth ? "client certificate replaces the token"
                                                      : "no auth, loopback",
          l->is_tcp ? ")" : "");
  return 0;
}

static char http_url[300];

/* The files that say this daemon is there: removed when it starts to stop,
 * or on the way out of main when it did not get that far, so no exit path
 * leaves them. Only once: by the time a drained daemon exits, a new one may
 * have made the same paths. */
static void remove_files(hfd_server *s) {
  if (s->files_removed) return;
  s->files_removed = 1;
  /* A path that names another socket now is another daemon's: left alone. */
  for (int i = 0; i < s->num_listeners; i++)
    if (s->listeners[i].unix_path[0] && listener_socket_present(&s->listeners[i]))
      unlink(s->listeners[i].unix_path);
  if (s->ready_written && s->cfg->ready_file) unlink(s->cfg->ready_file);
}

/* ---- stats ----------------------------------------------------------------- */

void hfd_fill_stats(hfd_server *s, hfp_stats *st) {
  memset(st, 0, sizeof *st);
  st->uptime_us = (uint64_t)(hfd_now_us() - s->t_start);
  st->connections_total = s->conns_total;
  st->connections_open = (uint32_t)s->num_conns;
  st->queue_depth = (uint32_t)hfd_worker_queue_depth(&s->worker);
  st->queue_capacity = (uint32_t)s->cfg->queue_size;
  st->protocol_errors = s->protocol_errors;
  for (int i = 0; i < s->num_variants; i++)
    if (s->variants[i].model) {
      hfp_variant_stats *v = &st->variants[st->num_variants++];
      *v = s->variants[i].stats;
      v->cache_bytes = atomic_load(&s->variants[i].model->cache_bytes);
    }
}

int hfd_ready(const hfd_server *s, char *why, size_t whylen) {
  int serving = 0;
  for (int i = 0; i < s->num_variants; i++) serving += s->variants[i].model != NULL;
  double stalled;
  why[0] = 0;
  if (s->draining)
    snprintf(why, whylen, "draining");
  else if (!s->load_started || !s->worker.backend)
    snprintf(why, whylen, "loading");
  else if (!serving)
    snprintf(why, whylen, "no variant is served");
  else if (s->missing)
    snprintf(why, whylen, "%d configured weights file(s) serve no variant; first: %s",
             s->missing, s->missing_why);
  else if (!s->stopped &&
           hfd_worker_stalled((hfd_worker *)&s->worker, s->cfg->watchdog_ms * 1e3, &stalled))
    snprintf(why, whylen, "inference worker made no progress for %.1f s", stalled / 1e6);
  else
    for (int i = 0; i < s->num_listeners; i++)
      if (!listener_socket_present(&s->listeners[i])) {
        snprintf(why, whylen, "%s: the socket file is gone or replaced; restart hairfilterd",
                 s->listeners[i].url);
        break;
      }
  return why[0] == 0;
}

/* ---- shutdown ------------------------------------------------------------ */

static void close_handle(uv_handle_t *h) {
  if (!uv_is_closing(h)) uv_close(h, NULL);
}

static void close_all_connections(hfd_server *s) {
  for (hfd_conn *c = s->conns, *next; c; c = next) {
    next = c->next;
    hfd_conn_close(c);
  }
}

static void on_flush_timeout(uv_timer_t *t) {
  hfd_server *s = t->data;
  hfd_log("flush timeout: closing %d connection(s) whose peers left replies unread",
          s->num_conns);
  close_all_connections(s);
}

/* Called whenever something finished. Draining ends in three steps:
 *  1. every admitted frame answered: the worker stops, and each connection
 *     is shut down once its replies are written (uv_shutdown);
 *  2. peers that do not read their replies get --flush-timeout-ms, then
 *     their connections are closed with the replies unsent;
 *  3. no connection left: the signal handlers and timers close, which lets
 *     uv_run return.
 * The signal handlers stay until step 3, so a second SIGTERM or SIGINT
 * while peers are flushed shortens the wait instead of killing the process
 * with the default action. */
void hfd_maybe_finish(hfd_server *s) {
  if (!s->draining) return;
  if (!s->stopped) {
    /* A segment being pinned uses the worker's backend (hfd_seg_pin). */
    if (s->jobs_outstanding || s->pins_outstanding) return;
    s->stopped = 1;
    /* Nothing is queued or running (every admitted job was answered), so
     * the worker exits at once. */
    hfd_worker_stop(&s->worker);
    hfd_models_after_stop(s);
    close_handle((uv_handle_t *)&s->async);
    close_handle((uv_handle_t *)&s->drain_timer);
    close_handle((uv_handle_t *)&s->sweep_timer);
    for (hfd_conn *c = s->conns, *next; c; c = next) {
      next = c->next;
      hfd_conn_shutdown(c);
    }
    if (s->num_conns && (s->hurry || s->cfg->flush_timeout_ms == 0)) {
      close_all_connections(s);
    } else if (s->num_conns) {
      int rc = uv_timer_start(&s->flush_timer, on_flush_timeout,
                              (uint64_t)s->cfg->flush_timeout_ms, 0);
      if (rc < 0) {
        hfd_err("flush timer: %s; closing connections now", uv_strerror(rc));
        close_all_connections(s);
      }
    }
  }
  /* A handshake step still on a thread comes back through the TLS
   * handle closed below: the stop waits for it (its connection is closed,
   * so the thread skips it or is about to finish it). */
  if (s->num_conns == 0 && !s->signals_closed && !hfd_tls_steps_outstanding(s)) {
    s->signals_closed = 1;
    /* Closing the last uv_signal_t restores the default action; block the
     * signals first (the worker and its threads already block them) and
     * ignore them after, so none can kill the process on its way out. */
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGHUP);
    sigaddset(&set, SIGUSR1);
    pthread_sigmask(SIG_BLOCK, &set, NULL);
    close_handle((uv_handle_t *)&s->sigint);
    close_handle((uv_handle_t *)&s->sigterm);
    close_handle((uv_handle_t *)&s->sighup);
    close_handle((uv_handle_t *)&s->sigusr1);
    close_handle((uv_handle_t *)&s->flush_timer);
    close_handle((uv_handle_t *)&s->beat_timer);
    close_handle((uv_handle_t *)&s->accept_check);
    hfd_tls_stop(s);
    hfd_http_loop_closing(s);
  }
}

static void ignore_stop_signals(void) {
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = SIG_IGN;
  sigaction(SIGINT, &sa, NULL);
  sigaction(SIGTERM, &sa, NULL);
  sigaction(SIGHUP, &sa, NULL);
  sigaction(SIGUSR1, &sa, NULL);
}

/* Signals that come while the daemon starts (loading its models and
 * building --warm plans takes minutes on a GPU), before libuv's handlers
 * are in place: recorded, so that none kills the process with its default
 * action (a reload or a statistics request sent during a start was an
 * outage), and acted on once the daemon can. */
static const int early_signo[] = {SIGINT, SIGTERM, SIGHUP, SIGUSR1};
static const char *const early_name[] = {"SIGINT", "SIGTERM", "SIGHUP", "SIGUSR1"};
static volatile sig_atomic_t early_signal[4];

/* The daemon; file-scope so that a stop during the start reaches its
 * worker from the signal handler. */
static hfd_server srv;

static void on_early_signal(int signo) {
  for (int i = 0; i < 4; i++)
    if (early_signo[i] == signo) early_signal[i] = 1;
  /* A stop does not wait for the rest of the models (minutes on a GPU):
   * the load under way ends at its next step. */
  if (signo == SIGINT || signo == SIGTERM) hfd_worker_abandon_loads(&srv.worker);
}

static void catch_early_signals(void) {
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_early_signal;
  sa.sa_flags = SA_RESTART;   /* the loads' reads go on */
  sigemptyset(&sa.sa_mask);
  for (int i = 0; i < 4; i++) sigaction(early_signo[i], &sa, NULL);
}

/* The name of a stop signal (SIGINT, SIGTERM) that came during the start,
 * or NULL. */
static const char *early_stop(void) {
  return early_signal[0] ? early_name[0] : early_signal[1] ? early_name[1] : NULL;
}

/* A stop (SIGINT, SIGTERM) that came during the start, before the daemon
 * listens: what was built is released (the worker, with the backend and the
 * models it built, the receive buffers kept, the TLS context), nothing was
 * bound and no ready file written, and the exit status is 0, as for any
 * stop. The worker must have started. */
static int stop_before_serving(hfd_server *s) {
  hfd_notice("%s during the start: stopping before serving", early_stop());
  hfd_worker_stop(&s->worker);
  s->stopped = 1;
  hfd_models_after_stop(s);
  hfd_rpool_free(&s->rpool);
  close_handle((uv_handle_t *)&s->async);
  uv_run(s->loop, UV_RUN_DEFAULT);  /* runs the close */
  int rc = uv_loop_close(s->loop);
  if (rc < 0) hfd_err("uv_loop_close: %s", uv_strerror(rc));
  hfd_tls_free(s);
  hfd_config_free(s->cfg);
  return 0;
}

/* Once libuv's handlers are in place and the daemon serves: each signal
 * that came during the start is sent again, and the loop handles it as
 * any other (a stop drains, a reload reads the configuration again). */
static void replay_early_signals(void) {
  for (int i = 0; i < 4; i++)
    if (early_signal[i]) {
      early_signal[i] = 0;
      hfd_log("%s came during the start: handled now", early_name[i]);
      kill(getpid(), early_signo[i]);
    }
}

/* SIGHUP reloads (models.c); SIGUSR1 writes the statistics to the log. Both
 * leave every connection and request as it is. */
static void on_hup(uv_signal_t *h, int signum) {
  (void)signum;
  hfd_models_reload(h->data);
}

static void on_usr1(uv_signal_t *h, int signum) {
  (void)signum;
  hfd_metrics_log(h->data);
}

/* The loop's heartbeat: /healthz reads it from the HTTP thread, and
 * systemd's watchdog is fed from here while the worker makes progress
 * too, so a wedged loop or worker stops the pings and gets the daemon
 * restarted. */
static void on_beat(uv_timer_t *t) {
  hfd_server *s = t->data;
  atomic_store(&s->loop_beat_us, (uint64_t)hfd_now_us());
  if (!s->draining)
    for (int i = 0; i < s->num_listeners; i++) {
      hfd_listener *l = &s->listeners[i];
      int lost = !listener_socket_present(l);
      if (lost && !l->socket_lost) {
        hfd_err("--listen %s: the socket file was removed or replaced by another file: local "
                "clients can no longer connect, and /readyz says not ready; restart hairfilterd "
                "to make it again (a socket directory another service removes, or a cleaner of "
                "its directory? docs/SERVER.md, \"Socket directory\")", l->url);
        /* `systemctl status` says it too, where no readiness probe looks. */
        hfd_notify_status("not ready: %s: the socket file is gone or replaced; restart "
                          "hairfilterd", l->url);
      } else if (!lost && l->socket_lost) {
        hfd_notice("--listen %s: the socket file is back", l->url);
        hfd_notify_ready(s);
      }
      l->socket_lost = lost;
    }
  static int stall_logged;
  double stalled;
  if (hfd_worker_stalled(&s->worker, s->cfg->watchdog_ms * 1e3, &stalled)) {
    if (!stall_logged)
      hfd_err("inference worker made no progress for %.1f s (--watchdog-ms %d): unhealthy",
              stalled / 1e6, s->cfg->watchdog_ms);
    stall_logged = 1;
    return;
  }
  if (stall_logged) hfd_notice("inference worker progressing again");
  stall_logged = 0;
  if (s->watchdog_usec) hfd_notify_watchdog();
}

static void on_sweep(uv_timer_t *t) { hfd_sweep_stalled(t->data); }

static void on_drain_timeout(uv_timer_t *t) {
  hfd_server *s = t->data;
  int depth = hfd_worker_queue_depth(&s->worker);
  hfd_log("drain timeout: failing %d queued request(s) with SHUTTING_DOWN", depth);
  hfd_worker_cancel(&s->worker);
}

static void on_signal(uv_signal_t *h, int signum) {
  hfd_server *s = h->data;
  const char *name = signum == SIGINT ? "SIGINT" : "SIGTERM";
  if (s->draining) {
    if (s->hurry) return;
    s->hurry = 1;
    if (s->stopped) {
      hfd_log("second %s: closing %d connection(s) without waiting for their replies to be read",
              name, s->num_conns);
      close_all_connections(s);
    } else {
      hfd_log("second %s: failing queued requests now; connections close once answered", name);
      hfd_worker_cancel(&s->worker);
    }
    return;
  }
  s->draining = 1;
  /* A reload's loads still under way are given up at their next step:
   * nothing is swapped in while draining, and the worker would otherwise
   * finish every one (minutes on a GPU), ahead of the queued frames and
   * before it can stop. */
  hfd_worker_abandon_loads(&s->worker);
  hfd_notify_stopping();
  hfd_notice("%s: draining %d request(s), no new work accepted (frames sent from now on get "
             "SHUTTING_DOWN; the stop line counts them)", name, s->jobs_outstanding);
  for (int i = 0; i < s->num_listeners; i++) close_handle(&s->listeners[i].h.handle);
  /* Not ready any more: clients find no socket and no ready file. */
  remove_files(s);
  if (s->cfg->drain_timeout_ms == 0) {
    hfd_worker_cancel(&s->worker);
  } else {
    int rc = uv_timer_start(&s->drain_timer, on_drain_timeout, (uint64_t)s->cfg->drain_timeout_ms, 0);
    if (rc < 0) {
      hfd_err("drain timer: %s; failing queued requests now", uv_strerror(rc));
      hfd_worker_cancel(&s->worker);
    }
  }
  hfd_maybe_finish(s);
}

/* ---- main ------------------------------------------------------------------ */

int main(int argc, char **argv) {
  static hfd_config cfg;
  hfd_log_init();
  int prc = hfd_config_parse(argc, argv, &cfg);
  if (prc) return prc > 0 ? 0 : 2;
  hfd_log_level = cfg.log_level;
  /* A peer that vanishes must not kill us with SIGPIPE; libuv reports EPIPE. */
  signal(SIGPIPE, SIG_IGN);
  catch_early_signals();
  /* Frames, results and plans of a megabyte or more are mapped and unmapped
   * on their own, so that what an oversized frame needed goes back to the
   * system when it is freed. glibc's default threshold rises with every
   * such block freed (up to 32 MiB) and would keep them in the heap. */
  if (!mallopt(M_MMAP_THRESHOLD, 1 << 20))
    hfd_warn("mallopt(M_MMAP_THRESHOLD) failed (an allocator other than glibc's, such as a "
             "sanitizer's, is in use): freed large frames may stay in the process's heap");

  hfd_server *s = &srv;
  s->cfg = &cfg;
  s->argc = argc;
  s->argv = argv;
  s->loop = uv_default_loop();
  s->t_start = hfd_now_us();
  struct timespec now;
  clock_gettime(CLOCK_REALTIME, &now);
  s->t_start_wall = (double)now.tv_sec + now.tv_nsec / 1e9;
  atomic_store(&s->loop_beat_us, (uint64_t)s->t_start);
  hfd_notice("starting %s %s (protocol v%d..v%d)%s%s", cfg.name, HAIRFILTER_VERSION_STRING, HFP_VERSION_MIN,
             HFP_VERSION, cfg.config_path ? ", config " : "",
             cfg.config_path ? cfg.config_path : "");
  if (sd_watchdog_enabled(0, &s->watchdog_usec) <= 0) s->watchdog_usec = 0;
  /* Before anything else: a stale ready file goes, and a path where no
   * ready file can be written stops the start now, not once the models
   * are built (ready_file.c). */
  if (cfg.ready_file && hfd_ready_file_prepare(&cfg)) return 1;

  hfd_worker *w = &s->worker;
  w->backend_name = cfg.backend;
  w->max_batch = cfg.max_batch;
  w->max_delay_us = cfg.max_queue_delay_us;
  w->pipeline_depth = cfg.pipeline_depth;
  w->cfg = &cfg;
  w->q_cap = cfg.queue_size;
  w->async = &s->async;
  /* Plans and scratch kept between runs may use a quarter of the memory
   * budget; one frame may use the rest (docs/SERVER.md, "Memory"). */
  w->cache_cap = cfg.max_memory_bytes / 4;
  w->pool_idle = &s->rpool.idle_bytes;
  s->frame_budget = cfg.max_memory_bytes - w->cache_cap;
  int rc = uv_async_init(s->loop, &s->async, hfd_on_async);
  if (rc < 0) {
    hfd_err("uv_async_init: %s", uv_strerror(rc));
    return 1;
  }
  s->async.data = s;
  /* The TLS files are read before the backend starts and the weights load
   * (minutes on a GPU with --warm), so a key the daemon cannot read stops
   * it at once. */
  if (hfd_tls_init(s)) return 1;
  if (hfd_worker_start(w)) {
    hfd_err("cannot start inference: %s", w->init_msg);
    return 1;
  }
  cfg.max_batch = w->max_batch; /* the backend's default, unless given */
  hfd_log("%s", w->init_msg);
  /* A stop asked for during the start is acted on between its steps (the
   * backend, each weights file and --warm plan, each receive buffer), not
   * once it is done: no point in serving, and systemd or the kubelet would
   * kill a daemon that takes minutes to stop. */
  if (early_stop()) return stop_before_serving(s);
  int lrc = hfd_models_load_initial(s);
  if (lrc > 0 || (lrc == 0 && early_stop())) return stop_before_serving(s);
  if (lrc) return 1;
  if (hfd_limits_derive(s)) return 1;
  if (hfd_limits_fds(s)) return 1;
  /* Receive buffers for the --warm shapes (float32 frames of the most
   * values per pixel any variant takes, an estimate included), faulted in
   * before the first frame, within the memory kept between runs
   * (recv_pool.c); before the listeners open, as a part of the start a
   * stop does not wait for (a second or more for large shapes). */
  int channels = 0;
  for (int i = 0; i < s->num_variants; i++)
    if (s->variants[i].model && s->variants[i].model->cfg.in_channels > channels)
      channels = s->variants[i].model->cfg.in_channels;
  uint64_t plans = atomic_load(&w->cached_bytes);
  uint64_t room = plans < w->cache_cap ? w->cache_cap - plans : 0;
  for (int i = 0; i < cfg.num_warm && !early_stop(); i++) {
    /* A shape over the lowered size was warned about (limits.c): none of
     * its frames come through the socket. */
    if (cfg.warm[i].width > s->max_width || cfg.warm[i].height > s->max_height) continue;
    size_t bytes = (size_t)cfg.warm[i].width * cfg.warm[i].height * channels * sizeof(float);
    if (hfd_rpool_prefault(&s->rpool, bytes, room))
      hfd_log("no receive buffer kept for %dx%d: over the memory kept between runs",
              cfg.warm[i].width, cfg.warm[i].height);
  }
  if (early_stop()) return stop_before_serving(s);
  if ((rc = uv_signal_init(s->loop, &s->sigint)) < 0 ||
      (rc = uv_signal_init(s->loop, &s->sigterm)) < 0 ||
      (rc = uv_signal_init(s->loop, &s->sighup)) < 0 ||
      (rc = uv_signal_init(s->loop, &s->sigusr1)) < 0 ||
      (rc = uv_timer_init(s->loop, &s->drain_timer)) < 0 ||
      (rc = uv_timer_init(s->loop, &s->flush_timer)) < 0 ||
      (rc = uv_timer_init(s->loop, &s->sweep_timer)) < 0 ||
      (rc = uv_timer_init(s->loop, &s->beat_timer)) < 0 ||
      (rc = uv_check_init(s->loop, &s->accept_check)) < 0) {
    hfd_err("libuv init: %s", uv_strerror(rc));
    return 1;
  }
  s->accept_check.data = s;
  s->sigint.data = s->sigterm.data = s->drain_timer.data = s->sweep_timer.data = s;
  s->sighup.data = s->sigusr1.data = s->beat_timer.data = s;
  s->flush_timer.data = s;
  int shortest = 0;
  if (cfg.stall_timeout_ms > 0) shortest = cfg.stall_timeout_ms;
  if (cfg.handshake_timeout_ms > 0 && (!shortest || cfg.handshake_timeout_ms < shortest))
    shortest = cfg.handshake_timeout_ms;
  if (shortest) {
    /* Checked four times per (shortest) timeout, at least once a second:
     * a late peer is cut off within 1.25x its timeout. */
    uint64_t every = (uint64_t)(shortest / 4 > 1000 ? 1000 : shortest / 4);
    if (every < 1) every = 1;
    if ((rc = uv_timer_start(&s->sweep_timer, on_sweep, every, every)) < 0) {
      hfd_err("sweep timer: %s", uv_strerror(rc));
      return 1;
    }
  }
  /* The heartbeat beats four times per watchdog limit (at most once a
   * second), and at least twice per systemd watchdog interval. */
  uint64_t beat = (uint64_t)cfg.watchdog_ms / 4 < 1000 ? (uint64_t)cfg.watchdog_ms / 4 : 1000;
  if (s->watchdog_usec && s->watchdog_usec / 2000 < beat) beat = s->watchdog_usec / 2000;
  if (beat < 1) beat = 1;
  if ((rc = uv_timer_start(&s->beat_timer, on_beat, beat, beat)) < 0) {
    hfd_err("heartbeat timer: %s", uv_strerror(rc));
    return 1;
  }
  if ((rc = uv_signal_start(&s->sigint, on_signal, SIGINT)) < 0 ||
      (rc = uv_signal_start(&s->sigterm, on_signal, SIGTERM)) < 0 ||
      (rc = uv_signal_start(&s->sighup, on_hup, SIGHUP)) < 0 ||
      (rc = uv_signal_start(&s->sigusr1, on_usr1, SIGUSR1)) < 0) {
    hfd_err("signal handlers: %s", uv_strerror(rc));
    return 1;
  }
  /* Every listener or none: a daemon that cannot open one of them stops
   * here, before it is ready, rather than serve on the others and leave
   * the missing one unnoticed (docs/SERVER.md, "Socket directory"). */
  for (int i = 0; i < cfg.num_listen; i++)
    if (open_listener(s, cfg.listen[i], &cfg.listen_url[i])) {
      remove_files(s);
      return 1;
    }
  if (cfg.http && hfd_http_start(s, http_url, sizeof http_url)) {
    remove_files(s);
    return 1;
  }
  int serving = 0;
  for (int i = 0; i < s->num_variants; i++) serving += s->variants[i].model != NULL;
  hfd_notice("serving: %d variant(s), max batch %d, queue %d, max in-flight %d per connection, "
             "max %dx%d, memory %llu MiB, shared memory %llu MiB (%llu MiB per client, %llu MiB "
             "per connection)",
             serving, cfg.max_batch, cfg.queue_size, cfg.max_inflight, s->max_width,
             s->max_height, (unsigned long long)(cfg.max_memory_bytes >> 20),
             (unsigned long long)(cfg.max_shm_bytes >> 20),
             (unsigned long long)((hfd_shm_client_cap(s) + (1 << 20) - 1) >> 20),
             (unsigned long long)((hfd_shm_conn_cap(s) + (1 << 20) - 1) >> 20));
  /* The operator's own value may be below what the default guarantees. */
  if (cfg.max_shm_bytes && hfd_shm_segment_max(s) < hfd_shm_largest_frame(s)) {
    /* The option that binds: the smallest of those given. */
    const char *opt = "--max-shm-mb";
    uint64_t val = cfg.max_shm_bytes;
    if (cfg.max_shm_client_bytes && cfg.max_shm_client_bytes < val) {
      opt = "--max-shm-mb-per-client";
      val = cfg.max_shm_client_bytes;
    }
    if (cfg.max_shm_conn_bytes && cfg.max_shm_conn_bytes < val) {
      opt = "--max-shm-mb-per-connection";
      val = cfg.max_shm_conn_bytes;
    }
    hfd_warn("a frame of %dx%d needs %.1f MiB of shared segments, over what one connection may "
             "hold (%s %llu): such frames must go through the socket; raise it, or lower "
             "--max-size", s->max_width, s->max_height, hfd_shm_largest_frame(s) / 1048576.0, opt,
             (unsigned long long)(val >> 20));
  }

  if (cfg.ready_file) {
    if (hfd_ready_file_write(s, http_url)) {
      remove_files(s);
      hfd_rpool_free(&s->rpool);
      return 1;
    }
    s->ready_written = 1;
  }
  hfd_notify_ready(s);
  replay_early_signals();

  rc = uv_run(s->loop, UV_RUN_DEFAULT);
  ignore_stop_signals();
  if (rc != 0) hfd_err("event loop ended with %d active handle(s)", rc);
  rc = uv_loop_close(s->loop);
  if (rc < 0) hfd_err("uv_loop_close: %s", uv_strerror(rc));
  hfd_http_stop(s);
  hfd_tls_free(s);
  remove_files(s);
  /* Frames pushed out of the queue (conn.c) are answered by a RESULT of
   * status BUSY, which STATS counts as failed; here they are overload.
   * Frames that came while draining were never admitted: refused with an
   * ERROR SHUTTING_DOWN, counted apart (and logged at debug level only). */
  uint64_t ok = s->served_answered, failed = s->failed_answered;
  hfd_notice("stopped: %llu request(s) served, %llu failed, %llu pushed out of the queue "
             "(BUSY), %llu refused while draining (SHUTTING_DOWN), %llu answer(s) not "
             "delivered (peer gone or not reading), %llu connection(s) in all",
             (unsigned long long)ok, (unsigned long long)failed,
             (unsigned long long)s->pushed_out_answered,
             (unsigned long long)s->refused_draining, (unsigned long long)s->replies_lost,
             (unsigned long long)s->conns_total);
  hfd_rpool_free(&s->rpool);
  hfd_config_free(&cfg);
  return 0;
}
