/*
 * Inside the conformance suite: the case table, the per-case context and
 * the raw-socket and frame helpers the cases are written with.
 *
 * Helpers that check something return 0 when it holds and CF_FAIL with the
 * reason recorded in the context when it does not, so a case reads as a
 * list of CF_TRY(...) lines. Everything a case opens (sockets, buffers,
 * mappings) is registered in its context and released by the runner, so a
 * case may return at any point.
 */
#ifndef HF_CF_INTERNAL_H
#define HF_CF_INTERNAL_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include <hairfilter/hairfilter.h>

#include "conformance.h"
#include "hfproto.h"

enum { CF_PASS = 0, CF_FAIL = -1, CF_SKIP = 1 };

/* What a case needs from the server under test; the runner skips it, with
 * the reason, where the server does not offer it. */
#define CF_NEED_UNIX   0x01u   /* a Unix-socket URL */
#define CF_NEED_TCP    0x02u   /* a TCP URL */
#define CF_NEED_SHM    0x04u   /* HELLO_OK bit 1 (shared memory on this connection) */
#define CF_NEED_NO_SHM 0x08u   /* HELLO_OK bit 1 clear */
#define CF_NEED_AUTH   0x10u   /* a listener that refuses a HELLO without the token */
#define CF_NEED_V2     0x20u   /* the server speaks version 2 */

/* What the probe learned about the server before the first case. */
typedef struct cf_server {
  int is_unix;
  int auth;                          /* refuses a HELLO without a token */
  int speaks[HFP_VERSION + 2];       /* speaks[k]: a HELLO offering k..k is accepted */
  int version;                       /* negotiated when offering 1..HFP_VERSION */
  hfp_hello_ok hello;                /* its HELLO_OK at that version */
  hfp_variant variants[HFP_MAX_VARIANTS];
  int nv;
  int probe;                         /* the variant of ordinary frames: the fewest spp */
  int pw, ph;                        /* ordinary frame size: 8x8, or the limits if smaller */
  uint8_t *reference;                /* result of the ordinary frame (f32), for the health check */
  size_t reference_len;
} cf_server;

typedef struct cf_test {
  const cf_options *o;
  const cf_server *srv;
  const struct cf_case *c;
  char why[768];
  int fds[512];
  int nfds;
  void **allocs;                     /* grows as the case keeps more */
  int nallocs, cap_allocs;
  struct {
    void *p;
    size_t n;
  } maps[32];
  int nmaps;
} cf_test;

typedef struct cf_case {
  const char *name;
  const char *rule;                  /* what PROTOCOL.md says, in a line */
  unsigned needs;                    /* CF_NEED_* */
  int (*run)(cf_test *t, intptr_t arg);
  intptr_t arg;
} cf_case;

/* Case tables, each ended by an entry with name NULL. */
extern const cf_case cf_cases_frame[], cf_cases_handshake[], cf_cases_filter[],
    cf_cases_control[], cf_cases_shm[], cf_cases_flow[], cf_cases_client[];

/* ---- verdicts ------------------------------------------------------------ */

