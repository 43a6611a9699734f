/*
 * request.c: hfc_submit, hfc_wait and hfc_filter: a request checked field by
 * field, its variant matched, and sent.
 *
 * Every check names the field and the value it wants, and comes before
 * anything is sent: above all the buffer sizes, so that a features buffer
 * shorter than its frame is refused instead of read past its end.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>

#include "client_internal.h"

static double now_us(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

size_t hfc_features_bytes(int width, int height, int spp, hfc_dtype dtype) {
  uint64_t n;
  if (width < 1 || height < 1 || spp < 1 ||
      hfp_features_bytes((uint32_t)width, (uint32_t)height, (uint32_t)spp, (int)dtype, &n))
    return 0;
  return (size_t)n;
}

size_t hfc_estimate_bytes(int width, int height, hfc_dtype dtype) {
  return hfc_output_bytes(width, height, HFP_ESTIMATE_VALUES, dtype);
}

size_t hfc_output_bytes(int width, int height, int channels, hfc_dtype dtype) {
  uint64_t n;
  if (width < 1 || height < 1 ||
      hfp_output_bytes((uint32_t)width, (uint32_t)height, (uint32_t)channels, (int)dtype, &n))
    return 0;
  return (size_t)n;
}

static const char *dtype_name(int d) { return d == HFC_F16 ? "f16" : "f32"; }

static int finite3(const float *v) { return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]); }

/* Checks r field by field: 0, or HFC_E_ARG with the field named. */
static int check_request(hfc_client *c, const hfc_request *r) {
  if (!r->variant || !r->variant[0])
    return hfci_arg(c, "hfc_request.variant is %s: name a variant (hfc_list_variants)",
                    r->variant ? "empty" : "NULL");
  if (strlen(r->variant) > HFP_NAME_MAX)
    return hfci_arg(c, "hfc_request.variant is longer than %d bytes", HFP_NAME_MAX);
  if (r->width < 1 || r->width > HFP_MAX_SIDE)
    return hfci_arg(c, "hfc_request.width is %d: want 1..%d", r->width, HFP_MAX_SIDE);
  if (r->height < 1 || r->height > HFP_MAX_SIDE)
    return hfci_arg(c, "hfc_request.height is %d: want 1..%d", r->height, HFP_MAX_SIDE);
  if (r->spp < 1 || r->spp > HFP_MAX_SPP)
    return hfci_arg(c, "hfc_request.spp is %d: want 1..%d, the variant's", r->spp, HFP_MAX_SPP);
  if (r->in_dtype != HFC_F32 && r->in_dtype != HFC_F16)
    return hfci_arg(c, "hfc_request.in_dtype is %d: want HFC_F32 or HFC_F16", (int)r->in_dtype);
  if (r->out_dtype != HFC_F32 && r->out_dtype != HFC_F16)
    return hfci_arg(c, "hfc_request.out_dtype is %d: want HFC_F32 or HFC_F16", (int)r->out_dtype);
  if (r->estimate != 0 && r->estimate != 1)
    return hfci_arg(c, "hfc_request.estimate is %d: want 0, or 1 when the request carries the "
                       "frame's alpha-corrected estimate", r->estimate);
  if (r->estimate_buffer && !r->estimate)
    return hfci_arg(c, "hfc_request.estimate_buffer is set but hfc_request.estimate is 0: set "
                       "estimate to 1 to send it, or estimate_buffer to NULL");
  size_t in = hfc_features_bytes(r->width, r->height, r->spp, r->in_dtype);
  size_t est = hfc_estimate_bytes(r->width, r->height, r->in_dtype);
  size_t out = hfc_output_bytes(r->width, r->height, 3, r->out_dtype);
  size_t rgba = hfc_output_bytes(r->width, r->height, 4, r->out_dtype);
  /* The estimate after the features, in the same buffer. */
  int follows = r->estimate && !r->estimate_buffer;
  if (!r->features)
    return hfci_arg(c, "hfc_request.features is NULL: give the frame's samples, "
                       "[height][width][spp*6] (hfc_features_bytes bytes)");
  if (r->features_bytes < in + (follows ? est : 0))
    return hfci_arg(c, "hfc_request.features_bytes is %zu: a %dx%d frame of %d spp in %s "
                       "(hfc_request.in_dtype) needs %zu ([height][width][spp*6]%s; "
                       "hfc_features_bytes gives it)", r->features_bytes, r->width, r->height,
                    r->spp, dtype_name(r->in_dtype), in + (follows ? est : 0),
                    follows ? ", then the estimate, [height][width][3]; or set "
                              "hfc_request.estimate_buffer to send it from a buffer of its own"
                            : "");
  if (r->estimate_buffer && r->estimate_bytes < est)
    return hfci_arg(c, "hfc_request.estimate_bytes is %zu: the estimate of a %dx%d frame in %s "
                       "(hfc_request.in_dtype) needs %zu ([height][width][3]; "
                       "hfc_estimate_bytes gives it)", r->estimate_bytes, r->width, r->height,
                    dtype_name(r->in_dtype), est);
  if (!r->result)
    return hfci_arg(c, "hfc_request.result is NULL: give the buffer the result is written to, "
                       "[height][width][3] (hfc_output_bytes(width, height, 3, out_dtype) bytes)");
  if (r->result_bytes < out)
    return hfci_arg(c, "hfc_request.result_bytes is %zu: a %dx%d result in %s "
                       "(hfc_request.out_dtype) needs %zu ([height][width][3]; "
                       "hfc_output_bytes(width, height, 3, out_dtype) gives it)", r->result_bytes, r->width, r->height,
                    dtype_name(r->out_dtype), out);
  if (r->rgba && r->rgba_bytes < rgba)
    return hfci_arg(c, "hfc_request.rgba_bytes is %zu: a %dx%d composite in %s "
                       "(hfc_request.out_dtype) needs %zu ([height][width][4]; "
                       "hfc_output_bytes(width, height, 4, out_dtype) gives it)", r->rgba_bytes, r->width, r->height,
                    dtype_name(r->out_dtype), rgba);
  if (!finite3(r->hair) || !finite3(r->light) || !finite3(r->background))
    return hfci_arg(c, "hfc_request.%s has a value that is not finite: want linear RGB, "
                       "finite (hfc_request_init leaves 0)",
                    !finite3(r->hair) ? "hair" : !finite3(r->light) ? "light" : "background");
  /* hfc_request_init() leaves the colours at 0; a composite under no light
   * is the hair drawn black, never what a caller asking for it meant. */
  if (r->rgba && r->light[0] == 0 && r->light[1] == 0 && r->light[2] == 0)
    return hfci_arg(c, "hfc_request.light is 0,0,0, so the composite (rgba) would draw the hair "
                       "black: set hfc_request.light (linear RGB, 1,1,1 for white) and "
                       "hfc_request.hair, or set rgba to NULL");
  return 0;
}

