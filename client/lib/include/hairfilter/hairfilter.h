/*
 * libhairfilter: the client side of hairfilterd (protocol versions 1 to 4,
 * protocol/PROTOCOL.md). C99 and C++ (hairfilter.hpp wraps it in RAII).
 * The documents cited here as protocol/PROTOCOL.md, protocol/FEATURES.md
 * and client/lib/README.md (the guide) are installed beside it in
 * share/doc/hairfilter/ as PROTOCOL.md, FEATURES.md and CLIENT.md.
 *
 *   hfc_client *c;
 *   if (hfc_connect("unix:/run/hairfilterd/hairfilterd.sock", NULL, &c)) ...
 *   hfc_request r;
 *   hfc_request_init(&r);
 *   r.variant = "Base"; r.width = w; r.height = h; r.spp = 4;
 *   r.features = in;  r.features_bytes = in_bytes;
 *   r.result = out;   r.result_bytes = out_bytes;
 *   hfc_timing t;
 *   int rc = hfc_filter(c, &r, &t);    // or hfc_submit() + hfc_wait()
 *
 * Buffers belong to the caller: features are sent from where they are and
 * results are received straight into the caller's arrays, whose sizes the
 * request gives so that a short buffer is refused, never overrun. A client
 * is not thread-safe: use one per thread, or guard it. Every blocking call
 * gives up after the timeout of hfc_options (default 30 s), so nothing here
 * hangs on a dead server.
 *
 * Errors are negative HFC_E_* codes; those the server sent keep the wire
 * code's number (HFC_E_BUSY == -HFP_E_BUSY, see protocol/PROTOCOL.md).
 * hfc_strerror() names the code; hfc_last_message() says what exactly went
 * wrong: the field of a bad argument, the endpoint and the system's reason
 * of a failed connect, the server's own words.
 *
 * ABI: the shared library's SONAME is libhairfilter.so.<major> from 1.0 on
 * and libhairfilter.so.0.<minor> before (every 0.x minor version may change
 * the ABI; CHANGELOG.md says what changed). The structs the caller fills
 * (hfc_options, hfc_request) start with struct_size, so fields can be
 * appended to them within a SONAME; hfc_options_init() and
 * hfc_request_init() set it. The library takes the sizes they have had
 * and a newer header's larger one whose fields past its own are zero;
 * another struct_size is HFC_E_ARG. The structs the library fills change only
 * with a new SONAME.
 */
#ifndef HAIRFILTER_H
#define HAIRFILTER_H

#include <stddef.h>
#include <stdint.h>

#include <hairfilter/hairfilter_version.h>

/* Only the hfc_* functions are exported from libhairfilter.so. */
#if defined(HFC_BUILDING) && defined(__GNUC__)
#define HFC_API __attribute__((visibility("default")))
#else
#define HFC_API
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* ---- version ----------------------------------------------------------- */

/* The version of the library loaded at run time, "MAJOR.MINOR.PATCH"
 * (HAIRFILTER_VERSION_STRING of its build; the headers' own version is
 * HAIRFILTER_VERSION_STRING). Never NULL. */
HFC_API const char *hfc_version(void);

/* ---- errors ---------------------------------------------------------------- */

#define HFC_OK               0
/* reported by the server (or a malformed reply from it) */
#define HFC_E_VERSION        -1
#define HFC_E_PROTOCOL       -2
#define HFC_E_UNKNOWN_VARIANT -3
#define HFC_E_TOO_LARGE      -4
#define HFC_E_LENGTH         -5
#define HFC_E_BUSY           -6   /* retry later: a queue, in-flight, memory or connection limit is full */
#define HFC_E_UNAUTHORIZED   -7
#define HFC_E_INTERNAL       -8
#define HFC_E_UNSUPPORTED    -9
#define HFC_E_SHUTTING_DOWN  -10
#define HFC_E_INVALID        -11
#define HFC_E_EXPIRED        -13  /* the frame's budget (hfc_request.deadline_us) passed
                                     while it was queued: not computed; retrying cannot help */
#define HFC_E_CANCELLED      -14  /* hfc_cancel took the frame off the server's queue: not
                                     computed */
