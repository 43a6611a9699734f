/* hairfilter load's reports (load.h): a text block per point and a table
 * over the sweep on stdout, CSV and JSON (cJSON) files, and the
 * latency-versus-throughput plot, drawn by gnuplot from a script written to
 * its standard input. */
#define _POSIX_C_SOURCE 200809L
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "load.h"

const char *const load_field_names[LF_COUNT] = {"total", "server", "queue",
                                                "input", "infer",  "output"};

static const double PCTS[] = {50, 90, 95, 99, 99.9};
enum { NPCT = sizeof PCTS / sizeof PCTS[0] };

static double throughput(const load_point *p) {
  return p->result.seconds > 0 ? (double)p->result.ok / p->result.seconds : 0;
}

static double ms(const load_point *p, int field, double pct) {
  return lh_percentile(&p->result.h[field], pct) / 1e3;
}

static const char *stability(const load_point *p) {
  return p->interrupted ? "interrupted" : p->stable > 0 ? "stable" : p->stable < 0 ? "fixed" : "unstable";
}

void load_print_header(FILE *f, const load_run *r) {
  fprintf(f, "command: %s\nmachine: %s, %d cores; %s; hairfilter %s\n\n", r->command, r->cpu,
          r->cores, r->date, r->version);
  fflush(f);
}

void load_print_point(FILE *f, const load_run *r, const load_point *p) {
  char mode[160];
  if (p->open_loop)
    snprintf(mode, sizeof mode, "open loop, %g frames/s (%s) over %d connection(s)", p->rate,
             r->distribution, p->connections);
  else
    snprintf(mode, sizeof mode, "closed loop, %d connection(s) x %d in flight", p->connections,
             p->concurrency / p->connections);
  /* The windows' measured length beside the one asked for: a window ends
   * early when every connection is lost. */
  fprintf(f, "%s %dx%d %s via %s%s (%s, %s): %s; %d window(s) of %.1f s, %s %d merged, %.2f s "
             "measured (%s)\n",
          r->variant, r->width, r->height, r->f16 ? "f16" : "f32", r->server,
          r->shm ? " + shared memory" : "", r->backend, r->precision, mode, p->trials, r->window_s,
          p->used == p->trials ? "all" : "last", p->used, p->result.seconds, stability(p));
  const load_window *w = &p->result;
  fprintf(f, "  frames %llu  throughput %.2f frames/s  busy %llu  errors %llu  mean batch %.2f\n",
          (unsigned long long)w->ok, throughput(p), (unsigned long long)w->busy,
          (unsigned long long)w->errors, w->ok ? (double)w->batch_sum / (double)w->ok : 0.0);
  if (r->deadline_us)
    fprintf(f, "  deadline %.3f ms  expired %llu (not computed: still queued at the server "
               "when their budget passed)  warm-up expired %llu\n",
            r->deadline_us / 1e3, (unsigned long long)w->expired,
            (unsigned long long)p->warm_expired);
  fprintf(f, "  requests sent %llu  answered %llu  unanswered %llu  late (open loop) %llu%s\n",
          (unsigned long long)p->sent, (unsigned long long)p->answered,
          (unsigned long long)p->unanswered, (unsigned long long)p->delayed,
          p->lost_connections ? "  CONNECTIONS LOST" : "");
  /* Expired ones only where a frame can expire (--deadline), as above. */
  char expired[48] = "";
  if (r->deadline_us || p->ans_expired)
    snprintf(expired, sizeof expired, "  expired %llu", (unsigned long long)p->ans_expired);
  fprintf(f, "  answered by outcome: ok %llu  busy %llu%s  errors %llu  (%s, and those answered "
             "after the last)\n",
          (unsigned long long)p->ans_ok, (unsigned long long)p->ans_busy, expired,
          (unsigned long long)p->ans_errors,
          p->used < p->trials ? "every window, not only those merged" : "every window");
  fprintf(f, "  warm-up: requests sent %llu  ok %llu  busy %llu  errors %llu\n",
          (unsigned long long)p->warm_sent, (unsigned long long)p->warm_ok,
          (unsigned long long)p->warm_busy, (unsigned long long)p->warm_errors);
  fprintf(f, "  %-8s %10s %10s %10s %10s %10s %10s   (ms)\n", "", "p50", "p90", "p95", "p99",
          "p99.9", "max");
  for (int k = 0; k < LF_COUNT; k++) {
    fprintf(f, "  %-8s", load_field_names[k]);
    for (int i = 0; i < NPCT; i++) fprintf(f, " %10.3f", ms(p, k, PCTS[i]));
    fprintf(f, " %10.3f\n", ms(p, k, 100));
  }
  const load_stats *s = &p->stats;
  if (s->valid) {
    /* The server's expired and cancelled frames beside the report's own:
     * they are among its failed ones. Cancelled ones are other clients'
     * (this one cancels none), shown when there are some. */
    char expired[96] = "";
    if ((r->deadline_us || s->expired) && s->cancelled)
      snprintf(expired, sizeof expired, " (%llu expired, %llu cancelled)",
               (unsigned long long)s->expired, (unsigned long long)s->cancelled);
    else if (r->deadline_us || s->expired)
      snprintf(expired, sizeof expired, " (%llu expired)", (unsigned long long)s->expired);
    else if (s->cancelled)
      snprintf(expired, sizeof expired, " (%llu cancelled)", (unsigned long long)s->cancelled);
    fprintf(f, "  server STATS over the point (all clients): %llu ok, %llu failed%s, %llu "
               "refused, mean batch %.2f, mean queue %.3f ms, infer %.3f ms, total %.3f ms (p50 "
               "<= %.3f, p99 <= %.3f ms)\n",
            (unsigned long long)s->ok, (unsigned long long)s->failed, expired,
            (unsigned long long)s->rejected, s->batches ? (double)s->ok / (double)s->batches : 0.0,
            s->mean_queue_ms, s->mean_infer_ms, s->mean_total_ms, s->p50_total_ms, s->p99_total_ms);
  }
  fflush(f);
}

