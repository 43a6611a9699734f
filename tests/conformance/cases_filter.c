/*
 * PROTOCOL.md, "Filtering", "Errors" and "Flow control" for FILTER: valid
 * frames in every dtype pair, with and without a composite, at the limits;
 * every field out of its domain answered with its non-fatal code and the
 * FILTER's id while the connection goes on; lengths that disagree or
 * overflow; duplicate ids; the in-flight limit; batching that never changes
 * values.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cf_internal.h"

static int connect_v(cf_test *t, int *fd) {
  return cf_connect_hello(t, 1, HFP_VERSION, fd, NULL);
}

/* ---- valid frames ------------------------------------------------------------ */

static int dtypes(cf_test *t, intptr_t arg) {
  int in = (int)(arg & 1), out = (int)((arg >> 1) & 1), composite = (int)((arg >> 2) & 1);
  uint32_t offered = t->srv->hello.dtypes;
  if (!(offered & (1u << in)) || !(offered & (1u << out)))
    return cf_skip(t, "the server does not offer %s", !(offered & (1u << in)) ? (in ? "f16" : "f32")
                                                                               : (out ? "f16" : "f32"));
  int fd;
  CF_TRY(connect_v(t, &fd));
  cf_filter f = {.id = 100 + (uint32_t)arg, .in_dtype = in, .out_dtype = out,
                 .flags = composite ? HFP_FILTER_COMPOSITE : 0};
  cf_filter_defaults(t, &f);
  return cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL);
}

/* Finite colours whose composite overflows float (a light of 3e38 on a hair
 * colour of 3e38), and values over f16's range: every RGBA value comes back
 * finite, the formula saturated at the dtype's largest value. */
static int huge_colours(cf_test *t, intptr_t out) {
  if (!(t->srv->hello.dtypes & (1u << out)))
    return cf_skip(t, "the server does not offer %s", out ? "f16" : "f32");
  int fd;
  CF_TRY(connect_v(t, &fd));
  cf_filter f = {.id = 130 + (uint32_t)out, .out_dtype = (int)out, .flags = HFP_FILTER_COMPOSITE,
                 .hair = {3e38f, -3e38f, 1e5f}, .light = {3e38f, 3e38f, 1e5f},
                 .bg = {3e38f, -3e38f, 1e5f}};
  cf_filter_defaults(t, &f);
  return cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL);
}

static int each_variant(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(connect_v(t, &fd));
  for (int i = 0; i < t->srv->nv; i++) {
    cf_filter f = {.id = 200 + (uint32_t)i, .variant = t->srv->variants[i].name,
                   .flags = HFP_FILTER_COMPOSITE};
    cf_filter_defaults(t, &f);
    CF_TRY(cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL));
  }
  return 0;
}

enum { SIZE_1X1, SIZE_ODD, SIZE_WIDE, SIZE_TALL };

static int sizes(cf_test *t, intptr_t which) {
  const hfp_hello_ok *h = &t->srv->hello;
  cf_filter f = {.id = 300 + (uint32_t)which};
  switch (which) {
    case SIZE_1X1: f.width = f.height = 1; break;
    case SIZE_ODD: f.width = h->max_width < 7 ? h->max_width : 7; f.height = h->max_height < 5 ? h->max_height : 5; break;
    case SIZE_WIDE: f.width = h->max_width; f.height = 1; break;
    case SIZE_TALL: f.width = 1; f.height = h->max_height; break;
  }
  cf_filter_defaults(t, &f);
  if (cf_features_bytes(&f) > ((uint64_t)64 << 20))
    return cf_skip(t, "a %ux%u frame is more than this suite sends (64 MiB)", f.width, f.height);
  int fd;
  CF_TRY(connect_v(t, &fd));
  return cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL);
}

/* The promise of HELLO_OK: max_width x max_height in f32 with COMPOSITE is
 * never TOO_LARGE. The head alone shows it (fixed fields are checked before
 * the tensor); the whole frame is sent when it is small enough. */
static int max_size(cf_test *t, intptr_t whole) {
  const hfp_hello_ok *h = &t->srv->hello;
  for (int i = 0; i < t->srv->nv; i++) {
    cf_filter f = {.id = 310 + (uint32_t)i, .variant = t->srv->variants[i].name,
                   .width = h->max_width, .height = h->max_height, .flags = HFP_FILTER_COMPOSITE};
    cf_filter_defaults(t, &f);
    uint64_t bytes = cf_features_bytes(&f);
    if (whole && bytes > ((uint64_t)16 << 20))
      return cf_skip(t, "%ux%u frames of %s are %llu MiB, more than this case sends (16 MiB)",
                     f.width, f.height, f.variant, (unsigned long long)(bytes >> 20));
    int fd;
    CF_TRY(connect_v(t, &fd));
    if (!whole) {
      /* Only the header and the fixed fields: a non-fatal refusal of them
       * would come now. */
      uint8_t head[HFP_HEADER_SIZE + HFP_FILTER_FIXED + HFP_NAME_MAX];
      size_t vn = strlen(f.variant);
      f.width = f.height = 1;
      size_t n;
      uint8_t *b = cf_filter_frame(t, &f, &n);
      CF_CHECK(t, b, "out of memory");
      memcpy(head, b, HFP_HEADER_SIZE + HFP_FILTER_FIXED + vn);
      hfp_put_u32(head + CF_FILTER_WIDTH, h->max_width);
      hfp_put_u32(head + CF_FILTER_HEIGHT, h->max_height);
      cf_set_length(head, (uint32_t)(HFP_FILTER_FIXED + vn + bytes));
      CF_TRY(cf_send(t, fd, head, HFP_HEADER_SIZE + HFP_FILTER_FIXED + vn));
      cf_frame r;
      int rc = cf_read(t, fd, t->o->quiet_ms, &r);
      if (rc == CF_GOT) {
        hfp_error e;
        char d[400];
        CF_CHECK(t, !(r.h.type == HFP_ERROR && hfp_decode_error(r.p, r.h.length, &e) == 0 &&
                      e.code == HFP_E_TOO_LARGE),
                 "the head of a %ux%u f32 COMPOSITE FILTER for %s was refused: %s", h->max_width,
                 h->max_height, f.variant, cf_describe(&r, d, sizeof d));
      }
      CF_CHECK(t, rc != CF_EOF, "the server closed on the head of a frame of the announced size");
      cf_close(t, fd);
      continue;
    }
    size_t n;
    uint8_t *b = cf_filter_frame(t, &f, &n);
    CF_CHECK(t, b, "out of memory");
    CF_TRY(cf_send(t, fd, b, n));
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "no reply to a frame of the announced size");
    /* Only BUSY may refuse it. */
    int busy = cf_busy(t, &r, NULL);
    if (busy < 0) return busy;
    if (!busy) CF_TRY(cf_check_result(t, &r, &f, t->srv->version, NULL, NULL, NULL));
  }
  return 0;
}

/* Whatever the input, results are finite and inside their ranges. */
static int adversarial(cf_test *t, intptr_t kind) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  for (int out = HFP_F32; out <= HFP_F16; out++) {
    if (!(t->srv->hello.dtypes & (1u << out))) continue;
    cf_filter f = {.id = 400 + (uint32_t)out, .features = (int)kind, .out_dtype = out,
                   .flags = HFP_FILTER_COMPOSITE};
    cf_filter_defaults(t, &f);
    CF_TRY(cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL));
  }
  return 0;
}

/* The same frame n times, pipelined: batched or not, every result is the
 * same, bit for bit. */
