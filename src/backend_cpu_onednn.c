/*
 * cpu: the network on oneDNN (2.x C API), float32, NHWC activations.
 *
 * Choices, measured on oneDNN 2.6 (docs/PERFORMANCE.md):
 *   - Every activation is dense NHWC. With NHWC, oneDNN picks its brgemm
 *     convolutions; blocked layouts (nChw16c) were slower for the
 *     deconvolutions, and the 24- and 3-channel ends fell back to reference
 *     (loop) kernels.
 *   - Decoders are not oneDNN deconvolutions. oneDNN's stride-2 deconvolution
 *     ran at two thirds of the rate of the equivalent 1x1 convolution below,
 *     and at a small fraction of it for dec0's 3 output channels. A 4x4 stride-2 transposed convolution is
 *     a 1x1 convolution from each input pixel to its 16 taps x cout products
 *     (same multiply-adds), then a pass summing the four taps that reach each
 *     output pixel, adding the bias and the ReLU (od_taps_rows). That pass
 *     writes the next decoder's input whole, a row at a time: its left half
 *     from the taps, its right half copied from the encoder's output, which
 *     keeps a buffer of its own until then. So the concat costs no pass of
 *     its own. HF_CPU_DECONV=1 selects the deconvolution path for
 *     comparison (there the concat is two copies).
 *   - The encoder's half is copied, not written in place by the encoder
 *     through a sub-memory descriptor: oneDNN 2.6 has only reference kernels
 *     for strided destinations, tens of times slower than the copy.
 *   - ReLU is a post-op of the convolutions. On the deconvolution path it is
 *     a separate in-place eltwise: fused into an fp32 deconvolution it made
 *     that primitive about ten times slower.
 *   - The Kernel architecture's head is one 1x1 convolution over a buffer
 *     that dec0's tap pass fills with the hidden channels (ReLU included)
 *     and, in the same pass, the input; HF_CPU_HEAD=sum computes it as two
 *     convolutions summed (no copy) for comparison. Its output stage runs
 *     with the row-vectorised code of cpu_kernel_output.c;
 *     HF_CPU_KERNEL_REF=1 uses net_config.c's reference rows instead, for
 *     comparison.
 *   - A decoder's tap convolution and its pass run band by band (od_band):
 *     each thread computes the taps of a few input rows (512 KiB,
 *     HF_CPU_BAND_KB) with a 1x1 convolution of its own and sums them while
 *     they are in its cache, instead of the whole level's taps (32 MiB for
 *     dec1 at 512 x 512) going to memory and back. HF_CPU_BAND_KB=0 keeps
 *     the whole-tensor convolution and pass, for comparison.
 *   - A U-Net's dec0 pass writes the caller's aligned float32 frames with
 *     the output transform, so the output stage has nothing to do there.
 *   - float16 frames are read where they are (reads_f16): every pass that
 *     reads the input widens it a row or a band at a time into the
 *     thread's part of the plan's padded-input buffer, which halves leave
 *     unused otherwise (od_input). enc0 runs band by band (od_enc_band): each
 *     thread widens a band's input rows (2 MiB, HF_CPU_ENC_BAND_KB) and
 *     runs the band's convolution on them while they are in its
 *     cache, where widening the frame first wrote 100 MB of floats at
 *     1024 x 1024 and 4 spp for the convolution to read back.
 *     HF_CPU_ENC_BAND_KB=0 (and the head as two convolutions,
 *     HF_CPU_HEAD=sum, whose input part reads the whole input) widens the
 *     whole frame first, for comparison.
 *   - The out-of-contract check and the input statistics are made in
 *     enc0's bands too (model_run_scan), each band's rows scanned just
 *     before its convolution reads them, for halves and for aligned float32
 *     frames (those read in place, by band primitives, a frame's first
 *     band padded above): the frame comes from memory once, where the
 *     common check's pass before the run read all of it (25 MB at 512 x
 *     512 and 4 spp) only for enc0 to read it again. A frame with a bad
 *     sample stops after enc0 (HF_RUN_UNCLEAN) and backend.c runs it again
 *     on a sanitised copy.
 *   - The backend's own passes (taps, output stage) run on the OpenMP
 *     threads oneDNN runs on, rows split between them (od_parallel).
 *   - Weights are reordered once, at model_create, into the format oneDNN
 *     chooses (format_tag_any); a size whose primitives want another format
 *     gets a private copy in its plan.
 *
 * A plan holds the primitives of one (batch, padded size) and its buffers'
 * places (od_layout); plans are cached per model (least recently used
 * goes), so a run of a size seen before allocates nothing. The activations
 * themselves lie in one arena per device (od_dev), which every plan of
 * every model on it uses: runs on a device take turns under its lock, so
 * N variants and sizes keep the largest run's activations once, not N
 * times. The arena counts in the cached bytes of the model that ran last
 * (hf_model_cached_bytes, the daemon's STATS), shrinks with the plans that
 * use it and is unmapped with the last of them.
 */
#define _GNU_SOURCE /* mremap */
#include <omp.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include <dnnl.h>

#include "backend.h"

#define OD_PLAN_CACHE 4
/* Steps per plan: per level at most a conv, a deconv, a ReLU and two
 * copies, plus slack (the head's two steps). */
#define OD_MAX_STEPS (6 * HF_MAX_LEVELS)
#define OD_MAX_MEMS (16 * HF_MAX_LEVELS)

/* The kinds of layer primitives: an encoder convolution, a decoder as a
 * oneDNN deconvolution, a decoder's 1x1 convolution to its taps, or the
 * Kernel architecture's head (a 1x1 convolution): over the concatenation of
 * dec0's hidden channels and the input (OD_HEAD), or over each alone, the
 * input's part with the bias, the hidden part summed onto it (OD_HEAD_IN,
 * OD_HEAD_HID); and enc0 over a band of rows (OD_ENC_BAND: the row above
 * the band is in its source, so no padding above or below; OD_ENC_BAND_TOP
 * a frame's first band read where it lies, padded above as the whole
 * frame's convolution is). */
typedef enum od_kind {
  OD_ENC, OD_DEC, OD_TAPS, OD_HEAD, OD_HEAD_IN, OD_HEAD_HID, OD_ENC_BAND, OD_ENC_BAND_TOP
} od_kind;

#define OD_MAX_THREADS 64
#define OD_RANGES_PER_THREAD 8

/* The run's input as the passes that read it find it (enc0, the Kernel
 * head's input channels, the Kernel and Residual output stages): float32
 * frames of pw x ph pixels (f32: the plan's padded copy, or the caller's
 * aligned frames where they are), or the caller's float16 frames of width
 * x height (f16), widened a row at a time where a pass reads them
 * (od_in_row), so that no float32 copy of the frame is written. */
typedef struct od_input {
  const float *f32;             /* [batch][ph][pw][cin], or NULL */
  const uint16_t *f16;          /* [batch][height][width][cin], or NULL */
  int width, height, pw, ph, cin;
} od_input;

/* Row y of frame n as pw pixels of floats: where it lies (f32), or widened
 * into buf (pw * cin floats; hf_f16_to_f32_serial, the values of
 * hf_f16_to_f32), zero beyond the frame's width; all zero for a row
 * outside the frame (y < 0 or y >= height), as the padded copy has it. */
static const float *od_in_row(const od_input *in, int n, int y, float *buf) {
  const size_t row = (size_t)in->pw * in->cin, have = (size_t)in->width * in->cin;
  if (y < 0 || y >= in->height) {
    memset(buf, 0, row * sizeof *buf);
    return buf;
  }
  if (in->f32) return in->f32 + ((size_t)n * in->ph + y) * row;
  hf_f16_to_f32_serial(in->f16 + ((size_t)n * in->height + y) * have, buf, have);
  memset(buf + have, 0, (row - have) * sizeof *buf);
  return buf;
}

struct od_model;

/* The device: oneDNN's engine and streams, and the activation arena that
 * every plan of every model on it uses (od_arena_reserve): runs on one
 * device take turns (lock), so N variants or sizes hold one set of
 * activations, the largest, instead of N. */
typedef struct od_dev {
  pthread_mutex_t lock;         /* runs, plan changes and counts, one at a time */
  char *arena;                  /* activations (od_arena_reserve): arena_bytes */
  size_t arena_bytes, arena_span; /* usable, of arena_span reserved */
  struct od_model *arena_owner; /* the model whose cached bytes include it */
  struct od_model *models;      /* every model on the device (od_model.next) */
  dnnl_engine_t eng;
  dnnl_stream_t stream;
  int threads;                  /* for the backend's own passes */
  int start_threads;            /* HF_CPU_PASS_THREADS=start (od_parallel) */
  size_t band_bytes;            /* HF_CPU_BAND_KB: a tap band's size, 0 for none */
  size_t enc_band_bytes;        /* HF_CPU_ENC_BAND_KB: enc0's bands, 0 for none */
  dnnl_stream_t tstream[OD_MAX_THREADS]; /* each thread's, for banded taps */
} od_dev;

/* A step is a oneDNN primitive, a tap-summing pass or a copy into a concat
 * buffer. */
typedef enum od_step_type { OD_STEP_PRIM, OD_STEP_TAPS, OD_STEP_COPY, OD_STEP_BAND } od_step_type;

/* A decoder's tap pass. Its output pixel holds the cout summed channels,
 * then, when skip is set, the skip_ch channels of the same pixel of skip:
 * the encoder's half of a concat buffer, or the input beside the Kernel
 * head's hidden channels, copied in the same pass. */
typedef struct od_taps_pass {
  const float *taps;            /* [batch][h][w][16][cout] */
  int h, w, cout, relu;
  const float *bias;
  const float *zeros;           /* cout zeros, the taps outside the input */
  float *out;                   /* pixel (n, Y, X) at ((n 2h + Y) 2w + X) * stride */
  int stride;
  const float *skip;            /* [batch][2h][2w][skip_ch], or NULL */
  int skip_ch;
  int fin;                      /* the output transform too: out is the caller's
                                 * frames (od_model_run_locked) */
  const od_input *skip_in;      /* instead of skip, the input in halves: a row
                                 * widened into the thread's row (below) */
  float *rows;                  /* each thread's row, rows_floats apart */
  size_t rows_floats;
  uint16_t *out16;              /* with fin: the caller's float16 frames
                                 * [batch][2h][2w][3] instead of out; a row is
                                 * made in the thread's row16 and converted */
  float *row16;                 /* each thread's, row16_floats apart (>= 6w) */
  size_t row16_floats;
  uint64_t *guarded;            /* with fin: hf_output_guard applied to each
                                 * row as it is made, the pixels it changed
                                 * counted in [thread][batch]; NULL: not */
  int batch;
} od_taps_pass;

/* Copies dense [npix][ch] into [npix][stride] (a concat buffer's half). */
typedef struct od_copy_pass {
  const float *src;
  size_t npix;
  int ch, stride;
  float *dst;
} od_copy_pass;

/* A decoder's tap convolution and tap pass run band by band (OD_STEP_BAND).
 * The frame's bands of bh input rows are dealt out in chunks of consecutive
 * bands, a chunk to a thread as it comes free. For each band of its chunk
 * the thread computes the band's taps with a 1x1 convolution into one of
 * its two band buffers (small enough to stay in its core's cache) and sums
 * them into every output row they complete, with the last input row of the
 * band before, kept in the other buffer. The two output rows at a seam
 * between chunks (and at a frame's top and bottom) take taps from both
 * sides: each chunk leaves the terms of its first and last input rows in
 * part, and a second pass adds the two sides' terms together. Same sums as
 * the whole tap pass, in a different order only at those seams. */
typedef struct od_band {
  const float *src;             /* the decoder's input [batch][h][w][cin] */
  int cin, bh, nb;              /* rows per band; bands per frame, the last
                                 * of h - (nb - 1) bh rows */
  int chunk, nchunks;           /* bands per chunk; chunks per frame */
  dnnl_primitive_t prim[2];     /* bh rows; the last band's rows if fewer */
  dnnl_memory_t wmem[2];
  int owned[2];                 /* wmem[k] is a private copy */
  dnnl_memory_t *src_mem;       /* [thread][prim] */
  dnnl_memory_t *dst_mem;       /* [thread][prim][buffer] */
  float *part;                  /* [batch][nchunks][4][2w][cout]: terms of Y =
                                 * 2a, 2a - 1, 2b - 1, 2b of a chunk of rows [a, b) */
} od_band;

/* enc0 a band of bh output rows at a time (od_enc_band_run), over float16
 * frames or over aligned float32 frames that the run checks as it reads
 * them (model_run_scan). Halves: a thread widens the band's 2 bh + 1 input
 * rows (the row above included, zeros above and below the frame and beyond
 * its width) into its part of the plan's padded input buffer, which frames
 * of halves leave unused (thread t's from row t (2 bh + 1)), and runs the
 * band's convolution from there into enc0's output. Floats: the band's
 * convolution reads the caller's rows where they lie, a frame's first band
 * with the primitive padded above (prim[2]), so nothing is copied. Each
 * output pixel is the same sum of the same products as in the whole
 * frame's convolution: the implicit padding above the frame becomes a row
 * of zeros, whose products (+0 or -0) leave the sum as it is, and the left
 * and right padding stays implicit. */
typedef struct od_enc_band {
  int bh, nb;                   /* output rows per band; bands per frame, the
                                 * last of ph / 2 - (nb - 1) bh rows */
  int nthreads;                 /* threads whose rows fit in the plan's in */
  dnnl_primitive_t prim[3];     /* bh rows; the last band's rows if fewer;
                                 * a first band of bh rows padded above */
  dnnl_memory_t wmem[3];
  int owned[3];                 /* wmem[k] is a private copy */
  dnnl_memory_t *src_mem;       /* [thread][prim], over the band's rows */
  dnnl_memory_t *dst_mem;       /* [thread][prim], set to the band's rows */
} od_enc_band;

typedef struct od_step {
  od_step_type type;
  dnnl_primitive_t prim;
  int nargs;
  dnnl_exec_arg_t args[5];
  od_taps_pass taps;
  od_copy_pass copy;
  od_band *band;
} od_step;

typedef struct od_plan {
  int batch, pw, ph;
  char *arena;                  /* the arena its buffers point into, and the */
  size_t need;                  /* bytes of it they take (od_layout.total) */
  uint64_t stamp;               /* last use, for eviction */
  size_t bytes;                 /* host memory of its own: weight copies, scratchpads */
  size_t scratch_bytes;         /* of which the primitives' scratchpad */
  float *in;                    /* padded input [batch][ph][pw][cin] */
  dnnl_memory_t in_mem;         /* enc0's source: in, or the caller's frames */
  od_input input;               /* the run's input, as its readers see it */
  int enc0_step;                /* enc0's step: od_enc_band_run for halves */
  int ebh;                      /* its band rows for halves, 0: none (od_layout) */
  od_enc_band *eband;           /* made on the first frame of halves */
  float *out;                   /* raw output [batch][ph][pw][out_channels] */
  float *head_in;               /* the head's input: concat(ReLU(dec0), input) for
                                 * OD_HEAD, ReLU(dec0) alone for OD_HEAD_HID */
  int in_skip_step;             /* the step copying the input into head_in, or -1 */
  int out_step;                 /* dec0's tap pass when it writes the output, or -1 */
  float *sums;                  /* Kernel output stage: per-pixel sums and the */
  float *fin;                   /* f32 result, [batch][ph][pw][3] each, and */
  float *kscratch;              /* each thread's scratch (hf_cpu_kernel_scratch) */
  void *enc[HF_MAX_LEVELS];     /* encoder outputs, kept for their concat */
  void *taps;                   /* a decoder's taps (or deconvolution output) */
  float *zeros;                 /* the largest decoder's cout zeros */
  void *cat[HF_MAX_LEVELS];     /* decoder inputs concat(dec{i+1}, enc{i}) */
  void *scratch;                /* shared by every primitive (run in order) */
  float *tband;                 /* each thread's two band buffers, tband_floats each */
  size_t tband_floats;
  float *part;                  /* the seams' terms, for one level at a time */
  void *tscratch;               /* each thread's scratchpad for band primitives, */
  size_t tscratch_each;         /* this many bytes apart */
  dnnl_memory_t tscratch_mem[OD_MAX_THREADS];
  int nthreads;                 /* threads the band memories were made for */
  int nsteps;
  od_step steps[OD_MAX_STEPS];
  int nmems;
  dnnl_memory_t mems[OD_MAX_MEMS];
} od_plan;

