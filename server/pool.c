/*
 * pool.c: threads that do work the event loop must not wait for, at a
 * lower CPU priority than the loop and the inference worker.
 *
 * What it is for: a TLS handshake (tls.c) costs the server a key exchange
 * and a signature before any token is checked, and a peer that replays a
 * recorded ClientHello pays next to nothing for it. Computed on the loop,
 * a flood of them held every other client's reads and replies, on every
 * listener, behind it. On these threads a flood takes their time (a few
 * of them, niced), and the loop goes on moving bytes.
 *
 * A task is submitted from the loop, run on one of the threads, and its
 * done callback runs on the loop after (through a uv_async). libuv's own
 * thread pool is not used: it also pins shared-memory segments
 * (conn.c), which would wait behind a flood, and its threads' priority is
 * not the pool's to lower.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "server.h"

#define POOL_MAX_THREADS 4
/* How much less CPU priority the threads take than the loop: nice 10 has a
 * tenth of the weight of nice 0 (CFS), so the loop and the inference
 * worker keep their cores while the threads are busy. */
#define POOL_NICE 10

struct hfd_pool {
  pthread_t threads[POOL_MAX_THREADS];
  int nthreads;
  pthread_mutex_t mu;
  pthread_cond_t cv;
  hfd_pool_task *q_head, *q_tail;     /* submitted, not taken by a thread */
  hfd_pool_task *done_head, *done_tail; /* run, for the loop */
  int stop;                           /* the threads exit once the queue is empty */
  int async_closed;                   /* no uv_async_send after this */
  int outstanding;                    /* loop: submitted, done not called yet */
  uv_async_t async;
  char what[32];
};

/* Threads: one per four CPUs this process may run on, at least one and at
 * most POOL_MAX_THREADS; the rest of the CPUs stay the loop's and the
 * inference worker's. */
static int pool_threads(void) {
  cpu_set_t set;
  int n = 0;
  if (sched_getaffinity(0, sizeof set, &set) == 0) n = CPU_COUNT(&set);
  if (n <= 0) {
    long c = sysconf(_SC_NPROCESSORS_ONLN);
    n = c > 0 ? (int)c : 1;
  }
  n /= 4;
  if (n < 1) n = 1;
  return n > POOL_MAX_THREADS ? POOL_MAX_THREADS : n;
}

static void *pool_main(void *arg) {
  hfd_pool *p = arg;
  /* Per-thread on Linux: setpriority on the thread's own id. Raising the
   * value needs no privilege; a failure leaves the thread at the loop's
   * priority, which is slower for others but correct. */
  pid_t tid = (pid_t)syscall(SYS_gettid);
  errno = 0;
  int prio = getpriority(PRIO_PROCESS, (id_t)tid);
  if (prio == -1 && errno != 0) {
    hfd_warn("%s thread: getpriority: %s; it runs at the loop's priority", p->what,
             strerror(errno));
  } else {
    int want = prio + POOL_NICE > 19 ? 19 : prio + POOL_NICE;
    if (want > prio && setpriority(PRIO_PROCESS, (id_t)tid, want) != 0)
      hfd_warn("%s thread: setpriority(%d): %s; it runs at the loop's priority", p->what, want,
               strerror(errno));
  }
  for (;;) {
    int rc = pthread_mutex_lock(&p->mu);
    if (rc) {
      hfd_err("%s thread: pthread_mutex_lock: %s; the thread stops", p->what, strerror(rc));
      return NULL;
    }
    while (!p->q_head && !p->stop) {
      rc = pthread_cond_wait(&p->cv, &p->mu);
      if (rc) {
        hfd_err("%s thread: pthread_cond_wait: %s; the thread stops", p->what, strerror(rc));
        pthread_mutex_unlock(&p->mu);
        return NULL;
      }
    }
    hfd_pool_task *t = p->q_head;
    if (!t) {
      pthread_mutex_unlock(&p->mu);
      return NULL;   /* stopping, nothing left */
    }
    p->q_head = t->next;
    if (!p->q_head) p->q_tail = NULL;
    pthread_mutex_unlock(&p->mu);

    t->run(t);

    if ((rc = pthread_mutex_lock(&p->mu)) != 0) {
      /* Cannot happen with a default mutex; the task is lost with its
       * connection, which the handshake deadline closes. */
      hfd_err("%s thread: pthread_mutex_lock: %s; the thread stops", p->what, strerror(rc));
      return NULL;
    }
    t->next = NULL;
    if (p->done_tail)
      p->done_tail->next = t;
    else
      p->done_head = t;
    p->done_tail = t;
    /* Under the lock, so that hfd_pool_close cannot close the handle
     * between the check and the send. */
    if (!p->async_closed && (rc = uv_async_send(&p->async)) < 0)
      hfd_err("%s thread: uv_async_send: %s", p->what, uv_strerror(rc));
    pthread_mutex_unlock(&p->mu);
  }
}

