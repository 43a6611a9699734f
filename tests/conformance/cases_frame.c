/*
 * PROTOCOL.md, "Frames": the header checked before the payload (magic, type,
 * flags, length against max_frame_bytes), request ids, control requests'
 * exact lengths, and framing that does not depend on how the bytes are cut
 * into writes.
 */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cf_internal.h"

/* After HELLO, a header with byte `which` of the magic changed. */
static int bad_magic(cf_test *t, intptr_t which) {
  int fd;
  if (which == 4) {
    /* Before HELLO: a HELLO with a bad magic. */
    uint8_t b[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
    size_t n = cf_hello_frame(b, sizeof b, 1, HFP_VERSION, "conformance", t->o->token);
    b[0] ^= 0x01;
    CF_TRY(cf_connect(t, &fd));
    CF_TRY(cf_send(t, fd, b, n));
    return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
  }
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE * 2];
  cf_header(b, HFP_LIST_VARIANTS, 0, 0, 0);
  b[which] ^= 0x20;
  /* A valid request after it: the server has lost the framing and must
   * not answer it. */
  cf_header(b + HFP_HEADER_SIZE, HFP_LIST_VARIANTS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* After HELLO, a frame of a type that is not a request. */
static int bad_type(cf_test *t, intptr_t type) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE + 56];
  memset(b, 0, sizeof b);
  cf_header(b, (int)type, 0, 5, 56);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* The header's type is checked before its length: a type that is not a
 * request claiming a payload far over max_frame_bytes is still PROTOCOL,
 * not TOO_LARGE (only the header is sent). */
static int bad_type_long(cf_test *t, intptr_t type) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, (int)type, 0, 5, UINT32_MAX);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* Header flags are reserved: any bit is a fatal PROTOCOL, on any type. */
static int bad_flags(cf_test *t, intptr_t arg) {
  int type = (int)(arg & 0xffff);
  uint16_t flags = (uint16_t)(arg >> 16);
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  size_t n = HFP_HEADER_SIZE;
  uint8_t *b;
  if (type == HFP_FILTER) {
    cf_filter f = {.id = 3};
    cf_filter_defaults(t, &f);
    b = cf_filter_frame(t, &f, &n);
    CF_CHECK(t, b, "out of memory");
  } else {
    b = cf_alloc(t, HFP_HEADER_SIZE);
    cf_header(b, type, 0, 0, 0);
  }
  hfp_put_u16(b + 6, flags);
  CF_TRY(cf_send(t, fd, b, n));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* A frame longer than max_frame_bytes: fatal TOO_LARGE, with the FILTER's id
 * for a FILTER and 0 for anything else (LENGTH is as right for a control
 * request, whose length is fixed). */
static int too_long(cf_test *t, intptr_t type) {
  uint64_t max = t->srv->hello.max_frame_bytes;
  if (max >= UINT32_MAX) return cf_skip(t, "max_frame_bytes %llu: no 32-bit length exceeds it",
                                        (unsigned long long)max);
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, (int)type, 0, type == HFP_FILTER ? 41 : 0, (uint32_t)max + 1);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  if (type == HFP_FILTER) return cf_expect_error(t, fd, HFP_E_TOO_LARGE, 1, 41);
  return cf_expect_error_in(t, fd, CF_CODE(HFP_E_TOO_LARGE) | CF_CODE(HFP_E_LENGTH), 1, 0);
}

/* A FILTER whose length is exactly max_frame_bytes is read (and refused for
 * disagreeing with its fields, not for its length); one byte more is not. */
static int at_limit(cf_test *t, intptr_t over) {
  uint64_t max = t->srv->hello.max_frame_bytes;
  if (max >= UINT32_MAX) return cf_skip(t, "max_frame_bytes is not below 2^32");
  if (!over && max > ((uint64_t)64 << 20))
    return cf_skip(t, "max_frame_bytes %llu: more than this suite sends (64 MiB)",
                   (unsigned long long)max);
  cf_filter f = {.id = 43};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *head = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, head, "out of memory");
  uint32_t length = (uint32_t)max + (over ? 1 : 0);
  cf_set_length(head, length);
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  if (over) {
    CF_TRY(cf_send(t, fd, head, HFP_HEADER_SIZE));
    return cf_expect_error(t, fd, HFP_E_TOO_LARGE, 1, 43);
  }
  size_t total = HFP_HEADER_SIZE + (size_t)length;
  uint8_t *b = cf_alloc(t, total);
  CF_CHECK(t, b, "out of memory for %zu bytes", total);
  memcpy(b, head, n < total ? n : total);
  CF_TRY(cf_send(t, fd, b, total));
  CF_TRY(cf_expect_error(t, fd, HFP_E_LENGTH, 0, 43));
  return cf_still_serves(t, fd);
}

