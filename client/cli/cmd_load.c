/*
 * hairfilter load: drives hairfilterd,
 * or any server of protocol/PROTOCOL.md, and measures latency against
 * throughput, after NVIDIA's perf_analyzer:
 *
 *   closed loop  --concurrency-range start:end:step  requests kept in flight
 *   open loop    --request-rate-range start:end:step frames/s offered, at
 *                constant or Poisson arrivals (--request-distribution)
 *
 * Each point of the sweep warms up, then measures windows of --window
 * seconds until the client p50 and p99 and the throughput of the last three
 * agree within --stability-percentage of their mean (or --max-trials is
 * reached), and reports those three merged: client percentiles from a
 * streaming histogram (load_hist.h, bounded memory), the server's RESULT
 * breakdown (queue, input, infer, output), BUSY and errors, and the
 * server's STATS differenced over the point. The windows count only
 * requests due after the first STATS was answered: one due before could
 * be written, and counted in that STATS, while its reply still waits in
 * the socket, and the server's difference would then miss a frame the
 * client counts.
 *
 * One thread per connection, since an hfc_client is single-threaded. In the
 * open loop each connection offers rate/connections frames/s; a request's
 * latency counts from when it was due, not from when a free slot let it go,
 * so a server that falls behind shows it (no coordinated omission). In the
 * closed loop a request refused BUSY or SHUTTING_DOWN is counted and its slot rests 10 ms
 * before it sends again, so that a refusing server is not spun against.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>

#include "cli_args.h"
#include "cli_common.h"
#include "commands.h"
#include <hairfilter/hairfilter.h>
#include "load.h"
#include "load_variant.h"
#include "run_header.h"

typedef struct opts {
  const char *server, *variant, *token, *input, *part, *json, *csv, *plot;
  cli_tls tls;
  int width, height, f16, shm, composite, quiet, verbose;
  int connections;               /* 0: per mode default */
  int inflight;                  /* per connection, legacy closed-loop form */
  double conc[3], rate[3];       /* ranges; conc[0] 0 / rate[0] 0: not given */
  int poisson;
  double window_s, warmup_s, stability;
  double drain_s;                /* how long requests may take to be answered after a point */
  int max_trials, trials;        /* trials > 0: exactly that many windows */
  uint32_t deadline_us;          /* --deadline: each frame's budget at the server; 0: none */
} opts;

enum { PHASE_WARMUP, PHASE_MEASURE, PHASE_STOP };

/* Shared by the workers of one point and the main thread. */
typedef struct shared {
  const opts *o;
  int spp;
  int estimate;                 /* the variant reads the alpha-corrected estimate */
  const void *features;          /* one frame, in the input dtype */
  size_t in_bytes, out_bytes, rgba_bytes;
  int open_loop;
  double rate_per_conn;
  atomic_int phase;
  pthread_mutex_t mu;
  load_window *cur;              /* under mu */
  atomic_uint_fast64_t sent, answered, delayed;
  /* Requests sent in the warm-up, and how they were answered: the server
   * counts them too. */
  atomic_uint_fast64_t warm_sent, warm_ok, warm_busy, warm_errors, warm_expired;
  /* Every answer to a request sent after the warm-up, by outcome, whether
   * or not a window counted it (those answered after the last window, or
   * due before the first STATS): they add up to the answered requests, as
   * the server's STATS count them. */
  atomic_uint_fast64_t ans_ok, ans_busy, ans_errors, ans_expired;
  atomic_int lost;
  /* Connections that stopped at a refusal no retry can fix, and whether
   * it has been said (once for all of them). */
  atomic_int refused, refusal_said;
  atomic_int ready;              /* connections set up (connected, segment mapped) */
  double t_stop;                 /* when the point stopped sending */
  double t_measure;              /* under mu: requests due from then on count */
} shared;

typedef struct worker {
  pthread_t thread;
  shared *sh;
  int index, nconn;
  int inflight;                  /* closed loop: requests kept in flight */
  int max_inflight;              /* the server's per-connection limit */
  uint64_t seed;
  int failed;
  int refused;                   /* a refusal no retry can fix: sends no more */
  int saw_draining;              /* the server answered SHUTTING_DOWN */
} worker;

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

/* Set by SIGINT or SIGTERM: the point in progress stops, and what was
 * measured is reported. */
static volatile sig_atomic_t interrupted;

static void on_signal(int sig) { interrupted = sig; }

static void sleep_s(double s) {
  if (s <= 0) return;
  struct timespec ts = {(time_t)s, (long)((s - floor(s)) * 1e9)};
  while (nanosleep(&ts, &ts) && errno == EINTR && !interrupted) {
  }
}

/* Options of every connection the tool makes. */
static hfc_options client_options(const char *name, const opts *o) {
  hfc_options co;
  hfc_options_init(&co);
  co.client_name = name;
  co.token = o->token;
  co.tls_ca_file = o->tls.ca;
  co.tls_cert_file = o->tls.cert;
  co.tls_key_file = o->tls.key;
  co.tls_server_name = o->tls.server_name;
  co.timeout_ms = 30000;
  return co;
}

/* ---- recording ------------------------------------------------------------- */

static void record(shared *sh, const hfc_completion *d, double started, int warm) {
  /* Local failures (a closed connection, a timeout) are not answers. */
  if (d->status > HFC_E_ARG) atomic_fetch_add(&sh->answered, 1);
  /* BUSY and SHUTTING_DOWN refuse for now, not for good: busy, apart from
   * the errors (as hairfilter-load counts them). */
  int refused = d->status == HFC_E_BUSY || d->status == HFC_E_SHUTTING_DOWN;
  /* EXPIRED: the frame's --deadline passed in the server's queue, what the
   * option is there to count; not an error. */
  int expired = d->status == HFC_E_EXPIRED;
  if (warm) {
    if (refused) atomic_fetch_add(&sh->warm_busy, 1);
    else if (expired) atomic_fetch_add(&sh->warm_expired, 1);
    else if (!d->status) atomic_fetch_add(&sh->warm_ok, 1);
    else if (d->status > HFC_E_ARG) atomic_fetch_add(&sh->warm_errors, 1);
    return;
  }
  if (refused) atomic_fetch_add(&sh->ans_busy, 1);
  else if (expired) atomic_fetch_add(&sh->ans_expired, 1);
  else if (!d->status) atomic_fetch_add(&sh->ans_ok, 1);
  else if (d->status > HFC_E_ARG) atomic_fetch_add(&sh->ans_errors, 1);
  if (atomic_load(&sh->phase) != PHASE_MEASURE) return;
  double t = now_s();
  pthread_mutex_lock(&sh->mu);
  if (started < sh->t_measure) {   /* due before the first STATS: see the top */
    pthread_mutex_unlock(&sh->mu);
    return;
  }
  load_window *w = sh->cur;
  if (refused) {
    w->busy++;
  } else if (expired) {
    w->expired++;
  } else if (d->status) {
    w->errors++;
  } else {
    w->ok++;
    w->batch_sum += (uint64_t)d->timing.batch;
    const hfc_timing *tm = &d->timing;
    double v[LF_COUNT] = {(t - started) * 1e6, tm->server_us, tm->queue_us,
                          tm->input_us,        tm->infer_us,  tm->output_us};
    for (int k = 0; k < LF_COUNT; k++) lh_record(&w->h[k], v[k] > 0 ? (uint64_t)(v[k] + 0.5) : 0);
  }
  pthread_mutex_unlock(&sh->mu);
}

