#define _POSIX_C_SOURCE 200809L
#define _DEFAULT_SOURCE
#include "harness.h"

#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#ifndef HAIRFILTERD_PATH
#error "HAIRFILTERD_PATH must name the daemon under test"
#endif

static void sleep_ms(int ms) {
  struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
  nanosleep(&ts, NULL);
}

/* Three variants with different spp and depth, small enough for cpu-ref. */
static const struct {
  const char *name;
  int spp, L, levels[3];
} variants[] = {
  {"Tiny", 2, 2, {8, 16}},
  {"Small", 4, 3, {16, 32, 64}},
  {"Mono", 1, 3, {8, 16, 32}},
};

int harness_init(harness *h) {
  memset(h, 0, sizeof *h);
  const char *tmp = getenv("TMPDIR");
  snprintf(h->dir, sizeof h->dir, "%s/hfsrv-XXXXXX", tmp && *tmp ? tmp : "/tmp");
  if (!mkdtemp(h->dir)) return -1;
  snprintf(h->weights_dir, sizeof h->weights_dir, "%s/weights", h->dir);
  if (mkdir(h->weights_dir, 0700)) return -1;
  char why[256];
  if (hf_backend_create("cpu-ref", &h->backend, why, sizeof why)) return -1;
  for (size_t i = 0; i < sizeof variants / sizeof variants[0]; i++) {
    hf_net_config c;
    memset(&c, 0, sizeof c);
    snprintf(c.name, sizeof c.name, "%s", variants[i].name);
    c.spp = variants[i].spp;
    c.in_channels = c.spp * HF_FEATURES_PER_SAMPLE;
    c.out_channels = HF_OUT_CHANNELS;
    c.num_levels = variants[i].L;
    for (int l = 0; l < c.num_levels; l++) c.levels[l] = variants[i].levels[l];
    if (hf_net_config_validate(&c)) return -1;
    hf_weights *w;
    if (hf_weights_init_random(&c, 1000 + i, &w)) return -1;
    char path[320];
    snprintf(path, sizeof path, "%s/%s.safetensors", h->weights_dir, c.name);
    int rc = hf_weights_save(path, w);
    if (!rc) rc = hf_model_create(h->backend, w, &h->v[h->nv].model);
    hf_weights_free(w);
    if (rc) return -1;
    h->v[h->nv++].cfg = c;
  }
  return 0;
}

/* Every daemon server_start_ex started, so that harness_free can stop those
 * a failed assertion left running: cmocka leaves a test at its first
 * failure, past the test's own server_stop. */
static pid_t started[256];
static int nstarted;

void harness_free(harness *h) {
  for (int i = 0; i < nstarted; i++) {
    int st;
    if (waitpid(started[i], &st, WNOHANG) != 0) continue;   /* reaped, or gone */
    fprintf(stderr, "harness: hairfilterd (pid %d) outlived its test (a failed assertion "
            "skipped its stop): killed\n", (int)started[i]);
    kill(started[i], SIGKILL);
    waitpid(started[i], NULL, 0);
  }
  nstarted = 0;
  for (int i = 0; i < h->nv; i++) hf_model_destroy(h->v[i].model);
  hf_backend_destroy(h->backend);
  char cmd[300];
  snprintf(cmd, sizeof cmd, "rm -rf '%s'", h->dir);
  if (system(cmd) != 0) fprintf(stderr, "harness: could not remove %s\n", h->dir);
}

/* Random weights of cfg (named name, seed) into <dir>/<sub>/<name>.safetensors,
 * out of the weights directory so the other suites' servers do not see
 * them; range_json, when not NULL, as their trained range. */
static int weights_aside(const harness *h, const char *sub, hf_net_config cfg, const char *name,
                         uint64_t seed, const char *range_json, char *path, size_t cap) {
  char dir[256];
  snprintf(dir, sizeof dir, "%s/%s", h->dir, sub);
  if (mkdir(dir, 0700)) return -1;
  snprintf(path, cap, "%s/%s.safetensors", dir, name);
  snprintf(cfg.name, sizeof cfg.name, "%s", name);
  hf_weights *w = NULL;
  if (hf_weights_init_random(&cfg, seed, &w)) return -1;
  int rc = (range_json && hf_input_range_parse(range_json, cfg.spp, &w->input_range, NULL, 0)) ||
           hf_weights_save(path, w);
  hf_weights_free(w);
  return rc ? -1 : 0;
}

