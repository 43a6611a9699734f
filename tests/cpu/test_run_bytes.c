/* hf_run_bytes is an upper bound of what a run really takes: for each CPU
 * backend, variant and size below, the process's peak resident memory grows
 * by no more than the estimate while the model runs a frame size it has not
 * seen; the plan a backend keeps is no larger than the estimate either; and
 * hf_model_trim gives that memory back; and models on one cpu backend keep
 * one set of activations between them, not one each. The daemon admits frames on these
 * estimates (docs/SERVER.md, "Memory"), so an estimate that is low is a bug.
 *
 * Peak RSS is read from /proc/self/status (VmHWM) after resetting it
 * (tests/common/proc_memory.h). Under AddressSanitizer, whose quarantine
 * keeps freed memory resident, only the plan sizes are checked. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <malloc.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"
#include "proc_memory.h"


typedef struct run_case {
  const char *variant;
  int w, h, batch;
} run_case;

static void check_backend(const char *backend, const run_case *cases, int ncases) {
  hf_backend *b = NULL;
  char why[256];
  assert_int_equal(hf_backend_create(backend, &b, why, sizeof why), 0);
  int rss_ok = !UNDER_ASAN && proc_reset_peak(0) == 0 && proc_status_kb(0, "VmHWM") > 0;
  if (!rss_ok) fprintf(stderr, "%s: peak RSS not checked (%s)\n", backend,
                       UNDER_ASAN ? "AddressSanitizer keeps freed memory" : "no clear_refs");
  for (int k = 0; k < ncases; k++) {
    const run_case *rc = &cases[k];
    hf_net_config cfg;
    assert_int_equal(hf_variant_preset(rc->variant, &cfg), 0);
    hf_weights *w = NULL;
    assert_int_equal(hf_weights_init_random(&cfg, 7, &w), 0);
    hf_model *m = NULL;
    assert_int_equal(hf_model_create(b, w, &m), 0);
    hf_weights_free(w);
    size_t nin = (size_t)rc->batch * rc->w * rc->h * cfg.in_channels;
    size_t nout = (size_t)rc->batch * rc->w * rc->h * 3;
    float *in = malloc(nin * sizeof *in), *out = malloc(nout * sizeof *out);
    assert_non_null(in);
    assert_non_null(out);
    for (size_t i = 0; i < nin; i++) in[i] = (float)(i % 97) / 97.0f;
    memset(out, 0, nout * sizeof *out);
    /* Warm up the backend's threads on a small frame, then forget every
     * plan, so that the measured run builds its own. */
    hf_io small = {1, 8, 8, in, HF_F32, out, HF_F32};
    assert_int_equal(hf_model_run(m, &small, NULL), 0);
    hf_model_trim(m, 0);
    assert_int_equal(hf_model_cached_bytes(m), 0);
    malloc_trim(0);
    size_t est = hf_run_bytes(b, &cfg, rc->w, rc->h, rc->batch);
    assert_true(est > 0);
    long rss0 = 0;
    if (rss_ok) {
      assert_int_equal(proc_reset_peak(0), 0);
      rss0 = proc_status_kb(0, "VmRSS");
    }
    hf_io io = {rc->batch, rc->w, rc->h, in, HF_F32, out, HF_F32};
    assert_int_equal(hf_model_run(m, &io, NULL), 0);
    size_t cached = hf_model_cached_bytes(m);
    long grew_kb = rss_ok ? proc_status_kb(0, "VmHWM") - rss0 : 0;
    printf("%-8s %-9s %4dx%-4d batch %d: estimate %8.2f MiB, peak RSS grew %8.2f MiB, "
           "plan kept %8.2f MiB\n", backend, rc->variant, rc->w, rc->h, rc->batch,
           est / 1048576.0, grew_kb / 1024.0, cached / 1048576.0);
    assert_true(cached <= est);
    if (rss_ok) assert_true((size_t)grew_kb * 1024 <= est);
    /* What the run kept goes back. */
    hf_model_trim(m, 0);
    assert_int_equal(hf_model_cached_bytes(m), 0);
    malloc_trim(0);
    if (rss_ok) {
      long after = proc_status_kb(0, "VmRSS");
      /* Within 2 MiB of before: allocator bookkeeping, not the plan. */
      assert_true(after - rss0 < 2048);
    }
    /* Estimates grow with the frame and the batch. */
    int a = hf_net_align(&cfg);
    assert_true(hf_run_bytes(b, &cfg, rc->w + a, rc->h, rc->batch) > est);
    assert_true(hf_run_bytes(b, &cfg, rc->w, rc->h, rc->batch + 1) > est);
    free(in);
    free(out);
    hf_model_destroy(m);
  }
  /* Out of range: no estimate. */
  hf_net_config cfg;
  assert_int_equal(hf_variant_preset("Small", &cfg), 0);
  assert_int_equal(hf_run_bytes(b, &cfg, 0, 8, 1), 0);
  assert_int_equal(hf_run_bytes(b, &cfg, 8, 8, 0), 0);
  assert_int_equal(hf_run_bytes(b, &cfg, 20000, 8, 1), 0);
  assert_int_equal(hf_run_bytes(NULL, &cfg, 8, 8, 1), 0);
  hf_backend_destroy(b);
}

