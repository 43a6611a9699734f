/*
 * The input pass of a network with an estimate (KernelMix, the default, and KernelAC),
 * hf_features_interleave, beside what bounds it, side by side in one run
 * (docs/PERFORMANCE.md, "KernelAC against Kernel"):
 *
 *   hf-interleave-bench SIZE[,SIZE...] ITERS
 *
 * For each size, a 4-spp frame of typical hair (a third of the samples
 * covered, every estimate in contract), float32 and binary16, planar as a
 * client sends it (samples, then estimate), ITERS times each of:
 *   interleave   hf_features_interleave: samples and estimate into one
 *                NHWC frame, checked, counted into the input statistics,
 *                each value of the input read once;
 *   check+copy   hf_features_scan over the samples, then a plain
 *                interleaving copy: the same work in two reads of the
 *                input, and without the estimate's check (what a client
 *                rewriting a shared-memory segment could slip past);
 *   copy         the plain interleaving copy alone: the floor.
 * Medians of the wall time and of the process's CPU time (all threads),
 * milliseconds. Prints the table with the command, the CPU model and the
 * date (bench_util.h).
 */
#define _GNU_SOURCE
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_util.h"
#include "hfcore.h"

enum { SPP = 4, NS = SPP * HF_FEATURES_PER_SAMPLE, CIN = NS + HF_ESTIMATE_CHANNELS };

/* The plain interleaving copy: [px][NS] then [px][3] into [px][CIN]. */
static void copy_interleave(const uint8_t *in, uint8_t *out, size_t px, size_t esz) {
  const uint8_t *est = in + px * NS * esz;
  for (size_t p = 0; p < px; p++) {
    memcpy(out + p * CIN * esz, in + p * NS * esz, NS * esz);
    memcpy(out + (p * CIN + NS) * esz, est + p * HF_ESTIMATE_CHANNELS * esz,
           HF_ESTIMATE_CHANNELS * esz);
  }
}

/* A planar frame of px pixels: each sample covered with probability 1/3
 * (alpha 0.2, features in range), else all zero; every estimate in
 * contract. */
static void make_frame(float *in, size_t px) {
  uint32_t s = 1;
  for (size_t p = 0; p < px; p++) {
    for (int k = 0; k < SPP; k++) {
      float *v = in + p * NS + k * HF_FEATURES_PER_SAMPLE;
      s = s * 1664525u + 1013904223u;
      int covered = (s >> 8) % 3 == 0;
      float c = (float)((s >> 9) & 0xffff) / 65536.0f;
      const float f[6] = {c, 0.3f, 0.2f, 0.5f, 0.1f, -0.1f};
      for (int i = 0; i < 6; i++) v[i] = covered ? f[i] : 0.0f;
    }
    float *e = in + px * NS + p * HF_ESTIMATE_CHANNELS;
    e[0] = 0.4f, e[1] = 0.2f, e[2] = 0.5f;
  }
}

int main(int argc, char **argv) {
  if (argc != 3) {
    fprintf(stderr, "usage: %s SIZE[,SIZE...] ITERS\n", argv[0]);
    return 2;
  }
  int iters = atoi(argv[2]);
  if (iters < 1 || iters > 10000) {
    fprintf(stderr, "ITERS must be 1 to 10000\n");
    return 2;
  }
  bench_print_header(argc, argv, NULL);
  printf("| pass | dtype | size | median ms | median CPU ms |\n|---|---|---|---:|---:|\n");
  char sizes[256];
  snprintf(sizes, sizeof sizes, "%s", argv[1]);
  double *wall = malloc(iters * sizeof *wall), *cpu = malloc(iters * sizeof *cpu);
  if (!wall || !cpu) return 1;
  for (char *tok = strtok(sizes, ","); tok; tok = strtok(NULL, ",")) {
    int w = 0, h = 0;
    if (sscanf(tok, "%dx%d", &w, &h) != 2 || w < 1 || h < 1 || w > 8192 || h > 8192) {
      fprintf(stderr, "SIZE %s: give WxH, each 1 to 8192\n", tok);
      return 2;
    }
    const size_t px = (size_t)w * h, n = px * CIN;
    float *in32 = malloc(n * 4), *out = malloc(n * 4);
    uint16_t *in16 = malloc(n * 2);
    if (!in32 || !out || !in16) {
      fprintf(stderr, "%s: out of memory\n", tok);
      return 1;
    }
    make_frame(in32, px);
    for (size_t i = 0; i < n; i++) in16[i] = hf_f32_to_f16(in32[i]);
    for (int dt = 0; dt < 2; dt++) {
      const hf_dtype dtype = dt ? HF_F16 : HF_F32;
      const void *in = dt ? (const void *)in16 : (const void *)in32;
      const size_t esz = dt ? 2 : 4;
      const char *names[3] = {"interleave", "check+copy", "copy"};
      for (int pass = 0; pass < 3; pass++) {
        for (int it = -1; it < iters; it++) {   /* one warm-up */
          hf_input_report r;
          hf_input_stats st;
          double t0 = bench_now_us(), c0 = bench_cpu_us();
          int rc = HF_OK;
          if (pass == 0) {
            rc = hf_features_interleave(in, dtype, w, h, SPP, out, &r, &st);
          } else {
            if (pass == 1) rc = hf_features_scan(in, dtype, w, h, SPP, &r, &st);
            copy_interleave(in, (uint8_t *)out, px, esz);
          }
          if (rc) {
            fprintf(stderr, "%s: %s\n", names[pass], hf_strerror(rc));
            return 1;
          }
          if (it >= 0) wall[it] = bench_now_us() - t0, cpu[it] = bench_cpu_us() - c0;
        }
        printf("| %s | %s | %dx%d | %.2f | %.2f |\n", names[pass], dt ? "f16" : "f32", w, h,
               bench_median(wall, iters) / 1e3, bench_median(cpu, iters) / 1e3);
      }
    }
    free(in32), free(out), free(in16);
  }
  free(wall), free(cpu);
  return 0;
}
