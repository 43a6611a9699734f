/*
 * tls.c: TLS on TCP listeners (--listen tls:HOST:PORT), with OpenSSL
 * (Debian's libssl-dev) driven through memory BIOs, so that the one loop
 * thread never blocks on it: ciphertext comes from libuv into the read BIO,
 * plaintext goes to the connection's read state machine exactly as a plain
 * socket's bytes would (conn.c's alloc and read callbacks), and what OpenSSL
 * writes into the write BIO leaves with uv_write.
 *
 * conn.c calls the hfd_io_* functions instead of libuv's stream calls; for
 * a plain connection they are those calls, for a TLS one they go through
 * here. What conn.c relies on is kept:
 *  - a write's callback runs once its last byte has been handed to the
 *    socket (or with an error when the connection closes first), so its
 *    buffers stay valid until then and are encrypted a piece at a time as
 *    the socket drains (a 100 MB RESULT is never encrypted whole);
 *  - reading stops when asked, and resumes with what OpenSSL had already
 *    decrypted (from an idle handle, not from inside the caller);
 *  - a shutdown sends close_notify after the last queued write, then shuts
 *    the socket down.
 *
 * A handshake's steps (SSL_do_handshake: the key exchange, the signature,
 * a client certificate's verification) run on the handshake threads
 * (pool.c), not on the loop: they cost the server far more than they cost
 * a peer replaying a recorded ClientHello, and come before any token is
 * checked. While a step runs there the SSL object is that thread's alone:
 * the loop stops reading the socket, and touches neither the SSL object
 * nor its BIOs until the step is back (step_busy). Records of an
 * established session are encrypted and decrypted on the loop, a piece at
 * a time (docs/SERVER.md, "TLS": a few microseconds a piece, paid by
 * clients that passed their handshake).
 *
 * Certificates (--tls-cert, --tls-key, --tls-client-ca) are read at start
 * and again on SIGHUP: a new SSL_CTX is built and swapped in when it loads
 * whole, else the one before keeps serving. Connections keep the context
 * they were accepted with (OpenSSL counts the references).
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <fcntl.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>

#include "server.h"

/* Plaintext encrypted per uv_write, and ciphertext writes in flight at
 * once: enough to keep a fast link busy, little memory per connection. */
#define TLS_CHUNK ((size_t)256 << 10)
#define TLS_WRITES_IN_FLIGHT 2
/* Ciphertext read from the socket at a time. */
#define TLS_RBUF ((size_t)64 << 10)
/* A TLS record's header, and the longest plaintext record (RFC 8446, 5.1):
 * a first record announcing more is refused by OpenSSL at once. */
#define TLS_RECORD_HEADER 5
#define TLS_RECORD_MAX 16384
/* The key-exchange groups offered (ctx_build). */
#define TLS_GROUPS "X25519:P-256:P-384"

struct hfd_tls {
  SSL_CTX *ctx;
  uv_idle_t idle;                /* resumes reading what OpenSSL has buffered */
  int idle_ready;
  hfd_conn *resume;              /* connections waiting for the idle handle */
  hfd_pool *pool;                /* the handshake threads */
  /* Ciphertext read from a socket, copied into its read BIO within the
   * same callback: one buffer serves every connection (the loop reads
   * one socket at a time), not 64 KiB zeroed for each one accepted. */
  char rbuf[TLS_RBUF];
};

/* A write conn.c asked for: its buffers, encrypted as the socket drains. */
typedef struct tls_wreq {
  struct tls_wreq *next;
  uv_write_t *req;
  uv_write_cb cb;
  uv_buf_t bufs[3];
  unsigned nbufs, cur;           /* the buffer being encrypted */
  size_t off;                    /* within it */
} tls_wreq;

/* One uv_write of ciphertext, and the writes it completes. */
typedef struct tls_raw {
  uv_write_t req;
  hfd_conn *c;
  tls_wreq *done;                /* their last byte is in this write */
  size_t plain;                  /* plaintext bytes it carries */
  size_t len;
  int close_after;
  char data[];
} tls_raw;

struct hfd_tls_conn {
  SSL *ssl;
  BIO *rbio, *wbio;              /* owned by ssl */
  uv_alloc_cb user_alloc;
  uv_read_cb user_read;
  int reading;                   /* conn.c wants bytes */
  int raw_reading;               /* uv_read_start on the socket */
  int established;
  int failed;                    /* handshake failed: closing after the alert */
  int eof;                       /* close_notify or EOF delivered */
  int answered;                  /* a handshake flight was written: the peer sent a whole
                                  * ClientHello (--max-handshakes) */
  /* The handshake's steps, on the handshake threads. */
  hfd_pool_task step;
  hfd_conn *conn;
  int step_busy;                 /* loop: a step is with the threads, and the SSL object too */
  _Atomic int step_cancel;       /* the connection closed: the thread skips the step */
  int step_ret, step_err;        /* thread: SSL_do_handshake's return, SSL_get_error's */
  char step_why[960];            /* thread: why the handshake failed, for the log */
  uint64_t fed;                  /* ciphertext given to OpenSSL before the handshake ended */
  uint8_t first[TLS_RECORD_HEADER]; /* the first record's header */
  int hello_whole;               /* the first record (a ClientHello) is whole: worth a step */
  int record_seen;               /* a whole record was seen waiting in the socket, unread */
  hfd_conn *resume_next;
  int in_resume;
  tls_wreq *q_head, *q_tail;     /* not yet wholly encrypted */
  tls_wreq *encrypted;           /* wholly encrypted, waiting for the next raw write */
  int raw_in_flight;
  size_t plain_unsent;           /* plaintext queued and not yet written */
  uv_shutdown_t *shutdown_req;   /* deferred until the queue is out */
  uv_shutdown_cb shutdown_cb;
};

