/* Options of hairfilterd (docs/SERVER.md lists them), from the config file
 * and the command line. Parsed with getopt_long, so both "--opt VALUE" and
 * "--opt=VALUE" work. The config file is read with inih (libinih, Debian's
 * libinih-dev): "key = value" lines whose keys are the long options without
 * their dashes; each line becomes "--key=value" ahead of the command line,
 * so the same parser checks both and the command line wins. A key that
 * takes one value and comes twice in the file is warned about, naming
 * both lines; the later line wins. Errors go through the log (log.c) at
 * error level, so under journald they carry priority 3 like the daemon's
 * other errors. */
#define _GNU_SOURCE
#include <ctype.h>
#include <errno.h>
#include <getopt.h>
#include <ini.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <hairfilter/hairfilter_version.h>

#include "peer_addr.h"
#include "server.h"

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilterd --listen URL [--listen URL ...]\n"
          "                   (--weights [NAME=]FILE.safetensors ... | --weights-dir DIR)\n"
          "                   [options]\n"
          "\n"
          "  --config FILE            key = value lines with the keys of these options\n"
          "                           (default " HFD_DEFAULT_CONFIG " when it\n"
          "                           exists; none: read none); the command line wins\n"
          "  --listen unix:PATH | tcp:HOST:PORT | tcp:[IPV6]:PORT | tcp:PORT | tls:HOST:PORT\n"
          "                           (repeatable; tcp:PORT is loopback; port 0: any free;\n"
          "                           tls: is TCP with TLS, tls:[IPV6]:PORT and tls:PORT too)\n"
          "  --weights [NAME=]FILE    load one variant (repeatable), named NAME or as its\n"
          "                           metadata says\n"
          "  --weights-dir DIR        load every *.safetensors in DIR\n"
          "  --backend NAME           auto | cpu | cpu-ref | cudnn (default auto)\n"
          "  --max-batch N            frames per backend run (default 1 on the CPU\n"
          "                           backends, 4 on cudnn)\n"
          "  --max-queue-delay-us N   how long a frame waits for batch partners (default 0)\n"
          "  --queue-size N           admitted frames not yet running: queued, or held for batch\n"
          "                           partners (default 64)\n"
          "  --max-inflight N         requests in flight per connection (default 32)\n"
          "  --queue-share-by client | connection\n"
          "                           what holds a share of the queue: a client (a process\n"
          "                           on a Unix socket, an IP address over TCP; default)\n"
          "                           or each connection\n"
          "  --max-size WxH           largest frame (default 3840x2160; lowered at start,\n"
          "                           keeping its aspect, to what the other limits let a\n"
          "                           frame of it meet)\n"
          "  --max-frame-mb N         largest payload read, MiB (default 1024)\n"
          "  --max-memory-mb N        request buffers and inference memory, MiB (default 4096)\n"
          "  --max-connections N      open connections (default 256)\n"
          "  --max-handshakes N       connections still before their HELLO (default 32)\n"
          "  --max-handshakes-per-address N\n"
          "                           of which one IP address may hold on tcp: and tls:\n"
          "                           listeners (default half of --max-handshakes)\n"
          "  --ipv6-client-prefix N   an IPv6 peer is one client (queue share, handshakes\n"
          "                           per address) by its first N bits, 48..128\n"
          "                           (default 64: one host's prefix)\n"

          "  --max-shm-mb N           shared segments for Unix-socket clients, MiB (default\n"
          "                           1024; 0: no shared memory)\n"
          "  --max-shm-mb-per-client N\n"
          "                           of which one client (a process, all its connections)\n"
          "                           may hold, MiB (default a quarter, at least the largest\n"
          "                           frame's segments)\n"
          "  --max-shm-mb-per-connection N\n"
          "                           of which one connection may hold, MiB (default the\n"
          "                           client's part)\n"
          "  --auth-token-file FILE   token TCP clients must send (or $HAIRFILTERD_TOKEN)\n"
          "  --no-auth                accept TCP clients without a token (loopback only)\n"
          "  --tls-cert FILE          PEM certificate chain of tls: listeners (server first)\n"
          "  --tls-key FILE           PEM private key of that certificate\n"
          "  --tls-client-ca FILE     mutual TLS: clients need a certificate this CA signed\n"
          "  --tls-client-cert-auth   with --tls-client-ca: on tls: listeners the verified\n"
          "                           client certificate replaces the token\n"
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
          "  --http tcp:HOST:PORT     /metrics (Prometheus), /healthz and /readyz here\n"
          "  --watchdog-ms N          unhealthy when the worker or the event loop makes no\n"
          "                           progress for this long (default 60000)\n"
          "  --log-level LEVEL        error | warning | notice | info (default) | debug\n"
          "  --verbose                --log-level debug: log connections too\n"
          "  --version                print the version and exit\n"
          "\n"
          "SIGHUP reads the config file and the weights again; SIGUSR1 logs the statistics;\n"
          "SIGTERM and SIGINT drain and stop.\n");
}

/* Whether two socket paths name one file: the same text, or the same
 * name in folders that resolve to one ("/run/x/../x/s.sock"). */
