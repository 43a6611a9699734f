/* hairfilter demo: the README's main job, the whole path of a frame on the
 * bundled defaults.
 *
 *   render (OSMesa, stochastic transparency, 4 spp + supersampled ground
 *   truth) -> start hairfilterd on a private Unix socket -> filter through
 *   the client library -> composite -> PNG (input | filtered | ground truth)
 *   -> stop hairfilterd with SIGTERM.
 *
 * --in-process skips the daemon and runs the network in this process. */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "cli_common.h"
#include "commands.h"
#include "eval_metrics.h"
#include <hairfilter/hairfilter.h>
#include "hfrender.h"

typedef struct demo_opts {
  const char *out, *backend, *weights, *style;
  int width, height, in_process;
  uint64_t seed;
} demo_opts;

/* hairfilterd lives beside this binary in the build tree and when installed. */
static int daemon_path(char *buf, size_t len) {
  char self[PATH_MAX];
  ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
  if (n <= 0) return -1;
  self[n] = 0;
  char *slash = strrchr(self, '/');
  if (!slash) return -1;
  *slash = 0;
  if ((size_t)snprintf(buf, len, "%.*s/hairfilterd", (int)(len - 13), self) >= len) return -1;
  return access(buf, X_OK);
}

/* Starts hairfilterd and waits until it says it is serving. */
static pid_t start_daemon(const char *exe, const char *weights, const char *backend,
                          const char *dir, char *url, size_t urllen) {
  char listen[PATH_MAX + 8], ready[PATH_MAX];
  snprintf(listen, sizeof listen, "unix:%s/hairfilterd.sock", dir);
  snprintf(ready, sizeof ready, "%s/ready", dir);
  pid_t pid = fork();
  if (pid < 0) return -1;
  if (pid == 0) {
    execl(exe, exe, "--listen", listen, "--weights", weights, "--backend", backend,
          "--ready-file", ready, (char *)NULL);
    fprintf(stderr, "hairfilter demo: cannot run %s: %s\n", exe, strerror(errno));
    _exit(127);
  }
  for (int i = 0; i < 600; i++) { /* up to 60 s: model preparation included */
    struct stat st;
    if (stat(ready, &st) == 0 && st.st_size > 0) {
      snprintf(url, urllen, "%s", listen);
      return pid;
    }
    int status;
    if (waitpid(pid, &status, WNOHANG) == pid) {
      fprintf(stderr, "hairfilter demo: hairfilterd exited before serving\n");
      return -1;
    }
    struct timespec ts = {0, 100 * 1000 * 1000};
    nanosleep(&ts, NULL);
  }
  kill(pid, SIGKILL);
  waitpid(pid, NULL, 0);
  fprintf(stderr, "hairfilter demo: hairfilterd did not become ready\n");
  return -1;
}

static int stop_daemon(pid_t pid) {
  int status;
  if (kill(pid, SIGTERM) != 0 || waitpid(pid, &status, 0) != pid) return -1;
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    fprintf(stderr, "hairfilter demo: hairfilterd did not exit cleanly\n");
    return -1;
  }
  return 0;
}

/* Filters through hairfilterd: the path a frame takes in production. */
static int filter_via_daemon(const demo_opts *o, const hf_net_config *cfg, const float *in,
                             float *out) {
  char exe[PATH_MAX], dir[] = "/tmp/hairfilter-demo-XXXXXX", url[PATH_MAX + 8];
  if (daemon_path(exe, sizeof exe) != 0) {
    fprintf(stderr, "hairfilter demo: hairfilterd not found beside this binary "
                    "(use --in-process)\n");
    return -1;
  }
  if (!mkdtemp(dir)) return -1;
  int rc = -1;
  pid_t pid = start_daemon(exe, o->weights, o->backend, dir, url, sizeof url);
  if (pid > 0) {
    hfc_client *c = NULL;
    int crc = hfc_connect(url, NULL, &c);
    if (crc == HFC_OK) {
      hfc_request r;
      hfc_request_init(&r);
      r.variant = cfg->name;
      r.width = o->width;
      r.height = o->height;
      r.spp = cfg->spp;
      r.features = in;
      r.estimate = cfg->estimate != HF_ESTIMATE_NONE;
      r.features_bytes = hfc_features_bytes(o->width, o->height, cfg->spp, HFC_F32) +
                         (r.estimate ? hfc_estimate_bytes(o->width, o->height, HFC_F32) : 0);
      r.result = out;
      r.result_bytes = hfc_output_bytes(o->width, o->height, 3, HFC_F32);
      hfc_timing t;
      crc = hfc_filter(c, &r, &t);
      if (crc == HFC_OK) {
        printf("filtered %dx%d with %s through hairfilterd: queue %.0f us, input %.0f us, "
               "infer %.0f us, output %.0f us, server %.0f us, round trip %.0f us\n",
               o->width, o->height, cfg->name, t.queue_us, t.input_us, t.infer_us,
               t.output_us, t.server_us, t.total_us);
        rc = 0;
      }
      hfc_close(c);
    }
    /* This thread's message: the client is closed by now. */
    if (crc != HFC_OK)
      fprintf(stderr, "hairfilter demo: %s (%s)\n", hfc_strerror(crc), hfc_last_message(NULL));
    if (stop_daemon(pid) != 0) rc = -1;
  }
  char path[PATH_MAX + 16];
  snprintf(path, sizeof path, "%s/ready", dir);
  unlink(path);
  rmdir(dir);
  return rc;
}