/* xorshift64*, for Poisson gaps: each connection its own stream. */
static double uniform01(uint64_t *s) {
  *s ^= *s >> 12;
  *s ^= *s << 25;
  *s ^= *s >> 27;
  return (double)((*s * 2685821657736338717ull) >> 11) / 9007199254740992.0;
}

/* ---- one connection ----------------------------------------------------------- */

/* A closed-loop request refused BUSY (or SHUTTING_DOWN, by a server that is
 * stopping) goes again after this long, so that a refusing server is not
 * spun against (that would take the CPU it needs). */
#define BUSY_BACKOFF_S 0.01

typedef struct slot {
  int busy;
  double started;                /* when the request was due */
  double not_before;             /* closed loop, after a BUSY: not sent again before */
  int warm;                      /* sent in the warm-up */
  void *out, *rgba;
} slot;

/* Sends r into slot s, its latency counted from started. */
static int submit(hfc_client *c, hfc_request *r, slot *s, double started, shared *sh,
                  int *pending) {
  s->started = started;
  r->result = s->out;
  r->rgba = s->rgba;
  r->user = s;
  int err = hfc_submit(c, r, NULL);
  if (err) return err;
  s->busy = 1;
  (*pending)++;
  s->warm = atomic_load(&sh->phase) == PHASE_WARMUP;
  if (s->warm) atomic_fetch_add(&sh->warm_sent, 1);
  atomic_fetch_add(&sh->sent, 1);
  return 0;
}

/* Whether stderr is a terminal: the progress line is drawn there. */
static int isatty_err;

static void *run(void *arg) {
  worker *w = arg;
  shared *sh = w->sh;
  const opts *o = sh->o;
  hfc_client *c = NULL;
  hfc_options co = client_options("hairfilter-load", o);
  int rc = hfc_connect(o->server, &co, &c);
  if (rc) {
    /* The server's reason (its connection limit, say), which starts with
     * the endpoint; the code's words are a guess at it. */
    const char *m = hfc_last_message(NULL);
    fprintf(stderr, "hairfilter load: connection %d: %s\n", w->index,
            m[0] ? m : hfc_strerror(rc));
    w->failed = 1;
    atomic_fetch_add(&sh->lost, 1);
    return NULL;
  }
  int k = sh->open_loop ? w->max_inflight : w->inflight;
  /* Open loop over shared memory: the connections share one connection's
   * limit, so that the first to connect do not take the whole segment
   * budget (a late request waits for a slot; its latency still counts from
   * when it was due). */
  if (sh->open_loop && o->shm && w->nconn > 1) k = k / w->nconn > 1 ? k / w->nconn : 1;
  slot *slots = calloc((size_t)k, sizeof *slots);
  size_t per = sh->out_bytes + sh->rgba_bytes;
  uint8_t *mem = NULL, *heap = NULL;
  const void *in = sh->features;
  if (slots && o->shm) {
    /* One segment: the features once, then a result (and composite) per
     * slot. In the open loop, where k is only the most the server allows in
     * flight, fewer slots are taken when the server's shared memory cannot
     * hold them all (BUSY: not now; TOO_LARGE: not within its budget). */
    while (((rc = hfc_shm_alloc(c, sh->in_bytes + per * (size_t)k, (void **)&mem)) == HFC_E_BUSY ||
            rc == HFC_E_TOO_LARGE) &&
           sh->open_loop && k > 1)
      k /= 2;
    if (rc) {
      /* The server's reason (the part of its budget one client may hold,
       * say), which names the option to raise; the code's words are a
       * guess at it. */
      const char *m = hfc_last_message(c);
      fprintf(stderr, "hairfilter load: connection %d: shared memory: %s\n", w->index,
              m[0] ? m : hfc_strerror(rc));
      w->failed = 1;
    } else {
      memcpy(mem, sh->features, sh->in_bytes);
      in = mem;
    }
  } else if (slots) {
    heap = malloc(per * (size_t)k);
  }
  uint8_t *outs = mem ? mem + sh->in_bytes : heap;
  if (!slots || (!mem && !heap) || w->failed) {
    if (!w->failed) fprintf(stderr, "hairfilter load: out of memory\n");
    w->failed = 1;
    atomic_fetch_add(&sh->lost, 1);
    free(slots);
    free(heap);
    hfc_close(c);
    return NULL;
  }
  for (int i = 0; i < k; i++) {
    slots[i].out = outs + per * (size_t)i;
    slots[i].rgba = o->composite ? outs + per * (size_t)i + sh->out_bytes : NULL;
  }
  hfc_request r;
  hfc_request_init(&r);
  r.variant = o->variant;
  r.width = o->width;
  r.height = o->height;
  r.spp = sh->spp;
  r.estimate = sh->estimate;
  r.deadline_us = o->deadline_us;
  r.in_dtype = r.out_dtype = o->f16 ? HFC_F16 : HFC_F32;
  r.features = in;
  r.features_bytes = sh->in_bytes;
  r.result_bytes = sh->out_bytes;
  r.rgba_bytes = o->composite ? sh->rgba_bytes : 0;
  memcpy(r.hair, CLI_HAIR_DEFAULT, sizeof r.hair);
  memcpy(r.light, CLI_LIGHT_DEFAULT, sizeof r.light);
  memcpy(r.background, CLI_BG_DEFAULT, sizeof r.background);
  int pending = 0;
  atomic_fetch_add(&sh->ready, 1);
  /* Open loop: due times of requests no slot was free for (bounded). */
  enum { BACKLOG = 4096 };
  double *backlog = sh->open_loop ? malloc(sizeof(double) * BACKLOG) : NULL;
  int bl_head = 0, bl_len = 0;
  double t_next = now_s();
  if (sh->open_loop) {
    /* Connections interleave evenly in the constant schedule. */
    t_next += o->poisson ? -log(1 - uniform01(&w->seed)) / sh->rate_per_conn
                         : (double)w->index / (sh->rate_per_conn * w->nconn);
  }
  int err = 0;
  for (;;) {
    int stopping = atomic_load(&sh->phase) == PHASE_STOP;
    if ((stopping || w->refused) && pending == 0) break;
    if (stopping && now_s() - sh->t_stop > o->drain_s) {
      fprintf(stderr, "\nhairfilter load: connection %d: %d request(s) unanswered %.0f s after "
                      "the end\n", w->index, pending, o->drain_s);
      break;
    }
    /* Submit what is due. */
    if (!stopping && !w->refused && !sh->open_loop) {
      double now = now_s();
      for (int i = 0; i < k && pending < k && !err; i++)
        if (!slots[i].busy && slots[i].not_before <= now)
          err = submit(c, &r, &slots[i], now_s(), sh, &pending);
    } else if (!stopping && !w->refused && sh->open_loop) {
      double now = now_s();
      while (t_next <= now) {
        /* Due with every slot taken: it waits for one (and its latency
         * counts from now on). */
        if (pending + bl_len >= k) atomic_fetch_add(&sh->delayed, 1);
        if (bl_len < BACKLOG)
          backlog[(bl_head + bl_len++) % BACKLOG] = t_next;
        t_next += o->poisson ? -log(1 - uniform01(&w->seed)) / sh->rate_per_conn
                             : 1.0 / sh->rate_per_conn;
      }
      while (bl_len && pending < k && !err) {
        int i = 0;
        while (slots[i].busy) i++;
        double due = backlog[bl_head];
        bl_head = (bl_head + 1) % BACKLOG;
        bl_len--;
        err = submit(c, &r, &slots[i], due, sh, &pending);
      }
    }
    if (err) break;
    /* Collect completions: block until one comes, the next is due, or (to
     * notice a stop) 100 ms pass. */
    int wait_ms = 100;
    if (sh->open_loop && !stopping) {
      double dt = t_next - now_s();
      if (bl_len && pending < k) dt = 0;
      wait_ms = dt <= 0 ? 0 : dt < 0.1 ? (int)ceil(dt * 1e3) : 100;
    }
    if (!sh->open_loop && !stopping && pending < k) {
      /* Slots resting after a BUSY: wake when the first may go again. */
      double now = now_s(), first = now + 0.1;
      for (int i = 0; i < k; i++)
        if (!slots[i].busy && slots[i].not_before < first) first = slots[i].not_before;
      wait_ms = first <= now ? 0 : (int)ceil((first - now) * 1e3);
    }
    if (pending == 0) {
      if (wait_ms) sleep_s(wait_ms / 1e3);
      continue;
    }
    hfc_completion d;
    int wr = hfc_wait(c, wait_ms, &d);
    if (wr == HFC_E_TIMEOUT) continue;
    if (wr) {
      err = wr;
      break;
    }
    slot *s = d.user;
    s->busy = 0;
    pending--;
    if (d.status == HFC_E_BUSY || d.status == HFC_E_SHUTTING_DOWN)
      s->not_before = now_s() + BUSY_BACKOFF_S;
    if (d.status == HFC_E_SHUTTING_DOWN) w->saw_draining = 1;
    record(sh, &d, s->started, s->warm);
    if (d.status < 0 && d.status > HFC_E_ARG && d.status != HFC_E_BUSY &&
        d.status != HFC_E_SHUTTING_DOWN && d.status != HFC_E_INTERNAL &&
        d.status != HFC_E_EXPIRED && !w->refused) {
      /* A refusal no retry can fix (the variant a reload removed, say):
       * sent again, each frame would be refused again, as fast as the
       * server answers. This connection sends no more (as hairfilter-load). */
      w->refused = 1;
      atomic_fetch_add(&sh->refused, 1);
      if (!atomic_exchange(&sh->refusal_said, 1)) {
        const char *m = hfc_last_message(c);
        fprintf(stderr, "%shairfilter load: the server refused a frame: %s%s%s%s; stopping\n",
                isatty_err && !o->quiet ? "\n" : "", hfc_strerror(d.status), m[0] ? " (" : "",
                m, m[0] ? ")" : "");
      }
    }
  }
  if (err) {
    /* What was pending is lost with the connection; the main thread counts
     * it as unanswered. The library's message is for an engine (connect
     * again); the tool says what happened, off the progress line if one
     * is shown. */
    fprintf(stderr, "%shairfilter load: connection %d lost: %s%s\n",
            isatty_err && !o->quiet ? "\n" : "", w->index, hfc_strerror(err),
            w->saw_draining ? " (the server is stopping: it answered SHUTTING_DOWN before)" : "");
    atomic_fetch_add(&sh->lost, 1);
    w->failed = 1;
  }
  if (mem && !err) hfc_shm_free(c, mem);
  hfc_close(c);
  free(backlog);
  free(heap);
  free(slots);
  return NULL;
}

