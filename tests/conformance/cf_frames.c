/*
 * Frames the cases send and the checks on what comes back: FILTERs built
 * field by field (so a case can break exactly one field), RESULTs checked
 * against every rule PROTOCOL.md and FEATURES.md give for them, shared
 * segments, and the ordinary client of the health check.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cf_internal.h"
#include <hairfilter/hairfilter.h>
#include "hfcore.h"

/* ---- FILTER ----------------------------------------------------------------- */

void cf_filter_defaults(const cf_test *t, cf_filter *f) {
  const cf_server *s = t->srv;
  if (!f->variant) f->variant = s->variants[s->probe].name;
  if (!f->width) f->width = (uint32_t)s->pw;
  if (!f->height) f->height = (uint32_t)s->ph;
  if (!f->spp) {
    f->spp = 1;
    for (int i = 0; i < s->nv; i++)
      if (!strcmp(s->variants[i].name, f->variant)) f->spp = s->variants[i].spp;
  }
  /* A variant that reads the estimate (version 3) gets it after the
   * features. */
  for (int i = 0; i < s->nv; i++)
    if (!strcmp(s->variants[i].name, f->variant) && s->variants[i].estimate)
      f->flags |= HFP_FILTER_ESTIMATE;
  static const float hair[3] = {0.55f, 0.35f, 0.2f}, light[3] = {1.0f, 0.95f, 0.9f},
                     bg[3] = {0.1f, 0.15f, 0.25f};
  if (!f->hair[0] && !f->hair[1] && !f->hair[2]) memcpy(f->hair, hair, sizeof hair);
  if (!f->light[0] && !f->light[1] && !f->light[2]) memcpy(f->light, light, sizeof light);
  if (!f->bg[0] && !f->bg[1] && !f->bg[2]) memcpy(f->bg, bg, sizeof bg);
}

uint64_t cf_features_bytes(const cf_filter *f) {
  uint64_t n = 0;
  if (hfp_filter_input_bytes(f->width, f->height, (uint32_t)f->spp, f->in_dtype, f->flags, &n))
    return 0;
  return n;
}

/* One sample's six features (FEATURES.md order: color, highlight, alpha,
 * depth, tangent.x, tangent.y) for kind at sample index i. */
static void sample(const cf_filter *f, uint64_t i, uint32_t *x, float s[6]) {
  for (int k = 0; k < 6; k++) {
    *x = *x * 1664525u + 1013904223u;
    float u = (float)(*x >> 8) / 16777216.0f;
    s[k] = k >= 4 ? 2.0f * u - 1.0f : u;
  }
  /* About half the samples uncovered, as on a frame's edges. */
  if (s[2] < 0.45f) memset(s, 0, 6 * sizeof(float));
  switch (f->features) {
    case CF_FEAT_NAN:
      if (i % 7 == 3) s[i % 6] = NAN;
      if (i % 11 == 5) s[(i + 1) % 6] = INFINITY;
      break;
    case CF_FEAT_HUGE:
      for (int k = 0; k < 6; k++) s[k] = (i + (uint64_t)k) % 2 ? 3e38f : 1e6f;
      break;
    case CF_FEAT_NEGATIVE:
      for (int k = 0; k < 6; k++) s[k] = -1e4f * (float)(k + 1);
      break;
    case CF_FEAT_COVERED:
      s[0] = 0.8f, s[1] = 0.1f, s[2] = f->alpha, s[3] = 0.5f, s[4] = 0.6f, s[5] = -0.8f;
      break;
  }
}

/* One value of dtype at d; returns the byte after it. d may sit anywhere in
 * a frame (after a variant name of any length), so values are copied in,
 * never stored through a float or uint16_t pointer. */
static uint8_t *put_value(uint8_t *d, float v, int dtype) {
  if (dtype == HFP_F16) {
    uint16_t h = hf_f32_to_f16(v);
    memcpy(d, &h, sizeof h);
    return d + sizeof h;
  }
  memcpy(d, &v, sizeof v);
  return d + sizeof v;
}

