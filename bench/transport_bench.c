/*
 * Transport of frames through hairfilterd against the socket floor, and
 * float16 against float32 end to end, side by side in one run
 * (docs/PERFORMANCE.md, "Transport, receive buffers and float16").
 *
 *   hf-transport-bench UNIX_URL TCP_URL VARIANT SIZE[,SIZE...] ITERS
 *
 * For each size, over the Unix socket, loopback TCP and shared memory (on
 * the Unix socket), ITERS frames of each of four callers one at a time,
 * in turn, after one warm-up frame of each: a caller holding float32
 * features that sends float32 ("f32"); one holding float32 that sends
 * float16 and gets float16 ("f16, caller f32"); one holding float32 that
 * sends float16 and asks for a float32 result ("f16 in, f32 out, caller
 * f32"); one whose features are float16 already, a renderer's half-float
 * targets or a half EXR, that sends and keeps float16 ("f16, caller f16"):
 *   end to end  what the caller waits for: for "f16, caller f32" the
 *               conversion to float16, hfc_filter and the result widened
 *               back to float32; for "f16 in, f32 out" the conversion and
 *               hfc_filter; for the others hfc_filter alone;
 *   transport   the client's total less the server's (from the frame's
 *               last byte in to its result out): the bytes on the wire
 *               and the client library's own work;
 *   server      the server's total, and its input, network and output
 *               stages.
 * First the conversions alone, the features of each size both ways: the
 * scalar reference, the vector code on one thread, the array functions.
 * Between the Unix socket's frames, the socket floor of the same bytes: a
 * FILTER's worth of float32 features written into one end of a Unix socket
 * pair and read at the other into memory used before (of the kind the
 * daemon receives into), and the result's bytes back the same way into
 * memory used before (no protocol, no daemon): what any socket transport of
 * the frame costs on this machine.
 * Its far end is a thread of this process, or a process of its own (as
 * hairfilterd is); one request and reply through each after every pair of
 * frames, and the float32 frames' transport over each floor frame by
 * frame.
 *
 * Medians over the ITERS frames, and their f16 / f32 ratios. Prints the
 * tables with the command, the CPU model (lscpu's "Model name", from
 * /proc/cpuinfo) and the date.
 */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <hairfilter/hairfilter.h>

#include "bench_util.h"
#include "hfcore.h"

/* ---- the socket floor --------------------------------------------------- */

/* A socket pair with a peer at the far end that reads a request of
 * in_bytes into its own buffer, touched before the first, and writes
 * out_bytes of it back: the same bytes, directions and socket buffer sizes
 * (the kernel's defaults, which neither libhairfilter nor hairfilterd
 * change) as a frame through the daemon, with no protocol, event loop or
 * daemon. The peer is a thread of this process, or a process of its own:
 * a client and hairfilterd are two processes, and a switch between two
 * processes costs more than one between two threads of one (another
 * address space; on this machine's hypervisor, much more). */
typedef struct floor_run {
  int fd[2];
  size_t in_bytes, out_bytes;
  int process;
  pthread_t th;
  pid_t pid;
  uint8_t *src, *back; /* this end's request and reply buffers */
} floor_run;

static int read_all(int fd, uint8_t *p, size_t n) {
  while (n) {
    ssize_t r = read(fd, p, n);
    if (r <= 0) return -1;
    p += r, n -= (size_t)r;
  }
  return 0;
}

static int write_all(int fd, const uint8_t *p, size_t n) {
  while (n) {
    ssize_t r = write(fd, p, n);
    if (r <= 0) return -1;
    p += r, n -= (size_t)r;
  }
  return 0;
}

/* The far end until the pair closes: mmap, madvise, memset, read and write
 * only, so that it is safe in a child forked from this threaded process.
 * Its buffer is memory of the kind hairfilterd receives into
 * (server/recv_pool.c): 2 MiB aligned, huge pages asked for before it is
 * touched. */
