/*
 * hfproto.c: encoders and decoders of protocol versions 1, 2 and 3 (PROTOCOL.md).
 *
 * Decoding goes through a bounds-checked reader: every get either succeeds
 * or latches an error, and callers check the latch once at the end. That
 * keeps each decoder a straight transcription of its PROTOCOL.md table while
 * still making a short frame impossible to over-read.
 */
#define _POSIX_C_SOURCE 200809L
#include "hfproto.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "hfproto: tensors are sent in host order, which must be little-endian"
#endif

static const char *const messages[HFP_E_COUNT] = {
  [HFP_OK] = "ok",
  [HFP_E_VERSION] = "no common protocol version",
  [HFP_E_PROTOCOL] = "malformed frame or unexpected message",
  [HFP_E_UNKNOWN_VARIANT] = "unknown variant",
  [HFP_E_TOO_LARGE] = "dimensions or frame over the server's limits",
  [HFP_E_LENGTH] = "payload length does not match its fields",
  [HFP_E_BUSY] = "server busy: a queue, in-flight, memory or connection limit is full; retry later",
  [HFP_E_UNAUTHORIZED] = "unauthorized: missing or wrong token",
  [HFP_E_INTERNAL] = "internal server error",
  [HFP_E_UNSUPPORTED] =
      "not supported here (a dtype, a flag, or shared memory on this connection)",
  [HFP_E_SHUTTING_DOWN] = "server shutting down",
  [HFP_E_INVALID] = "field out of range",
  [HFP_E_NOSPACE] = "buffer too small",
  [HFP_E_EXPIRED] = "the frame's deadline passed before it ran; retrying cannot help",
  [HFP_E_CANCELLED] = "cancelled by the client before it ran",
};

const char *hfp_strerror(int code) {
  if (code < 0) code = -code;
  if (code >= HFP_E_COUNT) return "unknown protocol error";
  return messages[code];
}

static const char *const names[HFP_E_COUNT] = {
  "OK", "VERSION", "PROTOCOL", "UNKNOWN_VARIANT", "TOO_LARGE", "LENGTH", "BUSY",
  "UNAUTHORIZED", "INTERNAL", "UNSUPPORTED", "SHUTTING_DOWN", "INVALID", "NOSPACE",
  "EXPIRED", "CANCELLED",
};

const char *hfp_code_name(int code) {
  if (code < 0) code = -code;
  return code < HFP_E_COUNT ? names[code] : "UNKNOWN";
}

const char *hfp_type_name(unsigned type) {
  static const char *const types[HFP_TYPE_MAX + 1] = {
      "", "HELLO", "HELLO_OK", "LIST_VARIANTS", "VARIANTS", "FILTER", "RESULT", "ERROR",
      "STATS", "STATS_REPLY", "SHM_CREATE", "SHM_CREATED", "SHM_DESTROY", "CANCEL"};
  return type >= 1 && type <= HFP_TYPE_MAX ? types[type] : "UNKNOWN";
}

int hfp_negotiate(uint16_t client_min, uint16_t client_max) {
  if (client_min > client_max) return -HFP_E_VERSION;
  int lo = client_min > HFP_VERSION_MIN ? client_min : HFP_VERSION_MIN;
  int hi = client_max < HFP_VERSION ? client_max : HFP_VERSION;
  return lo <= hi ? hi : -HFP_E_VERSION;
}

int hfp_hist_bucket(uint64_t us) {
  int b = 0;
  uint64_t bound = 32;
  while (b < HFP_HIST_BUCKETS - 1 && us >= bound) {
    b++;
    bound <<= 1;
  }
  return b;
}

uint64_t hfp_hist_upper(int i) {
  if (i < 0) return 0;
  if (i >= HFP_HIST_BUCKETS - 1) return UINT64_MAX;
  return (uint64_t)32 << i;
}

size_t hfp_dtype_size(int dtype) {
  switch (dtype) {
    case HFP_F32: return 4;
    case HFP_F16: return 2;
    default: return 0;
  }
}

static int tensor_bytes(uint32_t width, uint32_t height, uint64_t channels,
                        int dtype, uint64_t *out) {
  size_t es = hfp_dtype_size(dtype);
  if (!es) return -HFP_E_UNSUPPORTED;
  if (width < 1 || height < 1 || width > HFP_MAX_SIDE || height > HFP_MAX_SIDE)
    return -HFP_E_INVALID;
  /* 65535^2 * 96 * 4 < 2^41: no overflow possible in 64 bits. */
  *out = (uint64_t)width * height * channels * es;
  return 0;
}

int hfp_features_bytes(uint32_t width, uint32_t height, uint32_t spp, int dtype,
                       uint64_t *out) {
  if (spp < 1 || spp > HFP_MAX_SPP) return -HFP_E_INVALID;
  return tensor_bytes(width, height, (uint64_t)spp * HFP_FEATURES, dtype, out);
}

int hfp_output_bytes(uint32_t width, uint32_t height, uint32_t channels,
                     int dtype, uint64_t *out) {
  if (channels < 1 || channels > 4) return -HFP_E_INVALID;
  return tensor_bytes(width, height, channels, dtype, out);
}

int hfp_filter_input_bytes(uint32_t width, uint32_t height, uint32_t spp, int dtype,
                           unsigned flags, uint64_t *out) {
  if (spp < 1 || spp > HFP_MAX_SPP) return -HFP_E_INVALID;
  uint64_t channels = (uint64_t)spp * HFP_FEATURES +
                      ((flags & HFP_FILTER_ESTIMATE) ? HFP_ESTIMATE_VALUES : 0);
  return tensor_bytes(width, height, channels, dtype, out);
}

/* ---- header --------------------------------------------------------------- */

void hfp_header_encode(const hfp_header *h, uint8_t out[HFP_HEADER_SIZE]) {
  hfp_put_u32(out, HFP_MAGIC);
  hfp_put_u16(out + 4, h->type);
  hfp_put_u16(out + 6, h->flags);
  hfp_put_u32(out + 8, h->request_id);
  hfp_put_u32(out + 12, h->length);
}

int hfp_header_decode(const uint8_t in[HFP_HEADER_SIZE], uint32_t max_payload,
                      hfp_header *h) {
  memset(h, 0, sizeof *h);
  if (hfp_get_u32(in) != HFP_MAGIC) return -HFP_E_PROTOCOL;
  h->type = hfp_get_u16(in + 4);
  h->flags = hfp_get_u16(in + 6);
  h->request_id = hfp_get_u32(in + 8);
  h->length = hfp_get_u32(in + 12);
  if (h->type < 1 || h->type > HFP_TYPE_MAX) return -HFP_E_PROTOCOL;
  if (h->flags != 0) return -HFP_E_PROTOCOL;
  if (h->length > max_payload) return -HFP_E_TOO_LARGE;
  return 0;
}

/* ---- bounded reader and writer ---------------------------------------- */

typedef struct rd {
  const uint8_t *p;
  size_t len, off;
  int err;
} rd;

static const uint8_t *rd_take(rd *r, size_t n) {
  if (r->err) return NULL;
  if (n > r->len - r->off) {
    r->err = -HFP_E_LENGTH;
    return NULL;
  }
  const uint8_t *p = r->p + r->off;
  r->off += n;
  return p;
}

