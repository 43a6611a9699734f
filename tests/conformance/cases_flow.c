/*
 * PROTOCOL.md, "Transport" and "Flow control" at every stage of a session:
 * frames cut short at every byte, peers that half-close, disconnect or fall
 * silent before HELLO, in a header, in a FILTER's head or tensor, with
 * FILTERs in flight, while replies are being written; and what a server
 * may do about each (a fatal PROTOCOL for a stall) and must do (answer what
 * it admitted, then close). After each of them an ordinary client is
 * served (the runner checks).
 */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "cf_internal.h"

/* The frames a session is made of, for cutting. */
enum {
  M_HELLO, M_LIST_VARIANTS, M_STATS, M_FILTER, M_FILTER_COMPOSITE, M_SHM_CREATE, M_SHM_DESTROY,
  M_FILTER_SHM,
};

/* The whole frame of kind m; *needs_hello says whether it follows one. */
static uint8_t *message(cf_test *t, int m, size_t *n, uint32_t segment) {
  uint8_t *b;
  switch (m) {
    case M_HELLO:
      b = cf_alloc(t, HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX);
      if (b) *n = cf_hello_frame(b, HFP_HEADER_SIZE + 8 + HFP_NAME_MAX + HFP_TOKEN_MAX, 1,
                                 HFP_VERSION, "conformance", t->o->token);
      return b;
    case M_LIST_VARIANTS:
    case M_STATS:
      b = cf_alloc(t, HFP_HEADER_SIZE);
      if (b) cf_header(b, m == M_STATS ? HFP_STATS : HFP_LIST_VARIANTS, 0, 0, 0);
      *n = HFP_HEADER_SIZE;
      return b;
    case M_SHM_CREATE:
      b = cf_alloc(t, 24);
      if (b) *n = cf_shm_create_frame(b, 4096);
      return b;
    case M_SHM_DESTROY:
      b = cf_alloc(t, 20);
      if (b) *n = cf_shm_destroy_frame(b, segment);
      return b;
    default: {
      cf_filter f = {.id = 33};
      if (m == M_FILTER_COMPOSITE) f.flags = HFP_FILTER_COMPOSITE;
      if (m == M_FILTER_SHM) {
        f.flags = HFP_FILTER_SHM;
        f.segment = segment;
        f.shm_out = 1 << 16;
      }
      cf_filter_defaults(t, &f);
      return cf_filter_frame(t, &f, n);
    }
  }
}

/* Every cut of a frame, each on its own connection: its first k bytes,
 * then a half-close. The server drops the partial frame, sends nothing for
 * it (a FILTER may already have been refused BUSY while arriving) and
 * closes. With `step` > 1 the tensor's bytes are cut at every step-th. */
static int truncate_every_byte(cf_test *t, intptr_t m) {
  size_t n;
  uint8_t *b = message(t, (int)m, &n, 1);
  CF_CHECK(t, b, "out of memory");
  size_t head = m == M_FILTER || m == M_FILTER_COMPOSITE
                    ? (size_t)(CF_FILTER_NAME + strlen(t->srv->variants[t->srv->probe].name))
                    : n;
  for (size_t k = 1; k < n; k++) {
    int fd;
    if (m == M_HELLO) {
      CF_TRY(cf_connect(t, &fd));
    } else {
      CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
      if (m == M_FILTER_SHM || m == M_SHM_DESTROY) CF_TRY(cf_shm_create(t, fd, 1 << 18, NULL, NULL));
    }
    CF_TRY(cf_send(t, fd, b, k));
    cf_shutdown_wr(fd);
    cf_frame f;
    int rc = cf_read(t, fd, t->o->timeout_ms, &f);
    if (rc == CF_GOT && f.h.type == HFP_ERROR && k > head) {
      hfp_error e;
      if (hfp_decode_error(f.p, f.h.length, &e) == 0 && e.code == HFP_E_BUSY && !e.fatal)
        rc = cf_read(t, fd, t->o->timeout_ms, &f);
    }
    if (rc != CF_EOF) {
      char d[400];
      return cf_fail(t, "cut after %zu of %zu bytes and half-closed: wanted the close, got %s", k, n,
                     rc == CF_GOT ? cf_describe(&f, d, sizeof d)
                                  : rc == CF_TIMEOUT ? "nothing (still open)" : t->why);
    }
    cf_close(t, fd);
  }
  return 0;
}