static void floor_serve(int fd, size_t in_bytes, size_t out_bytes) {
  const size_t step = (size_t)2 << 20;
  size_t cap = ((in_bytes > out_bytes ? in_bytes : out_bytes) + step - 1) & ~(step - 1);
  uint8_t *raw = mmap(NULL, cap + step, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (raw == MAP_FAILED) return;
  uint8_t *buf = (uint8_t *)(((uintptr_t)raw + step - 1) & ~(uintptr_t)(step - 1));
#ifdef MADV_HUGEPAGE
  (void)madvise(buf, cap, MADV_HUGEPAGE);
#endif
  memset(buf, 2, cap);
  while (!read_all(fd, buf, in_bytes) && !write_all(fd, buf, out_bytes)) {
  }
  munmap(raw, cap + step);
}

static void *floor_thread(void *arg) {
  floor_run *f = arg;
  floor_serve(f->fd[1], f->in_bytes, f->out_bytes);
  return NULL;
}

/* Starts the far end; 0, or -1 with nothing left open. */
static int floor_open(floor_run *f, size_t in_bytes, size_t out_bytes, int process) {
  memset(f, 0, sizeof *f);
  f->in_bytes = in_bytes, f->out_bytes = out_bytes, f->process = process;
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, f->fd)) return -1;
  f->src = malloc(in_bytes), f->back = malloc(out_bytes);
  if (!f->src || !f->back) goto fail;
  memset(f->src, 1, in_bytes);
  memset(f->back, 3, out_bytes);
  if (process) {
    fflush(stdout);
    f->pid = fork();
    if (f->pid < 0) goto fail;
    if (f->pid == 0) {
      close(f->fd[0]);
      floor_serve(f->fd[1], in_bytes, out_bytes);
      _exit(0);
    }
    close(f->fd[1]);
    f->fd[1] = -1;
  } else if (pthread_create(&f->th, NULL, floor_thread, f)) {
    goto fail;
  }
  return 0;
fail:
  close(f->fd[0]), close(f->fd[1]);
  free(f->src), free(f->back);
  return -1;
}

/* Microseconds of one request and its reply; -1 on error. */
static double floor_once(floor_run *f) {
  double t0 = bench_now_us();
  if (write_all(f->fd[0], f->src, f->in_bytes) || read_all(f->fd[0], f->back, f->out_bytes))
    return -1;
  return bench_now_us() - t0;
}

static void floor_close(floor_run *f) {
  shutdown(f->fd[0], SHUT_RDWR);
  if (f->process)
    waitpid(f->pid, NULL, 0);
  else
    pthread_join(f->th, NULL);
  close(f->fd[0]);
  if (f->fd[1] >= 0) close(f->fd[1]);
  free(f->src), free(f->back);
}

/* ---- through the daemon ------------------------------------------------- */

typedef struct result {
  double e2e, conv, transport, server, input, infer, output;
} result;

/* The callers of a run, in the order they take turns. */
enum { CALLER_F32, CALLER_F32_SENDS_F16, CALLER_F32_SENDS_F16_GETS_F32, CALLER_F16, NCALLERS };
static const char *const CALLER_NAME[NCALLERS] = {"f32", "f16, caller f32",
                                                  "f16 in, f32 out, caller f32", "f16, caller f16"};
/* What each caller sends and asks back; all but CALLER_F16 hold float32,
 * so they convert what they send or get as float16. */
static const hfc_dtype CALLER_IN[NCALLERS] = {HFC_F32, HFC_F16, HFC_F16, HFC_F16};
static const hfc_dtype CALLER_OUT[NCALLERS] = {HFC_F32, HFC_F16, HFC_F32, HFC_F16};

#define NFLOORS 2 /* the socket floor with its far end a thread, a process */

/* The floors measured between a path's frames, and the float32 frames'
 * transport over each, frame by frame. */
typedef struct floors {
  floor_run run[NFLOORS];
  double us[NFLOORS], ratio[NFLOORS]; /* medians */
} floors;

/* ITERS frames of w x h through c for each caller, in turn (so all meet
 * the same machine: the cores here are shared); shm: the tensors in
 * segments. res[caller]. fl: when not NULL, after each round of frames one
 * request and reply through each socket floor, so that the floors meet the
 * machine as the frames do. */