int harness_narrow_weights(const harness *h, const char *range_json, char *path, size_t cap) {
  hf_net_config cfg;
  if (hf_variant_preset("Small", &cfg)) return -1;
  return weights_aside(h, "narrow", cfg, "Narrow", 77, range_json, path, cap);
}

int harness_estimate_weights(const harness *h, char *path, size_t cap) {
  hf_net_config cfg;
  if (hf_variant_preset("KernelAC", &cfg)) return -1;
  cfg.num_levels = 2, cfg.levels[0] = 8, cfg.levels[1] = 16;
  cfg.kernel_radius = 1, cfg.kernel_hidden = 4;
  cfg.out_channels = hf_kernel_taps(1) + HF_OUT_CHANNELS;
  return weights_aside(h, "estimate", cfg, "Estimate", 78, NULL, path, cap);
}

const ref_variant *harness_variant(const harness *h, const char *name) {
  for (int i = 0; i < h->nv; i++)
    if (!strcmp(h->v[i].cfg.name, name)) return &h->v[i];
  return NULL;
}

void server_dump_log(const server *s) {
  FILE *f = fopen(s->log, "r");
  if (!f) return;
  char line[1024];
  fprintf(stderr, "---- %s ----\n", s->log);
  while (fgets(line, sizeof line, f)) fputs(line, stderr);
  fclose(f);
}

int server_log_count(const server *s, const char *needle) {
  FILE *f = fopen(s->log, "r");
  if (!f) return 0;
  char line[1024];
  int n = 0;
  while (fgets(line, sizeof line, f)) n += strstr(line, needle) != NULL;
  fclose(f);
  return n;
}

int server_log_has(const server *s, const char *needle) { return server_log_count(s, needle) > 0; }

int server_start(const harness *h, server *s, const char *const *extra) {
  return server_start_ex(h, s, extra, NULL, NULL);
}

int server_start_ex(const harness *h, server *s, const char *const *extra,
                    const char *ready_path, const char *token_env) {
  static int serial;
  memset(s, 0, sizeof *s);
  serial++;
  char sock[200];
  snprintf(sock, sizeof sock, "%s/s%d.sock", h->dir, serial);
  snprintf(s->log, sizeof s->log, "%s/server%d.log", h->dir, serial);
  if (ready_path)
    snprintf(s->ready, sizeof s->ready, "%s", ready_path);
  else
    snprintf(s->ready, sizeof s->ready, "%s/ready%d", h->dir, serial);
  char listen_unix[220];
  snprintf(listen_unix, sizeof listen_unix, "unix:%s", sock);
  const char *argv[64];
  int n = 0;
  argv[n++] = HAIRFILTERD_PATH;
  argv[n++] = "--listen";
  argv[n++] = listen_unix;
  argv[n++] = "--listen";
  argv[n++] = "tcp:127.0.0.1:0";
  argv[n++] = "--weights-dir";
  argv[n++] = h->weights_dir;
  argv[n++] = "--backend";
  argv[n++] = "cpu-ref";
  argv[n++] = "--ready-file";
  argv[n++] = s->ready;
  for (int i = 0; extra && extra[i] && n < 62; i++) argv[n++] = extra[i];
  argv[n] = NULL;
  pid_t parent = getpid();
  pid_t pid = fork();
  if (pid < 0) return -1;
  if (pid == 0) {
    /* A test process that dies (a crash, an abort) takes its daemon along. */
    if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || getppid() != parent) _exit(127);
    int fd = open(s->log, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    if (fd >= 0) {
      dup2(fd, 2);
      dup2(fd, 1);
      close(fd);
    }
    setenv("HAIRFILTERD_TOKEN", token_env ? token_env : TEST_TOKEN, 1);
    execv(argv[0], (char *const *)argv);
    _exit(127);
  }
  s->pid = pid;
  if (nstarted < (int)(sizeof started / sizeof started[0])) started[nstarted++] = pid;
  /* The ready file appears once every listener is bound and every model
   * built: up to 30 s on a slow machine. */
  for (int waited = 0; waited < 30000; waited += 20) {
    FILE *f = fopen(s->ready, "r");
    if (f) {
      char line[256];
      while (fgets(line, sizeof line, f)) {
        line[strcspn(line, "\n")] = 0;
        if (!strncmp(line, "unix:", 5)) snprintf(s->unix_url, sizeof s->unix_url, "%s", line);
        if (!strncmp(line, "tcp:", 4)) snprintf(s->tcp_url, sizeof s->tcp_url, "%s", line);
        if (!strncmp(line, "tls:", 4)) snprintf(s->tls_url, sizeof s->tls_url, "%s", line);
      }
      fclose(f);
      if (s->unix_url[0] && s->tcp_url[0]) return 0;
    }
    int st;
    if (waitpid(pid, &st, WNOHANG) == pid) {
      fprintf(stderr, "hairfilterd exited during startup (status %d)\n", st);
      server_dump_log(s);
      s->pid = 0;
      return -1;
    }
    sleep_ms(20);
  }
  fprintf(stderr, "hairfilterd did not become ready\n");
  server_dump_log(s);
  kill(pid, SIGKILL);
  waitpid(pid, NULL, 0);
  s->pid = 0;
  return -1;
}

