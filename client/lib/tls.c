/*
 * tls.c: tls:HOST:PORT endpoints, with OpenSSL (Debian's libssl-dev) on the
 * client's non-blocking sockets. Every wait goes through poll() with the
 * client's timeout, as for plain sockets, so a server that stops in the
 * middle of a handshake costs a timeout, never a hang.
 *
 * The server's certificate must chain to tls_ca_file (or the system's CAs)
 * and name the host of the URL (SSL_set1_host; an IP address is checked
 * against the certificate's IP addresses), unless hfc_options says
 * otherwise. TLS 1.2 is the least accepted. Failures are explained in
 * words that name the problem and what to check: OpenSSL's own reason,
 * and the verification result for a refused certificate.
 */
#define _POSIX_C_SOURCE 200809L
#include <arpa/inet.h>
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>

#include "client_internal.h"

/* Why the last TLS call of this thread failed, for the caller's message. */
static _Thread_local char tls_why[400];

const char *hfci_tls_why(void) { return tls_why; }

/* What to check for the usual reasons, by OpenSSL's reason code. */
static const char *reason_hint(int reason) {
  switch (reason) {
    case SSL_R_TLSV13_ALERT_CERTIFICATE_REQUIRED:
      return " (the server requires a client certificate: give one with its key, "
             "hfc_options.tls_cert_file and tls_key_file / --tls-cert and --tls-key)";
    case SSL_R_SSLV3_ALERT_HANDSHAKE_FAILURE:
      return " (the server refused the handshake: does it require a client certificate?)";
    case SSL_R_TLSV1_ALERT_UNKNOWN_CA:
    case SSL_R_SSLV3_ALERT_BAD_CERTIFICATE:
      return " (the server does not trust this client certificate: is it signed by the CA "
             "of the server's --tls-client-ca?)";
    case SSL_R_SSLV3_ALERT_CERTIFICATE_EXPIRED:
      return " (the server says this client certificate has expired)";
    case SSL_R_SSLV3_ALERT_UNSUPPORTED_CERTIFICATE:
      return " (the server refused this client certificate's purpose: a client certificate "
             "needs extendedKeyUsage=clientAuth, docs/SERVER.md \"Certificates for a render "
             "farm\"; a server's certificate will not do)";
    case SSL_R_WRONG_VERSION_NUMBER:
    case SSL_R_PACKET_LENGTH_TOO_LONG:
      return " (the server did not answer in TLS: is it a plain tcp: listener? then use a "
             "tcp: URL)";
    case SSL_R_UNEXPECTED_EOF_WHILE_READING:
      return " (the server closed the connection during the TLS handshake: is it a plain "
             "tcp: listener? then use a tcp: URL)";
    default:
      return "";
  }
}

/* The DNS and IP names of the server's certificate (its subjectAltName),
 * as "DNS:a, IP:b", into buf; "" when there is none to read. After a
 * refused certificate OpenSSL still holds the chain the server sent. */
static void peer_names(SSL *ssl, char *buf, size_t cap) {
  buf[0] = 0;
  STACK_OF(X509) *chain = SSL_get_peer_cert_chain(ssl);
  X509 *leaf = chain && sk_X509_num(chain) > 0 ? sk_X509_value(chain, 0) : NULL;
  GENERAL_NAMES *g = leaf ? X509_get_ext_d2i(leaf, NID_subject_alt_name, NULL, NULL) : NULL;
  size_t used = 0;
  for (int i = 0; g && i < sk_GENERAL_NAME_num(g); i++) {
    const GENERAL_NAME *n = sk_GENERAL_NAME_value(g, i);
    char one[INET6_ADDRSTRLEN + 80];
    if (n->type == GEN_DNS) {
      snprintf(one, sizeof one, "DNS:%.*s", ASN1_STRING_length(n->d.dNSName) > 64 ? 64 :
               ASN1_STRING_length(n->d.dNSName), (const char *)ASN1_STRING_get0_data(n->d.dNSName));
    } else if (n->type == GEN_IPADD) {
      int len = ASN1_STRING_length(n->d.iPAddress);
      char ip[INET6_ADDRSTRLEN];
      if ((len != 4 && len != 16) ||
          !inet_ntop(len == 4 ? AF_INET : AF_INET6, ASN1_STRING_get0_data(n->d.iPAddress), ip,
                     sizeof ip))
        continue;
      snprintf(one, sizeof one, "IP:%s", ip);
    } else {
      continue;
    }
    int k = snprintf(buf + used, cap - used, "%s%s", used ? ", " : "", one);
    if (k < 0 || (size_t)k >= cap - used) break;
    used += (size_t)k;
  }
  GENERAL_NAMES_free(g);
}