static int same_socket_path(const char *a, const char *b) {
  if (!strcmp(a, b)) return 1;
  const char *ba = strrchr(a, '/'), *bb = strrchr(b, '/');
  if (strcmp(ba ? ba + 1 : a, bb ? bb + 1 : b)) return 0;
  char da[PATH_MAX], db[PATH_MAX], ra[PATH_MAX], rb[PATH_MAX];
  snprintf(da, sizeof da, "%.*s", ba ? (int)(ba - a) + 1 : 1, ba ? a : ".");
  snprintf(db, sizeof db, "%.*s", bb ? (int)(bb - b) + 1 : 1, bb ? b : ".");
  return realpath(da, ra) && realpath(db, rb) && !strcmp(ra, rb);
}

static int parse_int(const char *opt, const char *s, long lo, long hi, long *out) {
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  /* strtol skips leading whitespace; ' 5' is refused as '5 ' is. */
  if (errno || *end || end == s || isspace((unsigned char)*s) || v < lo || v > hi) {
    hfd_err("--%s wants an integer in %ld..%ld, not '%s'", opt, lo, hi, s);
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
    hfd_err("token in %s must be 1..%d bytes", source, HFP_TOKEN_MAX);
    return -1;
  }
  for (size_t i = 0; i < n; i++)
    if ((unsigned char)s[i] <= 0x20 || (unsigned char)s[i] > 0x7e) {
      hfd_err("token in %s must be printable ASCII without spaces", source);
      return -1;
    }
  memcpy(dst, s, n);
  dst[n] = 0;
  return 0;
}

/* Why a file the daemon must read (its config, its token) could not be
 * opened, err an errno value. "Permission denied" alone hides that the
 * daemon runs as its own user (hairfilter under systemd, 10001 in the
 * image) while the file was written by root with a private mode: say who
 * the daemon is, the file's owner and mode, and the fix, which keeps the
 * file from everyone but the daemon's group (a token is a secret). */
static void unreadable_why(const char *path, int err, char *why, size_t whylen) {
  struct stat st;
  if (err == EISDIR) {
    snprintf(why, whylen, "it is a directory; give the file in it");
    return;
  }
  if (err != EACCES || stat(path, &st) != 0) {
    snprintf(why, whylen, "%s", strerror(err));
    return;
  }
  char user[64], group[64];
  hfd_user_name(user, sizeof user);
  hfd_group_name(group, sizeof group);
  snprintf(why, whylen,
           "permission denied: hairfilterd runs as uid %ld (%s) gid %ld (%s) and cannot read it "
           "(owner uid %ld gid %ld, mode %04o); let its group read it and no one else: "
           "chgrp %s %s && chmod 0640 %s",
           (long)geteuid(), user, (long)getegid(), group, (long)st.st_uid, (long)st.st_gid,
           (unsigned)(st.st_mode & 07777), group, path, path);
}

/* fopen(path, "r"), refusing a directory (which Linux opens, and which
 * then reads as an empty file) with EISDIR. */
static FILE *open_file(const char *path) {
  FILE *f = fopen(path, "r");
  struct stat st;
  if (f && fstat(fileno(f), &st) == 0 && S_ISDIR(st.st_mode)) {
    fclose(f);
    errno = EISDIR;
    return NULL;
  }
  return f;
}

static int read_token(const char *path, char *dst) {
  FILE *f = open_file(path);
  if (!f) {
    char why[600];
    unreadable_why(path, errno, why, sizeof why);
    hfd_err("--auth-token-file %s: %s", path, why);
    return -1;
  }
  /* One byte more than the longest token and its line end, so that a
   * longer file is seen as too long rather than cut. */
  char buf[HFP_TOKEN_MAX + 3];
  size_t n = fread(buf, 1, sizeof buf, f);
  fclose(f);
  return token_take(path, buf, n, dst);
}

static char *own(hfd_config *cfg, char *s);

/* --weights [NAME=]FILE: NAME overrides the name in the file's metadata,
 * so that two files whose metadata say the same (a retrained Small beside
 * the bundled one) can be served side by side. What comes before the first
 * '=' is a name only when it could be one (printable, no space, no '/');
 * else the whole value is a path. */
static int weights_entry(hfd_config *cfg, const char *val) {
  const char *eq = strchr(val, '=');
  const char *name = NULL, *path = val;
  if (eq && eq > val && eq[1]) {
    size_t n = (size_t)(eq - val);
    int ok = n <= HFP_NAME_MAX;
    for (size_t i = 0; ok && i < n; i++) ok = val[i] > 0x20 && val[i] < 0x7f && val[i] != '/';
    if (ok) {
      if (!(name = own(cfg, strndup(val, n)))) return -1;
      path = eq + 1;
    }
  }
  if (!name && eq && !memchr(val, '/', (size_t)(eq - val)) && access(val, F_OK) != 0) {
    /* Meant as NAME=FILE (no file has the whole value's name, and what
     * comes before '=' is no directory), but one of the two is missing or
     * cannot be a name: said now, not as the whole value's "No such file"
     * after the backend starts. */
    if (!eq[1])
      hfd_err("--weights %s: no file after '='; give NAME=FILE, or the file's path alone", val);
    else
      hfd_err("--weights %s: '%.*s' before '=' is not a variant name (1..%d printable "
              "characters, no space or '/') and no file has that whole name; give NAME=FILE "
              "with such a name, or the file's path alone", val, (int)(eq - val), val,
              HFP_NAME_MAX);
    return -1;
  }
  cfg->weights_name[cfg->num_weights] = name;
  cfg->weights[cfg->num_weights++] = path;
  return 0;
}

/* --warm WxH[xN][,WxH[xN]...], checked against --max-size and --max-batch
 * (so give those first). */
