/* hairfilter bench: time backends and variants on random weights and
 * feature-like inputs, print a Markdown table; with --torch, PyTorch on the
 * same weights (bench/bench_torch.py) in the same table.
 *
 * Timing: per iteration the wall time of one hf_model_run of a batch
 * (input conversion, network, output transforms), after warm-up; the table
 * gives the median and 90th percentile over iterations divided by the batch.
 * "net ms" is the median of the backend's own infer_us alone. With
 * --pipeline, batches are submitted two at a time (hf_model_submit: the
 * next one uploads while this one computes) and an iteration is the time
 * between two consecutive completions, i.e. throughput.
 *
 * --input-stats adds a table of what judging a frame's input against a
 * trained range costs (hf_input_stats_compute, as hairfilterd runs it per
 * frame), beside a memcpy of the same frame: the cheapest pass over it;
 * --input-check the same for the out-of-contract check (hf_features_check,
 * one thread), then for both in the one threaded pass hf_model_run makes on
 * every frame (hf_features_scan); --exr what hf_exr_write costs with
 * its read-back comparison, beside hf_exr_read.
 *
 * Before the table it prints the CPU (model, vector flags) and the fp32
 * peak it measures before and after the runs (bench_peak.h); CPU rows say
 * how many GFLOP/s a frame's multiply-adds (hf_net_macs at the padded size)
 * came to, and what fraction of that peak; and the process's CPU time per
 * frame (every thread's, hf_model_run's alone: the median over iterations),
 * with the flops per CPU second as a fraction of one core's peak: what the
 * code does with the cores it gets, whatever other work on the machine took. */
#include <errno.h>
#include <getopt.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bench_peak.h"
#include "cli_common.h"
#include "commands.h"

#define BENCH_MAX_LIST 16
#define BENCH_ROWS_MAX 1024
#define BENCH_REF_SIDE 256 /* cpu-ref's sizes stop here by default: it is loops */
#define BENCH_REF_ITERS 5  /* and it runs at most this many iterations */

typedef struct bench_row {
  char backend[24], variant[HF_NAME_MAX], precision[8];
  int w, h, batch, iters;
  double med_ms, p90_ms;         /* per frame, wall time of hf_model_run */
  double in_ms, net_ms, out_ms;  /* per frame, medians of hf_timing; < 0 unknown */
  double cpu_ms;                 /* per frame, median of the process's CPU time; < 0 unknown */
  double dev_bytes;
  hf_net_config cfg;             /* the network timed (has_cfg), for its GFLOP/s */
  int has_cfg;
} bench_row;

typedef struct bench_opts {
  const char *backends[BENCH_MAX_LIST];
  int nbackends, backends_all;
  char variants[BENCH_MAX_LIST][HF_NAME_MAX];
  int nvariants;
  const char *weights[BENCH_MAX_LIST]; /* --weights: trained files, timed as they are */
  int nweights;
  hf_weights *loaded[BENCH_MAX_LIST];  /* each file, loaded once (NULL: it did not load) */
  char labels[BENCH_MAX_LIST][HF_NAME_MAX]; /* its variant column (weights_label) */
  int sizes[BENCH_MAX_LIST][2];
  int nsizes, ref_max_side;
  int batches[BENCH_MAX_LIST];
  int nbatches;
  int iters, warmup, torch, input_stats, input_check, exr, pipeline, pinned;
  hf_dtype io_dtype;
  const char *torch_device, *python;
  uint64_t seed;
} bench_opts;

static bench_row rows[BENCH_ROWS_MAX];
static int nrows;

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter bench [--backend cpu,cpu-ref,cudnn|all] [--variants Base,...|all]\n"
          "                        [--sizes 256x256,512x512,1024x1024] [--batch 1,4]\n"
          "                        [--iters N] [--warmup N] [--seed N] [--ref-max-side N]\n"
          "                        [--io f32|f16] [--pipeline] [--pinned] [--input-stats]\n"
          "                        [--torch] [--torch-device cpu|cuda] [--python PATH]\n"
          "                        [--input-check] [--exr] [--weights FILE,...]\n"
          "Times each backend, variant, size and batch on random weights; prints a Markdown\n"
          "table of ms per frame (median, p90 over iterations after warm-up), frames/s and\n"
          "device memory. cpu-ref runs only sizes whose sides are at most --ref-max-side\n"
          "(default %d), and at most %d iterations after 1 warm-up.\n"
          "--io f16 sends and receives FP16 tensors (default f32). --pipeline keeps two\n"
          "batches in flight (hf_model_submit/wait) and times completions: throughput.\n"
          "--pinned registers the frames' memory with the backend first\n"
          "(hf_backend_host_register), as hairfilterd does a shared-memory segment: the\n"
          "cudnn backend then uploads by DMA and checks the input on the device (rows\n"
          "labelled -pinned; HF_CUDNN_HOST_CHECK=1 checks on the host, to compare).\n"
          "--torch adds PyTorch rows (bench/bench_torch.py, found under the data directory:\n"
          "$HAIRFILTER_DATA, else beside this executable) on the same weights, run by\n"
          "--python, else $HAIRFILTER_PYTHON, else the first of python3 on PATH and\n"
          "/usr/bin/python3 that imports torch. --input-stats adds what the per-frame input\n"
          "statistics cost at each size (4 spp, f32 and f16, half the samples covered)\n"
          "beside a memcpy of the frame; --input-check the same for the out-of-contract\n"
          "check, then for both in hf_model_run's one threaded pass; --exr EXR writing\n"
          "(with its read-back check) beside reading, at each size. Defaults: every\n"
          "backend in this build, Base, the three sizes, batch 1, 20 iterations, 3 warm-up.\n"
          "Before the table: the CPU's model and vector flags, and its fp32 peak measured\n"
          "before and after the runs (an FMA loop on one thread, per second of its CPU time,\n"
          "times the threads); each CPU row gives its GFLOP/s (hf_net_macs) and %% of that,\n"
          "its CPU ms per frame (all threads) and its flops per CPU second as %% of one core's.\n"
          "--weights times these safetensors files as they are (a trained variant whose shape\n"
          "is no preset's, such as another kernel_hidden), in rows labelled NAME:FILE (the\n"
          "file's variant name and base name, #2 and on for a base name seen before);\n"
          "alone, without --variants, only them. Commas separate the files, so a path\n"
          "cannot hold one.\n",
          BENCH_REF_SIDE, BENCH_REF_ITERS);
}