void load_print_summary(FILE *f, const load_run *r) {
  int open = r->points[0].open_loop;
  fprintf(f, "\n%s %dx%d %s via %s%s: %s sweep (client latency, ms)\n", r->variant, r->width,
          r->height, r->f16 ? "f16" : "f32", r->server, r->shm ? " + shared memory" : "",
          open ? "open-loop" : "closed-loop");
  fprintf(f, "  %12s %12s %9s %9s %9s %9s %9s %9s %8s %8s %9s\n",
          open ? "offered/s" : "concurrency", "frames/s", "p50", "p90", "p95", "p99", "p99.9",
          "infer p50", "busy", "errors", "");
  for (int i = 0; i < r->npoints; i++) {
    const load_point *p = &r->points[i];
    if (open)
      fprintf(f, "  %12.2f", p->rate);
    else
      fprintf(f, "  %12d", p->concurrency);
    fprintf(f, " %12.2f", throughput(p));
    for (int k = 0; k < NPCT; k++) fprintf(f, " %9.3f", ms(p, LF_CLIENT, PCTS[k]));
    fprintf(f, " %9.3f %8llu %8llu %9s\n", ms(p, LF_INFER, 50), (unsigned long long)p->result.busy,
            (unsigned long long)p->result.errors, stability(p));
  }
  fflush(f);
}

/* A file is written under a temporary name beside it, then renamed, so
 * that a run stopped while writing leaves no half file under path. */
static void temp_name(char *tmp, size_t size, const char *path) {
  snprintf(tmp, size, "%s.tmp%ld", path, (long)getpid());
}

int load_out_probe(const char *option, const char *path) {
  if (!strcmp(path, "-")) return 0;
  char tmp[4200];
  temp_name(tmp, sizeof tmp, path);
  FILE *f = fopen(tmp, "w");
  if (!f) {
    fprintf(stderr, "hairfilter load: %s %s: cannot create a file beside it: %s; give a path in "
            "a directory this user can write\n", option, path, strerror(errno));
    return -1;
  }
  fclose(f);
  unlink(tmp);
  return 0;
}

static FILE *open_out(const char *path, const char *what) {
  if (!strcmp(path, "-")) return stdout;
  char tmp[4200];
  temp_name(tmp, sizeof tmp, path);
  FILE *f = fopen(tmp, "w");
  if (!f) fprintf(stderr, "hairfilter load: cannot write the %s to %s: %s\n", what, path,
                  strerror(errno));
  return f;
}

static int close_out(FILE *f, const char *path, const char *what) {
  if (f == stdout) return fflush(f) ? -1 : 0;
  char tmp[4200];
  temp_name(tmp, sizeof tmp, path);
  if (fclose(f) || rename(tmp, path)) {
    fprintf(stderr, "hairfilter load: writing the %s to %s failed: %s\n", what, path,
            strerror(errno));
    unlink(tmp);
    return -1;
  }
  return 0;
}

