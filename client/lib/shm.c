/*
 * shm.c: shared-memory segments (PROTOCOL.md, "Shared memory"). The server
 * makes and seals each segment and passes its descriptor with SHM_CREATED;
 * the client maps it. A segment belongs to the connection that asked for
 * it: after a failover it is plain memory of the caller's, and requests in
 * it take the socket path until it is freed.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "client_internal.h"

/* The segment holding n bytes at p, or NULL. */
static const segment *seg_of(const hfc_client *c, const void *p, uint64_t n) {
  const uint8_t *b = p;
  for (int i = 0; i < c->nsegs; i++) {
    const segment *g = &c->segs[i];
    if (b >= g->addr && b < g->addr + g->size && n <= (uint64_t)(g->addr + g->size - b)) return g;
  }
  return NULL;
}

const segment *hfci_shm_place(const hfc_client *c, hfp_filter *f, const pending *p) {
  uint64_t out_len, rgba_len = 0;
  if (!c->nsegs || c->active < 0 ||
      hfp_output_bytes(f->width, f->height, HFP_OUTPUTS, f->out_dtype, &out_len))
    return NULL;
  if (p->rgba && hfp_output_bytes(f->width, f->height, 4, f->out_dtype, &rgba_len)) return NULL;
  const segment *g = seg_of(c, p->features, f->data_len);
  if (!g || g->conn_serial != c->conns[c->active].serial || seg_of(c, p->result, out_len) != g ||
      (p->rgba && seg_of(c, p->rgba, rgba_len) != g))
    return NULL;
  f->shm_in = (uint64_t)((const uint8_t *)p->features - g->addr);
  f->shm_out = (uint64_t)((const uint8_t *)p->result - g->addr);
  f->shm_rgba = p->rgba ? (uint64_t)((const uint8_t *)p->rgba - g->addr) : 0;
  if (hfp_shm_check(f, g->size)) return NULL;  /* misaligned or overlapping: use the socket */
  return g;
}

void hfci_shm_orphan(hfc_client *c, uint64_t serial) {
  for (int i = 0; i < c->nsegs; i++)
    if (c->segs[i].conn_serial == serial) c->segs[i].conn_serial = 0;
}

void hfci_shm_release_all(hfc_client *c) {
  for (int i = 0; i < c->nsegs; i++) munmap(c->segs[i].addr, c->segs[i].size);
  c->nsegs = 0;
}