void cf_fill_features(const cf_filter *f, void *dst) {
  uint64_t samples = (uint64_t)f->width * f->height * (uint64_t)f->spp;
  uint32_t x = f->seed * 2654435761u + 12345u;
  uint8_t *d = dst;
  for (uint64_t i = 0; i < samples; i++) {
    float s[6];
    sample(f, i, &x, s);
    for (int k = 0; k < 6; k++) d = put_value(d, s[k], f->in_dtype);
  }
  /* With ESTIMATE, the estimate follows (FEATURES.md, "The alpha-corrected
   * estimate"): colour, highlight, alpha of each pixel, a sixth without
   * hair (all 0). */
  uint64_t pixels = (uint64_t)f->width * f->height;
  for (uint64_t p = 0; (f->flags & HFP_FILTER_ESTIMATE) && p < pixels; p++) {
    float s[6];
    sample(f, p, &x, s);
    float e[3] = {s[0], s[1], s[2]};
    if (p % 6 == 1) e[0] = e[1] = e[2] = 0;
    else if (e[2] <= 0) e[2] = 0.5f;
    for (int k = 0; k < 3; k++) d = put_value(d, e[k], f->in_dtype);
  }
}

uint8_t *cf_filter_frame(cf_test *t, const cf_filter *f, size_t *len) {
  size_t vn = strlen(f->variant);
  uint64_t data = (f->flags & HFP_FILTER_SHM) ? HFP_SHM_REF_SIZE : cf_features_bytes(f);
  size_t extra = (f->flags & HFP_FILTER_DEADLINE) ? HFP_DEADLINE_SIZE : 0;
  size_t n = HFP_HEADER_SIZE + HFP_FILTER_FIXED + vn + extra + (size_t)data;
  uint8_t *b = cf_alloc(t, n);
  if (!b) return NULL;
  cf_header(b, HFP_FILTER, 0, f->id, (uint32_t)(n - HFP_HEADER_SIZE));
  hfp_put_u16(b + CF_FILTER_VLEN, (uint16_t)vn);
  hfp_put_u16(b + CF_FILTER_FLAGS, f->flags);
  hfp_put_u32(b + CF_FILTER_WIDTH, f->width);
  hfp_put_u32(b + CF_FILTER_HEIGHT, f->height);
  hfp_put_u16(b + CF_FILTER_SPP, (uint16_t)f->spp);
  b[CF_FILTER_IN_DTYPE] = (uint8_t)f->in_dtype;
  b[CF_FILTER_OUT_DTYPE] = (uint8_t)f->out_dtype;
  memcpy(b + CF_FILTER_HAIR, f->hair, 12);
  memcpy(b + CF_FILTER_LIGHT, f->light, 12);
  memcpy(b + CF_FILTER_BG, f->bg, 12);
  memcpy(b + CF_FILTER_NAME, f->variant, vn);
  uint8_t *tail = b + CF_FILTER_NAME + vn;
  if (extra) hfp_put_u32(tail, f->budget_us);
  tail += extra;
  if (f->flags & HFP_FILTER_SHM) {
    hfp_put_u32(tail, f->segment);
    hfp_put_u32(tail + 4, 0);
    hfp_put_u32(tail + 8, (uint32_t)f->shm_in);
    hfp_put_u32(tail + 12, (uint32_t)(f->shm_in >> 32));
    hfp_put_u32(tail + 16, (uint32_t)f->shm_out);
    hfp_put_u32(tail + 20, (uint32_t)(f->shm_out >> 32));
    hfp_put_u32(tail + 24, (uint32_t)f->shm_rgba);
    hfp_put_u32(tail + 28, (uint32_t)(f->shm_rgba >> 32));
  } else if (data) {
    cf_fill_features(f, tail);
  }
  *len = n;
  return b;
}

/* ---- RESULT ------------------------------------------------------------------ */

static float value(const uint8_t *p, int dtype, size_t i) {
  if (dtype == HFP_F16) {
    uint16_t h;
    memcpy(&h, p + 2 * i, 2);
    return hf_f16_to_f32(h);
  }
  float v;
  memcpy(&v, p + 4 * i, 4);
  return v;
}

