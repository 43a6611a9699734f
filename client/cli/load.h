/* hairfilter load: shared between the measuring (cmd_load.c) and the
 * reporting (load_report.c) halves. */
#ifndef HF_CLI_LOAD_H
#define HF_CLI_LOAD_H

#include <stdint.h>
#include <stdio.h>

#include "load_hist.h"

/* Latency fields recorded per completion: the client's own round trip (from
 * the request's scheduled start), then the server's RESULT timing. */
enum { LF_CLIENT, LF_SERVER, LF_QUEUE, LF_INPUT, LF_INFER, LF_OUTPUT, LF_COUNT };
extern const char *const load_field_names[LF_COUNT];

/* What one measurement window (or several merged) saw. */
typedef struct load_window {
  lh_hist h[LF_COUNT];
  uint64_t ok, busy, errors;     /* completions by outcome */
  uint64_t expired;              /* EXPIRED: the frame's budget (--deadline) passed in
                                    the server's queue; not in errors */
  uint64_t batch_sum;            /* sum of RESULT batch sizes, for the mean */
  double seconds;                /* how long it lasted */
} load_window;

/* The server's own STATS for the variant, differenced over a point (all
 * clients of the server, not only ours). */
typedef struct load_stats {
  int valid;
  uint64_t ok, failed, rejected, batches;
  uint64_t expired;                    /* of failed: answered EXPIRED (protocol version 4) */
  uint64_t cancelled;                  /* of failed: answered CANCELLED (protocol version 4) */
  double mean_queue_ms, mean_infer_ms, mean_total_ms;
  double p50_total_ms, p99_total_ms;   /* from STATS' power-of-two buckets: upper bounds */
} load_stats;

/* One point of a sweep. */
typedef struct load_point {
  int open_loop;
  int concurrency;               /* closed loop: requests kept in flight */
  double rate;                   /* open loop: frames/s offered */
  int connections;
  int trials;                    /* windows measured */
  int used;                      /* of which merged into the result (--trials: all; else
                                    the last ones, which agreed) */
  int stable;
  load_window result;            /* the merged windows */
  double window_throughput[64];  /* each window's frames/s (up to 64 kept) */
  double window_p50[64], window_p99[64];
  uint64_t sent, answered, delayed, unanswered;
  /* Sent in the warm-up (not in sent), and their answers by outcome. */
  uint64_t warm_sent, warm_ok, warm_busy, warm_errors, warm_expired;
  /* The answered (after the warm-up) by outcome, windows or not: they add
   * up to answered. */
  uint64_t ans_ok, ans_busy, ans_errors, ans_expired;
  int lost_connections;
  int refused_connections;       /* stopped by a refusal no retry can fix */
  int interrupted;               /* stopped by a signal: windows cut short dropped */
  load_stats stats;
} load_point;

typedef struct load_run {
  const char *server, *variant, *input, *backend, *precision;
  int width, height, spp, f16, shm, composite;
  const char *distribution;
  double window_s, warmup_s;
  double stability;              /* percent */
  load_point *points;
  int npoints;
  /* Where the figures come from: the command line, the machine, when (UTC,
   * ISO 8601) and the tool's version. */
  const char *command, *cpu, *date, *version;
  int cores;
  int interrupted;               /* the sweep was stopped by a signal */
  uint32_t deadline_us;          /* --deadline: each frame's budget at the server; 0: none */
} load_run;

/* Writers of the report: the text table of one point, the sweep's summary,
 * CSV, JSON (cJSON) and a latency-versus-throughput PNG through gnuplot.
 * Return 0, or -1 with a message printed. */
void load_print_header(FILE *f, const load_run *r);
void load_print_point(FILE *f, const load_run *r, const load_point *p);
void load_print_summary(FILE *f, const load_run *r);
/* Whether a file can be made beside path (an output written at the end
 * of the run, under a temporary name there): 0, or -1 after saying why,
 * naming option. "-" (a standard stream) passes. */
int load_out_probe(const char *option, const char *path);
int load_write_csv(const char *path, const load_run *r);
int load_write_json(const char *path, const load_run *r);
int load_have_gnuplot(void);
int load_write_plot(const char *path, const load_run *r);

#endif
