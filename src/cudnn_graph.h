/*
 * One convolution layer as a cuDNN 9 graph (backend descriptor API;
 * internal to src/).
 *
 * A forward conv (enc) is CONVOLUTION_FORWARD; a transposed conv (dec) is
 * CONVOLUTION_BACKWARD_DATA of the conv it transposes. When `fused`, the
 * graph also holds pointwise ADD (bias, FP16 [1][K][1][1]) and RELU_FWD
 * with FP32 virtual tensors in between, so the engine writes the final FP16
 * activation once; otherwise the graph is the convolution alone and the
 * caller adds the bias with hf_cuk_bias_act.
 *
 * Building asks the heuristics (mode A, then FALLBACK) for engine configs
 * and keeps up to HF_CG_MAX_CAND that finalize into execution plans; tuning
 * times them on the real buffers and keeps the fastest.
 *
 * The graph and plan descriptors take the cuDNN handle through the
 * *_HANDLE attributes, which cuDNN 9.19 marks deprecated in favour of
 * device-property descriptors; they are kept because the cuDNN found at run
 * time may be an older 9.x that knows only them.
 */
#ifndef HF_CUDNN_GRAPH_H
#define HF_CUDNN_GRAPH_H

#include <stdint.h>

#include <cuda_runtime_api.h>
#include <cudnn.h>

#include "cudnn_layout.h"

#define HF_CG_MAX_CAND 4
#define HF_CG_MAX_DESC 64
/* Engine configs needing more workspace than this are passed over. */
#define HF_CG_MAX_WORKSPACE ((int64_t)1 << 30)

typedef struct hf_cg_op {
  int fused;
  int ncand;
  cudnnBackendDescriptor_t cand[HF_CG_MAX_CAND];  /* finalized plans, heuristic order */
  int64_t cand_ws[HF_CG_MAX_CAND];
  int chosen;                                     /* index into cand */
  cudnnBackendDescriptor_t varpack;
  /* Every other descriptor the plans may refer to, freed with the op. */
  cudnnBackendDescriptor_t keep[HF_CG_MAX_DESC];
  int nkeep;
} hf_cg_op;

/* Builds the graph for ly reading `in` and writing `out` (views of ly's
 * shapes, possibly with other strides) for `batch` frames. Returns HF_OK,
 * HF_EUNSUPPORTED when no engine takes the graph (reason in why), or
 * HF_EBACKEND / HF_ENOMEM. On failure the op holds nothing. */
int hf_cg_op_build(cudnnHandle_t h, const hf_cl_layer *ly, int batch, const hf_cl_view *in,
                   const hf_cl_view *out, int fused, hf_cg_op *op, char *why, size_t whylen);

/* Largest workspace any candidate needs. */
int64_t hf_cg_op_max_workspace(const hf_cg_op *op);

/* Device pointers of one execution: x (in), w, y (out), bias (FP16, fused
 * graphs only) and the workspace. */
int hf_cg_op_bind(hf_cg_op *op, void *x, void *w, void *y, void *bias, void *workspace);

/* Times every candidate (after one untimed run each) on stream and keeps
 * the fastest; candidates that fail to execute are dropped. With one
 * candidate it only checks that it runs. */
int hf_cg_op_tune(cudnnHandle_t h, hf_cg_op *op, cudaStream_t stream, const char *name);

/* Enqueues the chosen plan on the handle's stream. */
int hf_cg_op_exec(cudnnHandle_t h, const hf_cg_op *op);

void hf_cg_op_destroy(hf_cg_op *op);

#endif /* HF_CUDNN_GRAPH_H */
