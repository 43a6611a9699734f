/*
 * The small CUDA kernels around the cuDNN convolutions (internal to src/).
 * Each launches on the given stream and returns the launch status; none
 * synchronises. FP16 data is passed as void *.
 *
 * All are memory-bound. Each thread moves several elements (up to 8 FP16
 * = 16 bytes, the widest access a thread makes; fewer when a channel count,
 * stride or offset does not allow it), and the grid is (pixels of a row,
 * rows, frames), so no thread divides 64-bit numbers: a thread finds its
 * pixel with one 32-bit division by a small count.
 */
#ifndef HF_CUDNN_KERNELS_H
#define HF_CUDNN_KERNELS_H

#include <stdint.h>

#include <cuda_runtime_api.h>

#include "cudnn_layout.h"
#include "hfcore.h"

#ifdef __cplusplus
extern "C" {
#endif

/* FP16 pixels: element (n, y, x, k) of the view at base + n*sn + y*sy +
 * x*sx + k (strides in elements), 0 <= k < c, 0 <= y < h, 0 <= x < w. */
typedef struct hf_cuk_view {
  void *base;
  long long sn, sy, sx;
  int c, h, w;
} hf_cuk_view;

/* src: [batch][h][w][cin] of FP32 (src_f16 == 0) or FP16; dst: FP16
 * [batch][ph][pw][cpad], zeros right of w, below h and in channels >= cin.
 * cpad is a multiple of 8. */
cudaError_t hf_cuk_input(const void *src, int src_f16, int batch, int w, int h, int cin,
                         void *dst, int pw, int ph, int cpad, cudaStream_t stream);

/* What the input check counted in one frame: the first three fields are
 * hf_input_stats_acc's, in its layout (the statistics of the frame as it
 * came); bad is the number of out-of-contract samples, first_bad_inv the
 * bitwise complement of the lowest sample index among them (0: none);
 * outputs the output pixels the guard changed (hf_cuk_guard). */
typedef struct hf_cuk_scan_counts {
  unsigned long long hair, full, hist[HF_INPUT_STATS_BINS];
  unsigned long long bad, first_bad_inv, outputs;
} hf_cuk_scan_counts;
/* The input check on the device, for frames uploaded as they came: src is
 * [batch][pixels][spp * 6] of FP32 (src_f16 == 0) or FP16; each
 * out-of-contract sample is fixed in place by hfcore's rule
 * (hf_features_sanitise, bit for bit), and counts[n] (batch of them,
 * zeroed here first) gets frame n's statistics and rule counts. What
 * hf_features_scan reads on the host's cores, read at the device's memory
 * bandwidth after a plain upload. */
cudaError_t hf_cuk_scan(void *src, int src_f16, int batch, long long pixels, int spp,
                        hf_cuk_scan_counts *counts, cudaStream_t stream);
/* The output guard on the device (hf_output_guard, bit for bit): dst is
 * [batch][pixels][3] of FP32 (dst_f16 == 0) or FP16, each pixel kept in its
 * ranges in place; counts[n].outputs gets the pixels of frame n it changed
 * added (hf_cuk_scan zeroes it). */
cudaError_t hf_cuk_guard(void *dst, int dst_f16, int batch, long long pixels,
                         hf_cuk_scan_counts *counts, cudaStream_t stream);
/* y = y + bias[k] (FP32), then ReLU when relu, over batch frames of y. For
 * convolutions no cuDNN engine would fuse with their epilogue. */
cudaError_t hf_cuk_bias_act(hf_cuk_view y, int batch, const float *bias, int relu,
                            cudaStream_t stream);

/* Copies batch frames of src into dst (same c, h, w). For convolutions
 * whose views no engine accepts: they run on dense copies. */
cudaError_t hf_cuk_copy(hf_cuk_view dst, hf_cuk_view src, int batch, cudaStream_t stream);

/* Depth-to-space by 2 into dst ([batch][2h][2w], c = co channels; h, w of
 * dst are 2h, 2w): src is dense FP16 [batch][h+offset][w+offset][4*co];
 * dst pixel (2m+dy, 2n+dx), channel k, is src channel (2dy+dx)*co + k of
 * pixel (m + dy*offset, n + dx*offset). offset 0: the SHUFFLE form,
 * offset 1: the D2S form (cudnn_layout.h). */
cudaError_t hf_cuk_depth_to_space(hf_cuk_view dst, const void *src, int batch, int offset,
                                  cudaStream_t stream);

/* Pseudo-random FP16 values in [-1, 1) from seed into n elements: engines
 * and forms are timed on these, not on zeros. */
cudaError_t hf_cuk_fill(void *dst, size_t n, uint32_t seed, cudaStream_t stream);

/* ---- output stages: one kernel per output form ------------------------- */

/* The raw network output (color, highlight, alpha) as the last decoder
 * left it: hf_cl_raw (cudnn_layout.h) says where pixel (x, y) is. */
typedef struct hf_cuk_raw {
  const void *data;             /* FP16 */
  hf_cl_raw at;
} hf_cuk_raw;

/* HF_ARCH_UNET: the paper's transforms (alpha clamp, color x^3/32+x/5+1,
 * highlight max(0, x)) of the raw output of frame pixels w x h, written as
 * [batch][h][w][3] FP32 (dst_f16 == 0) or FP16. */
cudaError_t hf_cuk_output_unet(hf_cuk_raw raw, int batch, int w, int h, void *dst, int dst_f16,
                               cudaStream_t stream);

/* HF_ARCH_RESIDUAL: raw output plus the residual base (hf_residual_base:
 * the stochastic-transparency estimate over the samples of the
 * (2*HF_RESIDUAL_RADIUS+1)^2 window around the pixel, cut to the frame),
 * read from the FP16 network input in ([batch][ph][pw][in_stride], spp
 * samples of 6 features). Each block sums its tile's windows from shared
 * memory by separable sums: every input pixel is read once per tile. */
cudaError_t hf_cuk_output_residual(hf_cuk_raw raw, const void *in, int in_stride, int pw, int ph,
                                   int spp, int batch, int w, int h, void *dst, int dst_f16,
                                   cudaStream_t stream);

/* HF_ARCH_KERNEL's 1x1 head (hf_net_config), when the network has one:
 * FP32 weights [out_channels][hidden + cin] (taps + 3, + 1 with kernel_mix) (PyTorch's Conv2d layout) and bias,
 * over dec0's hidden channels (ReLU applied, the raw output's first hidden
 * channels) and the network input's cin channels. w NULL: no head, the raw
 * output holds the taps + 3 channels itself. */
typedef struct hf_cuk_head {
  const float *w, *b;
  int hidden, cin;
} hf_cuk_head;

/* HF_ARCH_KERNEL (hf_kernel_output_frame): per pixel, the softmax over its
 * kernel's taps inside the frame of the logits (the raw output's first
 * taps channels, or the head's) weighs the per-pixel sums (covered count,
 * colour, highlight) of the (2 radius + 1)^2 pixels around it, read from
 * the FP16 network input in ([batch][ph][pw][in_stride], spp samples) of
 * kind ksums (HF_KSUMS_*: the samples', the estimate's after them,
 * hf_estimate_sums, or both mixed at the pixel by the raw channel after the
 * corrections); then the three corrections. Each block reduces its tile and a halo of
 * HF_KERNEL_MAX_RADIUS pixels to per-pixel sums in shared memory once;
 * each thread computes its pixel's logits one tap at a time (the head's
 * dot products when there is one) into an online softmax, so no logit is
 * stored. */
cudaError_t hf_cuk_output_kernel(hf_cuk_raw raw, hf_cuk_head head, const void *in, int in_stride,
                                 int pw, int ph, int spp, int ksums, int radius, int batch,
                                 int w, int h, void *dst, int dst_f16, cudaStream_t stream);

#ifdef __cplusplus
}
#endif
#endif /* HF_CUDNN_KERNELS_H */
