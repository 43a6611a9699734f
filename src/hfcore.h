/*
 * hfcore: the hair-filtering network, its weights, its inference backends,
 * and the image helpers around them.
 *
 * The network is the U-Net of Currius, Assarsson & Sintorn (2022), section
 * 3.3. A variant is a configuration (samples per pixel, channels per level),
 * never code: every implementation (cpu-ref, cpu, cudnn, the PyTorch recipe in
 * weights/) reads the same hf_net_config and wires the layers the same way:
 *
 *   enc{i}, i = 0..L-1: 3x3 conv, stride 2, pad 1, ReLU; H/2^i -> H/2^(i+1),
 *                       c_i output channels; input is the network input for
 *                       i = 0, else enc{i-1}'s output.
 *   dec{i}, i = L-1..0: 4x4 transposed conv, stride 2, pad 1; H/2^(i+1) ->
 *                       H/2^i; input is enc{L-1}'s output for i = L-1, else
 *                       concat(dec{i+1} output, enc{i} output) (2*c_i ch);
 *                       output c_{i-1} channels with ReLU, or 3 for dec0
 *                       with no ReLU but the output transforms.
 *
 * The architectures beyond the paper change only the end: HF_ARCH_RESIDUAL
 * adds dec0's 3 channels to an estimate read off the samples; HF_ARCH_KERNEL
 * has dec0 output the kernel's taps + 3 channels, or kernel_hidden channels
 * with ReLU followed by the 1x1 head over them and the network input, and
 * reads the output off the samples of the pixels around each pixel with the
 * kernel those channels give (hf_net_config).
 *
 * Tensors in memory are NHWC, float32 unless a function says otherwise.
 * Input channels are sample-major: sample k's six features occupy channels
 * 6k..6k+5 in the order of HF_FEATURE_NAMES. Output channels are
 * (color, highlight, alpha). Frames whose sides are not multiples of 2^L are
 * zero-padded at the right and bottom and the output is cropped back.
 *
 * Errors are negative HF_E* codes; hf_strerror() names them.
 */
#ifndef HFCORE_H
#define HFCORE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- errors ------------------------------------------------------------ */

#define HF_OK            0
#define HF_EINVAL       -1  /* bad argument */
#define HF_ENOMEM       -2  /* allocation failed */
#define HF_EIO          -3  /* file could not be read or written */
#define HF_EFORMAT      -4  /* malformed or inconsistent file contents */
#define HF_EUNSUPPORTED -5  /* valid, but not something this build does */
#define HF_EUNAVAILABLE -6  /* backend cannot run here (no GPU, ...) */
#define HF_ERANGE       -7  /* size or count out of the allowed range */
#define HF_EBACKEND     -8  /* the backend library reported an error */
#define HF_ENOTFOUND    -9  /* named thing (variant, channel, backend) absent */

const char *hf_strerror(int err);

/* ---- network configuration --------------------------------------------- */

#define HF_FEATURES_PER_SAMPLE 6
#define HF_OUT_CHANNELS        3
#define HF_MAX_LEVELS          8
#define HF_MAX_SPP             16
#define HF_MAX_CHANNELS        4096
#define HF_NAME_MAX            64

/* Per-sample input features, in channel order. */
extern const char *const HF_FEATURE_NAMES[HF_FEATURES_PER_SAMPLE];
/* Output channels, in channel order. */
extern const char *const HF_OUTPUT_NAMES[HF_OUT_CHANNELS];

enum { HF_OUT_COLOR = 0, HF_OUT_HIGHLIGHT = 1, HF_OUT_ALPHA = 2 };

/* Architectures. HF_ARCH_UNET is the paper's network. HF_ARCH_RESIDUAL is the
 * same U-Net whose raw output is a residual added to the stochastic-
 * transparency estimate read off the samples of a small window around the
 * pixel (hf_residual_base), so coverage and colour come from the samples and
 * the network learns the correction, not a prior (protocol/FEATURES.md,
 * "Residual architecture"). HF_ARCH_KERNEL (beyond the paper;
 * protocol/FEATURES.md, "Kernel architecture") is the same U-Net whose raw
 * output is, per pixel, the logits of a softmax kernel over the
 * (2r+1)^2 pixels around it and three corrections: the result is the
 * stochastic-transparency estimate of those pixels' samples weighted by the
 * kernel, plus the corrections (hf_kernel_output_frame). */
typedef enum hf_arch { HF_ARCH_UNET = 0, HF_ARCH_RESIDUAL = 1, HF_ARCH_KERNEL = 2 } hf_arch;

#define HF_KERNEL_MAX_RADIUS 4  /* kernels of up to 9x9 pixels */

/* What a network reads besides the samples (hf_net_config.estimate).
 * HF_ESTIMATE_ALPHA_CORRECTED: stochastic transparency's alpha-corrected
 * estimate of each pixel (Enderton et al. 2010, section 3.3; the renderer's
 * acst4.* channels, `hairfilter render --alpha-corrected`): colour factor,
 * highlight (both not premultiplied) and alpha, HF_ESTIMATE_CHANNELS values
 * per pixel. The network reads them as 3 input channels after the samples'
 * (channel 6 spp + j), and the Kernel output stage weighs them instead of
 * the samples' own estimate (protocol/FEATURES.md, "The alpha-corrected
 * estimate"). */
enum { HF_ESTIMATE_NONE = 0, HF_ESTIMATE_ALPHA_CORRECTED = 1 };
#define HF_ESTIMATE_CHANNELS 3

/* What a Kernel network's kernel weighs at each tap (hf_kernel_sums_of):
 * the samples' own sums (Kernel), the alpha-corrected estimate's
 * (KernelAC), or both, mixed at each output pixel by one more raw channel
 * (KernelMix, hf_net_config.kernel_mix). The first two equal
 * HF_ESTIMATE_NONE and HF_ESTIMATE_ALPHA_CORRECTED, so a network's estimate
 * also says what its kernel weighs when it does not mix. */
enum { HF_KSUMS_SAMPLES = 0, HF_KSUMS_ESTIMATE = 1, HF_KSUMS_MIXED = 2 };
/* beta = 1 / (1 + e^(-HF_KERNEL_MIX_GAIN m)) for the mixing channel m
 * (weights/hfnet.py KERNEL_MIX_GAIN, the same value): the gain lets a
 * training run move beta as far as it moves the logits. */
#define HF_KERNEL_MIX_GAIN 16.0f
#define HF_KERNEL_MAX_HIDDEN 64
/* Most raw output channels of any network: the 9x9 kernel's taps + 3, and
 * the mixing channel. */
#define HF_MAX_RAW_CHANNELS  ((2 * HF_KERNEL_MAX_RADIUS + 1) * (2 * HF_KERNEL_MAX_RADIUS + 1) + HF_OUT_CHANNELS + 1)

