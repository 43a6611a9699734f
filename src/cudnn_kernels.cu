// The small CUDA kernels around the cuDNN convolutions: see cudnn_kernels.h.
// Each __global__ kernel hands its thread's grid position to the function
// in cudnn_kernels_body.cuh that does the work (which the host tests run
// too); the launchers pick the access width and the grid.
#include <stdint.h>

#include <cuda_fp16.h>

#include "cudnn_kernels.h"
#include "cudnn_kernels_body.cuh"

using namespace hf_kb;

namespace {

template <bool F16, bool PAIRS>
__global__ void input_kernel(const void *src, int w, int h, int cin, __half *dst, int pw, int ph,
                             int cpad) {
  input_unit<F16, PAIRS>(src, w, h, cin, dst, pw, ph, cpad, blockIdx.x * blockDim.x + threadIdx.x,
                         blockIdx.y, blockIdx.z);
}

// Most blocks per frame of the input check and the guard. Every block keeps
// a histogram in shared memory (8 KiB) and adds its non-zero bins to the
// frame's at the end: fewer, fuller blocks mean fewer global atomics, more
// mean more of the device busy. 1024 blocks of 256 threads are more than
// an H100/H200 holds at once (132 SMs; about 5 such blocks each at the
// scan's 41-44 registers a thread on sm_90: `nvcc -arch=sm_90
// --ptxas-options=-v`), so every SM has work to the end;
// the flush is then 1024 atomics per bin in use. Not yet tuned on a device.
constexpr int kScanBlocks = 1024;

template <bool F16>
__global__ void scan_kernel(void *src, long long pixels, int spp, hf_cuk_scan_counts *counts) {
  __shared__ unsigned hist[HF_INPUT_STATS_BINS];
  __shared__ unsigned long long hair, full, bad, first_inv;
  for (int i = threadIdx.x; i < HF_INPUT_STATS_BINS; i += blockDim.x) hist[i] = 0;
  if (threadIdx.x == 0) hair = full = bad = first_inv = 0;
  __syncthreads();
  const long long frame_values = pixels * spp * HF_FEATURES_PER_SAMPLE;
  void *frame = F16 ? (void *)((uint16_t *)src + blockIdx.y * frame_values)
                    : (void *)((float *)src + blockIdx.y * frame_values);
  unsigned long long my_hair = 0, my_full = 0, my_bad = 0, my_first_inv = 0;
  for (long long p = (long long)blockIdx.x * blockDim.x + threadIdx.x; p < pixels;
       p += (long long)gridDim.x * blockDim.x) {
    const ScanPixel r = scan_pixel<F16>(frame, spp, p);
    if (r.covered) {
      atomicAdd(&hist[r.bin], 1u);
      my_hair++;
      my_full += r.covered == spp;
    }
    if (r.bad) {
      my_bad += r.bad;
      const unsigned long long inv = ~(unsigned long long)(p * spp + r.first_bad);
      if (inv > my_first_inv) my_first_inv = inv;
    }
  }
  if (my_hair) atomicAdd(&hair, my_hair);
  if (my_full) atomicAdd(&full, my_full);
  if (my_bad) {
    atomicAdd(&bad, my_bad);
    atomicMax(&first_inv, my_first_inv);
  }
  __syncthreads();
  hf_cuk_scan_counts *c = counts + blockIdx.y;
  for (int i = threadIdx.x; i < HF_INPUT_STATS_BINS; i += blockDim.x)
    if (hist[i]) atomicAdd(&c->hist[i], (unsigned long long)hist[i]);
  if (threadIdx.x == 0) {
    if (hair) atomicAdd(&c->hair, hair);
    if (full) atomicAdd(&c->full, full);
    if (bad) {
      atomicAdd(&c->bad, bad);
      atomicMax(&c->first_bad_inv, first_inv);
    }
  }
}

template <bool F16>
__global__ void guard_kernel(void *dst, long long pixels, hf_cuk_scan_counts *counts) {
  __shared__ unsigned long long changed;
  if (threadIdx.x == 0) changed = 0;
  __syncthreads();
  void *frame = F16 ? (void *)((uint16_t *)dst + blockIdx.y * pixels * 3)
                    : (void *)((float *)dst + blockIdx.y * pixels * 3);
  unsigned long long mine = 0;
  for (long long p = (long long)blockIdx.x * blockDim.x + threadIdx.x; p < pixels;
       p += (long long)gridDim.x * blockDim.x)
    mine += guard_pixel<F16>(frame, p);
  if (mine) atomicAdd(&changed, mine);
  __syncthreads();
  if (threadIdx.x == 0 && changed) atomicAdd(&counts[blockIdx.y].outputs, changed);
}

template <int U> __global__ void bias_act_kernel(hf_cuk_view y, const float *bias, int relu) {
  bias_act_unit<U>(y, bias, relu, blockIdx.x * blockDim.x + threadIdx.x, blockIdx.y, blockIdx.z);
}

template <int U> __global__ void copy_kernel(hf_cuk_view dst, hf_cuk_view src) {
  copy_unit<U>(dst, src, blockIdx.x * blockDim.x + threadIdx.x, blockIdx.y, blockIdx.z);
}

template <int U> __global__ void d2s_kernel(hf_cuk_view dst, const __half *src, int offset) {
  d2s_unit<U>(dst, src, offset, blockIdx.x * blockDim.x + threadIdx.x, blockIdx.y, blockIdx.z);
}

__global__ void fill_kernel(__half *dst, size_t n, uint32_t seed) {
  for (size_t i = blockIdx.x * (size_t)blockDim.x + threadIdx.x; i < n;
       i += (size_t)gridDim.x * blockDim.x) {
    uint32_t x = (uint32_t)i * 0x9E3779B1u ^ (uint32_t)(i >> 32) ^ seed;
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    dst[i] = __float2half((float)(x >> 8) * (2.0f / 16777216.0f) - 1.0f);
  }
}

__global__ void output_unet_kernel(hf_cuk_raw raw, int w, int h, void *dst, int dst_f16) {
  output_unet_px(raw, w, h, dst, dst_f16, blockIdx.x * blockDim.x + threadIdx.x, blockIdx.y,
                 blockIdx.z);
}

__global__ void __launch_bounds__(kTileX * kTileY)
output_residual_kernel(hf_cuk_raw raw, const __half *in, int in_stride, int pw, int ph, int spp,
                       int w, int h, void *dst, int dst_f16) {
  __shared__ float3 px[kHaloH][kHaloW];
  __shared__ float3 rows[kHaloH][kTileX];
  const int tid = threadIdx.y * kTileX + threadIdx.x;
  residual_load(px, in, in_stride, pw, ph, spp, w, h, blockIdx.x, blockIdx.y, blockIdx.z, tid,
                kTileX * kTileY);
  __syncthreads();
  residual_rows(px, rows, tid, kTileX * kTileY);
  __syncthreads();
  residual_finish(rows, raw, spp, w, h, dst, dst_f16, blockIdx.x, blockIdx.y, blockIdx.z,
                  threadIdx.x, threadIdx.y);
}

__global__ void __launch_bounds__(kTileX * kTileY)
output_kernel_kernel(hf_cuk_raw raw, hf_cuk_head head, const __half *in, int in_stride, int pw,
                     int ph, int spp, int ksums, int radius, int w, int h, void *dst,
                     int dst_f16) {
  // pe: the estimate's sums of a kernel that mixes (HF_KSUMS_MIXED)
  __shared__ float3 px[kKHaloH][kKHaloW], pe_mem[kKHaloH][kKHaloW];
  float3 (*pe)[kKHaloW] = ksums == HF_KSUMS_MIXED ? pe_mem : nullptr;
  const int tid = threadIdx.y * kTileX + threadIdx.x;
  sums_load<kKR>(px, pe, in, in_stride, pw, ph, spp, ksums, w, h, blockIdx.x, blockIdx.y,
                 blockIdx.z, tid, kTileX * kTileY);
  __syncthreads();
  kernel_finish(px, pe, raw, head, in, in_stride, pw, ph, spp, radius, w, h, dst, dst_f16,
                blockIdx.x, blockIdx.y, blockIdx.z, threadIdx.x, threadIdx.y);
}

}  // namespace