/* ---- errors -------------------------------------------------------------- */

/* OpenSSL's error queue as one line (and cleared), for the log. */
static const char *ssl_errors(char *buf, size_t cap) {
  size_t used = 0;
  buf[0] = 0;
  unsigned long e;
  while ((e = ERR_get_error()) != 0) {
    char one[256];
    ERR_error_string_n(e, one, sizeof one);
    int n = snprintf(buf + used, cap - used, "%s%s", used ? "; " : "", one);
    if (n < 0 || (size_t)n >= cap - used) break;
    used += (size_t)n;
  }
  if (!buf[0]) snprintf(buf, cap, "no detail from OpenSSL");
  return buf;
}

/* ---- contexts -------------------------------------------------------------- */

/* What to say of a file OpenSSL could not read that holds no PEM block of
 * the kind wanted, which its errors ("no start line", "DECODER
 * routines::unsupported") do not say: a DER file, or the key given for the
 * certificate or the other way round. "" when the file has such a block
 * (OpenSSL's reason then stands). */
static const char *not_pem(const char *path, int key) {
  /* A directory opens and reads as empty: it is no DER file. */
  struct stat st;
  if (stat(path, &st) == 0 && S_ISDIR(st.st_mode))
    return " is a directory: give the PEM file in it (of a Kubernetes TLS Secret mounted "
           "there, DIR/tls.crt for --tls-cert and DIR/tls.key for --tls-key)";
  FILE *f = fopen(path, "rb");
  if (!f) return "";
  static char buf[65536];
  size_t n = fread(buf, 1, sizeof buf - 1, f);
  fclose(f);
  buf[n] = 0;
  for (size_t i = 0; i < n; i++)
    if (!buf[i]) buf[i] = ' ';  /* binary: keep searching past a zero byte */
  if (!strstr(buf, "-----BEGIN"))
    return key ? " holds no PEM key (no -----BEGIN line; a DER key converts with "
                 "openssl pkey -inform DER -in FILE -out FILE.pem)"
               : " holds no PEM certificate (no -----BEGIN line; a DER certificate converts "
                 "with openssl x509 -inform DER -in FILE -out FILE.pem)";
  if (key && !strstr(buf, "PRIVATE KEY-----"))
    return " holds no private key (no -----BEGIN ... PRIVATE KEY----- block: a certificate "
           "given in its place?)";
  if (!key && !strstr(buf, "-----BEGIN CERTIFICATE-----"))
    return " holds no certificate (no -----BEGIN CERTIFICATE----- block: a key or a request "
           "given in its place?)";
  return "";
}

/* A file the daemon cannot open, said before OpenSSL reads it (whose
 * error would be "error:8000000D:system library::Permission denied"):
 * which file, who the daemon runs as, who owns the file, and the fix, as
 * for the socket directory. A key is readable by the daemon's user alone;
 * a certificate or CA may be read by anyone. */
static int unreadable(const char *opt, const char *path, int secret, char *why, size_t whylen) {
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    close(fd);
    return 0;
  }
  int err = errno;
  struct stat st;
  if ((err == EACCES || err == EPERM) && stat(path, &st) == 0) {
    char user[64];
    hfd_user_name(user, sizeof user);
    snprintf(why, whylen,
             "%s %s: permission denied: hairfilterd runs as uid %ld (%s) gid %ld and cannot read "
             "it (owner uid %ld gid %ld, mode %04o); make it readable for that user, e.g. "
             "install -o %s -m %s NEW-FILE %s, or chown %s %s (docs/SERVER.md, \"TLS\")",
             opt, path, (long)geteuid(), user, (long)getegid(), (long)st.st_uid,
             (long)st.st_gid, (unsigned)(st.st_mode & 07777), user, secret ? "0600" : "0644",
             path, user, path);
  } else {
    snprintf(why, whylen, "%s %s: %s", opt, path, strerror(err));
  }
  return -1;
}

/* A server context from cfg's files: NULL with why when any of them does
 * not load (missing, not PEM, a key that is not the certificate's). */
