/*
 * The cudnn backend: the network on an NVIDIA GPU in FP16 NHWC with FP32
 * accumulation, through cuDNN 9's graph API (docs/GPU.md).
 *
 * A model holds the packed weights on the device, its own cuDNN handle,
 * three streams (upload, compute, download), two request slots and a cache
 * of plans, one per (batch, padded width, padded height). A plan is
 * everything a request of that shape needs, made once: activation buffers
 * laid out by cudnn_layout.h, each layer in the form and with the engines
 * that timed fastest, one workspace, and a CUDA graph of the whole forward
 * pass.
 *
 * A request (hf_model_submit) uploads its input on the upload stream: by
 * DMA straight from the caller's memory when that memory was registered
 * (hf_backend_host_register: shared-memory segments), else through a ring
 * of pinned chunks, converting FP32 to FP16 on the way so half the bytes
 * cross the bus. The compute stream waits for the upload, pads and converts
 * the input, replays the graph and runs the output stage; the download
 * stream brings the result back (again directly, or through pinned chunks
 * copied out as they land). With two slots, frame n+1 uploads while frame
 * n computes. hf_model_run is submit + wait.
 *
 * Environment (diagnosis and tuning; docs/GPU.md lists them):
 *   HF_CUDNN_VERBOSE=1      log engines, notes, finalize times, forms, plans
 *   HF_CUDNN_DECONV=LIST    decoder forms to try: auto (d2s,phase),
 *                           or any of bwd-data, d2s, phase, shuffle
 *   HF_CUDNN_DENSE=1        skip strided views: every conv on dense copies
 *   HF_CUDNN_NO_FUSION=1    skip the fused bias+ReLU graphs
 *   HF_CUDNN_NO_GRAPH=1     run layers eagerly instead of a CUDA graph
 *   HF_CUDNN_CANDIDATES=N   engine configs finalized and timed per graph (4)
 *   HF_CUDNN_RTC=N          of which run-time compiled (NVRTC), at most (1)
 *   HF_CUDNN_PLANS=N        plans kept besides prepared ones (8, LRU)
 *   HF_CUDNN_STAGE_MB=N     pinned staging chunk (4 MiB; 4 for input, 2 out)
 *   HF_CUDNN_NO_REGISTER=1  never pin caller memory (staging only)
 *   HF_CUDA_DEVICE=N        the device (0)
 */
#include <pthread.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cuda_runtime_api.h>
#include <cudnn.h>

#include "backend.h"
#include "cudnn_graph.h"
#include "cudnn_kernels.h"
#include "cudnn_layout.h"
#include "cudnn_util.h"

#define MAX_PLANS 32          /* prepared + cached, hard limit */
#define RING_IN 4
#define RING_OUT 2
#define TUNE_REPS 5

/* ---- options --------------------------------------------------------------- */

static int env_flag(const char *name) {
  const char *v = getenv(name);
  return v && v[0] && strcmp(v, "0") != 0;
}

static int env_int(const char *name, int def, int lo, int hi) {
  const char *v = getenv(name);
  if (!v || !v[0]) return def;
  char *end;
  long n = strtol(v, &end, 10);
  if (*end || n < lo || n > hi) {
    fprintf(stderr, "hfcore cudnn: %s=%s ignored (want %d..%d); using %d\n", name, v, lo, hi,
            def);
    return def;
  }
  return (int)n;
}

typedef struct cudnn_opts {
  int no_graph, no_fusion, dense, no_register, host_check;
  unsigned dec_forms;           /* mask of 1 << HF_CL_FORM_* tried for decoders */
  int candidates, rtc, plans;
  size_t stage_bytes;
} cudnn_opts;

/* bwd-data is not tried by default: on an H200 (cuDNN 9.19, docs/GPU.md,
 * "The first GPU run") d2s beat it on every decoder by 4-57x, and building
 * its fused data-gradient graphs took 2.7 s of a 3.6 s plan (run-time
 * compiled engines) for a form never kept. HF_CUDNN_DECONV still offers it. */
#define DEFAULT_DEC_FORMS (1u << HF_CL_FORM_D2S | 1u << HF_CL_FORM_PHASE)

static int parse_forms(const char *v, unsigned *mask) {
  if (!v || !v[0] || !strcmp(v, "auto")) {
    *mask = DEFAULT_DEC_FORMS;
    return HF_OK;
  }
  char buf[128];
  snprintf(buf, sizeof buf, "%s", v);
  *mask = 0;
  for (char *save, *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
    int f = hf_cl_form_from_name(tok);
    if (f < 0 || f == HF_CL_FORM_FWD)
      return hf_cudnn_report(HF_EINVAL,
                             "HF_CUDNN_DECONV: '%s' is not a decoder form (auto, bwd-data, d2s, "
                             "phase, shuffle)", tok);
    *mask |= 1u << f;
  }
  return *mask ? HF_OK : HF_EINVAL;
}

static int read_opts(cudnn_opts *o) {
  memset(o, 0, sizeof *o);
  o->no_graph = env_flag("HF_CUDNN_NO_GRAPH");
  o->no_fusion = env_flag("HF_CUDNN_NO_FUSION");
  o->dense = env_flag("HF_CUDNN_DENSE");
  o->no_register = env_flag("HF_CUDNN_NO_REGISTER");
  o->host_check = env_flag("HF_CUDNN_HOST_CHECK");
  o->candidates = env_int("HF_CUDNN_CANDIDATES", 4, 1, HF_CG_MAX_CAND);
  o->rtc = env_int("HF_CUDNN_RTC", 1, 0, HF_CG_MAX_CAND);
  o->plans = env_int("HF_CUDNN_PLANS", 8, 1, MAX_PLANS);
  o->stage_bytes = (size_t)env_int("HF_CUDNN_STAGE_MB", 4, 1, 256) << 20;
  return parse_forms(getenv("HF_CUDNN_DECONV"), &o->dec_forms);
}

static int env_device(void) { return env_int("HF_CUDA_DEVICE", 0, 0, 1024); }

/* ---- probe / open ------------------------------------------------------- */

/* Host memory registered for DMA (hf_backend_host_register). */
typedef struct host_range {
  uintptr_t lo, hi;
} host_range;

typedef struct cudnn_dev {
  int device;
  int no_register;
  pthread_mutex_t lock;
  host_range *ranges;
  int nranges, cap;
} cudnn_dev;

/* What "CUDA driver version is insufficient" means here. The CUDA runtime
 * answers that both without any NVIDIA driver (no GPU: nothing to do) and
 * with a driver older than the runtime (update the driver); the loaded
 * kernel module's version file tells them apart. */
static const char *driver_note(cudaError_t e, char *buf, size_t cap) {
  buf[0] = 0;
  if (e != cudaErrorInsufficientDriver) return buf;
  FILE *f = fopen("/proc/driver/nvidia/version", "r");
  if (!f) {
    snprintf(buf, cap, "; no NVIDIA driver is loaded (no /proc/driver/nvidia/version): "
                       "this machine has no usable GPU");
    return buf;
  }
  char line[160] = "";
  if (!fgets(line, sizeof line, f)) line[0] = 0;
  fclose(f);
  line[strcspn(line, "\n")] = 0;
  snprintf(buf, cap, "; the loaded driver (%s) is older than this build's CUDA %d.%d runtime "
                     "needs: update the NVIDIA driver", line[0] ? line : "version unknown",
           CUDART_VERSION / 1000, CUDART_VERSION % 1000 / 10);
  return buf;
}

