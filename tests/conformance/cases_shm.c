/*
 * PROTOCOL.md, "Shared memory": segments made and sealed by the server,
 * FILTERs by reference with every region checked (inside, aligned, no
 * 64-bit wrap-around), unknown and destroyed segments, segments of another
 * connection, SHM_DESTROY, descriptors sent by a client, and TCP, where
 * none of it is offered.
 */
#define _GNU_SOURCE
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "cf_internal.h"

static int connect_v(cf_test *t, int *fd) { return cf_connect_hello(t, 1, HFP_VERSION, fd, NULL); }

/* A segment holding one frame of f (features, result, rgba), regions
 * aligned to 64 bytes; fills f's reference and the features. */
typedef struct seg_frame {
  uint32_t id;
  uint8_t *mem;
  uint64_t bytes;
} seg_frame;

static uint64_t up64(uint64_t x) { return (x + 63) & ~(uint64_t)63; }

static int seg_for(cf_test *t, int fd, cf_filter *f, seg_frame *s) {
  uint64_t in = cf_features_bytes(f), es = f->out_dtype == HFP_F16 ? 2 : 4;
  uint64_t px = (uint64_t)f->width * f->height;
  uint64_t out = px * 3 * es, rgba = (f->flags & HFP_FILTER_COMPOSITE) ? px * 4 * es : 0;
  s->bytes = up64(in) + up64(out) + up64(rgba) + 64;
  CF_TRY(cf_shm_create(t, fd, s->bytes, &s->id, &s->mem));
  f->flags |= HFP_FILTER_SHM;
  f->segment = s->id;
  f->shm_in = 0;
  f->shm_out = up64(in);
  f->shm_rgba = rgba ? up64(in) + up64(out) : 0;
  cf_fill_features(f, s->mem + f->shm_in);
  return 0;
}

static int send_frame(cf_test *t, int fd, const cf_filter *f) {
  size_t n;
  uint8_t *b = cf_filter_frame(t, f, &n);
  CF_CHECK(t, b, "out of memory");
  return cf_send(t, fd, b, n);
}

static int shm_result(cf_test *t, int fd, const cf_filter *f, const seg_frame *s, float **res) {
  CF_TRY(send_frame(t, fd, f));
  cf_frame r;
  int rc = cf_read(t, fd, t->o->timeout_ms, &r);
  CF_CHECK(t, rc == CF_GOT, "no reply to a FILTER by reference");
  return cf_check_result(t, &r, f, t->srv->version, s->mem, res, NULL);
}

/* ---- SHM_CREATE ---------------------------------------------------------------- */

static int create_sealed(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(connect_v(t, &fd));
  uint8_t b[24];
  cf_shm_create_frame(b, 12345);
  hfp_put_u32(b + 8, 9);   /* a request id: the reply still carries 0 */
  CF_TRY(cf_send(t, fd, b, sizeof b));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, HFP_SHM_CREATED, &f));
  CF_CHECK(t, f.h.request_id == 0, "SHM_CREATED carries id %u, not 0", f.h.request_id);
  uint32_t seg;
  uint64_t bytes;
  CF_CHECK(t, hfp_decode_shm_created(f.p, f.h.length, &seg, &bytes) == 0,
           "SHM_CREATED does not decode");
  CF_CHECK(t, bytes == 12345, "SHM_CREATED says %llu bytes, 12345 were asked for",
           (unsigned long long)bytes);
  CF_CHECK(t, f.passed_fd >= 0, "SHM_CREATED came without a descriptor");
  int seals = fcntl(f.passed_fd, F_GET_SEALS);
  int want = F_SEAL_SHRINK | F_SEAL_GROW | F_SEAL_SEAL;
  CF_CHECK(t, seals >= 0 && (seals & want) == want,
           "the segment is not sealed against shrinking, growing and resealing (seals 0x%x)", seals);
  CF_CHECK(t, ftruncate(f.passed_fd, 10) != 0, "the client could shrink the segment");
  return 0;
}

enum { C_ZERO, C_HUGE, C_U63, C_OVER_BUDGET };

