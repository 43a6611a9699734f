/* hairfilter filter: filter a feature EXR through hairfilterd and print
 * where the time went. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>

#include "cli_args.h"
#include "cli_common.h"
#include "commands.h"
#include <hairfilter/hairfilter.h>

/* The variants README and `hairfilter demo` use: a server loaded from the
 * bundled weights directory has several, and an engine that just wants a
 * filtered frame should not have to pick one. KernelMix
 * (weights/kernel_mix.safetensors) for a frame that carries the
 * alpha-corrected estimate (acst4.*), else KernelAC (the default until
 * 2026-12-06, on servers with the weights of then), else Kernel. */
#define FILTER_DEFAULT_VARIANT "Kernel"
#define FILTER_DEFAULT_ESTIMATE_VARIANT "KernelMix"
#define FILTER_FALLBACK_ESTIMATE_VARIANT "KernelAC"

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter filter --server URL --in FEATURES.exr --out RESULT.exr\n"
          "                         [--variant NAME] [--part N|NAME] [--png PREVIEW.png] [--f16]\n"
          "                         [--hair r,g,b] [--light r,g,b] [--background r,g,b]\n"
          "                         [--token TOKEN] [--timeout-ms N]\n"
          "                         [--tls-ca FILE] [--tls-server-name NAME]\n"
          "                         [--tls-cert FILE --tls-key FILE]\n"
          "       hairfilter filter --server URL --list     (variants and limits)\n"
          "       hairfilter filter --server URL --stats    (counters and latency)\n"
          "URL is unix:PATH, tcp:HOST:PORT or tls:HOST:PORT, or several of them separated by commas\n"
          "(tried in order, and failed over to). The token defaults to $HAIRFILTER_TOKEN.\n"
          "--variant defaults to the server's only variant. Else, for a frame with the\n"
          "alpha-corrected estimate (acst4.*), to the first the server has of " FILTER_DEFAULT_ESTIMATE_VARIANT "\n"
          "(the bundled default) and " FILTER_FALLBACK_ESTIMATE_VARIANT "; else, for any frame, to " FILTER_DEFAULT_VARIANT " if\n"
          "the server has it. --f16 sends and receives half floats (a file of HALF channels\n"
          "is sent as stored, FLOAT ones are rounded to nearest even, finite ones beyond\n"
          "half's range to +-65504). The PNG is composited by the server, or here over the\n"
          "frame's background layer where it has one. The result keeps the\n"
          "input's data window and display window; --part picks the part of a multi-part\n"
          "file (default: the one with S0.color).\n");
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

static int list_variants(hfc_client *c) {
  const hfc_server_info *i = hfc_info(c);
  /* max_spp is the most any variant takes; each variant's own is on its
   * line below. */
  printf("%s%s%s, protocol v%d: max %dx%d, up to %d spp, %d in flight per connection, batch %d, "
         "queue %d, frames up to %llu MiB%s\n",
         i->name, i->software_version[0] ? " " : "", i->software_version, i->version,
         i->max_width, i->max_height, i->max_spp, i->max_inflight,
         i->max_batch, i->queue_size, (unsigned long long)(i->max_frame_bytes >> 20),
         i->auth_required ? ", token checked" : "");
  hfc_variant vs[64];
  int n = 0, rc = hfc_list_variants(c, vs, 64, &n);
  if (rc) {
    fprintf(stderr, "hairfilter: listing variants: %s (%s)\n", hfc_strerror(rc),
            hfc_last_message(c));
    return 1;
  }
  for (int k = 0; k < n && k < 64; k++) {
    printf("  %-16s %2d spp  levels ", vs[k].name, vs[k].spp);
    for (int l = 0; l < vs[k].num_levels; l++) printf("%s%d", l ? "," : "", vs[k].levels[l]);
    printf("  %s %s", vs[k].backend, vs[k].precision);
    /* What it reads besides the samples (protocol v3 servers). */
    if (vs[k].estimate) printf("  reads the alpha-corrected estimate (acst4.*)");
    /* What `filter` without --variant picks (with more than one variant). */
    if (n > 1 && !strcmp(vs[k].name, FILTER_DEFAULT_ESTIMATE_VARIANT) && vs[k].estimate)
      printf("  [default for frames with acst4.*]");
    else if (n > 1 && !strcmp(vs[k].name, FILTER_DEFAULT_VARIANT))
      printf("  [default for other frames]");
    /* The input statistics it was trained on (protocol v2 servers). */
    for (int s = 0, first = 1; s < HFC_MAX_STATS; s++)
      if (vs[k].range_mask & (1u << s)) {
        printf("%s%s %.4g..%.4g", first ? "  trained on " : ", ", hf_input_stat_name(s),
               vs[k].range_lo[s], vs[k].range_hi[s]);
        first = 0;
      }
    printf("\n");
  }
  return 0;
}

