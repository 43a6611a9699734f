/*
 * systemd integration (sd_notify(3), libsystemd): with Type=notify the unit
 * is "active" only once the daemon says READY=1, which it says when every
 * listener is bound and every model built; RELOADING=1 and READY=1 bracket
 * a SIGHUP reload, STOPPING=1 starts a drain, STATUS= is what `systemctl
 * status` shows, and WATCHDOG=1 is sent from the loop's heartbeat only
 * while the worker makes progress, so a wedged daemon is restarted by
 * WatchdogSec=. Outside systemd ($NOTIFY_SOCKET unset) every call does
 * nothing.
 */
#define _GNU_SOURCE
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <systemd/sd-daemon.h>

#include "server.h"

static void say(const char *what) {
  int rc = sd_notify(0, what);
  if (rc < 0) hfd_debug("sd_notify: %s", strerror(-rc));
}

void hfd_notify_ready(hfd_server *s) {
  int serving = 0;
  for (int i = 0; i < s->num_variants; i++) serving += s->variants[i].model != NULL;
  char msg[400];
  snprintf(msg, sizeof msg, "READY=1\nSTATUS=serving %d variant(s) on %s%s%s", serving,
           s->worker.backend ? hf_backend_name(s->worker.backend) : "?",
           s->missing ? "; not ready: " : "", s->missing ? s->missing_why : "");
  say(msg);
}

void hfd_notify_reloading(void) { say("RELOADING=1\nSTATUS=reloading"); }

void hfd_notify_stopping(void) { say("STOPPING=1\nSTATUS=draining"); }

void hfd_notify_status(const char *fmt, ...) {
  char msg[400] = "STATUS=";
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg + 7, sizeof msg - 7, fmt, ap);
  va_end(ap);
  say(msg);
}

void hfd_notify_watchdog(void) { say("WATCHDOG=1"); }