const char *cf_result_malformed(const cf_frame *fr, int rc, char *buf, size_t cap) {
  uint32_t len = fr->h.length;
  if (len < HFP_RESULT_FIXED) {
    snprintf(buf, cap, "its payload is %u bytes, shorter than the %d of its fixed fields", len,
             HFP_RESULT_FIXED);
    return buf;
  }
  /* Only the fixed fields are wanted, for the message: with len at least
   * their size they are always read (and m is zeroed first), whatever the
   * decoder then says of the rest, which rc already holds. */
  hfp_result m;
  (void)hfp_decode_result_head(fr->p, HFP_RESULT_FIXED, len, &m);
  char fields[200];
  snprintf(fields, sizeof fields, "status %s, dtype %u, flags 0x%02x, %ux%u, batch %u",
           hfp_code_name(m.status), m.dtype, m.flags, m.width, m.height, m.batch);
  if (rc != -HFP_E_LENGTH) {
    snprintf(buf, cap, "%s (%s; %u payload bytes)", hfp_strerror(rc), fields, len);
    return buf;
  }
  /* The sizes the fields imply (PROTOCOL.md, RESULT). */
  uint64_t dl = 0, rl = 0;
  if (m.status == HFP_OK && !(m.flags & HFP_FILTER_SHM)) {
    hfp_output_bytes(m.width, m.height, HFP_OUTPUTS, m.dtype, &dl);
    if (m.flags & HFP_FILTER_COMPOSITE) hfp_output_bytes(m.width, m.height, 4, m.dtype, &rl);
  }
  uint64_t want = HFP_RESULT_FIXED + dl + rl;
  char comp[48] = "";
  if (rl) snprintf(comp, sizeof comp, " + %llu composite", (unsigned long long)rl);
  snprintf(buf, cap, "its payload is %u bytes, %llu %s than its fields (%s) need: %llu = %d fixed "
           "+ %llu result%s", len, (unsigned long long)(len < want ? want - len : len - want),
           len < want ? "fewer" : "more", fields, (unsigned long long)want, HFP_RESULT_FIXED,
           (unsigned long long)dl, comp);
  return buf;
}

int cf_check_result(cf_test *t, const cf_frame *fr, const cf_filter *f, int version,
                    const uint8_t *shm_mem, float **result, uint8_t *result_flags) {
  char d[400];
  CF_CHECK(t, fr->h.type == HFP_RESULT, "wanted RESULT for request %u, got %s", f->id,
           cf_describe(fr, d, sizeof d));
  CF_CHECK(t, fr->h.request_id == f->id, "RESULT carries request id %u, the FILTER had %u",
           fr->h.request_id, f->id);
  hfp_result r;
  int rc = hfp_decode_result(fr->p, fr->h.length, &r);
  if (rc) {
    char why[400];
    return cf_fail(t, "RESULT for request %u is malformed: %s", f->id,
                   cf_result_malformed(fr, rc, why, sizeof why));
  }
  CF_CHECK(t, r.status == HFP_OK, "RESULT for request %u has status %s", f->id,
           hfp_code_name(r.status));
  CF_CHECK(t, r.dtype == f->out_dtype, "RESULT dtype %u, the FILTER asked for %d", r.dtype,
           f->out_dtype);
  CF_CHECK(t, r.width == f->width && r.height == f->height, "RESULT is %ux%u, the FILTER %ux%u",
           r.width, r.height, f->width, f->height);
  uint8_t want = (uint8_t)(f->flags & (HFP_FILTER_COMPOSITE | HFP_FILTER_SHM));
  uint8_t extra = (uint8_t)(r.flags & ~want);
  CF_CHECK(t, (r.flags & want) == want, "RESULT flags 0x%02x lack 0x%02x asked for", r.flags, want);
  if (version < 2)
    CF_CHECK(t, extra == 0, "RESULT flags 0x%02x on a version-1 connection (only 0x%02x allowed)",
             r.flags, want);
  else
    CF_CHECK(t, (extra & ~(HFP_RESULT_INPUT_SANITISED | HFP_RESULT_OUT_OF_RANGE)) == 0,
             "RESULT flags 0x%02x: unknown bits", r.flags);
  CF_CHECK(t, r.batch >= 1 && r.batch <= t->srv->hello.max_batch,
           "RESULT batch %u outside 1..max_batch %u", r.batch, t->srv->hello.max_batch);
  const hfp_timing *tm = &r.timing;
  uint64_t parts = tm->queue_us + tm->input_us + tm->infer_us + tm->output_us;
  CF_CHECK(t, parts >= tm->queue_us && parts <= tm->total_us,
           "RESULT timing: queue %llu + input %llu + infer %llu + output %llu exceeds total %llu us",
           (unsigned long long)tm->queue_us, (unsigned long long)tm->input_us,
           (unsigned long long)tm->infer_us, (unsigned long long)tm->output_us,
           (unsigned long long)tm->total_us);
  const uint8_t *res = r.data, *rgba = r.rgba;
  size_t px = (size_t)f->width * f->height;
  if (f->flags & HFP_FILTER_SHM) {
    CF_CHECK(t, fr->h.length == HFP_RESULT_FIXED, "a RESULT by reference has %u payload bytes, not 56",
             fr->h.length);
    res = shm_mem + f->shm_out;
    rgba = (f->flags & HFP_FILTER_COMPOSITE) ? shm_mem + f->shm_rgba : NULL;
  }
  if (!res) return 0;
  float *copy = result ? cf_alloc(t, px * 3 * sizeof(float)) : NULL;
  for (size_t p = 0; p < px; p++) {
    float c = value(res, r.dtype, 3 * p), h = value(res, r.dtype, 3 * p + 1),
          a = value(res, r.dtype, 3 * p + 2);
    CF_CHECK(t, isfinite(c) && isfinite(h) && isfinite(a),
             "result pixel %zu (x %zu, y %zu) is not finite: color %g highlight %g alpha %g", p,
             p % f->width, p / f->width, c, h, a);
    CF_CHECK(t, c >= -65504.f && c <= 65504.f && h >= 0 && h <= 65504.f && a >= 0 && a <= 1,
             "result pixel %zu outside FEATURES.md's ranges: color %g highlight %g alpha %g", p, c,
             h, a);
    if (copy) copy[3 * p] = c, copy[3 * p + 1] = h, copy[3 * p + 2] = a;
    if (!rgba) continue;
    float A = value(rgba, r.dtype, 4 * p + 3);
    CF_CHECK(t, A == a, "composite alpha %g of pixel %zu differs from the result's alpha %g", A, p,
             a);
    /* The formula, saturated at the dtype's largest finite value
     * (PROTOCOL.md, RESULT): finite for any finite colours. */
    double lim = r.dtype == HFP_F16 ? 65504.0 : FLT_MAX;
    for (int k = 0; k < 3; k++) {
      float got = value(rgba, r.dtype, 4 * p + (size_t)k);
      double want_v = (double)a * f->light[k] * ((double)f->hair[k] * c + h) +
                      (1.0 - a) * f->bg[k];
      want_v = want_v > lim ? lim : want_v < -lim ? -lim : want_v;
      /* The rounding allowed scales with the terms' size, but no further
       * than the limit: a saturated value must be the limit itself. */
      double mag = fabs((double)a * f->light[k] * ((double)f->hair[k] * fabs(c) + h)) +
                   fabs((1.0 - a) * f->bg[k]);
      if (mag > lim) mag = lim;
      double tol = r.dtype == HFP_F16 ? 2e-3 * mag + 2e-3 : 1e-5 * mag + 1e-6;
      CF_CHECK(t, isfinite(got),
               "composite of pixel %zu channel %d is %g: it must be finite for finite colours "
               "(hair %g light %g background %g)", p, k, got, f->hair[k], f->light[k], f->bg[k]);
      CF_CHECK(t, fabs(got - want_v) <= tol,
               "composite of pixel %zu channel %d is %g, a*light*(hair*c+h)+(1-a)*bg saturated "
               "at %g gives %g", p, k, got, lim, want_v);
    }
  }
  if (result) *result = copy;
  if (result_flags) *result_flags = r.flags;
  return 0;
}