static uint8_t rd_u8(rd *r) {
  const uint8_t *p = rd_take(r, 1);
  return p ? p[0] : 0;
}
static uint16_t rd_u16(rd *r) {
  const uint8_t *p = rd_take(r, 2);
  return p ? hfp_get_u16(p) : 0;
}
static uint32_t rd_u32(rd *r) {
  const uint8_t *p = rd_take(r, 4);
  return p ? hfp_get_u32(p) : 0;
}
static uint64_t rd_u64(rd *r) {
  const uint8_t *p = rd_take(r, 8);
  if (!p) return 0;
  return (uint64_t)hfp_get_u32(p) | ((uint64_t)hfp_get_u32(p + 4) << 32);
}
static float rd_f32(rd *r) {
  uint32_t u = rd_u32(r);
  float f;
  memcpy(&f, &u, 4);
  return f;
}
static double rd_f64(rd *r) {
  uint64_t u = rd_u64(r);
  double d;
  memcpy(&d, &u, 8);
  return d;
}

/* Names and tokens are printable ASCII without spaces; messages may hold
 * spaces. Rejecting control bytes here means no peer ever logs a terminal
 * escape sequence it received. */
static int text_ok(const uint8_t *s, size_t n, int allow_space) {
  for (size_t i = 0; i < n; i++) {
    uint8_t c = s[i];
    if (c > 0x7e || c < 0x20 || (c == 0x20 && !allow_space)) return 0;
  }
  return 1;
}

/* Reads n bytes of text into dst (dst has room for max + 1). */
static void rd_text(rd *r, size_t n, size_t max, int allow_space, int allow_empty,
                    char *dst) {
  dst[0] = 0;
  if (r->err) return;
  if (n > max || (n == 0 && !allow_empty)) {
    r->err = -HFP_E_INVALID;
    return;
  }
  const uint8_t *p = rd_take(r, n);
  if (!p) return;
  if (!text_ok(p, n, allow_space)) {
    r->err = -HFP_E_INVALID;
    return;
  }
  memcpy(dst, p, n);
  dst[n] = 0;
}

static int rd_end(rd *r) {
  if (r->err) return r->err;
  if (r->off != r->len) return -HFP_E_LENGTH;
  return 0;
}

typedef struct wr {
  uint8_t *p;
  size_t cap, off;
  int err;
} wr;

static uint8_t *wr_take(wr *w, size_t n) {
  if (w->err) return NULL;
  if (n > w->cap - w->off) {
    w->err = -HFP_E_NOSPACE;
    return NULL;
  }
  uint8_t *p = w->p + w->off;
  w->off += n;
  return p;
}
static void wr_u8(wr *w, uint8_t v) {
  uint8_t *p = wr_take(w, 1);
  if (p) p[0] = v;
}
static void wr_u16(wr *w, uint16_t v) {
  uint8_t *p = wr_take(w, 2);
  if (p) hfp_put_u16(p, v);
}
static void wr_u32(wr *w, uint32_t v) {
  uint8_t *p = wr_take(w, 4);
  if (p) hfp_put_u32(p, v);
}
static void wr_u64(wr *w, uint64_t v) {
  uint8_t *p = wr_take(w, 8);
  if (p) {
    hfp_put_u32(p, (uint32_t)v);
    hfp_put_u32(p + 4, (uint32_t)(v >> 32));
  }
}
static void wr_f32(wr *w, float f) {
  uint32_t u;
  memcpy(&u, &f, 4);
  wr_u32(w, u);
}
static void wr_f64(wr *w, double d) {
  uint64_t u;
  memcpy(&u, &d, 8);
  wr_u64(w, u);
}
static void wr_bytes(wr *w, const void *s, size_t n) {
  uint8_t *p = wr_take(w, n);
  if (p && n) memcpy(p, s, n);
}

/* Validates text before it is sent, with the receiver's rules. */
static size_t checked_text(wr *w, const char *s, size_t max, int allow_space,
                           int allow_empty) {
  size_t n = strnlen(s, max + 1);
  if (n > max || (n == 0 && !allow_empty) ||
      !text_ok((const uint8_t *)s, n, allow_space)) {
    if (!w->err) w->err = -HFP_E_INVALID;
    return 0;
  }
  return n;
}

/* Starts a frame: reserves the header, whose length is patched by wr_finish
 * (or set to `length` when the caller appends bulk data itself). */
static void wr_begin(wr *w, uint8_t *buf, size_t cap) {
  w->p = buf;
  w->cap = cap;
  w->off = 0;
  w->err = 0;
  wr_take(w, HFP_HEADER_SIZE);
}

static int wr_finish(wr *w, int type, uint32_t request_id, uint64_t extra) {
  if (w->err) return w->err;
  uint64_t length = (uint64_t)(w->off - HFP_HEADER_SIZE) + extra;
  if (length > UINT32_MAX) return -HFP_E_TOO_LARGE;
  hfp_header h = {(uint16_t)type, 0, request_id, (uint32_t)length};
  hfp_header_encode(&h, w->p);
  if (w->off > INT32_MAX) return -HFP_E_TOO_LARGE;
  return (int)w->off;
}

/* ---- HELLO / HELLO_OK ------------------------------------------------------ */

static void wr_short_text(wr *w, const char *s, int allow_empty);
static void rd_short_text(rd *r, char *dst, int allow_empty);

int hfp_encode_hello(uint8_t *buf, size_t cap, const hfp_hello *m) {
  wr w;
  wr_begin(&w, buf, cap);
  size_t nn = checked_text(&w, m->client_name, HFP_NAME_MAX, 0, 0);
  size_t tn = checked_text(&w, m->token, HFP_TOKEN_MAX, 0, 1);
  if (!w.err && (m->max_version < 1 || m->min_version > m->max_version))
    w.err = -HFP_E_INVALID;
  wr_u16(&w, m->min_version);
  wr_u16(&w, m->max_version);
  wr_u16(&w, (uint16_t)nn);
  wr_u16(&w, (uint16_t)tn);
  wr_bytes(&w, m->client_name, nn);
  wr_bytes(&w, m->token, tn);
  return wr_finish(&w, HFP_HELLO, 0, 0);
}

int hfp_decode_hello(const uint8_t *payload, size_t len, hfp_hello *m) {
  rd r = {payload, len, 0, 0};
  memset(m, 0, sizeof *m);
  m->min_version = rd_u16(&r);
  m->max_version = rd_u16(&r);
  uint16_t nn = rd_u16(&r), tn = rd_u16(&r);
  rd_text(&r, nn, HFP_NAME_MAX, 0, 0, m->client_name);
  rd_text(&r, tn, HFP_TOKEN_MAX, 0, 1, m->token);
  int rc = rd_end(&r);
  if (rc) return rc;
  /* An empty range, or one below version 1, holds no version at all. Which
   * versions are in common is hfp_negotiate's to say: [0, 1] holds 1. */
  if (m->max_version < 1 || m->min_version > m->max_version) return -HFP_E_VERSION;
  return 0;
}

/* Which of a text field's bytes is first outside its alphabet, or -1. */
static long first_bad_text_byte(const uint8_t *s, size_t n) {
  for (size_t i = 0; i < n; i++)
    if (!text_ok(s + i, 1, 0)) return (long)i;
  return -1;
}

