/*
 * hfproto: the hairfilter wire protocol, versions 1 to 4 (see
 * PROTOCOL.md, which is normative; this header follows it). Version 2 is
 * version 1 plus the input-range report and the input-sanitised flag:
 * RESULT flags HFP_RESULT_INPUT_SANITISED and HFP_RESULT_OUT_OF_RANGE, each
 * variant's trained input range after VARIANTS, and per-variant counters
 * after STATS_REPLY, and the server's software version after HELLO_OK. A
 * peer that negotiated version 1 never sees them. Version 3 is version 2
 * plus the alpha-corrected estimate: FILTER flag HFP_FILTER_ESTIMATE (the
 * features are followed by the frame's estimate) and, after VARIANTS'
 * ranges, the estimate each variant reads (hfp_variant.estimate). Version 4
 * is version 3 plus a frame's deadline: FILTER flag HFP_FILTER_DEADLINE and
 * its budget (hfp_filter.budget_us), the RESULT status HFP_E_EXPIRED, and a
 * fourth and fifth per-variant counters after STATS_REPLY (expired,
 * cancelled); and CANCEL, which
 * takes a queued FILTER off the queue (RESULT status HFP_E_CANCELLED).
 *
 * A pure codec: it turns message structs into bytes and bytes into structs.
 * It does no I/O and never allocates, so every length it reads from the wire
 * can only make it reject input, never make it reserve memory. Decoders
 * return pointers into the caller's buffer for bulk data (feature and result
 * tensors) instead of copying them.
 *
 * Every frame is a 16-byte header followed by `length` payload bytes:
 *
 *   u32 magic (HFP_MAGIC) | u16 type | u16 flags (0) | u32 request_id | u32 length
 *
 * All integers and floats are little-endian. Functions return 0 (or a byte
 * count) on success and a negative HFP_E* code on failure; the same codes,
 * positive, travel in ERROR frames and RESULT statuses. hfp_strerror() names
 * them.
 */
#ifndef HFPROTO_H
#define HFPROTO_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HFP_MAGIC          0x31504648u  /* "HFP1" in byte order */
#define HFP_VERSION        4            /* the newest version this codec speaks */
#define HFP_VERSION_MIN    1            /* the oldest */
#define HFP_HEADER_SIZE    16

#define HFP_NAME_MAX       64     /* client, server, variant, backend names */
#define HFP_TOKEN_MAX      256    /* auth token bytes */
#define HFP_MESSAGE_MAX    256    /* ERROR message bytes */
#define HFP_MAX_VARIANTS   64     /* entries in one VARIANTS reply */
#define HFP_MAX_LEVELS     8      /* U-Net levels per variant */
#define HFP_MAX_SPP        16     /* samples per pixel */
#define HFP_MAX_SIDE       65535  /* width/height the codec accepts at all */
#define HFP_FEATURES       6      /* features per sample */
#define HFP_OUTPUTS        3      /* color, highlight, alpha */
#define HFP_ESTIMATE_VALUES 3     /* the estimate's colour, highlight, alpha (v3) */
#define HFP_HIST_BUCKETS   24     /* latency histogram buckets */
#define HFP_MAX_STATS      16     /* input statistics a variant's range may name */
#define HFP_STATS_COUNTERS 5      /* per-variant counters after STATS_REPLY (v4; v2, v3: 3) */

/* ---- error codes (stable; wire values are the positive numbers) -------- */

#define HFP_OK               0
#define HFP_E_VERSION        1   /* no common protocol version */
#define HFP_E_PROTOCOL       2   /* malformed frame or unexpected message */
#define HFP_E_UNKNOWN_VARIANT 3  /* FILTER names no loaded variant */
#define HFP_E_TOO_LARGE      4   /* dimensions or frame over the server's limits */
#define HFP_E_LENGTH         5   /* payload length disagrees with its fields */
#define HFP_E_BUSY           6   /* a limit full: queue, in-flight, memory, shared memory, connections */
#define HFP_E_UNAUTHORIZED   7   /* missing or wrong auth token */
#define HFP_E_INTERNAL       8   /* the server failed; the request may be retried */
#define HFP_E_UNSUPPORTED    9   /* valid but not offered (dtype, flag, shared memory here) */
#define HFP_E_SHUTTING_DOWN  10  /* the server is draining and takes no new work */
#define HFP_E_INVALID        11  /* a field is out of its domain */
#define HFP_E_NOSPACE        12  /* (local only) output buffer too small */
#define HFP_E_EXPIRED        13  /* (version 4) the frame's budget passed before it ran;
                                    retrying cannot help */