/* The same cuts, closing outright: nothing to see on that connection, the
 * runner's health check shows the server is well. A sample of cut points
 * (every byte of the headers, every 61st of the rest). */
static int disconnect_every_byte(cf_test *t, intptr_t m) {
  size_t n;
  uint8_t *b = message(t, (int)m, &n, 1);
  CF_CHECK(t, b, "out of memory");
  for (size_t k = 0; k < n; k += k < 80 ? 1 : 61) {
    int fd;
    if (m == M_HELLO)
      CF_TRY(cf_connect(t, &fd));
    else
      CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
    if (k) CF_TRY(cf_send(t, fd, b, k));
    cf_close(t, fd);
  }
  return cf_health(t);
}

/* ---- half-close --------------------------------------------------------------- */

enum { HC_IDLE, HC_BEFORE_HELLO, HC_INFLIGHT, HC_AFTER_CONTROL, HC_MID_FILTER, HC_MID_HEADER,
       HC_AFTER_REFUSAL };

static int half_close(cf_test *t, intptr_t how) {
  int fd;
  if (how == HC_BEFORE_HELLO) {
    CF_TRY(cf_connect(t, &fd));
    cf_shutdown_wr(fd);
    return cf_expect_eof(t, fd);
  }
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_filter f = {.id = 40};
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  int k = 0;
  switch (how) {
    case HC_IDLE: break;
    case HC_AFTER_CONTROL: {
      uint8_t c[HFP_HEADER_SIZE];
      cf_header(c, HFP_STATS, 0, 0, 0);
      CF_TRY(cf_send(t, fd, c, sizeof c));
      break;
    }
    case HC_MID_HEADER: CF_TRY(cf_send(t, fd, b, 7)); break;
    case HC_AFTER_REFUSAL:
      /* A FILTER refused (spp 0), then the half-close: its ERROR, then the close. */
      hfp_put_u16(b + CF_FILTER_SPP, 0);
      CF_TRY(cf_send(t, fd, b, n));
      k = 1;
      break;
    case HC_INFLIGHT:
    case HC_MID_FILTER:
      k = t->srv->hello.max_inflight < 4 ? t->srv->hello.max_inflight : 4;
      for (int i = 0; i < k; i++) {
        hfp_put_u32(b + 8, 40 + (uint32_t)i);
        CF_TRY(cf_send(t, fd, b, n));
      }
      if (how == HC_MID_FILTER) CF_TRY(cf_send(t, fd, b, n / 2));
      break;
  }
  cf_shutdown_wr(fd);
  if (how == HC_AFTER_CONTROL) {
    cf_frame r;
    CF_TRY(cf_expect(t, fd, HFP_STATS_REPLY, &r));
  }
  /* Every admitted FILTER is answered (RESULT, or ERROR for the refused),
   * the partial one is not, then the close. */
  uint8_t seen[8] = {0};
  for (int i = 0; i < k; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    CF_CHECK(t, rc == CF_GOT, "after the half-close, %d of %d FILTERs were answered (%s)", i, k,
             rc == CF_EOF ? "closed" : "nothing more came");
    uint32_t id = r.h.request_id;
    char d[400];
    CF_CHECK(t, id >= 40 && id < 40 + (uint32_t)k && !seen[id - 40], "unexpected %s",
             cf_describe(&r, d, sizeof d));
    seen[id - 40] = 1;
    if (r.h.type == HFP_RESULT) {
      cf_filter fi = f;
      fi.id = id;
      CF_TRY(cf_check_result(t, &r, &fi, t->srv->version, NULL, NULL, NULL));
    } else {
      hfp_error e;
      CF_CHECK(t, r.h.type == HFP_ERROR && hfp_decode_error(r.p, r.h.length, &e) == 0 && !e.fatal,
               "unexpected %s", d);
    }
  }
  return cf_expect_eof(t, fd);
}

