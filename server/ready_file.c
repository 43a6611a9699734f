/*
 * The ready file (--ready-file): the listening URLs, written once the
 * daemon serves, so that whoever starts it knows when and where to
 * connect. Checked at start, before the models are built: a stale one (a
 * daemon killed before it could remove it) goes, a running daemon's stops
 * the start, and a path where none can be written is said then. Removed
 * by hairfilterd.c when the daemon stops.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include "server.h"

/* Logs why the ready file at path could not be made (what failed, err)
 * and what to do about it: a full file system and one the daemon may not
 * write need different fixes. */
static void ready_file_error(const char *path, const char *what, int err) {
  if (err == ENOSPC || err == EDQUOT)
    hfd_err("--ready-file %s: %s: %s; the file system it is on is full (or the user's quota "
            "is): free space there, or give a path on another file system",
            path, what, strerror(err));
  else if (err == EROFS)
    hfd_err("--ready-file %s: %s: %s; give a path on a writable file system (a tmpfs such as "
            "/run, an emptyDir in Kubernetes)", path, what, strerror(err));
  else
    hfd_err("--ready-file %s: %s: %s; its directory must exist and be writable by uid %ld, or "
            "give another path", path, what, strerror(err), (long)geteuid());
}

/* A temporary file beside the ready file path, in tmp ([cap]): its fd, or
 * -1 after saying why and what to do. It is made with O_CREAT | O_EXCL |
 * O_NOFOLLOW under a random name in the target's directory (mkostemp): a
 * symlink planted there, or at any name an attacker can guess, is never
 * written through. */
static int ready_file_temp(const char *path, char *tmp, size_t cap) {
  if ((size_t)snprintf(tmp, cap, "%s.XXXXXX", path) >= cap) {
    hfd_err("--ready-file %s: path too long", path);
    return -1;
  }
  int fd = mkostemp(tmp, O_CLOEXEC | O_NOFOLLOW);
  if (fd < 0) ready_file_error(path, "cannot create a file beside it", errno);
  return fd;
}

/* Writes the whole of text to fd: 0, or -1 with errno set. */
static int write_all(int fd, const char *text, size_t len) {
  while (len > 0) {
    ssize_t n = write(fd, text, len);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      if (n == 0) errno = EIO;
      return -1;
    }
    text += n;
    len -= (size_t)n;
  }
  return 0;
}

/* Whether the ready file at path is a running daemon's: 1 when a Unix
 * socket it lists accepts a connection (its URL in url[cap]), else 0 (no
 * file, none listed, or none answers: a stale one). TCP ports it lists
 * are not tried, as another program may have a freed port by now. */
static int ready_file_live(const char *path, char *url, size_t cap) {
  FILE *f = fopen(path, "re");
  if (!f) return 0;
  char line[512];
  int live = 0;
  for (int n = 0; n < 64 && !live && fgets(line, sizeof line, f); n++) {
    line[strcspn(line, "\r\n")] = 0;
    struct sockaddr_un sa;
    if (strncmp(line, "unix:", 5) != 0 || strlen(line + 5) >= sizeof sa.sun_path) continue;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    memcpy(sa.sun_path, line + 5, strlen(line + 5) + 1);
    /* Non-blocking, as clear_stale_socket's probe: a daemon that does not
     * accept (stopped, its backlog full) is EAGAIN, not a start that hangs. */
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (fd < 0) continue;
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) == 0 || errno == EAGAIN) {
      live = 1;
      snprintf(url, cap, "%s", line);
    }
    close(fd);
  }
  fclose(f);
  return live;
}

/* Whether the ready file can be made beside path and written, as
 * hfd_ready_file_write will: 0, or -1 after saying why and what to do. It
 * writes the listeners as configured (their resolved ports are not known
 * yet), so a file system with no room for them is said now, before the
 * models are built, and not once they are. */
static int ready_file_probe(const char *path, const hfd_config *cfg) {
  char tmp[4200];
  int fd = ready_file_temp(path, tmp, sizeof tmp);
  if (fd < 0) return -1;
  int rc = 0;
  for (int i = 0; i < cfg->num_listen && rc == 0; i++)
    if (write_all(fd, cfg->listen[i], strlen(cfg->listen[i])) || write_all(fd, "\n", 1)) {
      ready_file_error(path, "cannot write a file beside it", errno);
      rc = -1;
    }
  if (close(fd) != 0 && rc == 0) {
    ready_file_error(path, "cannot write a file beside it", errno);
    rc = -1;
  }
  unlink(tmp);
  return rc;
}

int hfd_ready_file_write(const hfd_server *s, const char *http_url) {
  const char *path = s->cfg->ready_file;
  char tmp[4200];
  int fd = ready_file_temp(path, tmp, sizeof tmp);
  if (fd < 0) return -1;
  /* mkostemp makes it 0600; a ready file is for others to read. */
  mode_t um = umask(0);
  umask(um);
  if (fchmod(fd, 0666 & ~um) != 0) {
    ready_file_error(path, "cannot set the mode of a file beside it", errno);
    close(fd);
    unlink(tmp);
    return -1;
  }
  int rc = 0;
  for (int i = 0; i < s->num_listeners && rc == 0; i++)
    rc = write_all(fd, s->listeners[i].url, strlen(s->listeners[i].url)) || write_all(fd, "\n", 1);
  if (rc == 0 && http_url[0])
    rc = write_all(fd, http_url, strlen(http_url)) || write_all(fd, "\n", 1);
  int err = errno;
  if (close(fd) != 0 && rc == 0) {
    rc = 1;
    err = errno;
  }
  if (rc) {
    ready_file_error(path, "cannot write a file beside it", err);
    unlink(tmp);
    return -1;
  }
  if (rename(tmp, path) != 0) {
    ready_file_error(path, "cannot rename the file written beside it into place", errno);
    unlink(tmp);
    return -1;
  }
  return 0;
}

int hfd_ready_file_prepare(const hfd_config *cfg) {
  const char *path = cfg->ready_file;
  struct stat rst;
  if (stat(path, &rst) == 0 && S_ISDIR(rst.st_mode)) {
    hfd_err("--ready-file %s is a directory: give the path of a file (%s/ready, say)", path, path);
    return -1;
  }
  /* Another daemon's, given the same path by mistake: removing it would
   * say that daemon is gone while it serves, and this one may not start. */
  char live_url[512];
  if (ready_file_live(path, live_url, sizeof live_url)) {
    hfd_err("--ready-file %s: a running daemon wrote it (%s answers); give each daemon its own "
            "ready file (docs/SERVER.md, \"Several daemons on one host\")", path, live_url);
    return -1;
  }
  /* One left by a daemon that could not remove it (SIGKILL, the OOM
   * killer, a crash) would say "serving" with its old URLs while this one
   * loads its models, or after this one failed to start: whoever waits
   * for the file would connect to nothing. */
  if (unlink(path) == 0)
    hfd_warn("--ready-file %s: removed the one there, left by a daemon that did not stop "
             "cleanly (or another daemon's: give each its own); written again once this one "
             "serves", path);
  else if (errno != ENOENT)
    hfd_warn("--ready-file %s: cannot remove the one there: %s", path, strerror(errno));
  /* It is written beside its place once every model is built, which with
   * --warm on a GPU takes minutes: a directory that is missing or not
   * writable, or a full file system, is said now, not then. */
  return ready_file_probe(path, cfg);
}