static int same_values(cf_test *t, intptr_t n) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  int k = (int)n;
  if (k > t->srv->hello.max_inflight) k = t->srv->hello.max_inflight;
  cf_filter f = {.id = 500};
  cf_filter_defaults(t, &f);
  size_t len;
  uint8_t *b = cf_filter_frame(t, &f, &len);
  CF_CHECK(t, b, "out of memory");
  for (int i = 0; i < k; i++) {
    hfp_put_u32(b + 8, 500 + (uint32_t)i);
    CF_TRY(cf_send(t, fd, b, len));
  }
  float *first = NULL;
  int got = 0;
  size_t px = (size_t)f.width * f.height;
  for (int i = 0; i < k; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of %d replies came", i, k);
    int b = cf_busy(t, &r, NULL);
    if (b < 0) return b;
    if (b) continue;
    cf_filter fi = f;
    fi.id = r.h.request_id;
    CF_CHECK(t, fi.id >= 500 && fi.id < 500 + (uint32_t)k, "RESULT for id %u, never sent", fi.id);
    float *res;
    CF_TRY(cf_check_result(t, &r, &fi, t->srv->version, NULL, &res, NULL));
    if (!first)
      first = res;
    else
      CF_CHECK(t, !memcmp(first, res, px * 3 * sizeof(float)),
               "request %u's result differs from the first one of the same frame", fi.id);
    got++;
  }
  CF_CHECK(t, got >= 1, "every one of %d frames was refused BUSY", k);
  return 0;
}

/* ---- fields out of their domain ---------------------------------------------- */

enum {
  F_WIDTH0, F_HEIGHT0, F_WIDTH_65536, F_HEIGHT_65536, F_WIDTH_U32, F_WIDTH_OVER, F_HEIGHT_OVER,
  F_SPP0, F_SPP17, F_SPP_PLUS, F_SPP_MINUS, F_IN2, F_IN255, F_OUT2, F_OUT255, F_FLAG10,
  F_FLAG8000, F_HAIR_NAN, F_HAIR_INF, F_HAIR_NINF, F_LIGHT_NAN, F_LIGHT_INF, F_LIGHT_NINF,
  F_BG_NAN, F_BG_INF, F_BG_NINF, F_UNKNOWN, F_CASE, F_VLEN0, F_VLEN65, F_VLEN_PAST,
  F_SHORT, F_LONG, F_FIXED_ONLY, F_BELOW_FIXED, F_EMPTY, F_OVERFLOW32, F_SHM_SHORT,
  F_SHM_LONG, F_DTYPE_UNOFFERED, F_F16_WITH_F32_TENSOR,
};

/* A FILTER that is well framed but wrong in one field: the non-fatal code
 * (one of codes) with the FILTER's id, and the connection goes on. */
/* Makes the name of the FILTER frame b (vn bytes) one no variant of s has:
 * same length, last byte changed until unknown. */
static void unknown_name(const cf_server *s, uint8_t *b, size_t vn) {
  for (int c = 0x21; c <= 0x7e; c++) {
    b[CF_FILTER_NAME + vn - 1] = (uint8_t)c;
    int known = 0;
    for (int i = 0; i < s->nv; i++)
      known |= strlen(s->variants[i].name) == vn &&
               !memcmp(s->variants[i].name, b + CF_FILTER_NAME, vn);
    if (!known) return;
  }
}