int server_alive(const server *s) {
  int st;
  return s->pid > 0 && waitpid(s->pid, &st, WNOHANG) == 0;
}

int server_pause(server *s) {
  if (s->pid <= 0 || kill(s->pid, SIGSTOP) != 0) return -1;
  int st;
  pid_t r;
  do {
    r = waitpid(s->pid, &st, WUNTRACED);   /* reported once every thread has stopped */
  } while (r < 0 && errno == EINTR);
  return r == s->pid && WIFSTOPPED(st) ? 0 : -1;
}

int server_stop(server *s, int timeout_ms) {
  if (s->pid <= 0) return -1;
  kill(s->pid, SIGTERM);
  for (int waited = 0; waited < timeout_ms; waited += 10) {
    int st;
    pid_t r = waitpid(s->pid, &st, WNOHANG);
    if (r == s->pid) {
      s->pid = 0;
      return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    }
    sleep_ms(10);
  }
  fprintf(stderr, "hairfilterd did not exit after SIGTERM; killing it\n");
  server_dump_log(s);
  kill(s->pid, SIGKILL);
  waitpid(s->pid, NULL, 0);
  s->pid = 0;
  return -1;
}

int daemon_run(const char *const *args, const char *token_env, int timeout_ms, char *out,
               size_t outlen) {
  char log[] = "/tmp/hfd-run-XXXXXX";
  int lfd = mkstemp(log);
  if (lfd < 0) return -1;
  const char *argv[64];
  int n = 0;
  argv[n++] = HAIRFILTERD_PATH;
  for (int i = 0; args[i] && n < 63; i++) argv[n++] = args[i];
  argv[n] = NULL;
  pid_t pid = fork();
  if (pid < 0) return -1;
  if (pid == 0) {
    dup2(lfd, 2);
    dup2(lfd, 1);
    if (token_env)
      setenv("HAIRFILTERD_TOKEN", token_env, 1);
    else
      unsetenv("HAIRFILTERD_TOKEN");
    execv(argv[0], (char *const *)argv);
    _exit(127);
  }
  int status = -1, st;
  for (int waited = 0; waited < timeout_ms; waited += 10) {
    if (waitpid(pid, &st, WNOHANG) == pid) {
      status = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      break;
    }
    sleep_ms(10);
  }
  if (status < 0) {
    kill(pid, SIGKILL);
    waitpid(pid, NULL, 0);
  }
  ssize_t r = pread(lfd, out, outlen - 1, 0);
  out[r > 0 ? r : 0] = 0;
  close(lfd);
  unlink(log);
  return status;
}

float *make_features(int w, int h, int spp, uint32_t seed) {
  size_t n = (size_t)w * h * spp * HF_FEATURES_PER_SAMPLE;
  float *f = malloc(n * sizeof *f);
  if (!f) return NULL;
  uint32_t x = seed * 2654435761u + 12345u;
  for (size_t i = 0; i < n; i++) {
    x = x * 1664525u + 1013904223u;
    float u = (float)(x >> 8) / 16777216.0f;
    int feature = (int)(i % HF_FEATURES_PER_SAMPLE);
    f[i] = feature >= 4 ? 2.0f * u - 1.0f : u;   /* tangents in [-1, 1] */
  }
  return f;
}

int reference(const ref_variant *v, int w, int h, const void *in, int in_dtype, void *out,
              int out_dtype) {
  hf_io io = {1, w, h, in, (hf_dtype)in_dtype, out, (hf_dtype)out_dtype};
  return hf_model_run(v->model, &io, NULL);
}

/* ---- raw sockets ------------------------------------------------------- */