typedef struct hf_net_config {
  char name[HF_NAME_MAX];
  int spp;                      /* samples per pixel, 1..HF_MAX_SPP */
  int in_channels;              /* spp * HF_FEATURES_PER_SAMPLE, plus
                                 * HF_ESTIMATE_CHANNELS with an estimate */
  int out_channels;             /* raw output channels: HF_OUT_CHANNELS, or
                                 * hf_kernel_taps(kernel_radius) + HF_OUT_CHANNELS
                                 * for HF_ARCH_KERNEL */
  int num_levels;               /* L */
  int levels[HF_MAX_LEVELS];    /* c_0 .. c_{L-1} */
  int arch;                     /* hf_arch */
  /* HF_ARCH_KERNEL only, 0 for the others (beyond the paper;
   * protocol/FEATURES.md, "Kernel architecture"):
   *   kernel_radius r, 1..HF_KERNEL_MAX_RADIUS: pixel (x, y)'s kernel covers
   *     the pixels x-r..x+r, y-r..y+r (taps (2r+1)^2, row-major: tap
   *     t = (dy+r)(2r+1) + dx+r is the pixel (x+dx, y+dy)); raw channels
   *     0..taps-1 are its logits, taps..taps+2 the colour, highlight and
   *     alpha corrections.
   *   kernel_hidden h, 0..HF_KERNEL_MAX_HIDDEN: 0, dec0 outputs the
   *     out_channels raw channels; h > 0, dec0 outputs h channels with ReLU
   *     and a 1x1 convolution, the head (hf_weights.head_w, head_b), maps
   *     concat(ReLU(dec0) (h channels), the network input (in_channels,
   *     zero in the padding)) to the out_channels raw channels, so each
   *     pixel's kernel also sees its own samples at full resolution. */
  int kernel_radius;
  int kernel_hidden;
  /* HF_ESTIMATE_NONE, or HF_ESTIMATE_ALPHA_CORRECTED (HF_ARCH_KERNEL only):
   * each frame also carries the alpha-corrected estimate; a frame in
   * memory is then its samples, [h][w][spp * 6], followed by the estimate,
   * [h][w][3] (hf_io), and the network reads both per pixel. */
  int estimate;
  /* HF_ARCH_KERNEL with an estimate only, else 0 (beyond the paper;
   * protocol/FEATURES.md, "Kernel architecture"): 1, raw channel taps + 3 is
   * m, and pixel p's kernel weighs both its taps' samples' sums S and their
   * estimate's E (hf_pixel_sums, hf_estimate_sums), mixed at p: (N, C, H) =
   * sum w E + beta (sum w S - sum w E), beta = 1 / (1 + e^(-HF_KERNEL_MIX_GAIN
   * m)); out_channels counts m. 0, the kernel weighs the estimate alone. */
  int kernel_mix;
} hf_net_config;

/* The seven variants of the paper's Table 1, by name ("Base", "Base@1spp",
 * "Base@2spp", "Large", "Small", "Shallow", "Deep"), "Residual" (Base's
 * shape with HF_ARCH_RESIDUAL), "Kernel" (Base's shape with
 * HF_ARCH_KERNEL, kernel_radius 3, kernel_hidden 32), "KernelAC"
 * (Kernel's shape reading HF_ESTIMATE_ALPHA_CORRECTED) and "KernelMix"
 * (KernelAC with kernel_mix), case-insensitive. */
int hf_variant_preset(const char *name, hf_net_config *out);
/* Number of presets and the i-th preset's name, for listings. */
int hf_variant_preset_count(void);
const char *hf_variant_preset_name(int i);

/* Checks that a configuration describes a network every backend can run. */
int hf_net_config_validate(const hf_net_config *cfg);
/* Values per pixel of a frame of cfg (in_channels): spp * 6 samples'
 * features, plus HF_ESTIMATE_CHANNELS with an estimate. */
int hf_net_in_channels(int spp, int estimate);
/* What cfg's kernel weighs, HF_KSUMS_*: HF_KSUMS_MIXED with kernel_mix,
 * else cfg->estimate (HF_KSUMS_SAMPLES for a network without a kernel). */
int hf_kernel_sums_of(const hf_net_config *cfg);
/* Floats per pixel of the sums of kind ksums: 6 for HF_KSUMS_MIXED (the
 * samples' three, then the estimate's), else 3. */
int hf_kernel_sums_floats(int ksums);
/* Name of an estimate in the weights' metadata and in messages
 * ("alpha_corrected"; "none"), and back (HF_ENOTFOUND). */
const char *hf_estimate_name(int estimate);
int hf_estimate_from_name(const char *name);
/* The frame side multiple a network needs: 2^L. */
int hf_net_align(const hf_net_config *cfg);
/* Input channels of enc{i} and dec{i}, output channels of enc{i}/dec{i}. */
int hf_enc_in(const hf_net_config *cfg, int i);
int hf_enc_out(const hf_net_config *cfg, int i);
int hf_dec_in(const hf_net_config *cfg, int i);
int hf_dec_out(const hf_net_config *cfg, int i);
/* Taps of a kernel of half side radius: (2 radius + 1)^2. */
int hf_kernel_taps(int radius);
/* Input channels of the head, kernel_hidden + in_channels; 0 for a network
 * without one (every architecture but HF_ARCH_KERNEL with kernel_hidden > 0). */
int hf_head_in(const hf_net_config *cfg);
/* Multiply-accumulates of one forward pass at w x h (after padding): the
 * convolutions, the head, and for HF_ARCH_KERNEL 4 per tap and pixel in the
 * output stage (the weight's normalisation and its three weighted sums). */
double hf_net_macs(const hf_net_config *cfg, int w, int h);

/* ---- input statistics: types (functions below) -------------------------- */

/* Per-frame statistics of a network input that say which regime the frame
 * is in (protocol/FEATURES.md, "Input statistics", is the definition). A
 * pixel's covered samples are those with alpha > 0; a hair pixel has at
 * least one. */
enum {
  HF_STAT_STRAND_ALPHA_P50 = 0, /* median over hair pixels of hf_pixel_strand_alpha */
  HF_STAT_STRAND_ALPHA_P90,     /* its 90th percentile */
  HF_STAT_FULL_COVERAGE,        /* hair pixels with all spp samples covered / hair pixels */
  HF_STAT_HAIR_FRACTION,        /* hair pixels / pixels */
  HF_STAT_LONG_SIDE,            /* max(width, height), pixels */
  HF_STAT_COUNT
};

/* Version of those definitions, recorded with every range. */
#define HF_INPUT_STATS_DEFINITION 1

typedef struct hf_input_stats {
  int width, height, spp;
  uint64_t hair_pixels;         /* pixels with at least one covered sample */
  uint64_t full_pixels;         /* pixels with all spp samples covered */
  double value[HF_STAT_COUNT];  /* by HF_STAT_*; NAN where undefined (no hair pixel) */
} hf_input_stats;

/* The range [lo, hi] of each statistic over a variant's training frames,
 * from the weights' `input_range` metadata (weights/FORMAT.md). */
typedef struct hf_input_range {
  int present;                  /* 0: the weights carry no (usable) range */
  int spp;                      /* the statistics were computed at this spp */
  int frames;                   /* training frames measured */
  unsigned has;                 /* bit k: statistic k has a range */
  double lo[HF_STAT_COUNT], hi[HF_STAT_COUNT];
} hf_input_range;

/* ---- weights ------------------------------------------------------------ */

/* Host-side float32 weights in PyTorch layouts:
 *   enc_w[i]: [out][in][3][3]   (Conv2d)
 *   dec_w[i]: [in][out][4][4]   (ConvTranspose2d)
 *   enc_b[i], dec_b[i]: [out]
 *   head_w: [out_channels][kernel_hidden + in_channels][1][1] (Conv2d),
 *   head_b: [out_channels]; NULL without a head (hf_head_in() == 0)     */
