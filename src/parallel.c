/* Chunks of a memory-bound pass over a frame shared between threads
 * (f16 <-> f32 conversion, the widening of an f16 input). Threads take
 * chunks in turn from a counter rather than fixed shares: on a machine
 * whose cores are shared with other work, a thread that is descheduled
 * holds up the pass by one chunk at most, and the caller's thread, which
 * also takes chunks, does the rest. A thread per call (tens of
 * microseconds) rather than a pool: the passes that use it are
 * milliseconds long, and there is no state to keep between frames. */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdatomic.h>
#include <unistd.h>

#include "hfcore.h"

typedef struct chunk_run {
  hf_chunk_fn fn;
  void *ctx;
  size_t n, chunk;
  _Atomic size_t next;
} chunk_run;

typedef struct chunk_worker {
  chunk_run *run;
  int worker;
} chunk_worker;

static void take_chunks(chunk_run *r, int worker) {
  for (;;) {
    size_t b = atomic_fetch_add_explicit(&r->next, r->chunk, memory_order_relaxed);
    if (b >= r->n) return;
    r->fn(r->ctx, worker, b, r->n - b < r->chunk ? r->n : b + r->chunk);
  }
}

static void *chunk_thread(void *arg) {
  chunk_worker *w = arg;
  take_chunks(w->run, w->worker);
  return NULL;
}

static int online_cpus(void) {
  static _Atomic int cpus = 0;
  int c = atomic_load_explicit(&cpus, memory_order_relaxed);
  if (!c) {
    long v = sysconf(_SC_NPROCESSORS_ONLN);
    c = v < 1 ? 1 : v > HF_PARALLEL_MAX ? HF_PARALLEL_MAX : (int)v;
    atomic_store(&cpus, c);
  }
  return c;
}

int hf_parallel_workers(size_t n, size_t min_per_thread) {
  size_t want = min_per_thread ? n / min_per_thread : (size_t)HF_PARALLEL_MAX;
  int c = online_cpus();
  return want < 1 ? 1 : want < (size_t)c ? (int)want : c;
}

int hf_parallel_chunks(size_t n, size_t chunk, size_t min_per_thread, hf_chunk_fn fn, void *ctx) {
  if (!n) return 0;
  if (!chunk) chunk = n;
  chunk_run r = {fn, ctx, n, chunk, 0};
  int nw = hf_parallel_workers(n, min_per_thread);
  if (nw < 2 || n <= chunk) {
    take_chunks(&r, 0);
    return 1;
  }
  chunk_worker w[HF_PARALLEL_MAX];
  pthread_t tid[HF_PARALLEL_MAX];
  int started[HF_PARALLEL_MAX] = {0};
  for (int k = 0; k < nw; k++) w[k] = (chunk_worker){&r, k};
  for (int k = 1; k < nw; k++) started[k] = pthread_create(&tid[k], NULL, chunk_thread, &w[k]) == 0;
  /* A thread that could not start takes no chunk: the others take its share. */
  take_chunks(&r, 0);
  for (int k = 1; k < nw; k++)
    if (started[k]) pthread_join(tid[k], NULL);
  return nw;
}
