/*
 * The client suite: libhairfilter (client/lib) against the scripted mock
 * server, each case one reply of PROTOCOL.md, valid or not, and what the
 * library must make of it: results delivered into the caller's buffers in
 * whatever order they come, every ERROR code turned into its HFC_E_*,
 * malformed, truncated and unexpected frames a protocol failure that fails
 * what was pending (never a crash, a hang or a success), a stalled server a
 * timeout, version-1 and version-2 replies each read as their version says.
 */
#define _GNU_SOURCE
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <unistd.h>

#include "cf_mock.h"
#include <hairfilter/hairfilter.h>
#include "hfcore.h"

enum { W = 4, H = 3 };

typedef struct frame_bufs {
  float in[W * H * MK_SPP * 6];
  float out[W * H * 3];
  float rgba[W * H * 4];
} frame_bufs;

static int start(cf_test *t, mock *m) { return mk_start(t, m); }

static int connect_to(cf_test *t, mock *m, int timeout_ms, hfc_client **c) {
  hfc_options o = cf_client_options("conformance", NULL, timeout_ms ? timeout_ms : 5000);
  int rc = hfc_connect(m->url, &o, c);
  if (rc) {
    *c = NULL;
    return cf_fail(t, "hfc_connect to the mock failed: %s", hfc_strerror(rc));
  }
  return 0;
}

static hfc_request request(frame_bufs *b, int composite) {
  /* The first value is the frame's tag (mk_values), different for every
   * request of a run. */
  static uint32_t tags;
  for (size_t i = 0; i < sizeof b->in / sizeof b->in[0]; i++) b->in[i] = (float)(i % 7) / 8.0f;
  b->in[0] = (float)(++tags % 60000 + 1);
  memset(b->out, 0xff, sizeof b->out);
  memset(b->rgba, 0xff, sizeof b->rgba);
  hfc_request r;
  hfc_request_init(&r);
  r.variant = MK_VARIANT;
  r.width = W;
  r.height = H;
  r.spp = MK_SPP;
  r.in_dtype = r.out_dtype = HFC_F32;
  r.features = b->in;
  r.features_bytes = sizeof b->in;
  r.result = b->out;
  r.result_bytes = sizeof b->out;
  r.rgba = composite ? b->rgba : NULL;
  r.rgba_bytes = composite ? sizeof b->rgba : 0;
  const float hair[3] = {0.5f, 0.4f, 0.3f}, light[3] = {1, 1, 1}, bg[3] = {0.1f, 0.2f, 0.3f};
  memcpy(r.hair, hair, sizeof hair);
  memcpy(r.light, light, sizeof light);
  memcpy(r.background, bg, sizeof bg);
  return r;
}

/* The result of request r (id, for messages) is the mock's values for its
 * features' tag, in the caller's buffer; with rgba the composite too. */
static int check_values(cf_test *t, uint32_t id, const float *out, const float *rgba,
                        const hfc_request *r) {
  uint32_t tag = mk_tag(r->features, r->in_dtype == HFC_F16 ? HFP_F16 : HFP_F32);
  for (size_t p = 0; p < (size_t)W * H; p++) {
    float v[3];
    mk_values(tag, p, v);
    for (int k = 0; k < 3; k++)
      CF_CHECK(t, out[3 * p + (size_t)k] == v[k], "request %u: result pixel %zu channel %d is %g, sent %g",
               id, p, k, out[3 * p + (size_t)k], v[k]);
    if (!rgba) continue;
    CF_CHECK(t, rgba[4 * p + 3] == v[2], "request %u: composite alpha of pixel %zu is %g", id, p,
             rgba[4 * p + 3]);
    float want = v[2] * r->light[0] * (r->hair[0] * v[0] + v[1]) + (1 - v[2]) * r->background[0];
    CF_CHECK(t, fabsf(rgba[4 * p] - want) < 1e-5f, "request %u: composite of pixel %zu is %g, sent %g",
             id, p, rgba[4 * p], want);
  }
  return 0;
}

/* Submits r, waits for its completion. */
static int one(cf_test *t, hfc_client *c, const hfc_request *r, hfc_completion *done) {
  uint32_t id;
  int rc = hfc_submit(c, r, &id);
  CF_CHECK(t, rc == 0, "hfc_submit failed: %s", hfc_strerror(rc));
  rc = hfc_wait(c, -1, done);
  CF_CHECK(t, rc == 0, "hfc_wait failed: %s", hfc_strerror(rc));
  CF_CHECK(t, done->id == id, "completion for id %u, submitted %u", done->id, id);
  return 0;
}

/* Ends a case: the client closes, the mock's verdict joins ours. */
static int finish(cf_test *t, mock *m, hfc_client *c, int rc) {
  hfc_close(c);
  int mrc = mk_finish(t, m);
  return rc ? rc : mrc;
}

#define CASE_BEGIN(t, m, c, timeout)         \
  hfc_client *c = NULL;                      \
  CF_TRY(start(t, m));                       \
  if (connect_to(t, m, timeout, &c)) return finish(t, m, NULL, CF_FAIL)

/* ---- handshake ------------------------------------------------------------------- */

static int hello_offer(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  CF_TRY(start(t, &m));
  hfc_client *c = NULL;
  hfc_options o = cf_client_options("engine-7", "s3cret-token", 5000);
  int rc = hfc_connect(m.url, &o, &c);
  if (rc) return finish(t, &m, c, cf_fail(t, "hfc_connect failed: %s", hfc_strerror(rc)));
  hfc_close(c);
  CF_TRY(mk_finish(t, &m));
  CF_CHECK(t, m.hello.min_version <= 1 && m.hello.max_version >= HFP_VERSION,
           "the client offered versions %u..%u, not 1..%d", m.hello.min_version,
           m.hello.max_version, HFP_VERSION);
  CF_CHECK(t, !strcmp(m.hello.client_name, "engine-7"), "the client sent the name '%s'",
           m.hello.client_name);
  CF_CHECK(t, !strcmp(m.hello.token, "s3cret-token"), "the client sent the token '%s'", m.hello.token);
  return 0;
}

/* HELLO_OK's fields as hfc_info reports them. */
static int hello_info(cf_test *t, intptr_t flags) {
  mock m = {0};
  m.ok.server_flags = (uint16_t)flags;
  m.ok.version = 1;
  CASE_BEGIN(t, &m, c, 0);
  const hfc_server_info *i = hfc_info(c);
  int rc = 0;
  if (i->version != 1 || i->max_width != 256 || i->max_height != 256 || i->max_spp != MK_SPP ||
      i->max_inflight != 8 || i->max_batch != 4 || i->queue_size != 64 || !i->f16 || !i->f32 ||
      i->max_frame_bytes != (1u << 24) || strcmp(i->name, "mock") ||
      i->auth_required != (int)(flags & 1) || i->shm != (int)((flags >> 1) & 1))
    rc = cf_fail(t, "hfc_info does not say what HELLO_OK said (version %d, %dx%d, spp %d, "
                 "inflight %d, auth %d, shm %d)", i->version, i->max_width, i->max_height,
                 i->max_spp, i->max_inflight, i->auth_required, i->shm);
  return finish(t, &m, c, rc);
}

enum {
  HO_VERSION_OVER, HO_VERSION_0, HO_INFLIGHT_0, HO_SPP_0, HO_SPP_17, HO_DTYPES_0, HO_DTYPES_4,
  HO_WIDTH_0, HO_HEIGHT_65536, HO_BATCH_0, HO_NAME_0, HO_NAME_SPACE, HO_TRAILING, HO_MISSING,
  HO_ID, HO_FLAGS, HO_MAGIC, HO_WRONG_TYPE, HO_REQUEST_TYPE, HO_TYPE_13,
};

/* A HELLO_OK that breaks one rule: hfc_connect fails (never succeeds). */
static int bad_hello_ok_script(mock *m) {
  if (mk_accept(m)) return CF_FAIL;
  hfp_header h;
  uint8_t *p;
  if (mk_read(m, &h, &p) <= 0) return mk_fail(m, "no HELLO");
  free(p);
  hfp_hello_ok ok = {2, 0, 256, 256, 2, 8, 3, 4, 64, 1 << 24, "mock", ""};
  /* With a software version, a byte missing or one too many is inside or
   * after it (without one, the last byte is the optional block's length). */
  if (m->arg == HO_MISSING || m->arg == HO_TRAILING)
    snprintf(ok.software_version, sizeof ok.software_version, "0.1.0");
  uint8_t b[HFP_HEADER_SIZE + 64 + 2 * HFP_NAME_MAX + 8];
  int n = hfp_encode_hello_ok(b, sizeof b, &ok);
  uint8_t *q = b + HFP_HEADER_SIZE;
  switch (m->arg) {
    case HO_VERSION_OVER: hfp_put_u16(q, HFP_VERSION + 1); break;
    case HO_VERSION_0: hfp_put_u16(q, 0); break;
    case HO_INFLIGHT_0: hfp_put_u16(q + 14, 0); break;
    case HO_SPP_0: hfp_put_u16(q + 12, 0); break;
    case HO_SPP_17: hfp_put_u16(q + 12, 17); break;
    case HO_DTYPES_0: hfp_put_u32(q + 16, 0); break;
    case HO_DTYPES_4: hfp_put_u32(q + 16, 7); break;
    case HO_WIDTH_0: hfp_put_u32(q + 4, 0); break;
    case HO_HEIGHT_65536: hfp_put_u32(q + 8, 65536); break;
    case HO_BATCH_0: hfp_put_u32(q + 20, 0); break;
    case HO_NAME_0:
      hfp_put_u16(q + 36, 0);
      n -= 4;
      cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE));
      break;
    case HO_NAME_SPACE: q[38] = ' '; break;
    case HO_TRAILING: b[n++] = 'x'; cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE)); break;
    case HO_MISSING: n--; cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE)); break;
    case HO_FLAGS: hfp_put_u16(b + 6, 1); break;
    case HO_MAGIC: b[3] ^= 0x40; break;
    case HO_WRONG_TYPE: hfp_put_u16(b + 4, HFP_STATS_REPLY); break;
    case HO_REQUEST_TYPE: hfp_put_u16(b + 4, HFP_HELLO); break;
    case HO_TYPE_13: hfp_put_u16(b + 4, 13); break;
  }
  mk_send(m, b, (size_t)n);
  /* Wait for the client to give up. */
  if (mk_read(m, &h, &p) > 0) free(p);
  return 0;
}

