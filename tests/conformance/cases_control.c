/*
 * PROTOCOL.md, "Variants" and "Statistics", and the order of control
 * replies ("Transport"): what VARIANTS and STATS_REPLY carry, that their
 * counters move as the server's work does, and that control replies keep
 * the order of their requests.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cf_internal.h"

static int request(cf_test *t, int fd, int type, cf_frame *f) {
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, type, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  return cf_expect(t, fd, type == HFP_STATS ? HFP_STATS_REPLY : HFP_VARIANTS, f);
}

static int get_stats(cf_test *t, int fd, hfp_stats *st) {
  cf_frame f;
  CF_TRY(request(t, fd, HFP_STATS, &f));
  int rc = hfp_decode_stats(f.p, f.h.length, st);
  CF_CHECK(t, rc == 0, "STATS_REPLY does not decode: %s", hfp_strerror(rc));
  return 0;
}

static const hfp_variant_stats *find(const hfp_stats *st, const char *name) {
  for (int i = 0; i < st->num_variants; i++)
    if (!strcmp(st->variants[i].name, name)) return &st->variants[i];
  return NULL;
}

/* ---- VARIANTS ---------------------------------------------------------------- */

static int variants_fields(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_frame f;
  CF_TRY(request(t, fd, HFP_LIST_VARIANTS, &f));
  hfp_variant *v = cf_alloc(t, sizeof *v * HFP_MAX_VARIANTS);
  int n = 0, rc = hfp_decode_variants(f.p, f.h.length, v, HFP_MAX_VARIANTS, &n);
  CF_CHECK(t, rc == 0, "VARIANTS does not decode: %s", hfp_strerror(rc));
  CF_CHECK(t, n >= 1, "VARIANTS lists no variant");
  for (int i = 0; i < n; i++) {
    for (int j = 0; j < i; j++)
      CF_CHECK(t, strcmp(v[i].name, v[j].name), "variant %s is listed twice", v[i].name);
    CF_CHECK(t, v[i].spp <= t->srv->hello.max_spp, "variant %s has %u spp, over HELLO_OK's max_spp %u",
             v[i].name, v[i].spp, t->srv->hello.max_spp);
  }
  /* The same list again, byte for byte. */
  cf_frame g;
  CF_TRY(request(t, fd, HFP_LIST_VARIANTS, &g));
  CF_CHECK(t, g.h.length == f.h.length && !memcmp(g.p, f.p, f.h.length),
           "two LIST_VARIANTS on one connection got different VARIANTS");
  return 0;
}

/* ---- STATS ------------------------------------------------------------------ */

static int stats_fields(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  hfp_stats *a = cf_alloc(t, sizeof *a), *b = cf_alloc(t, sizeof *b);
  CF_TRY(get_stats(t, fd, a));
  CF_CHECK(t, a->num_variants == t->srv->nv, "STATS has %u variants, VARIANTS %d", a->num_variants,
           t->srv->nv);
  for (int i = 0; i < t->srv->nv; i++)
    CF_CHECK(t, find(a, t->srv->variants[i].name), "STATS has no entry for variant %s",
             t->srv->variants[i].name);
  CF_CHECK(t, a->connections_open >= 1, "connections_open is 0 on an open connection");
  CF_CHECK(t, a->connections_total >= a->connections_open,
           "connections_total %llu is below connections_open %u",
           (unsigned long long)a->connections_total, a->connections_open);
  CF_CHECK(t, a->queue_depth <= a->queue_capacity, "queue_depth %u over queue_capacity %u",
           a->queue_depth, a->queue_capacity);
  CF_CHECK(t, a->queue_capacity == t->srv->hello.queue_size,
           "STATS queue_capacity %u, HELLO_OK queue_size %u", a->queue_capacity,
           t->srv->hello.queue_size);
  cf_sleep_ms(2);
  CF_TRY(get_stats(t, fd, b));
  CF_CHECK(t, b->uptime_us > a->uptime_us, "uptime did not advance (%llu then %llu us)",
           (unsigned long long)a->uptime_us, (unsigned long long)b->uptime_us);
  return 0;
}

