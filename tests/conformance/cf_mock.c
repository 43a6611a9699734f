/*
 * The mock server (cf_mock.h). It speaks with the codec of protocol/, so a
 * well-formed reply is well formed by the same rules the server follows;
 * the cases then break single bytes of it.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <unistd.h>

#include "cf_mock.h"
#include "hfcore.h"

int mk_fail(mock *m, const char *fmt, ...) {
  if (!m->failed) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m->why, sizeof m->why, fmt, ap);
    va_end(ap);
    m->failed = 1;
  }
  return CF_FAIL;
}

static int wait_for(int fd, short ev, int ms) {
  struct pollfd p = {fd, ev, 0};
  int n;
  do n = poll(&p, 1, ms); while (n < 0 && errno == EINTR);
  return n > 0 ? 0 : -1;
}

int mk_accept(mock *m) {
  if (m->fd >= 0) close(m->fd);
  m->fd = -1;
  if (wait_for(m->lfd, POLLIN, m->timeout_ms)) return mk_fail(m, "the client did not connect");
  m->fd = accept4(m->lfd, NULL, NULL, SOCK_CLOEXEC);
  return m->fd >= 0 ? 0 : mk_fail(m, "accept: %s", strerror(errno));
}

static int read_n(mock *m, uint8_t *p, size_t n) {
  size_t got = 0;
  while (got < n) {
    if (wait_for(m->fd, POLLIN, m->timeout_ms)) return -1;
    ssize_t r = recv(m->fd, p + got, n - got, 0);
    if (r == 0) return 0;
    if (r < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      return errno == ECONNRESET ? 0 : -1;
    }
    got += (size_t)r;
  }
  return 1;
}

int mk_read(mock *m, hfp_header *h, uint8_t **p) {
  uint8_t hb[HFP_HEADER_SIZE];
  *p = NULL;
  int rc = read_n(m, hb, sizeof hb);
  if (rc <= 0) return rc;
  if (hfp_header_decode(hb, 1u << 30, h))
    return mk_fail(m, "the client sent a bad header (type %u, flags %u)", hfp_get_u16(hb + 4),
                   hfp_get_u16(hb + 6)), -1;
  *p = malloc(h->length ? h->length : 1);
  if (!*p) return -1;
  rc = read_n(m, *p, h->length);
  if (rc <= 0) {
    free(*p);
    *p = NULL;
    return rc ? rc : (mk_fail(m, "the client left in the middle of a frame of type %u", h->type), -1);
  }
  return 1;
}

/* The client may have gone (its own business): a failed send ends the
 * script's reply, nothing more. */
static int send_msg(mock *m, const void *b, size_t n, int fd) {
  return cf_send_raw(m->fd, b, n, fd, m->timeout_ms) ? -1 : 0;
}

int mk_send(mock *m, const void *b, size_t n) { return send_msg(m, b, n, -1); }
int mk_send_fd(mock *m, const void *b, size_t n, int fd) { return send_msg(m, b, n, fd); }

int mk_hello(mock *m) {
  hfp_header h;
  uint8_t *p;
  int rc = mk_read(m, &h, &p);
  if (rc <= 0) return mk_fail(m, "no HELLO from the client");
  if (h.type != HFP_HELLO) {
    free(p);
    return mk_fail(m, "the client's first frame has type %u, not HELLO", h.type);
  }
  rc = hfp_decode_hello(p, h.length, &m->hello);
  free(p);
  if (rc) return mk_fail(m, "the client's HELLO does not decode: %s", hfp_strerror(rc));
  if (h.request_id != 0) return mk_fail(m, "the client's HELLO has request id %u, not 0", h.request_id);
  hfp_hello_ok ok = m->ok;
  if (!ok.version) ok.version = m->hello.max_version < HFP_VERSION ? m->hello.max_version : HFP_VERSION;
  m->ok.version = ok.version;
  uint8_t b[HFP_HEADER_SIZE + 64 + HFP_NAME_MAX];
  int n = hfp_encode_hello_ok(b, sizeof b, &ok);
  if (n < 0) return mk_fail(m, "mock: cannot encode HELLO_OK: %s", hfp_strerror(n));
  return mk_send(m, b, (size_t)n);
}

/* ---- replies ------------------------------------------------------------------ */

