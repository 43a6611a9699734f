/*
 * harness.h's raw-wire calls that a cmocka test needs to succeed, failing
 * the test where they do not. Include after <cmocka.h> and harness.h.
 */
#ifndef HF_TEST_HARNESS_CMOCKA_H
#define HF_TEST_HARNESS_CMOCKA_H

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

/* A connection to url that negotiated a version in lo..hi. */
static inline int connect_versions_or_fail(const char *url, int lo, int hi) {
  int fd = raw_connect_versions(url, lo, hi);
  if (fd < 0) fail_msg("no connection to %s offering versions %d..%d", url, lo, hi);
  return fd;
}

/* variant's counters from a STATS on fd, as fd's version reads them. */
static inline hfp_variant_stats variant_stats_or_fail(int fd, const char *variant) {
  hfp_variant_stats v;
  memset(&v, 0, sizeof v);
  if (raw_variant_stats(fd, variant, &v)) fail_msg("no STATS_REPLY listing variant %s", variant);
  return v;
}


/* Sends s SIGUSR1 and waits up to 5 s for needle in its log (the
 * statistics line it writes), failing with the log shown otherwise. */
static inline void usr1_line_or_fail(const server *s, const char *needle) {
  assert_int_equal(kill(s->pid, SIGUSR1), 0);
  int seen = 0;
  for (int waited = 0; waited < 5000 && !seen; waited += 10)
    if (!(seen = server_log_has(s, needle))) usleep(10000);
  if (!seen) {
    server_dump_log(s);
    fail_msg("no '%s' in the SIGUSR1 statistics lines", needle);
  }
}

#ifdef HAIRFILTER_CLI_PATH
/* What `hairfilter filter --server URL --stats` printed (stdout and
 * stderr) against s, into text (cap bytes), failing unless it exits 0. */
static inline void cli_stats_or_fail(const harness *h, const server *s, char *text, size_t cap) {
  char cmd[1200], out[300];
  snprintf(out, sizeof out, "%s/stats.out", h->dir);
  snprintf(cmd, sizeof cmd, "'%s' filter --server %s --stats > '%s' 2>&1", HAIRFILTER_CLI_PATH,
           s->unix_url, out);
  int rc = system(cmd);
  assert_true(WIFEXITED(rc) && WEXITSTATUS(rc) == 0);
  assert_int_equal(read_text_file(out, text, cap), 0);
}
#endif

#endif
