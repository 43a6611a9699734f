/*
 * What the compiled benchmarks share: clocks, the median, and the header
 * every table is printed under (the command, the CPU model as lscpu's
 * "Model name" gives it, from /proc/cpuinfo, the cores, the date).
 * Header-only: each benchmark is one executable of one file.
 */
#ifndef HF_BENCH_UTIL_H
#define HF_BENCH_UTIL_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

/* Wall clock, microseconds. */
static inline double bench_now_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

/* CPU time of the whole process (every thread), microseconds. */
static inline double bench_cpu_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

static inline int bench_cmp_d(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

/* Median of v[0..n) (n >= 1); sorts v. */
static inline double bench_median(double *v, int n) {
  qsort(v, (size_t)n, sizeof *v, bench_cmp_d);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static inline void bench_cpu_model(char *buf, size_t len) {
  snprintf(buf, len, "unknown CPU");
  FILE *f = fopen("/proc/cpuinfo", "r");
  char line[512];
  while (f && fgets(line, sizeof line, f))
    if (!strncmp(line, "model name", 10) && strchr(line, ':')) {
      snprintf(buf, len, "%s", strchr(line, ':') + 2);
      buf[strcspn(buf, "\n")] = 0;
      break;
    }
  if (f) fclose(f);
}

/* "$ command\nCPU model, N cores, date" and, when extra is not NULL,
 * "; extra", then a blank line. */
static inline void bench_print_header(int argc, char **argv, const char *extra) {
  char model[256], date[64];
  bench_cpu_model(model, sizeof model);
  time_t now = time(NULL);
  strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", gmtime(&now));
  printf("$");
  for (int i = 0; i < argc; i++) printf(" %s", argv[i]);
  printf("\n%s, %ld cores, %s%s%s\n\n", model, sysconf(_SC_NPROCESSORS_ONLN), date,
         extra ? "; " : "", extra ? extra : "");
}

#endif
