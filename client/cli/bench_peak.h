/* The machine a benchmark ran on, for `hairfilter bench`: the CPU's model
 * and vector flags, and its fp32 peak, measured.
 *
 * The peak is measured, not taken from a datasheet, because clocks under
 * vector load, the vector units' width and how many of them there are
 * differ between models of the same name (and a virtual machine's name says
 * little). Method: a loop of fused multiply-adds on the widest vectors the
 * CPU has (AVX-512, else AVX2 with FMA, else SSE2 multiplies and adds), on
 * BENCH_PEAK_CHAINS independent accumulators so that the FMA latency is
 * hidden and only the units' throughput counts; one thread alone, its
 * flops per second of its own CPU time (the rate of one core, whatever
 * other processes took of the core meanwhile), best of several short runs,
 * times the threads the cpu backend uses. The same loop on every thread at
 * once, in wall time, is reported beside it: what the machine gave at that
 * moment.
 *
 * Our own loop because no Debian package provides one as a library (the
 * STREAM-like tools measure memory; likwid-bench is not packaged for
 * Debian 12), and it is a few lines. */
#ifndef HF_BENCH_PEAK_H
#define HF_BENCH_PEAK_H

#include <stddef.h>

#define BENCH_PEAK_CHAINS 12

typedef struct bench_cpu {
  char model[128];            /* /proc/cpuinfo "model name", or "unknown" */
  int family, model_id;       /* "cpu family", "model"; -1 unknown */
  int online;                 /* online CPUs */
  char flags[256];            /* the vector flags it has, space-separated */
} bench_cpu;

typedef struct bench_peak {
  const char *isa;            /* "avx512f", "avx2+fma" or "sse2" */
  int lanes;                  /* fp32 values per vector */
  int fma;                    /* 1: fused multiply-add (2 flops), 0: mul + add */
  int threads;                /* what the peak is multiplied by */
  int runs;                   /* runs of the one-thread loop, best kept */
  double run_ms;              /* each run's length */
  double core_gflops;         /* one thread alone, per CPU second, best run */
  double all_gflops;          /* every thread at once, per wall second, best run */
  double peak_gflops;         /* core_gflops * threads */
} bench_peak;

/* Fills cpu from /proc/cpuinfo and sysconf; unknown fields stay "unknown"
 * or -1. Never fails. */
void bench_cpu_describe(bench_cpu *cpu);
/* Measures the fp32 peak for threads threads (1..256): 20 runs of about
 * 5 ms of CPU on one thread, then 10 of every thread at once (0.2 s or
 * more, as the machine's load allows).
 * Returns 0, or -1 (errno set) when the threads could not be started. */
int bench_peak_measure(int threads, bench_peak *out);
/* The threads the cpu backend runs on: the online CPUs, or OMP_NUM_THREADS
 * when set lower (as its OpenMP does). */
int bench_cpu_threads(void);

#endif /* HF_BENCH_PEAK_H */