void hfp_hello_fault(const uint8_t *payload, size_t len, int rc, char *buf, size_t cap) {
  if (!cap) return;
  if (rc < 0) rc = -rc;
  snprintf(buf, cap, "%s", hfp_strerror(rc));
  if (len < HFP_HELLO_FIXED) {
    snprintf(buf, cap, "a HELLO payload of %zu bytes is shorter than its %d fixed bytes", len,
             HFP_HELLO_FIXED);
    return;
  }
  uint16_t nn = hfp_get_u16(payload + 4), tn = hfp_get_u16(payload + 6);
  /* In hfp_decode_hello's order, so the text is about the fault that
   * decided the code. */
  if (nn < 1 || nn > HFP_NAME_MAX) {
    snprintf(buf, cap, "name_len %u is outside 1..%d", nn, HFP_NAME_MAX);
    return;
  }
  if ((size_t)HFP_HELLO_FIXED + nn > len) {
    snprintf(buf, cap, "a payload of %zu bytes ends inside the %u-byte client name", len, nn);
    return;
  }
  long bad = first_bad_text_byte(payload + HFP_HELLO_FIXED, nn);
  if (bad >= 0) {
    snprintf(buf, cap, "client name byte %ld is 0x%02x; a name is printable ASCII without "
             "spaces (0x21..0x7E)", bad, payload[HFP_HELLO_FIXED + bad]);
    return;
  }
  if (tn > HFP_TOKEN_MAX) {
    snprintf(buf, cap, "token_len %u is outside 0..%d", tn, HFP_TOKEN_MAX);
    return;
  }
  size_t need = (size_t)HFP_HELLO_FIXED + nn + tn;
  if (need > len) {
    snprintf(buf, cap, "a payload of %zu bytes ends inside the %u-byte auth token (the fields "
             "need %zu)", len, tn, need);
    return;
  }
  /* The token's bytes are not echoed: a server's log keeps no part of a
   * secret. */
  bad = first_bad_text_byte(payload + HFP_HELLO_FIXED + nn, tn);
  if (bad >= 0) {
    snprintf(buf, cap, "auth token byte %ld is outside printable ASCII without spaces "
             "(0x21..0x7E)", bad);
    return;
  }
  if (need != len)
    snprintf(buf, cap, "the payload is %zu bytes but its fields (8 fixed, a %u-byte name, a "
             "%u-byte token) make %zu", len, nn, tn, need);
}

int hfp_encode_hello_ok(uint8_t *buf, size_t cap, const hfp_hello_ok *m) {
  wr w;
  wr_begin(&w, buf, cap);
  size_t nn = checked_text(&w, m->server_name, HFP_NAME_MAX, 0, 0);
  if (!w.err && (m->version < HFP_VERSION_MIN || m->version > HFP_VERSION || m->max_spp < 1 ||
                 m->max_spp > HFP_MAX_SPP ||
                 m->max_width < 1 || m->max_height < 1 ||
                 m->max_width > HFP_MAX_SIDE || m->max_height > HFP_MAX_SIDE ||
                 m->max_inflight < 1 || m->max_batch < 1 ||
                 !(m->dtypes & HFP_DTYPE_MASK_ALL) || (m->dtypes & ~HFP_DTYPE_MASK_ALL)))
    w.err = -HFP_E_INVALID;
  wr_u16(&w, m->version);
  wr_u16(&w, m->server_flags);
  wr_u32(&w, m->max_width);
  wr_u32(&w, m->max_height);
  wr_u16(&w, m->max_spp);
  wr_u16(&w, m->max_inflight);
  wr_u32(&w, m->dtypes);
  wr_u32(&w, m->max_batch);
  wr_u32(&w, m->queue_size);
  wr_u64(&w, m->max_frame_bytes);
  wr_u16(&w, (uint16_t)nn);
  wr_bytes(&w, m->server_name, nn);
  /* Version 2: the server's software version after the name (empty: not
   * said). A version-1 peer gets exactly the version-1 frame. */
  if (m->version >= 2) wr_short_text(&w, m->software_version, 1);
  return wr_finish(&w, HFP_HELLO_OK, 0, 0);
}

int hfp_decode_hello_ok(const uint8_t *payload, size_t len, hfp_hello_ok *m) {
  rd r = {payload, len, 0, 0};
  memset(m, 0, sizeof *m);
  m->version = rd_u16(&r);
  m->server_flags = rd_u16(&r);
  m->max_width = rd_u32(&r);
  m->max_height = rd_u32(&r);
  m->max_spp = rd_u16(&r);
  m->max_inflight = rd_u16(&r);
  m->dtypes = rd_u32(&r);
  m->max_batch = rd_u32(&r);
  m->queue_size = rd_u32(&r);
  m->max_frame_bytes = rd_u64(&r);
  uint16_t nn = rd_u16(&r);
  rd_text(&r, nn, HFP_NAME_MAX, 0, 0, m->server_name);
  /* Bytes after the name: version 2's software version. A version-2 server
   * that sends none is read as one that does not say. */
  if (m->version >= 2 && !r.err && r.off < r.len) rd_short_text(&r, m->software_version, 1);
  int rc = rd_end(&r);
  if (rc) return rc;
  if (m->version < HFP_VERSION_MIN || m->version > HFP_VERSION) return -HFP_E_VERSION;
  if (m->max_spp < 1 || m->max_spp > HFP_MAX_SPP || m->max_width < 1 ||
      m->max_height < 1 || m->max_width > HFP_MAX_SIDE ||
      m->max_height > HFP_MAX_SIDE || m->max_inflight < 1 || m->max_batch < 1 ||
      !(m->dtypes & HFP_DTYPE_MASK_ALL) || (m->dtypes & ~HFP_DTYPE_MASK_ALL))
    return -HFP_E_INVALID;
  return 0;
}

/* ---- empty requests ---------------------------------------------------- */

int hfp_encode_empty(uint8_t *buf, size_t cap, int type, uint32_t request_id) {
  /* CANCEL names its FILTER's id; the control requests carry 0. */
  if (type == HFP_CANCEL ? request_id == 0 : type != HFP_LIST_VARIANTS && type != HFP_STATS)
    return -HFP_E_INVALID;
  wr w;
  wr_begin(&w, buf, cap);
  return wr_finish(&w, type, request_id, 0);
}

/* ---- VARIANTS -------------------------------------------------------------- */

static void wr_short_text(wr *w, const char *s, int allow_empty) {
  size_t n = checked_text(w, s, HFP_NAME_MAX, 0, allow_empty);
  wr_u8(w, (uint8_t)n);
  wr_bytes(w, s, n);
}

static void rd_short_text(rd *r, char *dst, int allow_empty) {
  uint8_t n = rd_u8(r);
  rd_text(r, n, HFP_NAME_MAX, 0, allow_empty, dst);
}

static int variant_ok(const hfp_variant *v) {
  if (v->spp < 1 || v->spp > HFP_MAX_SPP) return 0;
  if (v->num_levels < 1 || v->num_levels > HFP_MAX_LEVELS) return 0;
  for (int i = 0; i < v->num_levels; i++)
    if (v->levels[i] < 1) return 0;
  return 1;
}

