/*
 * libhairfilter: the client side of hairfilterd (protocol v1 and v2).
 *
 *   hfc_client *c;
 *   if (hfc_connect("unix:/run/hairfilterd/hairfilterd.sock", NULL, &c)) ...
 *   hfc_request r = {.variant = "Base", .width = w, .height = h, .spp = 4,
 *                    .features = in, .result = out};
 *   hfc_timing t;
 *   int rc = hfc_filter(c, &r, &t);    // or hfc_submit() + hfc_wait()
 *
 * Buffers belong to the caller: features are sent from where they are and
 * results are received straight into the caller's arrays. A client is a
 * single connection and is not thread-safe: use one per thread, or guard it.
 * Every blocking call gives up after the timeout of hfc_options (default
 * 30 s), so nothing here hangs on a dead server.
 *
 * Errors are negative HFC_E* codes; those the server sent keep the wire
 * code's number (HFC_E_BUSY == -HFP_E_BUSY, see protocol/PROTOCOL.md).
 * hfc_strerror() names them, hfc_last_message() gives the server's words.
 */
#ifndef HAIRFILTER_H
#define HAIRFILTER_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- errors ---------------------------------------------------------------- */

#define HFC_OK               0
/* reported by the server (or a malformed reply from it) */
#define HFC_E_VERSION        -1
#define HFC_E_PROTOCOL       -2
#define HFC_E_UNKNOWN_VARIANT -3
#define HFC_E_TOO_LARGE      -4
#define HFC_E_LENGTH         -5
#define HFC_E_BUSY           -6   /* retry later: queue or in-flight limit full */
#define HFC_E_UNAUTHORIZED   -7
#define HFC_E_INTERNAL       -8
#define HFC_E_UNSUPPORTED    -9
#define HFC_E_SHUTTING_DOWN  -10
#define HFC_E_INVALID        -11
/* local */
#define HFC_E_ARG            -100 /* bad argument */
#define HFC_E_URL            -101 /* not unix:PATH, tcp:HOST:PORT or tcp:PORT */
#define HFC_E_CONNECT        -102 /* could not connect */
#define HFC_E_IO             -103 /* the connection failed */
#define HFC_E_TIMEOUT        -104 /* no answer within the timeout */
#define HFC_E_CLOSED         -105 /* the server closed the connection */
#define HFC_E_NOMEM          -106
#define HFC_E_INFLIGHT       -107 /* as many requests pending as the server allows */
#define HFC_E_NOPENDING      -108 /* hfc_wait with nothing in flight */

const char *hfc_strerror(int err);

/* ---- connection -------------------------------------------------------- */

typedef struct hfc_client hfc_client;

typedef struct hfc_options {
  const char *client_name;   /* shown in the server's logs; default "libhairfilter" */
  const char *token;         /* auth token (TCP); NULL: none */
  int timeout_ms;            /* per blocking step; 0: 30000; < 0: no limit */
} hfc_options;

/* url: "unix:/path/to.sock", "tcp:HOST:PORT", "tcp:[v6addr]:PORT" or
 * "tcp:PORT" (127.0.0.1), the grammar of protocol/PROTOCOL.md ("Addresses");
 * HOST may be a name. opt may be NULL. Performs the HELLO handshake.
 * HFC_E_URL for a URL outside the grammar (hfc_check_url says why). */
int hfc_connect(const char *url, const hfc_options *opt, hfc_client **out);
/* Checks url without connecting: 0, or HFC_E_URL with why (when not NULL)
 * naming the URL and what is wrong with it, e.g. "bad URL 'tcp:h:70000':
 * port 70000 is outside 1..65535". */
int hfc_check_url(const char *url, char *why, size_t whylen);
/* Closes the connection; requests still in flight are abandoned. */
void hfc_close(hfc_client *c);

/* What the server said about itself in the handshake. */
typedef struct hfc_server_info {
  char name[65];
  int version;
  int max_width, max_height, max_spp;
  int max_inflight;          /* per connection */
  int max_batch, queue_size;
  int auth_required;
  int f16, f32;              /* dtypes accepted */
  int shm;                   /* hfc_shm_alloc works on this connection */
  uint64_t max_frame_bytes;
} hfc_server_info;

const hfc_server_info *hfc_info(const hfc_client *c);
/* The server's message with the last error, or "" (valid until the next
 * call on c). */
const char *hfc_last_message(const hfc_client *c);
/* The socket, to poll for readability before hfc_wait(c, 0, ...). */
int hfc_fd(const hfc_client *c);

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
} hfc_variant;