static int bad_hello_ok(cf_test *t, intptr_t how) {
  mock m = {0};
  m.script = bad_hello_ok_script;
  m.arg = how;
  CF_TRY(start(t, &m));
  hfc_client *c = NULL;
  hfc_options o = cf_client_options("conformance", NULL, 3000);
  int rc = hfc_connect(m.url, &o, &c);
  int want = how <= HO_VERSION_0 ? HFC_E_VERSION : HFC_E_PROTOCOL;
  int v = 0;
  if (rc == 0)
    v = cf_fail(t, "hfc_connect accepted a malformed HELLO_OK");
  else if (rc != want && !(how <= HO_VERSION_0 && rc == HFC_E_PROTOCOL))
    v = cf_fail(t, "hfc_connect returned %s, wanted %s", hfc_strerror(rc), hfc_strerror(want));
  return finish(t, &m, c, v);
}

/* An ERROR instead of HELLO_OK: hfc_connect returns its code. */
static int hello_error_script(mock *m) {
  if (mk_accept(m)) return CF_FAIL;
  hfp_header h;
  uint8_t *p;
  if (mk_read(m, &h, &p) <= 0) return mk_fail(m, "no HELLO");
  free(p);
  uint8_t b[300];
  mk_send(m, b, mk_error(b, 0, (int)m->arg, 1, "refused by the mock"));
  return 0;
}

static int hello_error(cf_test *t, intptr_t code) {
  mock m = {0};
  m.script = hello_error_script;
  m.arg = code;
  CF_TRY(start(t, &m));
  hfc_client *c = NULL;
  hfc_options o = cf_client_options("conformance", NULL, 3000);
  int rc = hfc_connect(m.url, &o, &c);
  int v = rc == -(int)code ? 0
                           : cf_fail(t, "hfc_connect returned %s, wanted %s", hfc_strerror(rc),
                                     hfc_strerror(-(int)code));
  return finish(t, &m, c, v);
}

/* HELLO_OK cut after every byte, then the close: never a success, but for
 * the cut that leaves out only the version-2 software block (optional:
 * PROTOCOL.md, "Version 2"), which is a whole HELLO_OK. */
static const hfp_hello_ok cut_ok = {2, 0, 256, 256, 2, 8, 3, 4, 64, 1 << 24, "mock", "0.1.0"};

static int hello_cut_script(mock *m) {
  uint8_t b[HFP_HEADER_SIZE + 64 + 2 * HFP_NAME_MAX];
  int n = hfp_encode_hello_ok(b, sizeof b, &cut_ok);
  for (int k = 0; k < n; k++) {
    if (mk_accept(m)) return CF_FAIL;
    hfp_header h;
    uint8_t *p;
    if (mk_read(m, &h, &p) <= 0) return mk_fail(m, "no HELLO on connection %d", k);
    free(p);
    mk_send(m, b, (size_t)k);
    close(m->fd);
    m->fd = -1;
  }
  return 0;
}

static int hello_cut(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.script = hello_cut_script;
  CF_TRY(start(t, &m));
  uint8_t b[HFP_HEADER_SIZE + 64 + 2 * HFP_NAME_MAX];
  int n = hfp_encode_hello_ok(b, sizeof b, &cut_ok), v = 0;
  int whole = n - 1 - (int)strlen(cut_ok.software_version);
  for (int k = 0; k < n && !v; k++) {
    hfc_client *c = NULL;
    hfc_options o = cf_client_options("conformance", NULL, 3000);
    int rc = hfc_connect(m.url, &o, &c);
    if (rc == 0 && k != whole)
      v = cf_fail(t, "hfc_connect succeeded on a HELLO_OK cut after %d bytes", k);
    else if (rc != HFC_E_CLOSED && rc != HFC_E_PROTOCOL)
      v = cf_fail(t, "a HELLO_OK cut after %d bytes: %s, wanted CLOSED", k, hfc_strerror(rc));
    hfc_close(c);
  }
  return finish(t, &m, NULL, v);
}

static int silent_script(mock *m) {
  if (mk_accept(m)) return CF_FAIL;
  /* Read everything, answer nothing, until the client leaves. */
  for (;;) {
    hfp_header h;
    uint8_t *p;
    int rc = mk_read(m, &h, &p);
    free(p);
    if (rc == 0) return 0;
    if (rc < 0 && !m->failed) continue;
    if (rc < 0) return CF_FAIL;
  }
}

static int hello_silent(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.script = silent_script;
  m.timeout_ms = 300;
  CF_TRY(start(t, &m));
  hfc_client *c = NULL;
  hfc_options o = cf_client_options("conformance", NULL, 300);
  double t0 = cf_now_ms();
  int rc = hfc_connect(m.url, &o, &c);
  double ms = cf_now_ms() - t0;
  int v = 0;
  if (rc != HFC_E_TIMEOUT) v = cf_fail(t, "a silent server: hfc_connect returned %s", hfc_strerror(rc));
  else if (ms > 3000) v = cf_fail(t, "a 300 ms timeout took %.0f ms", ms);
  m.timeout_ms = 1;
  return finish(t, &m, c, v);
}

static int closes_script(mock *m) {
  if (mk_accept(m)) return CF_FAIL;
  close(m->fd);
  m->fd = -1;
  return 0;
}

static int hello_closed(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.script = closes_script;
  CF_TRY(start(t, &m));
  hfc_client *c = NULL;
  hfc_options o = cf_client_options("conformance", NULL, 3000);
  int rc = hfc_connect(m.url, &o, &c);
  int v = rc == HFC_E_CLOSED ? 0
                             : cf_fail(t, "a server that closes at once: hfc_connect returned %s",
                                       hfc_strerror(rc));
  return finish(t, &m, c, v);
}

/* ---- filtering -------------------------------------------------------------------- */

static int filter_ok(cf_test *t, intptr_t arg) {
  int composite = (int)(arg & 1), version = (int)(arg >> 1) ? 1 : 0;
  mock m = {0};
  m.ok.version = (uint16_t)version;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, composite);
  hfc_completion d;
  int rc = one(t, c, &r, &d);
  if (!rc && d.status) rc = cf_fail(t, "the completion has status %s", hfc_strerror(d.status));
  if (!rc) rc = check_values(t, d.id, b.out, composite ? b.rgba : NULL, &r);
  if (!rc && (d.timing.queue_us != 11 || d.timing.input_us != 22 || d.timing.infer_us != 33 ||
              d.timing.output_us != 44 || d.timing.server_us != 200 || d.timing.batch != 1))
    rc = cf_fail(t, "the timing is not RESULT's: queue %g input %g infer %g output %g server %g",
                 d.timing.queue_us, d.timing.input_us, d.timing.infer_us, d.timing.output_us,
                 d.timing.server_us);
  return finish(t, &m, c, rc);
}

/* What the client put on the wire for a FILTER, checked by the mock. */
static int check_filter_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type == HFP_FILTER) {
    hfp_filter f;
    if (hfp_decode_filter(p, h->length, &f)) return mk_fail(m, "the FILTER does not decode");
    if (strcmp(f.variant, MK_VARIANT) || f.width != W || f.height != H || f.spp != MK_SPP ||
        f.in_dtype != HFP_F16 || f.out_dtype != HFP_F32 || f.flags != HFP_FILTER_COMPOSITE ||
        f.hair[0] != 0.5f || f.light[1] != 1.0f || f.bg[2] != 0.3f)
      return mk_fail(m, "the FILTER's fields are not the request's");
    for (size_t i = 0; i < (size_t)W * H * MK_SPP * 6; i++) {
      uint16_t v;
      memcpy(&v, (const uint8_t *)f.data + 2 * i, 2);
      if (v != (uint16_t)(0x3c00 + i)) return mk_fail(m, "feature %zu is 0x%04x on the wire", i, v);
    }
  }
  return mk_reply(m, h, p);
}

/* hfc_request.deadline_us on the wire: FILTER flag DEADLINE and the budget
 * from a server of version 4; nothing from an older one (PROTOCOL.md,
 * "Version 4"). m->arg is the version the mock speaks. */
static int deadline_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type == HFP_FILTER) {
    hfp_filter f;
    if (hfp_decode_filter(p, h->length, &f)) return mk_fail(m, "the FILTER does not decode");
    if (m->arg >= 4 && (!(f.flags & HFP_FILTER_DEADLINE) || f.budget_us != 16000))
      return mk_fail(m, "a version-4 FILTER with deadline_us 16000 has flags 0x%x, budget %u us",
                     f.flags, f.budget_us);
    if (m->arg < 4 && (f.flags & HFP_FILTER_DEADLINE))
      return mk_fail(m, "a version-%d server got FILTER flag DEADLINE, which it does not know",
                     (int)m->arg);
  }
  return mk_reply(m, h, p);
}

static int deadline_wire(cf_test *t, intptr_t version) {
  mock m = {0};
  m.ok.version = (uint16_t)version;
  m.on_frame = deadline_handler;
  m.arg = version;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  r.deadline_us = 16000;
  hfc_completion d;
  int rc = one(t, c, &r, &d);
  if (!rc && d.status) rc = cf_fail(t, "the completion has status %s", hfc_strerror(d.status));
  if (!rc) rc = check_values(t, d.id, b.out, NULL, &r);
  return finish(t, &m, c, rc);
}

