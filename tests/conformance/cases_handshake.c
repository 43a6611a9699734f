/*
 * PROTOCOL.md, "Handshake" and the text rules of "Transport": HELLO first
 * and nothing served before it, malformed HELLOs, version negotiation with
 * version-1 and version-2 peers and what each version's replies carry,
 * tokens on TCP, the handshake deadline and the limit on connections
 * before HELLO.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "cf_internal.h"

/* A HELLO of the suite's own making: versions, name and token as given,
 * then the bytes patched by the case. */
static size_t hello(const cf_test *t, uint8_t *b, size_t cap) {
  return cf_hello_frame(b, cap, 1, HFP_VERSION, "conformance", t->o->token);
}

/* ---- anything but HELLO first ------------------------------------------- */

static int first_not_hello(cf_test *t, intptr_t type) {
  uint8_t b[HFP_HEADER_SIZE + 64];
  size_t n = HFP_HEADER_SIZE;
  memset(b, 0, sizeof b);
  switch (type) {
    case HFP_SHM_CREATE: n = cf_shm_create_frame(b, 4096); break;
    case HFP_SHM_DESTROY: n = cf_shm_destroy_frame(b, 1); break;
    case HFP_FILTER: {
      cf_filter f = {.id = 1};
      cf_filter_defaults(t, &f);
      uint8_t *fb = cf_filter_frame(t, &f, &n);
      CF_CHECK(t, fb, "out of memory");
      int fd;
      CF_TRY(cf_connect(t, &fd));
      CF_TRY(cf_send(t, fd, fb, n));
      return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
    }
    default:
      /* Empty requests, and server-to-client types with a plausible length. */
      cf_header(b, (int)type, 0, 0, type == HFP_LIST_VARIANTS || type == HFP_STATS ? 0 : 48);
      n = HFP_HEADER_SIZE + (type == HFP_LIST_VARIANTS || type == HFP_STATS ? 0 : 48);
  }
  /* LIST_VARIANTS after it: nothing may be served before HELLO. */
  cf_header(b + n, HFP_LIST_VARIANTS, 0, 0, 0);
  n += HFP_HEADER_SIZE;
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* HELLO frames whose length field is out of 8 .. 8 + 64 + 256. */
static int hello_length(cf_test *t, intptr_t length) {
  uint8_t b[HFP_HEADER_SIZE + 400];
  memset(b, 'a', sizeof b);
  cf_header(b, HFP_HELLO, 0, 0, (uint32_t)length);
  size_t n = HFP_HEADER_SIZE + (length < 400 ? (size_t)length : 400);
  if (length >= 8) {
    /* A payload whose fields agree with what is sent, as far as they can. */
    hfp_put_u16(b + 16, 1);
    hfp_put_u16(b + 18, HFP_VERSION);
    hfp_put_u16(b + 20, 64);
    hfp_put_u16(b + 22, (uint16_t)(length - 8 - 64 > 256 ? 256 : length - 8 - 64));
  }
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

enum {
  BAD_NAME_LEN_0, BAD_NAME_LEN_65, BAD_TOKEN_LEN_257, BAD_NAME_PAST_END, BAD_TRAILING,
  BAD_MISSING, BAD_NAME_SPACE, BAD_NAME_DEL, BAD_NAME_NUL, BAD_NAME_HIGH, BAD_NAME_ESC,
  BAD_TOKEN_SPACE, BAD_TOKEN_NUL, BAD_TOKEN_HIGH,
};

/* A HELLO whose payload does not decode: a fatal PROTOCOL error. */
static int hello_malformed(cf_test *t, intptr_t how) {
  uint8_t b[HFP_HEADER_SIZE + 8 + 400];
  memset(b, 'x', sizeof b);
  size_t n = cf_hello_frame(b, sizeof b, 1, HFP_VERSION, "conformance", "tok");
  uint8_t *p = b + HFP_HEADER_SIZE;
  size_t name_at = 8, token_at = 8 + 11;
  switch (how) {
    case BAD_NAME_LEN_0: hfp_put_u16(p + 4, 0); break;
    case BAD_NAME_LEN_65:
      hfp_put_u16(p + 4, 65);
      hfp_put_u16(p + 6, 0);
      n = HFP_HEADER_SIZE + 8 + 65;
      break;
    case BAD_TOKEN_LEN_257:
      hfp_put_u16(p + 6, 257);
      n = HFP_HEADER_SIZE + 8 + 11 + 257;
      break;
    case BAD_NAME_PAST_END: hfp_put_u16(p + 4, 40); break;   /* more than is there */
    case BAD_TRAILING: n++; break;
    case BAD_MISSING: n--; break;
    case BAD_NAME_SPACE: p[name_at + 3] = ' '; break;
    case BAD_NAME_DEL: p[name_at + 3] = 0x7f; break;
    case BAD_NAME_NUL: p[name_at + 3] = 0; break;
    case BAD_NAME_HIGH: p[name_at + 3] = 0xc3; break;
    case BAD_NAME_ESC: p[name_at + 3] = 0x1b; break;
    case BAD_TOKEN_SPACE: p[token_at + 1] = ' '; break;
    case BAD_TOKEN_NUL: p[token_at + 1] = 0; break;
    case BAD_TOKEN_HIGH: p[token_at + 1] = 0xff; break;
  }
  cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE));
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* Names of every printable byte, and the longest name and token. */
static int hello_printable(cf_test *t, intptr_t part) {
  char name[65];
  for (int i = 0; i < 64; i++) name[i] = (char)(0x21 + (part * 64 + i) % 94);
  name[64] = 0;
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, 1, HFP_VERSION, name, t->o->token);
  CF_CHECK(t, n, "cannot encode the HELLO");
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  cf_frame f;
  return cf_expect(t, fd, HFP_HELLO_OK, &f);
}

