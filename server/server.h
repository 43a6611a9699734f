/*
 * hairfilterd internals: one libuv loop thread does all network I/O; one
 * inference worker thread owns the backend. They meet at a bounded queue
 * (loop -> worker) and a completion list (worker -> loop, with uv_async).
 *
 * Ownership, which is what keeps this simple: a job belongs to the loop
 * thread until it is queued, to the worker until it is on the completion
 * list, and to the loop thread again after. Connections, statistics and
 * every libuv handle are touched by the loop thread only.
 */
#ifndef HFD_SERVER_H
#define HFD_SERVER_H

#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <uv.h>

#include "hfcore.h"
#include "hfproto.h"

#define HFD_MAX_LISTENERS 8
#define HFD_MAX_WARM      16
#define HFD_MAX_VARIANTS  HFP_MAX_VARIANTS

/* ---- logging (log.c) ---------------------------------------------------- */

/* Levels are syslog priorities, so they reach journald as they are. */
enum { HFD_LOG_ERR = 3, HFD_LOG_WARNING = 4, HFD_LOG_NOTICE = 5, HFD_LOG_INFO = 6,
       HFD_LOG_DEBUG = 7 };

/* One line at level: "error: " or "warning: " before the message for those
 * two levels. On a terminal or file the line starts with the UTC time and
 * "hairfilterd[pid]: "; when stderr is the journal ($JOURNAL_STREAM names
 * it) with "<priority>" only, which journald turns into the entry's
 * priority. Context travels as key=value fields after the message
 * (hfd_kv quotes values that need it). Thread-safe: one write per line. */