/* The upper bound of the histogram bucket where the cumulative count
 * reaches fraction p: a percentile to within a factor of two. */
static double hist_pct(const uint64_t *h, uint64_t n, double p) {
  uint64_t want = (uint64_t)(p * (double)n + 0.999999), cum = 0;
  for (int b = 0; b < HFC_HIST_BUCKETS; b++) {
    cum += h[b];
    if (cum >= want && cum) return b == HFC_HIST_BUCKETS - 1 ? -1 : (double)(32ull << b) / 1e3;
  }
  return 0;
}

static int print_stats(hfc_client *c) {
  hfc_stats *st = malloc(sizeof *st);
  if (!st) return 1;
  int rc = hfc_get_stats(c, st);
  if (rc) {
    fprintf(stderr, "hairfilter: stats: %s (%s)\n", hfc_strerror(rc), hfc_last_message(c));
    free(st);
    return 1;
  }
  printf("uptime %.1f s, connections %d open / %llu total, queue %d/%d, protocol errors %llu\n",
         st->uptime_us / 1e6, st->connections_open, (unsigned long long)st->connections_total,
         st->queue_depth, st->queue_capacity, (unsigned long long)st->protocol_errors);
  printf("  %-16s %9s %7s %8s %8s %7s %9s %9s %9s %9s %8s\n", "variant", "ok", "failed",
         "rejected", "batches", "frm/bat", "queue", "infer", "total", "p99<=", "outside");
  for (int i = 0; i < st->num_variants; i++) {
    const hfc_variant_stats *v = &st->variants[i];
    double n = v->requests_ok ? (double)v->requests_ok : 1;
    double p99 = hist_pct(v->hist_total, v->requests_ok, 0.99);
    printf("  %-16s %9llu %7llu %8llu %8llu %7.2f %7.2fms %7.2fms %7.2fms ", v->name,
           (unsigned long long)v->requests_ok, (unsigned long long)v->requests_failed,
           (unsigned long long)v->rejected, (unsigned long long)v->batches,
           v->batches ? (double)v->requests_ok / (double)v->batches : 0.0,
           v->sum_queue_us / n / 1e3, v->sum_infer_us / n / 1e3, v->sum_total_us / n / 1e3);
    if (p99 < 0)
      printf("%9s", "overflow");
    else
      printf("%7.2fms", p99);
    printf(" %8llu\n", (unsigned long long)v->out_of_range);
  }
  for (int i = 0; i < st->num_variants; i++)
    if (st->variants[i].frames_sanitised)
      printf("  %s: %llu frame(s) with non-finite or out-of-range input, sanitised "
             "(protocol/FEATURES.md)\n", st->variants[i].name,
             (unsigned long long)st->variants[i].frames_sanitised);
  for (int i = 0; i < st->num_variants; i++)
    if (st->variants[i].expired)
      printf("  %s: %llu frame(s) expired in the queue, not computed (their budget passed: "
             "failed EXPIRED, protocol version 4)\n", st->variants[i].name,
             (unsigned long long)st->variants[i].expired);
  for (int i = 0; i < st->num_variants; i++)
    if (st->variants[i].cancelled)
      printf("  %s: %llu frame(s) cancelled in the queue, not computed (their client's CANCEL: "
             "failed CANCELLED, protocol version 4)\n", st->variants[i].name,
             (unsigned long long)st->variants[i].cancelled);
  printf("  (failed: frames answered with a status other than OK, EXPIRED and CANCELLED "
         "included;\n   queue/infer/total: means over successful requests; p99<=: bound from the "
         "total-latency histogram;\n   outside: frames outside the variant's trained input "
         "range, protocol v2 servers)\n");
  free(st);
  return 0;
}