/* Histograms count the successful requests, each once, in any state of the
 * server; batches move with the case's own requests. The case compares
 * counter changes, never absolute values across counters: `batches` counts
 * runs whose results reached no client (a client that left, as the
 * disconnect cases do), which count in neither requests_ok nor
 * requests_failed, so a server that has been used may well have more
 * batches than answered requests. */
enum { HIST_FRAMES = 3, HIST_WINDOWS = 3 };

static int stats_histograms(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  hfp_stats *a = cf_alloc(t, sizeof *a), *b = cf_alloc(t, sizeof *b);
  CF_TRY(get_stats(t, fd, a));
  for (int i = 0; i < a->num_variants; i++) {
    const hfp_variant_stats *v = &a->variants[i];
    uint64_t ht = 0, hi = 0;
    for (int k = 0; k < HFP_HIST_BUCKETS; k++) ht += v->hist_total[k], hi += v->hist_infer[k];
    CF_CHECK(t, ht == v->requests_ok && hi == v->requests_ok,
             "variant %s: %llu ok requests, but hist_total counts %llu and hist_infer %llu", v->name,
             (unsigned long long)v->requests_ok, (unsigned long long)ht, (unsigned long long)hi);
    CF_CHECK(t, v->sum_total_us >= v->sum_infer_us && v->sum_total_us >= v->sum_queue_us,
             "variant %s: sum_total_us %llu below sum_infer_us %llu or sum_queue_us %llu", v->name,
             (unsigned long long)v->sum_total_us, (unsigned long long)v->sum_infer_us,
             (unsigned long long)v->sum_queue_us);
  }
  /* HIST_FRAMES ordinary frames, each sent once the previous RESULT came:
   * each ran in a run of its own, so batches grows by at least as many. It
   * grows by at most the requests answered meanwhile, unless some other
   * client's run lost its client in the window (or was counted before its
   * RESULT was): a window where it grows by more is measured again, and
   * only HIST_WINDOWS such windows in a row fail. */
  cf_filter f = {.id = 32};
  cf_filter_defaults(t, &f);
  uint64_t db = 0, dr = 0;
  for (int w = 0; w < HIST_WINDOWS; w++) {
    CF_TRY(get_stats(t, fd, a));
    for (int k = 0; k < HIST_FRAMES; k++) {
      f.id = 32 + (uint32_t)k;
      CF_TRY(cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL));
    }
    CF_TRY(get_stats(t, fd, b));
    const hfp_variant_stats *va = find(a, f.variant), *vb = find(b, f.variant);
    CF_CHECK(t, va && vb, "STATS has no entry for %s", f.variant);
    CF_CHECK(t, vb->batches >= va->batches && vb->requests_ok >= va->requests_ok &&
                    vb->requests_failed >= va->requests_failed,
             "variant %s: counters went back (batches %llu then %llu, requests_ok %llu then %llu)",
             f.variant, (unsigned long long)va->batches, (unsigned long long)vb->batches,
             (unsigned long long)va->requests_ok, (unsigned long long)vb->requests_ok);
    db = vb->batches - va->batches;
    dr = (vb->requests_ok + vb->requests_failed) - (va->requests_ok + va->requests_failed);
    CF_CHECK(t, vb->requests_ok - va->requests_ok >= HIST_FRAMES,
             "variant %s: requests_ok grew by %llu over %d RESULTs", f.variant,
             (unsigned long long)(vb->requests_ok - va->requests_ok), HIST_FRAMES);
    CF_CHECK(t, db >= HIST_FRAMES,
             "variant %s: batches grew by %llu over %d frames each sent after the previous "
             "RESULT (each needs a run of its own)", f.variant, (unsigned long long)db, HIST_FRAMES);
    if (db <= dr) return 0;
  }
  return cf_fail(t, "variant %s: in %d windows of %d frames each, batches grew by more than the "
                 "requests answered (last: %llu batches, %llu requests)", f.variant, HIST_WINDOWS,
                 HIST_FRAMES, (unsigned long long)db, (unsigned long long)dr);
}