/* ---- variant names ---------------------------------------------------------- */

/* Lists the variants of the active connection into its cache. */
static int load_variants(hfc_client *c) {
  hfc_variant *v = malloc(sizeof *v * HFP_MAX_VARIANTS);
  if (!v) return HFC_E_NOMEM;
  int n = 0;
  int rc = hfci_list(c, v, HFP_MAX_VARIANTS, &n);
  if (rc || c->active < 0) {
    free(v);
    return rc ? rc : HFC_E_CLOSED;
  }
  conn *x = &c->conns[c->active];
  free(x->variants);
  x->variants = v;
  x->nvariants = n < HFP_MAX_VARIANTS ? n : HFP_MAX_VARIANTS;
  x->variants_known = 1;
  return 0;
}

/* The name of the active connection's variant that `name` means: itself,
 * or the one variant it matches without regard to case. Variants are
 * listed once per connection, and again when a name is not among them.
 * A name still unknown is sent as it is: the server answers
 * UNKNOWN_VARIANT for that frame alone (and counts it in its statistics),
 * and read_frame adds the names listed here to its message. */
static int resolve_variant(hfc_client *c, const char *name, char out[HFP_NAME_MAX + 1]) {
  int listed = 0;
  for (;;) {
    if (c->active < 0) return HFC_E_CLOSED;
    conn *x = &c->conns[c->active];
    if (!x->variants_known) {
      int rc = load_variants(c);
      if (rc) return rc;
      listed = 1;
      continue;
    }
    int exact = 0, nmatch = 0;
    const char *match = NULL;
    for (int i = 0; i < x->nvariants && !exact; i++) exact = !strcmp(x->variants[i].name, name);
    for (int i = 0; i < x->nvariants && !exact; i++)
      if (!strcasecmp(x->variants[i].name, name)) {
        match = x->variants[i].name;
        nmatch++;
      }
    if (!exact && nmatch == 1) {
      strcpy(out, match);
      return 0;
    }
    if (!exact && !listed) {
      /* Listed before this call: the server may have loaded it since. */
      x->variants_known = 0;
      continue;
    }
    strcpy(out, name);
    return 0;
  }
}

