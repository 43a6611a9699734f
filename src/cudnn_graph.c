/* One convolution as a cuDNN 9 graph: see cudnn_graph.h. */
#include <stdbool.h>
#include <stdio.h>
#include <string.h>

#include "backend.h"   /* hf_now_us */
#include "cudnn_graph.h"
#include "cudnn_util.h"

/* Tensor ids within one layer graph. */
enum { UID_X = 1, UID_W = 2, UID_Y = 3, UID_B = 4, UID_CONV = 5, UID_ADD = 6 };

#define MAX_HEUR_RESULTS 16

/* Numerical notes that rule an engine out (see cudnn_graph.h). */
#define NOTES_REFUSED                                      \
  (1u << CUDNN_NUMERICAL_NOTE_NONDETERMINISTIC |           \
   1u << CUDNN_NUMERICAL_NOTE_REDUCED_PRECISION_REDUCTION)

/* A graph no engine takes is an expected outcome (the caller then tries an
 * unfused or dense variant), so it is kept in why, and logged only when
 * verbose. */
static int unsupported(cudnnStatus_t s, const char *what, char *why, size_t whylen) {
  char detail[256] = "";
  cudnnGetLastErrorString(detail, sizeof detail);
  if (why && whylen)
    snprintf(why, whylen, "%s: %s%s%s", what, cudnnGetErrorString(s), detail[0] ? ": " : "",
             detail);
  if (hf_cudnn_verbose()) fprintf(stderr, "hfcore cudnn: %s\n", why ? why : what);
  return HF_EUNSUPPORTED;
}

