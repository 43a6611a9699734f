/* Checks on parsed JSON that cJSON does not make. */
#include <ctype.h>
#include <stdio.h>
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
  /* cJSON skips a UTF-8 byte order mark, which JSON text may not start
   * with and Python's json refuses. */
  if (len >= 3 && !memcmp(text, "\xef\xbb\xbf", 3)) return NULL;
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

/* Length of the well-formed UTF-8 sequence at p (at most n bytes), or 0:
 * RFC 3629's table, so no overlong form, no surrogate (U+D800..U+DFFF),
 * nothing above U+10FFFF. */
static size_t utf8_len(const unsigned char *p, size_t n) {
  unsigned char c = p[0];
  if (c < 0x80) return 1;
  size_t len = c >= 0xc2 && c <= 0xdf ? 2 : c >= 0xe0 && c <= 0xef ? 3
               : c >= 0xf0 && c <= 0xf4 ? 4 : 0;
  if (!len || len > n) return 0;
  unsigned char lo = 0x80, hi = 0xbf;   /* the second byte's range */
  if (c == 0xe0) lo = 0xa0;
  else if (c == 0xed) hi = 0x9f;
  else if (c == 0xf0) lo = 0x90;
  else if (c == 0xf4) hi = 0x8f;
  if (p[1] < lo || p[1] > hi) return 0;
  for (size_t i = 2; i < len; i++)
    if (p[i] < 0x80 || p[i] > 0xbf) return 0;
  return len;
}

/* 1 when the four hex digits at h are a high surrogate (D800-DBFF), 2 a
 * low one (DC00-DFFF), else 0. */
static int surrogate(const unsigned char *h) {
  if ((h[0] != 'd' && h[0] != 'D') || !strchr("89abAB" "cdefCDEF", h[1]) || !h[1]) return 0;
  for (int j = 2; j < 4; j++)
    if (!isxdigit(h[j])) return 0;
  return strchr("89abAB", h[1]) ? 1 : 2;
}

/* 1 when the n bytes at s are a number as JSON's grammar (RFC 8259, 6)
 * writes it: -?(0|[1-9][0-9]*)(.[0-9]+)?([eE][+-]?[0-9]+)?. */
static int number_ok(const char *s, size_t n) {
  size_t i = 0, d;
  if (i < n && s[i] == '-') i++;
  if (i < n && s[i] == '0') i++;
  else if (i < n && s[i] >= '1' && s[i] <= '9')
    while (i < n && isdigit((unsigned char)s[i])) i++;
  else return 0;
  if (i < n && s[i] == '.') {
    for (d = ++i; i < n && isdigit((unsigned char)s[i]);) i++;
    if (i == d) return 0;
  }
  if (i < n && (s[i] == 'e' || s[i] == 'E')) {
    if (++i < n && (s[i] == '+' || s[i] == '-')) i++;
    for (d = i; i < n && isdigit((unsigned char)s[i]);) i++;
    if (i == d) return 0;
  }
  return i == n;
}

/* The offset of the first number outside strings that JSON's grammar does
 * not allow, or -1. cJSON reads a number with strtod, so it takes "016"
 * as 16 and "1." as 1, which Python's json and safetensors' reference
 * reader refuse: one file would be two things to two readers. */
static long number_fault(const char *text, size_t len) {
  for (size_t i = 0; i < len;) {
    char c = text[i];
    if (c == '"') {
      for (i++; i < len && text[i] != '"';) i += text[i] == '\\' ? 2 : 1;
      i++;
    } else if (c == '-' || (c >= '0' && c <= '9')) {
      size_t start = i;
      while (i < len && (strchr("+-.eE", text[i]) || isdigit((unsigned char)text[i])) &&
             text[i])
        i++;
      /* "-Infinity" is not JSON either; cJSON refuses it (its number is
       * "-" alone), and the message for NaN and Infinity says why. */
      if (i - start == 1 && text[start] == '-' && i < len && isalpha((unsigned char)text[i]))
        continue;
      if (!number_ok(text + start, i - start)) return (long)start;
    } else {
      i++;
    }
  }
  return -1;
}

const char *hf_json_text_fault(const char *text, size_t len, size_t *at) {
  const unsigned char *p = (const unsigned char *)text;
  for (size_t i = 0; i < len;) {
    size_t k = utf8_len(p + i, len - i);
    if (!k) {
      if (at) *at = i;
      return "a byte that is not UTF-8";
    }
    /* Backslashes occur only in strings; an escaped one is skipped with
     * its escape, so "\\u0000" is a backslash and "u0000". */
    if (p[i] == '\\' && i + 1 < len) {
      if (p[i + 1] == 'u' && i + 6 <= len && !memcmp(p + i + 2, "0000", 4)) {
        if (at) *at = i;
        return "\\u0000 (a NUL character, at which this reader would cut its name or string "
               "short)";
      }
      /* A \uD800-\uDFFF escape is half of a UTF-16 surrogate pair: a high
       * half followed by a low one is one character; alone it is none,
       * refused by cJSON and taken by Python's json. */
      int half = p[i + 1] == 'u' && i + 6 <= len ? surrogate(p + i + 2) : 0;
      if (half == 1 && i + 12 <= len && p[i + 6] == '\\' && p[i + 7] == 'u' &&
          surrogate(p + i + 8) == 2) {
        k = 12;
      } else if (half) {
        if (at) *at = i;
        return "a \\uD800-\\uDFFF escape that is half of a UTF-16 surrogate pair, alone (no "
               "character: JSON readers disagree on it)";
      } else {
        k = 2;
      }
    }
    i += k;
  }
  long n = number_fault(text, len);
  if (n >= 0) {
    if (at) *at = (size_t)n;
    return "a number JSON does not allow (JSON writes no leading zero, no '+' before it, "
           "and digits on both sides of a '.')";
  }
  return NULL;
}

