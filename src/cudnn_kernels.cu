// The small CUDA kernels around the cuDNN convolutions: see cudnn_kernels.h.
#include <stdint.h>
#include <string.h>

#include <cuda_fp16.h>

#include "cudnn_kernels.h"
#include "hfcore.h"  // HF_RESIDUAL_RADIUS

namespace {

constexpr int kMaxThreads = 256;

// U FP16 elements moved as one access: 16, 8, 4 or 2 bytes.
template <int U> struct Access;
template <> struct Access<8> { using T = uint4; };
template <> struct Access<4> { using T = uint2; };
template <> struct Access<2> { using T = unsigned int; };
template <> struct Access<1> { using T = unsigned short; };

template <int U> union Pack {
  typename Access<U>::T v;
  __half h[U];
};

template <int U> __device__ __forceinline__ Pack<U> load(const __half *p) {
  Pack<U> r;
  r.v = *reinterpret_cast<const typename Access<U>::T *>(p);
  return r;
}
template <int U> __device__ __forceinline__ void store(__half *p, const Pack<U> &r) {
  *reinterpret_cast<typename Access<U>::T *>(p) = r.v;
}

// Grid of (units of a row, rows, frames): a block of up to kMaxThreads
// threads along the row, as few idle threads as a short row allows.
struct Launch {
  dim3 grid, block;
};

cudaError_t launch_shape(long long units, long long rows, long long frames, Launch *l) {
  if (units < 1 || rows < 1 || frames < 1) return cudaErrorInvalidValue;
  if (rows > 65535 || frames > 65535 || units > (long long)INT32_MAX) return cudaErrorInvalidValue;
  int threads = units >= kMaxThreads ? kMaxThreads : (int)((units + 31) / 32 * 32);
  l->block = dim3(threads);
  l->grid = dim3((unsigned)((units + threads - 1) / threads), (unsigned)rows, (unsigned)frames);
  return cudaSuccess;
}

// The widest access (8, 4, 2 or 1 elements) that every element offset the
// kernel makes is a multiple of.
int unit_for(long long c, long long a, long long b, long long d, const void *ptr) {
  int u = 8;
  const uintptr_t p = (uintptr_t)ptr;
  while (u > 1 && (c % u || a % u || b % u || d % u || p % (2u * u))) u /= 2;
  return u;
}
int unit_for_view(const hf_cuk_view &v) { return unit_for(v.c, v.sn, v.sy, v.sx, v.base); }

// ---- input ------------------------------------------------------------------

// One thread writes 8 channels (16 bytes) of one padded pixel. PAIRS: cin
// is even, so channel pairs never straddle a pixel and load as one access.
template <bool F16, bool PAIRS>
__global__ void input_kernel(const void *src, int w, int h, int cin, __half *dst, int pw, int ph,
                             int cpad) {
  const int groups = cpad >> 3;
  const int u = blockIdx.x * blockDim.x + threadIdx.x;
  if (u >= pw * groups) return;
  const int y = blockIdx.y, n = blockIdx.z;
  const int x = u / groups, c0 = (u - x * groups) << 3;
  Pack<8> out;
#pragma unroll
  for (int k = 0; k < 8; k++) out.h[k] = __float2half(0.0f);
  if (x < w && y < h && c0 < cin) {
    const size_t s = (((size_t)n * h + y) * w + x) * cin + c0;
    if (PAIRS) {
#pragma unroll
      for (int k = 0; k < 8; k += 2) {
        if (c0 + k >= cin) break;
        if (F16) {
          const __half2 v = *reinterpret_cast<const __half2 *>((const __half *)src + s + k);
          out.h[k] = __low2half(v);
          out.h[k + 1] = __high2half(v);
        } else {
          const float2 v = *reinterpret_cast<const float2 *>((const float *)src + s + k);
          out.h[k] = __float2half_rn(v.x);
          out.h[k + 1] = __float2half_rn(v.y);
        }
      }
    } else {
#pragma unroll
      for (int k = 0; k < 8; k++) {
        if (c0 + k >= cin) break;
        out.h[k] = F16 ? ((const __half *)src)[s + k] : __float2half_rn(((const float *)src)[s + k]);
      }
    }
  }
  store<8>(dst + (((size_t)n * ph + y) * pw + x) * cpad + c0, out);
}

// ---- bias + activation, copies, depth-to-space -------------------------------

template <int U>
__global__ void bias_act_kernel(hf_cuk_view y, const float *bias, int relu) {
  const int cu = y.c / U;
  const int u = blockIdx.x * blockDim.x + threadIdx.x;
  if (u >= y.w * cu) return;
  const int x = u / cu, k = (u - x * cu) * U;
  __half *p = (__half *)y.base + blockIdx.z * y.sn + blockIdx.y * y.sy + x * y.sx + k;
  Pack<U> v = load<U>(p);
#pragma unroll
  for (int i = 0; i < U; i++) {
    float f = __half2float(v.h[i]) + bias[k + i];
    v.h[i] = __float2half_rn(relu ? fmaxf(f, 0.0f) : f);
  }
  store<U>(p, v);
}

template <int U>
__global__ void copy_kernel(hf_cuk_view dst, hf_cuk_view src) {
  const int cu = dst.c / U;
  const int u = blockIdx.x * blockDim.x + threadIdx.x;
  if (u >= dst.w * cu) return;
  const int x = u / cu, k = (u - x * cu) * U;
  const __half *s =
      (const __half *)src.base + blockIdx.z * src.sn + blockIdx.y * src.sy + x * src.sx + k;
  __half *d = (__half *)dst.base + blockIdx.z * dst.sn + blockIdx.y * dst.sy + x * dst.sx + k;
  store<U>(d, load<U>(s));
}

// By destination pixel (coalesced writes along the row): its phase picks
// the source pixel and channel block.
template <int U>
__global__ void d2s_kernel(hf_cuk_view dst, const __half *src, int offset) {
  const int cu = dst.c / U;
  const int u = blockIdx.x * blockDim.x + threadIdx.x;
  if (u >= dst.w * cu) return;
  const int X = u / cu, k = (u - X * cu) * U;
  const int Y = blockIdx.y, n = blockIdx.z;
  const int dy = Y & 1, dx = X & 1;
  const int sh = (dst.h >> 1) + offset, sw = (dst.w >> 1) + offset, sc = 4 * dst.c;
  const int sy = (Y >> 1) + dy * offset, sx = (X >> 1) + dx * offset;
  const __half *s = src + (((size_t)n * sh + sy) * sw + sx) * sc + (2 * dy + dx) * dst.c + k;
  __half *d = (__half *)dst.base + n * dst.sn + Y * dst.sy + X * dst.sx + k;
  store<U>(d, load<U>(s));
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

// ---- output stages ------------------------------------------------------------

// The raw output of frame pixel (x, y) of frame n (hf_cl_raw).
__device__ __forceinline__ const __half *raw_pixel(const hf_cuk_raw &r, int n, int y, int x) {
  const __half *base = (const __half *)r.data;
  if (r.at.div == 1)
    return base + (((size_t)n * r.at.rows + y) * r.at.cols + x) * r.at.pix_stride;
  const int dy = y & 1, dx = x & 1;
  const int ry = (y >> 1) + dy * r.at.offset, rx = (x >> 1) + dx * r.at.offset;
  return base + (((size_t)n * r.at.rows + ry) * r.at.cols + rx) * r.at.pix_stride +
         (2 * dy + dx) * r.at.co;
}

__device__ __forceinline__ void store3(void *dst, int dst_f16, size_t i, float a, float b,
                                       float c) {
  if (dst_f16) {
    __half *d = (__half *)dst + i * 3;
    d[0] = __float2half_rn(a);
    d[1] = __float2half_rn(b);
    d[2] = __float2half_rn(c);
  } else {
    float *d = (float *)dst + i * 3;
    d[0] = a;
    d[1] = b;
    d[2] = c;
  }
}

// The paper's transforms (section 3.3.2), computed in FP32.
__global__ void output_unet_kernel(hf_cuk_raw raw, int w, int h, void *dst, int dst_f16) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x;
  if (x >= w) return;
  const int y = blockIdx.y, n = blockIdx.z;
  const __half *p = raw_pixel(raw, n, y, x);
  const float c = __half2float(p[0]), hl = __half2float(p[1]), a = __half2float(p[2]);
  store3(dst, dst_f16, ((size_t)n * h + y) * w + x, c * c * c / 32.0f + c / 5.0f + 1.0f,
         fmaxf(hl, 0.0f), fminf(fmaxf(a, 0.0f), 1.0f));
}

constexpr int kTileX = 32, kTileY = 8, kR = HF_RESIDUAL_RADIUS;

// One block finishes a kTileX x kTileY tile. Each input pixel of the tile
// and its halo is reduced once to (covered samples, their colour sum,
// their highlight sum) in shared memory; rows are then summed over the
// window's width, and the thread's pixel over its height.
__global__ void __launch_bounds__(kTileX * kTileY)
output_residual_kernel(hf_cuk_raw raw, const __half *in, int in_stride, int pw, int ph, int spp,
                       int w, int h, void *dst, int dst_f16) {
  constexpr int SW = kTileX + 2 * kR, SH = kTileY + 2 * kR;
  __shared__ float3 px[SH][SW];
  __shared__ float3 rows[SH][kTileX];
  const int n = blockIdx.z;
  const int gx0 = blockIdx.x * kTileX - kR, gy0 = blockIdx.y * kTileY - kR;
  const int tid = threadIdx.y * kTileX + threadIdx.x;
  for (int i = tid; i < SW * SH; i += kTileX * kTileY) {
    const int ly = i / SW, lx = i - ly * SW;
    const int gy = gy0 + ly, gx = gx0 + lx;
    float cnt = 0.0f, col = 0.0f, hsum = 0.0f;
    if (gx >= 0 && gx < w && gy >= 0 && gy < h) {
      const __half *s = in + (((size_t)n * ph + gy) * pw + gx) * in_stride;
      for (int k = 0; k < spp; k++, s += HF_FEATURES_PER_SAMPLE)
        if (__half2float(s[2]) > 0.0f) {
          cnt += 1.0f;
          col += __half2float(s[0]);
          hsum += __half2float(s[1]);
        }
    }
    px[ly][lx] = make_float3(cnt, col, hsum);
  }
  __syncthreads();
  for (int i = tid; i < SH * kTileX; i += kTileX * kTileY) {
    const int ly = i / kTileX, lx = i - ly * kTileX;
    float3 a = make_float3(0.0f, 0.0f, 0.0f);
#pragma unroll
    for (int d = 0; d <= 2 * kR; d++) {
      a.x += px[ly][lx + d].x;
      a.y += px[ly][lx + d].y;
      a.z += px[ly][lx + d].z;
    }
    rows[ly][lx] = a;
  }
  __syncthreads();
  const int x = blockIdx.x * kTileX + threadIdx.x, y = blockIdx.y * kTileY + threadIdx.y;
  if (x >= w || y >= h) return;
  float3 a = make_float3(0.0f, 0.0f, 0.0f);
#pragma unroll
  for (int d = 0; d <= 2 * kR; d++) {
    a.x += rows[threadIdx.y + d][threadIdx.x].x;
    a.y += rows[threadIdx.y + d][threadIdx.x].y;
    a.z += rows[threadIdx.y + d][threadIdx.x].z;
  }
  // The window cut to the frame, as hf_residual_base counts it.
  const int wy = min(y + kR, h - 1) - max(y - kR, 0) + 1;
  const int wx = min(x + kR, w - 1) - max(x - kR, 0) + 1;
  const float samples = (float)(wy * wx * spp);
  const float bc = a.x > 0.0f ? a.y / a.x : 1.0f;
  const float bh = a.x > 0.0f ? a.z / a.x : 0.0f;
  const __half *p = raw_pixel(raw, n, y, x);
  store3(dst, dst_f16, ((size_t)n * h + y) * w + x, bc + __half2float(p[0]),
         fmaxf(bh + __half2float(p[1]), 0.0f),
         fminf(fmaxf(a.x / samples + __half2float(p[2]), 0.0f), 1.0f));
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
