// The small CUDA kernels around the cuDNN convolutions: see cudnn_kernels.h.
// All are memory-bound element loops; a grid-stride loop over size_t
// indices keeps them correct for any frame the common code admits.
#include <cuda_fp16.h>

#include "cudnn_kernels.h"
#include "hfcore.h"  // HF_RESIDUAL_RADIUS

namespace {

constexpr int kThreads = 256;
constexpr size_t kMaxBlocks = 1u << 16;

unsigned blocks_for(size_t n) {
  size_t b = (n + kThreads - 1) / kThreads;
  if (b > kMaxBlocks) b = kMaxBlocks;
  return b ? (unsigned)b : 1u;
}

__global__ void input_kernel(const void *src, int src_f16, int batch, int w, int h, int cin,
                             __half *dst, int pw, int ph, int cpad) {
  const size_t total = (size_t)batch * ph * pw * cpad;
  for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < total;
       i += (size_t)gridDim.x * blockDim.x) {
    size_t t = i;
    const int c = (int)(t % cpad); t /= cpad;
    const int x = (int)(t % pw);   t /= pw;
    const int y = (int)(t % ph);
    const size_t n = t / ph;
    __half v = __float2half(0.0f);
    if (x < w && y < h && c < cin) {
      const size_t s = ((n * h + y) * w + x) * cin + c;
      v = src_f16 ? ((const __half *)src)[s] : __float2half_rn(((const float *)src)[s]);
    }
    dst[i] = v;
  }
}

__global__ void output_kernel(const __half *src, int src_stride, const __half *in,
                              int in_stride, int spp, int pw, int ph, int batch, int w, int h,
                              void *dst, int dst_f16) {
  const size_t total = (size_t)batch * h * w;
  for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < total;
       i += (size_t)gridDim.x * blockDim.x) {
    size_t t = i;
    const int x = (int)(t % w); t /= w;
    const int y = (int)(t % h);
    const size_t n = t / h;
    const size_t px = (n * ph + y) * pw + x;
    const __half *p = src + px * src_stride;
    const float c = __half2float(p[0]);
    const float hl = __half2float(p[1]);
    const float a = __half2float(p[2]);
    float out[3];
    if (in) {
      // Residual architecture: raw output plus the stochastic-transparency
      // estimate over the window around the pixel, cut to the frame
      // (hf_residual_base in net_config.c).
      const int y0 = max(y - HF_RESIDUAL_RADIUS, 0), y1 = min(y + HF_RESIDUAL_RADIUS, h - 1);
      const int x0 = max(x - HF_RESIDUAL_RADIUS, 0), x1 = min(x + HF_RESIDUAL_RADIUS, w - 1);
      float cnt = 0.0f, col = 0.0f, hsum = 0.0f;
      for (int yy = y0; yy <= y1; yy++)
        for (int xx = x0; xx <= x1; xx++) {
          const __half *s = in + ((n * ph + yy) * pw + xx) * in_stride;
          for (int k = 0; k < spp; k++, s += 6)
            if (__half2float(s[2]) > 0.0f) {
              cnt += 1.0f;
              col += __half2float(s[0]);
              hsum += __half2float(s[1]);
            }
        }
      const float samples = (float)((y1 - y0 + 1) * (x1 - x0 + 1) * spp);
      const float bc = cnt > 0.0f ? col / cnt : 1.0f;
      const float bh = cnt > 0.0f ? hsum / cnt : 0.0f;
      out[0] = bc + c;
      out[1] = fmaxf(bh + hl, 0.0f);
      out[2] = fminf(fmaxf(cnt / samples + a, 0.0f), 1.0f);
    } else {
      // The paper's transforms (section 3.3.2), computed in FP32.
      out[0] = c * c * c / 32.0f + c / 5.0f + 1.0f;
      out[1] = fmaxf(hl, 0.0f);
      out[2] = fminf(fmaxf(a, 0.0f), 1.0f);
    }
    if (dst_f16) {
      __half *d = (__half *)dst + i * 3;
      for (int k = 0; k < 3; k++) d[k] = __float2half_rn(out[k]);
    } else {
      float *d = (float *)dst + i * 3;
      for (int k = 0; k < 3; k++) d[k] = out[k];
    }
  }
}