/* A 256-byte token: accepted where tokens are not checked, refused with
 * UNAUTHORIZED (not a decoding error) where they are and it is wrong. */
static int hello_longest_token(cf_test *t, intptr_t arg) {
  (void)arg;
  char token[HFP_TOKEN_MAX + 1];
  for (int i = 0; i < HFP_TOKEN_MAX; i++) token[i] = (char)('a' + i % 26);
  token[HFP_TOKEN_MAX] = 0;
  int right = t->o->token && !strcmp(t->o->token, token);
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, 1, HFP_VERSION, "conformance", token);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  if (t->srv->auth && !right) return cf_expect_error(t, fd, HFP_E_UNAUTHORIZED, 1, 0);
  cf_frame f;
  return cf_expect(t, fd, HFP_HELLO_OK, &f);
}

/* A HELLO after the handshake. With over_max, only its header, claiming
 * 4 GiB: the type is checked before the length, and a second HELLO is no
 * request of this state whatever it claims, so still PROTOCOL, not the
 * TOO_LARGE of a request over max_frame_bytes. */
static int second_hello(cf_test *t, intptr_t over_max) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = hello(t, b, sizeof b);
  if (over_max) {
    hfp_put_u32(b + 12, UINT32_MAX);
    n = HFP_HEADER_SIZE;
  }
  CF_TRY(cf_send(t, fd, b, n));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

static int hello_id_ignored(cf_test *t, intptr_t arg) {
  (void)arg;
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = hello(t, b, sizeof b);
  hfp_put_u32(b + 8, 0xdeadbeefu);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, HFP_HELLO_OK, &f));
  CF_CHECK(t, f.h.request_id == 0, "HELLO_OK carries request id %u, not 0", f.h.request_id);
  return 0;
}

/* HELLO_OK's fields against the rest of what the server says. */
static int hello_ok_fields(cf_test *t, intptr_t arg) {
  (void)arg;
  const cf_server *s = t->srv;
  const hfp_hello_ok *h = &s->hello;
  int max_spp = 0;
  for (int i = 0; i < s->nv; i++)
    if (s->variants[i].spp > max_spp) max_spp = s->variants[i].spp;
  CF_CHECK(t, h->max_spp == max_spp, "HELLO_OK max_spp %u, the variants' largest spp is %d",
           h->max_spp, max_spp);
  CF_CHECK(t, (h->server_flags & ~3u) == 0, "HELLO_OK server_flags 0x%x: unknown bits",
           h->server_flags);
  CF_CHECK(t, !(h->server_flags & HFP_SERVER_SHM) || s->is_unix,
           "HELLO_OK offers shared memory on a TCP connection");
  CF_CHECK(t, !!(h->server_flags & HFP_SERVER_AUTH_REQUIRED) == s->auth,
           "HELLO_OK bit 0 (token checked) is %d, but a HELLO without a token was %s",
           !!(h->server_flags & HFP_SERVER_AUTH_REQUIRED), s->auth ? "refused" : "accepted");
  /* The promise: the largest frame fits max_frame_bytes. */
  uint64_t feat = 0;
  hfp_features_bytes(h->max_width, h->max_height, (uint32_t)s->variants[0].spp, HFP_F32, &feat);
  for (int i = 0; i < s->nv; i++) {
    uint64_t b = 0;
    hfp_features_bytes(h->max_width, h->max_height, s->variants[i].spp, HFP_F32, &b);
    size_t vn = strlen(s->variants[i].name);
    CF_CHECK(t, HFP_FILTER_FIXED + vn + b <= h->max_frame_bytes,
             "a %ux%u f32 FILTER for %s (%llu bytes) does not fit max_frame_bytes %llu",
             h->max_width, h->max_height, s->variants[i].name,
             (unsigned long long)(HFP_FILTER_FIXED + vn + b),
             (unsigned long long)h->max_frame_bytes);
  }
  (void)feat;
  return 0;
}

/* ---- versions --------------------------------------------------------------- */

