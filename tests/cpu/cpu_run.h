/* Helpers the cpu backend's comparison tests share (test_f16_input.c,
 * test_scan_in_bands.c): the bundled variants, a seeded generator, one run
 * through the public API, and the comparison of its reports and input
 * statistics. Included after cmocka.h and hfcore.h. */
#ifndef HF_TESTS_CPU_RUN_H
#define HF_TESTS_CPU_RUN_H

/* Every weights file in weights/ (tests/eval runs the same list). */
static const char *const VARIANTS[] = {"base",    "base_1spp", "base_2spp", "large",   "small",
                                       "shallow", "deep",      "residual",  "kernel"};
#define NVARIANTS (sizeof VARIANTS / sizeof VARIANTS[0])

static uint64_t rng_next(uint64_t *s) {
  *s ^= *s << 13;
  *s ^= *s >> 7;
  *s ^= *s << 17;
  return *s;
}

/* weights/VARIANT.safetensors, loaded into *w and prepared on b. */
static hf_model *load_variant(hf_backend *b, const char *variant, hf_weights **w) {
  char path[1024], err[256];
  snprintf(path, sizeof path, "%s/%s.safetensors", HF_WEIGHTS_DIR, variant);
  if (hf_weights_load(path, w, err, sizeof err) != HF_OK) fail_msg("%s: %s", path, err);
  hf_model *m;
  assert_int_equal(hf_model_create(b, *w, &m), HF_OK);
  return m;
}

/* Runs io through m and returns the result (the caller frees it), with its
 * reports and input statistics. */
static void *run(hf_model *m, const void *in, hf_dtype in_t, int batch, int w, int h,
                 hf_dtype out_t, hf_input_report *rep, hf_input_stats *stats) {
  size_t nout = (size_t)batch * w * h * 3 * (out_t == HF_F32 ? 4 : 2);
  void *out = malloc(nout);
  assert_non_null(out);
  memset(out, 0xa5, nout);
  hf_io io = {batch, w, h, in, in_t, out, out_t};
  hf_timing t;
  assert_int_equal(hf_model_run_stats(m, &io, &t, rep, stats), HF_OK);
  return out;
}

/* The same reports and statistics, field by field (value by its bits: a
 * NaN widened from a half is that NaN). */
static void same_reports(const hf_input_report *a, const hf_input_report *b,
                         const hf_input_stats *sa, const hf_input_stats *sb, int batch) {
  for (int n = 0; n < batch; n++) {
    assert_int_equal(a[n].samples, b[n].samples);
    assert_int_equal(a[n].x, b[n].x);
    assert_int_equal(a[n].y, b[n].y);
    assert_int_equal(a[n].sample, b[n].sample);
    assert_int_equal(a[n].feature, b[n].feature);
    assert_int_equal(a[n].kind, b[n].kind);
    assert_memory_equal(&a[n].value, &b[n].value, sizeof a[n].value);
    assert_int_equal(a[n].outputs, b[n].outputs);
    assert_int_equal(sa[n].hair_pixels, sb[n].hair_pixels);
    assert_int_equal(sa[n].full_pixels, sb[n].full_pixels);
    assert_memory_equal(sa[n].value, sb[n].value, sizeof sa[n].value);
  }
}

#endif
