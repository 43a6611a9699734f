/*
 * Error plumbing for the cudnn backend (internal to src/).
 *
 * Every CUDA runtime and cuDNN call goes through HF_CU_TRY / HF_DNN_TRY,
 * which turn a failure into HF_EBACKEND, log the library's own message to
 * stderr and keep it as this thread's last cudnn error, so a caller that
 * only sees the code can still ask what went wrong.
 *
 * The *_TRY macros jump to a label named `fail` after setting `rc`; the
 * function using them declares `int rc` and owns the cleanup there.
 */
#ifndef HF_CUDNN_UTIL_H
#define HF_CUDNN_UTIL_H

#include <stddef.h>

#include <cuda_runtime_api.h>
#include <cudnn.h>

#include "hfcore.h"

/* Records and logs a failed call; returns HF_EBACKEND. */
int hf_cu_report(cudaError_t e, const char *call, const char *file, int line);
int hf_dnn_report(cudnnStatus_t s, const char *call, const char *file, int line);
/* Records a failure that is not a library status (e.g. no engine found). */
int hf_cudnn_report(int rc, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* The last message recorded on this thread ("" when none). */
const char *hf_cudnn_last_error(void);
/* Non-zero when HF_CUDNN_VERBOSE is set: plan choices and expected
 * fallbacks (a fused graph no engine takes) are then logged too. */
int hf_cudnn_verbose(void);

#define HF_CU_TRY(call)                                                   \
  do {                                                                    \
    cudaError_t hf_e_ = (call);                                           \
    if (hf_e_ != cudaSuccess) {                                           \
      rc = hf_cu_report(hf_e_, #call, __FILE__, __LINE__);                \
      goto fail;                                                          \
    }                                                                     \
  } while (0)

#define HF_DNN_TRY(call)                                                  \
  do {                                                                    \
    cudnnStatus_t hf_s_ = (call);                                         \
    if (hf_s_ != CUDNN_STATUS_SUCCESS) {                                  \
      rc = hf_dnn_report(hf_s_, #call, __FILE__, __LINE__);               \
      goto fail;                                                          \
    }                                                                     \
  } while (0)

#define HF_TRY(expr)                                                      \
  do {                                                                    \
    rc = (expr);                                                          \
    if (rc) goto fail;                                                    \
  } while (0)

/* Overflow-checked size arithmetic: 0 on success, HF_ERANGE on overflow. */
static inline int hf_size_mul(size_t a, size_t b, size_t *out) {
  if (a && b > (size_t)-1 / a) return HF_ERANGE;
  *out = a * b;
  return 0;
}
static inline int hf_size_add(size_t a, size_t b, size_t *out) {
  if (b > (size_t)-1 - a) return HF_ERANGE;
  *out = a + b;
  return 0;
}

#endif /* HF_CUDNN_UTIL_H */