/* A CSV field in double quotes. */
static void csv_quoted(FILE *f, const char *v) {
  fputc('"', f);
  for (; *v; v++) {
    if (*v == '"') fputc('"', f);
    fputc(*v, f);
  }
  fputc('"', f);
}

int load_write_csv(const char *path, const load_run *r) {
  FILE *f = open_out(path, "CSV");
  if (!f) return -1;
  fprintf(f, "mode,concurrency,rate,distribution,connections,transport,dtype,width,height,windows,"
             "merged,stable,seconds,frames,throughput,busy,errors,sent,answered,unanswered,late,"
             "mean_batch");
  for (int k = 0; k < LF_COUNT; k++)
    fprintf(f, ",%s_p50_ms,%s_p90_ms,%s_p95_ms,%s_p99_ms,%s_p999_ms,%s_max_ms,%s_mean_ms",
            load_field_names[k], load_field_names[k], load_field_names[k], load_field_names[k],
            load_field_names[k], load_field_names[k], load_field_names[k]);
  fprintf(f, ",stats_ok,stats_refused,stats_mean_batch,stats_mean_queue_ms,stats_mean_infer_ms,"
             "stats_mean_total_ms,warmup_sent,warmup_ok,warmup_busy,warmup_errors,command,cpu,cores,"
             "date,version,deadline_ms,expired,warmup_expired,answered_ok,answered_busy,"
             "answered_expired,answered_errors,stats_failed,stats_expired\n");
  for (int i = 0; i < r->npoints; i++) {
    const load_point *p = &r->points[i];
    const load_window *w = &p->result;
    fprintf(f, "%s,%d,%g,%s,%d,%s,%s,%d,%d,%d,%d,%s,%.3f,%llu,%.3f,%llu,%llu,%llu,%llu,%llu,%llu,%.3f",
            p->open_loop ? "open" : "closed", p->concurrency, p->rate,
            p->open_loop ? r->distribution : "", p->connections,
            r->shm ? "shm" : !strncmp(r->server, "tcp:", 4) ? "tcp" : "unix", r->f16 ? "f16" : "f32",
            r->width, r->height, p->trials, p->used, stability(p), w->seconds,
            (unsigned long long)w->ok, throughput(p), (unsigned long long)w->busy,
            (unsigned long long)w->errors, (unsigned long long)p->sent,
            (unsigned long long)p->answered, (unsigned long long)p->unanswered,
            (unsigned long long)p->delayed, w->ok ? (double)w->batch_sum / (double)w->ok : 0.0);
    for (int k = 0; k < LF_COUNT; k++) {
      for (int j = 0; j < NPCT; j++) fprintf(f, ",%.3f", ms(p, k, PCTS[j]));
      fprintf(f, ",%.3f,%.3f", ms(p, k, 100), lh_mean(&w->h[k]) / 1e3);
    }
    const load_stats *s = &p->stats;
    fprintf(f, ",%llu,%llu,%.3f,%.3f,%.3f,%.3f", (unsigned long long)s->ok,
            (unsigned long long)s->rejected, s->batches ? (double)s->ok / (double)s->batches : 0.0,
            s->mean_queue_ms, s->mean_infer_ms, s->mean_total_ms);
    fprintf(f, ",%llu,%llu,%llu,%llu,", (unsigned long long)p->warm_sent,
            (unsigned long long)p->warm_ok, (unsigned long long)p->warm_busy,
            (unsigned long long)p->warm_errors);
    csv_quoted(f, r->command);
    fputc(',', f);
    csv_quoted(f, r->cpu);
    fprintf(f, ",%d,%s,%s,%.3f,%llu,%llu,%llu,%llu,%llu,%llu,%llu,%llu\n", r->cores, r->date,
            r->version, r->deadline_us / 1e3, (unsigned long long)w->expired,
            (unsigned long long)p->warm_expired, (unsigned long long)p->ans_ok,
            (unsigned long long)p->ans_busy, (unsigned long long)p->ans_expired,
            (unsigned long long)p->ans_errors, (unsigned long long)s->failed,
            (unsigned long long)s->expired);
  }
  return close_out(f, path, "CSV");
}