/* Version 2's range block of one variant: a count, then (statistic, low,
 * high) triples with distinct statistics and finite low <= high. */
#define RANGE_BYTES (1 + 8 + 8)

static int ranges_ok(const hfp_variant *v) {
  if (v->num_ranges > HFP_MAX_STATS) return 0;
  for (int k = 0; k < v->num_ranges; k++) {
    if (!isfinite(v->ranges[k].lo) || !isfinite(v->ranges[k].hi) ||
        v->ranges[k].lo > v->ranges[k].hi)
      return 0;
    for (int j = 0; j < k; j++)
      if (v->ranges[j].stat == v->ranges[k].stat) return 0;
  }
  return 1;
}

size_t hfp_frame_size_variants_v(const hfp_variant *v, int count, int version) {
  size_t n = HFP_HEADER_SIZE + 2;
  for (int i = 0; i < count; i++) {
    n += 3 + strnlen(v[i].name, HFP_NAME_MAX + 1) +
         strnlen(v[i].backend, HFP_NAME_MAX + 1) +
         strnlen(v[i].precision, HFP_NAME_MAX + 1) + 4 + 4 * (size_t)v[i].num_levels;
    if (version >= 2) n += 1 + RANGE_BYTES * (size_t)v[i].num_ranges;
    if (version >= 3) n += 1;
  }
  return n;
}

size_t hfp_frame_size_variants(const hfp_variant *v, int count) {
  return hfp_frame_size_variants_v(v, count, 1);
}

int hfp_encode_variants_v(uint8_t *buf, size_t cap, const hfp_variant *v, int count,
                          int version) {
  wr w;
  wr_begin(&w, buf, cap);
  if (count < 0 || count > HFP_MAX_VARIANTS) w.err = -HFP_E_INVALID;
  wr_u16(&w, (uint16_t)count);
  for (int i = 0; i < count && !w.err; i++) {
    if (!variant_ok(&v[i])) w.err = -HFP_E_INVALID;
    wr_short_text(&w, v[i].name, 0);
    wr_short_text(&w, v[i].backend, 0);
    wr_short_text(&w, v[i].precision, 0);
    wr_u16(&w, v[i].spp);
    wr_u16(&w, v[i].num_levels);
    for (int l = 0; l < v[i].num_levels && !w.err; l++) wr_u32(&w, v[i].levels[l]);
  }
  /* Version 2: every variant's input range, after the last entry. */
  for (int i = 0; version >= 2 && i < count && !w.err; i++) {
    if (!ranges_ok(&v[i])) w.err = -HFP_E_INVALID;
    wr_u8(&w, v[i].num_ranges);
    for (int k = 0; k < v[i].num_ranges && !w.err; k++) {
      wr_u8(&w, v[i].ranges[k].stat);
      wr_f64(&w, v[i].ranges[k].lo);
      wr_f64(&w, v[i].ranges[k].hi);
    }
  }
  /* Version 3: the estimate each variant reads, one byte per entry. */
  for (int i = 0; version >= 3 && i < count && !w.err; i++) {
    if (v[i].estimate > HFP_ESTIMATE_ALPHA_CORRECTED) w.err = -HFP_E_INVALID;
    wr_u8(&w, v[i].estimate);
  }
  return wr_finish(&w, HFP_VARIANTS, 0, 0);
}

int hfp_encode_variants(uint8_t *buf, size_t cap, const hfp_variant *v, int count) {
  return hfp_encode_variants_v(buf, cap, v, count, 1);
}

int hfp_decode_variants(const uint8_t *payload, size_t len, hfp_variant *v,
                        int max, int *count) {
  rd r = {payload, len, 0, 0};
  *count = 0;
  uint16_t n = rd_u16(&r);
  if (r.err) return r.err;
  if (n > HFP_MAX_VARIANTS) return -HFP_E_INVALID;
  if (n > max) return -HFP_E_NOSPACE;
  for (int i = 0; i < n; i++) {
    hfp_variant *e = &v[i];
    memset(e, 0, sizeof *e);
    rd_short_text(&r, e->name, 0);
    rd_short_text(&r, e->backend, 0);
    rd_short_text(&r, e->precision, 0);
    e->spp = rd_u16(&r);
    e->num_levels = rd_u16(&r);
    if (r.err) return r.err;
    if (e->num_levels < 1 || e->num_levels > HFP_MAX_LEVELS) return -HFP_E_INVALID;
    for (int l = 0; l < e->num_levels; l++) e->levels[l] = rd_u32(&r);
    if (r.err) return r.err;
    if (!variant_ok(e)) return -HFP_E_INVALID;
  }
  /* Bytes after the last entry: version 2's ranges, one block per entry. */
  int v2 = r.off < r.len;
  for (int i = 0; v2 && i < n; i++) {
    hfp_variant *e = &v[i];
    e->num_ranges = rd_u8(&r);
    if (r.err) return r.err;
    if (e->num_ranges > HFP_MAX_STATS) return -HFP_E_INVALID;
    for (int k = 0; k < e->num_ranges; k++) {
      e->ranges[k].stat = rd_u8(&r);
      e->ranges[k].lo = rd_f64(&r);
      e->ranges[k].hi = rd_f64(&r);
    }
    if (r.err) return r.err;
    if (!ranges_ok(e)) return -HFP_E_INVALID;
  }
  /* Bytes after the ranges: version 3's estimates, one byte per entry. */
  int v3 = v2 && r.off < r.len;
  for (int i = 0; v3 && i < n; i++) {
    v[i].estimate = rd_u8(&r);
    if (r.err) return r.err;
    if (v[i].estimate > HFP_ESTIMATE_ALPHA_CORRECTED) return -HFP_E_INVALID;
  }
  int rc = rd_end(&r);
  if (rc) return rc;
  *count = n;
  return 0;
}

/* ---- FILTER -------------------------------------------------------------- */

static int colors_finite(const float *c, int n) {
  for (int i = 0; i < n; i++)
    if (!isfinite(c[i])) return 0;
  return 1;
}

/* Checks the fields of a FILTER that the codec owns; limits are the
 * server's. */
static int filter_fields(const hfp_filter *m, uint64_t *data_len) {
  if (m->flags & ~HFP_FILTER_KNOWN) return -HFP_E_UNSUPPORTED;
  if (!hfp_dtype_size(m->in_dtype) || !hfp_dtype_size(m->out_dtype))
    return -HFP_E_UNSUPPORTED;
  if (!colors_finite(m->hair, 3) || !colors_finite(m->light, 3) ||
      !colors_finite(m->bg, 3))
    return -HFP_E_INVALID;
  return hfp_filter_input_bytes(m->width, m->height, m->spp, m->in_dtype, m->flags, data_len);
}

/* Bytes between the variant name and the tensor (or the SHM reference). */
static size_t filter_extra(unsigned flags) {
  return (flags & HFP_FILTER_DEADLINE) ? HFP_DEADLINE_SIZE : 0;
}