#define HFP_E_CANCELLED      14  /* (version 4) the client's CANCEL took the frame off the
                                    queue before it ran */
#define HFP_E_COUNT          15

/* Accepts a code of either sign. Never NULL. */
const char *hfp_strerror(int code);
/* The code's name as PROTOCOL.md spells it ("BUSY"), or "UNKNOWN". */
const char *hfp_code_name(int code);
/* The name of message type type (PROTOCOL.md, "Frames"), e.g. "CANCEL";
 * "UNKNOWN" outside 1..HFP_TYPE_MAX. */
const char *hfp_type_name(unsigned type);

/* ---- message types ------------------------------------------------------ */

enum {
  HFP_HELLO         = 1,  /* client -> server */
  HFP_HELLO_OK      = 2,  /* server -> client */
  HFP_LIST_VARIANTS = 3,  /* client -> server, empty payload */
  HFP_VARIANTS      = 4,  /* server -> client */
  HFP_FILTER        = 5,  /* client -> server */
  HFP_RESULT        = 6,  /* server -> client */
  HFP_ERROR         = 7,  /* server -> client */
  HFP_STATS         = 8,  /* client -> server, empty payload */
  HFP_STATS_REPLY   = 9,  /* server -> client */
  HFP_SHM_CREATE    = 10, /* client -> server: a shared segment, please */
  HFP_SHM_CREATED   = 11, /* server -> client: its id; the fd rides along */
  HFP_SHM_DESTROY   = 12, /* client -> server: done with a segment */
  HFP_CANCEL        = 13, /* client -> server, version 4: the FILTER of this request id is
                             no longer wanted; empty payload, no reply of its own */
  HFP_TYPE_MAX      = 13
};

/* Element types of tensors on the wire (same values as hfcore's hf_dtype). */
enum { HFP_F32 = 0, HFP_F16 = 1 };
#define HFP_DTYPE_MASK_ALL ((1u << HFP_F32) | (1u << HFP_F16))

/* FILTER flags. */
#define HFP_FILTER_COMPOSITE 0x0001u  /* also return composited RGBA */
#define HFP_FILTER_SHM       0x0002u  /* tensors in a shared segment, not the frame */
#define HFP_FILTER_ESTIMATE  0x0004u  /* version 3: the features are followed by the
                                         frame's alpha-corrected estimate, W*H*3 values */
#define HFP_FILTER_DEADLINE  0x0008u  /* version 4: a u32 budget_us follows the variant
                                         name; a frame not running by then is EXPIRED */
#define HFP_FILTER_KNOWN     (HFP_FILTER_COMPOSITE | HFP_FILTER_SHM | HFP_FILTER_ESTIMATE | \
                              HFP_FILTER_DEADLINE)
#define HFP_DEADLINE_SIZE    4        /* the budget field's bytes */

/* What a variant reads besides the samples (VARIANTS, version 3). */
enum { HFP_ESTIMATE_NONE = 0, HFP_ESTIMATE_ALPHA_CORRECTED = 1 };

/* RESULT flags beyond the FILTER's (version 2 only). */
#define HFP_RESULT_INPUT_SANITISED 0x04u  /* some samples were non-finite or out of
                                             range and were sanitised (FEATURES.md) */
#define HFP_RESULT_OUT_OF_RANGE 0x08u  /* the input is outside the variant's trained range */

/* HELLO_OK server flags. */
#define HFP_SERVER_AUTH_REQUIRED 0x0001u  /* this listener checked a token */
#define HFP_SERVER_SHM           0x0002u  /* this connection can use SHM_CREATE */

/* Size of the shared-memory reference that replaces a FILTER's tensor. */
#define HFP_SHM_REF_SIZE 32

/* ---- header ------------------------------------------------------------- */

typedef struct hfp_header {
  uint16_t type;
  uint16_t flags;
  uint32_t request_id;
  uint32_t length;        /* payload bytes after the header */
} hfp_header;