/* The listed variant named `name`, or NULL (a name not listed, which the
 * server answers). */
static const hfc_variant *find_listed(const conn *x, const char *name) {
  for (int i = 0; i < x->nvariants; i++)
    if (!strcmp(x->variants[i].name, name)) return &x->variants[i];
  return NULL;
}

/* Whether the listed variant takes other samples per pixel, or reads an
 * estimate other than, the request says. */
static int variant_mismatch(const conn *x, const char *name, int spp, int estimate) {
  const hfc_variant *v = find_listed(x, name);
  return v && (v->spp != spp || !v->estimate != !estimate);
}

/* A request whose spp or hfc_request.estimate the variant does not match,
 * refused here in the API's words, before its features go out (the
 * server's INVALID speaks of the wire's fields, and comes only after the
 * whole frame was sent). The variants are listed again first: a reload
 * may have changed what the name serves. 0, or HFC_E_ARG with the message
 * set. */
static int check_variant(hfc_client *c, const char *variant, int spp, int estimate) {
  if (variant_mismatch(&c->conns[c->active], variant, spp, estimate)) {
    int rc = load_variants(c);
    if (rc) return rc;
  }
  if (c->active < 0 || !variant_mismatch(&c->conns[c->active], variant, spp, estimate)) return 0;
  const hfc_variant *v = find_listed(&c->conns[c->active], variant);
  if (v->spp != spp)
    return hfci_arg(c, "hfc_request.spp is %d: variant %s takes %d samples per pixel "
                       "(hfc_variant.spp): render %d, or name a variant of %d spp "
                       "(hfc_list_variants)", spp, variant, v->spp, v->spp, spp);
  if (estimate)
    return hfci_arg(c, "variant %s reads no estimate: set hfc_request.estimate to 0 (and "
                       "estimate_buffer to NULL) and send the features alone", variant);
  return hfci_arg(c, "variant %s reads stochastic transparency's alpha-corrected estimate "
                     "(hfc_variant.estimate): set hfc_request.estimate to 1 and give the estimate, "
                     "[height][width][3], in hfc_request.estimate_buffer (or after the features "
                     "in the same buffer, features_bytes = hfc_features_bytes + "
                     "hfc_estimate_bytes; protocol/FEATURES.md)", variant);
}

/* ---- sending ------------------------------------------------------------------ */

int hfci_can_resend(const hfc_client *c, const pending *p, int err, int lost) {
  return p->resends < c->max_resends && hfci_can_failover(c, err, lost);
}

static int id_in_use(const hfc_client *c, uint32_t id, int wire) {
  for (int i = 0; i < c->np; i++)
    if (c->p[i].state != P_FREE && (wire ? c->p[i].wire_id : c->p[i].id) == id) return 1;
  return 0;
}

/* A request id for the wire or the caller: never 0 (reserved), never one
 * still in use. */
static uint32_t new_id(hfc_client *c, int wire) {
  uint32_t id;
  do {
    id = c->next_id++;
  } while (id == 0 || id_in_use(c, id, wire));
  return id;
}

/* The FILTER head of p for the active connection, with budget_us (sent
 * where the connection knows the flag, when p has a deadline): its size,
 * or a local error; *seg is the segment it refers to, or NULL, and
 * *frame_size the whole frame's bytes, head and tensors. */
