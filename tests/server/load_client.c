/*
 * A load client for the operator tests (test_metrics.py, test_reload.py):
 * C connections keep K requests each in flight against one variant, and
 * every answer is counted by status, so a test can compare what the daemon
 * reports with exactly what was sent. hairfilter-load measures latency and
 * counts only a measured window; this counts everything.
 *
 *   load_client --server URL --variant NAME --size WxH --spp N
 *               [--connections C] [--inflight K]
 *               (--count N | --until-file PATH)
 *
 * --count: N requests in all (split over the connections); --until-file:
 * until PATH exists. BUSY answers are counted, not retried. Prints one JSON
 * object: {"sent": N, "answered": N, "status": {"OK": n, "BUSY": n, ...},
 * "connection_errors": n}; exits 0 when every request sent was answered.
 */
#define _POSIX_C_SOURCE 200809L
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <hairfilter/hairfilter.h>

#include "hfproto.h"

typedef struct opts {
  const char *server, *variant, *until_file;
  int width, height, spp, connections, inflight;
  long count;
} opts;

typedef struct conn_run {
  pthread_t thread;
  const opts *o;
  long quota;                    /* requests to send; -1: until the file */
  long sent, answered;
  long status[HFP_E_COUNT];
  int conn_error;
} conn_run;

static int stop_now(const conn_run *r) {
  if (r->quota >= 0) return r->sent >= r->quota;
  return access(r->o->until_file, F_OK) == 0;
}

static void *run(void *arg) {
  conn_run *r = arg;
  const opts *o = r->o;
  hfc_client *c = NULL;
  hfc_options co;
  hfc_options_init(&co);
  co.client_name = "load_client";
  co.token = getenv("HAIRFILTER_TOKEN");
  co.timeout_ms = 60000;
  co.failover = HFC_FAILOVER_NEVER;  /* BUSY is counted, not sent again */
  int rc = hfc_connect(o->server, &co, &c);
  if (rc) {
    fprintf(stderr, "load_client: %s: %s\n", o->server, hfc_strerror(rc));
    r->conn_error = 1;
    return NULL;
  }
  size_t px = (size_t)o->width * o->height, nin = px * (size_t)o->spp * 6;
  float *in = malloc(nin * sizeof *in), *out = malloc(px * 3 * sizeof *out * (size_t)o->inflight);
  if (!in || !out) {
    r->conn_error = 1;
    goto done;
  }
  uint32_t x = 4242;
  for (size_t i = 0; i < nin; i++) {
    x = x * 1664525u + 1013904223u;
    in[i] = (float)(x >> 8) / 16777216.0f;
  }
  hfc_request q;
  hfc_request_init(&q);
  q.variant = o->variant;
  q.width = o->width;
  q.height = o->height;
  q.spp = o->spp;
  q.in_dtype = HFC_F32;
  q.features = in;
  q.features_bytes = nin * sizeof *in;
  q.out_dtype = HFC_F32;
  q.result_bytes = px * 3 * sizeof *out;
  int pending = 0;
  for (int s = 0; s < o->inflight && !stop_now(r); s++) {
    q.result = out + px * 3 * (size_t)s;
    q.user = (void *)(intptr_t)s;
    if ((rc = hfc_submit(c, &q, NULL)) != 0) break;
    r->sent++;
    pending++;
  }
  while (pending && !rc) {
    hfc_completion d;
    if ((rc = hfc_wait(c, -1, &d)) != 0) break;
    pending--;
    r->answered++;
    int code = d.status <= 0 && -d.status < HFP_E_COUNT ? -d.status : HFP_E_INTERNAL;
    r->status[code]++;
    if (!stop_now(r)) {
      q.result = out + px * 3 * (size_t)(intptr_t)d.user;
      q.user = d.user;
      if ((rc = hfc_submit(c, &q, NULL)) != 0) break;
      r->sent++;
      pending++;
    }
  }
  if (rc) {
    fprintf(stderr, "load_client: connection failed: %s\n", hfc_strerror(rc));
    r->conn_error = 1;
  }
done:
  free(in);
  free(out);
  hfc_close(c);
  return NULL;
}

int main(int argc, char **argv) {
  opts o = {.connections = 1, .inflight = 1, .count = -1, .spp = 4, .width = 16, .height = 16};
  for (int i = 1; i + 1 < argc; i += 2) {
    const char *a = argv[i], *v = argv[i + 1];
    if (!strcmp(a, "--server")) o.server = v;
    else if (!strcmp(a, "--variant")) o.variant = v;
    else if (!strcmp(a, "--until-file")) o.until_file = v;
    else if (!strcmp(a, "--size") && sscanf(v, "%dx%d", &o.width, &o.height) == 2) continue;
    else if (!strcmp(a, "--spp")) o.spp = atoi(v);
    else if (!strcmp(a, "--connections")) o.connections = atoi(v);
    else if (!strcmp(a, "--inflight")) o.inflight = atoi(v);
    else if (!strcmp(a, "--count")) o.count = atol(v);
    else {
      fprintf(stderr, "load_client: bad argument '%s'\n", a);
      return 2;
    }
  }
  if (!o.server || !o.variant || (o.count < 0 && !o.until_file) || o.connections < 1 ||
      o.connections > 64 || o.inflight < 1 || o.spp < 1 || o.width < 1 || o.height < 1) {
    fprintf(stderr, "usage: load_client --server URL --variant NAME --size WxH --spp N "
            "[--connections C] [--inflight K] (--count N | --until-file PATH)\n");
    return 2;
  }
  conn_run runs[64];
  memset(runs, 0, sizeof runs);
  for (int i = 0; i < o.connections; i++) {
    runs[i].o = &o;
    runs[i].quota = o.count < 0 ? -1 : o.count / o.connections + (i < o.count % o.connections);
    if (pthread_create(&runs[i].thread, NULL, run, &runs[i])) return 1;
  }
  long sent = 0, answered = 0, status[HFP_E_COUNT] = {0};
  int errors = 0;
  for (int i = 0; i < o.connections; i++) {
    pthread_join(runs[i].thread, NULL);
    sent += runs[i].sent;
    answered += runs[i].answered;
    errors += runs[i].conn_error;
    for (int k = 0; k < HFP_E_COUNT; k++) status[k] += runs[i].status[k];
  }
  printf("{\"sent\": %ld, \"answered\": %ld, \"connection_errors\": %d, \"status\": {", sent,
         answered, errors);
  int first = 1;
  for (int k = 0; k < HFP_E_COUNT; k++)
    if (status[k]) {
      printf("%s\"%s\": %ld", first ? "" : ", ", hfp_code_name(k), status[k]);
      first = 0;
    }
  printf("}}\n");
  return sent == answered && !errors ? 0 : 1;
}
