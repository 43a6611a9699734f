/*
 * hairfilter-load: drives hairfilterd with N connections, each keeping K
 * requests in flight, for S seconds, and reports throughput and latency
 * percentiles (client-observed, plus the server's own breakdown).
 *
 * One thread per connection, since an hfc_client is single-threaded; each
 * thread submits until K are pending, then waits for one and resubmits. A
 * request refused BUSY (or SHUTTING_DOWN) is counted apart and its slot
 * rests BUSY_BACKOFF_S before it sends again, as in `hairfilter load`; a
 * refusal no retry can fix (TOO_LARGE, UNKNOWN_VARIANT, ...) stops the run,
 * naming it. SIGINT or SIGTERM ends the window early and reports it.
 * Features are random but fixed and in contract (protocol/FEATURES.md), so
 * the server does the same work as for a real frame of that size.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>

#include <hairfilter/hairfilter.h>

#include "cli_args.h"
#include "load_variant.h"
#include "run_header.h"

typedef struct opts {
  const char *server, *variant, *token;
  const char *tls_ca, *tls_cert, *tls_key, *tls_server_name;   /* tls: URLs */
  int width, height, connections, inflight, f16, shm;
  double seconds, warmup;
  uint32_t deadline_us;          /* --deadline: each frame's budget at the server; 0: none */
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
  /* Requests sent after the warm-up, and their answers; busy and errors
   * are of those. The warm-up's apart, by outcome. */
  uint64_t sent, answered, busy, errors, expired;
  /* Of those answered, the ok ones in the window or after it (frames in
   * flight when it closed); busy, expired and errors count them all. */
  uint64_t answered_ok;
  uint64_t warm_sent, warm_ok, warm_busy, warm_errors, warm_expired;
  int last_error;                /* the last error answered, for its name */
  int lost_status;               /* why frames went unanswered: the connection's failure */
  int fatal;
  int gated;                     /* passed the common start (gate_pass) */
  int setup_failed;              /* never sent: no connection, segment or memory */
  int over_limits;               /* its segment is over the server's shared-memory limits */
  int cut;                       /* stopped (fatal) before its window's end */
  int refused;                   /* stopped by a refusal no retry can fix, its link intact */
  int batch_sum, batch_n;
} worker;

/* A refused request's slot rests this long before it sends again, so that
 * a refusing server is not spun against (as BUSY_BACKOFF_S in cmd_load.c). */
#define BUSY_BACKOFF_S 0.01
/* Seconds without an answer, frames pending, after which the server is
 * taken for stalled: the connections' hfc_options timeout. */
#define STALL_S 30.0

/* Connections that could not connect, and those lost after: the first of
 * each says why. */
static atomic_int connect_failures, connections_lost;

/* Set by SIGINT or SIGTERM: the window ends there. */
static volatile sig_atomic_t interrupted;

static void on_signal(int sig) { interrupted = sig; }

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

/* The connections' common start: each sets up (connects, maps its
 * segment, fills its frame), then waits here until every one has, and the
 * last sets the warm-up's and window's start for all. Windows opened one
 * by one as each connection got ready would be staggered, and frames
 * counted over their union divided by --seconds overstate the rate (with
 * many connections and a short window, by a third and more). */
static struct {
  pthread_mutex_t mu;
  pthread_cond_t cv;
  int arrived, n;
  double t_start;
} gate = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, 0, 0, 0};

/* Marks w set up (or failed) and returns when every connection is; sets
 * w's window. Called once per connection, whatever its outcome. */
