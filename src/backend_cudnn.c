/*
 * The cudnn backend: the network on an NVIDIA GPU in FP16 NHWC with FP32
 * accumulation, through cuDNN 9's graph API.
 *
 * A model holds the packed weights on the device, its own cuDNN handle and
 * stream (so two models never share a stream), and a small cache of plans,
 * one per (batch, padded width, padded height). A plan is everything a
 * request of that shape needs, made once: activation buffers laid out by
 * cudnn_layout.h, one execution plan per layer chosen by timing the
 * heuristics' candidates, one workspace, pinned host staging buffers, and a
 * CUDA graph of the whole forward pass. A request then costs two host
 * copies into and out of pinned memory, two async transfers, two small
 * kernels and one graph launch; nothing is allocated.
 *
 * Environment (for diagnosis): HF_CUDNN_VERBOSE=1 logs plan choices,
 * HF_CUDNN_NO_GRAPH=1 runs the layers eagerly instead of replaying the CUDA
 * graph, HF_CUDNN_NO_FUSION=1 skips the fused bias+ReLU graphs,
 * HF_CUDNN_DECONV=shuffle computes transposed convs as conv + pixel shuffle
 * instead of cuDNN's data gradient, HF_CUDA_DEVICE picks the device
 * (default 0).
 */
#include <pthread.h>
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

#define MAX_PLANS 4

static int env_flag(const char *name) {
  const char *v = getenv(name);
  return v && v[0] && strcmp(v, "0") != 0;
}

static int env_deconv(void) {
  const char *v = getenv("HF_CUDNN_DECONV");
  return v && !strcmp(v, "shuffle") ? HF_CL_DECONV_SHUFFLE : HF_CL_DECONV_BWD_DATA;
}

static int env_device(void) {
  const char *v = getenv("HF_CUDA_DEVICE");
  return v && v[0] ? atoi(v) : 0;
}

/* ---- probe / open ------------------------------------------------------- */

typedef struct cudnn_dev {
  int device;
} cudnn_dev;