uint32_t mk_tag(const void *features, int dtype) {
  float v;
  if (dtype == HFP_F16) {
    uint16_t h;
    memcpy(&h, features, 2);
    v = hf_f16_to_f32(h);
  } else {
    memcpy(&v, features, 4);
  }
  return v >= 0 && v < 65536 ? (uint32_t)v : 0;
}

void mk_values(uint32_t id, size_t p, float v[3]) {
  v[0] = 1.0f + (float)(id % 97) / 64.0f + (float)(p % 13) / 1024.0f;
  v[1] = (float)(p % 5) / 8.0f;
  v[2] = (float)((p + id) % 9) / 8.0f;
}

static void put(uint8_t *dst, int dtype, size_t i, float v) {
  if (dtype == HFP_F16) {
    uint16_t h = hf_f32_to_f16(v);
    memcpy(dst + 2 * i, &h, 2);
  } else {
    memcpy(dst + 4 * i, &v, 4);
  }
}

/* Result (and composite) of f, whose features carry tag, into res / rgba. */
static void fill_result(uint32_t tag, const hfp_filter *f, uint8_t *res, uint8_t *rgba) {
  size_t px = (size_t)f->width * f->height;
  for (size_t p = 0; p < px; p++) {
    float v[3];
    mk_values(tag, p, v);
    for (int k = 0; k < 3; k++) put(res, f->out_dtype, 3 * p + (size_t)k, v[k]);
    if (!rgba) continue;
    for (int k = 0; k < 3; k++)
      put(rgba, f->out_dtype, 4 * p + (size_t)k,
          v[2] * f->light[k] * (f->hair[k] * v[0] + v[1]) + (1 - v[2]) * f->bg[k]);
    put(rgba, f->out_dtype, 4 * p + 3, v[2]);
  }
}

uint8_t *mk_result(mock *m, uint32_t id, const uint8_t *payload, size_t len, size_t *n) {
  hfp_filter f;
  if (hfp_decode_filter(payload, len, &f)) {
    mk_fail(m, "the client's FILTER does not decode");
    return NULL;
  }
  hfp_result r;
  memset(&r, 0, sizeof r);
  r.dtype = f.out_dtype;
  r.flags = (uint8_t)(f.flags & (HFP_FILTER_COMPOSITE | HFP_FILTER_SHM));
  r.width = f.width;
  r.height = f.height;
  r.batch = 1;
  r.timing = (hfp_timing){11, 22, 33, 44, 200};
  uint64_t dl = 0, rl = 0;
  hfp_output_bytes(f.width, f.height, 3, f.out_dtype, &dl);
  if (f.flags & HFP_FILTER_COMPOSITE) hfp_output_bytes(f.width, f.height, 4, f.out_dtype, &rl);
  uint8_t *seg = NULL;
  uint64_t seg_bytes = 0;
  if (f.flags & HFP_FILTER_SHM) {
    for (int i = 0; i < m->nsegs; i++)
      if (m->segs[i].id == f.shm_segment) seg = m->segs[i].mem, seg_bytes = m->segs[i].bytes;
    if (!seg || hfp_shm_check(&f, seg_bytes)) {
      mk_fail(m, "the client's FILTER refers to segment %u, unknown or too small", f.shm_segment);
      return NULL;
    }
    fill_result(mk_tag(seg + f.shm_in, f.in_dtype), &f, seg + f.shm_out, rl ? seg + f.shm_rgba : NULL);
    dl = rl = 0;
  }
  r.data_len = dl;
  r.rgba_len = rl;
  uint8_t *b = malloc(HFP_RESULT_HEAD_MAX + dl + rl);
  if (!b) return NULL;
  uint64_t total;
  int hn = hfp_encode_result_head(b, HFP_RESULT_HEAD_MAX, id, &r, &total);
  if (hn < 0) {
    free(b);
    mk_fail(m, "mock: cannot encode RESULT: %s", hfp_strerror(hn));
    return NULL;
  }
  if (!seg) fill_result(mk_tag(f.data, f.in_dtype), &f, b + hn, rl ? b + hn + dl : NULL);
  *n = (size_t)total;
  return b;
}