#define SET(d, attr, type, n, ptr)                                            \
  do {                                                                        \
    cudnnStatus_t s_ = cudnnBackendSetAttribute((d), (attr), (type), (n), (ptr)); \
    if (s_ != CUDNN_STATUS_SUCCESS) {                                         \
      rc = unsupported(s_, "set " #attr, why, whylen);                        \
      goto fail;                                                              \
    }                                                                         \
  } while (0)

#define FINALIZE(d, what)                                                     \
  do {                                                                        \
    cudnnStatus_t s_ = cudnnBackendFinalize(d);                               \
    if (s_ != CUDNN_STATUS_SUCCESS) {                                         \
      rc = unsupported(s_, "finalize " what, why, whylen);                    \
      goto fail;                                                              \
    }                                                                         \
  } while (0)

/* Creates a descriptor that lives as long as the op. */
static int create(hf_cg_op *op, cudnnBackendDescriptorType_t type, cudnnBackendDescriptor_t *d) {
  *d = NULL;
  if (op->nkeep >= HF_CG_MAX_DESC)
    return hf_cudnn_report(HF_ERANGE, "cudnn graph: more than %d descriptors", HF_CG_MAX_DESC);
  cudnnStatus_t s = cudnnBackendCreateDescriptor(type, d);
  if (s != CUDNN_STATUS_SUCCESS)
    return hf_dnn_report(s, "cudnnBackendCreateDescriptor", __FILE__, __LINE__);
  op->keep[op->nkeep++] = *d;
  return HF_OK;
}

/* The largest power of two up to 16 that divides a byte offset: buffers
 * come from cudaMalloc (256-byte aligned), so that is the alignment of a
 * tensor starting there. */
static int64_t alignment_of(size_t byte_offset) {
  int64_t a = 16;
  while (a > 1 && byte_offset % (size_t)a) a /= 2;
  return a;
}

static int tensor(hf_cg_op *op, int64_t uid, cudnnDataType_t dt, const int64_t dims[4],
                  const int64_t strides[4], int64_t alignment, bool is_virtual,
                  cudnnBackendDescriptor_t *t, char *why, size_t whylen) {
  int rc = create(op, CUDNN_BACKEND_TENSOR_DESCRIPTOR, t);
  if (rc) return rc;
  SET(*t, CUDNN_ATTR_TENSOR_DATA_TYPE, CUDNN_TYPE_DATA_TYPE, 1, &dt);
  SET(*t, CUDNN_ATTR_TENSOR_DIMENSIONS, CUDNN_TYPE_INT64, 4, dims);
  SET(*t, CUDNN_ATTR_TENSOR_STRIDES, CUDNN_TYPE_INT64, 4, strides);
  SET(*t, CUDNN_ATTR_TENSOR_UNIQUE_ID, CUDNN_TYPE_INT64, 1, &uid);
  SET(*t, CUDNN_ATTR_TENSOR_BYTE_ALIGNMENT, CUDNN_TYPE_INT64, 1, &alignment);
  SET(*t, CUDNN_ATTR_TENSOR_IS_VIRTUAL, CUDNN_TYPE_BOOLEAN, 1, &is_virtual);
  FINALIZE(*t, "tensor");
  return HF_OK;
fail:
  return rc;
}

/* cuDNN describes every tensor by NCHW-ordered dims; NHWC is in the strides. */
static void view_dims(const hf_cl_view *v, int64_t batch, int dense, int64_t dims[4],
                      int64_t strides[4]) {
  dims[0] = batch;
  dims[1] = v->c;
  dims[2] = v->h;
  dims[3] = v->w;
  if (dense) {
    hf_cl_view d = hf_cl_view_packed(v->buf, v->c, v->h, v->w);
    hf_cl_view_strides(&d, strides);
  } else {
    hf_cl_view_strides(v, strides);
  }
}

static void packed_dims(int64_t n, int64_t c, int64_t h, int64_t w, int64_t dims[4],
                        int64_t strides[4]) {
  dims[0] = n; dims[1] = c; dims[2] = h; dims[3] = w;
  strides[0] = h * w * c; strides[1] = 1; strides[2] = w * c; strides[3] = c;
}

static int pointwise(hf_cg_op *op, cudnnPointwiseMode_t mode, cudnnBackendDescriptor_t x,
                     cudnnBackendDescriptor_t b, cudnnBackendDescriptor_t y,
                     cudnnBackendDescriptor_t *pop, char *why, size_t whylen) {
  cudnnBackendDescriptor_t pw;
  int rc = create(op, CUDNN_BACKEND_POINTWISE_DESCRIPTOR, &pw);
  if (rc) return rc;
  const cudnnDataType_t prec = CUDNN_DATA_FLOAT;
  SET(pw, CUDNN_ATTR_POINTWISE_MODE, CUDNN_TYPE_POINTWISE_MODE, 1, &mode);
  SET(pw, CUDNN_ATTR_POINTWISE_MATH_PREC, CUDNN_TYPE_DATA_TYPE, 1, &prec);
  FINALIZE(pw, "pointwise descriptor");
  if ((rc = create(op, CUDNN_BACKEND_OPERATION_POINTWISE_DESCRIPTOR, pop)) != 0) return rc;
  SET(*pop, CUDNN_ATTR_OPERATION_POINTWISE_PW_DESCRIPTOR, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &pw);
  SET(*pop, CUDNN_ATTR_OPERATION_POINTWISE_XDESC, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &x);
  if (b) SET(*pop, CUDNN_ATTR_OPERATION_POINTWISE_BDESC, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &b);
  SET(*pop, CUDNN_ATTR_OPERATION_POINTWISE_YDESC, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &y);
  FINALIZE(*pop, "pointwise operation");
  return HF_OK;
fail:
  return rc;
}

/* The engine behind an engine config: its global index and notes. Returns
 * a cuDNN status. */
static cudnnStatus_t engine_notes(cudnnBackendDescriptor_t cfg, int64_t *index,
                                  unsigned *numerical, unsigned *behavior) {
  cudnnBackendDescriptor_t eng = NULL;
  *index = -1;
  *numerical = *behavior = 0;
  cudnnStatus_t s = cudnnBackendCreateDescriptor(CUDNN_BACKEND_ENGINE_DESCRIPTOR, &eng);
  if (s != CUDNN_STATUS_SUCCESS) return s;
  int64_t n = 0;
  s = cudnnBackendGetAttribute(cfg, CUDNN_ATTR_ENGINECFG_ENGINE, CUDNN_TYPE_BACKEND_DESCRIPTOR,
                               1, &n, &eng);
  if (s == CUDNN_STATUS_SUCCESS)
    s = cudnnBackendGetAttribute(eng, CUDNN_ATTR_ENGINE_GLOBAL_INDEX, CUDNN_TYPE_INT64, 1, &n,
                                 index);
  if (s == CUDNN_STATUS_SUCCESS) {
    cudnnBackendNumericalNote_t notes[CUDNN_NUMERICAL_NOTE_TYPE_COUNT];
    s = cudnnBackendGetAttribute(eng, CUDNN_ATTR_ENGINE_NUMERICAL_NOTE,
                                 CUDNN_TYPE_NUMERICAL_NOTE, CUDNN_NUMERICAL_NOTE_TYPE_COUNT, &n,
                                 notes);
    for (int64_t i = 0; s == CUDNN_STATUS_SUCCESS && i < n; i++)
      if ((unsigned)notes[i] < 32) *numerical |= 1u << notes[i];
  }
  if (s == CUDNN_STATUS_SUCCESS) {
    cudnnBackendBehaviorNote_t notes[CUDNN_BEHAVIOR_NOTE_TYPE_COUNT];
    s = cudnnBackendGetAttribute(eng, CUDNN_ATTR_ENGINE_BEHAVIOR_NOTE, CUDNN_TYPE_BEHAVIOR_NOTE,
                                 CUDNN_BEHAVIOR_NOTE_TYPE_COUNT, &n, notes);
    for (int64_t i = 0; s == CUDNN_STATUS_SUCCESS && i < n; i++)
      if ((unsigned)notes[i] < 32) *behavior |= 1u << notes[i];
  }
  cudnnBackendDestroyDescriptor(eng);
  return s;
}

static void note_names(unsigned numerical, unsigned behavior, char *buf, size_t len) {
  static const char *const num[] = {"tensor_core", "down_convert", "reduced_precision", "fft",
                                    "nondeterministic", "winograd", "winograd4x4",
                                    "winograd6x6", "winograd13x13", "strict_nan"};
  static const char *const beh[] = {"rtc", "int8x32_filter", "int8x32_bias",
                                    "cuda_graph_native", "cublaslt"};
  size_t used = 0;
  buf[0] = 0;
  for (unsigned i = 0; i < sizeof num / sizeof num[0]; i++)
    if (numerical & 1u << i)
      used += snprintf(buf + used, used < len ? len - used : 0, "%s%s", used ? "," : "", num[i]);
  for (unsigned i = 0; i < sizeof beh / sizeof beh[0]; i++)
    if (behavior & 1u << i)
      used += snprintf(buf + used, used < len ? len - used : 0, "%s%s", used ? "," : "", beh[i]);
}

void hf_cg_cand_describe(const hf_cg_cand *c, char *buf, size_t len) {
  char notes[160];
  note_names(c->numerical, c->behavior, notes, sizeof notes);
  if (c->time_ms >= 0)
    snprintf(buf, len, "engine %lld [%s], finalize %.1f ms, %.4f ms, workspace %lld",
             (long long)c->engine, notes, c->finalize_ms, c->time_ms, (long long)c->ws);
  else
    snprintf(buf, len, "engine %lld [%s], finalize %.1f ms, workspace %lld",
             (long long)c->engine, notes, c->finalize_ms, (long long)c->ws);
}

/* Finalizes one engine config into a plan and keeps it as a candidate.
 * HF_EUNSUPPORTED when it does not finalize or needs too much workspace. */
static int add_candidate(const hf_cg_target *t, hf_cg_op *op, cudnnBackendDescriptor_t cfg,
                         int64_t engine, unsigned numerical, unsigned behavior, char *why,
                         size_t whylen) {
  cudnnBackendDescriptor_t plan;
  cudnnStatus_t s = cudnnBackendCreateDescriptor(CUDNN_BACKEND_EXECUTION_PLAN_DESCRIPTOR, &plan);
  if (s != CUDNN_STATUS_SUCCESS)
    return hf_dnn_report(s, "cudnnBackendCreateDescriptor(plan)", __FILE__, __LINE__);
  int64_t ws = 0, nws = 0;
  if (t->handle)
    s = cudnnBackendSetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_HANDLE, CUDNN_TYPE_HANDLE, 1,
                                 &t->handle);
  else
    s = cudnnBackendSetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_DEVICEPROP,
                                 CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &t->devprop);
  if (s == CUDNN_STATUS_SUCCESS)
    s = cudnnBackendSetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_ENGINE_CONFIG,
                                 CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &cfg);
  const double t0 = hf_now_us();
  if (s == CUDNN_STATUS_SUCCESS) s = cudnnBackendFinalize(plan);
  const double finalize_ms = (hf_now_us() - t0) / 1e3;
  if (s == CUDNN_STATUS_SUCCESS)
    s = cudnnBackendGetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_WORKSPACE_SIZE,
                                 CUDNN_TYPE_INT64, 1, &nws, &ws);
  if (s != CUDNN_STATUS_SUCCESS || ws < 0 || ws > HF_CG_MAX_WORKSPACE) {
    if (s != CUDNN_STATUS_SUCCESS) unsupported(s, "execution plan", why, whylen);
    else if (why && whylen)
      snprintf(why, whylen, "engine %lld needs %lld bytes of workspace", (long long)engine,
               (long long)ws);
    op->failed++;
    cudnnBackendDestroyDescriptor(plan);
    return HF_EUNSUPPORTED;
  }
  hf_cg_cand *c = &op->cand[op->ncand++];
  c->plan = plan;
  c->ws = ws;
  c->engine = engine;
  c->numerical = numerical;
  c->behavior = behavior;
  c->finalize_ms = finalize_ms;
  c->time_ms = -1;
  return HF_OK;
}

