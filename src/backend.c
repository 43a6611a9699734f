/* Backend registry, selection, and the hf_model_* entry points that check
 * arguments once so backends need not. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "backend.h"

static const hf_backend_ops *const registry[] = {
#ifdef HF_HAVE_CUDNN
  &hf_backend_cudnn,
#endif
#ifdef HF_HAVE_ONEDNN
  &hf_backend_cpu_onednn,
#endif
  &hf_backend_cpu_ref,
};
#define NREG ((int)(sizeof registry / sizeof registry[0]))

const char *const *hf_backend_list(void) {
  static const char *names[NREG + 1];
  for (int i = 0; i < NREG; i++) names[i] = registry[i]->name;
  names[NREG] = NULL;
  return names;
}

static int open_backend(const hf_backend_ops *ops, hf_backend **out, char *why, size_t whylen) {
  int rc = ops->probe(why, whylen);
  if (rc) return rc;
  hf_backend *b = calloc(1, sizeof *b);
  if (!b) return HF_ENOMEM;
  b->ops = ops;
  if (ops->open && (rc = ops->open(&b->dev, why, whylen)) != 0) {
    free(b);
    return rc;
  }
  *out = b;
  return HF_OK;
}

int hf_backend_create(const char *name, hf_backend **out, char *why, size_t whylen) {
  if (!name || !out) return HF_EINVAL;
  *out = NULL;
  if (why && whylen) why[0] = 0;
  if (strcmp(name, "auto") != 0) {
    for (int i = 0; i < NREG; i++)
      if (!strcmp(name, registry[i]->name)) return open_backend(registry[i], out, why, whylen);
    if (why && whylen) {
      /* Name the ones there are, and for a known backend left out of this
       * build, how to build it. */
      char have[128] = "";
      for (int i = 0; i < NREG; i++) {
        size_t used = strlen(have);
        snprintf(have + used, sizeof have - used, "%s%s", i ? ", " : "", registry[i]->name);
      }
      const char *how = "";
      if (!strcmp(name, "cudnn"))
        how = "; the cudnn backend is built when CMake finds CUDA and cuDNN 9 "
              "(HF_WITH_CUDNN=ON, docs/GPU.md)";
      else if (!strcmp(name, "cpu"))
        how = "; the cpu backend is built when CMake finds oneDNN (Debian's libdnnl-dev)";
      snprintf(why, whylen, "no backend named '%s' in this build: it has %s, or auto for the "
               "best of them%s", name, have, how);
    }
    return HF_ENOTFOUND;
  }
  /* "auto": try by priority and say why each better one was passed over. */
  const hf_backend_ops *order[NREG];
  memcpy(order, registry, sizeof order);
  for (int i = 1; i < NREG; i++)
    for (int j = i; j > 0 && order[j]->priority > order[j - 1]->priority; j--) {
      const hf_backend_ops *t = order[j];
      order[j] = order[j - 1];
      order[j - 1] = t;
    }
  /* Backends this build left out are named first, with how to build them:
   * a CPU-only package installed on a GPU node would otherwise say only
   * "backend cpu (best available)", and the operator would not learn why
   * the GPU sits idle. */
  char skipped[512] = "";
#ifndef HF_HAVE_CUDNN
  snprintf(skipped, sizeof skipped, "cudnn not in this build: it is built when CMake finds "
           "CUDA and cuDNN 9, HF_WITH_CUDNN=ON, docs/GPU.md");
#endif
#ifndef HF_HAVE_ONEDNN
  {
    size_t used = strlen(skipped);
    snprintf(skipped + used, sizeof skipped - used, "%scpu not in this build: it is built when "
             "CMake finds oneDNN (Debian's libdnnl-dev)", used ? "; " : "");
  }
#endif
  for (int i = 0; i < NREG; i++) {
    char reason[256] = "";
    int rc = open_backend(order[i], out, reason, sizeof reason);
    if (rc == HF_OK) {
      if (why && whylen) {
        const char *sep = reason[0] ? ": " : "";
        if (skipped[0])
          snprintf(why, whylen, "backend %s%s%s (%s)", order[i]->name, sep, reason, skipped);
        else
          snprintf(why, whylen, "backend %s%s%s (best available)", order[i]->name, sep, reason);
      }
      return HF_OK;
    }
    size_t used = strlen(skipped);
    snprintf(skipped + used, sizeof skipped - used, "%s%s unavailable: %s", used ? "; " : "",
             order[i]->name, reason[0] ? reason : hf_strerror(rc));
  }
  if (why && whylen) snprintf(why, whylen, "no backend usable: %s", skipped);
  return HF_EUNAVAILABLE;
}