typedef struct hf_weights {
  hf_net_config cfg;
  char features[HF_FEATURES_PER_SAMPLE][32];
  float *enc_w[HF_MAX_LEVELS], *enc_b[HF_MAX_LEVELS];
  float *dec_w[HF_MAX_LEVELS], *dec_b[HF_MAX_LEVELS];
  float *head_w, *head_b;
  size_t num_params;
  hf_input_range input_range;   /* from the metadata; .present 0 without one */
  void *storage;                /* one allocation behind every array */
} hf_weights;

/* Loads a safetensors file (see weights/FORMAT.md). Every length and offset
 * in the file is checked before use, a key named twice in one JSON object is
 * refused, and "__metadata__" must be an object of strings; on failure *out
 * is NULL (HF_EFORMAT, HF_EUNSUPPORTED, HF_EIO, HF_ENOMEM, HF_ERANGE) and err
 * (when not NULL) holds a one-line reason. */
int hf_weights_load(const char *path, hf_weights **out, char *err, size_t errlen);
int hf_weights_load_mem(const void *buf, size_t len, hf_weights **out,
                        char *err, size_t errlen);
/* Writes float32 safetensors with the metadata of w->cfg (and w->input_range
 * when present), into path.tmp renamed over path once whole: a file at path
 * is never half written, and survives a failed write (HF_EIO). */
int hf_weights_save(const char *path, const hf_weights *w);
/* Allocates zeroed weights for cfg. */
int hf_weights_alloc(const hf_net_config *cfg, hf_weights **out);
/* PyTorch-default-like uniform initialisation from a seed (tests, benches). */
int hf_weights_init_random(const hf_net_config *cfg, uint64_t seed, hf_weights **out);
void hf_weights_free(hf_weights *w);

/* ---- inference ---------------------------------------------------------- */

typedef enum hf_dtype { HF_F32 = 0, HF_F16 = 1 } hf_dtype;

/* Microseconds spent in one run, as the backend saw it. */
typedef struct hf_timing {
  double input_us;    /* upload / convert / pad the input */
  double infer_us;    /* the network itself */
  double output_us;   /* transforms, crop, download */
} hf_timing;

/* Out-of-contract values (protocol/FEATURES.md, "Out-of-contract values"):
 * the bounds finite features are clamped into are [0, HF_FEATURE_LIGHT_MAX]
 * for color and highlight, (0, 1] for alpha, [0, 1] for depth, [-1, 1] for
 * the tangent; outputs are kept in color [-HF_OUTPUT_MAX, HF_OUTPUT_MAX],
 * highlight [0, HF_OUTPUT_MAX], alpha [0, 1] (HF_OUTPUT_MAX: the largest
 * binary16, so either output dtype holds every result). */
#define HF_FEATURE_LIGHT_MAX 64.0f
#define HF_OUTPUT_MAX        65504.0f

/* What was wrong with the first sanitised sample of a frame. */
enum {
  HF_SANITISED_NONFINITE = 1, /* a feature is NaN or infinite: made uncovered */
  HF_SANITISED_UNCOVERED = 2, /* alpha <= 0, the sample not all zero: made uncovered */
  HF_SANITISED_CLAMPED = 3    /* a finite feature outside its range: clamped */
};

/* What sanitising found in one frame: the number of samples changed, and
 * the first one in memory order (pixel x, y of the frame, sample, feature
 * index into HF_FEATURE_NAMES, its value before, kind HF_SANITISED_*; x, y,
 * sample and feature are -1 when samples is 0), plus output values repaired
 * by hf_model_run's output guard. With an estimate (hf_net_config.estimate),
 * samples also counts the pixels whose estimate was changed; sample is
 * HF_REPORT_ESTIMATE when the first change is one, feature then an index
 * into HF_OUTPUT_NAMES (the estimate's colour, highlight, alpha). */
#define HF_REPORT_ESTIMATE (-2) /* hf_input_report.sample: the pixel's estimate */

typedef struct hf_input_report {
  uint64_t samples;
  int x, y, sample, feature, kind;
  float value;
  uint64_t outputs;
} hf_input_report;

/* Counts the out-of-contract samples of one frame ([height][width][spp*6]
 * of dtype) without changing it. */
void hf_features_check(const void *in, hf_dtype dtype, int width, int height, int spp,
                       hf_input_report *report);
/* Applies the rule to one frame in place: a sample with a non-finite
 * feature, or with alpha <= 0 and not all zero, becomes all 0
 * (uncovered); finite features outside their range are clamped into it. */
void hf_features_sanitise(void *in, hf_dtype dtype, int width, int height, int spp,
                          hf_input_report *report);
/* hf_features_sanitise on a copy: out ([height][width][spp*6] of dtype) gets
 * in with the rule applied, in is not written; report as
 * hf_features_sanitise's. Split between threads for large frames
 * (hf_parallel_chunks), each copying a chunk and fixing it while it is in
 * the cache, so one bad sample does not cost a single-threaded pass over
 * the frame. in and out must not overlap. HF_OK, or HF_ENOMEM (nothing
 * written). */
int hf_features_copy_sanitised(const void *in, void *out, hf_dtype dtype, int width, int height,
                               int spp, hf_input_report *report);
/* A binary16 frame in ([height][width][spp*6]) widened to float32 in out
 * (same shape) for a backend that computes in float32, with the rule
 * applied on the way: out is hf_f16_to_f32 of what hf_features_sanitise
 * makes of a copy of in, bit for bit, and report is what
 * hf_features_check(in, HF_F16, ...) reports; stats, when not NULL, gets
 * hf_input_stats_compute(in, HF_F16, ...)'s values. One pass over in
 * instead of a check, a copy, a conversion and the statistics' pass:
 * chunks of pixels whose halves stay in the cache from their conversion to
 * their check, split between threads for large frames
 * (hf_parallel_chunks). in is not written; in and out must not overlap.
 * out may be NULL: the same pass without the floats (the report and the
 * statistics only), for a backend that reads the halves itself.
 * HF_ENOMEM (nothing written) when the statistics' counts (16 KiB per
 * thread) cannot be allocated. */
int hf_features_widen(const uint16_t *in, float *out, int width, int height, int spp,
                      hf_input_report *report, hf_input_stats *stats);
/* hf_features_check's report and, when stats is not NULL,
 * hf_input_stats_compute's values for one frame ([height][width][spp*6] of
 * dtype, HF_F32 or HF_F16), in one pass that only reads it, split between
 * threads for large frames as hf_features_widen is: what hf_model_run does
 * to every frame before a backend sees it, at about the speed of a copy.
 * HF_ENOMEM (report and stats unset) when the statistics' counts cannot be
 * allocated. */
int hf_features_scan(const void *in, hf_dtype dtype, int width, int height, int spp,
                     hf_input_report *report, hf_input_stats *stats);