static int filter_head(hfc_client *c, const pending *p, uint32_t budget_us, uint32_t wire_id,
                       uint8_t head[HFP_FILTER_HEAD_MAX], const segment **seg,
                       uint64_t *frame_size) {
  hfp_filter f;
  memset(&f, 0, sizeof f);
  strcpy(f.variant, p->variant);
  f.flags = (p->rgba ? HFP_FILTER_COMPOSITE : 0) | (p->estimate ? HFP_FILTER_ESTIMATE : 0);
  f.width = p->width;
  f.height = p->height;
  f.spp = p->spp;
  f.in_dtype = p->in_dtype;
  f.out_dtype = p->out_dtype;
  memcpy(f.hair, p->hair, sizeof f.hair);
  memcpy(f.light, p->light, sizeof f.light);
  memcpy(f.bg, p->bg, sizeof f.bg);
  f.data = p->features;
  f.data_len = p->features_len + p->estimate_len;
  /* A budget only where the connection knows the flag (PROTOCOL.md,
   * "Version 4"); an older server computes the frame however late. */
  if (p->deadline_us && c->active >= 0 && c->conns[c->active].info.version >= 4) {
    f.flags |= HFP_FILTER_DEADLINE;
    f.budget_us = budget_us;
  }
  /* By reference only when the tensor is one run of the segment (an
   * estimate of its own directly after the features was joined to them at
   * submission). */
  *seg = p->estimate_buffer ? NULL : hfci_shm_place(c, &f, p);
  if (*seg) {
    f.flags |= HFP_FILTER_SHM;
    f.shm_segment = (*seg)->id;
  }
  int n = hfp_encode_filter_head(head, HFP_FILTER_HEAD_MAX, wire_id, &f, frame_size);
  if (n < 0) return n == -HFP_E_TOO_LARGE ? HFC_E_TOO_LARGE : HFC_E_ARG;
  return n;
}

/* Whether p, as encoded in a frame of frame_size bytes (by reference when
 * seg), is within what the server of connection x announced in HELLO_OK:
 * max_width x max_height for every frame, max_frame_bytes for one whose
 * tensors go through the socket, the dtypes it takes. The server would
 * refuse such a frame only once its header arrived, while the client goes
 * on writing the whole tensor, and one over max_frame_bytes closes the
 * connection. 0, or HFC_E_TOO_LARGE / HFC_E_UNSUPPORTED with why (naming
 * the limit, the frame's size and what to do) in why[0..whylen); a frame
 * with an estimate for a server of protocol version 1 or 2 is
 * HFC_E_UNSUPPORTED too. */
static int check_limits(const hfc_client *c, const conn *x, const pending *p,
                        uint64_t frame_size, const segment *seg, char *why, size_t whylen) {
  const hfc_server_info *i = &x->info;
  const char *url = c->eps[x->endpoint].url;
  if (p->width > (uint32_t)i->max_width || p->height > (uint32_t)i->max_height) {
    snprintf(why, whylen, "a %ux%u frame is over the limit of %dx%d that %s announced "
             "(hfc_info()->max_width, max_height; hairfilterd's --max-size): nothing was sent; "
             "filter it in tiles within the limit, or have the server take larger frames: "
             "its --max-size, or, where its log says 'max size lowered', the --max-memory-mb "
             "or --max-frame-mb that lowered it",
             p->width, p->height, i->max_width, i->max_height, url);
    return HFC_E_TOO_LARGE;
  }
  /* hfc_submit refuses this on such a server; after a failover to one
   * (a list of servers part upgraded) the flag and the estimate behind the
   * features are what it cannot read. */
  if (p->estimate && i->version < 3) {
    snprintf(why, whylen, "the frame carries an estimate, but %s speaks protocol version %d: "
             "the estimate needs version 3 (a newer hairfilterd); nothing was sent",
             url, i->version);
    return HFC_E_UNSUPPORTED;
  }
  if ((p->in_dtype == HFC_F16 && !i->f16) || (p->in_dtype == HFC_F32 && !i->f32) ||
      (p->out_dtype == HFC_F16 && !i->f16) || (p->out_dtype == HFC_F32 && !i->f32)) {
    snprintf(why, whylen, "%s takes %s tensors only (hfc_info()->f32, f16): set "
             "hfc_request.in_dtype and out_dtype to %s; nothing was sent",
             url, i->f16 ? "f16" : "f32", i->f16 ? "HFC_F16" : "HFC_F32");
    return HFC_E_UNSUPPORTED;
  }
  uint64_t payload = frame_size - HFP_HEADER_SIZE;
  if (!seg && payload > i->max_frame_bytes) {
    snprintf(why, whylen, "a %ux%u frame of %u spp is %llu bytes on the wire, over the "
             "%llu-byte limit that %s announced (hfc_info()->max_frame_bytes; hairfilterd's "
             "--max-frame-mb): nothing was sent; put its buffers in one shared segment "
             "(hfc_shm_alloc), send f16, or filter it in tiles",
             p->width, p->height, p->spp, (unsigned long long)payload,
             (unsigned long long)i->max_frame_bytes, url);
    return HFC_E_TOO_LARGE;
  }
  return 0;
}

/* The budget p is sent with: all of deadline_us the first time; sent again
 * after a failover, what remains of it after the time spent since
 * hfc_submit (on this client's monotonic clock: the servers' clocks need
 * not agree with it), so that the next server does not wait for the frame
 * longer than the caller allowed. 0 when nothing remains. */