/* ---- the server's statistics ----------------------------------------------------- */

static int stats_of(const opts *o, hfc_variant_stats *out) {
  hfc_client *c = NULL;
  hfc_options co = client_options("hairfilter-load-stats", o);
  if (hfc_connect(o->server, &co, &c)) return -1;
  hfc_stats *st = malloc(sizeof *st);
  int rc = st ? hfc_get_stats(c, st) : -1, found = -1;
  for (int i = 0; !rc && i < st->num_variants; i++)
    if (!strcmp(st->variants[i].name, o->variant)) {
      *out = st->variants[i];
      found = 0;
    }
  free(st);
  hfc_close(c);
  return found;
}

static double hist_pct_ms(const uint64_t *h, double p) {
  uint64_t n = 0, seen = 0;
  for (int i = 0; i < HFC_HIST_BUCKETS; i++) n += h[i];
  if (!n) return 0;
  uint64_t rank = (uint64_t)ceil(p / 100 * (double)n);
  for (int i = 0; i < HFC_HIST_BUCKETS; i++) {
    seen += h[i];
    if (seen >= rank && seen) return i == HFC_HIST_BUCKETS - 1 ? INFINITY : (double)(32ull << i) / 1e3;
  }
  return 0;
}

static void stats_delta(const hfc_variant_stats *a, const hfc_variant_stats *b, load_stats *s) {
  memset(s, 0, sizeof *s);
  s->valid = 1;
  s->ok = b->requests_ok - a->requests_ok;
  s->failed = b->requests_failed - a->requests_failed;
  s->expired = b->expired - a->expired;
  s->cancelled = b->cancelled - a->cancelled;
  s->rejected = b->rejected - a->rejected;
  s->batches = b->batches - a->batches;
  if (s->ok) {
    s->mean_queue_ms = (double)(b->sum_queue_us - a->sum_queue_us) / (double)s->ok / 1e3;
    s->mean_infer_ms = (double)(b->sum_infer_us - a->sum_infer_us) / (double)s->ok / 1e3;
    s->mean_total_ms = (double)(b->sum_total_us - a->sum_total_us) / (double)s->ok / 1e3;
  }
  uint64_t h[HFC_HIST_BUCKETS];
  for (int i = 0; i < HFC_HIST_BUCKETS; i++) h[i] = b->hist_total[i] - a->hist_total[i];
  s->p50_total_ms = hist_pct_ms(h, 50);
  s->p99_total_ms = hist_pct_ms(h, 99);
}

