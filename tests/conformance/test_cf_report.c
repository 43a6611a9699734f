/* The conformance command's reporting, not the cases: a --case pattern that
 * matches nothing exits 2, plain-number durations under 100 ms are refused,
 * --junit writes one testcase per case run (and an error when the suite
 * cannot run), its text escaped for XML whatever bytes a reason holds, and
 * a malformed RESULT's reason gives the byte counts.
 *
 *   test_cf_report   (HAIRFILTER_CLI_PATH names the CLI) */
#define _POSIX_C_SOURCE 200809L
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "cf_internal.h"

#ifndef HAIRFILTER_CLI_PATH
#error "HAIRFILTER_CLI_PATH must name the hairfilter CLI"
#endif

static int failures;
#define EXPECT(cond, ...)                                  \
  do {                                                     \
    if (!(cond)) {                                         \
      fprintf(stderr, "%s:%d: ", __FILE__, __LINE__);      \
      fprintf(stderr, __VA_ARGS__);                        \
      fputc('\n', stderr);                                 \
      failures++;                                          \
    }                                                      \
  } while (0)

static char dir[] = "/tmp/cfreportXXXXXX";

/* Reads a whole file (malloc'd, NUL-terminated); "" when it cannot. */
static char *slurp(const char *path) {
  FILE *f = fopen(path, "r");
  char *b = calloc(1, 1 << 20);
  if (f && b) {
    size_t n = fread(b, 1, (1 << 20) - 1, f);
    b[n] = 0;
  }
  if (f) fclose(f);
  return b;
}

static int count(const char *s, const char *what) {
  int n = 0;
  for (const char *p = strstr(s, what); p; p = strstr(p + 1, what)) n++;
  return n;
}

/* Runs `hairfilter conformance ARGS...`: its exit status, stdout and stderr
 * (malloc'd). */
static int cli(char **out, char **err, ...) {
  char *args[32] = {"hairfilter", "conformance"};
  int na = 2;
  va_list ap;
  va_start(ap, err);
  for (char *a; na < 31 && (a = va_arg(ap, char *));) args[na++] = a;
  va_end(ap);
  args[na] = NULL;
  char op[256], ep[256];
  snprintf(op, sizeof op, "%s/out", dir);
  snprintf(ep, sizeof ep, "%s/err", dir);
  pid_t pid = fork();
  if (pid == 0) {
    if (!freopen(op, "w", stdout) || !freopen(ep, "w", stderr)) _exit(126);
    execv(HAIRFILTER_CLI_PATH, args);
    _exit(127);
  }
  int st = 0;
  waitpid(pid, &st, 0);
  *out = slurp(op);
  *err = slurp(ep);
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128;
}

static void test_xml_text(void) {
  char *buf = NULL;
  size_t n = 0;
  FILE *f = open_memstream(&buf, &n);
  /* markup, quotes, tab/newline, a control character, a lone continuation
   * byte, an overlong '/', a surrogate, U+FFFE, valid two- and four-byte
   * characters */
  cf_xml_text(f, "a<b>&\"c'\td\ne\x01" "f\x80g\xC0\xAFh\xED\xA0\x80i\xEF\xBF\xBEj\xC3\xA9\xF0\x9F\x98\x80");
  fclose(f);
  const char *want = "a&lt;b&gt;&amp;&quot;c&apos;&#9;d&#10;e\\x01f\\x80g\\xC0\\xAFh\\xED\\xA0\\x80i"
                     "\\xEF\\xBF\\xBEj\xC3\xA9\xF0\x9F\x98\x80";
  EXPECT(!strcmp(buf, want), "cf_xml_text wrote\n  %s\nwanted\n  %s", buf, want);
  free(buf);
}

static void test_report_file(void) {
  char path[256];
  snprintf(path, sizeof path, "%s/r.xml", dir);
  cf_report r;
  EXPECT(cf_report_open(&r, path, "conformance unix:/x&y", stderr) == 0, "cannot open %s", path);
  cf_report_add(&r, "stats.histograms", CF_FAIL, "variant <A>: \"1\" & \x02", 12.5);
  cf_report_add(&r, "shm.create.ok", CF_SKIP, "needs a Unix socket", 0);
  cf_report_add(&r, "variants.fields", CF_PASS, "", 1);
  cf_summary s = {3, 1, 1, 1};
  EXPECT(cf_report_close(&r, &s, NULL, stderr) == 0, "cannot write %s", path);
  char *x = slurp(path);
  EXPECT(count(x, "<testcase ") == 3, "3 testcases wanted:\n%s", x);
  EXPECT(strstr(x, "tests=\"3\" failures=\"1\" errors=\"0\" skipped=\"1\""), "counts:\n%s", x);
  EXPECT(strstr(x, "<testsuite name=\"conformance unix:/x&amp;y\""), "suite name:\n%s", x);
  EXPECT(strstr(x, "classname=\"conformance.stats\" name=\"stats.histograms\" time=\"0.013\">\n"
                   "      <failure message=\"variant &lt;A&gt;: &quot;1&quot; &amp; \\x02\"/>"),
         "failure:\n%s", x);
  EXPECT(strstr(x, "<skipped message=\"needs a Unix socket\"/>"), "skip:\n%s", x);
  EXPECT(strstr(x, "name=\"variants.fields\" time=\"0.001\"/>"), "pass:\n%s", x);
  EXPECT(strstr(x, "</testsuite>\n</testsuites>\n"), "the end:\n%s", x);
  free(x);
}

