/* The command, machine and date of a load run (run_header.h). */
#define _POSIX_C_SOURCE 200809L
#include "run_header.h"

#include <stdio.h>
#include <string.h>
#include <sys/utsname.h>
#include <time.h>
#include <unistd.h>

#include "bench_peak.h"

/* A report is kept and passed around (pasted in a ticket, a CSV in a
 * shared folder): the token a server takes is written as this instead. */
#define HIDDEN_TOKEN "***"

/* Whether a names --token as getopt_long takes it: the whole name or any
 * abbreviation of it ("--tok"), alone (its value the next argument) or
 * with "=VALUE"; *eq gets the '=' or NULL. */
static int token_option(const char *a, const char **eq) {
  static const char name[] = "token";
  if (strncmp(a, "--", 2)) return 0;
  a += 2;
  size_t n = strcspn(a, "=");
  *eq = a[n] ? a + n : NULL;
  return n > 0 && n < sizeof name && !strncmp(a, name, n);
}

void run_header_describe(const char *prog, int argc, char **argv, run_header *h) {
  size_t cap = sizeof h->command;
  size_t n = (size_t)snprintf(h->command, cap, "%s", prog);
  for (int i = 0; i < argc && n < cap - 8; i++) {
    const char *a = argv[i];
    const char *eq = NULL;
    char shown[64];
    if (i > 0 && token_option(argv[i - 1], &eq) && !eq) {
      a = HIDDEN_TOKEN;
    } else if (token_option(a, &eq) && eq) {
      snprintf(shown, sizeof shown, "%.*s=" HIDDEN_TOKEN, (int)(eq - a), a);
      a = shown;
    }
    int plain = *a != 0;
    for (const char *c = a; *c; c++)
      if (!strchr("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_@%+=:,./-", *c))
        plain = 0;
    n += (size_t)snprintf(h->command + n, cap - n, plain ? " " : " '");
    for (const char *c = a; *c && n < cap - 8; c++)
      n += (size_t)snprintf(h->command + n, cap - n, *c == '\'' ? "'\\''" : "%c", *c);
    if (!plain && n < cap - 1) n += (size_t)snprintf(h->command + n, cap - n, "'");
  }
  bench_cpu cpu;
  bench_cpu_describe(&cpu);
  struct utsname u;
  if (strcmp(cpu.model, "unknown") || uname(&u) != 0)
    snprintf(h->cpu, sizeof h->cpu, "%s", cpu.model);
  else
    snprintf(h->cpu, sizeof h->cpu, "%s", u.machine);
  h->cores = cpu.online > 0 ? cpu.online : 0;
  time_t t = time(NULL);
  struct tm tm;
  if (!gmtime_r(&t, &tm) || !strftime(h->date, sizeof h->date, "%Y-%m-%dT%H:%M:%SZ", &tm))
    snprintf(h->date, sizeof h->date, "unknown");
}