int load_write_json(const char *path, const load_run *r) {
  cJSON *doc = cJSON_CreateObject(), *pts = cJSON_CreateArray();
  if (!doc || !pts) {
    cJSON_Delete(doc);
    cJSON_Delete(pts);
    return -1;
  }
  cJSON_AddStringToObject(doc, "server", r->server);
  cJSON_AddStringToObject(doc, "variant", r->variant);
  cJSON_AddStringToObject(doc, "backend", r->backend);
  cJSON_AddStringToObject(doc, "precision", r->precision);
  cJSON_AddStringToObject(doc, "input", r->input ? r->input : "random");
  cJSON_AddNumberToObject(doc, "width", r->width);
  cJSON_AddNumberToObject(doc, "height", r->height);
  cJSON_AddNumberToObject(doc, "spp", r->spp);
  cJSON_AddStringToObject(doc, "dtype", r->f16 ? "f16" : "f32");
  cJSON_AddBoolToObject(doc, "shared_memory", r->shm);
  cJSON_AddBoolToObject(doc, "composite", r->composite);
  cJSON_AddNumberToObject(doc, "window_s", r->window_s);
  cJSON_AddNumberToObject(doc, "warmup_s", r->warmup_s);
  cJSON_AddNumberToObject(doc, "stability_percentage", r->stability);
  cJSON_AddStringToObject(doc, "command", r->command);
  cJSON_AddStringToObject(doc, "cpu", r->cpu);
  cJSON_AddNumberToObject(doc, "cores", r->cores);
  cJSON_AddStringToObject(doc, "date", r->date);
  cJSON_AddStringToObject(doc, "version", r->version);
  cJSON_AddBoolToObject(doc, "interrupted", r->interrupted);
  cJSON_AddItemToObject(doc, "points", pts);
  for (int i = 0; i < r->npoints; i++) {
    const load_point *p = &r->points[i];
    const load_window *w = &p->result;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddItemToArray(pts, o);
    cJSON_AddStringToObject(o, "mode", p->open_loop ? "open" : "closed");
    if (p->open_loop) {
      cJSON_AddNumberToObject(o, "rate", p->rate);
      cJSON_AddStringToObject(o, "distribution", r->distribution);
    } else {
      cJSON_AddNumberToObject(o, "concurrency", p->concurrency);
    }
    cJSON_AddNumberToObject(o, "connections", p->connections);
    cJSON_AddNumberToObject(o, "windows", p->trials);
    cJSON_AddNumberToObject(o, "merged", p->used);
    cJSON_AddStringToObject(o, "stability", stability(p));
    cJSON_AddNumberToObject(o, "seconds", w->seconds);
    cJSON_AddNumberToObject(o, "frames", (double)w->ok);
    cJSON_AddNumberToObject(o, "throughput", throughput(p));
    cJSON_AddNumberToObject(o, "busy", (double)w->busy);
    cJSON_AddNumberToObject(o, "errors", (double)w->errors);
    cJSON_AddNumberToObject(o, "expired", (double)w->expired);
    cJSON_AddNumberToObject(o, "deadline_ms", r->deadline_us / 1e3);
    cJSON_AddNumberToObject(o, "sent", (double)p->sent);
    cJSON_AddNumberToObject(o, "answered", (double)p->answered);
    cJSON_AddNumberToObject(o, "unanswered", (double)p->unanswered);
    cJSON_AddNumberToObject(o, "late", (double)p->delayed);
    cJSON_AddNumberToObject(o, "mean_batch", w->ok ? (double)w->batch_sum / (double)w->ok : 0.0);
    cJSON *ao = cJSON_AddObjectToObject(o, "answered_by_outcome");
    cJSON_AddNumberToObject(ao, "ok", (double)p->ans_ok);
    cJSON_AddNumberToObject(ao, "busy", (double)p->ans_busy);
    cJSON_AddNumberToObject(ao, "expired", (double)p->ans_expired);
    cJSON_AddNumberToObject(ao, "errors", (double)p->ans_errors);
    cJSON *wu = cJSON_AddObjectToObject(o, "warmup");
    cJSON_AddNumberToObject(wu, "sent", (double)p->warm_sent);
    cJSON_AddNumberToObject(wu, "ok", (double)p->warm_ok);
    cJSON_AddNumberToObject(wu, "busy", (double)p->warm_busy);
    cJSON_AddNumberToObject(wu, "errors", (double)p->warm_errors);
    cJSON_AddNumberToObject(wu, "expired", (double)p->warm_expired);
    cJSON *lat = cJSON_AddObjectToObject(o, "latency_ms");
    for (int k = 0; k < LF_COUNT; k++) {
      cJSON *fo = cJSON_AddObjectToObject(lat, load_field_names[k]);
      static const char *const names[NPCT] = {"p50", "p90", "p95", "p99", "p99.9"};
      for (int j = 0; j < NPCT; j++) cJSON_AddNumberToObject(fo, names[j], ms(p, k, PCTS[j]));
      cJSON_AddNumberToObject(fo, "max", ms(p, k, 100));
      cJSON_AddNumberToObject(fo, "mean", lh_mean(&w->h[k]) / 1e3);
    }
    cJSON *wins = cJSON_AddArrayToObject(o, "window_results");
    for (int t = 0; t < p->trials && t < 64; t++) {
      cJSON *wo = cJSON_CreateObject();
      cJSON_AddNumberToObject(wo, "throughput", p->window_throughput[t]);
      cJSON_AddNumberToObject(wo, "p50_ms", p->window_p50[t] / 1e3);
      cJSON_AddNumberToObject(wo, "p99_ms", p->window_p99[t] / 1e3);
      cJSON_AddItemToArray(wins, wo);
    }
    if (p->stats.valid) {
      const load_stats *s = &p->stats;
      cJSON *so = cJSON_AddObjectToObject(o, "server_stats");
      cJSON_AddNumberToObject(so, "ok", (double)s->ok);
      cJSON_AddNumberToObject(so, "failed", (double)s->failed);
      cJSON_AddNumberToObject(so, "expired", (double)s->expired);
      cJSON_AddNumberToObject(so, "cancelled", (double)s->cancelled);
      cJSON_AddNumberToObject(so, "refused", (double)s->rejected);
      cJSON_AddNumberToObject(so, "batches", (double)s->batches);
      cJSON_AddNumberToObject(so, "mean_queue_ms", s->mean_queue_ms);
      cJSON_AddNumberToObject(so, "mean_infer_ms", s->mean_infer_ms);
      cJSON_AddNumberToObject(so, "mean_total_ms", s->mean_total_ms);
      if (isfinite(s->p99_total_ms)) cJSON_AddNumberToObject(so, "p99_total_ms_at_most", s->p99_total_ms);
    }
  }
  char *text = cJSON_Print(doc);
  cJSON_Delete(doc);
  if (!text) return -1;
  FILE *f = open_out(path, "JSON");
  if (!f) {
    free(text);
    return -1;
  }
  fputs(text, f);
  fputc('\n', f);
  free(text);
  return close_out(f, path, "JSON");
}

