/* Resident memory of a process, for tests that check what memory is used
 * and given back: VmRSS and its peak VmHWM from /proc/PID/status, and
 * /proc/PID/clear_refs to reset the peak (Linux >= 4.0). Under
 * AddressSanitizer, whose quarantine keeps freed memory resident, such
 * checks mean nothing; UNDER_ASAN says when that is the case. */
#ifndef HF_TEST_PROC_MEMORY_H
#define HF_TEST_PROC_MEMORY_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>

#if defined(__SANITIZE_ADDRESS__)
#define UNDER_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define UNDER_ASAN 1
#endif
#endif
#ifndef UNDER_ASAN
#define UNDER_ASAN 0
#endif

/* A /proc/PID/status value in kB ("VmRSS", "VmHWM"); pid 0 is this
 * process. -1 when it cannot be read. */
static inline long proc_status_kb(pid_t pid, const char *key) {
  char path[64], line[256];
  if (pid)
    snprintf(path, sizeof path, "/proc/%d/status", (int)pid);
  else
    snprintf(path, sizeof path, "/proc/self/status");
  FILE *f = fopen(path, "r");
  if (!f) return -1;
  long v = -1;
  size_t n = strlen(key);
  while (fgets(line, sizeof line, f))
    if (!strncmp(line, key, n) && line[n] == ':') v = atol(line + n + 1);
  fclose(f);
  return v;
}

/* Resets the peak resident memory (VmHWM) of pid (0: this process) to its
 * current resident memory; 0 or -1. */
static inline int proc_reset_peak(pid_t pid) {
  char path[64];
  if (pid)
    snprintf(path, sizeof path, "/proc/%d/clear_refs", (int)pid);
  else
    snprintf(path, sizeof path, "/proc/self/clear_refs");
  FILE *f = fopen(path, "w");
  if (!f) return -1;
  int ok = fputs("5", f) >= 0;
  return fclose(f) == 0 && ok ? 0 : -1;
}

#endif
