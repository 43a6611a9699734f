/*
 * The small CUDA kernels around the cuDNN convolutions (internal to src/).
 * Each launches on the given stream and returns the launch status; none
 * synchronises. Device pointers to FP16 data are passed as void *.
 */
#ifndef HF_CUDNN_KERNELS_H
#define HF_CUDNN_KERNELS_H

#include <cuda_runtime_api.h>

#ifdef __cplusplus
extern "C" {
#endif

/* src: [batch][h][w][cin] of FP32 (src_f16 == 0) or FP16; dst: FP16
 * [batch][ph][pw][cpad], zeros right of w, below h and in channels >= cin. */
cudaError_t hf_cuk_input(const void *src, int src_f16, int batch, int w, int h, int cin,
                         void *dst, int pw, int ph, int cpad, cudaStream_t stream);

/* src: FP16 [batch][ph][pw][src_stride], raw network output in channels
 * 0..2 (color, highlight, alpha). Applies the output transforms (or, when
 * in is not NULL, adds the residual base, hf_residual_base, over the FP16 network input in,
 * [batch][ph][pw][in_stride] with spp samples: HF_ARCH_RESIDUAL), crops to
 * w x h and writes [batch][h][w][3] as FP32 (dst_f16 == 0) or FP16. */
cudaError_t hf_cuk_output(const void *src, int src_stride, const void *in, int in_stride,
                          int spp, int pw, int ph, int batch, int w, int h, void *dst,
                          int dst_f16, cudaStream_t stream);

/* y: FP16 pixels with c channels each, pixel stride pix_stride, npix of
 * them: y = (y + bias) then ReLU when relu. For convolutions no cuDNN
 * engine would fuse with their epilogue. */
cudaError_t hf_cuk_bias_act(void *y, size_t npix, int c, int pix_stride, const float *bias,
                            int relu, cudaStream_t stream);

/* Copies c channels of npix FP16 pixels between two pixel strides. For
 * layers whose strided (skip-buffer) views no engine accepts. */
cudaError_t hf_cuk_copy_channels(void *dst, int dst_stride, const void *src, int src_stride,
                                 size_t npix, int c, cudaStream_t stream);

/* Depth-to-space by 2: src is dense FP16 [batch][h][w][4*c]; channel
 * (2dy+dx)*c + k of pixel (y, x) goes to channel k of pixel (2y+dy, 2x+dx)
 * of dst, [batch][2h][2w] with pixel stride dst_stride. */
cudaError_t hf_cuk_pixel_shuffle(void *dst, int dst_stride, const void *src, int batch, int h,
                                 int w, int c, cudaStream_t stream);

#ifdef __cplusplus
}
#endif
#endif /* HF_CUDNN_KERNELS_H */
