/* hairfilter filter: filter a feature EXR through hairfilterd and print
 * where the time went. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli_common.h"
#include "commands.h"
#include "hairfilter.h"

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter filter --server URL --in FEATURES.exr --out RESULT.exr\n"
          "                         [--variant NAME] [--png PREVIEW.png] [--f16]\n"
          "                         [--hair r,g,b] [--light r,g,b] [--background r,g,b]\n"
          "                         [--token TOKEN] [--timeout-ms N]\n"
          "URL is unix:PATH or tcp:HOST:PORT. The token defaults to $HAIRFILTER_TOKEN.\n"
          "--variant may be left out when the server has only one. --f16 sends and\n"
          "receives half floats. The PNG is composited by the server.\n");
}

static void print_timing(const hfc_timing *t) {
  printf("  queue   %10.3f ms\n", t->queue_us / 1e3);
  printf("  input   %10.3f ms\n", t->input_us / 1e3);
  printf("  infer   %10.3f ms\n", t->infer_us / 1e3);
  printf("  output  %10.3f ms\n", t->output_us / 1e3);
  printf("  server  %10.3f ms  (admitted -> reply sent)\n", t->server_us / 1e3);
  printf("  network %10.3f ms  (transfer both ways, client side)\n",
         (t->total_us - t->server_us) / 1e3);
  printf("  total   %10.3f ms\n", t->total_us / 1e3);
}

int cmd_filter(int argc, char **argv) {
  const char *server = NULL, *variant = NULL, *in_path = NULL, *out_path = NULL, *png = NULL;
  const char *token = getenv("HAIRFILTER_TOKEN");
  int f16 = 0, timeout_ms = 0;
  float hair[3], light[3], bg[3];
  memcpy(hair, CLI_HAIR_DEFAULT, sizeof hair);
  memcpy(light, CLI_LIGHT_DEFAULT, sizeof light);
  memcpy(bg, CLI_BG_DEFAULT, sizeof bg);
  static const struct option opts[] = {
    {"server", required_argument, 0, 's'}, {"variant", required_argument, 0, 'V'},
    {"in", required_argument, 0, 'i'},     {"out", required_argument, 0, 'o'},
    {"png", required_argument, 0, 'p'},    {"f16", no_argument, 0, 'F'},
    {"hair", required_argument, 0, 'H'},   {"light", required_argument, 0, 'L'},
    {"background", required_argument, 0, 'B'}, {"token", required_argument, 0, 'T'},
    {"timeout-ms", required_argument, 0, 't'}, {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0}};
  int opt;
  optind = 1;
  while ((opt = getopt_long(argc, argv, "s:V:i:o:p:h", opts, NULL)) != -1) {
    switch (opt) {
    case 's': server = optarg; break;
    case 'V': variant = optarg; break;
    case 'i': in_path = optarg; break;
    case 'o': out_path = optarg; break;
    case 'p': png = optarg; break;
    case 'F': f16 = 1; break;
    case 'T': token = optarg; break;
    case 't': timeout_ms = atoi(optarg); break;
    case 'H': if (cli_parse_rgb(optarg, hair)) goto bad; break;
    case 'L': if (cli_parse_rgb(optarg, light)) goto bad; break;
    case 'B': if (cli_parse_rgb(optarg, bg)) goto bad; break;
    case 'h': usage(stdout); return 0;
    default: goto bad;
    }
  }
  if (!server || !in_path || !out_path || optind != argc) goto bad;

  int ret = 1, rc;
  hfc_client *c = NULL;
  hf_image feat = {0}, res = {0};
  void *in = NULL, *out = NULL, *rgba = NULL;
  float *rgb = NULL;
  char err[512];
  hfc_options o = {"hairfilter-cli", token, timeout_ms};
  if ((rc = hfc_connect(server, &o, &c)) != 0) {
    fprintf(stderr, "hairfilter: %s: %s\n", server, hfc_strerror(rc));
    return 1;
  }
  hfc_variant vs[64];
  int nv = 0;
  if ((rc = hfc_list_variants(c, vs, 64, &nv)) != 0) {
    fprintf(stderr, "hairfilter: listing variants: %s\n", hfc_strerror(rc));
    goto out;
  }
  const hfc_variant *v = NULL;
  for (int i = 0; i < nv && i < 64; i++)
    if (variant ? !strcmp(vs[i].name, variant) : nv == 1) v = &vs[i];
  if (!v) {
    fprintf(stderr, "hairfilter: %s; the server has:", variant ? "no such variant" : "name a --variant");
    for (int i = 0; i < nv && i < 64; i++) fprintf(stderr, " %s", vs[i].name);
    fprintf(stderr, "\n");
    goto out;
  }
  if ((rc = hf_exr_read(in_path, &feat, err, sizeof err)) != 0) {
    fprintf(stderr, "hairfilter: %s\n", err);
    goto out;
  }
  int spp = hf_features_spp(&feat);
  if (spp < v->spp) {
    fprintf(stderr, "hairfilter: %s has %d samples per pixel, variant %s needs %d\n", in_path,
            spp < 0 ? 0 : spp, v->name, v->spp);
    goto out;
  }
  size_t npx = (size_t)feat.width * feat.height;
  size_t nin = npx * (size_t)v->spp * HF_FEATURES_PER_SAMPLE;
  float *in32 = malloc(nin * sizeof(float));
  out = malloc(npx * 3 * sizeof(float));
  rgba = png ? malloc(npx * 4 * sizeof(float)) : NULL;
  if (!in32 || !out || (png && !rgba)) {
    free(in32);
    fprintf(stderr, "hairfilter: out of memory for a %dx%d frame\n", feat.width, feat.height);
    goto out;
  }
  in = in32;
  if ((rc = hf_features_from_image(&feat, v->spp, in32)) < 0) {
    fprintf(stderr, "hairfilter: %s: missing feature channels\n", in_path);
    goto out;
  }
  if (f16) {
    /* Halves the bytes on the wire; converted in place, front to back. */
    uint16_t *h = (uint16_t *)in32;
    for (size_t i = 0; i < nin; i++) h[i] = hf_f32_to_f16(in32[i]);
  }
  hfc_request r = {.variant = v->name, .width = feat.width, .height = feat.height,
                   .spp = v->spp, .in_dtype = f16 ? HFC_F16 : HFC_F32, .features = in,
                   .out_dtype = f16 ? HFC_F16 : HFC_F32, .result = out, .rgba = rgba};
  memcpy(r.hair, hair, sizeof hair);
  memcpy(r.light, light, sizeof light);
  memcpy(r.background, bg, sizeof bg);
  hfc_timing t;
  if ((rc = hfc_filter(c, &r, &t)) != 0) {
    const char *m = hfc_last_message(c);
    fprintf(stderr, "hairfilter: filtering failed: %s%s%s\n", hfc_strerror(rc), m[0] ? ": " : "", m);
    goto out;
  }
  if (f16) {
    /* Widen back to float, back to front so nothing is overwritten early. */
    for (size_t i = npx * 3; i-- > 0;) ((float *)out)[i] = hf_f16_to_f32(((uint16_t *)out)[i]);
    if (rgba)
      for (size_t i = npx * 4; i-- > 0;) ((float *)rgba)[i] = hf_f16_to_f32(((uint16_t *)rgba)[i]);
  }
  printf("%s %dx%d via %s (%s, %s, batch %d)\n", v->name, feat.width, feat.height, server,
         v->backend, v->precision, t.batch);
  print_timing(&t);
  if ((rc = hf_result_to_image(out, feat.width, feat.height, &res)) != 0 ||
      (rc = hf_exr_write(out_path, &res, 0)) != 0) {
    fprintf(stderr, "hairfilter: writing %s: %s\n", out_path, hf_strerror(rc));
    goto out;
  }
  if (png) {
    rgb = malloc(npx * 3 * sizeof(float));
    if (!rgb) goto out;
    for (size_t i = 0; i < npx; i++)
      for (int k = 0; k < 3; k++) rgb[i * 3 + k] = ((float *)rgba)[i * 4 + k];
    if ((rc = hf_png_write_rgb(png, rgb, feat.width, feat.height)) != 0) {
      fprintf(stderr, "hairfilter: writing %s: %s\n", png, hf_strerror(rc));
      goto out;
    }
  }
  ret = 0;
out:
  hfc_close(c);
  hf_image_free(&feat);
  hf_image_free(&res);
  free(in);
  free(out);
  free(rgba);
  free(rgb);
  return ret;
bad:
  usage(stderr);
  return 2;
}
