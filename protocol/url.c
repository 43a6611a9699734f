/*
 * url.c: the server URLs of PROTOCOL.md ("Addresses"), parsed once for the
 * daemon's --listen and the client library's hfc_connect, so both sides
 * accept and refuse exactly the same strings.
 *
 * Our own code rather than a URI library: these are not RFC 3986 URIs
 * (`unix:/path` has no authority, `tcp:PORT` no host), the grammar is four
 * lines, and the point of the parser is its error messages, which name the
 * part that is wrong.
 */
#include "hfproto.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static int bad(char *why, size_t whylen, const char *url, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static int bad(char *why, size_t whylen, const char *url, const char *fmt, ...) {
  if (why && whylen) {
    /* The URL is quoted as given, cut (and said to be) to keep the
     * message one short line. */
    int n = snprintf(why, whylen, "bad URL '%.120s%s': ", url, strlen(url) > 120 ? "..." : "");
    if (n > 0 && (size_t)n < whylen) {
      va_list ap;
      va_start(ap, fmt);
      vsnprintf(why + n, whylen - (size_t)n, fmt, ap);
      va_end(ap);
    }
  }
  return -HFP_E_INVALID;
}

/* A host name or IPv4 address: letters, digits, '-', '.' and '_' (the last
 * for names in /etc/hosts that use it). */
static int host_char(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
         c == '-' || c == '.' || c == '_';
}

/* An IPv6 literal between brackets: hex digits, ':' and '.' (an embedded
 * IPv4 part); a zone ("%eth0") may follow. */
static int v6_char(char c) {
  return (c >= 'a' && c <= 'f') || (c >= 'A' && c <= 'F') || (c >= '0' && c <= '9') ||
         c == ':' || c == '.';
}

int hfp_url_parse(const char *url, int flags, hfp_url *out, char *why, size_t whylen) {
  if (why && whylen) why[0] = 0;
  memset(out, 0, sizeof *out);
  if (!url) return bad(why, whylen, "", "no URL");
  if (!strncmp(url, "unix:", 5)) {
    const char *path = url + 5;
    size_t n = strlen(path);
    if (n == 0) return bad(why, whylen, url, "empty socket path");
    if (n >= sizeof out->path)
      return bad(why, whylen, url, "socket path longer than %zu bytes", sizeof out->path - 1);
    out->kind = HFP_URL_UNIX;
    memcpy(out->path, path, n + 1);
    return 0;
  }
  /* tls: is TCP with TLS on top: the same host and port grammar. */
  int tls = !strncmp(url, "tls:", 4);
  if (strncmp(url, "tcp:", 4) && !tls)
    return bad(why, whylen, url, "want unix:PATH, tcp:HOST:PORT, tls:HOST:PORT or tcp:PORT");
  const char *rest = url + 4, *port_s;
  out->kind = HFP_URL_TCP;
  out->tls = tls;
  if (rest[0] == '/' && rest[1] == '/')
    return bad(why, whylen, url, "no '//' after '%.3s:': write %.3s:HOST:PORT", url, url);
  if (rest[0] == '[') {
    const char *close = strchr(rest, ']');
    if (!close) return bad(why, whylen, url, "'[' without ']' around the IPv6 address");
    size_t hl = (size_t)(close - rest - 1);
    if (hl == 0) return bad(why, whylen, url, "empty IPv6 address");
    if (hl >= sizeof out->host) return bad(why, whylen, url, "host too long");
    const char *zone = memchr(rest + 1, '%', hl);
    for (const char *p = rest + 1; p < (zone ? zone : close); p++)
      if (!v6_char(*p)) return bad(why, whylen, url, "'%c' in an IPv6 address", *p);
    if (zone && zone + 1 == close) return bad(why, whylen, url, "empty IPv6 zone");
    memcpy(out->host, rest + 1, hl);
    out->host[hl] = 0;
    if (close[1] != ':') return bad(why, whylen, url, "want [ADDRESS]:PORT");
    port_s = close + 2;
  } else {
    const char *colon = strchr(rest, ':');
    if (colon && strchr(colon + 1, ':'))
      return bad(why, whylen, url, "an IPv6 address goes in brackets: tcp:[ADDRESS]:PORT");
    if (colon) {
      size_t hl = (size_t)(colon - rest);
      if (hl == 0) return bad(why, whylen, url, "empty host before ':'");
      if (hl >= sizeof out->host) return bad(why, whylen, url, "host too long");
      for (const char *p = rest; p < colon; p++)
        if (!host_char(*p)) return bad(why, whylen, url, "'%c' in the host name", *p);
      memcpy(out->host, rest, hl);
      out->host[hl] = 0;
      port_s = colon + 1;
    } else {
      /* tcp:PORT is the loopback interface. */
      strcpy(out->host, "127.0.0.1");
      port_s = rest;
    }
  }
  /* Decimal digits only: no sign, no spaces, nothing after them. */
  if (!*port_s) return bad(why, whylen, url, "no port");
  unsigned long port = 0;
  for (const char *p = port_s; *p; p++) {
    if (*p < '0' || *p > '9')
      return bad(why, whylen, url, "port '%.20s' is not a decimal number", port_s);
    port = port * 10 + (unsigned long)(*p - '0');
    /* A listener's port may be 0 (any free one); a client's may not. */
    if (port > 65535)
      return bad(why, whylen, url, "port %.20s is outside %d..65535", port_s,
                 flags & HFP_URL_LISTEN ? 0 : 1);
  }
  if (port == 0 && !(flags & HFP_URL_LISTEN))
    return bad(why, whylen, url, "port 0 is outside 1..65535");
  out->port = (uint16_t)port;
  return 0;
}
