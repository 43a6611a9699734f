/* The cpu backend reads float16 frames where they are (reads_f16), widening
 * them a band or a row at a time in the passes that read the input; a
 * float32 frame of the same values goes through the whole-frame passes.
 * Both must give the same bytes, for every variant shipped in weights/ (and
 * the reports and input statistics of the run), at sizes that need padding
 * and sizes that do not, one frame and several, frames with out-of-contract
 * samples among them. ctest runs this with the default bands and with the
 * smallest (HF_CPU_BAND_KB=1: one output row of enc0 per band, every band a
 * seam). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "hfcore.h"

#include "cpu_run.h"

static hf_backend *cpu;

static int setup(void **state) {
  char why[256];
  if (hf_backend_create("cpu", &cpu, why, sizeof why) != HF_OK) {
    fprintf(stderr, "cpu backend unavailable: %s\n", why);
    return -1;
  }
  return 0;
}

static int teardown(void **state) {
  hf_backend_destroy(cpu);
  return 0;
}

/* Features as halves: colour and highlight in [0, 2), alpha in (0, 1] or
 * the sample empty, depth in [0, 1], tangents in [-1, 1]. bad > 0: every
 * bad-th sample gets one out-of-contract value of a kind that cycles (NaN,
 * infinity, alpha 0 with colour, a value beyond its range). */
static uint16_t *frames_f16(int spp, int batch, int w, int h, uint64_t seed, int bad) {
  size_t samples = (size_t)batch * w * h * spp;
  uint16_t *in = malloc(samples * HF_FEATURES_PER_SAMPLE * sizeof *in);
  assert_non_null(in);
  uint64_t s = seed * 2654435761u + 1;
  for (size_t i = 0; i < samples; i++) {
    uint16_t *v = in + i * HF_FEATURES_PER_SAMPLE;
    int empty = rng_next(&s) % 4 == 0;
    for (int k = 0; k < HF_FEATURES_PER_SAMPLE; k++) {
      float u = (float)(rng_next(&s) >> 11) / (float)(1ull << 53);
      /* alpha at least 2^-10, so that no half of it rounds to 0 */
      float x = k < 2    ? 2.0f * u
                : k == 2 ? (u >= 0x1p-10f ? u : 1.0f)
                : k == 3 ? u
                         : 2.0f * u - 1.0f;
      v[k] = hf_f32_to_f16(empty ? 0.0f : x);
    }
    if (bad && i % (size_t)bad == (size_t)bad - 1) {
      static const uint16_t wrong[][2] = {{0, 0x7e00}, {3, 0x7c00}, {2, 0x0000}, {4, 0xc200}};
      const int kind = (int)(i / (size_t)bad % 4);
      v[wrong[kind][0]] = wrong[kind][1];
      if (kind == 2) v[0] = hf_f32_to_f16(0.5f); /* uncovered, yet coloured */
    }
  }
  return in;
}

/* Variant v on batch frames of w x h: the halves as they are against the
 * same values as float32, every output byte equal. Returns the number of
 * samples the run sanitised (summed over the frames). */
static uint64_t compare(hf_model *m, const char *variant, int batch, int w, int h, int bad,
                        hf_dtype out_t, uint64_t seed) {
  const hf_net_config *c = hf_model_config(m);
  size_t nin = (size_t)batch * w * h * c->in_channels;
  uint16_t *half = frames_f16(c->spp, batch, w, h, seed, bad);
  float *wide = malloc(nin * sizeof *wide);
  assert_non_null(wide);
  for (size_t i = 0; i < nin; i++) wide[i] = hf_f16_to_f32(half[i]);
  hf_input_report ra[4], rb[4];
  hf_input_stats sa[4], sb[4];
  assert_true(batch <= 4);
  void *a = run(m, half, HF_F16, batch, w, h, out_t, ra, sa);
  void *b = run(m, wide, HF_F32, batch, w, h, out_t, rb, sb);
  size_t nout = (size_t)batch * w * h * 3, esz = out_t == HF_F32 ? 4 : 2, differ = 0, first = 0;
  for (size_t i = nout; i-- > 0;)
    if (memcmp((char *)a + i * esz, (char *)b + i * esz, esz)) differ++, first = i;
  if (differ)
    fail_msg("%s %dx%d batch %d%s, out %s: %zu of %zu output values differ between the "
             "float16 frame and its float32 values, the first at pixel %zu channel %zu",
             variant, w, h, batch, bad ? " with bad samples" : "",
             out_t == HF_F32 ? "f32" : "f16", differ, nout, first / 3, first % 3);
  same_reports(ra, rb, sa, sb, batch);
  uint64_t sanitised = 0;
  for (int n = 0; n < batch; n++) sanitised += ra[n].samples;
  assert_int_equal(sanitised > 0, bad > 0); /* the bad samples were seen */
  free(a);
  free(b);
  free(wide);
  free(half);
  return sanitised;
}