/* Writes 16 bytes. */
void hfp_header_encode(const hfp_header *h, uint8_t out[HFP_HEADER_SIZE]);
/* Checks magic, type, flags and length <= max_payload. On HFP_E_TOO_LARGE
 * *h is still filled in, so a receiver can name the request it rejects. */
int hfp_header_decode(const uint8_t in[HFP_HEADER_SIZE], uint32_t max_payload,
                      hfp_header *h);

/* ---- messages ------------------------------------------------------------ */

typedef struct hfp_hello {
  uint16_t min_version, max_version;
  char client_name[HFP_NAME_MAX + 1];
  char token[HFP_TOKEN_MAX + 1];      /* empty: none */
} hfp_hello;

typedef struct hfp_hello_ok {
  uint16_t version;
  uint16_t server_flags;
  uint32_t max_width, max_height;
  uint16_t max_spp;
  uint16_t max_inflight;              /* per connection */
  uint32_t dtypes;                    /* bit (1 << HFP_F32 / HFP_F16) */
  uint32_t max_batch;
  uint32_t queue_size;
  uint64_t max_frame_bytes;           /* largest payload the server reads */
  char server_name[HFP_NAME_MAX + 1];
  /* Version 2: the server's software version ("0.1.0"); empty when the
   * server does not say, and always on version 1 (not on the wire). */
  char software_version[HFP_NAME_MAX + 1];
} hfp_hello_ok;

typedef struct hfp_variant {
  char name[HFP_NAME_MAX + 1];
  char backend[HFP_NAME_MAX + 1];
  char precision[HFP_NAME_MAX + 1];
  uint16_t spp;
  uint16_t num_levels;
  uint32_t levels[HFP_MAX_LEVELS];
  /* Version 2: the range of input statistics the variant was trained on,
   * by statistic number (PROTOCOL.md, "Input range"); none when 0. */
  uint8_t num_ranges;
  struct {
    uint8_t stat;
    double lo, hi;
  } ranges[HFP_MAX_STATS];
  /* Version 3: HFP_ESTIMATE_ALPHA_CORRECTED when the variant reads the
   * alpha-corrected estimate (its FILTERs carry HFP_FILTER_ESTIMATE);
   * HFP_ESTIMATE_NONE, and always on versions 1 and 2 (not on the wire). */
  uint8_t estimate;
} hfp_variant;

typedef struct hfp_filter {
  char variant[HFP_NAME_MAX + 1];
  uint16_t flags;
  uint32_t width, height;
  uint16_t spp;
  uint8_t in_dtype, out_dtype;
  float hair[3], light[3], bg[3];     /* linear RGB, used with COMPOSITE */
  const void *data;                   /* [h][w][spp*6] of in_dtype, then with
                                         HFP_FILTER_ESTIMATE [h][w][3] */
  uint64_t data_len;                  /* bytes of features (and estimate), sent or in
                                         the segment: hfp_filter_input_bytes */
  /* With HFP_FILTER_SHM: where the tensors are in segment shm_segment. */
  uint32_t shm_segment;
  uint64_t shm_in, shm_out, shm_rgba;
  uint32_t budget_us;                 /* with HFP_FILTER_DEADLINE (version 4): 1..2^32-1 us
                                         from the frame's arrival; else 0 */
} hfp_filter;

/* Server-side per-request timing, microseconds. */
typedef struct hfp_timing {
  uint64_t queue_us;     /* admitted -> taken by the inference worker */
  uint64_t input_us;     /* batch assembly + upload/convert/pad */
  uint64_t infer_us;     /* the network */
  uint64_t output_us;    /* transforms, download, crop, composite */
  uint64_t total_us;     /* frame fully received -> reply handed to the socket */
} hfp_timing;

typedef struct hfp_result {
  uint16_t status;       /* HFP_OK, or an HFP_E_* code and no data */
  uint8_t dtype;
  uint8_t flags;         /* HFP_FILTER_COMPOSITE when rgba follows, HFP_FILTER_SHM,
                            HFP_RESULT_INPUT_SANITISED, HFP_RESULT_OUT_OF_RANGE
                            (version 2) */
  uint32_t width, height;
  uint32_t batch;        /* frames inferred together with this one */
  hfp_timing timing;
  const void *data;      /* [h][w][3] of dtype */
  uint64_t data_len;
  const void *rgba;      /* [h][w][4] of dtype, or NULL */
  uint64_t rgba_len;
} hfp_result;

