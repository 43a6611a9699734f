/* An LD_PRELOAD shim that steps the wall clock: CLOCK_REALTIME (and its
 * coarse form) read through clock_gettime are moved by the number of
 * seconds the file $HF_TEST_CLOCK_STEP_FILE holds, read at each call, so a
 * test can step the clock of a running daemon, as NTP does at boot or a
 * resumed virtual machine does, without changing the machine's. The
 * monotonic clocks are left as they are, as a real step leaves them. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <fcntl.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

static long step_seconds(void) {
  const char *path = getenv("HF_TEST_CLOCK_STEP_FILE");
  if (!path) return 0;
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return 0;
  char buf[32];
  ssize_t n = read(fd, buf, sizeof buf - 1);
  close(fd);
  if (n <= 0) return 0;
  buf[n] = 0;
  return strtol(buf, NULL, 10);
}

int clock_gettime(clockid_t id, struct timespec *ts) {
  static int (*real)(clockid_t, struct timespec *);
  if (!real) real = (int (*)(clockid_t, struct timespec *))dlsym(RTLD_NEXT, "clock_gettime");
  if (!real) return -1;
  int rc = real(id, ts);
  if (rc == 0 && (id == CLOCK_REALTIME || id == CLOCK_REALTIME_COARSE))
    ts->tv_sec += step_seconds();
  return rc;
}