static void test_cpu_ref(void **state) {
  (void)state;
  static const run_case cases[] = {
    {"Small", 192, 128, 1},
    {"Base", 128, 72, 2},
    {"Residual", 96, 96, 1},
    {"Kernel", 96, 64, 2},
    {"Deep", 64, 48, 1},
  };
  check_backend("cpu-ref", cases, (int)(sizeof cases / sizeof cases[0]));
}

#ifdef HF_HAVE_ONEDNN
static void test_cpu(void **state) {
  (void)state;
  static const run_case cases[] = {
    {"Small", 512, 384, 1},
    {"Base", 300, 200, 2},
    {"Residual", 256, 256, 1},
    {"Kernel", 384, 256, 2},
    {"Deep", 160, 96, 1},
    {"Large", 8, 8, 1},
  };
  check_backend("cpu", cases, (int)(sizeof cases / sizeof cases[0]));
}

/* One model of each variant on its own backend: its output and what it
 * keeps after one run of w x h. */
typedef struct alone {
  float *out;
  size_t cached;
} alone;

static hf_model *shared_model(hf_backend *b, const char *variant) {
  hf_net_config cfg;
  hf_weights *w = NULL;
  hf_model *m = NULL;
  assert_int_equal(hf_variant_preset(variant, &cfg), 0);
  assert_int_equal(hf_weights_init_random(&cfg, 11, &w), 0);
  assert_int_equal(hf_model_create(b, w, &m), 0);
  hf_weights_free(w);
  return m;
}

static void shared_run(hf_model *m, const float *in, int w, int h, float *out) {
  hf_io io = {1, w, h, in, HF_F32, out, HF_F32};
  assert_int_equal(hf_model_run(m, &io, NULL), 0);
}

/* Models on one cpu backend share their activations: after Base and
 * Residual both ran a size, the two keep about what the larger alone
 * keeps, not the sum; the second's run grows the peak RSS by a fraction of
 * its estimate; each output is bit for bit what the model gives alone,
 * also after the other ran in between; and trimming one model leaves the
 * shared memory counted by the other, trimming both gives it back. */