/* A frame of a network with an estimate, planar as hf_io holds it (in: the
 * samples, [height][width][spp * 6], then the estimate, [height][width][3],
 * of dtype), interleaved into out ([height][width][spp * 6 + 3] of the same
 * dtype) as the backends read it, with the rule applied on the way: the
 * samples as hf_features_sanitise does, the estimate by its own rule
 * (protocol/FEATURES.md, "The alpha-corrected estimate": a non-finite value,
 * or alpha <= 0 beside a non-zero value, makes all three 0; colour and
 * highlight are clamped to [0, HF_FEATURE_LIGHT_MAX], alpha to at most 1).
 * report gets what was changed (hf_input_report), stats, when not NULL,
 * hf_input_stats_compute's values of the samples. One pass over in that
 * reads each value once (each pixel's samples copied into out and checked
 * there, split between threads for large frames, hf_parallel_chunks), so
 * what is checked is what out holds though another process writes in
 * meanwhile. in and out must not overlap. HF_ENOMEM (out unset) when the statistics' counts cannot be
 * allocated. */
int hf_features_interleave(const void *in, hf_dtype dtype, int width, int height, int spp,
                           void *out, hf_input_report *report, hf_input_stats *stats);
/* The report of a frame ([height][width][spp*6] of dtype) whose
 * out-of-contract samples another pass counted (the cudnn backend's device
 * check, hf_cuk_scan): samples of them, the first at sample index first
 * (pixel first / spp, sample first % spp), which is read from in (not
 * written) for its feature, kind and value. The report hf_features_check
 * gives when the count and index are right; samples 0 gives the empty
 * report. */
void hf_features_report_counted(const void *in, hf_dtype dtype, int width, int spp,
                                uint64_t samples, size_t first, hf_input_report *report);
/* hf_features_scan's report and statistics made part by part, for a pass
 * that reads a frame anyway, in pieces and on several threads (the cpu
 * backend's enc0 bands), so that the frame is read from memory once: each
 * part is initialised (acc: its statistics' counts, or NULL for none), gets
 * any pixel ranges [p0, p1) of the frame (in: the frame, [pixels][spp*6] of
 * dtype, width pixels wide) in any order, and the parts are finished
 * together into one report and, when stats is not NULL (every part then
 * has an acc), the frame's statistics: the values hf_features_scan gives,
 * bit for bit, whatever the split. Finishing merges every acc into
 * parts[0]'s. */
typedef struct hf_scan_part {
  hf_input_report report;
  struct hf_input_stats_acc *acc;
} hf_scan_part;
void hf_scan_part_init(hf_scan_part *s, struct hf_input_stats_acc *acc);
void hf_scan_part_add(hf_scan_part *s, const void *in, hf_dtype dtype, int width, int spp,
                      size_t p0, size_t p1);
void hf_scan_parts_finish(hf_scan_part *parts, int nparts, int width, int height, int spp,
                          hf_input_report *report, hf_input_stats *stats);
/* Keeps pixels outputs ([pixels][3] of dtype) in their ranges: NaN becomes
 * the channel's neutral value (color 1, highlight 0, alpha 0), anything else
 * is clamped. Split between threads for large frames (hf_parallel_chunks).
 * Returns the number of pixels changed. */
uint64_t hf_output_guard(void *out, hf_dtype dtype, size_t pixels);
/* hf_output_guard on the calling thread alone, for a backend that guards
 * its output a row at a time while the row is in the cache (the cpu
 * backend's dec0): the same values and count. */
uint64_t hf_output_guard_serial(void *out, hf_dtype dtype, size_t pixels);

/* One batch of frames of the same size. in: [batch][h][w][in_channels],
 * out: [batch][h][w][3], both NHWC, dense, of the given dtypes. For a
 * network with an estimate (hf_net_config.estimate), each frame of in is
 * planar: its samples, [h][w][spp * 6], then its estimate, [h][w][3]
 * (still h * w * in_channels values a frame), as a renderer makes them in
 * two targets; hf_model_run interleaves them for the backend. */
typedef struct hf_io {
  int batch, width, height;
  const void *in;  hf_dtype in_dtype;
  void *out;       hf_dtype out_dtype;
} hf_io;

typedef struct hf_backend hf_backend;   /* a device and its library handles */
typedef struct hf_model hf_model;       /* a network prepared on a backend */

/* name: "cpu-ref", "cpu", "cudnn" or "auto" (best available). When a named
 * backend cannot run, returns HF_EUNAVAILABLE with the reason in why. For
 * "auto", why says which backend was chosen over which and why. */
int hf_backend_create(const char *name, hf_backend **out, char *why, size_t whylen);
void hf_backend_destroy(hf_backend *b);
const char *hf_backend_name(const hf_backend *b);
/* Names of the backends compiled into this build, NULL-terminated. */
const char *const *hf_backend_list(void);

/* Prepares weights on a backend. The model keeps no pointer into w. */
int hf_model_create(hf_backend *b, const hf_weights *w, hf_model **out);
void hf_model_destroy(hf_model *m);
const hf_net_config *hf_model_config(const hf_model *m);
/* Runs the network on io; timing may be NULL. Every backend sees the input
 * after hf_features_sanitise (on a copy the model keeps for reuse up to 128
 * MiB: io->in is never written) and its output goes through
 * hf_output_guard, so results are finite and inside their documented ranges
 * whatever the input; hf_model_submit/hf_model_wait do the same. A float16
 * input is checked in one pass that only reads it (hf_features_widen
 * without out), and read by the backend where it is: the cpu backend
 * widens it a band at a time in the passes that read it. For cpu-ref,
 * which computes from float32 frames, one of a size that needs no padding
 * and whose floats fit in those 128 MiB is widened into that copy in the
 * check's own pass instead. The check is attributed to timing->input_us,
 * the guard to output_us; except where the cpu backend makes the check
 * itself in enc0's bands, as the convolution reads the frame (float16
 * frames, float32 frames of a size that needs no padding): it is then part
 * of infer_us, and a frame found to need sanitising is run again through
 * the check's pass and a sanitised copy, with the same results. A network
 * with an estimate (hf_net_config.estimate) takes each frame planar
 * (hf_io) and always runs on such a copy: the frame interleaved, the rule
 * applied to samples and estimate on the way (hf_features_interleave), in
 * input_us. HF_ENOMEM when a frame needs sanitising or widening and there
 * is no memory for the copy. */
int hf_model_run(hf_model *m, const hf_io *io, hf_timing *timing);
/* hf_model_run that also says what it changed: report, when not NULL, is
 * [io->batch], one hf_input_report per frame. */
int hf_model_run_report(hf_model *m, const hf_io *io, hf_timing *timing,
                        hf_input_report *report);
/* hf_model_run_report that also makes each frame's input statistics:
 * stats, when not NULL, is [io->batch] and gets hf_input_stats_compute's
 * values, made in the pass that checks the input (for an f16 frame, the
 * one that also widens it for cpu-ref, hf_features_widen; on the cpu
 * backend, enc0's bands) and counted where the check is. */
int hf_model_run_stats(hf_model *m, const hf_io *io, hf_timing *timing, hf_input_report *report,
                       hf_input_stats *stats);
/* Builds whatever the backend needs to run batch frames of width x height
 * (the cudnn backend: activation buffers, tuned engines and the CUDA graph
 * of that shape; seconds), so the first request of that shape pays
 * nothing. The model keeps it for its life. HF_OK at once for backends that
 * prepare nothing; the arguments are checked like hf_model_run's. */