static SSL_CTX *ctx_build(const hfd_config *cfg, char *why, size_t whylen) {
  char err[512];
  if (unreadable("--tls-cert", cfg->tls_cert, 0, why, whylen) ||
      unreadable("--tls-key", cfg->tls_key, 1, why, whylen) ||
      (cfg->tls_client_ca && unreadable("--tls-client-ca", cfg->tls_client_ca, 0, why, whylen)))
    return NULL;
  SSL_CTX *ctx = SSL_CTX_new(TLS_server_method());
  if (!ctx) {
    snprintf(why, whylen, "SSL_CTX_new: %s", ssl_errors(err, sizeof err));
    return NULL;
  }
  /* TLS 1.2 at least (1.3 is preferred by the handshake); no
   * renegotiation, which a memory-BIO server need not support and which
   * has been a source of attacks; no compression (CRIME). */
  SSL_CTX_set_min_proto_version(ctx, TLS1_2_VERSION);
  SSL_CTX_set_options(ctx, SSL_OP_NO_RENEGOTIATION | SSL_OP_NO_COMPRESSION |
                               SSL_OP_CIPHER_SERVER_PREFERENCE);
  SSL_CTX_set_mode(ctx, SSL_MODE_RELEASE_BUFFERS);
  /* Key exchange on elliptic curves only: the client picks the group, and
   * OpenSSL's default list lets it pick finite-field Diffie-Hellman up to
   * ffdhe8192, which cost the daemon 118 ms a handshake against 0.33 ms
   * for X25519, before any token is checked. Every TLS 1.3 client has
   * X25519 or P-256. */
  if (SSL_CTX_set1_groups_list(ctx, TLS_GROUPS) != 1) {
    snprintf(why, whylen, "TLS key-exchange groups %s: %s", TLS_GROUPS,
             ssl_errors(err, sizeof err));
    goto fail;
  }
  if (SSL_CTX_use_certificate_chain_file(ctx, cfg->tls_cert) != 1) {
    const char *hint = not_pem(cfg->tls_cert, 0);
    snprintf(why, whylen, "--tls-cert %s%s: %s", cfg->tls_cert, hint, ssl_errors(err, sizeof err));
    goto fail;
  }
  if (SSL_CTX_use_PrivateKey_file(ctx, cfg->tls_key, SSL_FILETYPE_PEM) != 1) {
    int mismatch = ERR_GET_REASON(ERR_peek_last_error()) == X509_R_KEY_VALUES_MISMATCH;
    const char *hint = mismatch ? " is not the key of --tls-cert" : not_pem(cfg->tls_key, 1);
    snprintf(why, whylen, "--tls-key %s%s: %s", cfg->tls_key, hint, ssl_errors(err, sizeof err));
    if (mismatch) snprintf(why + strlen(why), whylen - strlen(why), " (%s)", cfg->tls_cert);
    goto fail;
  }
  if (SSL_CTX_check_private_key(ctx) != 1) {
    snprintf(why, whylen, "--tls-key %s is not the key of --tls-cert %s: %s", cfg->tls_key,
             cfg->tls_cert, ssl_errors(err, sizeof err));
    goto fail;
  }
  if (cfg->tls_client_ca) {
    /* Mutual TLS: a client without a certificate this CA signed fails the
     * handshake. */
    STACK_OF(X509_NAME) *names = SSL_load_client_CA_file(cfg->tls_client_ca);
    if (!names || SSL_CTX_load_verify_locations(ctx, cfg->tls_client_ca, NULL) != 1) {
      if (names) sk_X509_NAME_pop_free(names, X509_NAME_free);
      const char *hint = not_pem(cfg->tls_client_ca, 0);
      snprintf(why, whylen, "--tls-client-ca %s%s: %s", cfg->tls_client_ca, hint,
               ssl_errors(err, sizeof err));
      goto fail;
    }
    SSL_CTX_set_client_CA_list(ctx, names);
    SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT, NULL);
  }
  return ctx;
fail:
  SSL_CTX_free(ctx);
  return NULL;
}

/* "subject CN=..., valid until ..." of the context's certificate. */
static void ctx_describe(SSL_CTX *ctx, char *buf, size_t cap) {
  X509 *x = SSL_CTX_get0_certificate(ctx);
  buf[0] = 0;
  if (!x) return;
  char subject[256] = "?", until[64] = "?";
  X509_NAME_oneline(X509_get_subject_name(x), subject, sizeof subject);
  BIO *b = BIO_new(BIO_s_mem());
  if (b && ASN1_TIME_print(b, X509_get0_notAfter(x)) == 1) {
    int n = BIO_read(b, until, (int)sizeof until - 1);
    until[n > 0 ? n : 0] = 0;
  }
  BIO_free(b);
  snprintf(buf, cap, "certificate %s, valid until %s", subject, until);
  if (X509_cmp_current_time(X509_get0_notAfter(x)) < 0)
    snprintf(buf + strlen(buf), cap - strlen(buf), " (EXPIRED: clients will refuse it)");
}

int hfd_tls_not_after(const hfd_server *s, long long *unix_s) {
  if (!s->tls || !s->tls->ctx) return -1;
  X509 *x = SSL_CTX_get0_certificate(s->tls->ctx);
  if (!x) return -1;
  /* The difference from the epoch, in OpenSSL's own calendar arithmetic
   * (timegm is not POSIX, and mktime would read the time zone). */
  ASN1_TIME *epoch = ASN1_TIME_set(NULL, 0);
  int day = 0, sec = 0;
  int ok = epoch && ASN1_TIME_diff(&day, &sec, epoch, X509_get0_notAfter(x)) == 1;
  ASN1_TIME_free(epoch);
  if (!ok) return -1;
  *unix_s = (long long)day * 86400 + sec;
  return 0;
}

static int wants_tls(const hfd_config *cfg) {
  for (int i = 0; i < cfg->num_listen; i++)
    if (cfg->listen_url[i].kind == HFP_URL_TCP && cfg->listen_url[i].tls) return 1;
  return 0;
}

static void on_idle(uv_idle_t *h);

int hfd_tls_init(hfd_server *s) {
  const hfd_config *cfg = s->cfg;
  if (!wants_tls(cfg)) return 0;
  struct hfd_tls *t = calloc(1, sizeof *t);
  if (!t) {
    hfd_err("out of memory for TLS");
    return -1;
  }
  char why[1024];
  t->ctx = ctx_build(cfg, why, sizeof why);
  if (!t->ctx) {
    hfd_err("TLS: %s", why);
    free(t);
    return -1;
  }
  int rc = uv_idle_init(s->loop, &t->idle);
  if (rc < 0) {
    hfd_err("TLS: uv_idle_init: %s", uv_strerror(rc));
    SSL_CTX_free(t->ctx);
    free(t);
    return -1;
  }
  t->idle.data = s;
  t->idle_ready = 1;
  s->tls = t;
  if (hfd_pool_start(&t->pool, s->loop, "TLS handshake")) return -1;
  char desc[400];
  ctx_describe(t->ctx, desc, sizeof desc);
  hfd_log("TLS: %s%s%s; handshakes on %d thread(s) of their own", desc,
          cfg->tls_client_ca ? "; client certificates from " : "",
          cfg->tls_client_ca ? cfg->tls_client_ca : "", hfd_pool_threads(t->pool));
  return 0;
}