extern "C" cudaError_t hf_cuk_input(const void *src, int src_f16, int batch, int w, int h,
                                    int cin, void *dst, int pw, int ph, int cpad,
                                    cudaStream_t stream) {
  if (cpad % 8 || cin > cpad || w > pw || h > ph) return cudaErrorInvalidValue;
  Launch l;
  cudaError_t e = launch_shape((long long)pw * (cpad / 8), ph, batch, &l);
  if (e != cudaSuccess) return e;
  const bool pairs = cin % 2 == 0;
  __half *d = (__half *)dst;
  if (src_f16 && pairs)
    input_kernel<true, true><<<l.grid, l.block, 0, stream>>>(src, w, h, cin, d, pw, ph, cpad);
  else if (src_f16)
    input_kernel<true, false><<<l.grid, l.block, 0, stream>>>(src, w, h, cin, d, pw, ph, cpad);
  else if (pairs)
    input_kernel<false, true><<<l.grid, l.block, 0, stream>>>(src, w, h, cin, d, pw, ph, cpad);
  else
    input_kernel<false, false><<<l.grid, l.block, 0, stream>>>(src, w, h, cin, d, pw, ph, cpad);
  return cudaGetLastError();
}

// The grid of the input check and the guard: up to kScanBlocks blocks of
// kMaxThreads along the frame's pixels, one row of blocks per frame.
static dim3 scan_grid(long long pixels, int batch) {
  const long long blocks = (pixels + kMaxThreads - 1) / kMaxThreads;
  return dim3((unsigned)(blocks < kScanBlocks ? blocks : kScanBlocks), (unsigned)batch);
}