int cf_fail(cf_test *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
int cf_skip(cf_test *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
#define CF_CHECK(t, cond, ...)                        \
  do {                                                \
    if (!(cond)) return cf_fail((t), __VA_ARGS__);    \
  } while (0)
#define CF_TRY(expr)            \
  do {                          \
    int cf_rc_ = (expr);        \
    if (cf_rc_) return cf_rc_;  \
  } while (0)

/* Registers memory for release after the case (NULL-safe); returns p. */
void *cf_keep(cf_test *t, void *p);
void *cf_alloc(cf_test *t, size_t n);
int cf_keep_fd(cf_test *t, int fd);
/* Closes a registered socket now. */
void cf_close(cf_test *t, int fd);

/* ---- raw sockets ---------------------------------------------------------- */

/* A frame as read: the header and its payload (registered). */
typedef struct cf_frame {
  hfp_header h;
  uint8_t *p;
  int passed_fd;                     /* a descriptor that came with it, or -1 */
} cf_frame;

enum { CF_GOT = 1, CF_EOF = 0, CF_TIMEOUT = -2 };

int cf_connect(cf_test *t, int *fd);
/* A tls: URL's connected TCP socket tcp wrapped (cf_tls.c): the descriptor
 * a case uses as it would the socket, or -1 with why (tcp is closed). */
int cf_tls_wrap(const cf_options *o, const hfp_url *u, int tcp, char *why, size_t whylen);
/* Connects and completes a HELLO offering lo..hi with the suite's token. */
int cf_connect_hello(cf_test *t, int lo, int hi, int *fd, hfp_hello_ok *ok);
int cf_send(cf_test *t, int fd, const void *buf, size_t n);
/* Sends n bytes, with a descriptor attached (SCM_RIGHTS) when passed >= 0,
 * within timeout_ms: 0, the bytes left unsent when the peer read nothing
 * in time, or -1 with errno. */
int cf_send_raw(int fd, const void *buf, size_t n, int passed, int timeout_ms);
/* Sends buf with a descriptor attached (SCM_RIGHTS). */
int cf_send_with_fd(cf_test *t, int fd, const void *buf, size_t n, int passed);
void cf_shutdown_wr(int fd);
/* Reads one frame within timeout_ms: CF_GOT, CF_EOF (closed or reset before
 * a frame began), CF_TIMEOUT, or CF_FAIL (a partial frame, a bad header). */
int cf_read(cf_test *t, int fd, int timeout_ms, cf_frame *f);
/* The next frame must be of type; CF_FAIL names what came instead. */
int cf_expect(cf_test *t, int fd, int type, cf_frame *f);
/* The next frame must be an ERROR with a code in codes (a mask of 1 << code),
 * the fatal flag and the request id given; a fatal one must be followed by
 * the close. */
int cf_expect_error_in(cf_test *t, int fd, unsigned codes, int fatal, uint32_t id);
int cf_expect_error(cf_test *t, int fd, int code, int fatal, uint32_t id);
/* The server must close without sending anything (within the timeout). */
int cf_expect_eof(cf_test *t, int fd);
/* Nothing may arrive for quiet_ms, and the connection stays open. */
int cf_expect_quiet(cf_test *t, int fd);
/* A reply to a FILTER under load: 1 for a non-fatal BUSY (e filled when
 * not NULL), 0 for anything but an ERROR, CF_FAIL (recorded) for any other
 * ERROR. */
int cf_busy(cf_test *t, const cf_frame *r, hfp_error *e);
/* The connection still serves: LIST_VARIANTS gets VARIANTS. */
int cf_still_serves(cf_test *t, int fd);
/* PROTOCOL.md's name of a message type ("RESULT"), or "type N" (in buf). */
const char *cf_type_name(int type, char buf[16]);
/* A description of a frame for messages ("ERROR BUSY (fatal) id 3: ..."). */
const char *cf_describe(const cf_frame *f, char *buf, size_t cap);
#define CF_CODE(c) (1u << (c))

/* ---- frames -------------------------------------------------------------- */

/* Offsets inside a FILTER frame (header included), from PROTOCOL.md. */
enum {
  CF_FILTER_VLEN = HFP_HEADER_SIZE + 0,
  CF_FILTER_FLAGS = HFP_HEADER_SIZE + 2,
  CF_FILTER_WIDTH = HFP_HEADER_SIZE + 4,
  CF_FILTER_HEIGHT = HFP_HEADER_SIZE + 8,
  CF_FILTER_SPP = HFP_HEADER_SIZE + 12,
  CF_FILTER_IN_DTYPE = HFP_HEADER_SIZE + 14,
  CF_FILTER_OUT_DTYPE = HFP_HEADER_SIZE + 15,
  CF_FILTER_HAIR = HFP_HEADER_SIZE + 16,
  CF_FILTER_LIGHT = HFP_HEADER_SIZE + 28,
  CF_FILTER_BG = HFP_HEADER_SIZE + 40,
  CF_FILTER_NAME = HFP_HEADER_SIZE + 52,
};

/* Sample values of a frame's features. */
enum {
  CF_FEAT_PLAUSIBLE = 0,   /* renderer-like values in the FEATURES.md ranges */
  CF_FEAT_NAN,             /* some samples NaN (sanitised by the server) */
  CF_FEAT_HUGE,            /* finite values far out of range (clamped) */
  CF_FEAT_NEGATIVE,        /* negative colours, alphas and depths */
  CF_FEAT_COVERED,         /* every sample covered with alpha `alpha` */
};

typedef struct cf_filter {
  const char *variant;               /* NULL: the probe variant */
  uint32_t id;
  uint16_t flags;                    /* FILTER flags */
  uint32_t width, height;            /* 0: the ordinary size */
  int spp;                           /* 0: the variant's */
  int in_dtype, out_dtype;
  float hair[3], light[3], bg[3];
  int features;                      /* CF_FEAT_* */
  float alpha;                       /* for CF_FEAT_COVERED */
  uint32_t seed;
  /* With HFP_FILTER_SHM: the reference. */
  uint32_t segment;
  uint64_t shm_in, shm_out, shm_rgba;
  /* With HFP_FILTER_DEADLINE (version 4): the budget after the name. */
  uint32_t budget_us;
} cf_filter;

/* libhairfilter's options: name, token (NULL: none), timeout_ms. */
hfc_options cf_client_options(const char *name, const char *token, int timeout_ms);
/* The ordinary frame f (f32 in and out) as a libhairfilter request, from in
 * (cf_features_bytes(f)) into out (out_bytes). */
hfc_request cf_client_request(const cf_filter *f, const void *in, void *out, size_t out_bytes);

/* Fills the fields left 0 (variant, size, spp, colours) with ordinary ones. */
void cf_filter_defaults(const cf_test *t, cf_filter *f);
/* Bytes of the features the fields imply (0 when out of the codec's domain). */
uint64_t cf_features_bytes(const cf_filter *f);
/* Writes the features of f (f->features kind, f->in_dtype) to dst. */
void cf_fill_features(const cf_filter *f, void *dst);
/* A whole FILTER frame (registered) of f; *len its size. The header's length
 * counts what is written, so the caller may patch fields afterwards. */
uint8_t *cf_filter_frame(cf_test *t, const cf_filter *f, size_t *len);
/* The frame's header length field set to (length); returns length. */
void cf_set_length(uint8_t *frame, uint32_t length);
size_t cf_hello_frame(uint8_t *buf, size_t cap, int lo, int hi, const char *name,
                      const char *token);
/* A 16-byte header (and nothing else) into buf. */
void cf_header(uint8_t *buf, int type, uint16_t flags, uint32_t id, uint32_t length);

/* Reads the RESULT for f (sent with id) and checks it against PROTOCOL.md:
 * status 0, dtype, flags (only those version allows), sizes, batch within
 * max_batch, timing parts within the total, every value finite and inside
 * its channel's range (FEATURES.md), the composite by its formula. With
 * shm_mem the tensors are read from the segment. result (may be NULL) gets a
 * registered f32 copy of the result channels. */
int cf_check_result(cf_test *t, const cf_frame *fr, const cf_filter *f, int version,
                    const uint8_t *shm_mem, float **result, uint8_t *result_flags);
/* What is malformed in a RESULT that hfp_decode_result refused with rc:
 * for a length, the bytes it has and the bytes its fields need. */
const char *cf_result_malformed(const cf_frame *fr, int rc, char *buf, size_t cap);
/* Sends f on fd and checks its RESULT (cf_check_result). */
int cf_filter_ok(cf_test *t, int fd, const cf_filter *f, int version, float **result,
                 uint8_t *result_flags);

/* ---- shared memory ------------------------------------------------------- */

/* SHM_CREATE of bytes on fd; SHM_CREATED must come with a descriptor, which
 * is mapped (registered) into *mem when mem is not NULL, and closed. */
int cf_shm_create(cf_test *t, int fd, uint64_t bytes, uint32_t *segment, uint8_t **mem);
size_t cf_shm_create_frame(uint8_t *buf, uint64_t bytes);
size_t cf_shm_destroy_frame(uint8_t *buf, uint32_t segment);

/* ---- the ordinary client -------------------------------------------------- */

/* What an ordinary libhairfilter client gets for the probe frame: 0 when it
 * is served and its result equals the reference. */
int cf_health(cf_test *t);

/* ---- the JUnit report (cf_junit.c) ---------------------------------------- */

typedef struct cf_record {
  const char *name;
  int rc;                            /* CF_PASS, CF_FAIL, CF_SKIP */
  char *why;
  double ms;
} cf_record;

typedef struct cf_report {
  FILE *f;                           /* NULL: no report asked for */
  const char *path, *suite;
  cf_record *rec;
  int n, cap;
  double t0;
  char stamp[32];
} cf_report;

/* Text as XML character data or an attribute value: markup escaped, every
 * byte that is not valid UTF-8 of a character XML 1.0 allows written as the
 * text \xNN. */
void cf_xml_text(FILE *f, const char *text);
/* Opens path (NULL: no report) for the suite named suite; -1 with the
 * reason printed to out when it cannot be written. */
int cf_report_open(cf_report *r, const char *path, const char *suite, FILE *out);
void cf_report_add(cf_report *r, const char *name, int rc, const char *why, double ms);
/* Writes the report and closes it: the cases added, or with error (not
 * NULL) one errored testcase saying why the suite could not run. -1 with
 * the reason printed to out when writing failed. */
int cf_report_close(cf_report *r, const cf_summary *s, const char *error, FILE *out);

/* Milliseconds of CLOCK_MONOTONIC. */
double cf_now_ms(void);
void cf_sleep_ms(int ms);

#endif /* HF_CF_INTERNAL_H */
