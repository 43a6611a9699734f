/*
 * peer_addr.c: what an IP address is to the daemon. Pure functions of the
 * address, so that the cases no test host can connect from (another
 * interface's link-local address, a whole IPv6 prefix) are tested as
 * they are decided (tests/server/test_peer_addr.c).
 */
#ifndef HFD_PEER_ADDR_H
#define HFD_PEER_ADDR_H

#include <stddef.h>
#include <sys/socket.h>

/* 1 when sa is on the loopback interface: IPv4 127.0.0.0/8, IPv6 ::1, or
 * 127.0.0.0/8 as an IPv6 listener or peer sees it, v4-mapped
 * (::ffff:127.0.0.1); 0 otherwise, and for a family other than those two. */
int hfd_addr_is_loopback(const struct sockaddr *sa);

/* The same for a listener's host as written: 1 for a loopback address or
 * "localhost", 0 for another numeric address, -1 when host is not a
 * numeric address (which opening the listener refuses). */
int hfd_host_is_loopback(const char *host);

/* The shortest and longest IPv6 prefix a client may be counted by
 * (--ipv6-client-prefix), and the default: one host's usual share, a /64. */
#define HFD_V6_CLIENT_PREFIX_MIN 48
#define HFD_V6_CLIENT_PREFIX_MAX 128
#define HFD_V6_CLIENT_PREFIX_DEFAULT 64

/* The client a TCP or TLS peer at sa is, as messages name it, written
 * into buf (cap bytes): "address A". An IPv4 peer is its address, also
 * when an IPv6 socket sees it v4-mapped (::ffff:A.B.C.D), and ::1 is
 * itself. Any other IPv6 peer is its first v6_prefix bits
 * (HFD_V6_CLIENT_PREFIX_MIN..MAX), "address 2001:db8:1:2::/64" (the
 * address alone at 128): a host is commonly given a whole /64 and picks
 * any address in it, so counted per address it could be as many clients
 * as it likes. A link-local one (fe80::/10) is that on its interface, its
 * scope id before the length, "address fe80::%2/64": the same link-local
 * address on two links is two hosts. Peers with one name are one client.
 * 0, or -1 when sa is neither IPv4 nor IPv6, v6_prefix is out of range or
 * the name does not fit. */
int hfd_peer_client_name(const struct sockaddr *sa, int v6_prefix, char *buf, size_t cap);

#endif