typedef struct hfp_error {
  uint32_t code;
  uint8_t fatal;         /* the server closes the connection after it */
  char message[HFP_MESSAGE_MAX + 1];
} hfp_error;

typedef struct hfp_variant_stats {
  char name[HFP_NAME_MAX + 1];
  uint64_t requests_ok;
  uint64_t requests_failed;   /* RESULT with a non-zero status */
  uint64_t rejected;          /* ERROR before admission (busy, limits, ...) */
  uint64_t batches;           /* backend runs */
  uint64_t sum_queue_us, sum_infer_us, sum_total_us;
  uint64_t hist_total[HFP_HIST_BUCKETS];
  uint64_t hist_infer[HFP_HIST_BUCKETS];
  uint64_t out_of_range;      /* version 2: successful requests flagged out of range */
  uint64_t frames_sanitised;  /* version 2: successful requests whose input was
                                 sanitised (HFP_RESULT_INPUT_SANITISED) */
  uint64_t cache_bytes;       /* version 2: host memory, bytes, the variant's model
                                 keeps between runs (plans); a gauge */
  uint64_t expired;           /* version 4: RESULTs with status HFP_E_EXPIRED */
  uint64_t cancelled;         /* version 4: RESULTs with status HFP_E_CANCELLED */
} hfp_variant_stats;

typedef struct hfp_stats {
  uint64_t uptime_us;
  uint64_t connections_total;
  uint32_t connections_open;
  uint32_t queue_depth;
  uint32_t queue_capacity;
  uint64_t protocol_errors;   /* ERROR frames not tied to a variant */
  uint16_t num_variants;
  hfp_variant_stats variants[HFP_MAX_VARIANTS];
} hfp_stats;

/* Histogram bucket of a latency: bucket 0 is [0, 32) us, bucket i is
 * [2^(i+4), 2^(i+5)) us, the last bucket is everything from 2^27 us. */
int hfp_hist_bucket(uint64_t us);
/* Exclusive upper bound of bucket i in us (UINT64_MAX for the last). */
uint64_t hfp_hist_upper(int i);

/* Bytes per element of a dtype, or 0 for an unknown one. */
size_t hfp_dtype_size(int dtype);
/* Payload sizes of the tensors, with every multiplication checked. Return
 * HFP_E_INVALID for out-of-domain fields. */
int hfp_features_bytes(uint32_t width, uint32_t height, uint32_t spp, int dtype,
                       uint64_t *out);
int hfp_output_bytes(uint32_t width, uint32_t height, uint32_t channels,
                     int dtype, uint64_t *out);
/* Bytes of a FILTER's input tensor: the features, plus W*H*3 values of the
 * estimate with HFP_FILTER_ESTIMATE in flags. */
int hfp_filter_input_bytes(uint32_t width, uint32_t height, uint32_t spp, int dtype,
                           unsigned flags, uint64_t *out);

/* Encoders write header and payload to buf and return the frame size, or
 * HFP_E_NOSPACE when cap is too small, or HFP_E_INVALID for a field out of
 * its domain (so a buggy sender cannot emit what a receiver must reject).
 * hfp_frame_size_* says how large buf must be. */
int hfp_encode_hello(uint8_t *buf, size_t cap, const hfp_hello *m);
int hfp_encode_hello_ok(uint8_t *buf, size_t cap, const hfp_hello_ok *m);
/* The largest HELLO_OK frame (both names at their limit, version 2). */
#define HFP_HELLO_OK_MAX (HFP_HEADER_SIZE + 38 + HFP_NAME_MAX + 1 + HFP_NAME_MAX)
int hfp_encode_empty(uint8_t *buf, size_t cap, int type, uint32_t request_id);
int hfp_encode_variants(uint8_t *buf, size_t cap, const hfp_variant *v, int count);
int hfp_encode_error(uint8_t *buf, size_t cap, uint32_t request_id, const hfp_error *m);
int hfp_encode_stats(uint8_t *buf, size_t cap, const hfp_stats *m);
size_t hfp_frame_size_variants(const hfp_variant *v, int count);
size_t hfp_frame_size_stats(const hfp_stats *m);
/* The same for a connection that speaks `version`: from version 2 on,
 * VARIANTS carries the input ranges and STATS_REPLY the extra counters.
 * (The functions above are these at version 1.) */