static int bad_field(cf_test *t, intptr_t which) {
  const cf_server *s = t->srv;
  cf_filter f = {.id = 600 + (uint32_t)which};
  cf_filter_defaults(t, &f);
  unsigned codes = CF_CODE(HFP_E_INVALID);
  /* Fields that size the tensor are changed before the frame is built, so
   * that its length agrees with them and the field is all that is wrong. */
  switch (which) {
    case F_WIDTH_OVER:
      if (s->hello.max_width >= HFP_MAX_SIDE) return cf_skip(t, "max_width is the protocol's 65535");
      f.width = s->hello.max_width + 1;
      f.height = 1;
      break;
    case F_HEIGHT_OVER:
      if (s->hello.max_height >= HFP_MAX_SIDE) return cf_skip(t, "max_height is the protocol's 65535");
      f.height = s->hello.max_height + 1;
      f.width = 1;
      break;
    case F_SPP_PLUS: f.spp++; break;
    case F_SPP_MINUS:
      if (f.spp < 2) return cf_skip(t, "the variant takes 1 spp");
      f.spp--;
      break;
  }
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  size_t vn = strlen(f.variant);
  uint32_t length = (uint32_t)(n - HFP_HEADER_SIZE);
  float nan = NAN, inf = INFINITY, ninf = -INFINITY;
  switch (which) {
    case F_WIDTH0: hfp_put_u32(b + CF_FILTER_WIDTH, 0); break;
    case F_HEIGHT0: hfp_put_u32(b + CF_FILTER_HEIGHT, 0); break;
    /* Out of the protocol's domain and over any limit: either code. */
    case F_WIDTH_65536: hfp_put_u32(b + CF_FILTER_WIDTH, 65536); codes |= CF_CODE(HFP_E_TOO_LARGE); break;
    case F_HEIGHT_65536: hfp_put_u32(b + CF_FILTER_HEIGHT, 65536); codes |= CF_CODE(HFP_E_TOO_LARGE); break;
    case F_WIDTH_U32: hfp_put_u32(b + CF_FILTER_WIDTH, 0xffffffffu); codes |= CF_CODE(HFP_E_TOO_LARGE); break;
    case F_WIDTH_OVER:
    case F_HEIGHT_OVER: codes = CF_CODE(HFP_E_TOO_LARGE); break;
    case F_SPP0: hfp_put_u16(b + CF_FILTER_SPP, 0); break;
    case F_SPP17: hfp_put_u16(b + CF_FILTER_SPP, 17); break;
    case F_SPP_PLUS:
    case F_SPP_MINUS: break;
    case F_IN2: b[CF_FILTER_IN_DTYPE] = 2; codes = CF_CODE(HFP_E_UNSUPPORTED); break;
    case F_IN255: b[CF_FILTER_IN_DTYPE] = 255; codes = CF_CODE(HFP_E_UNSUPPORTED); break;
    case F_OUT2: b[CF_FILTER_OUT_DTYPE] = 2; codes = CF_CODE(HFP_E_UNSUPPORTED); break;
    case F_OUT255: b[CF_FILTER_OUT_DTYPE] = 255; codes = CF_CODE(HFP_E_UNSUPPORTED); break;
    /* Bit 3: unknown in every version (bit 2 is version 3's ESTIMATE). */
    case F_FLAG10: hfp_put_u16(b + CF_FILTER_FLAGS, 0x10); codes = CF_CODE(HFP_E_UNSUPPORTED); break;
    case F_FLAG8000: hfp_put_u16(b + CF_FILTER_FLAGS, 0x8000); codes = CF_CODE(HFP_E_UNSUPPORTED); break;
    case F_HAIR_NAN: memcpy(b + CF_FILTER_HAIR, &nan, 4); break;
    case F_HAIR_INF: memcpy(b + CF_FILTER_HAIR + 4, &inf, 4); break;
    case F_HAIR_NINF: memcpy(b + CF_FILTER_HAIR + 8, &ninf, 4); break;
    case F_LIGHT_NAN: memcpy(b + CF_FILTER_LIGHT + 4, &nan, 4); break;
    case F_LIGHT_INF: memcpy(b + CF_FILTER_LIGHT, &inf, 4); break;
    case F_LIGHT_NINF: memcpy(b + CF_FILTER_LIGHT + 8, &ninf, 4); break;
    case F_BG_NAN: memcpy(b + CF_FILTER_BG + 8, &nan, 4); break;
    case F_BG_INF: memcpy(b + CF_FILTER_BG + 4, &inf, 4); break;
    case F_BG_NINF: memcpy(b + CF_FILTER_BG, &ninf, 4); break;
    case F_UNKNOWN:
      codes = CF_CODE(HFP_E_UNKNOWN_VARIANT);
      unknown_name(s, b, vn);
      break;
    case F_CASE: {
      codes = CF_CODE(HFP_E_UNKNOWN_VARIANT);
      size_t i = 0;
      while (i < vn && !((b[CF_FILTER_NAME + i] | 0x20) >= 'a' && (b[CF_FILTER_NAME + i] | 0x20) <= 'z')) i++;
      if (i == vn) return cf_skip(t, "the variant's name has no letter");
      b[CF_FILTER_NAME + i] ^= 0x20;
      for (int k = 0; k < s->nv; k++)
        if (strlen(s->variants[k].name) == vn && !memcmp(s->variants[k].name, b + CF_FILTER_NAME, vn))
          return cf_skip(t, "another variant has that name in other case");
      break;
    }
    case F_VLEN0: hfp_put_u16(b + CF_FILTER_VLEN, 0); break;
    case F_VLEN65: hfp_put_u16(b + CF_FILTER_VLEN, 65); break;
    case F_VLEN_PAST:
      hfp_put_u16(b + CF_FILTER_VLEN, HFP_NAME_MAX);
      length = (uint32_t)(HFP_FILTER_FIXED + vn);
      n = HFP_HEADER_SIZE + length;
      if (vn >= HFP_NAME_MAX) return cf_skip(t, "the variant's name is 64 bytes");
      codes = CF_CODE(HFP_E_LENGTH);
      break;
    case F_SHORT: length--, n--; codes = CF_CODE(HFP_E_LENGTH); break;
    case F_LONG: {
      uint8_t *b2 = cf_alloc(t, n + 1);
      CF_CHECK(t, b2, "out of memory");
      memcpy(b2, b, n);
      b2[n] = 0;
      b = b2;
      length++, n++;
      codes = CF_CODE(HFP_E_LENGTH);
      break;
    }
    case F_FIXED_ONLY: length = (uint32_t)(HFP_FILTER_FIXED + vn); n = HFP_HEADER_SIZE + length; codes = CF_CODE(HFP_E_LENGTH); break;
    case F_BELOW_FIXED: length = HFP_FILTER_FIXED - 1; n = HFP_HEADER_SIZE + length; codes = CF_CODE(HFP_E_LENGTH); break;
    case F_EMPTY: length = 0; n = HFP_HEADER_SIZE; codes = CF_CODE(HFP_E_LENGTH); break;
    case F_OVERFLOW32: {
      /* Dimensions whose tensor is more than 2^32 bytes, with the length a
       * 32-bit product would give: TOO_LARGE (over the limits) or LENGTH,
       * never admitted, and the frame is skipped by its length. */
      uint32_t w = 65535, h = 65535;
      uint64_t bytes = (uint64_t)w * h * (uint64_t)f.spp * 6 * 4;
      uint32_t wrapped = (uint32_t)(HFP_FILTER_FIXED + vn + bytes);
      hfp_put_u32(b + CF_FILTER_WIDTH, w);
      hfp_put_u32(b + CF_FILTER_HEIGHT, h);
      if (wrapped < HFP_FILTER_FIXED + vn || wrapped > n - HFP_HEADER_SIZE) {
        /* Send what the wrapped length says, up to our frame's size. */
        wrapped = (uint32_t)(n - HFP_HEADER_SIZE);
      }
      length = wrapped;
      n = HFP_HEADER_SIZE + length;
      codes = CF_CODE(HFP_E_TOO_LARGE) | CF_CODE(HFP_E_LENGTH) | CF_CODE(HFP_E_INVALID);
      break;
    }
    case F_SHM_SHORT:
    case F_SHM_LONG: {
      /* SHM set, and the reference cut short or followed by a byte. */
      hfp_put_u16(b + CF_FILTER_FLAGS, HFP_FILTER_SHM);
      length = (uint32_t)(HFP_FILTER_FIXED + vn + HFP_SHM_REF_SIZE + (which == F_SHM_LONG ? 1 : -1));
      n = HFP_HEADER_SIZE + length;
      memset(b + CF_FILTER_NAME + vn, 0, HFP_SHM_REF_SIZE + 1);
      hfp_put_u32(b + CF_FILTER_NAME + vn, 1);
      /* Where this connection cannot have a segment, SHM itself is refused
       * first (PROTOCOL.md, "Which error a FILTER gets"). */
      codes = CF_CODE((s->hello.server_flags & HFP_SERVER_SHM) ? HFP_E_LENGTH : HFP_E_UNSUPPORTED);
      break;
    }
    case F_F16_WITH_F32_TENSOR:
      /* in_dtype f16, the tensor of f32's size: twice what the fields say */
      b[CF_FILTER_IN_DTYPE] = HFP_F16;
      codes = CF_CODE(HFP_E_LENGTH);
      break;
    case F_DTYPE_UNOFFERED: {
      int missing = !(s->hello.dtypes & 1) ? HFP_F32 : !(s->hello.dtypes & 2) ? HFP_F16 : -1;
      if (missing < 0) return cf_skip(t, "the server offers both dtypes");
      b[CF_FILTER_OUT_DTYPE] = (uint8_t)missing;
      codes = CF_CODE(HFP_E_UNSUPPORTED);
      break;
    }
  }
  cf_set_length(b, length);
  int fd;
  CF_TRY(connect_v(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_expect_error_in(t, fd, codes, 0, f.id));
  /* The connection goes on, the framing intact: a valid FILTER works. */
  cf_filter ok = {.id = f.id + 1000};
  cf_filter_defaults(t, &ok);
  return cf_filter_ok(t, fd, &ok, s->version, NULL, NULL);
}

/* ---- the alpha-corrected estimate (version 3) --------------------------------- */

enum { EST_V2_FLAG, EST_UNNEEDED, EST_SHORT, EST_MISSING, EST_SERVED, EST_NAN, EST_HUGE,
       EST_NEGATIVE };

/* The first variant VARIANTS says reads the estimate, or -1. */
static int estimate_variant(const cf_server *s) {
  for (int i = 0; i < s->nv; i++)
    if (s->variants[i].estimate) return i;
  return -1;
}

/* FILTER flag ESTIMATE: unknown before version 3 (UNSUPPORTED, whatever
 * the length); in version 3 refused for a variant that reads no estimate
 * (INVALID) and required by one that does (INVALID without it); a tensor
 * without the estimate it announces is LENGTH; with it, the frame is
 * served, also when samples and estimate are out of contract. Each refusal
 * is non-fatal and the connection goes on. */
static int estimate(cf_test *t, intptr_t which) {
  const cf_server *s = t->srv;
  if (which != EST_V2_FLAG && s->version < 3)
    return cf_skip(t, "the server speaks version %d, without the estimate", s->version);
  int ev = estimate_variant(s);
  const int served = which == EST_MISSING || which >= EST_SERVED;
  if (served && ev < 0) return cf_skip(t, "no variant reads the estimate");
  if (s->variants[s->probe].estimate && !served)
    return cf_skip(t, "the probe variant reads the estimate");
  if (which >= EST_NAN) {
    /* Samples and estimate alike out of contract: the RESULT is in range
     * (cf_check_result), in each offered output dtype, with a composite. */
    static const int kinds[] = {CF_FEAT_NAN, CF_FEAT_HUGE, CF_FEAT_NEGATIVE};
    int fd;
    CF_TRY(connect_v(t, &fd));
    for (int out = HFP_F32; out <= HFP_F16; out++) {
      if (!(s->hello.dtypes & (1u << out))) continue;
      cf_filter f = {.id = 1720 + (uint32_t)out, .variant = s->variants[ev].name,
                     .features = kinds[which - EST_NAN], .out_dtype = out,
                     .flags = HFP_FILTER_COMPOSITE};
      cf_filter_defaults(t, &f);
      CF_TRY(cf_filter_ok(t, fd, &f, s->version, NULL, NULL));
    }
    return 0;
  }
  int fd, version = which == EST_V2_FLAG ? 2 : s->version;
  if (which == EST_V2_FLAG) {
    if (s->version < 2) return cf_skip(t, "the server speaks version 1");
    CF_TRY(cf_connect_hello(t, 1, 2, &fd, NULL));
  } else {
    CF_TRY(connect_v(t, &fd));
  }
  cf_filter f = {.id = 1700 + (uint32_t)which};
  if (which == EST_MISSING || which == EST_SERVED) f.variant = s->variants[ev].name;
  cf_filter_defaults(t, &f);
  if (which == EST_SERVED) return cf_filter_ok(t, fd, &f, version, NULL, NULL);
  /* The tensor as the flags before the change say: with the estimate only
   * for EST_UNNEEDED. */
  int code = HFP_E_INVALID;
  if (which == EST_UNNEEDED) f.flags |= HFP_FILTER_ESTIMATE;
  if (which == EST_MISSING) f.flags &= (uint16_t)~HFP_FILTER_ESTIMATE;
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  if (which == EST_V2_FLAG || which == EST_SHORT) {
    hfp_put_u16(b + CF_FILTER_FLAGS, f.flags | HFP_FILTER_ESTIMATE);
    code = which == EST_V2_FLAG ? HFP_E_UNSUPPORTED : HFP_E_LENGTH;
  }
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_expect_error(t, fd, code, 0, f.id));
  cf_filter ok = {.id = f.id + 1000};
  cf_filter_defaults(t, &ok);
  return cf_filter_ok(t, fd, &ok, version, NULL, NULL);
}