int load_have_gnuplot(void) { return system("gnuplot --version > /dev/null 2>&1") == 0; }

int load_write_plot(const char *path, const load_run *r) {
  for (const char *c = path; *c; c++)
    if (*c == '"' || *c == '\\' || *c == '\n') {
      fprintf(stderr, "hairfilter load: --plot: the path may not hold quotes, backslashes or "
                      "line breaks\n");
      return -1;
    }
  FILE *g = popen("gnuplot", "w");
  if (!g) {
    fprintf(stderr, "hairfilter load: cannot run gnuplot\n");
    return -1;
  }
  int open = r->points[0].open_loop;
  char tmp[4200];
  temp_name(tmp, sizeof tmp, path);
  fprintf(g, "set terminal pngcairo size 900,600 font ',10'\nset output \"%s\"\n", tmp);
  fprintf(g, "set title \"%s %dx%d %s via %s%s (%s), %s loop\" noenhanced\n", r->variant, r->width,
          r->height, r->f16 ? "f16" : "f32", r->server, r->shm ? " + shared memory" : "",
          r->backend, open ? "open" : "closed");
  fprintf(g, "set xlabel \"throughput (frames/s)\"\nset ylabel \"client latency (ms)\"\n"
             "set grid\nset key top left\nset logscale y\n");
  fprintf(g, "$d << EOD\n");
  for (int i = 0; i < r->npoints; i++) {
    const load_point *p = &r->points[i];
    if (!p->result.ok) continue;
    fprintf(g, "%.4f %.4f %.4f %.4f %.4f \"%s%g\"\n", throughput(p), ms(p, LF_CLIENT, 50),
            ms(p, LF_CLIENT, 90), ms(p, LF_CLIENT, 99), ms(p, LF_CLIENT, 99.9), open ? "" : "c",
            open ? p->rate : (double)p->concurrency);
  }
  fprintf(g, "EOD\n");
  fprintf(g, "plot $d using 1:2 with linespoints title \"p50\", "
             "$d using 1:3 with linespoints title \"p90\", "
             "$d using 1:4 with linespoints title \"p99\", "
             "$d using 1:5 with linespoints title \"p99.9\", "
             "$d using 1:4:6 with labels offset 0,1 notitle\n");
  int rc = pclose(g);
  if (rc != 0 || rename(tmp, path)) {
    fprintf(stderr, "hairfilter load: gnuplot failed (status %d) writing %s\n", rc, path);
    unlink(tmp);
    return -1;
  }
  return 0;
}
