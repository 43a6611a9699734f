/*
 * The scripted mock server of the client suite: a Unix socket served by a
 * thread that plays a script against the client library under test. The
 * default script is a well-behaved server (HELLO_OK, VARIANTS, STATS,
 * RESULTs of known values, segments); a case changes one reply, or writes
 * its own script, and asserts what the library makes of it.
 */
#ifndef HF_CF_MOCK_H
#define HF_CF_MOCK_H

#include <pthread.h>
#include <stdint.h>

#include "cf_internal.h"

typedef struct mock mock;

/* Called for each frame the client sends after HELLO: 0 to go on, 1 to close
 * the connection, CF_FAIL (with mk_fail) when the client broke a rule. */
typedef int (*mk_handler)(mock *m, const hfp_header *h, const uint8_t *p);

struct mock {
  char dir[80], path[100], url[120];
  int lfd, fd;
  pthread_t thread;
  int running;
  int timeout_ms;                 /* how long the script waits for the client */
  hfp_hello_ok ok;                /* what HELLO_OK says; version 0: the client's highest */
  int (*script)(mock *m);         /* NULL: mk_session */
  mk_handler on_frame;            /* NULL: mk_reply */
  intptr_t arg;                   /* for the case's script or handler */
  /* What the client sent. */
  hfp_hello hello;
  int seen[HFP_TYPE_MAX + 1];     /* frames by type */
  uint32_t ids[512];              /* FILTER ids in order */
  int nids;
  uint32_t last_segment;
  /* Segments made for the client (SHM_CREATE). */
  struct {
    uint32_t id;
    uint8_t *mem;
    uint64_t bytes;
  } segs[16];
  int nsegs;
  /* The script's verdict. */
  int failed;
  char why[512];
};

/* Starts a mock on a fresh socket; fills m->url. m's script, handler, ok
 * fields set by the caller beforehand are kept (zeros: defaults). */
int mk_start(cf_test *t, mock *m);
/* Waits for the script (after the client has closed), removes the socket,
 * and turns a failed script into a failed case. */
int mk_finish(cf_test *t, mock *m);

int mk_fail(mock *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Accepts the next connection (closing the previous one). */
int mk_accept(mock *m);
/* Reads one frame from the client: 1, 0 at EOF, -1 on timeout or error.
 * *p is malloc'd (free it). */
int mk_read(mock *m, hfp_header *h, uint8_t **p);
int mk_send(mock *m, const void *b, size_t n);
int mk_send_fd(mock *m, const void *b, size_t n, int fd);
/* Reads the client's HELLO and answers with m->ok (version chosen as said). */
int mk_hello(mock *m);
/* The default session: accept, HELLO, then on_frame for each frame. */
int mk_session(mock *m);
/* The well-behaved server's reply to one frame. */
int mk_reply(mock *m, const hfp_header *h, const uint8_t *p);

/* Replies of the well-behaved server, built for a case to change. */
uint8_t *mk_result(mock *m, uint32_t id, const uint8_t *filter_payload, size_t len, size_t *n);
uint8_t *mk_variants(mock *m, int version, size_t *n);
uint8_t *mk_stats(mock *m, int version, size_t *n);
size_t mk_error(uint8_t *buf, uint32_t id, int code, int fatal, const char *msg);

/* The values the well-behaved server puts in a RESULT for a frame whose
 * features carry tag: color, highlight, alpha of pixel p, and the
 * composite. The tag is the frame's first feature value (mk_tag), which the
 * client suite makes different for every request, so a result delivered to
 * the wrong request shows; request ids are no use for that, as a client
 * may number its requests one way and the wire another. */
void mk_values(uint32_t tag, size_t p, float v[3]);
/* The tag of features in dtype (HFP_F32 or HFP_F16): the first value as an
 * integer, 0 when it is not one of 0..65535. */
uint32_t mk_tag(const void *features, int dtype);

/* Variants of the well-behaved server. */
#define MK_VARIANT "Mock"
#define MK_SPP 2

#endif /* HF_CF_MOCK_H */