void hf_backend_destroy(hf_backend *b) {
  if (!b) return;
  if (b->ops->close) b->ops->close(b->dev);
  free(b);
}

const char *hf_backend_name(const hf_backend *b) { return b ? b->ops->name : "none"; }

int hf_model_create(hf_backend *b, const hf_weights *w, hf_model **out) {
  if (!b || !w || !out) return HF_EINVAL;
  *out = NULL;
  int rc = hf_net_config_validate(&w->cfg);
  if (rc) return rc;
  unsigned archs = b->ops->archs ? b->ops->archs : 1u << HF_ARCH_UNET;
  if (!(archs & (1u << w->cfg.arch))) return HF_EUNSUPPORTED;
  hf_model *m = calloc(1, sizeof *m);
  if (!m) return HF_ENOMEM;
  m->backend = b;
  m->cfg = w->cfg;
  rc = b->ops->model_create(b->dev, w, &m->impl);
  if (rc) {
    free(m);
    return rc;
  }
  *out = m;
  return HF_OK;
}

void hf_model_destroy(hf_model *m) {
  if (!m) return;
  /* Runs still pending finish first: their buffers belong to the caller. */
  while (m->npending) hf_model_wait(m, NULL);
  m->backend->ops->model_destroy(m->impl);
  for (int i = 0; i < HF_MAX_PENDING; i++) free(m->sanitised[i].buf);
  free(m);
}

const hf_net_config *hf_model_config(const hf_model *m) { return m ? &m->cfg : NULL; }

/* Frames beyond this many pixels are refused before any backend allocates. */
#define HF_MAX_SIDE 16384
#define HF_MAX_PIXELS ((int64_t)1 << 28)

static int check_shape(int batch, int width, int height) {
  if (batch < 1 || width < 1 || height < 1) return HF_EINVAL;
  if (width > HF_MAX_SIDE || height > HF_MAX_SIDE ||
      (int64_t)batch * width * height > HF_MAX_PIXELS)
    return HF_ERANGE;
  return HF_OK;
}

static int check_io(const hf_io *io) {
  if (!io || !io->in || !io->out) return HF_EINVAL;
  int rc = check_shape(io->batch, io->width, io->height);
  if (rc) return rc;
  if ((io->in_dtype != HF_F32 && io->in_dtype != HF_F16) ||
      (io->out_dtype != HF_F32 && io->out_dtype != HF_F16))
    return HF_EINVAL;
  return HF_OK;
}

/* ---- out-of-contract values (protocol/FEATURES.md), for every backend ---- */

/* The sanitised copy of an input is kept in its slot for reuse up to this
 * size (a 1024x1024 frame of 4 samples in float32 is 96 MiB); larger ones
 * are released after their run rather than held. */
#define HF_SANITISED_KEEP ((size_t)128 << 20)

/* Makes the buffer of pending slot `slot` hold at least need bytes (kept:
 * a fresh buffer costs a page fault per 4 KiB on first write, more than
 * the copy). */
static void *slot_buffer(hf_model *m, int slot, size_t need) {
  if (m->sanitised[slot].cap < need) {
    free(m->sanitised[slot].buf);
    m->sanitised[slot].buf = malloc(need);
    m->sanitised[slot].cap = m->sanitised[slot].buf ? need : 0;
  }
  return m->sanitised[slot].buf;
}

/* Whether an f16 input of io is widened to float32 here, in the check's
 * pass, rather than by the backend after it: for backends that compute
 * from float32 frames on the host (cpu-ref; the cpu backend widens halves
 * itself, a band at a time), when the frame needs no padding (the backend
 * then reads the floats where they are, as it reads an aligned float32
 * frame; a padded frame it converts straight into its padded buffer) and
 * its floats fit in what a slot keeps between runs. */