int cf_filter_ok(cf_test *t, int fd, const cf_filter *f, int version, float **result,
                 uint8_t *result_flags) {
  size_t n;
  uint8_t *b = cf_filter_frame(t, f, &n);
  CF_CHECK(t, b, "out of memory");
  CF_TRY(cf_send(t, fd, b, n));
  cf_frame fr;
  int rc = cf_read(t, fd, t->o->timeout_ms, &fr);
  if (rc == CF_EOF) return cf_fail(t, "wanted RESULT %u, the server closed", f->id);
  if (rc == CF_TIMEOUT) return cf_fail(t, "wanted RESULT %u, nothing in %d ms", f->id, t->o->timeout_ms);
  if (rc != CF_GOT) return CF_FAIL;
  return cf_check_result(t, &fr, f, version, NULL, result, result_flags);
}

/* ---- shared memory ---------------------------------------------------------- */

size_t cf_shm_create_frame(uint8_t *buf, uint64_t bytes) {
  cf_header(buf, HFP_SHM_CREATE, 0, 0, 8);
  hfp_put_u32(buf + 16, (uint32_t)bytes);
  hfp_put_u32(buf + 20, (uint32_t)(bytes >> 32));
  return 24;
}

size_t cf_shm_destroy_frame(uint8_t *buf, uint32_t segment) {
  cf_header(buf, HFP_SHM_DESTROY, 0, 0, 4);
  hfp_put_u32(buf + 16, segment);
  return 20;
}