/* The highest version in lo..hi the server speaks (by the probe), or 0. */
static int expected_version(const cf_server *s, int lo, int hi) {
  int best = 0;
  for (int k = 1; k <= HFP_VERSION + 1; k++)
    if (s->speaks[k] && k >= lo && k <= hi) best = k;
  /* Beyond what the probe asked: a server that speaks HFP_VERSION + 1 may
   * speak more; such ranges are judged by what they must at least get. */
  return best;
}

static const uint16_t version_ranges[][2] = {
  {1, 1}, {2, 2}, {1, 2}, {0, 1}, {0, 2}, {0, 65535}, {1, 65535}, {2, 65535},
  {3, 3}, {3, 65535}, {2, 1}, {0, 0}, {65535, 65535}, {65535, 0},
};

/* What follows the server name in HELLO_OK: nothing on version 1 (its
 * frame byte for byte); on version 2 the software block, software_len
 * (0..64) and that many printable bytes without spaces (or no block, from
 * a server that does not say). */
static int hello_ok_tail(cf_test *t, intptr_t version) {
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, (int)version, (int)version, "conformance", t->o->token);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, HFP_HELLO_OK, &f));
  CF_CHECK(t, f.h.length >= 38, "HELLO_OK of %u bytes, shorter than its fixed fields", f.h.length);
  size_t name_end = 38 + (size_t)hfp_get_u16(f.p + 36);
  CF_CHECK(t, f.h.length >= name_end, "HELLO_OK ends inside its server name");
  size_t tail = f.h.length - name_end;
  if (version == 1) {
    CF_CHECK(t, tail == 0, "a version-1 HELLO_OK has %zu bytes after the server name", tail);
    return cf_still_serves(t, fd);
  }
  if (tail) {
    size_t sw = f.p[name_end];
    CF_CHECK(t, sw <= 64 && tail == 1 + sw,
             "HELLO_OK's software block says %zu bytes and %zu follow the name", sw, tail);
    for (size_t i = 0; i < sw; i++) {
      uint8_t ch = f.p[name_end + 1 + i];
      CF_CHECK(t, ch > 0x20 && ch < 0x7f, "byte %zu of the software version is 0x%02x", i, ch);
    }
  }
  return cf_still_serves(t, fd);
}

static int version_range(cf_test *t, intptr_t i) {
  int lo = version_ranges[i][0], hi = version_ranges[i][1];
  int want = lo <= hi ? expected_version(t->srv, lo, hi) : 0;
  int open_top = hi > HFP_VERSION + 1;
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, lo, hi, "conformance", t->o->token);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  cf_frame f;
  int rc = cf_read(t, fd, t->o->timeout_ms, &f);
  CF_CHECK(t, rc == CF_GOT, "no reply to a HELLO offering %d..%d", lo, hi);
  if (f.h.type == HFP_ERROR) {
    hfp_error e;
    CF_CHECK(t, hfp_decode_error(f.p, f.h.length, &e) == 0, "the ERROR does not decode");
    CF_CHECK(t, want == 0,
             "HELLO %d..%d was refused (%s: %s), but the server speaks version %d", lo, hi,
             hfp_code_name((int)e.code), e.message, want);
    CF_CHECK(t, e.code == HFP_E_VERSION && e.fatal && f.h.request_id == 0,
             "HELLO %d..%d: wanted a fatal VERSION with id 0, got %s (fatal %d, id %u)", lo, hi,
             hfp_code_name((int)e.code), e.fatal, f.h.request_id);
    return cf_expect_eof(t, fd);
  }
  char tn[16];
  CF_CHECK(t, f.h.type == HFP_HELLO_OK, "the reply to HELLO is %s, not HELLO_OK",
           cf_type_name(f.h.type, tn));
  hfp_hello_ok ok;
  /* The codec reads versions 1..HFP_VERSION; decode the version by hand. */
  CF_CHECK(t, f.h.length >= 2, "HELLO_OK too short");
  int got = hfp_get_u16(f.p);
  if (got <= HFP_VERSION) {
    rc = hfp_decode_hello_ok(f.p, f.h.length, &ok);
    CF_CHECK(t, rc == 0, "HELLO_OK does not decode: %s", hfp_strerror(rc));
  }
  CF_CHECK(t, want != 0 || (open_top && got > HFP_VERSION + 1),
           "HELLO %d..%d was accepted with version %d, but the server speaks none of them", lo, hi,
           got);
  CF_CHECK(t, got >= lo && got <= hi, "HELLO %d..%d got version %d, outside the range", lo, hi, got);
  CF_CHECK(t, got >= want, "HELLO %d..%d got version %d, not the highest in common (%d)", lo, hi,
           got, want);
  return 0;
}

/* Bytes of a reply at one version re-encoded from what they decode to:
 * equal only when the reply carries exactly that version's blocks. */
