/* Test helper: see test_paths.h. */
#define _XOPEN_SOURCE 700
#include <stdio.h>
#include <stdlib.h>

#include "test_paths.h"

#ifndef HF_TEST_DATA
#error "HF_TEST_DATA must name tests/data"
#endif

static char dir[256];

static char *ring(void) {
  static char buf[8][512];
  static int k;
  return buf[k++ % 8];
}

const char *test_field(const char *name) {
  char *p = ring();
  snprintf(p, 512, "%s/field/%s", HF_TEST_DATA, name);
  return p;
}

const char *test_data(const char *name) {
  char *p = ring();
  snprintf(p, 512, "%s/%s", HF_TEST_DATA, name);
  return p;
}

int test_tmp_create(const char *prefix) {
  snprintf(dir, sizeof dir, "/tmp/%s_XXXXXX", prefix);
  return mkdtemp(dir) ? 0 : -1;
}

const char *test_tmp(const char *name) {
  char *p = ring();
  snprintf(p, 512, "%s/%s", dir, name);
  return p;
}

const char *test_tmp_dir(void) { return dir; }

int test_tmp_remove(void) {
  char cmd[300];
  snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
  return system(cmd) == 0 ? 0 : -1;
}