/* Sets tls_why from OpenSSL's error queue (cleared) and, after a failed
 * handshake, the verification result. Returns HFC_E_TLS. */
static int tls_fail(SSL *ssl, const char *what) {
  const hfc_client *c = ssl ? SSL_get_app_data(ssl) : NULL;
  char hint[300];
  long v = ssl ? SSL_get_verify_result(ssl) : X509_V_OK;
  unsigned long e = ERR_peek_last_error();
  char reason[256] = "";
  if (e) ERR_error_string_n(e, reason, sizeof reason);
  const char *r = e ? ERR_reason_error_string(e) : NULL;
  ERR_clear_error();
  if (v != X509_V_OK && ssl) {
    hint[0] = 0;
    switch (v) {
      case X509_V_ERR_CERT_HAS_EXPIRED:
        snprintf(hint, sizeof hint, " (the server's certificate must be renewed)");
        break;
      case X509_V_ERR_CERT_NOT_YET_VALID:
        snprintf(hint, sizeof hint, " (check the clocks of both machines)");
        break;
      case X509_V_ERR_HOSTNAME_MISMATCH:
      case X509_V_ERR_IP_ADDRESS_MISMATCH: {
        char names[200];
        peer_names(ssl, names, sizeof names);
        snprintf(hint, sizeof hint, " (the certificate names %s: connect with %s, or set "
                 "hfc_options.tls_server_name / --tls-server-name NAME)",
                 names[0] ? names : "other hosts", names[0] ? "one of them" : "a name it has");
        break;
      }
      case X509_V_ERR_UNABLE_TO_GET_ISSUER_CERT_LOCALLY:
      case X509_V_ERR_UNABLE_TO_GET_ISSUER_CERT:
      case X509_V_ERR_SELF_SIGNED_CERT_IN_CHAIN:
      case X509_V_ERR_DEPTH_ZERO_SELF_SIGNED_CERT:
      case X509_V_ERR_UNABLE_TO_VERIFY_LEAF_SIGNATURE:
        if (c && c->tls_ca_file)
          snprintf(hint, sizeof hint, " (the server's certificate is not signed by a CA of "
                   "hfc_options.tls_ca_file / --tls-ca %.200s)", c->tls_ca_file);
        else
          snprintf(hint, sizeof hint, " (the server's certificate is not signed by a CA of "
                   "the system's CA store, used as no CA file was given: give the CA that "
                   "signed it, hfc_options.tls_ca_file / --tls-ca FILE)");
        break;
      default: break;
    }
    snprintf(tls_why, sizeof tls_why, "TLS %s: server certificate refused: %s%s", what,
             X509_verify_cert_error_string(v), hint);
    return HFC_E_TLS;
  }
  snprintf(tls_why, sizeof tls_why, "TLS %s: %s%s", what,
           r ? r : reason[0] ? reason : "the connection failed",
           e ? reason_hint(ERR_GET_REASON(e)) : "");
  return HFC_E_TLS;
}