uint8_t *mk_variants(mock *m, int version, size_t *n) {
  (void)m;
  hfp_variant v[2];
  memset(v, 0, sizeof v);
  snprintf(v[0].name, sizeof v[0].name, MK_VARIANT);
  snprintf(v[1].name, sizeof v[1].name, "Other");
  for (int i = 0; i < 2; i++) {
    snprintf(v[i].backend, sizeof v[i].backend, "cpu");
    snprintf(v[i].precision, sizeof v[i].precision, "fp32");
    v[i].spp = i ? 4 : MK_SPP;
    v[i].num_levels = 2;
    v[i].levels[0] = 8;
    v[i].levels[1] = 16;
  }
  v[0].num_ranges = 2;
  v[0].ranges[0].stat = 0;
  v[0].ranges[0].lo = 0.25;
  v[0].ranges[0].hi = 0.5;
  v[0].ranges[1].stat = 4;
  v[0].ranges[1].lo = 16;
  v[0].ranges[1].hi = 2048;
  v[1].estimate = HFP_ESTIMATE_ALPHA_CORRECTED;   /* said from version 3 on */
  size_t need = hfp_frame_size_variants_v(v, 2, version);
  uint8_t *b = malloc(need);
  int k = b ? hfp_encode_variants_v(b, need, v, 2, version) : -1;
  if (k < 0) {
    free(b);
    return NULL;
  }
  *n = (size_t)k;
  return b;
}

uint8_t *mk_stats(mock *m, int version, size_t *n) {
  (void)m;
  static hfp_stats st;   /* 30 KiB; only the mock thread uses it */
  memset(&st, 0, sizeof st);
  st.uptime_us = 123456;
  st.connections_total = 3;
  st.connections_open = 1;
  st.queue_capacity = 64;
  st.protocol_errors = 2;
  st.num_variants = 1;
  hfp_variant_stats *v = &st.variants[0];
  snprintf(v->name, sizeof v->name, MK_VARIANT);
  v->requests_ok = 5;
  v->batches = 4;
  v->hist_total[3] = 5;
  v->hist_infer[2] = 5;
  v->out_of_range = 2;
  v->frames_sanitised = 1;
  size_t need = hfp_frame_size_stats_v(&st, version);
  uint8_t *b = malloc(need + 64);
  int k = b ? hfp_encode_stats_v(b, need, &st, version) : -1;
  if (k < 0) {
    free(b);
    return NULL;
  }
  *n = (size_t)k;
  return b;
}

size_t mk_error(uint8_t *buf, uint32_t id, int code, int fatal, const char *msg) {
  /* By hand: the codec refuses codes it does not know, and cases send some. */
  size_t ml = strlen(msg);
  cf_header(buf, HFP_ERROR, 0, id, (uint32_t)(8 + ml));
  hfp_put_u32(buf + 16, (uint32_t)code);
  buf[20] = (uint8_t)fatal;
  buf[21] = 0;
  hfp_put_u16(buf + 22, (uint16_t)ml);
  memcpy(buf + 24, msg, ml);
  return 24 + ml;
}

