/*
 * sigpipe.c: OpenSSL writes to its socket with write(2), which has no
 * MSG_NOSIGNAL: a server that is gone (killed, restarted) while a frame is
 * being written would raise SIGPIPE, whose default action ends the whole
 * engine. The plain-socket path passes MSG_NOSIGNAL; around the OpenSSL
 * calls that may write, SIGPIPE is blocked in the calling thread instead,
 * and one that the call raised is consumed before the mask is restored, so
 * the write fails with EPIPE and the connection's loss is handled like any
 * other. The caller's own disposition and mask are left as they were; a
 * SIGPIPE already pending before the call is left pending.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <signal.h>
#include <time.h>

#include "client_internal.h"

void hfci_sigpipe_block(hfci_sigpipe *s) {
  sigset_t pipe, pending;
  sigemptyset(&pipe);
  sigaddset(&pipe, SIGPIPE);
  s->was_pending = sigpending(&pending) == 0 && sigismember(&pending, SIGPIPE) == 1;
  s->blocked = pthread_sigmask(SIG_BLOCK, &pipe, &s->old) == 0;
}

void hfci_sigpipe_restore(hfci_sigpipe *s) {
  if (!s->blocked) return;
  sigset_t pipe, pending;
  sigemptyset(&pipe);
  sigaddset(&pipe, SIGPIPE);
  if (!s->was_pending && sigpending(&pending) == 0 && sigismember(&pending, SIGPIPE) == 1) {
    /* Raised by the call just made: take it before unblocking. */
    const struct timespec zero = {0, 0};
    int saved = errno;
    while (sigtimedwait(&pipe, NULL, &zero) < 0 && errno == EINTR) {
    }
    errno = saved;
  }
  pthread_sigmask(SIG_SETMASK, &s->old, NULL);
}
