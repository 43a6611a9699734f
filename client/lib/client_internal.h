/*
 * client_internal.h: what the files of libhairfilter share. Nothing here is
 * exported (the library is built with -fvisibility=hidden; only the HFC_API
 * functions of hairfilter.h are).
 *
 * A client holds a list of endpoints and up to MAX_CONNS connections: the
 * one in use ("active"), and connections it left after a BUSY failover,
 * which it half-closed and still reads until their last reply ("draining").
 * Requests live in client-wide slots; each remembers its buffers, so that a
 * frame whose connection is lost can be sent again on the next one.
 */
#ifndef HFC_CLIENT_INTERNAL_H
#define HFC_CLIENT_INTERNAL_H

#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/uio.h>

#include "hairfilter.h"
#include "hfproto.h"

#define MAX_ENDPOINTS 8
#define MAX_CONNS 4             /* the active one and up to 3 draining */
#define MAX_SEGS 16
#define CTL_MAX (64 * 1024)     /* largest control reply (VARIANTS, STATS) */
#define MSG_MAX 1024            /* hfc_last_message, endpoint lists included */

typedef struct endpoint {
  char url[320];                /* as written in the list */
  hfp_url addr;
} endpoint;

typedef struct conn {
  int fd;                       /* -1: the slot is free */
  void *ssl;                    /* SSL * on a tls: endpoint, else NULL (tls.c) */
  int endpoint;                 /* index in hfc_client.eps */
  uint64_t serial;              /* never reused: segments name their connection by it */
  int draining;                 /* half-closed: replies still read, nothing sent */
  int inflight;                 /* FILTERs sent on it and not yet answered */
  double quiet_since_us;        /* owing replies, it has sent nothing since (monotonic
                                   us): the last frame it sent began, or the first
                                   FILTER of an idle spell went out */
  int rx_fd;                    /* a descriptor that came with a frame, or -1 */
  char why[320];                /* what ended it, when more than a code says */
  hfc_server_info info;
  /* The server's variants, listed once to match names (request.c). */
  hfc_variant *variants;
  int nvariants, variants_known;
} conn;

typedef struct segment {
  uint32_t id;
  uint8_t *addr;
  size_t size;
  uint64_t conn_serial;         /* the connection that made it; 0 once it is gone */
} segment;

enum { P_FREE = 0, P_SENT, P_QUEUED, P_DONE };

/* One request, from hfc_submit until hfc_wait returns it. */
typedef struct pending {
  int state;
  uint32_t id;                  /* the caller's (hfc_submit), for good */
  uint32_t wire_id;             /* on the connection it was last sent on */
  int conn;                     /* index in hfc_client.conns while P_SENT */
  uint64_t seq;                 /* completion order */
  uint64_t order;               /* submission order, for resending */
  /* the frame, to send it again after a failover */
  char variant[HFP_NAME_MAX + 1];
  uint32_t width, height;
  uint16_t spp;
  uint8_t in_dtype, out_dtype;
  float hair[3], light[3], bg[3];
  const void *features;
  uint64_t features_len;        /* bytes sent from features: the estimate's
                                   included when it follows them */
  int estimate;                 /* hfc_request.estimate */
  const void *estimate_buffer;  /* the estimate in a buffer of its own, or NULL */
  uint64_t estimate_len;        /* bytes sent from estimate_buffer (else 0) */
  uint32_t deadline_us;         /* hfc_request.deadline_us: sent to version 4 and later */
  uint32_t budget_sent;         /* the budget of the last send: deadline_us, or after a
                                   failover what remained of it */
  void *result, *rgba;
  int shm;                      /* the last send went by reference */
  int in_place;                 /* result or rgba overlaps the features: a
                                   failover cannot resend it (the result may
                                   already have overwritten them) */
  int resends;
  double t_submit;
  hfc_completion comp;
  char *msg;                    /* why it failed, for hfc_last_message (malloc'd) */
} pending;