/* hfc_cancel (version 4): a CANCEL with the FILTER's wire id goes out;
 * the mock holds the FILTER until then and answers it CANCELLED, which
 * completes it HFC_E_CANCELLED. Against a version-3 server nothing goes
 * out (HFC_E_UNSUPPORTED) and the frame completes as answered. m->arg is
 * the version the mock speaks. */
static int cancel_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type == HFP_CANCEL) {
    if (m->arg < 4) return mk_fail(m, "a version-%d server got a CANCEL", (int)m->arg);
    if (h->length || m->nids != 1 || h->request_id != m->ids[0])
      return mk_fail(m, "a CANCEL of id %u with %u payload bytes; the FILTER had id %u",
                     h->request_id, h->length, m->nids ? m->ids[0] : 0);
    hfp_result r;
    memset(&r, 0, sizeof r);
    r.status = HFP_E_CANCELLED;
    r.timing.total_us = r.timing.queue_us = 3;
    uint8_t b[HFP_RESULT_HEAD_MAX];
    int n = hfp_encode_result_head(b, sizeof b, h->request_id, &r, NULL);
    if (n < 0) return mk_fail(m, "mock: cannot encode the RESULT");
    mk_send(m, b, (size_t)n);
    return 0;
  }
  /* Version 4: the FILTER waits for its CANCEL. */
  if (h->type == HFP_FILTER && m->arg >= 4) return 0;
  return mk_reply(m, h, p);
}

static int cancel_wire(cf_test *t, intptr_t version) {
  mock m = {0};
  m.ok.version = (uint16_t)version;
  m.on_frame = cancel_handler;
  m.arg = version;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  uint32_t id;
  int rc = hfc_submit(c, &r, &id), v = 0;
  if (rc) v = cf_fail(t, "hfc_submit: %s", hfc_strerror(rc));
  int want = version >= 4 ? 0 : HFC_E_UNSUPPORTED;
  if (!v && (rc = hfc_cancel(c, id)) != want)
    v = cf_fail(t, "hfc_cancel against a version-%d server returned %s, wanted %s", (int)version,
                hfc_strerror(rc), hfc_strerror(want));
  hfc_completion d;
  if (!v && (rc = hfc_wait(c, 5000, &d)) != 0) v = cf_fail(t, "hfc_wait: %s", hfc_strerror(rc));
  want = version >= 4 ? HFC_E_CANCELLED : 0;
  if (!v && d.status != want)
    v = cf_fail(t, "the cancelled frame completed %s, wanted %s", hfc_strerror(d.status),
                hfc_strerror(want));
  if (!v && version < 4) v = check_values(t, d.id, b.out, NULL, &r);
  return finish(t, &m, c, v);
}

static int filter_wire(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = check_filter_handler;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 1);
  uint16_t in16[W * H * MK_SPP * 6];
  for (size_t i = 0; i < sizeof in16 / sizeof in16[0]; i++) in16[i] = (uint16_t)(0x3c00 + i);
  r.features = in16;
  r.features_bytes = sizeof in16;
  r.in_dtype = HFC_F16;
  hfc_completion d;
  int rc = one(t, c, &r, &d);
  if (!rc && d.status) rc = cf_fail(t, "status %s", hfc_strerror(d.status));
  return finish(t, &m, c, rc);
}

/* f16 results land as binary16 in the caller's buffer. */
static int filter_f16(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  uint16_t out16[W * H * 3];
  r.out_dtype = HFC_F16;
  r.result = out16;
  r.result_bytes = sizeof out16;
  hfc_completion d;
  int rc = one(t, c, &r, &d);
  for (size_t p = 0; !rc && p < (size_t)W * H; p++) {
    float v[3];
    mk_values(mk_tag(r.features, HFP_F32), p, v);
    for (int k = 0; k < 3 && !rc; k++)
      if (out16[3 * p + (size_t)k] != hf_f32_to_f16(v[k]))
        rc = cf_fail(t, "f16 result pixel %zu channel %d differs from what was sent", p, k);
  }
  return finish(t, &m, c, rc);
}

/* Results in the reverse of submission order: each lands in its own
 * request's buffers and comes with its own user pointer. */
static int reverse_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  static uint8_t *held[8];
  static size_t held_n[8];
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  int k = m->seen[HFP_FILTER] - 1;
  held[k] = mk_result(m, h->request_id, p, h->length, &held_n[k]);
  if (!held[k]) return CF_FAIL;
  if (k + 1 < (int)m->arg) return 0;
  for (int i = k; i >= 0; i--) {
    mk_send(m, held[i], held_n[i]);
    free(held[i]);
  }
  return 0;
}

static int out_of_order(cf_test *t, intptr_t n) {
  mock m = {0};
  m.on_frame = reverse_handler;
  m.arg = n;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b[8];
  hfc_request reqs[8];
  uint32_t ids[8];
  int rc = 0;
  for (int i = 0; i < n && !rc; i++) {
    reqs[i] = request(&b[i], i % 2);
    reqs[i].user = &b[i];
    if (hfc_submit(c, &reqs[i], &ids[i])) rc = cf_fail(t, "hfc_submit %d failed", i);
  }
  for (int i = 0; i < n && !rc; i++) {
    hfc_completion d;
    int w = hfc_wait(c, -1, &d);
    if (w) {
      rc = cf_fail(t, "hfc_wait %d: %s", i, hfc_strerror(w));
      break;
    }
    int k = (int)((frame_bufs *)d.user - b);
    if (k < 0 || k >= n || d.id != ids[k]) {
      rc = cf_fail(t, "completion %d has id %u and a user pointer of another request", i, d.id);
      break;
    }
    if (d.id != ids[n - 1 - i])
      rc = cf_fail(t, "completion %d is id %u, the server answered %u first", i, d.id, ids[n - 1 - i]);
    if (!rc) rc = check_values(t, d.id, b[k].out, k % 2 ? b[k].rgba : NULL, &reqs[k]);
  }
  return finish(t, &m, c, rc);
}

/* Ids are never 0 and never one still in flight. */
static int ids_unique(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = reverse_handler;
  m.arg = 8;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b[8];
  uint32_t ids[8];
  int rc = 0;
  for (int i = 0; i < 8 && !rc; i++) {
    hfc_request r = request(&b[i], 0);
    if (hfc_submit(c, &r, &ids[i])) rc = cf_fail(t, "hfc_submit %d failed", i);
    for (int j = 0; j < i && !rc; j++)
      if (ids[j] == ids[i] || !ids[i]) rc = cf_fail(t, "request %d got id %u, in flight or 0", i, ids[i]);
  }
  for (int i = 0; i < 8 && !rc; i++) {
    hfc_completion d;
    if (hfc_wait(c, -1, &d)) rc = cf_fail(t, "hfc_wait failed");
  }
  return finish(t, &m, c, rc);
}

/* No more than max_inflight pending: the next submit is refused locally. */
static int inflight_local(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.ok.max_inflight = 2;
  m.on_frame = reverse_handler;
  m.arg = 2;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b[3];
  int rc = 0;
  for (int i = 0; i < 2 && !rc; i++) {
    hfc_request r = request(&b[i], 0);
    if (hfc_submit(c, &r, NULL)) rc = cf_fail(t, "hfc_submit %d failed", i);
  }
  hfc_request r = request(&b[2], 0);
  int s = rc ? 0 : hfc_submit(c, &r, NULL);
  if (!rc && s != HFC_E_INFLIGHT)
    rc = cf_fail(t, "a third request with max_inflight 2: %s, wanted INFLIGHT", hfc_strerror(s));
  for (int i = 0; i < 2 && !rc; i++) {
    hfc_completion d;
    if (hfc_wait(c, -1, &d)) rc = cf_fail(t, "hfc_wait failed");
  }
  if (!rc && m.seen[HFP_FILTER] != 2) rc = cf_fail(t, "the mock saw %d FILTERs", m.seen[HFP_FILTER]);
  return finish(t, &m, c, rc);
}

/* An ERROR (non-fatal) for a FILTER: the request fails with its code and
 * the server's message; the connection goes on. */
static int error_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER || m->seen[HFP_FILTER] > 1) return mk_reply(m, h, p);
  uint8_t b[300];
  int code = (int)(m->arg & 0xffff), fatal = (int)(m->arg >> 16);
  mk_send(m, b, mk_error(b, h->request_id, code, fatal, "said the mock"));
  return fatal ? 1 : 0;
}

static int error_code(cf_test *t, intptr_t arg) {
  int code = (int)(arg & 0xffff), fatal = (int)(arg >> 16);
  mock m = {0};
  m.on_frame = error_handler;
  m.arg = arg;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  int rc = hfc_filter(c, &r, NULL);
  int want = code < HFP_E_COUNT && code != HFP_E_NOSPACE ? -code : 0;
  int v = 0;
  if (rc == 0) v = cf_fail(t, "an ERROR %d for the FILTER: hfc_filter returned OK", code);
  else if (want && rc != want) v = cf_fail(t, "ERROR %s: hfc_filter returned %s", hfp_code_name(code), hfc_strerror(rc));
  else if (strncmp(hfc_last_message(c), "said the mock", 13))
    v = cf_fail(t, "hfc_last_message is '%s', not the server's message (a library may add to it)",
                hfc_last_message(c));
  if (!v) {
    rc = hfc_filter(c, &r, NULL);
    if (fatal && rc == 0) v = cf_fail(t, "after a fatal ERROR the next hfc_filter succeeded");
    if (!fatal && rc) v = cf_fail(t, "after a non-fatal ERROR the next hfc_filter failed: %s", hfc_strerror(rc));
  }
  return finish(t, &m, c, v);
}

