/*
 * Receive buffers kept for reuse (docs/SERVER.md, "Memory").
 *
 * A socket request's tensor is read into memory allocated for it, and its
 * result is written into more. Above glibc's mmap threshold every such
 * allocation is a fresh mapping whose pages fault in one by one as the
 * bytes land in them (24,577 faults for a 1024x1024 frame of 4 spp, and a
 * copy at 1.5 GB/s instead of the 7-25 GB/s of memory already touched).
 * The pool keeps the mappings of answered frames, faulted in, and hands
 * them to the next frames of the same or a somewhat smaller size, so a
 * frame is copied once into warm memory and its result written into warm
 * memory. Mappings are made in 2 MiB steps (transparent huge pages where
 * the kernel gives them: fewer faults and TLB misses), so frames of nearby
 * sizes share them.
 *
 * Bounded and accounted: idle buffers, and the part of a lent idle buffer
 * its frame has not been charged for yet, are counted in the memory the
 * daemon commits (hfd_rpool_reserve, next to mem_held), so --max-memory-mb holds
 * with the pool; idle buffers and the backends' cached plans together stay
 * within the worker's cache_cap, and the least recently used idle buffer
 * goes first whenever a frame needs the room (hfd_rpool_shrink). Frames
 * below HFD_RPOOL_MIN are left to malloc, whose heap already reuses them.
 *
 * Everything here runs on the loop thread, except idle_bytes, which the
 * worker reads to share cache_cap.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "server.h"

#define RPOOL_STEP ((size_t)2 << 20)

static size_t round_step(size_t n) { return (n + RPOOL_STEP - 1) & ~(RPOOL_STEP - 1); }

static hfd_rbuf *find(hfd_rpool *p, const void *addr) {
  for (hfd_rbuf *b = p->bufs; b; b = b->next)
    if (b->addr == addr) return b;
  return NULL;
}

static void unmap(hfd_rpool *p, hfd_rbuf *b) {
  hfd_rbuf **pp = &p->bufs;
  while (*pp != b) pp = &(*pp)->next;
  *pp = b->next;
  if (munmap(b->addr, b->cap)) hfd_err("receive pool: munmap: %s", strerror(errno));
  p->mapped_bytes -= b->cap;
  free(b);
}

static void drop_idle(hfd_rpool *p, hfd_rbuf *b) {
  atomic_fetch_sub(&p->idle_bytes, b->cap);
  p->evicted++;
  unmap(p, b);
}

/* The least recently used idle buffer, or NULL. */
static hfd_rbuf *lru_idle(hfd_rpool *p) {
  hfd_rbuf *v = NULL;
  for (hfd_rbuf *b = p->bufs; b; b = b->next)
    if (!b->lent && (!v || b->last_use < v->last_use)) v = b;
  return v;
}

/* cap bytes (a multiple of RPOOL_STEP) of address space starting on a
 * RPOOL_STEP boundary, so that every 2 MiB of it can be one huge page; NULL
 * when there is none. Over-mapped by a step and trimmed: mmap promises only
 * page alignment. */
