/*
 * The inference worker: one thread that owns the backend and every model,
 * takes jobs from the bounded queue, groups compatible ones into a batch
 * (same variant, size and dtypes; at most max_batch; waiting at most
 * max_delay_us for partners, like Triton's dynamic batcher) and hands the
 * finished jobs back to the loop thread through uv_async_send. Frames held
 * for partners are still queued: they count in the depth and against
 * q_cap (q_forming), and a full queue ends the wait.
 *
 * With pipeline_depth 2 and a backend that overlaps runs
 * (hf_model_overlaps), a batch that goes straight from its request's
 * buffers to its reply's (one frame, no composite) is submitted
 * (hf_model_submit) and left pending while the next batch is formed and
 * submitted, so a GPU backend uploads frame n+1 while it computes frame n;
 * the pending batch is then waited for and completed, always before the
 * newer one. Batches that need the worker's scratch buffers, and backends
 * that compute inside submit (where a pending batch would only wait), run
 * one at a time as before.
 *
 * GPU libraries tie handles and streams to the thread that made them, so
 * the backend is created here, not in main(), and so are the models: the
 * loop thread queues loads and unloads (hfd_ctl), which are done between
 * batches, before the next one is formed.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <malloc.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "server.h"

double hfd_now_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

static uint64_t us(double v) { return v > 0 ? (uint64_t)v : 0; }

/* Grows a worker scratch buffer; sizes come from already-validated jobs. */
static int ensure(void **buf, size_t *cap, size_t need) {
  if (*cap >= need) return 0;
  void *p = NULL;
  if (posix_memalign(&p, 64, need ? need : 64)) return -1;
  free(*buf);
  *buf = p;
  *cap = need;
  return 0;
}

uint64_t hfd_worker_run_bytes(const hfd_worker *w, const hf_net_config *cfg, uint32_t width,
                              uint32_t height, int batch, uint64_t in_bytes) {
  size_t net = hf_run_bytes(w->backend, cfg, (int)width, (int)height, batch);
  if (!net) return UINT64_MAX;
  /* prepare_run's and finish_run's own buffers: the gathered inputs of a
   * batch, the float32 results of a batch or a composite, and the
   * composite's RGB. A frame's
   * slot in the gather buffer is counted even when it runs alone, so that
   * n frames never need more than n times what one frame was charged and
   * batches form under the memory bound (take_compatible). */
  uint64_t px = (uint64_t)width * height, f32_out = px * 3 * sizeof(float);
  return net + (in_bytes + f32_out) * (uint64_t)batch + f32_out;
}

static void free_seg_copies(hfd_worker *w) {
  for (int i = 0; i < 2; i++) {
    if (w->seg_in_registered[i]) hf_backend_host_unregister(w->backend, w->seg_in[i]);
    w->seg_in_registered[i] = 0;
    free(w->seg_in[i]);
    w->seg_in[i] = NULL;
    w->seg_in_cap[i] = 0;
  }
}

static size_t worker_cached(const hfd_worker *w) {
  size_t n = w->scratch_in_cap + w->scratch_out_cap + w->scratch_rgb_cap + w->seg_in_cap[0] +
             w->seg_in_cap[1];
  for (const hfd_model *m = w->models; m; m = m->wnext) n += hf_model_cached_bytes(m->model);
  return n;
}

/* After a run: what the backends and this worker keep for the next run of
 * the same size may stay while it is within cache_cap, less the receive
 * buffers kept idle (recv_pool.c: the two share it, and it counts against
 * --max-memory-mb all the same); beyond it, what is kept goes back to the
 * system: the worker's scratch; the largest plans of the model that ran
 * when they alone are over (an oversized frame's); then every plan of the
 * other models, least recently run first; then the rest of the ran model's
 * largest plans; then the heap's free pages. Each model's share is
 * published for STATS and /metrics. */
static void worker_trim(hfd_worker *w, hfd_model *ran) {
  uint64_t idle = w->pool_idle ? atomic_load(w->pool_idle) : 0;
  size_t cap = idle < w->cache_cap ? (size_t)(w->cache_cap - idle) : 0;
  size_t n = worker_cached(w);
  if (ran) ran->last_run = ++w->run_clock;
  if (n > cap) {
    free(w->scratch_in);
    free(w->scratch_out);
    free(w->scratch_rgb);
    w->scratch_in = w->scratch_out = NULL;
    w->scratch_rgb = NULL;
    w->scratch_in_cap = w->scratch_out_cap = w->scratch_rgb_cap = 0;
    free_seg_copies(w);
    if (ran) hf_model_trim(ran->model, cap);
    while (worker_cached(w) > cap) {
      hfd_model *lru = NULL;
      for (hfd_model *m = w->models; m; m = m->wnext)
        if (m != ran && hf_model_cached_bytes(m->model) && (!lru || m->last_run < lru->last_run))
          lru = m;
      if (!lru) break;
      hf_model_trim(lru->model, 0);
    }
    if (ran && (n = worker_cached(w)) > cap) {
      size_t mine = hf_model_cached_bytes(ran->model), others = n - mine;
      hf_model_trim(ran->model, others < cap ? cap - others : 0);
    }
    malloc_trim(0);
    n = worker_cached(w);
  }
  for (hfd_model *m = w->models; m; m = m->wnext)
    atomic_store(&m->cache_bytes, (uint64_t)hf_model_cached_bytes(m->model));
  atomic_store(&w->cached_bytes, (uint64_t)n);
}

