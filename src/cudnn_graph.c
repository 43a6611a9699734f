/* One convolution layer as a cuDNN 9 graph: see cudnn_graph.h. */
#include <stdbool.h>
#include <stdio.h>
#include <string.h>

#include "cudnn_graph.h"
#include "cudnn_util.h"

/* Tensor ids within one layer graph. */
enum { UID_X = 1, UID_W = 2, UID_Y = 3, UID_B = 4, UID_CONV = 5, UID_ADD = 6 };

#define MAX_HEUR_RESULTS 16

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

static int tensor(hf_cg_op *op, int64_t uid, cudnnDataType_t dt, const int64_t dims[4],
                  const int64_t strides[4], bool is_virtual, cudnnBackendDescriptor_t *t,
                  char *why, size_t whylen) {
  int rc = create(op, CUDNN_BACKEND_TENSOR_DESCRIPTOR, t);
  if (rc) return rc;
  /* Every real tensor starts on at least 16 bytes: buffers come from
   * cudaMalloc (256) and channel offsets are multiples of 8 FP16. */
  const int64_t alignment = 16;
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

/* cuDNN describes every tensor by NCHW-ordered dims; NHWC is in the strides.
 * A view with pix_stride > c (a half of a skip buffer) is expressed the same
 * way, with the larger pixel stride. */
static void nhwc(int64_t n, int64_t c, int64_t h, int64_t w, int64_t pix_stride, int64_t dims[4],
                 int64_t strides[4]) {
  dims[0] = n; dims[1] = c; dims[2] = h; dims[3] = w;
  strides[0] = h * w * pix_stride; strides[1] = 1; strides[2] = w * pix_stride;
  strides[3] = pix_stride;
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

/* Asks the heuristics for engine configs and keeps those that finalize
 * into execution plans, best first. */
static int make_plans(cudnnHandle_t h, hf_cg_op *op, cudnnBackendDescriptor_t graph, char *why,
                      size_t whylen) {
  static const cudnnBackendHeurMode_t modes[] = {CUDNN_HEUR_MODE_A, CUDNN_HEUR_MODE_FALLBACK};
  int rc = HF_EUNSUPPORTED;
  for (size_t m = 0; m < sizeof modes / sizeof modes[0] && op->ncand == 0; m++) {
    cudnnBackendDescriptor_t heur;
    if ((rc = create(op, CUDNN_BACKEND_ENGINEHEUR_DESCRIPTOR, &heur)) != 0) return rc;
    cudnnStatus_t s = cudnnBackendSetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_OPERATION_GRAPH,
                                               CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &graph);
    if (s == CUDNN_STATUS_SUCCESS)
      s = cudnnBackendSetAttribute(heur, CUDNN_ATTR_ENGINEHEUR_MODE, CUDNN_TYPE_HEUR_MODE, 1,
                                   &modes[m]);
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
    for (int64_t i = 0; i < got && i < count && op->ncand < HF_CG_MAX_CAND; i++) {
      cudnnBackendDescriptor_t plan;
      s = cudnnBackendCreateDescriptor(CUDNN_BACKEND_EXECUTION_PLAN_DESCRIPTOR, &plan);
      if (s != CUDNN_STATUS_SUCCESS)
        return hf_dnn_report(s, "cudnnBackendCreateDescriptor(plan)", __FILE__, __LINE__);
      int64_t ws = 0, nws = 0;
      s = cudnnBackendSetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_HANDLE, CUDNN_TYPE_HANDLE, 1,
                                   &h);
      if (s == CUDNN_STATUS_SUCCESS)
        s = cudnnBackendSetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_ENGINE_CONFIG,
                                     CUDNN_TYPE_BACKEND_DESCRIPTOR, 1, &cfg[i]);
      if (s == CUDNN_STATUS_SUCCESS) s = cudnnBackendFinalize(plan);
      if (s == CUDNN_STATUS_SUCCESS)
        s = cudnnBackendGetAttribute(plan, CUDNN_ATTR_EXECUTION_PLAN_WORKSPACE_SIZE,
                                     CUDNN_TYPE_INT64, 1, &nws, &ws);
      if (s != CUDNN_STATUS_SUCCESS || ws < 0 || ws > HF_CG_MAX_WORKSPACE) {
        if (s != CUDNN_STATUS_SUCCESS) rc = unsupported(s, "execution plan", why, whylen);
        cudnnBackendDestroyDescriptor(plan);
        continue;
      }
      op->cand[op->ncand] = plan;
      op->cand_ws[op->ncand] = ws;
      op->ncand++;
    }
  }
  return op->ncand > 0 ? HF_OK : (rc ? rc : HF_EUNSUPPORTED);
}