/* ---- a frame's deadline (version 4) ------------------------------------------ */

enum { DL_V3_FLAG, DL_ZERO, DL_SHORT, DL_SERVED, DL_TINY };

/* FILTER flag DEADLINE: unknown before version 4 (UNSUPPORTED, whatever
 * the length); in version 4 a budget of 0 is INVALID and a payload without
 * the 4 bytes the flag announces LENGTH (each non-fatal, the next frame
 * served); a frame within a generous budget is served as any other; one
 * whose budget of 1 us passes before it runs is a RESULT with status
 * EXPIRED, 56 bytes, no tensors (a server that starts it within 1 us may
 * serve it). */
static int deadline(cf_test *t, intptr_t which) {
  const cf_server *s = t->srv;
  if (which != DL_V3_FLAG && s->version < 4)
    return cf_skip(t, "the server speaks version %d, without deadlines", s->version);
  if (s->variants[s->probe].estimate)
    return cf_skip(t, "the probe variant reads the estimate");
  int fd, version = which == DL_V3_FLAG ? 3 : s->version;
  if (which == DL_V3_FLAG) {
    if (s->version < 3) return cf_skip(t, "the server speaks version %d", s->version);
    CF_TRY(cf_connect_hello(t, 1, 3, &fd, NULL));
  } else {
    CF_TRY(connect_v(t, &fd));
  }
  cf_filter f = {.id = 1800 + (uint32_t)which, .flags = HFP_FILTER_DEADLINE,
                 .budget_us = which == DL_TINY ? 1 : 60000000};
  cf_filter_defaults(t, &f);
  if (which == DL_SERVED) return cf_filter_ok(t, fd, &f, version, NULL, NULL);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  if (which == DL_TINY) {
    CF_TRY(cf_send(t, fd, b, n));
    cf_frame fr;
    int rc = cf_read(t, fd, t->o->timeout_ms, &fr);
    if (rc == CF_EOF) return cf_fail(t, "wanted RESULT %u, the server closed", f.id);
    if (rc == CF_TIMEOUT) return cf_fail(t, "wanted RESULT %u, nothing in %d ms", f.id, t->o->timeout_ms);
    if (rc != CF_GOT) return CF_FAIL;
    hfp_result r;
    if (fr.h.type == HFP_RESULT && fr.h.length >= 2 && hfp_get_u16(fr.p) == HFP_E_EXPIRED) {
      CF_CHECK(t, fr.h.request_id == f.id, "RESULT carries request id %u, the FILTER had %u",
               fr.h.request_id, f.id);
      CF_CHECK(t, hfp_decode_result(fr.p, fr.h.length, &r) == 0 && fr.h.length == HFP_RESULT_FIXED,
               "an EXPIRED RESULT must be the 56 fixed bytes with width, height, batch and flags 0 "
               "(%u payload bytes)", fr.h.length);
      CF_CHECK(t, r.batch == 0 && r.timing.infer_us == 0 && r.timing.queue_us <= r.timing.total_us,
               "an EXPIRED RESULT has batch %u, infer_us %llu, queue_us %llu of total %llu: "
               "want batch 0, infer 0, queue within the total", r.batch,
               (unsigned long long)r.timing.infer_us, (unsigned long long)r.timing.queue_us,
               (unsigned long long)r.timing.total_us);
    } else {
      CF_TRY(cf_check_result(t, &fr, &f, version, NULL, NULL, NULL));
    }
  } else {
    int code = HFP_E_UNSUPPORTED;
    if (which == DL_ZERO) {
      hfp_put_u32(b + CF_FILTER_NAME + strlen(f.variant), 0);
      code = HFP_E_INVALID;
    }
    if (which == DL_SHORT) {
      /* The budget announced, not sent: the tensor follows the name. */
      memmove(b + CF_FILTER_NAME + strlen(f.variant),
              b + CF_FILTER_NAME + strlen(f.variant) + HFP_DEADLINE_SIZE,
              n - CF_FILTER_NAME - strlen(f.variant) - HFP_DEADLINE_SIZE);
      n -= HFP_DEADLINE_SIZE;
      hfp_put_u32(b + 12, (uint32_t)(n - HFP_HEADER_SIZE));
      code = HFP_E_LENGTH;
    }
    CF_TRY(cf_send(t, fd, b, n));
    CF_TRY(cf_expect_error(t, fd, code, 0, f.id));
  }
  cf_filter ok = {.id = f.id + 1000};
  cf_filter_defaults(t, &ok);
  return cf_filter_ok(t, fd, &ok, version, NULL, NULL);
}

/* PROTOCOL.md, "Which error a FILTER gets": a FILTER with two faults gets
 * one non-fatal ERROR, with its id, for the fault that comes first in the
 * order, and the next frame is served. Each case pairs a fault with one
 * the order puts after it; the tensor agrees with the fields unless the
 * length is one of the two. */
enum {
  O_VLEN_FLAG,      /* variant_len 0 before an unknown flag: INVALID */
  O_NAME_FLAG,      /* a space in the name before an unknown flag: INVALID */
  O_FLAG_COLOUR,    /* an unknown flag before a NaN colour: UNSUPPORTED */
  O_DTYPE_SPP,      /* an unknown dtype before spp 0: UNSUPPORTED */
  O_COLOUR_LENGTH,  /* a NaN colour before a tensor a byte short: INVALID */
  O_WIDTH_LENGTH,   /* width 0 before the tensor of the ordinary size: INVALID */
  O_LENGTH_ID0,     /* a tensor a byte short before request id 0: LENGTH */
  O_LENGTH_VARIANT, /* a tensor a byte short before an unknown variant: LENGTH */
  O_FLAG_VARIANT,   /* an unknown flag before an unknown variant: UNSUPPORTED */
  O_ID0_VARIANT,    /* request id 0 before an unknown variant: INVALID */
  O_VARIANT_SPP,    /* an unknown variant before spp not the variant's: UNKNOWN_VARIANT */
  O_VARIANT_SIZE,   /* an unknown variant before a width over max_width: UNKNOWN_VARIANT */
  O_SPP_SIZE,       /* spp not the variant's before a width over max_width: INVALID */
};

