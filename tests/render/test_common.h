/* Helpers shared by the renderer's GL tests (include after cmocka.h). */
#ifndef HF_TEST_RENDER_COMMON_H
#define HF_TEST_RENDER_COMMON_H

#include <stdio.h>
#include <stdlib.h>

#include <cjson/cJSON.h>

#include "hr_internal.h"

/* The suite's renderer (OSMesa), made by setup, destroyed by teardown. */
static hfr_renderer *R;

static int setup(void **state) {
  (void)state;
  char err[512] = "";
  int rc = hfr_renderer_create("osmesa", &R, err, sizeof err);
  if (rc != HF_OK) fprintf(stderr, "renderer: %s\n", err);
  return rc == HF_OK ? 0 : -1;
}

static int teardown(void **state) {
  (void)state;
  hfr_renderer_destroy(R);
  return 0;
}

/* The whole file, NUL-terminated (freed by the caller). */
static char *slurp(const char *path) {
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  assert_int_equal(fseek(f, 0, SEEK_END), 0);
  long n = ftell(f);
  assert_true(n > 0 && n < (1 << 24));
  rewind(f);
  char *b = malloc((size_t)n + 1);
  assert_non_null(b);
  assert_int_equal(fread(b, 1, (size_t)n, f), (size_t)n);
  b[n] = 0;
  fclose(f);
  return b;
}

/* Runs dataset mode, puts the suite's context r back, and returns the
 * parsed DIR/manifest.json (cJSON_Delete it). */
static cJSON *run_dataset(const hfr_dataset_opts *o, hfr_renderer *r) {
  char err[512] = "", path[600];
  int rc = hfr_dataset_run(o, err, sizeof err);
  if (rc != HF_OK) fail_msg("dataset: %s", err);
  assert_int_equal(hr_renderer_bind(r), HF_OK);
  snprintf(path, sizeof path, "%s/manifest.json", o->out_dir);
  char *text = slurp(path);
  cJSON *doc = cJSON_Parse(text);
  free(text);
  assert_non_null(doc);
  return doc;
}

#endif