static int cudnn_probe(char *why, size_t whylen) {
  int count = 0;
  cudaError_t e = cudaGetDeviceCount(&count);
  if (e != cudaSuccess || count < 1) {
    char note[300];
    snprintf(why, whylen, "no CUDA device (cudaGetDeviceCount: %s%s)",
             e != cudaSuccess ? cudaGetErrorString(e) : "0 devices",
             driver_note(e, note, sizeof note));
    cudaGetLastError(); /* the failure is not sticky; leave no trace */
    return HF_EUNAVAILABLE;
  }
  const int dev = env_device();
  if (dev < 0 || dev >= count) {
    snprintf(why, whylen, "HF_CUDA_DEVICE=%d but %d CUDA device(s)", dev, count);
    return HF_EUNAVAILABLE;
  }
  struct cudaDeviceProp prop;
  if ((e = cudaGetDeviceProperties(&prop, dev)) != cudaSuccess) {
    snprintf(why, whylen, "CUDA device %d: cudaGetDeviceProperties: %s", dev,
             cudaGetErrorString(e));
    return HF_EUNAVAILABLE;
  }
  /* The kernels are built for sm_75 and newer (CUDA 13's minimum). */
  if (prop.major * 10 + prop.minor < 75) {
    snprintf(why, whylen, "CUDA device %d (%s) has compute capability %d.%d, need 7.5", dev,
             prop.name, prop.major, prop.minor);
    return HF_EUNAVAILABLE;
  }
  const size_t ver = cudnnGetVersion();
  if (ver / 10000 != CUDNN_MAJOR) {
    snprintf(why, whylen, "cuDNN %zu.%zu.%zu at run time, built for %d.x", ver / 10000,
             ver / 100 % 100, ver % 100, CUDNN_MAJOR);
    return HF_EUNAVAILABLE;
  }
  if ((e = cudaSetDevice(dev)) != cudaSuccess) {
    snprintf(why, whylen, "cudaSetDevice(%d): %s", dev, cudaGetErrorString(e));
    return HF_EUNAVAILABLE;
  }
  cudnnHandle_t h;
  cudnnStatus_t s = cudnnCreate(&h);
  if (s != CUDNN_STATUS_SUCCESS) {
    char detail[256] = "";
    cudnnGetLastErrorString(detail, sizeof detail);
    snprintf(why, whylen, "cudnnCreate: %s%s%s", cudnnGetErrorString(s), detail[0] ? ": " : "",
             detail);
    return HF_EUNAVAILABLE;
  }
  cudnnDestroy(h);
  /* What runs, for the log: the versions found at run time may differ
   * from the headers this was built with. */
  int rt = 0, drv = 0;
  cudaRuntimeGetVersion(&rt);
  cudaDriverGetVersion(&drv);
  snprintf(why, whylen,
           "%s (device %d, sm_%d%d, %d SMs), cuDNN %zu.%zu.%zu at run time (built with "
           "%d.%d.%d), CUDA runtime %d.%d, driver supports CUDA %d.%d",
           prop.name, dev, prop.major, prop.minor, prop.multiProcessorCount, ver / 10000,
           ver / 100 % 100, ver % 100, CUDNN_MAJOR, CUDNN_MINOR, CUDNN_PATCHLEVEL, rt / 1000,
           rt % 1000 / 10, drv / 1000, drv % 1000 / 10);
  if (hf_cudnn_verbose()) fprintf(stderr, "hfcore cudnn: %s\n", why);
  return HF_OK;
}

static int cudnn_open(void **devp, char *why, size_t whylen) {
  cudnn_dev *d = calloc(1, sizeof *d);
  if (!d) return HF_ENOMEM;
  if (pthread_mutex_init(&d->lock, NULL)) {
    free(d);
    return HF_ENOMEM;
  }
  d->device = env_device();
  d->no_register = env_flag("HF_CUDNN_NO_REGISTER");
  *devp = d;
  return HF_OK;
}

static void cudnn_close(void *dev) {
  cudnn_dev *d = dev;
  if (!d) return;
  cudaSetDevice(d->device);
  for (int i = 0; i < d->nranges; i++) cudaHostUnregister((void *)d->ranges[i].lo);
  free(d->ranges);
  pthread_mutex_destroy(&d->lock);
  free(d);
}

static int cudnn_host_register(void *dev, void *ptr, size_t bytes) {
  cudnn_dev *d = dev;
  if (d->no_register) return HF_OK;
  int rc;
  /* Pinning takes milliseconds (1.7 ms for 8 MiB to 7.1 ms for 192 MiB on
   * an H200 host): done outside the lock, which the worker's uploads take
   * to look a buffer up (is_registered). The calling thread (one of
   * hairfilterd's thread pool) may not have the device current yet; the
   * primary context is shared with the worker's. */
  HF_CU_TRY(cudaSetDevice(d->device));
  HF_CU_TRY(cudaHostRegister(ptr, bytes, cudaHostRegisterDefault));
  pthread_mutex_lock(&d->lock);
  if (d->nranges == d->cap) {
    int cap = d->cap ? 2 * d->cap : 16;
    host_range *r = realloc(d->ranges, (size_t)cap * sizeof *r);
    if (!r) {
      pthread_mutex_unlock(&d->lock);
      cudaError_t e = cudaHostUnregister(ptr);
      if (e != cudaSuccess) hf_cu_report(e, "cudaHostUnregister", __FILE__, __LINE__);
      return HF_ENOMEM;
    }
    d->ranges = r;
    d->cap = cap;
  }
  d->ranges[d->nranges].lo = (uintptr_t)ptr;
  d->ranges[d->nranges].hi = (uintptr_t)ptr + bytes;
  d->nranges++;
  pthread_mutex_unlock(&d->lock);
  return HF_OK;
fail:
  cudaGetLastError();
  return rc;
}

static void cudnn_host_unregister(void *dev, void *ptr) {
  cudnn_dev *d = dev;
  int found = 0;
  pthread_mutex_lock(&d->lock);
  for (int i = 0; i < d->nranges; i++)
    if (d->ranges[i].lo == (uintptr_t)ptr) {
      d->ranges[i] = d->ranges[--d->nranges];
      found = 1;
      break;
    }
  pthread_mutex_unlock(&d->lock);
  if (!found) return;
  /* Outside the lock, as registering is: it takes milliseconds. */
  cudaError_t e = cudaSetDevice(d->device);
  if (e != cudaSuccess) {
    hf_cu_report(e, "cudaSetDevice", __FILE__, __LINE__);
    return;
  }
  e = cudaHostUnregister(ptr);
  if (e != cudaSuccess) hf_cu_report(e, "cudaHostUnregister", __FILE__, __LINE__);
}

static int is_registered(cudnn_dev *d, const void *ptr, size_t bytes) {
  const uintptr_t lo = (uintptr_t)ptr, hi = lo + bytes;
  int found = 0;
  pthread_mutex_lock(&d->lock);
  for (int i = 0; i < d->nranges && !found; i++)
    found = lo >= d->ranges[i].lo && hi <= d->ranges[i].hi && hi >= lo;
  pthread_mutex_unlock(&d->lock);
  return found;
}

/* ---- plans ------------------------------------------------------------- */

/* One cuDNN convolution as it runs: on the layer's views, or on dense
 * copies when no engine accepted the views. */
typedef struct conv_run {
  hf_cl_conv cv;
  hf_cg_op op;
  int dense;
  void *x, *y;                  /* what the op reads and writes */
  void *scratch_in, *scratch_out;
} conv_run;

/* One layer in its chosen form. */
typedef struct step {
  const hf_cl_layer *ly;
  hf_cl_form f;
  conv_run cr[HF_CL_MAX_CONVS];
  void *scratch;                /* the form's depth-to-space input */
  size_t bytes;                 /* device bytes of the step's own tensors */
  float time_ms;                /* the whole layer, as tuned */
} step;

typedef struct plan {
  int batch, pw, ph;
  int pinned;                   /* made by hf_model_prepare: never evicted */
  int inflight;                 /* submitted runs not yet waited for */
  uint64_t last_used;
  hf_cl_layout lo;
  void *buf[HF_CL_MAX_BUFS];
  step steps[HF_CL_MAX_LAYERS];
  void *ws;
  size_t ws_bytes;
  cudaGraphExec_t gexec;
  size_t device_bytes;
  double build_ms, graphs_ms, tune_ms;
  int graphs;                   /* cuDNN graphs built, the ones given up included */
} plan;

/* One request in flight. Events, in stream order:
 *   upload:   IN0 [copies] IN1
 *   compute:  (waits IN1) C0 input kernel CONSUMED C1 network C2 output C3
 *   download: (waits C3) O0 [copies] O1 */
enum { EV_IN0, EV_IN1, EV_C0, EV_CONSUMED, EV_C1, EV_C2, EV_C3, EV_O0, EV_O1, EV_COUNT };

typedef struct slot {
  int busy, used;
  int rc;                       /* a failure after the run started */
  plan *p;
  hf_io io;
  void *d_in, *d_out;           /* the request's own tensors on the device */
  size_t d_in_cap, d_out_cap;
  int in_f16;                   /* d_in holds FP16 (staged) or the caller's dtype */
  int out_staged;               /* download through the ring (in wait) */
  size_t in_bytes, out_bytes;
  double host_in_us, host_out_us;
  cudaEvent_t ev[EV_COUNT];
  /* The input check on the device (model_submit_scan): the frames' counts,
   * on the device and in pinned host memory, and where they go. */
  int scan;
  hf_input_report *rep;
  hf_input_stats *stats;
  hf_cuk_scan_counts *d_counts, *h_counts;
  size_t d_counts_cap, h_counts_cap;   /* bytes */
} slot;