/* local */
#define HFC_E_ARG            -100 /* bad argument: hfc_last_message names the field */
#define HFC_E_URL            -101 /* not unix:PATH, tcp:HOST:PORT, tcp:PORT, tls:HOST:PORT or tls:PORT (or a list of them) */
#define HFC_E_CONNECT        -102 /* could not connect: errno and hfc_last_message say why */
#define HFC_E_IO             -103 /* the connection failed */
#define HFC_E_TIMEOUT        -104 /* no answer within the timeout */
#define HFC_E_CLOSED         -105 /* the server closed the connection */
#define HFC_E_NOMEM          -106
#define HFC_E_INFLIGHT       -107 /* as many requests pending as the server allows, or 16 segments */
#define HFC_E_NOPENDING      -108 /* hfc_wait with nothing in flight */
#define HFC_E_TLS            -109 /* TLS failed: a certificate refused (expired, another CA,
                                     another host name), a client certificate missing or
                                     refused, a peer that does not speak TLS;
                                     hfc_last_message names it */

/* The code's meaning in a few words ("server busy: ..."); never NULL. */
HFC_API const char *hfc_strerror(int err);

typedef struct hfc_client hfc_client;

/* What went wrong in the last call that failed: with c, the last call on c;
 * with c NULL, the last call in this thread on any client or none (so a
 * failed hfc_connect, which returns no client, explains itself). "" after
 * a call that succeeded: every call clears it first. Valid until the next
 * call on c (c NULL: in this thread). Examples:
 *   hfc_request.features_bytes is 1000: a 64x48 frame of 4 spp in f32
 *     (hfc_request.in_dtype) needs 294912 ([height][width][spp*6]; ...)
 *   unix:/run/hairfilterd/hairfilterd.sock: connect: Permission denied (...)
 *   unknown variant 'Bsae': this server has Base, Small, Large */
HFC_API const char *hfc_last_message(const hfc_client *c);

/* ---- connection -------------------------------------------------------- */

/* Failover when the URL lists several endpoints (hfc_options.failover). */
#define HFC_FAILOVER_LOST  0x1u  /* a connection lost, closed, timed out or shutting
                                    down: move to the next endpoint, resend its frames
                                    (not those filtered in place, whose result overlaps
                                    their features: they fail with the loss) */
#define HFC_FAILOVER_BUSY  0x2u  /* a frame answered BUSY: send it to the next endpoint
                                    and move there */
#define HFC_FAILOVER_NEVER 0x100u /* neither: a lost connection fails its frames */

typedef struct hfc_options {
  size_t struct_size;        /* sizeof(hfc_options), set by hfc_options_init() */
  const char *client_name;   /* shown in the server's logs; NULL: "libhairfilter"; 1..64
                                printable ASCII characters without spaces */
  const char *token;         /* auth token (TCP); NULL: none; up to 256 characters */
  int timeout_ms;            /* per blocking step, ms; 0: 30000; < 0: no limit. A
                                connection owing replies that sends nothing for this
                                long is given up (HFC_E_TIMEOUT): keep it above the
                                slowest frame, not at a frame budget (that is
                                hfc_wait's timeout, which leaves frames pending) */
  /* The retry policy, for a URL that lists several endpoints:
   * hfc_connect tries them in order; once connected, what failover allows
   * moves the client to the next endpoint that answers. */
  int connect_rounds;        /* passes over the whole list before giving up; 0: 1 */
  int retry_delay_ms;        /* pause between passes, milliseconds; 0: 100 */
  int max_resends;           /* times one frame may be sent again on another
                                connection; 0: 2; < 0: never */
  unsigned failover;         /* HFC_FAILOVER_* bits; 0: LOST | BUSY */
  /* TLS, for tls:HOST:PORT endpoints (appended after 0.1.0). The server's
   * certificate must chain to a CA of tls_ca_file and name the URL's host
   * (or tls_server_name) in its subjectAltName; TLS 1.2 at least. Set with
   * no tls: endpoint in the URL they are HFC_E_ARG: the connection would be
   * plain, its token and frames unencrypted. */
  const char *tls_ca_file;   /* PEM file of trusted CA certificates; NULL: the system's
                                (/etc/ssl/certs) */
  const char *tls_cert_file; /* PEM client certificate (chain) for mutual TLS; NULL: none */
  const char *tls_key_file;  /* its PEM private key: both or neither (else HFC_E_ARG) */
  const char *tls_server_name; /* name the server's certificate must carry; NULL: the
                                  URL's host */
  int tls_no_verify_host;    /* 1: accept any name on a certificate the CA signed (a
                                test set-up only: anyone the CA certified could
                                pose as the server) */
} hfc_options;