/* ---- one point of the sweep ----------------------------------------------------- */


static void progress(const load_point *p, int trial, double elapsed, const load_window *w,
                     const opts *o) {
  if (!isatty_err || o->quiet) return;
  char what[64];
  if (p->open_loop)
    snprintf(what, sizeof what, "rate %g/s", p->rate);
  else
    snprintf(what, sizeof what, "concurrency %d", p->concurrency);
  fprintf(stderr, "\r\033[K%s  window %d  %.1f/%.1f s  %llu frames  %.1f frames/s  p50 %.2f ms  "
                  "p99 %.2f ms  busy %llu  errors %llu",
          what, trial, elapsed, o->window_s, (unsigned long long)w->ok,
          elapsed > 0 ? (double)w->ok / elapsed : 0.0, lh_percentile(&w->h[LF_CLIENT], 50) / 1e3,
          lh_percentile(&w->h[LF_CLIENT], 99) / 1e3, (unsigned long long)w->busy,
          (unsigned long long)w->errors);
  fflush(stderr);
}

static int within(const double *v, int n, double pct) {
  double mean = 0;
  for (int i = 0; i < n; i++) mean += v[i];
  mean /= n;
  for (int i = 0; i < n; i++)
    if (fabs(v[i] - mean) > pct / 100 * fabs(mean)) return 0;
  return 1;
}

enum { STABLE_OVER = 3 };   /* windows that must agree (as perf_analyzer) */

/* Adds window src to dst: histograms, counts and duration. */
static void window_merge(load_window *dst, const load_window *src) {
  for (int k = 0; k < LF_COUNT; k++) lh_merge(&dst->h[k], &src->h[k]);
  dst->ok += src->ok;
  dst->busy += src->busy;
  dst->errors += src->errors;
  dst->expired += src->expired;
  dst->batch_sum += src->batch_sum;
  dst->seconds += src->seconds;
}

static int run_point(const opts *o, shared *sh, int max_inflight, load_point *p) {
  int n = p->connections;
  worker *ws = calloc((size_t)n, sizeof *ws);
  /* A ring of the last STABLE_OVER windows, the current one, and (for
   * --trials) every window merged. */
  load_window *win = calloc(STABLE_OVER + 2, sizeof *win);
  load_window *all = &win[STABLE_OVER + 1];
  if (!ws || !win) {
    free(ws);
    free(win);
    fprintf(stderr, "hairfilter load: out of memory\n");
    return -1;
  }
  atomic_store(&sh->phase, PHASE_WARMUP);
  atomic_store(&sh->sent, 0);
  atomic_store(&sh->answered, 0);
  atomic_store(&sh->delayed, 0);
  atomic_store(&sh->warm_sent, 0);
  atomic_store(&sh->warm_ok, 0);
  atomic_store(&sh->warm_busy, 0);
  atomic_store(&sh->warm_errors, 0);
  atomic_store(&sh->warm_expired, 0);
  atomic_store(&sh->ans_ok, 0);
  atomic_store(&sh->ans_busy, 0);
  atomic_store(&sh->ans_errors, 0);
  atomic_store(&sh->ans_expired, 0);
  atomic_store(&sh->lost, 0);
  atomic_store(&sh->refused, 0);
  atomic_store(&sh->refusal_said, 0);
  atomic_store(&sh->ready, 0);
  sh->open_loop = p->open_loop;
  sh->rate_per_conn = p->open_loop ? p->rate / n : 0;
  sh->cur = &win[STABLE_OVER];
  /* SIGINT and SIGTERM go to this thread alone, which stops the point. */
  sigset_t stop_sigs, old_sigs;
  sigemptyset(&stop_sigs);
  sigaddset(&stop_sigs, SIGINT);
  sigaddset(&stop_sigs, SIGTERM);
  int masked = pthread_sigmask(SIG_BLOCK, &stop_sigs, &old_sigs) == 0;
  for (int i = 0; i < n; i++) {
    ws[i].sh = sh;
    ws[i].index = i;
    ws[i].nconn = n;
    ws[i].max_inflight = max_inflight;
    ws[i].inflight = p->concurrency / n + (i < p->concurrency % n);
    ws[i].seed = 0x9e3779b97f4a7c15ull * (uint64_t)(i + 1) + (uint64_t)(p->rate * 1000);
    if (pthread_create(&ws[i].thread, NULL, run, &ws[i])) {
      fprintf(stderr, "hairfilter load: cannot start a thread\n");
      if (masked) pthread_sigmask(SIG_SETMASK, &old_sigs, NULL);
      atomic_store(&sh->phase, PHASE_STOP);
      for (int j = 0; j < i; j++) pthread_join(ws[j].thread, NULL);
      free(ws);
      free(win);
      return -1;
    }
  }
  if (masked) pthread_sigmask(SIG_SETMASK, &old_sigs, NULL);
  /* The warm-up starts once every connection is set up: connecting and
   * mapping a large segment can take longer than a short window on a
   * loaded machine, which would then hold no frame. Each connection either
   * gets ready or fails (counted lost) within its timeouts. */
  while (atomic_load(&sh->ready) + atomic_load(&sh->lost) < n && !interrupted) sleep_s(0.005);
  sleep_s(o->warmup_s);
  hfc_variant_stats before, after;
  int have_before = stats_of(o, &before) == 0;
  pthread_mutex_lock(&sh->mu);
  memset(sh->cur, 0, sizeof *sh->cur);
  sh->t_measure = now_s();
  atomic_store(&sh->phase, PHASE_MEASURE);
  pthread_mutex_unlock(&sh->mu);
  int trials = o->trials ? o->trials : o->max_trials;
  for (int t = 1; t <= trials && !interrupted; t++) {
    double t0 = now_s();
    while (now_s() - t0 < o->window_s && !interrupted) {
      double left = o->window_s - (now_s() - t0);
      sleep_s(left < 0.25 ? left : 0.25);
      pthread_mutex_lock(&sh->mu);
      progress(p, t, now_s() - t0, sh->cur, o);
      pthread_mutex_unlock(&sh->mu);
      if (atomic_load(&sh->lost) + atomic_load(&sh->refused) == n) break;
    }
    if (interrupted) {
      /* The window cut short is dropped: its figures would not be a
       * window's. */
      if (isatty_err && !o->quiet) fprintf(stderr, "\r\033[K");
      fprintf(stderr, "hairfilter load: interrupted; the unfinished window %d (%.2f of %.1f s) "
                      "is dropped\n", t, now_s() - t0, o->window_s);
      p->interrupted = 1;
      break;
    }
    /* Close the window: it joins the ring of the last STABLE_OVER. */
    pthread_mutex_lock(&sh->mu);
    load_window *done = &win[(t - 1) % STABLE_OVER];
    memcpy(done, sh->cur, sizeof *done);
    done->seconds = now_s() - t0;
    memset(sh->cur, 0, sizeof *sh->cur);
    pthread_mutex_unlock(&sh->mu);
    window_merge(all, done);
    p->trials = t;
    if (t <= 64) {
      p->window_throughput[t - 1] = (double)done->ok / done->seconds;
      p->window_p50[t - 1] = lh_percentile(&done->h[LF_CLIENT], 50);
      p->window_p99[t - 1] = lh_percentile(&done->h[LF_CLIENT], 99);
    }
    if (o->verbose) {
      if (isatty_err && !o->quiet) fprintf(stderr, "\r\033[K");
      fprintf(stderr, "  window %d: %.2f s, %llu frames, %.2f frames/s, p50 %.3f ms, p99 %.3f ms, "
                      "busy %llu, errors %llu\n",
              t, done->seconds, (unsigned long long)done->ok, (double)done->ok / done->seconds,
              lh_percentile(&done->h[LF_CLIENT], 50) / 1e3,
              lh_percentile(&done->h[LF_CLIENT], 99) / 1e3, (unsigned long long)done->busy,
              (unsigned long long)done->errors);
    }
    if (atomic_load(&sh->lost) + atomic_load(&sh->refused) == n) break;
    if (!o->trials && t >= STABLE_OVER && t <= 64) {
      const double *tp = p->window_throughput + t - STABLE_OVER;
      const double *p50 = p->window_p50 + t - STABLE_OVER, *p99 = p->window_p99 + t - STABLE_OVER;
      if (tp[0] > 0 && within(tp, STABLE_OVER, o->stability) &&
          within(p50, STABLE_OVER, o->stability) && within(p99, STABLE_OVER, o->stability)) {
        p->stable = 1;
        break;
      }
    }
  }
  if (isatty_err && !o->quiet) fprintf(stderr, "\r\033[K");
  /* The result: with --trials (a soak), every window; else the last (up
   * to) STABLE_OVER, those that agreed. */
  memset(&p->result, 0, sizeof p->result);
  if (o->trials) {
    p->used = p->trials;
    p->result = *all;
  } else {
    p->used = p->trials < STABLE_OVER ? p->trials : STABLE_OVER;
    for (int i = 0; i < p->used; i++) window_merge(&p->result, &win[(p->trials - 1 - i) % STABLE_OVER]);
  }
  if (o->trials) p->stable = -1;   /* not asked */
  if (interrupted) p->interrupted = 1;
  /* Stop sending; every request sent must still be answered. */
  sh->t_stop = now_s();
  atomic_store(&sh->phase, PHASE_STOP);
  if (have_before && stats_of(o, &after) == 0) stats_delta(&before, &after, &p->stats);
  for (int i = 0; i < n; i++) pthread_join(ws[i].thread, NULL);
  p->warm_sent = atomic_load(&sh->warm_sent);
  p->warm_ok = atomic_load(&sh->warm_ok);
  p->warm_busy = atomic_load(&sh->warm_busy);
  p->warm_errors = atomic_load(&sh->warm_errors);
  p->warm_expired = atomic_load(&sh->warm_expired);
  p->ans_ok = atomic_load(&sh->ans_ok);
  p->ans_busy = atomic_load(&sh->ans_busy);
  p->ans_errors = atomic_load(&sh->ans_errors);
  p->ans_expired = atomic_load(&sh->ans_expired);
  p->sent = atomic_load(&sh->sent) - p->warm_sent;
  p->delayed = atomic_load(&sh->delayed);
  p->lost_connections = atomic_load(&sh->lost);
  p->refused_connections = atomic_load(&sh->refused);
  uint64_t sent_all = atomic_load(&sh->sent), answered_all = atomic_load(&sh->answered);
  p->unanswered = sent_all > answered_all ? sent_all - answered_all : 0;
  p->answered = p->sent > p->unanswered ? p->sent - p->unanswered : 0;
  free(ws);
  free(win);
  return p->lost_connections == n ? -1 : 0;
}