static int filter_in_process(const demo_opts *o, const hf_weights *w, const float *in,
                             float *out) {
  hf_backend *b;
  hf_model *m;
  if (cli_open_backend(o->backend, &b)) return -1;
  int rc = hf_model_create(b, w, &m);
  if (rc == 0) {
    hf_io io = {1, o->width, o->height, in, HF_F32, out, HF_F32};
    hf_timing t;
    rc = hf_model_run(m, &io, &t);
    if (rc == 0)
      printf("filtered %dx%d with %s in-process on %s: infer %.0f us\n", o->width, o->height,
             w->cfg.name, hf_backend_name(b), t.infer_us);
    hf_model_destroy(m);
  }
  if (rc) fprintf(stderr, "hairfilter demo: %s\n", hf_strerror(rc));
  hf_backend_destroy(b);
  return rc ? -1 : 0;
}

/* Three composites side by side; returns the PNG's rc. */
static int write_triptych(const char *path, const float *const panels[3], int w, int h) {
  float *rgb = malloc((size_t)w * 3 * h * 3 * sizeof(float));
  if (!rgb) return HF_ENOMEM;
  for (int y = 0; y < h; y++)
    for (int p = 0; p < 3; p++)
      memcpy(rgb + ((size_t)y * 3 * w + (size_t)p * w) * 3, panels[p] + (size_t)y * w * 3,
             (size_t)w * 3 * sizeof(float));
  int rc = hf_png_write_rgb(path, rgb, 3 * w, h);
  free(rgb);
  return rc;
}

static void usage(FILE *f) {
  fprintf(f, "usage: hairfilter demo [--out PNG] [--weights W.safetensors] [--backend NAME]\n"
             "                       [--style NAME] [--size WxH] [--seed N] [--in-process]\n");
}