/* Sets size bytes at s to zero, for hfc_options_init and hfc_request_init.
 * Byte by byte rather than memset, so the header needs no <string.h>; an
 * aggregate initialiser would warn under -Wextra in C and C++. */
static inline void hfc_struct_clear(void *s, size_t size) {
#ifdef __cplusplus
  unsigned char *p = static_cast<unsigned char *>(s);
#else
  unsigned char *p = (unsigned char *)s;
#endif
  size_t i;
  for (i = 0; i < size; i++) p[i] = 0;
}

/* Options of this header's size with every field at its default (zero),
 * C and C++ alike:
 *   hfc_options o;
 *   hfc_options_init(&o);
 *   o.client_name = "my-engine"; */
static inline void hfc_options_init(hfc_options *o) {
  hfc_struct_clear(o, sizeof *o);
  o->struct_size = sizeof *o;
}

/* Connects and performs the HELLO handshake. opt may be NULL (defaults).
 *
 * url is one endpoint or a comma-separated list of up to 8 of them, each in
 * the grammar of protocol/PROTOCOL.md ("Addresses"): "unix:/path/to.sock",
 * "tcp:HOST:PORT", "tcp:[v6addr]:PORT" or "tcp:PORT" (127.0.0.1); HOST may
 * be a name. "tls:HOST:PORT" (and tls:[v6addr]:PORT, tls:PORT) is TCP with
 * TLS: the certificate and host name are checked as hfc_options says, and a
 * refusal is HFC_E_TLS with hfc_last_message naming the problem. With a list, endpoints that cannot be reached, close, or refuse
 * the handshake with BUSY or SHUTTING_DOWN are passed over (the retry policy
 * of hfc_options), and later calls fail over as hfc_options.failover says.
 * A single URL never fails over: after a connection error every pending
 * request completes with that error, and a new hfc_connect is needed.
 *
 * Returns 0 with *out set, or: HFC_E_URL (hfc_check_url says why), HFC_E_ARG
 * (hfc_last_message(NULL) names the option), HFC_E_CONNECT with errno set
 * to the last endpoint's connect error (ENOENT, ECONNREFUSED, EACCES, ...;
 * 0 when its host name did not resolve), HFC_E_TIMEOUT when a connection
 * was made but no answer to HELLO came within timeout_ms (a stopped or
 * stuck server: the kernel accepts connections for it), or the
 * handshake's error (HFC_E_UNAUTHORIZED, HFC_E_VERSION, HFC_E_BUSY, ...).
 * hfc_last_message(NULL) then names every endpoint and its reason. */
HFC_API int hfc_connect(const char *url, const hfc_options *opt, hfc_client **out);
/* Checks url (one endpoint or a list) without connecting: 0, or HFC_E_URL
 * with why (when not NULL) naming the URL and what is wrong with it, e.g.
 * "bad URL 'tcp:h:70000': port 70000 is outside 1..65535". */
HFC_API int hfc_check_url(const char *url, char *why, size_t whylen);
/* Closes the connections and unmaps shared segments; requests still in
 * flight are abandoned. NULL is allowed. */
HFC_API void hfc_close(hfc_client *c);

