/* Test harness for hairfilterd: start and stop a real daemon, raw protocol
 * sockets for what the client library would never send, and in-process
 * reference inference to compare against. */
#ifndef HF_TEST_HARNESS_H
#define HF_TEST_HARNESS_H

#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#include <hairfilter/hairfilter.h>
#include "hfcore.h"
#include "hfproto.h"

#define TEST_TOKEN "t0ken-for-tests"

/* Variants every test server loads (random weights, fixed seeds). */
typedef struct ref_variant {
  hf_net_config cfg;
  hf_model *model;     /* cpu-ref, in process */
} ref_variant;

typedef struct harness {
  char dir[128];               /* mkdtemp */
  char weights_dir[192];
  ref_variant v[4];
  int nv;
  hf_backend *backend;
} harness;

typedef struct server {
  pid_t pid;
  char log[256];
  char unix_url[256];
  char tcp_url[256];
  char tls_url[256];           /* when a tls: listener was among the extra arguments */
  char ready[256];
} server;

/* Creates the temp dir, the weight files and the reference models. */
int harness_init(harness *h);
void harness_free(harness *h);
const ref_variant *harness_variant(const harness *h, const char *name);
/* "Narrow": Small's shape with random weights (seed 77) whose metadata
 * records the trained range range_json (hf_input_range_parse's JSON, spp
 * 4), written to <dir>/narrow/Narrow.safetensors, out of the weights
 * directory so the other servers do not see it. Its path goes to path;
 * returns 0 or -1. */
int harness_narrow_weights(const harness *h, const char *range_json, char *path, size_t cap);
/* A small Kernel network that reads the alpha-corrected estimate (KernelAC's
 * kind: 2 levels of 8 and 16 channels, a 3x3 kernel, a 4-channel head),
 * named "Estimate", written to <dir>/estimate/Estimate.safetensors (out of
 * the weights directory). Its path goes to path; returns 0 or -1. */
int harness_estimate_weights(const harness *h, char *path, size_t cap);

/* Starts hairfilterd on a fresh Unix socket and a loopback port 0 with the
 * harness weights on cpu-ref, plus extra arguments (NULL-terminated).
 * Waits for its ready file; returns 0 or -1 (and prints its log). */
int server_start(const harness *h, server *s, const char *const *extra);
/* The same, with the ready file at ready_path (NULL: one in the temp dir)
 * and $HAIRFILTERD_TOKEN set to token_env (NULL: TEST_TOKEN). */
int server_start_ex(const harness *h, server *s, const char *const *extra,
                    const char *ready_path, const char *token_env);
/* Runs hairfilterd with exactly args (NULL-terminated, argv[0] added) and
 * $HAIRFILTERD_TOKEN = token_env (NULL: unset) until it exits, at most
 * timeout_ms; its stderr goes to out. Returns the exit status, or -1. */
int daemon_run(const char *const *args, const char *token_env, int timeout_ms, char *out,
               size_t outlen);

/* SIGTERM, then waits up to timeout_ms; returns the exit status, or -1 if it
 * had to be killed. */
int server_stop(server *s, int timeout_ms);
int server_alive(const server *s);
/* SIGSTOP, returning 0 once the whole daemon has stopped (-1 if it did
 * not): kill() only makes the signal pending, and the thread picked to
 * take it may wait for a CPU while the daemon's other threads still read
 * and answer, on a loaded machine for milliseconds. */
int server_pause(server *s);
/* 1 when the log contains needle. */
int server_log_has(const server *s, const char *needle);
/* The number of log lines that contain needle. */
int server_log_count(const server *s, const char *needle);
void server_dump_log(const server *s);
/* server_stop (dumping the log if it did not exit cleanly) and harness_free:
 * a cmocka group teardown's body; 0 when the server exited with status 0. */
int harness_stop(harness *h, server *s);
/* Client options: name, token (NULL: none), timeout; the rest defaults. */
hfc_options test_options(const char *name, const char *token, int timeout_ms);
/* server_start with extra, then a client named name on its Unix socket
 * (20 s timeout) in *c: 0, or -1 when either failed. */
