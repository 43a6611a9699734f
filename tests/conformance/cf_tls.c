/*
 * cf_tls.c: the raw-socket cases over a tls: URL. A case writes and reads
 * the protocol's bytes on a socket of its own; for TLS it gets one end of a
 * socketpair, and a thread carries the bytes between the other end and a
 * TLS session with the server, as they come (nothing is held back or
 * merged, so stalls, trickles and cuts reach the server as the case made
 * them). The case's half-close becomes close_notify, the server's
 * close_notify or EOF the case's EOF; a failed handshake closes the pair.
 */
#define _POSIX_C_SOURCE 200809L
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>

#include "cf_internal.h"

typedef struct proxy {
  SSL *ssl;
  int tcp, pair;
} proxy;

static int nonblock(int fd) {
  int fl = fcntl(fd, F_GETFL);
  return fl < 0 ? -1 : fcntl(fd, F_SETFL, fl | O_NONBLOCK);
}

static void *carry(void *arg) {
  proxy *p = arg;
  SSL *ssl = p->ssl;
  int s = p->tcp, b = p->pair;
  for (;;) {
    int r = SSL_connect(ssl);
    if (r == 1) break;
    int e = SSL_get_error(ssl, r);
    if (e != SSL_ERROR_WANT_READ && e != SSL_ERROR_WANT_WRITE) goto done;
    struct pollfd pf = {s, e == SSL_ERROR_WANT_READ ? POLLIN : POLLOUT, 0};
    if (poll(&pf, 1, 20000) <= 0) goto done;
  }
  static _Thread_local uint8_t up[65536], down[65536];
  size_t up_len = 0, up_off = 0, down_len = 0, down_off = 0;
  int b_eof = 0, s_eof = 0, want_write = 0;
  for (;;) {
    int progress = 0;
    if (!b_eof && !up_len) {
      ssize_t n = read(b, up, sizeof up);
      if (n > 0) {
        up_len = (size_t)n;
        up_off = 0;
        progress = 1;
      } else if (n == 0) {
        b_eof = progress = 1;
        SSL_shutdown(ssl);
      } else if (errno != EAGAIN && errno != EINTR) {
        goto done;
      }
    }
    if (up_len) {
      int r = SSL_write(ssl, up + up_off, (int)(up_len - up_off));
      want_write = 0;
      if (r > 0) {
        up_off += (size_t)r;
        if (up_off == up_len) up_len = 0;
        progress = 1;
      } else {
        int e = SSL_get_error(ssl, r);
        if (e != SSL_ERROR_WANT_READ && e != SSL_ERROR_WANT_WRITE) goto done;
        want_write = e == SSL_ERROR_WANT_WRITE;
      }
    }
    if (!s_eof && !down_len) {
      int r = SSL_read(ssl, down, (int)sizeof down);
      if (r > 0) {
        down_len = (size_t)r;
        down_off = 0;
        progress = 1;
      } else {
        int e = SSL_get_error(ssl, r);
        if (e == SSL_ERROR_ZERO_RETURN || (e == SSL_ERROR_SYSCALL && ERR_peek_error() == 0)) {
          s_eof = progress = 1;
          shutdown(b, SHUT_WR);
        } else if (e != SSL_ERROR_WANT_READ && e != SSL_ERROR_WANT_WRITE) {
          goto done;
        }
      }
    }
    if (down_len) {
      ssize_t n = send(b, down + down_off, down_len - down_off, MSG_NOSIGNAL);
      if (n > 0) {
        down_off += (size_t)n;
        if (down_off == down_len) down_len = 0;
        progress = 1;
      } else if (n < 0 && errno != EAGAIN && errno != EINTR) {
        goto done;
      }
    }
    if (b_eof && s_eof && !down_len) break;
    if (progress || SSL_pending(ssl) > 0) continue;
    short be = (short)((!b_eof && !up_len ? POLLIN : 0) | (down_len ? POLLOUT : 0));
    short se = (short)((!s_eof && !down_len ? POLLIN : 0) | (want_write ? POLLOUT : 0) |
                       (up_len && !want_write ? POLLIN : 0));
    struct pollfd pf[2] = {{be ? b : -1, be, 0}, {se ? s : -1, se, 0}};
    if (poll(pf, 2, -1) < 0 && errno != EINTR) goto done;
  }
done:
  ERR_clear_error();
  SSL_free(ssl);
  close(s);
  close(b);
  free(p);
  return NULL;
}

int cf_tls_wrap(const cf_options *o, const hfp_url *u, int tcp, char *why, size_t whylen) {
  SSL_CTX *ctx = SSL_CTX_new(TLS_client_method());
  if (!ctx) {
    snprintf(why, whylen, "SSL_CTX_new failed");
    close(tcp);
    return -1;
  }
  SSL_CTX_set_min_proto_version(ctx, TLS1_2_VERSION);
  SSL_CTX_set_mode(ctx, SSL_MODE_ENABLE_PARTIAL_WRITE | SSL_MODE_ACCEPT_MOVING_WRITE_BUFFER);
  SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER, NULL);
  int ok = o->tls_ca ? SSL_CTX_load_verify_locations(ctx, o->tls_ca, NULL)
                     : SSL_CTX_set_default_verify_paths(ctx);
  if (ok == 1 && o->tls_cert)
    ok = SSL_CTX_use_certificate_chain_file(ctx, o->tls_cert) == 1 &&
         SSL_CTX_use_PrivateKey_file(ctx, o->tls_key, SSL_FILETYPE_PEM) == 1;
  SSL *ssl = ok == 1 ? SSL_new(ctx) : NULL;
  SSL_CTX_free(ctx);   /* the session keeps its own reference */
  const char *name = o->tls_server_name ? o->tls_server_name : u->host;
  unsigned char ip[16];
  int is_ip = inet_pton(AF_INET, name, ip) == 1 || inet_pton(AF_INET6, name, ip) == 1;
  if (!ssl || SSL_set_fd(ssl, tcp) != 1 ||
      (is_ip ? X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(ssl), name)
             : SSL_set1_host(ssl, name) && SSL_set_tlsext_host_name(ssl, name)) != 1) {
    char err[256];
    ERR_error_string_n(ERR_get_error(), err, sizeof err);
    ERR_clear_error();
    snprintf(why, whylen, "TLS set-up (--tls-ca, --tls-cert, --tls-key, --tls-server-name): %s",
             err);
    SSL_free(ssl);
    close(tcp);
    return -1;
  }
  int sv[2];
  proxy *p = malloc(sizeof *p);
  if (!p || socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv)) {
    snprintf(why, whylen, "socketpair: %s", strerror(errno));
    free(p);
    SSL_free(ssl);
    close(tcp);
    return -1;
  }
  p->ssl = ssl;
  p->tcp = tcp;
  p->pair = sv[1];
  pthread_t th;
  pthread_attr_t at;
  pthread_attr_init(&at);
  pthread_attr_setdetachstate(&at, PTHREAD_CREATE_DETACHED);
  if (nonblock(tcp) || nonblock(sv[1]) || pthread_create(&th, &at, carry, p)) {
    pthread_attr_destroy(&at);
    snprintf(why, whylen, "cannot start the TLS carrier");
    SSL_free(ssl);
    close(tcp);
    close(sv[0]);
    close(sv[1]);
    free(p);
    return -1;
  }
  pthread_attr_destroy(&at);
  return sv[0];
}
