/* Error plumbing for the cudnn backend: see cudnn_util.h. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cudnn_util.h"

static _Thread_local char last_error[512];

const char *hf_cudnn_last_error(void) { return last_error; }

int hf_cudnn_verbose(void) {
  const char *v = getenv("HF_CUDNN_VERBOSE");
  return v && v[0] && strcmp(v, "0") != 0;
}

static const char *base_name(const char *path) {
  const char *s = strrchr(path, '/');
  return s ? s + 1 : path;
}

int hf_cu_report(cudaError_t e, const char *call, const char *file, int line) {
  snprintf(last_error, sizeof last_error, "%s:%d: %s: %s (%s)", base_name(file), line, call,
           cudaGetErrorString(e), cudaGetErrorName(e));
  fprintf(stderr, "hfcore cudnn: %s\n", last_error);
  return HF_EBACKEND;
}

int hf_dnn_report(cudnnStatus_t s, const char *call, const char *file, int line) {
  /* cuDNN 9 keeps a more specific message than the status name. */
  char detail[256] = "";
  cudnnGetLastErrorString(detail, sizeof detail);
  snprintf(last_error, sizeof last_error, "%s:%d: %s: %s%s%s", base_name(file), line, call,
           cudnnGetErrorString(s), detail[0] ? ": " : "", detail);
  fprintf(stderr, "hfcore cudnn: %s\n", last_error);
  return HF_EBACKEND;
}

int hf_cudnn_report(int rc, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(last_error, sizeof last_error, fmt, ap);
  va_end(ap);
  fprintf(stderr, "hfcore cudnn: %s\n", last_error);
  return rc;
}