int hf_cg_op_build(cudnnHandle_t h, const hf_cl_layer *ly, int batch, const hf_cl_view *in,
                   const hf_cl_view *out, int fused, hf_cg_op *op, char *why, size_t whylen) {
  memset(op, 0, sizeof *op);
  op->fused = fused;
  if (why && whylen) why[0] = 0;
  int rc;
  const int fwd = hf_cl_is_fwd(ly);
  /* Forward: x has C channels, y has K. Data gradient: dy has K, dx has C. */
  if (in->c != (fwd ? ly->c : ly->k) || out->c != (fwd ? ly->k : ly->c))
    return hf_cudnn_report(HF_EINVAL, "%s: view channels do not match the filter", ly->name);
  const int ych = out->c;

  int64_t dims[4], strides[4];
  cudnnBackendDescriptor_t tx, tw, ty, tb = NULL, tconv, tadd = NULL;
  nhwc(batch, in->c, in->h, in->w, in->pix_stride, dims, strides);
  if ((rc = tensor(op, UID_X, CUDNN_DATA_HALF, dims, strides, false, &tx, why, whylen))) goto fail;
  nhwc(ly->k, ly->c, ly->r, ly->s, ly->c, dims, strides);
  if ((rc = tensor(op, UID_W, CUDNN_DATA_HALF, dims, strides, false, &tw, why, whylen))) goto fail;
  nhwc(batch, out->c, out->h, out->w, out->pix_stride, dims, strides);
  if ((rc = tensor(op, UID_Y, CUDNN_DATA_HALF, dims, strides, false, &ty, why, whylen))) goto fail;
  if (fused) {
    /* Accumulate and apply the epilogue in FP32, store FP16 once. */
    nhwc(1, ych, 1, 1, ych, dims, strides);
    if ((rc = tensor(op, UID_B, CUDNN_DATA_HALF, dims, strides, false, &tb, why, whylen)))
      goto fail;
    nhwc(batch, ych, out->h, out->w, ych, dims, strides);
    if ((rc = tensor(op, UID_CONV, CUDNN_DATA_FLOAT, dims, strides, true, &tconv, why, whylen)))
      goto fail;
    if (ly->relu &&
        (rc = tensor(op, UID_ADD, CUDNN_DATA_FLOAT, dims, strides, true, &tadd, why, whylen)))
      goto fail;
  } else {
    tconv = ty;
  }

  cudnnBackendDescriptor_t conv;
  if ((rc = create(op, CUDNN_BACKEND_CONVOLUTION_DESCRIPTOR, &conv))) goto fail;
  {
    const int64_t nsd = 2, pad[2] = {ly->pad, ly->pad}, dil[2] = {1, 1},
                  str[2] = {ly->stride, ly->stride};
    const cudnnDataType_t comp = CUDNN_DATA_FLOAT;
    const cudnnConvolutionMode_t mode = CUDNN_CROSS_CORRELATION;
    SET(conv, CUDNN_ATTR_CONVOLUTION_SPATIAL_DIMS, CUDNN_TYPE_INT64, 1, &nsd);
    SET(conv, CUDNN_ATTR_CONVOLUTION_COMP_TYPE, CUDNN_TYPE_DATA_TYPE, 1, &comp);
    SET(conv, CUDNN_ATTR_CONVOLUTION_CONV_MODE, CUDNN_TYPE_CONVOLUTION_MODE, 1, &mode);
    SET(conv, CUDNN_ATTR_CONVOLUTION_PRE_PADDINGS, CUDNN_TYPE_INT64, 2, pad);
    SET(conv, CUDNN_ATTR_CONVOLUTION_POST_PADDINGS, CUDNN_TYPE_INT64, 2, pad);
    SET(conv, CUDNN_ATTR_CONVOLUTION_DILATIONS, CUDNN_TYPE_INT64, 2, dil);
    SET(conv, CUDNN_ATTR_CONVOLUTION_FILTER_STRIDES, CUDNN_TYPE_INT64, 2, str);
    FINALIZE(conv, "convolution descriptor");
  }

  cudnnBackendDescriptor_t ops[3];
  int nops = 0;
  {
    const float alpha = 1.0f, beta = 0.0f;
    cudnnBackendDescriptor_t cop;
    if (fwd) {
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
    if ((rc = pointwise(op, CUDNN_POINTWISE_ADD, tconv, tb, ly->relu ? tadd : ty, &add, why,
                        whylen)))
      goto fail;
    ops[nops++] = add;
    if (ly->relu) {
      if ((rc = pointwise(op, CUDNN_POINTWISE_RELU_FWD, tadd, NULL, ty, &relu, why, whylen)))
        goto fail;
      ops[nops++] = relu;
    }
  }

  cudnnBackendDescriptor_t graph;
  if ((rc = create(op, CUDNN_BACKEND_OPERATIONGRAPH_DESCRIPTOR, &graph))) goto fail;
  SET(graph, CUDNN_ATTR_OPERATIONGRAPH_OPS, CUDNN_TYPE_BACKEND_DESCRIPTOR, nops, ops);
  SET(graph, CUDNN_ATTR_OPERATIONGRAPH_HANDLE, CUDNN_TYPE_HANDLE, 1, &h);
  FINALIZE(graph, "operation graph");

  if ((rc = make_plans(h, op, graph, why, whylen))) goto fail;
  if (hf_cudnn_verbose())
    fprintf(stderr, "hfcore cudnn: %s: %s%s graph, %d engine config(s)\n", ly->name,
            fused ? "fused" : "unfused",
            (in->pix_stride != in->c || out->pix_stride != out->c) ? " strided" : "", op->ncand);
  return HF_OK;
fail:
  hf_cg_op_destroy(op);
  op->fused = fused;
  return rc;
}

int64_t hf_cg_op_max_workspace(const hf_cg_op *op) {
  int64_t m = 0;
  for (int i = 0; i < op->ncand; i++)
    if (op->cand_ws[i] > m) m = op->cand_ws[i];
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
  HF_DNN_TRY(cudnnBackendExecute(h, op->cand[op->chosen], op->varpack));
  return HF_OK;
fail:
  return rc;
}

int hf_cg_op_tune(cudnnHandle_t h, hf_cg_op *op, cudaStream_t stream, const char *name) {
  enum { REPS = 3 };
  int rc;
  cudaEvent_t e0 = NULL, e1 = NULL;
  float best_ms = 0;
  int best = -1;
  HF_CU_TRY(cudaEventCreate(&e0));
  HF_CU_TRY(cudaEventCreate(&e1));
  for (int i = 0; i < op->ncand; i++) {
    /* The first run also pays any lazy module loading; it is not timed. */
    cudnnStatus_t s = cudnnBackendExecute(h, op->cand[i], op->varpack);
    if (s != CUDNN_STATUS_SUCCESS) {
      char why[256];
      unsupported(s, "execute candidate plan", why, sizeof why);
      continue;
    }
    HF_CU_TRY(cudaStreamSynchronize(stream));
    if (op->ncand == 1) {
      best = 0;
      break;
    }
    HF_CU_TRY(cudaEventRecord(e0, stream));
    for (int r = 0; r < REPS; r++)
      HF_DNN_TRY(cudnnBackendExecute(h, op->cand[i], op->varpack));
    HF_CU_TRY(cudaEventRecord(e1, stream));
    HF_CU_TRY(cudaEventSynchronize(e1));
    float ms = 0;
    HF_CU_TRY(cudaEventElapsedTime(&ms, e0, e1));
    if (hf_cudnn_verbose())
      fprintf(stderr, "hfcore cudnn: %s: candidate %d: %.4f ms, workspace %lld bytes\n", name,
              i, ms / REPS, (long long)op->cand_ws[i]);
    if (best < 0 || ms < best_ms) {
      best = i;
      best_ms = ms;
    }
  }
  if (best < 0) {
    rc = hf_cudnn_report(HF_EBACKEND, "%s: no engine config executes: %s", name,
                         hf_cudnn_last_error());
    goto fail;
  }
  /* Keep only the winner: plans hold device-specific state. */
  for (int i = 0; i < op->ncand; i++)
    if (i != best) cudnnBackendDestroyDescriptor(op->cand[i]);
  op->cand[0] = op->cand[best];
  op->cand_ws[0] = op->cand_ws[best];
  op->ncand = 1;
  op->chosen = 0;
  rc = HF_OK;
fail:
  if (e0) cudaEventDestroy(e0);
  if (e1) cudaEventDestroy(e1);
  return rc;
}

void hf_cg_op_destroy(hf_cg_op *op) {
  if (!op) return;
  if (op->varpack) cudnnBackendDestroyDescriptor(op->varpack);
  for (int i = 0; i < op->ncand; i++) cudnnBackendDestroyDescriptor(op->cand[i]);
  for (int i = op->nkeep - 1; i >= 0; i--) cudnnBackendDestroyDescriptor(op->keep[i]);
  memset(op, 0, sizeof *op);
}