static int reply_at_version(cf_test *t, intptr_t which) {
  int version = (int)(which & 0xff), stats = (int)(which >> 8);
  if (!t->srv->speaks[version]) return cf_skip(t, "the server does not speak version %d", version);
  int fd;
  CF_TRY(cf_connect_hello(t, version, version, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, stats ? HFP_STATS : HFP_LIST_VARIANTS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, stats ? HFP_STATS_REPLY : HFP_VARIANTS, &f));
  uint8_t *again = cf_alloc(t, f.h.length + HFP_HEADER_SIZE + 64);
  int n;
  if (stats) {
    hfp_stats *st = cf_alloc(t, sizeof *st);
    int rc = hfp_decode_stats(f.p, f.h.length, st);
    CF_CHECK(t, rc == 0, "STATS_REPLY does not decode: %s", hfp_strerror(rc));
    n = hfp_encode_stats_v(again, f.h.length + HFP_HEADER_SIZE + 64, st, version);
  } else {
    hfp_variant *v = cf_alloc(t, sizeof *v * HFP_MAX_VARIANTS);
    int count = 0;
    int rc = hfp_decode_variants(f.p, f.h.length, v, HFP_MAX_VARIANTS, &count);
    CF_CHECK(t, rc == 0, "VARIANTS does not decode: %s", hfp_strerror(rc));
    n = hfp_encode_variants_v(again, f.h.length + HFP_HEADER_SIZE + 64, v, count, version);
  }
  CF_CHECK(t, n == (int)(f.h.length + HFP_HEADER_SIZE) &&
                  !memcmp(again + HFP_HEADER_SIZE, f.p, f.h.length),
           "%s on a version-%d connection is %u bytes, a version-%d one of its content %d: %s",
           stats ? "STATS_REPLY" : "VARIANTS", version, f.h.length, version,
           n - HFP_HEADER_SIZE,
           version == 1 ? "version-2 blocks were sent to a version-1 peer"
                        : "the version-2 blocks are missing or malformed");
  return 0;
}

/* A frame with non-finite samples: sanitised, flagged (bit 2) only on
 * version 2, counted in STATS either way. */
static int sanitised_flag(cf_test *t, intptr_t version) {
  if (!t->srv->speaks[version]) return cf_skip(t, "the server does not speak version %d", (int)version);
  int fd;
  CF_TRY(cf_connect_hello(t, (int)version, (int)version, &fd, NULL));
  cf_filter f = {.id = 7, .features = CF_FEAT_NAN};
  cf_filter_defaults(t, &f);
  uint8_t flags = 0;
  CF_TRY(cf_filter_ok(t, fd, &f, (int)version, NULL, &flags));
  if (version >= 2)
    CF_CHECK(t, flags & HFP_RESULT_INPUT_SANITISED,
             "a frame with NaN and infinite samples came back without flag bit 2 (sanitised)");
  /* A clean frame is never flagged sanitised. */
  f.features = CF_FEAT_PLAUSIBLE;
  f.id = 8;
  CF_TRY(cf_filter_ok(t, fd, &f, (int)version, NULL, &flags));
  CF_CHECK(t, !(flags & HFP_RESULT_INPUT_SANITISED), "a clean frame came back flagged sanitised");
  return 0;
}

static int stats_of(cf_test *t, hfp_stats *st) {
  int fd;
  CF_TRY(cf_connect_hello(t, 2, 2, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, HFP_STATS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, HFP_STATS_REPLY, &f));
  int rc = hfp_decode_stats(f.p, f.h.length, st);
  CF_CHECK(t, rc == 0, "STATS_REPLY does not decode: %s", hfp_strerror(rc));
  cf_close(t, fd);
  return 0;
}

static const hfp_variant_stats *vstats(const hfp_stats *st, const char *name) {
  for (int i = 0; i < st->num_variants; i++)
    if (!strcmp(st->variants[i].name, name)) return &st->variants[i];
  return NULL;
}

/* A version-1 frame with sanitised input is counted where version 2 sees it. */
static int sanitised_counted(cf_test *t, intptr_t arg) {
  (void)arg;
  hfp_stats *a = cf_alloc(t, sizeof *a), *b = cf_alloc(t, sizeof *b);
  CF_TRY(stats_of(t, a));
  int fd;
  CF_TRY(cf_connect_hello(t, 1, 1, &fd, NULL));
  cf_filter f = {.id = 9, .features = CF_FEAT_NAN};
  cf_filter_defaults(t, &f);
  CF_TRY(cf_filter_ok(t, fd, &f, 1, NULL, NULL));
  CF_TRY(stats_of(t, b));
  const hfp_variant_stats *va = vstats(a, f.variant), *vb = vstats(b, f.variant);
  CF_CHECK(t, va && vb, "STATS has no entry for %s", f.variant);
  CF_CHECK(t, vb->frames_sanitised > va->frames_sanitised,
           "frames_sanitised of %s stayed %llu after a sanitised frame on a version-1 connection",
           f.variant, (unsigned long long)vb->frames_sanitised);
  return 0;
}