typedef struct od_model {
  od_dev *dev;
  struct od_model *next;        /* in dev->models */
  hf_weights *w;                /* private copy, PyTorch layouts */
  /* Weights in oneDNN's chosen formats, NULL until known. */
  dnnl_memory_t enc_w[HF_MAX_LEVELS], dec_w[HF_MAX_LEVELS], taps_w[HF_MAX_LEVELS];
  /* Decoders computed as taps, and their weights as [16 * cout][cin]. */
  int use_taps[HF_MAX_LEVELS];
  float *taps_user[HF_MAX_LEVELS];
  dnnl_memory_t enc_b[HF_MAX_LEVELS], dec_b[HF_MAX_LEVELS];
  /* The head (HF_ARCH_KERNEL with kernel_hidden > 0): one convolution over
   * the concatenation, or two summed (head_split: the weights' input and
   * hidden columns, [out][cin] and [out][hidden]); by od_kind - OD_HEAD. */
  int head_sum;
  int kernel_ref;               /* HF_CPU_KERNEL_REF: the reference output stage */
  dnnl_memory_t head_w[3], head_b;
  float *head_split[3];
  od_plan *plans[OD_PLAN_CACHE];
  uint64_t clock;
} od_model;

/* ---- errors --------------------------------------------------------------- */

static const char *od_status_name(dnnl_status_t s) {
  switch (s) {
  case dnnl_success: return "success";
  case dnnl_out_of_memory: return "out of memory";
  case dnnl_invalid_arguments: return "invalid arguments";
  case dnnl_unimplemented: return "unimplemented";
  case dnnl_iterator_ends: return "iterator ends";
  case dnnl_runtime_error: return "runtime error";
  case dnnl_not_required: return "not required";
  default: return "unknown status";
  }
}

/* Logs a failed oneDNN call and maps it to an hfcore error: out-of-memory
 * stays HF_ENOMEM, everything else is HF_EBACKEND. */
static int od_report(dnnl_status_t s, const char *call, int line) {
  fprintf(stderr, "hfcore cpu: %s failed: %s (backend_cpu_onednn.c:%d)\n", call,
          od_status_name(s), line);
  return s == dnnl_out_of_memory ? HF_ENOMEM : HF_EBACKEND;
}