typedef struct ring {
  int n;
  void *buf[RING_IN];
  cudaEvent_t ev[RING_IN];
  int pending[RING_IN];
  int next;
} ring;

/* Graphs the heuristics offered no engine for at all, so no later plan,
 * of any model in the process, asks again: refusing a fused data gradient
 * costs cuDNN's heuristics one to three seconds on sm_90. That is the op
 * pattern's doing, not the frame size's, so the key is the convolution's
 * geometry without batch, size or strides (dense copies would not help
 * either), for one device. */
typedef struct refusal {
  int device, bwd_data, fused, k, c, r, s, stride, relu;
  int pad_pre[2], pad_post[2];
} refusal;

#define MAX_REFUSALS 256
static refusal refusals[MAX_REFUSALS];
static int nrefusals;
static pthread_mutex_t refusals_lock = PTHREAD_MUTEX_INITIALIZER;

static refusal refusal_of(int device, const hf_cl_conv *cv, int fused) {
  refusal r;
  memset(&r, 0, sizeof r);   /* padding too: compared with memcmp */
  r.device = device;
  r.bwd_data = cv->bwd_data;
  r.fused = fused;
  r.k = cv->k;
  r.c = cv->c;
  r.r = cv->r;
  r.s = cv->s;
  r.stride = cv->stride;
  r.relu = cv->relu;
  memcpy(r.pad_pre, cv->pad_pre, sizeof r.pad_pre);
  memcpy(r.pad_post, cv->pad_post, sizeof r.pad_post);
  return r;
}

static int refused(const refusal *r) {
  int found = 0;
  pthread_mutex_lock(&refusals_lock);
  for (int i = 0; i < nrefusals && !found; i++) found = !memcmp(&refusals[i], r, sizeof *r);
  pthread_mutex_unlock(&refusals_lock);
  return found;
}

static void remember_refusal(const refusal *r) {
  pthread_mutex_lock(&refusals_lock);
  if (nrefusals < MAX_REFUSALS) refusals[nrefusals++] = *r;
  pthread_mutex_unlock(&refusals_lock);
}

typedef struct cudnn_model cudnn_model;
typedef cudaError_t (*output_stage_fn)(const cudnn_model *m, const plan *p, const slot *s);

struct cudnn_model {
  cudnn_dev *dev;
  int device;
  cudnn_opts opts;
  hf_net_config cfg;
  output_stage_fn output;
  const char *output_name;
  cudnnHandle_t dnn;
  cudaStream_t s_comp, s_h2d, s_d2h;
  hf_cl_layout wlo;             /* filter shapes (size-independent part) */
  void *d_w16, *d_b16, *d_b32;
  float *d_head;                /* HF_ARCH_KERNEL's head: FP32 weights, then bias */
  size_t weight_bytes;
  plan *plans[MAX_PLANS];
  uint64_t tick;
  slot slots[HF_MAX_PENDING];
  int head, npending;
  ring rin, rout;
  size_t io_bytes;              /* device bytes of the slots' tensors */
  pthread_mutex_t lock;
};

static int dmalloc(void **p, size_t bytes, size_t *acct) {
  int rc;
  *p = NULL;
  HF_CU_TRY(cudaMalloc(p, bytes ? bytes : 1));
  *acct += bytes;
  return HF_OK;
fail:
  /* The runtime keeps the failure as the thread's last error, which the
   * next launch's check (cudaGetLastError) would take for its own. */
  (void)cudaGetLastError();
  *p = NULL;
  return rc;
}

static void conv_run_free(conv_run *cr) {
  hf_cg_op_destroy(&cr->op);
  cudaFree(cr->scratch_in);
  cudaFree(cr->scratch_out);
  cr->scratch_in = cr->scratch_out = NULL;
}

static void step_free(step *st) {
  for (int c = 0; c < st->f.nconv; c++) conv_run_free(&st->cr[c]);
  cudaFree(st->scratch);
  memset(st, 0, sizeof *st);
}

static void plan_destroy(plan *p) {
  if (!p) return;
  if (p->gexec) cudaGraphExecDestroy(p->gexec);
  for (int j = 0; j < p->lo.nlayers; j++) step_free(&p->steps[j]);
  for (int b = 0; b < HF_CL_MAX_BUFS; b++) cudaFree(p->buf[b]);
  cudaFree(p->ws);
  free(p);
}

/* The device address of a view's first element; SCRATCH is the step's. */
static uint16_t *view_ptr(const plan *p, const step *st, const hf_cl_view *v) {
  uint16_t *base = v->buf == HF_CL_BUF_SCRATCH ? st->scratch : p->buf[v->buf];
  return base + hf_cl_view_offset(v);
}

static hf_cuk_view kview(void *base, const hf_cl_view *v) {
  int64_t s[4];
  hf_cl_view_strides(v, s);
  hf_cuk_view k = {base, s[0], s[2], s[3], v->c, v->h, v->w};
  return k;
}

static hf_cuk_view kview_dense(void *base, const hf_cl_view *v) {
  hf_cl_view d = hf_cl_view_packed(v->buf, v->c, v->h, v->w);
  return kview(base, &d);
}

static hf_cg_target target_of(const cudnn_model *m) {
  hf_cg_target t = {m->dnn, NULL, m->opts.candidates, m->opts.rtc};
  return t;
}

/* A dense FP16 tensor of v's shape for the plan's batch, owned by the step
 * (its bytes counted there), filled with random values: engines and forms
 * are timed on plausible values, and every element a run reads is written
 * by that run first. */
static int dense_tensor(cudnn_model *m, const plan *p, step *st, const hf_cl_view *v,
                        uint32_t seed, void **out) {
  int rc;
  size_t bytes;
  HF_TRY(hf_size_mul((size_t)p->batch * v->h * v->w, (size_t)v->c * 2, &bytes));
  HF_TRY(dmalloc(out, bytes, &st->bytes));
  HF_CU_TRY(hf_cuk_fill(*out, bytes / 2, seed, m->s_comp));
  return HF_OK;
fail:
  return rc;
}

/* Finds an engine for conv c of a step: fused on the real views, unfused on
 * them, then both again on dense copies (unless the views are dense, or
 * HF_CUDNN_DENSE asks for dense copies only). */
static int conv_build(cudnn_model *m, plan *p, int j, step *st, int c, char *why, size_t whylen) {
  conv_run *cr = &st->cr[c];
  cr->cv = st->f.conv[c];
  const int views_dense = hf_cl_view_dense(&cr->cv.x) && hf_cl_view_dense(&cr->cv.y);
  char name[48];
  snprintf(name, sizeof name, "%s/%s/%d", st->ly->name, hf_cl_form_name(st->f.form), c);
  const hf_cg_target t = target_of(m);
  int rc = HF_EUNSUPPORTED;
  for (int dense = m->opts.dense && !views_dense ? 1 : 0; dense <= 1; dense++) {
    if (dense && views_dense) break;
    for (int fused = m->opts.no_fusion ? 0 : 1; fused >= 0; fused--) {
      const refusal key = refusal_of(m->device, &cr->cv, fused);
      if (refused(&key)) continue;
      rc = hf_cg_op_build(&t, name, &cr->cv, p->batch, dense, fused, &cr->op, why, whylen);
      p->graphs++;
      p->graphs_ms += cr->op.build_ms;
      if (rc == HF_OK) break;
      if (rc != HF_EUNSUPPORTED) return rc;
      /* Remembered only when no engine config was offered at all (see
       * refusal): configs that failed to finalize may do better at another
       * size. */
      if (cr->op.heur_configs == 0) remember_refusal(&key);
    }
    if (rc != HF_OK) continue;
    cr->dense = dense;
    cr->x = view_ptr(p, st, &cr->cv.x);
    cr->y = view_ptr(p, st, &cr->cv.y);
    if (dense && !hf_cl_view_dense(&cr->cv.x)) {
      if ((rc = dense_tensor(m, p, st, &cr->cv.x, 0x5eed0200u + j, &cr->scratch_in))) return rc;
      cr->x = cr->scratch_in;
    }
    if (dense && !hf_cl_view_dense(&cr->cv.y)) {
      if ((rc = dense_tensor(m, p, st, &cr->cv.y, 0x5eed0300u + j, &cr->scratch_out))) return rc;
      cr->y = cr->scratch_out;
    }
    return HF_OK;
  }
  return rc;
}

