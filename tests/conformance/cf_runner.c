/*
 * The runner: probes the server (versions, token, limits, variants, the
 * result of one ordinary frame), runs each case in a fresh context, checks
 * after each that an ordinary client is still served with the same result,
 * and prints the verdicts and the summary.
 */
#define _POSIX_C_SOURCE 200809L
#include <fnmatch.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "cf_internal.h"
#include <hairfilter/hairfilter.h>

static const cf_case *const server_tables[] = {cf_cases_handshake, cf_cases_frame,
                                               cf_cases_filter,    cf_cases_control,
                                               cf_cases_shm,       cf_cases_flow};

static void release(cf_test *t) {
  for (int i = 0; i < t->nfds; i++) close(t->fds[i]);
  for (int i = 0; i < t->nallocs; i++) free(t->allocs[i]);
  free(t->allocs);
  t->allocs = NULL;
  t->cap_allocs = 0;
  for (int i = 0; i < t->nmaps; i++) munmap(t->maps[i].p, t->maps[i].n);
  t->nfds = t->nallocs = t->nmaps = 0;
}

static cf_options defaults(const cf_options *o) {
  cf_options d = *o;
  if (d.timeout_ms <= 0) d.timeout_ms = 10000;
  if (d.quiet_ms <= 0) d.quiet_ms = 300;
  if (d.stall_ms <= 0) d.stall_ms = 1500;
  if (!d.out) d.out = stdout;
  return d;
}

/* ---- the probe -------------------------------------------------------------- */

static int hello_at(cf_test *t, int lo, int hi, const char *token, hfp_hello_ok *ok,
                    hfp_error *err) {
  int fd;
  memset(err, 0, sizeof *err);
  if (cf_connect(t, &fd)) return -1;
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, lo, hi, "conformance-probe", token);
  cf_frame f;
  if (cf_send(t, fd, b, n) || cf_read(t, fd, t->o->timeout_ms, &f) != CF_GOT) {
    cf_close(t, fd);
    if (!t->why[0]) cf_fail(t, "no reply to HELLO");
    return -1;
  }
  int rc = -1;
  if (f.h.type == HFP_HELLO_OK && hfp_decode_hello_ok(f.p, f.h.length, ok) == 0)
    rc = 0;
  else if (f.h.type == HFP_ERROR && hfp_decode_error(f.p, f.h.length, err) == 0)
    rc = 1;
  else {
    char tn[16];
    cf_fail(t, "the reply to HELLO is neither HELLO_OK nor ERROR that decodes (%s, %u bytes)",
            cf_type_name(f.h.type, tn), f.h.length);
  }
  cf_close(t, fd);
  return rc;
}