static int create_refused(cf_test *t, intptr_t how) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  uint64_t bytes = how == C_ZERO ? 0 : how == C_HUGE ? UINT64_MAX : (uint64_t)1 << 63;
  uint8_t b[24];
  cf_shm_create_frame(b, bytes);
  hfp_put_u32(b + 8, 5);
  CF_TRY(cf_send(t, fd, b, sizeof b));
  CF_TRY(cf_expect_error(t, fd, how == C_ZERO ? HFP_E_INVALID : HFP_E_TOO_LARGE, 0, 0));
  return cf_still_serves(t, fd);
}

/* SHM_CREATE or SHM_DESTROY (arg: type | length << 8) whose payload has
 * the wrong length: a fatal LENGTH, whatever the transport. */
static int control_length(cf_test *t, intptr_t arg) {
  int type = (int)(arg & 0xff), len = (int)(arg >> 8);
  int fd;
  CF_TRY(connect_v(t, &fd));
  uint8_t b[32];
  memset(b, 0, sizeof b);
  cf_header(b, type, 0, 0, (uint32_t)len);
  b[16] = 1;
  CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE + (size_t)len));
  return cf_expect_error(t, fd, HFP_E_LENGTH, 1, 0);
}

/* 16 segments a connection; the 17th is BUSY (it may succeed once one is
 * released). With over_budget, the 17th asks for 2^63 bytes, more than any
 * budget: TOO_LARGE, since no release can make it fit, and 0 bytes is
 * INVALID; the segment's size is judged before the connection's count. */
static int seventeenth(cf_test *t, intptr_t over_budget) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  uint32_t ids[16];
  for (int i = 0; i < 16; i++) {
    CF_TRY(cf_shm_create(t, fd, 4096, &ids[i], NULL));
    for (int j = 0; j < i; j++) CF_CHECK(t, ids[i] != ids[j], "two segments have id %u", ids[i]);
  }
  uint8_t b[24];
  if (over_budget) {
    CF_TRY(cf_send(t, fd, b, cf_shm_create_frame(b, (uint64_t)1 << 63)));
    CF_TRY(cf_expect_error(t, fd, HFP_E_TOO_LARGE, 0, 0));
    CF_TRY(cf_send(t, fd, b, cf_shm_create_frame(b, 0)));
    CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 0));
  }
  CF_TRY(cf_send(t, fd, b, cf_shm_create_frame(b, 4096)));
  CF_TRY(cf_expect_error(t, fd, HFP_E_BUSY, 0, 0));
  CF_TRY(cf_send(t, fd, b, cf_shm_destroy_frame(b, ids[3])));
  CF_TRY(cf_shm_create(t, fd, 4096, &ids[3], NULL));
  return 0;
}

/* ---- FILTER by reference --------------------------------------------------------- */

/* The same frame by reference and through the socket: the same result. */
static int by_reference(cf_test *t, intptr_t arg) {
  int in = (int)(arg & 1), out = (int)((arg >> 1) & 1), composite = (int)((arg >> 2) & 1);
  if (!(t->srv->hello.dtypes & (1u << in)) || !(t->srv->hello.dtypes & (1u << out)))
    return cf_skip(t, "the server does not offer the dtypes");
  int fd;
  CF_TRY(connect_v(t, &fd));
  cf_filter f = {.id = 60, .in_dtype = in, .out_dtype = out,
                 .flags = composite ? HFP_FILTER_COMPOSITE : 0};
  cf_filter_defaults(t, &f);
  float *via_socket, *via_shm;
  CF_TRY(cf_filter_ok(t, fd, &f, t->srv->version, &via_socket, NULL));
  seg_frame s;
  f.id = 61;
  CF_TRY(seg_for(t, fd, &f, &s));
  CF_TRY(shm_result(t, fd, &f, &s, &via_shm));
  CF_CHECK(t, !memcmp(via_socket, via_shm, (size_t)f.width * f.height * 3 * sizeof(float)),
           "the result by reference differs from the same frame's through the socket");
  return 0;
}