/* A frame outside a variant's recorded range: every sample covered with one
 * alpha (so strand_alpha_p50 and _p90 are that alpha, full_coverage and
 * hair_fraction 1). Returns the alpha that puts it outside, or 0. */
static float outside_alpha(const hfp_variant *v) {
  static const float alphas[] = {1.0f, 0.5f, 0.25f, 0.125f, 0.0625f, 0.015625f};
  for (size_t i = 0; i < sizeof alphas / sizeof alphas[0]; i++) {
    float a = alphas[i];
    for (int k = 0; k < v->num_ranges; k++) {
      double x = v->ranges[k].stat <= 1 ? a : v->ranges[k].stat <= 3 ? 1.0 : -1;
      if (x >= 0 && (x < v->ranges[k].lo || x > v->ranges[k].hi)) return a;
    }
  }
  return 0;
}

static int out_of_range(cf_test *t, intptr_t version) {
  const cf_server *s = t->srv;
  if (!s->speaks[version]) return cf_skip(t, "the server does not speak version %d", (int)version);
  int vi = -1, plain = -1;
  float a = 0;
  for (int i = 0; i < s->nv; i++) {
    if (!s->variants[i].num_ranges && !s->variants[i].estimate && plain < 0) plain = i;
    if (vi < 0 && (a = outside_alpha(&s->variants[i])) > 0) vi = i;
  }
  if (vi < 0 && version == 2)
    return cf_skip(t, "no variant records a range a frame of uniform alpha can leave");
  int fd;
  CF_TRY(cf_connect_hello(t, (int)version, (int)version, &fd, NULL));
  uint8_t flags = 0;
  if (vi >= 0) {
    cf_filter f = {.id = 11, .variant = s->variants[vi].name, .features = CF_FEAT_COVERED,
                   .alpha = a};
    cf_filter_defaults(t, &f);
    CF_TRY(cf_filter_ok(t, fd, &f, (int)version, NULL, &flags));
    if (version >= 2)
      CF_CHECK(t, flags & HFP_RESULT_OUT_OF_RANGE,
               "a frame of strand alpha %g came back without flag bit 3, outside %s's range", a,
               f.variant);
  }
  if (plain >= 0) {
    /* A variant without a range never sets it. */
    cf_filter f = {.id = 12, .variant = s->variants[plain].name, .features = CF_FEAT_COVERED,
                   .alpha = 1.0f};
    cf_filter_defaults(t, &f);
    CF_TRY(cf_filter_ok(t, fd, &f, (int)version, NULL, &flags));
    CF_CHECK(t, !(flags & HFP_RESULT_OUT_OF_RANGE),
             "variant %s records no range, yet its RESULT has flag bit 3", f.variant);
  }
  return 0;
}

static int out_of_range_counted(cf_test *t, intptr_t arg) {
  (void)arg;
  const cf_server *s = t->srv;
  int vi = -1;
  float a = 0;
  for (int i = 0; i < s->nv && vi < 0; i++)
    if ((a = outside_alpha(&s->variants[i])) > 0) vi = i;
  if (vi < 0) return cf_skip(t, "no variant records a range a frame of uniform alpha can leave");
  hfp_stats *sa = cf_alloc(t, sizeof *sa), *sb = cf_alloc(t, sizeof *sb);
  CF_TRY(stats_of(t, sa));
  int fd;
  CF_TRY(cf_connect_hello(t, 1, 1, &fd, NULL));
  cf_filter f = {.id = 13, .variant = s->variants[vi].name, .features = CF_FEAT_COVERED, .alpha = a};
  cf_filter_defaults(t, &f);
  CF_TRY(cf_filter_ok(t, fd, &f, 1, NULL, NULL));
  CF_TRY(stats_of(t, sb));
  const hfp_variant_stats *va = vstats(sa, f.variant), *vb = vstats(sb, f.variant);
  CF_CHECK(t, va && vb, "STATS has no entry for %s", f.variant);
  CF_CHECK(t, vb->out_of_range > va->out_of_range,
           "out_of_range of %s stayed %llu after a frame outside its range (version 1)", f.variant,
           (unsigned long long)vb->out_of_range);
  return 0;
}

/* ---- tokens ---------------------------------------------------------------- */

enum { TOK_NONE, TOK_WRONG, TOK_PREFIX, TOK_LONGER, TOK_CASE, TOK_RIGHT, TOK_WRONG_NO_VERSION };