/* What the server in use said about itself in the handshake. A request
 * over its limits (max_width x max_height; max_frame_bytes for a frame
 * sent through the socket, its FILTER fields and tensors; f16 or f32 not
 * offered) is refused by hfc_filter / hfc_submit before anything is sent,
 * HFC_E_TOO_LARGE (HFC_E_UNSUPPORTED for the dtype) with the limit and the
 * frame's size in hfc_last_message, and the connection stays usable. They
 * are the handshake's: a reload of the server (SIGHUP) that changes the
 * variants may raise or lower max_width and max_height for new connections
 * only, and a frame over the new limit is HFC_E_TOO_LARGE naming it. */
typedef struct hfc_server_info {
  char name[65];
  int version;               /* protocol version of this connection */
  int max_width, max_height, max_spp;
  int max_inflight;          /* per connection */
  int max_batch, queue_size;
  int auth_required;
  int f16, f32;              /* dtypes accepted */
  int shm;                   /* hfc_shm_alloc works on this connection */
  uint64_t max_frame_bytes;
  char software_version[65]; /* the server's version ("0.1.0"); "" from servers
                                that do not say (protocol version 1) */
} hfc_server_info;

/* The server in use; after a failover, the new one. Never NULL: with c
 * NULL, an info of all zeros (and hfc_last_message(NULL) says so). */
HFC_API const hfc_server_info *hfc_info(const hfc_client *c);
/* The endpoint in use, as written in the URL ("unix:/a"); "" with c NULL,
 * and once the connection of a single-endpoint URL is lost. */
HFC_API const char *hfc_endpoint(const hfc_client *c);
/* A descriptor that polls readable whenever hfc_wait(c, 0, ...) has
 * something to do, for an engine's own event loop: a reply waiting on any
 * of the client's connections (over TLS, also one OpenSSL holds decrypted
 * that the socket no longer shows), a completion the library made itself
 * (a frame failed with its lost connection), or a connection that owes
 * replies and has been silent for hfc_options.timeout_ms (hfc_wait gives
 * it up). So polling it without a timeout never waits for ever on a
 * stopped server; it may poll readable with no completion left
 * (hfc_wait then returns HFC_E_TIMEOUT). Stays the same across failovers.
 * Not the socket: use it only to poll. HFC_E_ARG with c NULL. */
HFC_API int hfc_fd(const hfc_client *c);

/* ---- variants ----------------------------------------------------------- */

#define HFC_MAX_STATS 16

typedef struct hfc_variant {
  char name[65];
  char backend[65];          /* "cudnn", "cpu", "cpu-ref" */
  char precision[65];        /* "fp32", "fp16" */
  int spp;
  int num_levels;
  int levels[8];             /* channels per U-Net level */
  /* The range [lo, hi] of each input statistic the variant was trained on
   * (protocol/FEATURES.md, "Input statistics"; statistic k is bit k):
   * frames outside it come back with hfc_timing.out_of_range set. 0: the
   * weights record none, or the server speaks protocol version 1. */
  unsigned range_mask;
  double range_lo[HFC_MAX_STATS], range_hi[HFC_MAX_STATS];
  /* 1: the variant reads stochastic transparency's alpha-corrected estimate
   * besides the samples (protocol/FEATURES.md, "The alpha-corrected
   * estimate"): its requests set hfc_request.estimate. 0 otherwise, and
   * always from servers of protocol versions 1 and 2. */
  int estimate;
} hfc_variant;

/* Fills up to max entries; *count is the number the server has (0..64). */
HFC_API int hfc_list_variants(hfc_client *c, hfc_variant *out, int max, int *count);

/* ---- filtering --------------------------------------------------------- */

typedef enum hfc_dtype { HFC_F32 = 0, HFC_F16 = 1 } hfc_dtype;

/* One frame. Tensors are NHWC and dense, top row first (an engine reading
 * an OpenGL framebuffer, bottom row first, flips its rows): features
 * [height][width][spp*6] in protocol/FEATURES.md order (sample-major:
 * color, highlight, alpha, depth, tangent.x, tangent.y), result
 * [height][width][3] (color, highlight, alpha), rgba [height][width][4]
 * composited over the background, alpha = hair coverage. f16 is IEEE
 * binary16 as uint16_t. Each buffer's size in bytes goes beside it; a
 * buffer smaller than its tensor (hfc_features_bytes, hfc_output_bytes)
 * is refused with HFC_E_ARG before anything is sent. */