static int parse_warm(const char *list, hfd_config *cfg) {
  char buf[1024];
  if (strlen(list) >= sizeof buf) {
    hfd_err("--warm list too long");
    return -1;
  }
  strcpy(buf, list);
  char *save = NULL;
  for (char *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
    int w = 0, h = 0, n = 1, at = 0, more = 0;
    /* WxH, then xBATCH or nothing: a tail ("8x8x", "8x8y") is refused, not
     * dropped. */
    int ok = sscanf(tok, "%dx%d%n", &w, &h, &at) == 2;
    if (ok && tok[at] == 'x')
      ok = sscanf(tok + at + 1, "%d%n", &n, &more) == 1 && tok[at + 1 + more] == 0 &&
           tok[at + 1] != ' ' && tok[at + 1] != '+';
    else if (ok)
      ok = tok[at] == 0;
    /* Without --max-batch, the default grows to the largest warm batch. */
    int max_batch = cfg->max_batch ? cfg->max_batch : 256;
    if (!ok || w < 1 || h < 1 || w > cfg->max_width || h > cfg->max_height ||
        n < 1 || n > max_batch) {
      hfd_err("--warm wants WxH or WxHxBATCH within --max-size %dx%d and --max-batch %d, "
              "not '%s'",
              cfg->max_width, cfg->max_height, max_batch, tok);
      return -1;
    }
    if (cfg->num_warm == HFD_MAX_WARM) {
      hfd_err("at most %d --warm shapes", HFD_MAX_WARM);
      return -1;
    }
    cfg->warm[cfg->num_warm].width = w;
    cfg->warm[cfg->num_warm].height = h;
    cfg->warm[cfg->num_warm].batch = n;
    cfg->num_warm++;
  }
  if (!cfg->num_warm) {
    hfd_err("--warm needs at least one WxH");
    return -1;
  }
  return 0;
}

/* The TLS options agree with each other and with the listeners. */
static int tls_check(const hfd_config *cfg) {
  int tls = 0;
  for (int i = 0; i < cfg->num_listen; i++)
    tls |= cfg->listen_url[i].kind == HFP_URL_TCP && cfg->listen_url[i].tls;
  if (tls && (!cfg->tls_cert || !cfg->tls_key)) {
    hfd_err("a tls: listener needs --tls-cert FILE and --tls-key FILE "
            "(docs/SERVER.md, \"TLS\")");
    return -1;
  }
  if ((cfg->tls_cert != NULL) != (cfg->tls_key != NULL)) {
    hfd_err("--tls-cert and --tls-key go together");
    return -1;
  }
  if (cfg->tls_client_cert_auth && !cfg->tls_client_ca) {
    hfd_err("--tls-client-cert-auth needs --tls-client-ca FILE (the CA "
            "whose client certificates replace the token)");
    return -1;
  }
  return 0;
}

int hfd_listener_auth(const hfd_config *cfg, const hfp_url *u, const char *url, int *loopback,
                      int *auth_required) {
  /* A host that is not a numeric address is refused when the listener
   * opens (hairfilterd.c), after what a start made is cleaned up. */
  int loop = hfd_host_is_loopback(u->host);
  if (cfg->no_auth && loop == 0) {
    hfd_err("--listen %s: --no-auth is only allowed on loopback addresses", url);
    return -1;
  }
  /* A verified client certificate replaces the token only where it is
   * asked for, and only on TLS listeners (mutual TLS). */
  int need = !cfg->no_auth && !(u->tls && cfg->tls_client_cert_auth);
  if (need && !cfg->token[0]) {
    hfd_err("--listen %s: TCP needs a token (--auth-token-file or $HAIRFILTERD_TOKEN), or "
            "--no-auth on loopback%s", url,
            u->tls ? ", or --tls-client-ca with --tls-client-cert-auth" : "");
    return -1;
  }
  if (loopback) *loopback = loop == 1;
  if (auth_required) *auth_required = need;
  return 0;
}

/* TCP listeners and their authentication, checked with the options rather
 * than after the weights are loaded (minutes with --warm on a GPU). */
static int auth_check(const hfd_config *cfg) {
  for (int i = 0; i < cfg->num_listen; i++)
    if (cfg->listen_url[i].kind == HFP_URL_TCP &&
        hfd_listener_auth(cfg, &cfg->listen_url[i], cfg->listen[i], NULL, NULL))
      return -1;
  return 0;
}

enum {
  OPT_LISTEN = 256, OPT_WEIGHTS, OPT_WEIGHTS_DIR, OPT_BACKEND, OPT_MAX_BATCH, OPT_QUEUE_DELAY,
  OPT_QUEUE_SIZE, OPT_MAX_INFLIGHT, OPT_MAX_SIZE, OPT_MAX_FRAME, OPT_MAX_MEMORY, OPT_MAX_SHM, OPT_MAX_SHM_CONN,
  OPT_MAX_SHM_CLIENT,
  OPT_MAX_CONNECTIONS, OPT_MAX_HANDSHAKES, OPT_TOKEN_FILE, OPT_NO_AUTH, OPT_DRAIN,
  OPT_FLUSH, OPT_HANDSHAKE, OPT_STALL, OPT_MIN_RATE, OPT_READY, OPT_NAME, OPT_WARM,
  OPT_PIPELINE, OPT_HTTP, OPT_WATCHDOG, OPT_LOG_LEVEL, OPT_CONFIG, OPT_TLS_CERT, OPT_TLS_KEY,
  OPT_TLS_CLIENT_CA, OPT_TLS_CLIENT_CERT_AUTH, OPT_QUEUE_SHARE_BY, OPT_MAX_HANDSHAKES_ADDR,
  OPT_IPV6_CLIENT_PREFIX
};

