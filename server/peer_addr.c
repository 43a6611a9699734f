/*
 * peer_addr.c: what an IP address is to the daemon (peer_addr.h).
 *
 * An IPv6 socket that takes IPv4 too ([::], or a v4-mapped address) sees
 * an IPv4 address as ::ffff:A.B.C.D: every decision about an address
 * takes that form for the IPv4 address it is, or the same host would be
 * one thing on an IPv4 listener and another on an IPv6 one.
 */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <stdio.h>
#include <string.h>

#include "peer_addr.h"

int hfd_addr_is_loopback(const struct sockaddr *sa) {
  if (sa->sa_family == AF_INET) {
    const struct sockaddr_in *s4 = (const struct sockaddr_in *)sa;
    return (ntohl(s4->sin_addr.s_addr) >> 24) == 127;
  }
  if (sa->sa_family == AF_INET6) {
    const struct in6_addr *a = &((const struct sockaddr_in6 *)sa)->sin6_addr;
    if (IN6_IS_ADDR_V4MAPPED(a)) return a->s6_addr[12] == 127;
    return IN6_IS_ADDR_LOOPBACK(a);
  }
  return 0;
}

int hfd_host_is_loopback(const char *host) {
  if (!strcmp(host, "localhost")) return 1;
  struct sockaddr_in s4;
  struct sockaddr_in6 s6;
  memset(&s4, 0, sizeof s4);
  memset(&s6, 0, sizeof s6);
  if (inet_pton(AF_INET, host, &s4.sin_addr) == 1) {
    s4.sin_family = AF_INET;
    return hfd_addr_is_loopback((const struct sockaddr *)&s4);
  }
  if (inet_pton(AF_INET6, host, &s6.sin6_addr) == 1) {
    s6.sin6_family = AF_INET6;
    return hfd_addr_is_loopback((const struct sockaddr *)&s6);
  }
  return -1;
}

int hfd_peer_client_name(const struct sockaddr *sa, int v6_prefix, char *buf, size_t cap) {
  char ip[INET6_ADDRSTRLEN];
  int n = -1;
  if (sa->sa_family == AF_INET) {
    if (inet_ntop(AF_INET, &((const struct sockaddr_in *)sa)->sin_addr, ip, sizeof ip))
      n = snprintf(buf, cap, "address %s", ip);
  } else if (sa->sa_family == AF_INET6) {
    const struct sockaddr_in6 *s6 = (const struct sockaddr_in6 *)sa;
    const struct in6_addr *a = &s6->sin6_addr;
    if (IN6_IS_ADDR_V4MAPPED(a)) {
      if (inet_ntop(AF_INET, &a->s6_addr[12], ip, sizeof ip))
        n = snprintf(buf, cap, "address %s", ip);
    } else if (v6_prefix >= HFD_V6_CLIENT_PREFIX_MIN && v6_prefix <= HFD_V6_CLIENT_PREFIX_MAX) {
      /* ::1 is this host, not the /64 of the unspecified address. */
      int bits = IN6_IS_ADDR_LOOPBACK(a) ? 128 : v6_prefix;
      struct in6_addr net = *a;
      for (int i = 0; i < 16; i++) {
        int keep = bits - 8 * i;
        if (keep <= 0)
          net.s6_addr[i] = 0;
        else if (keep < 8)
          net.s6_addr[i] &= (unsigned char)(0xff << (8 - keep));
      }
      /* A link-local address means something only on its link: without
       * the interface, the hosts of two links that picked the same one
       * (each link's router is often fe80::1) would be one client. */
      char zone[16] = "";
      if (IN6_IS_ADDR_LINKLOCAL(a)) snprintf(zone, sizeof zone, "%%%u", (unsigned)s6->sin6_scope_id);
      if (inet_ntop(AF_INET6, &net, ip, sizeof ip))
        n = bits == 128 ? snprintf(buf, cap, "address %s%s", ip, zone)
                        : snprintf(buf, cap, "address %s%s/%d", ip, zone, bits);
    }
  }
  if (n < 0 || (size_t)n >= cap) {
    if (cap) buf[0] = 0;
    return -1;
  }
  return 0;
}
