/* Checks on parsed JSON that cJSON does not make. */
#include <stdlib.h>
#include <string.h>

#include "json_check.h"

/* "a number", "an object", ... for messages. */
const char *hf_json_kind(const cJSON *v) {
  return cJSON_IsString(v)   ? "a string"
         : cJSON_IsNumber(v) ? "a number"
         : cJSON_IsObject(v) ? "an object"
         : cJSON_IsArray(v)  ? "an array"
         : cJSON_IsBool(v)   ? "a boolean"
         : cJSON_IsNull(v)   ? "null"
                             : "not a JSON value";
}

static int cmp_key(const void *a, const void *b) {
  return strcmp(*(const char *const *)a, *(const char *const *)b);
}

/* The first key named twice in one object anywhere in node, or NULL; where
 * gets the object's name ("" for the top level). JSON allows duplicate
 * names and parsers disagree on which one counts: cJSON's lookups find the
 * first, Python's json keeps the last, so a file with two "__metadata__"
 * would be two different networks. cJSON keeps every member in order, so
 * the names are sorted and compared neighbour to neighbour (n log n: a
 * hostile 16 MiB header has a million keys). */
const char *hf_json_duplicate(const cJSON *node, const char **where) {
  size_t n = 0;
  for (const cJSON *it = node->child; it; it = it->next) n++;
  if (cJSON_IsObject(node) && n > 1) {
    const char **keys = malloc(n * sizeof *keys);
    if (!keys) return "(out of memory)";
    size_t k = 0;
    for (const cJSON *it = node->child; it; it = it->next) keys[k++] = it->string ? it->string : "";
    qsort(keys, n, sizeof *keys, cmp_key);
    const char *dup = NULL;
    for (k = 1; k < n && !dup; k++)
      if (!strcmp(keys[k - 1], keys[k])) dup = keys[k];
    free(keys);
    if (dup) {
      *where = node->string ? node->string : "";
      return dup;
    }
  }
  for (const cJSON *it = node->child; it; it = it->next) {
    const char *d = hf_json_duplicate(it, where);
    if (d) return d;
  }
  return NULL;
}

/* The JSON value that text's len bytes hold, or NULL when anything but
 * JSON's whitespace (space, tab, CR, LF) follows it: cJSON's own check
 * also passes control bytes and stops at a NUL, which Python's json (the
 * recipe's reader, weights/hfnet.py) refuses. */
cJSON *hf_json_one_value(const char *text, size_t len) {
  const char *end = NULL;
  cJSON *v = cJSON_ParseWithLengthOpts(text, len, &end, 0);
  if (!v) return NULL;
  for (const char *p = end; p && p < text + len; p++)
    if (*p != ' ' && *p != '\t' && *p != '\r' && *p != '\n') {
      cJSON_Delete(v);
      return NULL;
    }
  return v;
}