static const struct option opts[] = {
  {"listen", required_argument, 0, OPT_LISTEN},
  {"weights", required_argument, 0, OPT_WEIGHTS},
  {"weights-dir", required_argument, 0, OPT_WEIGHTS_DIR},
  {"backend", required_argument, 0, OPT_BACKEND},
  {"max-batch", required_argument, 0, OPT_MAX_BATCH},
  {"max-queue-delay-us", required_argument, 0, OPT_QUEUE_DELAY},
  {"queue-size", required_argument, 0, OPT_QUEUE_SIZE},
  {"max-inflight", required_argument, 0, OPT_MAX_INFLIGHT},
  {"queue-share-by", required_argument, 0, OPT_QUEUE_SHARE_BY},
  {"max-size", required_argument, 0, OPT_MAX_SIZE},
  {"max-frame-mb", required_argument, 0, OPT_MAX_FRAME},
  {"max-memory-mb", required_argument, 0, OPT_MAX_MEMORY},
  {"max-shm-mb", required_argument, 0, OPT_MAX_SHM},
  {"max-shm-mb-per-connection", required_argument, 0, OPT_MAX_SHM_CONN},
  {"max-shm-mb-per-client", required_argument, 0, OPT_MAX_SHM_CLIENT},
  {"max-connections", required_argument, 0, OPT_MAX_CONNECTIONS},
  {"max-handshakes", required_argument, 0, OPT_MAX_HANDSHAKES},
  {"max-handshakes-per-address", required_argument, 0, OPT_MAX_HANDSHAKES_ADDR},
  {"ipv6-client-prefix", required_argument, 0, OPT_IPV6_CLIENT_PREFIX},
  {"auth-token-file", required_argument, 0, OPT_TOKEN_FILE},
  {"no-auth", no_argument, 0, OPT_NO_AUTH},
  {"tls-cert", required_argument, 0, OPT_TLS_CERT},
  {"tls-key", required_argument, 0, OPT_TLS_KEY},
  {"tls-client-ca", required_argument, 0, OPT_TLS_CLIENT_CA},
  {"tls-client-cert-auth", no_argument, 0, OPT_TLS_CLIENT_CERT_AUTH},
  {"drain-timeout-ms", required_argument, 0, OPT_DRAIN},
  {"flush-timeout-ms", required_argument, 0, OPT_FLUSH},
  {"handshake-timeout-ms", required_argument, 0, OPT_HANDSHAKE},
  {"stall-timeout-ms", required_argument, 0, OPT_STALL},
  {"min-recv-rate", required_argument, 0, OPT_MIN_RATE},
  {"ready-file", required_argument, 0, OPT_READY},
  {"warm", required_argument, 0, OPT_WARM},
  {"pipeline-depth", required_argument, 0, OPT_PIPELINE},
  {"name", required_argument, 0, OPT_NAME},
  {"http", required_argument, 0, OPT_HTTP},
  {"watchdog-ms", required_argument, 0, OPT_WATCHDOG},
  {"log-level", required_argument, 0, OPT_LOG_LEVEL},
  {"config", required_argument, 0, OPT_CONFIG},
  {"verbose", no_argument, 0, 'v'},
  {"help", no_argument, 0, 'h'},
  {"version", no_argument, 0, 'V'},
  {0, 0, 0, 0},
};

/* ---- the config file ------------------------------------------------------ */

_Static_assert(sizeof opts / sizeof opts[0] <= 64, "file_args.seen_line holds every option");

static char *own(hfd_config *cfg, char *s) {
  if (!s) return NULL;
  if (cfg->num_owned == cfg->cap_owned) {
    int cap = cfg->cap_owned ? cfg->cap_owned * 2 : 32;
    char **p = realloc(cfg->owned, (size_t)cap * sizeof *p);
    if (!p) {
      free(s);
      return NULL;
    }
    cfg->owned = p;
    cfg->cap_owned = cap;
  }
  return cfg->owned[cfg->num_owned++] = s;
}

void hfd_config_free(hfd_config *cfg) {
  for (int i = 0; i < cfg->num_owned; i++) free(cfg->owned[i]);
  free(cfg->owned);
  cfg->owned = NULL;
  cfg->num_owned = cfg->cap_owned = 0;
}

typedef struct file_args {
  hfd_config *cfg;
  const char *path;
  char **argv;                   /* "--key=value", owned by cfg */
  int *argline;                  /* the line each of argv came from */
  int argc, cap;
  int bad;                       /* a line was refused: why */
  char why[300];
  FILE *f;
  int line, next_line;           /* the line being parsed, the next one */
  char *buf;                     /* read_line's whole line (getline) */
  size_t buf_cap;
  int bad_line;                  /* a line refused before inih gave it to on_ini */
  int seen_line[64];             /* per option (opts[]): its last line, 0: none */
  int seen_arg[64];              /* and that line's index in argv, -1: none */
  /* Warnings about the file, said once --log-level (which the file or the
   * command line may set after them) is known. */
  char warning[8][300];
  int nwarnings;
} file_args;