/* RESULT with a non-zero status: the request fails with that code. */
static int status_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER || m->seen[HFP_FILTER] > 1) return mk_reply(m, h, p);
  hfp_result r;
  memset(&r, 0, sizeof r);
  r.status = (uint16_t)(m->arg & 0xff);
  r.timing.total_us = 5;
  uint8_t b[HFP_RESULT_HEAD_MAX + 16];
  int n = hfp_encode_result_head(b, sizeof b, h->request_id, &r, NULL);
  if (n < 0) return mk_fail(m, "mock: cannot encode the RESULT");
  if (m->arg >> 8) {
    /* a tensor where none may be */
    memset(b + n, 0, 12);
    cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE + 12));
    n += 12;
  }
  mk_send(m, b, (size_t)n);
  return 0;
}

static int result_status(cf_test *t, intptr_t arg) {
  mock m = {0};
  m.on_frame = status_handler;
  m.arg = arg;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  int rc = hfc_filter(c, &r, NULL), v = 0;
  int want = (arg >> 8) ? HFC_E_PROTOCOL : -(int)(arg & 0xff);
  if (rc != want) v = cf_fail(t, "RESULT status %d%s: hfc_filter returned %s, wanted %s",
                             (int)(arg & 0xff), (arg >> 8) ? " with a tensor" : "",
                             hfc_strerror(rc), hfc_strerror(want));
  if (!v && !(arg >> 8) && (rc = hfc_filter(c, &r, NULL)) != 0)
    v = cf_fail(t, "after a failed RESULT the connection does not serve: %s", hfc_strerror(rc));
  return finish(t, &m, c, v);
}

enum {
  RB_UNKNOWN_ID, RB_WIDTH, RB_HEIGHT, RB_DTYPE, RB_NO_RGBA, RB_EXTRA_RGBA, RB_SHM_UNASKED,
  RB_SHORT, RB_LONG, RB_BATCH0, RB_FLAG_BIT4, RB_V1_SANITISED, RB_V1_OUT_OF_RANGE, RB_MAGIC,
  RB_HEADER_FLAGS, RB_TYPE_13, RB_CLIENT_TYPE, RB_HUGE_CONTROL, RB_STATUS_99,
};

/* A malformed RESULT (or frame in its place): the request fails with
 * PROTOCOL, and so does everything after on that connection. */
static int bad_result_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  size_t n;
  uint8_t *b = mk_result(m, h->request_id, p, h->length, &n);
  if (!b) return CF_FAIL;
  uint8_t *q = b + HFP_HEADER_SIZE;
  switch (m->arg) {
    case RB_UNKNOWN_ID: hfp_put_u32(b + 8, h->request_id + 1000); break;
    case RB_WIDTH: hfp_put_u32(q + 4, W + 1); hfp_put_u32(q + 8, H - 1); break;  /* same pixel count */
    case RB_HEIGHT: hfp_put_u32(q + 8, H + 1); cf_set_length(b, HFP_RESULT_FIXED + W * (H + 1) * 12); break;
    case RB_DTYPE: q[2] = HFP_F16; cf_set_length(b, HFP_RESULT_FIXED + W * H * 6); n = HFP_HEADER_SIZE + HFP_RESULT_FIXED + W * H * 6; break;
    case RB_NO_RGBA: q[3] = 0; cf_set_length(b, HFP_RESULT_FIXED + W * H * 12); n = HFP_HEADER_SIZE + HFP_RESULT_FIXED + W * H * 12; break;
    case RB_EXTRA_RGBA: q[3] = HFP_FILTER_COMPOSITE; cf_set_length(b, HFP_RESULT_FIXED + W * H * 28); break;
    case RB_SHM_UNASKED: q[3] |= HFP_FILTER_SHM; cf_set_length(b, HFP_RESULT_FIXED); n = HFP_HEADER_SIZE + HFP_RESULT_FIXED; break;
    case RB_SHORT: cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE - 1)); n--; break;
    case RB_LONG: cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE + 1)); break;
    case RB_BATCH0: hfp_put_u32(q + 12, 0); break;
    case RB_FLAG_BIT4: q[3] |= 0x10; break;
    case RB_V1_SANITISED: q[3] |= HFP_RESULT_INPUT_SANITISED; break;
    case RB_V1_OUT_OF_RANGE: q[3] |= HFP_RESULT_OUT_OF_RANGE; break;
    case RB_MAGIC: b[1] ^= 1; break;
    case RB_HEADER_FLAGS: hfp_put_u16(b + 6, 0x10); break;
    case RB_TYPE_13: hfp_put_u16(b + 4, 13); break;
    case RB_CLIENT_TYPE: hfp_put_u16(b + 4, HFP_FILTER); break;
    case RB_HUGE_CONTROL: cf_header(b, HFP_VARIANTS, 0, 0, 0xfffffff0u); n = HFP_HEADER_SIZE + 64; break;
    case RB_STATUS_99: hfp_put_u16(q, 99); q[3] = 0; hfp_put_u32(q + 4, 0); hfp_put_u32(q + 8, 0); hfp_put_u32(q + 12, 0); cf_set_length(b, HFP_RESULT_FIXED); n = HFP_HEADER_SIZE + HFP_RESULT_FIXED; break;
  }
  mk_send(m, b, n);
  free(b);
  return 0;
}

static int bad_result(cf_test *t, intptr_t how) {
  mock m = {0};
  m.on_frame = bad_result_handler;
  m.arg = how;
  if (how == RB_V1_SANITISED || how == RB_V1_OUT_OF_RANGE) m.ok.version = 1;
  CASE_BEGIN(t, &m, c, 2000);
  frame_bufs b;
  hfc_request r = request(&b, how == RB_NO_RGBA);
  uint32_t id;
  int rc = hfc_submit(c, &r, &id), v = 0;
  hfc_completion d;
  if (rc) v = cf_fail(t, "hfc_submit failed: %s", hfc_strerror(rc));
  if (!v) {
    rc = hfc_wait(c, -1, &d);
    int status = rc ? rc : d.status;
    if (status == 0) v = cf_fail(t, "a malformed RESULT was taken as a success");
    else if (how != RB_STATUS_99 && status != HFC_E_PROTOCOL)
      v = cf_fail(t, "a malformed RESULT: %s, wanted PROTOCOL", hfc_strerror(status));
  }
  if (!v && how != RB_STATUS_99) {
    /* The stream is lost: nothing after it may succeed. */
    rc = hfc_filter(c, &r, NULL);
    if (rc == 0) v = cf_fail(t, "after a malformed RESULT the connection still served");
  }
  return finish(t, &m, c, v);
}

/* Version 2 flags in a RESULT reach hfc_timing. */
static int v2_flags_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  size_t n;
  uint8_t *b = mk_result(m, h->request_id, p, h->length, &n);
  if (!b) return CF_FAIL;
  b[HFP_HEADER_SIZE + 3] |= (uint8_t)m->arg;
  mk_send(m, b, n);
  free(b);
  return 0;
}

static int v2_flags(cf_test *t, intptr_t bits) {
  mock m = {0};
  m.on_frame = v2_flags_handler;
  m.arg = bits;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  hfc_timing tm;
  int rc = hfc_filter(c, &r, &tm), v = 0;
  if (rc) v = cf_fail(t, "hfc_filter: %s", hfc_strerror(rc));
  else if (tm.input_sanitised != !!(bits & HFP_RESULT_INPUT_SANITISED) ||
           tm.out_of_range != !!(bits & HFP_RESULT_OUT_OF_RANGE))
    v = cf_fail(t, "RESULT flags 0x%02x: input_sanitised %d, out_of_range %d", (unsigned)bits,
                tm.input_sanitised, tm.out_of_range);
  return finish(t, &m, c, v);
}

/* A RESULT cut after every byte of its header and fixed part (and into the
 * tensor), then the close: the request fails CLOSED, never succeeds. */
static int cut_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  size_t n;
  uint8_t *b = mk_result(m, h->request_id, p, h->length, &n);
  if (!b) return CF_FAIL;
  mk_send(m, b, (size_t)m->arg < n ? (size_t)m->arg : n - 1);
  free(b);
  return 1;
}

static int result_cut(cf_test *t, intptr_t arg) {
  (void)arg;
  size_t total = HFP_HEADER_SIZE + HFP_RESULT_FIXED + W * H * 12;
  for (size_t k = 0; k < total; k += k < HFP_HEADER_SIZE + HFP_RESULT_FIXED ? 1 : 7) {
    mock m = {0};
    m.on_frame = cut_handler;
    m.arg = (intptr_t)k;
    CASE_BEGIN(t, &m, c, 2000);
    frame_bufs b;
    hfc_request r = request(&b, 0);
    int rc = hfc_filter(c, &r, NULL), v = 0;
    if (rc == 0) v = cf_fail(t, "a RESULT cut after %zu bytes was taken as a success", k);
    else if (rc != HFC_E_CLOSED)
      v = cf_fail(t, "a RESULT cut after %zu bytes: %s, wanted CLOSED", k, hfc_strerror(rc));
    CF_TRY(finish(t, &m, c, v));
  }
  return 0;
}

/* A server that stops in the middle of a RESULT, or never answers: the
 * request times out within the client's timeout, and the connection is
 * not used again. */
static int stall_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  size_t n;
  uint8_t *b = mk_result(m, h->request_id, p, h->length, &n);
  if (!b) return CF_FAIL;
  if (m->arg) mk_send(m, b, (size_t)m->arg);
  free(b);
  /* Then silence until the client leaves. */
  hfp_header h2;
  uint8_t *p2;
  while (mk_read(m, &h2, &p2) > 0) free(p2);
  return 1;
}

