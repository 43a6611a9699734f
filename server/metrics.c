/*
 * What /metrics shows, in the Prometheus text exposition format (version
 * 0.0.4, https://prometheus.io/docs/instrumenting/exposition_formats/).
 *
 * Counters are kept by the loop thread, which owns every request, as plain
 * integers (no locks on the request path); the text is made on the loop
 * thread too, when http.c asks for it, and handed to the HTTP thread as a
 * finished buffer. Debian has no maintained C client library for
 * Prometheus, and the format is a few lines per family, so it is written
 * here; tests/server/test_metrics.py reads it back with Prometheus's own
 * parsers (promtool and the Python client's).
 *
 * Requests are counted by variant and status once answered: a RESULT when
 * it is written (as STATS counts it), a refusal when it is sent. `class`
 * groups the statuses for alerts: ok, overload (BUSY and EXPIRED: retry
 * or add capacity), client_error (the request was wrong: INVALID,
 * TOO_LARGE, UNKNOWN_VARIANT, ...), unavailable (SHUTTING_DOWN),
 * cancelled (CANCELLED: the client's choice), server_error (INTERNAL).
 * Latency histograms have fixed buckets from 0.5 ms to 30 s.
 */
#define _GNU_SOURCE
#include <ctype.h>
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <hairfilter/hairfilter_version.h>

#include "server.h"

const double hfd_time_buckets_s[HFD_TIME_BUCKETS] = {0.0005, 0.001, 0.0025, 0.005, 0.01,
                                                     0.025,  0.05,  0.1,    0.25,  0.5,
                                                     1,      2.5,   5,      10,    30};

static hfd_variant_metrics no_variant;   /* requests refused before a variant was known */

void hfd_metrics_count(hfd_server *s, int slot, int status) {
  if (status < 0) status = -status;
  if (status >= HFP_E_COUNT) status = HFP_E_INTERNAL;
  if (slot >= 0)
    s->variants[slot].m.by_status[status]++;
  else
    s->unrouted[status]++;
}

static void observe_time(hfd_hist *h, uint64_t us) {
  double v = (double)us / 1e6;
  int b = 0;
  while (b < HFD_TIME_BUCKETS && v > hfd_time_buckets_s[b]) b++;
  h->bucket[b]++;
  h->count++;
  h->sum += v;
}

void hfd_metrics_observe(hfd_server *s, const hfd_job *j) {
  hfd_variant_metrics *m = &s->variants[j->variant].m;
  observe_time(&m->time[HFD_T_QUEUE], j->timing.queue_us);
  observe_time(&m->time[HFD_T_INPUT], j->timing.input_us);
  observe_time(&m->time[HFD_T_INFER], j->timing.infer_us);
  observe_time(&m->time[HFD_T_OUTPUT], j->timing.output_us);
  observe_time(&m->time[HFD_T_TOTAL], j->timing.total_us);
}

/* Counted when the run's jobs come back from the worker, not when a reply
 * is written: the run happened (and took the backend's time) whether or
 * not its clients are still there, and whether or not it succeeded. */
void hfd_metrics_batch(hfd_server *s, const hfd_job *j) {
  hfd_variant *v = &s->variants[j->variant];
  hfd_hist *h = &v->m.batch;
  int b = 0;
  while (b < HFD_BATCH_BUCKETS && j->batch > (1u << b)) b++;
  h->bucket[b]++;
  h->count++;
  h->sum += j->batch;
  v->stats.batches++;
}

/* ---- text format ------------------------------------------------------ */

/* A label value with \, " and newline escaped, as the format asks. */
static void label(FILE *f, const char *v) {
  for (; *v; v++) {
    if (*v == '\\' || *v == '"')
      fprintf(f, "\\%c", *v);
    else if (*v == '\n')
      fputs("\\n", f);
    else
      fputc(*v, f);
  }
}