typedef struct hfc_request {
  size_t struct_size;        /* sizeof(hfc_request), set by hfc_request_init() */
  const char *variant;       /* a loaded variant; case does not matter ("base" is Base) */
  int width, height;         /* pixels, 1..65535; the server's limit may be lower
                                (hfc_info()->max_width, max_height: a frame over it is
                                HFC_E_TOO_LARGE before anything is sent) */
  int spp;                   /* samples per pixel, 1..16: the variant's */
  hfc_dtype in_dtype;
  const void *features;
  size_t features_bytes;     /* bytes at features: at least width*height*spp*6*dtype size */
  hfc_dtype out_dtype;
  void *result;
  size_t result_bytes;       /* bytes at result: at least width*height*3*dtype size */
  void *rgba;                /* NULL: no composite */
  size_t rgba_bytes;         /* bytes at rgba: at least width*height*4*dtype size */
  float hair[3], light[3], background[3];   /* linear RGB, finite, for rgba: set them
                                               when rgba is set (hfc_request_init leaves
                                               0; a light of 0,0,0 is refused then) */
  void *user;                /* returned in the completion */
  /* 1: the request carries the frame's alpha-corrected estimate,
   * [height][width][3] in in_dtype (colour, highlight, alpha;
   * protocol/FEATURES.md): in estimate_buffer, or, when that is NULL, after
   * the features in the same buffer, features_bytes then counting both
   * (hfc_features_bytes + hfc_estimate_bytes). Required by variants with
   * hfc_variant.estimate, refused by the others; needs a server of
   * protocol version 3 (hfc_info()->version). */
  int estimate;
  /* The estimate in a buffer of its own (with estimate 1), for a renderer
   * that makes it apart from the samples: it goes out after them with no
   * copy. Through shared memory only when it directly follows the features
   * in the same segment; elsewhere the frame takes the socket. NULL: the
   * estimate follows the features, or there is none. */
  const void *estimate_buffer;
  size_t estimate_bytes;     /* bytes at estimate_buffer: at least width*height*3*dtype size */
  /* The frame's budget in microseconds, counted from its arrival at the
   * server (on the server's clock: no clock sync needed); 0: none. A frame
   * that has not started running when it passes is not computed and
   * completes with HFC_E_EXPIRED (a frame that started runs to the end;
   * compare hfc_timing.server_us with the budget). Needs protocol version
   * 4 (hfc_info()->version >= 4): to an older server the frame goes
   * without it and is computed however late, so an engine that must know
   * checks the version. Sent again after a failover, the frame carries
   * what remains of it (less the time since hfc_submit, on this client's
   * monotonic clock), and one with nothing left completes HFC_E_EXPIRED
   * without being sent. */
  uint32_t deadline_us;
} hfc_request;

/* A request of this header's size with every field zero (NULL buffers,
 * f32, no composite, colours 0); then set what the frame needs. A request
 * of an older header's size is taken with the fields it lacks at these
 * values. */
static inline void hfc_request_init(hfc_request *r) {
  hfc_struct_clear(r, sizeof *r);
  r->struct_size = sizeof *r;
}

/* Bytes of a features tensor of width x height pixels, spp samples of 6
 * features each, in dtype; 0 when a dimension is outside its range. */
HFC_API size_t hfc_features_bytes(int width, int height, int spp, hfc_dtype dtype);
/* Bytes of a frame's alpha-corrected estimate, width x height x 3 values in
 * dtype (hfc_request.estimate); 0 when a dimension is outside its range. */
HFC_API size_t hfc_estimate_bytes(int width, int height, hfc_dtype dtype);
/* Bytes of an output tensor with channels per pixel: 3 for result, 4 for
 * rgba; 0 when a dimension is outside its range. */
HFC_API size_t hfc_output_bytes(int width, int height, int channels, hfc_dtype dtype);

/* What the server said about a result besides its tensors. Microseconds:
 * the server's parts (queue, input, infer, output) add up to at most
 * server_us; total_us is what the caller waited, so total_us - server_us is
 * transfer both ways plus client work (and, after a failover, the time on
 * the connection that was lost). */