static int widen_here(const hf_model *m, const hf_io *io) {
  int a = hf_net_align(&m->cfg);
  size_t bytes = (size_t)io->batch * io->width * io->height * m->cfg.in_channels * sizeof(float);
  return io->in_dtype == HF_F16 && !m->backend->ops->reads_f16 && io->width % a == 0 &&
         io->height % a == 0 && bytes <= HF_SANITISED_KEEP;
}

/* Checks every frame of io and, only when one needs it, sanitises a copy
 * in the buffer of pending slot `slot` (an f16 frame's copy stays f16: the
 * fixed values are exact in binary16, so it widens to the floats of a
 * sanitised float32 copy); or, for an f16 input that widen_here takes,
 * widens it into that buffer with the rule applied on the way
 * (hf_features_widen: what the backend would have widened from a sanitised
 * copy). Makes stats ([io->batch]) when not NULL, in the same pass where
 * there is one (every f16 frame). *run is the io the backend sees; rep,
 * when not NULL, gets [io->batch] reports. */
static int sanitise_input(hf_model *m, int slot, const hf_io *io, hf_io *run,
                          hf_input_report *rep, hf_input_stats *stats) {
  size_t esz = io->in_dtype == HF_F16 ? 2 : 4;
  size_t values = (size_t)io->width * io->height * m->cfg.in_channels;
  size_t frame = values * esz;
  hf_input_report one;
  *run = *io;
  if (m->cfg.estimate) {
    /* Samples and estimate, planar in io, interleaved for the backend: a
     * copy of every frame, checked on the way. */
    uint8_t *copy = slot_buffer(m, slot, frame * (size_t)io->batch);
    if (!copy) return HF_ENOMEM;
    for (int n = 0; n < io->batch; n++) {
      int rc = hf_features_interleave((const uint8_t *)io->in + n * frame, io->in_dtype,
                                      io->width, io->height, m->cfg.spp, copy + n * frame,
                                      rep ? &rep[n] : &one, stats ? &stats[n] : NULL);
      if (rc) return rc;
    }
    run->in = copy;
    return HF_OK;
  }
  if (widen_here(m, io)) {
    float *wide = slot_buffer(m, slot, values * sizeof(float) * (size_t)io->batch);
    if (!wide) return HF_ENOMEM;
    for (int n = 0; n < io->batch; n++) {
      int rc = hf_features_widen((const uint16_t *)io->in + n * values, wide + n * values,
                                 io->width, io->height, m->cfg.spp, rep ? &rep[n] : &one,
                                 stats ? &stats[n] : NULL);
      if (rc) return rc;
    }
    run->in = wide;
    run->in_dtype = HF_F32;
    return HF_OK;
  }
  /* The check and the statistics in one pass that only reads the frames
   * (halves the cpu backend reads itself, or floats read where they are). */
  uint64_t bad = 0;
  for (int n = 0; n < io->batch; n++) {
    hf_input_report *r = rep ? &rep[n] : &one;
    int rc = hf_features_scan((const uint8_t *)io->in + n * frame, io->in_dtype, io->width,
                              io->height, m->cfg.spp, r, stats ? &stats[n] : NULL);
    if (rc) return rc;
    bad += r->samples;
  }
  if (!bad) return HF_OK;
  size_t need = frame * (size_t)io->batch;
  uint8_t *copy = slot_buffer(m, slot, need);
  if (!copy) return HF_ENOMEM;
  /* Copied and fixed chunk by chunk on the pool's threads: a frame with
   * one bad sample costs about a copy, not a single-threaded pass. */
  for (int n = 0; n < io->batch; n++) {
    const uint8_t *src = (const uint8_t *)io->in + n * frame;
    if (rep && !rep[n].samples) {
      memcpy(copy + n * frame, src, frame);
      continue;
    }
    int rc = hf_features_copy_sanitised(src, copy + n * frame, io->in_dtype, io->width,
                                        io->height, m->cfg.spp, rep ? &rep[n] : &one);
    if (rc) return rc;
  }
  run->in = copy;
  return HF_OK;
}

/* After a run of io: the output guard on every frame (when it succeeded),
 * and the slot's buffer released when it is larger than HF_SANITISED_KEEP. */