int hfci_tls_setup(hfc_client *c, const hfc_options *o, char *why, size_t whylen) {
  int any = 0;
  for (int i = 0; i < c->neps; i++) any |= c->eps[i].addr.tls;
  /* Refused even without a tls: endpoint: the caller meant something else. */
  if (!o->tls_cert_file != !o->tls_key_file) {
    snprintf(why, whylen, "hfc_options.tls_cert_file and tls_key_file (--tls-cert and "
             "--tls-key) go together: give both, a client certificate and its private key, "
             "or neither");
    return HFC_E_ARG;
  }
  if (!any && (o->tls_ca_file || o->tls_cert_file || o->tls_server_name)) {
    /* The options would be ignored and the connection plain: its token
     * and frames unencrypted though the caller asked for TLS. */
    snprintf(why, whylen, "hfc_options.tls_ca_file, tls_cert_file and tls_server_name (--tls-ca, "
             "--tls-cert, --tls-server-name) are for tls: endpoints, and the URL has none: the "
             "connection would be plain, its token and frames unencrypted; connect to "
             "tls:HOST:PORT, or leave the TLS options unset");
    return HFC_E_ARG;
  }
  if (!any) return 0;
  SSL_CTX *ctx = SSL_CTX_new(TLS_client_method());
  if (!ctx) {
    snprintf(why, whylen, "SSL_CTX_new failed");
    return HFC_E_NOMEM;
  }
  c->tls_ctx = ctx;
  SSL_CTX_set_min_proto_version(ctx, TLS1_2_VERSION);
  SSL_CTX_set_options(ctx, SSL_OP_NO_RENEGOTIATION | SSL_OP_NO_COMPRESSION);
  SSL_CTX_set_mode(ctx, SSL_MODE_ENABLE_PARTIAL_WRITE | SSL_MODE_ACCEPT_MOVING_WRITE_BUFFER);
  SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER, NULL);
  char err[256];
  if (o->tls_ca_file) {
    if (SSL_CTX_load_verify_locations(ctx, o->tls_ca_file, NULL) != 1) {
      ERR_error_string_n(ERR_get_error(), err, sizeof err);
      ERR_clear_error();
      snprintf(why, whylen, "hfc_options.tls_ca_file (--tls-ca) %s: %s", o->tls_ca_file, err);
      return HFC_E_ARG;
    }
    if (!(c->tls_ca_file = strdup(o->tls_ca_file))) {
      snprintf(why, whylen, "out of memory");
      return HFC_E_NOMEM;
    }
  } else if (SSL_CTX_set_default_verify_paths(ctx) != 1) {
    ERR_clear_error();
    snprintf(why, whylen, "no tls_ca_file and the system's CA certificates cannot be read");
    return HFC_E_ARG;
  }
  if (o->tls_cert_file) {
    const char *key = o->tls_key_file;
    if (SSL_CTX_use_certificate_chain_file(ctx, o->tls_cert_file) != 1) {
      ERR_error_string_n(ERR_get_error(), err, sizeof err);
      ERR_clear_error();
      snprintf(why, whylen, "hfc_options.tls_cert_file (--tls-cert) %s: %s", o->tls_cert_file,
               err);
      return HFC_E_ARG;
    }
    if (SSL_CTX_use_PrivateKey_file(ctx, key, SSL_FILETYPE_PEM) != 1 ||
        SSL_CTX_check_private_key(ctx) != 1) {
      ERR_error_string_n(ERR_get_error(), err, sizeof err);
      ERR_clear_error();
      snprintf(why, whylen, "hfc_options.tls_key_file (--tls-key) %s: %s (is it the "
               "certificate's key?)", key, err);
      return HFC_E_ARG;
    }
  }
  if (o->tls_server_name) {
    size_t n = strlen(o->tls_server_name);
    if (n == 0 || n >= sizeof c->tls_server_name) {
      snprintf(why, whylen, "hfc_options.tls_server_name is %zu bytes: want 1..%zu", n,
               sizeof c->tls_server_name - 1);
      return HFC_E_ARG;
    }
    memcpy(c->tls_server_name, o->tls_server_name, n + 1);
  }
  c->tls_no_verify_host = o->tls_no_verify_host != 0;
  return 0;
}

