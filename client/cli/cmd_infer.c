/* hairfilter infer: filter a feature EXR in-process with one backend. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli_common.h"
#include "commands.h"

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter infer --weights W.safetensors --in FEATURES.exr --out RESULT.exr\n"
          "                        [--part N|NAME] [--backend auto|cpu|cpu-ref|cudnn]\n"
          "                        [--png PREVIEW.png]\n"
          "                        [--hair r,g,b] [--light r,g,b] [--background r,g,b]\n"
          "Reads S{k}.<feature> channels (and acst4.color/highlight/alpha, the alpha-corrected\n"
          "estimate, for weights that read it: KernelMix, KernelAC), writes color/highlight/alpha\n"
          "(protocol/FEATURES.md) with the input's data window and display window.\n"
          "--part picks the part of a multi-part file (default: the one with S0.color).\n"
          "--png composites the result over the frame's background layer where it has one,\n"
          "else over --background.\n");
}

/* Runs one frame through weights on backend; result_img gets [h][w][3] with
 * the features' data window and display window, layer the frame's
 * background layer (cli_read_features). */
static int infer_file(const char *weights, const char *in_path, const char *part,
                      const char *backend, hf_image *result_img, hf_image *layer) {
  char err[512];
  hf_weights *w = NULL;
  hf_backend *b = NULL;
  hf_model *m = NULL;
  hf_image feat = {0};
  float *in = NULL, *out = NULL;
  int rc = hf_weights_load(weights, &w, err, sizeof err);
  if (rc) {
    fprintf(stderr, "hairfilter: %s\n", err);
    return rc;
  }
  void *in_data = NULL;
  rc = cli_read_features(in_path, part, w->cfg.spp, w->cfg.estimate, w->cfg.name, HF_F32, &feat,
                         &in_data, layer);
  in = in_data;
  if (rc != 0) goto out;
  if (!(out = malloc((size_t)feat.width * feat.height * 3 * sizeof(float)))) {
    rc = HF_ENOMEM;
    goto out;
  }
  hf_input_stats st;
  int bad = cli_input_range_check(&w->input_range, in, HF_F32, feat.width, feat.height,
                                  w->cfg.spp, &st);
  if (bad > 0) cli_warn_input_range("hairfilter", in_path, w->cfg.name, &w->input_range, &st, bad);
  if ((rc = cli_open_backend(backend, &b)) != 0) goto out;
  if ((rc = hf_model_create(b, w, &m)) != 0) {
    fprintf(stderr, "hairfilter: preparing %s on %s: %s\n", w->cfg.name, hf_backend_name(b),
            hf_strerror(rc));
    goto out;
  }
  hf_io io = {.batch = 1, .width = feat.width, .height = feat.height,
              .in = in, .in_dtype = HF_F32, .out = out, .out_dtype = HF_F32};
  hf_timing t;
  hf_input_report rep;
  if ((rc = hf_model_run_report(m, &io, &t, &rep)) != 0) {
    fprintf(stderr, "hairfilter: inference failed: %s\n", hf_strerror(rc));
    goto out;
  }
  cli_warn_sanitised(in_path, &feat, &rep);
  printf("%s %dx%d on %s (%s): input %.3f ms, infer %.3f ms, output %.3f ms\n", w->cfg.name,
         feat.width, feat.height, hf_backend_name(b), hf_model_precision(m), t.input_us / 1e3,
         t.infer_us / 1e3, t.output_us / 1e3);
  if ((rc = hf_result_to_image(out, feat.width, feat.height, result_img)) == HF_OK)
    hf_image_copy_windows(result_img, &feat);
out:
  hf_model_destroy(m);
  hf_backend_destroy(b);
  hf_weights_free(w);
  hf_image_free(&feat);
  free(in);
  free(out);
  return rc;
}

int cmd_infer(int argc, char **argv) {
  const char *weights = NULL, *in = NULL, *out = NULL, *png = NULL, *backend = "auto";
  const char *part = NULL;
  float hair[3], light[3], bg[3];
  memcpy(hair, CLI_HAIR_DEFAULT, sizeof hair);
  memcpy(light, CLI_LIGHT_DEFAULT, sizeof light);
  memcpy(bg, CLI_BG_DEFAULT, sizeof bg);
  static const struct option opts[] = {
    {"weights", required_argument, 0, 'w'}, {"in", required_argument, 0, 'i'},
    {"out", required_argument, 0, 'o'},     {"backend", required_argument, 0, 'b'},
    {"png", required_argument, 0, 'p'},     {"hair", required_argument, 0, 'H'},
    {"light", required_argument, 0, 'L'},   {"background", required_argument, 0, 'B'},
    {"part", required_argument, 0, 'P'},    {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0}};
  int c;
  optind = 1;
  while ((c = getopt_long(argc, argv, "w:i:o:b:p:h", opts, NULL)) != -1) {
    switch (c) {
    case 'w': weights = optarg; break;
    case 'i': in = optarg; break;
    case 'o': out = optarg; break;
    case 'b': backend = optarg; break;
    case 'p': png = optarg; break;
    case 'P': part = optarg; break;
    case 'H': if (cli_parse_rgb("hairfilter infer", "--hair", optarg, hair)) return 2; break;
    case 'L': if (cli_parse_rgb("hairfilter infer", "--light", optarg, light)) return 2; break;
    case 'B': if (cli_parse_rgb("hairfilter infer", "--background", optarg, bg)) return 2; break;
    case 'h': usage(stdout); return 0;
    default: goto bad;
    }
  }
  if (optind != argc) {
    fprintf(stderr, "hairfilter infer: unexpected argument '%s'\n", argv[optind]);
    goto bad;
  }
  if (!weights || !in || !out) {
    /* Said before the usage, so the missing one is not lost in it. */
    char missing[80] = "";
    if (!weights) strcat(missing, " --weights FILE");
    if (!in) strcat(missing, " --in FEATURES.exr");
    if (!out) strcat(missing, " --out RESULT.exr");
    fprintf(stderr, "hairfilter infer: give%s (the default variant's weights: "
                    "weights/kernel_mix.safetensors; weights/kernel.safetensors for a frame "
                    "without the estimate)\n", missing);
    goto bad;
  }
  if (cli_check_output("hairfilter infer", out) || cli_check_output("hairfilter infer", png)) return 1;
  hf_image res = {0}, layer = {0};
  int rc = infer_file(weights, in, part, backend, &res, &layer);
  if (rc) {
    hf_image_free(&layer);
    return 1;
  }
  if ((rc = hf_exr_write(out, &res, 0)) != 0) {
    fprintf(stderr, "hairfilter: writing %s: %s\n", out, hf_strerror(rc));
  } else if (png && (rc = cli_write_preview(png, res.data, res.width, res.height, &layer, hair,
                                            light, bg))) {
    fprintf(stderr, "hairfilter: writing %s: %s\n", png, hf_strerror(rc));
  }
  hf_image_free(&res);
  hf_image_free(&layer);
  return rc ? 1 : 0;
bad:
  usage(stderr);
  return 2;
}