/* Builds layer j in the given form: scratch, then every conv. */
static int step_build(cudnn_model *m, plan *p, int j, int form, step *st) {
  memset(st, 0, sizeof *st);
  st->ly = &p->lo.layers[j];
  int rc = hf_cl_layer_form(&p->lo, st->ly, form, &st->f);
  if (rc) return rc;
  if (st->f.d2s && (rc = dense_tensor(m, p, st, &st->f.scratch, 0x5eed0000u + j, &st->scratch)))
    goto fail;
  char why[512] = "";
  for (int c = 0; c < st->f.nconv; c++) {
    rc = conv_build(m, p, j, st, c, why, sizeof why);
    if (rc == HF_EUNSUPPORTED) {
      if (hf_cudnn_verbose())
        fprintf(stderr, "hfcore cudnn: %s: form %s: no engine for conv %d: %s\n", st->ly->name,
                hf_cl_form_name(form), c, why);
      goto fail;
    }
    if (rc) goto fail;
  }
  return HF_OK;
fail:
  step_free(st);
  return rc;
}

static int64_t step_workspace(const step *st) {
  int64_t ws = 0;
  for (int c = 0; c < st->f.nconv; c++) {
    int64_t w = hf_cg_op_max_workspace(&st->cr[c].op);
    if (w > ws) ws = w;
  }
  return ws;
}

static int step_bind(cudnn_model *m, plan *p, step *st) {
  for (int c = 0; c < st->f.nconv; c++) {
    conv_run *cr = &st->cr[c];
    int rc = hf_cg_op_bind(&cr->op, cr->x, (uint16_t *)m->d_w16 + cr->cv.w_off, cr->y,
                           cr->op.fused ? (uint16_t *)m->d_b16 + cr->cv.b_off : NULL, p->ws);
    if (rc) return rc;
  }
  return HF_OK;
}

/* Makes the plan's workspace at least bytes; every step bound so far is
 * bound again to the new one. */
static int ensure_workspace(cudnn_model *m, plan *p, size_t bytes, int bound_steps) {
  int rc;
  if (bytes <= p->ws_bytes && p->ws) return HF_OK;
  HF_CU_TRY(cudaStreamSynchronize(m->s_comp));
  if (p->ws) {
    cudaFree(p->ws);
    p->device_bytes -= p->ws_bytes;
    p->ws = NULL;
  }
  p->ws_bytes = 0;
  HF_TRY(dmalloc(&p->ws, bytes, &p->device_bytes));
  p->ws_bytes = bytes;
  for (int j = 0; j < bound_steps; j++) HF_TRY(step_bind(m, p, &p->steps[j]));
  return HF_OK;
fail:
  return rc;
}

/* Enqueues one layer on the compute stream. */
static int step_enqueue(cudnn_model *m, const plan *p, const step *st) {
  int rc;
  for (int c = 0; c < st->f.nconv; c++) {
    const conv_run *cr = &st->cr[c];
    const hf_cl_conv *cv = &cr->cv;
    if (cr->scratch_in)
      HF_CU_TRY(hf_cuk_copy(kview_dense(cr->scratch_in, &cv->x),
                            kview(view_ptr(p, st, &cv->x), &cv->x), p->batch, m->s_comp));
    HF_TRY(hf_cg_op_exec(m->dnn, &cr->op));
    if (!cr->op.fused) {
      hf_cuk_view y = cr->dense ? kview_dense(cr->y, &cv->y) : kview(cr->y, &cv->y);
      HF_CU_TRY(hf_cuk_bias_act(y, p->batch, (const float *)m->d_b32 + cv->b_off, cv->relu,
                                m->s_comp));
    }
    if (cr->scratch_out)
      HF_CU_TRY(hf_cuk_copy(kview(view_ptr(p, st, &cv->y), &cv->y),
                            kview_dense(cr->scratch_out, &cv->y), p->batch, m->s_comp));
  }
  if (st->f.d2s && !st->f.out_in_scratch)
    HF_CU_TRY(hf_cuk_depth_to_space(kview(view_ptr(p, st, &st->f.out), &st->f.out), st->scratch,
                                    p->batch, st->f.d2s == HF_CL_D2S_OFFSET, m->s_comp));
  return HF_OK;
fail:
  return rc;
}

static int forward_enqueue(cudnn_model *m, const plan *p) {
  for (int j = 0; j < p->lo.nlayers; j++) {
    int rc = step_enqueue(m, p, &p->steps[j]);
    if (rc) return rc;
  }
  return HF_OK;
}

/* Times a built step, TUNE_REPS runs after one untimed. A failing step
 * (an engine that fails at execute) is HF_EUNSUPPORTED, its CUDA error
 * cleared. */
static int step_time(cudnn_model *m, const plan *p, step *st, cudaEvent_t e0, cudaEvent_t e1) {
  int rc = step_enqueue(m, p, st);
  cudaError_t e = rc ? cudaSuccess : cudaEventRecord(e0, m->s_comp);
  for (int r = 0; !rc && e == cudaSuccess && r < TUNE_REPS; r++) rc = step_enqueue(m, p, st);
  if (!rc && e == cudaSuccess) e = cudaEventRecord(e1, m->s_comp);
  if (!rc && e == cudaSuccess) e = cudaEventSynchronize(e1);
  float ms = 0;
  if (!rc && e == cudaSuccess) e = cudaEventElapsedTime(&ms, e0, e1);
  if (!rc && e == cudaSuccess) {
    st->time_ms = ms / TUNE_REPS;
    return HF_OK;
  }
  fprintf(stderr, "hfcore cudnn: %s: form %s failed when run, skipped: %s\n", st->ly->name,
          hf_cl_form_name(st->f.form), e != cudaSuccess ? cudaGetErrorString(e)
                                                         : hf_cudnn_last_error());
  return hf_cg_clear_cuda_error(m->s_comp) ? HF_EBACKEND : HF_EUNSUPPORTED;
}

static void log_step(const cudnn_model *m, const plan *p, const step *st) {
  for (int c = 0; c < st->f.nconv; c++) {
    const conv_run *cr = &st->cr[c];
    char d[256];
    hf_cg_cand_describe(&cr->op.cand[0], d, sizeof d);
    fprintf(stderr,
            "hfcore cudnn: plan %s %dx%dx%d: %s: form %s, %.4f ms; conv %d: %s, %s, %s\n",
            m->cfg.name, p->batch, p->pw, p->ph, st->ly->name, hf_cl_form_name(st->f.form),
            st->time_ms, c, cr->op.fused ? "fused bias+act" : "bias kernel",
            cr->dense ? "dense copies" : "direct views", d);
  }
}

/* Builds layer j in each form allowed, tunes the engines of each, times
 * each whole, keeps the fastest. */
static int layer_choose(cudnn_model *m, plan *p, int j, cudaEvent_t e0, cudaEvent_t e1) {
  const hf_cl_layer *ly = &p->lo.layers[j];
  const unsigned forms = ly->dec ? m->opts.dec_forms : 1u << HF_CL_FORM_FWD;
  step best, cand;
  int have = 0, rc = HF_OK;
  memset(&best, 0, sizeof best);
  for (int form = 0; form < HF_CL_NFORMS; form++) {
    if (!(forms & 1u << form)) continue;
    rc = step_build(m, p, j, form, &cand);
    if (rc == HF_EUNSUPPORTED) continue;
    if (rc) goto fail;
    const double t0 = hf_now_us();
    if ((rc = ensure_workspace(m, p, (size_t)step_workspace(&cand), j)) ||
        (rc = step_bind(m, p, &cand)))
      goto fail_cand;
    for (int c = 0; c < cand.f.nconv && !rc; c++) {
      char name[48];
      snprintf(name, sizeof name, "%s/%s/%d", ly->name, hf_cl_form_name(form), c);
      rc = hf_cg_op_tune(m->dnn, &cand.cr[c].op, m->s_comp, name);
    }
    if (rc == HF_OK) rc = step_time(m, p, &cand, e0, e1);
    p->tune_ms += (hf_now_us() - t0) / 1e3;
    if (rc == HF_EBACKEND && !hf_cg_clear_cuda_error(m->s_comp)) rc = HF_EUNSUPPORTED;
    if (rc == HF_EUNSUPPORTED) {   /* no engine of this form runs: next form */
      step_free(&cand);
      continue;
    }
    if (rc) goto fail_cand;
    if (hf_cudnn_verbose())
      fprintf(stderr, "hfcore cudnn: %s: form %s: %.4f ms\n", ly->name, hf_cl_form_name(form),
              cand.time_ms);
    if (!have || cand.time_ms < best.time_ms) {
      if (have) step_free(&best);
      best = cand;
      have = 1;
    } else {
      step_free(&cand);
    }
  }
  if (!have)
    return hf_cudnn_report(HF_EBACKEND, "%s: no form of this layer has a cuDNN engine that runs"
                           " (%s)", ly->name, hf_cudnn_last_error());
  p->steps[j] = best;
  p->device_bytes += best.bytes;
  return HF_OK;
fail_cand:
  step_free(&cand);
fail:
  if (have) step_free(&best);
  return rc;
}