static void test_cpu_shared_activations(void **state) {
  (void)state;
  static const char *variant[2] = {"Base", "Residual"};
  const int w = 320, h = 256;
  const size_t npx = (size_t)w * h;
  hf_net_config cfg;
  assert_int_equal(hf_variant_preset("Base", &cfg), 0);
  float *in = malloc(npx * cfg.in_channels * sizeof *in), *out = malloc(npx * 3 * sizeof *out);
  assert_non_null(in);
  assert_non_null(out);
  /* Inside the feature contract (every feature in [0.25, 0.75]), so that
   * no model keeps a sanitised copy of it. */
  for (size_t i = 0; i < npx * cfg.in_channels; i++) in[i] = 0.25f + (float)(i % 89) / 178.0f;
  char why[256];
  alone a[2];
  for (int k = 0; k < 2; k++) {
    hf_backend *b = NULL;
    assert_int_equal(hf_backend_create("cpu", &b, why, sizeof why), 0);
    hf_model *m = shared_model(b, variant[k]);
    a[k].out = malloc(npx * 3 * sizeof(float));
    assert_non_null(a[k].out);
    shared_run(m, in, w, h, a[k].out);
    a[k].cached = hf_model_cached_bytes(m);
    hf_model_destroy(m);
    hf_backend_destroy(b);
  }

  hf_backend *b = NULL;
  assert_int_equal(hf_backend_create("cpu", &b, why, sizeof why), 0);
  hf_model *m[2] = {shared_model(b, variant[0]), shared_model(b, variant[1])};
  shared_run(m[0], in, w, h, out);
  assert_memory_equal(out, a[0].out, npx * 3 * sizeof(float));
  malloc_trim(0);
  int rss_ok = !UNDER_ASAN && proc_reset_peak(0) == 0 && proc_status_kb(0, "VmHWM") > 0;
  long rss0 = rss_ok ? proc_status_kb(0, "VmRSS") : 0;
  shared_run(m[1], in, w, h, out);
  long grew_kb = rss_ok ? proc_status_kb(0, "VmHWM") - rss0 : 0;
  assert_memory_equal(out, a[1].out, npx * 3 * sizeof(float));
  shared_run(m[0], in, w, h, out);
  assert_memory_equal(out, a[0].out, npx * 3 * sizeof(float));
  size_t both = hf_model_cached_bytes(m[0]) + hf_model_cached_bytes(m[1]);
  size_t larger = a[0].cached > a[1].cached ? a[0].cached : a[1].cached;
  size_t smaller = a[0].cached + a[1].cached - larger;
  hf_net_config rcfg;
  assert_int_equal(hf_variant_preset(variant[1], &rcfg), 0);
  size_t est = hf_run_bytes(b, &rcfg, w, h, 1);
  printf("cpu Base + Residual %dx%d: alone %.2f + %.2f MiB, together %.2f MiB; "
         "the second's run grew peak RSS by %.2f MiB (estimate %.2f MiB)\n", w, h,
         a[0].cached / 1048576.0, a[1].cached / 1048576.0, both / 1048576.0, grew_kb / 1024.0,
         est / 1048576.0);
  /* Shared: each keeps its own weights' copies and scratchpads beside the
   * one set of activations, far less than the smaller model's whole. */
  assert_true(both < larger + smaller / 4);
  if (rss_ok) assert_true((size_t)grew_kb * 1024 < est / 4);

  /* Trimming the model that ran last hands the activations to the other. */
  hf_model_trim(m[0], 0);
  assert_int_equal(hf_model_cached_bytes(m[0]), 0);
  assert_true(hf_model_cached_bytes(m[1]) >= both - a[0].cached);
  shared_run(m[1], in, w, h, out);
  assert_memory_equal(out, a[1].out, npx * 3 * sizeof(float));
  hf_model_trim(m[1], 0);
  hf_model_trim(m[0], 0);
  assert_int_equal(hf_model_cached_bytes(m[0]) + hf_model_cached_bytes(m[1]), 0);
  hf_model_destroy(m[0]);
  hf_model_destroy(m[1]);
  hf_backend_destroy(b);
  for (int k = 0; k < 2; k++) free(a[k].out);
  free(in);
  free(out);
}
#endif

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_cpu_ref),
#ifdef HF_HAVE_ONEDNN
    cmocka_unit_test(test_cpu),
    cmocka_unit_test(test_cpu_shared_activations),
#endif
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