/* ---- closing outright ---------------------------------------------------------- */

enum { CL_INFLIGHT, CL_MID_REPLY, CL_AFTER_SHM_CREATE, CL_WITH_SEGMENTS_IN_USE };

static int close_outright(cf_test *t, intptr_t how) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_filter f = {.id = 45};
  if (how == CL_MID_REPLY) {
    f.width = t->srv->hello.max_width < 64 ? t->srv->hello.max_width : 64;
    f.height = t->srv->hello.max_height < 64 ? t->srv->hello.max_height : 64;
    f.flags = HFP_FILTER_COMPOSITE;
  }
  cf_filter_defaults(t, &f);
  size_t n;
  uint8_t *b = cf_filter_frame(t, &f, &n);
  CF_CHECK(t, b, "out of memory");
  int k = t->srv->hello.max_inflight < 4 ? t->srv->hello.max_inflight : 4;
  switch (how) {
    case CL_INFLIGHT:
      for (int i = 0; i < k; i++) {
        hfp_put_u32(b + 8, 45 + (uint32_t)i);
        CF_TRY(cf_send(t, fd, b, n));
      }
      break;
    case CL_MID_REPLY: {
      CF_TRY(cf_send(t, fd, b, n));
      /* Read the start of the RESULT, then leave while the rest is written. */
      uint8_t part[24];
      double end = cf_now_ms() + t->o->timeout_ms;
      while (recv(fd, part, sizeof part, MSG_PEEK | MSG_DONTWAIT) < (ssize_t)sizeof part &&
             cf_now_ms() < end)
        cf_sleep_ms(5);
      CF_CHECK(t, recv(fd, part, sizeof part, MSG_DONTWAIT) == (ssize_t)sizeof part,
               "no RESULT came to leave in the middle of");
      break;
    }
    case CL_AFTER_SHM_CREATE: {
      uint8_t c[24];
      CF_TRY(cf_send(t, fd, c, cf_shm_create_frame(c, 1 << 20)));
      break;
    }
    case CL_WITH_SEGMENTS_IN_USE: {
      uint32_t seg;
      uint8_t *mem;
      CF_TRY(cf_shm_create(t, fd, 1 << 20, &seg, &mem));
      cf_filter g = {.id = 46, .flags = HFP_FILTER_SHM, .segment = seg, .shm_out = 1 << 19};
      cf_filter_defaults(t, &g);
      cf_fill_features(&g, mem);
      size_t gn;
      uint8_t *gb = cf_filter_frame(t, &g, &gn);
      CF_CHECK(t, gb, "out of memory");
      CF_TRY(cf_send(t, fd, gb, gn));
      break;
    }
  }
  cf_close(t, fd);
  /* The server frees what the connection held; a new one is served. */
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  return cf_still_serves(t, fd);
}

/* ---- stalls ---------------------------------------------------------------------- */

enum { ST_MID_HEADER, ST_MID_FILTER_HEAD, ST_MID_TENSOR, ST_MID_CONTROL, ST_IDLE, ST_MID_NAME };

/* Silent for stall_ms in the middle of a frame: a server may close with a
 * fatal PROTOCOL (the FILTER's id for a FILTER, else 0); if it waited, the
 * rest of the frame is served as usual. Idle between frames, nothing
 * happens at all. */