/* ---- options ------------------------------------------------------------------------- */

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter load --server URL --variant NAME [options]\n"
          "\n"
          "Drives a server with frames and measures latency against throughput.\n"
          "  --server URL                    unix:PATH, tcp:HOST:PORT, tls:HOST:PORT or tcp:PORT\n"
          "  --token T                       TCP token (default $HAIRFILTER_TOKEN)\n"
          "  --tls-ca FILE                   tls: URLs: PEM CA certificates the server's must\n"
          "                                  chain to (default: the system's)\n"
          "  --tls-server-name NAME          the name the server's certificate must carry\n"
          "                                  (default: the URL's host)\n"
          "  --tls-cert FILE --tls-key FILE  client certificate and key (mutual TLS), together\n"
          "  --variant NAME                  a variant the server lists\n"
          "  --size WxH                      random frames of this size (default 256x256)\n"
          "  --input FILE.exr [--part P]     or a real feature EXR (its size; its spp must be\n"
          "                                  the variant's or more)\n"
          "  --f16                           f16 features and results (default f32)\n"
          "  --composite                     ask for the composited RGBA too\n"
          "  --shm                           tensors in shared memory (Unix sockets)\n"
          "  --deadline DUR                  each frame's budget at the server (plain number:\n"
          "                                  ms; protocol version 4): a frame still queued\n"
          "                                  then is not computed, counted as 'expired'\n"
          "closed loop (default):\n"
          "  --concurrency-range S[:E[:STEP]] requests kept in flight, swept (default 1)\n"
          "  --connections N                 connections they are spread over (default: one\n"
          "                                  per request; open loop: 4)\n"
          "  --inflight K                    with --connections N and no range: N x K in flight\n"
          "open loop:\n"
          "  --request-rate-range S[:E[:STEP]] frames/s offered, swept\n"
          "  --request-distribution constant|poisson   arrivals (default constant)\n"
          "measurement:\n"
          "  --window DUR                    one measurement window (default 5s)\n"
          "  --stability-percentage P        the last 3 windows' throughput, p50 and p99 within\n"
          "                                  P %% of their mean make a point stable (default 10)\n"
          "  --max-trials N                  windows before giving up on stability (default 10)\n"
          "  --trials N                      exactly N windows, all merged, no stability check\n"
          "                                  (a soak)\n"
          "  --seconds DUR                   one window of DUR, no repetition (--trials 1)\n"
          "  --warmup DUR                    before each point (default 1s)\n"
          "output:\n"
          "  --json FILE, --csv FILE         every point ('-': stdout, and the report goes to\n"
          "                                  stderr); written under a temporary name, then\n"
          "                                  renamed; an earlier FILE is removed at the start\n"
          "  --plot FILE.png                 latency against throughput over the sweep (gnuplot)\n"
          "  --verbose                       each window's figures; --quiet: no progress line\n"
          "Durations take a unit (us, ms, s, m, h); a plain number is seconds.\n"
          "In the report, 'frames' are the answers inside the measured windows; 'requests\n"
          "sent' and 'answered' count from the first STATS to the stop, frames in flight\n"
          "across a window's end included; the server's STATS line counts what it finished\n"
          "between its two STATS, the second taken when sending stops; 'warm-up' counts\n"
          "the requests sent before the first STATS, which the server counts too.\n"
          "The report starts with the command line, the CPU, cores, UTC date and version.\n"
          "SIGINT or SIGTERM stops the point in progress (a window cut short is dropped)\n"
          "and reports and writes the points done.\n"
          "A frame refused for good (UNKNOWN_VARIANT after a reload, INVALID, ...) stops\n"
          "the sweep, naming the refusal; BUSY and SHUTTING_DOWN are retried after 10 ms.\n"
          "Exit status: 0 every point measured; 1 the server could not be reached or\n"
          "used, a point measured no frame, requests went unanswered, connections were\n"
          "lost, a frame was refused for good or a file could not be written; 2 bad\n"
          "options, or a frame or concurrency over the server's limits; 130 interrupted\n"
          "(SIGINT or SIGTERM).\n");
}

