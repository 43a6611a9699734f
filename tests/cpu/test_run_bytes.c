/* hf_run_bytes is an upper bound of what a run really takes: for each CPU
 * backend, variant and size below, the process's peak resident memory grows
 * by no more than the estimate while the model runs a frame size it has not
 * seen; the plan a backend keeps is no larger than the estimate either; and
 * hf_model_trim gives that memory back. The daemon admits frames on these
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
#endif

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_cpu_ref),
#ifdef HF_HAVE_ONEDNN
    cmocka_unit_test(test_cpu),
#endif
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
