/* Command-line options of hairfilterd (docs/SERVER.md lists them). Parsed
 * with getopt_long, so both "--opt VALUE" and "--opt=VALUE" work. */
#define _GNU_SOURCE
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "server.h"

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilterd --listen URL [--listen URL ...]\n"
          "                   (--weights FILE.safetensors ... | --weights-dir DIR)\n"
          "                   [options]\n"
          "\n"
          "  --listen unix:PATH | tcp:HOST:PORT | tcp:[IPV6]:PORT | tcp:PORT\n"
          "                           (repeatable; tcp:PORT is loopback; port 0: any free)\n"
          "  --weights FILE           load one variant (repeatable)\n"
          "  --weights-dir DIR        load every *.safetensors in DIR\n"
          "  --backend NAME           auto | cpu | cpu-ref | cudnn (default auto)\n"
          "  --max-batch N            frames per backend run (default 4)\n"
          "  --max-queue-delay-us N   how long a frame waits for batch partners (default 0)\n"
          "  --queue-size N           admitted frames waiting for the worker (default 64)\n"
          "  --max-inflight N         requests in flight per connection (default 32)\n"
          "  --max-size WxH           largest frame (default 4096x4096; lowered at start\n"
          "                           to what the other limits let a frame of it meet)\n"
          "  --max-frame-mb N         largest payload read, MiB (default 1024)\n"
          "  --max-memory-mb N        request buffers and inference memory, MiB (default 4096)\n"
          "  --max-connections N      open connections (default 256)\n"
          "  --max-handshakes N       connections still before their HELLO (default 32)\n"
          "  --max-shm-mb N           shared segments for Unix-socket clients, MiB (default\n"
          "                           1024; 0: no shared memory)\n"
          "  --auth-token-file FILE   token TCP clients must send (or $HAIRFILTERD_TOKEN)\n"
          "  --no-auth                accept TCP clients without a token (loopback only)\n"
          "  --drain-timeout-ms N     on SIGTERM, how long queued work may finish (default 10000)\n"
          "  --flush-timeout-ms N     then, how long peers have to read their replies\n"
          "                           (default 5000)\n"
          "  --handshake-timeout-ms N HELLO must be complete this soon after connecting\n"
          "                           (default 10000; 0: never)\n"
          "  --stall-timeout-ms N     close a connection silent this long mid-frame\n"
          "                           (default 30000; 0: never)\n"
          "  --min-recv-rate N        KiB/s a frame must arrive at, measured over each\n"
          "                           stall-timeout window (default 64; 0: no minimum)\n"
          "  --ready-file PATH        write the listening URLs here once serving\n"
          "  --warm WxH[xN][,...]     before serving, build every variant's plan for these\n"
          "                           frame sizes and batches (default batch 1); a GPU backend\n"
          "                           otherwise builds one on the first request of a shape\n"
          "  --pipeline-depth N       backend runs in flight: 2 (default) uploads the next\n"
          "                           frame while one computes, 1 runs one at a time\n"
          "  --name NAME              server name in HELLO_OK (default hairfilterd)\n"
          "  --verbose                log connections too\n");
}

static int parse_int(const char *opt, const char *s, long lo, long hi, long *out) {
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (errno || *end || end == s || v < lo || v > hi) {
    fprintf(stderr, "hairfilterd: --%s wants an integer in %ld..%ld, not '%s'\n", opt, lo, hi, s);
    return -1;
  }
  *out = v;
  return 0;
}

/* One rule for a token, wherever it comes from (PROTOCOL.md: 1..256
 * printable ASCII bytes without spaces): trailing line ends and spaces are
 * dropped, as an editor or `echo` leaves them in a file and a Kubernetes
 * secret in the environment; anything else that breaks the rule is an
 * error naming the source, because such a token could never be matched by
 * a client and the daemon would start only to refuse everyone. */
