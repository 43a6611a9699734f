/* The CPU's model, flags and measured fp32 peak (bench_peak.h says how). */
#include "bench_peak.h"

#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define BP_X86 1
#endif

/* ---- the CPU -------------------------------------------------------------- */

/* The flags that say which vector code runs: what oneDNN and PyTorch pick
 * their kernels by. */
static const char *const BP_FLAGS[] = {
  "sse4_2",      "avx",         "avx2",        "fma",       "f16c",        "avx512f",
  "avx512dq",    "avx512cd",    "avx512bw",    "avx512vl",  "avx512_vnni", "avx512_bf16",
  "avx512_fp16", "avx_vnni",    "amx_tile",    "amx_bf16",  "amx_int8",    NULL,
};

/* The value of a "key : value" line of /proc/cpuinfo, trailing newline cut. */
static const char *bp_value(char *line, const char *key) {
  size_t n = strlen(key);
  if (strncmp(line, key, n)) return NULL;
  char *p = line + n;
  while (*p == ' ' || *p == '\t') p++;
  if (*p != ':') return NULL;
  p++;
  while (*p == ' ') p++;
  p[strcspn(p, "\n")] = 0;
  return p;
}

void bench_cpu_describe(bench_cpu *cpu) {
  memset(cpu, 0, sizeof *cpu);
  snprintf(cpu->model, sizeof cpu->model, "unknown");
  cpu->family = cpu->model_id = -1;
  long n = sysconf(_SC_NPROCESSORS_ONLN);
  cpu->online = n > 0 ? (int)n : 1;
  FILE *f = fopen("/proc/cpuinfo", "r");
  if (!f) return;
  /* The first processor's block: on x86 they all say the same. */
  char line[8192];
  while (fgets(line, sizeof line, f)) {
    const char *v;
    if (line[0] == '\n') break;
    if ((v = bp_value(line, "model name")))
      snprintf(cpu->model, sizeof cpu->model, "%s", v);
    else if ((v = bp_value(line, "cpu family")))
      cpu->family = atoi(v);
    else if ((v = bp_value(line, "model")))
      cpu->model_id = atoi(v);
    else if ((v = bp_value(line, "flags"))) {
      size_t used = 0;
      for (int i = 0; BP_FLAGS[i]; i++) {
        /* A whole word of the list. */
        size_t k = strlen(BP_FLAGS[i]);
        for (const char *p = strstr(v, BP_FLAGS[i]); p; p = strstr(p + 1, BP_FLAGS[i]))
          if ((p == v || p[-1] == ' ') && (p[k] == ' ' || p[k] == 0)) {
            int w = snprintf(cpu->flags + used, sizeof cpu->flags - used, "%s%s",
                             used ? " " : "", BP_FLAGS[i]);
            if (w > 0 && (size_t)w < sizeof cpu->flags - used) used += w;
            break;
          }
      }
    }
  }
  fclose(f);
}

int bench_cpu_threads(void) {
  long n = sysconf(_SC_NPROCESSORS_ONLN);
  const char *omp = getenv("OMP_NUM_THREADS");
  if (omp && atol(omp) > 0 && atol(omp) < n) n = atol(omp);
  return n < 1 ? 1 : n > 256 ? 256 : (int)n;
}

/* ---- the loops -------------------------------------------------------------- */

/* Each loop runs iters iterations of BENCH_PEAK_CHAINS independent
 * multiply-adds acc = acc * x + y (x just under 1: the values stay near
 * y / (1 - x), no overflow, no subnormals) and returns a sum of the
 * accumulators, which the caller keeps so the loop is not optimised away. */
#define BP_X 0.9999f
#define BP_Y 0.0001f
#define BP_REP(S) S(0) S(1) S(2) S(3) S(4) S(5) S(6) S(7) S(8) S(9) S(10) S(11)

#ifdef BP_X86
/* One loop per vector width: NAME(iters) on vectors of type T (LANES
 * floats), SET1 broadcasting, BP_STEP_OP(acc, x, y) (defined before each)
 * one multiply-add, ADD and STORE to sum the accumulators. */
#define BP_LOOP(NAME, TARGET, T, LANES, SET1, ADD, STORE)                     \
  TARGET static float NAME(long iters) {                                     \
    T a[BENCH_PEAK_CHAINS], x = SET1(BP_X), y = SET1(BP_Y);                  \
    for (int k = 0; k < BENCH_PEAK_CHAINS; k++) a[k] = SET1((float)k);       \
    for (long i = 0; i < iters; i++) {                                       \
      BP_REP(BP_STEP)                                                        \
    }                                                                        \
    T s = a[0];                                                              \
    for (int k = 1; k < BENCH_PEAK_CHAINS; k++) s = ADD(s, a[k]);            \
    float v[LANES], sum = 0;                                                 \
    STORE(v, s);                                                             \
    for (int l = 0; l < LANES; l++) sum += v[l];                             \
    return sum;                                                              \
  }
#define BP_STEP(k) a[k] = BP_STEP_OP(a[k], x, y);

#define BP_STEP_OP(a, x, y) _mm512_fmadd_ps(a, x, y)
BP_LOOP(bp_avx512, __attribute__((target("avx512f"))), __m512, 16, _mm512_set1_ps,
        _mm512_add_ps, _mm512_storeu_ps)
#undef BP_STEP_OP
#define BP_STEP_OP(a, x, y) _mm256_fmadd_ps(a, x, y)
BP_LOOP(bp_avx2, __attribute__((target("avx2,fma"))), __m256, 8, _mm256_set1_ps,
        _mm256_add_ps, _mm256_storeu_ps)