static int run_frames(hfc_client *c, const char *variant, int spp, int w, int h, int shm,
                      int iters, const float *feat32, result res[NCALLERS], floors *fl) {
  size_t nin = (size_t)w * h * spp * 6, nout = (size_t)w * h * 3;
  void *seg[NCALLERS] = {NULL}, *in[NCALLERS] = {NULL}, *out[NCALLERS] = {NULL};
  size_t in_b[NCALLERS], out_b[NCALLERS];
  float *res32 = malloc(nout * sizeof(float));
  double *t[NCALLERS][7], *ft[NFLOORS], *fr[NFLOORS];
  int rc = -1;
  for (int d = 0; d < NCALLERS; d++)
    for (int k = 0; k < 7; k++) t[d][k] = calloc((size_t)iters, sizeof(double));
  for (int k = 0; k < NFLOORS; k++)
    ft[k] = calloc((size_t)iters, sizeof(double)), fr[k] = calloc((size_t)iters, sizeof(double));
  for (int d = 0; d < NCALLERS; d++)
    for (int k = 0; k < 7; k++)
      if (!t[d][k]) goto out;
  for (int k = 0; k < NFLOORS; k++)
    if (!ft[k] || !fr[k]) goto out;
  if (!res32) goto out;
  for (int d = 0; d < NCALLERS; d++) {
    in_b[d] = nin * (CALLER_IN[d] == HFC_F16 ? 2 : 4);
    out_b[d] = nout * (CALLER_OUT[d] == HFC_F16 ? 2 : 4);
    if (shm) {
      if ((rc = hfc_shm_alloc(c, in_b[d] + out_b[d], &seg[d])) != 0) {
        fprintf(stderr, "hfc_shm_alloc: %s (%s)\n", hfc_strerror(rc), hfc_last_message(c));
        goto out;
      }
      in[d] = seg[d], out[d] = (uint8_t *)seg[d] + in_b[d];
    } else {
      in[d] = malloc(in_b[d]), out[d] = malloc(out_b[d]);
      if (!in[d] || !out[d]) goto out;
    }
  }
  /* Features are where the caller has them (in the segment, for shared
   * memory: an engine renders into it), float32 or float16; the caller
   * holding float32 that sends float16 converts them each time, inside
   * the timing. */
  memcpy(in[CALLER_F32], feat32, in_b[CALLER_F32]);
  hf_f32_to_f16_array(feat32, in[CALLER_F16], nin);
  for (int i = 0; i <= iters; i++) { /* the first of each is the warm-up */
    for (int d = 0; d < NCALLERS; d++) {
      const int convert = d != CALLER_F16 && CALLER_IN[d] == HFC_F16;
      const int widen = d != CALLER_F16 && CALLER_OUT[d] == HFC_F16;
      hfc_request r;
      hfc_request_init(&r);
      r.variant = variant, r.width = w, r.height = h, r.spp = spp;
      r.in_dtype = CALLER_IN[d], r.out_dtype = CALLER_OUT[d];
      r.features = in[d], r.features_bytes = in_b[d];
      r.result = out[d], r.result_bytes = out_b[d];
      hfc_timing tm;
      double t0 = bench_now_us();
      if (convert) hf_f32_to_f16_array(feat32, in[d], nin);
      double t1 = bench_now_us();
      if ((rc = hfc_filter(c, &r, &tm)) != 0) {
        fprintf(stderr, "hfc_filter %dx%d: %s (%s)\n", w, h, hfc_strerror(rc),
                hfc_last_message(c));
        goto out;
      }
      double t2 = bench_now_us();
      if (widen) hf_f16_to_f32_array(out[d], res32, nout);
      double t3 = bench_now_us();
      if (!i) continue;
      t[d][0][i - 1] = t3 - t0;
      t[d][1][i - 1] = (t1 - t0) + (t3 - t2);
      t[d][2][i - 1] = tm.total_us - tm.server_us;
      t[d][3][i - 1] = tm.server_us;
      t[d][4][i - 1] = tm.input_us;
      t[d][5][i - 1] = tm.infer_us;
      t[d][6][i - 1] = tm.output_us;
    }
    for (int k = 0; fl && k < NFLOORS; k++) {
      double f = floor_once(&fl->run[k]);
      if (f < 0) {
        fprintf(stderr, "socket floor %dx%d: the pair failed\n", w, h);
        rc = -1;
        goto out;
      }
      if (!i) continue;
      ft[k][i - 1] = f;
      fr[k][i - 1] = t[CALLER_F32][2][i - 1] / f;
    }
  }
  for (int d = 0; d < NCALLERS; d++) {
    result *q = &res[d];
    q->e2e = bench_median(t[d][0], iters), q->conv = bench_median(t[d][1], iters);
    q->transport = bench_median(t[d][2], iters), q->server = bench_median(t[d][3], iters);
    q->input = bench_median(t[d][4], iters), q->infer = bench_median(t[d][5], iters);
    q->output = bench_median(t[d][6], iters);
  }
  for (int k = 0; fl && k < NFLOORS; k++)
    fl->us[k] = bench_median(ft[k], iters), fl->ratio[k] = bench_median(fr[k], iters);
  rc = 0;
out:
  for (int d = 0; d < NCALLERS; d++) {
    if (seg[d]) hfc_shm_free(c, seg[d]);
    else free(in[d]), free(out[d]);
    for (int k = 0; k < 7; k++) free(t[d][k]);
  }
  for (int k = 0; k < NFLOORS; k++) free(ft[k]), free(fr[k]);
  free(res32);
  return rc;
}