static void family(FILE *f, const char *name, const char *type, const char *help) {
  fprintf(f, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

/* A family of one unlabelled integer sample. */
static void scalar(FILE *f, const char *name, const char *type, const char *help,
                   unsigned long long v) {
  family(f, name, type, help);
  fprintf(f, "%s %llu\n", name, v);
}

static void lower(char *dst, size_t cap, const char *src) {
  size_t i = 0;
  for (; src[i] && i + 1 < cap; i++) dst[i] = (char)tolower((unsigned char)src[i]);
  dst[i] = 0;
}

/* The classes of requests_total, for alerts, with the statuses each holds;
 * client_error (the request was wrong: INVALID, TOO_LARGE,
 * UNKNOWN_VARIANT, ...) holds every status not listed. The HELP line is
 * written from this table, so that it names every class and status the
 * samples carry. */
static const struct {
  const char *name;
  int codes[2];
} CLASSES[] = {
    {"ok", {HFP_OK, -1}},
    {"overload", {HFP_E_BUSY, HFP_E_EXPIRED}},  /* the server did not keep up */
    {"unavailable", {HFP_E_SHUTTING_DOWN, -1}},
    {"cancelled", {HFP_E_CANCELLED, -1}},       /* the client's own choice */
    {"server_error", {HFP_E_INTERNAL, -1}},
};
#define NCLASSES (sizeof CLASSES / sizeof CLASSES[0])

static const char *status_class(int code) {
  for (size_t i = 0; i < NCLASSES; i++)
    for (int k = 0; k < 2; k++)
      if (CLASSES[i].codes[k] == code) return CLASSES[i].name;
  return "client_error";
}

/* requests_total's HELP: what it counts, and each class with its statuses
 * (from CLASSES). */
static void requests_help(char *help, size_t cap) {
  size_t n = (size_t)snprintf(help, cap, "FILTER requests answered, by variant (empty: none could "
                                         "be found) and status; class is");
  for (size_t i = 0; i < NCLASSES && n < cap; i++) {
    n += (size_t)snprintf(help + n, cap - n, " %s (", CLASSES[i].name);
    for (int k = 0; k < 2 && CLASSES[i].codes[k] >= 0 && n < cap; k++)
      n += (size_t)snprintf(help + n, cap - n, "%s%s", k ? ", " : "",
                            hfp_code_name(CLASSES[i].codes[k]));
    if (n < cap) n += (size_t)snprintf(help + n, cap - n, "),");
  }
  if (n < cap) snprintf(help + n, cap - n, " or client_error (every other status).");
}

/* Statuses shown even at zero, so that rate() and alerts have a series
 * from the start; others appear once they happen. */
static int always_shown(int code) {
  return code == HFP_OK || code == HFP_E_BUSY || code == HFP_E_INVALID ||
         code == HFP_E_TOO_LARGE || code == HFP_E_INTERNAL || code == HFP_E_EXPIRED;
}

static void requests(FILE *f, const char *variant, const hfd_variant_metrics *m, int unrouted,
                     const uint64_t *counts) {
  for (int code = 0; code < HFP_E_COUNT; code++) {
    uint64_t n = counts ? counts[code] : m->by_status[code];
    int shown = unrouted ? (n || code == HFP_E_UNKNOWN_VARIANT) : (n || always_shown(code));
    if (!shown) continue;
    char st[32];
    lower(st, sizeof st, hfp_code_name(code));
    fputs("hairfilterd_requests_total{variant=\"", f);
    label(f, variant);
    fprintf(f, "\",status=\"%s\",class=\"%s\"} %llu\n", st, status_class(code),
            (unsigned long long)n);
  }
}

static void histogram(FILE *f, const char *name, const char *variant, const hfd_hist *h,
                      int batches) {
  uint64_t cum = 0;
  int nb = batches ? HFD_BATCH_BUCKETS : HFD_TIME_BUCKETS;
  for (int b = 0; b <= nb; b++) {
    cum += h->bucket[b];
    fprintf(f, "%s_bucket{variant=\"", name);
    label(f, variant);
    if (b == nb)
      fprintf(f, "\",le=\"+Inf\"} %llu\n", (unsigned long long)cum);
    else if (batches)
      fprintf(f, "\",le=\"%u\"} %llu\n", 1u << b, (unsigned long long)cum);
    else
      fprintf(f, "\",le=\"%g\"} %llu\n", hfd_time_buckets_s[b], (unsigned long long)cum);
  }
  fprintf(f, "%s_sum{variant=\"", name);
  label(f, variant);
  fprintf(f, "\"} %.9g\n", h->sum);
  fprintf(f, "%s_count{variant=\"", name);
  label(f, variant);
  fprintf(f, "\"} %llu\n", (unsigned long long)h->count);
}

/* Whether a variant's request counters are reported: while it serves, and
 * once the daemon has stopped its worker, while the last replies are
 * written (the series would otherwise vanish from a scrape then, and the
 * answers counted in that time with them). */
static int counted(const hfd_variant *v) { return v->model || v->served_at_stop; }

/* A counter with one sample per variant whose counters are reported. */
#define PER_VARIANT_COUNTED(f, s, metric, fmt, expr)                       \
  do {                                                                     \
    for (int i_ = 0; i_ < (s)->num_variants; i_++) {                       \
      const hfd_variant *v = &(s)->variants[i_];                           \
      if (!counted(v)) continue;                                           \
      fprintf(f, "%s{variant=\"", metric);                                 \
      label(f, v->name);                                                   \
      fprintf(f, "\"} " fmt "\n", expr);                                   \
    }                                                                      \
  } while (0)

/* A gauge or counter with one sample per serving variant. */
#define PER_VARIANT(f, s, metric, fmt, expr)                               \
  do {                                                                     \
    for (int i_ = 0; i_ < (s)->num_variants; i_++) {                       \
      const hfd_variant *v = &(s)->variants[i_];                           \
      if (!v->model) continue;                                             \
      fprintf(f, "%s{variant=\"", metric);                                 \
      label(f, v->name);                                                   \
      fprintf(f, "\"} " fmt "\n", expr);                                   \
    }                                                                      \
  } while (0)

/* Resident memory, CPU time and descriptors of this process, as every
 * Prometheus client library reports them (process_*), from /proc. */
static void process_metrics(FILE *f, const hfd_server *s) {
  long page = sysconf(_SC_PAGESIZE), tick = sysconf(_SC_CLK_TCK);
  FILE *p = fopen("/proc/self/statm", "r");
  unsigned long long size = 0, rss = 0;
  if (p) {
    if (fscanf(p, "%llu %llu", &size, &rss) != 2) size = rss = 0;
    fclose(p);
  }
  unsigned long long ut = 0, st = 0;
  p = fopen("/proc/self/stat", "r");
  if (p) {
    char buf[1024];
    size_t n = fread(buf, 1, sizeof buf - 1, p);
    buf[n] = 0;
    fclose(p);
    /* Fields after the command name (in parentheses, which may hold
     * spaces): state is field 3, utime 14, stime 15. */
    const char *q = strrchr(buf, ')');
    if (!q || sscanf(q + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %llu %llu", &ut,
                     &st) != 2)
      ut = st = 0;
  }
  int fds = 0;
  DIR *d = opendir("/proc/self/fd");
  if (d) {
    for (struct dirent *e; (e = readdir(d)) != NULL;) fds += e->d_name[0] != '.';
    closedir(d);
    fds--;  /* the one opendir holds */
  }
  family(f, "process_resident_memory_bytes", "gauge", "Resident memory size in bytes.");
  fprintf(f, "process_resident_memory_bytes %llu\n", rss * (unsigned long long)page);
  family(f, "process_virtual_memory_bytes", "gauge", "Virtual memory size in bytes.");
  fprintf(f, "process_virtual_memory_bytes %llu\n", size * (unsigned long long)page);
  family(f, "process_cpu_seconds_total", "counter", "User and system CPU time spent in seconds.");
  fprintf(f, "process_cpu_seconds_total %.2f\n", (double)(ut + st) / (double)tick);
  family(f, "process_open_fds", "gauge", "Number of open file descriptors.");
  fprintf(f, "process_open_fds %d\n", fds);
  family(f, "process_start_time_seconds", "gauge",
         "Start time of the process since the Unix epoch in seconds.");
  fprintf(f, "process_start_time_seconds %.3f\n", s->t_start_wall);
}

int hfd_metrics_render(hfd_server *s, char **out, size_t *len) {
  char *buf = NULL;
  size_t n = 0;
  FILE *f = open_memstream(&buf, &n);
  if (!f) return -1;
  const char *backend = s->worker.backend ? hf_backend_name(s->worker.backend) : "";
  char why[300];
  int ready = hfd_ready(s, why, sizeof why);

  family(f, "hairfilterd_build_info", "gauge",
         "Always 1; the labels say which hairfilterd this is and the protocol versions it speaks.");
  fprintf(f, "hairfilterd_build_info{version=\"%s\",protocol_min=\"%d\",protocol_max=\"%d\"} 1\n",
          HAIRFILTER_VERSION_STRING, HFP_VERSION_MIN, HFP_VERSION);
  family(f, "hairfilterd_backend_info", "gauge", "Always 1; the backend that runs the models.");
  fputs("hairfilterd_backend_info{backend=\"", f);
  label(f, backend);
  fputs("\"} 1\n", f);
  scalar(f, "hairfilterd_ready", "gauge", "1 when /readyz answers 200.",
         ready);
  scalar(f, "hairfilterd_draining", "gauge", "1 after SIGTERM or SIGINT, while finishing work.",
         s->draining);

  family(f, "hairfilterd_variant_info", "gauge",
         "Always 1 for each variant served; its backend, precision, samples per pixel, U-Net "
         "levels and weights file.");
  for (int i = 0; i < s->num_variants; i++) {
    const hfd_model *m = s->variants[i].model;
    if (!m) continue;
    char levels[128] = "";
    for (int l = 0; l < m->cfg.num_levels; l++) {
      size_t used = strlen(levels);
      snprintf(levels + used, sizeof levels - used, "%s%d", l ? "," : "", m->cfg.levels[l]);
    }
    fputs("hairfilterd_variant_info{variant=\"", f);
    label(f, m->name);
    fputs("\",backend=\"", f);
    label(f, backend);
    fputs("\",precision=\"", f);
    label(f, m->precision);
    fprintf(f, "\",spp=\"%d\",levels=\"%s\",file=\"", m->cfg.spp, levels);
    label(f, m->path);
    fputs("\"} 1\n", f);
  }
  family(f, "hairfilterd_variant_loaded_timestamp_seconds", "gauge",
         "When the version of each variant now serving was loaded, since the Unix epoch.");
  PER_VARIANT(f, s, "hairfilterd_variant_loaded_timestamp_seconds", "%.3f",
              v->model->t_loaded_wall);
  family(f, "hairfilterd_model_parameters", "gauge", "Weights in each variant's network.");
  PER_VARIANT(f, s, "hairfilterd_model_parameters", "%llu",
              (unsigned long long)v->model->params);
  family(f, "hairfilterd_model_device_memory_bytes", "gauge",
         "Device (GPU) memory each variant's model holds; 0 on CPU backends.");
  PER_VARIANT(f, s, "hairfilterd_model_device_memory_bytes", "%llu",
              (unsigned long long)v->model->device_bytes);
  scalar(f, "hairfilterd_model_cache_memory_bytes", "gauge",
         "Host memory the backend keeps between runs (plans, scratch), all models together; "
         "counted in the request memory limit.",
         atomic_load(&s->worker.cached_bytes));
  family(f, "hairfilterd_variant_cache_memory_bytes", "gauge",
         "Host memory each variant's model keeps between runs (plans); in "
         "hairfilterd_model_cache_memory_bytes.");
  PER_VARIANT(f, s, "hairfilterd_variant_cache_memory_bytes", "%llu",
              (unsigned long long)atomic_load(&v->model->cache_bytes));
  scalar(f, "hairfilterd_receive_buffer_bytes", "gauge",
         "Receive and result buffers mapped for socket frames, lent or kept idle for reuse.",
         s->rpool.mapped_bytes);
  scalar(f, "hairfilterd_receive_buffer_idle_bytes", "gauge",
         "Receive buffers kept idle for reuse; counted in the request memory limit, and within "
         "the quarter of it kept between runs together with the plans.",
         atomic_load(&s->rpool.idle_bytes));
  scalar(f, "hairfilterd_receive_buffer_reuses_total", "counter",
         "Socket frames whose buffer was one kept from an earlier frame.", s->rpool.hits);
  scalar(f, "hairfilterd_receive_buffer_maps_total", "counter",
         "Socket frames whose buffer had to be mapped afresh.", s->rpool.misses);

  char help[512];
  requests_help(help, sizeof help);
  family(f, "hairfilterd_requests_total", "counter", help);
  for (int i = 0; i < s->num_variants; i++) {
    const hfd_variant *v = &s->variants[i];
    if (counted(v)) requests(f, v->name, &v->m, 0, NULL);
  }
  requests(f, "", &no_variant, 1, s->unrouted);

  static const char *const hist_name[HFD_T_COUNT] = {
    "hairfilterd_queue_duration_seconds", "hairfilterd_input_duration_seconds",
    "hairfilterd_inference_duration_seconds", "hairfilterd_output_duration_seconds",
    "hairfilterd_request_duration_seconds"};
  static const char *const hist_help[HFD_T_COUNT] = {
    "Time successful requests waited in the queue (admitted to taken by the worker).",
    "Time spent on inputs: batch assembly, input statistics, upload, conversion, padding.",
    "Time the network ran.",
    "Time spent on outputs: transforms, crop, download, conversion, composite.",
    "Server time of successful requests, frame received to reply handed to the socket."};
  for (int t = 0; t < HFD_T_COUNT; t++) {
    family(f, hist_name[t], "histogram", hist_help[t]);
    for (int i = 0; i < s->num_variants; i++) {
      const hfd_variant *v = &s->variants[i];
      if (counted(v)) histogram(f, hist_name[t], v->name, &v->m.time[t], 0);
    }
  }
  family(f, "hairfilterd_batch_size", "histogram", "Frames per backend run.");
  for (int i = 0; i < s->num_variants; i++) {
    const hfd_variant *v = &s->variants[i];
    if (counted(v)) histogram(f, "hairfilterd_batch_size", v->name, &v->m.batch, 1);
  }
  family(f, "hairfilterd_frames_out_of_range_total", "counter",
         "Successful requests whose input was outside the variant's trained range.");
  PER_VARIANT_COUNTED(f, s, "hairfilterd_frames_out_of_range_total", "%llu",
              (unsigned long long)v->stats.out_of_range);
  family(f, "hairfilterd_frames_sanitised_total", "counter",
         "Successful requests whose input held NaN, infinite or out-of-range samples, "
         "sanitised before the network.");
  PER_VARIANT_COUNTED(f, s, "hairfilterd_frames_sanitised_total", "%llu",
              (unsigned long long)v->stats.frames_sanitised);

  scalar(f, "hairfilterd_queue_depth", "gauge",
         "Admitted frames not yet running, queued or held for batch partners.",
         s->stopped ? 0 : hfd_worker_queue_depth(&s->worker));
  scalar(f, "hairfilterd_queue_capacity", "gauge", "--queue-size.",
         s->cfg->queue_size);
  scalar(f, "hairfilterd_requests_in_flight", "gauge",
         "Requests admitted and not yet answered (queued or running).",
         s->jobs_outstanding);
  scalar(f, "hairfilterd_connections", "gauge", "Open connections.",
         s->num_conns);
  scalar(f, "hairfilterd_connections_handshaking", "gauge",
         "Open connections that have not completed their HELLO.",
         s->num_handshaking);
  scalar(f, "hairfilterd_connections_total", "counter", "Connections accepted.",
         s->conns_total);
  scalar(f, "hairfilterd_protocol_errors_total", "counter",
         "ERROR replies not tied to a variant: malformed frames, failed handshakes, deadlines.",
         s->protocol_errors);
  scalar(f, "hairfilterd_replies_lost_total", "counter",
         "Results computed and never delivered: the client had gone, or its connection was "
         "closed with them unread.",
         s->replies_lost);
  scalar(f, "hairfilterd_queue_pushed_out_total", "counter",
         "Admitted frames taken off the full queue for a connection under its share, "
         "answered by a RESULT of status BUSY (counted once written, as requests_total).",
         s->pushed_out_answered);
  scalar(f, "hairfilterd_request_memory_bytes", "gauge",
         "Host memory charged to requests: features, results, inference (--max-memory-mb).",
         s->mem_held);
  scalar(f, "hairfilterd_request_memory_limit_bytes", "gauge", "--max-memory-mb in bytes.",
         s->cfg->max_memory_bytes);
  scalar(f, "hairfilterd_shared_memory_bytes", "gauge",
         "Shared-memory segments held for Unix-socket clients.",
         s->shm_held);
  scalar(f, "hairfilterd_shared_memory_limit_bytes", "gauge", "--max-shm-mb in bytes.",
         s->cfg->max_shm_bytes);
  scalar(f, "hairfilterd_max_frame_pixels", "gauge",
         "Largest frame announced in HELLO_OK (--max-size as lowered to fit the limits).",
         (unsigned long long)s->max_width * (unsigned long long)s->max_height);

  family(f, "hairfilterd_reloads_total", "counter",
         "SIGHUP reloads, by result (failed: at least one file did not load).");
  fprintf(f, "hairfilterd_reloads_total{result=\"ok\"} %llu\n", (unsigned long long)s->reloads_ok);
  fprintf(f, "hairfilterd_reloads_total{result=\"failed\"} %llu\n",
          (unsigned long long)s->reloads_failed);
  family(f, "hairfilterd_model_loads_total", "counter", "Weights files loaded, by result.");
  fprintf(f, "hairfilterd_model_loads_total{result=\"ok\"} %llu\n",
          (unsigned long long)s->loads_ok);
  fprintf(f, "hairfilterd_model_loads_total{result=\"failed\"} %llu\n",
          (unsigned long long)s->loads_failed);
  long long not_after;
  if (hfd_tls_not_after(s, &not_after) == 0 && not_after >= 0)
    scalar(f, "hairfilterd_tls_certificate_expiry_timestamp_seconds", "gauge",
           "notAfter of the certificate new TLS connections get, as a Unix time (with a tls: "
           "listener only).", (unsigned long long)not_after);
  scalar(f, "hairfilterd_weights_files_unserved", "gauge",
         "Configured weights files that serve no variant (their load failed).",
         s->missing);

  process_metrics(f, s);
  if (fclose(f) != 0) {
    free(buf);
    return -1;
  }
  *out = buf;
  *len = n;
  return 0;
}

void hfd_metrics_log(hfd_server *s) {
  hfd_notice("statistics: uptime=%.1fs connections=%d connections_total=%llu queue=%d/%d "
             "in_flight=%d memory_mib=%.1f shm_mib=%.1f protocol_errors=%llu reloads=%llu",
             (hfd_now_us() - s->t_start) / 1e6, s->num_conns,
             (unsigned long long)s->conns_total,
             s->stopped ? 0 : hfd_worker_queue_depth(&s->worker),
             s->cfg->queue_size, s->jobs_outstanding, s->mem_held / 1048576.0,
             s->shm_held / 1048576.0, (unsigned long long)s->protocol_errors,
             (unsigned long long)(s->reloads_ok + s->reloads_failed));
  for (int i = 0; i < s->num_variants; i++) {
    const hfd_variant *v = &s->variants[i];
    if (!counted(v)) continue;
    const hfd_hist *t = &v->m.time[HFD_T_TOTAL];
    /* SHUTTING_DOWN apart, as /metrics' class "unavailable": every
     * rolling restart refuses what clients send while it drains, which is
     * no error of theirs or the server's. */
    uint64_t errors = 0;
    for (int c = 1; c < HFP_E_COUNT; c++)
      if (c != HFP_E_BUSY && c != HFP_E_SHUTTING_DOWN) errors += v->m.by_status[c];
    char kv[128] = "";
    hfd_kv(kv, sizeof kv, "variant", v->name);
    hfd_notice("statistics:%s ok=%llu busy=%llu unavailable=%llu errors=%llu batches=%llu "
               "mean_total_ms=%.3f out_of_range=%llu sanitised=%llu expired=%llu cancelled=%llu",
               kv,
               (unsigned long long)v->m.by_status[HFP_OK],
               (unsigned long long)v->m.by_status[HFP_E_BUSY],
               (unsigned long long)v->m.by_status[HFP_E_SHUTTING_DOWN],
               (unsigned long long)errors,
               (unsigned long long)v->m.batch.count, t->count ? t->sum / t->count * 1e3 : 0.0,
               (unsigned long long)v->stats.out_of_range,
               (unsigned long long)v->stats.frames_sanitised,
               (unsigned long long)v->stats.expired,
               (unsigned long long)v->stats.cancelled);
  }
}