struct hfc_client {
  endpoint eps[MAX_ENDPOINTS];
  int neps;
  /* the options, defaults filled in */
  char client_name[HFP_NAME_MAX + 1];
  char token[HFP_TOKEN_MAX + 1];
  int timeout_ms, connect_rounds, retry_delay_ms, max_resends;
  unsigned failover;

  conn conns[MAX_CONNS];
  int active;                   /* index of the connection in use, or -1 */
  int last_ep;                  /* endpoint of the connection lost last */
  int broken;                   /* without one: the error that ended the last */
  hfc_server_info info_last;    /* hfc_info when there is no connection */
  uint64_t next_serial;
  int epfd;                     /* hfc_fd: every connection's socket */
  void *tls_ctx;                /* SSL_CTX * when an endpoint is tls: (tls.c) */
  int tls_evfd;                 /* in epfd: readable while OpenSSL holds decrypted bytes */
  int due_fd;                   /* in epfd: a timerfd, readable while a completion waits
                                   that no socket shows, or once a silent connection is
                                   due to be given up (hfci_due_update) */
  char tls_server_name[256];    /* hfc_options.tls_server_name, or "" */
  char *tls_ca_file;            /* a copy of hfc_options.tls_ca_file; NULL: the system's CAs */
  int tls_no_verify_host;

  pending *p;
  int np;                       /* slots */
  int npending;                 /* submitted, not yet returned by hfc_wait */
  uint32_t next_id;
  uint64_t next_seq, next_order;

  segment segs[MAX_SEGS];
  int nsegs;

  /* the control reply being waited for */
  int ctl_type, ctl_conn, ctl_done, ctl_status;
  uint8_t *ctl;
  size_t ctl_len;

  char msg[MSG_MAX];
};

/* ---- errors.c ------------------------------------------------------------ */

/* Clears the message of c (may be NULL) and of this thread: every public
 * call starts with it. */