/* Control replies carry id 0 whatever the request's id. */
static int control_id(cf_test *t, intptr_t type) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, (int)type, 0, 77, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, type == HFP_STATS ? HFP_STATS_REPLY : HFP_VARIANTS, &f));
  CF_CHECK(t, f.h.request_id == 0, "the reply carries id %u, not 0", f.h.request_id);
  return 0;
}

/* LIST_VARIANTS and STATS have empty payloads: any byte is a fatal LENGTH. */
static int control_payload(cf_test *t, intptr_t arg) {
  int type = (int)(arg & 0xff), bytes = (int)(arg >> 8);
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE + 16];
  memset(b, 0, sizeof b);
  cf_header(b, type, 0, 0, (uint32_t)bytes);
  CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE + (size_t)bytes));
  return cf_expect_error(t, fd, HFP_E_LENGTH, 1, 0);
}

/* A FILTER with id 0: non-fatal INVALID, with id 0. */
static int filter_id_zero(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_filter f = {.id = 0};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 0));
  return cf_still_serves(t, fd);
}

static int filter_id_max(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_filter f = {.id = 0xffffffffu};
  cf_filter_defaults(t, &f);
  return cf_filter_ok(t, fd, &f, t->srv->version, NULL, NULL);
}

/* Framing does not depend on writes: a whole session one byte per write,
 * and everything in one write. */
static int split_writes(cf_test *t, intptr_t one_write) {
  uint8_t hb[HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX];
  size_t hn = cf_hello_frame(hb, sizeof hb, 1, HFP_VERSION, "conformance", t->o->token);
  cf_filter f = {.id = 21};
  cf_filter_defaults(t, &f);
  size_t fn;
  uint8_t *fb = cf_filter_frame(t, &f, &fn);
  CF_CHECK(t, fb, "out of memory");
  size_t n = hn + 2 * HFP_HEADER_SIZE + fn;
  uint8_t *b = cf_alloc(t, n);
  CF_CHECK(t, b, "out of memory");
  memcpy(b, hb, hn);
  cf_header(b + hn, HFP_LIST_VARIANTS, 0, 0, 0);
  cf_header(b + hn + HFP_HEADER_SIZE, HFP_STATS, 0, 0, 0);
  memcpy(b + hn + 2 * HFP_HEADER_SIZE, fb, fn);
  int fd;
  CF_TRY(cf_connect(t, &fd));
  if (one_write) {
    CF_TRY(cf_send(t, fd, b, n));
  } else {
    for (size_t i = 0; i < n; i++) CF_TRY(cf_send(t, fd, b + i, 1));
  }
  cf_frame r;
  CF_TRY(cf_expect(t, fd, HFP_HELLO_OK, &r));
  hfp_hello_ok ok;
  CF_CHECK(t, hfp_decode_hello_ok(r.p, r.h.length, &ok) == 0, "HELLO_OK does not decode");
  CF_TRY(cf_expect(t, fd, HFP_VARIANTS, &r));
  CF_TRY(cf_expect(t, fd, HFP_STATS_REPLY, &r));
  int rc = cf_read(t, fd, t->o->timeout_ms, &r);
  CF_CHECK(t, rc == CF_GOT, "no RESULT for the FILTER");
  return cf_check_result(t, &r, &f, ok.version, NULL, NULL, NULL);
}

/* Bytes after a frame that gets a fatal ERROR are never answered: the
 * ERROR, then the close. */
static int nothing_after_fatal(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t b[HFP_HEADER_SIZE * 4];
  cf_header(b, HFP_LIST_VARIANTS, 1, 0, 0);   /* flags set: fatal */
  for (int i = 1; i < 4; i++) cf_header(b + i * HFP_HEADER_SIZE, HFP_STATS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* Variant names in a FILTER follow the text rule: a non-fatal INVALID. */
static int variant_text(cf_test *t, intptr_t byte) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_filter f = {.id = 23};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  b[CF_FILTER_NAME] = (uint8_t)byte;
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 23));
  return cf_still_serves(t, fd);
}

#define MAGIC(i) {"frame.bad_magic.byte" #i, "a bad magic is a fatal PROTOCOL with id 0; what follows is not read", 0, bad_magic, i}
#define TYPE(v, name) {"frame.bad_type." name, "a type that is not a request is a fatal PROTOCOL with id 0", 0, bad_type, v}
#define FLAGS(type, bits, name) {"frame.bad_flags." name, "header flags are reserved: any bit set is a fatal PROTOCOL", 0, bad_flags, (type) | ((intptr_t)(bits) << 16)}