static int compatible(const hfd_job *a, const hfd_job *b) {
  return a->model == b->model && a->req.width == b->req.width &&
         a->req.height == b->req.height && a->req.in_dtype == b->req.in_dtype &&
         a->req.out_dtype == b->req.out_dtype;
}

/* One composite value in the RGBA dtype. f16 saturates at its largest
 * finite value (HF_OUTPUT_MAX), as hf_composite does at FLT_MAX: a FILTER's
 * colours are any finite floats, and its outputs are always finite
 * (PROTOCOL.md). */
static void store(void *dst, int dtype, size_t i, float v) {
  if (dtype == HFP_F16)
    ((uint16_t *)dst)[i] =
        hf_f32_to_f16(v > HF_OUTPUT_MAX ? HF_OUTPUT_MAX : v < -HF_OUTPUT_MAX ? -HF_OUTPUT_MAX : v);
  else
    ((float *)dst)[i] = v;
}

/* Writes one job's outputs from float32 results: the 3-channel result in
 * its dtype and, when asked, the composited RGBA (alpha = hair alpha). */
static int finish_from_f32(hfd_worker *w, hfd_job *j, const float *res) {
  size_t n = (size_t)j->req.width * j->req.height;
  if (j->req.out_dtype == HFP_F16) hf_f32_to_f16_array(res, j->out, n * 3);
  else memcpy(j->out, res, n * 3 * sizeof(float));
  if (!j->rgba) return 0;
  void *rgb = w->scratch_rgb;
  if (ensure(&rgb, &w->scratch_rgb_cap, n * 3 * sizeof(float))) return -1;
  w->scratch_rgb = rgb;
  hf_composite(res, (int)j->req.width, (int)j->req.height, j->req.hair, j->req.light,
               j->req.bg, w->scratch_rgb);
  for (size_t p = 0; p < n; p++) {
    for (int c = 0; c < 3; c++)
      store(j->rgba, j->req.out_dtype, p * 4 + c, w->scratch_rgb[p * 3 + c]);
    store(j->rgba, j->req.out_dtype, p * 4 + 3, res[p * 3 + HF_OUT_ALPHA]);
  }
  return 0;
}

/* One batch from its start to its completion. */
typedef struct run {
  hfd_job **jobs;
  int nb;
  int direct;                    /* request buffers in, reply buffer out */
  int rc;
  double t0, t1, t2;             /* started, submitted, backend finished */
  hf_timing t;
  hf_input_report *reports;      /* [max batch]: what the backend run sanitised */
  hf_input_stats *stats;         /* [max batch]: the inputs' statistics */
} run;

/* Gathers the batch's inputs and makes its hf_io. Fast path: one frame
 * whose output goes straight to its buffer (its input too, unless it lies
 * in a shared segment, which is copied out). Else inputs are gathered into
 * one tensor and the run has float32 output, converted per job: that is
 * also where the composite is made. */
static int prepare_run(hfd_worker *w, run *r, hf_io *io) {
  hfd_job *j0 = r->jobs[0];
  const int nb = r->nb;
  r->t0 = hfd_now_us();
  for (int i = 0; i < nb; i++) {
    r->jobs[i]->t_started = r->t0;
    r->jobs[i]->batch = (uint32_t)nb;
    r->jobs[i]->batch_leader = 0;
  }
  size_t in_bytes = (size_t)j0->req.data_len;
  size_t px = (size_t)j0->req.width * j0->req.height;
  int composite = 0;
  for (int i = 0; i < nb; i++) composite |= r->jobs[i]->rgba != NULL;
  r->direct = nb == 1 && !composite;
  const void *in = j0->input;
  if (nb == 1 && j0->seg && !hf_model_reads_input_once(j0->model->model, in, in_bytes)) {
    /* A frame in a shared segment is copied out unless the run reads it
     * once anyway (a network with an estimate interleaves it into a copy
     * of its own; cudnn moves a pinned segment's frame by DMA and checks
     * it on the device): its client can write the segment while the
     * backend runs, and the other paths read the input more than once (the
     * out-of-contract check, then the network), so a value rewritten
     * between them would reach the network unchecked. The copy is what is
     * both checked and run. Its room is charged already
     * (hfd_worker_run_bytes counts a frame's gather slot when it runs
     * alone); the other buffer may still feed a pending run. */
    int k = w->seg_in_next;
    w->seg_in_next ^= 1;
    if (w->seg_in_cap[k] < in_bytes) {
      /* Pinned like the segment was, so the cudnn backend still moves the
       * frame by DMA (and checks it on the device); unpinned, it is staged. */
      if (w->seg_in_registered[k]) hf_backend_host_unregister(w->backend, w->seg_in[k]);
      w->seg_in_registered[k] = 0;
      if (ensure(&w->seg_in[k], &w->seg_in_cap[k], in_bytes)) return HF_ENOMEM;
      w->seg_in_registered[k] =
          hf_backend_host_register(w->backend, w->seg_in[k], w->seg_in_cap[k]) == HF_OK;
    }
    memcpy(w->seg_in[k], j0->input, in_bytes);
    in = w->seg_in[k];
  } else if (nb > 1) {
    /* Gathered into one tensor: a private copy, segments' frames too. */
    if (ensure(&w->scratch_in, &w->scratch_in_cap, in_bytes * nb)) return HF_ENOMEM;
    for (int i = 0; i < nb; i++)
      memcpy((uint8_t *)w->scratch_in + in_bytes * i, r->jobs[i]->input, in_bytes);
    in = w->scratch_in;
  }
  if (!r->direct && ensure(&w->scratch_out, &w->scratch_out_cap, px * 3 * sizeof(float) * nb))
    return HF_ENOMEM;
  *io = (hf_io){nb, (int)j0->req.width, (int)j0->req.height, in, (hf_dtype)j0->req.in_dtype,
                r->direct ? j0->out : w->scratch_out,
                r->direct ? (hf_dtype)j0->req.out_dtype : HF_F32};
  /* The batch goes to the backend now: a backend run, counted whatever
   * becomes of it (hfd_worker_take_done). One that could not be prepared
   * never ran. */
  j0->batch_leader = 1;
  r->t1 = hfd_now_us();
  return HF_OK;
}

