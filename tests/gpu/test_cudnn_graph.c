/* Every layer graph of the cudnn backend through cuDNN's own validation,
 * without a GPU: cuDNN 9.8+ builds operation graphs, runs its engine
 * heuristics and finalizes execution plans for a device described by a
 * device-property descriptor (deviceless mode), here an sm_90 (H100/H200)
 * description in tests/data/cudnn/sm90.json. For each variant, size and
 * batch below, each layer in each form, each convolution of the form is
 * built the way the backend builds it (fused bias+ReLU and unfused; on the
 * real strided views and on dense copies), which finalizes every tensor,
 * convolution, pointwise and graph descriptor and the engine configs'
 * plans. It checks that
 *   - every encoder gets a fused engine on its real views;
 *   - the D2S and PHASE decoder rewrites get fused engines (the reason
 *     they exist: cuDNN has no fused data-gradient engine for sm_90);
 *   - every layer has at least one form whose every conv has an engine;
 *   - no kept engine is noted nondeterministic or reduced-precision, and
 *     no graph finalizes more run-time compiled engines than allowed.
 * Without deviceless mode (cuDNN < 9.8) it skips (exit 77) and says why.
 *
 * usage: test_cudnn_graph DEVICE.json [--all]
 * --all: every variant at 1024x1024 and 37x23, batches 1 and 4, fused data
 * gradients tried everywhere (minutes); by default the sweep is trimmed to
 * stay within seconds (see sweep()). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "backend.h"
#include "cudnn_graph.h"
#include "cudnn_util.h"

static int failures;

#define CHECK(cond, ...)                          \
  do {                                            \
    if (!(cond)) {                                \
      printf("FAIL: " __VA_ARGS__);               \
      printf("\n");                               \
      failures++;                                 \
    }                                             \
  } while (0)

typedef struct tally {
  int graphs, built, refused_fused_dgrad;
  double ms;
} tally;

/* Builds one conv in the 4 ways the backend may; returns a mask of the
 * ways that built: bit (dense*2 + fused). */
static unsigned build_ways(const hf_cg_target *t, const char *name, const hf_cl_conv *cv,
                           int batch, int try_fused_dgrad, tally *ty) {
  unsigned ok = 0;
  const int views_dense = hf_cl_view_dense(&cv->x) && hf_cl_view_dense(&cv->y);
  for (int dense = 0; dense <= 1; dense++) {
    if (dense && views_dense) break;
    for (int fused = 1; fused >= 0; fused--) {
      if (fused && cv->bwd_data && !try_fused_dgrad) {
        ty->refused_fused_dgrad++;
        continue;
      }
      hf_cg_op op;
      char why[512];
      const int rc = hf_cg_op_build(t, name, cv, batch, dense, fused, &op, why, sizeof why);
      ty->graphs++;
      ty->ms += op.build_ms;
      if (rc == HF_OK) {
        int rtc = 0;
        for (int i = 0; i < op.ncand; i++) {
          const hf_cg_cand *c = &op.cand[i];
          CHECK(!(c->numerical & (1u << CUDNN_NUMERICAL_NOTE_NONDETERMINISTIC |
                                  1u << CUDNN_NUMERICAL_NOTE_REDUCED_PRECISION_REDUCTION)),
                "%s: engine %lld kept despite its notes", name, (long long)c->engine);
          rtc += (c->behavior >> CUDNN_BEHAVIOR_NOTE_RUNTIME_COMPILATION) & 1;
        }
        CHECK(rtc <= t->max_rtc, "%s: %d run-time compiled engines finalized", name, rtc);
        ok |= 1u << (dense * 2 + fused);
        ty->built++;
        hf_cg_op_destroy(&op);
      } else {
        CHECK(rc == HF_EUNSUPPORTED, "%s: build failed: %s (%s)", name, hf_strerror(rc), why);
        /* As the backend: nothing offered at all is the op pattern's fault,
         * and dense copies will not help the fused graph. */
        if (fused && !dense && op.heur_configs == 0 && cv->bwd_data) try_fused_dgrad = 0;
      }
    }
  }
  return ok;
}

static void way_string(unsigned ok, int views_dense, char s[8]) {
  /* F: fused on views, U: unfused on views, f/u: the same on dense copies. */
  s[0] = ok & 2 ? 'F' : '-';
  s[1] = ok & 1 ? 'U' : '-';
  s[2] = views_dense ? ' ' : ok & 8 ? 'f' : '-';
  s[3] = views_dense ? ' ' : ok & 4 ? 'u' : '-';
  s[4] = 0;
}