int hf_model_prepare(hf_model *m, int batch, int width, int height);

/* Runs pending on one model at most. */
#define HF_MAX_PENDING 2

/* Starts a run of io and returns before it finishes, so the caller can
 * bring the next frame while the device works on this one: the cudnn
 * backend uploads frame n+1 while it computes frame n. io's buffers must
 * stay valid and unchanged until the matching hf_model_wait returns. At
 * most HF_MAX_PENDING runs may be pending (HF_ERANGE beyond); backends
 * that cannot overlap run io inside hf_model_submit. One thread at a time
 * may drive a model's submit/wait; hf_model_run must not be mixed in while
 * runs are pending. Errors of the run itself are returned by the wait. */
int hf_model_submit(hf_model *m, const hf_io *io);
/* hf_model_submit that also says what was sanitised: report, when not NULL,
 * is [io->batch] and must stay valid until the matching hf_model_wait,
 * which fills in the output guard's counts (and, for a frame the cudnn
 * backend checks on the device, the rest of it). */
int hf_model_submit_report(hf_model *m, const hf_io *io, hf_input_report *report);
/* hf_model_submit_report that also makes the input statistics as
 * hf_model_run_stats does: stats, when not NULL, is [io->batch], must stay
 * valid until the matching hf_model_wait, and is complete when that
 * returns (the cudnn backend counts a frame in registered memory on the
 * device, with its check: the statistics are then filled only at the
 * wait). */
int hf_model_submit_stats(hf_model *m, const hf_io *io, hf_input_report *report,
                          hf_input_stats *stats);
/* Waits for the oldest pending run and returns its status; timing (may be
 * NULL) gets its hf_timing. HF_EINVAL when no run is pending. */
int hf_model_wait(hf_model *m, hf_timing *timing);
/* 1 when a run of m with reports (hf_model_submit_report and the functions
 * after it) reads the batch input at in ([bytes] bytes) exactly once: a
 * network with an estimate (its samples and estimate are interleaved into
 * a copy, each value read once, hf_features_interleave), or the cudnn
 * backend's DMA of a frame from memory registered with
 * hf_backend_host_register, checked on the device. 0 when the
 * out-of-contract check (protocol/FEATURES.md) and the network read it
 * apart (the CPU backends, a staged upload): a caller whose input another
 * process may write during the run (a shared-memory segment) copies it
 * first, so that what is checked is what is run. */
int hf_model_reads_input_once(const hf_model *m, const void *in, size_t bytes);
/* 1 when hf_model_submit returns before the run ends, so keeping a second
 * run pending overlaps work (the cudnn backend); 0 when submit runs the
 * frame itself (the CPU backends), where a pending run only waits. */
int hf_model_overlaps(const hf_model *m);

/* Tells a backend that [ptr, ptr + bytes) will hold request tensors for a
 * while (a shared-memory segment). The cudnn backend pins it once
 * (cudaHostRegister), and then copies requests whose tensors lie inside it
 * by DMA, with no staging copy. HF_OK when the memory was registered or the
 * backend has no use for it; HF_EBACKEND when pinning failed (requests from
 * it still work, through staging). Safe from any thread. Unregister before
 * the memory is unmapped, with no run pending on it. */
int hf_backend_host_register(hf_backend *b, void *ptr, size_t bytes);
void hf_backend_host_unregister(hf_backend *b, void *ptr);

/* The precision the backend computes in ("fp32", "fp16"). */
const char *hf_model_precision(const hf_model *m);
/* Device memory the model holds, in bytes (0 for host backends). */
size_t hf_model_device_bytes(const hf_model *m);
/* Host memory, in bytes, that one hf_model_run of batch frames of width x
 * height on backend b allocates, or builds and keeps for later runs of that
 * size: padded copies of the input and output, activations, the backend
 * library's scratchpad and staging buffers, and the sanitised copy of an
 * input that breaks the feature contract (protocol/FEATURES.md). An upper
 * bound, checked against
 * the allocations by tests/cpu; not the model's weights (fixed once made),
 * nor a GPU backend's device memory (hf_model_device_bytes). Computed from
 * cfg alone, so it may be called from any thread while models run, and
 * before a frame is admitted. 0 for sizes out of range (width, height and
 * batch >= 1, as hf_model_run accepts them). */
size_t hf_run_bytes(const hf_backend *b, const hf_net_config *cfg, int width, int height,
                    int batch);
/* Host memory the model keeps between runs: the plans of the sizes it has
 * run, so that a size seen before allocates nothing (none for cpu-ref), and
 * the buffers kept for sanitised copies of inputs. Not
 * thread-safe against hf_model_run on the same model. */
size_t hf_model_cached_bytes(const hf_model *m);
/* Frees the sanitised-copy buffers (unless a submitted run is pending),
 * then cached plans, largest first, until at most keep bytes remain; keep
 * 0 frees them all. The next run of a freed size builds its plan again. Not
 * thread-safe against hf_model_run on the same model. */
void hf_model_trim(hf_model *m, size_t keep);

/* The paper's output transforms on one raw network output triple. Inline
 * so that a loop over a row of pixels vectorises (the cpu backend's output
 * stage). */
static inline void hf_output_transform(float *v) {
  float c = v[HF_OUT_COLOR];
  v[HF_OUT_COLOR] = c * c * c / 32.0f + c / 5.0f + 1.0f;
  v[HF_OUT_HIGHLIGHT] = v[HF_OUT_HIGHLIGHT] > 0.0f ? v[HF_OUT_HIGHLIGHT] : 0.0f;
  float a = v[HF_OUT_ALPHA];
  v[HF_OUT_ALPHA] = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}
/* Name of an architecture ("unet", "residual", "kernel"), and back
 * (HF_ENOTFOUND). */
const char *hf_arch_name(int arch);
int hf_arch_from_name(const char *name);
/* The covered samples' count (alpha > 0), colour sum and highlight sum of
 * one pixel's spp*6 input features: the stochastic-transparency estimate
 * before its division. */
void hf_pixel_sums(const float *pixel_in, int spp, float sums[3]);
/* The stochastic-transparency estimate of one pixel from its spp*6 input
 * features: mean colour and highlight of the covered samples (colour 1,
 * highlight 0 when none is), fraction of covered samples as alpha. */
void hf_st_estimate(const float *pixel_in, int spp, float est[3]);

/* Network input of a frame in a buffer that may be padded: pixel (x, y) at
 * data + (y * pitch + x) * stride; only 0 <= x < width, 0 <= y < height are
 * part of the frame. */
typedef struct hf_input_view {
  const float *data;
  int width, height, pitch, stride;
} hf_input_view;

/* Half side of the residual base's window: 2 = 5x5 pixels. */
#define HF_RESIDUAL_RADIUS 2

/* Residual base of pixel (x, y): the stochastic-transparency estimate over
 * the samples of the (2R+1)^2 window around it, cut to the frame: covered
 * fraction of those samples as alpha, mean colour and highlight of the
 * covered ones. Averaging 25 pixels' samples removes most of the noise of
 * 4; what the window blurs is what the network has to put back. */