int hfp_encode_filter_head(uint8_t *buf, size_t cap, uint32_t request_id,
                           const hfp_filter *m, uint64_t *frame_size) {
  wr w;
  wr_begin(&w, buf, cap);
  size_t vn = checked_text(&w, m->variant, HFP_NAME_MAX, 0, 0);
  uint64_t data_len = 0;
  if (!w.err) {
    int rc = filter_fields(m, &data_len);
    if (rc) w.err = rc;
    else if (m->data_len != data_len || request_id == 0) w.err = -HFP_E_INVALID;
    /* A budget of 0 would expire every frame; one without the flag would
     * be dropped on the wire. */
    else if ((m->flags & HFP_FILTER_DEADLINE) ? m->budget_us == 0 : m->budget_us != 0)
      w.err = -HFP_E_INVALID;
  }
  wr_u16(&w, (uint16_t)vn);
  wr_u16(&w, m->flags);
  wr_u32(&w, m->width);
  wr_u32(&w, m->height);
  wr_u16(&w, m->spp);
  wr_u8(&w, m->in_dtype);
  wr_u8(&w, m->out_dtype);
  for (int i = 0; i < 3; i++) wr_f32(&w, m->hair[i]);
  for (int i = 0; i < 3; i++) wr_f32(&w, m->light[i]);
  for (int i = 0; i < 3; i++) wr_f32(&w, m->bg[i]);
  wr_bytes(&w, m->variant, vn);
  if (m->flags & HFP_FILTER_DEADLINE) wr_u32(&w, m->budget_us);
  if (m->flags & HFP_FILTER_SHM) {
    /* The tensors stay in the segment: nothing follows the reference. */
    if (!w.err && (m->shm_segment == 0 || (!(m->flags & HFP_FILTER_COMPOSITE) && m->shm_rgba)))
      w.err = -HFP_E_INVALID;
    wr_u32(&w, m->shm_segment);
    wr_u32(&w, 0);
    wr_u64(&w, m->shm_in);
    wr_u64(&w, m->shm_out);
    wr_u64(&w, m->shm_rgba);
    data_len = 0;
  }
  int rc = wr_finish(&w, HFP_FILTER, request_id, data_len);
  if (rc > 0 && frame_size) *frame_size = (uint64_t)rc + data_len;
  return rc;
}

int hfp_decode_filter_head(const uint8_t *payload, size_t avail, size_t len,
                           hfp_filter *m, size_t *head_len) {
  memset(m, 0, sizeof *m);
  if (avail > len) return -HFP_E_INVALID;
  if (len < HFP_FILTER_FIXED) return -HFP_E_LENGTH;
  rd r = {payload, avail, 0, 0};
  uint16_t vn = rd_u16(&r);
  m->flags = rd_u16(&r);
  m->width = rd_u32(&r);
  m->height = rd_u32(&r);
  m->spp = rd_u16(&r);
  m->in_dtype = rd_u8(&r);
  m->out_dtype = rd_u8(&r);
  for (int i = 0; i < 3; i++) m->hair[i] = rd_f32(&r);
  for (int i = 0; i < 3; i++) m->light[i] = rd_f32(&r);
  for (int i = 0; i < 3; i++) m->bg[i] = rd_f32(&r);
  if (r.err) return -HFP_E_NOSPACE;  /* the fixed part has not all arrived */
  if (vn < 1 || vn > HFP_NAME_MAX) return -HFP_E_INVALID;
  if ((size_t)HFP_FILTER_FIXED + vn > len) return -HFP_E_LENGTH;
  size_t need = (size_t)HFP_FILTER_FIXED + vn + filter_extra(m->flags) +
                ((m->flags & HFP_FILTER_SHM) ? HFP_SHM_REF_SIZE : 0);
  if (need > len) return -HFP_E_LENGTH;
  if (need > avail) return -HFP_E_NOSPACE;
  rd_text(&r, vn, HFP_NAME_MAX, 0, 0, m->variant);
  if (r.err) return r.err;
  uint64_t data_len;
  int rc = filter_fields(m, &data_len);
  if (rc) return rc;
  m->data_len = data_len;
  if (m->flags & HFP_FILTER_DEADLINE) {
    m->budget_us = rd_u32(&r);
    if (r.err) return r.err;
    if (m->budget_us == 0) return -HFP_E_INVALID;
  }
  if (m->flags & HFP_FILTER_SHM) {
    m->shm_segment = rd_u32(&r);
    uint32_t reserved = rd_u32(&r);
    m->shm_in = rd_u64(&r);
    m->shm_out = rd_u64(&r);
    m->shm_rgba = rd_u64(&r);
    if (r.err) return r.err;
    if (len != r.off) return -HFP_E_LENGTH;
    if (m->shm_segment == 0 || reserved ||
        (!(m->flags & HFP_FILTER_COMPOSITE) && m->shm_rgba))
      return -HFP_E_INVALID;
  } else if ((uint64_t)len - r.off != data_len) {
    return -HFP_E_LENGTH;
  }
  *head_len = r.off;
  return 0;
}

int hfp_decode_filter(const uint8_t *payload, size_t len, hfp_filter *m) {
  size_t head;
  int rc = hfp_decode_filter_head(payload, len, len, m, &head);
  if (rc) return rc == -HFP_E_NOSPACE ? -HFP_E_LENGTH : rc;
  if (!(m->flags & HFP_FILTER_SHM)) m->data = payload + head;
  return 0;
}

/* The i-th colour of a FILTER's fixed fields (hair, light, background). */
static const char *const colour_names[3] = {"hair", "light", "background"};