static uint32_t budget_left(const pending *p) {
  if (p->resends == 0) return p->deadline_us;
  double left = (double)p->deadline_us - (now_us() - p->t_submit);
  if (left < 1) return 0;
  return (uint32_t)left;
}

int hfci_send_request(hfc_client *c, pending *p) {
  int k = c->active;
  conn *x = &c->conns[k];
  uint8_t head[HFP_FILTER_HEAD_MAX];
  const segment *g;
  uint32_t budget = p->deadline_us;
  if (p->deadline_us && x->info.version >= 4 && (budget = budget_left(p)) == 0) {
    /* Its budget passed while it went from one server to the next: the
     * server would answer EXPIRED unrun (PROTOCOL.md, "Version 4"), so it
     * is answered here, unsent (hfc_timing.resends counts the sends). */
    p->resends--;
    char why[MSG_MAX];
    snprintf(why, sizeof why, "its budget of %u us (hfc_request.deadline_us) passed before it "
             "could be sent again after a failover (%.0f us since hfc_submit): not sent to %s, "
             "not computed", p->deadline_us, now_us() - p->t_submit, c->eps[x->endpoint].url);
    hfci_finish(c, p, HFC_E_EXPIRED, why);
    return 0;
  }
  uint32_t wire = new_id(c, 1);
  uint64_t total = 0;
  p->budget_sent = budget;
  int n = filter_head(c, p, budget, wire, head, &g, &total);
  if (n < 0) {
    /* It was encoded once at submission: only a different server's
     * segment placement could change it, and that falls back to the socket. */
    hfci_finish(c, p, n, "the request cannot be encoded");
    return 0;
  }
  /* Checked at submission against the server then in use; a failover may
   * have brought one with lower limits. */
  char why[MSG_MAX];
  int lim = check_limits(c, x, p, total, g, why, sizeof why);
  if (lim) {
    hfci_finish(c, p, lim, why);
    return 0;
  }
  p->wire_id = wire;
  p->conn = k;
  p->shm = g != NULL;
  p->state = P_SENT;
  /* The first frame owed after an idle spell starts the silence clock. */
  if (x->inflight == 0) x->quiet_since_us = now_us();
  x->inflight++;
  /* On failure part of a frame may be out: the connection cannot be trusted
   * any more, and the caller ends it (hfci_conn_lost, which resends p). */
  struct iovec iov[3] = {{head, (size_t)n},
                         {(void *)p->features, g ? 0 : (size_t)p->features_len},
                         {(void *)p->estimate_buffer, g ? 0 : (size_t)p->estimate_len}};
  return hfci_send_iov(x->fd, x->ssl, c->timeout_ms, iov, 3);
}

/* Grows the slots to at least n. */
static int grow(hfc_client *c, int n) {
  if (c->np >= n) return 0;
  pending *q = realloc(c->p, sizeof *q * (size_t)n);
  if (!q) return HFC_E_NOMEM;
  memset(q + c->np, 0, sizeof *q * (size_t)(n - c->np));
  c->p = q;
  c->np = n;
  return 0;
}

/* Whether p's result or rgba shares a byte with its input, the features
 * or an estimate of its own (filtering in place). Such a frame may be sent
 * through the socket, where its result arrives only after its input has
 * gone, but never again after a failover: by then the result may have
 * overwritten it. */
static int overlaps_input(const pending *p) {
  uint64_t out_len = 0, rgba_len = 0;
  hfp_output_bytes(p->width, p->height, HFP_OUTPUTS, p->out_dtype, &out_len);
  if (p->rgba) hfp_output_bytes(p->width, p->height, 4, p->out_dtype, &rgba_len);
  const struct {
    uint64_t at, len;
  } in[2] = {{(uintptr_t)p->features, p->features_len},
             {(uintptr_t)p->estimate_buffer, p->estimate_len}};
  uint64_t r = (uintptr_t)p->result, a = (uintptr_t)p->rgba;
  for (int i = 0; i < 2; i++)
    if (in[i].len && (hfp_regions_overlap(in[i].at, in[i].len, r, out_len) ||
                      (p->rgba && hfp_regions_overlap(in[i].at, in[i].len, a, rgba_len))))
      return 1;
  return 0;
}