int hfci_tls_poll_setup(hfc_client *c, char *why, size_t whylen) {
  if (!c->tls_ctx) return 0;
  c->tls_evfd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  struct epoll_event ev;
  memset(&ev, 0, sizeof ev);
  ev.events = EPOLLIN;
  ev.data.fd = c->tls_evfd;
  if (c->tls_evfd < 0 || epoll_ctl(c->epfd, EPOLL_CTL_ADD, c->tls_evfd, &ev) != 0) {
    snprintf(why, whylen, "eventfd for hfc_fd: %s", strerror(errno));
    return HFC_E_IO;
  }
  return 0;
}

void hfci_tls_signal(hfc_client *c) {
  if (c->tls_evfd < 0) return;
  uint64_t v;
  /* Cleared, then set again while any connection has bytes waiting. */
  while (read(c->tls_evfd, &v, sizeof v) < 0 && errno == EINTR) {
  }
  for (int k = 0; k < MAX_CONNS; k++)
    if (c->conns[k].fd >= 0 && hfci_tls_pending(c->conns[k].ssl)) {
      v = 1;
      while (write(c->tls_evfd, &v, sizeof v) < 0 && errno == EINTR) {
      }
      return;
    }
}

void hfci_tls_free(hfc_client *c) {
  SSL_CTX_free(c->tls_ctx);
  c->tls_ctx = NULL;
  free(c->tls_ca_file);
  c->tls_ca_file = NULL;
}

/* Waits for what OpenSSL asked for (err of SSL_get_error). */
static int tls_wait(int fd, int err, int timeout_ms) {
  return hfci_wait_fd(fd, err == SSL_ERROR_WANT_WRITE ? POLLOUT : POLLIN, timeout_ms);
}

int hfci_tls_connect(hfc_client *c, int fd, const hfp_url *u, void **out) {
  *out = NULL;
  tls_why[0] = 0;
  SSL *ssl = SSL_new(c->tls_ctx);
  if (!ssl || SSL_set_fd(ssl, fd) != 1) {
    SSL_free(ssl);
    return tls_fail(NULL, "setup");
  }
  SSL_set_app_data(ssl, c);   /* for tls_fail's hints */
  const char *name = c->tls_server_name[0] ? c->tls_server_name : u->host;
  unsigned char ip[16];
  int is_ip = inet_pton(AF_INET, name, ip) == 1 || inet_pton(AF_INET6, name, ip) == 1;
  /* SNI carries names only (RFC 6066); the check covers addresses too. */
  if (!is_ip) SSL_set_tlsext_host_name(ssl, name);
  if (!c->tls_no_verify_host) {
    int ok = is_ip ? X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(ssl), name)
                   : SSL_set1_host(ssl, name);
    if (ok != 1) {
      SSL_free(ssl);
      return tls_fail(NULL, "setup of the host name check");
    }
  }
  for (;;) {
    hfci_sigpipe sp;
    hfci_sigpipe_block(&sp);
    int r = SSL_connect(ssl);
    hfci_sigpipe_restore(&sp);
    if (r == 1) break;
    int e = SSL_get_error(ssl, r);
    if (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_WANT_WRITE) {
      int w = tls_wait(fd, e, c->timeout_ms);
      if (w) {
        snprintf(tls_why, sizeof tls_why, "TLS handshake: %s", hfc_strerror(w));
        SSL_free(ssl);
        return w;
      }
      continue;
    }
    if (e == SSL_ERROR_SYSCALL && ERR_peek_error() == 0) {
      snprintf(tls_why, sizeof tls_why, "TLS handshake: the server closed the connection "
               "(%s%s: is it a plain tcp: listener? then use a tcp: URL)",
               errno ? "" : "at once", errno ? strerror(errno) : "");
      SSL_free(ssl);
      return HFC_E_TLS;
    }
    int rc = tls_fail(ssl, "handshake");
    SSL_free(ssl);
    return rc;
  }
  *out = ssl;
  return 0;
}