int raw_connect(const char *url) { return raw_connect_rcvbuf(url, 0); }

int raw_connect_rcvbuf(const char *url, int rcvbuf) {
  int fd = -1;
  hfp_url u;
  if (hfp_url_parse(url, 0, &u, NULL, 0)) return -1;
  if (u.kind == HFP_URL_UNIX) {
    struct sockaddr_un sun;
    memset(&sun, 0, sizeof sun);
    sun.sun_family = AF_UNIX;
    snprintf(sun.sun_path, sizeof sun.sun_path, "%s", u.path);
    fd = socket(AF_UNIX, SOCK_STREAM, 0);
    if (fd >= 0 && rcvbuf > 0) setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
    if (fd < 0 || connect(fd, (struct sockaddr *)&sun, sizeof sun)) {
      if (fd >= 0) close(fd);
      return -1;
    }
  } else {
    char port[8];
    snprintf(port, sizeof port, "%u", (unsigned)u.port);
    struct addrinfo hints = {0}, *res;
    hints.ai_socktype = SOCK_STREAM;
    if (getaddrinfo(u.host, port, &hints, &res)) return -1;
    fd = socket(res->ai_family, SOCK_STREAM, 0);
    if (fd >= 0 && rcvbuf > 0) setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
    if (fd < 0 || connect(fd, res->ai_addr, res->ai_addrlen)) {
      if (fd >= 0) close(fd);
      freeaddrinfo(res);
      return -1;
    }
    freeaddrinfo(res);
  }
  struct timeval tv = {10, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  return fd;
}

int raw_send(int fd, const void *buf, size_t n) {
  const uint8_t *p = buf;
  while (n) {
    ssize_t w = send(fd, p, n, MSG_NOSIGNAL);
    if (w <= 0) {
      if (w < 0 && errno == EINTR) continue;
      return -1;
    }
    p += w;
    n -= (size_t)w;
  }
  return 0;
}

static int recv_all(int fd, void *buf, size_t n) {
  uint8_t *p = buf;
  while (n) {
    ssize_t r = recv(fd, p, n, 0);
    if (r <= 0) {
      if (r < 0 && errno == EINTR) continue;
      return -1;
    }
    p += r;
    n -= (size_t)r;
  }
  return 0;
}

int raw_read_fd(int fd, hfp_header *h, uint8_t **payload, int *passed) {
  uint8_t hb[HFP_HEADER_SIZE];
  *payload = NULL;
  *passed = -1;
  struct iovec iov = {hb, sizeof hb};
  union {
    struct cmsghdr align;
    char buf[CMSG_SPACE(sizeof(int))];
  } cm;
  struct msghdr mh;
  memset(&mh, 0, sizeof mh);
  mh.msg_iov = &iov;
  mh.msg_iovlen = 1;
  mh.msg_control = cm.buf;
  mh.msg_controllen = sizeof cm.buf;
  ssize_t r = recvmsg(fd, &mh, MSG_WAITALL);
  if (r != (ssize_t)sizeof hb) return -1;
  struct cmsghdr *c = CMSG_FIRSTHDR(&mh);
  if (c && c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_RIGHTS)
    memcpy(passed, CMSG_DATA(c), sizeof(int));
  if (hfp_header_decode(hb, 1u << 30, h)) return -1;
  *payload = malloc(h->length ? h->length : 1);
  if (!*payload) return -1;
  if (recv_all(fd, *payload, h->length)) {
    free(*payload);
    *payload = NULL;
    return -1;
  }
  return 0;
}

int raw_read(int fd, hfp_header *h, uint8_t **payload) {
  uint8_t hb[HFP_HEADER_SIZE];
  *payload = NULL;
  if (recv_all(fd, hb, sizeof hb)) return -1;
  if (hfp_header_decode(hb, 1u << 30, h)) return -1;
  *payload = malloc(h->length ? h->length : 1);
  if (!*payload) return -1;
  if (recv_all(fd, *payload, h->length)) {
    free(*payload);
    *payload = NULL;
    return -1;
  }
  return 0;
}

int raw_hello(int fd, const char *token) { return raw_hello_versions(fd, token, 1, 1); }

int raw_hello_versions(int fd, const char *token, int lo, int hi) {
  hfp_hello m;
  memset(&m, 0, sizeof m);
  m.min_version = (uint16_t)lo;
  m.max_version = (uint16_t)hi;
  strcpy(m.client_name, "raw-test");
  if (token) snprintf(m.token, sizeof m.token, "%s", token);
  uint8_t b[512];
  int n = hfp_encode_hello(b, sizeof b, &m);
  if (n < 0 || raw_send(fd, b, (size_t)n)) return -1;
  hfp_header h;
  uint8_t *p;
  if (raw_read(fd, &h, &p)) return -1;
  int ok = h.type == HFP_HELLO_OK;
  free(p);
  return ok ? 0 : -1;
}

int raw_connect_versions(const char *url, int lo, int hi) {
  int fd = raw_connect(url);
  if (fd < 0) return -1;
  if (raw_hello_versions(fd, NULL, lo, hi)) {
    close(fd);
    return -1;
  }
  return fd;
}

int raw_variant_stats(int fd, const char *variant, hfp_variant_stats *out) {
  uint8_t b[HFP_HEADER_SIZE];
  if (hfp_encode_empty(b, sizeof b, HFP_STATS, 0) != HFP_HEADER_SIZE ||
      raw_send(fd, b, sizeof b))
    return -1;
  hfp_header h;
  uint8_t *p = NULL;
  if (raw_read(fd, &h, &p)) return -1;
  /* hfp_stats holds 64 variants' names and counters: too large for the
   * stack of a test's thread. */
  hfp_stats *st = malloc(sizeof *st);
  int rc = -1;
  if (st && h.type == HFP_STATS_REPLY && hfp_decode_stats(p, h.length, st) == 0)
    for (int i = 0; i < st->num_variants && rc; i++)
      if (!strcmp(st->variants[i].name, variant)) {
        *out = st->variants[i];
        rc = 0;
      }
  free(st);
  free(p);
  return rc;
}

uint8_t *raw_filter(uint32_t id, const char *variant, int w, int h, int spp, const float *in,
                    size_t *len) {
  return raw_filter_budget(id, variant, w, h, spp, in, 0, len);
}

uint8_t *raw_filter_budget(uint32_t id, const char *variant, int w, int h, int spp,
                           const float *in, uint32_t budget_us, size_t *len) {
  hfp_filter f;
  memset(&f, 0, sizeof f);
  snprintf(f.variant, sizeof f.variant, "%s", variant);
  f.width = (uint32_t)w;
  f.height = (uint32_t)h;
  f.spp = (uint16_t)spp;
  f.in_dtype = f.out_dtype = HFP_F32;
  f.data = in;
  if (budget_us) {
    f.flags = HFP_FILTER_DEADLINE;
    f.budget_us = budget_us;
  }
  if (hfp_features_bytes(f.width, f.height, f.spp, HFP_F32, &f.data_len)) return NULL;
  uint8_t head[HFP_FILTER_HEAD_MAX];
  uint64_t total;
  int n = hfp_encode_filter_head(head, sizeof head, id, &f, &total);
  if (n < 0) return NULL;
  uint8_t *b = malloc((size_t)total);
  if (!b) return NULL;
  memcpy(b, head, (size_t)n);
  memcpy(b + n, in, (size_t)f.data_len);
  *len = (size_t)total;
  return b;
}

int raw_closed(int fd, int timeout_ms) {
  struct pollfd p = {fd, POLLIN, 0};
  if (poll(&p, 1, timeout_ms) <= 0) return 0;
  char c;
  ssize_t r = recv(fd, &c, 1, MSG_DONTWAIT);
  /* Unread bytes at the server turn its close into a reset. */
  return r == 0 || (r < 0 && errno == ECONNRESET);
}

int harness_stop(harness *h, server *s) {
  int rc = server_stop(s, 20000);
  if (rc != 0) server_dump_log(s);
  harness_free(h);
  return rc == 0 ? 0 : -1;
}

hfc_options test_options(const char *name, const char *token, int timeout_ms) {
  hfc_options o;
  hfc_options_init(&o);
  o.client_name = name;
  o.token = token;
  o.timeout_ms = timeout_ms;
  return o;
}

int server_start_connected(const harness *h, server *s, const char *const *extra,
                           const char *name, hfc_client **c) {
  *c = NULL;
  if (server_start(h, s, extra)) return -1;
  hfc_options o = test_options(name, NULL, 20000);
  return hfc_connect(s->unix_url, &o, c) ? -1 : 0;
}

hfc_request test_request_sized(hfc_request r) {
  size_t est = r.estimate ? hfc_estimate_bytes(r.width, r.height, r.in_dtype) : 0;
  if (!r.features_bytes)
    r.features_bytes = hfc_features_bytes(r.width, r.height, r.spp, r.in_dtype) +
                       (r.estimate_buffer ? 0 : est);
  if (r.estimate_buffer && !r.estimate_bytes) r.estimate_bytes = est;
  if (!r.result_bytes) r.result_bytes = hfc_output_bytes(r.width, r.height, 3, r.out_dtype);
  if (r.rgba && !r.rgba_bytes) r.rgba_bytes = hfc_output_bytes(r.width, r.height, 4, r.out_dtype);
  return r;
}

int listed_variant(hfc_client *c, const char *name, hfc_variant *out) {
  hfc_variant v[HFP_MAX_VARIANTS];
  int n = 0;
  if (hfc_list_variants(c, v, HFP_MAX_VARIANTS, &n)) return -1;
  for (int i = 0; i < n && i < HFP_MAX_VARIANTS; i++)
    if (!strcmp(v[i].name, name)) {
      *out = v[i];
      return 0;
    }
  return -1;
}

hfc_client *client_connect(const server *s, const char *name) {
  hfc_client *c = NULL;
  hfc_options o = test_options(name, NULL, 20000);
  int rc = hfc_connect(s->unix_url, &o, &c);
  if (rc)
    fprintf(stderr, "connect %s: %s: %s\n", s->unix_url, hfc_strerror(rc), hfc_last_message(NULL));
  return c;
}

int read_text_file(const char *path, char *buf, size_t cap) {
  FILE *f = fopen(path, "r");
  if (!f || !cap) {
    if (f) fclose(f);
    return -1;
  }
  size_t n = fread(buf, 1, cap - 1, f);
  fclose(f);
  buf[n] = 0;
  return 0;
}

int raw_read_error(int fd, hfp_header *h, hfp_error *e) {
  uint8_t *p;
  if (raw_read(fd, h, &p)) return -1;
  int rc = h->type == HFP_ERROR && hfp_decode_error(p, h->length, e) == 0 ? 0 : -1;
  free(p);
  return rc;
}

size_t raw_hello_frame(uint8_t *buf, size_t cap, uint16_t min_version, uint16_t max_version,
                       const char *token) {
  hfp_hello m;
  memset(&m, 0, sizeof m);
  m.min_version = 1;
  m.max_version = 1;
  strcpy(m.client_name, "raw-test");
  if (token) snprintf(m.token, sizeof m.token, "%s", token);
  int n = hfp_encode_hello(buf, cap, &m);
  if (n < 0) return 0;
  /* The versions are written as given, whatever the encoder would allow. */
  hfp_put_u16(buf + HFP_HEADER_SIZE, min_version);
  hfp_put_u16(buf + HFP_HEADER_SIZE + 2, max_version);
  return (size_t)n;
}

double now_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec / 1e6;
}