static int token_case(cf_test *t, intptr_t how) {
  const char *right = t->o->token ? t->o->token : "";
  char tok[HFP_TOKEN_MAX + 2];
  snprintf(tok, sizeof tok, "%s", right);
  size_t n = strlen(tok);
  int lo = 1, hi = HFP_VERSION;
  switch (how) {
    case TOK_NONE: tok[0] = 0; break;
    case TOK_WRONG_NO_VERSION:
      /* No version in common as well: the token is checked first, so the
       * peer learns nothing of the server, not even the versions it speaks. */
      lo = hi = 65535;
      /* fall through */
    case TOK_WRONG: snprintf(tok, sizeof tok, "%s", strcmp(right, "not-the-token") ? "not-the-token" : "other"); break;
    case TOK_PREFIX:
      if (n < 2) return cf_skip(t, "the token is too short to cut");
      tok[n - 1] = 0;
      break;
    case TOK_LONGER:
      if (n >= HFP_TOKEN_MAX) return cf_skip(t, "the token is as long as tokens go");
      tok[n] = 'x', tok[n + 1] = 0;
      break;
    case TOK_CASE: {
      size_t i = 0;
      while (i < n && !((tok[i] >= 'a' && tok[i] <= 'z') || (tok[i] >= 'A' && tok[i] <= 'Z'))) i++;
      if (i == n) return cf_skip(t, "the token has no letter to change");
      tok[i] ^= 0x20;
      break;
    }
  }
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t len = cf_hello_frame(b, sizeof b, lo, hi, "conformance", tok);
  /* A request after it in the same write: nothing is served to a peer
   * that failed the check. */
  cf_header(b + len, HFP_STATS, 0, 0, 0);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, len + (how == TOK_RIGHT ? 0 : HFP_HEADER_SIZE)));
  if (how == TOK_RIGHT) {
    cf_frame f;
    CF_TRY(cf_expect(t, fd, HFP_HELLO_OK, &f));
    hfp_hello_ok ok;
    CF_CHECK(t, hfp_decode_hello_ok(f.p, f.h.length, &ok) == 0, "HELLO_OK does not decode");
    CF_CHECK(t, ok.server_flags & HFP_SERVER_AUTH_REQUIRED,
             "HELLO_OK of a listener that checked the token lacks server_flags bit 0");
    return 0;
  }
  return cf_expect_error(t, fd, HFP_E_UNAUTHORIZED, 1, 0);
}

/* Unix sockets ignore the token: any token is accepted, and bit 0 is clear. */
static int unix_ignores_token(cf_test *t, intptr_t arg) {
  (void)arg;
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = cf_hello_frame(b, sizeof b, 1, HFP_VERSION, "conformance", "any-token-at-all");
  int fd;
  CF_TRY(cf_connect(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, HFP_HELLO_OK, &f));
  hfp_hello_ok ok;
  CF_CHECK(t, hfp_decode_hello_ok(f.p, f.h.length, &ok) == 0, "HELLO_OK does not decode");
  CF_CHECK(t, !(ok.server_flags & HFP_SERVER_AUTH_REQUIRED),
           "a Unix socket's HELLO_OK says it checked a token (bit 0)");
  return 0;
}

/* ---- deadlines and crowds -------------------------------------------------- */

/* Before HELLO, a server may close a silent peer (fatal PROTOCOL, id 0) or
 * wait; if it waited, the HELLO still works. */
static int silent_before_hello(cf_test *t, intptr_t trickle) {
  uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t n = hello(t, b, sizeof b);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  size_t sent = 0;
  double end = cf_now_ms() + t->o->stall_ms;
  if (trickle) {
    /* One byte at a time over the stall time, holding back the last one. */
    int step = t->o->stall_ms / (int)n;
    while (sent + 1 < n && cf_now_ms() < end) {
      /* A send that fails means the server has closed: see why below. */
      if (send(fd, b + sent, 1, MSG_NOSIGNAL) != 1) break;
      sent++;
      cf_sleep_ms(step > 0 ? step : 1);
    }
  } else {
    cf_sleep_ms(t->o->stall_ms);
  }
  cf_frame f;
  char d[400];
  int rc = cf_read(t, fd, 0, &f);
  if (rc == CF_GOT) {
    cf_close(t, fd);
    /* Closed by the deadline: that must say so. */
    hfp_error e;
    CF_CHECK(t, f.h.type == HFP_ERROR && hfp_decode_error(f.p, f.h.length, &e) == 0 &&
                    (e.code == HFP_E_PROTOCOL || e.code == HFP_E_BUSY) && e.fatal &&
                    f.h.request_id == 0,
             "a peer silent before HELLO got %s, not a fatal PROTOCOL with id 0",
             cf_describe(&f, d, sizeof d));
    return 0;
  }
  if (rc == CF_EOF) return cf_fail(t, "the server closed a peer silent before HELLO without an ERROR");
  if (rc == CF_FAIL) return rc;
  /* The deadline may strike as the rest goes out: then the ERROR below. */
  if (send(fd, b + sent, n - sent, MSG_NOSIGNAL) < 0) {
  }
  rc = cf_read(t, fd, t->o->timeout_ms, &f);
  if (rc == CF_GOT && f.h.type == HFP_HELLO_OK) return 0;
  if (rc == CF_GOT && f.h.type == HFP_ERROR) {
    /* The deadline struck while the rest was on its way. */
    hfp_error e;
    CF_CHECK(t, hfp_decode_error(f.p, f.h.length, &e) == 0 && e.code == HFP_E_PROTOCOL && e.fatal,
             "got %s", cf_describe(&f, d, sizeof d));
    return 0;
  }
  return cf_fail(t, "after a slow HELLO: %s",
                 rc == CF_GOT ? cf_describe(&f, d, sizeof d) : "no HELLO_OK");
}