/* Asks the heuristics for engine configs and keeps those that finalize
 * into execution plans, best first, within the target's limits. */
static int make_plans(const hf_cg_target *t, hf_cg_op *op, cudnnBackendDescriptor_t graph,
                      char *why, size_t whylen) {
  static const cudnnBackendHeurMode_t modes[] = {CUDNN_HEUR_MODE_A, CUDNN_HEUR_MODE_FALLBACK};
  const int max_cand = t->max_cand < 1 ? 1 : t->max_cand > HF_CG_MAX_CAND ? HF_CG_MAX_CAND
                                                                          : t->max_cand;
  int rc = HF_EUNSUPPORTED, rtc = 0;
  for (size_t m = 0; m < sizeof modes / sizeof modes[0] && op->ncand == 0; m++) {
    cudnnBackendDescriptor_t heur;
    if ((rc = create(op, CUDNN_BACKEND_ENGINEHEUR_DESCRIPTOR, &heur)) != 0) return rc;
    cudnnStatus_t s = cudnnBackendSetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_OPERATION_GRAPH,
                                               CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &graph);
    if (s == CUDNN_STATUS_SUCCESS)
      s = cudnnBackendSetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_MODE, CUDNN_TYPE_HEUR_MODE, 1,
                                   &modes[m]);
    if (s == CUDNN_STATUS_SUCCESS && !t->handle)
      s = cudnnBackendSetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_DEVICEPROP,
                                   CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &t->devprop);
    if (s == CUDNN_STATUS_SUCCESS) s = cudnnBackendFinalize(heur);
    int64_t count = 0;
    if (s == CUDNN_STATUS_SUCCESS)
      s = cudnnBackendGetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_RESULTS,
                                   CUDNN_TYPE_BACKEND_DESCRIPTOR, 0, &count, NULL);
    if (s != CUDNN_STATUS_SUCCESS) {
      rc = unsupported(s, "engine heuristics", why, whylen);
      continue;
    }
    if (count > MAX_HEUR_RESULTS) count = MAX_HEUR_RESULTS;
    if (count <= 0) {
      if (why && whylen) snprintf(why, whylen, "engine heuristics: no engine config");
      rc = HF_EUNSUPPORTED;
      continue;
    }
    cudnnBackendDescriptor_t cfg[MAX_HEUR_RESULTS];
    for (int64_t i = 0; i < count; i++)
      if ((rc = create(op, CUDNN_BACKEND_ENGINECFG_DESCRIPTOR, &cfg[i])) != 0) return rc;
    int64_t got = 0;
    s = cudnnBackendGetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_RESULTS,
                                 CUDNN_TYPE_BACKEND_DESCRIPTOR, count, &got, cfg);
    if (s != CUDNN_STATUS_SUCCESS) {
      rc = unsupported(s, "engine heuristics results", why, whylen);
      continue;
    }
    op->heur_configs += (int)got;
    for (int64_t i = 0; i < got && i < count && op->ncand < max_cand; i++) {
      int64_t engine;
      unsigned numerical, behavior;
      /* The notes decide before finalizing, which is what costs. */
      s = engine_notes(cfg[i], &engine, &numerical, &behavior);
      if (s != CUDNN_STATUS_SUCCESS) {
        unsupported(s, "engine notes", why, whylen);
        op->failed++;
        continue;
      }
      if (numerical & NOTES_REFUSED) {
        op->skipped_notes++;
        continue;
      }
      const int is_rtc = (behavior >> CUDNN_BEHAVIOR_NOTE_RUNTIME_COMPILATION) & 1;
      if (is_rtc && rtc >= t->max_rtc) {
        op->skipped_rtc++;
        continue;
      }
      rc = add_candidate(t, op, cfg[i], engine, numerical, behavior, why, whylen);
      if (rc == HF_OK) rtc += is_rtc;
      else if (rc != HF_EUNSUPPORTED) return rc;
    }
  }
  if (op->ncand == 0 && why && whylen && !why[0])
    snprintf(why, whylen, "no engine config left (%d offered, %d refused for their notes, "
             "%d run-time compiled beyond the limit, %d failed)", op->heur_configs,
             op->skipped_notes, op->skipped_rtc, op->failed);
  return op->ncand > 0 ? HF_OK : (rc ? rc : HF_EUNSUPPORTED);
}