int hfc_cancel(hfc_client *c, uint32_t id) {
  hfci_begin(c);
  if (!c) return hfci_arg(NULL, "hfc_cancel: the client is NULL");
  pending *p = NULL;
  for (int i = 0; i < c->np && !p; i++)
    if (c->p[i].state != P_FREE && c->p[i].id == id) p = &c->p[i];
  if (!p)
    return hfci_arg(c, "hfc_cancel: request %u is not pending (the id hfc_submit gave; one "
                       "hfc_wait has returned is done)", id);
  /* Answered already: hfc_wait returns it as it came. */
  if (p->state == P_DONE) return 0;
  if (p->state == P_QUEUED) {
    hfci_finish(c, p, HFC_E_CANCELLED, "cancelled by hfc_cancel before it was sent again");
    return 0;
  }
  conn *x = &c->conns[p->conn];
  if (x->info.version < 4) {
    hfci_msg(c, "hfc_cancel: %s speaks protocol version %d; cancelling needs version 4 (a "
                "newer hairfilterd): request %u completes as the server answers it",
             c->eps[x->endpoint].url, x->info.version, id);
    return HFC_E_UNSUPPORTED;
  }
  if (x->draining) {
    hfci_msg(c, "hfc_cancel: the connection to %s is closing (nothing more is sent on it): "
                "request %u completes as the server answers it", c->eps[x->endpoint].url, id);
    return HFC_E_UNSUPPORTED;
  }
  uint8_t b[HFP_HEADER_SIZE];
  int n = hfp_encode_empty(b, sizeof b, HFP_CANCEL, p->wire_id);
  if (n < 0) return hfci_arg(c, "hfc_cancel: request %u cannot be encoded", id);
  int rc = hfci_send_io(x->fd, x->ssl, c->timeout_ms, b, (size_t)n);
  if (rc) {
    ptrdiff_t at = p - c->p;
    hfci_send_failed(c, p->conn, rc);
    /* The CANCEL did not go out, and the lost connection may have queued
     * the frame to be sent again, or sent it to the next endpoint already:
     * the engine still does not want it. The connection's loss is this
     * call's error either way. */
    p = &c->p[at];
    const char *then = "it completes with the connection's error";
    if (p->id == id && p->state == P_QUEUED) {
      hfci_finish(c, p, HFC_E_CANCELLED, "cancelled by hfc_cancel before it was sent again");
      then = "it completes HFC_E_CANCELLED, not sent again";
    } else if (p->id == id && p->state == P_SENT) {
      then = hfc_cancel(c, id) ? "it was sent again to the next endpoint, which could not be "
                                 "asked to cancel it: it completes as answered"
                               : "it was sent again to the next endpoint, and cancelled there";
    }
    hfci_msg(c, "hfc_cancel: the connection was lost sending the CANCEL of request %u (%s): %s",
             id, hfc_strerror(rc), then);
    return rc;
  }
  return 0;
}

/* The caller's request in this header's layout (hfci_take_struct):
 * 0.1.0's ended at user, so the estimate fields default to none; 0.2.0's
 * at estimate_bytes, so deadline_us defaults to none. */
static int take_request(hfc_client *c, const hfc_request *r, hfc_request *full) {
  if (!r) return hfci_arg(c, "the request is NULL");
  static const size_t released[] = {offsetof(hfc_request, estimate),      /* 0.1.0 */
                                    offsetof(hfc_request, deadline_us)};  /* 0.2.0 */
  hfc_request_init(full);
  return hfci_take_struct(c, "hfc_request", r, full, sizeof *full, released, 2,
                          "hfc_request_init");
}