static void gate_pass(worker *w) {
  if (w->gated) return;
  w->gated = 1;
  pthread_mutex_lock(&gate.mu);
  if (++gate.arrived == gate.n) {
    gate.t_start = now_s();
    pthread_cond_broadcast(&gate.cv);
  }
  while (gate.arrived < gate.n) pthread_cond_wait(&gate.cv, &gate.mu);
  double t = gate.t_start;
  pthread_mutex_unlock(&gate.mu);
  w->t_measure = t + w->o->warmup;
  w->t_end = w->t_measure + w->o->seconds;
}

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter-load --server URL --variant NAME [--size WxH] [--connections N]\n"
          "                       [--inflight K] [--seconds S] [--warmup S] [--f16]\n"
          "                       [--token TOKEN] [--shm] [--deadline DUR]\n"
          "                       [--tls-ca FILE] [--tls-server-name NAME]\n"
          "                       [--tls-cert FILE --tls-key FILE]\n"
          "--shm puts every frame in memory shared with the server (Unix sockets).\n"
          "--deadline gives every frame that budget at the server (a plain number is ms;\n"
          "protocol version 4): a frame still queued then is not computed and counts as\n"
          "expired, apart from the errors.\n"
          "Defaults: --size 640x480 --connections 1 --inflight 1 --seconds 10 --warmup 1.\n"
          "--seconds and --warmup count seconds, or take a unit: 500ms, 2s, 1m.\n"
          "The token defaults to $HAIRFILTER_TOKEN. --tls-ca names the CA that signed a\n"
          "tls: server's certificate (default: the system's), --tls-server-name the name\n"
          "it must carry (default: the URL's host); --tls-cert and --tls-key, together, a\n"
          "client certificate for mutual TLS.\n"
          "A request refused BUSY is sent again after 10 ms; a refusal no retry can fix\n"
          "stops the run, naming it. SIGINT or SIGTERM ends the window and reports it.\n"
          "Exit status: 0 frames measured; 1 none, a connection lost, or the server could\n"
          "not be reached or refused; 2 bad options, over the server's limits (a frame\n"
          "over its size, a --shm segment over its shared-memory limits), or --shm where\n"
          "the server offers no shared memory; 130 interrupted.\n");
}

/* BUSY and SHUTTING_DOWN are refusals for now, counted as busy apart from
 * the errors. */
static int refused_for_now(int status) {
  return status == HFC_E_BUSY || status == HFC_E_SHUTTING_DOWN;
}