enum {
  R_UNKNOWN, R_ZERO, R_RESERVED, R_IN_MISALIGNED, R_OUT_MISALIGNED, R_RGBA_MISALIGNED,
  R_IN_OUTSIDE, R_OUT_OUTSIDE, R_RGBA_OUTSIDE, R_IN_WRAP, R_OUT_WRAP, R_RGBA_WRAP,
  R_RGBA_NO_COMPOSITE, R_IN_PAST_END, R_DESTROYED, R_OUT_IS_IN, R_RGBA_OVERLAPS_OUT,
};

/* A reference that breaks one rule: the non-fatal code with the FILTER's
 * id; the connection and the segment go on serving. */
static int bad_reference(cf_test *t, intptr_t how) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  cf_filter f = {.id = 70, .flags = HFP_FILTER_COMPOSITE};
  cf_filter_defaults(t, &f);
  seg_frame s;
  CF_TRY(seg_for(t, fd, &f, &s));
  cf_filter g = f;
  int code = HFP_E_LENGTH;
  size_t n;
  uint8_t *b;
  switch (how) {
    case R_UNKNOWN: g.segment = s.id + 1000; code = HFP_E_INVALID; break;
    case R_ZERO: g.segment = 0; code = HFP_E_INVALID; break;
    case R_IN_MISALIGNED: g.shm_in += 2; break;
    case R_OUT_MISALIGNED: g.shm_out += 2; break;
    case R_RGBA_MISALIGNED: g.shm_rgba += 2; break;
    case R_IN_OUTSIDE: g.shm_in = s.bytes - cf_features_bytes(&f) + 4; break;
    case R_OUT_OUTSIDE: g.shm_out = s.bytes - (uint64_t)f.width * f.height * 12 + 4; break;
    case R_RGBA_OUTSIDE: g.shm_rgba = s.bytes - (uint64_t)f.width * f.height * 16 + 4; break;
    case R_IN_WRAP: g.shm_in = UINT64_MAX - 3; break;
    case R_OUT_WRAP: g.shm_out = UINT64_MAX - 3; break;
    case R_RGBA_WRAP: g.shm_rgba = UINT64_MAX - 3; break;
    case R_IN_PAST_END: g.shm_in = s.bytes; break;
    case R_OUT_IS_IN: g.shm_out = g.shm_in; break;
    case R_RGBA_OVERLAPS_OUT: g.shm_rgba = g.shm_out + 4; break;
    case R_RGBA_NO_COMPOSITE: g.flags &= (uint16_t)~HFP_FILTER_COMPOSITE; code = HFP_E_INVALID; break;
    case R_DESTROYED: {
      uint8_t d[20];
      CF_TRY(cf_send(t, fd, d, cf_shm_destroy_frame(d, s.id)));
      code = HFP_E_INVALID;
      break;
    }
  }
  b = cf_filter_frame(t, &g, &n);
  CF_CHECK(t, b, "out of memory");
  if (how == R_RESERVED) {
    hfp_put_u32(b + n - HFP_SHM_REF_SIZE + 4, 1);
    code = HFP_E_INVALID;
  }
  CF_TRY(cf_send(t, fd, b, n));
  CF_TRY(cf_expect_error(t, fd, code, 0, 70));
  if (how == R_DESTROYED) return cf_still_serves(t, fd);
  /* The segment still serves a good reference. */
  f.id = 71;
  return shm_result(t, fd, &f, &s, NULL);
}

/* Segment ids belong to their connection. */
static int other_connection(cf_test *t, intptr_t same_id) {
  int a, b;
  CF_TRY(connect_v(t, &a));
  CF_TRY(connect_v(t, &b));
  cf_filter fa = {.id = 80, .seed = 1};
  cf_filter_defaults(t, &fa);
  seg_frame sa;
  CF_TRY(seg_for(t, a, &fa, &sa));
  size_t out_bytes = (size_t)fa.width * fa.height * 12;
  memset(sa.mem + fa.shm_out, 0x5a, out_bytes);
  if (!same_id) {
    /* b has no segment: a's id means nothing there. */
    CF_TRY(send_frame(t, b, &fa));
    CF_TRY(cf_expect_error(t, b, HFP_E_INVALID, 0, 80));
  } else {
    /* b makes segments until one has a's id, with other features in it:
     * its FILTER must read b's segment and write nothing into a's. */
    cf_filter fb = {.id = 81, .seed = 2};
    cf_filter_defaults(t, &fb);
    seg_frame sb = {0};
    for (int i = 0; i < 16 && sb.id != sa.id; i++) CF_TRY(seg_for(t, b, &fb, &sb));
    if (sb.id != sa.id) return cf_skip(t, "the second connection's segments never had id %u", sa.id);
    float *via_shm, *via_socket;
    CF_TRY(shm_result(t, b, &fb, &sb, &via_shm));
    cf_filter fs = fb;
    fs.flags = 0;
    fs.id = 82;
    CF_TRY(cf_filter_ok(t, b, &fs, t->srv->version, &via_socket, NULL));
    CF_CHECK(t, !memcmp(via_shm, via_socket, out_bytes),
             "a FILTER on one connection did not read its own segment of the same id");
  }
  for (size_t i = 0; i < out_bytes; i++)
    CF_CHECK(t, sa.mem[fa.shm_out + i] == 0x5a,
             "another connection's FILTER wrote into this connection's segment");
  return 0;
}