static int fault_order(cf_test *t, intptr_t which) {
  const cf_server *s = t->srv;
  cf_filter f = {.id = 700 + (uint32_t)which};
  cf_filter_defaults(t, &f);
  if (which == O_VARIANT_SPP || which == O_SPP_SIZE) f.spp = f.spp < HFP_MAX_SPP ? f.spp + 1 : f.spp - 1;
  if (which == O_VARIANT_SIZE || which == O_SPP_SIZE) {
    if (s->hello.max_width >= HFP_MAX_SIDE) return cf_skip(t, "max_width is the protocol's 65535");
    f.width = s->hello.max_width + 1;
    f.height = 1;
  }
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  size_t vn = strlen(f.variant);
  uint32_t length = (uint32_t)(n - HFP_HEADER_SIZE), id = f.id;
  float nan = NAN;
  int code = HFP_E_INVALID;
  switch (which) {
    case O_VLEN_FLAG:
      hfp_put_u16(b + CF_FILTER_VLEN, 0);
      hfp_put_u16(b + CF_FILTER_FLAGS, 0x10);   /* a flag of no version up to 4 */
      break;
    case O_NAME_FLAG:
      b[CF_FILTER_NAME] = ' ';
      hfp_put_u16(b + CF_FILTER_FLAGS, 0x10);   /* a flag of no version up to 4 */
      break;
    case O_FLAG_COLOUR:
      hfp_put_u16(b + CF_FILTER_FLAGS, 0x10);   /* a flag of no version up to 4 */
      memcpy(b + CF_FILTER_HAIR, &nan, 4);
      code = HFP_E_UNSUPPORTED;
      break;
    case O_DTYPE_SPP:
      b[CF_FILTER_IN_DTYPE] = 2;
      hfp_put_u16(b + CF_FILTER_SPP, 0);
      code = HFP_E_UNSUPPORTED;
      break;
    case O_COLOUR_LENGTH:
      memcpy(b + CF_FILTER_LIGHT, &nan, 4);
      length--, n--;
      break;
    case O_WIDTH_LENGTH: hfp_put_u32(b + CF_FILTER_WIDTH, 0); break;
    case O_LENGTH_ID0:
      length--, n--;
      id = 0;
      code = HFP_E_LENGTH;
      break;
    case O_LENGTH_VARIANT:
      length--, n--;
      unknown_name(s, b, vn);
      code = HFP_E_LENGTH;
      break;
    case O_FLAG_VARIANT:
      hfp_put_u16(b + CF_FILTER_FLAGS, 0x10);   /* a flag of no version up to 4 */
      unknown_name(s, b, vn);
      code = HFP_E_UNSUPPORTED;
      break;
    case O_ID0_VARIANT:
      id = 0;
      unknown_name(s, b, vn);
      break;
    case O_VARIANT_SPP:
    case O_VARIANT_SIZE:
      unknown_name(s, b, vn);
      code = HFP_E_UNKNOWN_VARIANT;
      break;
    case O_SPP_SIZE: break;
  }
  hfp_put_u32(b + 8, id);
  cf_set_length(b, length);
  int fd;
  CF_TRY(connect_v(t, &fd));
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_expect_error(t, fd, code, 0, id));
  cf_filter ok = {.id = f.id + 1000};
  cf_filter_defaults(t, &ok);
  return cf_filter_ok(t, fd, &ok, s->version, NULL, NULL);
}

/* A refusal may come before the tensor; the rest is read and dropped, and
 * the next frame is served. */
static int early_refusal(cf_test *t, intptr_t arg) {
  (void)arg;
  cf_filter f = {.id = 700, .width = t->srv->hello.max_width, .height = 1};
  cf_filter_defaults(t, &f);
  f.spp++;   /* not the variant's: INVALID, the length agreeing */
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  size_t head = CF_FILTER_NAME + strlen(f.variant);
  int fd;
  CF_TRY(connect_v(t, &fd));
  CF_TRY(cf_send(t, fd, b, head));
  cf_frame r;
  int rc = cf_read(t, fd, t->o->quiet_ms, &r);
  if (rc == CF_GOT) {
    hfp_error e;
    char d[400];
    CF_CHECK(t, r.h.type == HFP_ERROR && hfp_decode_error(r.p, r.h.length, &e) == 0 &&
                    e.code == HFP_E_INVALID && !e.fatal && r.h.request_id == 700,
             "got %s before the tensor", cf_describe(&r, d, sizeof d));
  }
  CF_CHECK(t, rc == CF_GOT || rc == CF_TIMEOUT, "the server closed after a FILTER head");
  CF_TRY(cf_send(t, fd, b + head, n - head));
  if (rc != CF_GOT) CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 700));
  cf_filter ok = {.id = 701};
  cf_filter_defaults(t, &ok);
  return cf_filter_ok(t, fd, &ok, t->srv->version, NULL, NULL);
}

/* Two FILTERs with the same id in flight: the server does not check; each
 * gets exactly one reply with that id. */
static int duplicate_id(cf_test *t, intptr_t arg) {
  (void)arg;
  if (t->srv->hello.max_inflight < 2) return cf_skip(t, "max_inflight is 1");
  int fd;
  CF_TRY(connect_v(t, &fd));
  cf_filter f = {.id = 800};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_send(t, fd, b, n));
  for (int i = 0; i < 2; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of 2 replies to a reused id came", i);
    char d[400];
    CF_CHECK(t, r.h.request_id == 800, "a reply carries id %u: %s", r.h.request_id,
             cf_describe(&r, d, sizeof d));
    int busy = cf_busy(t, &r, NULL);
    if (busy < 0) return busy;
    if (!busy) CF_TRY(cf_check_result(t, &r, &f, t->srv->version, NULL, NULL, NULL));
  }
  CF_TRY(cf_expect_quiet(t, fd));
  return cf_still_serves(t, fd);
}

/* CANCEL (version 4): before version 4 no request (a fatal PROTOCOL with id
 * 0); with a payload a fatal LENGTH; of an id not in flight (never sent,
 * or already answered) no reply at all, the connection serving on; after
 * several FILTERs in one write, each still gets exactly one reply, the
 * cancelled one a RESULT CANCELLED (56 bytes) or, when it had started,
 * its result. */
enum { CN_V3, CN_PAYLOAD, CN_UNKNOWN, CN_PIPELINED };

