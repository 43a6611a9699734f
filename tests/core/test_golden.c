/* Golden tests: every CPU backend reproduces PyTorch's output (fixtures made
 * by weights/make_golden.py) within 1e-4 relative L2 error. */
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

/* preset: the Table 1 or beyond-the-paper preset the fixture's weights stand
 * for (their shape must be the preset's as it is now, so a changed preset
 * cannot leave its golden test checking the old network); NULL for a
 * configuration that varies one (weights/make_golden.py, CONFIGS). */
static const struct { const char *weights, *stem, *preset; } cases[] = {
  {"Base", "Base_64x48", "Base"},                {"Base", "Base_37x23", "Base"},
  {"Shallow", "Shallow_64x48", "Shallow"},       {"Shallow", "Shallow_29x17", "Shallow"},
  {"Deep", "Deep_64x48", "Deep"},                {"Deep", "Deep_45x31", "Deep"},
  {"Base_1spp", "Base_1spp_64x48", "Base@1spp"}, {"Base_1spp", "Base_1spp_19x41", "Base@1spp"},
  {"Residual", "Residual_64x48", "Residual"},    {"Residual", "Residual_27x35", "Residual"},
  {"Kernel", "Kernel_64x48", "Kernel"},          {"Kernel", "Kernel_37x23", "Kernel"},
  {"Kernel_r2h0", "Kernel_r2h0_64x48", NULL},    {"Kernel_r2h0", "Kernel_r2h0_37x23", NULL},
  {"KernelAC", "KernelAC_64x48", "KernelAC"},    {"KernelAC", "KernelAC_37x23", "KernelAC"},
  {"KernelMix", "KernelMix_64x48", "KernelMix"}, {"KernelMix", "KernelMix_37x23", "KernelMix"},
};

static int backend_in_build(const char *name) {
  for (const char *const *b = hf_backend_list(); *b; b++)
    if (!strcmp(*b, name)) return 1;
  return 0;
}

static void run_golden(const char *backend) {
  if (!backend_in_build(backend)) {
    printf("SKIP: backend %s is not in this build\n", backend);
    skip();
  }
  hf_backend *b;
  char why[256];
  assert_int_equal(hf_backend_create(backend, &b, why, sizeof why), HF_OK);
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
    char path[512], err[256];
    hf_weights *w;
    snprintf(path, sizeof path, "%s/golden/%s.safetensors", HF_TEST_DATA, cases[k].weights);
    assert_int_equal(hf_weights_load(path, &w, err, sizeof err), HF_OK);
    hf_image feat, want;
    snprintf(path, sizeof path, "%s/golden/%s.features.exr", HF_TEST_DATA, cases[k].stem);
    assert_int_equal(hf_exr_read(path, &feat, err, sizeof err), HF_OK);
    snprintf(path, sizeof path, "%s/golden/%s.expected.exr", HF_TEST_DATA, cases[k].stem);
    assert_int_equal(hf_exr_read(path, &want, err, sizeof err), HF_OK);
    assert_int_equal(hf_features_spp(&feat), w->cfg.spp);
    size_t npx = (size_t)feat.width * feat.height;
    float *in = malloc(npx * w->cfg.in_channels * 4), *out = malloc(npx * 3 * 4);
    assert_int_equal(hf_features_from_image(&feat, w->cfg.spp, in), w->cfg.spp);
    /* KernelAC: the alpha-corrected estimate after the samples (planar). */
    if (w->cfg.estimate)
      assert_int_equal(hf_estimate_from_data(&feat, feat.data, HF_F32,
                                             in + npx * w->cfg.spp * HF_FEATURES_PER_SAMPLE),
                       HF_OK);
    hf_model *m;
    assert_int_equal(hf_model_create(b, w, &m), HF_OK);
    hf_io io = {1, feat.width, feat.height, in, HF_F32, out, HF_F32};
    assert_int_equal(hf_model_run(m, &io, NULL), HF_OK);
    double num = 0, den = 0;
    for (size_t p = 0; p < npx; p++)
      for (int c = 0; c < 3; c++) {
        int wc = hf_image_channel(&want, HF_OUTPUT_NAMES[c]);
        assert_true(wc >= 0);
        double e = want.data[p * want.channels + wc], g = out[p * 3 + c];
        assert_false(isnan(g));
        num += (g - e) * (g - e);
        den += e * e;
      }
    double rel = sqrt(num / den);
    printf("  %-8s %-16s rel L2 %.2e\n", backend, cases[k].stem, rel);
    assert_true(rel < 1e-4);
    hf_model_destroy(m);
    free(in), free(out);
    hf_image_free(&feat), hf_image_free(&want);
    hf_weights_free(w);
  }
  hf_backend_destroy(b);
}

/* Every fixture of a preset has the preset's shape: levels, architecture,
 * kernel radius, head width and estimate (make_golden.py writes them from
 * hfnet.variant_config, which mirrors the C presets). */
static void test_fixtures_have_preset_shapes(void **state) {
  for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
    if (!cases[k].preset) continue;
    char path[512], err[256];
    hf_weights *w;
    hf_net_config want;
    snprintf(path, sizeof path, "%s/golden/%s.safetensors", HF_TEST_DATA, cases[k].weights);
    assert_int_equal(hf_weights_load(path, &w, err, sizeof err), HF_OK);
    assert_int_equal(hf_variant_preset(cases[k].preset, &want), HF_OK);
    const hf_net_config *got = &w->cfg;
    int same = got->spp == want.spp && got->in_channels == want.in_channels &&
               got->out_channels == want.out_channels && got->num_levels == want.num_levels &&
               !memcmp(got->levels, want.levels, sizeof want.levels) && got->arch == want.arch &&
               got->kernel_radius == want.kernel_radius &&
               got->kernel_hidden == want.kernel_hidden && got->estimate == want.estimate;
    if (!same)
      print_error("%s.safetensors is not the %s preset as it is now (head %d, preset %d): "
                  "rerun /usr/bin/python3 weights/make_golden.py\n",
                  cases[k].weights, cases[k].preset, got->kernel_hidden, want.kernel_hidden);
    assert_true(same);
    hf_weights_free(w);
  }
}

static void test_cpu_ref_matches_pytorch(void **state) { run_golden("cpu-ref"); }
static void test_cpu_matches_pytorch(void **state) { run_golden("cpu"); }

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_fixtures_have_preset_shapes),
    cmocka_unit_test(test_cpu_ref_matches_pytorch),
    cmocka_unit_test(test_cpu_matches_pytorch),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
