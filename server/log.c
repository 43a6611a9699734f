/*
 * hairfilterd's log: one line per event on stderr, with a level.
 *
 * Levels are syslog priorities (sd-daemon(3)): under systemd, stderr is a
 * stream to journald, which reads a "<N>" prefix as the line's priority, so
 * `journalctl -p err -u hairfilterd` shows the errors only. Elsewhere (a
 * terminal, a file, a container runtime) each line carries its own UTC time
 * and the pid. The journal is recognised the way systemd documents it:
 * $JOURNAL_STREAM holds the device and inode of the stream, which must be
 * stderr's. Context goes after the message as key=value fields, in the
 * logfmt convention, so a line is both readable and parseable.
 */
#define _GNU_SOURCE
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "server.h"

_Atomic int hfd_log_level = HFD_LOG_INFO;
static int to_journal;

static const char *const level_names[] = {
  [HFD_LOG_ERR] = "error", [HFD_LOG_WARNING] = "warning", [HFD_LOG_NOTICE] = "notice",
  [HFD_LOG_INFO] = "info", [HFD_LOG_DEBUG] = "debug",
};

int hfd_log_level_parse(const char *name) {
  for (int l = HFD_LOG_ERR; l <= HFD_LOG_DEBUG; l++)
    if (!strcmp(name, level_names[l])) return l;
  return -1;
}

const char *hfd_log_level_name(int level) {
  return level >= HFD_LOG_ERR && level <= HFD_LOG_DEBUG ? level_names[level] : "?";
}

void hfd_log_init(void) {
  const char *js = getenv("JOURNAL_STREAM");
  struct stat st;
  unsigned long long dev, ino;
  to_journal = js && sscanf(js, "%llu:%llu", &dev, &ino) == 2 && fstat(2, &st) == 0 &&
               (unsigned long long)st.st_dev == dev && (unsigned long long)st.st_ino == ino;
}

static __thread const char *log_context;

void hfd_log_context(const char *where) { log_context = where; }

void hfd_logl(int level, const char *fmt, ...) {
  if (level > hfd_log_level) return;
  char msg[1024];
  size_t at = 0;
  if (log_context && level <= HFD_LOG_WARNING)
    at = (size_t)snprintf(msg, sizeof msg, "%s", log_context);
  if (at >= sizeof msg) at = sizeof msg - 1;
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg + at, sizeof msg - at, fmt, ap);
  va_end(ap);
  /* Only errors and warnings name their level in the text: that is what a
   * reader scans for, and what the lines said before levels existed. */
  const char *tag = level == HFD_LOG_ERR ? "error: " : level == HFD_LOG_WARNING ? "warning: " : "";
  /* One fprintf per line so lines from the two threads never interleave. */
  if (to_journal) {
    fprintf(stderr, "<%d>%s%s\n", level, tag, msg);
    return;
  }
  struct timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  struct tm tm;
  gmtime_r(&ts.tv_sec, &tm);
  char when[32];
  strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%S", &tm);
  fprintf(stderr, "%s.%03ldZ hairfilterd[%ld]: %s%s\n", when, ts.tv_nsec / 1000000L,
          (long)getpid(), tag, msg);
}

int hfd_rate_allow(hfd_rate *r, int per_second, const char *what) {
  double now = hfd_now_us();
  if (now - r->window_start > 1e6) {
    if (r->suppressed)
      hfd_log("%lu %s line(s) suppressed in the last interval", r->suppressed, what);
    r->window_start = now;
    r->in_window = 0;
    r->suppressed = 0;
  }
  if (r->in_window < per_second) {
    r->in_window++;
    return 1;
  }
  r->suppressed++;
  return 0;
}

void hfd_kv(char *buf, size_t cap, const char *key, const char *value) {
  size_t n = strlen(buf);
  int quote = !value[0];
  for (const char *p = value; *p && !quote; p++)
    quote = *p <= 0x20 || *p > 0x7e || *p == '"' || *p == '=' || *p == '\\';
  int w = snprintf(buf + n, n < cap ? cap - n : 0, " %s=%s", key, quote ? "\"" : "");
  if (w < 0 || (n += (size_t)w) >= cap) return;
  for (const char *p = value; *p && n + 3 < cap; p++) {
    char ch = *p > 0x1f && *p < 0x7f ? *p : '?';
    if (quote && (ch == '"' || ch == '\\')) buf[n++] = '\\';
    buf[n++] = ch;
  }
  if (quote && n + 1 < cap) buf[n++] = '"';
  buf[n < cap ? n : cap - 1] = 0;
}
