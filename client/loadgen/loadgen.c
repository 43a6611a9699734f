/*
 * hairfilter-load: drives hairfilterd with N connections, each keeping K
 * requests in flight, for S seconds, and reports throughput and latency
 * percentiles (client-observed, plus the server's own breakdown).
 *
 * One thread per connection, since an hfc_client is single-threaded; each
 * thread submits until K are pending, then waits for one and resubmits.
 * Features are random but fixed and in contract (protocol/FEATURES.md), so
 * the server does the same work as for a real frame of that size.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <hairfilter/hairfilter.h>

typedef struct opts {
  const char *server, *variant, *token;
  const char *tls_ca, *tls_cert, *tls_key, *tls_server_name;   /* tls: URLs */
  int width, height, connections, inflight, f16, shm;
  double seconds, warmup;
} opts;

typedef struct sample {
  float total_us, server_us, queue_us, input_us, infer_us, output_us;
} sample;

typedef struct worker {
  pthread_t thread;
  const opts *o;
  int spp;
  int estimate;                 /* the variant reads the alpha-corrected estimate */
  double t_end, t_measure;
  sample *samples;
  size_t n, cap;
  uint64_t busy, errors;
  int fatal;
  int batch_sum, batch_n;
} worker;

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter-load --server URL --variant NAME [--size WxH] [--connections N]\n"
          "                       [--inflight K] [--seconds S] [--warmup S] [--f16]\n"
          "                       [--token TOKEN] [--shm]\n"
          "                       [--tls-ca FILE] [--tls-server-name NAME]\n"
          "                       [--tls-cert FILE --tls-key FILE]\n"
          "--shm puts every frame in memory shared with the server (Unix sockets).\n"
          "Defaults: --size 640x480 --connections 1 --inflight 1 --seconds 10 --warmup 1.\n"
          "The token defaults to $HAIRFILTER_TOKEN. --tls-ca names the CA that signed a\n"
          "tls: server's certificate (default: the system's), --tls-server-name the name\n"
          "it must carry (default: the URL's host); --tls-cert and --tls-key, together, a\n"
          "client certificate for mutual TLS.\n");
}

static int record(worker *w, const hfc_completion *d) {
  if (d->status == HFC_E_BUSY) {
    w->busy++;
    return 0;
  }
  if (d->status) {
    w->errors++;
    return 0;
  }
  /* Only completions inside the measured window count, so the frames still
   * in flight when it closes do not stretch it. */
  double t = now_s();
  if (t < w->t_measure || t > w->t_end) return 0;
  if (w->n == w->cap) {
    size_t cap = w->cap ? w->cap * 2 : 4096;
    sample *s = realloc(w->samples, cap * sizeof *s);
    if (!s) return -1;
    w->samples = s;
    w->cap = cap;
  }
  w->samples[w->n++] = (sample){(float)d->timing.total_us, (float)d->timing.server_us,
                                (float)d->timing.queue_us, (float)d->timing.input_us,
                                (float)d->timing.infer_us, (float)d->timing.output_us};
  w->batch_sum += d->timing.batch;
  w->batch_n++;
  return 0;
}