static int stall(cf_test *t, intptr_t where) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  cf_filter f = {.id = 47};
  cf_filter_defaults(t, &f);
  size_t n, cut;
  uint8_t *b;
  uint32_t id = 0;
  if (where == ST_MID_CONTROL) {
    b = cf_alloc(t, 24);
    CF_CHECK(t, b, "out of memory");
    n = cf_shm_create_frame(b, 4096);
    cut = 20;
    if (!(t->srv->hello.server_flags & HFP_SERVER_SHM)) {
      /* Without shared memory any control frame with a payload will do:
       * none has one but SHM_*, so cut inside the header. */
      cf_header(b, HFP_STATS, 0, 0, 0);
      n = HFP_HEADER_SIZE;
      cut = 9;
    }
  } else {
    b = cf_filter_frame(t, &f, &n);
    CF_CHECK(t, b, "out of memory");
    cut = where == ST_MID_HEADER ? 10 : where == ST_MID_FILTER_HEAD ? CF_FILTER_HAIR
          : where == ST_MID_NAME ? CF_FILTER_NAME + 1 : where == ST_MID_TENSOR ? n - 7 : 0;
    if (where == ST_MID_FILTER_HEAD || where == ST_MID_TENSOR || where == ST_MID_NAME) id = f.id;
  }
  if (cut) CF_TRY(cf_send(t, fd, b, cut));
  cf_sleep_ms(t->o->stall_ms);
  cf_frame r;
  char d[400];
  int rc = cf_read(t, fd, 0, &r);
  if (where == ST_IDLE) {
    CF_CHECK(t, rc == CF_TIMEOUT, "a connection idle between frames got %s",
             rc == CF_GOT ? cf_describe(&r, d, sizeof d) : "closed");
    return cf_still_serves(t, fd);
  }
  if (rc == CF_GOT) {
    hfp_error e;
    CF_CHECK(t, r.h.type == HFP_ERROR && hfp_decode_error(r.p, r.h.length, &e) == 0 &&
                    e.code == HFP_E_PROTOCOL && e.fatal && r.h.request_id == id,
             "a stalled frame got %s; a server may only close it with a fatal PROTOCOL, id %u",
             cf_describe(&r, d, sizeof d), id);
    return cf_expect_eof(t, fd);
  }
  CF_CHECK(t, rc == CF_TIMEOUT, "the server closed a stalled connection without an ERROR");
  CF_TRY(cf_send(t, fd, b + cut, n - cut));
  rc = cf_read(t, fd, t->o->timeout_ms, &r);
  CF_CHECK(t, rc == CF_GOT, "no reply once the stalled frame was complete");
  if (r.h.type == HFP_ERROR) {
    /* The deadline struck as the rest arrived. */
    hfp_error e;
    CF_CHECK(t, hfp_decode_error(r.p, r.h.length, &e) == 0 && e.code == HFP_E_PROTOCOL && e.fatal,
             "got %s", cf_describe(&r, d, sizeof d));
    return 0;
  }
  if (where == ST_MID_CONTROL) return 0;
  return cf_check_result(t, &r, &f, t->srv->version, NULL, NULL, NULL);
}

/* Replies left unread for stall_ms: all of them once read, or the
 * connection closed (a server may close a peer that reads none). */
static int unread_replies(cf_test *t, intptr_t count) {
  int fd;
  CF_TRY(cf_connect_hello(t, 1, HFP_VERSION, &fd, NULL));
  uint8_t *b = cf_alloc(t, HFP_HEADER_SIZE * (size_t)count);
  CF_CHECK(t, b, "out of memory");
  for (int i = 0; i < count; i++) cf_header(b + HFP_HEADER_SIZE * (size_t)i, HFP_STATS, 0, 0, 0);
  CF_TRY(cf_send(t, fd, b, HFP_HEADER_SIZE * (size_t)count));
  cf_sleep_ms(t->o->stall_ms);
  for (int i = 0; i < count; i++) {
    cf_frame r;
    int rc = cf_read(t, fd, t->o->timeout_ms, &r);
    if (rc == CF_EOF && i == 0) return 0;   /* closed for not reading: allowed */
    if (rc == CF_EOF) return 0;
    CF_CHECK(t, rc == CF_GOT && r.h.type == HFP_STATS_REPLY, "reply %d of %d: %s", i, (int)count,
             rc == CF_GOT ? "not STATS_REPLY" : "nothing");
  }
  return 0;
}

#define TRUNC(m, name) {"truncate." name, "a frame cut at any byte and half-closed: dropped, no reply, the close", 0, truncate_every_byte, m}
#define DISC(m, name) {"disconnect." name, "a peer that leaves in the middle of a frame affects no one else", 0, disconnect_every_byte, m}

