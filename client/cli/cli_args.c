/* Option values, parsed strictly (cli_args.h). strtod/strtol do the
 * number; what follows it must be nothing or a unit named here. */
#include "cli_args.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int cli_arg_long(const char *cmd, const char *opt, const char *s, long lo, long hi, long *out) {
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (!*s || *end || errno) {
    fprintf(stderr, "%s: %s: '%s' is not an integer\n", cmd, opt, s);
    return -1;
  }
  if (v < lo || v > hi) {
    fprintf(stderr, "%s: %s: %ld is outside %ld..%ld\n", cmd, opt, v, lo, hi);
    return -1;
  }
  *out = v;
  return 0;
}

static int number(const char *s, double *v, char **end) {
  errno = 0;
  *v = strtod(s, end);
  return *end != s && !errno && isfinite(*v);
}

int cli_arg_double(const char *cmd, const char *opt, const char *s, double lo, double hi,
                   double *out) {
  char *end;
  double v;
  if (!number(s, &v, &end) || *end) {
    fprintf(stderr, "%s: %s: '%s' is not a number\n", cmd, opt, s);
    return -1;
  }
  if (v < lo || v > hi) {
    fprintf(stderr, "%s: %s: %g is outside %g..%g\n", cmd, opt, v, lo, hi);
    return -1;
  }
  *out = v;
  return 0;
}

/* A bound of a duration written in the unit that shows it exactly (1us,
 * 4294.967295s), so that the range an error gives holds what it says. */
static void fmt_bound(char *out, size_t cap, double s) {
  if (s > 0 && s < 1e-3)
    snprintf(out, cap, "%.10gus", s * 1e6);
  else if (s > 0 && s < 1)
    snprintf(out, cap, "%.10gms", s * 1e3);
  else
    snprintf(out, cap, "%.10gs", s);
}

int cli_arg_duration(const char *cmd, const char *opt, const char *s, double plain_unit_s,
                     double lo_s, double hi_s, double *seconds) {
  static const struct {
    const char *name;
    double s;
  } units[] = {{"h", 3600}, {"m", 60}, {"min", 60}, {"s", 1}, {"ms", 1e-3}, {"us", 1e-6}};
  char *end;
  double v;
  if (!number(s, &v, &end)) {
    fprintf(stderr, "%s: %s: '%s' is not a duration (a number, optionally with h, m, "
                    "s, ms or us)\n", cmd, opt, s);
    return -1;
  }
  double unit = plain_unit_s;
  if (*end) {
    unit = 0;
    for (size_t i = 0; i < sizeof units / sizeof units[0]; i++)
      if (!strcmp(end, units[i].name)) unit = units[i].s;
    if (unit == 0) {
      fprintf(stderr, "%s: %s: unknown unit '%s' in '%s' (use h, m, s, ms or us)\n",
              cmd, opt, end, s);
      return -1;
    }
  }
  v *= unit;
  if (v < lo_s || v > hi_s) {
    char lo[32], hi[32];
    fmt_bound(lo, sizeof lo, lo_s);
    fmt_bound(hi, sizeof hi, hi_s);
    fprintf(stderr, "%s: %s: %s is outside %s..%s\n", cmd, opt, s, lo, hi);
    return -1;
  }
  *seconds = v;
  return 0;
}

int cli_arg_range(const char *cmd, const char *opt, const char *s, double lo, double hi,
                  int integer, double out[3]) {
  double v[3] = {0, 0, 1};
  int n = 0;
  const char *p = s;
  for (;;) {
    char *end;
    if (n == 3 || !number(p, &v[n], &end) || (integer && v[n] != floor(v[n]))) {
      fprintf(stderr, "%s: %s: '%s' is not start[:end[:step]] of %s\n", cmd, opt, s,
              integer ? "integers" : "numbers");
      return -1;
    }
    n++;
    if (!*end) break;
    if (*end != ':') {
      fprintf(stderr, "%s: %s: '%s': unexpected '%s' (want start[:end[:step]])\n", cmd,
              opt, s, end);
      return -1;
    }
    p = end + 1;
  }
  if (n == 1) v[1] = v[0];
  if (v[0] < lo || v[1] > hi || v[0] > v[1] || v[2] <= 0) {
    fprintf(stderr, "%s: %s: '%s': want %g <= start <= end <= %g and step > 0\n", cmd,
            opt, s, lo, hi);
    return -1;
  }
  memcpy(out, v, sizeof v);
  return 0;
}

void cli_arg_bad_option(const char *cmd, char **argv, int optind_now, int optopt_now,
                        int missing_value) {
  /* A long option is argv[optind - 1] as written (up to any '='); a short
   * one is optopt. */
  const char *arg = optind_now > 0 ? argv[optind_now - 1] : "";
  char o[80];
  if (!strncmp(arg, "--", 2))
    snprintf(o, sizeof o, "%.*s", (int)strcspn(arg, "="), arg);
  else
    snprintf(o, sizeof o, "-%c", optopt_now > 32 && optopt_now < 127 ? optopt_now : '?');
  if (missing_value)
    fprintf(stderr, "%s: option '%s' needs a value\n", cmd, o);
  else
    fprintf(stderr, "%s: unknown option '%s' (see %s --help)\n", cmd, o, cmd);
}

int cli_tls_option(int ch, const char *arg, cli_tls *t) {
  switch (ch) {
    case CLI_TLS_CA: t->ca = arg; return 1;
    case CLI_TLS_CERT: t->cert = arg; return 1;
    case CLI_TLS_KEY: t->key = arg; return 1;
    case CLI_TLS_SERVER_NAME: t->server_name = arg; return 1;
    default: return 0;
  }
}

int cli_tls_for_server(const char *cmd, const char *server, const cli_tls *t) {
  if (!server || !(t->ca || t->cert || t->key || t->server_name)) return 0;
  /* An endpoint list: one tls: endpoint is enough. */
  for (const char *p = server; p; p = strchr(p, ',')) {
    if (*p == ',') p++;
    if (!strncmp(p, "tls:", 4)) return 0;
  }
  fprintf(stderr, "%s: the --tls-* options are for tls: URLs, and --server %s has none: the "
          "connection would be plain, its token and frames unencrypted; connect with "
          "tls:HOST:PORT, or leave the TLS options out\n", cmd, server);
  return -1;
}

int cli_tls_pair(const char *cmd, const char *cert, const char *key) {
  if (!cert == !key) return 0;
  fprintf(stderr, "%s: give --tls-cert and --tls-key together (a client certificate "
          "and its private key; %s is missing)\n", cmd, cert ? "--tls-key" : "--tls-cert");
  return -1;
}