static int stall(cf_test *t, intptr_t where) {
  mock m = {0};
  m.on_frame = stall_handler;
  m.arg = where;
  CASE_BEGIN(t, &m, c, 300);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  double t0 = cf_now_ms();
  int rc = hfc_filter(c, &r, NULL), v = 0;
  double ms = cf_now_ms() - t0;
  if (rc != HFC_E_TIMEOUT) v = cf_fail(t, "a stalled server: hfc_filter returned %s", hfc_strerror(rc));
  else if (ms > 3000) v = cf_fail(t, "a 300 ms timeout took %.0f ms", ms);
  else if ((rc = hfc_filter(c, &r, NULL)) == 0)
    v = cf_fail(t, "after a timeout in the middle of a frame the connection still served");
  return finish(t, &m, c, v);
}

/* Part of a RESULT header, a pause longer than the client's timeout, then
 * the rest: the library either gives the connection up (the bytes it read
 * are gone) or keeps the partial frame and completes the request; it never
 * reads the rest as a new frame. */
static int late_rest_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  size_t n;
  uint8_t *b = mk_result(m, h->request_id, p, h->length, &n);
  if (!b) return CF_FAIL;
  mk_send(m, b, 9);
  cf_sleep_ms(600);
  mk_send(m, b + 9, n - 9);
  free(b);
  return 0;
}

static int late_rest(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = late_rest_handler;
  CASE_BEGIN(t, &m, c, 300);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  uint32_t id;
  int rc = hfc_submit(c, &r, &id), v = 0;
  hfc_completion d;
  memset(&d, 0, sizeof d);
  if (rc) v = cf_fail(t, "hfc_submit: %s", hfc_strerror(rc));
  if (!v) rc = hfc_wait(c, -1, &d);
  if (!v && rc == 0 && d.status == 0) v = check_values(t, id, b.out, NULL, &r);
  if (!v && (rc == HFC_E_TIMEOUT || (rc == 0 && d.status == HFC_E_TIMEOUT))) {
    /* Timed out inside a frame: kept whole, or given up. */
    cf_sleep_ms(700);
    int w = hfc_wait(c, -1, &d);
    if (w == 0 && d.status == 0) {
      v = check_values(t, id, b.out, NULL, &r);
    } else if (w == 0 || w == HFC_E_NOPENDING || w == HFC_E_TIMEOUT) {
      if (w == 0 && d.status == HFC_E_PROTOCOL)
        v = cf_fail(t, "after a timeout inside a RESULT header, the rest was read as a new frame");
      else if (hfc_submit(c, &r, NULL) == 0)
        v = cf_fail(t, "after a timeout inside a frame the connection was still used");
    } else if (w == HFC_E_PROTOCOL) {
      v = cf_fail(t, "after a timeout inside a RESULT header, the rest was read as a new frame");
    }
  } else if (!v && rc) {
    v = cf_fail(t, "hfc_wait: %s", hfc_strerror(rc));
  }
  return finish(t, &m, c, v);
}

/* Asynchronously: hfc_wait(0) on nothing yet is a timeout that keeps the
 * request pending; the server closing fails it with CLOSED. */
static int close_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_FILTER) return mk_reply(m, h, p);
  cf_sleep_ms(100);
  return 1;
}

static int server_closes(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = close_handler;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  uint32_t id;
  int rc = hfc_submit(c, &r, &id), v = 0;
  hfc_completion d;
  if (rc) v = cf_fail(t, "hfc_submit: %s", hfc_strerror(rc));
  if (!v && (rc = hfc_wait(c, 0, &d)) != HFC_E_TIMEOUT)
    v = cf_fail(t, "hfc_wait(0) with nothing back yet: %s, wanted TIMEOUT", hfc_strerror(rc));
  if (!v && hfc_pending(c) != 1) v = cf_fail(t, "the request is no longer pending after a poll");
  if (!v) {
    rc = hfc_wait(c, -1, &d);
    if (rc || d.id != id || d.status != HFC_E_CLOSED)
      v = cf_fail(t, "the server closed: hfc_wait %s, status %s", hfc_strerror(rc), hfc_strerror(d.status));
  }
  if (!v && (rc = hfc_wait(c, 0, &d)) != HFC_E_CLOSED)
    v = cf_fail(t, "after the close, hfc_wait with nothing pending: %s", hfc_strerror(rc));
  return finish(t, &m, c, v);
}

/* A server that answers a FILTER from its header and closes while the
 * client is still writing the frame (a fatal TOO_LARGE over
 * max_frame_bytes; a draining server's SHUTTING_DOWN, then the end of the
 * drain): the frame is larger than the socket's buffers, so the client's
 * write fails, and the answer waits on the socket. The request completes
 * with the server's code and message, not as a lost connection. */
static int closed_mid_frame_script(mock *m) {
  if (mk_accept(m) || mk_hello(m)) return CF_FAIL;
  uint8_t hb[HFP_HEADER_SIZE];
  hfp_header h;
  /* Control requests (the variants' list) answered as usual, up to the
   * FILTER, of which only the header is read. */
  for (;;) {
    ssize_t got = recv(m->fd, hb, sizeof hb, MSG_WAITALL);
    if (got != (ssize_t)sizeof hb || hfp_header_decode(hb, 1u << 30, &h))
      return mk_fail(m, "no FILTER header from the client");
    if (h.type == HFP_FILTER) break;
    uint8_t *p = malloc(h.length ? h.length : 1);
    if (!p || (h.length && recv(m->fd, p, h.length, MSG_WAITALL) != (ssize_t)h.length)) {
      free(p);
      return mk_fail(m, "the client's message of type %u was cut", h.type);
    }
    int rc = mk_reply(m, &h, p);
    free(p);
    if (rc) return rc;
  }
  uint8_t b[300];
  int code = (int)(m->arg & 0xffff), fatal = (int)(m->arg >> 16);
  mk_send(m, b, mk_error(b, h.request_id, code, fatal, "said the mock"));
  /* Closed with the rest of the frame unread. */
  close(m->fd);
  m->fd = -1;
  return 0;
}

static int closed_mid_frame(cf_test *t, intptr_t arg) {
  int code = (int)(arg & 0xffff);
  mock m = {0};
  m.script = closed_mid_frame_script;
  m.arg = arg;
  CASE_BEGIN(t, &m, c, 0);
  /* 256x256 at 2 spp in f32: 3 MiB, far over a socket's buffers. */
  enum { BW = 256, BH = 256 };
  size_t n = (size_t)BW * BH * MK_SPP * 6;
  float *in = calloc(n, sizeof *in), *out = malloc((size_t)BW * BH * 3 * sizeof *out);
  int v = 0;
  if (!in || !out) v = cf_fail(t, "out of memory");
  hfc_request r;
  hfc_request_init(&r);
  r.variant = MK_VARIANT;
  r.width = BW;
  r.height = BH;
  r.spp = MK_SPP;
  r.in_dtype = r.out_dtype = HFC_F32;
  r.features = in;
  r.features_bytes = n * sizeof *in;
  r.result = out;
  r.result_bytes = (size_t)BW * BH * 3 * sizeof *out;
  uint32_t id = 0;
  hfc_completion d;
  int rc = v ? 0 : hfc_submit(c, &r, &id);
  if (!v && rc) v = cf_fail(t, "hfc_submit: %s", hfc_strerror(rc));
  if (!v && (rc = hfc_wait(c, -1, &d)))
    v = cf_fail(t, "hfc_wait: %s", hfc_strerror(rc));
  if (!v && (d.id != id || d.status != -code))
    v = cf_fail(t, "the server answered %s and closed while the frame was being written: the "
                "request completed %s, wanted %s", hfp_code_name(code), hfc_strerror(d.status),
                hfc_strerror(-code));
  if (!v && !strstr(hfc_last_message(c), "said the mock"))
    v = cf_fail(t, "hfc_last_message is '%s', without the server's message", hfc_last_message(c));
  free(in);
  free(out);
  return finish(t, &m, c, v);
}

/* A RESULT arriving while a control reply is awaited is kept for hfc_wait. */
static int interleave_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  static uint8_t *held;
  static size_t held_n;
  if (h->type == HFP_FILTER) {
    held = mk_result(m, h->request_id, p, h->length, &held_n);
    return held ? 0 : CF_FAIL;
  }
  if (h->type == HFP_STATS && held) {
    mk_send(m, held, held_n);
    free(held);
    held = NULL;
  }
  return mk_reply(m, h, p);
}

static int interleaved(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = interleave_handler;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  uint32_t id;
  int rc = hfc_submit(c, &r, &id), v = 0;
  hfc_stats *st = calloc(1, sizeof *st);
  if (!rc) rc = st ? hfc_get_stats(c, st) : HFC_E_NOMEM;
  if (rc) v = cf_fail(t, "hfc_get_stats with a RESULT arriving first: %s", hfc_strerror(rc));
  hfc_completion d;
  if (!v && (hfc_wait(c, 0, &d) || d.id != id || d.status))
    v = cf_fail(t, "the RESULT that came before STATS_REPLY was not kept");
  if (!v) v = check_values(t, id, b.out, NULL, &r);
  free(st);
  return finish(t, &m, c, v);
}

/* A non-fatal ERROR with id 0 that answers nothing pending (as for a
 * SHM_DESTROY of an unknown segment): kept as the message, nothing fails. */
static int stray_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type == HFP_FILTER && m->seen[HFP_FILTER] == 1) {
    uint8_t b[300];
    mk_send(m, b, mk_error(b, 0, HFP_E_INVALID, 0, "no segment 9 on this connection"));
  }
  return mk_reply(m, h, p);
}

static int stray_error(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = stray_handler;
  CASE_BEGIN(t, &m, c, 0);
  frame_bufs b;
  hfc_request r = request(&b, 0);
  int rc = hfc_filter(c, &r, NULL), v = 0;
  if (rc) v = cf_fail(t, "a FILTER after a stray non-fatal ERROR (id 0) failed: %s", hfc_strerror(rc));
  if (!v && (rc = hfc_filter(c, &r, NULL)) != 0) v = cf_fail(t, "the next one failed: %s", hfc_strerror(rc));
  return finish(t, &m, c, v);
}