void hfp_filter_fault(const uint8_t *payload, size_t avail, size_t len, int rc, char *buf,
                      size_t cap) {
  if (!cap) return;
  if (rc < 0) rc = -rc;
  /* Whatever is not recognised below is said by its code alone. */
  snprintf(buf, cap, "%s", hfp_strerror(rc));
  if (avail > len || len < HFP_FILTER_FIXED || avail < HFP_FILTER_FIXED) {
    if (len < HFP_FILTER_FIXED)
      snprintf(buf, cap, "a FILTER payload of %zu bytes is shorter than its %d fixed bytes", len,
               HFP_FILTER_FIXED);
    return;
  }
  rd r = {payload, avail, 0, 0};
  hfp_filter m;
  memset(&m, 0, sizeof m);
  uint16_t vn = rd_u16(&r);
  m.flags = rd_u16(&r);
  m.width = rd_u32(&r);
  m.height = rd_u32(&r);
  m.spp = rd_u16(&r);
  m.in_dtype = rd_u8(&r);
  m.out_dtype = rd_u8(&r);
  for (int i = 0; i < 3; i++) m.hair[i] = rd_f32(&r);
  for (int i = 0; i < 3; i++) m.light[i] = rd_f32(&r);
  for (int i = 0; i < 3; i++) m.bg[i] = rd_f32(&r);
  /* In hfp_decode_filter_head's order, so the text is about the fault
   * that decided the code. */
  if (vn < 1 || vn > HFP_NAME_MAX) {
    snprintf(buf, cap, "variant_len %u is outside 1..%d", vn, HFP_NAME_MAX);
    return;
  }
  size_t extra = filter_extra(m.flags);
  size_t ref = (m.flags & HFP_FILTER_SHM) ? HFP_SHM_REF_SIZE : 0;
  size_t need = (size_t)HFP_FILTER_FIXED + vn + extra + ref;
  if (need > len) {
    snprintf(buf, cap,
             "a payload of %zu bytes ends inside the fields after the fixed ones: the %u-byte "
             "variant name%s%s need %zu bytes",
             len, vn, extra ? ", the 4-byte budget_us (flag DEADLINE)" : "",
             ref ? ", the 32-byte shared-memory reference (flag SHM)" : "", need);
    return;
  }
  if (need > avail) return;
  const uint8_t *name = payload + HFP_FILTER_FIXED;
  for (size_t i = 0; i < vn; i++)
    if (name[i] < 0x21 || name[i] > 0x7E) {
      snprintf(buf, cap,
               "variant name byte %zu is 0x%02x; a name is printable ASCII without spaces "
               "(0x21..0x7E)",
               i, name[i]);
      return;
    }
  if (m.flags & ~HFP_FILTER_KNOWN) {
    snprintf(buf, cap, "unknown FILTER flag bits 0x%04x (the known ones are 0x%04x)",
             m.flags & ~HFP_FILTER_KNOWN, HFP_FILTER_KNOWN);
    return;
  }
  if (!hfp_dtype_size(m.in_dtype) || !hfp_dtype_size(m.out_dtype)) {
    snprintf(buf, cap, "%s %u is no dtype: 0 (f32) or 1 (f16)",
             hfp_dtype_size(m.in_dtype) ? "out_dtype" : "in_dtype",
             hfp_dtype_size(m.in_dtype) ? m.out_dtype : m.in_dtype);
    return;
  }
  const float *colours[3] = {m.hair, m.light, m.bg};
  for (int k = 0; k < 3; k++)
    for (int i = 0; i < 3; i++)
      if (!colors_finite(&colours[k][i], 1)) {
        snprintf(buf, cap, "%s colour component %d is not finite; colours must be finite even "
                 "without COMPOSITE", colour_names[k], i);
        return;
      }
  if (m.spp < 1 || m.spp > HFP_MAX_SPP) {
    snprintf(buf, cap, "spp %u is outside 1..%d", m.spp, HFP_MAX_SPP);
    return;
  }
  if (m.width < 1 || m.width > HFP_MAX_SIDE || m.height < 1 || m.height > HFP_MAX_SIDE) {
    snprintf(buf, cap, "%s %u is outside 1..%d", m.width < 1 || m.width > HFP_MAX_SIDE ?
             "width" : "height", m.width < 1 || m.width > HFP_MAX_SIDE ? m.width : m.height,
             HFP_MAX_SIDE);
    return;
  }
  uint64_t data_len = 0;
  if (hfp_filter_input_bytes(m.width, m.height, m.spp, m.in_dtype, m.flags, &data_len)) return;
  size_t off = (size_t)HFP_FILTER_FIXED + vn;
  if (m.flags & HFP_FILTER_DEADLINE) {
    if (hfp_get_u32(payload + off) == 0) {
      snprintf(buf, cap, "budget_us is 0: a DEADLINE budget is 1..4294967295 microseconds "
               "(send the frame without flag DEADLINE for no budget)");
      return;
    }
    off += HFP_DEADLINE_SIZE;
  }
  if (m.flags & HFP_FILTER_SHM) {
    if (len != off + HFP_SHM_REF_SIZE) {
      snprintf(buf, cap, "the payload is %zu bytes; with flag SHM it must be %zu (the fixed "
               "fields, the name%s and the 32-byte reference)", len, off + HFP_SHM_REF_SIZE,
               extra ? ", the budget" : "");
      return;
    }
    uint32_t seg = hfp_get_u32(payload + off), reserved = hfp_get_u32(payload + off + 4);
    uint64_t rgba = hfp_get_u32(payload + off + 24) |
                    (uint64_t)hfp_get_u32(payload + off + 28) << 32;
    if (seg == 0)
      snprintf(buf, cap, "the shared-memory reference names segment 0; use an id SHM_CREATED "
               "gave");
    else if (reserved)
      snprintf(buf, cap, "the shared-memory reference's reserved word is %u; it must be 0",
               reserved);
    else if (rgba && !(m.flags & HFP_FILTER_COMPOSITE))
      snprintf(buf, cap, "rgba_offset is %llu without flag COMPOSITE; it must be 0",
               (unsigned long long)rgba);
    return;
  }
  if ((uint64_t)len - off != data_len)
    snprintf(buf, cap,
             "the tensor is %llu bytes; %ux%u with spp %u in %s%s needs %llu (payload %zu "
             "bytes: %zu before the tensor)",
             (unsigned long long)(len - off), m.width, m.height, m.spp,
             m.in_dtype == HFP_F16 ? "f16" : "f32",
             (m.flags & HFP_FILTER_ESTIMATE) ? " with the estimate (flag ESTIMATE)" : "",
             (unsigned long long)data_len, len, off);
}

/* ---- RESULT --------------------------------------------------------------- */

static int result_sizes(const hfp_result *m, uint64_t *data_len, uint64_t *rgba_len) {
  *data_len = *rgba_len = 0;
  if (m->flags & ~(HFP_FILTER_COMPOSITE | HFP_FILTER_SHM | HFP_RESULT_INPUT_SANITISED |
                   HFP_RESULT_OUT_OF_RANGE))
    return -HFP_E_INVALID;
  if (m->status != HFP_OK) {
    if (m->status >= HFP_E_COUNT || m->width || m->height || m->flags)
      return -HFP_E_INVALID;
    return 0;
  }
  int rc = hfp_output_bytes(m->width, m->height, HFP_OUTPUTS, m->dtype, data_len);
  if (rc) return rc;
  if (m->batch < 1) return -HFP_E_INVALID;
  if (m->flags & HFP_FILTER_COMPOSITE) {
    rc = hfp_output_bytes(m->width, m->height, 4, m->dtype, rgba_len);
    if (rc) return rc;
  }
  /* SHM results were written to the segment: no tensor follows. */
  if (m->flags & HFP_FILTER_SHM) *data_len = *rgba_len = 0;
  return 0;
}

int hfp_encode_result_head(uint8_t *buf, size_t cap, uint32_t request_id,
                           const hfp_result *m, uint64_t *frame_size) {
  wr w;
  wr_begin(&w, buf, cap);
  uint64_t dl = 0, rl = 0;
  int rc = result_sizes(m, &dl, &rl);
  if (rc) w.err = rc;
  else if (m->data_len != dl || m->rgba_len != rl || request_id == 0)
    w.err = -HFP_E_INVALID;
  wr_u16(&w, m->status);
  wr_u8(&w, m->dtype);
  wr_u8(&w, m->flags);
  wr_u32(&w, m->width);
  wr_u32(&w, m->height);
  wr_u32(&w, m->batch);
  wr_u64(&w, m->timing.queue_us);
  wr_u64(&w, m->timing.input_us);
  wr_u64(&w, m->timing.infer_us);
  wr_u64(&w, m->timing.output_us);
  wr_u64(&w, m->timing.total_us);
  rc = wr_finish(&w, HFP_RESULT, request_id, dl + rl);
  if (rc > 0 && frame_size) *frame_size = (uint64_t)rc + dl + rl;
  return rc;
}