/* Records the forward pass into a CUDA graph. Any failure leaves the plan
 * running eagerly, which is slower but equally correct. */
static void plan_capture(cudnn_model *m, plan *p) {
  cudaGraph_t g = NULL;
  cudaError_t e = cudaStreamBeginCapture(m->s_comp, cudaStreamCaptureModeThreadLocal);
  if (e != cudaSuccess) goto fail;
  int rc = forward_enqueue(m, p);
  e = cudaStreamEndCapture(m->s_comp, &g);
  if (rc || e != cudaSuccess || !g) goto fail;
  e = cudaGraphInstantiate(&p->gexec, g, 0);
  if (e != cudaSuccess) {
    p->gexec = NULL;
    goto fail;
  }
  cudaGraphDestroy(g);
  g = NULL;
  /* Replay once now so a graph that cannot run is found at plan time. */
  if ((e = cudaGraphLaunch(p->gexec, m->s_comp)) == cudaSuccess &&
      (e = cudaStreamSynchronize(m->s_comp)) == cudaSuccess)
    return;
fail:
  fprintf(stderr, "hfcore cudnn: CUDA graph capture failed (%s); running layers eagerly\n",
          e != cudaSuccess ? cudaGetErrorString(e) : hf_cudnn_last_error());
  if (g) cudaGraphDestroy(g);
  if (p->gexec) cudaGraphExecDestroy(p->gexec);
  p->gexec = NULL;
  cudaGetLastError();
}

static int plan_create(cudnn_model *m, int batch, int pw, int ph, plan **out) {
  int rc;
  cudaEvent_t e0 = NULL, e1 = NULL;
  const double t0 = hf_now_us();
  plan *p = calloc(1, sizeof *p);
  if (!p) return HF_ENOMEM;
  p->batch = batch;
  p->pw = pw;
  p->ph = ph;
  HF_TRY(hf_cl_layout_init(&m->cfg, batch, pw, ph, &p->lo));
  HF_CU_TRY(cudaEventCreate(&e0));
  HF_CU_TRY(cudaEventCreate(&e1));

  for (int b = 0; b < p->lo.nbufs; b++) {
    size_t bytes;
    HF_TRY(hf_size_mul(p->lo.buf_elems[b], 2, &bytes));
    HF_TRY(dmalloc(&p->buf[b], bytes, &p->device_bytes));
    /* Engines and forms are timed on plausible values, not zeros; every
     * element a run reads is written by that run first. */
    HF_CU_TRY(hf_cuk_fill(p->buf[b], p->lo.buf_elems[b], 0x5eed0100u + b, m->s_comp));
  }
  for (int j = 0; j < p->lo.nlayers; j++) HF_TRY(layer_choose(m, p, j, e0, e1));
  /* The workspace may have grown after the first layers were bound. */
  for (int j = 0; j < p->lo.nlayers; j++) HF_TRY(step_bind(m, p, &p->steps[j]));
  /* One eager pass end to end, then the graph. */
  HF_TRY(forward_enqueue(m, p));
  HF_CU_TRY(cudaStreamSynchronize(m->s_comp));
  if (!m->opts.no_graph) plan_capture(m, p);
  p->build_ms = (hf_now_us() - t0) / 1e3;
  if (hf_cudnn_verbose()) {
    for (int j = 0; j < p->lo.nlayers; j++) log_step(m, p, &p->steps[j]);
    fprintf(stderr,
            "hfcore cudnn: plan %s %dx%dx%d: built in %.1f ms (%d cuDNN graphs %.1f ms, tuning "
            "%.1f ms), %zu device bytes, workspace %zu, %s\n",
            m->cfg.name, batch, pw, ph, p->build_ms, p->graphs, p->graphs_ms, p->tune_ms,
            p->device_bytes, p->ws_bytes, p->gexec ? "CUDA graph" : "eager");
  }
  cudaEventDestroy(e0);
  cudaEventDestroy(e1);
  *out = p;
  return HF_OK;
fail:
  if (e0) cudaEventDestroy(e0);
  if (e1) cudaEventDestroy(e1);
  cudaStreamSynchronize(m->s_comp);
  plan_destroy(p);
  return rc;
}

/* The plan for a shape, made on first use. Plans made by prepare stay;
 * of the others at most opts.plans are kept, the least recently used one
 * making room (never one a pending run still uses). */
static int plan_get(cudnn_model *m, int batch, int pw, int ph, int pin, plan **out) {
  int free_slot = -1, lru = -1, cached = 0;
  for (int i = 0; i < MAX_PLANS; i++) {
    plan *p = m->plans[i];
    if (!p) {
      if (free_slot < 0) free_slot = i;
      continue;
    }
    if (p->batch == batch && p->pw == pw && p->ph == ph) {
      p->last_used = ++m->tick;
      p->pinned |= pin;
      *out = p;
      return HF_OK;
    }
    if (p->pinned) continue;
    cached++;
    if (!p->inflight && (lru < 0 || p->last_used < m->plans[lru]->last_used)) lru = i;
  }
  if ((cached >= m->opts.plans || free_slot < 0) && lru >= 0) {
    if (hf_cudnn_verbose())
      fprintf(stderr, "hfcore cudnn: plan %dx%dx%d evicted\n", m->plans[lru]->batch,
              m->plans[lru]->pw, m->plans[lru]->ph);
    plan_destroy(m->plans[lru]);
    m->plans[lru] = NULL;
    if (free_slot < 0) free_slot = lru;
  }
  if (free_slot < 0)
    return hf_cudnn_report(HF_ERANGE, "%d plans prepared or in use: no room for %dx%dx%d",
                           MAX_PLANS, batch, pw, ph);
  plan *p = NULL;
  int rc = plan_create(m, batch, pw, ph, &p);
  if (rc) return rc;
  p->pinned = pin;
  p->last_used = ++m->tick;
  m->plans[free_slot] = p;
  *out = p;
  return HF_OK;
}

/* ---- output stages: one per architecture ---------------------------------- */

static hf_cuk_raw raw_output(const plan *p) {
  const step *dec0 = &p->steps[p->lo.nlayers - 1];
  hf_cuk_raw r;
  r.at = hf_cl_raw_output(&dec0->f);
  r.data = r.at.buf == HF_CL_BUF_SCRATCH ? dec0->scratch : p->buf[r.at.buf];
  return r;
}

static cudaError_t output_unet(const cudnn_model *m, const plan *p, const slot *s) {
  return hf_cuk_output_unet(raw_output(p), s->io.batch, s->io.width, s->io.height, s->d_out,
                            s->io.out_dtype == HF_F16, m->s_comp);
}

static cudaError_t output_residual(const cudnn_model *m, const plan *p, const slot *s) {
  return hf_cuk_output_residual(raw_output(p), p->buf[HF_CL_BUF_IN], p->lo.cin_pad, p->pw,
                                p->ph, m->cfg.spp, s->io.batch, s->io.width, s->io.height,
                                s->d_out, s->io.out_dtype == HF_F16, m->s_comp);
}

static cudaError_t output_kernel(const cudnn_model *m, const plan *p, const slot *s) {
  const hf_net_config *c = &m->cfg;
  hf_cuk_head head = {NULL, NULL, c->kernel_hidden, c->in_channels};
  if (m->d_head) {
    head.w = m->d_head;
    head.b = m->d_head + (size_t)c->out_channels * hf_head_in(c);
  }
  return hf_cuk_output_kernel(raw_output(p), head, p->buf[HF_CL_BUF_IN], p->lo.cin_pad, p->pw,
                              p->ph, c->spp, hf_kernel_sums_of(c), c->kernel_radius, s->io.batch,
                              s->io.width,
                              s->io.height, s->d_out, s->io.out_dtype == HF_F16, m->s_comp);
}

static const struct {
  int arch;
  const char *name;
  output_stage_fn fn;
} output_stages[] = {
  {HF_ARCH_UNET, "unet transforms", output_unet},
  {HF_ARCH_RESIDUAL, "residual base", output_residual},
  {HF_ARCH_KERNEL, "kernel taps", output_kernel},
};

/* ---- model --------------------------------------------------------------- */

static void ring_free(ring *r) {
  for (int i = 0; i < r->n; i++) {
    if (r->ev[i]) cudaEventDestroy(r->ev[i]);
    cudaFreeHost(r->buf[i]);
  }
  memset(r, 0, sizeof *r);
}