/* inih's reader, one whole line of the file a call, so that inih's line
 * numbers are the file's and on_ini knows which line it is given. inih
 * (Debian's libinih, built with INI_MAX_LINE 200) takes num - 1 bytes of a
 * line at most and would read a longer one as several lines: a comment of
 * any length is passed on as an empty comment, and a longer key line is
 * refused as such (the command line takes any length). */
/* The first line refused before inih sees it: its reason, and its number. */
static void refuse_line(file_args *fa, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void refuse_line(file_args *fa, const char *fmt, ...) {
  if (fa->bad) return;
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(fa->why, sizeof fa->why, fmt, ap);
  va_end(ap);
  fa->bad = 1;
  fa->bad_line = fa->line;
}

static char *read_line(char *str, int num, void *stream) {
  file_args *fa = stream;
  ssize_t n = getline(&fa->buf, &fa->buf_cap, fa->f);
  if (n < 0) return NULL;
  fa->line = fa->next_line++;
  const char *t = fa->buf + strspn(fa->buf, " \t");
  int nul = memchr(fa->buf, 0, (size_t)n) != NULL;
  if (n >= num || nul) {
    if (!nul && (*t == ';' || *t == '#')) {
      snprintf(str, (size_t)num, "#\n");
      return str;
    }
    if (nul)
      refuse_line(fa, "the line holds a NUL byte: a config file is text");
    else
      refuse_line(fa, "the line is %zd bytes with its line end, more than the %d a line of the "
                  "file may have (libinih's INI_MAX_LINE): give this option on the command "
                  "line instead, or shorten its value (a long path: a shorter link to it)", n,
                  num - 1);
    snprintf(str, (size_t)num, "\n");
    return str;
  }
  memcpy(str, fa->buf, (size_t)n + 1);
  /* A section header is refused here: inih hands on_ini only key lines,
   * so one with no key after it (at the end of the file) would pass. */
  if (*t == '[') {
    size_t k = strcspn(t + 1, "]\r\n");
    refuse_line(fa, "no sections ([%.*s]): keys are the options' names",
                (int)(k > 64 ? 64 : k), t + 1);
  }
  /* An indented line is, to inih, more of the value of the key above it
   * (a second --listen URL 'weights = FILE', say), which no message
   * about that value would make plain. Comments and empty lines may be
   * indented. */
  if (t != fa->buf && !strchr(";#\r\n", *t) && *t)
    refuse_line(fa, "the line starts with whitespace, which continues the key above it (inih's "
                "rule): indent nothing");
  return str;
}

static int truthy(const char *v, int *out) {
  static const char *const yes[] = {"1", "yes", "true", "on"};
  static const char *const no[] = {"0", "no", "false", "off"};
  for (int i = 0; i < 4; i++) {
    if (!strcasecmp(v, yes[i])) return *out = 1, 0;
    if (!strcasecmp(v, no[i])) return *out = 0, 0;
  }
  return -1;
}

/* inih calls this for every "key = value" line, in order (a key may come
 * more than once: --listen, --weights). Returning 0 makes ini_parse report
 * the line; why says what was wrong with it. */
static int on_ini(void *user, const char *section, const char *key, const char *value) {
  file_args *fa = user;
  if (fa->bad) return 0;
  if (section[0]) {
    snprintf(fa->why, sizeof fa->why, "no sections ([%s]): keys are the options' names", section);
    fa->bad = 1;
    return 0;
  }
  const struct option *o = NULL;
  for (const struct option *p = opts; p->name; p++)
    if (!strcmp(p->name, key)) o = p;
  int oi = o ? (int)(o - opts) : 0;
  if (!o || !strcmp(key, "config") || !strcmp(key, "help") ||
      !strcmp(key, "version")) {
    snprintf(fa->why, sizeof fa->why, "unknown key '%s' (keys are the long options without "
             "their dashes; see hairfilterd --help)", key);
    fa->bad = 1;
    return 0;
  }
  char *arg = NULL;
  int on = 1;
  if (o->has_arg == no_argument && truthy(value, &on)) {
    snprintf(fa->why, sizeof fa->why, "%s wants yes or no, not '%s'", key, value);
    fa->bad = 1;
    return 0;
  }
  /* A key of one value given again: the later line wins (a flag set to
   * no drops the earlier yes), and both lines are named, since an edit
   * that appended a key the file already had is otherwise invisible. */
  int repeatable = o->val == OPT_LISTEN || o->val == OPT_WEIGHTS;
  if (!repeatable && fa->seen_line[oi]) {
    if (fa->nwarnings < (int)(sizeof fa->warning / sizeof fa->warning[0]))
      snprintf(fa->warning[fa->nwarnings++], sizeof fa->warning[0],
               "%s:%d: '%s' was given already on line %d; a key takes one value, so line %d's "
               "wins", fa->path, fa->line, key, fa->seen_line[oi], fa->line);
    if (fa->seen_arg[oi] >= 0) fa->argv[fa->seen_arg[oi]] = NULL;
  }
  fa->seen_line[oi] = fa->line;
  fa->seen_arg[oi] = -1;
  if (o->has_arg == no_argument) {
    if (!on) return 1;
    if (asprintf(&arg, "--%s", key) < 0) arg = NULL;
  } else if (asprintf(&arg, "--%s=%s", key, value) < 0) {
    arg = NULL;
  }
  if (fa->argc + 2 >= fa->cap) {
    int cap = fa->cap ? fa->cap * 2 : 32;
    char **p = realloc(fa->argv, (size_t)cap * sizeof *p);
    int *pl = p ? realloc(fa->argline, (size_t)cap * sizeof *pl) : NULL;
    if (pl) fa->argline = pl;
    if (!p || !pl) {
      if (p) fa->argv = p;
      free(arg);
      snprintf(fa->why, sizeof fa->why, "out of memory");
      fa->bad = 1;
      return 0;
    }
    fa->argv = p;
    fa->cap = cap;
  }
  if (!(fa->argv[fa->argc] = own(fa->cfg, arg))) {
    snprintf(fa->why, sizeof fa->why, "out of memory");
    fa->bad = 1;
    return 0;
  }
  fa->argline[fa->argc] = fa->line;
  fa->seen_arg[oi] = fa->argc++;
  return 1;
}

/* --config FILE or --config=FILE anywhere on the command line (the last
 * wins), else the default path. NULL for "none", and for --help and
 * --version, which answer whatever state the config file is in (an
 * operator asks for the version when something is wrong). */
static const char *config_path(int argc, char **argv, int *explicit) {
  const char *path = HFD_DEFAULT_CONFIG;
  *explicit = 0;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--")) break;
    if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h") || !strcmp(argv[i], "--version")) {
      *explicit = 0;
      return NULL;
    }
    if (!strcmp(argv[i], "--config") && i + 1 < argc) {
      path = argv[++i];
      *explicit = 1;
    } else if (!strncmp(argv[i], "--config=", 9)) {
      path = argv[i] + 9;
      *explicit = 1;
    }
  }
  return strcmp(path, "none") ? path : NULL;
}