/* Is each input inside the range the variant was trained on? The run makes
 * the inputs' statistics in its input pass (hf_model_run_stats; for an f16
 * frame, in the one pass that checks it), so they count as input time;
 * variants whose weights record no range skip them. */
static hf_input_stats *range_stats(run *r) {
  return r->jobs[0]->model->range.present ? r->stats : NULL;
}

/* The backend is done with the batch (r->rc, r->t): outputs, timings,
 * status. */
static void finish_run(hfd_worker *w, run *r) {
  hfd_job *j0 = r->jobs[0];
  const hfd_model *v = j0->model;
  const int nb = r->nb;
  size_t px = (size_t)j0->req.width * j0->req.height;
  int rc = r->rc;
  for (int i = 0; i < nb && !rc; i++) {
    r->jobs[i]->sanitised = r->reports[i].samples;
    r->jobs[i]->out_of_range =
        v->range.present && hf_input_range_check(&v->range, &r->stats[i]) != 0;
  }
  if (!rc && !r->direct)
    for (int i = 0; i < nb && !rc; i++)
      if (finish_from_f32(w, r->jobs[i], (const float *)w->scratch_out + px * 3 * i))
        rc = HF_ENOMEM;
  double t3 = hfd_now_us();
  if (!rc)
    for (int i = 0; i < nb; i++) {
      hfp_timing *tm = &r->jobs[i]->timing;
      tm->input_us = us((r->t1 - r->t0) + r->t.input_us);
      tm->infer_us = us(r->t.infer_us);
      /* What the backend did not attribute to input or inference is output
       * work (transforms, crop, download), plus our own conversion. A
       * pipelined run's backend time includes the wait behind the run
       * before it, which is queueing, not output: left out. */
      double rest = (r->t2 - r->t1) - r->t.input_us - r->t.infer_us;
      if (w->pipeline_depth > 1 && r->direct && hf_model_overlaps(v->model)) rest = r->t.output_us;
      tm->output_us = us((rest > 0 ? rest : 0) + (t3 - r->t2));
    }
  for (int i = 0; i < nb; i++) {
    r->jobs[i]->status = rc ? HFP_E_INTERNAL : HFP_OK;
    r->jobs[i]->t_done = hfd_now_us();
  }
  if (rc)
    hfd_err("variant %s: inference of %d frame(s) %ux%u failed: %s", v->name, nb,
            j0->req.width, j0->req.height, hf_strerror(rc));
}


static void complete(hfd_worker *w, hfd_job **batch, int nb) {
  pthread_mutex_lock(&w->mu);
  for (int i = 0; i < nb; i++) {
    batch[i]->next = NULL;
    if (w->done_tail)
      w->done_tail->next = batch[i];
    else
      w->done_head = batch[i];
    w->done_tail = batch[i];
  }
  pthread_mutex_unlock(&w->mu);
  /* uv_async_send is the one libuv call that is safe from another thread;
   * it only fails for a closed handle, which cannot happen before stop
   * (the loop closes it after joining this thread). */
  int rc = uv_async_send(w->async);
  if (rc < 0) hfd_err("worker: uv_async_send: %s", uv_strerror(rc));
}

/* Takes j, queued after prev (NULL: first), off the queue (mu held). */
static void unlink_queued(hfd_worker *w, hfd_job *prev, hfd_job *j) {
  if (prev)
    prev->next = j->next;
  else
    w->q_head = j->next;
  if (w->q_tail == j) w->q_tail = prev;
  w->q_len--;
  j->next = NULL;
}

/* When j's budget (FILTER flag DEADLINE, version 4) ends, on hfd_now_us's
 * clock: it counts from the frame's arrival, as total_us does. Frames
 * without one never expire. */
static double expires_at(const hfd_job *j) {
  if (!(j->req.flags & HFP_FILTER_DEADLINE)) return INFINITY;
  return j->t_received + (double)j->req.budget_us;
}

/* Takes the queued frames whose budget has passed by now off the queue
 * (mu held) and returns them as a list: they are answered EXPIRED unrun,
 * and leave their queue places and memory to frames that can still make
 * it. Frames in the batch being formed have left the queue: they run. */
