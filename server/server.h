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

/* ---- logging ----------------------------------------------------------- */

void hfd_log(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
extern int hfd_verbose;
#define hfd_debug(...) \
  do {                 \
    if (hfd_verbose) hfd_log(__VA_ARGS__); \
  } while (0)

/* ---- configuration ----------------------------------------------------- */

typedef struct hfd_config {
  const char *listen[HFD_MAX_LISTENERS];
  hfp_url listen_url[HFD_MAX_LISTENERS];   /* parsed at option time */
  int num_listen;
  const char *weights[HFD_MAX_VARIANTS];
  int num_weights;
  const char *weights_dir;
  const char *backend;           /* auto | cpu | cpu-ref | cudnn */
  int max_batch;                 /* frames per backend run */
  int max_queue_delay_us;        /* how long a batch may wait for partners */
  int queue_size;                /* admitted, not yet running */
  int max_inflight;              /* per connection */
  int max_width, max_height;
  int max_connections;
  int max_handshakes;            /* connections that have not said HELLO */
  uint64_t max_frame_bytes;      /* largest payload read */
  uint64_t max_memory_bytes;     /* request buffers + inference memory */
  uint64_t max_shm_bytes;        /* shared segments held at once; 0: no SHM */
  int drain_timeout_ms;          /* queued work after SIGTERM */
  int flush_timeout_ms;          /* then, replies still unread by peers */
  int handshake_timeout_ms;      /* accept -> HELLO complete; 0: none */
  int stall_timeout_ms;          /* mid-frame silence, rate window; 0: none */
  uint64_t min_recv_rate;        /* bytes/s a frame must arrive at; 0: none */
  int no_auth;
  char token[HFP_TOKEN_MAX + 1];
  const char *ready_file;
  const char *name;
  /* Shapes whose plans every variant builds before serving (--warm). */
  struct {
    int width, height, batch;
  } warm[HFD_MAX_WARM];
  int num_warm;
  int pipeline_depth;            /* backend runs pending at once: 1 or 2 */
} hfd_config;

int hfd_config_parse(int argc, char **argv, hfd_config *cfg);

/* ---- variants ---------------------------------------------------------- */

typedef struct hfd_variant {
  char name[HFP_NAME_MAX + 1];
  hf_weights *weights;           /* freed once the worker built the model */
  hf_model *model;               /* worker thread only */
  hf_net_config cfg;
  char precision[16];
  hf_input_range range;          /* trained input range; .present 0: none */
  hfp_variant_stats stats;       /* loop thread only */
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
} hfd_seg;

typedef struct hfd_job {
  struct hfd_job *next;
  struct hfd_conn *conn;
  uint32_t request_id;
  int variant;
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
  int batch_leader;              /* counts the backend run in the stats */
  uint64_t sanitised;            /* samples hf_model_run sanitised (FEATURES.md) */
  int status;                    /* HFP_OK or an HFP_E_* code */
  int out_of_range;              /* input outside the variant's trained range */
  hfd_seg *seg;                  /* tensors live in this segment, or NULL */
  uint8_t head[HFP_RESULT_HEAD_MAX];
  uv_write_t wreq;
} hfd_job;

typedef struct hfd_worker {
  pthread_t thread;
  pthread_mutex_t mu;
  pthread_cond_t cv;
  hfd_job *q_head, *q_tail;
  int q_len, q_cap;
  hfd_job *done_head, *done_tail;
  int stop;                      /* finish what is queued, then exit */
  int cancel;                    /* fail what is queued, then exit */
  int busy;                      /* a batch is running */
  /* startup handshake */
  int ready, init_rc;
  char init_msg[512];
  /* set before start */
  const char *backend_name;
  hfd_variant *variants;
  int num_variants;
  int max_batch;
  double max_delay_us;
  int pipeline_depth;
  const hfd_config *cfg;         /* for the warm shapes */
  uv_async_t *async;
  uint64_t cache_cap;            /* plans and scratch kept between runs */
  /* Host memory kept between runs (backend plans, the worker's scratch):
   * written by the worker, read by the loop thread when it admits a frame. */
  _Atomic uint64_t cached_bytes;
  /* worker-private */
  hf_backend *backend;
  void *scratch_in, *scratch_out;
  size_t scratch_in_cap, scratch_out_cap;
  float *scratch_rgb;
  size_t scratch_rgb_cap;
} hfd_worker;

/* Starts the thread; it creates the backend and the models and reports
 * through init_rc / init_msg before hfd_worker_start returns. */
int hfd_worker_start(hfd_worker *w);
/* 0 when queued, HFP_E_BUSY when the queue is full. */
int hfd_worker_submit(hfd_worker *w, hfd_job *job);
/* Takes every completed job (in completion order). */
hfd_job *hfd_worker_take_done(hfd_worker *w);
int hfd_worker_queue_depth(hfd_worker *w);
/* Fails every queued job with HFP_E_SHUTTING_DOWN. */
void hfd_worker_cancel(hfd_worker *w);
/* Asks the thread to exit once the queue is empty, and joins it. */
void hfd_worker_stop(hfd_worker *w);
/* Host memory the worker needs to run batch frames of variant at width x
 * height whose features are in_bytes each: the backend's hf_run_bytes plus
 * the worker's own batch and conversion buffers. UINT64_MAX when the
 * backend cannot run that size. Pure; callable from either thread once the
 * worker has started. */
uint64_t hfd_worker_run_bytes(const hfd_worker *w, int variant, uint32_t width,
                              uint32_t height, int batch, uint64_t in_bytes);

double hfd_now_us(void);

/* ---- listeners and connections ----------------------------------------- */

typedef struct hfd_server hfd_server;

typedef struct hfd_listener {
  union {
    uv_tcp_t tcp;
    uv_pipe_t pipe;
    uv_stream_t stream;
    uv_handle_t handle;
  } h;
  hfd_server *srv;
  int is_tcp;
  int auth_required;
  char url[256];                 /* as resolved (the real port) */
  char unix_path[200];
} hfd_listener;

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
  int eof;                       /* the peer shut down its sending side */
  int shutting;                  /* uv_shutdown sent: flushing, then closing */
  int closing;                   /* uv_close called or pending */
  int fatal_sent;                /* reading stopped, closing after the write */
  int handle_closed;
  int inflight;                  /* jobs admitted and not yet answered */
  int writes_pending;
  int read_paused;               /* too many replies unread by the peer */
  int is_ipc;                    /* a Unix socket that can pass segments */
  hfd_seg *segs;
  int num_segs;
  uint32_t next_seg_id;
  double t_accept;               /* for the handshake deadline */
  double t_last_read;            /* for the stall sweep */
  double t_window;               /* start of the current receive-rate window */
  uint64_t window_bytes;         /* received in it */
  uint64_t bytes_queued;         /* handed to uv_write, all replies */
  uint64_t written_seen;         /* of those, written to the socket at t_write */
  double t_write;                /* last time a reply byte left */

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
  int num_variants;
  hfd_worker worker;
  uv_async_t async;
  uv_signal_t sigint, sigterm;
  uv_timer_t drain_timer;
  uv_timer_t flush_timer;        /* bounds the wait for peers to read replies */
  uv_timer_t sweep_timer;        /* closes stalled connections */
  hfd_conn *conns;
  int num_conns;
  int num_handshaking;           /* connections before their HELLO */
  int max_width, max_height;     /* --max-size, lowered to what a frame can meet */
  uint64_t conns_total, next_conn_id;
  uint64_t protocol_errors;
  uint64_t mem_held;             /* bytes charged: buffers and inference */
  uint64_t frame_budget;         /* the most one frame may need */
  uint64_t shm_held;             /* bytes of shared segments */
  uint64_t replies_lost;         /* computed, but the peer had gone */
  int jobs_outstanding;          /* admitted, not yet answered */
  int draining, stopped;
  int hurry;                     /* a second signal: no more waiting */
  int ready_written;             /* the ready file is ours to remove */
  int files_removed;             /* socket files and ready file gone */
  int signals_closed;            /* the stop is complete */
  double t_start;
  char backend_desc[512];
};

/* conn.c */
void hfd_on_connection(uv_stream_t *listener, int status);
void hfd_on_async(uv_async_t *a);
void hfd_conn_shutdown(hfd_conn *c);
void hfd_conn_close(hfd_conn *c);
/* Closes connections past their handshake deadline, silent or too slow in
 * the middle of a frame, or whose peer has stopped reading its replies. */
void hfd_sweep_stalled(hfd_server *s);
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
/* shm.c */
/* Makes a sealed, mapped segment of bytes; *fd is its memfd, which the
 * caller sends to the peer and then closes. */
int hfd_seg_create(hfd_server *s, uint64_t bytes, hfd_seg **out, int *fd, char *why,
                   size_t whylen);
void hfd_seg_unref(hfd_server *s, hfd_seg *g);
/* Drops the connection's reference (SHM_DESTROY or close). */
void hfd_seg_drop(hfd_server *s, hfd_seg *g);
/* server.c */
void hfd_maybe_finish(hfd_server *s);
void hfd_fill_stats(hfd_server *s, hfp_stats *st);

#endif /* HFD_SERVER_H */
