/*
 * Shared-memory segments for local clients (PROTOCOL.md, "Shared memory").
 *
 * The server, not the client, makes each segment: a memfd, sized, sealed
 * against shrinking and growing, mapped, and handed to the client over the
 * Unix socket. A client-made segment could be truncated while the worker
 * reads it, and the worker would die of SIGBUS; a sealed one cannot change
 * size, so the worst a client can do is scribble over its own frame.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <unistd.h>

#include "server.h"

uint64_t hfd_shm_largest_frame(const hfd_server *s) {
  uint64_t most = 0;
  for (int v = 0; v < s->num_variants; v++) {
    const hfd_model *var = s->variants[v].model;
    if (!var) continue;  /* removed */
    uint64_t in = 0, out = 0, rgba = 0;
    unsigned flags = var->cfg.estimate ? HFP_FILTER_ESTIMATE : 0;
    if (hfp_filter_input_bytes((uint32_t)s->max_width, (uint32_t)s->max_height,
                               (uint32_t)var->cfg.spp, HFP_F32, flags, &in) ||
        hfp_output_bytes((uint32_t)s->max_width, (uint32_t)s->max_height, HFP_OUTPUTS, HFP_F32,
                         &out) ||
        hfp_output_bytes((uint32_t)s->max_width, (uint32_t)s->max_height, 4, HFP_F32, &rgba))
      continue;
    if (in + out + rgba > most) most = in + out + rgba;
  }
  return most;
}

uint64_t hfd_shm_client_cap(const hfd_server *s) {
  uint64_t all = s->cfg->max_shm_bytes;
  uint64_t set = s->cfg->max_shm_client_bytes;
  if (set) return set < all ? set : all;
  uint64_t cap = all / 4, frame = hfd_shm_largest_frame(s);
  if (cap < frame) cap = frame;
  return cap < all ? cap : all;
}

uint64_t hfd_shm_conn_cap(const hfd_server *s) {
  uint64_t all = s->cfg->max_shm_bytes;
  uint64_t set = s->cfg->max_shm_conn_bytes;
  if (set) return set < all ? set : all;
  return hfd_shm_client_cap(s);
}

uint64_t hfd_shm_segment_max(const hfd_server *s) {
  uint64_t conn = hfd_shm_conn_cap(s), client = hfd_shm_client_cap(s);
  return conn < client ? conn : client;
}

int hfd_shm_client_join(hfd_server *s, hfd_conn *c) {
  /* The process at the other end, as the kernel recorded it at connect:
   * one process is one client, whatever connections it opens. A process
   * that forks makes clients of its children; --max-connections bounds
   * how many connections, and so parts, they can have. */
  long pid = 0;
  uv_os_fd_t fd;
  struct ucred cr;
  socklen_t len = sizeof cr;
  int rc = uv_fileno(&c->h.handle, &fd);
  if (rc == 0 && getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cr, &len) == 0 && len == sizeof cr)
    pid = (long)cr.pid;
  else
    hfd_debug("conn %llu: the peer's process is not known (%s); the connection is a client of "
              "its own for --max-shm-mb-per-client", (unsigned long long)c->id,
              rc ? uv_strerror(rc) : strerror(errno));
  hfd_shm_client *k = NULL;
  if (pid > 0)
    for (k = s->shm_clients; k && k->pid != pid; k = k->next) {
    }
  if (!k) {
    k = calloc(1, sizeof *k);
    if (!k) {
      hfd_err("conn %llu: out of memory for its client's shared-memory count; the "
              "connection is a client of its own", (unsigned long long)c->id);
      return -1;
    }
    k->pid = pid;
    k->next = s->shm_clients;
    s->shm_clients = k;
  }
  k->conns++;
  c->shm_client = k;
  return 0;
}

void hfd_shm_client_leave(hfd_server *s, hfd_conn *c) {
  hfd_shm_client *k = c->shm_client;
  if (!k) return;
  c->shm_client = NULL;
  if (--k->conns > 0) return;
  for (hfd_shm_client **p = &s->shm_clients; *p; p = &(*p)->next)
    if (*p == k) {
      *p = k->next;
      break;
    }
  free(k);
}