/* Whether the error OpenSSL just reported is the peer's close without
 * close_notify: OpenSSL 3 reports it as SSL_ERROR_SSL with this reason
 * (1.1 as SSL_ERROR_SYSCALL, handled below). A server that was killed, or
 * exited, did just that: the connection is closed (HFC_E_CLOSED, which
 * fails over), not a TLS failure. */
static int unexpected_eof(void) {
#ifdef SSL_R_UNEXPECTED_EOF_WHILE_READING
  unsigned long e = ERR_peek_error();
  return e && ERR_GET_LIB(e) == ERR_LIB_SSL &&
         ERR_GET_REASON(e) == SSL_R_UNEXPECTED_EOF_WHILE_READING;
#else
  return 0;
#endif
}

/* Moves n bytes through ssl, writing from p or reading into it, waiting
 * on fd for what OpenSSL asks for, up to timeout_ms each time. */
static int transfer(SSL *ssl, int fd, int writing, uint8_t *p, size_t n, int timeout_ms) {
  while (n) {
    int chunk = n > (1u << 30) ? 1 << 30 : (int)n;
    /* A read may write too (a TLS 1.3 key update's answer). */
    hfci_sigpipe sp;
    hfci_sigpipe_block(&sp);
    int r = writing ? SSL_write(ssl, p, chunk) : SSL_read(ssl, p, chunk);
    hfci_sigpipe_restore(&sp);
    if (r > 0) {
      p += r;
      n -= (size_t)r;
      continue;
    }
    int e = SSL_get_error(ssl, r);
    if (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_WANT_WRITE) {
      int w = tls_wait(fd, e, timeout_ms);
      if (w) return w;
      continue;
    }
    if (e == SSL_ERROR_ZERO_RETURN) return HFC_E_CLOSED;
    if (e == SSL_ERROR_SYSCALL &&
        (ERR_peek_error() == 0 || errno == EPIPE || errno == ECONNRESET)) {
      /* EOF or a reset without close_notify (OpenSSL 3 may have queued
       * the system error: the peer is gone all the same). */
      ERR_clear_error();
      return errno == EPIPE || errno == ECONNRESET || errno == 0 ? HFC_E_CLOSED : HFC_E_IO;
    }
    if (e == SSL_ERROR_SSL && unexpected_eof()) {
      ERR_clear_error();
      return HFC_E_CLOSED;
    }
    return tls_fail(ssl, writing ? "write" : "read");
  }
  return 0;
}

int hfci_tls_send(void *s, int fd, int timeout_ms, const struct iovec *iov, int n) {
  /* SSL_MODE_ACCEPT_MOVING_WRITE_BUFFER and partial writes: the pointer
   * may move on between retries. Buffer by buffer: TLS records are copied
   * and encrypted anyway, so a gather write would save nothing. */
  for (int i = 0; i < n; i++) {
    int rc = transfer(s, fd, 1, (uint8_t *)iov[i].iov_base, iov[i].iov_len, timeout_ms);
    if (rc) return rc;
  }
  return 0;
}

int hfci_tls_recv(void *s, int fd, void *buf, size_t n, int timeout_ms) {
  return transfer(s, fd, 0, buf, n, timeout_ms);
}

int hfci_tls_pending(void *s) { return s && SSL_pending((SSL *)s) > 0; }

int hfci_tls_shutdown_wr(void *s) {
  /* close_notify is TLS's half-close: the server answers what it has
   * admitted and closes (PROTOCOL.md, "Transport"). */
  hfci_sigpipe sp;
  hfci_sigpipe_block(&sp);
  int r = SSL_shutdown((SSL *)s);
  hfci_sigpipe_restore(&sp);
  ERR_clear_error();
  return r < 0 ? HFC_E_IO : 0;
}

void hfci_tls_close(void *s) { SSL_free((SSL *)s); }