__global__ void bias_act_kernel(__half *y, size_t npix, int c, int pix_stride,
                                const float *bias, int relu) {
  const size_t total = npix * c;
  for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < total;
       i += (size_t)gridDim.x * blockDim.x) {
    const size_t p = i / c;
    const int k = (int)(i % c);
    __half *e = y + p * pix_stride + k;
    float v = __half2float(*e) + bias[k];
    if (relu) v = fmaxf(v, 0.0f);
    *e = __float2half_rn(v);
  }
}

__global__ void copy_kernel(__half *dst, int dst_stride, const __half *src, int src_stride,
                            size_t npix, int c) {
  const size_t total = npix * c;
  for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < total;
       i += (size_t)gridDim.x * blockDim.x) {
    const size_t p = i / c;
    const int k = (int)(i % c);
    dst[p * dst_stride + k] = src[p * src_stride + k];
  }
}

__global__ void shuffle_kernel(__half *dst, int dst_stride, const __half *src, int batch, int h,
                               int w, int c) {
  const size_t total = (size_t)batch * h * w * 4 * c;
  for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < total;
       i += (size_t)gridDim.x * blockDim.x) {
    size_t t = i;
    const int k = (int)(t % c); t /= c;
    const int q = (int)(t % 4); t /= 4;
    const int x = (int)(t % w); t /= w;
    const int y = (int)(t % h);
    const size_t n = t / h;
    const size_t oy = 2 * (size_t)y + (q >> 1), ox = 2 * (size_t)x + (q & 1);
    dst[((n * 2 * h + oy) * 2 * w + ox) * dst_stride + k] = src[i];
  }
}

}  // namespace

extern "C" cudaError_t hf_cuk_input(const void *src, int src_f16, int batch, int w, int h,
                                    int cin, void *dst, int pw, int ph, int cpad,
                                    cudaStream_t stream) {
  const size_t total = (size_t)batch * ph * pw * cpad;
  input_kernel<<<blocks_for(total), kThreads, 0, stream>>>(src, src_f16, batch, w, h, cin,
                                                           (__half *)dst, pw, ph, cpad);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_output(const void *src, int src_stride, const void *in,
                                     int in_stride, int spp, int pw, int ph, int batch, int w,
                                     int h, void *dst, int dst_f16, cudaStream_t stream) {
  const size_t total = (size_t)batch * h * w;
  output_kernel<<<blocks_for(total), kThreads, 0, stream>>>(
      (const __half *)src, src_stride, (const __half *)in, in_stride, spp, pw, ph, batch, w, h,
      dst, dst_f16);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_bias_act(void *y, size_t npix, int c, int pix_stride,
                                       const float *bias, int relu, cudaStream_t stream) {
  bias_act_kernel<<<blocks_for(npix * c), kThreads, 0, stream>>>((__half *)y, npix, c,
                                                                  pix_stride, bias, relu);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_copy_channels(void *dst, int dst_stride, const void *src,
                                            int src_stride, size_t npix, int c,
                                            cudaStream_t stream) {
  copy_kernel<<<blocks_for(npix * c), kThreads, 0, stream>>>(
      (__half *)dst, dst_stride, (const __half *)src, src_stride, npix, c);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_pixel_shuffle(void *dst, int dst_stride, const void *src, int batch,
                                            int h, int w, int c, cudaStream_t stream) {
  const size_t total = (size_t)batch * h * w * 4 * c;
  shuffle_kernel<<<blocks_for(total), kThreads, 0, stream>>>((__half *)dst, dst_stride,
                                                              (const __half *)src, batch, h, w, c);
  return cudaGetLastError();
}