static hfd_job *take_expired(hfd_worker *w, double now) {
  hfd_job *late = NULL, **tail = &late, *prev = NULL;
  for (hfd_job *j = w->q_head, *next; j; j = next) {
    next = j->next;
    if (now < expires_at(j)) {
      prev = j;
      continue;
    }
    unlink_queued(w, prev, j);
    *tail = j;
    tail = &j->next;
  }
  return late;
}

/* When the first budget of the queued frames ends (mu held); INFINITY
 * when none has one. */
static double first_expiry(const hfd_worker *w) {
  double first = INFINITY;
  for (const hfd_job *j = w->q_head; j; j = j->next)
    if (expires_at(j) < first) first = expires_at(j);
  return first;
}

/* Removes and returns the first queued job compatible with j0 (mu held),
 * when running it in the batch (nb jobs so far, which reserved reserved
 * bytes for running) needs no more than the batch's jobs reserved. */
static hfd_job *take_compatible(hfd_worker *w, const hfd_job *j0, int nb, uint64_t reserved) {
  hfd_job *prev = NULL;
  double now = hfd_now_us();
  for (hfd_job *j = w->q_head; j; prev = j, j = j->next) {
    if (!compatible(j, j0)) continue;
    if (now >= expires_at(j)) continue;   /* take_expired answers it */
    if (hfd_worker_run_bytes(w, &j0->model->cfg, j0->req.width, j0->req.height, nb + 1,
                             j0->req.data_len) > reserved + j->infer_bytes)
      return NULL;
    unlink_queued(w, prev, j);
    return j;
  }
  return NULL;
}

static void deadline_ts(double when_us, struct timespec *ts) {
  /* pthread_cond_timedwait takes CLOCK_REALTIME unless told otherwise; the
   * condition variable is made with CLOCK_MONOTONIC in hfd_worker_start. */
  ts->tv_sec = (time_t)(when_us / 1e6);
  ts->tv_nsec = (long)((when_us - (double)ts->tv_sec * 1e6) * 1e3);
  if (ts->tv_nsec >= 1000000000L) {
    ts->tv_sec++;
    ts->tv_nsec -= 1000000000L;
  }
  if (ts->tv_nsec < 0) ts->tv_nsec = 0;
}

static void progress(hfd_worker *w) { atomic_store(&w->progress_us, (uint64_t)hfd_now_us()); }

/* Frames per backend run when --max-batch is not given. 1 on the CPU
 * backends: on the cpu backend a batch of frames took as long per frame as
 * the frames one by one, or longer (docs/PERFORMANCE.md, "Batching on the
 * CPU"), so waiting for partners only added latency and memory. 4 on
 * cudnn, as before: not measured yet (no GPU where the CPU's was). At least
 * the largest --warm batch, which asks for batches of that size. */
static int default_max_batch(const hf_backend *b, const hfd_config *cfg) {
  int n = strcmp(hf_backend_name(b), "cudnn") ? 1 : 4;
  for (int k = 0; cfg && k < cfg->num_warm; k++)
    if (cfg->warm[k].batch > n) n = cfg->warm[k].batch;
  return n;
}

static int init_backend(hfd_worker *w) {
  int rc = hf_backend_create(w->backend_name, &w->backend, w->init_msg, sizeof w->init_msg);
  if (rc) {
    if (!w->init_msg[0]) snprintf(w->init_msg, sizeof w->init_msg, "%s", hf_strerror(rc));
    return rc;
  }
  if (w->max_batch < 1) w->max_batch = default_max_batch(w->backend, w->cfg);
  if (!w->init_msg[0])
    snprintf(w->init_msg, sizeof w->init_msg, "backend %s (as requested)",
             hf_backend_name(w->backend));
  return 0;
}

static int name_ok(const char *s) {
  size_t n = strlen(s);
  if (n < 1 || n > HFP_NAME_MAX) return 0;
  for (size_t i = 0; i < n; i++)
    if (s[i] <= 0x20 || s[i] > 0x7e) return 0;
  return 1;
}

/* A load abandoned for a stop during the start (hfd_worker_abandon_loads):
 * 1, with c->rc and c->msg set, when it must go no further. */
static int abandoned(hfd_worker *w, hfd_ctl *c) {
  if (!atomic_load(&w->abandon)) return 0;
  c->rc = HF_EUNAVAILABLE;
  snprintf(c->msg, sizeof c->msg, "not loaded: the daemon is stopping");
  return 1;
}

/* Reads m->path, builds its model on the backend, and the plans of the
 * --warm shapes. On failure, c->rc and c->msg say why and m is not kept. */