void hfd_logl(int level, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Where the errors and warnings said from now on come from ("FILE:LINE: ",
 * put after their "error: "), on this thread; NULL for nowhere in
 * particular. The config parser sets it while it reads a file's line. */
void hfd_log_context(const char *where);
#define hfd_err(...) hfd_logl(HFD_LOG_ERR, __VA_ARGS__)
#define hfd_warn(...) hfd_logl(HFD_LOG_WARNING, __VA_ARGS__)
#define hfd_notice(...) hfd_logl(HFD_LOG_NOTICE, __VA_ARGS__)
#define hfd_log(...) hfd_logl(HFD_LOG_INFO, __VA_ARGS__)
#define hfd_debug(...) hfd_logl(HFD_LOG_DEBUG, __VA_ARGS__)
/* Lines above this level are dropped (--log-level; default info). */
extern _Atomic int hfd_log_level;
/* Parses error|warning|notice|info|debug; -1 for anything else. */
int hfd_log_level_parse(const char *name);
const char *hfd_log_level_name(int level);
/* Checks stderr against $JOURNAL_STREAM; call once at start. */
void hfd_log_init(void);
/* A budget of lines per second for lines a peer can cause as fast as it
 * sends bytes. One hfd_rate per thread that uses it (not locked); zeroed to
 * start. hfd_rate_allow says whether one more line fits in the current
 * second; the first line of a new second is preceded by "N <what> line(s)
 * suppressed in the last interval" when lines were dropped. */
typedef struct hfd_rate {
  double window_start;           /* hfd_now_us */
  int in_window;
  unsigned long suppressed;
} hfd_rate;
int hfd_rate_allow(hfd_rate *r, int per_second, const char *what);
/* Appends " key=value" to buf (of cap bytes, NUL-terminated), quoting the
 * value ("...", with \" and \\) when it is empty or holds a space, a quote,
 * '=' or a byte outside printable ASCII (shown as '?'). */
void hfd_kv(char *buf, size_t cap, const char *key, const char *value);

/* ---- configuration (config.c) -------------------------------------------- */

#define HFD_DEFAULT_CONFIG "/etc/hairfilter/hairfilterd.conf"

typedef struct hfd_config {
  const char *listen[HFD_MAX_LISTENERS];
  hfp_url listen_url[HFD_MAX_LISTENERS];   /* parsed at option time */
  int num_listen;
  const char *weights[HFD_MAX_VARIANTS];
  const char *weights_name[HFD_MAX_VARIANTS]; /* --weights NAME=FILE, or NULL */
  int num_weights;
  const char *weights_dir;
  const char *backend;           /* auto | cpu | cpu-ref | cudnn */
  int max_batch;                 /* frames per backend run; 0 until the backend is
                                  * known, when not given (hfd_worker_start) */
  int max_queue_delay_us;        /* how long a batch may wait for partners */
  int queue_size;                /* admitted, not yet running */
  int max_inflight;              /* per connection */
  int share_by_connection;       /* --queue-share-by connection: each its own share */
  int max_width, max_height;
  int max_connections;
  int max_handshakes;            /* connections that have not said HELLO */
  int max_handshakes_addr;       /* of which one IP address may hold; 0: the default */
  int ipv6_client_prefix;        /* an IPv6 peer is a client by this many leading bits */
  uint64_t max_frame_bytes;      /* largest payload read */
  uint64_t max_memory_bytes;     /* request buffers + inference memory */
  uint64_t max_shm_bytes;        /* shared segments held at once; 0: no SHM */
  uint64_t max_shm_conn_bytes;   /* of which one connection may hold; 0: the default */
  uint64_t max_shm_client_bytes; /* of which one client (process) may hold; 0: the default */
  int drain_timeout_ms;          /* queued work after SIGTERM */
  int flush_timeout_ms;          /* then, replies still unread by peers */
  int handshake_timeout_ms;      /* accept -> HELLO complete; 0: none */
  int stall_timeout_ms;          /* mid-frame silence, rate window; 0: none */
  uint64_t min_recv_rate;        /* bytes/s a frame must arrive at; 0: none */
  int no_auth;
  char token[HFP_TOKEN_MAX + 1];
  /* TLS listeners (tls.c): PEM files, read at start and on SIGHUP. */
  const char *tls_cert;          /* certificate chain, the server's first */
  const char *tls_key;           /* its private key */
  const char *tls_client_ca;     /* mutual TLS: clients need a certificate it signed */
  int tls_client_cert_auth;      /* on TLS listeners, that certificate replaces the token */
  const char *ready_file;
  const char *name;
  const char *http;              /* --http tcp:HOST:PORT, or NULL */
  hfp_url http_url;
  int watchdog_ms;               /* worker or loop without progress this long: unhealthy */
  int log_level;                 /* HFD_LOG_* */
  const char *config_path;       /* the file read, or NULL */
  /* Shapes whose plans every variant builds before serving (--warm). */
  struct {
    int width, height, batch;
  } warm[HFD_MAX_WARM];
  int num_warm;
  int pipeline_depth;            /* backend runs pending at once: 1 or 2 */
  /* Strings read from the config file, owned by this config. */
  char **owned;
  int num_owned, cap_owned;
} hfd_config;

/* Reads the config file (--config FILE, else HFD_DEFAULT_CONFIG when it
 * exists; "--config none" reads none), then the command line: flags win,
 * and a repeatable flag (--listen, --weights) given on the command line
 * replaces the file's entries of that key. Returns 0, 1 after --help, -1
 * after an error it logged at error level (naming the file and line, or
 * the flag). Checks that need nothing loaded (URLs, tokens, TLS options, a
 * TCP listener's authentication) are made here. */
int hfd_config_parse(int argc, char **argv, hfd_config *cfg);
/* For the tcp:/tls: listener u (written url) of cfg: *loopback 1 when its
 * host is the loopback interface (127.0.0.0/8, ::1, ::ffff:127.0.0.0/104,
 * localhost: hfd_host_is_loopback), and
 * *auth_required 1 when its clients must give the token (not with
 * --no-auth, nor on tls: with --tls-client-cert-auth); either may be NULL.
 * -1, logged, when cfg cannot serve it: --no-auth off loopback, or no
 * token where one is required. */
int hfd_listener_auth(const hfd_config *cfg, const hfp_url *u, const char *url, int *loopback,
                      int *auth_required);
/* Logs why a TCP address (a --listen or --http URL, named by option and
 * url) could not be bound or listened on, err an errno value: a port in
 * use, an address not this host's or a privileged port said as such with
 * what to do, anything else as strerror says it. */
void hfd_bind_error(const char *option, const char *url, const char *host, int port, int err);
/* Frees what the config owns (the strings read from its file). */
void hfd_config_free(hfd_config *cfg);

/* ---- models and variants (models.c) ------------------------------------- */

/* Which file a model was read from, as it was then: a file whose identity
 * changed is read again on reload. */
typedef struct hfd_file_id {
  uint64_t dev, ino, size;
  int64_t mtime_ns;
} hfd_file_id;

/* One loaded weights file. Immutable once built, so requests admitted for it
 * finish on it even after a reload replaced it: jobs hold references
 * (refs, loop thread), and the last one gone hands it to the worker to be
 * destroyed there (GPU handles belong to that thread). */
typedef struct hfd_model {
  struct hfd_model *wnext;       /* the worker's list of built models */
  int refs;                      /* loop thread: its variant's, one per job */
  int slot;                      /* the variant (name) it serves, or -1 */
  char name[HFP_NAME_MAX + 1];   /* the metadata's, or the override */
  char override[HFP_NAME_MAX + 1]; /* --weights NAME=FILE, or "" */
  char *path;
  hfd_file_id file;
  hf_model *model;               /* worker thread only */
  hf_net_config cfg;
  char precision[16];
  hf_input_range range;          /* trained input range; .present 0: none */
  uint64_t params;               /* number of weights */
  uint64_t device_bytes;         /* hf_model_device_bytes once built */
  /* The wall clock when built, for variant_loaded_timestamp_seconds: read
   * then, not derived from the start's and the monotonic clock, which a
   * clock step (NTP at boot, a VM resumed) would leave off by the step. */
  double t_loaded_wall;
  uint64_t last_run;             /* worker thread: its clock at the last run */
  /* Host memory its backend model keeps between runs (plans): written by
   * the worker, read for STATS and /metrics. */
  _Atomic uint64_t cache_bytes;
} hfd_model;

/* Latency histogram buckets (seconds, upper bounds): what an operator sets
 * alerts on, from half a millisecond to half a minute; +Inf is implicit. */
#define HFD_TIME_BUCKETS 15
extern const double hfd_time_buckets_s[HFD_TIME_BUCKETS];
/* Batch sizes: 1, 2, 4 .. 256 (--max-batch is at most 256). */
#define HFD_BATCH_BUCKETS 9
enum { HFD_T_QUEUE, HFD_T_INPUT, HFD_T_INFER, HFD_T_OUTPUT, HFD_T_TOTAL, HFD_T_COUNT };

typedef struct hfd_hist {
  uint64_t bucket[HFD_TIME_BUCKETS + 1];  /* per bucket (not cumulative); last: +Inf */
  uint64_t count;
  double sum;                    /* seconds, or frames for batches */
} hfd_hist;

/* Per-variant counters behind /metrics (loop thread only). */
typedef struct hfd_variant_metrics {
  uint64_t by_status[HFP_E_COUNT]; /* answers by status: [0] OK, else HFP_E_* */
  hfd_hist time[HFD_T_COUNT];    /* of successful requests */
  hfd_hist batch;                /* frames per backend run (first HFD_BATCH_BUCKETS + 1) */
} hfd_variant_metrics;

/* A name clients ask for. Its counters outlive the models that serve it. */
typedef struct hfd_variant {
  char name[HFP_NAME_MAX + 1];
  hfd_model *model;              /* serving now; NULL: free, or removed and retiring */
  /* Served when the daemon stopped its worker (its models unloaded): its
   * counters are still reported while the last replies are written. */
  int served_at_stop;
  int models;                    /* models of this name not yet unloaded */
  hfp_variant_stats stats;       /* loop thread only */
  hfd_variant_metrics m;         /* loop thread only */
} hfd_variant;

/* ---- jobs and the worker --------------------------------------------- */

struct hfd_conn;

/* A shared-memory segment made for one connection (shm.c): a sealed
 * memfd, so the peer can neither shrink it under us (no SIGBUS) nor grow
 * it past what was counted. Jobs that use it hold references; it is
 * unmapped when its connection or SHM_DESTROY dropped it and no job is left. */
#define HFD_MAX_SEGMENTS 16

typedef struct hfd_seg {
  struct hfd_seg *next;
  uint32_t id;
  uint8_t *addr;
  uint64_t size;
  int refs;                      /* jobs using it */
  int dropped;                   /* no longer reachable by id */
  int registered;                /* pinned by the backend (hf_backend_host_register) */
  /* The connection that made it, whose shm_bytes counts it until it is
   * freed (SHM_DESTROY leaves frames running on it to finish): its jobs
   * keep the connection alive at least that long. */
  struct hfd_conn *owner;
} hfd_seg;

typedef struct hfd_job {
  struct hfd_job *next;
  struct hfd_conn *conn;
  uint32_t request_id;
  int variant;                   /* its slot in hfd_server.variants */
  hfd_model *model;              /* the version it runs on (a reference) */
  hfp_filter req;                /* decoded head; req.data == input */
  void *input;                   /* features, 64-byte aligned */
  void *out;                     /* [h][w][3] of req.out_dtype */
  void *rgba;                    /* [h][w][4] of req.out_dtype, or NULL */
  uint64_t out_len, rgba_len;
  uint64_t bytes_held;           /* charged to the server's memory budget */
  uint64_t infer_bytes;          /* of which reserved for running it */
  double t_received, t_started, t_done;
  hfp_timing timing;
  uint32_t batch;
  /* The first job of a backend run: set by the worker, cleared by
   * hfd_worker_take_done once it has counted the run (hfd_metrics_batch),
   * so the run counts once, whether or not its replies are delivered. */
  int batch_leader;
  uint64_t sanitised;            /* samples hf_model_run sanitised (FEATURES.md) */
  int status;                    /* HFP_OK or an HFP_E_* code */
  int out_of_range;              /* input outside the variant's trained range */
  hfd_seg *seg;                  /* tensors live in this segment, or NULL */
  uint8_t head[HFP_RESULT_HEAD_MAX];
  uv_write_t wreq;
} hfd_job;

/* Work for the worker other than frames: building a model from a weights
 * file (which must happen on the thread that owns the backend) and
 * destroying one. Done before the next batch is formed. */
enum { HFD_CTL_LOAD = 1, HFD_CTL_UNLOAD };

typedef struct hfd_ctl {
  struct hfd_ctl *next;
  int op;
  hfd_model *model;              /* LOAD: path and override set; UNLOAD: the model */
  int rc;                        /* LOAD: HF_OK or an error, why in msg */
  int done;
  char msg[512];
} hfd_ctl;

typedef struct hfd_worker {
  pthread_t thread;
  pthread_mutex_t mu;
  pthread_cond_t cv;
  hfd_job *q_head, *q_tail;
  int q_len, q_cap;
  /* Frames taken off the queue into the batch being formed, waiting there
   * for partners: still admitted frames not yet running, so they count as
   * queued (q_len + q_forming, in the depth and against q_cap). */
  int q_forming;
  hfd_job *done_head, *done_tail;
  hfd_ctl *ctl_head, *ctl_tail;  /* loads and unloads to do */
  hfd_ctl *ctl_done;             /* loads done, for the loop thread (LIFO) */
  int stop;                      /* finish what is queued, then exit */
  int cancel;                    /* fail what is queued, then exit */
  /* A stop came, during the start or a reload (hfd_worker_abandon_loads):
   * loads not begun fail at once, and one under way stops between its
   * steps (the file, the model, each --warm plan), so the daemon stops
   * within one step instead of after every model (minutes on a GPU). Set
   * from a signal handler: a lock-free atomic. */
  atomic_int abandon;
  int busy;                      /* a batch is running */
  /* startup handshake */
  int ready, init_rc;
  char init_msg[512];
  /* set before start */
  const char *backend_name;
  int max_batch;
  double max_delay_us;
  int pipeline_depth;
  const hfd_config *cfg;         /* for the warm shapes */
  uv_async_t *async;
  uint64_t cache_cap;            /* plans, scratch and idle receive buffers kept */
  const _Atomic uint64_t *pool_idle; /* idle receive buffers' bytes (recv_pool.c) */
  uint64_t run_clock;            /* worker thread: counts runs, for hfd_model.last_run */
  /* Host memory kept between runs (backend plans, the worker's scratch):
   * written by the worker, read by the loop thread when it admits a frame. */
  _Atomic uint64_t cached_bytes;
  /* Progress, for the watchdog (read by the HTTP thread and the loop):
   * when the worker last finished something, and whether it is in the
   * middle of something (a batch, a load) that should finish. */
  _Atomic uint64_t progress_us;
  _Atomic int working;
  /* worker-private */
  hf_backend *backend;
  hfd_model *models;             /* every built model (hfd_model.wnext) */
  void *scratch_in, *scratch_out;
  size_t scratch_in_cap, scratch_out_cap;
  float *scratch_rgb;
  size_t scratch_rgb_cap;
  /* Private copies of frames in shared segments, one per run that may be
   * in flight (HF_MAX_PENDING), used in turn: the backend reads the copy,
   * never the segment its client can write meanwhile. */
  void *seg_in[2];
  size_t seg_in_cap[2];
  int seg_in_registered[2];      /* pinned by the backend (hf_backend_host_register) */
  int seg_in_next;
} hfd_worker;

/* Starts the thread; it creates the backend and reports through init_rc /
 * init_msg before hfd_worker_start returns. Models are loaded with
 * hfd_worker_control. */
int hfd_worker_start(hfd_worker *w);
/* Makes every load not yet done fail (HF_EUNAVAILABLE, "the daemon is
 * stopping") at its next step, for a stop that comes during the start or
 * a reload. Async-signal-safe (one lock-free atomic store), so a signal
 * handler calls it; it may come before hfd_worker_start, and is not
 * undone. */
void hfd_worker_abandon_loads(hfd_worker *w);
/* 0 when queued, HFP_E_BUSY when the queue is full. */
int hfd_worker_submit(hfd_worker *w, hfd_job *job);
/* hfd_worker_submit for a frame of a client (hfd_conn.share) holding fewer
 * than share frames: when the queue is full, the newest queued frame (not
 * one the batcher holds or runs) of the client holding the most frames,
 * more than share, leaves the queue and job takes its place, in one step.
 * 0 when job is queued, *pushed then the frame taken off (for the caller
 * to answer BUSY) or NULL when there was room; HFP_E_BUSY when no
 * client over share has a frame in the queue, or the worker is
 * stopping. Loop thread only: it reads the clients' inflight counts.
 * So the queue is shared (docs/SERVER.md, "Limits and backpressure"): a
 * client within its share is not refused for a queue that clients over
 * theirs keep full, however quickly they resend. */
int hfd_worker_push_out(hfd_worker *w, hfd_job *job, int share, hfd_job **pushed);
/* Takes every completed job (in completion order). Loop thread: it also
 * counts each backend run among them in its variant's statistics
 * (hfd_metrics_batch), before any reply is written. */
hfd_job *hfd_worker_take_done(hfd_worker *w);
/* Queues a load or unload. An UNLOAD's ctl and model are freed by the
 * worker; a LOAD comes back through hfd_worker_take_ctl (and uv_async). */
void hfd_worker_control(hfd_worker *w, hfd_ctl *ctl);
/* Takes every finished LOAD; with wait, blocks until there is one. */
hfd_ctl *hfd_worker_take_ctl(hfd_worker *w, int wait);
/* Admitted frames not yet running: queued, or held by the batcher while
 * it waits for partners. */
int hfd_worker_queue_depth(hfd_worker *w);
/* Frees LOADs that were never applied, once the worker has stopped: the
 * models of failed ones (built ones went with the worker). */
void hfd_ctl_free_list(hfd_ctl *c);
/* Fails every queued job with HFP_E_SHUTTING_DOWN (the batch being formed
 * is failed by the worker, which sees cancel). */
void hfd_worker_cancel(hfd_worker *w);
/* Takes conn's queued frames (not those in a batch being formed or run)
 * off the queue and completes them unrun: their connection is gone, so
 * nothing would read their results, and they would hold queue places and
 * memory other clients are refused for. Loop thread; returns how many. */
int hfd_worker_drop_conn(hfd_worker *w, const struct hfd_conn *conn);
/* Takes the queued frames whose budget (FILTER flag DEADLINE) has passed
 * off the queue and returns them, linked by next, with status
 * HFP_E_EXPIRED, for the caller to answer at once (NULL: none). Loop
 * thread: a connection at its in-flight limit or its share of the queue
 * is not refused for places its dead frames hold. */
hfd_job *hfd_worker_take_expired(hfd_worker *w);
/* Takes conn's queued frame of request_id (the first, for a reused id)
 * off the queue and completes it unrun with HFP_E_CANCELLED: 1 when one
 * was queued, 0 when none was (not admitted, answered, or already taken
 * by the batcher, which runs it). Loop thread (PROTOCOL.md, "Version 4",
 * CANCEL). */
int hfd_worker_cancel_frame(hfd_worker *w, const struct hfd_conn *conn, uint32_t request_id);
/* Asks the thread to exit once the queue is empty, and joins it; models
 * still built are destroyed there. */
void hfd_worker_stop(hfd_worker *w);
/* 1 when the worker has been in the middle of something for longer than
 * limit_us without finishing it; *stalled_us says for how long. Any thread. */
int hfd_worker_stalled(hfd_worker *w, double limit_us, double *stalled_us);
/* Host memory the worker needs to run batch frames of a model with cfg at
 * width x height whose features are in_bytes each: the backend's
 * hf_run_bytes plus the worker's own batch and conversion buffers.
 * UINT64_MAX when the backend cannot run that size. Pure; callable from
 * either thread once the worker has started. */
uint64_t hfd_worker_run_bytes(const hfd_worker *w, const hf_net_config *cfg, uint32_t width,
                              uint32_t height, int batch, uint64_t in_bytes);

double hfd_now_us(void);

/* ---- listeners and connections ----------------------------------------- */

typedef struct hfd_server hfd_server;

/* Receive buffers kept for reuse (recv_pool.c). */
#define HFD_RPOOL_MIN ((size_t)1 << 20) /* smaller frames: malloc */

typedef struct hfd_rbuf {
  struct hfd_rbuf *next;
  void *addr;
  size_t cap;                    /* bytes mapped */
  uint64_t charged;              /* lent: bytes its frame has been charged */
  uint64_t reserved;             /* lent: of its uncharged bytes, those resident */
  int warm;                      /* lent: faulted in whole before it was lent */
  uint64_t last_use;             /* idle: when it came back (pool clock) */
  int lent;
} hfd_rbuf;

typedef struct hfd_rpool {
  hfd_rbuf *bufs;
  _Atomic uint64_t idle_bytes;   /* kept, not lent; the worker reads it */
  uint64_t lent_uncharged;       /* of lent buffers, not charged to a frame */
  uint64_t mapped_bytes;         /* every buffer, idle or lent */
  uint64_t clock;
  uint64_t hits, misses, evicted;
} hfd_rpool;

/* A buffer of at least bytes, 64-byte aligned: an idle pooled one, a new
 * mapping (from HFD_RPOOL_MIN up), or malloc's; NULL when out of memory.
 * An idle buffer's bytes are resident: they count in hfd_rpool_reserve
 * until hfd_rpool_charge says a frame has been charged for them. A new
 * mapping's pages become resident only as bytes land in them, which the
 * frame is charged for as they arrive: of it, only the rest of the 2 MiB
 * steps (huge pages) that its bytes have reached is reserved, so a peer
 * that sends a large frame's head and then trickles holds what it sent,
 * rounded up to 2 MiB, not the whole frame. */
void *hfd_rpool_take(hfd_rpool *p, size_t bytes);
/* The most a buffer of bytes from hfd_rpool_take holds resident outside
 * the idle buffers: a new mapping's bytes rounded up to its 2 MiB steps;
 * bytes itself below HFD_RPOOL_MIN (malloc's), 0 for 0. */
uint64_t hfd_rpool_footprint(uint64_t bytes);
/* n more bytes of addr's buffer are charged to its frame (mem_held). */
void hfd_rpool_charge(hfd_rpool *p, const void *addr, uint64_t n);
/* Gives back addr (from hfd_rpool_take; NULL: nothing): kept idle while
 * idle buffers plus cache_bytes (the backends' cached plans) fit
 * cache_cap, least recently used idle buffers unmapped to make room, else
 * unmapped (or freed). */
void hfd_rpool_give(hfd_rpool *p, void *addr, uint64_t cache_bytes, uint64_t cache_cap);
/* Bytes resident for the pool and charged to no frame: idle buffers and
 * the uncharged part of lent ones. Counted in the committed memory. */
uint64_t hfd_rpool_reserve(const hfd_rpool *p);
/* Unmaps idle buffers, least recently used first, until want bytes are
 * freed or none is left; returns the bytes freed. */
uint64_t hfd_rpool_shrink(hfd_rpool *p, uint64_t want);
/* Maps and faults in one idle buffer for frames of bytes (none when one
 * of that size is kept or it would not fit cache_cap: -1). */
int hfd_rpool_prefault(hfd_rpool *p, size_t bytes, uint64_t cache_cap);
void hfd_rpool_free(hfd_rpool *p);
/* A socket frame's result buffer of bytes from s's pool, charged in full
 * (the caller has charged them to mem_held); NULL when out of memory. */
void *hfd_rbuf_result(hfd_server *s, uint64_t bytes);
/* Gives a socket frame's input or result buffer back to s's pool. */
void hfd_rbuf_release(hfd_server *s, void *addr);

typedef struct hfd_listener {
  union {
    uv_tcp_t tcp;
    uv_pipe_t pipe;
    uv_stream_t stream;
    uv_handle_t handle;
  } h;
  hfd_server *srv;
  int is_tcp;
  int is_tls;                    /* tls:HOST:PORT (tls.c) */
  int auth_required;
  char url[256];                 /* as resolved (the real port) */
  char unix_path[200];
  /* The socket file as bound (unix:): a path removed or taken by another
   * file is no longer this listener's, and local clients cannot reach it. */
  unsigned long long sock_dev, sock_ino;
  int socket_lost;               /* last seen gone (logged once per loss) */
  int accept_deferred;           /* a connection left pending until the turn ends (conn.c) */
} hfd_listener;

/* A client (clients.c): the peer a connection belongs to, for what is
 * shared among clients rather than connections. On a Unix socket, a
 * process (the pid SO_PEERCRED gives); over TCP and TLS, an IP address
 * (an IPv6 one by its --ipv6-client-prefix bits: hfd_peer_client_name).
 * A Unix peer whose pid the daemon cannot see (another pid namespace: 0)
 * is a client of its own on each connection. */
typedef struct hfd_client {
  struct hfd_client *next;       /* in hfd_server.clients, when listed */
  int listed;                    /* 0: a connection's own (hfd_conn.own) */
  char name[64];                 /* "pid 1234", "address 10.0.0.3",
                                  * "address 2001:db8:1:2::/64", for messages */
  int conns;                     /* connections counted in it */
  int inflight;                  /* their frames admitted, not yet answered */
  int handshaking;               /* their TCP and TLS connections before their HELLO */
} hfd_client;

enum hfd_read_state {
  RD_HEADER,       /* the 16-byte header */
  RD_CONTROL,      /* a small control payload into ctl[] */
  RD_FILTER_HEAD,  /* a FILTER's fixed fields and variant name */
  RD_FILTER_DATA,  /* its tensor, straight into the job's input buffer */
  RD_DISCARD       /* the rest of a rejected frame */
};

typedef struct hfd_conn {
  union {
    uv_tcp_t tcp;
    uv_pipe_t pipe;
    uv_stream_t stream;
    uv_handle_t handle;
  } h;
  hfd_server *srv;
  hfd_listener *listener;
  struct hfd_conn *prev, *next;
  uint64_t id;
  char peer[80];
  char client_name[HFP_NAME_MAX + 1];
  int hello_done;
  int version;                   /* protocol version negotiated in the HELLO */
  int handshaking;               /* counted in num_handshaking */
  int hello_waiting;             /* its whole HELLO is in its socket, unread (oldest_handshake) */
  int eof;                       /* the peer shut down its sending side */
  int shutting;                  /* uv_shutdown sent: flushing, then closing */
  int closing;                   /* uv_close called or pending */
  int fatal_sent;                /* reading stopped, closing after the write */
  double t_fatal;                /* when the fatal ERROR was queued */
  int lingering;                 /* fatal ERROR written: half-closed, draining input */
  double t_linger;               /* when lingering began */
  int flush_sending;             /* stopping: the peer was sending while its replies went out */
  int flushed;                   /* stopping: replies out, waiting for the peer's end (TCP) */
  int handle_closed;
  int inflight;                  /* jobs admitted and not yet answered */
  int writes_pending;
  int read_paused;               /* too many replies unread by the peer */
  int pin_wait;                  /* a new segment is being pinned: not reading */
  int fd_sending;                /* SHM_CREATED and its descriptor not yet written: not reading */
  int is_ipc;                    /* a Unix socket that can pass segments */
  int is_pipe;                   /* a Unix socket: descriptors a client sends are seen */
  struct hfd_tls_conn *tls;      /* on a TLS listener: its session (tls.c) */
  hfd_seg *segs;
  int num_segs;
  uint64_t shm_bytes;            /* of its segments not yet freed (--max-shm-mb-per-connection) */
  struct hfd_shm_client *shm_client; /* its client's count (--max-shm-mb-per-client), or NULL */
  hfd_client *client;            /* its peer (clients.c); never NULL once accepted */
  hfd_client *share;             /* what holds its share of the queue: client, or own
                                  * with --queue-share-by connection */
  hfd_client own;                /* the connection as a client of its own */
  uint32_t next_seg_id;
  double t_accept;               /* for the handshake deadline */
  double t_last_read;            /* for the stall sweep */
  double t_window;               /* start of the current receive-rate window */
  uint64_t window_bytes;         /* received in it */
  uint64_t bytes_queued;         /* handed to uv_write, all replies */
  uint64_t ctl_bytes;            /* of replies other than RESULT, not yet written */
  uint64_t written_seen;         /* of those, written to the socket at t_write */
  double t_write;                /* last time a reply byte left */
  double t_rwin;                 /* start of the current reply-read-rate window */
  uint64_t rwin_written;         /* bytes written to the socket at t_rwin */

  enum hfd_read_state rstate;
  hfp_header hdr;
  uint8_t hbuf[HFP_HEADER_SIZE];
  uint8_t ctl[HFP_FILTER_FIXED + HFP_TOKEN_MAX + HFP_NAME_MAX + 16];
  size_t want, got;              /* bytes of the current piece */
  uint64_t discard_left;
  hfd_job *job;                  /* the FILTER being received */
  uint8_t sink[16384];           /* where discarded bytes go */
} hfd_conn;

struct hfd_server {
  uv_loop_t *loop;
  hfd_config *cfg;
  hfd_listener listeners[HFD_MAX_LISTENERS];
  int num_listeners;
  hfd_variant variants[HFD_MAX_VARIANTS];
  int num_variants;              /* slots used so far; serving: those with a model */
  hfd_worker worker;
  uv_async_t async;
  uv_signal_t sigint, sigterm;
  uv_signal_t sighup;            /* reload (models.c) */
  uv_signal_t sigusr1;           /* statistics to the log */
  uv_timer_t beat_timer;         /* loop heartbeat, systemd watchdog */
  uv_timer_t drain_timer;
  uv_timer_t flush_timer;        /* bounds the wait for peers to read replies */
  uv_timer_t sweep_timer;        /* closes stalled connections */
  uv_check_t accept_check;       /* resumes listeners past their accepts for a turn */
  int accepts_in_turn;           /* connections accepted since accept_check last ran; it
                                  * runs only after a deferral, so a listener is held
                                  * back one turn at most once per 64 accepts */
  hfd_conn *conns;               /* newest first, in the order of accepting */
  hfd_conn *conns_tail;          /* the oldest */
  int num_conns;
  int num_handshaking;           /* connections before their HELLO */
  int max_width, max_height;     /* --max-size, lowered to what a frame can meet */
  int max_connections;           /* --max-connections, lowered to the open-file limit */
  uint64_t conns_total, next_conn_id;
  uint64_t protocol_errors;
  uint64_t mem_held;             /* bytes charged: buffers and inference */
  hfd_rpool rpool;               /* receive buffers kept for reuse */
  uint64_t frame_budget;         /* the most one frame may need */
  uint64_t shm_held;             /* bytes of shared segments */
  struct hfd_shm_client *shm_clients; /* local clients with a connection that can hold segments */
  uint64_t replies_lost;         /* computed, never delivered (peer gone or closed) */
  /* RESULTs written, for the stop line: server-wide, so they outlive a
   * variant a reload removes (its STATS counters go with it). */
  uint64_t served_answered;      /* status 0 */
  uint64_t failed_answered;      /* another status, push-outs' BUSY not counted */
  uint64_t pushed_out_answered;  /* frames pushed out of the queue whose RESULT BUSY was
                                    written (one whose client had gone: replies_lost) */
  uint64_t refused_draining;     /* frames refused with an ERROR SHUTTING_DOWN while
                                    draining (never admitted, so in no count above) */
  int jobs_outstanding;          /* admitted, not yet answered */
  int pins_outstanding;          /* segments being pinned on the thread pool: the
                                    worker (and its backend) must outlive them */
  int sharers_with_frames;       /* queue-share holders (hfd_conn.share) with inflight > 0 */
  hfd_client *clients;           /* clients with a connection, listed (clients.c) */
  int draining, stopped;
  int hurry;                     /* a second signal: no more waiting */
  int ready_written;             /* the ready file is ours to remove */
  int files_removed;             /* socket files and ready file gone */
  int signals_closed;            /* the stop is complete */
  double t_start;
  double t_start_wall;           /* Unix time of the start, seconds */
  char backend_desc[512];
  /* Requests refused before a variant was known (malformed, unknown
   * variant), by status. */
  uint64_t unrouted[HFP_E_COUNT];
  /* Model repository (models.c). */
  int argc;
  char **argv;                   /* to read the configuration again */
  struct {
    int active;                  /* loads queued, not all back */
    int again;                   /* another SIGHUP came meanwhile */
    int pending;                 /* loads not yet back */
    int tls_failed;              /* this reload's TLS files did not load */
    hfd_ctl *done;               /* loads back, to apply together */
    hfd_model *remove[HFD_MAX_VARIANTS]; /* models whose file went away */
    int num_remove;
  } reload;
  uint64_t reloads_ok, reloads_failed;
  uint64_t loads_ok, loads_failed;
  int missing;                   /* configured files that serve no variant */
  char missing_why[300];         /* the first of them and why */
  int load_started;              /* startup: every variant built, the backend up */
  /* Liveness (http.c reads it from its own thread). */
  _Atomic uint64_t loop_beat_us;
  uint64_t watchdog_usec;        /* systemd's WatchdogSec, 0: none */
  struct hfd_http *http;
  struct hfd_tls *tls;           /* the TLS context, when a listener speaks TLS */
};

/* conn.c */
void hfd_on_connection(uv_stream_t *listener, int status);
void hfd_on_accept_check(uv_check_t *h);
void hfd_on_async(uv_async_t *a);
void hfd_conn_shutdown(hfd_conn *c);
void hfd_conn_close(hfd_conn *c);
/* Whether one more error line a peer caused fits the loop's budget (20 a
 * second; what is dropped is counted in the next line): a peer can cause
 * them as fast as it connects, and journald, past its own rate limit,
 * drops every line of the service, an operator's real errors too. */
int hfd_conn_log_allowed(void);
/* Frees c once its handle is closed and nothing in flight (jobs, writes,
 * a segment being pinned, a TLS handshake step) points at it; else later,
 * when the last of them calls this again. */
void hfd_conn_release(hfd_conn *c);
/* Closes connections past their handshake deadline, silent or too slow in
 * the middle of a frame, or whose peer has stopped reading its replies. */
void hfd_sweep_stalled(hfd_server *s);
/* pool.c: threads for work the loop must not wait for (a TLS handshake's
 * key exchange and signature), at a lower CPU priority than the loop.
 * A task is submitted on the loop, run on a thread, and done on the loop. */
typedef struct hfd_pool_task {
  struct hfd_pool_task *next;
  void (*run)(struct hfd_pool_task *t);   /* on a pool thread */
  void (*done)(struct hfd_pool_task *t);  /* on the loop, after run; may free t */
} hfd_pool_task;
typedef struct hfd_pool hfd_pool;
/* Starts the threads (one per four CPUs, 1..4; named what in the log) and
 * their uv_async on loop: 0, or -1 after logging why. */
int hfd_pool_start(hfd_pool **out, uv_loop_t *loop, const char *what);
/* How many threads run. */
int hfd_pool_threads(const hfd_pool *p);
/* Queues t (first in, first out): 0, or a negative error (the pool is
 * closing: UV_ECANCELED), when t->done will not be called. Loop thread. */
int hfd_pool_submit(hfd_pool *p, hfd_pool_task *t);
/* Tasks submitted whose done has not run yet. Loop thread. */
int hfd_pool_outstanding(const hfd_pool *p);
/* Closes the uv_async (the loop's last turn): call when nothing is
 * outstanding. hfd_pool_free after uv_run joins the threads. */
void hfd_pool_close(hfd_pool *p);
void hfd_pool_free(hfd_pool *p);
/* tls.c: TLS on TCP listeners, OpenSSL through memory BIOs. */
/* Builds the context from --tls-cert, --tls-key and --tls-client-ca when a
 * listener is tls:; 0, or -1 after logging which file failed and why. */
int hfd_tls_init(hfd_server *s);
/* SIGHUP: builds a context from the new configuration's files and swaps it
 * in for new connections; on any failure the one before keeps serving
 * (logged) and -1 is returned, which makes the reload a failed one. */
int hfd_tls_reload(hfd_server *s, const hfd_config *n);
/* identity.c: the daemon's effective user and group by name, or their
 * number where none is found, for permission errors (always NUL-ended). */
void hfd_user_name(char *buf, size_t cap);
void hfd_group_name(char *buf, size_t cap);
/* The notAfter of the certificate new TLS connections get (the one loaded at
 * start or by the last reload that loaded), in seconds since 1970-01-01 UTC:
 * 0, or -1 without a TLS listener or where OpenSSL cannot read the time. */
int hfd_tls_not_after(const hfd_server *s, long long *unix_s);
/* Closes the loop handles (drain's last step, once no handshake step is
 * outstanding); hfd_tls_free after uv_run joins the handshake threads. */
void hfd_tls_stop(hfd_server *s);
/* Handshake steps handed to the threads and not back on the loop yet. */
int hfd_tls_steps_outstanding(const hfd_server *s);
/* 1 while a step of c's handshake is on a thread: c's SSL object is that
 * thread's, and c is not freed before the step is back. */
int hfd_tls_stepping(const hfd_conn *c);
void hfd_tls_free(hfd_server *s);
/* A connection accepted on a TLS listener gets its session: 0 or a UV_E*. */
int hfd_tls_conn_start(hfd_conn *c);
/* Its handle closed: writes still queued complete with UV_ECANCELED. */
void hfd_tls_conn_closing(hfd_conn *c);
void hfd_tls_conn_free(hfd_conn *c);
/* The stream calls of conn.c: libuv's own on a plain connection, through
 * TLS on a TLS one (same callbacks, same guarantees). */
int hfd_io_read_start(hfd_conn *c, uv_alloc_cb alloc_cb, uv_read_cb read_cb);
int hfd_io_read_stop(hfd_conn *c);
int hfd_io_write(hfd_conn *c, uv_write_t *req, const uv_buf_t *bufs, unsigned nbufs,
                 uv_write_cb cb);
int hfd_io_shutdown(hfd_conn *c, uv_shutdown_t *req, uv_shutdown_cb cb);
/* 1 when c is a TLS connection whose handshake completed and has not
 * failed: its stream can be ended with close_notify and read on. */
int hfd_tls_established(const hfd_conn *c);
/* 1 when c was answered with a fatal ERROR before its TLS handshake was
 * done, and the handshake has come neither within HFD_TLS_FATAL_GRACE_MS of
 * that ERROR nor within the handshake deadline (10 s without one): the
 * ERROR can never be sent, so the sweep closes it. */
#define HFD_TLS_FATAL_GRACE_MS 2000
int hfd_tls_overdue(const hfd_conn *c, double now_us);
/* 1 when c is a TLS connection the server has not answered yet: its peer
 * has sent no whole ClientHello (nothing, a byte, the start of one), and
 * no whole record waits unread in its socket. Such a peer has cost itself
 * no more than a bare connection. */
int hfd_tls_unanswered(const hfd_conn *c);
/* 1 when a whole TLS record waits unread in c's socket: the peer has done
 * its part of the handshake's step, the server has not read it yet. Once
 * seen, remembered until the socket is read (no second look). */
int hfd_tls_record_waiting(const hfd_conn *c);
/* Reply bytes handed over and not yet written to the socket. */
size_t hfd_io_write_queue_size(const hfd_conn *c);
/* clients.c */
/* Counts c, accepted, in its client (c->client; made when it is the
 * client's first connection) and sets c->share. A connection whose peer
 * cannot be told (no pid, no address) or that finds no memory for an entry
 * is a client of its own (the latter logged). */
void hfd_client_join(hfd_server *s, hfd_conn *c);
/* c is freed: its client goes with its last connection. */
void hfd_client_leave(hfd_server *s, hfd_conn *c);
/* The most connections before their HELLO one IP address may hold:
 * --max-handshakes-per-address, or by default half of --max-handshakes
 * (at least 1), never more than --max-handshakes (as many: no bound but
 * that one). */
int hfd_client_handshake_cap(const hfd_server *s);
/* limits.c */
/* Host memory a frame is charged while the server holds it: its features
 * (unless in a shared segment), result and composite buffers, and what
 * running it takes (hfd_worker_run_bytes). UINT64_MAX when it cannot run. */
uint64_t hfd_frame_bytes(const hfd_server *s, int variant, const hfp_filter *f);
/* Lowers --max-size to the largest W x H (same aspect) at which a frame of
 * every loaded variant, f32 in and out with a composite, fits both the
 * frame limit and the memory one frame may use; logs why it was lowered.
 * -1 when not even 1x1 fits (the budget is too small to serve anything). */
int hfd_limits_derive(hfd_server *s);
/* Sets s->max_connections: --max-connections, when the open-file limit
 * holds that many connections (raising the soft limit up to the hard one
 * when needed), else as many as it holds, with a warning naming both and
 * the fix. -1, logged, when not even one fits. */
int hfd_limits_fds(hfd_server *s);
/* libmicrohttpd's connection limit on the --http endpoint (http.c). */
#define HFD_HTTP_CONN_LIMIT 128
/* shm.c */
/* A local client, one process (the pid SO_PEERCRED gives for its Unix
 * socket), and the segments its connections hold together. A peer whose
 * pid the daemon cannot see (another pid namespace: 0) is a client of its
 * own on each connection. */
typedef struct hfd_shm_client {
  struct hfd_shm_client *next;
  long pid;                      /* > 0, or 0: this connection alone */
  int conns;                     /* connections counted in it */
  uint64_t bytes;                /* of their segments not yet freed */
} hfd_shm_client;
/* Counts c (a Unix-socket connection that can hold segments) in its
 * client's entry, made when it is the client's first: 0, or -1 (out of
 * memory, logged) when c is left its own client. */
int hfd_shm_client_join(hfd_server *s, hfd_conn *c);
/* c is freed: its client's entry goes with its last connection. */
void hfd_shm_client_leave(hfd_server *s, hfd_conn *c);
/* The shared memory one client may hold, all its connections together:
 * --max-shm-mb-per-client, or by default a quarter of --max-shm-mb but at
 * least the segments of the largest frame HELLO_OK announces (features and
 * estimate, result and composite, all f32), and never more than
 * --max-shm-mb. */
uint64_t hfd_shm_client_cap(const hfd_server *s);
/* The shared memory one connection may hold: --max-shm-mb-per-connection
 * (at most --max-shm-mb), or by default the client's part. */
uint64_t hfd_shm_conn_cap(const hfd_server *s);
/* The largest segment one connection can ever be given: the smallest of
 * the budget, the connection's part and the client's part. */
uint64_t hfd_shm_segment_max(const hfd_server *s);
/* The segments the largest frame HELLO_OK announces needs, for the most
 * demanding loaded variant: f32 features (and estimate), f32 result and
 * composite. */
uint64_t hfd_shm_largest_frame(const hfd_server *s);
/* Makes a sealed, mapped segment of bytes for connection c; *fd is its
 * memfd, which the caller sends to the peer and then closes. Not pinned:
 * hfd_seg_pin. 0, or an HFP_E_* code with the reason in why: TOO_LARGE
 * for a segment over the whole budget, a connection's part or a client's,
 * BUSY for one over what is left of any of them (naming the option). */
int hfd_seg_create(hfd_server *s, hfd_conn *c, uint64_t bytes, hfd_seg **out, int *fd, char *why,
                   size_t whylen);
/* Pins g for the backend's DMA (hf_backend_host_register): HF_OK, or the
 * backend's error (then frames in g are staged: slower, same results).
 * Safe on any thread while nothing else touches g; takes milliseconds
 * (cudaHostRegister: 1.7 ms for 8 MiB to 7.1 ms for 192 MiB on an H200
 * host, docs/GPU.md), so hairfilterd calls it on libuv's thread pool. */
int hfd_seg_pin(hfd_server *s, hfd_seg *g);
/* On the loop, once hfd_seg_pin returned rc: records it, and says once per
 * process when a backend could not pin. */
void hfd_seg_pinned(hfd_server *s, hfd_seg *g, int rc);
void hfd_seg_unref(hfd_server *s, hfd_seg *g);
/* Drops the connection's reference (SHM_DESTROY or close). */
void hfd_seg_drop(hfd_server *s, hfd_seg *g);
/* hairfilterd.c */
void hfd_maybe_finish(hfd_server *s);
void hfd_fill_stats(hfd_server *s, hfp_stats *st);
/* ready_file.c */
/* Before the models are built: refuses a --ready-file that is a directory
 * or a running daemon's, removes a stale one, and checks that one can be
 * written beside the path. 0, or -1 after saying why and what to do. */
int hfd_ready_file_prepare(const hfd_config *cfg);
/* Writes the listeners' URLs (and http_url when not empty) to the ready
 * file whole, then renames it into place, so a reader never sees half of
 * it (rename replaces a symlink at the target rather than following it).
 * 0, or -1 after saying why and what to do. */
int hfd_ready_file_write(const hfd_server *s, const char *http_url);

/* 1 when serving: the backend up, every configured file serving a variant,
 * at least one variant, not draining, every Unix socket file still the one
 * bound; else 0 with why. Loop thread. */
int hfd_ready(const hfd_server *s, char *why, size_t whylen);

/* models.c */
/* The slot serving name, or -1. */
int hfd_variant_find(const hfd_server *s, const char *name);
/* Loads what the configuration names, waiting for the worker: 0, or -1
 * after logging why (any file that fails stops the start), or 1 when a stop
 * came meanwhile (hfd_worker_abandon_loads): then nothing is installed, and
 * the models built go when the worker stops. */
int hfd_models_load_initial(hfd_server *s);
/* SIGHUP: reads the configuration and the weights directory again, loads
 * new and changed files on the worker, and swaps them in when all are
 * back; files gone are drained and unloaded. */
void hfd_models_reload(hfd_server *s);
/* A LOAD came back (from hfd_on_async). */
void hfd_models_on_loaded(hfd_server *s, hfd_ctl *ctl);
/* The worker has stopped (and freed every model it built): frees what a
 * reload in flight was still waiting to apply. */
void hfd_models_after_stop(hfd_server *s);
/* A job or a variant lets go of a model; the last one unloads it. */
void hfd_model_unref(hfd_server *s, hfd_model *m);

/* metrics.c */
/* Counts an answer (RESULT or refusal) for a variant slot, or for no variant
 * (slot -1), by status. */
void hfd_metrics_count(hfd_server *s, int slot, int status);
/* Records a successful request's timings. */
void hfd_metrics_observe(hfd_server *s, const hfd_job *j);
/* Counts one backend run, of which j is the first job: STATS' batches and
 * the batch_size histogram of j's variant. Loop thread. */
void hfd_metrics_batch(hfd_server *s, const hfd_job *j);
/* Prometheus text exposition format 0.0.4 of everything /metrics shows,
 * taken on the loop thread; *out is malloc'd, *len its length. */
int hfd_metrics_render(hfd_server *s, char **out, size_t *len);
/* The statistics as log lines (SIGUSR1). */
void hfd_metrics_log(hfd_server *s);

/* http.c: /metrics, /healthz, /readyz on libmicrohttpd's own thread. */
/* Starts the endpoint on cfg->http; url gets "http://HOST:PORT". */
int hfd_http_start(hfd_server *s, char *url, size_t urlcap);
/* The loop is about to stop answering: requests for metrics get 503. */
void hfd_http_loop_closing(hfd_server *s);
void hfd_http_stop(hfd_server *s);

/* notify.c: systemd (sd_notify); every call is a no-op outside systemd. */
void hfd_notify_ready(hfd_server *s);
void hfd_notify_reloading(void);
void hfd_notify_stopping(void);
void hfd_notify_status(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void hfd_notify_watchdog(void);

#endif /* HFD_SERVER_H */