/* The body of GET path on the daemon's --http endpoint, whose URL
 * (http://HOST:PORT) its ready file lists; malloc'd, or NULL. */
char *http_get(const server *d, const char *path) {
  char buf[4096], url[300] = "";
  if (read_text_file(d->ready, buf, sizeof buf) < 0) return NULL;
  for (char *line = strtok(buf, "\n"); line; line = strtok(NULL, "\n"))
    if (!strncmp(line, "http://", 7)) snprintf(url, sizeof url, "tcp:%s", line + 7);
  if (!url[0]) return NULL;
  int fd = raw_connect(url);
  if (fd < 0) return NULL;
  char req[256];
  int n = snprintf(req, sizeof req, "GET %s HTTP/1.0\r\n\r\n", path);
  size_t len = 0, cap = 1 << 16;
  char *all = malloc(cap);
  if (!all || raw_send(fd, req, (size_t)n)) {
    free(all);
    close(fd);
    return NULL;
  }
  for (;;) {
    if (len + 1 == cap) {
      char *more = realloc(all, cap *= 2);
      if (!more) break;
      all = more;
    }
    ssize_t got = recv(fd, all + len, cap - 1 - len, 0);
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) break;
    len += (size_t)got;
  }
  close(fd);
  all[len] = 0;
  char *body = strstr(all, "\r\n\r\n");
  if (!body || strncmp(all, "HTTP/1.", 7) || strncmp(all + 8, " 200", 4)) {
    free(all);
    return NULL;
  }
  memmove(all, body + 4, strlen(body + 4) + 1);
  return all;
}
