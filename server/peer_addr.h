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

/* The client a TCP or TLS peer at sa is, as messages name it, written
 * into buf (cap bytes): "address A". An IPv4 peer is its address, also
 * when an IPv6 socket sees it v4-mapped (::ffff:A.B.C.D); an IPv6 peer
 * its address, with the scope id (the interface's index) of a link-local
 * one, "address fe80::1%2": the same link-local address on two links is
 * two hosts. Peers with one name are one client. 0, or -1 when sa is
 * neither IPv4 nor IPv6 or the name does not fit. */
int hfd_peer_client_name(const struct sockaddr *sa, char *buf, size_t cap);

#endif