/* fn: the public function called, for the message of a NULL client. */
static int submit(const char *fn, hfc_client *c, const hfc_request *caller, uint32_t *id,
                  int *slot) {
  hfci_begin(c);
  if (!c) return hfci_arg(NULL, "%s: the client is NULL", fn);
  hfc_request full;
  int rc = take_request(c, caller, &full);
  if (rc) return rc;
  const hfc_request *r = &full;
  rc = check_request(c, r);
  if (rc) return rc;
  int k = hfci_need_conn(c);
  if (k < 0) return k;
  char variant[HFP_NAME_MAX + 1];
  if ((rc = resolve_variant(c, r->variant, variant))) return rc;
  if ((k = hfci_need_conn(c)) < 0) return k;
  const conn *x = &c->conns[c->active];
  if (r->estimate && x->info.version < 3) {
    hfci_msg(c, "hfc_request.estimate is 1, but %s speaks protocol version %d: the estimate "
                "needs version 3 (a newer hairfilterd)", c->eps[x->endpoint].url,
             x->info.version);
    return HFC_E_ARG;
  }
  if ((rc = check_variant(c, variant, r->spp, r->estimate))) return rc;
  if ((k = hfci_need_conn(c)) < 0) return k;
  x = &c->conns[c->active];
  if (c->npending >= x->info.max_inflight) {
    hfci_msg(c, "%d requests pending, as many as %s allows on a connection: collect some "
                "with hfc_wait", c->npending, c->eps[x->endpoint].url);
    return HFC_E_INFLIGHT;
  }
  if ((rc = grow(c, x->info.max_inflight > c->npending + 1 ? x->info.max_inflight
                                                           : c->npending + 1)))
    return rc;
  pending *p = NULL;
  for (int i = 0; i < c->np && !p; i++)
    if (c->p[i].state == P_FREE) {
      p = &c->p[i];
      *slot = i;
    }
  if (!p) return HFC_E_NOMEM;   /* grow made one: cannot happen */
  memset(p, 0, sizeof *p);
  strcpy(p->variant, variant);
  p->width = (uint32_t)r->width;
  p->height = (uint32_t)r->height;
  p->spp = (uint16_t)r->spp;
  p->in_dtype = (uint8_t)r->in_dtype;
  p->out_dtype = (uint8_t)r->out_dtype;
  memcpy(p->hair, r->hair, sizeof p->hair);
  memcpy(p->light, r->light, sizeof p->light);
  memcpy(p->bg, r->background, sizeof p->bg);
  p->features = r->features;
  p->estimate = r->estimate;
  p->deadline_us = r->deadline_us;
  p->features_len = hfc_features_bytes(r->width, r->height, r->spp, r->in_dtype);
  uint64_t est = r->estimate ? hfc_estimate_bytes(r->width, r->height, r->in_dtype) : 0;
  if (r->estimate_buffer &&
      r->estimate_buffer != (const uint8_t *)r->features + p->features_len) {
    p->estimate_buffer = r->estimate_buffer;
    p->estimate_len = est;
  } else {
    /* After the features in the same buffer, or in a buffer of its own
     * that directly follows them: one run, which shared memory can take
     * by reference. */
    p->features_len += est;
  }
  p->result = r->result;
  p->rgba = r->rgba;
  p->in_place = overlaps_input(p);
  /* Whatever the codec refuses is refused now, before the slot is taken. */
  uint8_t head[HFP_FILTER_HEAD_MAX];
  const segment *g;
  uint64_t total = 0;
  int n = filter_head(c, p, p->deadline_us, 1, head, &g, &total);
  if (n < 0) {
    hfci_msg(c, "the request cannot be encoded: %s", hfc_strerror(n));
    return n;
  }
  /* Over the server's announced limits: refused here, the connection
   * untouched, rather than after an upload the server only discards. */
  char why[MSG_MAX];
  if ((n = check_limits(c, x, p, total, g, why, sizeof why))) {
    hfci_msg(c, "%s", why);
    return n;
  }
  p->id = new_id(c, 0);
  p->comp.user = r->user;
  p->order = c->next_order++;
  p->t_submit = now_us();
  p->state = P_QUEUED;
  c->npending++;
  if (id) *id = p->id;
  /* Sent now when the window has room; a failure is the completion's. */
  hfci_progress(c);
  return 0;
}

int hfc_submit(hfc_client *c, const hfc_request *r, uint32_t *id) {
  int slot;
  int rc = submit("hfc_submit", c, r, id, &slot);
  /* A send that failed is the frame's completion already, and the first
   * frame in flight starts the silence clock: either is due on hfc_fd. */
  if (c) hfci_due_update(c);
  return rc;
}

int hfc_pending(const hfc_client *c) {
  if (!c)
    return hfci_arg(NULL, "hfc_pending: the client is NULL (hfc_connect failed or was not called)");
  return c->npending;
}

static pending *first_done(hfc_client *c) {
  pending *best = NULL;
  for (int i = 0; i < c->np; i++)
    if (c->p[i].state == P_DONE && (!best || c->p[i].seq < best->seq)) best = &c->p[i];
  return best;
}

