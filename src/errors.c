/* Error codes to text, and error messages for callers. */
#include <stdarg.h>
#include <stdio.h>

#include "errors.h"
#include "hfcore.h"

const char *hf_strerror(int err) {
  switch (err) {
  case HF_OK:           return "success";
  case HF_EINVAL:       return "invalid argument";
  case HF_ENOMEM:       return "out of memory";
  case HF_EIO:          return "input/output error";
  case HF_EFORMAT:      return "malformed or inconsistent data";
  case HF_EUNSUPPORTED: return "not supported by this build";
  case HF_EUNAVAILABLE: return "backend unavailable on this machine";
  case HF_ERANGE:       return "size or count out of range";
  case HF_EBACKEND:     return "backend library error";
  case HF_ENOTFOUND:    return "not found";
  default:              return "unknown error";
  }
}

int hf_fail_msg(char *err, size_t errlen, int rc, const char *fmt, ...) {
  if (err && errlen) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
  }
  return rc;
}
