/*
 * harness.h's raw-wire calls that a cmocka test needs to succeed, failing
 * the test where they do not. Include after <cmocka.h> and harness.h.
 */
#ifndef HF_TEST_HARNESS_CMOCKA_H
#define HF_TEST_HARNESS_CMOCKA_H

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

#endif