static int cancel(cf_test *t, intptr_t which) {
  const cf_server *s = t->srv;
  if (s->version < 4) return cf_skip(t, "the server speaks version %d, without CANCEL", s->version);
  if (s->variants[s->probe].estimate) return cf_skip(t, "the probe variant reads the estimate");
  int fd;
  uint8_t b[HFP_HEADER_SIZE + 4];
  memset(b, 0, sizeof b);
  if (which == CN_V3) {
    CF_TRY(cf_connect_hello(t, 1, 3, &fd, NULL));
    cf_header(b, HFP_CANCEL, 0, 5, 0);
    CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE));
    return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
  }
  CF_TRY(connect_v(t, &fd));
  if (which == CN_PAYLOAD) {
    cf_header(b, HFP_CANCEL, 0, 5, 4);
    CF_TRY(cf_send(t, fd, b, sizeof b));
    return cf_expect_error(t, fd, HFP_E_LENGTH, 1, 0);
  }
  cf_filter f = {.id = 1900};
  cf_filter_defaults(t, &f);
  if (which == CN_UNKNOWN) {
    cf_header(b, HFP_CANCEL, 0, 77, 0);   /* never sent */
    CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE));
    CF_TRY(cf_filter_ok(t, fd, &f, s->version, NULL, NULL));
    cf_header(b, HFP_CANCEL, 0, f.id, 0);  /* already answered */
    CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE));
    CF_TRY(cf_expect_quiet(t, fd));
    return cf_still_serves(t, fd);
  }
  int n = (int)s->hello.max_inflight < 4 ? (int)s->hello.max_inflight : 4;
  if (n < 2) return cf_skip(t, "max_inflight is 1");
  size_t len;
  for (int i = 0; i < n; i++) {
    f.id = 1910 + (uint32_t)i;
    uint8_t *fb = cf_filter_frame(t, &f, &len);
    CF_CHECK(t, fb, "out of memory");
    CF_TRY(cf_send(t, fd, fb, len));
  }
  cf_header(b, HFP_CANCEL, 0, 1910 + (uint32_t)n - 1, 0);
  CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE));
  int seen = 0;
  for (int i = 0; i < n; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of %d replies came", i, n);
    uint32_t id = r.h.request_id;
    CF_CHECK(t, id >= 1910 && id < 1910 + (uint32_t)n && !(seen & (1 << (id - 1910))),
             "a reply with id %u: none or another was due", id);
    seen |= 1 << (id - 1910);
    int busy = cf_busy(t, &r, NULL);
    if (busy < 0) return busy;
    if (busy) continue;
    if (r.h.type == HFP_RESULT && r.h.length >= 2 && hfp_get_u16(r.p) == HFP_E_CANCELLED) {
      hfp_result res;
      CF_CHECK(t, id == 1910 + (uint32_t)n - 1, "RESULT CANCELLED for request %u, not cancelled",
               id);
      CF_CHECK(t, hfp_decode_result(r.p, r.h.length, &res) == 0 && r.h.length == HFP_RESULT_FIXED &&
                      res.batch == 0,
               "a CANCELLED RESULT must be the 56 fixed bytes, batch 0 (%u payload bytes)",
               r.h.length);
      continue;
    }
    f.id = id;
    CF_TRY(cf_check_result(t, &r, &f, s->version, NULL, NULL, NULL));
  }
  CF_TRY(cf_expect_quiet(t, fd));
  return cf_still_serves(t, fd);
}

/* Many more FILTERs than max_inflight in one write: each gets exactly one
 * reply, a RESULT or a non-fatal BUSY with its id, and afterwards the
 * connection serves. */
static int inflight_limit(cf_test *t, intptr_t factor) {
  int k = t->srv->hello.max_inflight * (int)factor + 2;
  if (k > 256) k = 256;
  cf_filter f = {.id = 1};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *one = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, one, "out of memory");
  uint8_t *all = cf_alloc(t, n * (size_t)k);
  CF_CHECK(t, all, "out of memory");
  for (int i = 0; i < k; i++) {
    memcpy(all + n * (size_t)i, one, n);
    hfp_put_u32(all + n * (size_t)i + 8, 1000 + (uint32_t)i);
  }
  int fd;
  CF_TRY(connect_v(t, &fd));
  CF_TRY(cf_send(t, fd, all, n * (size_t)k));
  uint8_t *seen = cf_alloc(t, (size_t)k);
  int results = 0;
  for (int i = 0; i < k; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of %d replies came", i, k);
    uint32_t id = r.h.request_id;
    char d[400];
    CF_CHECK(t, id >= 1000 && id < 1000 + (uint32_t)k, "a reply for id %u, never sent: %s", id,
             cf_describe(&r, d, sizeof d));
    CF_CHECK(t, !seen[id - 1000], "a second reply for id %u: %s", id, cf_describe(&r, d, sizeof d));
    seen[id - 1000] = 1;
    int b = cf_busy(t, &r, NULL);
    if (b < 0) return b;
    if (!b) {
      cf_filter fi = f;
      fi.id = id;
      CF_TRY(cf_check_result(t, &r, &fi, t->srv->version, NULL, NULL, NULL));
      results++;
    }
  }
  CF_CHECK(t, results >= 1, "all %d frames were refused", k);
  CF_TRY(cf_expect_quiet(t, fd));
  return cf_still_serves(t, fd);
}

/* A client that reads while it sends and keeps max_inflight in flight is
 * never refused for the in-flight limit: every frame gets a RESULT (or a
 * BUSY for the queue or memory, which others may have filled). */
static int window(cf_test *t, intptr_t rounds) {
  int k = t->srv->hello.max_inflight;
  if (k > 16) k = 16;
  cf_filter f = {.id = 1};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  int fd;
  CF_TRY(connect_v(t, &fd));
  int total = k * (int)rounds, sent = 0, got = 0;
  while (got < total) {
    while (sent < total && sent - got < k) {
      hfp_put_u32(b + 8, 2000 + (uint32_t)sent);
      CF_TRY(cf_send(t, fd, b, n));
      sent++;
    }
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of %d replies came", got, total);
    hfp_error e;
    int busy = cf_busy(t, &r, &e);
    if (busy < 0) return busy;
    if (busy) {
      CF_CHECK(t, !strstr(e.message, "in flight"),
               "a FILTER within max_inflight %d was refused for the in-flight limit: %s", k, e.message);
    } else {
      cf_filter fi = f;
      fi.id = r.h.request_id;
      CF_TRY(cf_check_result(t, &r, &fi, t->srv->version, NULL, NULL, NULL));
    }
    got++;
  }
  return 0;
}

/* A refused FILTER followed at once by a valid one, in one write. */
static int refused_then_valid(cf_test *t, intptr_t arg) {
  (void)arg;
  cf_filter bad = {.id = 900}, good = {.id = 901};
  cf_filter_defaults(t, &bad);
  cf_filter_defaults(t, &good);
  size_t n1, n2;
  uint8_t *b1 = cf_filter_frame(t, &bad, &n1), *b2 = cf_filter_frame(t, &good, &n2);
  CF_CHECK(t, b1 && b2, "out of memory");
  hfp_put_u32(b1 + CF_FILTER_WIDTH, 0);   /* INVALID, tensor still sent */
  uint8_t *all = cf_alloc(t, n1 + n2);
  CF_CHECK(t, all, "out of memory");
  memcpy(all, b1, n1);
  memcpy(all + n1, b2, n2);
  int fd;
  CF_TRY(connect_v(t, &fd));
  CF_TRY(cf_send(t, fd, all, n1 + n2));
  /* The refused FILTER's length still counts its tensor, which is read
   * and dropped; the valid one after it is framed as sent. */
  CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 900));
  cf_frame r;
  int rc = cf_read(t, fd, t->o->timeout_ms, &r);
  CF_CHECK(t, rc == CF_GOT, "no reply to the valid FILTER after the refused one");
  return cf_check_result(t, &r, &good, t->srv->version, NULL, NULL, NULL);
}

/* Frames of different variants, sizes or dtypes in flight together: each
 * gets the result it gets alone (batches form only of compatible frames). */
enum { MIX_VARIANTS, MIX_SIZES, MIX_DTYPES };