typedef struct hfc_timing {
  double queue_us, input_us, infer_us, output_us, server_us;
  double total_us;
  int batch;                 /* frames the server ran together with this one */
  int via_shm;               /* 1: the tensors went through shared memory */
  int out_of_range;          /* 1: the input is outside the range the variant was
                                trained on (hfc_variant.range_*): the result may
                                not be good (always 0 from version-1 servers) */
  int input_sanitised;       /* 1: some samples were non-finite or out of range and
                                the server sanitised them (protocol/FEATURES.md,
                                "Out-of-contract values"); always 0 from version-1
                                servers */
  int resends;               /* times the frame was sent again after a failover */
} hfc_timing;

/* Synchronous: sends r and waits for its result. timing may be NULL; it is
 * filled whatever the outcome: all 0 for a request refused before it was
 * sent, total_us and resends for one that failed after. */
HFC_API int hfc_filter(hfc_client *c, const hfc_request *r, hfc_timing *timing);

/* Asynchronous: sends r and returns with its id, without waiting for the
 * result. Through a socket, sending is writing the whole frame: one larger
 * than the socket's buffers waits while the server reads it (up to
 * hfc_options.timeout_ms); through shared memory only a reference is
 * written, whatever the frame's size. r's buffers (not r
 * itself: features, estimate_buffer, result, rgba) must stay valid until
 * its completion comes out of hfc_wait. At
 * most hfc_info(c)->max_inflight may be pending (HFC_E_INFLIGHT). The first
 * request naming a variant on a connection lists the server's variants
 * once, to match the name without regard to case; a name the server does
 * not have is still sent, and its completion is HFC_E_UNKNOWN_VARIANT with
 * the listed names in hfc_last_message. A request whose spp or estimate
 * flag the listed variant does not match (hfc_variant.spp,
 * hfc_variant.estimate) is HFC_E_ARG before anything is sent, and so is
 * one over the server's announced limits HFC_E_TOO_LARGE (hfc_server_info):
 * the server's refusal would come only after the whole upload. id may be
 * NULL when the caller does not need it (it cannot then hfc_cancel the
 * frame; the completion carries r->user either way). On a server that
 * stopped reading, sending waits up to timeout_ms and may still return
 * HFC_OK: the frame then completes HFC_E_TIMEOUT (every frame submitted
 * completes exactly once). */
HFC_API int hfc_submit(hfc_client *c, const hfc_request *r, uint32_t *id);

typedef struct hfc_completion {
  uint32_t id;
  int status;                /* HFC_OK or an error; result filled only on OK */
  hfc_timing timing;
  void *user;
} hfc_completion;

/* Waits up to timeout_ms (0: just poll, < 0: the client's timeout) for the
 * next completion, in whatever order the server finishes them. Returns 0
 * with *done filled; HFC_E_TIMEOUT when none came within timeout_ms;
 * HFC_E_NOPENDING when nothing is pending; or, when nothing is pending and
 * the connection is gone, the error that ended it (HFC_E_CLOSED, HFC_E_IO,
 * HFC_E_TIMEOUT for a server given up as silent, ...; hfc_pending(c) is 0
 * and hfc_last_message says to connect again, or, on a list with
 * HFC_FAILOVER_LOST, that the next request goes to the next endpoint that
 * answers). Frames pending when a
 * connection is lost complete with its error, one per call.
 * A connection that owes replies and has sent nothing for
 * hfc_options.timeout_ms (a stopped or stuck server) is given up as lost,
 * whatever timeout_ms this call has and however often it polls: its
 * frames fail over (a list) or complete with HFC_E_TIMEOUT. */
HFC_API int hfc_wait(hfc_client *c, int timeout_ms, hfc_completion *done);
/* Requests submitted and not yet returned by hfc_wait; HFC_E_ARG with c
 * NULL. */
