/* Command-line options of hairfilterd (docs/SERVER.md lists them). */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
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
          "  --listen unix:PATH | tcp:HOST:PORT | tcp:PORT   (repeatable; tcp:PORT is loopback)\n"
          "  --weights FILE           load one variant (repeatable)\n"
          "  --weights-dir DIR        load every *.safetensors in DIR\n"
          "  --backend NAME           auto | cpu | cpu-ref | cudnn (default auto)\n"
          "  --max-batch N            frames per backend run (default 4)\n"
          "  --max-queue-delay-us N   how long a frame waits for batch partners (default 0)\n"
          "  --queue-size N           admitted frames waiting for the worker (default 64)\n"
          "  --max-inflight N         requests in flight per connection (default 32)\n"
          "  --max-size WxH           largest frame (default 4096x4096)\n"
          "  --max-frame-mb N         largest payload read, MiB (default 1024)\n"
          "  --max-memory-mb N        request buffers held at once, MiB (default 4096)\n"
          "  --max-connections N      open connections (default 256)\n"
          "  --max-shm-mb N           shared segments for Unix-socket clients, MiB (default\n"
          "                           1024; 0: no shared memory)\n"
          "  --auth-token-file FILE   token TCP clients must send (or $HAIRFILTERD_TOKEN)\n"
          "  --no-auth                accept TCP clients without a token (loopback only)\n"
          "  --drain-timeout-ms N     on SIGTERM, how long queued work may finish (default 10000)\n"
          "  --stall-timeout-ms N     close a connection silent this long mid-frame or before\n"
          "                           HELLO (default 30000; 0: never)\n"
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
    fprintf(stderr, "hairfilterd: %s wants an integer in %ld..%ld, not '%s'\n", opt, lo, hi, s);
    return -1;
  }
  *out = v;
  return 0;
}