static void *run(void *arg) {
  worker *w = arg;
  const opts *o = w->o;
  hfc_client *c = NULL;
  hfc_options co;
  hfc_options_init(&co);
  co.client_name = "hairfilter-load";
  co.token = o->token;
  co.tls_ca_file = o->tls_ca;
  co.tls_cert_file = o->tls_cert;
  co.tls_key_file = o->tls_key;
  co.tls_server_name = o->tls_server_name;
  co.timeout_ms = 30000;
  int rc = hfc_connect(o->server, &co, &c);
  if (rc) {
    const char *m = hfc_last_message(NULL);
    fprintf(stderr, "hairfilter-load: %s\n", m[0] ? m : hfc_strerror(rc));
    w->fatal = 1;
    return NULL;
  }
  size_t px = (size_t)o->width * o->height;
  /* The features, and for a variant that reads it the estimate after
   * them (3 values per pixel; the same random values in [0, 1)). */
  size_t nin = px * ((size_t)w->spp * 6 + (w->estimate ? 3 : 0)), es = o->f16 ? 2 : 4;
  int k = o->inflight;
  uint8_t *in, *out, *shm = NULL;
  if (o->shm) {
    /* One segment: the features once, then K result slots. */
    size_t bytes = nin * es + px * 3 * es * (size_t)k;
    rc = hfc_shm_alloc(c, bytes, (void **)&shm);
    if (rc) {
      fprintf(stderr, "hairfilter-load: shared memory: %s\n", hfc_strerror(rc));
      w->fatal = 1;
      hfc_close(c);
      return NULL;
    }
    in = shm;
    out = shm + nin * es;
  } else {
    in = malloc(nin * es);
    out = malloc(px * 3 * es * (size_t)k);
  }
  if (!in || !out) {
    fprintf(stderr, "hairfilter-load: out of memory\n");
    w->fatal = 1;
    goto done;
  }
  /* Every value in [0.125, 1), in both dtypes: each sample covered with
   * every feature in range (protocol/FEATURES.md), as a renderer's frame
   * is, so the server never takes its sanitising path (a copy of the whole
   * frame) and the timings are those of a clean frame. Values from 0 would
   * now and then give an alpha of exactly 0 beside non-zero features: one
   * such sample in a 1024x1024 float32 frame made every request a
   * sanitised one. */
  uint32_t x = 12345;
  for (size_t i = 0; i < nin; i++) {
    x = x * 1664525u + 1013904223u;
    if (o->f16) {
      /* binary16 bit patterns 0x3000..0x3bff: values in [0.125, 1). */
      ((uint16_t *)in)[i] = (uint16_t)(0x3000u + (x >> 8) % 0x0c00u);
    } else {
      ((float *)in)[i] = 0.125f + 0.875f * ((float)(x >> 8) / 16777216.0f);
    }
  }
  /* The warm-up and the window start now that the connection is set up:
   * connecting, mapping a large segment and filling the frame can take
   * longer than a short window on a loaded machine. */
  w->t_measure = now_s() + o->warmup;
  w->t_end = w->t_measure + o->seconds;
  /* Each in-flight slot owns an output buffer; the slot index rides in
   * the request's user pointer. */
  hfc_request r;
  hfc_request_init(&r);
  r.variant = o->variant;
  r.width = o->width;
  r.height = o->height;
  r.spp = w->spp;
  r.in_dtype = r.out_dtype = o->f16 ? HFC_F16 : HFC_F32;
  r.features = in;
  r.features_bytes = nin * es;
  r.estimate = w->estimate;
  r.result_bytes = px * 3 * es;
  int pending = 0;
  for (int s = 0; s < k; s++) {
    r.result = out + px * 3 * es * (size_t)s;
    r.user = (void *)(intptr_t)s;
    if ((rc = hfc_submit(c, &r, NULL)) != 0) break;
    pending++;
  }
  while (pending && !rc) {
    hfc_completion d;
    rc = hfc_wait(c, -1, &d);
    if (rc) break;
    pending--;
    if (record(w, &d)) {
      rc = HFC_E_NOMEM;
      break;
    }
    if (now_s() < w->t_end) {
      r.result = out + px * 3 * es * (size_t)(intptr_t)d.user;
      r.user = d.user;
      if ((rc = hfc_submit(c, &r, NULL)) != 0) break;
      pending++;
    }
  }
  if (rc) {
    fprintf(stderr, "hairfilter-load: connection failed: %s\n", hfc_strerror(rc));
    w->fatal = 1;
  }
done:
  if (shm) {
    hfc_shm_free(c, shm);
  } else {
    free(in);
    free(out);
  }
  hfc_close(c);
  return NULL;
}

static int cmp_float(const void *a, const void *b) {
  float x = *(const float *)a, y = *(const float *)b;
  return x < y ? -1 : x > y;
}