static void do_load(hfd_worker *w, hfd_ctl *c) {
  hfd_model *m = c->model;
  struct stat st;
  char err[256] = "";
  hf_weights *wt = NULL;
  if (abandoned(w, c)) return;
  /* The file as it is now: what the next reload compares against. */
  if (stat(m->path, &st) == 0) {
    m->file = (hfd_file_id){(uint64_t)st.st_dev, (uint64_t)st.st_ino, (uint64_t)st.st_size,
                            (int64_t)st.st_mtim.tv_sec * 1000000000 + st.st_mtim.tv_nsec};
  }
  int rc = hf_weights_load(m->path, &wt, err, sizeof err);
  if (rc) {
    c->rc = rc;
    snprintf(c->msg, sizeof c->msg, "%s", err[0] ? err : hf_strerror(rc));
    return;
  }
  const char *name = m->override[0] ? m->override : wt->cfg.name;
  if (!name_ok(name)) {
    c->rc = HF_EFORMAT;
    snprintf(c->msg, sizeof c->msg,
             "variant name '%s' is not 1..%d printable characters without spaces", name,
             HFP_NAME_MAX);
    hf_weights_free(wt);
    return;
  }
  snprintf(m->name, sizeof m->name, "%s", name);
  m->cfg = wt->cfg;
  m->range = wt->input_range;
  m->params = wt->num_params;
  if (abandoned(w, c)) {
    hf_weights_free(wt);
    return;
  }
  rc = hf_model_create(w->backend, wt, &m->model);
  hf_weights_free(wt);
  if (rc) {
    c->rc = rc;
    snprintf(c->msg, sizeof c->msg, "model creation on %s failed: %s",
             hf_backend_name(w->backend), hf_strerror(rc));
    return;
  }
  snprintf(m->precision, sizeof m->precision, "%s", hf_model_precision(m->model));
  m->device_bytes = hf_model_device_bytes(m->model);
  /* Plans for the configured shapes now, so no request waits for one. */
  for (int k = 0; w->cfg && k < w->cfg->num_warm; k++) {
    const int ww = w->cfg->warm[k].width, hh = w->cfg->warm[k].height,
              nb = w->cfg->warm[k].batch;
    const double t0 = hfd_now_us();
    if (abandoned(w, c))
      rc = c->rc;
    else if ((rc = hf_model_prepare(m->model, nb, ww, hh)) != 0)
      snprintf(c->msg, sizeof c->msg, "preparing %dx%d batch %d on %s failed: %s", ww, hh, nb,
               hf_backend_name(w->backend), hf_strerror(rc));
    progress(w);
    if (rc) {
      c->rc = rc;
      hf_model_destroy(m->model);
      m->model = NULL;
      return;
    }
    hfd_log("variant %s: %dx%d batch %d prepared in %.2f s", m->name, ww, hh, nb,
            (hfd_now_us() - t0) / 1e6);
  }
  struct timespec wall;
  clock_gettime(CLOCK_REALTIME, &wall);
  m->t_loaded_wall = (double)wall.tv_sec + wall.tv_nsec / 1e9;
  m->wnext = w->models;
  w->models = m;
  worker_trim(w, NULL);
  c->rc = 0;
}

static void do_unload(hfd_worker *w, hfd_model *m) {
  for (hfd_model **pp = &w->models; *pp; pp = &(*pp)->wnext)
    if (*pp == m) {
      *pp = m->wnext;
      break;
    }
  hf_model_destroy(m->model);
  free(m->path);
  free(m);
  worker_trim(w, NULL);
}

/* Does one queued load or unload (mu not held). Loads go back to the loop
 * thread; unloads are freed here. */
static void do_ctl(hfd_worker *w, hfd_ctl *c) {
  if (c->op == HFD_CTL_UNLOAD) {
    do_unload(w, c->model);
    free(c);
    return;
  }
  do_load(w, c);
  pthread_mutex_lock(&w->mu);
  c->done = 1;
  c->next = w->ctl_done;
  w->ctl_done = c;
  pthread_cond_broadcast(&w->cv);
  pthread_mutex_unlock(&w->mu);
  int rc = uv_async_send(w->async);
  if (rc < 0) hfd_err("worker: uv_async_send: %s", uv_strerror(rc));
}

static void release_models(hfd_worker *w) {
  while (w->models) {
    hfd_model *m = w->models;
    w->models = m->wnext;
    hf_model_destroy(m->model);
    free(m->path);
    free(m);
  }
  free_seg_copies(w);   /* unregistered while the backend is there */
  hf_backend_destroy(w->backend);
  w->backend = NULL;
  free(w->scratch_in);
  free(w->scratch_out);
  free(w->scratch_rgb);
}

static void complete(hfd_worker *w, hfd_job **batch, int nb);
static void complete_unrun(hfd_worker *w, hfd_job *list, int status);

/* Waits for the pending run (submitted earlier) and completes its jobs. */
static void finish_pending(hfd_worker *w, run *p) {
  p->rc = hf_model_wait(p->jobs[0]->model->model, &p->t);
  p->t2 = hfd_now_us();
  finish_run(w, p);
  complete(w, p->jobs, p->nb);
  p->nb = 0;
}

