/* The line above a load tool's figures (docs/PERFORMANCE.md: every figure
 * with its command, machine and date): the command line as a shell takes
 * it back (a --token's value hidden), the CPU model and online cores, the
 * UTC date. Shared by `hairfilter load` and `hairfilter-load`. */
#ifndef HF_RUN_HEADER_H
#define HF_RUN_HEADER_H

typedef struct run_header {
  char command[4096];   /* prog, then each argument, quoted where a shell needs it */
  char cpu[128];        /* /proc/cpuinfo "model name", else the machine type */
  int cores;            /* online CPUs, 0 unknown */
  char date[32];        /* "2026-12-05T13:09:08Z", or "unknown" */
} run_header;

/* Fills h for prog followed by the argc arguments at argv. Never fails:
 * what cannot be read is "unknown" (the command is cut at 4095 bytes). */
void run_header_describe(const char *prog, int argc, char **argv, run_header *h);

#endif