/* ---- control replies ---------------------------------------------------------------- */

static int variants(cf_test *t, intptr_t version) {
  mock m = {0};
  m.ok.version = (uint16_t)version;
  CASE_BEGIN(t, &m, c, 0);
  hfc_variant v[4];
  const int room = version >= 3 ? 2 : 1;
  int n = 0, rc = hfc_list_variants(c, v, room, &n), res = 0;
  if (rc) res = cf_fail(t, "hfc_list_variants: %s", hfc_strerror(rc));
  else if (n != 2) res = cf_fail(t, "%d variants, the mock has 2 (with room for %d)", n, room);
  else if (strcmp(v[0].name, MK_VARIANT) || v[0].spp != MK_SPP || v[0].num_levels != 2 || v[0].levels[1] != 16)
    res = cf_fail(t, "the first variant is not the mock's");
  else if (version == 1 && v[0].range_mask)
    res = cf_fail(t, "a version-1 VARIANTS gave a range mask 0x%x", v[0].range_mask);
  else if (version == 2 && (v[0].range_mask != 0x11 || v[0].range_lo[0] != 0.25 ||
                            v[0].range_hi[4] != 2048))
    res = cf_fail(t, "the version-2 ranges read as mask 0x%x, [%g, %g]", v[0].range_mask,
                  v[0].range_lo[0], v[0].range_hi[4]);
  else if (v[0].estimate)
    res = cf_fail(t, "variant %s reads no estimate, yet hfc_variant.estimate is 1", v[0].name);
  else if (version >= 3 && !v[1].estimate)
    res = cf_fail(t, "a version-3 VARIANTS said variant %s reads the estimate; "
                     "hfc_variant.estimate is 0", v[1].name);
  return finish(t, &m, c, res);
}

/* A statistic number the library does not know is skipped. */
static int unknown_stat_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_LIST_VARIANTS) return mk_reply(m, h, p);
  hfp_variant v;
  memset(&v, 0, sizeof v);
  snprintf(v.name, sizeof v.name, MK_VARIANT);
  snprintf(v.backend, sizeof v.backend, "cpu");
  snprintf(v.precision, sizeof v.precision, "fp16");
  v.spp = MK_SPP;
  v.num_levels = 1;
  v.levels[0] = 4;
  v.num_ranges = 2;
  v.ranges[0].stat = 200;
  v.ranges[0].lo = 1, v.ranges[0].hi = 2;
  v.ranges[1].stat = 1;
  v.ranges[1].lo = 0.5, v.ranges[1].hi = 0.75;
  uint8_t b[256];
  int n = hfp_encode_variants_v(b, sizeof b, &v, 1, 2);
  if (n < 0) return mk_fail(m, "mock: cannot encode");
  mk_send(m, b, (size_t)n);
  return 0;
}

static int unknown_stat(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = unknown_stat_handler;
  CASE_BEGIN(t, &m, c, 0);
  hfc_variant v;
  int n = 0, rc = hfc_list_variants(c, &v, 1, &n), res = 0;
  if (rc) res = cf_fail(t, "a range of an unknown statistic: %s", hfc_strerror(rc));
  else if (v.range_mask != 0x2 || v.range_lo[1] != 0.5) res = cf_fail(t, "range mask 0x%x", v.range_mask);
  return finish(t, &m, c, res);
}

enum { SV_V1 = 1, SV_V2 = 2, SV_MORE_COUNTERS, SV_ZERO_COUNTERS, SV_BUCKETS_23, SV_VARIANTS_65 };

static int stats_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_STATS) return mk_reply(m, h, p);
  size_t n;
  /* Version 1, 2, or this codec's newest, whose counters are
   * HFP_STATS_COUNTERS. */
  uint8_t *b = mk_stats(m, m->arg == SV_V1 ? 1 : m->arg == SV_V2 ? 2 : HFP_VERSION, &n);
  if (!b) return CF_FAIL;
  uint8_t *q = b + HFP_HEADER_SIZE;
  switch (m->arg) {
    case SV_MORE_COUNTERS: {
      /* The known counters, then one more (a later version's). */
      uint8_t *tail = b + n - 2 - 8 * HFP_STATS_COUNTERS;
      hfp_put_u16(tail, HFP_STATS_COUNTERS + 1);
      memset(b + n, 0x11, 8);
      n += 8;
      cf_set_length(b, (uint32_t)(n - HFP_HEADER_SIZE));
      break;
    }
    case SV_ZERO_COUNTERS: hfp_put_u16(b + n - 2 - 8 * HFP_STATS_COUNTERS, 0); break;
    case SV_BUCKETS_23: hfp_put_u16(q + 38, 23); break;
    case SV_VARIANTS_65: hfp_put_u16(q + 36, 65); break;
  }
  mk_send(m, b, n);
  free(b);
  return 0;
}

static int stats(cf_test *t, intptr_t how) {
  mock m = {0};
  m.on_frame = stats_handler;
  m.arg = how;
  m.ok.version = how == SV_V1 ? 1 : 2;
  CASE_BEGIN(t, &m, c, 2000);
  hfc_stats *st = calloc(1, sizeof *st);
  int rc = st ? hfc_get_stats(c, st) : HFC_E_NOMEM, v = 0;
  if (how == SV_ZERO_COUNTERS || how == SV_BUCKETS_23 || how == SV_VARIANTS_65) {
    if (rc != HFC_E_PROTOCOL) v = cf_fail(t, "a malformed STATS_REPLY: %s, wanted PROTOCOL", hfc_strerror(rc));
  } else if (rc) {
    v = cf_fail(t, "hfc_get_stats: %s", hfc_strerror(rc));
  } else if (st->num_variants != 1 || st->variants[0].requests_ok != 5 || st->uptime_us != 123456 ||
             st->variants[0].hist_total[3] != 5) {
    v = cf_fail(t, "STATS_REPLY read wrong");
  } else if (how == SV_V1 && (st->variants[0].out_of_range || st->variants[0].frames_sanitised)) {
    v = cf_fail(t, "a version-1 STATS_REPLY gave counters");
  } else if (how != SV_V1 && (st->variants[0].out_of_range != 2 || st->variants[0].frames_sanitised != 1)) {
    v = cf_fail(t, "the version-2 counters read %llu and %llu, sent 2 and 1",
                (unsigned long long)st->variants[0].out_of_range,
                (unsigned long long)st->variants[0].frames_sanitised);
  }
  free(st);
  return finish(t, &m, c, v);
}

/* A control request answered by a non-fatal ERROR (id 0): that call fails
 * with its code, the connection goes on. */
static int control_error_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type == HFP_LIST_VARIANTS && m->seen[HFP_LIST_VARIANTS] == 1) {
    uint8_t b[300];
    mk_send(m, b, mk_error(b, 0, HFP_E_INTERNAL, 0, "cannot encode VARIANTS"));
    return 0;
  }
  return mk_reply(m, h, p);
}

static int control_error(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  m.on_frame = control_error_handler;
  CASE_BEGIN(t, &m, c, 0);
  hfc_variant v[2];
  int n, rc = hfc_list_variants(c, v, 2, &n), res = 0;
  if (rc != HFC_E_INTERNAL) res = cf_fail(t, "LIST_VARIANTS answered by ERROR INTERNAL: %s", hfc_strerror(rc));
  if (!res && (rc = hfc_list_variants(c, v, 2, &n)) != 0)
    res = cf_fail(t, "the next LIST_VARIANTS failed: %s", hfc_strerror(rc));
  return finish(t, &m, c, res);
}

/* Text the protocol does not allow, in an ERROR message or a name. */
static int bad_text_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (m->arg == 0 && h->type == HFP_FILTER) {
    uint8_t b[300];
    size_t n = mk_error(b, h->request_id, HFP_E_INVALID, 0, "bad \x1b[31m text");
    mk_send(m, b, n);
    return 0;
  }
  if (m->arg == 1 && h->type == HFP_LIST_VARIANTS) {
    size_t n;
    uint8_t *b = mk_variants(m, m->ok.version, &n);
    if (!b) return CF_FAIL;
    b[HFP_HEADER_SIZE + 3] = ' ';   /* inside the first name */
    mk_send(m, b, n);
    free(b);
    return 0;
  }
  if (m->arg == 2 && h->type == HFP_FILTER) {
    uint8_t b[600];
    size_t n = mk_error(b, h->request_id, HFP_E_INVALID, 0, "x");
    hfp_put_u16(b + 22, 257);       /* message_len over 256 */
    memset(b + 24, 'a', 257);
    cf_set_length(b, 8 + 257);
    n = 24 + 257;
    mk_send(m, b, n);
    return 0;
  }
  return mk_reply(m, h, p);
}

static int bad_text(cf_test *t, intptr_t which) {
  mock m = {0};
  m.on_frame = bad_text_handler;
  m.arg = which;
  CASE_BEGIN(t, &m, c, 2000);
  int rc, res = 0;
  if (which == 1) {
    hfc_variant v[2];
    int n;
    rc = hfc_list_variants(c, v, 2, &n);
  } else {
    frame_bufs b;
    hfc_request r = request(&b, 0);
    rc = hfc_filter(c, &r, NULL);
  }
  if (rc != HFC_E_PROTOCOL) res = cf_fail(t, "a reply with text out of the rules: %s, wanted PROTOCOL", hfc_strerror(rc));
  return finish(t, &m, c, res);
}

/* ---- shared memory ----------------------------------------------------------------- */