int hfp_encode_variants_v(uint8_t *buf, size_t cap, const hfp_variant *v, int count,
                          int version);
int hfp_encode_stats_v(uint8_t *buf, size_t cap, const hfp_stats *m, int version);
size_t hfp_frame_size_variants_v(const hfp_variant *v, int count, int version);
size_t hfp_frame_size_stats_v(const hfp_stats *m, int version);

/* FILTER and RESULT carry tensors that senders write straight from their
 * own buffers: the *_head encoders write the header (whose length counts the
 * tensors) and the fixed fields, and return the head's size; the sender then
 * writes m->data (and m->rgba) after it. data_len / rgba_len must equal the
 * sizes the dimensions imply. */
#define HFP_FILTER_FIXED   52
#define HFP_RESULT_FIXED   56
int hfp_encode_filter_head(uint8_t *buf, size_t cap, uint32_t request_id,
                           const hfp_filter *m, uint64_t *frame_size);
int hfp_encode_result_head(uint8_t *buf, size_t cap, uint32_t request_id,
                           const hfp_result *m, uint64_t *frame_size);
/* The largest FILTER head: a 64-byte name, the budget and the shared-memory
 * reference (a frame by reference is all head). */
#define HFP_FILTER_HEAD_MAX (HFP_HEADER_SIZE + HFP_FILTER_FIXED + HFP_NAME_MAX + \
                             HFP_DEADLINE_SIZE + HFP_SHM_REF_SIZE)
#define HFP_RESULT_HEAD_MAX (HFP_HEADER_SIZE + HFP_RESULT_FIXED)

/* Decoders read a payload (the bytes after the header) of exactly len bytes:
 * a frame with trailing or missing bytes is HFP_E_LENGTH, and a field out of
 * its domain HFP_E_INVALID (or HFP_E_VERSION, HFP_E_UNSUPPORTED). Pointers
 * in the output point into payload. They read either version: the
 * version-2 blocks of VARIANTS and STATS_REPLY are recognised by the bytes
 * after the last entry (none: version 1, no ranges, counters 0). */
int hfp_decode_hello(const uint8_t *payload, size_t len, hfp_hello *m);
int hfp_decode_hello_ok(const uint8_t *payload, size_t len, hfp_hello_ok *m);
#define HFP_HELLO_FIXED    8   /* min/max_version, name_len, token_len */
/* Says in buf (cap bytes; always terminated) which field of a HELLO of len
 * bytes made hfp_decode_hello return rc (HFP_E_LENGTH or HFP_E_INVALID) and
 * what it must be (PROTOCOL.md, "HELLO"): the text of a server's refusal.
 * The token's bytes are never copied into buf. */
void hfp_hello_fault(const uint8_t *payload, size_t len, int rc, char *buf, size_t cap);
int hfp_decode_variants(const uint8_t *payload, size_t len, hfp_variant *v,
                        int max, int *count);
int hfp_decode_filter(const uint8_t *payload, size_t len, hfp_filter *m);
/* The fixed part of a FILTER alone (first HFP_FILTER_FIXED + variant bytes),
 * so a receiver can validate a request before reading its tensor.
 * data_len is set from the dimensions; data is NULL. On an error, m->variant
 * holds the name if it was read and well formed: for a fault in the flags,
 * dtypes, colours, dimensions, the tensor's length or the SHM reference's
 * fields (segment 0, the reserved word, rgba_offset without COMPOSITE), so
 * the fault can be charged to the variant the request named. It is empty
 * for a fault in the name and when the name or the SHM reference runs past
 * the payload (checked before the name is read). */
int hfp_decode_filter_head(const uint8_t *payload, size_t avail, size_t len,
                           hfp_filter *m, size_t *head_len);
/* Says in buf (cap bytes; always terminated) which field of a FILTER made
 * hfp_decode_filter_head return rc (its arguments as given to it) and what
 * the field must be: the text of the refusal a server sends, so a client
 * learns the field to fix, not the error code alone. */
void hfp_filter_fault(const uint8_t *payload, size_t avail, size_t len, int rc, char *buf,
                      size_t cap);