void hf_residual_base(const hf_input_view *in, int spp, int x, int y, float base[3]);
/* The stochastic-transparency estimate of every pixel of the frame pooled
 * over the (2 radius + 1)^2 window around it, cut to the frame (as
 * hf_residual_base, whose window has radius HF_RESIDUAL_RADIUS), into base
 * ([height][width][3]), by separable window sums; tmp is scratch of the
 * same size. radius 0 is hf_st_estimate per pixel. HF_EINVAL for an empty
 * frame or a negative radius. */
int hf_pooled_estimate_frame(const hf_input_view *in, int spp, int radius, float *base,
                             float *tmp);
/* The second half of hf_pooled_estimate_frame, for a caller that made the
 * per-pixel sums itself (hf_pixel_sums_rows, a row at a time): base holds
 * them on entry ([height][width][3]) and the pooled estimate on return,
 * the same values. */
int hf_pooled_estimate_sums(int width, int height, int spp, int radius, float *base,
                            float *tmp);
/* hf_residual_base of every pixel: hf_pooled_estimate_frame with radius
 * HF_RESIDUAL_RADIUS. */
int hf_residual_base_frame(const hf_input_view *in, int spp, float *base, float *tmp);
/* Adds a residual base to the raw output v in place, with the clamps of the
 * Residual architecture. */
void hf_residual_apply(const float base[3], float *v);
/* Final output of pixel (x, y) from its raw network output v (the
 * cfg->out_channels values of the pixel), in place in v[0..2]: the output
 * transforms for HF_ARCH_UNET, base + residual for HF_ARCH_RESIDUAL, the
 * kernel's estimate plus the corrections for HF_ARCH_KERNEL (the latter two
 * read in, which may be NULL for HF_ARCH_UNET). Per pixel, for tests and
 * fallbacks; hf_residual_base_frame and hf_kernel_output_frame do frames. */
void hf_output_finish(const hf_net_config *cfg, const hf_input_view *in, int x, int y, float *v);

/* The sums of one pixel's alpha-corrected estimate in hf_pixel_sums' form
 * (protocol/FEATURES.md, "The alpha-corrected estimate"): with a, c, h the
 * estimate's alpha, colour and highlight (pixel_in[spp * 6 + 2], [+0],
 * [+1]), n = spp a, then n c and n h: spp samples that all show the
 * estimate, so that n / spp is its alpha and the ratios its colour and
 * highlight. pixel_in: the pixel's interleaved spp * 6 + 3 values. */
void hf_estimate_sums(const float *pixel_in, int spp, float sums[3]);
/* Per-pixel sums of rows y0..y1-1 of the frame into those rows of sums
 * ([height][width][k] for the whole frame, k = hf_kernel_sums_floats(ksums)):
 * with ksums HF_KSUMS_SAMPLES the number of covered samples (alpha > 0), the
 * sum of their colour and the sum of their highlight, the stochastic-
 * transparency estimate before its division (hf_pixel_sums); with
 * HF_KSUMS_ESTIMATE hf_estimate_sums of the pixel's estimate (in
 * interleaved: stride spp * 6 + 3) instead; with HF_KSUMS_MIXED both, the
 * samples' first. */
void hf_pixel_sums_rows(const hf_input_view *in, int spp, int ksums, int y0, int y1,
                        float *sums);
/* The output stage of HF_ARCH_KERNEL (beyond the paper; protocol/FEATURES.md,
 * "Kernel architecture"; weights/hfnet.py kernel_finish is its twin) for a
 * frame of in->width x in->height pixels. raw holds the network's raw output
 * for the frame: pixel (x, y)'s hf_kernel_taps(radius) + 3 channels (+ 1,
 * the mixing channel m, with ksums HF_KSUMS_MIXED) at
 * raw + (y * raw_pitch + x) * raw_stride. For each pixel, w_t is the softmax
 * of its logits over the taps inside the frame (taps outside are left out;
 * the frame is cut, never padded) and (N, C, H) = sum_t w_t (n, C, H) of the
 * tap's pixel (hf_pixel_sums_rows of kind ksums, HF_KSUMS_*; with
 * HF_KSUMS_MIXED the estimate's weighted sums plus beta times the samples'
 * less the estimate's, beta = 1 / (1 + e^(-HF_KERNEL_MIX_GAIN m))); then
 *   colour    = C / N (1 when N <= 1e-12) + c0,
 *   highlight = max(0, H / N (0 when N <= 1e-12) + c1),
 *   alpha     = min(1, max(0, N / spp + c2))
 * with c the three raw channels after the logits. out: [height][width][3];
 * sums: scratch of [height][width][hf_kernel_sums_floats(ksums)]. HF_EINVAL
 * for an empty frame, a radius outside 0..HF_KERNEL_MAX_RADIUS or an
 * unknown ksums. */
int hf_kernel_output_frame(const hf_input_view *in, int spp, int ksums, int radius,
                           const float *raw,
                           int raw_pitch, int raw_stride, float *out, float *sums);
/* The same on rows y0..y1-1 of a width x height frame, from sums already
 * made for rows y0 - radius .. y1 - 1 + radius (those inside the frame), for
 * backends that split the frame over threads; radius as above (unchecked). */
void hf_kernel_output_rows(int width, int height, int spp, int radius, int ksums,
                           const float *sums, const float *raw, int raw_pitch, int raw_stride,
                           int y0, int y1, float *out);

/* ---- input statistics --------------------------------------------------- */

/* Number of covered samples (alpha > 0) of one pixel's spp*6 features. */
int hf_pixel_covered(const float *pixel_in, int spp);
/* Strand width in pixels as one pixel sees it: the mean alpha of its covered
 * samples (each covered sample's alpha is the strand's share of the pixel,
 * FEATURES.md), summed in sample order in float; in (0, 1] for valid input,
 * 0 when no sample is covered. */
float hf_pixel_strand_alpha(const float *pixel_in, int spp);

/* The statistics of one frame, in one pass reading only the samples' alpha:
 * in is [height][width][spp*6] of dtype (f32, or f16 as uint16_t), dense
 * NHWC as the network reads it. The percentiles are nearest-rank (the
 * ceil(p n)-th smallest of the n hair pixels' values) on a histogram of 128
 * bins per octave between 2^-16 and 1, reported as the lower edge of the
 * bin (at most 0.8% below the exact value; exact for values with at most 8
 * significant bits, such as 0.25 or 0.375; 0 below 2^-16, 1 from 1 up).
 * HF_EINVAL for a bad argument (*out is zeroed). weights/input_stats.py
 * computes the same values. */
int hf_input_stats_compute(const void *in, hf_dtype dtype, int width, int height, int spp,
                           hf_input_stats *out);
/* The counts behind hf_input_stats_compute, made part by part, for a pass
 * that reads a frame for other reasons too and splits it between threads
 * (hf_features_widen): init, then add pixels [p0, p1) of in (as for
 * hf_input_stats_compute) in any order and any parts, merge the parts'
 * accumulators, finish: the values hf_input_stats_compute gives for the
 * whole frame, bit for bit (the counts are integers). */
#define HF_INPUT_STATS_BINS 2050
typedef struct hf_input_stats_acc {
  uint64_t hair, full;
  uint64_t hist[HF_INPUT_STATS_BINS];
} hf_input_stats_acc;
void hf_input_stats_acc_init(hf_input_stats_acc *a);
void hf_input_stats_add(hf_input_stats_acc *a, const void *in, hf_dtype dtype, int spp,
                        size_t p0, size_t p1);