int server_start_connected(const harness *h, server *s, const char *const *extra,
                           const char *name, hfc_client **c);
/* A request from designated initialisers, with struct_size set and every
 * buffer size left at 0 set to what its dimensions need (the tests' buffers
 * are exactly that large):
 *   hfc_request r = TEST_REQUEST(.variant = "Tiny", .width = 8, ...); */
#define TEST_REQUEST(...) test_request_sized((hfc_request){.struct_size = sizeof(hfc_request), __VA_ARGS__})
hfc_request test_request_sized(hfc_request r);
/* The server's listing of variant name (hfc_list_variants) into *out: 0, or
 * -1 when it lists none of that name or the listing fails. */
int listed_variant(hfc_client *c, const char *name, hfc_variant *out);
/* A libhairfilter connection to the server's Unix socket, or NULL (printed). */
hfc_client *client_connect(const server *s, const char *name);
/* A file's first cap - 1 bytes as a string in buf; -1 if unreadable. */
int read_text_file(const char *path, char *buf, size_t cap);

/* Deterministic features in plausible ranges. */
float *make_features(int w, int h, int spp, uint32_t seed);
/* Reference run on the in-process model. */
int reference(const ref_variant *v, int w, int h, const void *in, int in_dtype, void *out,
              int out_dtype);

/* The body of GET path on the daemon's --http endpoint, whose URL
 * (http://HOST:PORT) its ready file lists; malloc'd, or NULL. */
char *http_get(const server *d, const char *path);
/* Milliseconds on the monotonic clock, for deadlines and durations. */
double now_ms(void);

/* Raw sockets (blocking, 10 s timeouts). */
int raw_connect(const char *url);
/* raw_connect with the socket's receive buffer set to rcvbuf bytes before
 * it connects (0: the system's), so that a peer's replies back up. */
int raw_connect_rcvbuf(const char *url, int rcvbuf);
int raw_send(int fd, const void *buf, size_t n);
/* Sends HELLO and reads HELLO_OK; 0 on success. */
int raw_hello(int fd, const char *token);
/* The same offering protocol versions lo..hi (raw_hello offers 1 only). */
int raw_hello_versions(int fd, const char *token, int lo, int hi);
/* Reads one frame: payload (malloc'd) in *payload. 0, or -1 on EOF/timeout. */
int raw_read(int fd, hfp_header *h, uint8_t **payload);
/* The same, also taking a descriptor passed with the frame (-1 if none). */
int raw_read_fd(int fd, hfp_header *h, uint8_t **payload, int *passed);
/* raw_connect then raw_hello_versions (no token): the socket, or -1
 * (closed) when either fails. */
int raw_connect_versions(const char *url, int lo, int hi);
/* Sends STATS on fd and reads the STATS_REPLY: variant's counters, as a
 * connection of fd's version reads them, into *out; 0, or -1 (no reply,
 * another type, a reply that does not decode, no such variant). */
int raw_variant_stats(int fd, const char *variant, hfp_variant_stats *out);
/* Builds a FILTER frame (malloc'd, *len bytes). */
uint8_t *raw_filter(uint32_t id, const char *variant, int w, int h, int spp, const float *in,
                    size_t *len);
/* The same with FILTER flag DEADLINE and budget_us (0: no flag), for a
 * connection of version 4. */
uint8_t *raw_filter_budget(uint32_t id, const char *variant, int w, int h, int spp,
                           const float *in, uint32_t budget_us, size_t *len);
/* 1 when the peer has closed (recv returns 0 within timeout_ms). */
int raw_closed(int fd, int timeout_ms);
/* Reads one frame that must be an ERROR: 0 with *h and *e filled, -1 for
 * anything else (EOF, another type, a bad ERROR). */
int raw_read_error(int fd, hfp_header *h, hfp_error *e);
/* A HELLO frame with the given versions, name and token (NULL: none) into
 * buf; returns its size. */
size_t raw_hello_frame(uint8_t *buf, size_t cap, uint16_t min_version, uint16_t max_version,
                       const char *token);

#endif
