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

#endif