static int shm_alloc(hfc_client *c, size_t bytes, void **mem) {
  hfci_begin(c);
  if (!c || !mem) return hfci_arg(c, "hfc_shm_alloc: %s is NULL", c ? "mem" : "the client");
  *mem = NULL;
  if (bytes == 0)
    return hfci_arg(c, "hfc_shm_alloc: bytes is 0: want the bytes of the buffers to share "
                       "(hfc_features_bytes, hfc_estimate_bytes, hfc_output_bytes)");
  int k = hfci_need_conn(c);
  if (k < 0) return k;
  if (!c->conns[k].info.shm) {
    hfci_msg(c, "%s offers no shared memory (only Unix sockets do, unless the server runs "
                "with --max-shm-mb 0)", c->eps[c->conns[k].endpoint].url);
    return HFC_E_UNSUPPORTED;
  }
  if (c->nsegs == MAX_SEGS) {
    hfci_msg(c, "%d segments already: free one with hfc_shm_free", MAX_SEGS);
    return HFC_E_INFLIGHT;
  }
  uint8_t frame[HFP_HEADER_SIZE + 8];
  int n = hfp_encode_shm_create(frame, sizeof frame, (uint64_t)bytes);
  if (n < 0) return hfci_arg(c, "hfc_shm_alloc: bytes is %zu, which cannot be encoded", bytes);
  for (int i = 0; i < MAX_CONNS; i++)
    if (c->conns[i].rx_fd >= 0) {
      close(c->conns[i].rx_fd);
      c->conns[i].rx_fd = -1;
    }
  int rc = hfci_control(c, frame, (size_t)n, HFP_SHM_CREATED);
  if (rc) return rc;
  conn *x = &c->conns[c->ctl_conn];
  uint32_t id;
  uint64_t size;
  rc = hfp_decode_shm_created(c->ctl, c->ctl_len, &id, &size);
  free(c->ctl);
  c->ctl = NULL;
  int fd = x->rx_fd;
  x->rx_fd = -1;
  if (rc || size != bytes || fd < 0) {
    if (fd >= 0) close(fd);
    snprintf(x->why, sizeof x->why, "a SHM_CREATED %s",
             fd < 0 ? "without its descriptor" : "that does not match the request");
    hfci_conn_lost(c, c->ctl_conn, HFC_E_PROTOCOL);
    return HFC_E_PROTOCOL;
  }
  void *addr = mmap(NULL, bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  int map_errno = errno;   /* before the close and the send below */
  close(fd);
  if (addr == MAP_FAILED) {
    uint8_t d[HFP_HEADER_SIZE + 4];
    int dn = hfp_encode_shm_destroy(d, sizeof d, id);
    if (dn > 0 && !x->draining && (rc = hfci_send_io(x->fd, x->ssl, c->timeout_ms, d, (size_t)dn)))
      hfci_send_failed(c, c->ctl_conn, rc);
    hfci_msg(c, "mmap of a %zu-byte segment failed: %s (the process's address space or "
                "memory limit)", bytes, strerror(map_errno));
    return HFC_E_NOMEM;
  }
  c->segs[c->nsegs++] = (segment){id, addr, bytes, x->draining ? 0 : x->serial};
  *mem = addr;
  return 0;
}

/* Whether a pending request has a buffer in g: the server or the socket
 * path may still read or write it. */
static int in_use(const hfc_client *c, const segment *g) {
  for (int k = 0; k < c->np; k++) {
    const pending *p = &c->p[k];
    if (p->state != P_SENT && p->state != P_QUEUED) continue;
    if (seg_of(c, p->features, 1) == g || seg_of(c, p->result, 1) == g ||
        (p->rgba && seg_of(c, p->rgba, 1) == g) ||
        (p->estimate_buffer && seg_of(c, p->estimate_buffer, 1) == g))
      return 1;
  }
  return 0;
}

static int shm_free(hfc_client *c, void *mem) {
  hfci_begin(c);
  if (!c || !mem) return hfci_arg(c, "hfc_shm_free: %s is NULL", c ? "mem" : "the client");
  for (int i = 0; i < c->nsegs; i++) {
    segment g = c->segs[i];
    if (g.addr != mem) continue;
    if (in_use(c, &c->segs[i]))
      return hfci_arg(c, "hfc_shm_free: a request pending on this segment still uses it: "
                         "wait for its completion first");
    munmap(g.addr, g.size);
    c->segs[i] = c->segs[--c->nsegs];
    /* The connection that made it releases it; one that is gone, or
     * draining (half-closed), has dropped it or will on closing. */
    for (int k = 0; k < MAX_CONNS; k++) {
      conn *x = &c->conns[k];
      if (x->fd < 0 || x->serial != g.conn_serial || x->draining || !g.conn_serial) continue;
      uint8_t d[HFP_HEADER_SIZE + 4];
      int n = hfp_encode_shm_destroy(d, sizeof d, g.id);
      int rc = n < 0 ? HFC_E_ARG : hfci_send_io(x->fd, x->ssl, c->timeout_ms, d, (size_t)n);
      if (rc) hfci_send_failed(c, k, rc);
      return rc;
    }
    return 0;
  }
  return hfci_arg(c, "hfc_shm_free: %p is not a segment of this client (from hfc_shm_alloc)", mem);
}

/* Either may lose the connection (a send that fails), which completes the
 * frames in flight on it: hfc_fd must then poll readable for them, as no
 * socket shows them. */
int hfc_shm_alloc(hfc_client *c, size_t bytes, void **mem) {
  int rc = shm_alloc(c, bytes, mem);
  if (c) hfci_due_update(c);
  return rc;
}

int hfc_shm_free(hfc_client *c, void *mem) {
  int rc = shm_free(c, mem);
  if (c) hfci_due_update(c);
  return rc;
}