/* hfc_wait with nothing pending: HFC_E_NOPENDING, or, once the connection
 * is gone, the error that ended it, so that an engine collecting until
 * hfc_wait fails learns it must connect again. Either way the message says
 * which and what to do: an engine polling hfc_wait(c, 0) in a loop that
 * takes HFC_E_TIMEOUT for "nothing yet" would otherwise spin on a
 * connection given up as silent with nothing to tell it why. */
static int nothing_pending(hfc_client *c) {
  if (!(c->broken && c->active < 0)) {
    hfci_msg(c, "hfc_wait: no request is pending (every completion has been returned; "
                "hfc_submit sends the next)");
    return HFC_E_NOPENDING;
  }
  const char *url = c->last_ep >= 0 && c->last_ep < c->neps ? c->eps[c->last_ep].url : "the server";
  int relist = hfci_follows_list(c);
  hfci_msg(c, "hfc_wait: no request is pending, and the connection to %s was lost (%s): %s", url,
           hfc_strerror(c->broken),
           relist ? "the next request connects to the next endpoint that answers"
                  : "hfc_close, then hfc_connect again");
  return c->broken;
}

static int wait_next(hfc_client *c, int timeout_ms, hfc_completion *done) {
  hfci_begin(c);
  if (!c || !done) return hfci_arg(c, "hfc_wait: %s is NULL", c ? "done" : "the client");
  if (timeout_ms < 0) timeout_ms = c->timeout_ms;
  double deadline = now_us() + (double)timeout_ms * 1e3;
  for (;;) {
    pending *p = first_done(c);
    if (p) {
      /* The message is the completion's (hfc_last_message). */
      hfci_release(c, p, done);
      return 0;
    }
    if (c->npending == 0) return nothing_pending(c);
    int left = timeout_ms < 0 ? -1 : (int)((deadline - now_us()) / 1e3);
    if (left < 0 && timeout_ms >= 0) left = 0;
    /* Not past the moment a silent connection is to be given up: a wait
     * longer than the client's timeout, or a loop of polls, must not keep
     * frames on a stopped server pending for ever (nor from failing over). */
    int step = left, silent = hfci_silence_left_ms(c);
    if (silent >= 0 && (step < 0 || silent < step)) step = silent;
    int rc = hfci_pump(c, step);
    hfci_check_silent(c);
    hfci_progress(c);
    if (first_done(c)) continue;
    if (rc == HFC_E_TIMEOUT) {
      if (timeout_ms >= 0 && now_us() >= deadline) {
        /* Routine for an engine with a frame budget; the message tells it
         * apart from a connection given up, which has nothing pending. */
        hfci_msg(c, "hfc_wait: no completion within %d ms; %d request(s) still pending "
                    "(their buffers stay in use: collect them later)", timeout_ms, c->npending);
        return rc;
      }
      continue;
    }
    if (rc && rc != HFC_E_TIMEOUT && !first_done(c)) {
      /* No connection left and nothing could complete: fail what waits. */
      for (int i = 0; i < c->np; i++)
        if (c->p[i].state == P_SENT || c->p[i].state == P_QUEUED)
          hfci_finish(c, &c->p[i], rc, c->msg);
    }
  }
}

int hfc_wait(hfc_client *c, int timeout_ms, hfc_completion *done) {
  int rc = wait_next(c, timeout_ms, done);
  /* The completion returned may have been the last one due. */
  if (c) hfci_due_update(c);
  return rc;
}

int hfc_filter(hfc_client *c, const hfc_request *r, hfc_timing *timing) {
  uint32_t id;
  int slot;
  if (timing) memset(timing, 0, sizeof *timing);
  int rc = submit("hfc_filter", c, r, &id, &slot);
  if (rc) return rc;
  /* The slot stays this request's until released below (slots only grow in
   * hfc_submit, so the index holds). */
  while (c->p[slot].state != P_DONE) {
    rc = hfci_pump(c, c->timeout_ms);
    pending *p = &c->p[slot];
    if (rc == HFC_E_TIMEOUT) {
      /* Nothing at all for a whole timeout: the server is stuck. */
      int k = p->state == P_SENT ? p->conn : c->active;
      if (k >= 0)
        hfci_give_up_silent(c, k);
      else
        hfci_finish(c, p, rc, "no answer within the timeout");
    } else if (rc && p->state != P_DONE) {
      hfci_finish(c, p, rc, c->msg);
    }
    hfci_progress(c);
  }
  hfc_completion comp;
  hfci_release(c, &c->p[slot], &comp);
  hfci_due_update(c);
  if (timing) *timing = comp.timing;
  return comp.status;
}