static void test_malformed_result(void) {
  /* An 8x8 f32 RESULT a byte short: 56 + 8*8*3*4 = 824 bytes wanted. */
  uint8_t p[824] = {0};
  p[2] = HFP_F32;
  hfp_put_u32(p + 4, 8);
  hfp_put_u32(p + 8, 8);
  hfp_put_u32(p + 12, 1);
  cf_frame fr = {.h = {.type = HFP_RESULT, .length = 823}, .p = p};
  hfp_result m;
  int rc = hfp_decode_result(p, 823, &m);
  char why[400];
  cf_result_malformed(&fr, rc, why, sizeof why);
  EXPECT(strstr(why, "823 bytes, 1 fewer than") && strstr(why, "need: 824 = 56 fixed + 768 result"),
         "a RESULT a byte short: %s", why);
  fr.h.length = 20;
  cf_result_malformed(&fr, -HFP_E_LENGTH, why, sizeof why);
  EXPECT(strstr(why, "20 bytes, shorter than the 56"), "a 20-byte RESULT: %s", why);
  char tn[16];
  EXPECT(!strcmp(cf_type_name(HFP_RESULT, tn), "RESULT"), "type 6 is %s", cf_type_name(6, tn));
  EXPECT(!strcmp(cf_type_name(77, tn), "type 77"), "type 77 is %s", cf_type_name(77, tn));
}

static void test_cli(void) {
  char *o, *e, path[256];
  int rc = cli(&o, &e, "--client", "--case", "nomatch.*", NULL);
  EXPECT(rc == 2 && strstr(o, "no case matches 'nomatch.*'"),
         "--case nomatch.*: exit %d, stdout %s", rc, o);
  free(o), free(e);
  rc = cli(&o, &e, "--server", "unix:/nonexistent.sock", "--case", "nomatch.*", NULL);
  EXPECT(rc == 2 && strstr(o, "no case matches"), "server --case nomatch.*: exit %d, %s", rc, o);
  free(o), free(e);

  rc = cli(&o, &e, "--client", "--timeout", "10", NULL);
  EXPECT(rc == 2 && strstr(e, "write 10s for seconds"), "--timeout 10: exit %d, stderr %s", rc, e);
  free(o), free(e);
  rc = cli(&o, &e, "--client", "--stall", "99", NULL);
  EXPECT(rc == 2, "--stall 99: exit %d", rc);
  free(o), free(e);

  snprintf(path, sizeof path, "%s/client.xml", dir);
  rc = cli(&o, &e, "--client", "--timeout", "10s", "--quiet", "300", "--case", "client.hello.*",
           "--junit", path, NULL);
  int cases = -1, passed = -1;
  const char *sum = strstr(o, "conformance: ");
  sum = sum ? strstr(sum + 1, "conformance: ") : NULL;   /* after the header line */
  if (sum) sscanf(sum, "conformance: %d cases, %d passed", &cases, &passed);
  EXPECT(rc == 0 && cases > 0 && passed == cases && !strncmp(o, "conformance: libhairfilter", 26),
         "--client --junit: exit %d, stdout %s", rc, o);
  char *x = slurp(path);
  EXPECT(cases > 0 && count(x, "<testcase ") == cases && count(x, "name=\"client.hello.") == cases,
         "%d cases, the report:\n%s", cases, x);
  free(x), free(o), free(e);

  /* The suite cannot run: the report says why in an error. */
  snprintf(path, sizeof path, "%s/probe.xml", dir);
  rc = cli(&o, &e, "--server", "unix:/nonexistent/conformance.sock", "--junit", path, NULL);
  x = slurp(path);
  EXPECT(rc == 2 && count(x, "<testcase ") == 1 && strstr(x, "errors=\"1\"") &&
             strstr(x, "<error message=\"cannot probe unix:/nonexistent/conformance.sock") &&
             strstr(o, "No such file or directory (is hairfilterd running?)"),
         "unreachable server: exit %d, stdout %s, the report:\n%s", rc, o, x);
  free(x), free(o), free(e);

  rc = cli(&o, &e, "--client", "--junit", "/nonexistent/dir/r.xml", NULL);
  EXPECT(rc == 2 && strstr(o, "cannot write the JUnit report"), "unwritable --junit: exit %d, %s",
         rc, o);
  free(o), free(e);
}

int main(void) {
  if (!mkdtemp(dir)) {
    perror("mkdtemp");
    return 1;
  }
  test_xml_text();
  test_report_file();
  test_malformed_result();
  test_cli();
  char cmd[300];
  snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
  if (system(cmd)) fprintf(stderr, "cannot remove %s\n", dir);
  if (failures) fprintf(stderr, "test_cf_report: %d check(s) failed\n", failures);
  return failures ? 1 : 0;
}