static double pct(const float *v, size_t n, double p) {
  if (!n) return 0;
  size_t i = (size_t)(p / 100.0 * (double)(n - 1) + 0.5);
  return v[i < n ? i : n - 1];
}

int main(int argc, char **argv) {
  opts o = {.token = getenv("HAIRFILTER_TOKEN"), .width = 640, .height = 480, .connections = 1,
            .inflight = 1, .seconds = 10, .warmup = 1};
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      usage(stdout);
      return 0;
    }
    if (!strcmp(a, "--version")) {
      printf("hairfilter-load %s (libhairfilter %s)\n", HAIRFILTER_VERSION_STRING, hfc_version());
      return 0;
    }
    if (!strcmp(a, "--f16")) {
      o.f16 = 1;
      continue;
    }
    if (!strcmp(a, "--shm")) {
      o.shm = 1;
      continue;
    }
    if (!v) {
      usage(stderr);
      return 2;
    }
    i++;
    if (!strcmp(a, "--server")) o.server = v;
    else if (!strcmp(a, "--variant")) o.variant = v;
    else if (!strcmp(a, "--token")) o.token = v;
    else if (!strcmp(a, "--tls-ca")) o.tls_ca = v;
    else if (!strcmp(a, "--tls-cert")) o.tls_cert = v;
    else if (!strcmp(a, "--tls-key")) o.tls_key = v;
    else if (!strcmp(a, "--tls-server-name")) o.tls_server_name = v;
    else if (!strcmp(a, "--size")) {
      char tail;
      if (sscanf(v, "%dx%d%c", &o.width, &o.height, &tail) != 2 || o.width < 1 || o.height < 1) {
        fprintf(stderr, "hairfilter-load: --size wants WxH\n");
        return 2;
      }
    } else if (!strcmp(a, "--connections")) o.connections = atoi(v);
    else if (!strcmp(a, "--inflight")) o.inflight = atoi(v);
    else if (!strcmp(a, "--seconds")) o.seconds = atof(v);
    else if (!strcmp(a, "--warmup")) o.warmup = atof(v);
    else {
      usage(stderr);
      return 2;
    }
  }
  if (!o.server || !o.variant || o.connections < 1 || o.connections > 1024 || o.inflight < 1 ||
      o.seconds <= 0 || o.warmup < 0) {
    usage(stderr);
    return 2;
  }
  if (!o.tls_cert != !o.tls_key) {
    fprintf(stderr, "hairfilter-load: give --tls-cert and --tls-key together (a client "
            "certificate and its private key)\n");
    return 2;
  }
  char why[300];
  if (hfc_check_url(o.server, why, sizeof why)) {
    fprintf(stderr, "hairfilter-load: --server: %s\n", why);
    return 2;
  }
  /* Look the variant up once, for its spp and to fail early. */
  hfc_client *c;
  hfc_options co;
  hfc_options_init(&co);
  co.client_name = "hairfilter-load";
  co.token = o.token;
  co.tls_ca_file = o.tls_ca;
  co.tls_cert_file = o.tls_cert;
  co.tls_key_file = o.tls_key;
  co.tls_server_name = o.tls_server_name;
  co.timeout_ms = 30000;
  int rc = hfc_connect(o.server, &co, &c);
  if (rc) {
    const char *m = hfc_last_message(NULL);
    fprintf(stderr, "hairfilter-load: %s\n", m[0] ? m : hfc_strerror(rc));
    if (rc == HFC_E_UNAUTHORIZED)
      fprintf(stderr, "hairfilter-load: give the server's token with --token TOKEN\n");
    return 1;
  }
  hfc_variant vs[64];
  int nv = 0, spp = 0, estimate = 0;
  const char *backend = "?", *precision = "?";
  char backend_s[65] = "", precision_s[65] = "";
  if ((rc = hfc_list_variants(c, vs, 64, &nv)) != 0) {
    fprintf(stderr, "hairfilter-load: listing variants: %s\n", hfc_strerror(rc));
    hfc_close(c);
    return 1;
  }
  for (int i = 0; i < nv && i < 64; i++)
    if (!strcmp(vs[i].name, o.variant)) {
      spp = vs[i].spp;
      estimate = vs[i].estimate;
      snprintf(backend_s, sizeof backend_s, "%s", vs[i].backend);
      snprintf(precision_s, sizeof precision_s, "%s", vs[i].precision);
      backend = backend_s;
      precision = precision_s;
    }
  int max_inflight = hfc_info(c)->max_inflight;
  hfc_close(c);
  if (!spp) {
    fprintf(stderr, "hairfilter-load: the server has no variant '%s'\n", o.variant);
    return 1;
  }
  if (o.inflight > max_inflight) {
    fprintf(stderr, "hairfilter-load: --inflight %d is over the server's limit of %d\n",
            o.inflight, max_inflight);
    return 2;
  }

  worker *w = calloc((size_t)o.connections, sizeof *w);
  if (!w) return 1;
  for (int i = 0; i < o.connections; i++) {
    w[i].o = &o;
    w[i].spp = spp;
    w[i].estimate = estimate;
    if ((rc = pthread_create(&w[i].thread, NULL, run, &w[i])) != 0) {
      fprintf(stderr, "hairfilter-load: thread: %s\n", strerror(rc));
      return 1;
    }
  }
  size_t total = 0;
  uint64_t busy = 0, errors = 0;
  int fatal = 0, bsum = 0, bn = 0;
  for (int i = 0; i < o.connections; i++) {
    pthread_join(w[i].thread, NULL);
    total += w[i].n;
    busy += w[i].busy;
    errors += w[i].errors;
    fatal |= w[i].fatal;
    bsum += w[i].batch_sum;
    bn += w[i].batch_n;
  }
  double elapsed = o.seconds;
  /* One sorted column per timing field, for the percentiles. */
  enum { COLS = 6 };
  static const char *const names[COLS] = {"total", "server", "queue", "input", "infer", "output"};
  float *col[COLS];
  for (int j = 0; j < COLS; j++)
    if (!(col[j] = malloc((total ? total : 1) * sizeof(float)))) return 1;
  size_t k = 0;
  for (int i = 0; i < o.connections; i++) {
    for (size_t j = 0; j < w[i].n; j++, k++) {
      const sample *sm = &w[i].samples[j];
      col[0][k] = sm->total_us;
      col[1][k] = sm->server_us;
      col[2][k] = sm->queue_us;
      col[3][k] = sm->input_us;
      col[4][k] = sm->infer_us;
      col[5][k] = sm->output_us;
    }
    free(w[i].samples);
  }
  for (int j = 0; j < COLS; j++) qsort(col[j], total, sizeof(float), cmp_float);
  printf("%s %dx%d %s via %s%s (%s, %s): %d connection(s) x %d in flight, %.1f s measured\n",
         o.variant, o.width, o.height, o.f16 ? "f16" : "f32", o.server,
         o.shm ? " + shared memory" : "", backend, precision,
         o.connections, o.inflight, elapsed);
  printf("  frames %zu  throughput %.1f frames/s  busy %llu  errors %llu  mean batch %.2f\n",
         total, elapsed > 0 ? (double)total / elapsed : 0.0, (unsigned long long)busy,
         (unsigned long long)errors, bn ? (double)bsum / bn : 0.0);
  printf("  %-8s %10s %10s %10s %10s %10s   (ms)\n", "", "p50", "p90", "p99", "p99.9", "max");
  for (int j = 0; j < COLS; j++) {
    printf("  %-8s %10.3f %10.3f %10.3f %10.3f %10.3f\n", names[j], pct(col[j], total, 50) / 1e3,
           pct(col[j], total, 90) / 1e3, pct(col[j], total, 99) / 1e3,
           pct(col[j], total, 99.9) / 1e3, total ? col[j][total - 1] / 1e3 : 0.0);
    free(col[j]);
  }
  free(w);
  return fatal || total == 0 ? 1 : 0;
}