HFC_API int hfc_pending(const hfc_client *c);
/* Asks the server to drop request id (hfc_submit's) if it has not started
 * it (protocol version 4: CANCEL, protocol/PROTOCOL.md). It still
 * completes through hfc_wait, exactly once: with HFC_E_CANCELLED when the
 * server took it off its queue (not computed), or as usual when it had
 * started (a server never cuts a computation short) or had answered
 * already; until then its buffers stay the server's. A frame waiting to be
 * sent again after a failover completes HFC_E_CANCELLED at once. Returns
 * 0 when the cancel went out (or nothing was left to cancel: the
 * completion is in); HFC_E_ARG for an id that is not pending (never
 * submitted, or hfc_wait returned it); HFC_E_UNSUPPORTED when its server
 * speaks a version before 4, or when the frame went on a connection the
 * client left after a BUSY failover (half-closed, its replies still read:
 * nothing more is sent on it), the frame completing as answered; or the
 * connection's error when the send failed (the frame is then not computed
 * elsewhere either: where the loss would send it again, it completes
 * HFC_E_CANCELLED, or the CANCEL follows it to the next endpoint). */
HFC_API int hfc_cancel(hfc_client *c, uint32_t id);

/* ---- shared memory ------------------------------------------------------- */

/* On a Unix socket, frames can skip the socket: allocate buffers in memory
 * shared with the server, put features (the estimate directly after them,
 * when the request carries one), result and rgba of a request in the same
 * segment, not overlapping, and hfc_filter / hfc_submit send only a
 * reference; the server reads the features and writes the results in
 * place. Requests whose buffers are elsewhere, or overlap one another (a
 * result written over its own features, never resent by a failover), go
 * through the socket as usual, and so do those in a segment of a
 * connection lost in a failover (the memory stays mapped until
 * hfc_shm_free). At most 16 segments per client (a 17th is HFC_E_INFLIGHT,
 * with nothing asked of the server); *mem is page-aligned.
 * The server may refuse (HFC_E_BUSY when its shared-memory budget, or the
 * part of it one client process, all its connections together, or one
 * connection may hold, is spent, HFC_E_TOO_LARGE over all of any of them,
 * HFC_E_UNSUPPORTED on TCP or when disabled; hfc_last_message names the
 * server's option). While a request is pending, do not write its features or read
 * its results. */
HFC_API int hfc_shm_alloc(hfc_client *c, size_t bytes, void **mem);
/* Releases a segment from hfc_shm_alloc; no request on it may be pending. */
HFC_API int hfc_shm_free(hfc_client *c, void *mem);

/* ---- statistics -------------------------------------------------------- */

#define HFC_HIST_BUCKETS 24   /* bucket 0: < 32 us; i: [2^(i+4), 2^(i+5)) us */

typedef struct hfc_variant_stats {
  char name[65];
  uint64_t requests_ok, requests_failed, rejected, batches;
  uint64_t sum_queue_us, sum_infer_us, sum_total_us;
  uint64_t hist_total[HFC_HIST_BUCKETS], hist_infer[HFC_HIST_BUCKETS];
  uint64_t out_of_range;     /* successful requests flagged out of range (v2) */
  uint64_t frames_sanitised; /* successful requests whose input was sanitised (v2) */
  uint64_t cache_bytes;      /* host memory, bytes, the variant's model keeps between
                                runs (plans, activations); a gauge that falls when the
                                server gives memory back (v2; 0 from a version-1 server) */
  uint64_t expired;          /* requests answered EXPIRED: their budget
                                (hfc_request.deadline_us) passed in the queue (v4; 0
                                from an older server); also in requests_failed */
  uint64_t cancelled;        /* requests answered CANCELLED: hfc_cancel took them off
                                the queue unrun (v4; 0 from an older server); also in
                                requests_failed */
} hfc_variant_stats;

typedef struct hfc_stats {
  uint64_t uptime_us, connections_total, protocol_errors;
  int connections_open, queue_depth, queue_capacity;
  int num_variants;
  hfc_variant_stats variants[64];
} hfc_stats;

/* The counters of the server in use. */
HFC_API int hfc_get_stats(hfc_client *c, hfc_stats *out);

#ifdef __cplusplus
}
#endif
#endif /* HAIRFILTER_H */