/* ---- SHM_DESTROY ----------------------------------------------------------------- */

enum { D_UNKNOWN, D_ZERO, D_TWICE, D_SILENT, D_RUNNING };

static int destroy(cf_test *t, intptr_t how) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  uint32_t seg = 0;
  uint8_t *mem = NULL;
  if (how != D_UNKNOWN && how != D_ZERO) CF_TRY(cf_shm_create(t, fd, 4096, &seg, &mem));
  uint8_t d[20];
  switch (how) {
    case D_UNKNOWN:
    case D_ZERO:
      cf_shm_destroy_frame(d, how == D_ZERO ? 0 : 0x7fff1234u);
      hfp_put_u32(d + 8, 3);
      CF_TRY(cf_send(t, fd, d, sizeof d));
      CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 0));
      return cf_still_serves(t, fd);
    case D_TWICE:
      CF_TRY(cf_send(t, fd, d, cf_shm_destroy_frame(d, seg)));
      CF_TRY(cf_send(t, fd, d, cf_shm_destroy_frame(d, seg)));
      CF_TRY(cf_expect_error(t, fd, HFP_E_INVALID, 0, 0));
      return cf_still_serves(t, fd);
    case D_SILENT:
      /* No reply: the next frame is the answer to the next request. */
      CF_TRY(cf_send(t, fd, d, cf_shm_destroy_frame(d, seg)));
      return cf_still_serves(t, fd);
    case D_RUNNING: {
      /* Frames still running on a segment finish first. */
      cf_filter f = {.id = 90};
      cf_filter_defaults(t, &f);
      seg_frame s;
      CF_TRY(seg_for(t, fd, &f, &s));
      CF_TRY(send_frame(t, fd, &f));
      CF_TRY(cf_send(t, fd, d, cf_shm_destroy_frame(d, s.id)));
      cf_frame r;
      int rc = cf_read(t, fd, t->o->timeout_ms, &r);
      CF_CHECK(t, rc == CF_GOT, "no RESULT for a frame whose segment was destroyed while it ran");
      return cf_check_result(t, &r, &f, t->srv->version, s.mem, NULL, NULL);
    }
  }
  return 0;
}

/* A client never sends descriptors: fatal PROTOCOL. */
static int client_fd(cf_test *t, intptr_t arg) {
  (void)arg;
  int fd;
  CF_TRY(connect_v(t, &fd));
  int p[2];
  CF_CHECK(t, pipe(p) == 0, "pipe failed");
  cf_keep_fd(t, p[0]);
  cf_keep_fd(t, p[1]);
  uint8_t b[HFP_HEADER_SIZE];
  cf_header(b, HFP_LIST_VARIANTS, 0, 0, 0);
  CF_TRY(cf_send_with_fd(t, fd, b, sizeof b, p[0]));
  return cf_expect_error(t, fd, HFP_E_PROTOCOL, 1, 0);
}

/* ---- where shared memory is not offered ---------------------------------------- */

enum { U_CREATE, U_DESTROY, U_FILTER, U_FILTER_BAD_REF };