static void sweep(const hf_cg_target *t, const char *variant, int batch, int w, int h,
                  int try_fused_dgrad, tally *ty) {
  hf_net_config cfg;
  if (hf_variant_preset(variant, &cfg)) {
    CHECK(0, "no variant %s", variant);
    return;
  }
  const int a = hf_net_align(&cfg);
  hf_cl_layout lo;
  if (hf_cl_layout_init(&cfg, batch, hf_round_up(w, a), hf_round_up(h, a), &lo)) {
    CHECK(0, "%s: layout", variant);
    return;
  }
  printf("  %-10s %dx%dx%d:", cfg.name, batch, lo.pw, lo.ph);
  for (int j = 0; j < lo.nlayers; j++) {
    const hf_cl_layer *ly = &lo.layers[j];
    int layer_ok = 0;
    printf(" %s", ly->name);
    for (int form = 0; form < HF_CL_NFORMS; form++) {
      hf_cl_form f;
      if (hf_cl_layer_form(&lo, ly, form, &f)) continue;
      int form_ok = 1, fused_all = 1;
      char ways[HF_CL_MAX_CONVS][8];
      for (int c = 0; c < f.nconv; c++) {
        char name[HF_NAME_MAX + 48];
        snprintf(name, sizeof name, "%s %s/%s/%d", cfg.name, ly->name, hf_cl_form_name(form), c);
        const unsigned ok = build_ways(t, name, &f.conv[c], batch, try_fused_dgrad, ty);
        way_string(ok, hf_cl_view_dense(&f.conv[c].x) && hf_cl_view_dense(&f.conv[c].y),
                   ways[c]);
        form_ok &= ok != 0;
        fused_all &= (ok & 2) != 0 || (ok & 8) != 0;
      }
      layer_ok |= form_ok;
      printf(" %s[%s]", form == HF_CL_FORM_FWD ? "" : hf_cl_form_name(form), ways[0]);
      if (form == HF_CL_FORM_FWD)
        CHECK(fused_all && form_ok, "%s %s: no fused engine for the encoder", cfg.name, ly->name);
      if (form == HF_CL_FORM_D2S || form == HF_CL_FORM_PHASE)
        CHECK(fused_all, "%s %s: form %s has no fused engine", cfg.name, ly->name,
              hf_cl_form_name(form));
    }
    CHECK(layer_ok, "%s %s: no form has an engine for every conv", cfg.name, ly->name);
  }
  printf("\n");
}

int main(int argc, char **argv) {
  if (argc < 2 || argc > 3 || (argc == 3 && strcmp(argv[2], "--all"))) {
    fprintf(stderr, "usage: test_cudnn_graph DEVICE.json [--all]\n");
    return 2;
  }
  const int all = argc == 3;
  FILE *fp = fopen(argv[1], "r");
  char json[8192];
  size_t n = fp ? fread(json, 1, sizeof json - 1, fp) : 0;
  if (fp) fclose(fp);
  if (!n) {
    fprintf(stderr, "test_cudnn_graph: cannot read %s\n", argv[1]);
    return 2;
  }
  json[n] = 0;
  hf_cg_target t = {NULL, NULL, 4, 1};
  char why[512];
  if (hf_cg_devprop_from_json(json, &t.devprop, why, sizeof why)) {
    printf("SKIP: cuDNN %zu cannot build plans without a device: %s\n", cudnnGetVersion(), why);
    return 77;
  }
  printf("cuDNN %zu, deviceless, device %s\n"
         "per layer and form, per conv 0: F/U fused/unfused on the real views, f/u on dense "
         "copies, '-' no engine\n",
         cudnnGetVersion(), argv[1]);
  tally ty = {0, 0, 0, 0};
  const double t0 = hf_now_us();
  /* Every variant at an odd size, batch 1; Base also at 1024x1024, batch
   * 4. Refusing a fused data gradient costs cuDNN's heuristics one to three
   * seconds, so by default that is tried for Base's first size alone;
   * --all tries it everywhere, for every variant at both sizes and batches. */
  for (int i = 0; i < hf_variant_preset_count(); i++) {
    const char *v = hf_variant_preset_name(i);
    const int base = !strcmp(v, "Base");
    sweep(&t, v, 1, 37, 23, all || base, &ty);
    if (all || base) sweep(&t, v, 4, 1024, 1024, all, &ty);
    if (all) {
      sweep(&t, v, 4, 37, 23, 1, &ty);
      sweep(&t, v, 1, 1024, 1024, 1, &ty);
    }
  }
  printf("%d graphs built (%d with an engine), %.1f s in cuDNN; %d fused data-gradient graphs "
         "not tried (--all tries them)\n",
         ty.graphs, ty.built, ty.ms / 1e3, ty.refused_fused_dgrad);
  printf("total %.1f s\n", (hf_now_us() - t0) / 1e6);
  cudnnBackendDestroyDescriptor(t.devprop);
  if (failures) {
    printf("%d check(s) failed\n", failures);
    return 1;
  }
  printf("PASSED\n");
  return 0;
}