static int parse(int argc, char **argv, opts *o) {
  static const struct option lo[] = {
    {"server", required_argument, 0, 1},          {"variant", required_argument, 0, 2},
    {"token", required_argument, 0, 3},           {"size", required_argument, 0, 4},
    {"input", required_argument, 0, 5},           {"part", required_argument, 0, 6},
    {"f16", no_argument, 0, 7},                   {"composite", no_argument, 0, 8},
    {"shm", no_argument, 0, 9},                   {"concurrency-range", required_argument, 0, 10},
    {"connections", required_argument, 0, 11},    {"inflight", required_argument, 0, 12},
    {"request-rate-range", required_argument, 0, 13},
    {"request-distribution", required_argument, 0, 14},
    {"window", required_argument, 0, 15},         {"stability-percentage", required_argument, 0, 16},
    {"max-trials", required_argument, 0, 17},     {"trials", required_argument, 0, 18},
    {"seconds", required_argument, 0, 19},        {"warmup", required_argument, 0, 20},
    {"json", required_argument, 0, 21},           {"csv", required_argument, 0, 22},
    {"plot", required_argument, 0, 23},           {"verbose", no_argument, 0, 24},
    {"quiet", no_argument, 0, 25},                {"deadline", required_argument, 0, 26},
    {"help", no_argument, 0, 'h'},
    CLI_TLS_LONG_OPTIONS,
    {0, 0, 0, 0},
  };
  const char *cmd = "hairfilter load";
  long v;
  int size_given = 0;
  opterr = 0;
  optind = 1;
  int ch, li = 0;
  /* Options with a value seen, so that one given twice is refused rather
   * than the last silently winning (two --json files, two --window
   * lengths); a flag given twice says the same thing twice. */
  unsigned char seen[CLI_TLS_SERVER_NAME + 1] = {0};
  const char *seconds_with = NULL;   /* --window, --trials or --max-trials beside --seconds */
  int seconds_given = 0, stability_given = 0;
  while ((ch = getopt_long(argc, argv, ":h", lo, &li)) != -1) {
    /* Every option but -h is long: messages name it as it is spelt. */
    char opt[64];
    snprintf(opt, sizeof opt, "--%s", ch > 0 && ch < 'h' ? lo[li].name : "");
    if (ch > 0 && ch <= CLI_TLS_SERVER_NAME && ch != ':' && ch != '?' && ch != 'h' &&
        lo[li].has_arg == required_argument) {
      if (seen[ch]) {
        fprintf(stderr, "hairfilter load: --%s given twice: give it once\n", lo[li].name);
        return -1;
      }
      seen[ch] = 1;
    }
    if (ch == 15 || ch == 17 || ch == 18) seconds_with = ch == 15 ? "--window" : ch == 17 ? "--max-trials" : "--trials";
    if (ch == 19) seconds_given = 1;
    if (ch == 16) stability_given = 1;
    switch (ch) {
      case 1: o->server = optarg; break;
      case 2: o->variant = optarg; break;
      case 3: o->token = optarg; break;
      case 4:
        if (cli_parse_size(optarg, &o->width, &o->height) || o->width > 65535 || o->height > 65535) {
          fprintf(stderr, "hairfilter load: --size: '%s' is not WxH (1..65535 each)\n", optarg);
          return -1;
        }
        size_given = 1;
        break;
      case 5: o->input = optarg; break;
      case 6: o->part = optarg; break;
      case 7: o->f16 = 1; break;
      case 8: o->composite = 1; break;
      case 9: o->shm = 1; break;
      case 10: if (cli_arg_range(cmd, opt, optarg, 1, 65535, 1, o->conc)) return -1; break;
      case 11: if (cli_arg_long(cmd, opt, optarg, 1, 1024, &v)) return -1; o->connections = (int)v; break;
      case 12: if (cli_arg_long(cmd, opt, optarg, 1, 65535, &v)) return -1; o->inflight = (int)v; break;
      case 13: if (cli_arg_range(cmd, opt, optarg, 1e-3, 1e6, 0, o->rate)) return -1; break;
      case 14:
        if (!strcmp(optarg, "constant")) o->poisson = 0;
        else if (!strcmp(optarg, "poisson")) o->poisson = 1;
        else {
          fprintf(stderr, "hairfilter load: --request-distribution: '%s' is neither constant nor poisson\n",
                  optarg);
          return -1;
        }
        break;
      case 15: if (cli_arg_duration(cmd, opt, optarg, 1, 0.01, 86400, &o->window_s)) return -1; break;
      case 16: if (cli_arg_double(cmd, opt, optarg, 0, 100, &o->stability)) return -1; break;
      case 17: if (cli_arg_long(cmd, opt, optarg, STABLE_OVER, 64, &v)) return -1; o->max_trials = (int)v; break;
      case 18: if (cli_arg_long(cmd, opt, optarg, 1, 100000, &v)) return -1; o->trials = (int)v; break;
      case 19:
        if (cli_arg_duration(cmd, opt, optarg, 1, 0.01, 86400, &o->window_s)) return -1;
        o->trials = 1;
        break;
      case 20: if (cli_arg_duration(cmd, opt, optarg, 1, 0, 3600, &o->warmup_s)) return -1; break;
      case 21: o->json = optarg; break;
      case 22: o->csv = optarg; break;
      case 23: o->plot = optarg; break;
      case 24: o->verbose = 1; break;
      case 25: o->quiet = 1; break;
      case 26: {
        /* 1 us .. 2^32-1 us, the protocol's budget_us. */
        double s;
        if (cli_arg_duration(cmd, opt, optarg, 1e-3, 1e-6, 4294.967295, &s)) return -1;
        o->deadline_us = s * 1e6 < 1 ? 1 : (uint32_t)(s * 1e6 + 0.5);
        break;
      }
      case 'h': usage(stdout); return 1;
      case ':': cli_arg_bad_option(cmd, argv, optind, optopt, 1); return -1;
      default:
        if (cli_tls_option(ch, optarg, &o->tls)) break;
        cli_arg_bad_option(cmd, argv, optind, optopt, 0);
        return -1;
    }
  }
  if (optind < argc) {
    fprintf(stderr, "hairfilter load: unexpected argument '%s'\n", argv[optind]);
    return -1;
  }
  if (seconds_given && seconds_with) {
    fprintf(stderr, "hairfilter load: --seconds DUR is one window of DUR (--window DUR --trials "
                    "1): give it or %s, not both\n", seconds_with);
    return -1;
  }
  if (stability_given && o->trials) {
    /* A fixed number of windows is not checked for stability: the option
     * would do nothing. */
    fprintf(stderr, "hairfilter load: --stability-percentage goes with the stability check, "
                    "which %s turns off (exactly that many windows); leave one out\n",
            seconds_given ? "--seconds" : "--trials");
    return -1;
  }
  if (!o->server || !o->variant) {
    fprintf(stderr, "hairfilter load: give --server URL and --variant NAME (see --help)\n");
    return -1;
  }
  if (o->conc[0] && o->rate[0]) {
    fprintf(stderr, "hairfilter load: --concurrency-range (closed loop) and --request-rate-range "
                    "(open loop) exclude each other\n");
    return -1;
  }
  if (cli_tls_pair(cmd, o->tls.cert, o->tls.key)) return -1;
  if (cli_tls_for_server(cmd, o->server, &o->tls)) return -1;
  if (o->input && size_given) {
    fprintf(stderr, "hairfilter load: --size and --input exclude each other (the EXR has its size)\n");
    return -1;
  }
  if (o->inflight && (o->conc[0] || o->rate[0])) {
    fprintf(stderr, "hairfilter load: --inflight goes with --connections alone; with a range, "
                    "--concurrency-range says how many are in flight\n");
    return -1;
  }
  if (o->part && !o->input) {
    fprintf(stderr, "hairfilter load: --part needs --input\n");
    return -1;
  }
  return 0;
}