static int probe(const cf_options *o, cf_server *s, char *why, size_t whylen) {
  memset(s, 0, sizeof *s);
  cf_test t;
  memset(&t, 0, sizeof t);
  t.o = o;
  t.srv = s;
  hfp_url u;
  if (hfp_url_parse(o->server, 0, &u, why, whylen)) return -1;
  s->is_unix = u.kind == HFP_URL_UNIX;
  hfp_error e;
  int rc = hello_at(&t, 1, HFP_VERSION, o->token, &s->hello, &e);
  if (rc < 0) {
    snprintf(why, whylen, "%.500s", t.why);
    release(&t);
    return -1;
  }
  if (rc == 1) {
    snprintf(why, whylen, "HELLO offering versions 1..%d was refused: %s: %s%s", HFP_VERSION,
             hfp_code_name((int)e.code), e.message,
             e.code == HFP_E_UNAUTHORIZED ? " (give the listener's token with --token)" : "");
    release(&t);
    return -1;
  }
  s->version = s->hello.version;
  /* Does the listener check tokens? A HELLO without one tells. */
  if (!s->is_unix) {
    hfp_hello_ok ok;
    s->auth = hello_at(&t, 1, HFP_VERSION, NULL, &ok, &e) == 1 && e.code == HFP_E_UNAUTHORIZED;
  }
  for (int k = 1; k <= HFP_VERSION + 1; k++) {
    hfp_hello_ok ok;
    s->speaks[k] = hello_at(&t, k, k, o->token, &ok, &e) == 0 && ok.version == k;
  }
  int fd;
  hfp_hello_ok ok;
  cf_frame f;
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, HFP_LIST_VARIANTS, 0, 0, 0);
  if (cf_connect_hello(&t, 1, HFP_VERSION, &fd, &ok) || cf_send(&t, fd, b, sizeof b) ||
      cf_expect(&t, fd, HFP_VARIANTS, &f) ||
      hfp_decode_variants(f.p, f.h.length, s->variants, HFP_MAX_VARIANTS, &s->nv)) {
    snprintf(why, whylen, "cannot list the variants: %.500s", t.why[0] ? t.why : "VARIANTS does not decode");
    release(&t);
    return -1;
  }
  release(&t);
  if (s->nv == 0) {
    snprintf(why, whylen, "the server has no variant: there is nothing to filter");
    return -1;
  }
  /* Ordinary frames go to the cheapest variant: fewest spp, then fewest
   * channels. */
  for (int i = 1; i < s->nv; i++) {
    const hfp_variant *a = &s->variants[i], *b0 = &s->variants[s->probe];
    uint64_t ca = 0, cb = 0;
    for (int l = 0; l < a->num_levels; l++) ca += a->levels[l];
    for (int l = 0; l < b0->num_levels; l++) cb += b0->levels[l];
    if (a->spp < b0->spp || (a->spp == b0->spp && ca < cb)) s->probe = i;
  }
  s->pw = s->hello.max_width < 8 ? (int)s->hello.max_width : 8;
  s->ph = s->hello.max_height < 8 ? (int)s->hello.max_height : 8;
  /* The reference result of the ordinary frame: what the health check must
   * get again after every case. */
  s->reference_len = (size_t)s->pw * s->ph * 3 * sizeof(float);
  s->reference = malloc(s->reference_len);
  hfc_client *c = NULL;
  hfc_options co = cf_client_options("conformance-probe", o->token, o->timeout_ms);
  co.tls_ca_file = o->tls_ca;
  co.tls_cert_file = o->tls_cert;
  co.tls_key_file = o->tls_key;
  co.tls_server_name = o->tls_server_name;
  rc = hfc_connect(o->server, &co, &c);
  if (!rc) {
    cf_filter pf = {0};
    memset(&t, 0, sizeof t);
    t.o = o;
    t.srv = s;
    cf_filter_defaults(&t, &pf);
    void *in = malloc((size_t)cf_features_bytes(&pf));
    if (in && s->reference) {
      cf_fill_features(&pf, in);
      hfc_request r = cf_client_request(&pf, in, s->reference, s->reference_len);
      rc = hfc_filter(c, &r, NULL);
    } else {
      rc = HFC_E_NOMEM;
    }
    free(in);
    if (rc) {
      /* Say what was wrong with the reply: the same frame over a raw
       * connection, its RESULT checked field by field. */
      char lib[300];
      snprintf(lib, sizeof lib, "%s (%s)", hfc_strerror(rc), hfc_last_message(c));
      int fd;
      pf.id = 1;
      t.why[0] = 0;
      if (cf_connect_hello(&t, 1, HFP_VERSION, &fd, NULL) == 0)
        cf_filter_ok(&t, fd, &pf, s->version, NULL, NULL);
      snprintf(why, whylen,
               "the probe's ordinary frame (variant %s, %dx%d, f32), which every case's health "
               "check needs, failed through libhairfilter: %.200s%s%.200s", pf.variant, s->pw,
               s->ph, lib, t.why[0] ? "; sent again directly: " : "", t.why);
      release(&t);
    }
    hfc_close(c);
  } else {
    snprintf(why, whylen, "libhairfilter cannot connect: %s", hfc_strerror(rc));
  }
  if (rc) {
    free(s->reference);
    s->reference = NULL;
    return -1;
  }
  return 0;
}

/* ---- running ---------------------------------------------------------------- */

static const char *unmet(const cf_server *s, unsigned needs) {
  if ((needs & CF_NEED_UNIX) && !s->is_unix) return "needs a Unix socket";
  if ((needs & CF_NEED_TCP) && s->is_unix) return "needs a TCP listener";
  if ((needs & CF_NEED_SHM) && !(s->hello.server_flags & HFP_SERVER_SHM))
    return "the connection offers no shared memory";
  if ((needs & CF_NEED_NO_SHM) && (s->hello.server_flags & HFP_SERVER_SHM))
    return "the connection offers shared memory";
  if ((needs & CF_NEED_AUTH) && !s->auth) return "the listener checks no token";
  if ((needs & CF_NEED_V2) && !s->speaks[2]) return "the server does not speak version 2";
  return NULL;
}