static int mixed(cf_test *t, intptr_t how) {
  const cf_server *s = t->srv;
  cf_filter fs[8];
  int n = 0;
  memset(fs, 0, sizeof fs);
  switch (how) {
    case MIX_VARIANTS:
      for (int i = 0; i < s->nv && n < 4; i++) fs[n++].variant = s->variants[i].name;
      if (n < 2) return cf_skip(t, "the server has one variant");
      break;
    case MIX_SIZES:
      fs[0].width = fs[0].height = 1;
      fs[1].width = s->hello.max_width < 6 ? s->hello.max_width : 6;
      fs[1].height = s->hello.max_height < 3 ? s->hello.max_height : 3;
      fs[2].width = 2, fs[2].height = 2;
      n = 3;
      break;
    case MIX_DTYPES:
      for (int k = 0; k < 4; k++) {
        if (!(s->hello.dtypes & (1u << (k & 1))) || !(s->hello.dtypes & (1u << (k >> 1)))) continue;
        fs[n].in_dtype = k & 1;
        fs[n++].out_dtype = k >> 1;
      }
      if (n < 2) return cf_skip(t, "the server offers one dtype");
      break;
  }
  int k = n * 2;   /* each twice: alone's twin in the crowd */
  if (k > s->hello.max_inflight) k = s->hello.max_inflight;
  if (k < 2) return cf_skip(t, "max_inflight is 1");
  int fd;
  CF_TRY(connect_v(t, &fd));
  float *alone[8];
  for (int i = 0; i < n; i++) {
    fs[i].id = 1100 + (uint32_t)i;
    cf_filter_defaults(t, &fs[i]);
    CF_TRY(cf_filter_ok(t, fd, &fs[i], s->version, &alone[i], NULL));
  }
  for (int i = 0; i < k; i++) {
    cf_filter f = fs[i % n];
    f.id = 1200 + (uint32_t)i;
    size_t len;
    uint8_t *b = cf_filter_frame(t, &f, &len);
    CF_CHECK(t, b, "out of memory");
    CF_TRY(cf_send(t, fd, b, len));
  }
  for (int i = 0; i < k; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "%d of %d replies came", i, k);
    uint32_t id = r.h.request_id;
    CF_CHECK(t, id >= 1200 && id < 1200 + (uint32_t)k, "a reply for id %u, never sent", id);
    int busy = cf_busy(t, &r, NULL);
    if (busy < 0) return busy;
    if (busy) continue;
    cf_filter f = fs[(id - 1200) % (uint32_t)n];
    f.id = id;
    float *res;
    CF_TRY(cf_check_result(t, &r, &f, s->version, NULL, &res, NULL));
    CF_CHECK(t, !memcmp(res, alone[(id - 1200) % (uint32_t)n], (size_t)f.width * f.height * 12),
             "request %u (%s %ux%u, dtypes %d/%d) in a crowd differs from the same frame alone", id,
             f.variant, f.width, f.height, f.in_dtype, f.out_dtype);
  }
  return 0;
}

#define DT(in, out, c, name) {"filter.dtypes." name, "FILTER in any offered dtype pair: RESULT in out_dtype, values in range", 0, dtypes, (in) | (out) << 1 | (c) << 2}
#define BF(w, name, rule) {"filter.bad_field." name, rule, 0, bad_field, w}