int hfd_seg_create(hfd_server *s, hfd_conn *c, uint64_t bytes, hfd_seg **out, int *fd, char *why,
                   size_t whylen) {
  *out = NULL;
  *fd = -1;
  /* Larger than the whole budget: no retry can succeed. Larger than what
   * is left of it: it may, once other segments are released. */
  if (bytes > s->cfg->max_shm_bytes) {
    snprintf(why, whylen, "a segment of %llu bytes is larger than the whole shared-memory "
             "budget (--max-shm-mb %llu)", (unsigned long long)bytes,
             (unsigned long long)(s->cfg->max_shm_bytes >> 20));
    return HFP_E_TOO_LARGE;
  }
  /* So too against a connection's part of it and a client's (a process,
   * all its connections together), which keep one client from taking the
   * whole budget and leaving every other local client BUSY. A connection
   * whose process is not known is a client of its own. */
  uint64_t cap = hfd_shm_conn_cap(s), ccap = hfd_shm_client_cap(s);
  uint64_t cheld = c->shm_client ? c->shm_client->bytes : c->shm_bytes;
  int cconns = c->shm_client ? c->shm_client->conns : 1;
  if (bytes > cap) {
    snprintf(why, whylen, "a segment of %llu bytes is larger than one connection may hold "
             "(%llu bytes, --max-shm-mb-per-connection)", (unsigned long long)bytes,
             (unsigned long long)cap);
    return HFP_E_TOO_LARGE;
  }
  if (bytes > ccap) {
    snprintf(why, whylen, "a segment of %llu bytes is larger than one client may hold "
             "(%llu bytes, --max-shm-mb-per-client)", (unsigned long long)bytes,
             (unsigned long long)ccap);
    return HFP_E_TOO_LARGE;
  }
  if (c->shm_bytes + bytes > cap) {
    snprintf(why, whylen, "this connection holds %llu bytes of segments; %llu more would pass "
             "its %llu (--max-shm-mb-per-connection): release one first",
             (unsigned long long)c->shm_bytes, (unsigned long long)bytes,
             (unsigned long long)cap);
    return HFP_E_BUSY;
  }
  if (cheld + bytes > ccap) {
    /* Within an ERROR's 256 bytes with every number at its widest in
     * practice (a 7-digit pid, 64 GiB figures). */
    snprintf(why, whylen, "this client (process %ld, %d connection(s)) holds %llu bytes of "
             "segments; %llu more would pass its %llu (--max-shm-mb-per-client): release one "
             "first, or ask the operator to raise it for a client of many connections",
             c->shm_client ? c->shm_client->pid : 0L, cconns, (unsigned long long)cheld,
             (unsigned long long)bytes, (unsigned long long)ccap);
    return HFP_E_BUSY;
  }
  if (s->shm_held + bytes > s->cfg->max_shm_bytes) {
    snprintf(why, whylen, "shared memory full (%llu of %llu MiB held)",
             (unsigned long long)(s->shm_held >> 20),
             (unsigned long long)(s->cfg->max_shm_bytes >> 20));
    return HFP_E_BUSY;
  }
  hfd_seg *g = calloc(1, sizeof *g);
  if (!g) {
    snprintf(why, whylen, "out of memory");
    return HFP_E_BUSY;
  }
  int f = memfd_create("hairfilterd-segment", MFD_CLOEXEC | MFD_ALLOW_SEALING);
  if (f < 0) {
    snprintf(why, whylen, "memfd_create: %s", strerror(errno));
    free(g);
    return HFP_E_INTERNAL;
  }
  void *addr = MAP_FAILED;
  if (ftruncate(f, (off_t)bytes) != 0 ||
      fcntl(f, F_ADD_SEALS, F_SEAL_SHRINK | F_SEAL_GROW | F_SEAL_SEAL) != 0 ||
      (addr = mmap(NULL, (size_t)bytes, PROT_READ | PROT_WRITE, MAP_SHARED, f, 0)) == MAP_FAILED) {
    snprintf(why, whylen, "cannot make a %llu-byte segment: %s", (unsigned long long)bytes,
             strerror(errno));
    close(f);
    free(g);
    return errno == ENOMEM || errno == ENOSPC ? HFP_E_BUSY : HFP_E_INTERNAL;
  }
  g->addr = addr;
  g->size = bytes;
  g->owner = c;
  c->shm_bytes += bytes;
  if (c->shm_client) c->shm_client->bytes += bytes;
  s->shm_held += bytes;
  *out = g;
  *fd = f;
  return 0;
}

/* A GPU backend pins the segment once, so requests in it are copied by DMA
 * with no staging copy. */
int hfd_seg_pin(hfd_server *s, hfd_seg *g) {
  if (!s->worker.backend) return HF_OK;
  return hf_backend_host_register(s->worker.backend, g->addr, (size_t)g->size);
}

void hfd_seg_pinned(hfd_server *s, hfd_seg *g, int rc) {
  g->registered = s->worker.backend && rc == HF_OK;
  static int warned;
  if (rc && !warned) {
    warned = 1;
    hfd_warn("%s could not pin a shared-memory segment (%s); requests in segments "
             "are staged", hf_backend_name(s->worker.backend), hf_strerror(rc));
  }
}

static void seg_free(hfd_server *s, hfd_seg *g) {
  /* No job uses the segment any more (refs == 0): no transfer is pending. */
  if (g->registered) hf_backend_host_unregister(s->worker.backend, g->addr);
  /* The pages go back now, not when the last descriptor closes: the
   * client keeps its copy of the memfd as long as it likes, and the pages
   * the worker faulted in (reading features the client never wrote,
   * writing results) are charged to this process. A client that made,
   * used and released segments in a loop, keeping each descriptor, would
   * otherwise hold memory without bound outside --max-shm-mb, which has
   * given the segment's bytes back. The seals (no F_SEAL_WRITE) allow the
   * hole; a client still mapping the segment reads zeros from now on. */
  if (madvise(g->addr, (size_t)g->size, MADV_REMOVE) != 0)
    hfd_err("madvise(MADV_REMOVE) of a %llu-byte segment: %s; its pages stay until the "
            "client closes its descriptor", (unsigned long long)g->size, strerror(errno));
  if (munmap(g->addr, (size_t)g->size) != 0)
    hfd_err("munmap of a %llu-byte segment: %s", (unsigned long long)g->size,
            strerror(errno));
  s->shm_held -= g->size;
  if (g->owner) {
    g->owner->shm_bytes -= g->size;
    if (g->owner->shm_client) g->owner->shm_client->bytes -= g->size;
  }
  free(g);
}

void hfd_seg_unref(hfd_server *s, hfd_seg *g) {
  if (--g->refs == 0 && g->dropped) seg_free(s, g);
}

void hfd_seg_drop(hfd_server *s, hfd_seg *g) {
  g->dropped = 1;
  if (g->refs == 0) seg_free(s, g);
}