static int unsupported(cf_test *t, intptr_t what) {
  int fd;
  CF_TRY(connect_v(t, &fd));
  uint8_t b[24];
  if (what == U_FILTER || what == U_FILTER_BAD_REF) {
    /* A reference that would be INVALID where shared memory is offered
     * (segment 0, rgba_offset without COMPOSITE, an unknown variant): the
     * transport is checked first (PROTOCOL.md, "Which error a FILTER gets"). */
    cf_filter f = {.id = 95, .flags = HFP_FILTER_SHM, .segment = 1};
    if (what == U_FILTER_BAD_REF) f.segment = 0, f.shm_rgba = 64, f.variant = "no-such-variant";
    cf_filter_defaults(t, &f);
    CF_TRY(send_frame(t, fd, &f));
    CF_TRY(cf_expect_error(t, fd, HFP_E_UNSUPPORTED, 0, 95));
  } else {
    size_t n = what == U_CREATE ? cf_shm_create_frame(b, 4096) : cf_shm_destroy_frame(b, 1);
    CF_TRY(cf_send(t, fd, b, n));
    CF_TRY(cf_expect_error(t, fd, HFP_E_UNSUPPORTED, 0, 0));
  }
  return cf_still_serves(t, fd);
}

#define UX (CF_NEED_UNIX | CF_NEED_SHM)
#define REF(how, name, rule) {"shm.reference." name, rule, UX, bad_reference, how}

