/*
 * The interface every inference backend implements (internal to src/).
 *
 * A backend is a table of functions. hf_backend_create() in backend.c picks
 * one by name; hf_model_* forward to it. Backends own their device state;
 * the common code owns argument checking, so a backend may assume:
 *   - cfg passed hf_net_config_validate();
 *   - io->batch >= 1, io->width >= 1, io->height >= 1, pointers non-NULL,
 *     io dtypes are HF_F32 or HF_F16.
 * Padding to multiples of 2^L and cropping back is the backend's job, since
 * a GPU backend does it on the device.
 */
#ifndef HF_BACKEND_H
#define HF_BACKEND_H

#include "hfcore.h"

/* For the cpu backend's own hot loops: compiled for the widest vector unit
 * the CPU has, chosen when the program loads (GCC's function
 * multiversioning), since the build targets any x86-64 (SSE2). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define HF_CPU_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define HF_CPU_CLONES
#endif

/* model_run_scan's answers besides HF_OK and the (negative) errors. */
#define HF_RUN_DECLINED 1
#define HF_RUN_UNCLEAN 2

typedef struct hf_backend_ops {
  const char *name;
  /* Larger is preferred by "auto". */
  int priority;
  /* 1: model_run takes float16 inputs as they are (a GPU uploads the
   * halves; the cpu backend widens them a band at a time where its passes
   * read the input), checked in one pass that only reads them. 0: the
   * backend computes from float32 in host memory, and the common code
   * hands it an f16 input already widened to float32, made in the same
   * pass as the out-of-contract check (hf_features_widen), where the
   * frame's size allows (backend.c, sanitise_input). */
  int reads_f16;
  /* Architectures implemented, as a mask of 1 << hf_arch; 0 means the
   * paper's U-Net only. hf_model_create refuses the others. */
  unsigned archs;
  /* 0 when usable here, else HF_EUNAVAILABLE with why filled in. */
  int (*probe)(char *why, size_t whylen);
  /* Device-wide state (handles, streams); may be NULL. */
  int (*open)(void **dev, char *why, size_t whylen);
  void (*close)(void *dev);
  /* A prepared network. */
  int (*model_create)(void *dev, const hf_weights *w, void **model);
  void (*model_destroy)(void *model);
  int (*model_run)(void *model, const hf_io *io, hf_timing *timing);
  /* Optional: model_run that also makes, in its own first read of the
   * input, what backend.c's pass before model_run makes (sanitise_input):
   * rep ([io->batch]) gets hf_features_scan's report of each frame and
   * stats, when not NULL, its statistics, so that the frame is read from
   * memory once; *guarded set to 1 when it also applied hf_output_guard
   * to every output row as it made it (the counts in rep[n].outputs), so
   * that backend.c does not read the output again. Besides HF_OK and the
   * errors it answers HF_RUN_DECLINED
   * (an io it does not scan itself: nothing read or written) and
   * HF_RUN_UNCLEAN (a frame has out-of-contract samples, the reports say
   * which: io->out is untouched), and backend.c then checks and sanitises
   * the input itself and runs model_run. */
  int (*model_run_scan)(void *model, const hf_io *io, hf_timing *timing, hf_input_report *rep,
                        hf_input_stats *stats, int *guarded);
  const char *(*model_precision)(void *model);
  /* Device memory held by the model (weights, activations, workspace);
   * NULL means 0 (host-only backends). */
  size_t (*model_device_bytes)(void *model);
  /* Optional (NULL: nothing to do): build what a shape needs ahead of its
   * first run (hf_model_prepare). */
  int (*model_prepare)(void *model, int batch, int width, int height);
  /* Optional, both or neither: asynchronous runs (hf_model_submit/wait).
   * Without them the common code runs io inside submit. */
  int (*model_submit)(void *model, const hf_io *io);
  int (*model_wait)(void *model, hf_timing *timing);
  /* Optional, with model_submit: model_submit that takes io as it came and
   * makes, itself (on the device), what backend.c's pass before
   * model_submit makes (sanitise_input): each out-of-contract sample fixed
   * by the rule in its own copy of the input, rep ([io->batch]) given
   * hf_features_check's report of each frame and stats, when not NULL,
   * hf_input_stats_compute's values, both filled in by the model_wait that
   * completes the run (io->in must stay as it is until then), which has
   * also applied hf_output_guard's rule to the outputs (the counts in
   * rep[n].outputs). Answers
   * HF_RUN_DECLINED (nothing started) for an io it does not check itself,
   * which then takes the common path. */
  int (*model_submit_scan)(void *model, const hf_io *io, hf_input_report *rep,
                           hf_input_stats *stats);
  /* Optional: 1 when a run with reports reads io->in == in ([bytes]) once
   * (hf_model_reads_input_once); absent: 0. */
  int (*model_reads_input_once)(void *model, const void *in, size_t bytes);
  /* Optional: host memory that will hold tensors (hf_backend_host_register). */
  int (*host_register)(void *dev, void *ptr, size_t bytes);
  void (*host_unregister)(void *dev, void *ptr);
  /* Host memory one run of batch frames of padded size pw x ph allocates or
   * keeps (hf_run_bytes): an upper bound computed from cfg alone, callable
   * from any thread. */
  size_t (*run_bytes)(const hf_net_config *cfg, int batch, int pw, int ph);
  /* Host memory the model keeps between runs (cached plans); NULL: none. */
  size_t (*model_cached_bytes)(void *model);
  /* Frees cached plans, largest first, until at most keep bytes remain;
   * NULL when nothing is cached. */
  void (*model_trim)(void *model, size_t keep);
} hf_backend_ops;