static hf_model *load(const char *variant, hf_weights **w) { return load_variant(cpu, variant, w); }

/* Every bundled variant: a size that needs padding (37x23), one that does
 * not (64x48: a multiple of 16, the deepest variant's alignment), a size
 * whose frames are split over threads and several bands of enc0 with a
 * shorter last one (96x72), one frame and several, and frames with
 * out-of-contract samples (sanitised copies, kept in halves). */
static void test_variants_bit_exact(void **state) {
  for (size_t v = 0; v < NVARIANTS; v++) {
    hf_weights *w;
    hf_model *m = load(VARIANTS[v], &w);
    const uint64_t seed = 1000 + 10 * v;
    compare(m, VARIANTS[v], 1, 37, 23, 0, HF_F32, seed);
    compare(m, VARIANTS[v], 1, 64, 48, 0, HF_F32, seed + 1);
    compare(m, VARIANTS[v], 3, 37, 23, 0, HF_F32, seed + 2);
    compare(m, VARIANTS[v], 2, 64, 48, 0, HF_F32, seed + 3);
    compare(m, VARIANTS[v], 2, 96, 72, 0, HF_F32, seed + 4);
    compare(m, VARIANTS[v], 1, 64, 48, 0, HF_F16, seed + 5);
    compare(m, VARIANTS[v], 2, 37, 23, 97, HF_F32, seed + 6);
    compare(m, VARIANTS[v], 1, 64, 48, 13, HF_F16, seed + 7);
    compare(m, VARIANTS[v], 1, 1, 1, 0, HF_F32, seed + 8);
    hf_model_destroy(m);
    hf_weights_free(w);
  }
}

/* No float32 copy of a frame of halves is made or kept: after a clean
 * frame the model holds what it holds after the same frame in float32 (the
 * plan and the activations), where widening it first kept the frame's
 * floats for the next run; a frame that needs sanitising is copied in
 * halves. */
static void test_no_float_copy(void **state) {
  hf_weights *w;
  hf_model *m = load("kernel", &w);
  const int batch = 2, width = 64, height = 48;
  size_t nin = (size_t)batch * width * height * hf_model_config(m)->in_channels;
  uint16_t *half = frames_f16(4, batch, width, height, 3000, 0);
  uint16_t *bad = frames_f16(4, batch, width, height, 3001, 50);
  float *wide = malloc(nin * sizeof *wide);
  assert_non_null(wide);
  for (size_t i = 0; i < nin; i++) wide[i] = hf_f16_to_f32(half[i]);
  free(run(m, wide, HF_F32, batch, width, height, HF_F32, NULL, NULL));
  size_t held = hf_model_cached_bytes(m);
  assert_true(held > 0);
  free(run(m, half, HF_F16, batch, width, height, HF_F32, NULL, NULL));
  assert_int_equal(hf_model_cached_bytes(m), held);
  free(run(m, bad, HF_F16, batch, width, height, HF_F32, NULL, NULL));
  assert_int_equal(hf_model_cached_bytes(m), held + nin * sizeof *half);
  free(wide);
  free(bad);
  free(half);
  hf_model_destroy(m);
  hf_weights_free(w);
}

/* The Kernel variant's other output stage (HF_CPU_KERNEL_REF, read at
 * model creation) reads the input a row at a time too. */
static void test_kernel_reference_stage(void **state) {
  assert_int_equal(setenv("HF_CPU_KERNEL_REF", "1", 1), 0);
  hf_weights *w;
  hf_model *m = load("kernel", &w);
  compare(m, "kernel (HF_CPU_KERNEL_REF)", 2, 37, 23, 0, HF_F32, 2000);
  compare(m, "kernel (HF_CPU_KERNEL_REF)", 1, 64, 48, 31, HF_F32, 2001);
  hf_model_destroy(m);
  hf_weights_free(w);
  assert_int_equal(unsetenv("HF_CPU_KERNEL_REF"), 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_variants_bit_exact),
    cmocka_unit_test(test_no_float_copy),
    cmocka_unit_test(test_kernel_reference_stage),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