static int token_take(const char *source, const char *s, size_t n, char *dst) {
  while (n && (s[n - 1] == '\n' || s[n - 1] == '\r' || s[n - 1] == ' ')) n--;
  if (n == 0 || n > HFP_TOKEN_MAX) {
    fprintf(stderr, "hairfilterd: token in %s must be 1..%d bytes\n", source, HFP_TOKEN_MAX);
    return -1;
  }
  for (size_t i = 0; i < n; i++)
    if ((unsigned char)s[i] <= 0x20 || (unsigned char)s[i] > 0x7e) {
      fprintf(stderr, "hairfilterd: token in %s must be printable ASCII without spaces\n",
              source);
      return -1;
    }
  memcpy(dst, s, n);
  dst[n] = 0;
  return 0;
}

static int read_token(const char *path, char *dst) {
  FILE *f = fopen(path, "r");
  if (!f) {
    fprintf(stderr, "hairfilterd: cannot read %s: %s\n", path, strerror(errno));
    return -1;
  }
  /* One byte more than the longest token and its line end, so that a
   * longer file is seen as too long rather than cut. */
  char buf[HFP_TOKEN_MAX + 3];
  size_t n = fread(buf, 1, sizeof buf, f);
  fclose(f);
  return token_take(path, buf, n, dst);
}

/* --warm WxH[xN][,WxH[xN]...], checked against --max-size and --max-batch
 * (so give those first). */
static int parse_warm(const char *list, hfd_config *cfg) {
  char buf[1024];
  if (strlen(list) >= sizeof buf) {
    fprintf(stderr, "hairfilterd: --warm list too long\n");
    return -1;
  }
  strcpy(buf, list);
  char *save = NULL;
  for (char *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
    int w, h, n = 1;
    char tail;
    int got = sscanf(tok, "%dx%dx%d%c", &w, &h, &n, &tail);
    if ((got != 2 && got != 3) || w < 1 || h < 1 || w > cfg->max_width || h > cfg->max_height ||
        n < 1 || n > cfg->max_batch) {
      fprintf(stderr,
              "hairfilterd: --warm wants WxH or WxHxBATCH within --max-size %dx%d and "
              "--max-batch %d, not '%s'\n",
              cfg->max_width, cfg->max_height, cfg->max_batch, tok);
      return -1;
    }
    if (cfg->num_warm == HFD_MAX_WARM) {
      fprintf(stderr, "hairfilterd: at most %d --warm shapes\n", HFD_MAX_WARM);
      return -1;
    }
    cfg->warm[cfg->num_warm].width = w;
    cfg->warm[cfg->num_warm].height = h;
    cfg->warm[cfg->num_warm].batch = n;
    cfg->num_warm++;
  }
  if (!cfg->num_warm) {
    fprintf(stderr, "hairfilterd: --warm needs at least one WxH\n");
    return -1;
  }
  return 0;
}

enum {
  OPT_LISTEN = 256, OPT_WEIGHTS, OPT_WEIGHTS_DIR, OPT_BACKEND, OPT_MAX_BATCH, OPT_QUEUE_DELAY,
  OPT_QUEUE_SIZE, OPT_MAX_INFLIGHT, OPT_MAX_SIZE, OPT_MAX_FRAME, OPT_MAX_MEMORY, OPT_MAX_SHM,
  OPT_MAX_CONNECTIONS, OPT_MAX_HANDSHAKES, OPT_TOKEN_FILE, OPT_NO_AUTH, OPT_DRAIN,
  OPT_FLUSH, OPT_HANDSHAKE, OPT_STALL, OPT_MIN_RATE, OPT_READY, OPT_NAME, OPT_WARM,
  OPT_PIPELINE
};