int hfp_decode_result(const uint8_t *payload, size_t len, hfp_result *m);
int hfp_decode_result_head(const uint8_t *payload, size_t avail, size_t len,
                           hfp_result *m);
int hfp_decode_error(const uint8_t *payload, size_t len, hfp_error *m);
int hfp_decode_stats(const uint8_t *payload, size_t len, hfp_stats *m);

/* Shared segments (PROTOCOL.md, "Shared memory"). */
int hfp_encode_shm_create(uint8_t *buf, size_t cap, uint64_t bytes);
int hfp_decode_shm_create(const uint8_t *payload, size_t len, uint64_t *bytes);
int hfp_encode_shm_created(uint8_t *buf, size_t cap, uint32_t segment, uint64_t bytes);
int hfp_decode_shm_created(const uint8_t *payload, size_t len, uint32_t *segment,
                           uint64_t *bytes);
int hfp_encode_shm_destroy(uint8_t *buf, size_t cap, uint32_t segment);
int hfp_decode_shm_destroy(const uint8_t *payload, size_t len, uint32_t *segment);
/* Checks a FILTER's SHM reference against a segment of seg_bytes: every
 * region inside it, aligned to its element size and overlapping no other
 * region of the request; -HFP_E_LENGTH if not. */
int hfp_shm_check(const hfp_filter *m, uint64_t seg_bytes);
/* The same, and when it fails writes into why (NUL-terminated, whylen
 * bytes at most; NULL: nothing) which region is wrong and how: "the
 * result: 288 bytes at offset 4000 would end past the segment's 4096
 * bytes", "the features: offset 2 is not a multiple of the 4-byte
 * elements", "the features and the result overlap". */
int hfp_shm_check_why(const hfp_filter *m, uint64_t seg_bytes, char *why, size_t whylen);
/* Whether the byte ranges [a, a + an) and [b, b + bn) share a byte (offsets
 * in one segment, or addresses in one process); an empty range shares none.
 * The caller keeps a + an and b + bn below 2^64, as ranges that exist do. */
int hfp_regions_overlap(uint64_t a, uint64_t an, uint64_t b, uint64_t bn);

/* Version negotiation: the highest version both sides speak, or
 * HFP_E_VERSION (also for an empty range, client_min > client_max). */
int hfp_negotiate(uint16_t client_min, uint16_t client_max);

/* ---- addresses (PROTOCOL.md, "Addresses") ------------------------------- */

enum { HFP_URL_UNIX = 1, HFP_URL_TCP = 2 };
#define HFP_URL_LISTEN 0x1   /* port 0 allowed: "any free port" when binding */

typedef struct hfp_url {
  int kind;                /* HFP_URL_UNIX or HFP_URL_TCP */
  int tls;                 /* tcp: 1 for "tls:...", TLS over that TCP connection */
  char path[108];          /* unix: the socket path (sockaddr_un's limit) */
  char host[256];          /* tcp: name or address, IPv6 without brackets;
                              "127.0.0.1" for tcp:PORT */
  uint16_t port;           /* tcp: 1..65535 (0 only with HFP_URL_LISTEN) */
} hfp_url;

/* Parses "unix:PATH", "tcp:HOST:PORT", "tcp:[IPV6]:PORT" or "tcp:PORT", and
 * the same TCP forms with "tls:" (kind HFP_URL_TCP, tls 1).
 * Returns 0, or -HFP_E_INVALID with why (when not NULL) naming the URL and
 * what is wrong with it: an empty or over-long path, a host with characters
 * no name or address has, an IPv6 address without brackets, a port that is
 * not plain decimal digits or is outside 1..65535. Resolving the host is the
 * caller's business. Pure: no I/O, no allocation. */
int hfp_url_parse(const char *url, int flags, hfp_url *out, char *why, size_t whylen);

/* Little-endian helpers (exposed for the tensor converters of the peers). */
static inline void hfp_put_u16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8);
}
static inline void hfp_put_u32(uint8_t *p, uint32_t v) {
  p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8);
  p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline uint16_t hfp_get_u16(const uint8_t *p) {
  return (uint16_t)(p[0] | (p[1] << 8));
}
static inline uint32_t hfp_get_u32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
         ((uint32_t)p[3] << 24);
}

#ifdef __cplusplus
}
#endif
#endif /* HFPROTO_H */