/* Splits a comma-separated list in place; returns the count or -1. */
static int split(char *s, char **out, int max) {
  int n = 0;
  for (char *tok = strtok(s, ","); tok; tok = strtok(NULL, ",")) {
    if (n == max) return -1;
    out[n++] = tok;
  }
  return n;
}

static int parse_opts(int argc, char **argv, bench_opts *o) {
  static const struct option longs[] = {
    {"backend", required_argument, 0, 'b'}, {"variants", required_argument, 0, 'v'},
    {"sizes", required_argument, 0, 's'},   {"batch", required_argument, 0, 'n'},
    {"iters", required_argument, 0, 'i'},   {"warmup", required_argument, 0, 'w'},
    {"seed", required_argument, 0, 'S'},    {"torch", no_argument, 0, 't'},
    {"torch-device", required_argument, 0, 'd'}, {"ref-max-side", required_argument, 0, 'r'},
    {"python", required_argument, 0, 'p'},  {"io", required_argument, 0, 'o'},
    {"pipeline", no_argument, 0, 'P'},      {"input-stats", no_argument, 0, 'I'},
    {"pinned", no_argument, 0, 'R'},
    {"help", no_argument, 0, 'h'},
    {"input-check", no_argument, 0, 'C'},   {"exr", no_argument, 0, 'E'},
    {"weights", required_argument, 0, 'W'},
    {0, 0, 0, 0},
  };
  static char buf_b[512], buf_v[512], buf_s[512], buf_n[256], buf_w[4096];
  const char *arg_b = "all", *arg_v = "Base", *arg_s = "256x256,512x512,1024x1024",
             *arg_n = "1", *arg_w = NULL;
  int variants_given = 0;
  o->iters = 20;
  o->warmup = 3;
  o->seed = 1;
  o->torch_device = "cpu";
  o->ref_max_side = BENCH_REF_SIDE;
  int c;
  optind = 1;
  while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
    char *end;
    switch (c) {
    case 'b': arg_b = optarg; break;
    case 'v': arg_v = optarg, variants_given = 1; break;
    case 'W': arg_w = optarg; break;
    case 's': arg_s = optarg; break;
    case 'n': arg_n = optarg; break;
    case 'i':
    case 'w':
    case 'r': {
      long v = strtol(optarg, &end, 10);
      const char *name = c == 'i' ? "iters" : c == 'w' ? "warmup" : "ref-max-side";
      if (*end || v < (c == 'w' ? 0 : 1) || v > 100000) {
        fprintf(stderr, "hairfilter bench: bad --%s '%s'\n", name, optarg);
        return 2;
      }
      *(c == 'i' ? &o->iters : c == 'w' ? &o->warmup : &o->ref_max_side) = (int)v;
      break;
    }
    case 'S': o->seed = strtoull(optarg, &end, 10); if (*end) return 2; break;
    case 't': o->torch = 1; break;
    case 'I': o->input_stats = 1; break;
    case 'p': o->python = optarg; break;
    case 'P': o->pipeline = 1; break;
    case 'R': o->pinned = 1; break;
    case 'o':
      if (strcmp(optarg, "f32") && strcmp(optarg, "f16")) {
        fprintf(stderr, "hairfilter bench: --io is f32 or f16\n");
        return 2;
      }
      o->io_dtype = !strcmp(optarg, "f16") ? HF_F16 : HF_F32;
      break;
    case 'C': o->input_check = 1; break;
    case 'E': o->exr = 1; break;
    case 'd':
      if (strcmp(optarg, "cpu") && strcmp(optarg, "cuda")) {
        fprintf(stderr, "hairfilter bench: --torch-device is cpu or cuda\n");
        return 2;
      }
      o->torch_device = optarg;
      break;
    case 'h': usage(stdout); return 1;
    default: usage(stderr); return 2;
    }
  }
  if (optind < argc) {
    fprintf(stderr, "hairfilter bench: unexpected argument '%s'\n", argv[optind]);
    return 2;
  }
  char *items[BENCH_MAX_LIST];
  const char *list = "";        /* the option whose list is bad */
  int n;
  /* Backends. */
  snprintf(buf_b, sizeof buf_b, "%s", arg_b);
  if (!strcmp(buf_b, "all")) {
    o->backends_all = 1;
    const char *const *names = hf_backend_list();
    for (int i = 0; names[i] && o->nbackends < BENCH_MAX_LIST; i++)
      o->backends[o->nbackends++] = names[i];
  } else {
    if ((n = split(buf_b, items, BENCH_MAX_LIST)) <= 0) {
      list = "--backend";
      goto bad_list;
    }
    for (int i = 0; i < n; i++) o->backends[o->nbackends++] = items[i];
  }
  /* Weights files. */
  if (arg_w) {
    list = "--weights";
    if (strlen(arg_w) >= sizeof buf_w) {
      fprintf(stderr, "hairfilter bench: --weights: the list is longer than %zu characters\n",
              sizeof buf_w - 1);
      return 2;
    }
    snprintf(buf_w, sizeof buf_w, "%s", arg_w);
    if ((n = split(buf_w, items, BENCH_MAX_LIST)) <= 0) goto bad_list;
    for (int i = 0; i < n; i++) o->weights[o->nweights++] = items[i];
  }
  /* Variants. */
  snprintf(buf_v, sizeof buf_v, "%s", arg_v);
  if (arg_w && !variants_given) {
    /* --weights alone: only the files. */
  } else if (!strcmp(buf_v, "all")) {
    for (int i = 0; i < hf_variant_preset_count() && o->nvariants < BENCH_MAX_LIST; i++)
      snprintf(o->variants[o->nvariants++], HF_NAME_MAX, "%s", hf_variant_preset_name(i));
  } else {
    if ((n = split(buf_v, items, BENCH_MAX_LIST)) <= 0) {
      list = "--variants";
      goto bad_list;
    }
    for (int i = 0; i < n; i++) {
      hf_net_config cfg;
      if (hf_variant_preset(items[i], &cfg)) {
        fprintf(stderr, "hairfilter bench: unknown variant '%s'\n", items[i]);
        return 2;
      }
      snprintf(o->variants[o->nvariants++], HF_NAME_MAX, "%s", cfg.name);
    }
  }
  /* Sizes. */
  snprintf(buf_s, sizeof buf_s, "%s", arg_s);
  list = "--sizes";
  if ((n = split(buf_s, items, BENCH_MAX_LIST)) <= 0) goto bad_list;
  for (int i = 0; i < n; i++) {
    int *wh = o->sizes[o->nsizes++];
    if (cli_parse_size(items[i], &wh[0], &wh[1]) || wh[0] < 1 || wh[1] < 1 || wh[0] > 16384 ||
        wh[1] > 16384) {
      fprintf(stderr, "hairfilter bench: bad size '%s' (WxH, sides 1..16384)\n", items[i]);
      return 2;
    }
  }
  /* Batches. */
  snprintf(buf_n, sizeof buf_n, "%s", arg_n);
  list = "--batch";
  if ((n = split(buf_n, items, BENCH_MAX_LIST)) <= 0) goto bad_list;
  for (int i = 0; i < n; i++) {
    char *end;
    long v = strtol(items[i], &end, 10);
    if (*end || v < 1 || v > 256) {
      fprintf(stderr, "hairfilter bench: bad batch '%s' (1..256)\n", items[i]);
      return 2;
    }
    o->batches[o->nbatches++] = (int)v;
  }
  return 0;