static void *worker_main(void *arg) {
  hfd_worker *w = arg;
  /* Signals are the loop thread's (libuv's handlers run there); threads
   * this one starts (a backend's pool) inherit the mask. */
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &set, NULL);
  int rc = init_backend(w);
  progress(w);
  pthread_mutex_lock(&w->mu);
  w->init_rc = rc;
  w->ready = 1;
  pthread_cond_broadcast(&w->cv);
  pthread_mutex_unlock(&w->mu);
  if (rc) {
    release_models(w);
    return NULL;
  }
  /* Two batch tables: the one being formed, and the pending one. */
  hfd_job **tables = calloc((size_t)w->max_batch * 2, sizeof *tables);
  hf_input_report *reports = calloc((size_t)w->max_batch * 2, sizeof *reports);
  hf_input_stats *stats = calloc((size_t)w->max_batch * 2, sizeof *stats);
  if (!tables || !reports || !stats) {
    hfd_err("worker: out of memory for the batch table");
    abort();
  }
  run cur = {tables, 0, 0, 0, 0, 0, 0, {0, 0, 0}, reports, stats};
  run pend = {tables + w->max_batch, 0, 0, 0, 0, 0, 0, {0, 0, 0}, reports + w->max_batch,
              stats + w->max_batch};
  hfd_job **batch = cur.jobs;
  pthread_mutex_lock(&w->mu);
  for (;;) {
    while (!w->q_head && !w->ctl_head && !w->stop && !pend.nb) {
      atomic_store(&w->working, 0);
      pthread_cond_wait(&w->cv, &w->mu);
    }
    atomic_store(&w->working, 1);
    if (w->ctl_head) {
      /* Loads and unloads first: a model being replaced is let go of as
       * soon as its last frame is answered, and a load does not wait
       * behind a busy queue. The pending batch finishes before, so that no
       * backend run is in flight while models come and go. */
      hfd_ctl *c = w->ctl_head;
      w->ctl_head = c->next;
      if (!w->ctl_head) w->ctl_tail = NULL;
      pthread_mutex_unlock(&w->mu);
      if (pend.nb) finish_pending(w, &pend);
      do_ctl(w, c);
      progress(w);
      pthread_mutex_lock(&w->mu);
      continue;
    }
    if (!w->q_head && pend.nb) {
      /* Nothing to overlap with: finish the pending batch now. */
      pthread_mutex_unlock(&w->mu);
      finish_pending(w, &pend);
      progress(w);
      pthread_mutex_lock(&w->mu);
      continue;
    }
    if (!w->q_head) break;  /* stop requested and nothing left */
    hfd_job *late = take_expired(w, hfd_now_us());
    if (late) {
      pthread_mutex_unlock(&w->mu);
      complete_unrun(w, late, HFP_E_EXPIRED);
      progress(w);
      pthread_mutex_lock(&w->mu);
      continue;
    }
    hfd_job *j0 = w->q_head;
    w->q_head = j0->next;
    if (!w->q_head) w->q_tail = NULL;
    w->q_len--;
    j0->next = NULL;
    int nb = 1;
    batch[0] = j0;
    /* Until the batch is formed its frames wait here instead of in the
     * queue, and count there: the queue's depth and --queue-size are about
     * admitted frames that are not running yet, wherever they wait. */
    w->q_forming = 1;
    uint64_t reserved = j0->infer_bytes;
    /* The batch waits for partners no longer than the shortest budget of
     * its frames: taken before their budget passed, they run. */
    double deadline = j0->t_received + w->max_delay_us;
    if (expires_at(j0) < deadline) deadline = expires_at(j0);
    while (nb < w->max_batch && !w->cancel) {
      hfd_job *j = take_compatible(w, j0, nb, reserved);
      if (j) {
        reserved += j->infer_bytes;
        if (expires_at(j) < deadline) deadline = expires_at(j);
        batch[nb++] = j;
        w->q_forming = nb;
        continue;
      }
      /* A pending batch is not kept waiting for partners of this one. Nor
       * is a full queue: no partner can be admitted until a frame leaves
       * it, and none leaves while this batch waits. */
      double now = hfd_now_us();
      if (w->stop || pend.nb || now >= deadline || w->q_len + w->q_forming >= w->q_cap)
        break;
      /* The frames queued behind the batch are answered EXPIRED as their
       * budget passes, not once the batch has waited and run: the wait
       * wakes for the first of their budgets too. */
      double wake = first_expiry(w);
      if (wake <= now) {
        hfd_job *late = take_expired(w, now);
        pthread_mutex_unlock(&w->mu);
        complete_unrun(w, late, HFP_E_EXPIRED);
        progress(w);
        pthread_mutex_lock(&w->mu);
        continue;
      }
      if (wake > deadline) wake = deadline;
      struct timespec ts;
      deadline_ts(wake, &ts);
      int wr = pthread_cond_timedwait(&w->cv, &w->mu, &ts);
      if (wr && wr != ETIMEDOUT && wr != EINTR) break;
    }
    int cancelled = w->cancel;
    w->q_forming = 0;   /* running (or failed, when cancelled) from here */
    w->busy = 1;
    pthread_mutex_unlock(&w->mu);
    cur.nb = nb;
    if (cancelled) {
      if (pend.nb) finish_pending(w, &pend);
      for (int i = 0; i < nb; i++) {
        batch[i]->status = HFP_E_SHUTTING_DOWN;
        batch[i]->t_started = batch[i]->t_done = hfd_now_us();
        batch[i]->batch = 0;
      }
      complete(w, batch, nb);
    } else {
      hf_io io;
      cur.t = (hf_timing){0, 0, 0};
      cur.rc = prepare_run(w, &cur, &io);
      hf_model *m = batch[0]->model->model;
      if (!cur.rc && cur.direct && w->pipeline_depth > 1 && hf_model_overlaps(m)) {
        /* Submit this one, then finish the one before it: the upload of
         * this frame overlaps that one's compute. */
        cur.rc = hf_model_submit_stats(m, &io, cur.reports, range_stats(&cur));
        if (pend.nb) finish_pending(w, &pend);
        if (cur.rc) {
          cur.t2 = hfd_now_us();
          finish_run(w, &cur);
          complete(w, batch, nb);
        } else {
          run t = pend;   /* this batch is now the pending one */
          pend = cur;
          cur = t;
          batch = cur.jobs;
        }
      } else {
        if (pend.nb) finish_pending(w, &pend);
        if (!cur.rc) cur.rc = hf_model_run_stats(m, &io, &cur.t, cur.reports, range_stats(&cur));
        cur.t2 = hfd_now_us();
        finish_run(w, &cur);
        /* Nothing is pending on any model: what this run kept may be
         * trimmed before its frames' memory is released. */
        worker_trim(w, j0->model);
        complete(w, batch, nb);
      }
    }
    progress(w);
    pthread_mutex_lock(&w->mu);
    w->busy = pend.nb > 0;
  }
  pthread_mutex_unlock(&w->mu);
  if (pend.nb) finish_pending(w, &pend);
  atomic_store(&w->working, 0);
  free(tables);
  free(reports);
  free(stats);
  release_models(w);
  return NULL;
}