/* ---- the conversions alone --------------------------------------------- */

/* Median ms of converting n values each way with the scalar reference
 * loop, the vector code on one thread, and the array functions (vector,
 * split between threads). */
static void conversion_table(const float *f32, size_t n, const char *what, int iters) {
  uint16_t *h = malloc(n * sizeof *h);
  float *back = malloc(n * sizeof *back), *t = calloc((size_t)iters, sizeof *t);
  double *d = calloc((size_t)iters, sizeof *d);
  if (!h || !back || !t || !d) goto out;
  hf_f32_to_f16_array(f32, h, n);
  hf_f16_to_f32_array(h, back, n); /* every page touched before timing */
  static const char *impl[3] = {"scalar reference, 1 thread", "vector, 1 thread",
                                "vector, threads (hf_*_array)"};
  for (int m = 0; m < 3; m++) {
    int had = hf_half_use_simd(m > 0);
    double med[2];
    for (int dir = 0; dir < 2; dir++) {
      for (int i = 0; i < iters; i++) {
        double t0 = bench_now_us();
        if (m == 2 && dir == 0) hf_f32_to_f16_array(f32, h, n);
        else if (m == 2) hf_f16_to_f32_array(h, back, n);
        else if (dir == 0) hf_f32_to_f16_serial(f32, h, n);
        else hf_f16_to_f32_serial(h, back, n);
        d[i] = bench_now_us() - t0;
      }
      med[dir] = bench_median(d, iters);
    }
    hf_half_use_simd(had);
    printf("| %s | %s | %.2f | %.2f |\n", what, impl[m], med[0] / 1e3, med[1] / 1e3);
  }
out:
  free(h), free(back), free(t), free(d);
}

