/* The channel lists of an EXR file read from its bytes, for what
 * OpenEXRCore does not say when it refuses a header for one of its
 * entries (a channel listed twice, a pixel type it does not know, a
 * sampling below 1): it reports the list as missing ("'channels'
 * attribute not found"), which sends a user looking for the wrong fault.
 * OpenEXR's C++ library (OpenImageIO, weights/dataset.py) keeps one of two
 * channels of a name and reads on.
 *
 * The layout is the format's (openexr.com, "OpenEXR File Layout"): magic
 * and version (8 bytes), then each part's header, attributes of name\0
 * type\0 int32 size and value, ended by a 0 byte (a multi-part file's
 * headers end with an empty one); a chlist value is entries of name\0 and
 * 16 bytes (pixel type, pLinear and reserved, x and y sampling), ended by
 * a 0 byte. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "exr_internal.h"

/* Attributes and entries past these are not looked at: a header of a real
 * file has tens of attributes and at most a few thousand channels. */
#define MAX_ATTRS 4096
#define MAX_CHLIST (1u << 20)

/* Reads a NUL-terminated string of at most max - 1 bytes into buf: its
 * length, or -1 (end of file, or no NUL in max bytes). */
static int read_name(FILE *f, char *buf, int max) {
  for (int i = 0; i < max; i++) {
    int c = fgetc(f);
    if (c == EOF) return -1;
    buf[i] = (char)c;
    if (!c) return i;
  }
  return -1;
}

/* 1 when the chlist value v of n bytes of part has an entry OpenEXRCore
 * refuses (a name twice, a pixel type it does not know, a sampling below
 * 1), what in why. */
static int chlist_fault(const unsigned char *v, size_t n, int part, char *why, size_t len) {
  const char *names[4096];
  int count = 0;
  for (size_t at = 0; at < n && v[at] && count < (int)(sizeof names / sizeof names[0]);) {
    const unsigned char *end = memchr(v + at, 0, n - at);
    if (!end || (size_t)(end - v) + 17 > n) return 0;
    const char *name = (const char *)v + at;
    const unsigned char *e = end + 1;
    int32_t type = (int32_t)((uint32_t)e[0] | (uint32_t)e[1] << 8 | (uint32_t)e[2] << 16 |
                             (uint32_t)e[3] << 24);
    int32_t xs = (int32_t)((uint32_t)e[8] | (uint32_t)e[9] << 8 | (uint32_t)e[10] << 16 |
                           (uint32_t)e[11] << 24);
    int32_t ys = (int32_t)((uint32_t)e[12] | (uint32_t)e[13] << 8 | (uint32_t)e[14] << 16 |
                           (uint32_t)e[15] << 24);
    for (int k = 0; k < count; k++)
      if (!strcmp(names[k], name)) {
        snprintf(why, len, "channel \"%.64s\" is listed twice in the channel list of part %d: "
                 "every channel of a part needs its own name; write the file again with one "
                 "of them renamed or left out", name, part);
        return 1;
      }
    if (type < 0 || type > 2) {
      snprintf(why, len, "channel \"%.64s\" of part %d has pixel type %d, not UINT (0), HALF "
               "(1) or FLOAT (2); the file is damaged, write it again", name, part, (int)type);
      return 1;
    }
    if (xs < 1 || ys < 1) {
      snprintf(why, len, "channel \"%.64s\" of part %d has sampling %dx%d, below 1; the file "
               "is damaged, write it again", name, part, (int)xs, (int)ys);
      return 1;
    }
    names[count++] = name;
    at = (size_t)(end - v) + 17;
  }
  return 0;
}

int hf_exr_chlist_fault(const char *path, char *why, size_t len) {
  FILE *f = fopen(path, "rb");
  if (!f) return 0;
  unsigned char head[8];
  int found = 0;
  if (fread(head, 1, 8, f) != 8) goto out;
  int multipart = (head[5] & 0x10) != 0;
  char name[256], type[256];
  for (int p = 0; !found && (p == 0 || multipart); p++) {
    int attrs = 0;
    for (;; attrs++) {
      int n = read_name(f, name, (int)sizeof name);
      if (n < 0 || attrs > MAX_ATTRS) goto out;
      if (n == 0) break;
      unsigned char l[4];
      if (read_name(f, type, (int)sizeof type) < 0 || fread(l, 1, 4, f) != 4) goto out;
      uint32_t vlen = (uint32_t)l[0] | (uint32_t)l[1] << 8 | (uint32_t)l[2] << 16 |
                      (uint32_t)l[3] << 24;
      if (!strcmp(name, "channels") && !strcmp(type, "chlist") && vlen <= MAX_CHLIST) {
        unsigned char *v = malloc(vlen ? vlen : 1);
        if (!v) goto out;
        found = fread(v, 1, vlen, f) == vlen && chlist_fault(v, vlen, p, why, len);
        free(v);
        if (found) goto out;
      } else if (vlen > 0x7fffffffu || fseek(f, (long)vlen, SEEK_CUR) != 0) {
        goto out;
      }
    }
    if (attrs == 0) break;   /* the empty header that ends a multi-part file's */
  }
out:
  fclose(f);
  return found;
}