int hf_cg_op_build(const hf_cg_target *t, const char *name, const hf_cl_conv *cv, int batch,
                   int dense, int fused, hf_cg_op *op, char *why, size_t whylen) {
  memset(op, 0, sizeof *op);
  op->fused = fused;
  if (why && whylen) why[0] = 0;
  const double t0 = hf_now_us();
  int rc;
  /* Forward: x has C channels, y has K. Data gradient: dy has K, dx has C. */
  if (cv->x.c != (cv->bwd_data ? cv->k : cv->c) || cv->y.c != (cv->bwd_data ? cv->c : cv->k))
    return hf_cudnn_report(HF_EINVAL, "%s: view channels do not match the filter", name);
  if (!t || (!t->handle && !t->devprop))
    return hf_cudnn_report(HF_EINVAL, "%s: no cuDNN handle or device properties", name);
  const int ych = cv->y.c;
  const size_t x_off = dense ? 0 : hf_cl_view_offset(&cv->x);
  const size_t y_off = dense ? 0 : hf_cl_view_offset(&cv->y);

  int64_t dims[4], strides[4];
  cudnnBackendDescriptor_t tx, tw, ty, tb = NULL, tconv, tadd = NULL;
  view_dims(&cv->x, batch, dense, dims, strides);
  if ((rc = tensor(op, UID_X, CUDNN_DATA_HALF, dims, strides, alignment_of(2 * x_off), false,
                   &tx, why, whylen)))
    goto fail;
  packed_dims(cv->k, cv->c, cv->r, cv->s, dims, strides);
  if ((rc = tensor(op, UID_W, CUDNN_DATA_HALF, dims, strides, alignment_of(2 * cv->w_off),
                   false, &tw, why, whylen)))
    goto fail;
  view_dims(&cv->y, batch, dense, dims, strides);
  if ((rc = tensor(op, UID_Y, CUDNN_DATA_HALF, dims, strides, alignment_of(2 * y_off), false,
                   &ty, why, whylen)))
    goto fail;
  if (fused) {
    /* Accumulate and apply the epilogue in FP32, store FP16 once. */
    packed_dims(1, ych, 1, 1, dims, strides);
    if ((rc = tensor(op, UID_B, CUDNN_DATA_HALF, dims, strides, alignment_of(2 * cv->b_off),
                     false, &tb, why, whylen)))
      goto fail;
    packed_dims(batch, ych, cv->y.h, cv->y.w, dims, strides);
    if ((rc = tensor(op, UID_CONV, CUDNN_DATA_FLOAT, dims, strides, 16, true, &tconv, why,
                     whylen)))
      goto fail;
    if (cv->relu && (rc = tensor(op, UID_ADD, CUDNN_DATA_FLOAT, dims, strides, 16, true, &tadd,
                                 why, whylen)))
      goto fail;
  } else {
    tconv = ty;
  }

  cudnnBackendDescriptor_t conv;
  if ((rc = create(op, CUDNN_BACKEND_CONVOLUTION_DESCRIPTOR, &conv))) goto fail;
  {
    const int64_t nsd = 2, pre[2] = {cv->pad_pre[0], cv->pad_pre[1]},
                  post[2] = {cv->pad_post[0], cv->pad_post[1]}, dil[2] = {1, 1},
                  str[2] = {cv->stride, cv->stride};
    const cudnnDataType_t comp = CUDNN_DATA_FLOAT;
    const cudnnConvolutionMode_t mode = CUDNN_CROSS_CORRELATION;
    SET(conv, CUDNN_ATTR_CONVOLUTION_SPATIAL_DIMS, CUDNN_TYPE_INT64, 1, &nsd);
    SET(conv, CUDNN_ATTR_CONVOLUTION_COMP_TYPE, CUDNN_TYPE_DATA_TYPE, 1, &comp);
    SET(conv, CUDNN_ATTR_CONVOLUTION_CONV_MODE, CUDNN_TYPE_CONVOLUTION_MODE, 1, &mode);
    SET(conv, CUDNN_ATTR_CONVOLUTION_PRE_PADDINGS, CUDNN_TYPE_INT64, 2, pre);
    SET(conv, CUDNN_ATTR_CONVOLUTION_POST_PADDINGS, CUDNN_TYPE_INT64, 2, post);
    SET(conv, CUDNN_ATTR_CONVOLUTION_DILATIONS, CUDNN_TYPE_INT64, 2, dil);
    SET(conv, CUDNN_ATTR_CONVOLUTION_FILTER_STRIDES, CUDNN_TYPE_INT64, 2, str);
    FINALIZE(conv, "convolution descriptor");
  }

  cudnnBackendDescriptor_t ops[3];
  int nops = 0;
  {
    const float alpha = 1.0f, beta = 0.0f;
    cudnnBackendDescriptor_t cop;
    if (!cv->bwd_data) {
      if ((rc = create(op, CUDNN_BACKEND_OPERATION_CONVOLUTION_FORWARD_DESCRIPTOR, &cop))) goto fail;
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_FORWARD_X, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &tx);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_FORWARD_W, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &tw);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_FORWARD_Y, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1,
          &tconv);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_FORWARD_CONV_DESC,
          CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &conv);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_FORWARD_ALPHA, CUDNN_TYPE_FLOAT, 1, &alpha);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_FORWARD_BETA, CUDNN_TYPE_FLOAT, 1, &beta);
      FINALIZE(cop, "convolution forward operation");
    } else {
      if ((rc = create(op, CUDNN_BACKEND_OPERATION_CONVOLUTION_BACKWARD_DATA_DESCRIPTOR, &cop)))
        goto fail;
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_BWD_DATA_DY, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1,
          &tx);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_BWD_DATA_W, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1,
          &tw);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_BWD_DATA_DX, CUDNN_TYPE_BACKEND_DESCRIPTOR, 1,
          &tconv);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_BWD_DATA_CONV_DESC,
          CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &conv);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_BWD_DATA_ALPHA, CUDNN_TYPE_FLOAT, 1, &alpha);
      SET(cop, CUDNN_ATTR_OPERATION_CONVOLUTION_BWD_DATA_BETA, CUDNN_TYPE_FLOAT, 1, &beta);
      FINALIZE(cop, "convolution backward-data operation");
    }
    ops[nops++] = cop;
  }
  if (fused) {
    cudnnBackendDescriptor_t add, relu;
    if ((rc = pointwise(op, CUDNN_POINTWISE_ADD, tconv, tb, cv->relu ? tadd : ty, &add, why,
                        whylen)))
      goto fail;
    ops[nops++] = add;
    if (cv->relu) {
      if ((rc = pointwise(op, CUDNN_POINTWISE_RELU_FWD, tadd, NULL, ty, &relu, why, whylen)))
        goto fail;
      ops[nops++] = relu;
    }
  }

  cudnnBackendDescriptor_t graph;
  if ((rc = create(op, CUDNN_BACKEND_OPERATIONGRAPH_DESCRIPTOR, &graph))) goto fail;
  SET(graph, CUDNN_ATTR_OPERATIONGRAPH_OPS, CUDNN_TYPE_BACKEND_DESCRIPTOR, nops, ops);
  if (t->handle) SET(graph, CUDNN_ATTR_OPERATIONGRAPH_HANDLE, CUDNN_TYPE_HANDLE, 1, &t->handle);
  FINALIZE(graph, "operation graph");

  if ((rc = make_plans(t, op, graph, why, whylen))) goto fail;
  op->build_ms = (hf_now_us() - t0) / 1e3;
  if (hf_cudnn_verbose()) {
    fprintf(stderr,
            "hfcore cudnn: %s: %s%s graph: %d engine config(s) kept of %d offered (%d refused "
            "for notes, %d run-time compiled beyond the limit, %d failed), %.1f ms\n",
            name, fused ? "fused" : "unfused", dense ? " dense" : "", op->ncand,
            op->heur_configs, op->skipped_notes, op->skipped_rtc, op->failed, op->build_ms);
    for (int i = 0; i < op->ncand; i++) {
      char d[256];
      hf_cg_cand_describe(&op->cand[i], d, sizeof d);
      fprintf(stderr, "hfcore cudnn: %s:   candidate %d: %s\n", name, i, d);
    }
  }
  return HF_OK;