const cf_case cf_cases_flow[] = {
  TRUNC(M_HELLO, "hello"),
  TRUNC(M_LIST_VARIANTS, "list_variants"),
  TRUNC(M_STATS, "stats"),
  TRUNC(M_FILTER, "filter"),
  TRUNC(M_FILTER_COMPOSITE, "filter_composite"),
  {"truncate.shm_create", "a frame cut at any byte and half-closed: dropped, no reply, the close", CF_NEED_UNIX | CF_NEED_SHM, truncate_every_byte, M_SHM_CREATE},
  {"truncate.shm_destroy", "a frame cut at any byte and half-closed: dropped, no reply, the close", CF_NEED_UNIX | CF_NEED_SHM, truncate_every_byte, M_SHM_DESTROY},
  {"truncate.filter_shm", "a frame cut at any byte and half-closed: dropped, no reply, the close", CF_NEED_UNIX | CF_NEED_SHM, truncate_every_byte, M_FILTER_SHM},
  DISC(M_HELLO, "hello"),
  DISC(M_LIST_VARIANTS, "list_variants"),
  DISC(M_FILTER, "filter"),
  DISC(M_FILTER_COMPOSITE, "filter_composite"),
  {"transport.half_close.before_hello", "a half-close before HELLO: the close, nothing sent", 0, half_close, HC_BEFORE_HELLO},
  {"transport.half_close.idle", "a half-close with nothing in flight: the close", 0, half_close, HC_IDLE},
  {"transport.half_close.after_control", "a half-close after STATS: its reply, then the close", 0, half_close, HC_AFTER_CONTROL},
  {"transport.half_close.with_inflight", "a half-close with FILTERs in flight: every admitted one answered, then the close", 0, half_close, HC_INFLIGHT},
  {"transport.half_close.mid_filter", "a half-close in the middle of a FILTER: it is dropped, the admitted answered", 0, half_close, HC_MID_FILTER},
  {"transport.half_close.mid_header", "a half-close inside a header: the close, nothing sent", 0, half_close, HC_MID_HEADER},
  {"transport.half_close.after_refusal", "a half-close after a refused FILTER: its ERROR, then the close", 0, half_close, HC_AFTER_REFUSAL},
  {"transport.close.with_inflight", "a client that closes with FILTERs in flight loses their replies, nothing else", 0, close_outright, CL_INFLIGHT},
  {"transport.close.mid_reply", "a client that closes while a RESULT is written affects no one else", 0, close_outright, CL_MID_REPLY},
  {"transport.close.after_shm_create", "closing before reading SHM_CREATED releases the segment", CF_NEED_UNIX | CF_NEED_SHM, close_outright, CL_AFTER_SHM_CREATE},
  {"transport.close.segment_in_use", "closing with a FILTER running on a segment", CF_NEED_UNIX | CF_NEED_SHM, close_outright, CL_WITH_SEGMENTS_IN_USE},
  {"stall.mid_header", "silent inside a header: kept, or closed with a fatal PROTOCOL (id 0)", 0, stall, ST_MID_HEADER},
  {"stall.mid_filter_head", "silent inside a FILTER's fixed fields: kept, or a fatal PROTOCOL with its id", 0, stall, ST_MID_FILTER_HEAD},
  {"stall.mid_variant_name", "silent inside a FILTER's variant name: kept, or a fatal PROTOCOL with its id", 0, stall, ST_MID_NAME},
  {"stall.mid_tensor", "silent inside a FILTER's tensor: kept, or a fatal PROTOCOL with its id", 0, stall, ST_MID_TENSOR},
  {"stall.mid_control", "silent inside a control frame: kept, or a fatal PROTOCOL (id 0)", 0, stall, ST_MID_CONTROL},
  {"stall.idle", "a connection idle between frames is not closed", 0, stall, ST_IDLE},
  {"stall.unread_replies", "replies left unread: all delivered once read, or the connection closed", 0, unread_replies, 300},
  {NULL, NULL, 0, NULL, 0},
};