/* Fills up to max entries; *count is the number the server has. */
int hfc_list_variants(hfc_client *c, hfc_variant *out, int max, int *count);

/* ---- filtering --------------------------------------------------------- */

typedef enum hfc_dtype { HFC_F32 = 0, HFC_F16 = 1 } hfc_dtype;

/* One frame. Tensors are NHWC and dense: features [height][width][spp*6]
 * in protocol/FEATURES.md order (sample-major: color, highlight, alpha,
 * depth, tangent.x, tangent.y), result [height][width][3] (color,
 * highlight, alpha), rgba [height][width][4] composited over the
 * background, alpha = hair coverage. f16 is IEEE binary16 as uint16_t. */
typedef struct hfc_request {
  const char *variant;
  int width, height, spp;
  hfc_dtype in_dtype;
  const void *features;
  hfc_dtype out_dtype;
  void *result;
  void *rgba;                /* NULL: no composite */
  float hair[3], light[3], background[3];   /* linear RGB, for rgba */
  void *user;                /* returned in the completion */
} hfc_request;

/* What the server said about a result besides its tensors. Microseconds:
 * the server's parts (queue, input, infer, output) add up to at most
 * server_us; total_us is what the caller waited, so total_us - server_us is
 * transfer both ways plus client work. */
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
} hfc_timing;

/* Synchronous: sends r and waits for its result. timing may be NULL. */
int hfc_filter(hfc_client *c, const hfc_request *r, hfc_timing *timing);

/* Asynchronous: sends r and returns at once with its id. r's buffers (not r
 * itself) must stay valid until its completion comes out of hfc_wait. At
 * most hfc_info(c)->max_inflight may be pending (HFC_E_INFLIGHT). */
int hfc_submit(hfc_client *c, const hfc_request *r, uint32_t *id);

typedef struct hfc_completion {
  uint32_t id;
  int status;                /* HFC_OK or an error; result filled only on OK */
  hfc_timing timing;
  void *user;
} hfc_completion;

/* Waits up to timeout_ms (0: just poll, < 0: the client's timeout) for the
 * next completion, in whatever order the server finishes them. Returns 0
 * with *done filled, HFC_E_TIMEOUT, HFC_E_NOPENDING, or a connection error
 * (then every pending request completes with that error on later calls). */
int hfc_wait(hfc_client *c, int timeout_ms, hfc_completion *done);
/* Requests submitted and not yet returned by hfc_wait. */
int hfc_pending(const hfc_client *c);

/* ---- shared memory ------------------------------------------------------- */

/* On a Unix socket, frames can skip the socket: allocate buffers in memory
 * shared with the server, put features, result and rgba of a request in
 * the same segment, and hfc_filter / hfc_submit send only a reference;
 * the server reads the features and writes the results in place. Requests
 * whose buffers are elsewhere go through the socket as usual. At most 16
 * segments per client; *mem is page-aligned. The server may refuse
 * (HFC_E_BUSY when its shared-memory budget is spent, HFC_E_UNSUPPORTED on
 * TCP or when disabled). While a request is pending, do not write its
 * features or read its results. */
int hfc_shm_alloc(hfc_client *c, size_t bytes, void **mem);
/* Releases a segment from hfc_shm_alloc; no request on it may be pending. */
int hfc_shm_free(hfc_client *c, void *mem);

/* ---- statistics -------------------------------------------------------- */

#define HFC_HIST_BUCKETS 24   /* bucket 0: < 32 us; i: [2^(i+4), 2^(i+5)) us */

typedef struct hfc_variant_stats {
  char name[65];
  uint64_t requests_ok, requests_failed, rejected, batches;
  uint64_t sum_queue_us, sum_infer_us, sum_total_us;
  uint64_t hist_total[HFC_HIST_BUCKETS], hist_infer[HFC_HIST_BUCKETS];
  uint64_t out_of_range;     /* successful requests flagged out of range (v2) */
  uint64_t frames_sanitised; /* successful requests whose input was sanitised (v2) */
} hfc_variant_stats;

typedef struct hfc_stats {
  uint64_t uptime_us, connections_total, protocol_errors;
  int connections_open, queue_depth, queue_capacity;
  int num_variants;
  hfc_variant_stats variants[64];
} hfc_stats;

int hfc_get_stats(hfc_client *c, hfc_stats *out);

#ifdef __cplusplus
}
#endif
#endif /* HAIRFILTER_H */