static void on_pool_async(uv_async_t *a) {
  hfd_pool *p = a->data;
  int rc = pthread_mutex_lock(&p->mu);
  if (rc) {
    /* A default mutex does not fail; the tasks wait for the next send. */
    hfd_err("%s threads: pthread_mutex_lock: %s", p->what, strerror(rc));
    return;
  }
  hfd_pool_task *t = p->done_head;
  p->done_head = p->done_tail = NULL;
  pthread_mutex_unlock(&p->mu);
  while (t) {
    hfd_pool_task *next = t->next;
    p->outstanding--;
    t->done(t);   /* may free t */
    t = next;
  }
}

int hfd_pool_start(hfd_pool **out, uv_loop_t *loop, const char *what) {
  *out = NULL;
  hfd_pool *p = calloc(1, sizeof *p);
  if (!p) {
    hfd_err("%s threads: out of memory", what);
    return -1;
  }
  snprintf(p->what, sizeof p->what, "%s", what);
  int rc = pthread_mutex_init(&p->mu, NULL);
  if (rc) {
    hfd_err("%s threads: pthread_mutex_init: %s", what, strerror(rc));
    free(p);
    return -1;
  }
  if ((rc = pthread_cond_init(&p->cv, NULL)) != 0) {
    hfd_err("%s threads: pthread_cond_init: %s", what, strerror(rc));
    pthread_mutex_destroy(&p->mu);
    free(p);
    return -1;
  }
  if ((rc = uv_async_init(loop, &p->async, on_pool_async)) < 0) {
    hfd_err("%s threads: uv_async_init: %s", what, uv_strerror(rc));
    pthread_cond_destroy(&p->cv);
    pthread_mutex_destroy(&p->mu);
    free(p);
    return -1;
  }
  p->async.data = p;
  /* The threads take no signal: the loop handles them (uv_signal). */
  sigset_t all, old;
  sigfillset(&all);
  /* A thread that takes one anyway runs libuv's handler, which only
   * writes to the loop's pipe: correct, so a failure here is said only. */
  int masked = (rc = pthread_sigmask(SIG_BLOCK, &all, &old)) == 0;
  if (!masked) hfd_err("%s threads: pthread_sigmask: %s", what, strerror(rc));
  int want = pool_threads();
  for (int i = 0; i < want; i++) {
    if ((rc = pthread_create(&p->threads[i], NULL, pool_main, p)) != 0) {
      hfd_err("%s threads: pthread_create: %s", what, strerror(rc));
      break;
    }
    p->nthreads++;
  }
  if (masked && (rc = pthread_sigmask(SIG_SETMASK, &old, NULL)) != 0)
    hfd_err("%s threads: pthread_sigmask: %s", what, strerror(rc));
  *out = p;
  /* Without a thread the daemon does not start (the caller returns):
   * the handle and p go with the process. */
  return p->nthreads ? 0 : -1;
}

int hfd_pool_threads(const hfd_pool *p) { return p ? p->nthreads : 0; }

int hfd_pool_submit(hfd_pool *p, hfd_pool_task *t) {
  int rc = pthread_mutex_lock(&p->mu);
  if (rc) return -rc;
  if (p->stop || p->async_closed) {
    pthread_mutex_unlock(&p->mu);
    return UV_ECANCELED;
  }
  t->next = NULL;
  if (p->q_tail)
    p->q_tail->next = t;
  else
    p->q_head = t;
  p->q_tail = t;
  p->outstanding++;
  rc = pthread_cond_signal(&p->cv);
  pthread_mutex_unlock(&p->mu);
  return rc ? -rc : 0;
}

int hfd_pool_outstanding(const hfd_pool *p) { return p ? p->outstanding : 0; }

void hfd_pool_close(hfd_pool *p) {
  if (!p || p->async_closed) return;
  int rc = pthread_mutex_lock(&p->mu);
  if (rc) hfd_err("%s threads: pthread_mutex_lock: %s", p->what, strerror(rc));
  p->async_closed = 1;
  if (!rc) pthread_mutex_unlock(&p->mu);
  uv_close((uv_handle_t *)&p->async, NULL);
}

void hfd_pool_free(hfd_pool *p) {
  if (!p) return;
  int rc = pthread_mutex_lock(&p->mu);
  if (rc == 0) {
    p->stop = 1;
    if ((rc = pthread_cond_broadcast(&p->cv)) != 0)
      hfd_err("%s threads: pthread_cond_broadcast: %s", p->what, strerror(rc));
    pthread_mutex_unlock(&p->mu);
  } else {
    hfd_err("%s threads: pthread_mutex_lock: %s", p->what, strerror(rc));
  }
  for (int i = 0; i < p->nthreads; i++)
    if ((rc = pthread_join(p->threads[i], NULL)) != 0)
      hfd_err("%s threads: pthread_join: %s", p->what, strerror(rc));
  if ((rc = pthread_cond_destroy(&p->cv)) != 0)
    hfd_err("%s threads: pthread_cond_destroy: %s", p->what, strerror(rc));
  if ((rc = pthread_mutex_destroy(&p->mu)) != 0)
    hfd_err("%s threads: pthread_mutex_destroy: %s", p->what, strerror(rc));
  free(p);
}