int cf_shm_create(cf_test *t, int fd, uint64_t bytes, uint32_t *segment, uint8_t **mem) {
  uint8_t b[24];
  CF_TRY(cf_send(t, fd, b, cf_shm_create_frame(b, bytes)));
  cf_frame f;
  CF_TRY(cf_expect(t, fd, HFP_SHM_CREATED, &f));
  CF_CHECK(t, f.h.request_id == 0, "SHM_CREATED carries request id %u, not 0", f.h.request_id);
  uint64_t got;
  uint32_t id;
  int rc = hfp_decode_shm_created(f.p, f.h.length, &id, &got);
  if (segment) *segment = id;
  CF_CHECK(t, rc == 0, "SHM_CREATED does not decode: %s", hfp_strerror(rc));
  CF_CHECK(t, got == bytes, "SHM_CREATED says %llu bytes, %llu were asked for",
           (unsigned long long)got, (unsigned long long)bytes);
  CF_CHECK(t, f.passed_fd >= 0, "SHM_CREATED came without a file descriptor");
  struct stat st;
  int ok = fstat(f.passed_fd, &st) == 0 && (uint64_t)st.st_size >= bytes;
  void *p = NULL;
  if (ok && mem) p = mmap(NULL, (size_t)bytes, PROT_READ | PROT_WRITE, MAP_SHARED, f.passed_fd, 0);
  cf_close(t, f.passed_fd);
  CF_CHECK(t, ok, "the segment's file is smaller than %llu bytes", (unsigned long long)bytes);
  if (!mem) return 0;
  CF_CHECK(t, p != MAP_FAILED, "cannot map the segment: %s", strerror(errno));
  CF_CHECK(t, t->nmaps < (int)(sizeof t->maps / sizeof t->maps[0]),
           "more segments mapped in one case than the suite keeps");
  t->maps[t->nmaps].p = p;
  t->maps[t->nmaps++].n = (size_t)bytes;
  *mem = p;
  return 0;
}

/* ---- the ordinary client ------------------------------------------------------- */

hfc_options cf_client_options(const char *name, const char *token, int timeout_ms) {
  hfc_options o;
  hfc_options_init(&o);
  o.client_name = name;
  o.token = token;
  o.timeout_ms = timeout_ms;
  return o;
}

hfc_request cf_client_request(const cf_filter *f, const void *in, void *out, size_t out_bytes) {
  hfc_request r;
  hfc_request_init(&r);
  r.variant = f->variant;
  r.width = (int)f->width;
  r.height = (int)f->height;
  r.spp = f->spp;
  r.in_dtype = r.out_dtype = HFC_F32;
  r.features = in;
  r.features_bytes = (size_t)cf_features_bytes(f);
  r.estimate = (f->flags & HFP_FILTER_ESTIMATE) != 0;
  r.result = out;
  r.result_bytes = out_bytes;
  return r;
}

int cf_health(cf_test *t) {
  const cf_server *s = t->srv;
  hfc_client *c = NULL;
  hfc_options o = cf_client_options("conformance-check", t->o->token, t->o->timeout_ms);
  o.tls_ca_file = t->o->tls_ca;
  o.tls_cert_file = t->o->tls_cert;
  o.tls_key_file = t->o->tls_key;
  o.tls_server_name = t->o->tls_server_name;
  int rc = hfc_connect(t->o->server, &o, &c);
  /* The case's own connections, just closed, count against the server's
   * connection limit until it has read their close (its next turns of the
   * loop): a BUSY then is retried for up to 2 s, not taken for harm done
   * to other clients. */
  for (int tries = 0; rc == HFC_E_BUSY && tries < 40; tries++) {
    struct timespec pause = {0, 50 * 1000000L};
    nanosleep(&pause, NULL);
    rc = hfc_connect(t->o->server, &o, &c);
  }
  if (rc)
    return cf_fail(t, "libhairfilter cannot connect%s: %s: %s",
                   rc == HFC_E_BUSY ? " (still BUSY 2 s after the case closed its connections)"
                                    : "",
                   hfc_strerror(rc), hfc_last_message(NULL));
  cf_filter f = {0};
  cf_filter_defaults(t, &f);
  size_t in_bytes = (size_t)cf_features_bytes(&f);
  void *in = malloc(in_bytes), *out = malloc(s->reference_len);
  if (!in || !out) {
    free(in);
    free(out);
    hfc_close(c);
    return cf_fail(t, "out of memory");
  }
  cf_fill_features(&f, in);
  hfc_request r = cf_client_request(&f, in, out, s->reference_len);
  rc = hfc_filter(c, &r, NULL);
  int same = !rc && s->reference && !memcmp(out, s->reference, s->reference_len);
  char msg[300];
  snprintf(msg, sizeof msg, "%s", hfc_last_message(c));
  free(in);
  free(out);
  hfc_close(c);
  if (rc) return cf_fail(t, "an ordinary frame failed: %s (%s)", hfc_strerror(rc), msg);
  if (!same) return cf_fail(t, "an ordinary frame's result differs from the one it had before");
  return 0;
}
