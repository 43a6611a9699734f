/* Internal to src/: filling a caller's error buffer. */
#ifndef HF_ERRORS_H
#define HF_ERRORS_H

#include <stddef.h>

/* Formats a one-line reason into err (when err is not NULL) and returns rc,
 * so failures read `return hf_fail_msg(err, len, HF_EFORMAT, "...", ...)`. */
int hf_fail_msg(char *err, size_t errlen, int rc, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

#endif