static int ring_init(ring *r, int n, size_t bytes) {
  int rc;
  memset(r, 0, sizeof *r);
  r->n = n;
  for (int i = 0; i < n; i++) {
    HF_CU_TRY(cudaHostAlloc(&r->buf[i], bytes, cudaHostAllocDefault));
    HF_CU_TRY(cudaEventCreateWithFlags(&r->ev[i], cudaEventDisableTiming));
  }
  return HF_OK;
fail:
  return rc;
}

static void cudnn_model_destroy(void *impl) {
  cudnn_model *m = impl;
  if (!m) return;
  cudaSetDevice(m->device);
  if (m->s_comp) cudaStreamSynchronize(m->s_comp);
  if (m->s_h2d) cudaStreamSynchronize(m->s_h2d);
  if (m->s_d2h) cudaStreamSynchronize(m->s_d2h);
  for (int i = 0; i < MAX_PLANS; i++) plan_destroy(m->plans[i]);
  for (int i = 0; i < HF_MAX_PENDING; i++) {
    slot *s = &m->slots[i];
    cudaFree(s->d_in);
    cudaFree(s->d_out);
    cudaFree(s->d_counts);
    cudaFreeHost(s->h_counts);
    for (int k = 0; k < EV_COUNT; k++)
      if (s->ev[k]) cudaEventDestroy(s->ev[k]);
  }
  ring_free(&m->rin);
  ring_free(&m->rout);
  cudaFree(m->d_w16);
  cudaFree(m->d_b16);
  cudaFree(m->d_b32);
  cudaFree(m->d_head);
  if (m->dnn) cudnnDestroy(m->dnn);
  if (m->s_comp) cudaStreamDestroy(m->s_comp);
  if (m->s_h2d) cudaStreamDestroy(m->s_h2d);
  if (m->s_d2h) cudaStreamDestroy(m->s_d2h);
  pthread_mutex_destroy(&m->lock);
  free(m);
}

static int cudnn_model_create(void *dev, const hf_weights *w, void **out) {
  cudnn_dev *d = dev;
  int rc;
  uint16_t *w16 = NULL, *b16 = NULL;
  float *b32 = NULL;
  cudnn_model *m = calloc(1, sizeof *m);
  if (!m) return HF_ENOMEM;
  if (pthread_mutex_init(&m->lock, NULL)) {
    free(m);
    return HF_ENOMEM;
  }
  m->dev = d;
  m->device = d->device;
  m->cfg = w->cfg;
  HF_TRY(read_opts(&m->opts));
  for (size_t i = 0; i < sizeof output_stages / sizeof output_stages[0]; i++)
    if (output_stages[i].arch == m->cfg.arch) {
      m->output = output_stages[i].fn;
      m->output_name = output_stages[i].name;
    }
  if (!m->output) {
    rc = hf_cudnn_report(HF_EUNSUPPORTED, "architecture %s has no output stage on the GPU",
                         hf_arch_name(m->cfg.arch));
    goto fail;
  }
  HF_CU_TRY(cudaSetDevice(m->device));
  HF_CU_TRY(cudaStreamCreateWithFlags(&m->s_comp, cudaStreamNonBlocking));
  HF_CU_TRY(cudaStreamCreateWithFlags(&m->s_h2d, cudaStreamNonBlocking));
  HF_CU_TRY(cudaStreamCreateWithFlags(&m->s_d2h, cudaStreamNonBlocking));
  for (int i = 0; i < HF_MAX_PENDING; i++)
    for (int k = 0; k < EV_COUNT; k++) HF_CU_TRY(cudaEventCreate(&m->slots[i].ev[k]));
  HF_DNN_TRY(cudnnCreate(&m->dnn));
  HF_DNN_TRY(cudnnSetStream(m->dnn, m->s_comp));
  HF_TRY(ring_init(&m->rin, RING_IN, m->opts.stage_bytes));
  HF_TRY(ring_init(&m->rout, RING_OUT, m->opts.stage_bytes));

  /* Filter shapes do not depend on the frame size: lay out the smallest. */
  const int a = hf_net_align(&m->cfg);
  HF_TRY(hf_cl_layout_init(&m->cfg, 1, a, a, &m->wlo));
  w16 = malloc(m->wlo.w_elems * sizeof *w16);
  b16 = malloc(m->wlo.b_elems * sizeof *b16);
  b32 = malloc(m->wlo.b_elems * sizeof *b32);
  if (!w16 || !b16 || !b32) {
    rc = HF_ENOMEM;
    goto fail;
  }
  HF_TRY(hf_cl_pack_weights(&m->wlo, w, w16, b16, b32));
  HF_TRY(dmalloc(&m->d_w16, m->wlo.w_elems * sizeof *w16, &m->weight_bytes));
  HF_TRY(dmalloc(&m->d_b16, m->wlo.b_elems * sizeof *b16, &m->weight_bytes));
  HF_TRY(dmalloc(&m->d_b32, m->wlo.b_elems * sizeof *b32, &m->weight_bytes));
  /* Synchronous copies: the host arrays are freed right after. */
  HF_CU_TRY(cudaMemcpy(m->d_w16, w16, m->wlo.w_elems * sizeof *w16, cudaMemcpyHostToDevice));
  HF_CU_TRY(cudaMemcpy(m->d_b16, b16, m->wlo.b_elems * sizeof *b16, cudaMemcpyHostToDevice));
  HF_CU_TRY(cudaMemcpy(m->d_b32, b32, m->wlo.b_elems * sizeof *b32, cudaMemcpyHostToDevice));
  free(w16);
  free(b16);
  free(b32);
  w16 = b16 = NULL;
  b32 = NULL;
  if (hf_head_in(&m->cfg)) {
    /* The head as it is: the output stage reads it in FP32 (2 KiB to 54 KiB). */
    const size_t nw = (size_t)m->cfg.out_channels * hf_head_in(&m->cfg);
    const size_t bytes = (nw + m->cfg.out_channels) * sizeof(float);
    HF_TRY(dmalloc((void **)&m->d_head, bytes, &m->weight_bytes));
    HF_CU_TRY(cudaMemcpy(m->d_head, w->head_w, nw * sizeof(float), cudaMemcpyHostToDevice));
    HF_CU_TRY(cudaMemcpy(m->d_head + nw, w->head_b, m->cfg.out_channels * sizeof(float),
                         cudaMemcpyHostToDevice));
  }
  if (hf_cudnn_verbose())
    fprintf(stderr, "hfcore cudnn: model %s: output stage %s, %zu weight bytes\n", m->cfg.name,
            m->output_name, m->weight_bytes);
  *out = m;
  return HF_OK;
fail:
  free(w16);
  free(b16);
  free(b32);
  cudnn_model_destroy(m);
  return rc;
}

static int cudnn_model_prepare(void *impl, int batch, int width, int height) {
  cudnn_model *m = impl;
  const int a = hf_net_align(&m->cfg);
  plan *p;
  pthread_mutex_lock(&m->lock);
  int rc = cudaSetDevice(m->device) == cudaSuccess ? HF_OK : HF_EBACKEND;
  if (!rc) rc = plan_get(m, batch, hf_round_up(width, a), hf_round_up(height, a), 1, &p);
  pthread_mutex_unlock(&m->lock);
  return rc;
}

/* ---- requests ------------------------------------------------------------- */

static int grow(void **p, size_t *cap, size_t need, size_t *acct) {
  if (*cap >= need) return HF_OK;
  if (*p) {
    cudaFree(*p);
    *acct -= *cap;
  }
  *cap = 0;
  int rc = dmalloc(p, need, acct);
  if (rc == HF_OK) *cap = need;
  return rc;
}

/* Uploads the request's input: DMA from registered memory, else through the
 * pinned ring, FP32 converted to FP16 on the host as it goes. */