#undef BP_STEP_OP
#define BP_STEP_OP(a, x, y) _mm_add_ps(_mm_mul_ps(a, x), y)
BP_LOOP(bp_sse2, , __m128, 4, _mm_set1_ps, _mm_add_ps, _mm_storeu_ps)
#undef BP_STEP_OP
#else
/* Elsewhere: plain C on 4-float groups, which the compiler vectorises for
 * the target's base vector unit. */
static float bp_generic(long iters) {
  float a[BENCH_PEAK_CHAINS][4];
  for (int k = 0; k < BENCH_PEAK_CHAINS; k++)
    for (int l = 0; l < 4; l++) a[k][l] = (float)k;
  for (long i = 0; i < iters; i++)
    for (int k = 0; k < BENCH_PEAK_CHAINS; k++)
      for (int l = 0; l < 4; l++) a[k][l] = a[k][l] * BP_X + BP_Y;
  float s = 0;
  for (int k = 0; k < BENCH_PEAK_CHAINS; k++)
    for (int l = 0; l < 4; l++) s += a[k][l];
  return s;
}
#endif

typedef float (*bp_loop)(long iters);

static double bp_clock(clockid_t id) {
  struct timespec t;
  clock_gettime(id, &t);
  return t.tv_sec + t.tv_nsec * 1e-9;
}
static double bp_now(void) { return bp_clock(CLOCK_MONOTONIC); }
/* This thread's CPU time: what it ran, not what other processes on the
 * same core took in between. */
static double bp_cpu(void) { return bp_clock(CLOCK_THREAD_CPUTIME_ID); }

/* Threads of one all-at-once run, released together once all exist. */
typedef struct bp_start {
  pthread_mutex_t mu;
  pthread_cond_t cv;
  int go;
} bp_start;

typedef struct bp_job {
  bp_loop loop;
  long iters;
  bp_start *start;
  float result;
} bp_job;

static void *bp_thread(void *arg) {
  bp_job *j = arg;
  pthread_mutex_lock(&j->start->mu);
  while (!j->start->go) pthread_cond_wait(&j->start->cv, &j->start->mu);
  pthread_mutex_unlock(&j->start->mu);
  j->result = j->loop(j->iters);
  return NULL;
}

#define BP_RUNS 20
#define BP_ALL_RUNS 10
#define BP_RUN_SECONDS 0.005

int bench_peak_measure(int threads, bench_peak *out) {
  memset(out, 0, sizeof *out);
  if (threads < 1) threads = 1;
  if (threads > 256) threads = 256;
  bp_loop loop;
#ifdef BP_X86
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx512f"))
    loop = bp_avx512, out->isa = "avx512f", out->lanes = 16, out->fma = 1;
  else if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
    loop = bp_avx2, out->isa = "avx2+fma", out->lanes = 8, out->fma = 1;
  else
    loop = bp_sse2, out->isa = "sse2", out->lanes = 4, out->fma = 0;
#else
  loop = bp_generic, out->isa = "generic C", out->lanes = 4, out->fma = 0;
#endif
  /* Two flops per lane and step either way: one FMA, or a mul and an add. */
  const double flops_per_iter = 2.0 * out->lanes * BENCH_PEAK_CHAINS;
  volatile float sink = 0;
  /* Iterations for a run of BP_RUN_SECONDS, from the fastest of a few
   * shorter runs. */
  long iters = 5000;
  double t0, dt, fastest = 0;
  for (int r = 0; r < 5; r++) {
    t0 = bp_cpu();
    sink += loop(iters);
    dt = bp_cpu() - t0;
    if (dt > 0 && (fastest == 0 || dt < fastest)) fastest = dt;
  }
  if (fastest > 0) iters = (long)(iters * BP_RUN_SECONDS / fastest);
  if (iters < 1000) iters = 1000;
  out->threads = threads;
  out->runs = BP_RUNS;
  for (int r = 0; r < BP_RUNS; r++) {
    t0 = bp_cpu();
    sink += loop(iters);
    dt = bp_cpu() - t0;
    double g = iters * flops_per_iter / dt / 1e9;
    if (dt > 0 && g > out->core_gflops) out->core_gflops = g, out->run_ms = dt * 1e3;
  }
  out->peak_gflops = out->core_gflops * threads;
  /* Every thread at once; this thread is one of them. */
  pthread_t *th = calloc(threads, sizeof *th);
  bp_job *jobs = calloc(threads, sizeof *jobs);
  int rc = 0;
  if (!th || !jobs) {
    free(th), free(jobs);
    errno = ENOMEM;
    return -1;
  }
  for (int r = 0; r < BP_ALL_RUNS && !rc; r++) {
    bp_start start = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, 0};
    int started = 1, err = 0;
    for (int k = 0; k < threads; k++) jobs[k] = (bp_job){loop, iters, &start, 0};
    for (; started < threads; started++)
      if ((err = pthread_create(&th[started], NULL, bp_thread, &jobs[started])) != 0) break;
    pthread_mutex_lock(&start.mu);
    start.go = 1;
    pthread_cond_broadcast(&start.cv);
    pthread_mutex_unlock(&start.mu);
    t0 = bp_now();
    jobs[0].result = loop(iters);
    for (int k = 1; k < started; k++) pthread_join(th[k], NULL);
    dt = bp_now() - t0;
    for (int k = 0; k < started; k++) sink += jobs[k].result;
    if (started < threads) {
      errno = err;
      rc = -1;
      break;
    }
    double g = threads * iters * flops_per_iter / dt / 1e9;
    if (dt > 0 && g > out->all_gflops) out->all_gflops = g;
  }
  free(th);
  free(jobs);
  (void)sink;
  return rc;
}