static void *map_aligned(size_t cap) {
  size_t len = cap + RPOOL_STEP;
  if (len < cap) return NULL;
  uint8_t *raw = mmap(NULL, len, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (raw == MAP_FAILED) return NULL;
  uint8_t *a = (uint8_t *)(((uintptr_t)raw + RPOOL_STEP - 1) & ~(uintptr_t)(RPOOL_STEP - 1));
  size_t head = (size_t)(a - raw), tail = len - head - cap;
  if ((head && munmap(raw, head)) || (tail && munmap(a + cap, tail)))
    hfd_err("receive pool: munmap: %s", strerror(errno));
  return a;
}

/* Faults in every page of [a, a + n) writable now. */
static void prefault(uint8_t *a, size_t n) {
#ifdef MADV_POPULATE_WRITE
  if (madvise(a, n, MADV_POPULATE_WRITE) == 0) return; /* Linux 5.14 and later */
#endif
  /* One store per small page (a huge page takes the first, the rest hit). */
  for (size_t i = 0; i < n; i += 4096) ((volatile uint8_t *)a)[i] = 0;
}

/* A new mapping of cap bytes, faulted in when populate is set. Huge pages
 * are asked for before the first fault: pages faulted in small stay small
 * until khugepaged, scanning a few MiB every ten seconds, merges them. On
 * the virtual machine of docs/PERFORMANCE.md ("Socket frames into reused
 * buffers") a 1024x1024 frame took about twice as long to receive into
 * small pages as into huge ones, frame by frame in the same minutes. */
static hfd_rbuf *map_new(hfd_rpool *p, size_t cap, int populate) {
  hfd_rbuf *b = calloc(1, sizeof *b);
  if (!b) return NULL;
  uint8_t *a = map_aligned(cap);
  if (!a) {
    free(b);
    return NULL;
  }
#ifdef MADV_HUGEPAGE
  (void)madvise(a, cap, MADV_HUGEPAGE); /* a hint; without THP nothing changes */
#endif
  if (populate) prefault(a, cap);
  b->addr = a;
  b->cap = cap;
  b->next = p->bufs;
  p->bufs = b;
  p->mapped_bytes += cap;
  return b;
}

void *hfd_rpool_take(hfd_rpool *p, size_t bytes) {
  if (bytes < HFD_RPOOL_MIN) {
    void *m = NULL;
    return posix_memalign(&m, 64, bytes ? bytes : 64) ? NULL : m;
  }
  /* The smallest idle buffer that holds the frame without wasting more
   * than the frame itself (a 100 MB buffer is not lent to a 2 MB frame,
   * whose uncharged rest would count against everyone). */
  hfd_rbuf *best = NULL;
  for (hfd_rbuf *b = p->bufs; b; b = b->next)
    if (!b->lent && b->cap >= bytes && b->cap / 2 <= bytes && (!best || b->cap < best->cap))
      best = b;
  uint64_t resident;
  if (best) {
    atomic_fetch_sub(&p->idle_bytes, best->cap);
    p->hits++;
    resident = best->cap; /* faulted in: stays counted, now as lent */
  } else {
    /* Not populated here: the loop thread would stall for the whole
     * frame's faults at once; they happen as the bytes arrive instead, and
     * the frame is charged for those bytes as they do (hfd_rpool_take's
     * comment in server.h). */
    size_t cap = round_step(bytes);
    if (cap < bytes || !(best = map_new(p, cap, 0))) return NULL;
    p->misses++;
    resident = 0;
  }
  best->lent = 1;
  best->warm = resident != 0;
  best->charged = 0;
  best->reserved = resident;
  p->lent_uncharged += resident;
  return best->addr;
}

uint64_t hfd_rpool_footprint(uint64_t bytes) {
  if (bytes < HFD_RPOOL_MIN || bytes > SIZE_MAX - RPOOL_STEP) return bytes;
  return round_step((size_t)bytes);
}

void hfd_rpool_charge(hfd_rpool *p, const void *addr, uint64_t n) {
  hfd_rbuf *b = addr ? find(p, addr) : NULL;
  if (!b || !b->lent) return;
  if (n > b->cap - b->charged) n = b->cap - b->charged;
  b->charged += n;
  /* Resident: all of a warm buffer; of a new mapping, the 2 MiB steps its
   * bytes have reached (a huge page faults in whole). */
  uint64_t resident = b->cap;
  if (!b->warm && round_step((size_t)b->charged) < b->cap) resident = round_step((size_t)b->charged);
  uint64_t reserved = resident - b->charged;
  p->lent_uncharged = p->lent_uncharged - b->reserved + reserved;
  b->reserved = reserved;
}

void hfd_rpool_give(hfd_rpool *p, void *addr, uint64_t cache_bytes, uint64_t cache_cap) {
  if (!addr) return;
  hfd_rbuf *b = find(p, addr);
  if (!b) {
    free(addr);
    return;
  }
  p->lent_uncharged -= b->reserved;
  b->lent = 0;
  b->warm = 0;
  b->charged = 0;
  b->reserved = 0;
  b->last_use = ++p->clock;
  /* Kept while idle buffers and the backends' cache fit cache_cap, older
   * idle buffers making way for it. */
  if (b->cap > cache_cap || cache_bytes > cache_cap - b->cap) {
    p->evicted++;
    unmap(p, b);
    return;
  }
  hfd_rbuf *v;
  while (atomic_load(&p->idle_bytes) + b->cap + cache_bytes > cache_cap && (v = lru_idle(p)))
    drop_idle(p, v);
  if (atomic_load(&p->idle_bytes) + b->cap + cache_bytes > cache_cap) {
    p->evicted++;
    unmap(p, b);
    return;
  }
  atomic_fetch_add(&p->idle_bytes, b->cap);
}

uint64_t hfd_rpool_reserve(const hfd_rpool *p) {
  return atomic_load(&p->idle_bytes) + p->lent_uncharged;
}

uint64_t hfd_rpool_shrink(hfd_rpool *p, uint64_t want) {
  uint64_t freed = 0;
  hfd_rbuf *v;
  while (freed < want && (v = lru_idle(p))) {
    freed += v->cap;
    drop_idle(p, v);
  }
  return freed;
}

int hfd_rpool_prefault(hfd_rpool *p, size_t bytes, uint64_t cache_cap) {
  if (bytes < HFD_RPOOL_MIN) return 0;
  size_t cap = round_step(bytes);
  for (hfd_rbuf *b = p->bufs; b; b = b->next)
    if (b->cap == cap) return 0; /* one per size is enough to start */
  if (atomic_load(&p->idle_bytes) + cap > cache_cap) return -1;
  hfd_rbuf *b = map_new(p, cap, 1);
  if (!b) return -1;
  b->last_use = ++p->clock;
  atomic_fetch_add(&p->idle_bytes, cap);
  return 0;
}

void hfd_rpool_free(hfd_rpool *p) {
  while (p->bufs) unmap(p, p->bufs);
  atomic_store(&p->idle_bytes, 0);
  p->lent_uncharged = 0;
}

void hfd_rbuf_release(hfd_server *s, void *addr) {
  uint64_t kept = atomic_load(&s->worker.cached_bytes);
  hfd_rpool_give(&s->rpool, addr, kept, s->worker.cache_cap);
}

void *hfd_rbuf_result(hfd_server *s, uint64_t bytes) {
  void *p = hfd_rpool_take(&s->rpool, (size_t)bytes);
  hfd_rpool_charge(&s->rpool, p, bytes); /* charged in full at admission */
  return p;
}