int hfd_worker_start(hfd_worker *w) {
  pthread_condattr_t ca;
  if (pthread_mutex_init(&w->mu, NULL)) return -1;
  if (pthread_condattr_init(&ca) || pthread_condattr_setclock(&ca, CLOCK_MONOTONIC) ||
      pthread_cond_init(&w->cv, &ca))
    return -1;
  pthread_condattr_destroy(&ca);
  int rc = pthread_create(&w->thread, NULL, worker_main, w);
  if (rc) {
    snprintf(w->init_msg, sizeof w->init_msg, "cannot start the worker thread: %s",
             strerror(rc));
    return -1;
  }
  pthread_mutex_lock(&w->mu);
  while (!w->ready) pthread_cond_wait(&w->cv, &w->mu);
  pthread_mutex_unlock(&w->mu);
  if (w->init_rc) {
    pthread_join(w->thread, NULL);
    return w->init_rc;
  }
  return 0;
}

/* Appends job to the queue and wakes the worker (mu held). */
static void enqueue(hfd_worker *w, hfd_job *job) {
  job->next = NULL;
  if (w->q_tail)
    w->q_tail->next = job;
  else
    w->q_head = job;
  w->q_tail = job;
  w->q_len++;
  pthread_cond_signal(&w->cv);
}

static void complete_unrun(hfd_worker *w, hfd_job *list, int status);

/* A full queue first gives back the places of its frames whose budget has
 * passed (mu held): they are answered EXPIRED (the caller completes the
 * list returned once mu is released), and a frame that can still make it
 * takes a place a dead one held, instead of a BUSY. The worker checks
 * budgets before it forms a batch and while it waits for partners, and a
 * long run holds that off. */
static hfd_job *expire_if_full(hfd_worker *w) {
  if (w->stop || w->q_len + w->q_forming < w->q_cap) return NULL;
  return take_expired(w, hfd_now_us());
}

int hfd_worker_submit(hfd_worker *w, hfd_job *job) {
  pthread_mutex_lock(&w->mu);
  hfd_job *late = expire_if_full(w);
  int rc = 0;
  if (w->q_len + w->q_forming >= w->q_cap || w->stop)
    rc = HFP_E_BUSY;
  else
    enqueue(w, job);
  pthread_mutex_unlock(&w->mu);
  complete_unrun(w, late, HFP_E_EXPIRED);
  return rc;
}

int hfd_worker_push_out(hfd_worker *w, hfd_job *job, int share, hfd_job **pushed) {
  *pushed = NULL;
  pthread_mutex_lock(&w->mu);
  if (w->stop) {
    pthread_mutex_unlock(&w->mu);
    return HFP_E_BUSY;
  }
  /* Frames past their budget leave first: none is pushed out (a BUSY
   * RESULT for a frame that is EXPIRED) while a dead one holds a place. */
  hfd_job *late = expire_if_full(w);
  if (w->q_len + w->q_forming >= w->q_cap) {
    /* The client (hfd_conn.share) holding the most frames over share, and
     * its newest frame in the queue: the one it sent last, which loses the
     * least waiting. Reading share->inflight is safe only because this
     * runs on the loop thread, which alone writes it. */
    hfd_job *victim = NULL, *victim_prev = NULL, *prev = NULL;
    for (hfd_job *j = w->q_head; j; prev = j, j = j->next) {
      int held = j->conn->share->inflight;
      if (held <= share) continue;
      if (!victim || held > victim->conn->share->inflight ||
          j->conn->share == victim->conn->share) {
        victim = j;
        victim_prev = prev;
      }
    }
    if (!victim) {
      pthread_mutex_unlock(&w->mu);
      complete_unrun(w, late, HFP_E_EXPIRED);
      return HFP_E_BUSY;
    }
    unlink_queued(w, victim_prev, victim);
    *pushed = victim;
  }
  enqueue(w, job);
  pthread_mutex_unlock(&w->mu);
  complete_unrun(w, late, HFP_E_EXPIRED);
  return 0;
}