fail:;
  hf_cg_op keep_counts = *op;
  hf_cg_op_destroy(op);
  op->fused = fused;
  op->heur_configs = keep_counts.heur_configs;
  op->skipped_notes = keep_counts.skipped_notes;
  op->skipped_rtc = keep_counts.skipped_rtc;
  op->failed = keep_counts.failed;
  op->build_ms = (hf_now_us() - t0) / 1e3;
  return rc;
}

int64_t hf_cg_op_max_workspace(const hf_cg_op *op) {
  int64_t m = 0;
  for (int i = 0; i < op->ncand; i++)
    if (op->cand[i].ws > m) m = op->cand[i].ws;
  return m;
}

int hf_cg_op_bind(hf_cg_op *op, void *x, void *w, void *y, void *bias, void *workspace) {
  int rc;
  if (op->varpack) {
    cudnnBackendDestroyDescriptor(op->varpack);
    op->varpack = NULL;
  }
  int64_t uids[4] = {UID_X, UID_W, UID_Y, UID_B};
  void *ptrs[4] = {x, w, y, bias};
  const int64_t n = op->fused ? 4 : 3;
  HF_DNN_TRY(cudnnBackendCreateDescriptor(CUDNN_BACKEND_VARIANT_PACK_DESCRIPTOR, &op->varpack));
  HF_DNN_TRY(cudnnBackendSetAttribute(op->varpack, CUDNN_ATTR_VARIANT_PACK_UNIQUE_IDS,
                                      CUDNN_TYPE_INT64, n, uids));
  HF_DNN_TRY(cudnnBackendSetAttribute(op->varpack, CUDNN_ATTR_VARIANT_PACK_DATA_POINTERS,
                                      CUDNN_TYPE_VOID_PTR, n, ptrs));
  HF_DNN_TRY(cudnnBackendSetAttribute(op->varpack, CUDNN_ATTR_VARIANT_PACK_WORKSPACE,
                                      CUDNN_TYPE_VOID_PTR, 1, &workspace));
  HF_DNN_TRY(cudnnBackendFinalize(op->varpack));
  return HF_OK;
fail:
  if (op->varpack) cudnnBackendDestroyDescriptor(op->varpack);
  op->varpack = NULL;
  return rc;
}