const cf_case cf_cases_shm[] = {
  {"shm.create.sealed", "SHM_CREATED (id 0) brings a descriptor sealed against shrink, grow and reseal", UX, create_sealed, 0},
  {"shm.create.zero_bytes", "SHM_CREATE of 0 bytes is a non-fatal INVALID with id 0", UX, create_refused, C_ZERO},
  {"shm.create.u64_max", "a segment over the whole budget is a non-fatal TOO_LARGE with id 0", UX, create_refused, C_HUGE},
  {"shm.create.two_to_63", "a segment over the whole budget is a non-fatal TOO_LARGE with id 0", UX, create_refused, C_U63},
  {"shm.create.length_7", "SHM_CREATE with a payload of the wrong length is a fatal LENGTH, on any transport", 0, control_length, HFP_SHM_CREATE | 7 << 8},
  {"shm.create.length_9", "SHM_CREATE with a payload of the wrong length is a fatal LENGTH, on any transport", 0, control_length, HFP_SHM_CREATE | 9 << 8},
  {"shm.create.length_0", "SHM_CREATE with a payload of the wrong length is a fatal LENGTH, on any transport", 0, control_length, HFP_SHM_CREATE | 0 << 8},
  {"shm.create.seventeenth", "the 17th segment of a connection is BUSY; after a release one more fits", UX, seventeenth, 0},
  {"shm.create.seventeenth_over_budget", "a 17th segment over the whole budget is TOO_LARGE, not BUSY: no release makes it fit", UX, seventeenth, 1},
  {"shm.filter.f32", "a FILTER by reference: RESULT flag bit 1, 56 bytes, the socket path's values", UX, by_reference, 0},
  {"shm.filter.f16", "a FILTER by reference in f16", UX, by_reference, 3},
  {"shm.filter.composite", "a FILTER by reference with COMPOSITE writes rgba to its region", UX, by_reference, 4},
  {"shm.filter.f32_in_f16_out_composite", "a FILTER by reference, mixed dtypes, COMPOSITE", UX, by_reference, 2 | 4},
  REF(R_UNKNOWN, "unknown_segment", "a segment not made on this connection is a non-fatal INVALID"),
  REF(R_ZERO, "segment_zero", "segment 0 is a non-fatal INVALID"),
  REF(R_RESERVED, "reserved_nonzero", "the reserved word must be 0: INVALID"),
  REF(R_IN_MISALIGNED, "in_misaligned", "in_offset must be a multiple of the element size: LENGTH"),
  REF(R_OUT_MISALIGNED, "out_misaligned", "out_offset must be a multiple of the element size: LENGTH"),
  REF(R_RGBA_MISALIGNED, "rgba_misaligned", "rgba_offset must be a multiple of the element size: LENGTH"),
  REF(R_IN_OUTSIDE, "in_outside", "the features must lie inside the segment: LENGTH"),
  REF(R_OUT_IS_IN, "out_is_in", "the result may not overwrite the features in place: LENGTH"),
  REF(R_RGBA_OVERLAPS_OUT, "rgba_overlaps_out", "the composite may not share a byte with the result: LENGTH"),
  REF(R_OUT_OUTSIDE, "out_outside", "the result must lie inside the segment: LENGTH"),
  REF(R_RGBA_OUTSIDE, "rgba_outside", "the composite must lie inside the segment: LENGTH"),
  REF(R_IN_PAST_END, "in_at_end", "an offset at the segment's end holds nothing: LENGTH"),
  REF(R_IN_WRAP, "in_wraps_64", "an offset whose end overflows 64 bits is LENGTH"),
  REF(R_OUT_WRAP, "out_wraps_64", "an offset whose end overflows 64 bits is LENGTH"),
  REF(R_RGBA_WRAP, "rgba_wraps_64", "an offset whose end overflows 64 bits is LENGTH"),
  REF(R_RGBA_NO_COMPOSITE, "rgba_without_composite", "rgba_offset is 0 without COMPOSITE: INVALID"),
  REF(R_DESTROYED, "after_destroy", "a destroyed segment is unknown: INVALID"),
  {"shm.other_connection.unknown", "a segment of another connection is unknown here: INVALID", UX, other_connection, 0},
  {"shm.other_connection.same_id", "ids are per connection: the same id on another connection is that connection's segment", UX, other_connection, 1},
  {"shm.destroy.unknown", "SHM_DESTROY of an unknown id is a non-fatal INVALID with id 0", UX, destroy, D_UNKNOWN},
  {"shm.destroy.zero", "SHM_DESTROY of segment 0 is a non-fatal INVALID", UX, destroy, D_ZERO},
  {"shm.destroy.twice", "a segment destroyed twice: the second is INVALID", UX, destroy, D_TWICE},
  {"shm.destroy.no_reply", "SHM_DESTROY of a known segment has no reply", UX, destroy, D_SILENT},
  {"shm.destroy.while_running", "frames running on a destroyed segment finish first", UX, destroy, D_RUNNING},
  {"shm.destroy.length_3", "SHM_DESTROY with a payload of the wrong length is a fatal LENGTH, on any transport", 0, control_length, HFP_SHM_DESTROY | 3 << 8},
  {"shm.destroy.length_5", "SHM_DESTROY with a payload of the wrong length is a fatal LENGTH, on any transport", 0, control_length, HFP_SHM_DESTROY | 5 << 8},
  {"shm.client_sends_fd", "a client that sends a descriptor gets a fatal PROTOCOL", CF_NEED_UNIX, client_fd, 0},
  {"shm.tcp.create", "SHM_CREATE on TCP is a non-fatal UNSUPPORTED with id 0", CF_NEED_TCP, unsupported, U_CREATE},
  {"shm.tcp.destroy", "SHM_DESTROY on TCP is a non-fatal UNSUPPORTED with id 0", CF_NEED_TCP, unsupported, U_DESTROY},
  {"shm.tcp.filter", "a FILTER with SHM on TCP is a non-fatal UNSUPPORTED with its id", CF_NEED_TCP, unsupported, U_FILTER},
  {"shm.disabled.create", "where HELLO_OK clears bit 1, SHM_CREATE is UNSUPPORTED", CF_NEED_UNIX | CF_NEED_NO_SHM, unsupported, U_CREATE},
  {"shm.disabled.filter", "where HELLO_OK clears bit 1, a FILTER with SHM is UNSUPPORTED", CF_NEED_UNIX | CF_NEED_NO_SHM, unsupported, U_FILTER},
  {"shm.tcp.filter_bad_reference", "a FILTER with SHM on TCP is UNSUPPORTED before its reference and variant are checked", CF_NEED_TCP, unsupported, U_FILTER_BAD_REF},
  {"shm.disabled.filter_bad_reference", "where HELLO_OK clears bit 1, a FILTER with SHM is UNSUPPORTED before its reference is checked", CF_NEED_UNIX | CF_NEED_NO_SHM, unsupported, U_FILTER_BAD_REF},
  {NULL, NULL, 0, NULL, 0},
};
