/* An LD_PRELOAD shim that makes reading a weights file slow: fopen of a
 * path ending in .safetensors (and holding $HF_TEST_SLOW_WEIGHTS_MATCH,
 * when set) first sleeps $HF_TEST_SLOW_WEIGHTS_MS milliseconds, as a slow
 * disk or a GPU's model build makes each one take, so a test can act while
 * a daemon on the cpu backend is still loading its models (a second for
 * all the bundled ones otherwise). Other files are opened as they are. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static void slow_down(const char *path) {
  const char *ms = getenv("HF_TEST_SLOW_WEIGHTS_MS");
  size_t n = path ? strlen(path) : 0, m = strlen(".safetensors");
  const char *match = getenv("HF_TEST_SLOW_WEIGHTS_MATCH");
  if (!ms || n < m || strcmp(path + n - m, ".safetensors")) return;
  if (match && !strstr(path, match)) return;
  long v = strtol(ms, NULL, 10);
  if (v <= 0) return;
  struct timespec ts = {v / 1000, (v % 1000) * 1000000L};
  /* Resumed after a signal: the whole delay, whatever comes meanwhile. */
  while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
  }
}

FILE *fopen(const char *path, const char *mode) {
  static FILE *(*real)(const char *, const char *);
  if (!real) real = (FILE *(*)(const char *, const char *))dlsym(RTLD_NEXT, "fopen");
  if (!real) return NULL;
  slow_down(path);
  return real(path, mode);
}

FILE *fopen64(const char *path, const char *mode) {
  static FILE *(*real)(const char *, const char *);
  if (!real) real = (FILE *(*)(const char *, const char *))dlsym(RTLD_NEXT, "fopen64");
  if (!real) return NULL;
  slow_down(path);
  return real(path, mode);
}