static int shm_created(mock *m, uint64_t bytes) {
  if (m->nsegs == 16) return 0;
  int fd = memfd_create("mock-segment", MFD_CLOEXEC | MFD_ALLOW_SEALING);
  if (fd < 0 || ftruncate(fd, (off_t)bytes) ||
      fcntl(fd, F_ADD_SEALS, F_SEAL_SHRINK | F_SEAL_GROW | F_SEAL_SEAL)) {
    if (fd >= 0) close(fd);
    return mk_fail(m, "mock: memfd: %s", strerror(errno));
  }
  void *mem = mmap(NULL, (size_t)bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  if (mem == MAP_FAILED) {
    close(fd);
    return mk_fail(m, "mock: mmap: %s", strerror(errno));
  }
  uint32_t id = ++m->last_segment;
  m->segs[m->nsegs].id = id;
  m->segs[m->nsegs].mem = mem;
  m->segs[m->nsegs++].bytes = bytes;
  uint8_t b[HFP_HEADER_SIZE + 12];
  int n = hfp_encode_shm_created(b, sizeof b, id, bytes);
  int rc = mk_send_fd(m, b, (size_t)n, fd);
  close(fd);
  return rc;
}

int mk_reply(mock *m, const hfp_header *h, const uint8_t *p) {
  size_t n = 0;
  uint8_t *b = NULL;
  switch (h->type) {
    case HFP_LIST_VARIANTS:
    case HFP_STATS:
      if (h->length || h->request_id)
        return mk_fail(m, "the client sent a %s with id %u and %u payload bytes (0 and 0)",
                       h->type == HFP_STATS ? "STATS" : "LIST_VARIANTS", h->request_id, h->length);
      b = h->type == HFP_STATS ? mk_stats(m, m->ok.version, &n) : mk_variants(m, m->ok.version, &n);
      break;
    case HFP_FILTER: {
      hfp_filter f;
      int rc = hfp_decode_filter(p, h->length, &f);
      if (rc) return mk_fail(m, "the client's FILTER does not decode: %s", hfp_strerror(rc));
      if (h->request_id == 0) return mk_fail(m, "the client sent a FILTER with id 0");
      b = mk_result(m, h->request_id, p, h->length, &n);
      break;
    }
    case HFP_SHM_CREATE: {
      uint64_t bytes;
      if (hfp_decode_shm_create(p, h->length, &bytes) || h->request_id)
        return mk_fail(m, "the client's SHM_CREATE is malformed or has an id");
      return shm_created(m, bytes);
    }
    case HFP_SHM_DESTROY: {
      uint32_t id;
      if (hfp_decode_shm_destroy(p, h->length, &id) || h->request_id)
        return mk_fail(m, "the client's SHM_DESTROY is malformed or has an id");
      return 0;
    }
    default:
      return mk_fail(m, "the client sent a frame of type %u", h->type);
  }
  if (!b) return mk_fail(m, "mock: cannot build the reply");
  int rc = mk_send(m, b, n);
  free(b);
  (void)rc;
  return 0;
}

int mk_session(mock *m) {
  if (mk_accept(m) || mk_hello(m)) return CF_FAIL;
  for (;;) {
    hfp_header h;
    uint8_t *p;
    int rc = mk_read(m, &h, &p);
    if (rc <= 0) return rc == 0 ? 0 : (m->failed ? CF_FAIL : 0);
    if (h.type <= HFP_TYPE_MAX) m->seen[h.type]++;
    if (h.type == HFP_FILTER && m->nids < (int)(sizeof m->ids / sizeof m->ids[0]))
      m->ids[m->nids++] = h.request_id;
    rc = (m->on_frame ? m->on_frame : mk_reply)(m, &h, p);
    free(p);
    if (rc) return rc < 0 ? CF_FAIL : 0;
  }
}

static void *run(void *arg) {
  mock *m = arg;
  (m->script ? m->script : mk_session)(m);
  if (m->fd >= 0) close(m->fd);
  m->fd = -1;
  return NULL;
}

int mk_start(cf_test *t, mock *m) {
  const char *tmp = getenv("TMPDIR");
  snprintf(m->dir, sizeof m->dir, "%s/hfmock-XXXXXX", tmp && *tmp ? tmp : "/tmp");
  if (!mkdtemp(m->dir)) return cf_fail(t, "mkdtemp: %s", strerror(errno));
  snprintf(m->path, sizeof m->path, "%s/s", m->dir);
  snprintf(m->url, sizeof m->url, "unix:%s", m->path);
  m->fd = -1;
  if (!m->timeout_ms) m->timeout_ms = 5000;
  hfp_hello_ok d = {0, 0, 256, 256, MK_SPP, 8, HFP_DTYPE_MASK_ALL, 4, 64, 1 << 24, "mock", ""};
  if (!m->ok.max_width) {
    uint16_t v = m->ok.version, fl = m->ok.server_flags;
    uint16_t inflight = m->ok.max_inflight;
    m->ok = d;
    m->ok.version = v;
    m->ok.server_flags = fl;
    if (inflight) m->ok.max_inflight = inflight;
  }
  m->lfd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  struct sockaddr_un sun;
  memset(&sun, 0, sizeof sun);
  sun.sun_family = AF_UNIX;
  snprintf(sun.sun_path, sizeof sun.sun_path, "%s", m->path);
  if (m->lfd < 0 || bind(m->lfd, (struct sockaddr *)&sun, sizeof sun) || listen(m->lfd, 8))
    return cf_fail(t, "mock: cannot listen on %s: %s", m->path, strerror(errno));
  if (pthread_create(&m->thread, NULL, run, m)) return cf_fail(t, "mock: no thread");
  m->running = 1;
  return 0;
}

int mk_finish(cf_test *t, mock *m) {
  if (m->running) pthread_join(m->thread, NULL);
  m->running = 0;
  if (m->lfd >= 0) close(m->lfd);
  m->lfd = -1;
  for (int i = 0; i < m->nsegs; i++) munmap(m->segs[i].mem, (size_t)m->segs[i].bytes);
  m->nsegs = 0;
  unlink(m->path);
  rmdir(m->dir);
  if (m->failed) return cf_fail(t, "the mock server says: %s", m->why);
  return 0;
}