int main(int argc, char **argv) {
  if (argc != 6) {
    fprintf(stderr, "usage: %s UNIX_URL TCP_URL VARIANT SIZE[,SIZE...] ITERS\n", argv[0]);
    return 2;
  }
  const char *urls[2] = {argv[1], argv[2]}, *variant = argv[3];
  int iters = atoi(argv[5]);
  if (iters < 1) {
    fprintf(stderr, "ITERS must be at least 1\n");
    return 2;
  }
  char conv[96];
  snprintf(conv, sizeof conv, "half conversion: %s", hf_half_impl());
  bench_print_header(argc, argv, conv);
  hfc_client *c[2] = {NULL, NULL};
  hfc_options o;
  hfc_options_init(&o);
  o.timeout_ms = 120000;
  for (int k = 0; k < 2; k++) {
    int rc = hfc_connect(urls[k], &o, &c[k]);
    if (rc) {
      fprintf(stderr, "connect %s: %s (%s)\n", urls[k], hfc_strerror(rc), hfc_last_message(c[k]));
      return 1;
    }
  }
  hfc_variant vs[64];
  int nv = 0, spp = 0;
  if (hfc_list_variants(c[0], vs, 64, &nv)) return 1;
  for (int i = 0; i < nv && i < 64; i++)
    if (!strcmp(vs[i].name, variant)) spp = vs[i].spp;
  if (!spp) {
    fprintf(stderr, "the daemon has no variant %s\n", variant);
    return 1;
  }
  printf("| frame | conversion | f32 -> f16 ms | f16 -> f32 ms |\n|---|---|---:|---:|\n");
  {
    char *list = strdup(argv[4]), *sv = NULL;
    for (char *s = strtok_r(list, ",", &sv); s; s = strtok_r(NULL, ",", &sv)) {
      int w, h;
      if (sscanf(s, "%dx%d", &w, &h) != 2 || w < 1 || h < 1) continue;
      size_t n = (size_t)w * h * spp * 6;
      float *f = malloc(n * sizeof *f);
      if (!f) return 1;
      for (size_t i = 0; i < n; i++) f[i] = (float)(i % 4093) / 4093.0f;
      char what[96];
      snprintf(what, sizeof what, "%dx%d features (%zu values)", w, h, n);
      conversion_table(f, n, what, iters);
      free(f);
    }
    free(list);
  }
  printf("\n");
  printf("| size | path | dtype | end to end ms | client conversion ms | transport ms | "
         "server ms | server input / infer / output ms |\n"
         "|---|---|---|---:|---:|---:|---:|---:|\n");
  char *sizes = strdup(argv[4]), *save = NULL;
  for (char *s = strtok_r(sizes, ",", &save); s; s = strtok_r(NULL, ",", &save)) {
    int w, h;
    if (sscanf(s, "%dx%d", &w, &h) != 2 || w < 1 || h < 1) {
      fprintf(stderr, "bad size %s\n", s);
      return 2;
    }
    size_t nin = (size_t)w * h * spp * 6;
    float *feat = malloc(nin * sizeof *feat);
    if (!feat) return 1;
    uint32_t r = 7;
    for (size_t i = 0; i < nin; i++) {
      r ^= r << 13, r ^= r >> 17, r ^= r << 5;
      feat[i] = (float)(r >> 8) / 16777216.0f; /* in [0, 1): inside every feature's range */
    }
    static const char *path[3] = {"unix", "tcp", "shm"};
    floors fl;
    for (int k = 0; k < NFLOORS; k++)
      if (floor_open(&fl.run[k], nin * 4 + 64, (size_t)w * h * 3 * 4, k)) {
        fprintf(stderr, "socket floor %dx%d: cannot start its far end\n", w, h);
        return 1;
      }
    for (int p = 0; p < 3; p++) {
      result res[NCALLERS];
      memset(res, 0, sizeof res);
      if (run_frames(c[p == 1], variant, spp, w, h, p == 2, iters, feat, res, p ? NULL : &fl))
        return 1;
      for (int d = 0; d < NCALLERS; d++)
        printf("| %dx%d | %s | %s | %.2f | %.2f | %.2f | %.2f | %.2f / %.2f / %.2f |\n", w, h,
               path[p], CALLER_NAME[d], res[d].e2e / 1e3, res[d].conv / 1e3,
               res[d].transport / 1e3, res[d].server / 1e3, res[d].input / 1e3,
               res[d].infer / 1e3, res[d].output / 1e3);
      for (int d = CALLER_F32_SENDS_F16; d < NCALLERS; d++)
        printf("| %dx%d | %s | %s / f32 | %.2fx | | %.2fx | %.2fx | %.2fx input |\n", w, h,
               path[p], CALLER_NAME[d], res[d].e2e / res[0].e2e,
               res[d].transport / res[0].transport, res[d].server / res[0].server,
               res[d].input / res[0].input);
      fflush(stdout);
    }
    for (int k = 0; k < NFLOORS; k++) floor_close(&fl.run[k]);
    static const char *far[NFLOORS] = {"a thread", "a process"};
    for (int k = 0; k < NFLOORS; k++)
      printf("| %dx%d | socket floor (socket pair, warm buffers, far end %s) | f32 | - | - | "
             "%.2f | - | - |\n", w, h, far[k], fl.us[k] / 1e3);
    for (int k = 0; k < NFLOORS; k++)
      printf("| %dx%d | unix / socket floor (far end %s), frame by frame | f32 | | | %.2fx | | |\n",
             w, h, far[k], fl.ratio[k]);
    free(feat);
  }
  free(sizes);
  hfc_close(c[0]);
  hfc_close(c[1]);
  return 0;
}