/* hf_input_stats_add over pixels whose samples lie stride values apart
 * (stride >= spp * 6): pixel p's at in + p * stride, as an interleaved
 * frame holds them ([pixels][spp * 6 + 3], hf_features_interleave). */
void hf_input_stats_add_strided(hf_input_stats_acc *a, const void *in, hf_dtype dtype, int spp,
                                size_t stride, size_t p0, size_t p1);
void hf_input_stats_merge(hf_input_stats_acc *a, const hf_input_stats_acc *b);
void hf_input_stats_finish(const hf_input_stats_acc *a, int width, int height, int spp,
                           hf_input_stats *out);
/* Name of statistic HF_STAT_* ("strand_alpha_p50", ...; "unknown"), and
 * back (HF_ENOTFOUND). The names are the metadata's keys. */
const char *hf_input_stat_name(int stat);
int hf_input_stat_from_name(const char *name);

/* Parses `input_range` metadata (JSON text, weights/FORMAT.md) of a variant
 * that reads spp samples. A range whose "definition" is not
 * HF_INPUT_STATS_DEFINITION is left unused (HF_OK, present 0); a malformed
 * one is HF_EFORMAT with the reason in err. */
int hf_input_range_parse(const char *json, int spp, hf_input_range *out, char *err,
                         size_t errlen);
/* The range as metadata JSON text (malloc'd; NULL when not present). */
char *hf_input_range_to_json(const hf_input_range *r);
/* Bit k set for each statistic k outside its range; 0 when r is not
 * present, when the frame has no hair pixel (nothing to filter) and for
 * statistics without a range or undefined on this frame. */
unsigned hf_input_range_check(const hf_input_range *r, const hf_input_stats *s);
/* "strand_alpha_p50 VALUE (trained LOW..HIGH), ..." (%.4g) for the
 * statistics in mask, into buf (always terminated; HF_ERANGE if cut). */
int hf_input_range_describe(const hf_input_range *r, const hf_input_stats *s, unsigned mask,
                            char *buf, size_t len);

/* ---- half floats -------------------------------------------------------- */

/* One value, IEEE 754 binary32 <-> binary16, round to nearest even; the
 * reference the array functions follow bit for bit. Overflow gives
 * infinity, values under half the smallest subnormal give zero (signed).
 * A NaN keeps its sign and the top bits of its payload and is made quiet
 * (IEEE 754-2008 5.4.2), in both directions. */
uint16_t hf_f32_to_f16(float f);
float hf_f16_to_f32(uint16_t h);
/* n values at once, bit for bit as hf_f32_to_f16 / hf_f16_to_f32 for every
 * input, NaNs included: with the processor's F16C conversion when it has
 * one (8 values per instruction, chosen at run time), else the scalar
 * functions; from 1 M values on, split between up to one thread per online
 * CPU (16 at most), which take chunks of 64 Ki values in turn
 * (hf_parallel_chunks). src and dst must not overlap. Never fails. */
void hf_f32_to_f16_array(const float *src, uint16_t *dst, size_t n);
void hf_f16_to_f32_array(const uint16_t *src, float *dst, size_t n);
/* As the array functions, on the calling thread alone: for code that
 * already splits a frame between its own threads. */
void hf_f32_to_f16_serial(const float *src, uint16_t *dst, size_t n);
void hf_f16_to_f32_serial(const uint16_t *src, float *dst, size_t n);
/* hf_f16_to_f32_serial with non-temporal stores: for one part of a frame
 * far larger than the caches, whose floats are not read back soon (they
 * bypass the caches, and no line of dst is read before it is written). */
void hf_f16_to_f32_stream(const uint16_t *src, float *dst, size_t n);
/* The array functions' implementation: "f16c" or "scalar". */
const char *hf_half_impl(void);
/* on = 0 makes the array functions use the scalar code, 1 the vector code
 * where the processor has it (the default), -1 changes nothing (for tests
 * and benchmarks that compare the two). Returns whether the vector code was
 * in use before the call. Not meant to be called while another thread
 * converts. */
int hf_half_use_simd(int on);

/* ---- passes over a frame split between threads ---------------------------- */

#define HF_PARALLEL_MAX 16
/* One worker's part of a pass: items [begin, end). */
typedef void (*hf_chunk_fn)(void *ctx, int worker, size_t begin, size_t end);
/* Runs fn over items [0, n) in chunks of chunk items (the last one
 * shorter; chunk 0: one chunk), taken in turn from a shared counter by up
 * to hf_parallel_workers(n, min_per_thread) workers: the calling thread
 * (worker 0) and a thread started for each other one. A worker's chunks
 * come in increasing order; worker (0 .. the returned count - 1) indexes
 * per-worker partial results, which the caller sets up for every worker
 * before the call (a worker whose thread cannot start, or starts only
 * after every chunk is taken, takes no chunk, and the others take its
 * share, so the result never depends on threads). Returns when every chunk
 * is done, with the number of workers: 0 when n is 0, 1 for a single
 * chunk, else hf_parallel_workers(n, min_per_thread) (src/parallel.c). */
int hf_parallel_chunks(size_t n, size_t chunk, size_t min_per_thread, hf_chunk_fn fn, void *ctx);
/* The workers hf_parallel_chunks uses for n items: one per online CPU
 * (HF_PARALLEL_MAX at most), no more than n / min_per_thread, at least 1. */
int hf_parallel_workers(size_t n, size_t min_per_thread);

/* ---- images ------------------------------------------------------------- */

/* A float image with named channels, interleaved (pixel-major).
 *
 * Where the pixels sit follows OpenEXR's windows: the data window is the
 * width x height pixels starting at (origin_x, origin_y) in image space
 * (y down), and the display window is the frame they belong to, e.g. a crop
 * of a 1920x1080 render holds its pixels at their place in the full frame.
 * display_width == 0 means the display window is the data window. A zeroed
 * image (hf_image_alloc) has origin (0, 0) and no display window of its own. */
typedef struct hf_image {
  int width, height, channels;
  char (*names)[32];            /* channels names */
  float *data;                  /* [height][width][channels] */
  int origin_x, origin_y;       /* data window's top-left pixel */
  int display_x, display_y;     /* display window's top-left pixel */
  int display_width, display_height; /* 0: same as the data window */
  const char *lossy;            /* read from a file: NULL, or the lossy compression its
                                 * values went through ("B44", "B44A" for half channels,
                                 * "PXR24" for float ones, "DWAA", "DWAB") */
  unsigned char *uint_stored;   /* read from a file with UINT channels: [channels], 1 where
                                 * the channel is stored as UINT (32-bit unsigned
                                 * integers, read as their values); else NULL */
} hf_image;

int hf_image_alloc(hf_image *img, int width, int height, int channels);
void hf_image_free(hf_image *img);
/* Index of a channel by name, or HF_ENOTFOUND. */
int hf_image_channel(const hf_image *img, const char *name);
/* Copies the data window origin and display window of src into dst (whose
 * pixels must be the same width x height): a result keeps its input's place. */
void hf_image_copy_windows(hf_image *dst, const hf_image *src);