extern const hf_backend_ops hf_backend_cpu_ref;
#ifdef HF_HAVE_ONEDNN
extern const hf_backend_ops hf_backend_cpu_onednn;
#endif
#ifdef HF_HAVE_CUDNN
extern const hf_backend_ops hf_backend_cudnn;
#endif

/* Frames whose reports a scanning run keeps itself when the caller wants
 * none (model_run_scan, model_submit_scan). */
#define HF_SCAN_OWN_REPORTS 16

struct hf_backend {
  const hf_backend_ops *ops;
  void *dev;
};

struct hf_model {
  hf_backend *backend;
  hf_net_config cfg;
  void *impl;
  /* Runs pending through hf_model_submit, oldest first; results kept here
   * for backends that run inside submit, and what the output guard needs. */
  int npending, head;
  struct {
    int rc;
    hf_timing t;
    hf_io io;                  /* the caller's */
    hf_input_report *report;   /* the caller's, own, or NULL */
    hf_input_report own[HF_SCAN_OWN_REPORTS];   /* when the caller wants none */
    double input_us;           /* the out-of-contract check at submit */
    int guarded;               /* the backend applied the output guard */
  } pending[HF_MAX_PENDING];
  /* Per slot (hf_model_run uses slot 0), the sanitised copy of an input
   * that needed one, kept for the next (backend.c, HF_SANITISED_KEEP). */
  struct {
    void *buf;
    size_t cap;
  } sanitised[HF_MAX_PENDING];
};

/* Shared helpers for CPU backends. */

/* Converts io->in to dense float32 NHWC, zero-padded to (pw, ph) per frame:
 * dst is [batch][ph][pw][cin]. */
void hf_input_to_padded_f32(const hf_io *io, int cin, int pw, int ph, float *dst);
/* Finishes the raw network output src ([batch][ph][pw][cfg->out_channels])
 * with hf_output_finish's values (which read the padded input in,
 * [batch][ph][pw][cin], for the residual and kernel architectures), crops
 * to io->width x io->height and stores in io->out's dtype. */
void hf_output_from_padded_f32(const hf_net_config *cfg, const float *in, const float *src,
                               int pw, int ph, const hf_io *io);
/* Host memory hf_output_from_padded_f32 allocates for io's frames (a row
 * of an f16 result in float, the Residual base or the Kernel output of a
 * frame, and its scratch). */
size_t hf_output_extra_bytes(const hf_net_config *cfg, int width, int height);
/* The Kernel architecture's output stage across each row's pixels
 * (cpu_kernel_output.c), the values of hf_kernel_output_rows up to
 * rounding: hf_cpu_kernel_sums writes the per-pixel sums of kind ksums
 * (HF_KSUMS_*; hf_pixel_sums_rows) of rows y0..y1-1 as
 * hf_kernel_sums_floats(ksums) planes (planes: [k][in->height][in->width],
 * covered count, colour, highlight, then with HF_KSUMS_MIXED the
 * estimate's three); hf_cpu_kernel_rows reads them for rows
 * y0-radius..y1-1+radius and writes rows y0..y1-1 of out
 * ([height][width][3]), with scratch of hf_cpu_kernel_scratch(width, radius)
 * floats. */
size_t hf_cpu_kernel_scratch(int width, int radius);
void hf_cpu_kernel_sums(const hf_input_view *in, int spp, int ksums, int y0, int y1,
                        float *planes);
/* The sums of one row of width pixels px (stride floats apart) into
 * planes[x], planes[plane + x], planes[2 plane + x] (and 3..5 plane with
 * HF_KSUMS_MIXED): hf_cpu_kernel_sums a row at a time, for a caller that has
 * the row elsewhere. ksums: the network's (hf_kernel_sums_of). */
void hf_cpu_kernel_sums_row(const float *px, int width, int stride, int spp, int ksums,
                            float *planes, size_t plane);
void hf_cpu_kernel_rows(int width, int height, int spp, int radius, int ksums,
                        const float *planes, const float *raw, int raw_pitch, int raw_stride,
                        int y0, int y1, float *out, float *scratch);
/* Rounds n up to a multiple of a (a power of two). */
static inline int hf_round_up(int n, int a) { return (n + a - 1) & ~(a - 1); }
/* Monotonic clock in microseconds. */
double hf_now_us(void);

#endif /* HF_BACKEND_H */