bad_list:
  fprintf(stderr, "hairfilter bench: %s: empty list, or more than %d items\n", list,
          BENCH_MAX_LIST);
  return 2;
}

/* n rounded up to a multiple of a (a power of two), as the backends pad. */
static int round_up(int n, int a) { return (n + a - 1) & ~(a - 1); }

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* Median (mean of the middle two for an even count) and the 90th percentile
 * by nearest rank (the value at index ceil(0.9 n) - 1 of sorted v);
 * bench_torch.py uses the same rules. */
static double median(double *v, int n) {
  qsort(v, n, sizeof *v, cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}
static double p90(const double *sorted, int n) {
  int k = (9 * n + 9) / 10 - 1; /* ceil(0.9 n) - 1 in integers */
  return sorted[k < 0 ? 0 : k];
}

static bench_row *new_row(void) {
  if (nrows == BENCH_ROWS_MAX) return NULL;
  memset(&rows[nrows], 0, sizeof rows[nrows]);
  return &rows[nrows++];
}

/* Feature-like input: colour, highlight, depth in [0, 1], alpha in (0, 1],
 * tangents in [-1, 1]. Values matter for timing only through denormals and
 * NaNs, which this avoids, and through out-of-contract samples (an alpha of
 * 0 under other features), which hf_model_run would sanitise on a copy. */
static void fill_input(float *in, size_t n, uint64_t seed) {
  uint64_t s = seed * 0x9E3779B97F4A7C15ull + 1;
  for (size_t i = 0; i < n; i++) {
    s ^= s << 13, s ^= s >> 7, s ^= s << 17;
    int f = (int)(i % HF_FEATURES_PER_SAMPLE);
    float u = (float)((s >> 40) + (f == 2)) / (float)(1u << 24);
    in[i] = f >= 4 ? 2 * u - 1 : u;
  }
}

static double clock_ms(clockid_t id) {
  struct timespec t;
  clock_gettime(id, &t);
  return t.tv_sec * 1e3 + t.tv_nsec / 1e6;
}

/* A pass over a whole input frame that runs before the network: the input
 * statistics (hairfilterd, for variants with a trained range) and the
 * out-of-contract check, each on one thread as defined; and both in the
 * one threaded pass that hf_model_run makes (hf_features_scan). */
typedef struct frame_pass {
  const char *title;   /* table column: "input statistics" */
  const char *short_name;
  void (*run)(const void *in, hf_dtype dtype, int w, int h, int spp);
  int threaded;        /* CPU time of every thread of the process, not this one's */
} frame_pass;

static void run_input_stats(const void *in, hf_dtype dtype, int w, int h, int spp) {
  hf_input_stats st;
  hf_input_stats_compute(in, dtype, w, h, spp, &st);
}

static void run_input_check(const void *in, hf_dtype dtype, int w, int h, int spp) {
  hf_input_report r;
  hf_features_check(in, dtype, w, h, spp, &r);
}

static void run_input_scan(const void *in, hf_dtype dtype, int w, int h, int spp) {
  hf_input_report r;
  hf_input_stats st;
  hf_features_scan(in, dtype, w, h, spp, &r, &st);
}

static const frame_pass PASS_STATS = {"input statistics", "statistics", run_input_stats, 0};
static const frame_pass PASS_CHECK = {"out-of-contract check", "check", run_input_check, 0};
static const frame_pass PASS_SCAN = {"check and statistics in hf_model_run's threaded pass",
                                     "pass", run_input_scan, 1};

/* pass on a 4-spp frame of each size, f32 and f16, with every sample
 * covered or not at random (the worst case for a branch on coverage),
 * against memcpy of the same bytes: median and p90 of iters, in wall time
 * and in this thread's CPU time (which other jobs on the machine do not
 * inflate). */
static int bench_frame_pass(const bench_opts *o, const frame_pass *pass) {
  printf("\n| size | input | %s ms, wall median / p90 | %s CPU median | "
         "memcpy of the frame ms, wall / CPU median | %s / memcpy (CPU) | iters |\n"
         "|---|---|---:|---:|---:|---:|---:|\n", pass->title,
         pass->threaded ? "all threads'" : "thread", pass->short_name);
  const clockid_t cpu = pass->threaded ? CLOCK_PROCESS_CPUTIME_ID : CLOCK_THREAD_CPUTIME_ID;
  const int spp = 4, ch = spp * HF_FEATURES_PER_SAMPLE;
  for (int s = 0; s < o->nsizes; s++) {
    int w = o->sizes[s][0], h = o->sizes[s][1];
    size_t n = (size_t)w * h * ch;
    float *in = malloc(n * sizeof(float)), *copy = malloc(n * sizeof(float));
    uint16_t *in16 = malloc(n * sizeof(uint16_t));
    double *t = malloc(4 * (size_t)o->iters * sizeof(double));
    if (!in || !copy || !in16 || !t) {
      free(in), free(copy), free(in16), free(t);
      return HF_ENOMEM;
    }
    fill_input(in, n, o->seed);
    uint64_t r = o->seed;
    for (size_t p = 0; p < n; p += HF_FEATURES_PER_SAMPLE) {
      r ^= r << 13, r ^= r >> 7, r ^= r << 17;
      if (r & 1) memset(in + p, 0, HF_FEATURES_PER_SAMPLE * sizeof(float));
    }
    hf_f32_to_f16_array(in, in16, n);
    memcpy(copy, in, n * sizeof(float));   /* its pages are mapped before timing */
    for (int d = 0; d < 2; d++) {
      const void *src = d ? (const void *)in16 : in;
      size_t bytes = n * (d ? 2 : 4);
      double *sw = t, *sc = t + o->iters, *cw = t + 2 * o->iters, *cc = t + 3 * o->iters;
      volatile double sink = 0;
      for (int i = -o->warmup; i < o->iters; i++) {
        double w0 = clock_ms(CLOCK_MONOTONIC), c0 = clock_ms(cpu);
        pass->run(src, d ? HF_F16 : HF_F32, w, h, spp);
        double w1 = clock_ms(CLOCK_MONOTONIC), c1 = clock_ms(cpu);
        double m0 = clock_ms(CLOCK_THREAD_CPUTIME_ID);   /* memcpy: this thread alone */
        memcpy(copy, src, bytes);
        double w2 = clock_ms(CLOCK_MONOTONIC), m1 = clock_ms(CLOCK_THREAD_CPUTIME_ID);
        sink += ((const float *)copy)[i & 1023];
        if (i >= 0) sw[i] = w1 - w0, sc[i] = c1 - c0, cw[i] = w2 - w1, cc[i] = m1 - m0;
      }
      (void)sink;
      double mw = median(sw, o->iters), pw = p90(sw, o->iters), mc = median(sc, o->iters);
      double kw = median(cw, o->iters), kc = median(cc, o->iters);
      printf("| %dx%d | %d spp %s, %.0f MiB | %.2f / %.2f | %.2f | %.2f / %.2f | %.2f | %d |\n",
             w, h, spp, d ? "f16" : "f32", bytes / 1048576.0, mw, pw, mc, kw, kc,
             kc > 0 ? mc / kc : 0, o->iters);
    }
    free(in), free(copy), free(in16), free(t);
  }
  return 0;
}

static double now_ms(void) { return clock_ms(CLOCK_MONOTONIC); }

/* hf_exr_write (whose read-back comparison is part of it) beside
 * hf_exr_read of the same file: a 4-spp feature frame of each size, float
 * and half storage; wall and thread-CPU medians of iters. */
static int bench_exr(const bench_opts *o) {
  printf("\n| size | storage | MiB raw | write (with read-back) ms, wall / CPU median | "
         "read ms, wall / CPU median | read / write (CPU) | iters |\n"
         "|---|---|---:|---:|---:|---:|---:|\n");
  char path[64];
  snprintf(path, sizeof path, "/tmp/hairfilter-bench-%d.exr", (int)getpid());
  const int spp = 4, ch = spp * HF_FEATURES_PER_SAMPLE;
  int rc = 0;
  for (int s = 0; s < o->nsizes && !rc; s++) {
    int w = o->sizes[s][0], h = o->sizes[s][1];
    float *in = malloc((size_t)w * h * ch * sizeof(float));
    double *t = malloc(4 * (size_t)o->iters * sizeof(double));
    hf_image img = {0};
    if (!in || !t) {
      free(in), free(t);
      return HF_ENOMEM;
    }
    fill_input(in, (size_t)w * h * ch, o->seed);
    if ((rc = hf_features_to_image(in, w, h, spp, &img)) != 0) break;
    for (int half = 0; half < 2 && !rc; half++) {
      double *ww = t, *wc = t + o->iters, *rw = t + 2 * o->iters, *rcpu = t + 3 * o->iters;
      for (int i = -o->warmup; i < o->iters && !rc; i++) {
        hf_image back;
        char err[512];
        double w0 = clock_ms(CLOCK_MONOTONIC), c0 = clock_ms(CLOCK_THREAD_CPUTIME_ID);
        if ((rc = hf_exr_write(path, &img, half)) != 0) {
          fprintf(stderr, "hairfilter bench: writing %s: %s\n", path, hf_strerror(rc));
          break;
        }
        double w1 = clock_ms(CLOCK_MONOTONIC), c1 = clock_ms(CLOCK_THREAD_CPUTIME_ID);
        if ((rc = hf_exr_read(path, &back, err, sizeof err)) != 0) {
          fprintf(stderr, "hairfilter bench: %s\n", err);
          break;
        }
        double w2 = clock_ms(CLOCK_MONOTONIC), c2 = clock_ms(CLOCK_THREAD_CPUTIME_ID);
        hf_image_free(&back);
        if (i >= 0) ww[i] = w1 - w0, wc[i] = c1 - c0, rw[i] = w2 - w1, rcpu[i] = c2 - c1;
      }
      if (rc) break;
      double a = median(ww, o->iters), b = median(wc, o->iters);
      double c = median(rw, o->iters), d = median(rcpu, o->iters);
      printf("| %dx%d | %s | %.0f | %.1f / %.1f | %.1f / %.1f | %.2f | %d |\n", w, h,
             half ? "half" : "float", (double)w * h * ch * (half ? 2 : 4) / 1048576.0, a, b,
             c, d, b > 0 ? d / b : 0, o->iters);
    }
    hf_image_free(&img);
    free(in), free(t);
  }
  unlink(path);
  return rc;
}

/* Times model m on one size and batch, appending a row labelled label (the
 * variant column). */
static int bench_one(hf_model *m, hf_backend *be, const char *label, int w, int h, int batch,
                     int iters, int warmup, uint64_t seed, hf_dtype dt, int pipeline,
                     int pinned) {
  const char *backend = hf_backend_name(be);
  const hf_net_config *c = hf_model_config(m);
  const size_t px = (size_t)batch * w * h, es = dt == HF_F16 ? 2 : 4;
  const size_t nin = px * c->in_channels;
  /* Two sets of buffers: with --pipeline one batch is in flight while the
   * next is submitted. One page-aligned arena, registered with the
   * backend when pinned. */
  const size_t in_bytes = (nin * es + 4095) / 4096 * 4096;
  const size_t out_bytes = (px * 3 * es + 4095) / 4096 * 4096;
  const size_t arena_bytes = 2 * (in_bytes + out_bytes);
  uint8_t *arena = aligned_alloc(4096, arena_bytes);
  int registered = 0;
  void *in[2] = {arena, arena ? arena + in_bytes : NULL};
  void *out[2] = {arena ? arena + 2 * in_bytes : NULL,
                  arena ? arena + 2 * in_bytes + out_bytes : NULL};
  float *tmp = malloc(nin * sizeof(float));
  double *wall = malloc(iters * sizeof(double)), *net = malloc(iters * sizeof(double));
  double *tin = malloc(iters * sizeof(double)), *tout = malloc(iters * sizeof(double));
  double *cpu = malloc(iters * sizeof(double));
  int rc = HF_ENOMEM, pending = 0;
  if (!arena || !tmp || !wall || !net || !tin || !tout || !cpu) goto out;
  if (pinned) {
    if ((rc = hf_backend_host_register(be, arena, arena_bytes)) != HF_OK) goto fail;
    registered = 1;
  }
  fill_input(tmp, nin, seed);
  for (int b = 0; b < 2; b++) {
    if (dt == HF_F16) hf_f32_to_f16_array(tmp, in[b], nin);
    else memcpy(in[b], tmp, nin * sizeof(float));
  }
  hf_io io[2] = {{batch, w, h, in[0], dt, out[0], dt}, {batch, w, h, in[1], dt, out[1], dt}};
  hf_timing t;
  double last = now_ms();
  if (pipeline && (rc = hf_model_submit(m, &io[0])) != 0) goto fail;
  pending = pipeline;
  double last_cpu = clock_ms(CLOCK_PROCESS_CPUTIME_ID);
  for (int k = 0; k < warmup + iters; k++) {
    const double t0 = now_ms(), c0 = clock_ms(CLOCK_PROCESS_CPUTIME_ID);
    if (pipeline) {
      /* Submit the next batch before waiting for this one. */
      if (k + 1 < warmup + iters) {
        if ((rc = hf_model_submit(m, &io[(k + 1) % 2])) != 0) goto fail;
        pending++;
      }
      pending--;
      if ((rc = hf_model_wait(m, &t)) != 0) goto fail;
    } else if ((rc = hf_model_run(m, &io[0], &t)) != 0) {
      goto fail;
    }
    const double t1 = now_ms(), c1 = clock_ms(CLOCK_PROCESS_CPUTIME_ID);
    if (k >= warmup) {
      wall[k - warmup] = pipeline ? t1 - last : t1 - t0;
      cpu[k - warmup] = pipeline ? c1 - last_cpu : c1 - c0;
      net[k - warmup] = t.infer_us * 1e-3;
      tin[k - warmup] = t.input_us * 1e-3;
      tout[k - warmup] = t.output_us * 1e-3;
    }
    last = t1, last_cpu = c1;
  }
  bench_row *r = new_row();
  if (!r) {
    rc = HF_ERANGE;
    goto out;
  }
  snprintf(r->backend, sizeof r->backend, "%s%s%s%s", backend, dt == HF_F16 ? "-f16io" : "",
           pipeline ? "-pipe" : "", pinned ? "-pinned" : "");
  snprintf(r->variant, sizeof r->variant, "%s", label);
  r->cfg = *c, r->has_cfg = 1;
  snprintf(r->precision, sizeof r->precision, "%s", hf_model_precision(m));
  r->w = w, r->h = h, r->batch = batch, r->iters = iters;
  r->med_ms = median(wall, iters) / batch;
  r->p90_ms = p90(wall, iters) / batch;
  r->net_ms = median(net, iters) / batch;
  r->in_ms = median(tin, iters) / batch;
  r->out_ms = median(tout, iters) / batch;
  r->cpu_ms = median(cpu, iters) / batch;
  r->dev_bytes = (double)hf_model_device_bytes(m);
  fprintf(stderr, "  %-8s %-10s %5dx%-5d batch %-3d %9.2f ms/frame\n", backend, label, w, h,
          batch, r->med_ms);
  rc = HF_OK;
  goto out;
fail:
  fprintf(stderr, "hairfilter bench: %s %s %dx%d batch %d: %s\n", backend, label, w, h, batch,
          hf_strerror(rc));
out:
  while (pending-- > 0) hf_model_wait(m, NULL);
  if (registered) hf_backend_host_unregister(be, arena);
  free(arena);
  free(tmp);
  free(wall);
  free(net);
  free(tin);
  free(tout);
  free(cpu);
  return rc;
}

static const char *base_name(const char *path) {
  const char *slash = strrchr(path, '/');
  return slash ? slash + 1 : path;
}

/* The variant column of --weights file i (a name, the variant name in
 * it): NAME:FILE with FILE its base name, and #K after it for the K-th
 * file of that base name (old and new weights of one name side by side),
 * cut to fit len, with blanks, bars, commas and quotes made underscores
 * (the column is one word in bench_torch.py's rows, an item of its
 * --labels list and a Markdown table cell). */
static void weights_label(const bench_opts *o, int i, const char *name, char *out,
                          size_t len) {
  const char *base = base_name(o->weights[i]);
  int same = 1;
  for (int j = 0; j < i; j++) same += !strcmp(base_name(o->weights[j]), base);
  char suffix[16] = "";
  if (same > 1) snprintf(suffix, sizeof suffix, "#%d", same);
  /* Room for the suffix: the name and file are cut before it. */
  size_t room = len - strlen(suffix);
  if (snprintf(out, room, "%s:%s", name, base) >= (int)room) out[room - 1] = 0;
  strcat(out, suffix);
  for (char *p = out; *p; p++)
    if (*p == ' ' || *p == '\t' || *p == '|' || *p == ',' || *p == '\'') *p = '_';
}

/* Whether a path can go inside single quotes on a shell command line. */
static int shell_safe(const char *s) { return s && *s && !strchr(s, '\''); }

/* Writes the random weights of every variant to dir/<variant>.safetensors
 * and lists their paths, then --weights' files, in paths. */
static int write_weights(const bench_opts *o, const char *dir, char *paths, size_t len) {
  size_t used = 0;
  paths[0] = 0;
  for (int v = 0; v < o->nvariants; v++) {
    hf_net_config cfg;
    hf_weights *w;
    char path[512];
    int rc = hf_variant_preset(o->variants[v], &cfg);
    if (!rc) rc = hf_weights_init_random(&cfg, o->seed + v, &w);
    if (rc) return rc;
    /* '@' is fine in file names; the name only has to be unique. */
    snprintf(path, sizeof path, "%s/%s.safetensors", dir, cfg.name);
    rc = hf_weights_save(path, w);
    hf_weights_free(w);
    if (rc) return rc;
    int k = snprintf(paths + used, len - used, " '%s'", path);
    if (k < 0 || (size_t)k >= len - used) return HF_ERANGE;
    used += k;
  }
  /* --weights files as they are, after the presets' random ones. */
  for (int i = 0; i < o->nweights; i++) {
    if (!shell_safe(o->weights[i])) {
      fprintf(stderr, "hairfilter bench: --torch: %s: a path with a ' cannot go to PyTorch\n",
              o->weights[i]);
      return HF_EINVAL;
    }
    int k = snprintf(paths + used, len - used, " '%s'", o->weights[i]);
    if (k < 0 || (size_t)k >= len - used) return HF_ERANGE;
    used += k;
  }
  return 0;
}

/* bench_torch.py's --labels: the variant column of each weights file in
 * write_weights' order (presets by name, then the --weights files). */
static int torch_labels(const bench_opts *o, char *out, size_t len) {
  size_t used = 0;
  out[0] = 0;
  for (int i = 0; i < o->nvariants + o->nweights; i++) {
    if (i >= o->nvariants && !o->loaded[i - o->nvariants]) return HF_EINVAL; /* said once */
    const char *label = i < o->nvariants ? o->variants[i] : o->labels[i - o->nvariants];
    int k = snprintf(out + used, len - used, "%s%s", i ? "," : "", label);
    if (k < 0 || (size_t)k >= len - used) return HF_ERANGE;
    used += k;
  }
  return 0;
}

/* The Python that runs bench_torch.py: --python, $HAIRFILTER_PYTHON, else
 * the first candidate that imports torch (a GPU machine's PyTorch often
 * lives in another Python than Debian's /usr/bin/python3). */
static const char *find_python(const bench_opts *o, char *why, size_t whylen) {
  const char *env = getenv("HAIRFILTER_PYTHON");
  if (o->python) {
    snprintf(why, whylen, "--python");
    return o->python;
  }
  if (env && *env) {
    snprintf(why, whylen, "$HAIRFILTER_PYTHON");
    return env;
  }
  static const char *const candidates[] = {"python3", "/usr/bin/python3"};
  for (size_t i = 0; i < sizeof candidates / sizeof candidates[0]; i++) {
    char cmd[512];
    snprintf(cmd, sizeof cmd, "'%s' -c 'import torch' >/dev/null 2>&1", candidates[i]);
    int st = system(cmd);
    if (st != -1 && WIFEXITED(st) && WEXITSTATUS(st) == 0) {
      snprintf(why, whylen, "the first of python3 on PATH, /usr/bin/python3 that imports torch");
      return candidates[i];
    }
  }
  snprintf(why, whylen, "none of python3 on PATH, /usr/bin/python3 imports torch; give --python");
  return NULL;
}

/* Runs bench_torch.py and appends its ROW lines. */
static int run_torch(const bench_opts *o) {
  char dir[] = "/tmp/hairfilter-bench-XXXXXX", paths[8192], cmd[16384], list[1024];
  char labels[BENCH_MAX_LIST * 2 * HF_NAME_MAX];
  char script[4096], how[160];
  const char *python = find_python(o, how, sizeof how);
  if (!python) {
    fprintf(stderr, "hairfilter bench: --torch: %s\n", how);
    return HF_ENOTFOUND;
  }
  snprintf(script, sizeof script, "%s/bench/bench_torch.py", cli_data_dir());
  if (access(script, R_OK) != 0) {
    fprintf(stderr,
            "hairfilter bench: --torch: cannot read %s (%s); set HAIRFILTER_DATA to the "
            "directory holding bench/ and weights/\n",
            script, strerror(errno));
    return HF_ENOTFOUND;
  }
  if (!shell_safe(python) || !shell_safe(script)) {
    fprintf(stderr, "hairfilter bench: --torch: paths with a ' are not supported\n");
    return HF_EINVAL;
  }
  fprintf(stderr, "hairfilter bench: PyTorch: %s through %s (%s)\n", script, python, how);
  if (!mkdtemp(dir)) {
    fprintf(stderr, "hairfilter bench: mkdtemp: %s\n", strerror(errno));
    return HF_EIO;
  }
  int rc = write_weights(o, dir, paths, sizeof paths);
  if (!rc) rc = torch_labels(o, labels, sizeof labels);
  if (rc) {
    fprintf(stderr, "hairfilter bench: weights for PyTorch: %s\n", hf_strerror(rc));
    goto out;
  }
  size_t used = 0;
  for (int i = 0; i < o->nsizes; i++)
    used += snprintf(list + used, sizeof list - used, "%s%dx%d", i ? "," : "", o->sizes[i][0],
                     o->sizes[i][1]);
  char batches[256];
  used = 0;
  for (int i = 0; i < o->nbatches; i++)
    used += snprintf(batches + used, sizeof batches - used, "%s%d", i ? "," : "",
                     o->batches[i]);
  int k = snprintf(cmd, sizeof cmd,
                   "'%s' '%s' --sizes %s --batch %s --iters %d --warmup %d --device %s "
                   "--labels '%s'%s",
                   python, script, list, batches, o->iters, o->warmup, o->torch_device, labels,
                   paths);
  if (k < 0 || (size_t)k >= sizeof cmd) {
    rc = HF_ERANGE;
    goto out;
  }
  fprintf(stderr, "hairfilter bench: %s\n", cmd);
  FILE *p = popen(cmd, "r");
  if (!p) {
    fprintf(stderr, "hairfilter bench: cannot run %s: %s\n", python, strerror(errno));
    rc = HF_EIO;
    goto out;
  }
  char line[512];
  while (fgets(line, sizeof line, p)) {
    bench_row r = {0};
    double dev;
    if (!strncmp(line, "INFO\t", 5)) {
      fprintf(stderr, "  %s", line + 5);
      continue;
    }
    r.cpu_ms = -1; /* a last field: an older bench_torch.py has none */
    if (sscanf(line, "ROW\t%23s\t%63s\t%dx%d\t%d\t%7s\t%lf\t%lf\t%*f\t%lf\t%d\t%lf", r.backend,
               r.variant, &r.w, &r.h, &r.batch, r.precision, &r.med_ms, &r.p90_ms, &dev,
               &r.iters, &r.cpu_ms) < 10)
      continue;
    r.in_ms = r.net_ms = r.out_ms = -1;
    r.dev_bytes = dev;
    bench_row *slot = new_row();
    if (!slot) break;
    *slot = r;
    fprintf(stderr, "  %-8s %-10s %5dx%-5d batch %-3d %9.2f ms/frame\n", r.backend, r.variant,
            r.w, r.h, r.batch, r.med_ms);
  }
  int st = pclose(p);
  if (st == -1 || !WIFEXITED(st) || WEXITSTATUS(st) != 0) {
    fprintf(stderr, "hairfilter bench: bench_torch.py failed (%s %d)%s%s\n",
            st != -1 && WIFEXITED(st) ? "exit status" : "wait status",
            st != -1 && WIFEXITED(st) ? WEXITSTATUS(st) : st,
            st != -1 && WIFEXITED(st) && WEXITSTATUS(st) == 127 ? ": could not run " : "",
            st != -1 && WIFEXITED(st) && WEXITSTATUS(st) == 127 ? python : "");
    rc = HF_EBACKEND;
  }
out:
  /* Remove the temporary weights. */
  for (int v = 0; v < o->nvariants; v++) {
    char path[512];
    hf_net_config cfg;
    if (hf_variant_preset(o->variants[v], &cfg)) continue;
    snprintf(path, sizeof path, "%s/%s.safetensors", dir, cfg.name);
    unlink(path);
  }
  rmdir(dir);
  return rc;
}

/* The machine: the CPU and its fp32 peak, measured before and after the
 * runs (the larger one-thread rate is the peak: other work on the machine
 * only ever slows a run down). */
typedef struct bench_machine {
  bench_cpu cpu;
  bench_peak before, after;
  int measured;                 /* peaks: 0 none, 1 before, 2 both */
  int threads;                  /* the peak's */
  double peak_gflops;
} bench_machine;

static void measure_peak(bench_machine *mc, bench_peak *p) {
  if (bench_peak_measure(bench_cpu_threads(), p)) {
    fprintf(stderr, "hairfilter bench: measuring the fp32 peak: %s\n", strerror(errno));
    return;
  }
  mc->measured++;
  if (p->peak_gflops > mc->peak_gflops) mc->peak_gflops = p->peak_gflops, mc->threads = p->threads;
}

static void print_machine(const bench_machine *mc) {
  const bench_cpu *c = &mc->cpu;
  printf("CPU: %s (family %d, model %d), %d online CPUs; vector flags: %s\n", c->model, c->family,
         c->model_id, c->online, c->flags[0] ? c->flags : "none of those looked for");
  if (!mc->measured) {
    printf("fp32 peak: not measured\n\n");
    return;
  }
  const bench_peak *b = &mc->before, *a = mc->measured > 1 ? &mc->after : &mc->before;
  const bench_peak *best = a->peak_gflops > b->peak_gflops ? a : b;
  printf("fp32 peak: %.1f GFLOP/s = %.1f GFLOP/s of one core x %d threads. Method: %s %s loop, "
         "%d lanes x %d independent accumulators, on one thread alone, per second of its CPU "
         "time, best of %d runs of %.1f ms, before the runs (%.1f) and after (%.1f); all %d "
         "threads at once, per second of wall time, gave %.1f before and %.1f after (what the "
         "machine's other load left)\n\n",
         mc->peak_gflops, best->core_gflops, best->threads, best->isa,
         best->fma ? "fused multiply-add" : "multiply and add", best->lanes, BENCH_PEAK_CHAINS,
         best->runs, best->run_ms, b->core_gflops, a->core_gflops, best->threads,
         b->all_gflops, a->all_gflops);
}

/* Whether a row ran on this machine's CPU (its GFLOP/s compare with the
 * CPU's peak). */
static int cpu_row(const bench_row *r) {
  return strncmp(r->backend, "cudnn", 5) && !strstr(r->backend, "cuda");
}

/* The network of row r: the one it timed, else (a PyTorch row) that of a
 * row with the same label that has one, else the preset of that name. */
static int row_config(const bench_row *r, hf_net_config *cfg) {
  if (r->has_cfg) {
    *cfg = r->cfg;
    return 0;
  }
  for (int i = 0; i < nrows; i++)
    if (rows[i].has_cfg && !strcmp(rows[i].variant, r->variant)) {
      *cfg = rows[i].cfg;
      return 0;
    }
  return hf_variant_preset(r->variant, cfg);
}

static void print_table(const bench_machine *mc) {
  print_machine(mc);
  printf("| backend | variant | size | batch | precision | median ms/frame | p90 ms/frame "
         "| in / net / out ms | frames/s | device MiB | iters | GFLOP/s | %% of fp32 peak "
         "| CPU ms/frame | %% of one core's peak per CPU second |\n");
  printf("|---|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (int i = 0; i < nrows; i++) {
    bench_row *r = &rows[i];
    char parts[64] = "-", rate[32] = "-", share[32] = "-", cpu[32] = "-", per_cpu[32] = "-";
    if (r->net_ms >= 0)
      snprintf(parts, sizeof parts, "%.2f / %.2f / %.2f", r->in_ms, r->net_ms, r->out_ms);
    hf_net_config cfg;
    if (r->med_ms > 0 && row_config(r, &cfg) == 0) {
      int a = hf_net_align(&cfg);
      double g = 2 * hf_net_macs(&cfg, round_up(r->w, a), round_up(r->h, a)) /
                 (r->med_ms * 1e-3) / 1e9;
      snprintf(rate, sizeof rate, "%.1f", g);
      if (cpu_row(r) && mc->peak_gflops > 0)
        snprintf(share, sizeof share, "%.1f", 100 * g / mc->peak_gflops);
      if (cpu_row(r) && r->cpu_ms > 0) {
        snprintf(cpu, sizeof cpu, "%.2f", r->cpu_ms);
        if (mc->peak_gflops > 0)
          snprintf(per_cpu, sizeof per_cpu, "%.1f",
                   100 * g * r->med_ms / r->cpu_ms / (mc->peak_gflops / mc->threads));
      }
    }
    printf("| %s | %s | %dx%d | %d | %s | %.2f | %.2f | %s | %.1f | %.1f | %d | %s | %s | %s | %s |\n",
           r->backend, r->variant, r->w, r->h, r->batch, r->precision, r->med_ms, r->p90_ms,
           parts, r->med_ms > 0 ? 1e3 / r->med_ms : 0, r->dev_bytes / (1024.0 * 1024.0),
           r->iters, rate, share, cpu, per_cpu);
  }
  /* The comparison the cpu backend is judged by. */
  int first = 1;
  for (int i = 0; i < nrows; i++) {
    if (strcmp(rows[i].backend, "cpu")) continue;
    for (int j = 0; j < nrows; j++) {
      bench_row *t = &rows[j];
      if (strncmp(t->backend, "torch-cpu", 9) || strcmp(t->variant, rows[i].variant) ||
          t->w != rows[i].w || t->h != rows[i].h || t->batch != rows[i].batch)
        continue;
      printf("%s%s %dx%d batch %d: cpu is %.2fx as fast as %s", first ? "\n" : "",
             rows[i].variant, t->w, t->h, t->batch, t->med_ms / rows[i].med_ms, t->backend);
      if (t->cpu_ms > 0 && rows[i].cpu_ms > 0) {
        /* Said the way round that reads: a ratio under 1 is more time
         * ("0.10x less" meant ten times more). */
        const double less = t->cpu_ms / rows[i].cpu_ms;
        if (less >= 1)
          printf(" and takes %.2fx less CPU time per frame", less);
        else
          printf(" and takes %.2fx more CPU time per frame", 1 / less);
      }
      printf("\n");
      first = 0;
    }
  }
}

/* Times weights w on backend be at every size and batch of o, rows labelled
 * label; nonzero if any failed. */
static int bench_weights(const bench_opts *o, hf_backend *be, int is_ref, const hf_weights *w,
                         const char *label) {
  hf_model *m = NULL;
  int rc = hf_model_create(be, w, &m), failed = 0;
  if (rc) {
    fprintf(stderr, "hairfilter bench: %s %s: %s\n", hf_backend_name(be), label, hf_strerror(rc));
    return 1;
  }
  for (int s = 0; s < o->nsizes; s++) {
    if (is_ref && (o->sizes[s][0] > o->ref_max_side || o->sizes[s][1] > o->ref_max_side))
      continue;
    for (int n = 0; n < o->nbatches; n++)
      if (bench_one(m, be, label, o->sizes[s][0], o->sizes[s][1], o->batches[n],
                    is_ref && o->iters > BENCH_REF_ITERS ? BENCH_REF_ITERS : o->iters,
                    is_ref && o->warmup > 1 ? 1 : o->warmup, o->seed, o->io_dtype, o->pipeline,
                    o->pinned))
        failed = 1;
  }
  hf_model_destroy(m);
  return failed;
}

int cmd_bench(int argc, char **argv) {
  bench_opts o;
  memset(&o, 0, sizeof o);
  int rc = parse_opts(argc, argv, &o);
  if (rc) return rc == 1 ? 0 : 2;
  int failed = 0;
  /* The --weights files, loaded once for every backend and PyTorch. */
  for (int i = 0; i < o.nweights; i++) {
    char err[512];
    if ((rc = hf_weights_load(o.weights[i], &o.loaded[i], err, sizeof err)) != 0) {
      fprintf(stderr, "hairfilter bench: --weights: %s\n", err[0] ? err : hf_strerror(rc));
      o.loaded[i] = NULL;
      failed = 1;
      continue;
    }
    weights_label(&o, i, o.loaded[i]->cfg.name, o.labels[i], sizeof o.labels[i]);
  }
  /* What is about to run, before the minutes it may take (every backend at
   * three sizes by default, cpu-ref among them). */
  fprintf(stderr,
          "hairfilter bench: %d backend(s) x %d network(s) x %d size(s) x %d batch(es), %d timed "
          "runs each after %d warm-up%s; --backend, --variants, --weights, --sizes and --iters "
          "narrow it\n",
          o.nbackends, o.nvariants + o.nweights, o.nsizes, o.nbatches, o.iters, o.warmup,
          o.torch ? ", then PyTorch on the same" : "");
  bench_machine mc;
  memset(&mc, 0, sizeof mc);
  bench_cpu_describe(&mc.cpu);
  measure_peak(&mc, &mc.before);
  for (int b = 0; b < o.nbackends; b++) {
    hf_backend *be;
    char why[512];
    rc = hf_backend_create(o.backends[b], &be, why, sizeof why);
    if (rc) {
      fprintf(stderr, "hairfilter bench: skipping %s: %s (%s)\n", o.backends[b],
              why[0] ? why : "", hf_strerror(rc));
      /* An explicitly named backend that cannot run is an error; "all"
       * just lists what is compiled in. */
      if (!o.backends_all) failed = 1;
      continue;
    }
    int is_ref = !strcmp(hf_backend_name(be), "cpu-ref");
    for (int v = 0; v < o.nvariants; v++) {
      hf_net_config cfg;
      hf_weights *w = NULL;
      if ((rc = hf_variant_preset(o.variants[v], &cfg)) != 0 ||
          (rc = hf_weights_init_random(&cfg, o.seed + v, &w)) != 0) {
        fprintf(stderr, "hairfilter bench: %s %s: %s\n", o.backends[b], o.variants[v],
                hf_strerror(rc));
        failed = 1;
        continue;
      }
      if (bench_weights(&o, be, is_ref, w, cfg.name)) failed = 1;
      hf_weights_free(w);
    }
    for (int i = 0; i < o.nweights; i++)
      if (o.loaded[i] && bench_weights(&o, be, is_ref, o.loaded[i], o.labels[i])) failed = 1;
    hf_backend_destroy(be);
  }
  if (o.torch && run_torch(&o)) failed = 1;
  if (mc.measured) measure_peak(&mc, &mc.after);
  print_table(&mc);
  if (o.input_stats && bench_frame_pass(&o, &PASS_STATS)) failed = 1;
  if (o.input_check && bench_frame_pass(&o, &PASS_CHECK)) failed = 1;
  if (o.input_check && bench_frame_pass(&o, &PASS_SCAN)) failed = 1;
  if (o.exr && bench_exr(&o)) failed = 1;
  for (int i = 0; i < o.nweights; i++) hf_weights_free(o.loaded[i]);
  return failed ? 1 : 0;
}