/* Reads every channel of one part of an EXR file (scanline or tiled; of a
 * tiled file its full-resolution level) as float32, with its data window
 * and display window. The part is chosen by `part`: NULL to choose
 * automatically, else a part index ("0", "1", ...) or a part name. The
 * automatic choice is the only part of a single-part file, else the one part
 * holding channel `channel` (e.g. "S0.color"); when none or several do, or
 * channel is NULL, the file is refused with a list of its parts.
 * Errors (err gets one line naming the file, the part or channel, and what
 * to do): HF_EIO unreadable or truncated / incomplete file, HF_EFORMAT
 * corrupt, HF_EUNSUPPORTED compression this build's OpenEXR cannot decode,
 * deep or subsampled data, HF_ERANGE more pixels x channels than 2^29 values,
 * HF_ENOTFOUND no such part or no part with `channel`. */
int hf_exr_read_part(const char *path, const char *part, const char *channel, hf_image *img,
                     char *err, size_t errlen);
/* hf_exr_read_part with the values in a buffer of their own, of dtype:
 * *data (malloc'd, the caller frees it) gets [height][width][channels]
 * values, float32 for HF_F32, IEEE 754 binary16 bits for HF_F16, channel c
 * of a pixel being img->names[c]; img gets the size, the channel names and
 * the windows, with img->data NULL. For HF_F16, a part whose channels are
 * all HALF (the usual renderer output) is decoded straight into halves, its
 * bits exactly as stored; any other part is decoded as float32 and
 * converted once by hf_f32_to_f16_array (a HALF channel beside a FLOAT one
 * keeps its value; a signalling NaN comes back quiet). For HF_F32, HALF
 * channels are widened exactly, as by hf_exr_read_part. Errors: those of
 * hf_exr_read_part, and HF_EINVAL for a NULL argument or another dtype;
 * on failure img and *data are released (NULL). */
int hf_exr_read_part_as(const char *path, const char *part, const char *channel, hf_dtype dtype,
                        hf_image *img, void **data, char *err, size_t errlen);
/* hf_exr_read_part(path, NULL, NULL, ...): a single-part file, any layout. */
int hf_exr_read(const char *path, hf_image *img, char *err, size_t errlen);
/* Whether some part of an EXR file has a channel of that name, from the
 * headers alone: 1 or 0, HF_EIO when the file cannot be read as EXR,
 * HF_EINVAL for a NULL argument. */
int hf_exr_has_channel(const char *path, const char *channel);
/* Size of an EXR's display window (the whole image a crop was cut from;
 * equal to the data window's size for an uncropped file), header only, of
 * its first part. */
int hf_exr_display_size(const char *path, int *width, int *height, char *err, size_t errlen);
/* Writes a single-part scanline EXR with the image's channel names, data
 * window and display window; half selects 16-bit storage, else float32.
 * ZIP compression, with every chunk that does not shrink stored raw (the
 * layout rule OpenEXRCore 3.1 breaks, upstream issue 2306), and the file is
 * read back and compared bit for bit before this returns: HF_OK means the
 * file holds exactly img's values (rounded to half with half). The file is
 * written under a temporary name in the same directory and renamed to path
 * when complete, so path never holds half a file. Errors:
 * HF_EINVAL bad image or channel names, HF_ENOMEM, HF_EIO the file could not
 * be written or did not read back as written. */
int hf_exr_write(const char *path, const hf_image *img, int half);
/* An int attribute of an EXR header, named "tool:name" (OpenEXR's
 * convention for attributes of one tool: a prefix keeps them apart from the
 * standard ones), such as "hairfilter:gtSupersample". */
typedef struct hf_exr_int_attr {
  const char *name;
  int value;
} hf_exr_int_attr;
/* hf_exr_write with n_attrs int attributes in the header. HF_EINVAL also
 * for a name without ':' or one the library refuses. */
int hf_exr_write_attrs(const char *path, const hf_image *img, int half,
                       const hf_exr_int_attr *attrs, int n_attrs);
/* The int attribute name of the first part's header of path into *value:
 * HF_OK, HF_ENOTFOUND when the header has none, HF_EFORMAT when it has one
 * of another type, HF_EIO when the file cannot be opened as an EXR. */
int hf_exr_read_int_attr(const char *path, const char *name, int *value);

/* Feature EXR <-> network input. Channels are S{k}.color, S{k}.highlight,
 * S{k}.alpha, S{k}.depth, S{k}.tangent.x, S{k}.tangent.y (protocol/FEATURES.md).
 * hf_features_spp counts the samples (consecutive S{k}.color from S0; may be
 * more than HF_MAX_SPP, of which a network reads the first spp) or returns
 * HF_ENOTFOUND. hf_features_from_image fills in (width*height*spp*6 floats,
 * NHWC) with the first spp samples and returns spp, or HF_ENOTFOUND when a
 * channel is missing. */
int hf_features_spp(const hf_image *img);
int hf_features_from_image(const hf_image *img, int spp, float *in);
/* hf_features_from_image on values of dtype held apart from the image (as
 * hf_exr_read_part_as gives them): data is [height][width][img->channels]
 * of dtype, in gets width*height*spp*6 values of the same dtype (NHWC),
 * copied bit for bit. Returns spp, HF_ENOTFOUND when a channel is missing,
 * HF_EINVAL for a NULL argument, spp outside 1..HF_MAX_SPP or another dtype. */
int hf_features_from_data(const hf_image *img, const void *data, hf_dtype dtype, int spp,
                          void *in);
int hf_features_to_image(const float *in, int width, int height, int spp, hf_image *img);
/* The alpha-corrected estimate's channels in EXR files (the renderer's
 * `--alpha-corrected` output): HF_ESTIMATE_PREFIX ".color", ".highlight",
 * ".alpha" (protocol/FEATURES.md, "The alpha-corrected estimate"). */
#define HF_ESTIMATE_PREFIX "acst4"
/* The estimate of an image whose values are data ([height][width]
 * [img->channels] of dtype) into est ([height][width][3] of the same dtype:
 * colour, highlight, alpha), copied bit for bit: the block a frame of a
 * network with an estimate carries after its samples (hf_io). HF_OK,
 * HF_ENOTFOUND when one of the three channels is missing, HF_EINVAL for a
 * NULL argument or another dtype. */
int hf_estimate_from_data(const hf_image *img, const void *data, hf_dtype dtype, void *est);
/* Result channels "color", "highlight", "alpha". */
int hf_result_to_image(const float *out, int width, int height, hf_image *img);

/* Composite (paper Fig. 3, L_o = L_S (C_H (F_d + F_TRT) + F_R)):
 * rgb = alpha * light * (hair * color + highlight) + (1 - alpha) * bg.
 * out is [h][w][3] linear float. Evaluated in double precision and
 * saturated to [-FLT_MAX, FLT_MAX], so finite colours of any magnitude give
 * finite values (a FILTER's colours are only checked to be finite); a NaN
 * in result3 gives 0. */
void hf_composite(const float *result3, int width, int height, const float hair[3],
                  const float light[3], const float bg[3], float *rgb);
/* 8-bit sRGB PNG of a linear [h][w][3] float image. */
int hf_png_write_rgb(const char *path, const float *rgb, int width, int height);

#ifdef __cplusplus
}
#endif
#endif /* HFCORE_H */