int cmd_filter(int argc, char **argv) {
  const char *server = NULL, *variant = NULL, *in_path = NULL, *out_path = NULL, *png = NULL;
  const char *part = NULL;
  const char *token = getenv("HAIRFILTER_TOKEN");
  int f16 = 0, timeout_ms = 0, list = 0, stats = 0;
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
    {"list", no_argument, 0, 'l'},         {"stats", no_argument, 0, 'S'},
    {"part", required_argument, 0, 'P'},   CLI_TLS_LONG_OPTIONS,
    {0, 0, 0, 0}};
  cli_tls tls = {0};
  int opt;
  optind = 1;
  while ((opt = getopt_long(argc, argv, "s:V:i:o:p:h", opts, NULL)) != -1) {
    switch (opt) {
    case 's': server = optarg; break;
    case 'V': variant = optarg; break;
    case 'i': in_path = optarg; break;
    case 'o': out_path = optarg; break;
    case 'p': png = optarg; break;
    case 'P': part = optarg; break;
    case 'F': f16 = 1; break;
    case 'l': list = 1; break;
    case 'S': stats = 1; break;
    case 'T': token = optarg; break;
    case 't': {
      /* Milliseconds, the whole argument: "10s" is refused, not 10 ms. */
      long v;
      if (cli_arg_long("hairfilter filter", "--timeout-ms", optarg, -1, 86400000, &v)) return 2;
      timeout_ms = (int)v;
      break;
    }
    case 'H': if (cli_parse_rgb("hairfilter filter", "--hair", optarg, hair)) return 2; break;
    case 'L': if (cli_parse_rgb("hairfilter filter", "--light", optarg, light)) return 2; break;
    case 'B': if (cli_parse_rgb("hairfilter filter", "--background", optarg, bg)) return 2; break;
    case 'h': usage(stdout); return 0;
    default:
      if (!cli_tls_option(opt, optarg, &tls)) goto bad;
    }
  }
  if (!server || optind != argc) goto bad;
  if (cli_tls_pair("hairfilter filter", tls.cert, tls.key)) return 2;
  if (cli_tls_for_server("hairfilter filter", server, &tls)) return 2;
  char why[300];
  if (hfc_check_url(server, why, sizeof why)) {
    fprintf(stderr, "hairfilter: --server: %s\n", why);
    return 2;
  }
  hfc_options o;
  hfc_options_init(&o);
  o.client_name = "hairfilter-cli";
  o.token = token;
  o.timeout_ms = timeout_ms;
  o.tls_ca_file = tls.ca;
  o.tls_cert_file = tls.cert;
  o.tls_key_file = tls.key;
  o.tls_server_name = tls.server_name;
  if (list || stats) {
    hfc_client *c = NULL;
    int rc = hfc_connect(server, &o, &c);
    if (rc) {
      cli_connect_failed("hairfilter", rc);
      return 1;
    }
    int ret = (list && list_variants(c)) || (stats && print_stats(c));
    hfc_close(c);
    return ret;
  }
  if (!in_path || !out_path) goto bad;
  if (cli_check_output("hairfilter filter", out_path) || cli_check_output("hairfilter filter", png))
    return 1;

  int ret = 1, rc;
  hfc_client *c = NULL;
  hf_image feat = {0}, res = {0}, layer = {0};
  void *in = NULL, *out = NULL, *rgba = NULL, *out16 = NULL, *rgba16 = NULL;
  float *rgb = NULL;
  if ((rc = hfc_connect(server, &o, &c)) != 0) {
    cli_connect_failed("hairfilter", rc);
    return 1;
  }
  hfc_variant vs[64];
  int nv = 0;
  if ((rc = hfc_list_variants(c, vs, 64, &nv)) != 0) {
    fprintf(stderr, "hairfilter: listing variants: %s (%s)\n", hfc_strerror(rc),
            hfc_last_message(c));
    goto out;
  }
  /* Names are matched as the library matches them: exactly, else without
   * regard to case. */
  const hfc_variant *v = NULL;
  for (int i = 0; i < nv && i < 64; i++)
    if (variant ? !strcmp(vs[i].name, variant) : nv == 1) v = &vs[i];
  for (int i = 0; i < nv && i < 64 && variant && !v; i++)
    if (!strcasecmp(vs[i].name, variant)) v = &vs[i];
  /* The default: KernelMix, else KernelAC, where the frame has the estimate
   * to give it. */
  const int has_estimate =
      !variant && !v && hf_exr_has_channel(in_path, HF_ESTIMATE_PREFIX ".alpha") == 1;
  static const char *const estimate_defaults[] = {FILTER_DEFAULT_ESTIMATE_VARIANT,
                                                  FILTER_FALLBACK_ESTIMATE_VARIANT};
  const size_t n_defaults = sizeof estimate_defaults / sizeof *estimate_defaults;
  for (size_t d = 0; d < n_defaults && !variant && !v && has_estimate; d++)
    for (int i = 0; i < nv && i < 64 && !v; i++)
      if (!strcmp(vs[i].name, estimate_defaults[d]) && vs[i].estimate) v = &vs[i];
  /* Kernel reads the samples alone: any frame, the estimate or not. */
  for (int i = 0; i < nv && i < 64 && !variant && !v; i++)
    if (!strcmp(vs[i].name, FILTER_DEFAULT_VARIANT)) v = &vs[i];
  if (!v) {
    if (variant)
      fprintf(stderr, "hairfilter: no such variant \"%s\"; the server has:", variant);
    else
      fprintf(stderr, "hairfilter: name a --variant: the default is "
              FILTER_DEFAULT_ESTIMATE_VARIANT " (else " FILTER_FALLBACK_ESTIMATE_VARIANT ") for "
              "a frame with the alpha-corrected estimate (acst4.*), else " FILTER_DEFAULT_VARIANT
              "; this frame has %s, and the server has no %s; it has:", has_estimate ? "it" : "none",
              has_estimate ? FILTER_DEFAULT_ESTIMATE_VARIANT ", " FILTER_FALLBACK_ESTIMATE_VARIANT
                             " nor " FILTER_DEFAULT_VARIANT
                           : FILTER_DEFAULT_VARIANT);
    for (int i = 0; i < nv && i < 64; i++) fprintf(stderr, " %s", vs[i].name);
    fprintf(stderr, "\n");
    goto out;
  }
  /* With --f16 a HALF file goes to the server as stored: no conversion. */
  struct timespec t0, t1;
  clock_gettime(CLOCK_MONOTONIC, &t0);
  /* A variant that reads the estimate gets it after the samples. */
  const int estimate = v->estimate ? HF_ESTIMATE_ALPHA_CORRECTED : HF_ESTIMATE_NONE;
  if (cli_read_features(in_path, part, v->spp, estimate, v->name, f16 ? HF_F16 : HF_F32, &feat,
                        &in, &layer) != 0)
    goto out;
  /* A frame with a background layer is composited here over it (the
   * server's composite knows only a flat background); else by the server. */
  const int local = png && layer.width > 0;
  clock_gettime(CLOCK_MONOTONIC, &t1);
  double read_ms = (double)(t1.tv_sec - t0.tv_sec) * 1e3 + (double)(t1.tv_nsec - t0.tv_nsec) / 1e6;
  size_t npx = (size_t)feat.width * feat.height;
  size_t nin = npx * (size_t)hf_net_in_channels(v->spp, estimate);
  out = malloc(npx * 3 * sizeof(float));
  const int remote = png && !local;
  rgba = remote ? malloc(npx * 4 * sizeof(float)) : NULL;
  if (f16) {
    out16 = malloc(npx * 3 * sizeof(uint16_t));
    rgba16 = remote ? malloc(npx * 4 * sizeof(uint16_t)) : NULL;
  }
  if (!out || (remote && !rgba) || (f16 && (!out16 || (remote && !rgba16)))) {
    fprintf(stderr, "hairfilter: out of memory for a %dx%d frame\n", feat.width, feat.height);
    goto out;
  }
  hfc_request r;
  hfc_request_init(&r);
  r.variant = v->name;
  r.width = feat.width;
  r.height = feat.height;
  r.spp = v->spp;
  r.in_dtype = r.out_dtype = f16 ? HFC_F16 : HFC_F32;
  const size_t es = f16 ? sizeof(uint16_t) : sizeof(float);
  r.features = in;
  r.features_bytes = nin * es;
  r.estimate = estimate != HF_ESTIMATE_NONE;
  r.result = f16 ? out16 : out;
  r.result_bytes = npx * 3 * es;
  r.rgba = f16 ? rgba16 : rgba;
  r.rgba_bytes = rgba ? npx * 4 * es : 0;
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
    hf_f16_to_f32_array(out16, out, npx * 3);
    if (rgba) hf_f16_to_f32_array(rgba16, rgba, npx * 4);
  }
  if (t.out_of_range) {
    /* The server judged the frame; its statistics and the range, from the
     * same definitions (hf_input_stats), say why. The input is still as
     * sent (f16 or f32) until here. */
    hf_input_range r;
    memset(&r, 0, sizeof r);
    r.present = 1;
    r.spp = v->spp;
    for (int s = 0; s < HFC_MAX_STATS && s < HF_STAT_COUNT; s++)
      if (v->range_mask & (1u << s)) {
        r.has |= 1u << s;
        r.lo[s] = v->range_lo[s];
        r.hi[s] = v->range_hi[s];
      }
    hf_input_stats st;
    int bad = cli_input_range_check(&r, in, f16 ? HF_F16 : HF_F32, feat.width, feat.height,
                                    v->spp, &st);
    if (bad > 0)
      cli_warn_input_range("hairfilter", in_path, v->name, &r, &st, (unsigned)bad);
    else
      fprintf(stderr, "hairfilter: warning: %s is outside the input range %s was trained on "
              "(the server says so)\n", in_path, v->name);
  }
  if (t.input_sanitised) {
    /* The server says that it sanitised; the same check here says where. */
    hf_input_report rep;
    void *scratch = estimate ? malloc(nin * es) : NULL;
    if (scratch)  /* the estimate's values too, as the server checked them */
      hf_features_interleave(in, f16 ? HF_F16 : HF_F32, feat.width, feat.height, v->spp, scratch,
                             &rep, NULL);
    else
      hf_features_check(in, f16 ? HF_F16 : HF_F32, feat.width, feat.height, v->spp, &rep);
    free(scratch);
    cli_warn_sanitised(in_path, &feat, &rep);
  }
  printf("%s %dx%d via %s (%s, %s, batch %d)\n", v->name, feat.width, feat.height, server,
         v->backend, v->precision, t.batch);
  printf("  read    %10.3f ms  (%s into the request's %s, client side)\n", read_ms, in_path,
         f16 ? "f16" : "f32");
  print_timing(&t);
  if ((rc = hf_result_to_image(out, feat.width, feat.height, &res)) == 0)
    hf_image_copy_windows(&res, &feat);
  if (rc != 0 || (rc = hf_exr_write(out_path, &res, 0)) != 0) {
    fprintf(stderr, "hairfilter: writing %s: %s\n", out_path, hf_strerror(rc));
    goto out;
  }
  if (local) {
    if ((rc = cli_write_preview(png, out, feat.width, feat.height, &layer, hair, light, bg))) {
      fprintf(stderr, "hairfilter: writing %s: %s\n", png, hf_strerror(rc));
      goto out;
    }
  } else if (png) {
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
  hf_image_free(&layer);
  hf_image_free(&res);
  free(in);
  free(out);
  free(rgba);
  free(out16);
  free(rgba16);
  free(rgb);
  return ret;
bad:
  usage(stderr);
  return 2;
}