int cmd_demo(int argc, char **argv) {
  char default_weights[PATH_MAX];
  snprintf(default_weights, sizeof default_weights, "%s/weights/kernel_mix.safetensors",
           cli_data_dir());
  demo_opts o = {.out = "hairfilter-demo.png", .backend = "auto", .weights = default_weights,
                 .style = "wavy", .width = 256, .height = 256, .seed = 7};
  static const struct option opts[] = {
    {"out", required_argument, 0, 'o'},   {"backend", required_argument, 0, 'b'},
    {"weights", required_argument, 0, 'w'}, {"style", required_argument, 0, 's'},
    {"size", required_argument, 0, 'S'},  {"seed", required_argument, 0, 'r'},
    {"in-process", no_argument, 0, 'i'},  {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0}};
  int ch;
  optind = 1;
  while ((ch = getopt_long(argc, argv, "o:b:w:h", opts, NULL)) != -1) {
    switch (ch) {
    case 'o': o.out = optarg; break;
    case 'b': o.backend = optarg; break;
    case 'w': o.weights = optarg; break;
    case 's': o.style = optarg; break;
    case 'S': if (cli_parse_size(optarg, &o.width, &o.height)) goto bad; break;
    case 'r': o.seed = strtoull(optarg, NULL, 10); break;
    case 'i': o.in_process = 1; break;
    case 'h': usage(stdout); return 0;
    default: goto bad;
    }
  }
  if (optind != argc) goto bad;
  if (cli_check_output("hairfilter demo", o.out)) return 1;

  char err[512];
  hf_weights *w = NULL;
  if (hf_weights_load(o.weights, &w, err, sizeof err)) {
    fprintf(stderr, "hairfilter demo: %s\n", err);
    return 1;
  }
  hfr_frame f;
  hfr_frame_defaults(&f, o.width, o.height);
  if (hfr_style_from_name(o.style, &f.style.style) < 0 ||
      hfr_style_defaults(f.style.style, &f.style) < 0) {
    char known[256];
    hfr_style_list(known, sizeof known);
    fprintf(stderr, "hairfilter demo: --style '%s': no such style (the styles: %s)\n", o.style,
            known);
    hf_weights_free(w);
    return 2;
  }
  f.style.seed = o.seed;
  f.outputs.spp = w->cfg.spp;
  f.outputs.background_layer = 1; /* the head under the hair, not a hole */
  /* A variant that reads stochastic transparency's alpha-corrected estimate
   * gets it rendered too (one more draw of the hair). */
  f.outputs.alpha_corrected = w->cfg.estimate != HF_ESTIMATE_NONE;
  hf_image img = {0};
  hfr_stats st;
  int rc = 1;
  float *in = NULL, *out = NULL, *panels[3] = {0};
  if (hfr_render_frame(&f, &img, &st, err, sizeof err)) {
    fprintf(stderr, "hairfilter demo: render: %s\n", err);
    goto done;
  }
  printf("rendered %s, %d strands, %dx%d at %d spp: features %.0f ms, ground truth %.0f ms\n",
         hfr_style_name(f.style.style), f.style.strands, o.width, o.height, w->cfg.spp,
         st.features_ms, st.gt_ms);
  size_t npx = (size_t)o.width * o.height;
  in = malloc(npx * w->cfg.in_channels * sizeof(float));
  out = malloc(npx * 3 * sizeof(float));
  for (int p = 0; p < 3; p++) panels[p] = malloc(npx * 3 * sizeof(float));
  if (!in || !out || !panels[0] || !panels[1] || !panels[2]) goto done;
  if (hf_features_from_image(&img, w->cfg.spp, in) < 0) goto done;
  if (w->cfg.estimate &&
      hf_estimate_from_data(&img, img.data, HF_F32, in + npx * w->cfg.spp * HF_FEATURES_PER_SAMPLE))
    goto done;

  if ((o.in_process ? filter_in_process(&o, w, in, out) : filter_via_daemon(&o, &w->cfg, in, out)))
    goto done;

  /* Input panel: what stochastic transparency alone shows at this spp. */
  float *est = malloc(npx * 3 * sizeof(float));
  if (!est) goto done;
  for (size_t p = 0; p < npx; p++)
    hf_st_estimate(in + p * w->cfg.spp * HF_FEATURES_PER_SAMPLE, w->cfg.spp, est + p * 3);
  hfr_composite_result(est, o.width, o.height, &img, f.view.hair_color, f.view.light_color,
                       f.view.background, panels[0]);
  free(est);
  hfr_composite_result(out, o.width, o.height, &img, f.view.hair_color, f.view.light_color,
                       f.view.background, panels[1]);
  if (hfr_composite_channels(&img, "gt", &f.view, panels[2])) goto done;

  /* Scores on hair pixels (ground-truth alpha > 0), as docs/QUALITY.md. */
  uint8_t *mask = malloc(npx);
  int gta = hf_image_channel(&img, "gt.alpha");
  if (mask && gta >= 0) {
    for (size_t p = 0; p < npx; p++) mask[p] = img.data[p * img.channels + gta] > 0;
    printf("PSNR on hair pixels vs ground truth: stochastic transparency %d spp %.2f dB, "
           "filtered %.2f dB\n", w->cfg.spp,
           eval_psnr(eval_mse(panels[0], panels[2], o.width, o.height, 3, mask, NULL), 1.0),
           eval_psnr(eval_mse(panels[1], panels[2], o.width, o.height, 3, mask, NULL), 1.0));
  }
  free(mask);
  if ((rc = write_triptych(o.out, (const float *const *)panels, o.width, o.height)) != 0) {
    fprintf(stderr, "hairfilter demo: writing %s: %s\n", o.out, hf_strerror(rc));
    rc = 1;
    goto done;
  }
  printf("wrote %s (stochastic transparency %d spp | filtered | ground truth)\n", o.out,
         w->cfg.spp);
  rc = 0;
done:
  for (int p = 0; p < 3; p++) free(panels[p]);
  free(in);
  free(out);
  hf_image_free(&img);
  hf_weights_free(w);
  return rc;
bad:
  usage(stderr);
  return 2;
}