int hfd_tls_reload(hfd_server *s, const hfd_config *n) {
  struct hfd_tls *t = s->tls;
  if (!t) return 0;
  if (!n->tls_cert || !n->tls_key) {
    hfd_err("reload: TLS: the configuration no longer names --tls-cert and --tls-key; the "
            "certificate loaded before keeps serving");
    return -1;
  }
  char why[1024];
  SSL_CTX *ctx = ctx_build(n, why, sizeof why);
  if (!ctx) {
    hfd_err("reload: TLS: %s; the certificate loaded before keeps serving", why);
    return -1;
  }
  /* Connections hold their own reference to the context they began with. */
  SSL_CTX_free(t->ctx);
  t->ctx = ctx;
  char desc[400];
  ctx_describe(ctx, desc, sizeof desc);
  hfd_notice("reload: TLS: %s; new connections use it", desc);
  return 0;
}

void hfd_tls_stop(hfd_server *s) {
  struct hfd_tls *t = s->tls;
  if (t && t->idle_ready && !uv_is_closing((uv_handle_t *)&t->idle))
    uv_close((uv_handle_t *)&t->idle, NULL);
  if (t) hfd_pool_close(t->pool);
}

int hfd_tls_steps_outstanding(const hfd_server *s) {
  return s->tls ? hfd_pool_outstanding(s->tls->pool) : 0;
}

void hfd_tls_free(hfd_server *s) {
  struct hfd_tls *t = s->tls;
  if (!t) return;
  hfd_pool_free(t->pool);
  SSL_CTX_free(t->ctx);
  free(t);
  s->tls = NULL;
}

/* ---- writing ciphertext --------------------------------------------------- */

static void pump(hfd_conn *c);
static void flush_queue(hfd_conn *c);

static void complete_list(tls_wreq *w, int status) {
  while (w) {
    tls_wreq *next = w->next;
    uv_write_t *req = w->req;
    uv_write_cb cb = w->cb;
    free(w);
    cb(req, status);
    w = next;
  }
}

static void on_raw_written(uv_write_t *req, int status) {
  tls_raw *r = (tls_raw *)req;
  hfd_conn *c = r->c;
  struct hfd_tls_conn *t = c->tls;
  t->raw_in_flight--;
  t->plain_unsent -= r->plain;
  tls_wreq *done = r->done;
  int close_after = r->close_after;
  free(r);
  /* conn.c's callbacks may close the connection; c itself stays until
   * on_closed (its handle is not closed before this returns). */
  complete_list(done, status);
  if (status < 0) {
    if (status != UV_ECANCELED)
      hfd_debug("conn %llu: TLS write failed: %s", (unsigned long long)c->id,
                uv_strerror(status));
    hfd_conn_close(c);
    return;
  }
  if (close_after) {
    hfd_conn_close(c);
    return;
  }
  flush_queue(c);
}

/* Hands what OpenSSL has written into the write BIO to the socket, with
 * the writes it completes. */
static int send_out(hfd_conn *c, tls_wreq *done, size_t plain, int close_after) {
  struct hfd_tls_conn *t = c->tls;
  size_t len = (size_t)BIO_ctrl_pending(t->wbio);
  if (!len && !done && !close_after) return 0;
  tls_raw *r = malloc(sizeof *r + (len ? len : 1));
  if (!r) {
    hfd_err("conn %llu: out of memory for TLS output; closing it", (unsigned long long)c->id);
    complete_list(done, UV_ENOMEM);
    hfd_conn_close(c);
    return -1;
  }
  r->c = c;
  r->done = done;
  r->plain = plain;
  r->close_after = close_after;
  r->len = len;
  if (len && BIO_read(t->wbio, r->data, (int)len) != (int)len) {
    hfd_err("conn %llu: TLS write BIO short read; closing it", (unsigned long long)c->id);
    free(r);
    complete_list(done, UV_EIO);
    hfd_conn_close(c);
    return -1;
  }
  uv_buf_t b = uv_buf_init(r->data, (unsigned)len);
  int rc = uv_write(&r->req, &c->h.stream, &b, 1, on_raw_written);
  if (rc < 0) {
    hfd_debug("conn %llu: uv_write: %s", (unsigned long long)c->id, uv_strerror(rc));
    free(r);
    complete_list(done, rc);
    hfd_conn_close(c);
    return -1;
  }
  t->raw_in_flight++;
  return 0;
}

/* Encrypts queued writes, a chunk per uv_write, while fewer than
 * TLS_WRITES_IN_FLIGHT are on their way; then a deferred shutdown. */
static void flush_queue(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (c->closing || !t->established) return;
  while (t->q_head && t->raw_in_flight < TLS_WRITES_IN_FLIGHT) {
    size_t plain = 0;
    tls_wreq *done = NULL, **done_tail = &done;
    while (t->q_head && plain < TLS_CHUNK) {
      tls_wreq *w = t->q_head;
      if (w->cur < w->nbufs) {
        uv_buf_t *b = &w->bufs[w->cur];
        size_t n = b->len - w->off;
        if (n > TLS_CHUNK - plain) n = TLS_CHUNK - plain;
        if (n > 0) {
          /* A memory BIO never blocks, so SSL_write takes it all. */
          int r = SSL_write(t->ssl, b->base + w->off, (int)n);
          if (r <= 0) {
            char err[512];
            hfd_err("conn %llu: TLS encrypt: %s; closing it", (unsigned long long)c->id,
                    ssl_errors(err, sizeof err));
            hfd_conn_close(c);
            complete_list(done, UV_EIO);
            return;
          }
          w->off += (size_t)r;
          plain += (size_t)r;
        }
        if (w->off == b->len) {
          w->cur++;
          w->off = 0;
        }
        continue;
      }
      t->q_head = w->next;
      if (!t->q_head) t->q_tail = NULL;
      w->next = NULL;
      *done_tail = w;
      done_tail = &w->next;
    }
    if (send_out(c, done, plain, 0)) return;
  }
  if (!t->q_head && t->shutdown_req && !c->closing) {
    uv_shutdown_t *req = t->shutdown_req;
    uv_shutdown_cb cb = t->shutdown_cb;
    t->shutdown_req = NULL;
    SSL_shutdown(t->ssl);   /* close_notify into the write BIO */
    ERR_clear_error();
    if (send_out(c, NULL, 0, 0)) {
      cb(req, UV_ECANCELED);
      return;
    }
    int rc = uv_shutdown(req, &c->h.stream, cb);
    if (rc < 0) cb(req, rc);
  }
}