extern "C" cudaError_t hf_cuk_scan(void *src, int src_f16, int batch, long long pixels, int spp,
                                   hf_cuk_scan_counts *counts, cudaStream_t stream) {
  if (batch < 1 || batch > 65535 || pixels < 1 || spp < 1) return cudaErrorInvalidValue;
  cudaError_t e = cudaMemsetAsync(counts, 0, sizeof *counts * (size_t)batch, stream);
  if (e != cudaSuccess) return e;
  const dim3 grid = scan_grid(pixels, batch);
  if (src_f16)
    scan_kernel<true><<<grid, kMaxThreads, 0, stream>>>(src, pixels, spp, counts);
  else
    scan_kernel<false><<<grid, kMaxThreads, 0, stream>>>(src, pixels, spp, counts);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_guard(void *dst, int dst_f16, int batch, long long pixels,
                                    hf_cuk_scan_counts *counts, cudaStream_t stream) {
  if (batch < 1 || batch > 65535 || pixels < 1) return cudaErrorInvalidValue;
  const dim3 grid = scan_grid(pixels, batch);
  if (dst_f16)
    guard_kernel<true><<<grid, kMaxThreads, 0, stream>>>(dst, pixels, counts);
  else
    guard_kernel<false><<<grid, kMaxThreads, 0, stream>>>(dst, pixels, counts);
  return cudaGetLastError();
}

#define DISPATCH_UNIT(u, KERNEL, l, stream, ...)                                \
  switch (u) {                                                                  \
  case 8: KERNEL<8><<<l.grid, l.block, 0, stream>>>(__VA_ARGS__); break;        \
  case 4: KERNEL<4><<<l.grid, l.block, 0, stream>>>(__VA_ARGS__); break;        \
  case 2: KERNEL<2><<<l.grid, l.block, 0, stream>>>(__VA_ARGS__); break;        \
  default: KERNEL<1><<<l.grid, l.block, 0, stream>>>(__VA_ARGS__); break;       \
  }

extern "C" cudaError_t hf_cuk_bias_act(hf_cuk_view y, int batch, const float *bias, int relu,
                                       cudaStream_t stream) {
  const int u = unit_for_view(y);
  Launch l;
  cudaError_t e = launch_shape((long long)y.w * (y.c / u), y.h, batch, &l);
  if (e != cudaSuccess) return e;
  DISPATCH_UNIT(u, bias_act_kernel, l, stream, y, bias, relu);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_copy(hf_cuk_view dst, hf_cuk_view src, int batch,
                                   cudaStream_t stream) {
  if (dst.c != src.c || dst.h != src.h || dst.w != src.w) return cudaErrorInvalidValue;
  const int a = unit_for_view(dst), b = unit_for_view(src);
  const int u = a < b ? a : b;
  Launch l;
  cudaError_t e = launch_shape((long long)dst.w * (dst.c / u), dst.h, batch, &l);
  if (e != cudaSuccess) return e;
  DISPATCH_UNIT(u, copy_kernel, l, stream, dst, src);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_depth_to_space(hf_cuk_view dst, const void *src, int batch,
                                             int offset, cudaStream_t stream) {
  if (dst.h % 2 || dst.w % 2 || (offset != 0 && offset != 1)) return cudaErrorInvalidValue;
  const int a = unit_for_view(dst), b = unit_for(4 * dst.c, dst.c, 0, 0, src);
  const int u = a < b ? a : b;
  Launch l;
  cudaError_t e = launch_shape((long long)dst.w * (dst.c / u), dst.h, batch, &l);
  if (e != cudaSuccess) return e;
  DISPATCH_UNIT(u, d2s_kernel, l, stream, dst, (const __half *)src, offset);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_fill(void *dst, size_t n, uint32_t seed, cudaStream_t stream) {
  if (!n) return cudaSuccess;
  size_t blocks = (n + kMaxThreads - 1) / kMaxThreads;
  if (blocks > 4096) blocks = 4096;
  fill_kernel<<<(unsigned)blocks, kMaxThreads, 0, stream>>>((__half *)dst, n, seed);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_output_unet(hf_cuk_raw raw, int batch, int w, int h, void *dst,
                                          int dst_f16, cudaStream_t stream) {
  Launch l;
  cudaError_t e = launch_shape(w, h, batch, &l);
  if (e != cudaSuccess) return e;
  output_unet_kernel<<<l.grid, l.block, 0, stream>>>(raw, w, h, dst, dst_f16);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_output_residual(hf_cuk_raw raw, const void *in, int in_stride,
                                              int pw, int ph, int spp, int batch, int w, int h,
                                              void *dst, int dst_f16, cudaStream_t stream) {
  if (batch < 1 || batch > 65535 || w < 1 || h < 1) return cudaErrorInvalidValue;
  dim3 grid((w + kTileX - 1) / kTileX, (h + kTileY - 1) / kTileY, batch);
  if (grid.y > 65535) return cudaErrorInvalidValue;
  output_residual_kernel<<<grid, dim3(kTileX, kTileY), 0, stream>>>(
      raw, (const __half *)in, in_stride, pw, ph, spp, w, h, dst, dst_f16);
  return cudaGetLastError();
}

extern "C" cudaError_t hf_cuk_output_kernel(hf_cuk_raw raw, hf_cuk_head head, const void *in,
                                            int in_stride, int pw, int ph, int spp, int ksums,
                                            int radius, int batch, int w, int h, void *dst,
                                            int dst_f16, cudaStream_t stream) {
  if (batch < 1 || batch > 65535 || w < 1 || h < 1 || radius < 0 || radius > kKR)
    return cudaErrorInvalidValue;
  if (ksums != HF_KSUMS_SAMPLES && ksums != HF_KSUMS_ESTIMATE && ksums != HF_KSUMS_MIXED)
    return cudaErrorInvalidValue;
  if (ksums && spp * HF_FEATURES_PER_SAMPLE + HF_ESTIMATE_CHANNELS > in_stride)
    return cudaErrorInvalidValue;
  if (head.w && (!head.b || head.hidden < 0 || head.cin < 0 || head.hidden + head.cin > kMaxFeat ||
                 head.cin > in_stride))
    return cudaErrorInvalidValue;
  dim3 grid((w + kTileX - 1) / kTileX, (h + kTileY - 1) / kTileY, batch);
  if (grid.y > 65535) return cudaErrorInvalidValue;
  output_kernel_kernel<<<grid, dim3(kTileX, kTileY), 0, stream>>>(
      raw, head, (const __half *)in, in_stride, pw, ph, spp, ksums, radius, w, h, dst, dst_f16);
  return cudaGetLastError();
}