static void verdict(const cf_options *o, cf_summary *sum, cf_report *rep, const char *name,
                    int rc, const char *why, double ms) {
  sum->cases++;
  cf_report_add(rep, name, rc, why, ms);
  const char *word = rc == CF_PASS ? "PASS" : rc == CF_SKIP ? "SKIP" : "FAIL";
  if (rc == CF_PASS) sum->passed++;
  else if (rc == CF_SKIP) sum->skipped++;
  else sum->failed++;
  if (rc != CF_PASS || o->verbose) {
    if (why && why[0])
      fprintf(o->out, "%s %s: %s", word, name, why);
    else
      fprintf(o->out, "%s %s", word, name);
    if (o->verbose) fprintf(o->out, " (%.0f ms)", ms);
    fputc('\n', o->out);
    fflush(o->out);
  }
}

/* The summary line, the report written: 0, 1 or 2 as cf_run_server says. */
static int summary(const cf_options *o, const cf_summary *sum, cf_report *rep, const char *what) {
  fprintf(o->out, "conformance: %d cases, %d passed, %d failed, %d skipped (%s)\n", sum->cases,
          sum->passed, sum->failed, sum->skipped, what);
  fflush(o->out);
  if (cf_report_close(rep, sum, NULL, o->out)) return 2;
  return sum->failed ? 1 : 0;
}

/* How many cases of the tables match the pattern; with none, says so (a
 * mistyped filter must not pass as an empty run). */
static int matching(const cf_options *o, const cf_case *const *tables, size_t nt, int client) {
  int n = 0;
  for (size_t k = 0; k < nt; k++)
    for (const cf_case *c = tables[k]; c->name; c++)
      n += !o->pattern || !fnmatch(o->pattern, c->name, 0);
  if (!n)
    fprintf(o->out, "conformance: no case matches '%s' (hairfilter conformance --list%s names "
            "them)\n", o->pattern, client ? " --client" : "");
  return n;
}

/* Gives up before any case ran: the reason in the report too. */
static int give_up(const cf_options *o, const cf_summary *sum, cf_report *rep, const char *why) {
  cf_report_close(rep, sum, why, o->out);
  return 2;
}

int cf_run_server(const cf_options *opt, cf_summary *sum) {
  cf_options o = defaults(opt);
  memset(sum, 0, sizeof *sum);
  signal(SIGPIPE, SIG_IGN);
  cf_server s;
  char why[1024], suite[400];
  snprintf(suite, sizeof suite, "conformance %.380s", o.server ? o.server : "(no server)");
  cf_report rep;
  if (cf_report_open(&rep, o.junit, suite, o.out)) return 2;
  if (!matching(&o, server_tables, sizeof server_tables / sizeof server_tables[0], 0)) {
    snprintf(why, sizeof why, "no case matches '%.900s'", o.pattern);
    return give_up(&o, sum, &rep, why);
  }
  if (!o.server || probe(&o, &s, why, sizeof why)) {
    char line[1200];
    snprintf(line, sizeof line, "cannot probe %s: %s", o.server ? o.server : "(no server)",
             o.server ? why : "give --server URL");
    fprintf(o.out, "conformance: %s\n", line);
    return give_up(&o, sum, &rep, line);
  }
  /* The older versions the server also speaks, as probed. */
  char older[40] = "";
  for (int v = 1; v <= 3; v++)
    if (s.speaks[v])
      snprintf(older + strlen(older), sizeof older - strlen(older), "%s%d", older[0] ? ", " : "", v);
  fprintf(o.out, "conformance: %s: %s, protocol version %d (older ones it also speaks: %s), %s%s, "
                 "%d variant(s), limits %ux%u, %u in flight\n",
          o.server, s.hello.server_name, s.version, older[0] ? older : "none",
          s.auth ? "token checked" : "no token",
          (s.hello.server_flags & HFP_SERVER_SHM) ? ", shared memory" : "", s.nv,
          s.hello.max_width, s.hello.max_height, s.hello.max_inflight);
  fflush(o.out);
  for (size_t k = 0; k < sizeof server_tables / sizeof server_tables[0]; k++)
    for (const cf_case *c = server_tables[k]; c->name; c++) {
      if (o.pattern && fnmatch(o.pattern, c->name, 0)) continue;
      cf_test t;
      memset(&t, 0, sizeof t);
      t.o = &o;
      t.srv = &s;
      t.c = c;
      double t0 = cf_now_ms();
      const char *no = unmet(&s, c->needs);
      int rc = no ? cf_skip(&t, "%s", no) : c->run(&t, c->arg);
      release(&t);
      if (rc == CF_PASS) {
        /* Whatever the case did, an ordinary client is still served. */
        if (cf_health(&t)) {
          char w[sizeof t.why];
          memcpy(w, t.why, sizeof w);
          snprintf(t.why, sizeof t.why, "afterwards, %.700s", w);
          rc = CF_FAIL;
        }
        release(&t);
      }
      verdict(&o, sum, &rep, c->name, rc, t.why, cf_now_ms() - t0);
    }
  free(s.reference);
  return summary(&o, sum, &rep, o.server);
}