int hf_cg_op_exec(cudnnHandle_t h, const hf_cg_op *op) {
  int rc;
  HF_DNN_TRY(cudnnBackendExecute(h, op->cand[0].plan, op->varpack));
  return HF_OK;
fail:
  return rc;
}

int hf_cg_clear_cuda_error(cudaStream_t stream) {
  cudaError_t first = cudaGetLastError();
  /* A sticky error (an illegal address, a kernel trap) comes back on every
   * call: then the context is lost and nothing more can run. */
  cudaError_t e = cudaStreamSynchronize(stream);
  if (e == cudaSuccess) e = cudaGetLastError();
  if (e == cudaSuccess) return HF_OK;
  return hf_cudnn_report(HF_EBACKEND, "CUDA context unusable after a failed engine: %s (%s)",
                         cudaGetErrorString(e),
                         first != cudaSuccess ? cudaGetErrorName(first) : cudaGetErrorName(e));
}

/* Runs candidate i reps times on stream; *ms is the time of all of them.
 * HF_EUNSUPPORTED when it fails (its error cleared), HF_EBACKEND when the
 * context is lost. */
static int run_candidate(cudnnHandle_t h, hf_cg_op *op, int i, cudaStream_t stream, int reps,
                         cudaEvent_t e0, cudaEvent_t e1, float *ms, const char *name) {
  cudaError_t e = cudaEventRecord(e0, stream);
  cudnnStatus_t s = CUDNN_STATUS_SUCCESS;
  for (int r = 0; e == cudaSuccess && s == CUDNN_STATUS_SUCCESS && r < reps; r++)
    s = cudnnBackendExecute(h, op->cand[i].plan, op->varpack);
  if (e == cudaSuccess && s == CUDNN_STATUS_SUCCESS) e = cudaEventRecord(e1, stream);
  if (e == cudaSuccess && s == CUDNN_STATUS_SUCCESS) e = cudaEventSynchronize(e1);
  if (e == cudaSuccess && s == CUDNN_STATUS_SUCCESS) e = cudaEventElapsedTime(ms, e0, e1);
  if (e == cudaSuccess && s == CUDNN_STATUS_SUCCESS) return HF_OK;
  char why[384];
  if (s != CUDNN_STATUS_SUCCESS) {
    unsupported(s, "execute", why, sizeof why);
  } else {
    snprintf(why, sizeof why, "%s", cudaGetErrorString(e));
  }
  char d[256];
  hf_cg_cand_describe(&op->cand[i], d, sizeof d);
  fprintf(stderr, "hfcore cudnn: %s: candidate %d (%s) failed, skipped: %s\n", name, i, d, why);
  op->failed++;
  return hf_cg_clear_cuda_error(stream) ? HF_EBACKEND : HF_EUNSUPPORTED;
}