static void finish_output(hf_model *m, int slot, const hf_io *io, hf_input_report *rep, int rc,
                          int guarded) {
  if (rc == HF_OK && !guarded) {
    size_t px = (size_t)io->width * io->height;
    size_t oes = io->out_dtype == HF_F16 ? 2 : 4;
    for (int n = 0; n < io->batch; n++) {
      uint64_t fixed = hf_output_guard((uint8_t *)io->out + n * px * 3 * oes, io->out_dtype, px);
      if (rep) rep[n].outputs = fixed;
    }
  }
  if (m->sanitised[slot].cap > HF_SANITISED_KEEP) {
    free(m->sanitised[slot].buf);
    m->sanitised[slot].buf = NULL;
    m->sanitised[slot].cap = 0;
  }
}

/* Whether a backend that checks frames itself (model_run_scan,
 * model_submit_scan) may take io: not a network with an estimate, which is
 * interleaved first (sanitise_input), and reports somewhere to go. */
static int may_scan(const hf_model *m, const hf_io *io, const hf_input_report *rep) {
  return !m->cfg.estimate && (rep || io->batch <= HF_SCAN_OWN_REPORTS);
}

/* Pending slot `slot` holds io, run or started by the backend itself. */
static void pend(hf_model *m, int slot, const hf_io *io, hf_input_report *report, int guarded,
                 int rc, hf_timing t) {
  m->pending[slot].io = *io;
  m->pending[slot].report = report;
  m->pending[slot].input_us = 0;
  m->pending[slot].guarded = guarded;
  m->pending[slot].rc = rc;
  m->pending[slot].t = t;
  m->npending++;
}

/* io run by a backend that checks it in its own first read of the input
 * (model_run_scan), saving sanitise_input's pass over memory: HF_OK (the
 * output guard applied), an error, or HF_RUN_DECLINED / HF_RUN_UNCLEAN,
 * after which the caller takes the common path (check, sanitised copy,
 * model_run) and nothing it needs has changed. */
static int run_scanning(hf_model *m, const hf_io *io, hf_timing *t, hf_input_report *rep,
                        hf_input_stats *stats) {
  const hf_backend_ops *ops = m->backend->ops;
  hf_input_report own[HF_SCAN_OWN_REPORTS];
  if (!may_scan(m, io, rep)) return HF_RUN_DECLINED;
  int guarded = 0, rc;
  if (ops->model_run_scan) {
    rc = ops->model_run_scan(m->impl, io, t, rep ? rep : own, stats, &guarded);
  } else if (ops->model_submit_scan) {
    /* Checked by the backend on the device; complete when waited for. */
    rc = ops->model_submit_scan(m->impl, io, rep ? rep : own, stats);
    if (rc == HF_OK) rc = ops->model_wait(m->impl, t);
    guarded = 1;
  } else {
    return HF_RUN_DECLINED;
  }
  if (rc != HF_OK) return rc;
  double t0 = hf_now_us();
  finish_output(m, 0, io, rep, rc, guarded);
  t->output_us += hf_now_us() - t0;
  return HF_OK;
}

int hf_model_run(hf_model *m, const hf_io *io, hf_timing *timing) {
  return hf_model_run_report(m, io, timing, NULL);
}

int hf_model_run_report(hf_model *m, const hf_io *io, hf_timing *timing,
                        hf_input_report *rep) {
  return hf_model_run_stats(m, io, timing, rep, NULL);
}

int hf_model_run_stats(hf_model *m, const hf_io *io, hf_timing *timing, hf_input_report *rep,
                       hf_input_stats *stats) {
  if (!m) return HF_EINVAL;
  int rc = check_io(io);
  if (rc) return rc;
  if (m->npending) return HF_EINVAL;   /* wait for the pending runs first */
  hf_timing t = {0, 0, 0};
  rc = run_scanning(m, io, &t, rep, stats);
  if (rc <= 0) {
    if (timing) *timing = t;
    return rc;
  }
  double t0 = hf_now_us();
  hf_io run;
  if ((rc = sanitise_input(m, 0, io, &run, rep, stats)) != 0) return rc;
  double t1 = hf_now_us();
  t = (hf_timing){0, 0, 0};
  rc = m->backend->ops->model_run(m->impl, &run, &t);
  double t2 = hf_now_us();
  finish_output(m, 0, io, rep, rc, 0);
  t.input_us += t1 - t0;
  t.output_us += hf_now_us() - t2;
  if (timing) *timing = t;
  return rc;
}