/* The frame every request sends: the EXR's features, or random ones in the
 * ranges of FEATURES.md, in the input dtype; for a variant that reads the
 * estimate, followed by it (the file's acst4.*, or random values in its
 * ranges). */
static void *make_frame(opts *o, int spp, int estimate, size_t *bytes) {
  float *in = NULL;
  const int channels = hf_net_in_channels(spp, estimate);
  if (o->input) {
    hf_image img;
    void *data = NULL;
    hf_dtype dt = o->f16 ? HF_F16 : HF_F32;
    if (cli_read_features(o->input, o->part, spp, estimate, o->variant, dt, &img, &data, NULL))
      return NULL;
    o->width = img.width;
    o->height = img.height;
    hf_image_free(&img);
    *bytes = (size_t)o->width * o->height * (size_t)channels * (o->f16 ? 2 : 4);
    return data;
  }
  size_t samples = (size_t)o->width * o->height * (size_t)spp * 6;
  size_t n = (size_t)o->width * o->height * (size_t)channels;
  {
    in = malloc(n * sizeof *in);
    if (!in) return NULL;
    /* In contract in both dtypes (protocol/FEATURES.md): every sample
     * covered, alpha and the other features in [0.125, 1), tangents in
     * [-0.75, 1), so the server never sanitises (copies) the frame and the
     * timings are a clean frame's. From 0, an alpha of exactly 0 beside
     * non-zero features turned up in frames from 1024x1024 on, and in f16
     * tiny values round to 0. */
    uint32_t x = 12345;
    for (size_t i = 0; i < n; i++) {
      x = x * 1664525u + 1013904223u;
      float u = 0.125f + 0.875f * ((float)(x >> 8) / 16777216.0f);
      in[i] = i < samples && i % 6 >= 4 ? 2 * u - 1 : u;
    }
  }
  if (!o->f16) {
    *bytes = n * sizeof(float);
    return in;
  }
  uint16_t *h = malloc(n * sizeof *h);
  if (h) hf_f32_to_f16_array(in, h, n);
  free(in);
  *bytes = n * sizeof(uint16_t);
  return h;
}

/* The header's fields (run_header.h) and the tool's version. */
static void describe_run(int argc, char **argv, load_run *r) {
  static run_header h;
  run_header_describe("hairfilter", argc, argv, &h);
  r->command = h.command;
  r->cpu = h.cpu;
  r->date = h.date;
  r->version = HAIRFILTER_VERSION_STRING;
  r->cores = h.cores;
}