static int read_token(const char *path, char *dst) {
  FILE *f = fopen(path, "r");
  if (!f) {
    fprintf(stderr, "hairfilterd: cannot read %s: %s\n", path, strerror(errno));
    return -1;
  }
  char buf[HFP_TOKEN_MAX + 2];
  size_t n = fread(buf, 1, sizeof buf - 1, f);
  fclose(f);
  buf[n] = 0;
  while (n && (buf[n - 1] == '\n' || buf[n - 1] == '\r' || buf[n - 1] == ' ')) buf[--n] = 0;
  if (n == 0 || n > HFP_TOKEN_MAX) {
    fprintf(stderr, "hairfilterd: token in %s must be 1..%d bytes\n", path, HFP_TOKEN_MAX);
    return -1;
  }
  for (size_t i = 0; i < n; i++)
    if (buf[i] <= 0x20 || buf[i] > 0x7e) {
      fprintf(stderr, "hairfilterd: token in %s must be printable ASCII without spaces\n", path);
      return -1;
    }
  memcpy(dst, buf, n + 1);
  return 0;
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

int hfd_config_parse(int argc, char **argv, hfd_config *cfg) {
  memset(cfg, 0, sizeof *cfg);
  cfg->backend = "auto";
  cfg->max_batch = 4;
  cfg->queue_size = 64;
  cfg->max_inflight = 32;
  cfg->max_width = cfg->max_height = 4096;
  cfg->max_connections = 256;
  cfg->max_frame_bytes = 1024ull << 20;
  cfg->max_memory_bytes = 4096ull << 20;
  cfg->max_shm_bytes = 1024ull << 20;
  cfg->drain_timeout_ms = 10000;
  cfg->stall_timeout_ms = 30000;
  cfg->name = "hairfilterd";
  cfg->pipeline_depth = 2;
  const char *token_file = NULL;
  const char *warm = NULL;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    const char *val = i + 1 < argc ? argv[i + 1] : NULL;
    long v;
#define NEED_VAL                                                     \
  do {                                                               \
    if (!val) {                                                      \
      fprintf(stderr, "hairfilterd: %s needs a value\n", a);       \
      return -1;                                                     \
    }                                                                \
    i++;                                                             \
  } while (0)
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      usage(stdout);
      return 1;
    } else if (!strcmp(a, "--listen")) {
      NEED_VAL;
      if (cfg->num_listen == HFD_MAX_LISTENERS) {
        fprintf(stderr, "hairfilterd: at most %d --listen\n", HFD_MAX_LISTENERS);
        return -1;
      }
      cfg->listen[cfg->num_listen++] = val;
    } else if (!strcmp(a, "--weights")) {
      NEED_VAL;
      if (cfg->num_weights == HFD_MAX_VARIANTS) {
        fprintf(stderr, "hairfilterd: at most %d --weights\n", HFD_MAX_VARIANTS);
        return -1;
      }
      cfg->weights[cfg->num_weights++] = val;
    } else if (!strcmp(a, "--weights-dir")) {
      NEED_VAL;
      cfg->weights_dir = val;
    } else if (!strcmp(a, "--backend")) {
      NEED_VAL;
      cfg->backend = val;
    } else if (!strcmp(a, "--max-batch")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 256, &v)) return -1;
      cfg->max_batch = (int)v;
    } else if (!strcmp(a, "--max-queue-delay-us")) {
      NEED_VAL;
      if (parse_int(a, val, 0, 10000000, &v)) return -1;
      cfg->max_queue_delay_us = (int)v;
    } else if (!strcmp(a, "--queue-size")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 65536, &v)) return -1;
      cfg->queue_size = (int)v;
    } else if (!strcmp(a, "--max-inflight")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 65535, &v)) return -1;
      cfg->max_inflight = (int)v;
    } else if (!strcmp(a, "--max-size")) {
      NEED_VAL;
      int w, h;
      char tail;
      if (sscanf(val, "%dx%d%c", &w, &h, &tail) != 2 || w < 1 || h < 1 || w > HFP_MAX_SIDE ||
          h > HFP_MAX_SIDE) {
        fprintf(stderr, "hairfilterd: --max-size wants WxH within 1..%d, not '%s'\n",
                HFP_MAX_SIDE, val);
        return -1;
      }
      cfg->max_width = w;
      cfg->max_height = h;
    } else if (!strcmp(a, "--max-frame-mb")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 4095, &v)) return -1;
      cfg->max_frame_bytes = (uint64_t)v << 20;
    } else if (!strcmp(a, "--max-memory-mb")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 1 << 30, &v)) return -1;
      cfg->max_memory_bytes = (uint64_t)v << 20;
    } else if (!strcmp(a, "--max-shm-mb")) {
      NEED_VAL;
      if (parse_int(a, val, 0, 1 << 30, &v)) return -1;
      cfg->max_shm_bytes = (uint64_t)v << 20;
    } else if (!strcmp(a, "--max-connections")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 1000000, &v)) return -1;
      cfg->max_connections = (int)v;
    } else if (!strcmp(a, "--auth-token-file")) {
      NEED_VAL;
      token_file = val;
    } else if (!strcmp(a, "--no-auth")) {
      cfg->no_auth = 1;
    } else if (!strcmp(a, "--drain-timeout-ms")) {
      NEED_VAL;
      if (parse_int(a, val, 0, 3600000, &v)) return -1;
      cfg->drain_timeout_ms = (int)v;
    } else if (!strcmp(a, "--stall-timeout-ms")) {
      NEED_VAL;
      if (parse_int(a, val, 0, 3600000, &v)) return -1;
      cfg->stall_timeout_ms = (int)v;
    } else if (!strcmp(a, "--warm")) {
      NEED_VAL;
      warm = val;
    } else if (!strcmp(a, "--pipeline-depth")) {
      NEED_VAL;
      if (parse_int(a, val, 1, 2, &v)) return -1;
      cfg->pipeline_depth = (int)v;
    } else if (!strcmp(a, "--ready-file")) {
      NEED_VAL;
      cfg->ready_file = val;
    } else if (!strcmp(a, "--name")) {
      NEED_VAL;
      size_t n = strlen(val);
      int ok = n >= 1 && n <= HFP_NAME_MAX;
      for (size_t k = 0; ok && k < n; k++) ok = val[k] > 0x20 && val[k] < 0x7f;
      if (!ok) {
        fprintf(stderr, "hairfilterd: --name must be 1..%d printable characters\n", HFP_NAME_MAX);
        return -1;
      }
      cfg->name = val;
    } else if (!strcmp(a, "--verbose") || !strcmp(a, "-v")) {
      hfd_verbose = 1;
    } else {
      fprintf(stderr, "hairfilterd: unknown option '%s'\n", a);
      usage(stderr);
      return -1;
    }
#undef NEED_VAL
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
    if (env && *env) {
      size_t n = strlen(env);
      if (n > HFP_TOKEN_MAX) {
        fprintf(stderr, "hairfilterd: $HAIRFILTERD_TOKEN is longer than %d bytes\n", HFP_TOKEN_MAX);
        return -1;
      }
      memcpy(cfg->token, env, n + 1);
    }
  }
  return 0;
}