/* Many connections that never say HELLO: an ordinary client still gets in,
 * and each of them is either still waiting or was closed with a fatal BUSY
 * or PROTOCOL. */
static int crowd_before_hello(cf_test *t, intptr_t count) {
  int fds[128];
  for (int i = 0; i < count; i++) CF_TRY(cf_connect(t, &fds[i]));
  cf_sleep_ms(50);
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  CF_TRY(cf_still_serves(t, fd));
  int closed = 0;
  for (int i = 0; i < count; i++) {
    cf_frame f;
    char d[400];
    int rc = cf_read(t, fds[i], 0, &f);
    if (rc == CF_TIMEOUT) continue;
    CF_CHECK(t, rc == CF_GOT, "connection %d before HELLO was closed without an ERROR", i);
    hfp_error e;
    CF_CHECK(t, f.h.type == HFP_ERROR && hfp_decode_error(f.p, f.h.length, &e) == 0 && e.fatal &&
                    (e.code == HFP_E_BUSY || e.code == HFP_E_PROTOCOL) && f.h.request_id == 0,
             "connection %d before HELLO got %s", i, cf_describe(&f, d, sizeof d));
    closed++;
  }
  (void)closed;
  return 0;
}

#define FIRST(type, name) \
  {"handshake.first_not_hello." name, "the first frame must be HELLO; anything else is a fatal PROTOCOL with id 0, nothing served", 0, first_not_hello, type}
#define LEN(n, name) \
  {"handshake.hello_length." name, "a HELLO whose length is under 8 or over 8+64+256 is a fatal PROTOCOL", 0, hello_length, n}
