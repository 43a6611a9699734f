/*
 * The verdicts as JUnit XML, the report CI systems read (Jenkins, GitLab,
 * GitHub Actions' test reporters): a <testsuite> with one <testcase> per
 * case, failures and skips with their reasons.
 *
 * Written by hand rather than with libxml2's xmlTextWriter: the document is
 * a fixed shape of a few elements, and the one thing that needs care is the
 * text, which can hold whatever a server sent (an ERROR's message, a
 * variant's name): bytes that are not UTF-8 and control characters that XML
 * 1.0 forbids even as character references, which a writer escaping only
 * markup would pass on into a file no parser accepts. cf_xml_text keeps
 * valid UTF-8 and the characters XML allows, escapes the markup, and writes
 * every other byte as the text \xNN; the command needs no further library.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "cf_internal.h"

/* The length of the valid UTF-8 sequence at s holding a character XML 1.0
 * allows (#x9 | #xA | #xD | [#x20-#xD7FF] | [#xE000-#xFFFD] |
 * [#x10000-#x10FFFF]), or 0. */
static int xml_char(const unsigned char *s) {
  unsigned c = s[0];
  if (c < 0x80) return c >= 0x20 || c == 0x9 || c == 0xA || c == 0xD ? 1 : 0;
  int n = c >= 0xF0 ? 4 : c >= 0xE0 ? 3 : c >= 0xC0 ? 2 : 0;
  if (!n || c > 0xF4) return 0;
  unsigned long cp = c & (0x3Fu >> (n - 1));
  for (int i = 1; i < n; i++) {
    if ((s[i] & 0xC0) != 0x80) return 0;   /* also stops at the terminating 0 */
    cp = cp << 6 | (s[i] & 0x3Fu);
  }
  static const unsigned long least[] = {0, 0, 0x80, 0x800, 0x10000};
  if (cp < least[n] || cp > 0x10FFFF) return 0;                 /* overlong, too large */
  if ((cp >= 0xD800 && cp <= 0xDFFF) || cp == 0xFFFE || cp == 0xFFFF) return 0;
  return n;
}

void cf_xml_text(FILE *f, const char *text) {
  const unsigned char *s = (const unsigned char *)(text ? text : "");
  while (*s) {
    int n = xml_char(s);
    if (!n) {
      fprintf(f, "\\x%02X", *s++);
      continue;
    }
    switch (*s) {
      case '&': fputs("&amp;", f); break;
      case '<': fputs("&lt;", f); break;
      case '>': fputs("&gt;", f); break;
      case '"': fputs("&quot;", f); break;
      case '\'': fputs("&apos;", f); break;
      /* Kept as they are in attribute values, which would otherwise turn
       * them into spaces. */
      case '\t': fputs("&#9;", f); break;
      case '\n': fputs("&#10;", f); break;
      case '\r': fputs("&#13;", f); break;
      default: fwrite(s, 1, (size_t)n, f);
    }
    s += n;
  }
}

int cf_report_open(cf_report *r, const char *path, const char *suite, FILE *out) {
  memset(r, 0, sizeof *r);
  r->suite = suite;
  r->t0 = cf_now_ms();
  time_t now = time(NULL);
  struct tm tm;
  if (gmtime_r(&now, &tm)) strftime(r->stamp, sizeof r->stamp, "%Y-%m-%dT%H:%M:%S", &tm);
  if (!path) return 0;
  r->path = path;
  r->f = fopen(path, "w");
  if (!r->f) {
    fprintf(out, "conformance: cannot write the JUnit report %s: %s\n", path, strerror(errno));
    return -1;
  }
  return 0;
}

void cf_report_add(cf_report *r, const char *name, int rc, const char *why, double ms) {
  if (!r->f) return;
  if (r->n == r->cap) {
    int cap = r->cap ? 2 * r->cap : 64;
    cf_record *n = realloc(r->rec, sizeof *n * (size_t)cap);
    if (!n) return;   /* the summary's counts still say it; the file is then short */
    r->rec = n;
    r->cap = cap;
  }
  cf_record *c = &r->rec[r->n++];
  c->name = name;
  c->rc = rc;
  c->why = strdup(why ? why : "");
  c->ms = ms;
}

static void attr(FILE *f, const char *name, const char *value) {
  fprintf(f, " %s=\"", name);
  cf_xml_text(f, value);
  fputc('"', f);
}

int cf_report_close(cf_report *r, const cf_summary *s, const char *error, FILE *out) {
  if (!r->f) return 0;
  FILE *f = r->f;
  double secs = (cf_now_ms() - r->t0) / 1e3;
  int tests = error ? 1 : s->cases, failures = error ? 0 : s->failed;
  int skipped = error ? 0 : s->skipped, errors = error ? 1 : 0;
  fputs("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<testsuites", f);
  attr(f, "name", "hairfilter conformance");
  fprintf(f, " tests=\"%d\" failures=\"%d\" errors=\"%d\" skipped=\"%d\" time=\"%.3f\">\n", tests,
          failures, errors, skipped, secs);
  fputs("  <testsuite", f);
  attr(f, "name", r->suite);
  fprintf(f, " tests=\"%d\" failures=\"%d\" errors=\"%d\" skipped=\"%d\" time=\"%.3f\"", tests,
          failures, errors, skipped, secs);
  if (r->stamp[0]) attr(f, "timestamp", r->stamp);
  fputs(">\n", f);
  if (error) {
    fputs("    <testcase classname=\"conformance\" name=\"conformance\" time=\"0\">\n"
          "      <error", f);
    attr(f, "message", error);
    fputs("/>\n    </testcase>\n", f);
  }
  for (int i = 0; !error && i < r->n; i++) {
    const cf_record *c = &r->rec[i];
    /* classname: the case's name up to its last dot ("stats" of
     * "stats.histograms", "client.hello_ok" of "client.hello_ok.version_zero"),
     * so reports group the cases by rule. */
    char cls[64];
    const char *dot = strrchr(c->name, '.');
    size_t n = dot ? (size_t)(dot - c->name) : strlen(c->name);
    snprintf(cls, sizeof cls, "conformance.%.*s", (int)(n < 40 ? n : 40), c->name);
    fputs("    <testcase", f);
    attr(f, "classname", cls);
    attr(f, "name", c->name);
    fprintf(f, " time=\"%.3f\"", c->ms / 1e3);
    if (c->rc == CF_PASS) {
      fputs("/>\n", f);
      continue;
    }
    fputs(">\n      <", f);
    fputs(c->rc == CF_SKIP ? "skipped" : "failure", f);
    attr(f, "message", c->why && c->why[0] ? c->why : c->rc == CF_SKIP ? "skipped" : "failed");
    fputs("/>\n    </testcase>\n", f);
  }
  fputs("  </testsuite>\n</testsuites>\n", f);
  int bad = ferror(f);
  if (fclose(f)) bad = 1;
  r->f = NULL;
  for (int i = 0; i < r->n; i++) free(r->rec[i].why);
  free(r->rec);
  r->rec = NULL;
  if (bad) {
    fprintf(out, "conformance: writing the JUnit report %s failed\n", r->path);
    return -1;
  }
  return 0;
}
