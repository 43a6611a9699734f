/*
 * One convolution (hf_cl_conv) as a cuDNN 9 graph (backend descriptor API;
 * internal to src/).
 *
 * A forward conv is CONVOLUTION_FORWARD; a data gradient is
 * CONVOLUTION_BACKWARD_DATA. When `fused`, the graph also holds pointwise
 * ADD (bias, FP16 [1][K][1][1]) and, when the conv has one, RELU_FWD, with
 * FP32 virtual tensors in between, so the engine writes the final FP16
 * activation once; otherwise the graph is the convolution alone and the
 * caller adds the bias with a kernel of its own.
 *
 * Building asks the heuristics (mode A, then FALLBACK when A has none) for
 * engine configs, reads each config's engine notes before finalizing it,
 * and keeps up to target->max_cand that finalize into execution plans:
 *   - engines noted NONDETERMINISTIC or REDUCED_PRECISION_REDUCTION are
 *     passed over (a replay must give the same bits, and FP16 reductions
 *     lose the FP32 accumulation the network was checked with);
 *   - at most target->max_rtc engine configs noted RUNTIME_COMPILATION are
 *     finalized per graph: finalizing one compiles a kernel with NVRTC,
 *     which takes on the order of a second.
 * Tuning times the candidates on the real buffers and keeps the fastest.
 *
 * Graphs are built for a target: a live cuDNN handle (plans that execute),
 * or a device-property descriptor alone (cuDNN >= 9.8 deviceless mode:
 * plans that finalize, including run-time compilation, but cannot execute;
 * tests/gpu/test_cudnn_graph checks every layer's descriptors this way on
 * machines without a GPU). The handle is passed through the *_HANDLE
 * attributes, which cuDNN 9.19 marks deprecated in favour of device-property
 * descriptors; they are kept because the cuDNN found at run time may be an
 * older 9.x that knows only them.
 */
#ifndef HF_CUDNN_GRAPH_H
#define HF_CUDNN_GRAPH_H

#include <stdint.h>

#include <cuda_runtime_api.h>
#include <cudnn.h>

#include "cudnn_layout.h"

#define HF_CG_MAX_CAND 8
#define HF_CG_MAX_DESC 64
/* Engine configs needing more workspace than this are passed over. */
#define HF_CG_MAX_WORKSPACE ((int64_t)1 << 30)

/* What graphs are built for, and how many engine configs to keep. */
typedef struct hf_cg_target {
  cudnnHandle_t handle;               /* NULL: deviceless (devprop) */
  cudnnBackendDescriptor_t devprop;   /* a finalized DEVICEPROP descriptor */
  int max_cand;                       /* 1..HF_CG_MAX_CAND */
  int max_rtc;                        /* run-time compiled ones among them, 0.. */
} hf_cg_target;

/* One finalized engine config. Notes are masks of 1 << the cuDNN enum
 * (cudnnBackendNumericalNote_t, cudnnBackendBehaviorNote_t). */
typedef struct hf_cg_cand {
  cudnnBackendDescriptor_t plan;
  int64_t ws;                   /* workspace bytes */
  int64_t engine;               /* CUDNN_ATTR_ENGINE_GLOBAL_INDEX */
  unsigned numerical, behavior;
  double finalize_ms;           /* cudnnBackendFinalize of the plan */
  float time_ms;                /* one execution, after tuning; < 0 unknown */
} hf_cg_cand;

typedef struct hf_cg_op {
  int fused;
  int ncand;
  hf_cg_cand cand[HF_CG_MAX_CAND];   /* heuristic order; after tuning, the winner alone */
  int heur_configs;             /* engine configs the heuristics offered */
  int skipped_notes;            /* passed over for their numerical notes */
  int skipped_rtc;              /* run-time compiled ones beyond max_rtc */
  int failed;                   /* configs that did not finalize or execute */
  double build_ms;              /* descriptors + heuristics + every finalize */
  cudnnBackendDescriptor_t varpack;
  /* Every other descriptor the plans may refer to, freed with the op. */
  cudnnBackendDescriptor_t keep[HF_CG_MAX_DESC];
  int nkeep;
} hf_cg_op;

/* Builds the graph of cv for `batch` frames, reading cv->x and writing
 * cv->y, or the dense tensors of their shapes when dense. Returns HF_OK,
 * HF_EUNSUPPORTED when no engine takes the graph (reason in why), or
 * HF_EBACKEND / HF_ENOMEM. On failure the op holds nothing but its
 * counters. */
int hf_cg_op_build(const hf_cg_target *t, const char *name, const hf_cl_conv *cv, int batch,
                   int dense, int fused, hf_cg_op *op, char *why, size_t whylen);

/* Largest workspace any candidate needs. */
int64_t hf_cg_op_max_workspace(const hf_cg_op *op);

/* Device pointers of one execution: x (in), w, y (out), bias (FP16, fused
 * graphs only) and the workspace. */
int hf_cg_op_bind(hf_cg_op *op, void *x, void *w, void *y, void *bias, void *workspace);

/* Times every candidate (after one untimed run each) on stream and keeps
 * the fastest. A candidate that fails to execute, or whose kernels fail,
 * is dropped and the CUDA error it left is cleared; HF_EBACKEND only when
 * none runs, or when the failure left the CUDA context unusable. */
int hf_cg_op_tune(cudnnHandle_t h, hf_cg_op *op, cudaStream_t stream, const char *name);

/* Enqueues the chosen plan (cand[0] after tuning) on the handle's stream. */
int hf_cg_op_exec(cudnnHandle_t h, const hf_cg_op *op);

/* "engine 42 [tensor_core,rtc], finalize 1523.4 ms" for candidate i. */
void hf_cg_cand_describe(const hf_cg_cand *c, char *buf, size_t len);

void hf_cg_op_destroy(hf_cg_op *op);

/* A DEVICEPROP descriptor from its JSON representation (as cuDNN writes it
 * with hf_cg_devprop_json). HF_EUNSUPPORTED when this cuDNN has no
 * deviceless mode or refuses the JSON (why says which). */
int hf_cg_devprop_from_json(const char *json, cudnnBackendDescriptor_t *out, char *why,
                            size_t whylen);
/* The JSON representation of the device behind handle h, NUL-terminated in
 * buf; HF_ERANGE when len is too small. */
int hf_cg_devprop_json(cudnnHandle_t h, char *buf, size_t len);

/* Clears a CUDA error a failed launch left behind. Returns HF_OK when the
 * context is still usable (the error was not sticky), else HF_EBACKEND
 * with the reason recorded. */
int hf_cg_clear_cuda_error(cudaStream_t stream);

#endif /* HF_CUDNN_GRAPH_H */