int hfp_decode_result_head(const uint8_t *payload, size_t avail, size_t len,
                           hfp_result *m) {
  memset(m, 0, sizeof *m);
  if (avail > len) return -HFP_E_INVALID;
  if (avail < HFP_RESULT_FIXED) return len < HFP_RESULT_FIXED ? -HFP_E_LENGTH
                                                              : -HFP_E_NOSPACE;
  rd r = {payload, avail, 0, 0};
  m->status = rd_u16(&r);
  m->dtype = rd_u8(&r);
  m->flags = rd_u8(&r);
  m->width = rd_u32(&r);
  m->height = rd_u32(&r);
  m->batch = rd_u32(&r);
  m->timing.queue_us = rd_u64(&r);
  m->timing.input_us = rd_u64(&r);
  m->timing.infer_us = rd_u64(&r);
  m->timing.output_us = rd_u64(&r);
  m->timing.total_us = rd_u64(&r);
  if (r.err) return r.err;
  uint64_t dl, rl;
  int rc = result_sizes(m, &dl, &rl);
  if (rc) return rc;
  if ((uint64_t)len != HFP_RESULT_FIXED + dl + rl) return -HFP_E_LENGTH;
  m->data_len = dl;
  m->rgba_len = rl;
  return 0;
}

int hfp_decode_result(const uint8_t *payload, size_t len, hfp_result *m) {
  int rc = hfp_decode_result_head(payload, len, len, m);
  if (rc) return rc;
  if (m->data_len) m->data = payload + HFP_RESULT_FIXED;
  if (m->rgba_len) m->rgba = payload + HFP_RESULT_FIXED + m->data_len;
  return 0;
}

/* ---- ERROR ----------------------------------------------------------------- */

int hfp_encode_error(uint8_t *buf, size_t cap, uint32_t request_id, const hfp_error *m) {
  wr w;
  wr_begin(&w, buf, cap);
  size_t n = checked_text(&w, m->message, HFP_MESSAGE_MAX, 1, 1);
  if (!w.err && (m->code < 1 || m->code >= HFP_E_COUNT || m->code == HFP_E_NOSPACE ||
                 m->fatal > 1))
    w.err = -HFP_E_INVALID;
  wr_u32(&w, m->code);
  wr_u8(&w, m->fatal);
  wr_u8(&w, 0);
  wr_u16(&w, (uint16_t)n);
  wr_bytes(&w, m->message, n);
  return wr_finish(&w, HFP_ERROR, request_id, 0);
}

int hfp_decode_error(const uint8_t *payload, size_t len, hfp_error *m) {
  rd r = {payload, len, 0, 0};
  memset(m, 0, sizeof *m);
  m->code = rd_u32(&r);
  m->fatal = rd_u8(&r);
  uint8_t reserved = rd_u8(&r);
  uint16_t n = rd_u16(&r);
  rd_text(&r, n, HFP_MESSAGE_MAX, 1, 1, m->message);
  int rc = rd_end(&r);
  if (rc) return rc;
  /* Unknown codes from a newer server are still errors: keep them. */
  if (m->code == 0 || m->fatal > 1 || reserved) return -HFP_E_INVALID;
  return 0;
}

/* ---- STATS_REPLY -------------------------------------------------------- */

#define VSTATS_FIXED (7 * 8 + 2 * HFP_HIST_BUCKETS * 8)

/* Per-variant counters after the entries: 3 in versions 2 and 3, 5 from
 * version 4 (expired, cancelled). */
static int stats_counters(int version) { return version >= 4 ? HFP_STATS_COUNTERS : 3; }

size_t hfp_frame_size_stats_v(const hfp_stats *m, int version) {
  size_t n = HFP_HEADER_SIZE + 40;
  for (int i = 0; i < m->num_variants && i < HFP_MAX_VARIANTS; i++)
    n += 1 + strnlen(m->variants[i].name, HFP_NAME_MAX + 1) + VSTATS_FIXED;
  if (version >= 2) {
    int nv = m->num_variants < HFP_MAX_VARIANTS ? m->num_variants : HFP_MAX_VARIANTS;
    n += 2 + (size_t)nv * stats_counters(version) * 8;
  }
  return n;
}

size_t hfp_frame_size_stats(const hfp_stats *m) { return hfp_frame_size_stats_v(m, 1); }

int hfp_encode_stats_v(uint8_t *buf, size_t cap, const hfp_stats *m, int version) {
  wr w;
  wr_begin(&w, buf, cap);
  if (m->num_variants > HFP_MAX_VARIANTS) w.err = -HFP_E_INVALID;
  wr_u64(&w, m->uptime_us);
  wr_u64(&w, m->connections_total);
  wr_u32(&w, m->connections_open);
  wr_u32(&w, m->queue_depth);
  wr_u32(&w, m->queue_capacity);
  wr_u64(&w, m->protocol_errors);
  wr_u16(&w, m->num_variants);
  wr_u16(&w, HFP_HIST_BUCKETS);
  for (int i = 0; i < m->num_variants && !w.err; i++) {
    const hfp_variant_stats *v = &m->variants[i];
    wr_short_text(&w, v->name, 0);
    wr_u64(&w, v->requests_ok);
    wr_u64(&w, v->requests_failed);
    wr_u64(&w, v->rejected);
    wr_u64(&w, v->batches);
    wr_u64(&w, v->sum_queue_us);
    wr_u64(&w, v->sum_infer_us);
    wr_u64(&w, v->sum_total_us);
    for (int b = 0; b < HFP_HIST_BUCKETS; b++) wr_u64(&w, v->hist_total[b]);
    for (int b = 0; b < HFP_HIST_BUCKETS; b++) wr_u64(&w, v->hist_infer[b]);
  }
  /* Version 2: the counters a version-1 entry has no room for. */
  if (version >= 2 && !w.err) {
    int nc = stats_counters(version);
    wr_u16(&w, (uint16_t)nc);
    for (int i = 0; i < m->num_variants; i++) {
      wr_u64(&w, m->variants[i].out_of_range);
      wr_u64(&w, m->variants[i].frames_sanitised);
      wr_u64(&w, m->variants[i].cache_bytes);
      if (nc > 3) wr_u64(&w, m->variants[i].expired);
      if (nc > 4) wr_u64(&w, m->variants[i].cancelled);
    }
  }
  return wr_finish(&w, HFP_STATS_REPLY, 0, 0);
}

int hfp_encode_stats(uint8_t *buf, size_t cap, const hfp_stats *m) {
  return hfp_encode_stats_v(buf, cap, m, 1);
}