const cf_case cf_cases_filter[] = {
  DT(0, 0, 0, "f32_f32"),
  DT(0, 1, 0, "f32_f16"),
  DT(1, 0, 0, "f16_f32"),
  DT(1, 1, 0, "f16_f16"),
  DT(0, 0, 1, "f32_f32_composite"),
  DT(1, 1, 1, "f16_f16_composite"),
  DT(0, 1, 1, "f32_f16_composite"),
  {"filter.composite.huge_colours_f32", "finite colours whose composite overflows: RGBA finite, saturated at FLT_MAX", 0, huge_colours, 0},
  {"filter.composite.huge_colours_f16", "colours over f16's range: RGBA finite, saturated at 65504", 0, huge_colours, 1},
  {"filter.each_variant", "every variant VARIANTS lists filters a frame", 0, each_variant, 0},
  {"filter.size.1x1", "a 1x1 frame is within 1..max", 0, sizes, SIZE_1X1},
  {"filter.size.odd", "odd sizes are served", 0, sizes, SIZE_ODD},
  {"filter.size.max_width", "a frame max_width wide is served", 0, sizes, SIZE_WIDE},
  {"filter.size.max_height", "a frame max_height tall is served", 0, sizes, SIZE_TALL},
  {"filter.max_size.head", "max_width x max_height f32 COMPOSITE is never TOO_LARGE (checked on the head)", 0, max_size, 0},
  {"filter.max_size.whole", "max_width x max_height f32 COMPOSITE on an idle server is admitted (or BUSY)", 0, max_size, 1},
  {"filter.input.non_finite", "results stay finite and in range whatever the input (NaN, infinities)", 0, adversarial, CF_FEAT_NAN},
  {"filter.input.huge", "results stay finite and in range whatever the input (huge values)", 0, adversarial, CF_FEAT_HUGE},
  {"filter.input.negative", "results stay finite and in range whatever the input (negative values)", 0, adversarial, CF_FEAT_NEGATIVE},
  {"filter.mixed.variants", "frames of different variants in flight together get their results alone", 0, mixed, MIX_VARIANTS},
  {"filter.mixed.sizes", "frames of different sizes in flight together get their results alone", 0, mixed, MIX_SIZES},
  {"filter.mixed.dtypes", "frames of different dtypes in flight together get their results alone", 0, mixed, MIX_DTYPES},
  {"filter.batching_same_values", "batching changes only batch and timing, never the values", 0, same_values, 4},
  BF(F_WIDTH0, "width_zero", "width 0 is a non-fatal INVALID with the FILTER's id"),
  BF(F_HEIGHT0, "height_zero", "height 0 is a non-fatal INVALID"),
  BF(F_WIDTH_65536, "width_65536", "width over 65535 is out of the domain (INVALID or TOO_LARGE)"),
  BF(F_HEIGHT_65536, "height_65536", "height over 65535 is out of the domain (INVALID or TOO_LARGE)"),
  BF(F_WIDTH_U32, "width_u32_max", "width 2^32-1 is out of the domain (INVALID or TOO_LARGE)"),
  BF(F_WIDTH_OVER, "width_over_limit", "width over max_width is a non-fatal TOO_LARGE"),
  BF(F_HEIGHT_OVER, "height_over_limit", "height over max_height is a non-fatal TOO_LARGE"),
  BF(F_SPP0, "spp_zero", "spp 0 is a non-fatal INVALID"),
  BF(F_SPP17, "spp_17", "spp over 16 is a non-fatal INVALID"),
  BF(F_SPP_PLUS, "spp_not_variants_more", "spp must equal the variant's: INVALID"),
  BF(F_SPP_MINUS, "spp_not_variants_fewer", "spp must equal the variant's: INVALID"),
  BF(F_IN2, "in_dtype_2", "an unknown in_dtype is a non-fatal UNSUPPORTED"),
  BF(F_IN255, "in_dtype_255", "an unknown in_dtype is a non-fatal UNSUPPORTED"),
  BF(F_OUT2, "out_dtype_2", "an unknown out_dtype is a non-fatal UNSUPPORTED"),
  BF(F_OUT255, "out_dtype_255", "an unknown out_dtype is a non-fatal UNSUPPORTED"),
  BF(F_F16_WITH_F32_TENSOR, "f16_with_f32_tensor", "in_dtype f16 with a tensor of f32's size: LENGTH"),
  BF(F_DTYPE_UNOFFERED, "dtype_not_offered", "a dtype HELLO_OK does not offer is UNSUPPORTED"),
  BF(F_FLAG10, "flags_bit4", "unknown FILTER flags are a non-fatal UNSUPPORTED (bit 3 is DEADLINE from version 4)"),
  BF(F_FLAG8000, "flags_bit15", "unknown FILTER flags are a non-fatal UNSUPPORTED"),
  BF(F_HAIR_NAN, "hair_nan", "colours must be finite even without COMPOSITE: INVALID"),
  BF(F_HAIR_INF, "hair_inf", "colours must be finite: INVALID"),
  BF(F_HAIR_NINF, "hair_minus_inf", "colours must be finite: INVALID"),
  BF(F_LIGHT_NAN, "light_nan", "colours must be finite: INVALID"),
  BF(F_LIGHT_INF, "light_inf", "colours must be finite: INVALID"),
  BF(F_LIGHT_NINF, "light_minus_inf", "colours must be finite: INVALID"),
  BF(F_BG_NAN, "background_nan", "colours must be finite: INVALID"),
  BF(F_BG_INF, "background_inf", "colours must be finite: INVALID"),
  BF(F_BG_NINF, "background_minus_inf", "colours must be finite: INVALID"),
  BF(F_UNKNOWN, "unknown_variant", "a name no loaded variant has is a non-fatal UNKNOWN_VARIANT"),
  BF(F_CASE, "variant_case", "variant names are compared byte for byte: UNKNOWN_VARIANT"),
  BF(F_VLEN0, "variant_len_zero", "variant_len 0 is a non-fatal INVALID"),
  BF(F_VLEN65, "variant_len_65", "variant_len over 64 is a non-fatal INVALID"),
  BF(F_VLEN_PAST, "variant_past_end", "a variant name past the payload's end is LENGTH"),
  BF(F_SHORT, "length_short_by_one", "a payload one byte short of its fields is a non-fatal LENGTH"),
  BF(F_LONG, "length_long_by_one", "a payload one byte longer than its fields is a non-fatal LENGTH"),
  BF(F_FIXED_ONLY, "length_no_tensor", "a payload without its tensor is a non-fatal LENGTH"),
  BF(F_BELOW_FIXED, "length_below_fixed", "a payload shorter than the fixed fields is a non-fatal LENGTH"),
  BF(F_EMPTY, "length_zero", "an empty FILTER is a non-fatal LENGTH"),
  BF(F_OVERFLOW32, "length_overflow_32", "dimensions whose tensor overflows 32 bits are never admitted"),
  BF(F_SHM_SHORT, "shm_reference_short", "with SHM, a reference cut short is LENGTH (UNSUPPORTED where SHM is not offered)"),
  BF(F_SHM_LONG, "shm_reference_long", "with SHM, bytes after the reference are LENGTH (UNSUPPORTED where SHM is not offered)"),
  {"filter.estimate.v2_flag", "before version 3, FILTER flag bit 2 is unknown: a non-fatal UNSUPPORTED", 0, estimate, EST_V2_FLAG},
  {"filter.estimate.unneeded", "ESTIMATE to a variant that reads no estimate is a non-fatal INVALID", 0, estimate, EST_UNNEEDED},
  {"filter.estimate.short", "ESTIMATE with a tensor that lacks the estimate is a non-fatal LENGTH", 0, estimate, EST_SHORT},
  {"filter.estimate.missing", "a variant that reads the estimate refuses a FILTER without ESTIMATE: INVALID", 0, estimate, EST_MISSING},
  {"filter.estimate.served", "a variant that reads the estimate filters a frame with it", 0, estimate, EST_SERVED},
  {"filter.estimate.input_non_finite", "NaN and infinities in samples and estimate: results finite and in range", 0, estimate, EST_NAN},
  {"filter.estimate.input_huge", "huge values in samples and estimate: results finite and in range", 0, estimate, EST_HUGE},
  {"filter.estimate.input_negative", "negative values in samples and estimate: results finite and in range", 0, estimate, EST_NEGATIVE},
  {"filter.deadline.v3_flag", "before version 4, FILTER flag bit 3 is unknown: a non-fatal UNSUPPORTED", 0, deadline, DL_V3_FLAG},
  {"filter.deadline.zero", "DEADLINE with a budget of 0 is a non-fatal INVALID", 0, deadline, DL_ZERO},
  {"filter.deadline.short", "DEADLINE without its 4 budget bytes is a non-fatal LENGTH", 0, deadline, DL_SHORT},
  {"filter.deadline.served", "a frame within its budget is filtered as any other", 0, deadline, DL_SERVED},
  {"filter.deadline.tiny_budget", "a budget of 1 us: a RESULT, EXPIRED (56 bytes, no tensors) or served", 0, deadline, DL_TINY},
  {"cancel.v3", "before version 4, CANCEL is no request: a fatal PROTOCOL with id 0", 0, cancel, CN_V3},
  {"cancel.payload", "a CANCEL with a payload is a fatal LENGTH", 0, cancel, CN_PAYLOAD},
  {"cancel.unknown_id", "a CANCEL of an id not in flight, never sent or answered, gets no reply", 0, cancel, CN_UNKNOWN},
  {"cancel.pipelined", "FILTERs then a CANCEL of the last: one reply each, CANCELLED or the result", 0, cancel, CN_PIPELINED},
  {"filter.order.variant_len_before_flag", "variant_len 0 and an unknown flag: INVALID, the name's fault first", 0, fault_order, O_VLEN_FLAG},
  {"filter.order.name_byte_before_flag", "a space in the name and an unknown flag: INVALID, the name's fault first", 0, fault_order, O_NAME_FLAG},
  {"filter.order.flag_before_colour", "an unknown flag and a NaN colour: UNSUPPORTED, the flag first", 0, fault_order, O_FLAG_COLOUR},
  {"filter.order.dtype_before_spp", "an unknown dtype and spp 0: UNSUPPORTED, the dtype first", 0, fault_order, O_DTYPE_SPP},
  {"filter.order.colour_before_length", "a NaN colour and a tensor a byte short: INVALID, the colour first", 0, fault_order, O_COLOUR_LENGTH},
  {"filter.order.width_before_length", "width 0 and a tensor of another size: INVALID, the width first", 0, fault_order, O_WIDTH_LENGTH},
  {"filter.order.length_before_id", "a tensor a byte short and request id 0: LENGTH, the frame's own fields first", 0, fault_order, O_LENGTH_ID0},
  {"filter.order.length_before_variant", "a tensor a byte short and an unknown variant: LENGTH, the frame's own fields first", 0, fault_order, O_LENGTH_VARIANT},
  {"filter.order.flag_before_variant", "an unknown flag and an unknown variant: UNSUPPORTED, the frame's own fields first", 0, fault_order, O_FLAG_VARIANT},
  {"filter.order.id_before_variant", "request id 0 and an unknown variant: INVALID, the id first", 0, fault_order, O_ID0_VARIANT},
  {"filter.order.variant_before_spp", "an unknown variant and spp not the variant's: UNKNOWN_VARIANT, the variant first", 0, fault_order, O_VARIANT_SPP},
  {"filter.order.variant_before_size", "an unknown variant and a width over max_width: UNKNOWN_VARIANT, the variant first", 0, fault_order, O_VARIANT_SIZE},
  {"filter.order.spp_before_size", "spp not the variant's and a width over max_width: INVALID, the spp first", 0, fault_order, O_SPP_SIZE},
  {"filter.early_refusal", "a refusal may come before the tensor; the rest is dropped, the next frame served", 0, early_refusal, 0},
  {"filter.refused_then_valid", "a refused FILTER and a valid one in one write: ERROR then RESULT", 0, refused_then_valid, 0},
  {"filter.duplicate_id", "a reused id is not checked: each FILTER gets exactly one reply", 0, duplicate_id, 0},
  {"filter.inflight.over_limit", "past max_inflight: exactly one reply per FILTER, RESULT or non-fatal BUSY", 0, inflight_limit, 4},
  {"filter.inflight.within_window", "a client keeping max_inflight in flight is never refused for it", 0, window, 3},
  {NULL, NULL, 0, NULL, 0},
};