int hf_cg_op_tune(cudnnHandle_t h, hf_cg_op *op, cudaStream_t stream, const char *name) {
  enum { REPS = 3 };
  int rc;
  cudaEvent_t e0 = NULL, e1 = NULL;
  int best = -1;
  HF_CU_TRY(cudaEventCreate(&e0));
  HF_CU_TRY(cudaEventCreate(&e1));
  for (int i = 0; i < op->ncand; i++) {
    float ms = 0;
    /* The first run also pays any lazy module loading; it is not timed. */
    rc = run_candidate(h, op, i, stream, 1, e0, e1, &ms, name);
    if (rc == HF_OK) rc = run_candidate(h, op, i, stream, REPS, e0, e1, &ms, name);
    if (rc == HF_EBACKEND) goto fail;
    if (rc != HF_OK) continue;
    op->cand[i].time_ms = ms / REPS;
    if (hf_cudnn_verbose()) {
      char d[256];
      hf_cg_cand_describe(&op->cand[i], d, sizeof d);
      fprintf(stderr, "hfcore cudnn: %s: timed candidate %d: %s\n", name, i, d);
    }
    if (best < 0 || op->cand[i].time_ms < op->cand[best].time_ms) best = i;
  }
  if (best < 0) {
    rc = hf_cudnn_report(HF_EBACKEND, "%s: none of %d engine config(s) executes", name,
                         op->ncand);
    goto fail;
  }
  /* Keep only the winner: plans hold device-specific state. */
  for (int i = 0; i < op->ncand; i++)
    if (i != best) cudnnBackendDestroyDescriptor(op->cand[i].plan);
  op->cand[0] = op->cand[best];
  op->ncand = 1;
  rc = HF_OK;
fail:
  if (e0) cudaEventDestroy(e0);
  if (e1) cudaEventDestroy(e1);
  return rc;
}