hfd_job *hfd_worker_take_done(hfd_worker *w) {
  pthread_mutex_lock(&w->mu);
  hfd_job *j = w->done_head;
  w->done_head = w->done_tail = NULL;
  pthread_mutex_unlock(&w->mu);
  /* Every job passes here on the loop thread, those whose connection has
   * gone included (delivery drops them), so this is where a backend run is
   * counted: once, by its first job, whoever is left to receive it. */
  for (hfd_job *k = j; k; k = k->next)
    if (k->batch_leader) {
      hfd_metrics_batch(k->conn->srv, k);
      k->batch_leader = 0;
    }
  return j;
}

void hfd_worker_control(hfd_worker *w, hfd_ctl *ctl) {
  pthread_mutex_lock(&w->mu);
  ctl->next = NULL;
  ctl->done = 0;
  if (w->ctl_tail)
    w->ctl_tail->next = ctl;
  else
    w->ctl_head = ctl;
  w->ctl_tail = ctl;
  pthread_cond_broadcast(&w->cv);
  pthread_mutex_unlock(&w->mu);
}

hfd_ctl *hfd_worker_take_ctl(hfd_worker *w, int wait) {
  pthread_mutex_lock(&w->mu);
  while (wait && !w->ctl_done) pthread_cond_wait(&w->cv, &w->mu);
  hfd_ctl *c = w->ctl_done;
  w->ctl_done = NULL;
  pthread_mutex_unlock(&w->mu);
  return c;
}

int hfd_worker_stalled(hfd_worker *w, double limit_us, double *stalled_us) {
  double since = hfd_now_us() - (double)atomic_load(&w->progress_us);
  *stalled_us = since;
  return atomic_load(&w->working) && since > limit_us;
}

int hfd_worker_queue_depth(hfd_worker *w) {
  pthread_mutex_lock(&w->mu);
  int n = w->q_len + w->q_forming;
  pthread_mutex_unlock(&w->mu);
  return n;
}

/* Completes the jobs of list (taken off the queue) unrun, with status
 * (SHUTTING_DOWN, EXPIRED or CANCELLED). */
static void complete_unrun(hfd_worker *w, hfd_job *list, int status) {
  for (hfd_job *j = list, *next; j; j = next) {
    next = j->next;
    j->status = status;
    j->t_started = j->t_done = hfd_now_us();
    j->batch = 0;
    hfd_job *one[1] = {j};
    complete(w, one, 1);
  }
}

void hfd_worker_cancel(hfd_worker *w) {
  pthread_mutex_lock(&w->mu);
  w->cancel = 1;
  hfd_job *list = w->q_head;
  w->q_head = w->q_tail = NULL;
  w->q_len = 0;
  pthread_mutex_unlock(&w->mu);
  complete_unrun(w, list, HFP_E_SHUTTING_DOWN);
}

int hfd_worker_drop_conn(hfd_worker *w, const struct hfd_conn *conn) {
  hfd_job *dropped = NULL, **tail = &dropped;
  int n = 0;
  pthread_mutex_lock(&w->mu);
  hfd_job *prev = NULL;
  for (hfd_job *j = w->q_head, *next; j; j = next) {
    next = j->next;
    if (j->conn != conn) {
      prev = j;
      continue;
    }
    unlink_queued(w, prev, j);
    *tail = j;
    tail = &j->next;
    n++;
  }
  pthread_mutex_unlock(&w->mu);
  complete_unrun(w, dropped, HFP_E_SHUTTING_DOWN); /* their status is never written: the connection is gone */
  return n;
}

hfd_job *hfd_worker_take_expired(hfd_worker *w) {
  pthread_mutex_lock(&w->mu);
  double now = hfd_now_us();
  hfd_job *late = take_expired(w, now);
  pthread_mutex_unlock(&w->mu);
  for (hfd_job *j = late; j; j = j->next) {
    j->status = HFP_E_EXPIRED;
    j->t_started = j->t_done = now;
    j->batch = 0;
  }
  return late;
}

int hfd_worker_cancel_frame(hfd_worker *w, const struct hfd_conn *conn, uint32_t request_id) {
  pthread_mutex_lock(&w->mu);
  hfd_job *prev = NULL, *found = NULL;
  for (hfd_job *j = w->q_head; j; prev = j, j = j->next)
    if (j->conn == conn && j->request_id == request_id) {
      unlink_queued(w, prev, j);
      found = j;
      break;
    }
  pthread_mutex_unlock(&w->mu);
  if (found) complete_unrun(w, found, HFP_E_CANCELLED);
  return found != NULL;
}

/* Called from a signal handler: the store must not take a lock. */
_Static_assert(ATOMIC_INT_LOCK_FREE == 2, "hfd_worker_abandon_loads stores a lock-free int");

void hfd_worker_abandon_loads(hfd_worker *w) { atomic_store(&w->abandon, 1); }

void hfd_worker_stop(hfd_worker *w) {
  pthread_mutex_lock(&w->mu);
  w->stop = 1;
  pthread_cond_broadcast(&w->cv);
  pthread_mutex_unlock(&w->mu);
  pthread_join(w->thread, NULL);
  pthread_cond_destroy(&w->cv);
  pthread_mutex_destroy(&w->mu);
}

void hfd_ctl_free_list(hfd_ctl *c) {
  for (hfd_ctl *next; c; c = next) {
    next = c->next;
    if (c->rc) {
      free(c->model->path);
      free(c->model);
    }
    free(c);
  }
}