#define BAD(how, name, rule) {"handshake.hello_malformed." name, rule, 0, hello_malformed, how}
#define VR(i, lo, hi) \
  {"version.range." #lo "_" #hi, "the server picks the highest version in [min, max] it speaks, else a fatal VERSION", 0, version_range, i}
#define TOK(how, name, rule) {"auth." name, rule, CF_NEED_TCP | CF_NEED_AUTH, token_case, how}

const cf_case cf_cases_handshake[] = {
  FIRST(HFP_LIST_VARIANTS, "list_variants"),
  FIRST(HFP_STATS, "stats"),
  FIRST(HFP_FILTER, "filter"),
  FIRST(HFP_SHM_CREATE, "shm_create"),
  FIRST(HFP_SHM_DESTROY, "shm_destroy"),
  FIRST(HFP_HELLO_OK, "hello_ok"),
  FIRST(HFP_VARIANTS, "variants"),
  FIRST(HFP_RESULT, "result"),
  FIRST(HFP_ERROR, "error"),
  FIRST(HFP_STATS_REPLY, "stats_reply"),
  FIRST(HFP_SHM_CREATED, "shm_created"),
  LEN(0, "zero"),
  LEN(1, "one"),
  LEN(7, "seven"),
  LEN(8 + HFP_NAME_MAX + HFP_TOKEN_MAX + 1, "max_plus_one"),
  LEN(0xffffffff, "u32_max"),
  BAD(BAD_NAME_LEN_0, "name_len_zero", "a HELLO's name_len is 1..64"),
  BAD(BAD_NAME_LEN_65, "name_len_65", "a HELLO's name_len is 1..64"),
  BAD(BAD_TOKEN_LEN_257, "token_len_257", "a HELLO's token_len is 0..256"),
  BAD(BAD_NAME_PAST_END, "name_past_end", "lengths that disagree with the payload are a fatal PROTOCOL"),
  BAD(BAD_TRAILING, "trailing_byte", "a payload with trailing bytes does not decode"),
  BAD(BAD_MISSING, "missing_byte", "a payload with missing bytes does not decode"),
  BAD(BAD_NAME_SPACE, "name_space", "names are bytes 0x21..0x7E"),
  BAD(BAD_NAME_DEL, "name_del", "names are bytes 0x21..0x7E"),
  BAD(BAD_NAME_NUL, "name_nul", "names are bytes 0x21..0x7E"),
  BAD(BAD_NAME_HIGH, "name_non_ascii", "names are bytes 0x21..0x7E"),
  BAD(BAD_NAME_ESC, "name_escape", "names are bytes 0x21..0x7E"),
  BAD(BAD_TOKEN_SPACE, "token_space", "tokens are bytes 0x21..0x7E"),
  BAD(BAD_TOKEN_NUL, "token_nul", "tokens are bytes 0x21..0x7E"),
  BAD(BAD_TOKEN_HIGH, "token_non_ascii", "tokens are bytes 0x21..0x7E"),
  {"handshake.name_printable.first", "every byte 0x21..0x7E is allowed in a name (64 bytes)", 0, hello_printable, 0},
  {"handshake.name_printable.second", "every byte 0x21..0x7E is allowed in a name (64 bytes)", 0, hello_printable, 1},
  {"handshake.longest_token", "a 256-byte token decodes: accepted, or UNAUTHORIZED where it is wrong", 0, hello_longest_token, 0},
  {"handshake.second_hello", "a repeated HELLO is a fatal PROTOCOL", 0, second_hello, 0},
  {"handshake.second_hello_over_max", "a repeated HELLO claiming 4 GiB is a fatal PROTOCOL, not TOO_LARGE", 0, second_hello, 1},
  {"handshake.request_id_ignored", "HELLO_OK carries id 0 whatever the HELLO's id", 0, hello_id_ignored, 0},
  {"handshake.hello_ok_fields", "HELLO_OK's max_spp, flags and size promise agree with the server", 0, hello_ok_fields, 0},
  {"handshake.silent", "a server may close a peer silent before HELLO (fatal PROTOCOL, id 0); if not, HELLO works", 0, silent_before_hello, 0},
  {"handshake.trickled", "a HELLO trickled over the deadline: served, or a fatal PROTOCOL", 0, silent_before_hello, 1},
  {"handshake.crowd", "peers that never say HELLO cannot keep an ordinary client out (fatal BUSY for the oldest)", 0, crowd_before_hello, 40},
  VR(0, 1, 1),
  VR(1, 2, 2),
  VR(2, 1, 2),
  VR(3, 0, 1),
  VR(4, 0, 2),
  VR(5, 0, 65535),
  VR(6, 1, 65535),
  VR(7, 2, 65535),
  VR(8, 3, 3),
  VR(9, 3, 65535),
  VR(10, 2, 1),
  VR(11, 0, 0),
  VR(12, 65535, 65535),
  VR(13, 65535, 0),
  {"version.v1.hello_ok", "a version-1 HELLO_OK ends with the server name", 0, hello_ok_tail, 1},
  {"version.v2.software_version", "a version-2 HELLO_OK's software block: 0..64 printable bytes without spaces", CF_NEED_V2, hello_ok_tail, 2},
  {"version.v1.variants", "a version-1 connection gets VARIANTS without the range blocks", 0, reply_at_version, 1},
  {"version.v2.variants", "a version-2 connection gets VARIANTS with one range block per entry", CF_NEED_V2, reply_at_version, 2},
  {"version.v1.stats", "a version-1 connection gets STATS_REPLY without the counters", 0, reply_at_version, 1 | 1 << 8},
  {"version.v2.stats", "a version-2 connection gets STATS_REPLY with the counters", CF_NEED_V2, reply_at_version, 2 | 1 << 8},
  {"version.v1.sanitised_not_flagged", "RESULT flag bit 2 never reaches a version-1 peer", 0, sanitised_flag, 1},
  {"version.v2.sanitised_flagged", "RESULT flag bit 2 is set for a frame with non-finite samples (version 2)", CF_NEED_V2, sanitised_flag, 2},
  {"version.v1.sanitised_counted", "a version-1 frame with sanitised input is counted in frames_sanitised", CF_NEED_V2, sanitised_counted, 0},
  {"version.v1.out_of_range_not_flagged", "RESULT flag bit 3 never reaches a version-1 peer", 0, out_of_range, 1},
  {"version.v2.out_of_range_flagged", "RESULT flag bit 3 for a frame outside the trained range; never for a variant without one", CF_NEED_V2, out_of_range, 2},
  {"version.v1.out_of_range_counted", "a version-1 frame outside the range is counted in out_of_range", CF_NEED_V2, out_of_range_counted, 0},
  TOK(TOK_NONE, "missing_token", "a TCP listener that checks tokens refuses a HELLO without one: fatal UNAUTHORIZED"),
  TOK(TOK_WRONG, "wrong_token", "a wrong token: fatal UNAUTHORIZED, nothing served"),
  TOK(TOK_PREFIX, "token_prefix", "the token less its last byte: fatal UNAUTHORIZED"),
  TOK(TOK_LONGER, "token_longer", "the token and one byte more: fatal UNAUTHORIZED"),
  TOK(TOK_CASE, "token_case", "the token with one letter's case changed: fatal UNAUTHORIZED"),
  TOK(TOK_WRONG_NO_VERSION, "before_version", "a wrong token and no version in common: fatal UNAUTHORIZED (the token is checked first)"),
  TOK(TOK_RIGHT, "right_token", "the right token is accepted and HELLO_OK sets bit 0"),
  {"auth.unix_ignores_token", "Unix sockets ignore the token and clear bit 0", CF_NEED_UNIX, unix_ignores_token, 0},
  {NULL, NULL, 0, NULL, 0},
};