/* ---- reading plaintext ---------------------------------------------------- */

static void resume_later(hfd_conn *c) {
  struct hfd_tls *st = c->srv->tls;
  struct hfd_tls_conn *t = c->tls;
  if (t->in_resume || !st->idle_ready || uv_is_closing((uv_handle_t *)&st->idle)) return;
  t->in_resume = 1;
  t->resume_next = st->resume;
  st->resume = c;
  int rc = uv_idle_start(&st->idle, on_idle);
  if (rc < 0) hfd_err("TLS: uv_idle_start: %s", uv_strerror(rc));
}

static void resume_forget(hfd_conn *c) {
  struct hfd_tls *st = c->srv->tls;
  struct hfd_tls_conn *t = c->tls;
  if (!t->in_resume) return;
  for (hfd_conn **p = &st->resume; *p; p = &(*p)->tls->resume_next)
    if (*p == c) {
      *p = t->resume_next;
      break;
    }
  t->in_resume = 0;
}

static void on_idle(uv_idle_t *h) {
  hfd_server *s = h->data;
  struct hfd_tls *st = s->tls;
  hfd_conn *list = st->resume;
  st->resume = NULL;
  uv_idle_stop(h);
  while (list) {
    hfd_conn *c = list;
    list = c->tls->resume_next;
    c->tls->in_resume = 0;
    pump(c);
  }
}

/* The peer's certificate in a line, for the log. */
static void peer_subject(SSL *ssl, char *buf, size_t cap) {
  X509 *x = SSL_get0_peer_certificate(ssl);
  buf[0] = 0;
  if (x) X509_NAME_oneline(X509_get_subject_name(x), buf, (int)cap);
}

/* Which side refused, in words, from OpenSSL's last error: an alert the
 * client sent (its reason is SSL_AD_REASON_OFFSET + the alert), or this
 * server's verification of the client's certificate. NULL: neither. */
static const char *refusal(SSL *ssl, unsigned long e, char *buf, size_t cap) {
  int reason = ERR_GET_LIB(e) == ERR_LIB_SSL ? ERR_GET_REASON(e) : 0;
  long v = SSL_get_verify_result(ssl);
  if (reason > SSL_AD_REASON_OFFSET && reason < SSL_AD_REASON_OFFSET + 256) {
    int alert = reason - SSL_AD_REASON_OFFSET;
    switch (alert) {
      case SSL_AD_BAD_CERTIFICATE:
      case SSL_AD_UNSUPPORTED_CERTIFICATE:
      case SSL_AD_CERTIFICATE_REVOKED:
      case SSL_AD_CERTIFICATE_EXPIRED:
      case SSL_AD_CERTIFICATE_UNKNOWN:
      case SSL_AD_UNKNOWN_CA:
      case SSL_AD_CERTIFICATE_REQUIRED:
        snprintf(buf, cap, "the client refused this server's certificate: %s (is the client "
                 "given the CA that signed --tls-cert, and does the certificate name the host "
                 "it connects to?)", SSL_alert_desc_string_long(alert));
        break;
      default:
        snprintf(buf, cap, "the client ended the handshake with the alert: %s",
                 SSL_alert_desc_string_long(alert));
        break;
    }
    return buf;
  }
  if (reason == SSL_R_PEER_DID_NOT_RETURN_A_CERTIFICATE) {
    snprintf(buf, cap, "this server refused the client's certificate: the client sent no "
             "certificate (--tls-client-ca requires one)");
    return buf;
  }
  if (v != X509_V_OK) {
    snprintf(buf, cap, "this server refused the client's certificate: %s",
             X509_verify_cert_error_string(v));
    return buf;
  }
  return NULL;
}

/* The step failed: t->step_why says why (written on the thread, which
 * holds OpenSSL's error queue). */
static void handshake_failed(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  char kv[300];
  c->srv->protocol_errors++;
  if (hfd_conn_log_allowed())
    hfd_err("TLS handshake failed: %s; closing the connection%s", t->step_why,
            (snprintf(kv, sizeof kv, " conn=%llu peer=%s", (unsigned long long)c->id, c->peer),
             kv));
  t->failed = 1;
  if (t->raw_reading) uv_read_stop(&c->h.stream);
  t->raw_reading = 0;
  /* The alert OpenSSL wrote goes out, then the connection closes. */
  send_out(c, NULL, 0, 1);
}

/* ---- the handshake, on the handshake threads ------------------------------ */

static struct hfd_tls_conn *of_step(hfd_pool_task *task) {
  return (struct hfd_tls_conn *)((char *)task - offsetof(struct hfd_tls_conn, step));
}

/* One handshake step, on a handshake thread: what OpenSSL can do with the
 * ciphertext fed so far. OpenSSL's error queue is this thread's, so a
 * failure is put in words here. */