static int upload(cudnn_model *m, slot *s) {
  int rc;
  const hf_io *io = &s->io;
  const size_t n = (size_t)io->batch * io->width * io->height * m->cfg.in_channels;
  const size_t es = io->in_dtype == HF_F16 ? 2 : 4;
  /* A frame checked on the device goes up as it came (model_submit_scan
   * found it registered; were it unregistered since, the copy from pageable
   * memory is slower, not wrong). */
  const int direct = s->scan || is_registered(m->dev, io->in, n * es);
  s->in_f16 = direct ? io->in_dtype == HF_F16 : 1;
  s->in_bytes = n * (s->in_f16 ? 2 : 4);
  HF_TRY(grow(&s->d_in, &s->d_in_cap, s->in_bytes, &m->io_bytes));
  /* The last input kernel that read this slot's tensor must be done. */
  if (s->used) HF_CU_TRY(cudaStreamWaitEvent(m->s_h2d, s->ev[EV_CONSUMED], 0));
  HF_CU_TRY(cudaEventRecord(s->ev[EV_IN0], m->s_h2d));
  const double t0 = hf_now_us();
  if (direct) {
    HF_CU_TRY(cudaMemcpyAsync(s->d_in, io->in, s->in_bytes, cudaMemcpyHostToDevice, m->s_h2d));
  } else {
    ring *r = &m->rin;
    const size_t chunk = m->opts.stage_bytes / 2;   /* FP16 elements per chunk */
    for (size_t off = 0; off < n; off += chunk) {
      const size_t len = n - off < chunk ? n - off : chunk;
      const int k = r->next;
      r->next = (k + 1) % r->n;
      if (r->pending[k]) HF_CU_TRY(cudaEventSynchronize(r->ev[k]));
      r->pending[k] = 0;
      if (io->in_dtype == HF_F16)
        memcpy(r->buf[k], (const uint16_t *)io->in + off, len * 2);
      else
        hf_f32_to_f16_array((const float *)io->in + off, r->buf[k], len);
      HF_CU_TRY(cudaMemcpyAsync((uint16_t *)s->d_in + off, r->buf[k], len * 2,
                                cudaMemcpyHostToDevice, m->s_h2d));
      HF_CU_TRY(cudaEventRecord(r->ev[k], m->s_h2d));
      r->pending[k] = 1;
    }
  }
  s->host_in_us = hf_now_us() - t0;
  HF_CU_TRY(cudaEventRecord(s->ev[EV_IN1], m->s_h2d));
  return HF_OK;
fail:
  return rc;
}

/* Input kernel, network, output stage, on the compute stream. */
static int compute(cudnn_model *m, slot *s) {
  int rc;
  const plan *p = s->p;
  const hf_io *io = &s->io;
  HF_CU_TRY(cudaStreamWaitEvent(m->s_comp, s->ev[EV_IN1], 0));
  HF_CU_TRY(cudaEventRecord(s->ev[EV_C0], m->s_comp));
  if (s->scan) {
    /* The check on the frames as uploaded, fixed in place before the input
     * kernel reads them; the counts come back beside the network's work. */
    HF_CU_TRY(hf_cuk_scan(s->d_in, s->in_f16, io->batch, (long long)io->width * io->height,
                          m->cfg.spp, s->d_counts, m->s_comp));
  }
  HF_CU_TRY(hf_cuk_input(s->d_in, s->in_f16, io->batch, io->width, io->height,
                         m->cfg.in_channels, p->buf[HF_CL_BUF_IN], p->pw, p->ph, p->lo.cin_pad,
                         m->s_comp));
  HF_CU_TRY(cudaEventRecord(s->ev[EV_CONSUMED], m->s_comp));
  HF_CU_TRY(cudaEventRecord(s->ev[EV_C1], m->s_comp));
  if (p->gexec)
    HF_CU_TRY(cudaGraphLaunch(p->gexec, m->s_comp));
  else
    HF_TRY(forward_enqueue(m, p));
  HF_CU_TRY(cudaEventRecord(s->ev[EV_C2], m->s_comp));
  /* The slot's output tensor must have been downloaded from last time. */
  if (s->used) HF_CU_TRY(cudaStreamWaitEvent(m->s_comp, s->ev[EV_O1], 0));
  HF_CU_TRY(m->output(m, p, s));
  if (s->scan) {
    /* The output guard here too, so the host reads neither the frame nor
     * the result; the counts come back with it. */
    HF_CU_TRY(hf_cuk_guard(s->d_out, io->out_dtype == HF_F16, io->batch,
                           (long long)io->width * io->height, s->d_counts, m->s_comp));
    HF_CU_TRY(cudaMemcpyAsync(s->h_counts, s->d_counts, sizeof *s->h_counts * io->batch,
                              cudaMemcpyDeviceToHost, m->s_comp));
  }
  HF_CU_TRY(cudaEventRecord(s->ev[EV_C3], m->s_comp));
  return HF_OK;
fail:
  return rc;
}

/* Downloads the result: DMA into registered memory (enqueued at submit),
 * else through the pinned ring, each chunk copied out as it lands (at
 * wait). */
static int download(cudnn_model *m, slot *s, int at_wait) {
  int rc;
  if (!at_wait) {
    s->out_staged = !is_registered(m->dev, s->io.out, s->out_bytes);
    if (s->out_staged) return HF_OK;
  } else if (!s->out_staged) {
    return HF_OK;
  }
  HF_CU_TRY(cudaStreamWaitEvent(m->s_d2h, s->ev[EV_C3], 0));
  HF_CU_TRY(cudaEventRecord(s->ev[EV_O0], m->s_d2h));
  const double t0 = hf_now_us();
  if (!s->out_staged) {
    HF_CU_TRY(cudaMemcpyAsync(s->io.out, s->d_out, s->out_bytes, cudaMemcpyDeviceToHost,
                              m->s_d2h));
  } else {
    ring *r = &m->rout;
    const size_t chunk = m->opts.stage_bytes, total = s->out_bytes;
    const size_t nchunks = (total + chunk - 1) / chunk;
    size_t issued = 0, done = 0;
    while (done < nchunks) {
      while (issued < nchunks && issued - done < (size_t)r->n) {
        const int k = (int)(issued % (size_t)r->n);
        const size_t off = issued * chunk, len = total - off < chunk ? total - off : chunk;
        HF_CU_TRY(cudaMemcpyAsync(r->buf[k], (uint8_t *)s->d_out + off, len,
                                  cudaMemcpyDeviceToHost, m->s_d2h));
        HF_CU_TRY(cudaEventRecord(r->ev[k], m->s_d2h));
        issued++;
      }
      const int k = (int)(done % (size_t)r->n);
      const size_t off = done * chunk, len = total - off < chunk ? total - off : chunk;
      HF_CU_TRY(cudaEventSynchronize(r->ev[k]));
      memcpy((uint8_t *)s->io.out + off, r->buf[k], len);
      done++;
    }
  }
  HF_CU_TRY(cudaEventRecord(s->ev[EV_O1], m->s_d2h));
  s->host_out_us = at_wait ? hf_now_us() - t0 : 0;
  return HF_OK;
fail:
  return rc;
}

/* Makes s hold the input check's counts of batch frames, on the device
 * (grow) and in pinned host memory. */
static int counts_grow(cudnn_model *m, slot *s, int batch) {
  int rc;
  const size_t bytes = sizeof(hf_cuk_scan_counts) * (size_t)batch;
  if (s->h_counts_cap >= bytes && s->d_counts_cap >= bytes) return HF_OK;
  HF_TRY(grow((void **)&s->d_counts, &s->d_counts_cap, bytes, &m->io_bytes));
  cudaFreeHost(s->h_counts);
  s->h_counts = NULL, s->h_counts_cap = 0;
  HF_CU_TRY(cudaHostAlloc((void **)&s->h_counts, bytes, cudaHostAllocDefault));
  s->h_counts_cap = bytes;
  return HF_OK;
fail:
  (void)cudaGetLastError();   /* as in dmalloc */
  s->h_counts = NULL;
  return rc;
}

/* The check's counts of s's frames as the reports and statistics
 * hf_features_scan would have made of them, with the output guard's counts
 * (model_submit_scan). */
static void scan_results(const cudnn_model *m, const slot *s) {
  const hf_io *io = &s->io;
  const size_t frame = (size_t)io->width * io->height * m->cfg.in_channels *
                       (io->in_dtype == HF_F16 ? 2 : 4);
  for (int n = 0; n < io->batch; n++) {
    const hf_cuk_scan_counts *c = &s->h_counts[n];
    hf_features_report_counted((const uint8_t *)io->in + frame * n, io->in_dtype, io->width,
                               m->cfg.spp, c->bad, (size_t)~c->first_bad_inv, &s->rep[n]);
    s->rep[n].outputs = c->outputs;
    if (s->stats) {
      hf_input_stats_acc acc;
      memcpy(&acc, c, sizeof acc);
      hf_input_stats_finish(&acc, io->width, io->height, m->cfg.spp, &s->stats[n]);
    }
  }
}

/* The counts' first fields are hf_input_stats_acc, copied as they are. */
_Static_assert(offsetof(hf_cuk_scan_counts, hair) == offsetof(hf_input_stats_acc, hair) &&
                   offsetof(hf_cuk_scan_counts, full) == offsetof(hf_input_stats_acc, full) &&
                   offsetof(hf_cuk_scan_counts, hist) == offsetof(hf_input_stats_acc, hist) &&
                   sizeof(unsigned long long) == sizeof(uint64_t),
               "hf_cuk_scan_counts begins as hf_input_stats_acc");