int hfd_config_parse(int argc, char **argv, hfd_config *cfg) {
  memset(cfg, 0, sizeof *cfg);
  cfg->backend = "auto";
  cfg->max_batch = 0; /* by backend: default_max_batch in worker.c */
  cfg->queue_size = 64;
  cfg->max_inflight = 32;
  /* Ultra HD: engines render landscape frames, and the memory budget lowers
   * this keeping its aspect, so a square default would shut out 1920x1080
   * (1648x1648 with the bundled variants and the default budget) though it
   * fits the budget. */
  cfg->max_width = 3840;
  cfg->max_height = 2160;
  cfg->max_connections = 256;
  cfg->max_handshakes = 32;
  cfg->ipv6_client_prefix = HFD_V6_CLIENT_PREFIX_DEFAULT;
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
  cfg->watchdog_ms = 60000;
  cfg->log_level = HFD_LOG_INFO;
  const char *token_file = NULL, *warm = NULL;

  /* The file's lines first, then the command line, through one parser. */
  int explicit;
  const char *path = config_path(argc, argv, &explicit);
  static file_args zero;
  file_args fa = zero;
  fa.cfg = cfg;
  fa.path = path;
  fa.next_line = 1;
  struct stat st;
  if (path && (explicit || stat(path, &st) == 0)) {
    int rc = -1;
    if ((fa.f = open_file(path))) {
      rc = ini_parse_stream(read_line, &fa, on_ini, &fa);
      fclose(fa.f);
      free(fa.buf);
      /* Lines a repeated key overrode (on_ini) leave holes. */
      int n = 0;
      for (int i = 0; i < fa.argc; i++)
        if (fa.argv[i]) fa.argline[n] = fa.argline[i], fa.argv[n++] = fa.argv[i];
      fa.argc = n;
    }
    /* A line read_line refused: its own line, whatever inih made of it. */
    if (rc >= 0 && fa.bad_line) rc = fa.bad_line;
    if (rc == -1) {
      char why[600];
      unreadable_why(path, errno, why, sizeof why);
      hfd_err("cannot read config file %s: %s", path, why);
    } else if (rc < 0) {
      hfd_err("cannot read config file %s: out of memory", path);
    }
    else if (rc > 0)
      hfd_err("%s:%d: %s", path, rc,
              fa.bad ? fa.why : "not a 'key = value' line");
    if (rc) {
      free(fa.argv);
      free(fa.argline);
      return -1;
    }
    cfg->config_path = path;
  }
  int nall = 1 + fa.argc + argc;
  char **all = calloc((size_t)nall + 1, sizeof *all);
  if (!all) {
    free(fa.argv);
    free(fa.argline);
    return -1;
  }
  all[0] = argv[0];
  for (int i = 0; i < fa.argc; i++) all[1 + i] = fa.argv[i];
  for (int i = 1; i < argc; i++) all[fa.argc + i] = argv[i];
  nall = 1 + fa.argc + argc - 1;
  free(fa.argv);
  /* A repeatable key on the command line replaces the file's list. */
  int listen_from_file = 0, weights_from_file = 0;
  int rc = 0;
  optind = 1;
  opterr = 0;
  char where[4300];
  for (;;) {
    hfd_log_context(NULL);
    int idx = -1, o = getopt_long(nall, all, ":hv", opts, &idx);
    if (o == -1) break;
    /* Arguments up to index fa.argc came from the file: what is wrong
     * with one is said with its file and line, as the file's own checks
     * are. */
    int from_file = optind - 1 <= fa.argc;
    if (from_file && optind >= 2 && optind - 2 < fa.argc) {
      snprintf(where, sizeof where, "%s:%d: ", path, fa.argline[optind - 2]);
      hfd_log_context(where);
    }
    const char *name = idx >= 0 ? opts[idx].name : "";
    const char *val = optarg;
    long v;
    if (o == OPT_LISTEN && !from_file && listen_from_file) {
      cfg->num_listen = 0;
      listen_from_file = 0;
    }
    if (o == OPT_WEIGHTS && !from_file && weights_from_file) {
      cfg->num_weights = 0;
      weights_from_file = 0;
    }
    if (o == OPT_LISTEN && from_file) listen_from_file = 1;
    if (o == OPT_WEIGHTS && from_file) weights_from_file = 1;
    switch (o) {
      case 'h':
        usage(stdout);
        rc = 1;
        goto out;
      case 'V':
        printf("hairfilterd %s (protocol v%d..v%d)\n", HAIRFILTER_VERSION_STRING, HFP_VERSION_MIN,
               HFP_VERSION);
        rc = 1;
        goto out;
      case 'v':
        cfg->log_level = HFD_LOG_DEBUG;
        break;
      case OPT_CONFIG: break;  /* read above */
      case OPT_HTTP: {
        char why[300];
        if (hfp_url_parse(val, HFP_URL_LISTEN, &cfg->http_url, why, sizeof why) ||
            cfg->http_url.kind != HFP_URL_TCP || cfg->http_url.tls) {
          if (cfg->http_url.tls) snprintf(why, sizeof why, "it serves plain HTTP, not TLS");
          hfd_err("--http wants tcp:HOST:PORT%s%s",
                  cfg->http_url.kind == HFP_URL_UNIX ? "" : ": ",
                  cfg->http_url.kind == HFP_URL_UNIX ? "" : why);
          rc = -1;
          goto out;
        }
        cfg->http = val;
        break;
      }
      case OPT_WATCHDOG:
        if (parse_int(name, val, 1000, 3600000, &v)) goto fail;
        cfg->watchdog_ms = (int)v;
        break;
      case OPT_LOG_LEVEL: {
        int l = hfd_log_level_parse(val);
        if (l < 0) {
          hfd_err("--log-level wants error, warning, notice, info or "
                  "debug, not '%s'", val);
          goto fail;
        }
        cfg->log_level = l;
        break;
      }
      case OPT_LISTEN: {
        if (cfg->num_listen == HFD_MAX_LISTENERS) {
          hfd_err("at most %d --listen", HFD_MAX_LISTENERS);
          goto fail;
        }
        char why[300];
        const hfp_url *u = &cfg->listen_url[cfg->num_listen];
        if (hfp_url_parse(val, HFP_URL_LISTEN, &cfg->listen_url[cfg->num_listen], why,
                          sizeof why)) {
          hfd_err("--listen: %s", why);
          goto fail;
        }
        /* The same address twice would fail at its second bind as if
         * another server held it. Port 0 (any free port) may repeat. */
        for (int i = 0; i < cfg->num_listen; i++) {
          const hfp_url *o = &cfg->listen_url[i];
          if (o->kind == u->kind &&
              (u->kind == HFP_URL_UNIX ? same_socket_path(o->path, u->path)
                                       : u->port && o->port == u->port && !strcmp(o->host, u->host))) {
            hfd_err("--listen %s is given twice (also as %s): give each address once", val,
                    cfg->listen[i]);
            goto fail;
          }
        }
        cfg->listen[cfg->num_listen++] = val;
        break;
      }
      case OPT_WEIGHTS:
        if (cfg->num_weights == HFD_MAX_VARIANTS) {
          hfd_err("at most %d --weights", HFD_MAX_VARIANTS);
          goto fail;
        }
        if (weights_entry(cfg, val)) goto fail;
        break;
      case OPT_WEIGHTS_DIR: cfg->weights_dir = val; break;
      case OPT_BACKEND:
        /* A name that is no backend at all is a bad option (status 2, at
         * once); one this build lacks (cudnn without CUDA) is found when
         * the backend starts, which says how to build it. */
        if (strcmp(val, "auto") && strcmp(val, "cudnn") && strcmp(val, "cpu") &&
            strcmp(val, "cpu-ref")) {
          hfd_err("--backend wants auto, cudnn, cpu or cpu-ref, not '%s'", val);
          goto fail;
        }
        cfg->backend = val;
        break;
      case OPT_MAX_BATCH:
        if (parse_int(name, val, 1, 256, &v)) goto fail;
        cfg->max_batch = (int)v;
        break;
      case OPT_QUEUE_DELAY:
        if (parse_int(name, val, 0, 10000000, &v)) goto fail;
        cfg->max_queue_delay_us = (int)v;
        break;
      case OPT_QUEUE_SIZE:
        if (parse_int(name, val, 1, 65536, &v)) goto fail;
        cfg->queue_size = (int)v;
        break;
      case OPT_MAX_INFLIGHT:
        if (parse_int(name, val, 1, 65535, &v)) goto fail;
        cfg->max_inflight = (int)v;
        break;
      case OPT_MAX_SIZE: {
        int w, h;
        char tail;
        if (sscanf(val, "%dx%d%c", &w, &h, &tail) != 2 || w < 1 || h < 1 ||
            w > HFP_MAX_SIDE || h > HFP_MAX_SIDE) {
          hfd_err("--max-size wants WxH within 1..%d, not '%s'",
                  HFP_MAX_SIDE, val);
          goto fail;
        }
        cfg->max_width = w;
        cfg->max_height = h;
        break;
      }
      case OPT_MAX_FRAME:
        if (parse_int(name, val, 1, 4095, &v)) goto fail;
        cfg->max_frame_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_MEMORY:
        if (parse_int(name, val, 1, 1 << 30, &v)) goto fail;
        cfg->max_memory_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_SHM:
        if (parse_int(name, val, 0, 1 << 30, &v)) goto fail;
        cfg->max_shm_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_SHM_CONN:
        if (parse_int(name, val, 1, 1 << 30, &v)) goto fail;
        cfg->max_shm_conn_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_SHM_CLIENT:
        if (parse_int(name, val, 1, 1 << 30, &v)) goto fail;
        cfg->max_shm_client_bytes = (uint64_t)v << 20;
        break;
      case OPT_MAX_CONNECTIONS:
        if (parse_int(name, val, 1, 1000000, &v)) goto fail;
        cfg->max_connections = (int)v;
        break;
      case OPT_MAX_HANDSHAKES:
        if (parse_int(name, val, 1, 1000000, &v)) goto fail;
        cfg->max_handshakes = (int)v;
        break;
      case OPT_MAX_HANDSHAKES_ADDR:
        if (parse_int(name, val, 1, 1000000, &v)) goto fail;
        cfg->max_handshakes_addr = (int)v;
        break;
      case OPT_IPV6_CLIENT_PREFIX:
        if (parse_int(name, val, HFD_V6_CLIENT_PREFIX_MIN, HFD_V6_CLIENT_PREFIX_MAX, &v)) goto fail;
        cfg->ipv6_client_prefix = (int)v;
        break;
      case OPT_QUEUE_SHARE_BY:
        if (!strcmp(val, "client")) {
          cfg->share_by_connection = 0;
        } else if (!strcmp(val, "connection")) {
          cfg->share_by_connection = 1;
        } else {
          hfd_err("--queue-share-by wants client or connection, not '%s'", val);
          goto fail;
        }
        break;
      case OPT_TOKEN_FILE: token_file = val; break;
      case OPT_NO_AUTH: cfg->no_auth = 1; break;
      case OPT_TLS_CERT: cfg->tls_cert = val; break;
      case OPT_TLS_KEY: cfg->tls_key = val; break;
      case OPT_TLS_CLIENT_CA: cfg->tls_client_ca = val; break;
      case OPT_TLS_CLIENT_CERT_AUTH: cfg->tls_client_cert_auth = 1; break;
      case OPT_DRAIN:
        if (parse_int(name, val, 0, 3600000, &v)) goto fail;
        cfg->drain_timeout_ms = (int)v;
        break;
      case OPT_FLUSH:
        if (parse_int(name, val, 0, 3600000, &v)) goto fail;
        cfg->flush_timeout_ms = (int)v;
        break;
      case OPT_HANDSHAKE:
        if (parse_int(name, val, 0, 3600000, &v)) goto fail;
        cfg->handshake_timeout_ms = (int)v;
        break;
      case OPT_STALL:
        if (parse_int(name, val, 0, 3600000, &v)) goto fail;
        cfg->stall_timeout_ms = (int)v;
        break;
      case OPT_MIN_RATE:
        if (parse_int(name, val, 0, 1 << 20, &v)) goto fail;
        cfg->min_recv_rate = (uint64_t)v << 10;
        break;
      case OPT_READY: cfg->ready_file = val; break;
      case OPT_WARM: warm = val; break;
      case OPT_PIPELINE:
        if (parse_int(name, val, 1, 2, &v)) goto fail;
        cfg->pipeline_depth = (int)v;
        break;
      case OPT_NAME: {
        size_t n = strlen(val);
        int ok = n >= 1 && n <= HFP_NAME_MAX;
        for (size_t k = 0; ok && k < n; k++) ok = val[k] > 0x20 && val[k] < 0x7f;
        if (!ok) {
          hfd_err("--name must be 1..%d printable characters",
                  HFP_NAME_MAX);
          goto fail;
        }
        cfg->name = val;
        break;
      }
      case ':':
        hfd_err("%s needs a value", all[optind - 1]);
        goto fail;
      default:
        hfd_err("unknown option '%s'", all[optind - 1]);
        usage(stderr);
        goto fail;
    }
  }
  if (optind < nall) {
    hfd_err("unexpected argument '%s'", all[optind]);
    usage(stderr);
    goto fail;
  }
  if (cfg->log_level >= HFD_LOG_WARNING)
    for (int i = 0; i < fa.nwarnings; i++) hfd_warn("%s", fa.warning[i]);
  if (!cfg->num_listen) {
    hfd_err("nothing to listen on: give --listen unix:PATH, tcp:HOST:PORT or tls:HOST:PORT");
    goto fail;
  }
  if (!cfg->num_weights && !cfg->weights_dir) {
    hfd_err("no variants: give --weights FILE or --weights-dir DIR");
    goto fail;
  }
  if (warm && parse_warm(warm, cfg)) goto fail;
  if (tls_check(cfg)) goto fail;
  if (token_file) {
    if (read_token(token_file, cfg->token)) goto fail;
  } else {
    const char *env = getenv("HAIRFILTERD_TOKEN");
    if (env && token_take("$HAIRFILTERD_TOKEN", env, strlen(env), cfg->token)) goto fail;
  }
  if (auth_check(cfg)) goto fail;
  goto out;
fail:
  rc = -1;
out:
  hfd_log_context(NULL);
  free(fa.argline);
  free(all);
  return rc;
}