static void step_run(hfd_pool_task *task) {
  struct hfd_tls_conn *t = of_step(task);
  t->step_ret = 0;
  t->step_err = SSL_ERROR_SYSCALL;
  snprintf(t->step_why, sizeof t->step_why, "connection error");
  if (atomic_load(&t->step_cancel)) return;   /* closed meanwhile: its done only releases */
  ERR_clear_error();
  int r = SSL_do_handshake(t->ssl);
  t->step_ret = r;
  if (r == 1) {
    t->step_err = SSL_ERROR_NONE;
    ERR_clear_error();
    return;
  }
  int e = SSL_get_error(t->ssl, r);
  t->step_err = e;
  if (e == SSL_ERROR_SSL) {
    char err[512], who[400];
    const char *why = refusal(t->ssl, ERR_peek_last_error(), who, sizeof who);
    const char *what = ssl_errors(err, sizeof err);
    snprintf(t->step_why, sizeof t->step_why, "%s%s%s", why ? why : what,
             why ? "; OpenSSL: " : "", why ? what : "");
  }
  ERR_clear_error();
}

static void raw_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf);
static void raw_read(uv_stream_t *stream, ssize_t nread, const uv_buf_t *buf);

/* Reads the socket again, when the connection wants bytes (always before
 * the handshake ends): 0, or -1 when it failed and c is closing. */
static int raw_resume(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (t->raw_reading || t->eof || t->failed || c->closing || t->step_busy) return 0;
  if (t->established && !t->reading) return 0;
  int rc = uv_read_start(&c->h.stream, raw_alloc, raw_read);
  if (rc < 0) {
    hfd_debug("conn %llu: read start: %s", (unsigned long long)c->id, uv_strerror(rc));
    hfd_conn_close(c);
    return -1;
  }
  t->raw_reading = 1;
  return 0;
}

static void step_done(hfd_pool_task *task);

/* Hands the next step to the threads; the socket is not read until it is
 * back (the read BIO is the thread's meanwhile), so what a peer can make
 * the daemon hold is its socket buffer. */
static void step_submit(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (t->raw_reading) {
    int rc = uv_read_stop(&c->h.stream);
    if (rc < 0) hfd_debug("conn %llu: read stop: %s", (unsigned long long)c->id, uv_strerror(rc));
    t->raw_reading = 0;
  }
  t->step.run = step_run;
  t->step.done = step_done;
  atomic_store(&t->step_cancel, 0);
  int rc = hfd_pool_submit(c->srv->tls->pool, &t->step);
  if (rc < 0) {
    hfd_err("conn %llu: TLS handshake: cannot hand it to a thread: %s; closing it",
            (unsigned long long)c->id, rc == UV_ECANCELED ? "stopping" : strerror(-rc));
    hfd_conn_close(c);
    return;
  }
  t->step_busy = 1;
}

static void established_pump(hfd_conn *c);

/* On the loop: a step is back, and the SSL object with it. */
static void step_done(hfd_pool_task *task) {
  struct hfd_tls_conn *t = of_step(task);
  hfd_conn *c = t->conn;
  hfd_server *s = c->srv;
  t->step_busy = 0;
  if (c->closing) {
    hfd_conn_release(c);   /* what on_closed could not free while the step ran */
    hfd_maybe_finish(s);   /* a stop may have waited for it */
    return;
  }
  if (t->step_ret != 1) {
    if (t->step_err == SSL_ERROR_WANT_READ || t->step_err == SSL_ERROR_WANT_WRITE) {
      if (BIO_ctrl_pending(t->wbio)) t->answered = 1;
      if (send_out(c, NULL, 0, 0)) return;
      raw_resume(c);
      return;
    }
    handshake_failed(c);
    return;
  }
  t->established = 1;
  if (hfd_log_level >= HFD_LOG_DEBUG) {
    char subject[256], kv[300];
    peer_subject(t->ssl, subject, sizeof subject);
    snprintf(kv, sizeof kv, " conn=%llu", (unsigned long long)c->id);
    hfd_kv(kv, sizeof kv, "tls", SSL_get_version(t->ssl));
    hfd_kv(kv, sizeof kv, "cipher", SSL_get_cipher_name(t->ssl));
    if (subject[0]) hfd_kv(kv, sizeof kv, "client_cert", subject);
    hfd_debug("TLS established%s", kv);
  }
  /* Reading resumes only when the connection wants bytes; what came with
   * the handshake's last flight (a HELLO) is in the read BIO already. */
  if (raw_resume(c)) return;
  established_pump(c);
}

/* A plain-protocol HELLO on a TLS port: answered in the clear, so the
 * client can say what is wrong instead of a TLS error it cannot explain. */
static int plain_hello(hfd_conn *c, const char *data, size_t n) {
  static const uint8_t magic[4] = {0x48, 0x46, 0x50, 0x31};   /* "HFP1" */
  if (n < 4 || memcmp(data, magic, 4)) return 0;
  hfp_error e;
  memset(&e, 0, sizeof e);
  e.code = HFP_E_PROTOCOL;
  e.fatal = 1;
  snprintf(e.message, sizeof e.message,
           "this listener speaks TLS: connect with tls:HOST:PORT (and the CA's certificate)");
  uint8_t frame[HFP_HEADER_SIZE + 8 + HFP_MESSAGE_MAX];
  int len = hfp_encode_error(frame, sizeof frame, 0, &e);
  c->srv->protocol_errors++;
  char kv[120];
  snprintf(kv, sizeof kv, " conn=%llu peer=%s", (unsigned long long)c->id, c->peer);
  if (hfd_conn_log_allowed())
    hfd_err("PROTOCOL: a plain-text HELLO on TLS listener %s; closing the connection%s",
            c->listener->url, kv);
  struct hfd_tls_conn *t = c->tls;
  t->failed = 1;
  if (t->raw_reading) uv_read_stop(&c->h.stream);
  t->raw_reading = 0;
  if (len > 0) BIO_write(t->wbio, frame, len);
  send_out(c, NULL, 0, 1);
  return 1;
}