/* What stats_move does: a RESULT; an ERROR to a FILTER for the variant
 * found against the server (spp), or in the frame's own fields (a NaN
 * colour, an unknown dtype, a tensor a byte short); a bad header. */
enum { MOVE_OK, MOVE_REJECTED, MOVE_REJECTED_COLOUR, MOVE_REJECTED_DTYPE, MOVE_REJECTED_LENGTH,
       MOVE_PROTOCOL };

/* The counters move with what we did (others may add to them too). */
static int stats_move(cf_test *t, intptr_t what) {
  int fd, other;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  hfp_stats *a = cf_alloc(t, sizeof *a), *b = cf_alloc(t, sizeof *b);
  CF_TRY(get_stats(t, fd, a));
  cf_filter f = {.id = 31};
  cf_filter_defaults(t, &f);
  if (what == MOVE_OK) {
    CF_TRY(cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL));
  } else if (what != MOVE_PROTOCOL) {
    cf_filter g = f;
    if (what == MOVE_REJECTED) g.spp++;   /* not the variant's */
    size_t n;
    uint8_t *fb = cf_filter_frame(t, &g, &n);
    CF_CHECK(t, fb, "out of memory");
    int code = HFP_E_INVALID;
    float nan = NAN;
    if (what == MOVE_REJECTED_COLOUR) {
      memcpy(fb + CF_FILTER_HAIR, &nan, 4);
    } else if (what == MOVE_REJECTED_DTYPE) {
      fb[CF_FILTER_IN_DTYPE] = 255;
      code = HFP_E_UNSUPPORTED;
    } else if (what == MOVE_REJECTED_LENGTH) {
      n--;
      cf_set_length(fb, (uint32_t)(n - HFP_HEADER_SIZE));
      code = HFP_E_LENGTH;
    }
    CF_TRY(cf_send(t, fd, fb, n));
    CF_TRY(cf_expect_error(t, fd, code, 0, 31));
  } else {
    CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &other, NULL));
    uint8_t hb[HFP_HEADER_SIZE];
    cf_header(hb, HFP_STATS, 0, 0, 0);
    hb[0] ^= 1;
    CF_TRY(cf_send(t, other, hb, sizeof hb));
    CF_TRY(cf_expect_error(t, other, HFP_E_PROTOCOL, 1, 0));
  }
  CF_TRY(get_stats(t, fd, b));
  const hfp_variant_stats *va = find(a, f.variant), *vb = find(b, f.variant);
  CF_CHECK(t, va && vb, "STATS has no entry for %s", f.variant);
  if (what == MOVE_OK) {
    CF_CHECK(t, vb->requests_ok > va->requests_ok, "requests_ok of %s stayed %llu after a RESULT",
             f.variant, (unsigned long long)vb->requests_ok);
  } else if (what != MOVE_PROTOCOL) {
    CF_CHECK(t, vb->rejected > va->rejected,
             "rejected of %s stayed %llu after an ERROR to a FILTER for it", f.variant,
             (unsigned long long)vb->rejected);
  } else {
    CF_CHECK(t, b->protocol_errors > a->protocol_errors,
             "protocol_errors stayed %llu after a bad header", (unsigned long long)b->protocol_errors);
  }
  return 0;
}

/* ---- order of control replies --------------------------------------------------- */

