// What each thread of the cudnn backend's small kernels does (internal to
// src/), as __host__ __device__ functions of the thread's grid position:
// cudnn_kernels.cu wraps them in __global__ kernels, and
// tests/gpu/test_cudnn_kernels.cu runs the very same functions over the same
// grid on the CPU, so the index arithmetic is checked without a GPU.
//
// Grids are (units of a row, rows, frames); a unit is U FP16 elements moved
// as one access (16, 8, 4 or 2 bytes). No thread divides 64-bit numbers.
#ifndef HF_CUDNN_KERNELS_BODY_CUH
#define HF_CUDNN_KERNELS_BODY_CUH

#include <stdint.h>

#include <cuda_fp16.h>
#include <vector_types.h>

#include "cudnn_kernels.h"
#include "hfcore.h"  // HF_RESIDUAL_RADIUS, HF_KERNEL_MAX_*, HF_FEATURES_PER_SAMPLE
#include "sample_rule.h"

#define HF_HD __host__ __device__ __forceinline__

namespace hf_kb {

constexpr int kMaxThreads = 256;

template <int U> struct Access;
template <> struct Access<8> { using T = uint4; };
template <> struct Access<4> { using T = uint2; };
template <> struct Access<2> { using T = unsigned int; };
template <> struct Access<1> { using T = unsigned short; };

template <int U> union Pack {
  typename Access<U>::T v;
  __half h[U];
};

template <int U> HF_HD Pack<U> load(const __half *p) {
  Pack<U> r;
  r.v = *reinterpret_cast<const typename Access<U>::T *>(p);
  return r;
}
template <int U> HF_HD void store(__half *p, const Pack<U> &r) {
  *reinterpret_cast<typename Access<U>::T *>(p) = r.v;
}

// The launch of a (units, rows, frames) grid: blocks of up to kMaxThreads
// threads along a row, as few idle ones as a short row allows.
struct Launch {
  dim3 grid, block;
};

inline cudaError_t launch_shape(long long units, long long rows, long long frames, Launch *l) {
  if (units < 1 || rows < 1 || frames < 1) return cudaErrorInvalidValue;
  if (rows > 65535 || frames > 65535 || units > (long long)INT32_MAX) return cudaErrorInvalidValue;
  int threads = units >= kMaxThreads ? kMaxThreads : (int)((units + 31) / 32 * 32);
  l->block = dim3(threads);
  l->grid = dim3((unsigned)((units + threads - 1) / threads), (unsigned)rows, (unsigned)frames);
  return cudaSuccess;
}

// The widest unit (8, 4, 2 or 1 elements) that every element offset a
// kernel makes (c, the strides, the base address) is a multiple of.
inline int unit_for(long long c, long long a, long long b, long long d, const void *ptr) {
  int u = 8;
  const uintptr_t p = (uintptr_t)ptr;
  while (u > 1 && (c % u || a % u || b % u || d % u || p % (2u * u))) u /= 2;
  return u;
}
inline int unit_for_view(const hf_cuk_view &v) { return unit_for(v.c, v.sn, v.sy, v.sx, v.base); }

// ---- input: 8 channels (16 bytes) of one padded pixel per thread ----------
// PAIRS: cin is even, so channel pairs never straddle a pixel and load as
// one access.
template <bool F16, bool PAIRS>
HF_HD void input_unit(const void *src, int w, int h, int cin, __half *dst, int pw, int ph, int cpad,
                      int u, int y, int n) {
  const int groups = cpad >> 3;
  if (u >= pw * groups) return;
  const int x = u / groups, c0 = (u - x * groups) << 3;
  Pack<8> out;
  for (int k = 0; k < 8; k++) out.h[k] = __float2half(0.0f);
  if (x < w && y < h && c0 < cin) {
    const size_t s = (((size_t)n * h + y) * w + x) * cin + c0;
    // Fixed trip counts and no early exit, so the loops unroll and out
    // stays in registers.
    if (PAIRS) {
      for (int k = 0; k < 8; k += 2) {
        if (c0 + k >= cin) continue;
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
      for (int k = 0; k < 8; k++) {
        if (c0 + k >= cin) continue;
        out.h[k] = F16 ? ((const __half *)src)[s + k] : __float2half_rn(((const float *)src)[s + k]);
      }
    }
  }
  store<8>(dst + (((size_t)n * ph + y) * pw + x) * cpad + c0, out);
}

// ---- input check: one pixel of the frame as uploaded per thread --------------

// What one pixel adds to its frame's counts (hf_cuk_scan_counts).
struct ScanPixel {
  int covered;       // covered samples of the pixel as it came (the statistics' input)
  unsigned bin;      // its strand alpha's histogram bin, when covered
  int bad;           // out-of-contract samples, fixed in place
  int first_bad;     // the first of them, as a sample index in the pixel; -1 if none
};

// Pixel `pixel` of a frame of spp samples of six FP32 (F16 false) or FP16
// values: its statistic made from the values as they came
// (hf_input_stats_add's), then each out-of-contract sample fixed in place
// by the rule (hf_features_sanitise's, through float32 as it does: exact,
// sample_rule.h). What the host passes make of the same pixel, bit for bit.
template <bool F16> HF_HD ScanPixel scan_pixel(void *frame, int spp, long long pixel) {
  ScanPixel r;
  r.bad = 0;
  r.first_bad = -1;
  const long long stride = (long long)spp * HF_FEATURES_PER_SAMPLE;
  float v;
  if (F16) {
    uint16_t *px = (uint16_t *)frame + pixel * stride;
    v = hf_rule_strand_alpha_f16(px, spp, &r.covered);
    for (int k = 0; k < spp; k++) {
      uint16_t *sm = px + k * HF_FEATURES_PER_SAMPLE;
      if (hf_rule_ok_f16(sm)) continue;
      float f[HF_FEATURES_PER_SAMPLE];
      for (int i = 0; i < HF_FEATURES_PER_SAMPLE; i++) {
        __half_raw hr;
        hr.x = sm[i];
        f[i] = __half2float(__half(hr));
      }
      int kind, feature;
      hf_rule_fix_f32(f, &kind, &feature);
      for (int i = 0; i < HF_FEATURES_PER_SAMPLE; i++) {
        __half_raw hr = __half_raw(__float2half_rn(f[i]));
        sm[i] = hr.x;
      }
      if (!r.bad++) r.first_bad = k;
    }
  } else {
    float *px = (float *)frame + pixel * stride;
    v = hf_rule_strand_alpha_f32(px, spp, &r.covered);
    for (int k = 0; k < spp; k++) {
      float *sm = px + k * HF_FEATURES_PER_SAMPLE;
      if (hf_rule_ok_f32(sm)) continue;
      int kind, feature;
      hf_rule_fix_f32(sm, &kind, &feature);
      if (!r.bad++) r.first_bad = k;
    }
  }
  r.bin = r.covered ? hf_rule_stat_bin(v) : 0;
  return r;
}

// Output pixel `pixel` of [pixels][3] FP32 (F16 false) or FP16 values kept in
// its ranges in place (hf_output_guard's rule, sample_rule.h); 1 when it
// changed.
template <bool F16> HF_HD int guard_pixel(void *out, long long pixel) {
  return F16 ? hf_rule_guard_f16((uint16_t *)out + pixel * 3)
             : hf_rule_guard_f32((float *)out + pixel * 3);
}

// ---- bias + activation, copies, depth-to-space: U channels per thread ----
template <int U>
HF_HD void bias_act_unit(const hf_cuk_view &y, const float *bias, int relu, int u, int row, int n) {
  const int cu = y.c / U;
  if (u >= y.w * cu) return;
  const int x = u / cu, k = (u - x * cu) * U;
  __half *p = (__half *)y.base + n * y.sn + row * y.sy + x * y.sx + k;
  Pack<U> v = load<U>(p);
  for (int i = 0; i < U; i++) {
    const float f = __half2float(v.h[i]) + bias[k + i];
    v.h[i] = __float2half_rn(relu ? fmaxf(f, 0.0f) : f);
  }
  store<U>(p, v);
}

template <int U>
HF_HD void copy_unit(const hf_cuk_view &dst, const hf_cuk_view &src, int u, int row, int n) {
  const int cu = dst.c / U;
  if (u >= dst.w * cu) return;
  const int x = u / cu, k = (u - x * cu) * U;
  const __half *s = (const __half *)src.base + n * src.sn + row * src.sy + x * src.sx + k;
  __half *d = (__half *)dst.base + n * dst.sn + row * dst.sy + x * dst.sx + k;
  store<U>(d, load<U>(s));
}

// By destination pixel (coalesced writes along the row): its phase picks
// the source pixel and channel block (cudnn_layout.h, D2S and SHUFFLE).
template <int U>
HF_HD void d2s_unit(const hf_cuk_view &dst, const __half *src, int offset, int u, int Y, int n) {
  const int cu = dst.c / U;
  if (u >= dst.w * cu) return;
  const int X = u / cu, k = (u - X * cu) * U;
  const int dy = Y & 1, dx = X & 1;
  const int sh = (dst.h >> 1) + offset, sw = (dst.w >> 1) + offset, sc = 4 * dst.c;
  const int sy = (Y >> 1) + dy * offset, sx = (X >> 1) + dx * offset;
  const __half *s = src + (((size_t)n * sh + sy) * sw + sx) * sc + (2 * dy + dx) * dst.c + k;
  __half *d = (__half *)dst.base + n * dst.sn + Y * dst.sy + X * dst.sx + k;
  store<U>(d, load<U>(s));
}

// ---- output stages ---------------------------------------------------------

// The raw output of frame pixel (x, y) of frame n (hf_cl_raw).
HF_HD const __half *raw_pixel(const hf_cuk_raw &r, int n, int y, int x) {
  const __half *base = (const __half *)r.data;
  if (r.at.div == 1)
    return base + (((size_t)n * r.at.rows + y) * r.at.cols + x) * r.at.pix_stride;
  const int dy = y & 1, dx = x & 1;
  const int ry = (y >> 1) + dy * r.at.offset, rx = (x >> 1) + dx * r.at.offset;
  return base + (((size_t)n * r.at.rows + ry) * r.at.cols + rx) * r.at.pix_stride +
         (2 * dy + dx) * r.at.co;
}

HF_HD void store3(void *dst, int dst_f16, size_t i, float a, float b, float c) {
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

// HF_ARCH_UNET: the paper's transforms (section 3.3.2), in FP32. One pixel
// per thread.
HF_HD void output_unet_px(const hf_cuk_raw &raw, int w, int h, void *dst, int dst_f16, int x,
                          int y, int n) {
  if (x >= w) return;
  const __half *p = raw_pixel(raw, n, y, x);
  const float c = __half2float(p[0]), hl = __half2float(p[1]), a = __half2float(p[2]);
  store3(dst, dst_f16, ((size_t)n * h + y) * w + x, c * c * c / 32.0f + c / 5.0f + 1.0f,
         fmaxf(hl, 0.0f), fminf(fmaxf(a, 0.0f), 1.0f));
}

// HF_ARCH_RESIDUAL, one block per kTileX x kTileY tile, in three phases
// separated by a barrier: (1) each input pixel of the tile and its halo is
// reduced once to (covered samples, their colour sum, their highlight sum)
// in shared memory; (2) rows are summed over the window's width; (3) each
// thread sums its pixel's column of row sums and finishes the pixel.
constexpr int kTileX = 32, kTileY = 8, kR = HF_RESIDUAL_RADIUS;
constexpr int kHaloW = kTileX + 2 * kR, kHaloH = kTileY + 2 * kR;

// A tile and a halo of R pixels around it.
template <int R> struct Halo {
  static constexpr int W = kTileX + 2 * R, H = kTileY + 2 * R;
};

// Per-pixel sums (covered samples, their colour sum, their highlight sum)
// of a tile and its halo of R pixels, zero outside the frame, of kind ksums
// (HF_KSUMS_*, hf_pixel_sums_rows): the samples', the estimate's after them
// (hf_estimate_sums), or with HF_KSUMS_MIXED the samples' into px and the
// estimate's into pe (NULL otherwise).
template <int R>
HF_HD void sums_load(float3 (*px)[Halo<R>::W], float3 (*pe)[Halo<R>::W], const __half *in,
                     int in_stride, int pw, int ph, int spp, int ksums, int w, int h, int bx,
                     int by, int n, int tid, int nthreads) {
  constexpr int HW = Halo<R>::W, HH = Halo<R>::H;
  const int gx0 = bx * kTileX - R, gy0 = by * kTileY - R;
  for (int i = tid; i < HW * HH; i += nthreads) {
    const int ly = i / HW, lx = i - ly * HW;
    const int gy = gy0 + ly, gx = gx0 + lx;
    float cnt = 0.0f, col = 0.0f, hsum = 0.0f, ecnt = 0.0f, ecol = 0.0f, ehsum = 0.0f;
    if (gx >= 0 && gx < w && gy >= 0 && gy < h) {
      const __half *s = in + (((size_t)n * ph + gy) * pw + gx) * in_stride;
      if (ksums != HF_KSUMS_SAMPLES) {
        const __half *e = s + spp * HF_FEATURES_PER_SAMPLE;
        ecnt = (float)spp * __half2float(e[2]);
        ecol = ecnt * __half2float(e[0]);
        ehsum = ecnt * __half2float(e[1]);
      }
      if (ksums != HF_KSUMS_ESTIMATE) {
        for (int k = 0; k < spp; k++, s += HF_FEATURES_PER_SAMPLE)
          if (__half2float(s[2]) > 0.0f) {
            cnt += 1.0f;
            col += __half2float(s[0]);
            hsum += __half2float(s[1]);
          }
      }
    }
    if (ksums == HF_KSUMS_ESTIMATE) px[ly][lx] = make_float3(ecnt, ecol, ehsum);
    else px[ly][lx] = make_float3(cnt, col, hsum);
    if (ksums == HF_KSUMS_MIXED) pe[ly][lx] = make_float3(ecnt, ecol, ehsum);
  }
}

HF_HD void residual_load(float3 (*px)[kHaloW], const __half *in, int in_stride, int pw, int ph,
                         int spp, int w, int h, int bx, int by, int n, int tid, int nthreads) {
  sums_load<kR>(px, nullptr, in, in_stride, pw, ph, spp, HF_KSUMS_SAMPLES, w, h, bx, by, n, tid,
                nthreads);
}

HF_HD void residual_rows(float3 (*px)[kHaloW], float3 (*rows)[kTileX], int tid, int nthreads) {
  for (int i = tid; i < kHaloH * kTileX; i += nthreads) {
    const int ly = i / kTileX, lx = i - ly * kTileX;
    float3 a = make_float3(0.0f, 0.0f, 0.0f);
    for (int d = 0; d <= 2 * kR; d++) {
      a.x += px[ly][lx + d].x;
      a.y += px[ly][lx + d].y;
      a.z += px[ly][lx + d].z;
    }
    rows[ly][lx] = a;
  }
}

HF_HD void residual_finish(float3 (*rows)[kTileX], const hf_cuk_raw &raw, int spp, int w, int h,
                           void *dst, int dst_f16, int bx, int by, int n, int tx, int ty) {
  const int x = bx * kTileX + tx, y = by * kTileY + ty;
  if (x >= w || y >= h) return;
  float3 a = make_float3(0.0f, 0.0f, 0.0f);
  for (int d = 0; d <= 2 * kR; d++) {
    a.x += rows[ty + d][tx].x;
    a.y += rows[ty + d][tx].y;
    a.z += rows[ty + d][tx].z;
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

// HF_ARCH_KERNEL, one block per kTileX x kTileY tile: (1) sums_load of the
// tile and a halo of the largest radius; (2) each thread its pixel
// (hf_kernel_output_frame's values; with pe, the estimate's sums of a
// kernel that mixes, HF_KSUMS_MIXED).
constexpr int kKR = HF_KERNEL_MAX_RADIUS;
constexpr int kKHaloW = Halo<kKR>::W, kKHaloH = Halo<kKR>::H;
constexpr int kMaxFeat =
    HF_KERNEL_MAX_HIDDEN + HF_MAX_SPP * HF_FEATURES_PER_SAMPLE + HF_ESTIMATE_CHANNELS;

// Raw channel o of a pixel: dec0's, or the head's dot product over feat
// (ReLU(dec0)'s hidden channels, then the input's).
HF_HD float kernel_channel(const __half *rp, const hf_cuk_head &hd, const float *feat, int o) {
  if (!hd.w) return __half2float(rp[o]);
  const int nfeat = hd.hidden + hd.cin;
  const float *wr = hd.w + (size_t)o * nfeat;
  float a = hd.b[o];
  for (int j = 0; j < nfeat; j++) a += wr[j] * feat[j];
  return a;
}

HF_HD void kernel_finish(const float3 (*px)[kKHaloW], const float3 (*pe)[kKHaloW],
                         const hf_cuk_raw &raw, const hf_cuk_head &hd, const __half *in, int in_stride, int pw, int ph,
                         int spp, int radius, int w, int h, void *dst, int dst_f16, int bx,
                         int by, int n, int tx, int ty) {
  const int x = bx * kTileX + tx, y = by * kTileY + ty;
  if (x >= w || y >= h) return;
  const __half *rp = raw_pixel(raw, n, y, x);
  float feat[kMaxFeat];
  if (hd.w) {
    const __half *ip = in + (((size_t)n * ph + y) * pw + x) * in_stride;
    for (int j = 0; j < hd.hidden; j++) feat[j] = __half2float(rp[j]);
    for (int j = 0; j < hd.cin; j++) feat[hd.hidden + j] = __half2float(ip[j]);
  }
  const int side = 2 * radius + 1, taps = side * side;
  const int dy0 = max(-radius, -y), dy1 = min(radius, h - 1 - y);
  const int dx0 = max(-radius, -x), dx1 = min(radius, w - 1 - x);
  // An online softmax over the taps inside the frame: the sums are kept
  // relative to the largest logit so far and rescaled when a larger comes.
  float m = -INFINITY, den = 0.0f, an = 0.0f, ac = 0.0f, ah = 0.0f;
  float bn = 0.0f, bc = 0.0f, bh = 0.0f;  // the estimate's, when mixing
  for (int dy = dy0; dy <= dy1; dy++)
    for (int dx = dx0; dx <= dx1; dx++) {
      const float l = kernel_channel(rp, hd, feat, (dy + radius) * side + dx + radius);
      if (l > m) {
        const float s = expf(m - l);  // 0 for the first tap
        den *= s;
        an *= s;
        ac *= s;
        ah *= s;
        bn *= s;
        bc *= s;
        bh *= s;
        m = l;
      }
      const float e = expf(l - m);
      const float3 q = px[ty + kKR + dy][tx + kKR + dx];
      den += e;
      an += e * q.x;
      ac += e * q.y;
      ah += e * q.z;
      if (pe) {
        const float3 qe = pe[ty + kKR + dy][tx + kKR + dx];
        bn += e * qe.x;
        bc += e * qe.y;
        bh += e * qe.z;
      }
    }
  if (pe) {
    // The estimate's sums plus beta times the samples' less the estimate's.
    const float mv = kernel_channel(rp, hd, feat, taps + 3);
    const float beta = 1.0f / (1.0f + expf(-HF_KERNEL_MIX_GAIN * mv));
    an = bn + beta * (an - bn);
    ac = bc + beta * (ac - bc);
    ah = bh + beta * (ah - bh);
  }
  const float c0 = kernel_channel(rp, hd, feat, taps), c1 = kernel_channel(rp, hd, feat, taps + 1);
  const float c2 = kernel_channel(rp, hd, feat, taps + 2);
  // The weights are e / den: N = an / den, and C / N = ac / an.
  const float nn = an / den;
  const bool ok = nn > 1e-12f;
  store3(dst, dst_f16, ((size_t)n * h + y) * w + x, (ok ? ac / an : 1.0f) + c0,
         fmaxf((ok ? ah / an : 0.0f) + c1, 0.0f), fminf(fmaxf(nn / (float)spp + c2, 0.0f), 1.0f));
}

}  // namespace hf_kb

#endif  // HF_CUDNN_KERNELS_BODY_CUH