static void pump(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (c->closing || t->failed) return;
  if (!t->established) {
    /* Nothing for OpenSSL before the first record is whole: a peer
     * trickling a ClientHello costs a step only once it has sent one. */
    if (!t->step_busy && t->hello_whole) step_submit(c);
    return;
  }
  established_pump(c);
}

/* Plaintext to the connection while it wants it, then what OpenSSL wrote. */
static void established_pump(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (c->closing || t->failed) return;
  while (t->reading && !c->closing && !t->eof) {
    uv_buf_t b;
    t->user_alloc(&c->h.handle, 65536, &b);
    if (!b.len) break;
    int r = SSL_read(t->ssl, b.base, (int)b.len);
    if (r > 0) {
      t->user_read(&c->h.stream, r, &b);
      continue;
    }
    int e = SSL_get_error(t->ssl, r);
    if (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_WANT_WRITE) break;
    if (e == SSL_ERROR_ZERO_RETURN) {
      /* close_notify: the peer's half-close (PROTOCOL.md, "Transport"). */
      t->eof = 1;
      t->user_read(&c->h.stream, UV_EOF, &b);
      break;
    }
    char err[512];
    hfd_debug("conn %llu: TLS read: %s", (unsigned long long)c->id, ssl_errors(err, sizeof err));
    t->eof = 1;
    t->user_read(&c->h.stream, UV_EPROTO, &b);
    break;
  }
  /* A session ticket or a key update may have been written. */
  if (!c->closing && !t->failed) {
    send_out(c, NULL, 0, 0);
    flush_queue(c);
  }
}

static void raw_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf) {
  hfd_conn *c = h->data;
  (void)suggested;
  *buf = uv_buf_init(c->srv->tls->rbuf, (unsigned)sizeof c->srv->tls->rbuf);
}

static void raw_read(uv_stream_t *stream, ssize_t nread, const uv_buf_t *buf) {
  hfd_conn *c = stream->data;
  struct hfd_tls_conn *t = c->tls;
  if (nread == 0 || c->closing || t->failed) return;
  t->record_seen = 0;   /* read: what waits now is looked at afresh */
  if (nread < 0) {
    if (t->raw_reading) uv_read_stop(&c->h.stream);
    t->raw_reading = 0;
    if (!t->established) {
      hfd_debug("conn %llu: peer left during the TLS handshake: %s", (unsigned long long)c->id,
                uv_strerror((int)nread));
      hfd_conn_close(c);
      return;
    }
    if (t->eof) return;
    /* EOF without close_notify is a half-close all the same: nothing the
     * peer sent is taken for more than it was. */
    t->eof = 1;
    uv_buf_t b = uv_buf_init(NULL, 0);
    t->user_read(&c->h.stream, nread, &b);
    return;
  }
  if (!t->established && t->fed == 0 && plain_hello(c, buf->base, (size_t)nread)) return;
  if (BIO_write(t->rbio, buf->base, (int)nread) != (int)nread) {
    hfd_err("conn %llu: TLS read BIO refused data; closing it", (unsigned long long)c->id);
    hfd_conn_close(c);
    return;
  }
  if (!t->established && !t->hello_whole) {
    for (ssize_t i = 0; i < nread && t->fed + (uint64_t)i < TLS_RECORD_HEADER; i++)
      t->first[t->fed + (uint64_t)i] = (uint8_t)buf->base[i];
    t->fed += (uint64_t)nread;
    if (t->fed >= TLS_RECORD_HEADER) {
      /* Not a handshake record, or longer than a record can be: OpenSSL
       * refuses it at once, so the step is run for its error. */
      size_t len = (size_t)t->first[3] << 8 | t->first[4];
      t->hello_whole = t->first[0] != 0x16 || len > TLS_RECORD_MAX ||
                       t->fed >= TLS_RECORD_HEADER + len;
    }
  }
  pump(c);
}

/* ---- connections ------------------------------------------------------------ */

int hfd_tls_conn_start(hfd_conn *c) {
  struct hfd_tls *st = c->srv->tls;
  struct hfd_tls_conn *t = calloc(1, sizeof *t);
  if (!t) return UV_ENOMEM;
  t->ssl = SSL_new(st->ctx);
  t->rbio = BIO_new(BIO_s_mem());
  t->wbio = BIO_new(BIO_s_mem());
  if (!t->ssl || !t->rbio || !t->wbio) {
    SSL_free(t->ssl);
    BIO_free(t->rbio);
    BIO_free(t->wbio);
    free(t);
    ERR_clear_error();
    return UV_ENOMEM;
  }
  /* An empty read BIO says "retry", not EOF. */
  BIO_set_mem_eof_return(t->rbio, -1);
  SSL_set_bio(t->ssl, t->rbio, t->wbio);
  SSL_set_accept_state(t->ssl);
  t->conn = c;
  c->tls = t;
  return 0;
}

void hfd_tls_conn_closing(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (!t) return;
  resume_forget(c);
  /* A step on a thread is skipped if not begun; it comes back all the
   * same, and c is freed after (hfd_tls_stepping). */
  if (t->step_busy) atomic_store(&t->step_cancel, 1);
  tls_wreq *q = t->q_head, *e = t->encrypted;
  t->q_head = t->q_tail = t->encrypted = NULL;
  if (t->shutdown_req) {
    uv_shutdown_t *req = t->shutdown_req;
    t->shutdown_req = NULL;
    t->shutdown_cb(req, UV_ECANCELED);
  }
  complete_list(e, UV_ECANCELED);
  complete_list(q, UV_ECANCELED);
}