static int shm_filter(cf_test *t, intptr_t composite) {
  mock m = {0};
  m.ok.server_flags = HFP_SERVER_SHM;
  CASE_BEGIN(t, &m, c, 0);
  uint8_t *mem = NULL;
  size_t in = (size_t)W * H * MK_SPP * 6 * 4, out = (size_t)W * H * 12, rgba = (size_t)W * H * 16;
  int rc = hfc_shm_alloc(c, in + out + rgba, (void **)&mem), v = 0;
  if (rc) return finish(t, &m, c, cf_fail(t, "hfc_shm_alloc: %s", hfc_strerror(rc)));
  frame_bufs b;
  hfc_request r = request(&b, (int)composite);
  memcpy(mem, b.in, in);
  r.features = mem;
  r.features_bytes = in;
  r.result = mem + in;
  r.result_bytes = out;
  r.rgba = composite ? mem + in + out : NULL;
  r.rgba_bytes = composite ? rgba : 0;
  hfc_timing tm;
  rc = hfc_filter(c, &r, &tm);
  if (rc) v = cf_fail(t, "a FILTER in the segment: %s", hfc_strerror(rc));
  else if (!tm.via_shm) v = cf_fail(t, "the frame did not go by reference");
  else if (m.seen[HFP_FILTER] != 1) v = cf_fail(t, "the mock saw %d FILTERs", m.seen[HFP_FILTER]);
  else v = check_values(t, m.ids[0], (float *)(mem + in), composite ? (float *)(mem + in + out) : NULL, &r);
  if (!v && (rc = hfc_shm_free(c, mem)) != 0) v = cf_fail(t, "hfc_shm_free: %s", hfc_strerror(rc));
  /* The SHM_DESTROY is on its way; a LIST_VARIANTS after it shows it was read. */
  hfc_variant vv[2];
  int n;
  if (!v && (rc = hfc_list_variants(c, vv, 2, &n)) != 0) v = cf_fail(t, "after hfc_shm_free: %s", hfc_strerror(rc));
  if (!v && m.seen[HFP_SHM_DESTROY] != 1) v = cf_fail(t, "hfc_shm_free sent no SHM_DESTROY");
  return finish(t, &m, c, v);
}

enum { SC_NO_FD, SC_SIZE, SC_BUSY, SC_TOO_LARGE, SC_UNSUPPORTED };

static int shm_create_handler(mock *m, const hfp_header *h, const uint8_t *p) {
  if (h->type != HFP_SHM_CREATE) return mk_reply(m, h, p);
  uint64_t bytes = 0;
  hfp_decode_shm_create(p, h->length, &bytes);
  uint8_t b[300];
  switch (m->arg) {
    case SC_NO_FD: {
      int n = hfp_encode_shm_created(b, sizeof b, 1, bytes);
      mk_send(m, b, (size_t)n);
      return 0;
    }
    case SC_SIZE: {
      int fd = memfd_create("mock", MFD_CLOEXEC);
      if (fd < 0 || ftruncate(fd, (off_t)bytes)) return mk_fail(m, "memfd");
      int n = hfp_encode_shm_created(b, sizeof b, 1, bytes + 4096);
      mk_send_fd(m, b, (size_t)n, fd);
      close(fd);
      return 0;
    }
    case SC_BUSY: mk_send(m, b, mk_error(b, 0, HFP_E_BUSY, 0, "budget spent")); return 0;
    case SC_TOO_LARGE: mk_send(m, b, mk_error(b, 0, HFP_E_TOO_LARGE, 0, "over the budget")); return 0;
    case SC_UNSUPPORTED: mk_send(m, b, mk_error(b, 0, HFP_E_UNSUPPORTED, 0, "no shared memory")); return 0;
  }
  return 0;
}

static int shm_create(cf_test *t, intptr_t how) {
  mock m = {0};
  m.ok.server_flags = HFP_SERVER_SHM;
  m.on_frame = shm_create_handler;
  m.arg = how;
  CASE_BEGIN(t, &m, c, 2000);
  void *mem = NULL;
  int rc = hfc_shm_alloc(c, 65536, &mem), v = 0;
  int want = how == SC_BUSY ? HFC_E_BUSY : how == SC_TOO_LARGE ? HFC_E_TOO_LARGE
           : how == SC_UNSUPPORTED ? HFC_E_UNSUPPORTED : HFC_E_PROTOCOL;
  if (rc != want) v = cf_fail(t, "hfc_shm_alloc: %s, wanted %s", hfc_strerror(rc), hfc_strerror(want));
  else if (mem) v = cf_fail(t, "a failed hfc_shm_alloc gave memory");
  if (!v && want != HFC_E_PROTOCOL) {
    hfc_variant vv[2];
    int n;
    if ((rc = hfc_list_variants(c, vv, 2, &n)) != 0)
      v = cf_fail(t, "after a refused segment the connection does not serve: %s", hfc_strerror(rc));
  }
  return finish(t, &m, c, v);
}

/* Without HELLO_OK bit 1 the library does not ask. */
static int shm_not_offered(cf_test *t, intptr_t arg) {
  (void)arg;
  mock m = {0};
  CASE_BEGIN(t, &m, c, 0);
  void *mem = NULL;
  int rc = hfc_shm_alloc(c, 4096, &mem), v = 0;
  if (rc != HFC_E_UNSUPPORTED) v = cf_fail(t, "hfc_shm_alloc without bit 1: %s", hfc_strerror(rc));
  hfc_variant vv[2];
  int n;
  if (!v && (rc = hfc_list_variants(c, vv, 2, &n)) != 0) v = cf_fail(t, "LIST_VARIANTS: %s", hfc_strerror(rc));
  if (!v && m.seen[HFP_SHM_CREATE]) v = cf_fail(t, "SHM_CREATE was sent although not offered");
  return finish(t, &m, c, v);
}

/* ---- the table ------------------------------------------------------------------------ */

#define HO(how, name, rule) {"client.hello_ok." name, rule, 0, bad_hello_ok, how}
#define HE(code, name) {"client.hello_error." name, "an ERROR instead of HELLO_OK: hfc_connect returns its code", 0, hello_error, code}
#define EC(code, name) {"client.error." name, "an ERROR for a FILTER: the request fails with its code and message, the connection goes on", 0, error_code, code}
#define RB(how, name, rule) {"client.bad_result." name, rule, 0, bad_result, how}