#define OD_TRY(call)                                                      \
  do {                                                                    \
    dnnl_status_t od_s_ = (call);                                         \
    if (od_s_ != dnnl_success) {                                          \
      rc = od_report(od_s_, #call, __LINE__);                             \
      goto fail;                                                          \
    }                                                                     \
  } while (0)

#define OD_RC(expr)                                                       \
  do {                                                                    \
    rc = (expr);                                                          \
    if (rc) goto fail;                                                    \
  } while (0)

/* ---- device --------------------------------------------------------------- */

static int od_probe(char *why, size_t whylen) {
  if (dnnl_engine_get_count(dnnl_cpu) < 1) {
    if (why && whylen) snprintf(why, whylen, "oneDNN reports no CPU engine");
    return HF_EUNAVAILABLE;
  }
  return HF_OK;
}

/* As many threads as oneDNN's OpenMP would use: the online cores, or
 * OMP_NUM_THREADS when that is set lower. */
static int od_thread_count(void) {
  long n = sysconf(_SC_NPROCESSORS_ONLN);
  const char *omp = getenv("OMP_NUM_THREADS");
  if (omp && atol(omp) > 0 && atol(omp) < n) n = atol(omp);
  return n < 1 ? 1 : n > OD_MAX_THREADS ? OD_MAX_THREADS : (int)n;
}

/* The bytes of one band's taps (HF_CPU_BAND_KB, in KiB; 0 runs each tap
 * convolution whole, then its pass, for comparison). The default, 512 KiB,
 * keeps a band in a core's L2 cache beside the band's input rows and
 * output rows (docs/PERFORMANCE.md). */
static size_t od_band_bytes(void) {
  const char *e = getenv("HF_CPU_BAND_KB");
  if (!e || !*e) return (size_t)512 << 10;
  long kb = atol(e);
  return kb > 0 ? (size_t)kb << 10 : 0;
}

/* The bytes of the widened input rows of one of enc0's bands over halves
 * (HF_CPU_ENC_BAND_KB, in KiB; 0 widens each frame of halves whole before
 * enc0, for comparison). The default, four times a decoder band's (2 MiB
 * with HF_CPU_BAND_KB's default; none when that is 0): each band's
 * convolution costs a call of the primitive beyond its arithmetic, so
 * fewer, larger bands than the decoders' (docs/PERFORMANCE.md, "float16
 * read where it lies"). */
static size_t od_enc_band_bytes(size_t band_bytes) {
  const char *e = getenv("HF_CPU_ENC_BAND_KB");
  if (!e || !*e) return band_bytes <= SIZE_MAX / 4 ? 4 * band_bytes : band_bytes;
  long kb = atol(e);
  return kb > 0 ? (size_t)kb << 10 : 0;
}

/* Every primitive the backend makes lives in a plan (od_plan), and plans
 * are counted in hf_model_cached_bytes and freed within the daemon's
 * memory budget. oneDNN's own primitive cache keeps primitives and the
 * code it generated for their shapes after the plan that made them is
 * gone: memory no budget sees. At its default of 1024 entries it grows
 * with every new frame size a client sends (docs/SERVER.md has the
 * measurement: 88 MiB resident under --max-memory-mb 48 after 900 sizes);
 * off, the bands of one plan, which share shapes, each generate their
 * code again, and a plan's first frame takes longer. 128 entries keep the
 * sharing and bound what is kept (36 MiB after the same 900 sizes). An
 * operator's size in the environment
 * (ONEDNN_PRIMITIVE_CACHE_CAPACITY, or DNNL_, which oneDNN 2 also reads)
 * is left as it is. docs/SERVER.md, "Memory". */
#define OD_PRIMITIVE_CACHE 128

static int od_primitive_cache_bound(void) {
  const char *a = getenv("ONEDNN_PRIMITIVE_CACHE_CAPACITY");
  const char *b = getenv("DNNL_PRIMITIVE_CACHE_CAPACITY");
  if ((a && *a) || (b && *b)) return HF_OK;
  dnnl_status_t s = dnnl_set_primitive_cache_capacity(OD_PRIMITIVE_CACHE);
  return s == dnnl_success ? HF_OK : od_report(s, "dnnl_set_primitive_cache_capacity", __LINE__);
}

static int od_open(void **out, char *why, size_t whylen) {
  int rc;
  if ((rc = od_primitive_cache_bound()) != HF_OK) {
    if (why && whylen) snprintf(why, whylen, "oneDNN's primitive cache could not be bounded");
    return rc;
  }
  od_dev *d = calloc(1, sizeof *d);
  if (!d) return HF_ENOMEM;
  if (pthread_mutex_init(&d->lock, NULL)) {
    free(d);
    return HF_ENOMEM;
  }
  OD_TRY(dnnl_engine_create(&d->eng, dnnl_cpu, 0));
  OD_TRY(dnnl_stream_create(&d->stream, d->eng, dnnl_stream_default_flags));
  d->threads = od_thread_count();
  for (int t = 0; t < d->threads; t++)
    OD_TRY(dnnl_stream_create(&d->tstream[t], d->eng, dnnl_stream_default_flags));
  const char *e = getenv("HF_CPU_PASS_THREADS");
  d->start_threads = e && !strcmp(e, "start");
  d->band_bytes = od_band_bytes();
  d->enc_band_bytes = od_enc_band_bytes(d->band_bytes);
  *out = d;
  return HF_OK;
fail:
  if (why && whylen) snprintf(why, whylen, "oneDNN CPU engine could not be created");
  for (int t = 0; t < OD_MAX_THREADS; t++)
    if (d->tstream[t]) dnnl_stream_destroy(d->tstream[t]);
  if (d->stream) dnnl_stream_destroy(d->stream);
  if (d->eng) dnnl_engine_destroy(d->eng);
  pthread_mutex_destroy(&d->lock);
  free(d);
  return rc;
}

static void od_close(void *p) {
  od_dev *d = p;
  if (!d) return;
  for (int t = 0; t < d->threads; t++) dnnl_stream_destroy(d->tstream[t]);
  dnnl_stream_destroy(d->stream);
  dnnl_engine_destroy(d->eng);
  if (d->arena) munmap(d->arena, d->arena_span);
  pthread_mutex_destroy(&d->lock);
  free(d);
}

/* ---- descriptors ---------------------------------------------------------- */

static int od_size_ok(int64_t n, int64_t c, int64_t h, int64_t w) {
  /* Fits a size_t byte count of floats with room to spare. */
  return n > 0 && c > 0 && h > 0 && w > 0 && n * c <= INT64_MAX / 4 / h / w;
}

static int od_nhwc(dnnl_memory_desc_t *md, int n, int c, int h, int w) {
  dnnl_dims_t d = {n, c, h, w};
  int rc = HF_OK;
  if (!od_size_ok(n, c, h, w)) return HF_ERANGE;
  OD_TRY(dnnl_memory_desc_init_by_tag(md, 4, d, dnnl_f32, dnnl_nhwc));
fail:
  return rc;
}

/* Creates the primitive descriptor of one layer between src and dst, with
 * weights and scratchpad formats left to oneDNN: OD_ENC a 3x3 stride-2
 * pad-1 convolution with fused ReLU (OD_ENC_BAND the same, padded left and
 * right only, OD_ENC_BAND_TOP left, right and above); OD_DEC a 4x4 stride-2 pad-1
 * deconvolution (its ReLU is a separate primitive); OD_TAPS a 1x1
 * convolution without bias or ReLU (the tap pass adds them); OD_HEAD and
 * OD_HEAD_IN 1x1 convolutions with bias, OD_HEAD_HID one without, adding
 * its result to what dst holds (a sum post-op). */
static int od_layer_pd(od_dev *dev, od_kind kind, const dnnl_memory_desc_t *src,
                       const dnnl_memory_desc_t *dst, int cin, int cout,
                       dnnl_primitive_desc_t *pd) {
  const int enc = kind == OD_ENC || kind == OD_ENC_BAND || kind == OD_ENC_BAND_TOP;
  int rc = HF_OK, k = kind == OD_DEC ? 4 : enc ? 3 : 1;
  int deconv = kind == OD_DEC;
  dnnl_memory_desc_t wmd, bmd;
  dnnl_dims_t wd = {cout, cin, k, k}, bd = {cout};
  dnnl_dims_t strides = {2, 2}, pad = {1, 1}, one = {1, 1}, zero = {0, 0};
  dnnl_dims_t enc_pad = {kind == OD_ENC_BAND ? 0 : 1, 1};
  dnnl_dims_t enc_pad_r = {kind == OD_ENC_BAND || kind == OD_ENC_BAND_TOP ? 0 : 1, 1};
  dnnl_primitive_attr_t attr = NULL;
  dnnl_post_ops_t po = NULL;
  *pd = NULL;
  OD_TRY(dnnl_memory_desc_init_by_tag(&wmd, 4, wd, dnnl_f32, dnnl_format_tag_any));
  OD_TRY(dnnl_memory_desc_init_by_tag(&bmd, 1, bd, dnnl_f32, dnnl_x));
  OD_TRY(dnnl_primitive_attr_create(&attr));
  OD_TRY(dnnl_primitive_attr_set_scratchpad_mode(attr, dnnl_scratchpad_mode_user));
  if (deconv) {
    dnnl_deconvolution_desc_t dd;
    OD_TRY(dnnl_deconvolution_forward_desc_init(&dd, dnnl_forward_inference,
                                                dnnl_deconvolution_direct, src, &wmd, &bmd,
                                                dst, strides, pad, pad));
    OD_TRY(dnnl_primitive_desc_create(pd, &dd, attr, dev->eng, NULL));
  } else if (!enc) {
    /* Taps: no bias, it is added once per output pixel, not per tap. */
    dnnl_convolution_desc_t cd;
    int bias = kind == OD_HEAD || kind == OD_HEAD_IN;
    if (kind == OD_HEAD_HID) {
      OD_TRY(dnnl_post_ops_create(&po));
      OD_TRY(dnnl_post_ops_append_sum(po, 1.0f));
      OD_TRY(dnnl_primitive_attr_set_post_ops(attr, po));
    }
    OD_TRY(dnnl_convolution_forward_desc_init(&cd, dnnl_forward_inference,
                                              dnnl_convolution_direct, src, &wmd,
                                              bias ? &bmd : NULL, dst, one, zero, zero));
    OD_TRY(dnnl_primitive_desc_create(pd, &cd, attr, dev->eng, NULL));
  } else {
    dnnl_convolution_desc_t cd;
    OD_TRY(dnnl_post_ops_create(&po));
    OD_TRY(dnnl_post_ops_append_eltwise(po, 1.0f, dnnl_eltwise_relu, 0.0f, 0.0f));
    OD_TRY(dnnl_primitive_attr_set_post_ops(attr, po));
    OD_TRY(dnnl_convolution_forward_desc_init(&cd, dnnl_forward_inference,
                                              dnnl_convolution_direct, src, &wmd, &bmd, dst,
                                              strides, enc_pad, enc_pad_r));
    OD_TRY(dnnl_primitive_desc_create(pd, &cd, attr, dev->eng, NULL));
  }
fail:
  if (po) dnnl_post_ops_destroy(po);
  if (attr) dnnl_primitive_attr_destroy(attr);
  return rc;
}

/* Reorders src_mem into a new memory of layout md (allocated by oneDNN). */
static int od_reorder_new(od_dev *dev, dnnl_memory_t src_mem, const dnnl_memory_desc_t *md,
                          dnnl_memory_t *out) {
  int rc = HF_OK;
  const dnnl_memory_desc_t *smd;
  dnnl_primitive_desc_t pd = NULL;
  dnnl_primitive_t prim = NULL;
  *out = NULL;
  OD_TRY(dnnl_memory_get_memory_desc(src_mem, &smd));
  OD_TRY(dnnl_memory_create(out, md, dev->eng, DNNL_MEMORY_ALLOCATE));
  OD_TRY(dnnl_reorder_primitive_desc_create(&pd, smd, dev->eng, md, dev->eng, NULL));
  OD_TRY(dnnl_primitive_create(&prim, pd));
  dnnl_exec_arg_t args[2] = {{DNNL_ARG_FROM, src_mem}, {DNNL_ARG_TO, *out}};
  OD_TRY(dnnl_primitive_execute(prim, dev->stream, 2, args));
  OD_TRY(dnnl_stream_wait(dev->stream));
fail:
  if (prim) dnnl_primitive_destroy(prim);
  if (pd) dnnl_primitive_desc_destroy(pd);
  if (rc && *out) {
    dnnl_memory_destroy(*out);
    *out = NULL;
  }
  return rc;
}

/* Input and output channels of layer i of a kind (the head's: i is 0). */
static void od_layer_dims(const hf_net_config *c, od_kind kind, int i, int *cin, int *cout) {
  switch (kind) {
  case OD_ENC:
  case OD_ENC_BAND:
  case OD_ENC_BAND_TOP: *cin = hf_enc_in(c, i), *cout = hf_enc_out(c, i); break;
  case OD_DEC: *cin = hf_dec_in(c, i), *cout = hf_dec_out(c, i); break;
  case OD_TAPS: *cin = hf_dec_in(c, i), *cout = 16 * hf_dec_out(c, i); break;
  case OD_HEAD: *cin = hf_head_in(c), *cout = c->out_channels; break;
  case OD_HEAD_IN: *cin = c->in_channels, *cout = c->out_channels; break;
  case OD_HEAD_HID: *cin = c->kernel_hidden, *cout = c->out_channels; break;
  }
}

/* The weights of one layer in the layout md: the model's copy when it
 * matches (or when the model has none yet and keeps this one), else a new
 * memory the caller owns (*owned = 1). */
static int od_weights_for(od_model *m, od_kind kind, int i, const dnnl_memory_desc_t *md,
                          dnnl_memory_t *out, int *owned) {
  if (kind == OD_ENC_BAND || kind == OD_ENC_BAND_TOP) kind = OD_ENC; /* the same weights */
  int rc = HF_OK, deconv = kind == OD_DEC, head = kind >= OD_HEAD;
  const hf_net_config *c = &m->w->cfg;
  dnnl_memory_t *slot = head ? &m->head_w[kind - OD_HEAD]
                        : kind == OD_TAPS ? &m->taps_w[i] : deconv ? &m->dec_w[i] : &m->enc_w[i];
  dnnl_memory_t user = NULL;
  *owned = 0;
  if (*slot) {
    const dnnl_memory_desc_t *have;
    OD_TRY(dnnl_memory_get_memory_desc(*slot, &have));
    if (dnnl_memory_desc_equal(have, md)) {
      *out = *slot;
      return HF_OK;
    }
  }
  /* PyTorch layouts: Conv2d [out][in][kh][kw] is oihw; ConvTranspose2d
   * [in][out][kh][kw] is iohw in oneDNN's (out, in) dimension order. */
  int cin, cout, k = kind == OD_DEC ? 4 : kind == OD_ENC ? 3 : 1;
  od_layer_dims(c, kind, i, &cin, &cout);
  dnnl_dims_t wd = {cout, cin, k, k};
  dnnl_memory_desc_t umd;
  float *host = kind == OD_HEAD ? m->w->head_w
                : head          ? m->head_split[kind - OD_HEAD]
                : kind == OD_TAPS ? m->taps_user[i] : deconv ? m->w->dec_w[i] : m->w->enc_w[i];
  OD_TRY(dnnl_memory_desc_init_by_tag(&umd, 4, wd, dnnl_f32, deconv ? dnnl_iohw : dnnl_oihw));
  OD_TRY(dnnl_memory_create(&user, &umd, m->dev->eng, host));
  OD_RC(od_reorder_new(m->dev, user, md, out));
  if (!*slot)
    *slot = *out;
  else
    *owned = 1;
fail:
  if (user) dnnl_memory_destroy(user);
  return rc;
}

/* ---- decoders as taps ---------------------------------------------------- */

/* dec{i}'s weights, PyTorch [cin][cout][4][4], as a 1x1 convolution's
 * [(ky * 4 + kx) * cout + o][cin]: output channel t of the convolution at
 * input pixel (y, x) is what tap (ky, kx) of channel o adds to output pixel
 * (2y - 1 + ky, 2x - 1 + kx). */
static int od_taps_weights(od_model *m, int l) {
  const hf_net_config *c = &m->w->cfg;
  int cin = hf_dec_in(c, l), cout = hf_dec_out(c, l);
  m->taps_user[l] = malloc((size_t)16 * cout * cin * sizeof(float));
  if (!m->taps_user[l]) return HF_ENOMEM;
  const float *wt = m->w->dec_w[l];
  for (int i = 0; i < cin; i++)
    for (int o = 0; o < cout; o++)
      for (int k = 0; k < 16; k++)
        m->taps_user[l][((size_t)k * cout + o) * cin + i] = wt[((size_t)i * cout + o) * 16 + k];
  return HF_OK;
}

/* The tap passes carry HF_CPU_CLONES (backend.h): dec1's at 512 x 512 took
 * 4.1 ms of CPU with AVX-512 against 5.5 ms with SSE2 (docs/PERFORMANCE.md). */

/* o = ReLU(bias + a + b + c + d), the terms added in that order. */
static inline void od_sum4(float *restrict o, const float *restrict a, const float *restrict b,
                           const float *restrict c, const float *restrict d,
                           const float *restrict bias, int n, int relu) {
  if (relu) {
#pragma omp simd
    for (int ch = 0; ch < n; ch++) {
      float v = bias[ch] + a[ch] + b[ch] + c[ch] + d[ch];
      o[ch] = v < 0 ? 0 : v;
    }
  } else {
#pragma omp simd
    for (int ch = 0; ch < n; ch++) o[ch] = bias[ch] + a[ch] + b[ch] + c[ch] + d[ch];
  }
}

/* One output row of a tap pass: pixel X of o (ostride floats apart) gets
 * bias + taps ky0 of input row r0 + taps ky1 of input row r1, the ReLU if
 * relu, hf_output_transform if fin, then the skip channels of sk beside
 * them (when sk is set). Output
 * column X = 2q takes taps kx = 1 of input column q and kx = 3 of column
 * q - 1; X = 2q + 1 takes kx = 2 of column q and kx = 0 of column q + 1. A
 * tap outside the input (r1 NULL, or a column outside) reads zeros, so that
 * every pixel is the same four-term sum. */
static inline __attribute__((always_inline)) void
od_taps_line_c(const od_taps_pass *t, const float *r0, int ky0, const float *r1, int ky1, float *o,
               int ostride, const float *bias, int relu, int fin, const float *sk, const int C) {
  const int T = 16 * C, w = t->w, E = t->skip_ch;
  for (int X = 0; X < 2 * w; X++, o += ostride) {
    const int q = X >> 1, px = X & 1;
    const int kx0 = px ? 2 : 1, kx1 = px ? 0 : 3, x1 = px ? q + 1 : q - 1;
    const int has_x1 = x1 >= 0 && x1 < w;
    const float *a = r0 + (size_t)q * T + (ky0 * 4 + kx0) * C;
    const float *b = has_x1 ? r0 + (size_t)x1 * T + (ky0 * 4 + kx1) * C : t->zeros;
    const float *c = r1 ? r1 + (size_t)q * T + (ky1 * 4 + kx0) * C : t->zeros;
    const float *d = r1 && has_x1 ? r1 + (size_t)x1 * T + (ky1 * 4 + kx1) * C : t->zeros;
    od_sum4(o, a, b, c, d, bias, C, relu);
    if (fin) hf_output_transform(o);
    if (sk) {
      const float *restrict s = sk + (size_t)X * E;
      float *restrict e = o + C;
#pragma omp simd
      for (int k = 0; k < E; k++) e[k] = s[k];
    }
  }
}

/* od_taps_line_c for three dense output channels (dec0 of the U-Net and
 * Residual architectures), two output pixels per input column q: X = 2q
 * from taps kx = 1 of column q and kx = 3 of q - 1, X = 2q + 1 from kx = 2
 * of q and kx = 0 of q + 1, the same terms added in the same order. A
 * column outside reads zeros (t->zeros holds at least 12). */
static inline __attribute__((always_inline)) void
od_taps_line3(const od_taps_pass *t, const float *r0, int ky0, const float *r1, int ky1, float *o,
              const float *bias, int relu, int fin) {
  const int w = t->w;
  const float *z = t->zeros;
  for (int q = 0; q < w; q++, o += 6) {
    const float *a = r0 + (size_t)q * 48 + ky0 * 12;
    const float *al = q > 0 ? a - 48 : z, *ar = q < w - 1 ? a + 48 : z;
    const float *b = r1 ? r1 + (size_t)q * 48 + ky1 * 12 : z;
    const float *bl = r1 && q > 0 ? b - 48 : z, *br = r1 && q < w - 1 ? b + 48 : z;
    for (int ch = 0; ch < 3; ch++) {
      float e = bias[ch] + a[3 + ch] + al[9 + ch] + b[3 + ch] + bl[9 + ch];
      float f = bias[ch] + a[6 + ch] + ar[ch] + b[6 + ch] + br[ch];
      o[ch] = relu && e < 0 ? 0 : e;
      o[3 + ch] = relu && f < 0 ? 0 : f;
    }
    if (fin) hf_output_transform(o), hf_output_transform(o + 3);
  }
}

/* od_taps_line_c, with dec0's three dense output channels taken two pixels
 * at a time (od_taps_line3), other counts by the channel loop. */
HF_CPU_CLONES static void od_taps_line(const od_taps_pass *t, const float *r0, int ky0,
                                   const float *r1, int ky1, float *o, int ostride,
                                   const float *bias, int relu, int fin, const float *sk) {
  if (t->cout == 3 && ostride == 3 && !sk)
    od_taps_line3(t, r0, ky0, r1, ky1, o, bias, relu, fin);
  else if (t->cout == 3)
    od_taps_line_c(t, r0, ky0, r1, ky1, o, ostride, bias, relu, fin, sk, 3);
  else
    od_taps_line_c(t, r0, ky0, r1, ky1, o, ostride, bias, relu, fin, sk, t->cout);
}

/* Output row Y of frame n of a tap pass, and the skip channels beside it. */
static float *od_taps_out_row(const od_taps_pass *t, int n, int Y) {
  return t->out + ((size_t)n * 2 * t->h + Y) * 2 * t->w * t->stride;
}

/* Where thread `thread` makes output row Y of frame n: the row itself, or
 * for float16 frames its row buffer, converted by od_taps_row_done. */
static float *od_taps_dst(const od_taps_pass *t, int n, int Y, int thread) {
  return t->out16 ? t->row16 + (size_t)thread * t->row16_floats : od_taps_out_row(t, n, Y);
}

/* Row Y of frame n, made at dst by od_taps_dst on thread `thread`, into the
 * caller's float16 frames, and through the output guard where the run asks
 * for it (while the row is still in the cache). */
static void od_taps_row_done(const od_taps_pass *t, int n, int Y, float *dst, int thread) {
  const size_t row = (size_t)2 * t->w * 3;
  uint16_t *o16 = t->out16 ? t->out16 + ((size_t)n * 2 * t->h + Y) * row : NULL;
  if (o16) hf_f32_to_f16_serial(dst, o16, row);
  if (t->guarded)
    t->guarded[(size_t)thread * t->batch + n] +=
        o16 ? hf_output_guard_serial(o16, HF_F16, 2 * (size_t)t->w)
            : hf_output_guard_serial(dst, HF_F32, 2 * (size_t)t->w);
}

/* The skip channels of output row Y of frame n on thread `thread`, whose
 * rows buffer holds them when they are widened from halves. */
static const float *od_taps_skip_row(const od_taps_pass *t, int n, int Y, int thread) {
  if (t->skip_in) return od_in_row(t->skip_in, n, Y, t->rows + (size_t)thread * t->rows_floats);
  return t->skip ? t->skip + ((size_t)n * 2 * t->h + Y) * 2 * t->w * t->skip_ch : NULL;
}

/* Sums the taps into output row Y of frame n, adds the bias, applies the
 * ReLU if asked, and copies the skip channels beside them. Output row
 * Y = 2m takes taps ky = 1 of input row m and ky = 3 of row m - 1; Y = 2m + 1
 * takes ky = 2 of row m and ky = 0 of row m + 1. */
static void od_taps_row(const od_taps_pass *t, int n, int Y, int thread) {
  const int T = 16 * t->cout, h = t->h, w = t->w;
  const int m = Y >> 1, py = Y & 1;
  const int ky0 = py ? 2 : 1, ky1 = py ? 0 : 3, y1 = py ? m + 1 : m - 1;
  const float *r0 = t->taps + ((size_t)n * h + m) * w * T;
  const float *r1 = y1 >= 0 && y1 < h ? t->taps + ((size_t)n * h + y1) * w * T : NULL;
  float *dst = od_taps_dst(t, n, Y, thread);
  od_taps_line(t, r0, ky0, r1, ky1, dst, t->stride, t->bias, t->relu, t->fin,
               od_taps_skip_row(t, n, Y, thread));
  od_taps_row_done(t, n, Y, dst, thread);
}

static void od_taps_rows(const od_taps_pass *t, int thread, size_t row0, size_t row1) {
  for (size_t row = row0; row < row1; row++)
    od_taps_row(t, (int)(row / (2 * t->h)), (int)(row % (2 * t->h)), thread);
}

/* ---- plans ---------------------------------------------------------------- */

/* What a banded step (od_band, od_enc_band) owns: its two primitives,
 * their weights where private (owned), and nsrc and ndst memories (NULL
 * entries, or arrays, where made only in part). */
static void od_band_prims_free(int nprim, dnnl_primitive_t *prim, dnnl_memory_t *wmem,
                               const int *owned, dnnl_memory_t *src, int nsrc, dnnl_memory_t *dst,
                               int ndst) {
  for (int k = 0; k < nprim; k++) {
    if (prim[k]) dnnl_primitive_destroy(prim[k]);
    if (owned[k]) dnnl_memory_destroy(wmem[k]);
  }
  for (int k = 0; src && k < nsrc; k++)
    if (src[k]) dnnl_memory_destroy(src[k]);
  for (int k = 0; dst && k < ndst; k++)
    if (dst[k]) dnnl_memory_destroy(dst[k]);
  free(src);
  free(dst);
}

static void od_band_free(od_band *b, int nthreads) {
  if (!b) return;
  od_band_prims_free(2, b->prim, b->wmem, b->owned, b->src_mem, 2 * nthreads, b->dst_mem,
                     4 * nthreads);
  free(b);
}

static void od_enc_band_free(od_enc_band *b, int nthreads) {
  if (!b) return;
  od_band_prims_free(3, b->prim, b->wmem, b->owned, b->src_mem, 3 * nthreads, b->dst_mem,
                     3 * nthreads);
  free(b);
}

static void od_plan_free(od_plan *p) {
  if (!p) return;
  od_enc_band_free(p->eband, p->nthreads);
  for (int s = 0; s < p->nsteps; s++) {
    if (p->steps[s].type == OD_STEP_PRIM) dnnl_primitive_destroy(p->steps[s].prim);
    if (p->steps[s].type == OD_STEP_BAND) od_band_free(p->steps[s].band, p->nthreads);
  }
  for (int k = 0; k < p->nmems; k++) dnnl_memory_destroy(p->mems[k]);
  for (int t = 0; t < OD_MAX_THREADS; t++)
    if (p->tscratch_mem[t]) dnnl_memory_destroy(p->tscratch_mem[t]);
  /* Activations are the arena's. */
  free(p->tscratch);
  free(p->zeros);
  free(p->scratch);
  free(p);
}

/* Allocates n bytes, 64-byte aligned. */
static int od_alloc_bytes(size_t n, void **buf) {
  size_t r = (n + 63) & ~(size_t)63;
  if (r < n) return HF_ERANGE;
  *buf = aligned_alloc(64, r ? r : 64);
  if (!*buf) return HF_ENOMEM;
  return HF_OK;
}

/* Allocates a buffer of md's size. */
static int od_alloc(const dnnl_memory_desc_t *md, void **buf) {
  return od_alloc_bytes(dnnl_memory_desc_get_size(md), buf);
}

/* A memory object over buf, owned by the plan. */
static int od_mem(od_plan *p, od_dev *dev, const dnnl_memory_desc_t *md, void *buf,
                  dnnl_memory_t *out) {
  int rc = HF_OK;
  if (p->nmems >= OD_MAX_MEMS) return HF_ERANGE;
  OD_TRY(dnnl_memory_create(out, md, dev->eng, buf));
  p->mems[p->nmems++] = *out;
fail:
  return rc;
}

static int od_add_step(od_plan *p, dnnl_primitive_t prim, int nargs, const dnnl_exec_arg_t *args) {
  if (p->nsteps >= OD_MAX_STEPS) {
    dnnl_primitive_destroy(prim);
    return HF_ERANGE;
  }
  od_step *s = &p->steps[p->nsteps++];
  memset(s, 0, sizeof *s);
  s->type = OD_STEP_PRIM;
  s->prim = prim;
  s->nargs = nargs;
  memcpy(s->args, args, sizeof *args * nargs);
  return HF_OK;
}

/* Deferred: the scratchpad is sized after every primitive exists, so steps
 * record which argument slot to point at it. */
typedef struct od_scratch_ref {
  int step;
  const dnnl_memory_desc_t *md;
} od_scratch_ref;

/* Adds a conv/deconv step from src_mem to dst_mem. */
static int od_add_layer(od_model *m, od_plan *p, od_kind kind, int i, dnnl_memory_t src_mem,
                        dnnl_memory_t dst_mem, size_t *scratch_bytes) {
  int rc = HF_OK, owned = 0;
  const hf_net_config *c = &m->w->cfg;
  const dnnl_memory_desc_t *smd, *dmd;
  dnnl_primitive_desc_t pd = NULL;
  dnnl_primitive_t prim = NULL;
  dnnl_memory_t wmem = NULL;
  OD_TRY(dnnl_memory_get_memory_desc(src_mem, &smd));
  OD_TRY(dnnl_memory_get_memory_desc(dst_mem, &dmd));
  int cin, cout;
  od_layer_dims(c, kind, i, &cin, &cout);
  OD_RC(od_layer_pd(m->dev, kind, smd, dmd, cin, cout, &pd));
  const dnnl_memory_desc_t *wmd = dnnl_primitive_desc_query_md(pd, dnnl_query_weights_md, 0);
  const dnnl_memory_desc_t *scr = dnnl_primitive_desc_query_md(pd, dnnl_query_scratchpad_md, 0);
  if (!wmd) {
    rc = od_report(dnnl_runtime_error, "dnnl_primitive_desc_query_md(weights)", __LINE__);
    goto fail;
  }
  OD_RC(od_weights_for(m, kind, i, wmd, &wmem, &owned));
  if (owned && p->nmems >= OD_MAX_MEMS) {
    rc = HF_ERANGE;
    goto fail;
  }
  if (owned) {
    p->bytes += dnnl_memory_desc_get_size(wmd);
    p->mems[p->nmems++] = wmem, owned = 0;
  }
  size_t sb = scr ? dnnl_memory_desc_get_size(scr) : 0;
  if (sb > *scratch_bytes) *scratch_bytes = sb;
  OD_TRY(dnnl_primitive_create(&prim, pd));
  dnnl_exec_arg_t args[5] = {
    {DNNL_ARG_SRC, src_mem},
    {DNNL_ARG_WEIGHTS, wmem},
    {DNNL_ARG_DST, dst_mem},
    {DNNL_ARG_SCRATCHPAD, NULL}, /* set once the scratchpad exists */
    {DNNL_ARG_BIAS, kind >= OD_HEAD ? m->head_b : kind == OD_DEC ? m->dec_b[i] : m->enc_b[i]},
  };
  /* The scratchpad stays at index 3 so that dropping it (below, when a
   * primitive needs none) is a swap with the last argument. */
  rc = od_add_step(p, prim, kind == OD_TAPS || kind == OD_HEAD_HID ? 4 : 5, args);
  prim = NULL;
fail:
  if (owned) dnnl_memory_destroy(wmem);
  if (prim) dnnl_primitive_destroy(prim);
  if (pd) dnnl_primitive_desc_destroy(pd);
  return rc;
}

static int od_add_relu(od_plan *p, od_dev *dev, dnnl_memory_t mem) {
  int rc = HF_OK;
  const dnnl_memory_desc_t *md;
  dnnl_eltwise_desc_t ed;
  dnnl_primitive_desc_t pd = NULL;
  dnnl_primitive_t prim = NULL;
  OD_TRY(dnnl_memory_get_memory_desc(mem, &md));
  OD_TRY(dnnl_eltwise_forward_desc_init(&ed, dnnl_forward_inference, dnnl_eltwise_relu, md,
                                        0.0f, 0.0f));
  OD_TRY(dnnl_primitive_desc_create(&pd, &ed, NULL, dev->eng, NULL));
  OD_TRY(dnnl_primitive_create(&prim, pd));
  dnnl_exec_arg_t args[2] = {{DNNL_ARG_SRC, mem}, {DNNL_ARG_DST, mem}};
  rc = od_add_step(p, prim, 2, args);
  prim = NULL;
fail:
  if (prim) dnnl_primitive_destroy(prim);
  if (pd) dnnl_primitive_desc_destroy(pd);
  return rc;
}

/* Adds a copy of dense [npix][ch] at src into channels [off, off + ch) of
 * the concat buffer cat of stride channels. A plain loop, not a oneDNN
 * reorder: it is memory-bound either way, and a single-threaded copy does
 * not wait at a thread barrier when the cores are shared with other work. */
static int od_add_copy(od_plan *p, const void *src, size_t npix, int ch, void *cat, int off,
                       int stride) {
  if (p->nsteps >= OD_MAX_STEPS) return HF_ERANGE;
  od_step *st = &p->steps[p->nsteps++];
  memset(st, 0, sizeof *st);
  st->type = OD_STEP_COPY;
  st->copy = (od_copy_pass){src, npix, ch, stride, (float *)cat + off};
  return HF_OK;
}

static void od_copy_pixels(const od_copy_pass *c, size_t i0, size_t i1) {
  for (size_t i = i0; i < i1; i++)
    memcpy(c->dst + i * c->stride, c->src + i * c->ch, c->ch * sizeof(float));
}

/* The backend's own passes are split over the machine's cores like the
 * oneDNN primitives around them, in ranges of rows (taps, output stage) or
 * pixels (copy). They run on OpenMP's threads, the ones oneDNN runs its
 * primitives on (the same libgomp): kept alive between passes and runs,
 * asleep between them under OMP_WAIT_POLICY=passive, instead of a thread
 * started per pass (HF_CPU_PASS_THREADS=start, kept for comparison:
 * docs/PERFORMANCE.md). Each thread takes the next of a few ranges per
 * thread as it finishes one, so that a thread whose core is shared with
 * other work does less of the pass instead of holding up the others. */
typedef void (*od_range_fn)(const void *ctx, int job, size_t begin, size_t end);

typedef struct od_job {
  od_range_fn fn;
  const void *ctx;
  int job;                      /* 0 .. threads - 1, for per-thread scratch */
  size_t begin, end;
} od_job;

static void *od_job_thread(void *arg) {
  const od_job *j = arg;
  j->fn(j->ctx, j->job, j->begin, j->end);
  return NULL;
}

/* fn over [0, total) split over nthreads threads started for it. */
static void od_parallel_start(od_range_fn fn, const void *ctx, size_t total, int nthreads) {
  od_job jobs[OD_MAX_THREADS];
  pthread_t th[OD_MAX_THREADS];
  int started[OD_MAX_THREADS] = {0};
  for (int k = 0; k < nthreads; k++)
    jobs[k] = (od_job){fn, ctx, k, total * k / nthreads, total * (k + 1) / nthreads};
  for (int k = 1; k < nthreads; k++)
    started[k] = pthread_create(&th[k], NULL, od_job_thread, &jobs[k]) == 0;
  od_job_thread(&jobs[0]);
  /* A thread that could not start has its share done here. */
  for (int k = 1; k < nthreads; k++) {
    if (started[k])
      pthread_join(th[k], NULL);
    else
      od_job_thread(&jobs[k]);
  }
}

/* fn over items [0, total) of per_item values of work each, split into
 * ranges taken in turn by up to dev->threads threads; job is the thread's
 * number (0 .. dev->threads - 1), for per-thread scratch. */
static void od_parallel(od_range_fn fn, const void *ctx, size_t total, size_t per_item,
                        const od_dev *dev) {
  int nthreads = dev->threads;
  /* Below this much work a thread costs more than it saves. */
  if (total * per_item < (size_t)1 << 16) nthreads = 1;
  if ((size_t)nthreads > total) nthreads = (int)total;
  if (nthreads < 1) return;
  if (nthreads == 1) {
    fn(ctx, 0, 0, total);
    return;
  }
  if (dev->start_threads) {
    od_parallel_start(fn, ctx, total, nthreads);
    return;
  }
  /* Up to OD_RANGES_PER_THREAD ranges per thread, each of at least 2^14
   * values of work, so that taking one costs little beside doing it. */
  size_t ranges = (size_t)nthreads * OD_RANGES_PER_THREAD;
  if (ranges > total) ranges = total;
  if (ranges > total * per_item >> 14) ranges = total * per_item >> 14;
  if (ranges < (size_t)nthreads) ranges = nthreads;
#pragma omp parallel for num_threads(nthreads) schedule(dynamic, 1)
  for (size_t r = 0; r < ranges; r++)
    fn(ctx, omp_get_thread_num(), total * r / ranges, total * (r + 1) / ranges);
}

static void od_step_range(const void *ctx, int job, size_t begin, size_t end) {
  const od_step *st = ctx;
  if (st->type == OD_STEP_TAPS)
    od_taps_rows(&st->taps, job, begin, end);
  else
    od_copy_pixels(&st->copy, begin, end);
}

static void od_pass_run(const od_step *st, int batch, const od_dev *dev) {
  size_t total = st->type == OD_STEP_TAPS ? (size_t)batch * 2 * st->taps.h : st->copy.npix;
  size_t per_row = st->type == OD_STEP_TAPS ? (size_t)2 * st->taps.w * st->taps.cout
                                             : (size_t)st->copy.ch;
  od_parallel(od_step_range, st, total, per_row, dev);
}

/* ---- decoders' taps in bands (od_band) ------------------------------------- */

/* Input rows per band of a decoder whose input is h x w with cout output
 * channels: as many as fit dev->band_bytes of taps, at least 2 (a band then
 * has rows of its own besides the seams'), at most h. */
static int od_band_rows(size_t band_bytes, int h, int w, int cout) {
  size_t row = (size_t)w * 16 * cout * sizeof(float), r = band_bytes / row;
  if (r < 2) r = 2;
  if (r > (size_t)h) r = (size_t)h;
  return (int)r;
}

/* Bands per chunk of a frame of nb bands: four chunks per thread, so that
 * a thread slowed by other work on its core takes fewer of them. */
static int od_band_chunk(int nb, int threads) {
  int chunks = 4 * threads < nb ? 4 * threads : nb;
  return (nb + chunks - 1) / chunks;
}

/* One primitive of a banded step: layer i of kind between a band's smd
 * and dmd, into *prim, with the weights in the format it chooses (the
 * model's, or a private copy counted in p->bytes: *owned); the size of its
 * scratchpad raises *tscratch_bytes. */
static int od_band_prim(od_model *m, od_plan *p, od_kind kind, int i,
                        const dnnl_memory_desc_t *smd, const dnnl_memory_desc_t *dmd, int cin,
                        int cout, dnnl_primitive_t *prim, dnnl_memory_t *wmem, int *owned,
                        size_t *tscratch_bytes) {
  dnnl_primitive_desc_t pd = NULL;
  int rc = od_layer_pd(m->dev, kind, smd, dmd, cin, cout, &pd);
  if (rc) return rc;
  const dnnl_memory_desc_t *wmd = dnnl_primitive_desc_query_md(pd, dnnl_query_weights_md, 0);
  const dnnl_memory_desc_t *scr = dnnl_primitive_desc_query_md(pd, dnnl_query_scratchpad_md, 0);
  size_t sb = scr ? dnnl_memory_desc_get_size(scr) : 0;
  if (sb > *tscratch_bytes) *tscratch_bytes = sb;
  rc = wmd ? od_weights_for(m, kind, i, wmd, wmem, owned)
           : od_report(dnnl_runtime_error, "dnnl_primitive_desc_query_md(weights)", __LINE__);
  if (!rc && *owned) p->bytes += dnnl_memory_desc_get_size(wmd);
  if (!rc) {
    dnnl_status_t ds = dnnl_primitive_create(prim, pd);
    if (ds != dnnl_success) rc = od_report(ds, "dnnl_primitive_create(band)", __LINE__);
  }
  dnnl_primitive_desc_destroy(pd);
  return rc;
}

/* Adds dec{i}'s banded step: its 1x1 convolutions for a band of bh rows
 * and for the last band's rows when fewer, each thread's memories over its
 * band buffer (p->tband, allocated) and the seams' buffer (p->part). The
 * largest scratchpad a band primitive needs goes to *tscratch_bytes. */
static int od_add_band(od_model *m, od_plan *p, int i, const float *src,
                       const od_taps_pass *pass, int bh, size_t *tscratch_bytes) {
  od_dev *dev = m->dev;
  const int h = pass->h, w = pass->w, cin = hf_dec_in(&m->w->cfg, i), T = 16 * pass->cout;
  int rc = HF_OK;
  if (p->nsteps >= OD_MAX_STEPS) return HF_ERANGE;
  od_band *b = calloc(1, sizeof *b);
  if (!b) return HF_ENOMEM;
  od_step *st = &p->steps[p->nsteps++];
  memset(st, 0, sizeof *st);
  st->type = OD_STEP_BAND;
  st->taps = *pass;
  st->band = b;
  b->src = src, b->cin = cin, b->bh = bh, b->nb = (h + bh - 1) / bh, b->part = p->part;
  b->chunk = od_band_chunk(b->nb, p->nthreads), b->nchunks = (b->nb + b->chunk - 1) / b->chunk;
  b->src_mem = calloc((size_t)2 * p->nthreads, sizeof *b->src_mem);
  b->dst_mem = calloc((size_t)4 * p->nthreads, sizeof *b->dst_mem);
  if (!b->src_mem || !b->dst_mem) return HF_ENOMEM;
  const int rows[2] = {bh, h - (b->nb - 1) * bh};
  for (int k = 0; k < 2 && (k == 0 || rows[1] != bh); k++) {
    dnnl_memory_desc_t smd, dmd;
    OD_RC(od_nhwc(&smd, 1, cin, rows[k], w));
    OD_RC(od_nhwc(&dmd, 1, T, rows[k], w));
    OD_RC(od_band_prim(m, p, OD_TAPS, i, &smd, &dmd, cin, T, &b->prim[k], &b->wmem[k],
                       &b->owned[k], tscratch_bytes));
    for (int t = 0; t < p->nthreads; t++) {
      OD_TRY(dnnl_memory_create(&b->src_mem[2 * t + k], &smd, dev->eng, DNNL_MEMORY_NONE));
      for (int half = 0; half < 2; half++)
        OD_TRY(dnnl_memory_create(&b->dst_mem[(2 * t + k) * 2 + half], &dmd, dev->eng,
                                  p->tband + (size_t)(2 * t + half) * p->tband_floats));
    }
  }
fail:
  return rc;
}

/* Pixel X of output row o (t->stride floats apart) gets the bias, the seam
 * terms pr0 and pr1 (pr1 NULL: none), the ReLU and the skip channels. */
HF_CPU_CLONES static void od_taps_join(const od_taps_pass *t, const float *pr0, const float *pr1,
                                   float *o, const float *sk) {
  const int C = t->cout, E = t->skip_ch;
  for (int X = 0; X < 2 * t->w; X++, o += t->stride) {
    od_sum4(o, pr0 + (size_t)X * C, t->zeros, pr1 ? pr1 + (size_t)X * C : t->zeros, t->zeros,
            t->bias, C, t->relu);
    if (t->fin) hf_output_transform(o);
    if (sk) {
      const float *restrict s = sk + (size_t)X * E;
      float *restrict e = o + C;
#pragma omp simd
      for (int k = 0; k < E; k++) e[k] = s[k];
    }
  }
}

/* Chunk c of frame n on thread t. Band k of it, input rows [a, b): its taps
 * into buffer (k - first) & 1 of the thread's, then output rows 2a - 1 ..
 * 2b - 2 whole, with row a - 1 from the band before; the chunk's first band
 * has none, and leaves the seam terms of row 2a (taps ky = 1 of row a) and
 * 2a - 1 (ky = 0 of row a) instead, and its last band those of 2b - 1 (ky =
 * 2 of row b - 1) and 2b (ky = 3 of row b - 1). */
static int od_band_job(const od_plan *p, const od_step *st, const od_dev *dev, int t, int n,
                       int c) {
  const od_band *b = st->band;
  const od_taps_pass *tp = &st->taps;
  const int h = tp->h, w = tp->w, C = tp->cout;
  const size_t rowf = (size_t)w * 16 * C, prow = (size_t)2 * w * C;
  const int first = c * b->chunk, end = first + b->chunk < b->nb ? first + b->chunk : b->nb;
  float *P = b->part + ((size_t)n * b->nchunks + c) * 4 * prow;
  const float *prev = NULL;
  for (int k = first; k < end; k++) {
    const int a = k * b->bh, rows = k < b->nb - 1 ? b->bh : h - a, which = rows != b->bh;
    const int half = (k - first) & 1;
    dnnl_memory_t sm = b->src_mem[2 * t + which];
    dnnl_status_t s =
        dnnl_memory_set_data_handle(sm, (void *)(b->src + ((size_t)n * h + a) * w * b->cin));
    if (s == dnnl_success) {
      dnnl_exec_arg_t args[4] = {{DNNL_ARG_SRC, sm},
                                 {DNNL_ARG_WEIGHTS, b->wmem[which]},
                                 {DNNL_ARG_DST, b->dst_mem[(2 * t + which) * 2 + half]},
                                 {DNNL_ARG_SCRATCHPAD, p->tscratch_mem[t]}};
      s = dnnl_primitive_execute(b->prim[which], dev->tstream[t], p->tscratch_mem[t] ? 4 : 3,
                                 args);
    }
    if (s == dnnl_success) s = dnnl_stream_wait(dev->tstream[t]);
    if (s != dnnl_success) return od_report(s, "dnnl_primitive_execute(band)", __LINE__);
    const float *tb = p->tband + (size_t)(2 * t + half) * p->tband_floats;
    const float *last = tb + (rows - 1) * rowf;
    for (int Y = prev ? 2 * a - 1 : 2 * a + 1; Y <= 2 * (a + rows) - 2; Y++) {
      const int m = Y >> 1, py = Y & 1, y1 = py ? m + 1 : m - 1;
      const float *r0 = m < a ? prev : tb + (m - a) * rowf;
      const float *r1 = y1 < a ? prev : tb + (y1 - a) * rowf;
      float *dst = od_taps_dst(tp, n, Y, t);
      od_taps_line(tp, r0, py ? 2 : 1, r1, py ? 0 : 3, dst, tp->stride, tp->bias, tp->relu,
                   tp->fin, od_taps_skip_row(tp, n, Y, t));
      od_taps_row_done(tp, n, Y, dst, t);
    }
    if (!prev) {
      od_taps_line(tp, tb, 1, NULL, 0, P, C, tp->zeros, 0, 0, NULL);
      if (k > 0) od_taps_line(tp, tb, 0, NULL, 0, P + prow, C, tp->zeros, 0, 0, NULL);
    }
    if (k == end - 1) {
      od_taps_line(tp, last, 2, NULL, 0, P + 2 * prow, C, tp->zeros, 0, 0, NULL);
      if (k < b->nb - 1) od_taps_line(tp, last, 3, NULL, 0, P + 3 * prow, C, tp->zeros, 0, 0, NULL);
    }
    prev = last;
  }
  return HF_OK;
}

/* Seam j (0 .. nchunks) of frame n, at the first input row a of chunk j (h
 * for j = nchunks): output rows 2a from chunk j's terms and chunk j - 1's,
 * and 2a - 1 from chunk j - 1's and chunk j's; a row outside the frame is
 * skipped, a chunk outside adds nothing. */
static void od_band_seam(const od_step *st, int n, int j, int thread) {
  const od_band *b = st->band;
  const od_taps_pass *tp = &st->taps;
  const size_t prow = (size_t)2 * tp->w * tp->cout;
  const int a = j < b->nchunks ? j * b->chunk * b->bh : tp->h;
  const float *P = b->part + (size_t)n * b->nchunks * 4 * prow;
  if (a < tp->h) {
    float *dst = od_taps_dst(tp, n, 2 * a, thread);
    od_taps_join(tp, P + (size_t)j * 4 * prow, j > 0 ? P + ((size_t)(j - 1) * 4 + 3) * prow : NULL,
                 dst, od_taps_skip_row(tp, n, 2 * a, thread));
    od_taps_row_done(tp, n, 2 * a, dst, thread);
  }
  if (a > 0) {
    float *dst = od_taps_dst(tp, n, 2 * a - 1, thread);
    od_taps_join(tp, P + ((size_t)(j - 1) * 4 + 2) * prow,
                 j < b->nchunks ? P + ((size_t)j * 4 + 1) * prow : NULL, dst,
                 od_taps_skip_row(tp, n, 2 * a - 1, thread));
    od_taps_row_done(tp, n, 2 * a - 1, dst, thread);
  }
}

/* Runs a banded step: the chunks taken in turn by the threads (a thread on
 * a core shared with other work takes fewer), then the seams. oneDNN runs
 * a primitive executed inside an OpenMP parallel region on the calling
 * thread alone, so each band's convolution is one thread's. */
static int od_band_run(const od_plan *p, const od_step *st, int batch, const od_dev *dev) {
  const od_band *b = st->band;
  const int jobs = batch * b->nchunks, seams = batch * (b->nchunks + 1);
  int nthreads = p->nthreads < jobs ? p->nthreads : jobs, rc = HF_OK;
#pragma omp parallel num_threads(nthreads)
  {
    const int t = omp_get_thread_num();
#pragma omp for schedule(dynamic, 1)
    for (int j = 0; j < jobs; j++) {
      int e = od_band_job(p, st, dev, t, j / b->nchunks, j % b->nchunks);
      if (e) {
#pragma omp atomic write
        rc = e;
      }
    }
#pragma omp for schedule(dynamic, 4)
    for (int j = 0; j < seams; j++)
      od_band_seam(st, j / (b->nchunks + 1), j % (b->nchunks + 1), t);
  }
  return rc;
}

/* ---- enc0 in bands (od_enc_band) ------------------------------------------ */

/* Output rows per band of enc0: as many as keep the band's
 * 2 bh + 1 input rows within band_bytes (od_enc_band_bytes), and every
 * thread's band within the padded input's buffer (batch ph rows) where it
 * fits, at least 1, at most ph / 2; 0 for none (band_bytes 0, or a buffer
 * of fewer than the 3 rows of a band of one: the frame is widened whole). */
static int od_enc_band_rows(size_t band_bytes, int batch, int pw, int ph, int cin, int threads) {
  const size_t have = (size_t)batch * ph, per_thread = have / threads;
  if (!band_bytes || have < 3) return 0;
  size_t row = (size_t)pw * cin * sizeof(float), rows = band_bytes / row;
  size_t bh = rows > 1 ? (rows - 1) / 2 : 1;
  if (per_thread >= 3 && bh > (per_thread - 1) / 2) bh = (per_thread - 1) / 2;
  if (bh > (have - 1) / 2) bh = (have - 1) / 2;
  if (bh > (size_t)ph / 2) bh = (size_t)ph / 2;
  return bh < 1 ? 1 : (int)bh;
}

/* Makes each thread's scratchpad for band primitives at least bytes: made
 * anew, larger, when a primitive made later needs more. */
static int od_tscratch_reserve(od_plan *p, od_dev *dev, size_t bytes) {
  int rc = HF_OK;
  if (bytes <= p->tscratch_each) return HF_OK;
  size_t each = (bytes + 63) & ~(size_t)63;
  void *buf;
  dnnl_memory_desc_t md;
  dnnl_dims_t d = {(dnnl_dim_t)each};
  OD_TRY(dnnl_memory_desc_init_by_tag(&md, 1, d, dnnl_u8, dnnl_x));
  OD_RC(od_alloc_bytes(each * p->nthreads, &buf));
  for (int t = 0; t < p->nthreads; t++)
    if (p->tscratch_mem[t]) dnnl_memory_destroy(p->tscratch_mem[t]), p->tscratch_mem[t] = NULL;
  free(p->tscratch);
  p->bytes = p->bytes - p->tscratch_each * p->nthreads + each * p->nthreads;
  p->tscratch = buf, p->tscratch_each = each;
  for (int t = 0; t < p->nthreads; t++)
    OD_TRY(dnnl_memory_create(&p->tscratch_mem[t], &md, dev->eng, (char *)buf + each * t));
fail:
  return rc;
}

/* Builds p->eband for bands of bh output rows: the band's convolution and
 * the last band's when it has fewer rows, and each thread's memories. The
 * largest scratchpad a band primitive needs goes to *tscratch_bytes. */
static int od_add_enc_band(od_model *m, od_plan *p, int bh, size_t *tscratch_bytes) {
  const hf_net_config *c = &m->w->cfg;
  const int cin = c->in_channels, c0 = hf_enc_out(c, 0), oh = p->ph / 2, ow = p->pw / 2;
  int rc = HF_OK;
  od_enc_band *b = p->eband = calloc(1, sizeof *b);
  if (!b) return HF_ENOMEM;
  b->bh = bh, b->nb = (oh + bh - 1) / bh;
  b->nthreads = (int)((size_t)p->batch * p->ph / (2 * bh + 1));
  if (b->nthreads > p->nthreads) b->nthreads = p->nthreads;
  b->src_mem = calloc((size_t)3 * p->nthreads, sizeof *b->src_mem);
  b->dst_mem = calloc((size_t)3 * p->nthreads, sizeof *b->dst_mem);
  if (!b->src_mem || !b->dst_mem) return HF_ENOMEM;
  /* A first band has bh rows: the frame's bands are bh rows but the last,
   * and a frame of one band has bh = ph / 2. */
  const int rows[3] = {bh, oh - (b->nb - 1) * bh, bh};
  for (int k = 0; k < 3; k++) {
    if (k == 1 && rows[1] == bh) continue;
    dnnl_memory_desc_t smd, dmd;
    OD_RC(od_nhwc(&smd, 1, cin, 2 * rows[k] + (k < 2), p->pw));
    OD_RC(od_nhwc(&dmd, 1, c0, rows[k], ow));
    OD_RC(od_band_prim(m, p, k < 2 ? OD_ENC_BAND : OD_ENC_BAND_TOP, 0, &smd, &dmd, cin, c0,
                       &b->prim[k], &b->wmem[k], &b->owned[k], tscratch_bytes));
    for (int t = 0; t < b->nthreads; t++) {
      OD_TRY(dnnl_memory_create(&b->src_mem[3 * t + k], &smd, m->dev->eng, DNNL_MEMORY_NONE));
      OD_TRY(dnnl_memory_create(&b->dst_mem[3 * t + k], &dmd, m->dev->eng, DNNL_MEMORY_NONE));
    }
  }
fail:
  return rc;
}

/* The out-of-contract check and the statistics of a run's input, made by
 * enc0's bands as they read it (model_run_scan): each thread's part of
 * each frame, part[n * nthreads + t]. */
typedef struct od_scan {
  hf_scan_part *part;
  int nthreads;
  const char *in;               /* the caller's frames */
  hf_dtype dtype;
  size_t frame_bytes;
  int width, height, spp;
} od_scan;

/* Band j (frame j / nb, band j % nb) of enc0 on thread t: its input rows
 * scanned into the thread's part when sc is not NULL (the rows the band
 * owns, 2 r0 .. 2 r0 + 2 rows - 1, so each row of the frame once), then
 * its convolution (on this thread alone: oneDNN runs a primitive executed
 * inside an OpenMP parallel region on the calling thread) into the band's
 * rows of enc0's output, from the thread's rows where halves are widened
 * (and the first band's row above the frame is zero), else from the
 * caller's aligned float32 rows where they lie, while the scan has them in
 * the cache. */
static int od_enc_band_job(const od_plan *p, const od_model *m, const od_scan *sc, int t, int j) {
  const od_enc_band *b = p->eband;
  const int oh = p->ph / 2, ow = p->pw / 2, c0 = hf_enc_out(&m->w->cfg, 0);
  const int n = j / b->nb, r0 = j % b->nb * b->bh;
  const int rows = r0 + b->bh <= oh ? b->bh : oh - r0;
  const size_t row = (size_t)p->pw * p->input.cin;
  float *buf = p->in + (size_t)t * (2 * b->bh + 1) * row;
  if (sc) {
    int y0 = 2 * r0, y1 = 2 * r0 + 2 * rows;
    if (y1 > sc->height) y1 = sc->height;
    if (y0 < y1)
      hf_scan_part_add(&sc->part[n * sc->nthreads + t], sc->in + n * sc->frame_bytes, sc->dtype,
                       sc->width, sc->spp, (size_t)y0 * sc->width, (size_t)y1 * sc->width);
  }
  const float *src = buf;
  int which = rows != b->bh;
  if (!p->input.f32) {
    for (int i = 0; i < 2 * rows + 1; i++) od_in_row(&p->input, n, 2 * r0 - 1 + i, buf + i * row);
  } else if (r0 == 0) {
    src = p->input.f32 + (size_t)n * p->ph * row;
    which = 2;
  } else {
    src = p->input.f32 + ((size_t)n * p->ph + 2 * r0 - 1) * row;
  }
  dnnl_memory_t dst = b->dst_mem[3 * t + which], smem = b->src_mem[3 * t + which];
  dnnl_status_t s = dnnl_memory_set_data_handle(smem, (void *)src);
  if (s == dnnl_success)
    s = dnnl_memory_set_data_handle(dst, (float *)p->enc[0] + ((size_t)n * oh + r0) * ow * c0);
  if (s == dnnl_success) {
    dnnl_exec_arg_t args[5] = {{DNNL_ARG_SRC, smem},
                               {DNNL_ARG_WEIGHTS, b->wmem[which]},
                               {DNNL_ARG_BIAS, m->enc_b[0]},
                               {DNNL_ARG_DST, dst},
                               {DNNL_ARG_SCRATCHPAD, p->tscratch_mem[t]}};
    s = dnnl_primitive_execute(b->prim[which], m->dev->tstream[t], p->tscratch_mem[t] ? 5 : 4,
                               args);
  }
  if (s == dnnl_success) s = dnnl_stream_wait(m->dev->tstream[t]);
  return s == dnnl_success ? HF_OK : od_report(s, "dnnl_primitive_execute(enc band)", __LINE__);
}

/* Makes p->eband on the plan's first frame of halves, so that a plan that
 * only ever sees float32 frames holds no memory for it (the primitives'
 * code, weight copies). A failure leaves the plan to be built anew. */
static int od_enc_band_prepare(od_model *m, od_plan *p) {
  size_t tscratch = 0;
  int rc = od_add_enc_band(m, p, p->ebh, &tscratch);
  if (!rc) rc = od_tscratch_reserve(p, m->dev, tscratch);
  if (rc) {
    od_enc_band_free(p->eband, p->nthreads);
    p->eband = NULL;
    p->arena = NULL; /* od_plan_valid fails: od_plan_get builds it again */
  }
  return rc;
}

/* enc0 in bands (over p->input's halves, or over aligned float32 frames
 * that sc scans): the frames' bands taken in turn by the threads. */
static int od_enc_band_run(const od_plan *p, const od_model *m, const od_scan *sc, int batch) {
  const int jobs = batch * p->eband->nb;
  int nthreads = p->eband->nthreads < jobs ? p->eband->nthreads : jobs, rc = HF_OK;
#pragma omp parallel for num_threads(nthreads) schedule(dynamic, 1)
  for (int j = 0; j < jobs; j++) {
    int e = od_enc_band_job(p, m, sc, omp_get_thread_num(), j);
    if (e) {
#pragma omp atomic write
      rc = e;
    }
  }
  return rc;
}

/* ---- the output stage ------------------------------------------------------ */

/* One run's output stage, the values of hf_output_from_padded_f32 (what
 * cpu-ref runs) with the frames' rows split over the threads. The Kernel
 * architecture: hf_cpu_kernel_sums then hf_cpu_kernel_rows, split between
 * the two (the taps of a row read the sums of the rows around it), the
 * result written to the caller's f32 frames or through fin to its f16 ones.
 * The others: hf_output_finish's values a row at a time (for Residual,
 * after each frame's base was made into sums), through a row of the
 * thread's scratch for f16. */
typedef struct od_kernel_out {
  const hf_net_config *cfg;
  const od_input *in;           /* read a row at a time (od_in_row) */
  const float *raw;             /* raw output [batch][ph][pw][out_channels] */
  int pw, ph;
  float *sums, *fin;            /* Kernel: [batch][k][height][width] (k: hf_kernel_sums_floats),
                                 * [batch][height][width][3];
                                 * Residual: each frame's base [batch][height][width][3], and
                                 * a frame's scratch */
  float *scratch;               /* per thread, scratch_floats each */
  size_t scratch_floats;
  int ref;                      /* the reference's rows instead (HF_CPU_KERNEL_REF) */
  const hf_io *io;
  float *rows;                  /* each thread's row of widened input, */
  size_t rows_floats;           /* rows_floats apart (in the plan's in) */
} od_kernel_out;

static void od_kernel_sums(const void *ctx, int job, size_t r0, size_t r1) {
  const od_kernel_out *k = ctx;
  const int w = k->io->width, h = k->io->height, cin = k->cfg->in_channels;
  float *buf = k->rows + (size_t)job * k->rows_floats;
  const int ksums = hf_kernel_sums_of(k->cfg), nk = hf_kernel_sums_floats(ksums);
  for (size_t r = r0; r < r1; r++) {
    const size_t n = r / h, y = r % h;
    const float *row = od_in_row(k->in, (int)n, (int)y, buf);
    float *sums = k->sums + n * h * w * nk;
    if (k->ref) {
      hf_input_view v = {row, w, 1, k->pw, cin};
      hf_pixel_sums_rows(&v, k->cfg->spp, ksums, 0, 1, sums + y * w * nk);
    } else {
      hf_cpu_kernel_sums_row(row, w, cin, k->cfg->spp, ksums, sums + y * w, (size_t)h * w);
    }
  }
}

static void od_kernel_rows(const void *ctx, int job, size_t r0, size_t r1) {
  const od_kernel_out *k = ctx;
  const int w = k->io->width, h = k->io->height, ch = k->cfg->out_channels;
  const int f16 = k->io->out_dtype == HF_F16, ksums = hf_kernel_sums_of(k->cfg);
  const int nk = hf_kernel_sums_floats(ksums);
  for (size_t r = r0; r < r1;) {
    size_t n = r / h, frame = n * h * w * 3, fsums = n * h * w * nk;
    int y0 = (int)(r % h), y1 = r1 - r < (size_t)(h - y0) ? y0 + (int)(r1 - r) : h;
    float *out = f16 ? k->fin + frame : (float *)k->io->out + frame;
    const float *raw = k->raw + n * k->ph * k->pw * ch;
    if (k->ref)
      hf_kernel_output_rows(w, h, k->cfg->spp, k->cfg->kernel_radius, ksums, k->sums + fsums, raw,
                            k->pw, ch, y0, y1, out);
    else
      hf_cpu_kernel_rows(w, h, k->cfg->spp, k->cfg->kernel_radius, ksums, k->sums + fsums, raw, k->pw,
                         ch, y0, y1, out, k->scratch + (size_t)job * k->scratch_floats);
    if (f16)
      hf_f32_to_f16_serial(out + (size_t)y0 * w * 3,
                           (uint16_t *)k->io->out + frame + (size_t)y0 * w * 3,
                           (size_t)(y1 - y0) * w * 3);
    r += (size_t)(y1 - y0);
  }
}

/* Rows of the U-Net and Residual architectures: raw values through
 * hf_output_transform, or onto the Residual base (hf_residual_apply). */
static void od_output_rows(const void *ctx, int job, size_t r0, size_t r1) {
  const od_kernel_out *k = ctx;
  const int w = k->io->width, h = k->io->height, ch = k->cfg->out_channels;
  const int f16 = k->io->out_dtype == HF_F16, residual = k->cfg->arch == HF_ARCH_RESIDUAL;
  for (size_t r = r0; r < r1; r++) {
    const size_t n = r / h, y = r % h, o = r * w * 3;
    const float *raw = k->raw + (n * k->ph + y) * k->pw * ch;
    const float *base = residual ? k->sums + o : NULL;
    float *out = f16 ? k->scratch + (size_t)job * k->scratch_floats : (float *)k->io->out + o;
    if (!residual && ch == 3) {
      /* Dense triples: the row in one copy, transformed in place. */
      memcpy(out, raw, (size_t)w * 3 * sizeof(float));
      for (int x = 0; x < w; x++) hf_output_transform(out + (size_t)x * 3);
    } else {
      for (int x = 0; x < w; x++, raw += ch) {
        float v[HF_MAX_RAW_CHANNELS];
        memcpy(v, raw, ch * sizeof(float));
        if (residual)
          hf_residual_apply(base + (size_t)x * 3, v);
        else
          hf_output_transform(v);
        memcpy(out + (size_t)x * 3, v, 3 * sizeof(float));
      }
    }
    if (f16) hf_f32_to_f16_serial(out, (uint16_t *)k->io->out + o, (size_t)w * 3);
  }
}

static void od_output(const od_kernel_out *k, const od_dev *dev) {
  const hf_net_config *c = k->cfg;
  size_t rows = (size_t)k->io->batch * k->io->height, w = (size_t)k->io->width;
  if (c->arch == HF_ARCH_KERNEL) {
    od_parallel(od_kernel_sums, k, rows, w * c->in_channels, dev);
    od_parallel(od_kernel_rows, k, rows, w * 4 * hf_kernel_taps(c->kernel_radius), dev);
    return;
  }
  if (c->arch == HF_ARCH_RESIDUAL)
    for (int n = 0; n < k->io->batch; n++) {
      /* hf_residual_base_frame's values, its per-pixel sums made a row at
       * a time from rows that may be widened from halves. */
      const int h = k->io->height;
      float *base = k->sums + (size_t)n * h * w * 3;
      for (int y = 0; y < h; y++) {
        hf_input_view v = {od_in_row(k->in, n, y, k->rows), (int)w, 1, k->pw, c->in_channels};
        hf_pixel_sums_rows(&v, c->spp, HF_ESTIMATE_NONE, 0, 1, base + (size_t)y * w * 3);
      }
      hf_pooled_estimate_sums((int)w, h, c->spp, HF_RESIDUAL_RADIUS, base, k->fin);
    }
  od_parallel(od_output_rows, k, rows, w * c->out_channels, dev);
}

/* Floats of each thread's scratch in the output stage: the Kernel rows',
 * or a row of results for an f16 output. */
static size_t od_thread_scratch(const hf_net_config *c, int pw) {
  size_t row = (size_t)pw * 3;
  if (c->arch != HF_ARCH_KERNEL) return row;
  size_t k = hf_cpu_kernel_scratch(pw, c->kernel_radius);
  return k > row ? k : row;
}

/* ---- the activation arena ---------------------------------------------------- */

/* Where a plan's activations lie in the device's arena: byte offsets, each
 * 64-byte aligned, OD_NONE for a buffer the plan has no use for. Made from
 * the configuration, the size, the threads and the band size alone, so
 * that the plan and hf_run_bytes agree on it. */
#define OD_NONE SIZE_MAX

typedef struct od_layout {
  size_t in, out, head_in, sums, fin, kscratch, taps, tband, part;
  size_t enc[HF_MAX_LEVELS], cat[HF_MAX_LEVELS];
  int ebh;                      /* enc0's band rows, 0 when whole */
  size_t tband_floats;          /* each of a thread's two band buffers */
  int bh[HF_MAX_LEVELS];        /* each decoder's band rows, 0 when whole */
  int max_cout;
  size_t total;
} od_layout;

/* The offset of the next bytes in the arena (OD_NONE for none); the total
 * becomes SIZE_MAX, and stays so, when it would not fit a size_t. */
static size_t od_take(od_layout *l, size_t bytes) {
  if (!bytes) return OD_NONE;
  size_t r = (bytes + 63) & ~(size_t)63, off = l->total;
  if (r < bytes || off > SIZE_MAX - 64 - r) {
    l->total = SIZE_MAX;
    return OD_NONE;
  }
  l->total += r;
  return off;
}

/* The float32 bytes of a [batch][h][w][ch] tensor, 0 when out of range. */
static size_t od_tensor_bytes(int batch, int ch, int h, int w) {
  return od_size_ok(batch, ch, h, w) ? (size_t)batch * ch * h * w * sizeof(float) : 0;
}

/* The layout of a plan for batch frames of pw x ph: padded input and raw
 * output, the Kernel head's input (its larger, concatenated form when
 * head_sum is 0), the output stage's sums, result and per-thread scratch,
 * every encoder's output and decoder's concat input, one buffer for the
 * whole-tensor decoders' taps (or deconvolution outputs), each thread's
 * band of taps and the seams' terms of the banded ones. HF_ERANGE when a
 * size does not fit. */
static int od_layout_make(const hf_net_config *c, const int *use_taps, int head_sum, int batch,
                          int pw, int ph, int threads, size_t band_bytes,
                          size_t enc_band_bytes, od_layout *l) {
  const int L = c->num_levels, head = hf_head_in(c);
  size_t taps = 0, tband = 0, part = 0;
  memset(l, 0, sizeof *l);
  l->max_cout = 1;
  l->in = od_take(l, od_tensor_bytes(batch, c->in_channels, ph, pw));
  l->out = od_take(l, od_tensor_bytes(batch, c->out_channels, ph, pw));
  l->head_in = head ? od_take(l, od_tensor_bytes(batch, head_sum ? c->kernel_hidden : head, ph, pw))
                    : OD_NONE;
  const int sums = c->arch == HF_ARCH_KERNEL || c->arch == HF_ARCH_RESIDUAL;
  /* a Kernel that mixes keeps 6 sums a pixel (hf_kernel_sums_floats) */
  const int nsums = c->arch == HF_ARCH_KERNEL ? hf_kernel_sums_floats(hf_kernel_sums_of(c)) : 3;
  l->sums = sums ? od_take(l, od_tensor_bytes(batch, nsums, ph, pw)) : OD_NONE;
  l->fin = sums ? od_take(l, od_tensor_bytes(batch, 3, ph, pw)) : OD_NONE;
  size_t ks = od_thread_scratch(c, pw);
  l->kscratch = ks <= SIZE_MAX / sizeof(float) / threads ? od_take(l, ks * threads * sizeof(float))
                                                         : (l->total = SIZE_MAX, OD_NONE);
  l->ebh = od_enc_band_rows(enc_band_bytes, batch, pw, ph, c->in_channels, threads);
  for (int i = 0; i < L; i++) {
    const int h = ph >> (i + 1), w = pw >> (i + 1), cout = hf_dec_out(c, i);
    if (cout > l->max_cout) l->max_cout = cout;
    l->enc[i] = od_take(l, od_tensor_bytes(batch, hf_enc_out(c, i), h, w));
    l->cat[i] = i < L - 1 ? od_take(l, od_tensor_bytes(batch, hf_dec_in(c, i), h, w)) : OD_NONE;
    if (use_taps[i] && band_bytes) {
      l->bh[i] = od_band_rows(band_bytes, h, w, cout);
      int nb = (h + l->bh[i] - 1) / l->bh[i], chunk = od_band_chunk(nb, threads);
      size_t tb = od_tensor_bytes(1, 16 * cout, l->bh[i], w);
      size_t pb = od_tensor_bytes(batch, 8 * cout, (nb + chunk - 1) / chunk, w);
      if (tb > tband) tband = tb;
      if (pb > part) part = pb;
    } else {
      size_t b = use_taps[i] ? od_tensor_bytes(batch, 16 * cout, h, w)
                             : od_tensor_bytes(batch, cout, ph >> i, pw >> i);
      if (b > taps) taps = b;
    }
  }
  l->taps = od_take(l, taps);
  l->tband_floats = ((tband + 63) & ~(size_t)63) / sizeof(float);
  l->tband = tband <= SIZE_MAX / 4 / threads
                ? od_take(l, l->tband_floats * sizeof(float) * 2 * threads)
                : (l->total = SIZE_MAX, OD_NONE);
  l->part = od_take(l, part);
  return l->total == SIZE_MAX || l->in == OD_NONE || l->out == OD_NONE ? HF_ERANGE : HF_OK;
}

/* Buffer off of the arena a plan was laid out in, NULL for OD_NONE. */
static void *od_at(char *arena, size_t off) { return off == OD_NONE ? NULL : arena + off; }

/* Address space reserved for the arena, which takes no memory until it is
 * used: the arena grows and shrinks inside it without moving, so that the
 * plans laid out in it stay valid whatever ran in between. */
#define OD_ARENA_SPAN ((size_t)64 << 30)

/* A plan may run when its buffers lie in the arena's reservation (after
 * od_arena_reserve of its need). A reservation made again at the same
 * address serves: the arena's contents are scratch. */
static int od_plan_valid(const od_dev *d, const od_plan *p) { return p->arena == d->arena; }

/* Makes at least need bytes of the arena usable: inside the reservation
 * (made on first use, or anew when need exceeds it: the plans laid out in
 * the old one are rebuilt when next used). Mapped directly, not with
 * malloc, so that it can grow and give back its tail in place. */
static int od_arena_reserve(od_dev *d, size_t need) {
  const size_t page = 4096;
  if (need > SIZE_MAX - page) return HF_ERANGE;
  need = (need + page - 1) & ~(page - 1);
  if (need <= d->arena_bytes) return HF_OK;
  if (!d->arena || need > d->arena_span) {
    if (d->arena) munmap(d->arena, d->arena_span);
    d->arena = NULL, d->arena_bytes = d->arena_span = 0;
    size_t span = need > OD_ARENA_SPAN ? need : OD_ARENA_SPAN;
    const int flags = MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE;
    void *q = mmap(NULL, span, PROT_NONE, flags, -1, 0);
    if (q == MAP_FAILED && span > need) q = mmap(NULL, span = need, PROT_NONE, flags, -1, 0);
    if (q == MAP_FAILED) return HF_ENOMEM;
    d->arena = q, d->arena_span = span;
  }
  if (mprotect(d->arena + d->arena_bytes, need - d->arena_bytes, PROT_READ | PROT_WRITE))
    return HF_ENOMEM;
  d->arena_bytes = need;
  return HF_OK;
}

/* After plans were freed: the arena shrinks to what the largest plan left
 * in it needs (its pages beyond go back to the system), and its bytes are
 * counted by a model that has such a plan, the current one if it still
 * does. */
static void od_arena_fit(od_dev *d) {
  size_t need = 0;
  struct od_model *owner = NULL;
  for (struct od_model *m = d->models; m; m = m->next)
    for (int k = 0; k < OD_PLAN_CACHE; k++) {
      const od_plan *p = m->plans[k];
      if (!p || !od_plan_valid(d, p)) continue;
      if (p->need > need) need = p->need;
      if (!owner || m == d->arena_owner) owner = m;
    }
  need = (need + 4095) & ~(size_t)4095;
  if (need < d->arena_bytes) {
    void *q = mmap(d->arena + need, d->arena_bytes - need, PROT_NONE,
                   MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE | MAP_FIXED, -1, 0);
    if (q != MAP_FAILED) d->arena_bytes = need;
  }
  d->arena_owner = owner;
}

/* Builds every primitive and buffer for batch frames of pw x ph. */
static int od_plan_create(od_model *m, int batch, int pw, int ph, od_plan **out) {
  const hf_net_config *c = &m->w->cfg;
  od_dev *dev = m->dev;
  int L = c->num_levels, rc = HF_OK;
  size_t scratch_bytes = 0;
  od_plan *p = calloc(1, sizeof *p);
  if (!p) return HF_ENOMEM;
  p->batch = batch, p->pw = pw, p->ph = ph;
  p->in_skip_step = -1;
  p->out_step = -1;

  /* The activations, in the device's arena (grown to fit if need be). */
  od_layout lay;
  OD_RC(od_layout_make(c, m->use_taps, m->head_sum, batch, pw, ph, dev->threads, dev->band_bytes,
                       dev->enc_band_bytes, &lay));
  OD_RC(od_arena_reserve(dev, lay.total));
  char *A = p->arena = dev->arena;
  p->need = lay.total;
  p->nthreads = dev->threads;
  p->in = od_at(A, lay.in), p->out = od_at(A, lay.out), p->head_in = od_at(A, lay.head_in);
  p->sums = od_at(A, lay.sums), p->fin = od_at(A, lay.fin), p->kscratch = od_at(A, lay.kscratch);
  p->taps = od_at(A, lay.taps), p->tband = od_at(A, lay.tband), p->part = od_at(A, lay.part);
  p->tband_floats = lay.tband_floats;
  for (int i = 0; i < L; i++) p->enc[i] = od_at(A, lay.enc[i]), p->cat[i] = od_at(A, lay.cat[i]);
  const int *bh = lay.bh, max_cout = lay.max_cout;
  size_t tscratch_bytes = 0;
  /* At least a pixel of dec0's taps (12 floats) for od_taps_line3. */
  const int nzeros = max_cout > 16 ? max_cout : 16;
  p->zeros = calloc(nzeros, sizeof(float));
  if (!p->zeros) OD_RC(HF_ENOMEM);
  p->bytes += nzeros * sizeof(float);

  dnnl_memory_desc_t in_md, out_md, cat_md[HF_MAX_LEVELS], head_md;
  OD_RC(od_nhwc(&in_md, batch, c->in_channels, ph, pw));
  OD_RC(od_nhwc(&out_md, batch, c->out_channels, ph, pw));
  /* The head reads dec0's hidden channels, after them the input's when it
   * is one convolution over their concatenation. */
  const int head = hf_head_in(c), head_ch = m->head_sum ? c->kernel_hidden : head;
  if (head) OD_RC(od_nhwc(&head_md, batch, head_ch, ph, pw));
  for (int i = 0; i < L - 1; i++)
    OD_RC(od_nhwc(&cat_md[i], batch, hf_dec_in(c, i), ph >> (i + 1), pw >> (i + 1)));

  /* Encoder: enc{i} reads enc{i-1}'s output (or the input). */
  dnnl_memory_t src, dst;
  OD_RC(od_mem(p, dev, &in_md, p->in, &src));
  p->in_mem = src;
  p->enc0_step = p->nsteps;
  for (int i = 0; i < L; i++) {
    dnnl_memory_desc_t md;
    OD_RC(od_nhwc(&md, batch, hf_enc_out(c, i), ph >> (i + 1), pw >> (i + 1)));
    OD_RC(od_mem(p, dev, &md, p->enc[i], &dst));
    OD_RC(od_add_layer(m, p, OD_ENC, i, src, dst, &scratch_bytes));
    src = dst;
  }
  p->ebh = lay.ebh;
  /* Decoder: dec{L-1} reads enc{L-1}'s output, the others their concat
   * buffer. Taps go to the taps buffer, and their pass writes the whole
   * next concat buffer: the decoder's half (ReLU included) and a copy of
   * the encoder's (or the output, or the head's input). A deconvolution
   * writes the taps buffer, gets its ReLU, and is copied into the left half
   * of the next concat buffer, the encoder's output into the right half. */
  for (int i = L - 1; i >= 0; i--) {
    if (i < L - 1) OD_RC(od_mem(p, dev, &cat_md[i], p->cat[i], &src));
    int cout = hf_dec_out(c, i);
    dnnl_memory_desc_t md;
    if (m->use_taps[i]) {
      /* dec0's pass also copies the input beside the head's hidden
       * channels, from where od_model_run finds it. */
      const int head_cat = i == 0 && head && !m->head_sum;
      od_taps_pass pass = {p->taps, ph >> (i + 1), pw >> (i + 1), cout,
                           i > 0 || head, m->w->dec_b[i], p->zeros,
                           i ? p->cat[i - 1] : head ? p->head_in : p->out,
                           i ? hf_dec_in(c, i - 1) : head ? head_ch : c->out_channels,
                           i ? p->enc[i - 1] : head_cat ? p->in : NULL,
                           i ? hf_enc_out(c, i - 1) : head_cat ? c->in_channels : 0, 0,
                           NULL, p->in, (size_t)pw * c->in_channels, NULL, NULL, 0, NULL, 0};
      if (i == 0 && !head) p->out_step = p->nsteps + (bh[i] ? 0 : 1);
      if (bh[i]) {
        if (head_cat) p->in_skip_step = p->nsteps;
        const float *from = i < L - 1 ? p->cat[i] : p->enc[L - 1];
        OD_RC(od_add_band(m, p, i, from, &pass, bh[i], &tscratch_bytes));
        continue;
      }
      OD_RC(od_nhwc(&md, batch, 16 * cout, ph >> (i + 1), pw >> (i + 1)));
      OD_RC(od_mem(p, dev, &md, p->taps, &dst));
      OD_RC(od_add_layer(m, p, OD_TAPS, i, src, dst, &scratch_bytes));
      if (p->nsteps >= OD_MAX_STEPS) {
        rc = HF_ERANGE;
        goto fail;
      }
      if (head_cat) p->in_skip_step = p->nsteps;
      od_step *st = &p->steps[p->nsteps++];
      memset(st, 0, sizeof *st);
      st->type = OD_STEP_TAPS;
      st->taps = pass;
      continue;
    }
    if (i == 0) {
      OD_RC(od_mem(p, dev, &out_md, p->out, &dst));
      OD_RC(od_add_layer(m, p, OD_DEC, i, src, dst, &scratch_bytes));
      break;
    }
    OD_RC(od_nhwc(&md, batch, cout, ph >> i, pw >> i));
    OD_RC(od_mem(p, dev, &md, p->taps, &dst));
    OD_RC(od_add_layer(m, p, OD_DEC, i, src, dst, &scratch_bytes));
    OD_RC(od_add_relu(p, dev, dst));
    size_t npix = (size_t)batch * (ph >> i) * (pw >> i);
    OD_RC(od_add_copy(p, p->taps, npix, cout, p->cat[i - 1], 0, hf_dec_in(c, i - 1)));
    OD_RC(od_add_copy(p, p->enc[i - 1], npix, hf_enc_out(c, i - 1), p->cat[i - 1], cout,
                      hf_dec_in(c, i - 1)));
  }
  /* The head, after dec0's pass wrote its input: one convolution over the
   * hidden channels and the input, or the input's part with the bias and
   * the hidden part summed onto it. */
  if (head) {
    OD_RC(od_mem(p, dev, &head_md, p->head_in, &src));
    OD_RC(od_mem(p, dev, &out_md, p->out, &dst));
    if (m->head_sum) {
      OD_RC(od_add_layer(m, p, OD_HEAD_IN, 0, p->in_mem, dst, &scratch_bytes));
      OD_RC(od_add_layer(m, p, OD_HEAD_HID, 0, src, dst, &scratch_bytes));
    } else {
      OD_RC(od_add_layer(m, p, OD_HEAD, 0, src, dst, &scratch_bytes));
    }
  }

  if (scratch_bytes) {
    dnnl_memory_desc_t md;
    dnnl_memory_t smem;
    dnnl_dims_t d = {(dnnl_dim_t)scratch_bytes};
    OD_TRY(dnnl_memory_desc_init_by_tag(&md, 1, d, dnnl_u8, dnnl_x));
    OD_RC(od_alloc(&md, &p->scratch));
    p->bytes += scratch_bytes;
    p->scratch_bytes = scratch_bytes;
    OD_RC(od_mem(p, dev, &md, p->scratch, &smem));
    for (int s = 0; s < p->nsteps; s++)
      for (int a = 0; a < p->steps[s].nargs; a++)
        if (p->steps[s].args[a].arg == DNNL_ARG_SCRATCHPAD) p->steps[s].args[a].memory = smem;
  }
  OD_RC(od_tscratch_reserve(p, dev, tscratch_bytes));
  /* Primitives without a scratchpad need no argument for it. */
  for (int s = 0; s < p->nsteps; s++) {
    od_step *st = &p->steps[s];
    for (int a = 0; a < st->nargs; a++)
      if (st->args[a].arg == DNNL_ARG_SCRATCHPAD && !st->args[a].memory) {
        st->args[a] = st->args[--st->nargs];
        break;
      }
  }
  *out = p;
  return HF_OK;
fail:
  od_plan_free(p);
  return rc;
}

/* The plan for (batch, pw, ph): cached (the arena grown to what it needs),
 * or built in place of the least recently used one (or of the cached one,
 * when the arena it was laid out in has moved). The device's lock is
 * held. */
static int od_plan_get(od_model *m, int batch, int pw, int ph, od_plan **out) {
  int victim = 0;
  for (int k = 0; k < OD_PLAN_CACHE; k++) {
    od_plan *p = m->plans[k];
    if (p && p->batch == batch && p->pw == pw && p->ph == ph) {
      if (!od_plan_valid(m->dev, p)) {
        victim = k;
        break;
      }
      int rc = od_arena_reserve(m->dev, p->need);
      if (rc) return rc;
      p->stamp = ++m->clock;
      *out = p;
      return HF_OK;
    }
    if (!p || (m->plans[victim] && p->stamp < m->plans[victim]->stamp)) victim = k;
  }
  od_plan_free(m->plans[victim]);
  m->plans[victim] = NULL;
  od_arena_fit(m->dev);
  int rc = od_plan_create(m, batch, pw, ph, &m->plans[victim]);
  if (rc) {
    od_arena_fit(m->dev);
    return rc;
  }
  m->plans[victim]->stamp = ++m->clock;
  m->dev->arena_owner = m;
  *out = m->plans[victim];
  return HF_OK;
}

/* ---- model ---------------------------------------------------------------- */

/* Which decoders run as taps (see the top of this file): all of them,
 * unless HF_CPU_DECONV is set to a non-empty value, which keeps oneDNN's
 * deconvolution for every decoder but dec0, to compare the two (tests and
 * docs/PERFORMANCE.md do). */
static int od_use_taps(int i) {
  const char *e = getenv("HF_CPU_DECONV");
  return i == 0 || !e || !*e;
}

/* How the head is computed (see od_kind): one convolution over the
 * concatenation, which was a few percent faster at 1024 x 1024 than two
 * convolutions summed (docs/PERFORMANCE.md), unless HF_CPU_HEAD is "sum",
 * to compare the two. */
static int od_head_sum(void) {
  const char *e = getenv("HF_CPU_HEAD");
  return e && !strcmp(e, "sum");
}

/* The head's weights [out][hidden + cin] split into the input's columns
 * (head_split[OD_HEAD_IN - OD_HEAD], [out][cin]) and the hidden channels'
 * (head_split[OD_HEAD_HID - OD_HEAD], [out][hidden]). */
static int od_head_split(od_model *m) {
  const hf_net_config *c = &m->w->cfg;
  int hid = c->kernel_hidden, cin = c->in_channels, hin = hf_head_in(c), out = c->out_channels;
  float *a = malloc((size_t)out * cin * sizeof(float));
  float *b = malloc((size_t)out * hid * sizeof(float));
  m->head_split[OD_HEAD_IN - OD_HEAD] = a;
  m->head_split[OD_HEAD_HID - OD_HEAD] = b;
  if (!a || !b) return HF_ENOMEM;
  for (int o = 0; o < out; o++) {
    memcpy(b + (size_t)o * hid, m->w->head_w + (size_t)o * hin, hid * sizeof(float));
    memcpy(a + (size_t)o * cin, m->w->head_w + (size_t)o * hin + hid, cin * sizeof(float));
  }
  return HF_OK;
}

static void od_model_destroy(void *impl) {
  od_model *m = impl;
  if (!m) return;
  od_dev *d = m->dev;
  pthread_mutex_lock(&d->lock);
  for (int k = 0; k < OD_PLAN_CACHE; k++) od_plan_free(m->plans[k]), m->plans[k] = NULL;
  for (od_model **q = &d->models; *q; q = &(*q)->next)
    if (*q == m) {
      *q = m->next;
      break;
    }
  od_arena_fit(d);
  pthread_mutex_unlock(&d->lock);
  for (int k = 0; k < 3; k++) {
    if (m->head_w[k]) dnnl_memory_destroy(m->head_w[k]);
    free(m->head_split[k]);
  }
  if (m->head_b) dnnl_memory_destroy(m->head_b);
  for (int i = 0; i < HF_MAX_LEVELS; i++) {
    if (m->enc_w[i]) dnnl_memory_destroy(m->enc_w[i]);
    if (m->dec_w[i]) dnnl_memory_destroy(m->dec_w[i]);
    if (m->enc_b[i]) dnnl_memory_destroy(m->enc_b[i]);
    if (m->dec_b[i]) dnnl_memory_destroy(m->dec_b[i]);
  }
  for (int i = 0; i < HF_MAX_LEVELS; i++) {
    if (m->taps_w[i]) dnnl_memory_destroy(m->taps_w[i]);
    free(m->taps_user[i]);
  }
  hf_weights_free(m->w);
  free(m);
}

static int od_model_create(void *devp, const hf_weights *w, void **out) {
  od_dev *dev = devp;
  int rc;
  od_model *m = calloc(1, sizeof *m);
  if (!m) return HF_ENOMEM;
  m->dev = dev;
  OD_RC(hf_weights_alloc(&w->cfg, &m->w));
  memcpy(m->w->storage, w->storage, w->num_params * sizeof(float));
  memcpy(m->w->features, w->features, sizeof m->w->features);
  const hf_net_config *c = &m->w->cfg;
  for (int i = 0; i < c->num_levels; i++) {
    m->use_taps[i] = od_use_taps(i);
    if (m->use_taps[i]) OD_RC(od_taps_weights(m, i));
  }
  for (int i = 0; i < c->num_levels; i++) {
    dnnl_memory_desc_t md;
    dnnl_dims_t d = {hf_enc_out(c, i)};
    OD_TRY(dnnl_memory_desc_init_by_tag(&md, 1, d, dnnl_f32, dnnl_x));
    OD_TRY(dnnl_memory_create(&m->enc_b[i], &md, dev->eng, m->w->enc_b[i]));
    d[0] = hf_dec_out(c, i);
    OD_TRY(dnnl_memory_desc_init_by_tag(&md, 1, d, dnnl_f32, dnnl_x));
    OD_TRY(dnnl_memory_create(&m->dec_b[i], &md, dev->eng, m->w->dec_b[i]));
  }
  const char *ref = getenv("HF_CPU_KERNEL_REF");
  m->kernel_ref = ref && *ref && strcmp(ref, "0");
  if (hf_head_in(c)) {
    dnnl_memory_desc_t md;
    dnnl_dims_t d = {c->out_channels};
    m->head_sum = od_head_sum();
    if (m->head_sum) OD_RC(od_head_split(m));
    OD_TRY(dnnl_memory_desc_init_by_tag(&md, 1, d, dnnl_f32, dnnl_x));
    OD_TRY(dnnl_memory_create(&m->head_b, &md, dev->eng, m->w->head_b));
  }
  /* Reorder the weights now, into the formats oneDNN picks for a frame of
   * 256 x 256 (or the alignment, if larger): the plan built here is kept,
   * and plans of other sizes find the same formats in the model. */
  int a = hf_net_align(c), side = a > 256 ? a : 256;
  pthread_mutex_lock(&dev->lock);
  m->next = dev->models;
  dev->models = m;
  rc = od_plan_get(m, 1, side, side, &(od_plan *){NULL});
  pthread_mutex_unlock(&dev->lock);
  if (rc) goto fail;
  *out = m;
  return HF_OK;
fail:
  od_model_destroy(m);
  return rc;
}

/* Runs io; with rep (model_run_scan), also checks it and makes its
 * statistics in enc0's bands, or declines (HF_RUN_DECLINED, before
 * anything is read) when enc0 does not run in bands for io: a float32
 * frame that needs padding, a plan without bands (HF_CPU_ENC_BAND_KB=0, a
 * frame of fewer than 3 rows), HF_CPU_HEAD=sum. Where dec0 then writes the
 * caller's frames itself, it applies the output guard to each row as it
 * makes it (rep[n].outputs, *guarded = 1). */
static int od_model_run_locked(od_model *m, const hf_io *io, hf_timing *t, hf_input_report *rep,
                               hf_input_stats *stats, int *guarded) {
  const hf_net_config *c = &m->w->cfg;
  int a = hf_net_align(c), rc = HF_OK;
  int pw = hf_round_up(io->width, a), ph = hf_round_up(io->height, a);
  od_plan *p = NULL;
  od_scan scan = {0}, *sc = NULL;
  hf_input_stats_acc *acc = NULL;
  uint64_t *fixed = NULL;
  double t0 = hf_now_us();
  OD_RC(od_plan_get(m, io->batch, pw, ph, &p));
  m->dev->arena_owner = m;
  /* Aligned float32 frames are read where they are, and so are halves,
   * widened a band or a row at a time by the passes that read them (unless
   * the head reads the whole input as one convolution, HF_CPU_HEAD=sum);
   * others are converted and padded into the plan's buffer. oneDNN never
   * writes a source. */
  const int bands = p->ebh && !m->head_sum;
  const int halves = io->in_dtype == HF_F16 && bands;
  const int aligned = io->in_dtype == HF_F32 && io->width == pw && io->height == ph;
  if (rep) {
    if (!halves && !(aligned && bands)) return HF_RUN_DECLINED;
    const int nt = p->nthreads, parts = io->batch * nt;
    scan = (od_scan){calloc((size_t)parts, sizeof *scan.part), nt, io->in, io->in_dtype,
                     (size_t)io->width * io->height * c->in_channels *
                         (io->in_dtype == HF_F16 ? 2 : 4),
                     io->width, io->height, c->spp};
    if (stats) acc = malloc((size_t)parts * sizeof *acc);
    if (!scan.part || (stats && !acc)) {
      rc = HF_ENOMEM;
      goto fail;
    }
    for (int k = 0; k < parts; k++) hf_scan_part_init(&scan.part[k], acc ? &acc[k] : NULL);
    sc = &scan;
  }
  const int enc_bands = halves || sc;
  if (enc_bands && !p->eband) OD_RC(od_enc_band_prepare(m, p));
  const float *in = p->in;
  if (halves)
    in = NULL;
  else if (io->in_dtype == HF_F32 && io->width == pw && io->height == ph)
    in = io->in;
  else
    hf_input_to_padded_f32(io, c->in_channels, pw, ph, p->in);
  p->input = (od_input){in, halves ? io->in : NULL, io->width, io->height, pw, ph,
                        c->in_channels};
  if (in) OD_TRY(dnnl_memory_set_data_handle(p->in_mem, (void *)in));
  if (p->in_skip_step >= 0) {
    p->steps[p->in_skip_step].taps.skip = in;
    p->steps[p->in_skip_step].taps.skip_in = halves ? &p->input : NULL;
  }
  /* A U-Net's dec0 writes the caller's frames, transformed (and for
   * float16 converted a row at a time), when no padding is cropped: the
   * output stage then has nothing left to do. */
  const int direct = p->out_step >= 0 && c->arch == HF_ARCH_UNET && c->out_channels == 3 &&
                     io->width == pw && io->height == ph;
  if (p->out_step >= 0) {
    od_taps_pass *tp = &p->steps[p->out_step].taps;
    tp->out = direct && io->out_dtype == HF_F32 ? (float *)io->out : p->out;
    tp->fin = direct;
    tp->out16 = direct && io->out_dtype == HF_F16 ? (uint16_t *)io->out : NULL;
    tp->row16 = p->kscratch;
    tp->row16_floats = od_thread_scratch(c, pw);
    tp->guarded = NULL;
    tp->batch = io->batch;
    if (direct && sc) {
      /* Counted per thread: no thread waits for another's row. */
      if (!(fixed = calloc((size_t)OD_MAX_THREADS * io->batch, sizeof *fixed))) {
        rc = HF_ENOMEM;
        goto fail;
      }
      tp->guarded = fixed;
    }
  }
  double t1 = hf_now_us();
  for (int s = 0; s < p->nsteps; s++) {
    od_step *st = &p->steps[s];
    const int enc_band = enc_bands && s == p->enc0_step;
    if (st->type == OD_STEP_PRIM && !enc_band) {
      OD_TRY(dnnl_primitive_execute(st->prim, m->dev->stream, st->nargs, st->args));
      continue;
    }
    OD_TRY(dnnl_stream_wait(m->dev->stream));
    if (enc_band) {
      OD_RC(od_enc_band_run(p, m, sc, io->batch));
      if (sc) {
        /* Every frame's input has been read: a bad sample stops the run
         * before anything reaches the caller's output. */
        uint64_t bad = 0;
        for (int n = 0; n < io->batch; n++) {
          hf_scan_parts_finish(&scan.part[n * scan.nthreads], scan.nthreads, io->width,
                               io->height, c->spp, &rep[n], stats ? &stats[n] : NULL);
          bad += rep[n].samples;
        }
        if (bad) {
          rc = HF_RUN_UNCLEAN;
          goto fail;
        }
      }
    } else if (st->type == OD_STEP_BAND)
      OD_RC(od_band_run(p, st, io->batch, m->dev));
    else
      od_pass_run(st, io->batch, m->dev);
  }
  OD_TRY(dnnl_stream_wait(m->dev->stream));
  double t2 = hf_now_us();
  od_kernel_out k = {c, &p->input, p->out, pw, ph, p->sums, p->fin, p->kscratch,
                     od_thread_scratch(c, pw), m->kernel_ref, io, p->in,
                     (size_t)pw * c->in_channels};
  if (!direct) od_output(&k, m->dev);
  if (fixed) {
    for (int n = 0; n < io->batch; n++) {
      rep[n].outputs = 0;
      for (int th = 0; th < OD_MAX_THREADS; th++) rep[n].outputs += fixed[(size_t)th * io->batch + n];
    }
    *guarded = 1;
  }
  t->input_us = t1 - t0;
  t->infer_us = t2 - t1;
  t->output_us = hf_now_us() - t2;
fail:
  if (p && p->out_step >= 0) p->steps[p->out_step].taps.guarded = NULL;
  free(fixed);
  free(scan.part);
  free(acc);
  return rc;
}

/* Runs of the models of one device take turns: they share its arena (and
 * would share its cores anyway). */
static int od_model_run(void *impl, const hf_io *io, hf_timing *t) {
  od_model *m = impl;
  pthread_mutex_lock(&m->dev->lock);
  int rc = od_model_run_locked(m, io, t, NULL, NULL, NULL);
  pthread_mutex_unlock(&m->dev->lock);
  return rc;
}

/* od_model_run that checks the input and makes its statistics in enc0's
 * bands, as it reads it (backend.h, model_run_scan): the frame is read from
 * memory once instead of twice. */
static int od_model_run_scan(void *impl, const hf_io *io, hf_timing *t, hf_input_report *rep,
                             hf_input_stats *stats, int *guarded) {
  od_model *m = impl;
  pthread_mutex_lock(&m->dev->lock);
  int rc = od_model_run_locked(m, io, t, rep, stats, guarded);
  pthread_mutex_unlock(&m->dev->lock);
  return rc;
}

static const char *od_model_precision(void *impl) { return "fp32"; }

/* ---- memory ---------------------------------------------------------------- */

/* Scratchpad allowance of a plan: oneDNN sizes the scratchpad only once the
 * primitives exist, so the estimate cannot know it. On this project's
 * development machine (AVX2) every plan's scratchpad was 12 KiB
 * (tests/cpu checks the whole estimate against the plans it builds); a
 * reference (im2col) kernel on another ISA can need a column buffer, which
 * a quarter of the largest activation plus 1 MiB allows for. */
static size_t od_scratch_allowance(size_t ping_bytes) { return ping_bytes / 4 + ((size_t)1 << 20); }

/* What od_plan_create allocates for (batch, pw, ph), from the same sizes:
 * the arena's share (od_layout_make: the activations, rounded to a page),
 * the zeros beside the taps, the scratchpads (the primitives' shared one
 * and each thread's for the band primitives) and private weight copies (at
 * most one of every weight, two of a banded decoder's: its band's and its
 * last band's, three more of enc0's for its bands). Each buffer
 * outside the arena is rounded as od_alloc_bytes rounds it, plus a page of
 * allocator overhead. An upper bound of what a run allocates whatever the
 * arena holds already. */
static size_t od_run_bytes(const hf_net_config *c, int batch, int pw, int ph) {
  const size_t f = sizeof(float), page = 4096;
  int use_taps[HF_MAX_LEVELS] = {0}, threads = od_thread_count();
  od_layout lay;
  for (int i = 0; i < c->num_levels; i++) use_taps[i] = od_use_taps(i);
  size_t band = od_band_bytes();
  if (od_layout_make(c, use_taps, 0, batch, pw, ph, threads, band, od_enc_band_bytes(band), &lay))
    return 0;
  size_t largest = 0, weights = 0;
  for (int i = 0; i < c->num_levels; i++) {
    size_t e = od_tensor_bytes(batch, hf_enc_out(c, i), ph >> (i + 1), pw >> (i + 1));
    size_t t = od_tensor_bytes(batch, (use_taps[i] ? 16 : 4) * hf_dec_out(c, i), ph >> (i + 1),
                               pw >> (i + 1));
    if (e > largest) largest = e;
    if (t > largest) largest = t;
    weights += (size_t)hf_enc_out(c, i) * hf_enc_in(c, i) * 9 * f + 64 + page;
    weights += 2 * ((size_t)hf_dec_in(c, i) * hf_dec_out(c, i) * 16 * f + 64 + page);
  }
  if (hf_head_in(c)) weights += (size_t)c->out_channels * hf_head_in(c) * f + 64 + page;
  if (lay.ebh) weights += 3 * ((size_t)hf_enc_out(c, 0) * hf_enc_in(c, 0) * 9 * f + 64 + page);
  size_t own = (size_t)(lay.max_cout > 16 ? lay.max_cout : 16) * f + 64 + page;
  own += od_scratch_allowance(largest) + 64 + page;
  /* Each thread's scratchpad serves the enc0 bands too (12 KiB for them
   * as for the decoders' bands on this project's machines). */
  if (lay.tband != OD_NONE || lay.ebh)
    own += threads * od_scratch_allowance(lay.tband_floats * f) + 64 + page;
  return lay.total + page + own + weights;
}

/* A model's count includes the arena when it is the model that last ran
 * (or, once that one has no plan left, one that has a valid plan). */
static size_t od_cached_locked(const od_model *m) {
  size_t n = m->dev->arena_owner == m ? m->dev->arena_bytes : 0;
  for (int k = 0; k < OD_PLAN_CACHE; k++)
    if (m->plans[k]) n += m->plans[k]->bytes;
  return n;
}

static size_t od_model_cached_bytes(void *impl) {
  od_model *m = impl;
  pthread_mutex_lock(&m->dev->lock);
  size_t n = od_cached_locked(m);
  pthread_mutex_unlock(&m->dev->lock);
  return n;
}

/* Frees the model's plans until it counts at most keep bytes: those laid
 * out in an arena that moved first, then the largest. The arena shrinks to
 * what the valid plans left need, and passes to a model that has one. */
static void od_model_trim(void *impl, size_t keep) {
  od_model *m = impl;
  od_dev *d = m->dev;
  pthread_mutex_lock(&d->lock);
  while (od_cached_locked(m) > keep) {
    int big = -1;
    for (int k = 0; k < OD_PLAN_CACHE; k++) {
      const od_plan *p = m->plans[k], *b = big < 0 ? NULL : m->plans[big];
      if (!p) continue;
      int pv = od_plan_valid(d, p), bv = b && od_plan_valid(d, b);
      if (!b || (bv && !pv) || (bv == pv && p->need + p->bytes > b->need + b->bytes)) big = k;
    }
    if (big < 0) break;
    od_plan_free(m->plans[big]);
    m->plans[big] = NULL;
    od_arena_fit(d);
  }
  pthread_mutex_unlock(&d->lock);
}

const hf_backend_ops hf_backend_cpu_onednn = {
  .name = "cpu",
  .priority = 50,
  .reads_f16 = 1,
  .archs = 1u << HF_ARCH_UNET | 1u << HF_ARCH_RESIDUAL | 1u << HF_ARCH_KERNEL,
  .probe = od_probe,
  .open = od_open,
  .close = od_close,
  .model_create = od_model_create,
  .model_destroy = od_model_destroy,
  .model_run = od_model_run,
  .model_run_scan = od_model_run_scan,
  .model_precision = od_model_precision,
  .run_bytes = od_run_bytes,
  .model_cached_bytes = od_model_cached_bytes,
  .model_trim = od_model_trim,
};