void hfd_tls_conn_free(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (!t) return;
  SSL_free(t->ssl);   /* and its BIOs */
  free(t);
  c->tls = NULL;
}

/* ---- the stream calls conn.c makes ---------------------------------------- */

int hfd_io_read_start(hfd_conn *c, uv_alloc_cb alloc_cb, uv_read_cb read_cb) {
  struct hfd_tls_conn *t = c->tls;
  if (!t) return uv_read_start(&c->h.stream, alloc_cb, read_cb);
  t->user_alloc = alloc_cb;
  t->user_read = read_cb;
  t->reading = 1;
  if (!t->raw_reading && !t->eof && !t->failed && !t->step_busy) {
    int rc = uv_read_start(&c->h.stream, raw_alloc, raw_read);
    if (rc < 0) return rc;
    t->raw_reading = 1;
  }
  /* Bytes OpenSSL already holds would wait for more from the socket. */
  if (t->established && (SSL_pending(t->ssl) > 0 || BIO_ctrl_pending(t->rbio) > 0))
    resume_later(c);
  return 0;
}

int hfd_io_read_stop(hfd_conn *c) {
  struct hfd_tls_conn *t = c->tls;
  if (!t) return uv_read_stop(&c->h.stream);
  t->reading = 0;
  resume_forget(c);
  if (!t->raw_reading || !t->established) return 0;   /* the handshake reads on */
  t->raw_reading = 0;
  return uv_read_stop(&c->h.stream);
}

int hfd_io_write(hfd_conn *c, uv_write_t *req, const uv_buf_t *bufs, unsigned nbufs,
                 uv_write_cb cb) {
  struct hfd_tls_conn *t = c->tls;
  if (!t) return uv_write(req, &c->h.stream, bufs, nbufs, cb);
  /* Before the handshake is done the write waits for it (a limit's fatal
   * ERROR reaches a peer that is still negotiating); hfd_tls_overdue
   * closes a connection whose handshake never comes. */
  if (t->failed) return UV_ENOTCONN;
  if (nbufs > 3 || t->shutdown_req) return UV_EINVAL;
  tls_wreq *w = calloc(1, sizeof *w);
  if (!w) return UV_ENOMEM;
  w->req = req;
  w->cb = cb;
  w->nbufs = nbufs;
  for (unsigned i = 0; i < nbufs; i++) {
    w->bufs[i] = bufs[i];
    t->plain_unsent += bufs[i].len;
  }
  if (t->q_tail)
    t->q_tail->next = w;
  else
    t->q_head = w;
  t->q_tail = w;
  flush_queue(c);
  return 0;
}

int hfd_io_shutdown(hfd_conn *c, uv_shutdown_t *req, uv_shutdown_cb cb) {
  struct hfd_tls_conn *t = c->tls;
  if (!t) return uv_shutdown(req, &c->h.stream, cb);
  if (t->failed) return UV_ENOTCONN;
  t->shutdown_req = req;
  t->shutdown_cb = cb;
  flush_queue(c);
  return 0;
}

int hfd_tls_established(const hfd_conn *c) {
  const struct hfd_tls_conn *t = c->tls;
  return t && t->established && !t->failed;
}

int hfd_tls_overdue(const hfd_conn *c, double now_us) {
  const struct hfd_tls_conn *t = c->tls;
  if (!t || t->established || !c->fatal_sent) return 0;
  /* A client racing its handshake finishes it in milliseconds; a peer that
   * has not within the grace never will, and holding it would let a crowd
   * of bare TCP peers on this listener outnumber --max-handshakes. */
  int limit_ms = c->srv->cfg->handshake_timeout_ms > 0 ? c->srv->cfg->handshake_timeout_ms : 10000;
  return now_us - c->t_accept > limit_ms * 1e3 || now_us - c->t_fatal > HFD_TLS_FATAL_GRACE_MS * 1e3;
}

/* Bytes waiting in c's socket, not read yet; 0 on an error. */
static size_t unread(const hfd_conn *c) {
  uv_os_fd_t fd;
  int n = 0;
  if (uv_fileno((const uv_handle_t *)&c->h.handle, &fd) != 0 || ioctl(fd, FIONREAD, &n) != 0 ||
      n < 0)
    return 0;
  return (size_t)n;
}

int hfd_tls_unanswered(const hfd_conn *c) {
  return c->tls && !c->tls->established && !c->tls->answered && !c->tls->hello_whole &&
         !hfd_tls_record_waiting(c);
}

int hfd_tls_stepping(const hfd_conn *c) { return c->tls && c->tls->step_busy; }

int hfd_tls_record_waiting(const hfd_conn *c) {
  if (!c->tls) return 0;
  if (c->tls->record_seen) return 1;
  uv_os_fd_t fd;
  uint8_t h[5];   /* a record's header: type, version, length (big-endian) */
  if (uv_fileno((const uv_handle_t *)&c->h.handle, &fd) != 0 ||
      recv(fd, h, sizeof h, MSG_PEEK | MSG_DONTWAIT) != (ssize_t)sizeof h)
    return 0;
  if (unread(c) < sizeof h + ((size_t)h[3] << 8 | h[4])) return 0;
  c->tls->record_seen = 1;   /* it stays there until raw_read takes it */
  return 1;
}

size_t hfd_io_write_queue_size(const hfd_conn *c) {
  if (!c->tls) return uv_stream_get_write_queue_size(&c->h.stream);
  return c->tls->plain_unsent;
}