/* Skips JSON whitespace from text[i]. */
static size_t skip_ws(const char *text, size_t len, size_t i) {
  while (i < len && (text[i] == ' ' || text[i] == '\t' || text[i] == '\r' || text[i] == '\n'))
    i++;
  return i;
}

/* Whether the key whose n bytes start at text[start] (inside its quotes)
 * is key once its escapes are decoded: "sp\u0070" is "spp" to cJSON and
 * Python's json alike, so a check by name that compared the bytes as
 * written would pass it over. */
static int key_is(const char *text, size_t start, size_t n, const char *key) {
  if (!memchr(text + start, '\\', n)) return strlen(key) == n && !memcmp(text + start, key, n);
  cJSON *s = cJSON_ParseWithLength(text + start - 1, n + 2);   /* with its quotes */
  int same = cJSON_IsString(s) && !strcmp(s->valuestring, key);
  cJSON_Delete(s);
  return same;
}

/* The scan of hf_json_nonint_field and hf_json_nonint_member: the first
 * number written with a fraction or an exponent that is, in an object at
 * depth key_depth (1: the top object), an element of an array that is the
 * value of one of keys, or (when direct) that value itself. *outer_at and
 * *outer_n, when outer_at is not NULL, get the last key read at depth
 * key_depth - 1 (inside its quotes). */
static long nonint_scan(const char *text, size_t len, const char *const *keys, int nkeys,
                        int key_depth, int direct, size_t *outer_at, size_t *outer_n,
                        const char **key, size_t *tok_len) {
  int depth = 0;
  const char *target = NULL;   /* the key of keys whose value is being read */
  for (size_t i = 0; i < len;) {
    char c = text[i];
    if (c == '"') {
      size_t start = ++i;
      while (i < len && text[i] != '"') i += text[i] == '\\' ? 2 : 1;
      size_t n = i - start;
      i++;
      size_t j = skip_ws(text, len, i);
      if (j < len && text[j] == ':') {   /* a key; else a string value */
        if (depth == key_depth - 1 && outer_at) *outer_at = start, *outer_n = n;
        target = NULL;
        if (depth == key_depth)
          for (int k = 0; k < nkeys; k++)
            if (key_is(text, start, n, keys[k])) target = keys[k];
        i = j + 1;
      }
      continue;
    }
    if (c == '{' || c == '[') {
      depth++;
      /* The key's value is this array: its numbers are checked. */
      if (!(c == '[' && depth == key_depth + 1)) target = NULL;
      i++;
      continue;
    }
    if (c == '}' || c == ']') {
      if (depth <= key_depth + 1) target = NULL;
      depth--;
      i++;
      continue;
    }
    if (c == '-' || (c >= '0' && c <= '9')) {
      size_t start = i;
      int integral = 1;
      while (i < len && (text[i] == '-' || text[i] == '+' || text[i] == '.' || text[i] == 'e' ||
                         text[i] == 'E' || (text[i] >= '0' && text[i] <= '9'))) {
        if (text[i] == '.' || text[i] == 'e' || text[i] == 'E') integral = 0;
        i++;
      }
      if (target && !integral && (depth == key_depth + 1 || (direct && depth == key_depth))) {
        if (key) *key = target;
        if (tok_len) *tok_len = i - start;
        return (long)start;
      }
      if (depth == key_depth) target = NULL;
      continue;
    }
    if (c == ',' && depth == key_depth) target = NULL;
    i++;
  }
  return -1;
}

long hf_json_nonint_member(const char *text, size_t len, const char *const *keys, int nkeys,
                           char *outer, size_t outer_len, const char **key, size_t *tok_len) {
  size_t at = 0, n = 0;
  long r = nonint_scan(text, len, keys, nkeys, 2, 0, &at, &n, key, tok_len);
  if (r >= 0 && outer && outer_len)
    snprintf(outer, outer_len, "%.*s", (int)(n < outer_len ? n : outer_len - 1), text + at);
  return r;
}

long hf_json_nonint_field(const char *text, size_t len, const char *const *keys, int nkeys,
                          const char **key, size_t *tok_len) {
  return nonint_scan(text, len, keys, nkeys, 1, 1, NULL, NULL, key, tok_len);
}