void hfci_begin(hfc_client *c);
/* Sets the message of c (may be NULL) and of this thread. */
void hfci_msg(hfc_client *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* HFC_E_ARG with a message naming the field. */
int hfci_arg(hfc_client *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Copies a caller's struct of struct_size bytes (its first field) into
 * full, a struct of this header's size already at its init values: fields
 * are appended within a SONAME (hairfilter.h, "ABI"), so one of an older
 * header keeps the rest at their defaults. sizes[0..nsizes) are the sizes
 * of the struct in earlier releases, the first 0.1.0's; a newer header's
 * larger struct is taken when the fields this library lacks are all zero.
 * 0, or HFC_E_ARG naming type.struct_size when it is 0, another size, or
 * larger with a set field past ours; init names the function that sets
 * it. */
int hfci_take_struct(hfc_client *c, const char *type, const void *given, void *full,
                     size_t full_size, const size_t *sizes, int nsizes, const char *init);

/* ---- endpoints.c ----------------------------------------------------------- */

/* Splits and parses a comma-separated list; HFC_E_URL with why. */
int hfci_parse_endpoints(const char *url, endpoint *eps, int *neps, char *why, size_t whylen);
/* Opens, handshakes and makes active a connection to the first endpoint
 * from `start` on (wrapping) that takes one, over the retry policy's
 * rounds. 0, or the last endpoint's error with a message naming each. */
int hfci_connect_next(hfc_client *c, int start);
/* The same, for leaving endpoint `leave` (tried last of all: never). */
int hfci_connect_other(hfc_client *c, int leave);
/* Closes connection k and frees its slot (no failover: see hfci_conn_lost). */
void hfci_conn_close(hfc_client *c, int k);
/* Whether err moves the client to another endpoint: lost = 1 for a
 * connection that failed with it, 0 for a request answered with it. */
int hfci_can_failover(const hfc_client *c, int err, int lost);
/* Whether, its connection gone, the client goes on to the next endpoint of
 * its list by itself (a list, HFC_FAILOVER_LOST, no HFC_FAILOVER_NEVER):
 * the next call connects (hfci_need_conn). Else the engine must connect
 * again, which the messages of a loss say. */
int hfci_follows_list(const hfc_client *c);

/* ---- client.c -------------------------------------------------------------- */

/* Milliseconds from now to deadline_us (monotonic), rounded up, 0 once it
 * passed; -1 (no limit) when timeout_ms, the wait it ends, is < 0. */
int hfci_ms_left(double deadline_us, int timeout_ms);
/* poll() for events on fd, up to timeout_ms in all however many signals
 * interrupt it: 0, HFC_E_TIMEOUT or HFC_E_IO. */
int hfci_wait_fd(int fd, short events, int timeout_ms);
/* Reads exactly n bytes from fd, waiting up to timeout_ms whenever none
 * come; a descriptor passed with them goes to *rx_fd when that is -1, any
 * other is closed (rx_fd may be NULL). 0, or HFC_E_CLOSED / HFC_E_IO /
 * HFC_E_TIMEOUT. */
int hfci_recv_fd(int fd, int *rx_fd, void *buf, size_t n, int timeout_ms);
/* Sends the n (1..HFCI_MAX_IOV) buffers of iov in order on fd (one
 * sendmsg() while the socket takes them), waiting up to timeout_ms whenever
 * it is full. 0, or HFC_E_CLOSED / HFC_E_IO / HFC_E_TIMEOUT. */
#define HFCI_MAX_IOV 3
int hfci_send_fd(int fd, int timeout_ms, const struct iovec *iov, int n);
/* The same through TLS when ssl is not NULL (no descriptors travel then):
 * the calls every frame goes through. hfci_send_io sends one buffer. */
int hfci_send_iov(int fd, void *ssl, int timeout_ms, const struct iovec *iov, int n);
int hfci_send_io(int fd, void *ssl, int timeout_ms, const void *buf, size_t n);
int hfci_recv_io(int fd, void *ssl, int *rx_fd, void *buf, size_t n, int timeout_ms);
/* Reads one frame from any connection (waiting up to timeout_ms for one to
 * start) and dispatches it. 0 when something happened (a frame, or a
 * connection lost and dealt with), HFC_E_TIMEOUT, or the error that left
 * the client without a connection. */
int hfci_pump(hfc_client *c, int timeout_ms);
/* Connection k failed with err: its requests go to the next endpoint when
 * the policy allows, else complete with err. */
void hfci_conn_lost(hfc_client *c, int k, int err);
/* A send on connection k failed with err: the replies the server wrote
 * before it closed are read and dispatched first (a plain socket keeps
 * them), then the connection is lost as hfci_conn_lost says. */
void hfci_send_failed(hfc_client *c, int k, int err);
/* A connection owing replies that has sent nothing for the client's
 * timeout is stuck (a stopped or wedged server keeps its socket open):
 * it is lost with HFC_E_TIMEOUT, so its frames fail over or complete.
 * hfc_wait calls it, as hfc_filter ends a silent wait of its own. */
void hfci_check_silent(hfc_client *c);
/* Gives connection k up as silent (HFC_E_TIMEOUT), its reason saying that
 * hfc_options.timeout_ms passed without a reply and what to change. */
void hfci_give_up_silent(hfc_client *c, int k);
/* Milliseconds until hfci_check_silent would end a connection (0: now),
 * or -1 when none owes replies or the timeout is off. */
int hfci_silence_left_ms(const hfc_client *c);
/* Arms c->due_fd after a call changed what is pending: at once when a
 * completion waits (one the library made itself, a failed send or a lost
 * connection, shows on no socket; one read ahead of another, neither),
 * when the first silent connection is due to be given up (which only a
 * call notices), else never. So hfc_fd polls readable whenever hfc_wait(c,
 * 0) has something to do, and an engine that polls it without a timeout
 * cannot wait for ever. */
void hfci_due_update(hfc_client *c);
/* Sends queued requests while the active connection has room, and closes
 * draining connections that have nothing left to answer. */
void hfci_progress(hfc_client *c);
/* Sends a control request on the active connection and waits for its
 * reply (payload in c->ctl, to be freed by the caller). Sent again on the
 * next connection when the active one fails over meanwhile. */
int hfci_control(hfc_client *c, const uint8_t *frame, size_t len, int reply_type);
/* An active connection, connecting anew when a list's endpoints were all
 * lost earlier: its index, or the error. */
int hfci_need_conn(hfc_client *c);
/* p is complete with status; why (may be NULL) is what hfc_last_message
 * says when the completion is returned. */
void hfci_finish(hfc_client *c, pending *p, int status, const char *why);
/* The completion of p to the caller, its message set; the slot is free. */
void hfci_release(hfc_client *c, pending *p, hfc_completion *done);

/* ---- tls.c ------------------------------------------------------------------- */

/* The TLS context of a client whose list has a tls: endpoint, from the
 * options' CA file, client certificate and key: 0, or HFC_E_ARG / HFC_E_NOMEM
 * with why naming the option and OpenSSL's reason. */
int hfci_tls_setup(hfc_client *c, const hfc_options *o, char *why, size_t whylen);
void hfci_tls_free(hfc_client *c);
/* With TLS: an eventfd in c->epfd that hfci_tls_signal keeps readable while
 * a connection's decrypted bytes wait in OpenSSL, so that hfc_fd polls
 * readable for them too. 0, or HFC_E_IO with why. */
int hfci_tls_poll_setup(hfc_client *c, char *why, size_t whylen);
void hfci_tls_signal(hfc_client *c);
/* TLS handshake on the connected socket fd to u (certificate and host name
 * checked): 0 with *ssl set, or HFC_E_TLS / HFC_E_TIMEOUT with
 * hfci_tls_why() saying what failed and what to check. */
int hfci_tls_connect(hfc_client *c, int fd, const hfp_url *u, void **ssl);
int hfci_tls_send(void *ssl, int fd, int timeout_ms, const struct iovec *iov, int n);
int hfci_tls_recv(void *ssl, int fd, void *buf, size_t n, int timeout_ms);
/* Decrypted bytes waiting in OpenSSL, which poll() on the socket cannot see. */
int hfci_tls_pending(void *ssl);
/* Sends close_notify, TLS's half-close. */
int hfci_tls_shutdown_wr(void *ssl);
void hfci_tls_close(void *ssl);
/* This thread's explanation of the last TLS failure. */
const char *hfci_tls_why(void);

/* ---- sigpipe.c ---------------------------------------------------------------- */

/* SIGPIPE blocked in this thread around an OpenSSL call that may write to
 * a socket whose peer is gone (OpenSSL's write(2) has no MSG_NOSIGNAL):
 * block before the call, restore after it; a SIGPIPE the call raised is
 * consumed, so the write just fails with EPIPE. */
typedef struct hfci_sigpipe {
  sigset_t old;
  int was_pending, blocked;
} hfci_sigpipe;
void hfci_sigpipe_block(hfci_sigpipe *s);
void hfci_sigpipe_restore(hfci_sigpipe *s);

/* ---- queries.c --------------------------------------------------------------- */

/* LIST_VARIANTS into out (up to max); *count is the server's number. */
int hfci_list(hfc_client *c, hfc_variant *out, int max, int *count);

/* ---- request.c -------------------------------------------------------------- */

/* Sends p on the active connection (by reference when its tensors lie in one
 * of that connection's segments). 0, or the connection's error. */
int hfci_send_request(hfc_client *c, pending *p);
/* Whether p, failed with err (lost as for hfci_can_failover), may be sent
 * again on another connection. */
int hfci_can_resend(const hfc_client *c, const pending *p, int err, int lost);

/* ---- shm.c ------------------------------------------------------------------ */

/* When every tensor of p lies in one segment of the active connection, fills
 * f's references and returns that segment; else NULL (the socket path). */
const segment *hfci_shm_place(const hfc_client *c, hfp_filter *f, const pending *p);
/* Segments of connection serial s become the caller's memory alone. */
void hfci_shm_orphan(hfc_client *c, uint64_t serial);
/* Unmaps every segment (hfc_close). */
void hfci_shm_release_all(hfc_client *c);

#endif /* HFC_CLIENT_INTERNAL_H */