static int cudnn_probe(char *why, size_t whylen) {
  int count = 0;
  cudaError_t e = cudaGetDeviceCount(&count);
  if (e != cudaSuccess || count < 1) {
    snprintf(why, whylen, "no CUDA device (cudaGetDeviceCount: %s)",
             e != cudaSuccess ? cudaGetErrorString(e) : "0 devices");
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
  size_t ver = cudnnGetVersion();
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
  return HF_OK;
}

static int cudnn_open(void **devp, char *why, size_t whylen) {
  cudnn_dev *d = calloc(1, sizeof *d);
  if (!d) return HF_ENOMEM;
  d->device = env_device();
  *devp = d;
  return HF_OK;
}

static void cudnn_close(void *dev) { free(dev); }

/* ---- plans ------------------------------------------------------------- */

/* One layer as it runs: the cuDNN op, plus copies through dense scratch
 * tensors when no engine accepted its strided skip views, plus the bias
 * kernel when no engine fused the epilogue, plus the pixel shuffle of a
 * SHUFFLE decoder (whose op always writes a dense scratch). */
typedef struct step {
  const hf_cl_layer *ly;
  hf_cg_op op;
  void *x, *y;              /* what the op reads and writes */
  int y_c, y_stride;        /* channels and pixel stride the op writes */
  void *in_ptr, *out_ptr;   /* the layer's real views */
  void *scratch_in, *scratch_out;
  size_t npix_in, npix_out;
} step;

typedef struct plan {
  int batch, pw, ph;
  uint64_t last_used;
  hf_cl_layout lo;
  void *buf[HF_CL_MAX_BUFS];
  step steps[HF_CL_MAX_LAYERS];
  void *ws;
  int64_t ws_bytes;
  void *d_in_raw, *d_out_raw;   /* the request's own dtype and size */
  void *h_in, *h_out;           /* pinned staging */
  size_t in_raw_bytes, out_raw_bytes;
  cudaGraphExec_t gexec;
  size_t device_bytes;
} plan;

typedef struct cudnn_model {
  int device;
  int deconv;                   /* HF_CL_DECONV_* */
  hf_net_config cfg;
  cudnnHandle_t dnn;
  cudaStream_t stream;
  cudaEvent_t ev[4];
  hf_cl_layout wlo;             /* filter shapes (size-independent part) */
  void *d_w16, *d_b16, *d_b32;
  size_t weight_bytes;
  plan *plans[MAX_PLANS];
  uint64_t tick;
  pthread_mutex_t lock;
} cudnn_model;

static int dmalloc(void **p, size_t bytes, size_t *acct) {
  int rc;
  *p = NULL;
  HF_CU_TRY(cudaMalloc(p, bytes ? bytes : 1));
  *acct += bytes;
  return HF_OK;
fail:
  *p = NULL;
  return rc;
}

static void plan_destroy(plan *p) {
  if (!p) return;
  if (p->gexec) cudaGraphExecDestroy(p->gexec);
  for (int j = 0; j < p->lo.nlayers; j++) {
    hf_cg_op_destroy(&p->steps[j].op);
    cudaFree(p->steps[j].scratch_in);
    cudaFree(p->steps[j].scratch_out);
  }
  for (int b = 0; b < HF_CL_MAX_BUFS; b++) cudaFree(p->buf[b]);
  cudaFree(p->ws);
  cudaFree(p->d_in_raw);
  cudaFree(p->d_out_raw);
  cudaFreeHost(p->h_in);
  cudaFreeHost(p->h_out);
  free(p);
}

static void *view_ptr(const plan *p, const hf_cl_view *v) {
  return (uint16_t *)p->buf[v->buf] + v->ch_off;
}

static int is_dense(const hf_cl_view *v) { return v->ch_off == 0 && v->pix_stride == v->c; }

/* Finds an engine for one layer, from the cheapest form down: fused on the
 * real strided views, unfused on them, then both again on dense scratch
 * copies. */
static int step_build(cudnn_model *m, plan *p, int j) {
  step *st = &p->steps[j];
  const hf_cl_layer *ly = &p->lo.layers[j];
  const int shuffle = ly->kind == HF_CL_CONV_SHUFFLE;
  st->ly = ly;
  st->in_ptr = view_ptr(p, &ly->in);
  st->out_ptr = view_ptr(p, &ly->out);
  st->npix_in = (size_t)p->batch * ly->in.h * ly->in.w;
  st->npix_out = (size_t)p->batch * ly->out.h * ly->out.w;
  /* What the cuDNN op writes: the layer's output view, or for SHUFFLE the
   * 4*C channels at the input resolution. */
  hf_cl_view opout = ly->out;
  if (shuffle) {
    opout.buf = -1;
    opout.ch_off = 0;
    opout.c = opout.pix_stride = ly->k;
    opout.h = ly->in.h;
    opout.w = ly->in.w;
  }
  const int strided = !is_dense(&ly->in) || !is_dense(&opout);
  const int no_fusion = env_flag("HF_CUDNN_NO_FUSION");
  char why[512] = "";
  int rc = HF_EUNSUPPORTED;
  for (int dense = 0; dense <= 1; dense++) {
    if (dense && !strided) break;
    hf_cl_view in = ly->in, out = opout;
    if (dense) {
      in.ch_off = out.ch_off = 0;
      in.pix_stride = in.c;
      out.pix_stride = out.c;
    }
    for (int fused = no_fusion ? 0 : 1; fused >= 0; fused--) {
      rc = hf_cg_op_build(m->dnn, ly, p->batch, &in, &out, fused, &st->op, why, sizeof why);
      if (rc == HF_OK) break;
      if (rc != HF_EUNSUPPORTED) return rc;
    }
    if (rc != HF_OK) continue;
    size_t acct = 0;
    st->x = st->in_ptr;
    st->y = st->out_ptr;
    st->y_c = out.c;
    st->y_stride = out.pix_stride;
    if (dense && !is_dense(&ly->in)) {
      if ((rc = dmalloc(&st->scratch_in, st->npix_in * in.c * 2, &acct))) return rc;
      st->x = st->scratch_in;
    }
    if (shuffle || (dense && !is_dense(&ly->out))) {
      const size_t npix = shuffle ? st->npix_in : st->npix_out;
      if ((rc = dmalloc(&st->scratch_out, npix * out.c * 2, &acct))) return rc;
      st->y = st->scratch_out;
      st->y_stride = out.c;
    }
    p->device_bytes += acct;
    if (hf_cudnn_verbose())
      fprintf(stderr, "hfcore cudnn: %s: %s%s, %s views\n", ly->name,
              st->op.fused ? "fused bias+activation" : "separate bias kernel",
              shuffle ? ", pixel shuffle" : "", dense ? "dense scratch" : "direct");
    return HF_OK;
  }
  return hf_cudnn_report(HF_EBACKEND, "%s: no cuDNN engine for this layer: %s", ly->name, why);
}

/* Enqueues one layer on the model's stream. */
static int step_enqueue(cudnn_model *m, const plan *p, const step *st) {
  int rc;
  const hf_cl_layer *ly = st->ly;
  if (st->scratch_in)
    HF_CU_TRY(hf_cuk_copy_channels(st->scratch_in, ly->in.c, st->in_ptr, ly->in.pix_stride,
                                   st->npix_in, ly->in.c, m->stream));
  HF_TRY(hf_cg_op_exec(m->dnn, &st->op));
  const int shuffle = ly->kind == HF_CL_CONV_SHUFFLE;
  if (!st->op.fused)
    HF_CU_TRY(hf_cuk_bias_act(st->y, shuffle ? st->npix_in : st->npix_out, st->y_c,
                              st->y_stride, (const float *)m->d_b32 + ly->b_off, ly->relu,
                              m->stream));
  if (shuffle)
    HF_CU_TRY(hf_cuk_pixel_shuffle(st->out_ptr, ly->out.pix_stride, st->scratch_out, p->batch,
                                   ly->in.h, ly->in.w, ly->out.c, m->stream));
  else if (st->scratch_out)
    HF_CU_TRY(hf_cuk_copy_channels(st->out_ptr, ly->out.pix_stride, st->scratch_out, ly->out.c,
                                   st->npix_out, ly->out.c, m->stream));
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

/* Records the forward pass into a CUDA graph. Any failure leaves the plan
 * running eagerly, which is slower but equally correct. */
static void plan_capture(cudnn_model *m, plan *p) {
  cudaGraph_t g = NULL;
  cudaError_t e = cudaStreamBeginCapture(m->stream, cudaStreamCaptureModeThreadLocal);
  if (e != cudaSuccess) goto fail;
  int rc = forward_enqueue(m, p);
  e = cudaStreamEndCapture(m->stream, &g);
  if (rc || e != cudaSuccess || !g) goto fail;
  e = cudaGraphInstantiate(&p->gexec, g, 0);
  if (e != cudaSuccess) {
    p->gexec = NULL;
    goto fail;
  }
  cudaGraphDestroy(g);
  g = NULL;
  /* Replay once now so a graph that cannot run is found at plan time. */
  if ((e = cudaGraphLaunch(p->gexec, m->stream)) == cudaSuccess &&
      (e = cudaStreamSynchronize(m->stream)) == cudaSuccess)
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
  plan *p = calloc(1, sizeof *p);
  if (!p) return HF_ENOMEM;
  p->batch = batch;
  p->pw = pw;
  p->ph = ph;
  HF_TRY(hf_cl_layout_init(&m->cfg, batch, pw, ph, m->deconv, &p->lo));

  for (int b = 0; b < p->lo.nbufs; b++) {
    size_t bytes;
    HF_TRY(hf_size_mul(p->lo.buf_elems[b], 2, &bytes));
    HF_TRY(dmalloc(&p->buf[b], bytes, &p->device_bytes));
    /* Zeros so padded channels never hold NaN bit patterns. */
    HF_CU_TRY(cudaMemsetAsync(p->buf[b], 0, bytes, m->stream));
  }
  /* Raw request buffers, sized for the largest frame of this padded size
   * in FP32, so any dtype and any crop fits. */
  size_t pix;
  HF_TRY(hf_size_mul((size_t)batch * pw, (size_t)ph, &pix));
  HF_TRY(hf_size_mul(pix, (size_t)m->cfg.in_channels * sizeof(float), &p->in_raw_bytes));
  HF_TRY(hf_size_mul(pix, (size_t)HF_OUT_CHANNELS * sizeof(float), &p->out_raw_bytes));
  HF_TRY(dmalloc(&p->d_in_raw, p->in_raw_bytes, &p->device_bytes));
  HF_TRY(dmalloc(&p->d_out_raw, p->out_raw_bytes, &p->device_bytes));
  HF_CU_TRY(cudaHostAlloc(&p->h_in, p->in_raw_bytes, cudaHostAllocDefault));
  HF_CU_TRY(cudaHostAlloc(&p->h_out, p->out_raw_bytes, cudaHostAllocDefault));

  for (int j = 0; j < p->lo.nlayers; j++) HF_TRY(step_build(m, p, j));

  p->ws_bytes = 0;
  for (int j = 0; j < p->lo.nlayers; j++) {
    int64_t ws = hf_cg_op_max_workspace(&p->steps[j].op);
    if (ws > p->ws_bytes) p->ws_bytes = ws;
  }
  if (p->ws_bytes > 0) HF_TRY(dmalloc(&p->ws, (size_t)p->ws_bytes, &p->device_bytes));

  for (int j = 0; j < p->lo.nlayers; j++) {
    step *st = &p->steps[j];
    const hf_cl_layer *ly = st->ly;
    HF_TRY(hf_cg_op_bind(&st->op, st->x, (uint16_t *)m->d_w16 + ly->w_off, st->y,
                         st->op.fused ? (uint16_t *)m->d_b16 + ly->b_off : NULL, p->ws));
  }
  /* Time each layer's candidates on the plan's own buffers (their contents
   * do not change which engine is fastest) and keep the fastest. */
  HF_CU_TRY(cudaStreamSynchronize(m->stream));
  for (int j = 0; j < p->lo.nlayers; j++)
    HF_TRY(hf_cg_op_tune(m->dnn, &p->steps[j].op, m->stream, p->steps[j].ly->name));
  /* One eager pass end to end, then the graph. */
  HF_TRY(forward_enqueue(m, p));
  HF_CU_TRY(cudaStreamSynchronize(m->stream));
  if (!env_flag("HF_CUDNN_NO_GRAPH")) plan_capture(m, p);
  if (hf_cudnn_verbose())
    fprintf(stderr,
            "hfcore cudnn: plan %s batch %d %dx%d: %zu device bytes, workspace %lld, %s\n",
            m->cfg.name, batch, pw, ph, p->device_bytes, (long long)p->ws_bytes,
            p->gexec ? "CUDA graph" : "eager");
  *out = p;
  return HF_OK;
fail:
  plan_destroy(p);
  return rc;
}

/* The plan for a shape, made on first use; the least recently used one
 * makes room when the cache is full. */
static int plan_get(cudnn_model *m, int batch, int pw, int ph, plan **out) {
  int free_slot = -1, lru = 0;
  for (int i = 0; i < MAX_PLANS; i++) {
    plan *p = m->plans[i];
    if (!p) {
      if (free_slot < 0) free_slot = i;
      continue;
    }
    if (p->batch == batch && p->pw == pw && p->ph == ph) {
      p->last_used = ++m->tick;
      *out = p;
      return HF_OK;
    }
    if (m->plans[lru] && p->last_used < m->plans[lru]->last_used) lru = i;
  }
  if (free_slot < 0) {
    free_slot = lru;
    plan_destroy(m->plans[lru]);
    m->plans[lru] = NULL;
  }
  plan *p = NULL;
  int rc = plan_create(m, batch, pw, ph, &p);
  if (rc) return rc;
  p->last_used = ++m->tick;
  m->plans[free_slot] = p;
  *out = p;
  return HF_OK;
}

/* ---- model --------------------------------------------------------------- */

static void cudnn_model_destroy(void *impl) {
  cudnn_model *m = impl;
  if (!m) return;
  cudaSetDevice(m->device);
  if (m->stream) cudaStreamSynchronize(m->stream);
  for (int i = 0; i < MAX_PLANS; i++) plan_destroy(m->plans[i]);
  cudaFree(m->d_w16);
  cudaFree(m->d_b16);
  cudaFree(m->d_b32);
  for (int i = 0; i < 4; i++)
    if (m->ev[i]) cudaEventDestroy(m->ev[i]);
  if (m->dnn) cudnnDestroy(m->dnn);
  if (m->stream) cudaStreamDestroy(m->stream);
  pthread_mutex_destroy(&m->lock);
  free(m);
}

static int cudnn_model_create(void *dev, const hf_weights *w, void **out) {
  const cudnn_dev *d = dev;
  int rc;
  uint16_t *w16 = NULL, *b16 = NULL;
  float *b32 = NULL;
  cudnn_model *m = calloc(1, sizeof *m);
  if (!m) return HF_ENOMEM;
  if (pthread_mutex_init(&m->lock, NULL)) {
    free(m);
    return HF_ENOMEM;
  }
  m->device = d->device;
  m->deconv = env_deconv();
  m->cfg = w->cfg;
  HF_CU_TRY(cudaSetDevice(m->device));
  HF_CU_TRY(cudaStreamCreateWithFlags(&m->stream, cudaStreamNonBlocking));
  for (int i = 0; i < 4; i++) HF_CU_TRY(cudaEventCreate(&m->ev[i]));
  HF_DNN_TRY(cudnnCreate(&m->dnn));
  HF_DNN_TRY(cudnnSetStream(m->dnn, m->stream));

  /* Filter shapes do not depend on the frame size: lay out the smallest. */
  const int a = hf_net_align(&m->cfg);
  HF_TRY(hf_cl_layout_init(&m->cfg, 1, a, a, m->deconv, &m->wlo));
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
  *out = m;
  return HF_OK;
fail:
  free(w16);
  free(b16);
  free(b32);
  cudnn_model_destroy(m);
  return rc;
}

static int elapsed_us(cudaEvent_t a, cudaEvent_t b, double *us) {
  int rc;
  float ms = 0;
  HF_CU_TRY(cudaEventElapsedTime(&ms, a, b));
  *us = ms * 1000.0;
  return HF_OK;
fail:
  return rc;
}

static int run_locked(cudnn_model *m, const hf_io *io, hf_timing *t) {
  int rc;
  const int a = hf_net_align(&m->cfg);
  const int pw = hf_round_up(io->width, a), ph = hf_round_up(io->height, a);
  plan *p = NULL;
  HF_CU_TRY(cudaSetDevice(m->device));
  HF_TRY(plan_get(m, io->batch, pw, ph, &p));

  const size_t in_es = io->in_dtype == HF_F16 ? 2 : 4;
  const size_t out_es = io->out_dtype == HF_F16 ? 2 : 4;
  const size_t pix = (size_t)io->batch * io->width * io->height;
  const size_t in_bytes = pix * m->cfg.in_channels * in_es;
  const size_t out_bytes = pix * HF_OUT_CHANNELS * out_es;
  if (in_bytes > p->in_raw_bytes || out_bytes > p->out_raw_bytes)
    return hf_cudnn_report(HF_ERANGE, "request larger than its plan");

  /* Input: host copy into pinned memory, async upload, pad + convert. */
  double h0 = hf_now_us();
  memcpy(p->h_in, io->in, in_bytes);
  double host_in = hf_now_us() - h0;
  HF_CU_TRY(cudaEventRecord(m->ev[0], m->stream));
  HF_CU_TRY(cudaMemcpyAsync(p->d_in_raw, p->h_in, in_bytes, cudaMemcpyHostToDevice, m->stream));
  HF_CU_TRY(hf_cuk_input(p->d_in_raw, io->in_dtype == HF_F16, io->batch, io->width, io->height,
                         m->cfg.in_channels, p->buf[HF_CL_BUF_IN], pw, ph, p->lo.cin_pad,
                         m->stream));
  HF_CU_TRY(cudaEventRecord(m->ev[1], m->stream));
  /* The network. */
  if (p->gexec)
    HF_CU_TRY(cudaGraphLaunch(p->gexec, m->stream));
  else
    HF_TRY(forward_enqueue(m, p));
  HF_CU_TRY(cudaEventRecord(m->ev[2], m->stream));
  /* Output: transforms + crop + dtype in one kernel, async download. */
  const int residual = m->cfg.arch == HF_ARCH_RESIDUAL;
  HF_CU_TRY(hf_cuk_output(p->buf[HF_CL_BUF_OUT], HF_CL_OUT_CH,
                          residual ? p->buf[HF_CL_BUF_IN] : NULL, p->lo.cin_pad, m->cfg.spp, pw,
                          ph, io->batch, io->width, io->height, p->d_out_raw,
                          io->out_dtype == HF_F16, m->stream));
  HF_CU_TRY(cudaMemcpyAsync(p->h_out, p->d_out_raw, out_bytes, cudaMemcpyDeviceToHost,
                            m->stream));
  HF_CU_TRY(cudaEventRecord(m->ev[3], m->stream));
  HF_CU_TRY(cudaEventSynchronize(m->ev[3]));
  h0 = hf_now_us();
  memcpy(io->out, p->h_out, out_bytes);
  double host_out = hf_now_us() - h0;

  double gin = 0, gnet = 0, gout = 0;
  HF_TRY(elapsed_us(m->ev[0], m->ev[1], &gin));
  HF_TRY(elapsed_us(m->ev[1], m->ev[2], &gnet));
  HF_TRY(elapsed_us(m->ev[2], m->ev[3], &gout));
  t->input_us = host_in + gin;
  t->infer_us = gnet;
  t->output_us = gout + host_out;
  return HF_OK;
fail:
  return rc;
}

static int cudnn_model_run(void *impl, const hf_io *io, hf_timing *t) {
  cudnn_model *m = impl;
  pthread_mutex_lock(&m->lock);
  int rc = run_locked(m, io, t);
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
  size_t n = m->weight_bytes;
  for (int i = 0; i < MAX_PLANS; i++)
    if (m->plans[i]) n += m->plans[i]->device_bytes;
  pthread_mutex_unlock(&m->lock);
  return n;
}

const hf_backend_ops hf_backend_cudnn = {
  .name = "cudnn",
  .priority = 100,
  .archs = 1u << HF_ARCH_UNET | 1u << HF_ARCH_RESIDUAL,
  .probe = cudnn_probe,
  .open = cudnn_open,
  .close = cudnn_close,
  .model_create = cudnn_model_create,
  .model_destroy = cudnn_model_destroy,
  .model_run = cudnn_model_run,
  .model_precision = cudnn_model_precision,
  .model_device_bytes = cudnn_model_device_bytes,
};