int hfd_config_parse(int argc, char **argv, hfd_config *cfg) {
  static const struct option opts[] = {
    {"listen", required_argument, 0, OPT_LISTEN},
    {"weights", required_argument, 0, OPT_WEIGHTS},
    {"weights-dir", required_argument, 0, OPT_WEIGHTS_DIR},
    {"backend", required_argument, 0, OPT_BACKEND},
    {"max-batch", required_argument, 0, OPT_MAX_BATCH},
    {"max-queue-delay-us", required_argument, 0, OPT_QUEUE_DELAY},
    {"queue-size", required_argument, 0, OPT_QUEUE_SIZE},
    {"max-inflight", required_argument, 0, OPT_MAX_INFLIGHT},
    {"max-size", required_argument, 0, OPT_MAX_SIZE},
    {"max-frame-mb", required_argument, 0, OPT_MAX_FRAME},
    {"max-memory-mb", required_argument, 0, OPT_MAX_MEMORY},
    {"max-shm-mb", required_argument, 0, OPT_MAX_SHM},
    {"max-connections", required_argument, 0, OPT_MAX_CONNECTIONS},
    {"max-handshakes", required_argument, 0, OPT_MAX_HANDSHAKES},
    {"auth-token-file", required_argument, 0, OPT_TOKEN_FILE},
    {"no-auth", no_argument, 0, OPT_NO_AUTH},
    {"drain-timeout-ms", required_argument, 0, OPT_DRAIN},
    {"flush-timeout-ms", required_argument, 0, OPT_FLUSH},
    {"handshake-timeout-ms", required_argument, 0, OPT_HANDSHAKE},
    {"stall-timeout-ms", required_argument, 0, OPT_STALL},
    {"min-recv-rate", required_argument, 0, OPT_MIN_RATE},
    {"ready-file", required_argument, 0, OPT_READY},
    {"warm", required_argument, 0, OPT_WARM},
    {"pipeline-depth", required_argument, 0, OPT_PIPELINE},
    {"name", required_argument, 0, OPT_NAME},
    {"verbose", no_argument, 0, 'v'},
    {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0},
  };
  memset(cfg, 0, sizeof *cfg);
  cfg->backend = "auto";
  cfg->max_batch = 4;
  cfg->queue_size = 64;
  cfg->max_inflight = 32;
  cfg->max_width = cfg->max_height = 4096;
  cfg->max_connections = 256;
  cfg->max_handshakes = 32;
  cfg->max_frame_bytes = 1024ull << 20;
  cfg->max_memory_bytes = 4096ull << 20;
  cfg->max_shm_bytes = 1024ull << 20;
  cfg->drain_timeout_ms = 10000;
  cfg->flush_timeout_ms = 5000;
  cfg->handshake_timeout_ms = 10000;
  cfg->stall_timeout_ms = 30000;
  cfg->min_recv_rate = 64 << 10;
  cfg->name = "hairfilterd";
  cfg->pipeline_depth = 2;
  const char *token_file = NULL, *warm = NULL;
  optind = 1;
  opterr = 0;
  for (;;) {
    int idx = -1, o = getopt_long(argc, argv, ":hv", opts, &idx);
    if (o == -1) break;
    const char *name = idx >= 0 ? opts[idx].name : "";
    const char *val = optarg;
    long v;
    switch (o) {
      case 'h':
        usage(stdout);
        return 1;
      case 'v':
        hfd_verbose = 1;
        break;
      case OPT_LISTEN: {
        if (cfg->num_listen == HFD_MAX_LISTENERS) {
          fprintf(stderr, "hairfilterd: at most %d --listen\n", HFD_MAX_LISTENERS);
          return -1;
        }
        char why[300];
        if (hfp_url_parse(val, HFP_URL_LISTEN, &cfg->listen_url[cfg->num_listen], why,
                          sizeof why)) {
          fprintf(stderr, "hairfilterd: --listen: %s\n", why);
          return -1;
        }
        cfg->listen[cfg->num_listen++] = val;
        break;
      }
      case OPT_WEIGHTS:
        if (cfg->num_weights == HFD_MAX_VARIANTS) {
          fprintf(stderr, "hairfilterd: at most %d --weights\n", HFD_MAX_VARIANTS);
          return -1;
        }
        cfg->weights[cfg->num_weights++] = val;
        break;
      case OPT_WEIGHTS_DIR: cfg->weights_dir = val; break;
      case OPT_BACKEND: cfg->backend = val; break;
      case OPT_MAX_BATCH:
        if (parse_int(name, val, 1, 256, &v)) return -1;
        cfg->max_batch = (int)v;
        break;
      case OPT_QUEUE_DELAY:
        if (parse_int(name, val, 0, 10000000, &v)) return -1;
        cfg->max_queue_delay_us = (int)v;
        break;
      case OPT_QUEUE_SIZE:
        if (parse_int(name, val, 1, 65536, &v)) return -1;
        cfg->queue_size = (int)v;
        break;
      case OPT_MAX_INFLIGHT:
        if (parse_int(name, val, 1, 65535, &v)) return -1;
        cfg->max_inflight = (int)v;
        break;
      case OPT_MAX_SIZE: {
        int w, h;
        char tail;
        if (sscanf(val, "%dx%d%c", &w, &h, &tail) != 2 || w < 1 || h < 1 ||
            w > HFP_MAX_SIDE || h > HFP_MAX_SIDE) {
          fprintf(stderr, "hairfilterd: --max-size wants WxH within 1..%d, not '%s'\n",
                  HFP_MAX_SIDE, val);
          return -1;
        }
        cfg->max_width = w;
        cfg->max_height = h;
        break;
      }
      case OPT_MAX_FRAME:
        if (parse_int(name, val, 1, 4095, &v)) return -1;
        cfg->max_frame_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_MEMORY:
        if (parse_int(name, val, 1, 1 << 30, &v)) return -1;
        cfg->max_memory_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_SHM:
        if (parse_int(name, val, 0, 1 << 30, &v)) return -1;
        cfg->max_shm_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_CONNECTIONS:
        if (parse_int(name, val, 1, 1000000, &v)) return -1;
        cfg->max_connections = (int)v;
        break;
      case OPT_MAX_HANDSHAKES:
        if (parse_int(name, val, 1, 1000000, &v)) return -1;
        cfg->max_handshakes = (int)v;
        break;
      case OPT_TOKEN_FILE: token_file = val; break;
      case OPT_NO_AUTH: cfg->no_auth = 1; break;
      case OPT_DRAIN:
        if (parse_int(name, val, 0, 3600000, &v)) return -1;
        cfg->drain_timeout_ms = (int)v;
        break;
      case OPT_FLUSH:
        if (parse_int(name, val, 0, 3600000, &v)) return -1;
        cfg->flush_timeout_ms = (int)v;
        break;
      case OPT_HANDSHAKE:
        if (parse_int(name, val, 0, 3600000, &v)) return -1;
        cfg->handshake_timeout_ms = (int)v;
        break;
      case OPT_STALL:
        if (parse_int(name, val, 0, 3600000, &v)) return -1;
        cfg->stall_timeout_ms = (int)v;
        break;
      case OPT_MIN_RATE:
        if (parse_int(name, val, 0, 1 << 20, &v)) return -1;
        cfg->min_recv_rate = (uint64_t)v << 10;
        break;
      case OPT_READY: cfg->ready_file = val; break;
      case OPT_WARM: warm = val; break;
      case OPT_PIPELINE:
        if (parse_int(name, val, 1, 2, &v)) return -1;
        cfg->pipeline_depth = (int)v;
        break;
      case OPT_NAME: {
        size_t n = strlen(val);
        int ok = n >= 1 && n <= HFP_NAME_MAX;
        for (size_t k = 0; ok && k < n; k++) ok = val[k] > 0x20 && val[k] < 0x7f;
        if (!ok) {
          fprintf(stderr, "hairfilterd: --name must be 1..%d printable characters\n",
                  HFP_NAME_MAX);
          return -1;
        }
        cfg->name = val;
        break;
      }
      case ':':
        fprintf(stderr, "hairfilterd: %s needs a value\n", argv[optind - 1]);
        return -1;
      default:
        fprintf(stderr, "hairfilterd: unknown option '%s'\n", argv[optind - 1]);
        usage(stderr);
        return -1;
    }
  }
  if (optind < argc) {
    fprintf(stderr, "hairfilterd: unexpected argument '%s'\n", argv[optind]);
    usage(stderr);
    return -1;
  }
  if (!cfg->num_listen) {
    fprintf(stderr, "hairfilterd: nothing to listen on: give --listen unix:PATH or tcp:HOST:PORT\n");
    return -1;
  }
  if (!cfg->num_weights && !cfg->weights_dir) {
    fprintf(stderr, "hairfilterd: no variants: give --weights FILE or --weights-dir DIR\n");
    return -1;
  }
  if (warm && parse_warm(warm, cfg)) return -1;
  if (token_file) {
    if (read_token(token_file, cfg->token)) return -1;
  } else {
    const char *env = getenv("HAIRFILTERD_TOKEN");
    if (env && token_take("$HAIRFILTERD_TOKEN", env, strlen(env), cfg->token)) return -1;
  }
  return 0;
}
