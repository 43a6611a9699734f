/*
 * clients.c: which client a connection belongs to.
 *
 * Some limits are shares among clients, not connections: a share of the
 * queue, and the connections before their HELLO one IP address may hold.
 * Counted per connection, a client that opens N connections gets N shares
 * and pushes the others' frames out of the queue, and a peer that opens
 * connections as fast as it can takes every handshake slot. A client is
 * what a peer cannot multiply at will: on a Unix socket its process (the
 * pid the kernel recorded at connect, SO_PEERCRED, as the shared-memory
 * budget counts it), over TCP and TLS its IP address, an IPv4 one named
 * alike on IPv4 and IPv6 listeners, an IPv6 one by its /64 (what one host
 * is commonly given: --ipv6-client-prefix), a link-local one on its
 * interface (peer_addr.c: hfd_peer_client_name; several render nodes
 * behind one NAT address are then one client: --queue-share-by connection
 * gives each connection its share again, docs/SERVER.md).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "peer_addr.h"
#include "server.h"

/* The name of c's peer as a client: "pid N" or "address A"; "" when it
 * cannot be told (then c is a client of its own). */
static void peer_name(hfd_conn *c, char *buf, size_t cap) {
  buf[0] = 0;
  if (c->listener->is_tcp) {
    struct sockaddr_storage ss;
    int len = sizeof ss;
    if (uv_tcp_getpeername(&c->h.tcp, (struct sockaddr *)&ss, &len) != 0 ||
        hfd_peer_client_name((const struct sockaddr *)&ss, c->listener->srv->cfg->ipv6_client_prefix,
                             buf, cap) != 0)
      buf[0] = 0;
    return;
  }
  uv_os_fd_t fd;
  struct ucred cr;
  socklen_t len = sizeof cr;
  if (uv_fileno(&c->h.handle, &fd) == 0 &&
      getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cr, &len) == 0 && len == sizeof cr && cr.pid > 0)
    snprintf(buf, cap, "pid %ld", (long)cr.pid);
}

void hfd_client_join(hfd_server *s, hfd_conn *c) {
  char name[sizeof c->own.name];
  peer_name(c, name, sizeof name);
  hfd_client *k = NULL;
  if (name[0]) {
    for (k = s->clients; k && strcmp(k->name, name); k = k->next) {
    }
    if (!k) {
      k = calloc(1, sizeof *k);
      if (!k)
        hfd_err("conn %llu: out of memory for its client's count; the connection is a "
                "client of its own", (unsigned long long)c->id);
    }
    if (k && !k->listed) {
      snprintf(k->name, sizeof k->name, "%s", name);
      k->listed = 1;
      k->next = s->clients;
      s->clients = k;
    }
  }
  if (!k) {
    k = &c->own;
    snprintf(k->name, sizeof k->name, "connection %llu", (unsigned long long)c->id);
  }
  k->conns++;
  c->client = k;
  c->share = s->cfg->share_by_connection ? &c->own : k;
  if (c->share == &c->own && k != &c->own)
    snprintf(c->own.name, sizeof c->own.name, "connection %llu", (unsigned long long)c->id);
}

void hfd_client_leave(hfd_server *s, hfd_conn *c) {
  hfd_client *k = c->client;
  if (!k) return;
  c->client = c->share = NULL;
  if (--k->conns > 0 || !k->listed) return;
  for (hfd_client **p = &s->clients; *p; p = &(*p)->next)
    if (*p == k) {
      *p = k->next;
      break;
    }
  free(k);
}

int hfd_client_handshake_cap(const hfd_server *s) {
  int all = s->cfg->max_handshakes, cap = s->cfg->max_handshakes_addr;
  if (cap <= 0) cap = all / 2 > 0 ? all / 2 : 1;
  return cap < all ? cap : all;
}