const cf_case cf_cases_frame[] = {
  MAGIC(0), MAGIC(1), MAGIC(2), MAGIC(3),
  {"frame.bad_magic.before_hello", "a bad magic before HELLO is a fatal PROTOCOL", 0, bad_magic, 4},
  TYPE(0, "zero"),
  TYPE(14, "fourteen"),
  TYPE(0x100, "type_256"),
  TYPE(0xffff, "u16_max"),
  TYPE(HFP_HELLO_OK, "hello_ok"),
  TYPE(HFP_VARIANTS, "variants"),
  TYPE(HFP_RESULT, "result"),
  TYPE(HFP_ERROR, "error"),
  TYPE(HFP_STATS_REPLY, "stats_reply"),
  TYPE(HFP_SHM_CREATED, "shm_created"),
  {"frame.bad_type.result_over_max", "the type before the length: a RESULT claiming 4 GiB is a fatal PROTOCOL, not TOO_LARGE", 0, bad_type_long, HFP_RESULT},
  {"frame.bad_type.error_over_max", "the type before the length: an ERROR claiming 4 GiB is a fatal PROTOCOL, not TOO_LARGE", 0, bad_type_long, HFP_ERROR},
  {"frame.bad_type.fourteen_over_max", "the type before the length: type 14 claiming 4 GiB is a fatal PROTOCOL, not TOO_LARGE", 0, bad_type_long, 14},
  FLAGS(HFP_LIST_VARIANTS, 1, "bit0"),
  FLAGS(HFP_LIST_VARIANTS, 0x8000, "bit15"),
  FLAGS(HFP_STATS, 0x0100, "stats_bit8"),
  FLAGS(HFP_FILTER, 1, "filter_bit0"),
  {"frame.too_long.filter", "a FILTER over max_frame_bytes is a fatal TOO_LARGE with its id", 0, too_long, HFP_FILTER},
  {"frame.too_long.list_variants", "a control frame over max_frame_bytes is fatal, id 0", 0, too_long, HFP_LIST_VARIANTS},
  {"frame.too_long.stats", "a control frame over max_frame_bytes is fatal, id 0", 0, too_long, HFP_STATS},
  {"frame.max_frame_bytes.at_limit", "a frame of exactly max_frame_bytes is read (refused only for its fields)", 0, at_limit, 0},
  {"frame.max_frame_bytes.over_by_one", "max_frame_bytes + 1 is a fatal TOO_LARGE", 0, at_limit, 1},
  {"frame.control_id.list_variants", "replies to control requests carry id 0", 0, control_id, HFP_LIST_VARIANTS},
  {"frame.control_id.stats", "replies to control requests carry id 0", 0, control_id, HFP_STATS},
  {"frame.control_payload.list_variants_1", "LIST_VARIANTS has an empty payload; extra bytes are a fatal LENGTH", 0, control_payload, HFP_LIST_VARIANTS | 1 << 8},
  {"frame.control_payload.list_variants_16", "LIST_VARIANTS has an empty payload; extra bytes are a fatal LENGTH", 0, control_payload, HFP_LIST_VARIANTS | 16 << 8},
  {"frame.control_payload.stats_1", "STATS has an empty payload; extra bytes are a fatal LENGTH", 0, control_payload, HFP_STATS | 1 << 8},
  {"frame.control_payload.stats_8", "STATS has an empty payload; extra bytes are a fatal LENGTH", 0, control_payload, HFP_STATS | 8 << 8},
  {"frame.filter_id.zero", "a FILTER with id 0 is a non-fatal INVALID", 0, filter_id_zero, 0},
  {"frame.filter_id.u32_max", "any non-zero id is a FILTER's to choose", 0, filter_id_max, 0},
  {"frame.split.byte_per_write", "framing does not depend on how bytes are cut into writes", 0, split_writes, 0},
  {"frame.split.one_write", "several frames in one write are each answered, in order", 0, split_writes, 1},
  {"frame.nothing_after_fatal", "after a fatal ERROR nothing more is read or answered", 0, nothing_after_fatal, 0},
  {"frame.variant_text.space", "a variant name with a space is a non-fatal INVALID", 0, variant_text, ' '},
  {"frame.variant_text.nul", "a variant name with a NUL is a non-fatal INVALID", 0, variant_text, 0},
  {"frame.variant_text.non_ascii", "a variant name with a byte over 0x7E is a non-fatal INVALID", 0, variant_text, 0xe9},
  {"frame.variant_text.del", "a variant name with 0x7F is a non-fatal INVALID", 0, variant_text, 0x7f},
  {NULL, NULL, 0, NULL, 0},
};