int hfp_decode_stats(const uint8_t *payload, size_t len, hfp_stats *m) {
  rd r = {payload, len, 0, 0};
  memset(m, 0, sizeof *m);
  m->uptime_us = rd_u64(&r);
  m->connections_total = rd_u64(&r);
  m->connections_open = rd_u32(&r);
  m->queue_depth = rd_u32(&r);
  m->queue_capacity = rd_u32(&r);
  m->protocol_errors = rd_u64(&r);
  m->num_variants = rd_u16(&r);
  uint16_t buckets = rd_u16(&r);
  if (r.err) return r.err;
  if (m->num_variants > HFP_MAX_VARIANTS || buckets != HFP_HIST_BUCKETS) {
    m->num_variants = 0;
    return -HFP_E_INVALID;
  }
  for (int i = 0; i < m->num_variants; i++) {
    hfp_variant_stats *v = &m->variants[i];
    rd_short_text(&r, v->name, 0);
    v->requests_ok = rd_u64(&r);
    v->requests_failed = rd_u64(&r);
    v->rejected = rd_u64(&r);
    v->batches = rd_u64(&r);
    v->sum_queue_us = rd_u64(&r);
    v->sum_infer_us = rd_u64(&r);
    v->sum_total_us = rd_u64(&r);
    for (int b = 0; b < HFP_HIST_BUCKETS; b++) v->hist_total[b] = rd_u64(&r);
    for (int b = 0; b < HFP_HIST_BUCKETS; b++) v->hist_infer[b] = rd_u64(&r);
    if (r.err) break;
  }
  /* Bytes after the last entry: version 2's counters. A newer peer may send
   * more per variant than we know; the known ones come first. */
  if (!r.err && r.off < r.len) {
    uint16_t nc = rd_u16(&r);
    if (!r.err && (nc < 1 || nc > 64)) r.err = -HFP_E_INVALID;
    for (int i = 0; i < m->num_variants && !r.err; i++)
      for (int k = 0; k < nc; k++) {
        uint64_t c = rd_u64(&r);
        if (k == 0) m->variants[i].out_of_range = c;
        if (k == 1) m->variants[i].frames_sanitised = c;
        if (k == 2) m->variants[i].cache_bytes = c;
        if (k == 3) m->variants[i].expired = c;
        if (k == 4) m->variants[i].cancelled = c;
      }
  }
  int rc = rd_end(&r);
  if (rc) m->num_variants = 0;
  return rc;
}

/* ---- shared segments ------------------------------------------------------ */

int hfp_encode_shm_create(uint8_t *buf, size_t cap, uint64_t bytes) {
  wr w;
  wr_begin(&w, buf, cap);
  if (bytes == 0) w.err = -HFP_E_INVALID;
  wr_u64(&w, bytes);
  return wr_finish(&w, HFP_SHM_CREATE, 0, 0);
}

int hfp_decode_shm_create(const uint8_t *payload, size_t len, uint64_t *bytes) {
  rd r = {payload, len, 0, 0};
  *bytes = rd_u64(&r);
  int rc = rd_end(&r);
  if (rc) return rc;
  return *bytes ? 0 : -HFP_E_INVALID;
}

int hfp_encode_shm_created(uint8_t *buf, size_t cap, uint32_t segment, uint64_t bytes) {
  wr w;
  wr_begin(&w, buf, cap);
  if (segment == 0 || bytes == 0) w.err = -HFP_E_INVALID;
  wr_u32(&w, segment);
  wr_u64(&w, bytes);
  return wr_finish(&w, HFP_SHM_CREATED, 0, 0);
}

int hfp_decode_shm_created(const uint8_t *payload, size_t len, uint32_t *segment,
                           uint64_t *bytes) {
  rd r = {payload, len, 0, 0};
  *segment = rd_u32(&r);
  *bytes = rd_u64(&r);
  int rc = rd_end(&r);
  if (rc) return rc;
  return *segment && *bytes ? 0 : -HFP_E_INVALID;
}

int hfp_encode_shm_destroy(uint8_t *buf, size_t cap, uint32_t segment) {
  wr w;
  wr_begin(&w, buf, cap);
  if (segment == 0) w.err = -HFP_E_INVALID;
  wr_u32(&w, segment);
  return wr_finish(&w, HFP_SHM_DESTROY, 0, 0);
}

int hfp_decode_shm_destroy(const uint8_t *payload, size_t len, uint32_t *segment) {
  rd r = {payload, len, 0, 0};
  *segment = rd_u32(&r);
  int rc = rd_end(&r);
  if (rc) return rc;
  return *segment ? 0 : -HFP_E_INVALID;
}

/* Region [off, off + n) inside [0, size) and aligned to es. */
static int region_ok(uint64_t off, uint64_t n, uint64_t size, size_t es) {
  return off % es == 0 && off <= size && n <= size - off;
}

int hfp_regions_overlap(uint64_t a, uint64_t an, uint64_t b, uint64_t bn) {
  return an && bn && a < b + bn && b < a + an;
}

/* Whether region (named what) of n bytes at off fits; writes why when not. */
static int region_fits(const char *what, uint64_t off, uint64_t n, uint64_t size, size_t es,
                       char *why, size_t whylen) {
  if (region_ok(off, n, size, es)) return 1;
  if (why && whylen) {
    if (off % es)
      snprintf(why, whylen, "%s: offset %llu is not a multiple of the %zu-byte elements", what,
               (unsigned long long)off, es);
    else
      snprintf(why, whylen, "%s: %llu bytes at offset %llu would end past the segment's %llu "
               "bytes", what, (unsigned long long)n, (unsigned long long)off,
               (unsigned long long)size);
  }
  return 0;
}

int hfp_shm_check_why(const hfp_filter *m, uint64_t seg_bytes, char *why, size_t whylen) {
  uint64_t in_len, out_len, rgba_len = 0;
  int rc = hfp_filter_input_bytes(m->width, m->height, m->spp, m->in_dtype, m->flags, &in_len);
  if (!rc) rc = hfp_output_bytes(m->width, m->height, HFP_OUTPUTS, m->out_dtype, &out_len);
  if (!rc && (m->flags & HFP_FILTER_COMPOSITE))
    rc = hfp_output_bytes(m->width, m->height, 4, m->out_dtype, &rgba_len);
  if (rc) {
    if (why && whylen) snprintf(why, whylen, "the frame's tensor sizes are out of range");
    return rc;
  }
  if (!region_fits("the features", m->shm_in, in_len, seg_bytes, hfp_dtype_size(m->in_dtype),
                   why, whylen) ||
      !region_fits("the result", m->shm_out, out_len, seg_bytes, hfp_dtype_size(m->out_dtype),
                   why, whylen) ||
      (rgba_len && !region_fits("the rgba composite", m->shm_rgba, rgba_len, seg_bytes,
                                hfp_dtype_size(m->out_dtype), why, whylen)))
    return -HFP_E_LENGTH;
  /* Disjoint: a backend may still read the features (Kernel's output stage
   * reads them again) while it writes the result, from several threads. */
  const char *a = NULL, *b = NULL;
  if (hfp_regions_overlap(m->shm_in, in_len, m->shm_out, out_len))
    a = "the features", b = "the result";
  else if (rgba_len && hfp_regions_overlap(m->shm_in, in_len, m->shm_rgba, rgba_len))
    a = "the features", b = "the rgba composite";
  else if (rgba_len && hfp_regions_overlap(m->shm_out, out_len, m->shm_rgba, rgba_len))
    a = "the result", b = "the rgba composite";
  if (a) {
    if (why && whylen) snprintf(why, whylen, "%s and %s overlap", a, b);
    return -HFP_E_LENGTH;
  }
  return 0;
}

int hfp_shm_check(const hfp_filter *m, uint64_t seg_bytes) {
  return hfp_shm_check_why(m, seg_bytes, NULL, 0);
}
