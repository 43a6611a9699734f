/* The daemon's own user and group by name, for the permission errors about
 * files it cannot read (config, token, weights, TLS): "Permission denied"
 * alone does not say that it runs as its own user (hairfilter under
 * systemd, 10001 in the image) while the file was written by root. */
#define _POSIX_C_SOURCE 200809L
#include <grp.h>
#include <pwd.h>
#include <stdio.h>
#include <unistd.h>

#include "server.h"

void hfd_user_name(char *buf, size_t cap) {
  struct passwd *pw = getpwuid(geteuid());
  if (pw && pw->pw_name[0])
    snprintf(buf, cap, "%s", pw->pw_name);
  else
    snprintf(buf, cap, "%ld", (long)geteuid());
}

void hfd_group_name(char *buf, size_t cap) {
  struct group *gr = getgrgid(getegid());
  if (gr && gr->gr_name[0])
    snprintf(buf, cap, "%s", gr->gr_name);
  else
    snprintf(buf, cap, "%ld", (long)getegid());
}