const cf_case cf_cases_client[] = {
  {"client.hello.offer", "the client offers versions 1..3, its name and its token", 0, hello_offer, 0},
  {"client.hello.info_v1", "hfc_info reports HELLO_OK's fields (a version-1 server)", 0, hello_info, 0},
  {"client.hello.info_flags", "server_flags bit 0 and 1 reach hfc_info", 0, hello_info, 3},
  HO(HO_VERSION_OVER, "version_not_offered", "HELLO_OK with a version not offered: VERSION"),
  HO(HO_VERSION_0, "version_zero", "HELLO_OK with version 0: VERSION"),
  HO(HO_INFLIGHT_0, "max_inflight_zero", "HELLO_OK max_inflight must be >= 1: PROTOCOL"),
  HO(HO_SPP_0, "max_spp_zero", "HELLO_OK max_spp is 1..16: PROTOCOL"),
  HO(HO_SPP_17, "max_spp_17", "HELLO_OK max_spp is 1..16: PROTOCOL"),
  HO(HO_DTYPES_0, "dtypes_none", "HELLO_OK dtypes offers at least one: PROTOCOL"),
  HO(HO_DTYPES_4, "dtypes_unknown_bit", "HELLO_OK dtypes has no other bits: PROTOCOL"),
  HO(HO_WIDTH_0, "max_width_zero", "HELLO_OK max_width is 1..65535: PROTOCOL"),
  HO(HO_HEIGHT_65536, "max_height_65536", "HELLO_OK max_height is 1..65535: PROTOCOL"),
  HO(HO_BATCH_0, "max_batch_zero", "HELLO_OK max_batch must be >= 1: PROTOCOL"),
  HO(HO_NAME_0, "name_empty", "HELLO_OK name_len is 1..64: PROTOCOL"),
  HO(HO_NAME_SPACE, "name_space", "names are bytes 0x21..0x7E: PROTOCOL"),
  HO(HO_TRAILING, "trailing_byte", "a payload with trailing bytes: PROTOCOL"),
  HO(HO_MISSING, "missing_byte", "a payload with missing bytes: PROTOCOL"),
  HO(HO_FLAGS, "header_flags", "header flags must be 0: PROTOCOL"),
  HO(HO_MAGIC, "bad_magic", "a bad magic: PROTOCOL"),
  HO(HO_WRONG_TYPE, "other_reply", "a reply of another type instead of HELLO_OK: PROTOCOL"),
  HO(HO_REQUEST_TYPE, "request_type", "a client-to-server type from the server: PROTOCOL"),
  HO(HO_TYPE_13, "unknown_type", "an unknown type: PROTOCOL"),
  HE(HFP_E_VERSION, "version"),
  HE(HFP_E_UNAUTHORIZED, "unauthorized"),
  HE(HFP_E_BUSY, "busy"),
  HE(HFP_E_PROTOCOL, "protocol"),
  {"client.hello.cut", "HELLO_OK cut at any byte, then the close: CLOSED, never a success", 0, hello_cut, 0},
  {"client.hello.silent", "a server that never answers HELLO: TIMEOUT within the client's timeout", 0, hello_silent, 0},
  {"client.hello.closed", "a server that closes at once: CLOSED", 0, hello_closed, 0},
  {"client.filter.result", "a RESULT lands in the caller's buffer with RESULT's timing", 0, filter_ok, 0},
  {"client.filter.composite", "a RESULT with rgba lands in both buffers", 0, filter_ok, 1},
  {"client.filter.v1_server", "against a version-1 server, results as in version 1", 0, filter_ok, 2},
  {"client.filter.wire", "the FILTER sent carries the request's fields and its features untouched", 0, filter_wire, 0},
  {"client.filter.f16", "f16 results land as binary16", 0, filter_f16, 0},
  {"client.filter.out_of_order", "RESULTs in any order complete their own requests", 0, out_of_order, 4},
  {"client.filter.out_of_order_8", "RESULTs in reverse order, eight in flight", 0, out_of_order, 8},
  {"client.filter.ids", "FILTER ids are never 0 and never one in flight", 0, ids_unique, 0},
  {"client.filter.inflight_limit", "no more than max_inflight pending: the next submit is INFLIGHT", 0, inflight_local, 0},
  {"client.filter.interleaved_control", "a RESULT arriving while STATS is awaited is kept", 0, interleaved, 0},
  {"client.filter.stray_error", "a non-fatal ERROR with id 0 that answers nothing fails nothing", 0, stray_error, 0},
  EC(HFP_E_UNKNOWN_VARIANT, "unknown_variant"),
  EC(HFP_E_TOO_LARGE, "too_large"),
  EC(HFP_E_LENGTH, "length"),
  EC(HFP_E_BUSY, "busy"),
  EC(HFP_E_INTERNAL, "internal"),
  EC(HFP_E_UNSUPPORTED, "unsupported"),
  EC(HFP_E_SHUTTING_DOWN, "shutting_down"),
  EC(HFP_E_INVALID, "invalid"),
  EC(99, "unknown_code"),
  EC(HFP_E_PROTOCOL | 1 << 16, "fatal_protocol"),
  EC(HFP_E_TOO_LARGE | 1 << 16, "fatal_too_large"),
  {"client.result_status.internal", "RESULT status INTERNAL: the request fails INTERNAL", 0, result_status, HFP_E_INTERNAL},
  {"client.result_status.shutting_down", "RESULT status SHUTTING_DOWN: the request fails SHUTTING_DOWN", 0, result_status, HFP_E_SHUTTING_DOWN},
  {"client.result_status.expired", "RESULT status EXPIRED (version 4): the request fails EXPIRED, the connection serves on", 0, result_status, HFP_E_EXPIRED},
  {"client.cancel.wire", "hfc_cancel sends CANCEL with the FILTER's id; RESULT CANCELLED completes it HFC_E_CANCELLED", 0, cancel_wire, 4},
  {"client.cancel.v3_server", "hfc_cancel against a version-3 server: UNSUPPORTED, nothing sent, the frame served", 0, cancel_wire, 3},
  {"client.deadline.wire", "deadline_us goes out as FILTER flag DEADLINE and its budget to a version-4 server", 0, deadline_wire, 4},
  {"client.deadline.v3_server", "to a version-3 server a frame with deadline_us goes without the flag, and is served", 0, deadline_wire, 3},
  {"client.result_status.busy", "RESULT status BUSY (pushed out of a full queue): the request fails BUSY", 0, result_status, HFP_E_BUSY},
  {"client.result_status.with_tensor", "a RESULT with status and a tensor is malformed: PROTOCOL", 0, result_status, HFP_E_INTERNAL | 1 << 8},
  RB(RB_UNKNOWN_ID, "unknown_id", "a RESULT for an id not in flight: PROTOCOL"),
  RB(RB_WIDTH, "width", "a RESULT whose size is not the request's: PROTOCOL"),
  RB(RB_HEIGHT, "height", "a RESULT whose size is not the request's: PROTOCOL"),
  RB(RB_DTYPE, "dtype", "a RESULT in another dtype: PROTOCOL"),
  RB(RB_NO_RGBA, "missing_rgba", "no rgba when COMPOSITE was asked: PROTOCOL"),
  RB(RB_EXTRA_RGBA, "unasked_rgba", "rgba when COMPOSITE was not asked: PROTOCOL"),
  RB(RB_SHM_UNASKED, "unasked_shm", "flag bit 1 for a frame sent through the socket: PROTOCOL"),
  RB(RB_SHORT, "length_short", "a RESULT one byte short: PROTOCOL"),
  RB(RB_LONG, "length_long", "a RESULT one byte long: PROTOCOL"),
  RB(RB_BATCH0, "batch_zero", "batch 0 with status 0: PROTOCOL"),
  RB(RB_FLAG_BIT4, "unknown_flag", "an unknown RESULT flag: PROTOCOL"),
  RB(RB_V1_SANITISED, "v1_sanitised_flag", "flag bit 2 on a version-1 connection: PROTOCOL"),
  RB(RB_V1_OUT_OF_RANGE, "v1_out_of_range_flag", "flag bit 3 on a version-1 connection: PROTOCOL"),
  RB(RB_MAGIC, "bad_magic", "a bad magic in place of a RESULT: PROTOCOL"),
  RB(RB_HEADER_FLAGS, "header_flags", "header flags set: PROTOCOL"),
  RB(RB_TYPE_13, "unknown_type", "an unknown type: PROTOCOL"),
  RB(RB_CLIENT_TYPE, "request_type", "a FILTER from the server: PROTOCOL"),
  RB(RB_HUGE_CONTROL, "huge_control", "a control frame announcing 4 GiB: PROTOCOL, nothing allocated"),
  RB(RB_STATUS_99, "unknown_status", "a RESULT status this library does not know: a failure, never OK"),
  {"client.v2_flags.sanitised", "RESULT flag bit 2 (version 2) sets input_sanitised", 0, v2_flags, HFP_RESULT_INPUT_SANITISED},
  {"client.v2_flags.out_of_range", "RESULT flag bit 3 (version 2) sets out_of_range", 0, v2_flags, HFP_RESULT_OUT_OF_RANGE},
  {"client.v2_flags.both", "RESULT flags 2 and 3 together", 0, v2_flags, HFP_RESULT_INPUT_SANITISED | HFP_RESULT_OUT_OF_RANGE},
  {"client.truncated.result", "a RESULT cut at any byte, then the close: CLOSED, never a success", 0, result_cut, 0},
  {"client.stall.before_reply", "a server that never answers a FILTER: TIMEOUT", 0, stall, 0},
  {"client.stall.mid_header", "a server that stops inside a RESULT header: TIMEOUT, the connection given up", 0, stall, 9},
  {"client.stall.mid_result", "a server that stops inside a RESULT: TIMEOUT, the connection given up", 0, stall, HFP_HEADER_SIZE + HFP_RESULT_FIXED + 20},
  {"client.stall.mid_header_async", "a timeout inside a frame gives the connection up or keeps the frame; never misreads the rest", 0, late_rest, 0},
  {"client.server_closes", "a pending request fails CLOSED when the server closes; polling does not fail it", 0, server_closes, 0},
  {"client.closed_mid_frame.shutting_down", "a server that refuses a frame SHUTTING_DOWN and closes while the client still writes it: the request fails SHUTTING_DOWN, not CLOSED", 0, closed_mid_frame, HFP_E_SHUTTING_DOWN},
  {"client.closed_mid_frame.too_large", "a fatal TOO_LARGE for a frame still being written, then the close: the request fails TOO_LARGE with the server's message", 0, closed_mid_frame, HFP_E_TOO_LARGE | 1 << 16},
  {"client.variants.v1", "a version-1 VARIANTS: no ranges", 0, variants, 1},
  {"client.variants.v2", "a version-2 VARIANTS: each variant's ranges", 0, variants, 2},
  {"client.variants.v3", "a version-3 VARIANTS: the estimate each variant reads", 0, variants, 3},
  {"client.variants.unknown_statistic", "a range of a statistic the library does not know is skipped", 0, unknown_stat, 0},
  {"client.variants.error", "LIST_VARIANTS answered by a non-fatal ERROR: that call fails, the connection goes on", 0, control_error, 0},
  {"client.stats.v1", "a version-1 STATS_REPLY: the extra counters are 0", 0, stats, SV_V1},
  {"client.stats.v2", "a version-2 STATS_REPLY: out_of_range and frames_sanitised", 0, stats, SV_V2},
  {"client.stats.more_counters", "counters a later version appends are skipped", 0, stats, SV_MORE_COUNTERS},
  {"client.stats.zero_counters", "counters 0 is out of 1..64: PROTOCOL", 0, stats, SV_ZERO_COUNTERS},
  {"client.stats.buckets_23", "hist_buckets other than 24: PROTOCOL", 0, stats, SV_BUCKETS_23},
  {"client.stats.variants_65", "more than 64 variants: PROTOCOL", 0, stats, SV_VARIANTS_65},
  {"client.text.error_message", "an ERROR message with a control byte: PROTOCOL", 0, bad_text, 0},
  {"client.text.variant_name", "a variant name with a space: PROTOCOL", 0, bad_text, 1},
  {"client.text.message_257", "an ERROR message over 256 bytes: PROTOCOL", 0, bad_text, 2},
  {"client.shm.filter", "frames in a segment go by reference; results read in place; free sends SHM_DESTROY", 0, shm_filter, 0},
  {"client.shm.filter_composite", "the same with a composite region", 0, shm_filter, 1},
  {"client.shm.no_descriptor", "SHM_CREATED without a descriptor: PROTOCOL", 0, shm_create, SC_NO_FD},
  {"client.shm.size_mismatch", "SHM_CREATED of another size: PROTOCOL", 0, shm_create, SC_SIZE},
  {"client.shm.busy", "SHM_CREATE refused BUSY: that call fails BUSY, the connection goes on", 0, shm_create, SC_BUSY},
  {"client.shm.too_large", "SHM_CREATE refused TOO_LARGE", 0, shm_create, SC_TOO_LARGE},
  {"client.shm.unsupported", "SHM_CREATE refused UNSUPPORTED", 0, shm_create, SC_UNSUPPORTED},
  {"client.shm.not_offered", "without HELLO_OK bit 1 no SHM_CREATE is sent", 0, shm_not_offered, 0},
  {NULL, NULL, 0, NULL, 0},
};