int hf_model_prepare(hf_model *m, int batch, int width, int height) {
  if (!m) return HF_EINVAL;
  int rc = check_shape(batch, width, height);
  if (rc) return rc;
  return m->backend->ops->model_prepare
             ? m->backend->ops->model_prepare(m->impl, batch, width, height)
             : HF_OK;
}

int hf_model_submit(hf_model *m, const hf_io *io) { return hf_model_submit_report(m, io, NULL); }

int hf_model_submit_report(hf_model *m, const hf_io *io, hf_input_report *rep) {
  return hf_model_submit_stats(m, io, rep, NULL);
}

int hf_model_submit_stats(hf_model *m, const hf_io *io, hf_input_report *rep,
                          hf_input_stats *stats) {
  if (!m) return HF_EINVAL;
  int rc = check_io(io);
  if (rc) return rc;
  if (m->npending == HF_MAX_PENDING) return HF_ERANGE;
  const int slot = (m->head + m->npending) % HF_MAX_PENDING;
  const hf_backend_ops *ops = m->backend->ops;
  if (!ops->model_submit && ops->model_run_scan && may_scan(m, io, rep)) {
    /* Run here, checked in the backend's own read of the input; the guard
     * and its time come at the wait. */
    hf_input_report own[HF_SCAN_OWN_REPORTS];
    hf_timing t = {0, 0, 0};
    int guarded = 0;
    rc = ops->model_run_scan(m->impl, io, &t, rep ? rep : own, stats, &guarded);
    if (rc <= 0) {
      pend(m, slot, io, rep, guarded, rc, t);
      return HF_OK;
    }
  }
  if (ops->model_submit_scan && may_scan(m, io, rep)) {
    /* Checked by the backend itself, on the device: the reports and
     * statistics are complete at the wait. */
    hf_input_report *r = rep ? rep : m->pending[slot].own;
    rc = ops->model_submit_scan(m->impl, io, r, stats);
    if (rc != HF_RUN_DECLINED) {
      if (rc != HF_OK) return rc;
      pend(m, slot, io, r, 1, HF_OK, (hf_timing){0, 0, 0});
      return HF_OK;
    }
  }
  /* The slot's sanitised copy, if any, stays until the wait: the backend
   * may read it until then. */
  double t0 = hf_now_us();
  hf_io run;
  if ((rc = sanitise_input(m, slot, io, &run, rep, stats)) != 0) return rc;
  m->pending[slot].io = *io;
  m->pending[slot].report = rep;
  m->pending[slot].input_us = hf_now_us() - t0;
  m->pending[slot].guarded = 0;
  if (ops->model_submit) {
    /* A failure to start leaves nothing pending; a failure of the run
     * itself is the wait's to report. */
    if ((rc = ops->model_submit(m->impl, &run)) != 0) {
      finish_output(m, slot, io, NULL, rc, 0);
      return rc;
    }
    m->pending[slot].rc = HF_OK;
  } else {
    hf_timing t = {0, 0, 0};
    m->pending[slot].rc = ops->model_run(m->impl, &run, &t);
    m->pending[slot].t = t;
  }
  m->npending++;
  return HF_OK;
}

int hf_model_wait(hf_model *m, hf_timing *timing) {
  if (!m || !m->npending) return HF_EINVAL;
  const int slot = m->head;
  m->head = (m->head + 1) % HF_MAX_PENDING;
  m->npending--;
  hf_timing t = m->pending[slot].t;
  int rc = m->pending[slot].rc;
  if (m->backend->ops->model_wait) rc = m->backend->ops->model_wait(m->impl, &t);
  double t2 = hf_now_us();
  finish_output(m, slot, &m->pending[slot].io, m->pending[slot].report, rc,
                m->pending[slot].guarded);
  t.input_us += m->pending[slot].input_us;
  t.output_us += hf_now_us() - t2;
  if (timing) *timing = t;
  return rc;
}

int hf_model_reads_input_once(const hf_model *m, const void *in, size_t bytes) {
  if (!m || !in) return 0;
  /* sanitise_input interleaves such a network's samples and estimate into
   * a copy, reading each once (hf_features_interleave), and the backend
   * reads only the copy. */
  if (m->cfg.estimate) return 1;
  const hf_backend_ops *ops = m->backend->ops;
  return ops->model_reads_input_once ? ops->model_reads_input_once(m->impl, in, bytes) : 0;
}