int cf_run_client(const cf_options *opt, cf_summary *sum) {
  cf_options o = defaults(opt);
  memset(sum, 0, sizeof *sum);
  signal(SIGPIPE, SIG_IGN);
  static const char what[] = "libhairfilter against the mock server";
  static const cf_case *const tables[] = {cf_cases_client};
  cf_report rep;
  if (cf_report_open(&rep, o.junit, "conformance --client", o.out)) return 2;
  int n = matching(&o, tables, 1, 1);
  if (!n) {
    char why[1024];
    snprintf(why, sizeof why, "no case matches '%.900s'", o.pattern);
    return give_up(&o, sum, &rep, why);
  }
  /* The header line, as for a server. */
  fprintf(o.out, "conformance: %s, %d case(s)\n", what, n);
  fflush(o.out);
  for (const cf_case *c = cf_cases_client; c->name; c++) {
    if (o.pattern && fnmatch(o.pattern, c->name, 0)) continue;
    cf_test t;
    memset(&t, 0, sizeof t);
    t.o = &o;
    t.c = c;
    double t0 = cf_now_ms();
    int rc = c->run(&t, c->arg);
    release(&t);
    verdict(&o, sum, &rep, c->name, rc, t.why, cf_now_ms() - t0);
  }
  return summary(&o, sum, &rep, what);
}

void cf_list(FILE *out, int client_suite) {
  if (client_suite) {
    for (const cf_case *c = cf_cases_client; c->name; c++) fprintf(out, "%s\t%s\n", c->name, c->rule);
    return;
  }
  for (size_t k = 0; k < sizeof server_tables / sizeof server_tables[0]; k++)
    for (const cf_case *c = server_tables[k]; c->name; c++)
      fprintf(out, "%s\t%s\n", c->name, c->rule);
}

/* ---- PROTOCOL.md and the cases ----------------------------------------------- */

typedef struct doc_name {
  char name[96];
  int family;         /* "prefix.*" */
  int used;
} doc_name;

static int matches(const doc_name *d, const char *name) {
  if (!d->family) return !strcmp(d->name, name);
  size_t n = strlen(d->name);
  return !strncmp(d->name, name, n);
}

static void check_table(const cf_case *c, doc_name *names, int nn, FILE *out, int *problems) {
  for (; c->name; c++) {
    int found = 0;
    for (int i = 0; i < nn; i++)
      if (matches(&names[i], c->name)) {
        names[i].used = 1;
        found = 1;
      }
    if (!found) {
      fprintf(out, "not named in the document: %s (%s)\n", c->name, c->rule);
      (*problems)++;
    }
  }
}

int cf_check_doc(const char *path, FILE *out) {
  FILE *f = fopen(path, "r");
  if (!f) {
    fprintf(out, "cannot read %s\n", path);
    return -1;
  }
  doc_name *names = calloc(1024, sizeof *names);
  int nn = 0, in_cases = 0;
  char line[4096];
  while (names && fgets(line, sizeof line, f)) {
    /* A paragraph that begins "*Cases:*" runs to the next blank line. */
    if (!strncmp(line, "*Cases:*", 8)) in_cases = 1;
    if (line[0] == '\n') in_cases = 0;
    if (!in_cases) continue;
    for (char *p = strchr(line, '`'); p && nn < 1024; p = strchr(p + 1, '`')) {
      char *e = strchr(p + 1, '`');
      if (!e) break;
      size_t n = (size_t)(e - p - 1);
      if (n > 0 && n < sizeof names[nn].name) {
        memcpy(names[nn].name, p + 1, n);
        names[nn].name[n] = 0;
        if (n > 2 && !strcmp(names[nn].name + n - 2, ".*")) {
          names[nn].family = 1;
          names[nn].name[n - 1] = 0;   /* keep the dot: "frame.bad_type." */
        }
        nn++;
      }
      p = e;
    }
  }
  fclose(f);
  if (!names) return -1;
  int problems = 0;
  for (size_t k = 0; k < sizeof server_tables / sizeof server_tables[0]; k++)
    check_table(server_tables[k], names, nn, out, &problems);
  check_table(cf_cases_client, names, nn, out, &problems);
  for (int i = 0; i < nn; i++)
    if (!names[i].used) {
      fprintf(out, "named in the document but no such case: %s%s\n", names[i].name,
              names[i].family ? "*" : "");
      problems++;
    }
  fprintf(out, "%s: %d case name(s) in the document, %d problem(s)\n", path, nn, problems);
  free(names);
  return problems;
}