static int control_order(cf_test *t, intptr_t with_filters) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  static const int seq[] = {HFP_LIST_VARIANTS, HFP_STATS, HFP_STATS, HFP_LIST_VARIANTS,
                            HFP_STATS, HFP_LIST_VARIANTS};
  enum { N = sizeof seq / sizeof seq[0] };
  cf_filter f = {.id = 50};
  cf_filter_defaults(t, &f);
  size_t fn;
  uint8_t *fb = cf_filter_frame(t, &f, &fn);
  CF_CHECK(t, fb, "out of memory");
  int filters = 0;
  for (int i = 0; i < N; i++) {
    uint8_t b[HFP_HEADER_SIZE];
    cf_header(b, seq[i], 0, 0, 0);
    CF_TRY(cf_send(t, fd, b, sizeof b));
    if (with_filters && filters < t->srv->hello.max_inflight) {
      hfp_put_u32(fb + 8, 50 + (uint32_t)i);
      CF_TRY(cf_send(t, fd, fb, fn));
      filters++;
    }
  }
  int next = 0, results = 0;
  while (next < N || results < filters) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of %d control replies and %d of %d RESULTs came", next, N,
             results, filters);
    if (r.h.type == HFP_RESULT || r.h.type == HFP_ERROR) {
      char d[400];
      CF_CHECK(t, r.h.request_id >= 50 && r.h.request_id < 50 + N, "unexpected %s",
               cf_describe(&r, d, sizeof d));
      int busy = cf_busy(t, &r, NULL);
      if (busy < 0) return busy;
      results++;
      continue;
    }
    char tn[16];
    CF_CHECK(t, next < N, "a control reply (%s) after all %d were answered",
             cf_type_name(r.h.type, tn), N);
    int want = seq[next] == HFP_STATS ? HFP_STATS_REPLY : HFP_VARIANTS;
    CF_CHECK(t, r.h.type == want, "control reply %d is %s, wanted %s (replies keep the order "
             "of their requests)", next, cf_type_name(r.h.type, tn), want == HFP_VARIANTS ? "VARIANTS" : "STATS_REPLY");
    next++;
  }
  return 0;
}

/* Requests sent without reading replies are all answered once the client
 * reads; a server may pause reading meanwhile, never drop. */
static int read_later(cf_test *t, intptr_t n) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t *b = cf_alloc(t, HFP_HEADER_SIZE * (size_t)n);
  CF_CHECK(t, b, "out of memory");
  for (int i = 0; i < n; i++) cf_header(b + HFP_HEADER_SIZE * (size_t)i, HFP_LIST_VARIANTS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE * (size_t)n));
  for (int i = 0; i < n; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT && r.h.type == HFP_VARIANTS, "reply %d of %d: %s", i, (int)n,
             rc == CF_GOT ? "not VARIANTS" : rc == CF_EOF ? "closed" : "nothing");
  }
  return 0;
}

const cf_case cf_cases_control[] = {
  {"variants.fields", "VARIANTS: 1..64 distinct entries within max_spp, the same on every request", 0, variants_fields, 0},
  {"stats.fields", "STATS_REPLY: an entry per variant, open connections, queue within capacity, uptime advancing", 0, stats_fields, 0},
  {"stats.histograms", "hist_total and hist_infer each count every successful request once; sums agree; batches grow with runs, by no more than the requests answered", 0, stats_histograms, 0},
  {"stats.counts_ok", "requests_ok grows with each RESULT", 0, stats_move, MOVE_OK},
  {"stats.counts_rejected", "rejected grows with each ERROR to a FILTER for the variant", 0, stats_move, MOVE_REJECTED},
  {"stats.counts_rejected_colour", "rejected grows with an ERROR to a FILTER for the variant with a NaN colour", 0, stats_move, MOVE_REJECTED_COLOUR},
  {"stats.counts_rejected_dtype", "rejected grows with an ERROR to a FILTER for the variant with an unknown dtype", 0, stats_move, MOVE_REJECTED_DTYPE},
  {"stats.counts_rejected_length", "rejected grows with an ERROR to a FILTER for the variant a byte short", 0, stats_move, MOVE_REJECTED_LENGTH},
  {"stats.counts_protocol_errors", "protocol_errors grows with each error not tied to a variant", 0, stats_move, MOVE_PROTOCOL},
  {"transport.control_order", "replies to LIST_VARIANTS and STATS keep the order of the requests", 0, control_order, 0},
  {"transport.control_order_with_filters", "control replies keep their order among RESULTs in any order", 0, control_order, 1},
  {"transport.read_later", "requests sent without reading are all answered once the client reads", 0, read_later, 300},
  {NULL, NULL, 0, NULL, 0},
};