/* scan: check the input on the device (rep and stats filled at the wait),
 * which only an upload of the frames as they came allows. */
static int submit_locked(cudnn_model *m, const hf_io *io, hf_input_report *rep,
                         hf_input_stats *stats) {
  int rc;
  if (m->npending == HF_MAX_PENDING) return HF_ERANGE;
  slot *s = &m->slots[(m->head + m->npending) % HF_MAX_PENDING];
  HF_CU_TRY(cudaSetDevice(m->device));
  const int a = hf_net_align(&m->cfg);
  plan *p;
  HF_TRY(plan_get(m, io->batch, hf_round_up(io->width, a), hf_round_up(io->height, a), 0, &p));
  s->p = p;
  s->io = *io;
  s->rc = HF_OK;
  s->scan = rep != NULL;
  s->rep = rep;
  s->stats = stats;
  /* Without room for the counts the frame fails (nothing is pending yet)
   * rather than going to the host's check: that path reads the input
   * twice, and a caller told it is read once (hf_model_reads_input_once)
   * may have handed memory another process writes. */
  if (s->scan && (rc = counts_grow(m, s, io->batch)) != HF_OK) return rc;
  s->host_in_us = s->host_out_us = 0;
  const size_t pix = (size_t)io->batch * io->width * io->height;
  s->out_bytes = pix * HF_OUT_CHANNELS * (io->out_dtype == HF_F16 ? 2 : 4);
  HF_TRY(grow(&s->d_out, &s->d_out_cap, s->out_bytes, &m->io_bytes));
  /* From here on the slot is pending: a failure is the wait's to report,
   * after the streams are drained. */
  p->inflight++;
  s->busy = 1;
  m->npending++;
  if ((rc = upload(m, s)) || (rc = compute(m, s)) || (rc = download(m, s, 0))) s->rc = rc;
  s->used = !s->rc;
  return HF_OK;
fail:
  return rc;
}

static int elapsed_us(cudaEvent_t a, cudaEvent_t b, double *us) {
  float ms = 0;
  cudaError_t e = cudaEventElapsedTime(&ms, a, b);
  if (e != cudaSuccess) return hf_cu_report(e, "cudaEventElapsedTime", __FILE__, __LINE__);
  *us = ms * 1000.0;
  return HF_OK;
}

static int wait_locked(cudnn_model *m, hf_timing *t) {
  int rc;
  if (!m->npending) return HF_EINVAL;
  slot *s = &m->slots[m->head];
  m->head = (m->head + 1) % HF_MAX_PENDING;
  m->npending--;
  s->busy = 0;
  s->p->inflight--;
  HF_CU_TRY(cudaSetDevice(m->device));
  if (s->rc) {
    rc = s->rc;
    goto fail;
  }
  HF_TRY(download(m, s, 1));
  HF_CU_TRY(cudaEventSynchronize(s->ev[EV_O1]));
  if (s->scan) scan_results(m, s);
  double dma_in = 0, kin = 0, net = 0, out = 0, dma_out = 0;
  HF_TRY(elapsed_us(s->ev[EV_IN0], s->ev[EV_IN1], &dma_in));
  HF_TRY(elapsed_us(s->ev[EV_C0], s->ev[EV_C1], &kin));
  HF_TRY(elapsed_us(s->ev[EV_C1], s->ev[EV_C2], &net));
  HF_TRY(elapsed_us(s->ev[EV_C2], s->ev[EV_C3], &out));
  HF_TRY(elapsed_us(s->ev[EV_O0], s->ev[EV_O1], &dma_out));
  /* Staging overlaps the upload: the longer of the two is the input's. */
  t->input_us = (s->host_in_us > dma_in ? s->host_in_us : dma_in) + kin;
  t->infer_us = net;
  t->output_us = out + (s->host_out_us > dma_out ? s->host_out_us : dma_out);
  return HF_OK;
fail:
  /* Leave no half-finished work behind for the next request. */
  cudaStreamSynchronize(m->s_h2d);
  cudaStreamSynchronize(m->s_comp);
  cudaStreamSynchronize(m->s_d2h);
  hf_cg_clear_cuda_error(m->s_comp);
  s->used = 0;
  return rc;
}

static int cudnn_model_submit(void *impl, const hf_io *io) {
  cudnn_model *m = impl;
  pthread_mutex_lock(&m->lock);
  int rc = submit_locked(m, io, NULL, NULL);
  pthread_mutex_unlock(&m->lock);
  return rc;
}

/* The check on the device needs the frames uploaded as they came: from
 * registered memory (a shared-memory segment, a pinned buffer), by DMA.
 * Through the staging ring an FP32 frame is narrowed to FP16 on the host,
 * which changes what the rule sees (70000 is "clamped" as a float and
 * infinite as a half), so those frames are checked on the host first. */
static int cudnn_model_submit_scan(void *impl, const hf_io *io, hf_input_report *rep,
                                   hf_input_stats *stats) {
  cudnn_model *m = impl;
  if (!rep || m->cfg.estimate || m->opts.host_check) return HF_RUN_DECLINED;
  const size_t bytes = (size_t)io->batch * io->width * io->height * m->cfg.in_channels *
                       (io->in_dtype == HF_F16 ? 2 : 4);
  pthread_mutex_lock(&m->lock);
  int rc = is_registered(m->dev, io->in, bytes) ? submit_locked(m, io, rep, stats)
                                                : HF_RUN_DECLINED;
  pthread_mutex_unlock(&m->lock);
  return rc;
}

/* A frame that model_submit_scan takes is read once: uploaded by DMA as it
 * came, then checked and run on the device. */
static int cudnn_model_reads_input_once(void *impl, const void *in, size_t bytes) {
  cudnn_model *m = impl;
  return !m->cfg.estimate && !m->opts.host_check && is_registered(m->dev, in, bytes);
}

static int cudnn_model_wait(void *impl, hf_timing *t) {
  cudnn_model *m = impl;
  pthread_mutex_lock(&m->lock);
  int rc = wait_locked(m, t);
  pthread_mutex_unlock(&m->lock);
  return rc;
}

static int cudnn_model_run(void *impl, const hf_io *io, hf_timing *t) {
  cudnn_model *m = impl;
  pthread_mutex_lock(&m->lock);
  int rc = submit_locked(m, io, NULL, NULL);
  if (rc == HF_OK) rc = wait_locked(m, t);
  pthread_mutex_unlock(&m->lock);
  return rc;
}

static const char *cudnn_model_precision(void *impl) {
  (void)impl;
  return "fp16";
}

static size_t cudnn_model_device_bytes(void *impl) {
  cudnn_model *m = impl;
  pthread_mutex_lock(&m->lock);
  size_t n = m->weight_bytes + m->io_bytes;
  for (int i = 0; i < MAX_PLANS; i++)
    if (m->plans[i]) n += m->plans[i]->device_bytes;
  pthread_mutex_unlock(&m->lock);
  return n;
}

/* Host memory a run takes beyond the model: none. Frames go to the device
 * by DMA from registered memory or through the model's fixed ring of pinned
 * chunks, made with the model; plans are device memory, reported by
 * model_device_bytes and bounded by the GPU, not by a host budget. A page
 * stands for the bookkeeping. Nothing is kept on the host per size, so
 * there is no model_cached_bytes or model_trim. */
static size_t cudnn_run_bytes(const hf_net_config *c, int batch, int pw, int ph) {
  (void)c, (void)batch, (void)pw, (void)ph;
  return 4096;
}

const hf_backend_ops hf_backend_cudnn = {
  .name = "cudnn",
  .priority = 100,
  .reads_f16 = 1,
  .archs = 1u << HF_ARCH_UNET | 1u << HF_ARCH_RESIDUAL | 1u << HF_ARCH_KERNEL,
  .probe = cudnn_probe,
  .open = cudnn_open,
  .close = cudnn_close,
  .model_create = cudnn_model_create,
  .model_destroy = cudnn_model_destroy,
  .model_run = cudnn_model_run,
  .model_precision = cudnn_model_precision,
  .model_device_bytes = cudnn_model_device_bytes,
  .model_prepare = cudnn_model_prepare,
  .model_submit = cudnn_model_submit,
  .model_wait = cudnn_model_wait,
  .model_submit_scan = cudnn_model_submit_scan,
  .model_reads_input_once = cudnn_model_reads_input_once,
  .host_register = cudnn_host_register,
  .host_unregister = cudnn_host_unregister,
  .run_bytes = cudnn_run_bytes,
};