int hf_model_overlaps(const hf_model *m) { return m && m->backend->ops->model_submit != NULL; }

int hf_backend_host_register(hf_backend *b, void *ptr, size_t bytes) {
  if (!b || !ptr || !bytes) return HF_EINVAL;
  return b->ops->host_register ? b->ops->host_register(b->dev, ptr, bytes) : HF_OK;
}

void hf_backend_host_unregister(hf_backend *b, void *ptr) {
  if (b && ptr && b->ops->host_unregister) b->ops->host_unregister(b->dev, ptr);
}

const char *hf_model_precision(const hf_model *m) {
  if (!m) return "none";
  return m->backend->ops->model_precision ? m->backend->ops->model_precision(m->impl) : "fp32";
}

size_t hf_model_device_bytes(const hf_model *m) {
  if (!m || !m->backend->ops->model_device_bytes) return 0;
  return m->backend->ops->model_device_bytes(m->impl);
}

/* The same range hf_model_run accepts, so an estimate exists for every frame
 * that can run. */
static int run_size_ok(int width, int height, int batch) {
  return batch >= 1 && width >= 1 && height >= 1 && width <= HF_MAX_SIDE &&
         height <= HF_MAX_SIDE && (int64_t)batch * width * height <= HF_MAX_PIXELS;
}

size_t hf_run_bytes(const hf_backend *b, const hf_net_config *cfg, int width, int height,
                    int batch) {
  if (!b || !cfg || !b->ops->run_bytes || !run_size_ok(width, height, batch) ||
      hf_net_config_validate(cfg))
    return 0;
  int a = hf_net_align(cfg);
  /* Plus the sanitised copy of an input that needs one (float32 at most). */
  size_t sanitised = (size_t)batch * width * height * cfg->in_channels * sizeof(float);
  return b->ops->run_bytes(cfg, batch, hf_round_up(width, a), hf_round_up(height, a)) +
         sanitised;
}

static size_t sanitised_bytes(const hf_model *m) {
  size_t n = 0;
  for (int i = 0; i < HF_MAX_PENDING; i++) n += m->sanitised[i].cap;
  return n;
}

size_t hf_model_cached_bytes(const hf_model *m) {
  if (!m) return 0;
  size_t n = sanitised_bytes(m);
  if (m->backend->ops->model_cached_bytes) n += m->backend->ops->model_cached_bytes(m->impl);
  return n;
}

void hf_model_trim(hf_model *m, size_t keep) {
  if (!m) return;
  /* The sanitised copies go first: they are rebuilt from the input anyway
   * (not while a submitted run may still read one). */
  size_t kept = sanitised_bytes(m);
  if (kept > keep && m->npending == 0) {
    for (int i = 0; i < HF_MAX_PENDING; i++) {
      free(m->sanitised[i].buf);
      m->sanitised[i].buf = NULL;
      m->sanitised[i].cap = 0;
    }
    kept = 0;
  }
  if (m->backend->ops->model_trim)
    m->backend->ops->model_trim(m->impl, keep > kept ? keep - kept : 0);
}

/* ---- helpers shared by the CPU backends ---------------------------------- */

size_t hf_output_extra_bytes(const hf_net_config *cfg, int width, int height) {
  /* A row of float results for an f16 output, the whole-frame base and its
   * scratch (a Kernel's per-pixel sums, 6 floats a pixel when it mixes). */
  size_t row = (size_t)width * 3 * sizeof(float);
  if (cfg->arch != HF_ARCH_RESIDUAL && cfg->arch != HF_ARCH_KERNEL) return row;
  const int k = cfg->arch == HF_ARCH_KERNEL ? hf_kernel_sums_floats(hf_kernel_sums_of(cfg)) : 3;
  return row + (size_t)width * height * (3 + k) * sizeof(float);
}

double hf_now_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