void hf_cg_op_destroy(hf_cg_op *op) {
  if (!op) return;
  if (op->varpack) cudnnBackendDestroyDescriptor(op->varpack);
  for (int i = 0; i < op->ncand; i++) cudnnBackendDestroyDescriptor(op->cand[i].plan);
  for (int i = op->nkeep - 1; i >= 0; i--) cudnnBackendDestroyDescriptor(op->keep[i]);
  memset(op, 0, sizeof *op);
}

int hf_cg_devprop_from_json(const char *json, cudnnBackendDescriptor_t *out, char *why,
                            size_t whylen) {
  *out = NULL;
  if (cudnnGetVersion() < 90800) {
    snprintf(why, whylen, "cuDNN %zu has no deviceless mode (9.8 or newer needed)",
             cudnnGetVersion());
    return HF_EUNSUPPORTED;
  }
  cudnnBackendDescriptor_t d;
  cudnnStatus_t s = cudnnBackendCreateDescriptor(CUDNN_BACKEND_DEVICEPROP_DESCRIPTOR, &d);
  if (s != CUDNN_STATUS_SUCCESS) return unsupported(s, "device properties", why, whylen);
  s = cudnnBackendSetAttribute(d, CUDNN_ATTR_DEVICEPROP_JSON_REPRESENTATION, CUDNN_TYPE_CHAR,
                               (int64_t)strlen(json) + 1, json);
  if (s == CUDNN_STATUS_SUCCESS) s = cudnnBackendFinalize(d);
  if (s != CUDNN_STATUS_SUCCESS) {
    unsupported(s, "device properties from JSON", why, whylen);
    cudnnBackendDestroyDescriptor(d);
    return HF_EUNSUPPORTED;
  }
  *out = d;
  return HF_OK;
}

int hf_cg_devprop_json(cudnnHandle_t h, char *buf, size_t len) {
  int rc;
  cudnnBackendDescriptor_t d = NULL;
  int64_t n = 0;
  HF_DNN_TRY(cudnnBackendCreateDescriptor(CUDNN_BACKEND_DEVICEPROP_DESCRIPTOR, &d));
  HF_DNN_TRY(cudnnBackendSetAttribute(d, CUDNN_ATTR_DEVICEPROP_HANDLE, CUDNN_TYPE_HANDLE, 1, &h));
  HF_DNN_TRY(cudnnBackendFinalize(d));
  HF_DNN_TRY(cudnnBackendGetAttribute(d, CUDNN_ATTR_DEVICEPROP_JSON_REPRESENTATION,
                                      CUDNN_TYPE_CHAR, 0, &n, NULL));
  if (n < 1 || (size_t)n >= len) {
    rc = hf_cudnn_report(HF_ERANGE, "device properties: %lld bytes of JSON", (long long)n);
    goto fail;
  }
  HF_DNN_TRY(cudnnBackendGetAttribute(d, CUDNN_ATTR_DEVICEPROP_JSON_REPRESENTATION,
                                      CUDNN_TYPE_CHAR, n, &n, buf));
  buf[n < (int64_t)len ? n : (int64_t)len - 1] = 0;
  rc = HF_OK;
fail:
  if (d) cudnnBackendDestroyDescriptor(d);
  return rc;
}