int cmd_load(int argc, char **argv) {
  opts o = {.token = getenv("HAIRFILTER_TOKEN"), .width = 256, .height = 256, .window_s = 5,
            .warmup_s = 1, .stability = 10, .max_trials = 10, .drain_s = 60};
  int prc = parse(argc, argv, &o);
  if (prc) return prc > 0 ? 0 : 2;
  if (o.json && o.csv && !strcmp(o.json, "-") && !strcmp(o.csv, "-")) {
    fprintf(stderr, "hairfilter load: --json - and --csv - would share stdout; give one a file\n");
    return 2;
  }
  /* With a file on stdout, the report goes to stderr. */
  FILE *rep = (o.json && !strcmp(o.json, "-")) || (o.csv && !strcmp(o.csv, "-")) ? stderr : stdout;
  if (o.token && !*o.token) o.token = NULL;
  isatty_err = isatty(2);
  char why[300];
  if (hfc_check_url(o.server, why, sizeof why)) {
    fprintf(stderr, "hairfilter load: --server: %s\n", why);
    return 2;
  }
  if (o.plot && !load_have_gnuplot()) {
    fprintf(stderr, "hairfilter load: --plot needs gnuplot on PATH (Debian: apt-get install "
                    "gnuplot-nox)\n");
    return 2;
  }
  /* Look the server and the variant up once. */
  hfc_client *c;
  hfc_options co = client_options("hairfilter-load", &o);
  int rc = hfc_connect(o.server, &co, &c);
  if (rc) {
    cli_connect_failed("hairfilter load", rc);
    return 1;
  }
  /* Static: o.variant points at its name until the report is written. */
  static hfc_variant v;
  if (load_find_variant(c, "hairfilter load", o.variant, &v)) {
    hfc_close(c);
    return 1;
  }
  int spp = v.spp, estimate = v.estimate;
  const char *backend = v.backend, *precision = v.precision;
  hfc_server_info info = *hfc_info(c);
  hfc_close(c);
  o.variant = v.name;
  if (o.shm && !info.shm) {
    fprintf(stderr, "hairfilter load: --shm: this connection offers no shared memory (a Unix "
                    "socket to a server with it enabled is needed)\n");
    return 2;
  }
  if (o.f16 && !info.f16) {
    fprintf(stderr, "hairfilter load: --f16: the server does not take f16\n");
    return 2;
  }
  if (o.deadline_us && info.version < 4)
    fprintf(stderr, "hairfilter load: --deadline: %s speaks protocol version %d, which has no "
                    "deadlines (version 4 does): frames go without one and none can expire\n",
            o.server, info.version);
  size_t in_bytes;
  void *frame = make_frame(&o, spp, estimate, &in_bytes);
  if (!frame) {
    if (!o.input) fprintf(stderr, "hairfilter load: out of memory for a %dx%d frame\n", o.width, o.height);
    return 1;
  }
  if (o.width > info.max_width || o.height > info.max_height) {
    fprintf(stderr, "hairfilter load: %dx%d is over the server's limit of %dx%d\n", o.width,
            o.height, info.max_width, info.max_height);
    free(frame);
    return 2;
  }

  /* The points of the sweep. */
  int open = o.rate[0] > 0;
  double *range = open ? o.rate : o.conc;
  if (!open && !o.conc[0]) {
    /* No range: --connections N x --inflight K, or one request in flight;
     * --inflight alone keeps its requests on one connection. */
    int conns = o.connections ? o.connections : 1;
    o.conc[0] = o.conc[1] = conns * (o.inflight ? o.inflight : 1);
    o.conc[2] = 1;
    if (!o.connections) o.connections = o.inflight ? 1 : (int)o.conc[0];
  }
  int npoints = (int)floor((range[1] - range[0]) / range[2] + 1e-9) + 1;
  if (npoints > 1000) {
    fprintf(stderr, "hairfilter load: %d points in the sweep; at most 1000\n", npoints);
    free(frame);
    return 2;
  }
  load_point *points = calloc((size_t)npoints, sizeof *points);
  if (!points) {
    free(frame);
    return 1;
  }
  load_run run_info = {o.server, o.variant, o.input, backend, precision, o.width, o.height, spp,
                       o.f16, o.shm, o.composite, o.poisson ? "poisson" : "constant",
                       o.window_s, o.warmup_s, o.stability, points, 0, NULL, NULL, NULL, NULL, 0, 0,
                       o.deadline_us};
  describe_run(argc, argv, &run_info);
  /* Results of an earlier run are not left where this run's go: a run
   * stopped before it writes leaves none (each is written under a
   * temporary name, then renamed). */
  const char *outs[] = {o.json, o.csv, o.plot};
  for (int i = 0; i < 3; i++)
    if (outs[i] && strcmp(outs[i], "-") && unlink(outs[i]) && errno != ENOENT) {
      fprintf(stderr, "hairfilter load: cannot remove the earlier %s: %s\n", outs[i], strerror(errno));
      free(points);
      free(frame);
      return 1;
    }
  /* They are written at the end: a directory that cannot take them is
   * said now, not after the run (an hour's soak). */
  static const char *const out_options[] = {"--json", "--csv", "--plot"};
  for (int i = 0; i < 3; i++)
    if (outs[i] && load_out_probe(out_options[i], outs[i])) {
      free(points);
      free(frame);
      return 1;
    }
  /* SIGINT or SIGTERM stops the point in progress; the points done are
   * reported and written. A second one kills. */
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_signal;
  sa.sa_flags = SA_RESETHAND;
  sigemptyset(&sa.sa_mask);
  interrupted = 0;
  if (sigaction(SIGINT, &sa, NULL) || sigaction(SIGTERM, &sa, NULL))
    fprintf(stderr, "hairfilter load: warning: cannot catch SIGINT/SIGTERM (%s): an interrupt "
            "will lose the points done\n", strerror(errno));
  load_print_header(rep, &run_info);
  shared sh = {.o = &o, .spp = spp, .estimate = estimate, .features = frame, .in_bytes = in_bytes};
  size_t es = o.f16 ? 2 : 4;
  sh.out_bytes = (size_t)o.width * o.height * 3 * es;
  sh.rgba_bytes = o.composite ? (size_t)o.width * o.height * 4 * es : 0;
  pthread_mutex_init(&sh.mu, NULL);
  sh.cur = NULL;
  int status = 0;
  for (int i = 0; i < npoints && !interrupted; i++) {
    load_point *p = &points[i];
    p->open_loop = open;
    if (open) {
      p->rate = range[0] + i * range[2];
      p->connections = o.connections ? o.connections : 4;
    } else {
      p->concurrency = (int)(range[0] + i * range[2]);
      p->connections = o.connections ? o.connections : p->concurrency;
      if (p->connections > p->concurrency) p->connections = p->concurrency;
      int per = (p->concurrency + p->connections - 1) / p->connections;
      if (per > info.max_inflight) {
        fprintf(stderr, "hairfilter load: concurrency %d over %d connection(s) is %d in flight "
                        "each, over the server's limit of %d (give more --connections)\n",
                p->concurrency, p->connections, per, info.max_inflight);
        status = 2;
        break;
      }
    }
    if (run_point(&o, &sh, info.max_inflight, p)) {
      fprintf(stderr, "hairfilter load: every connection failed; stopping the sweep\n");
      status = 1;
      run_info.npoints = i + 1;
      load_print_point(rep, &run_info, p);
      break;
    }
    if (p->interrupted && !p->trials) {
      /* Stopped before a whole window: nothing to report of it. */
      fprintf(stderr, "hairfilter load: interrupted before a window of this point was complete; "
                      "the point is dropped\n");
      break;
    }
    run_info.npoints = i + 1;
    load_print_point(rep, &run_info, p);
    if (p->unanswered || p->lost_connections) status = 1;
    if (p->refused_connections) {
      /* Said where it happened; the next points would meet it too. */
      status = 1;
      break;
    }
  }
  run_info.interrupted = interrupted != 0;
  if (run_info.npoints > 1) load_print_summary(rep, &run_info);
  int write_failed = (run_info.npoints && o.csv && load_write_csv(o.csv, &run_info)) |
                     (run_info.npoints && o.json && load_write_json(o.json, &run_info)) |
                     (run_info.npoints && o.plot && load_write_plot(o.plot, &run_info));
  if (write_failed) status = 1;
  int measured = 0;
  for (int i = 0; i < run_info.npoints; i++) measured += points[i].result.ok > 0;
  if (!status && !measured) status = 1;
  /* 130 says interrupted; a file that could not be written (said above)
   * keeps 1, which a script must not take for a complete run either. */
  if (run_info.interrupted) {
    fprintf(stderr, "hairfilter load: interrupted by %s after %d point(s)\n",
            interrupted == SIGTERM ? "SIGTERM" : "SIGINT", run_info.npoints);
    if (!write_failed) status = 130;
  }
  signal(SIGINT, SIG_DFL);
  signal(SIGTERM, SIG_DFL);
  pthread_mutex_destroy(&sh.mu);
  free(points);
  free(frame);
  return status;
}