static int record(worker *w, const hfc_completion *d, int warm) {
  /* Failed here, not answered (the connection lost, no answer in time):
   * counted as unanswered, with the reason, not as the server's error. */
  if (d->status <= HFC_E_ARG) {
    w->lost_status = d->status;
    return 0;
  }
  if (warm) {
    if (refused_for_now(d->status)) {
      w->warm_busy++;
    } else if (d->status == HFC_E_EXPIRED) {
      w->warm_expired++;
    } else if (d->status) {
      w->warm_errors++;
      w->last_error = d->status;
    } else {
      w->warm_ok++;
    }
    return 0;
  }
  if (refused_for_now(d->status)) {
    w->busy++;
    return 0;
  }
  /* The frame's --deadline passed in the server's queue: what the option
   * counts, not an error. */
  if (d->status == HFC_E_EXPIRED) {
    w->expired++;
    return 0;
  }
  if (d->status) {
    w->errors++;
    w->last_error = d->status;
    return 0;
  }
  w->answered_ok++;
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
  co.timeout_ms = (int)(STALL_S * 1000);
  int rc = hfc_connect(o->server, &co, &c);
  if (rc) {
    const char *m = hfc_last_message(NULL);
    /* Said once for all connections that fail alike (300 connections to
     * a server of --max-connections 256 printed 44 lines); the count is
     * in the report. */
    if (atomic_fetch_add(&connect_failures, 1) == 0)
      fprintf(stderr, "hairfilter-load: %s\n", m[0] ? m : hfc_strerror(rc));
    w->fatal = w->setup_failed = 1;
    gate_pass(w);
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
      const char *m = hfc_last_message(c);
      fprintf(stderr, "hairfilter-load: --shm: %s\n", m[0] ? m : hfc_strerror(rc));
      w->fatal = w->setup_failed = 1;
      /* A segment over the server's shared-memory limits (not over what is
       * left of them): exit status 2, as for a frame over its size limit. */
      w->over_limits = rc == HFC_E_TOO_LARGE;
      gate_pass(w);
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
  gate_pass(w);
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
  r.deadline_us = w->o->deadline_us;
  r.result_bytes = px * 3 * es;
  struct {
    int busy, warm;
    double not_before;           /* after a BUSY: not sent again before */
  } *slots = calloc((size_t)k, sizeof *slots);
  if (!slots) {
    fprintf(stderr, "hairfilter-load: out of memory\n");
    w->fatal = 1;
    goto done;
  }
  int pending = 0, refused = 0;
  /* hfc_wait is asked for 100 ms at most, to see the end and signals, so
   * it never times a stalled server out itself: nothing back for the
   * client's timeout with frames pending fails the connection here. */
  double last_answer = now_s();
  for (;;) {
    double now = now_s();
    if (pending && now - last_answer > STALL_S) {
      fprintf(stderr, "hairfilter-load: no answer from the server for %.0f s with %d frame(s) "
              "pending; stopping\n", STALL_S, pending);
      w->fatal = 1;
      break;
    }
    if (!pending) last_answer = now;
    if (interrupted && now < w->t_end) w->t_end = now < w->t_measure ? w->t_measure : now;
    int stopping = now >= w->t_end || refused;
    if (stopping && !pending) break;
    double first = now + 0.1;
    for (int s = 0; s < k && !stopping; s++) {
      if (slots[s].busy) continue;
      if (slots[s].not_before > now) {
        if (slots[s].not_before < first) first = slots[s].not_before;
        continue;
      }
      r.result = out + px * 3 * es * (size_t)s;
      r.user = (void *)(intptr_t)s;
      if ((rc = hfc_submit(c, &r, NULL)) != 0) break;
      slots[s].busy = 1;
      slots[s].warm = now < w->t_measure;
      if (slots[s].warm) w->warm_sent++;
      else w->sent++;
      pending++;
    }
    if (rc) break;
    /* Wait for a completion, the first resting slot, or (to notice the end
     * or a signal) 100 ms. */
    int wait_ms = first <= now ? 0 : (int)((first - now) * 1e3) + 1;
    if (!pending) {
      struct timespec ts = {0, (long)wait_ms * 1000000L};
      nanosleep(&ts, NULL);
      continue;
    }
    hfc_completion d;
    rc = hfc_wait(c, wait_ms, &d);
    if (rc == HFC_E_TIMEOUT) {
      rc = 0;
      continue;
    }
    if (rc) break;
    pending--;
    last_answer = now_s();
    int s = (int)(intptr_t)d.user;
    slots[s].busy = 0;
    /* An answer is the server's: local failures (the connection lost, a
     * timeout) are not. */
    if (!slots[s].warm && d.status > HFC_E_ARG) w->answered++;
    if (record(w, &d, slots[s].warm)) {
      rc = HFC_E_NOMEM;
      break;
    }
    /* Failed here (the connection lost): the frames still pending on it
     * fail the same way; the connection is done. */
    if (d.status <= HFC_E_ARG) {
      rc = d.status;
      break;
    }
    if (refused_for_now(d.status)) {
      slots[s].not_before = now_s() + BUSY_BACKOFF_S;
    } else if (d.status < 0 && d.status > HFC_E_ARG && d.status != HFC_E_INTERNAL &&
               d.status != HFC_E_EXPIRED && !refused) {
      /* Sent again, it would be refused again. */
      const char *m = hfc_last_message(c);
      fprintf(stderr, "hairfilter-load: the server refused a frame: %s%s%s%s; stopping\n",
              hfc_strerror(d.status), m[0] ? " (" : "", m, m[0] ? ")" : "");
      refused = 1;
      w->refused = 1;
      w->fatal = 1;
    }
  }
  free(slots);
  if (rc) {
    if (pending) w->lost_status = rc;
    /* Said once, as the connect failures are (a killed server loses every
     * connection at once); the report counts what went unanswered. */
    if (atomic_fetch_add(&connections_lost, 1) == 0)
      fprintf(stderr, "hairfilter-load: connection failed: %s\n", hfc_strerror(rc));
    w->fatal = 1;
    w->refused = 0;   /* lost, whatever came before */
  }
  if (w->fatal) {
    /* Its window ends here: the throughput is over the time measured. */
    double now = now_s();
    if (now < w->t_end) {
      w->t_end = now < w->t_measure ? w->t_measure : now;
      w->cut = 1;
    }
  }
done:
  if (!w->gated) w->setup_failed = 1;
  gate_pass(w);   /* no-op unless set-up failed */
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

/* The line above the figures: the command, the machine (CPU model and
 * cores), the UTC date and the version (run_header.h). */
static void print_header(int argc, char **argv) {
  run_header h;
  run_header_describe("hairfilter-load", argc - 1, argv + 1, &h);
  printf("command: %s\nmachine: %s, %d cores; %s; hairfilter-load %s\n\n", h.command, h.cpu,
         h.cores, h.date, HAIRFILTER_VERSION_STRING);
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
    static const char *const valued[] = {"--server", "--variant", "--token", "--tls-ca",
                                         "--tls-cert", "--tls-key", "--tls-server-name", "--size",
                                         "--connections", "--inflight", "--seconds", "--warmup",
                                         "--deadline"};
    /* Each at most once: a second value would silently replace the first. */
    static unsigned char given[sizeof valued / sizeof valued[0]];
    int known = 0;
    for (size_t j = 0; j < sizeof valued / sizeof valued[0]; j++)
      if (!strcmp(a, valued[j])) {
        known = 1;
        if (given[j]++) {
          fprintf(stderr, "hairfilter-load: %s given twice: give it once\n", a);
          return 2;
        }
      }
    if (!known || !v) {
      if (!known)
        fprintf(stderr, "hairfilter-load: %s '%s'\n",
                strncmp(a, "-", 1) ? "unexpected argument" : "unknown option", a);
      else
        fprintf(stderr, "hairfilter-load: option '%s' needs a value\n", a);
      usage(stderr);
      return 2;
    }
    i++;
    long n;
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
    } else if (!strcmp(a, "--connections")) {
      if (cli_arg_long("hairfilter-load", a, v, 1, 1024, &n)) return 2;
      o.connections = (int)n;
    } else if (!strcmp(a, "--inflight")) {
      if (cli_arg_long("hairfilter-load", a, v, 1, 1 << 20, &n)) return 2;
      o.inflight = (int)n;
    } else if (!strcmp(a, "--seconds")) {
      if (cli_arg_duration("hairfilter-load", a, v, 1, 1e-3, 7 * 86400, &o.seconds)) return 2;
    } else if (!strcmp(a, "--warmup")) {
      if (cli_arg_duration("hairfilter-load", a, v, 1, 0, 7 * 86400, &o.warmup)) return 2;
    } else if (!strcmp(a, "--deadline")) {
      /* 1 us .. 2^32-1 us, the protocol's budget_us. */
      double s;
      if (cli_arg_duration("hairfilter-load", a, v, 1e-3, 1e-6, 4294.967295, &s)) return 2;
      o.deadline_us = s * 1e6 < 1 ? 1 : (uint32_t)(s * 1e6 + 0.5);
    }
  }
  if (!o.server || !o.variant) {
    fprintf(stderr, "hairfilter-load: give %s (see --help)\n",
            !o.server && !o.variant ? "--server URL and --variant NAME"
            : !o.server             ? "--server URL"
                                    : "--variant NAME");
    return 2;
  }
  if (!o.tls_cert != !o.tls_key) {
    fprintf(stderr, "hairfilter-load: give --tls-cert and --tls-key together (a client "
            "certificate and its private key)\n");
    return 2;
  }
  const cli_tls tls = {o.tls_ca, o.tls_cert, o.tls_key, o.tls_server_name};
  if (cli_tls_for_server("hairfilter-load", o.server, &tls)) return 2;
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
  co.timeout_ms = (int)(STALL_S * 1000);
  int rc = hfc_connect(o.server, &co, &c);
  if (rc) {
    const char *m = hfc_last_message(NULL);
    fprintf(stderr, "hairfilter-load: %s\n", m[0] ? m : hfc_strerror(rc));
    if (rc == HFC_E_UNAUTHORIZED && strstr(m, "wrong token"))
      fprintf(stderr, "hairfilter-load: the token given is not the server's: compare --token "
                      "or $HAIRFILTER_TOKEN with the server's --auth-token-file\n");
    else if (rc == HFC_E_UNAUTHORIZED)
      fprintf(stderr, "hairfilter-load: give the server's token with --token TOKEN or "
                      "$HAIRFILTER_TOKEN\n");
    return 1;
  }
  /* Static: o.variant points at its name until the report is written. */
  static hfc_variant v;
  if (load_find_variant(c, "hairfilter-load", o.variant, &v)) {
    hfc_close(c);
    return 1;
  }
  int spp = v.spp, estimate = v.estimate;
  const char *backend = v.backend, *precision = v.precision;
  hfc_server_info info = *hfc_info(c);
  int max_inflight = info.max_inflight;
  hfc_close(c);
  o.variant = v.name;
  if (o.width > info.max_width || o.height > info.max_height) {
    fprintf(stderr, "hairfilter-load: %dx%d is over the server's limit of %dx%d\n", o.width,
            o.height, info.max_width, info.max_height);
    return 2;
  }
  /* A server that offers no shared memory here (a TCP connection, or
   * hairfilterd --max-shm-mb 0) is said before the run, as the limits
   * above are, rather than after an empty window. */
  if (o.deadline_us && info.version < 4)
    fprintf(stderr, "hairfilter-load: --deadline: %s speaks protocol version %d, which has no "
                    "deadlines (version 4 does): frames go without one and none can expire\n",
            o.server, info.version);
  if (o.shm && !info.shm) {
    fprintf(stderr, "hairfilter-load: --shm: %s offers no shared memory (only Unix sockets do, "
            "unless the server runs with --max-shm-mb 0); leave out --shm\n", o.server);
    return 2;
  }
  if (o.inflight > max_inflight) {
    fprintf(stderr, "hairfilter-load: --inflight %d is over the server's limit of %d\n",
            o.inflight, max_inflight);
    return 2;
  }

  worker *w = calloc((size_t)o.connections, sizeof *w);
  if (!w) return 1;
  /* SIGINT or SIGTERM ends the window; what was measured is reported. A
   * second one kills. */
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_signal;
  sa.sa_flags = SA_RESETHAND;
  sigemptyset(&sa.sa_mask);
  if (sigaction(SIGINT, &sa, NULL) || sigaction(SIGTERM, &sa, NULL))
    fprintf(stderr, "hairfilter-load: warning: cannot catch SIGINT/SIGTERM (%s)\n",
            strerror(errno));
  else
    fprintf(stderr, "hairfilter-load: %d connection(s) starting; SIGINT or SIGTERM ends the "
            "window and reports it\n", o.connections);
  gate.n = o.connections;
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
  uint64_t busy = 0, errors = 0, sent = 0, answered = 0, wsent = 0, wok = 0, wbusy = 0, werr = 0;
  uint64_t expired = 0, wexpired = 0;
  int lost_status = 0, over_limits = 0;
  uint64_t answered_ok = 0;
  int fatal = 0, bsum = 0, bn = 0, last_error = 0, cut = 0, cut_lost = 0;
  /* Every connection's window opened at the same moment (gate_pass); the
   * run measured for as long as any of them still did: one cut short (lost,
   * refused for good) or an interruption ends its own window early. */
  double elapsed = 0;
  int running = 0;
  for (int i = 0; i < o.connections; i++) {
    pthread_join(w[i].thread, NULL);
    total += w[i].n;
    busy += w[i].busy;
    errors += w[i].errors;
    sent += w[i].sent;
    answered += w[i].answered;
    wsent += w[i].warm_sent;
    wok += w[i].warm_ok;
    wbusy += w[i].warm_busy;
    werr += w[i].warm_errors;
    expired += w[i].expired;
    wexpired += w[i].warm_expired;
    if (w[i].lost_status) lost_status = w[i].lost_status;
    answered_ok += w[i].answered_ok;
    over_limits |= w[i].over_limits;
    if (w[i].last_error) last_error = w[i].last_error;
    if (!w[i].setup_failed) {
      running++;
      double span = w[i].t_end - w[i].t_measure;
      if (span > o.seconds) span = o.seconds;
      if (span > elapsed) elapsed = span;
    }
    cut |= w[i].cut;
    cut_lost |= w[i].cut && !w[i].refused;
    fatal |= w[i].fatal;
    bsum += w[i].batch_sum;
    bn += w[i].batch_n;
  }
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
  print_header(argc, argv);
  int lost_connections = atomic_load(&connections_lost);
  if (lost_connections > 1)
    fprintf(stderr, "hairfilter-load: %d of the %d connections failed (the first said why "
            "above)\n", lost_connections, o.connections);
  int failed_connects = atomic_load(&connect_failures);
  if (failed_connects > 1)
    fprintf(stderr, "hairfilter-load: %d of the %d connections could not connect (the first "
            "said why above)\n", failed_connects, o.connections);
  if (!running) {
    /* Not one connection got to send (each said why above): no window,
     * nothing to report but that. */
    printf("%s %dx%d %s via %s%s: none of the %d connection(s) was set up; nothing measured\n",
           o.variant, o.width, o.height, o.f16 ? "f16" : "f32", o.server,
           o.shm ? " + shared memory" : "", o.connections);
    for (int j = 0; j < COLS; j++) free(col[j]);
    free(w);
    return over_limits ? 2 : 1;
  }
  printf("%s %dx%d %s via %s%s (%s, %s): %d connection(s) x %d in flight, %.2f s measured%s\n",
         o.variant, o.width, o.height, o.f16 ? "f16" : "f32", o.server,
         o.shm ? " + shared memory" : "", backend, precision, o.connections, o.inflight, elapsed,
         interrupted ? " (interrupted)"
         : !cut      ? ""
         : cut_lost  ? " (cut short: connections lost)"
                     : " (cut short: a frame refused for good)");
  printf("  frames %zu  throughput %.1f frames/s  busy %llu  errors %llu%s%s%s  mean batch %.2f\n",
         total, elapsed > 0 ? (double)total / elapsed : 0.0, (unsigned long long)busy,
         (unsigned long long)errors, last_error ? " (last: " : "",
         last_error ? hfc_strerror(last_error) : "", last_error ? ")" : "",
         bn ? (double)bsum / bn : 0.0);
  if (o.deadline_us)
    printf("  deadline %.3f ms  expired %llu (not computed: still queued at the server when "
           "their budget passed)  warm-up expired %llu\n", o.deadline_us / 1e3,
           (unsigned long long)expired, (unsigned long long)wexpired);
  /* Every request sent after the warm-up is answered (frames + busy +
   * expired + errors) or unanswered: in flight at the window's end, or
   * lost with its connection (the reason said). */
  printf("  requests sent %llu  answered %llu  unanswered %llu%s%s%s\n", (unsigned long long)sent,
         (unsigned long long)answered, (unsigned long long)(sent > answered ? sent - answered : 0),
         lost_status ? " (a connection lost: " : "", lost_status ? hfc_strerror(lost_status) : "",
         lost_status ? ")" : "");
  /* The answered by outcome add up to answered; frames above are the ok
   * ones inside the window, those after it (in flight when it closed) are
   * here too. */
  char exp_txt[48] = "";
  if (o.deadline_us || expired)
    snprintf(exp_txt, sizeof exp_txt, "  expired %llu", (unsigned long long)expired);
  printf("  answered by outcome: ok %llu  busy %llu%s  errors %llu  (ok: the frames above and "
         "those answered after the window)\n", (unsigned long long)answered_ok,
         (unsigned long long)busy, exp_txt, (unsigned long long)errors);
  printf("  warm-up: requests sent %llu  ok %llu  busy %llu  errors %llu\n",
         (unsigned long long)wsent, (unsigned long long)wok, (unsigned long long)wbusy,
         (unsigned long long)werr);
  printf("  %-8s %10s %10s %10s %10s %10s   (ms)\n", "", "p50", "p90", "p99", "p99.9", "max");
  for (int j = 0; j < COLS; j++) {
    printf("  %-8s %10.3f %10.3f %10.3f %10.3f %10.3f\n", names[j], pct(col[j], total, 50) / 1e3,
           pct(col[j], total, 90) / 1e3, pct(col[j], total, 99) / 1e3,
           pct(col[j], total, 99.9) / 1e3, total ? col[j][total - 1] / 1e3 : 0.0);
    free(col[j]);
  }
  free(w);
  if (interrupted) {
    fprintf(stderr, "hairfilter-load: interrupted by %s\n", interrupted == SIGTERM ? "SIGTERM" : "SIGINT");
    return 130;
  }
  return fatal || total == 0 ? 1 : 0;
}
