/* Chunks of a memory-bound pass over a frame shared between threads
 * (f16 <-> f32 conversion, the widening of an f16 input). Threads take
 * chunks in turn from a counter rather than fixed shares: on a machine
 * whose cores are shared with other work, a thread that is descheduled
 * holds up the pass by one chunk at most, and the caller's thread, which
 * also takes chunks, does the rest; and the caller waits for the chunks
 * taken, not for the threads, so one that the scheduler starts only after
 * the pass is done costs the pass nothing. A thread per call (tens of
 * microseconds) rather than a pool: the passes that use it are
 * milliseconds long, and there is no state to keep between frames. */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <unistd.h>

#include "hfcore.h"

/* Shared by the caller and the threads it starts, freed by the last one to
 * let go of it: a thread that the scheduler starts late, after every chunk
 * is done and the caller has returned, finds no chunk and only touches
 * this. */
typedef struct chunk_run {
  hf_chunk_fn fn;
  void *ctx;
  size_t n, chunk;
  _Atomic size_t next;          /* first item not yet taken */
  _Atomic size_t done;          /* items finished */
  _Atomic int refs;
  pthread_mutex_t mu;
  pthread_cond_t all_done;
} chunk_run;

typedef struct chunk_worker {
  chunk_run *run;
  int worker;
} chunk_worker;

static void take_chunks(chunk_run *r, int worker) {
  for (;;) {
    size_t b = atomic_fetch_add_explicit(&r->next, r->chunk, memory_order_relaxed);
    if (b >= r->n) return;
    size_t e = r->n - b < r->chunk ? r->n : b + r->chunk;
    r->fn(r->ctx, worker, b, e);
    if (atomic_fetch_add_explicit(&r->done, e - b, memory_order_acq_rel) + (e - b) == r->n) {
      pthread_mutex_lock(&r->mu);
      pthread_cond_broadcast(&r->all_done);
      pthread_mutex_unlock(&r->mu);
    }
  }
}

static void release(chunk_run *r) {
  if (atomic_fetch_sub_explicit(&r->refs, 1, memory_order_acq_rel) != 1) return;
  pthread_mutex_destroy(&r->mu);
  pthread_cond_destroy(&r->all_done);
  free(r);
}

static void *chunk_thread(void *arg) {
  chunk_worker w = *(chunk_worker *)arg;
  free(arg);
  take_chunks(w.run, w.worker);
  release(w.run);
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
  int nw = hf_parallel_workers(n, min_per_thread);
  chunk_run *r = nw > 1 && n > chunk ? malloc(sizeof *r) : NULL;
  if (!r) {
    /* One worker (or no memory to share the pass): the caller alone. */
    for (size_t b = 0; b < n; b += chunk) fn(ctx, 0, b, n - b < chunk ? n : b + chunk);
    return 1;
  }
  *r = (chunk_run){.fn = fn, .ctx = ctx, .n = n, .chunk = chunk, .refs = nw};
  pthread_mutex_init(&r->mu, NULL);
  pthread_cond_init(&r->all_done, NULL);
  pthread_attr_t attr;
  int detached = !pthread_attr_init(&attr) &&
                 !pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
  for (int k = 1; k < nw; k++) {
    chunk_worker *w = detached ? malloc(sizeof *w) : NULL;
    pthread_t tid;
    if (w) *w = (chunk_worker){r, k};
    /* A thread that cannot start takes no chunk: the others take its share. */
    if (!w || pthread_create(&tid, &attr, chunk_thread, w)) {
      free(w);
      atomic_fetch_sub(&r->refs, 1);
    }
  }
  if (detached) pthread_attr_destroy(&attr);
  take_chunks(r, 0);
  /* Wait for the chunks other threads still hold, not for the threads:
   * one not yet scheduled when the last chunk is done is not waited for. */
  pthread_mutex_lock(&r->mu);
  while (atomic_load_explicit(&r->done, memory_order_acquire) < n)
    pthread_cond_wait(&r->all_done, &r->mu);
  pthread_mutex_unlock(&r->mu);
  release(r);
  return nw;
}