void hf_input_to_padded_f32(const hf_io *io, int cin, int pw, int ph, float *dst) {
  size_t frame_in = (size_t)io->width * io->height * cin;
  for (int n = 0; n < io->batch; n++) {
    float *d = dst + (size_t)n * pw * ph * cin;
    int y0 = 0;
    if (io->in_dtype == HF_F16 && pw == io->width) {
      /* Rows already dense: the whole frame in one conversion, which
       * spreads a large frame over threads. */
      hf_f16_to_f32_array((const uint16_t *)io->in + n * frame_in, d, frame_in);
      y0 = io->height;
    }
    for (int y = y0; y < ph; y++) {
      float *row = d + (size_t)y * pw * cin;
      if (y >= io->height) {
        memset(row, 0, sizeof(float) * pw * cin);
        continue;
      }
      size_t src0 = n * frame_in + (size_t)y * io->width * cin;
      size_t cnt = (size_t)io->width * cin;
      if (io->in_dtype == HF_F32) {
        memcpy(row, (const float *)io->in + src0, cnt * sizeof(float));
      } else {
        const uint16_t *s = (const uint16_t *)io->in + src0;
        hf_f16_to_f32_array(s, row, cnt);
      }
      memset(row + cnt, 0, sizeof(float) * (size_t)(pw - io->width) * cin);
    }
  }
}

void hf_output_from_padded_f32(const hf_net_config *cfg, const float *in, const float *src,
                               int pw, int ph, const hf_io *io) {
  /* The Residual base or the Kernel output of a whole frame at once
   * (separable sums; per-pixel sums made once); without the memory for it,
   * pixel by pixel (same values, more work). */
  float *base = NULL, *tmp = NULL, *row = NULL;
  const int kernel = cfg->arch == HF_ARCH_KERNEL, raw_ch = cfg->out_channels;
  if (cfg->arch == HF_ARCH_RESIDUAL || kernel) {
    /* tmp: the Kernel's per-pixel sums, 6 floats a pixel when it mixes */
    const int k = kernel ? hf_kernel_sums_floats(hf_kernel_sums_of(cfg)) : 3;
    base = malloc((size_t)io->width * io->height * 3 * sizeof(float));
    tmp = malloc((size_t)io->width * io->height * k * sizeof(float));
    if (!base || !tmp) free(base), free(tmp), base = tmp = NULL;
  }
  /* An f16 result is gathered a row at a time in float and converted per
   * row (hf_f32_to_f16_array); without the row's memory, value by value. */
  if (io->out_dtype == HF_F16) row = malloc((size_t)io->width * 3 * sizeof(float));
  for (int n = 0; n < io->batch; n++) {
    hf_input_view view = {in + (size_t)n * ph * pw * cfg->in_channels, io->width, io->height,
                          pw, cfg->in_channels};
    const float *raw = src + (size_t)n * ph * pw * raw_ch;
    if (base && kernel)
      hf_kernel_output_frame(&view, cfg->spp, hf_kernel_sums_of(cfg), cfg->kernel_radius, raw, pw,
                             raw_ch, base, tmp);
    else if (base)
      hf_residual_base_frame(&view, cfg->spp, base, tmp);
    for (int y = 0; y < io->height; y++) {
      for (int x = 0; x < io->width; x++) {
        size_t px = (size_t)y * pw + x;
        float v[HF_MAX_RAW_CHANNELS];
        if (base && kernel) {
          memcpy(v, base + ((size_t)y * io->width + x) * 3, 3 * sizeof(float));
        } else {
          memcpy(v, raw + px * raw_ch, raw_ch * sizeof(float));
          if (base) hf_residual_apply(base + ((size_t)y * io->width + x) * 3, v);
          else hf_output_finish(cfg, &view, x, y, v);
        }
        size_t o = (((size_t)n * io->height + y) * io->width + x) * 3;
        if (io->out_dtype == HF_F32) {
          memcpy((float *)io->out + o, v, 3 * sizeof(float));
        } else if (row) {
          memcpy(row + (size_t)x * 3, v, 3 * sizeof(float));
        } else {
          uint16_t *d = (uint16_t *)io->out + o;
          for (int c = 0; c < 3; c++) d[c] = hf_f32_to_f16(v[c]);
        }
      }
      if (row)
        hf_f32_to_f16_array(row, (uint16_t *)io->out + ((size_t)n * io->height + y) * io->width * 3,
                            (size_t)io->width * 3);
    }
  }
  free(base);
  free(tmp);
  free(row);
}
