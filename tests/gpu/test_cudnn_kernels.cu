// The cudnn backend's element-wise kernels, checked without a GPU: the
// per-thread functions of src/cudnn_kernels_body.cuh (the code the device
// kernels run) are run here on the CPU over the same grids, with the same
// access widths the launchers pick for the same (256-byte aligned) buffers,
// and their results compared with the definitions: the input padding and
// FP16 conversion, bias + ReLU, view copies, depth-to-space with and
// without the one-pixel offset, the output stages against hfcore's
// hf_output_transform, hf_residual_base and hf_output_finish (the Kernel
// architecture, head included), the input check against hf_features_scan
// and hf_features_sanitise, and the output guard against hf_output_guard.
// Exit status 1 on any mismatch.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cudnn_kernels_body.cuh"

using namespace hf_kb;

static int failures;

#define CHECK(cond, ...)              \
  do {                                \
    if (!(cond)) {                    \
      if (failures++ < 20) {          \
        printf("FAIL: " __VA_ARGS__); \
        printf("\n");                 \
      }                               \
    }                                 \
  } while (0)

static uint64_t rng = 0x243F6A8885A308D3ull;
static float frand(void) {  // [0, 1)
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (float)(rng >> 40) / (float)(1 << 24);
}

// cudaMalloc's alignment, so the launchers' width choice is the device's.
static void *dalloc(size_t bytes) {
  void *p = aligned_alloc(256, (bytes + 255) / 256 * 256);
  if (!p) abort();
  return p;
}

static float h2f(__half h) { return __half2float(h); }

// Runs body(unit, row, frame) for every thread of the launch, as the GPU
// would (in any order: no body depends on another's result).
template <class F> static void run_grid(const Launch &l, F body) {
  for (unsigned n = 0; n < l.grid.z; n++)
    for (unsigned y = 0; y < l.grid.y; y++)
      for (unsigned b = 0; b < l.grid.x; b++)
        for (unsigned t = 0; t < l.block.x; t++) body((int)(b * l.block.x + t), (int)y, (int)n);
}

static Launch shape(long long units, long long rows, long long frames) {
  Launch l;
  if (launch_shape(units, rows, frames, &l) != cudaSuccess) abort();
  return l;
}

// ---- input -------------------------------------------------------------------

static void test_input(int cin, int f16) {
  const int batch = 2, w = 37, h = 23, pw = 40, ph = 24, cpad = (cin + 7) / 8 * 8;
  const size_t n_src = (size_t)batch * w * h * cin, n_dst = (size_t)batch * ph * pw * cpad;
  void *src = dalloc(n_src * 4);
  __half *dst = (__half *)dalloc(n_dst * 2);
  for (size_t i = 0; i < n_src; i++) {
    const float v = 4 * frand() - 2;
    if (f16) ((__half *)src)[i] = __float2half_rn(v);
    else ((float *)src)[i] = v;
  }
  memset((void *)dst, 0x7f, n_dst * 2);  // not zeros: every element must be written
  const Launch l = shape((long long)pw * (cpad / 8), ph, batch);
  const bool pairs = cin % 2 == 0;
  run_grid(l, [&](int u, int y, int n) {
    if (f16 && pairs) input_unit<true, true>(src, w, h, cin, dst, pw, ph, cpad, u, y, n);
    else if (f16) input_unit<true, false>(src, w, h, cin, dst, pw, ph, cpad, u, y, n);
    else if (pairs) input_unit<false, true>(src, w, h, cin, dst, pw, ph, cpad, u, y, n);
    else input_unit<false, false>(src, w, h, cin, dst, pw, ph, cpad, u, y, n);
  });
  int bad = 0;
  for (int n = 0; n < batch; n++)
    for (int y = 0; y < ph; y++)
      for (int x = 0; x < pw; x++)
        for (int c = 0; c < cpad; c++) {
          const uint16_t got = hf_f32_to_f16(h2f(dst[(((size_t)n * ph + y) * pw + x) * cpad + c]));
          float want = 0;
          if (x < w && y < h && c < cin) {
            const size_t s = (((size_t)n * h + y) * w + x) * cin + c;
            want = f16 ? h2f(((__half *)src)[s]) : ((float *)src)[s];
          }
          bad += got != hf_f32_to_f16(want);
        }
  CHECK(!bad, "input cin %d %s: %d elements wrong", cin, f16 ? "f16" : "f32", bad);
  printf("  input      cin %2d %s %dx%d -> %dx%dx%d: %s\n", cin, f16 ? "f16" : "f32", w, h, pw, ph,
         cpad, bad ? "WRONG" : "exact");
  free(src);
  free(dst);
}

// ---- views: bias + ReLU, copies, depth-to-space -------------------------------

// A view of a buffer of bh x bw pixels, pix_stride elements each: c
// channels from ch_off, pixel (y, x) at buffer pixel (y0 + step*y, x0 + step*x).
static hf_cuk_view make_view(__half *buf, int bh, int bw, int pix_stride, int ch_off, int c,
                             int h, int w, int y0, int x0, int step) {
  hf_cuk_view v;
  v.base = buf + ch_off + ((size_t)y0 * bw + x0) * pix_stride;
  v.sn = (long long)bh * bw * pix_stride;
  v.sy = (long long)step * bw * pix_stride;
  v.sx = (long long)step * pix_stride;
  v.c = c;
  v.h = h;
  v.w = w;
  return v;
}

static __half *at(const hf_cuk_view &v, int n, int y, int x, int k) {
  return (__half *)v.base + n * v.sn + y * v.sy + x * v.sx + k;
}

static void fill(__half *p, size_t n) {
  for (size_t i = 0; i < n; i++) p[i] = __float2half_rn(4 * frand() - 2);
}

static void test_bias_act(const char *what, int bh, int bw, int ps, int ch_off, int c, int y0,
                          int x0, int step, int want_unit) {
  const int batch = 2, h = (bh - y0 + step - 1) / step, w = (bw - x0 + step - 1) / step;
  const size_t n = (size_t)batch * bh * bw * ps;
  __half *buf = (__half *)dalloc(n * 2), *ref = (__half *)malloc(n * 2);
  float *bias = (float *)dalloc(c * 4);
  fill(buf, n);
  memcpy(ref, buf, n * 2);
  for (int k = 0; k < c; k++) bias[k] = frand() - 0.5f;
  const hf_cuk_view v = make_view(buf, bh, bw, ps, ch_off, c, h, w, y0, x0, step);
  const hf_cuk_view rv = make_view(ref, bh, bw, ps, ch_off, c, h, w, y0, x0, step);
  const int u = unit_for_view(v);
  CHECK(u == want_unit, "bias_act %s: access of %d elements, want %d", what, u, want_unit);
  run_grid(shape((long long)w * (c / u), h, batch), [&](int uu, int y, int nn) {
    switch (u) {
    case 8: bias_act_unit<8>(v, bias, 1, uu, y, nn); break;
    case 4: bias_act_unit<4>(v, bias, 1, uu, y, nn); break;
    case 2: bias_act_unit<2>(v, bias, 1, uu, y, nn); break;
    default: bias_act_unit<1>(v, bias, 1, uu, y, nn); break;
    }
  });
  for (int nn = 0; nn < batch; nn++)
    for (int y = 0; y < h; y++)
      for (int x = 0; x < w; x++)
        for (int k = 0; k < c; k++) {
          __half *e = at(rv, nn, y, x, k);
          *e = __float2half_rn(fmaxf(h2f(*e) + bias[k], 0.0f));
        }
  CHECK(!memcmp(buf, ref, n * 2), "bias_act %s: differs from the definition", what);
  printf("  bias_act   %-28s %d-element accesses: %s\n", what, u,
         memcmp(buf, ref, n * 2) ? "WRONG" : "exact");
  free(buf);
  free(ref);
  free(bias);
}

static void test_copy(void) {
  // The second half of a skip buffer (32 of 64 channels) to a dense
  // tensor and back into a fresh buffer: the dense-copy fallback.
  const int batch = 2, h = 11, w = 13, c = 32;
  const size_t nb = (size_t)batch * h * w * 64, nd = (size_t)batch * h * w * c;
  __half *skip = (__half *)dalloc(nb * 2), *dense = (__half *)dalloc(nd * 2),
         *back = (__half *)dalloc(nb * 2);
  fill(skip, nb);
  memset(back, 0, nb * 2);
  const hf_cuk_view sv = make_view(skip, h, w, 64, 32, c, h, w, 0, 0, 1);
  const hf_cuk_view dv = make_view(dense, h, w, c, 0, c, h, w, 0, 0, 1);
  const hf_cuk_view bv = make_view(back, h, w, 64, 32, c, h, w, 0, 0, 1);
  const int u = unit_for_view(sv) < unit_for_view(dv) ? unit_for_view(sv) : unit_for_view(dv);
  CHECK(u == 8, "copy: %d-element accesses, want 8", u);
  run_grid(shape((long long)w * (c / 8), h, batch),
           [&](int uu, int y, int n) { copy_unit<8>(dv, sv, uu, y, n); });
  run_grid(shape((long long)w * (c / 8), h, batch),
           [&](int uu, int y, int n) { copy_unit<8>(bv, dv, uu, y, n); });
  int bad = 0;
  for (size_t p = 0; p < (size_t)batch * h * w; p++)
    for (int k = 0; k < 64; k++) {
      const uint16_t *a = (const uint16_t *)skip + p * 64 + k, *b = (const uint16_t *)back + p * 64 + k;
      bad += k < 32 ? *b != 0 : *a != *b;
    }
  CHECK(!bad, "copy: %d elements wrong", bad);
  printf("  copy       strided -> dense -> strided, %d-element accesses: %s\n", u,
         bad ? "WRONG" : "exact");
  free(skip);
  free(dense);
  free(back);
}

static void test_d2s(int offset, int co, int ps, int ch_off) {
  const int batch = 2, h = 12, w = 16, sh = h + offset, sw = w + offset;
  const size_t ns = (size_t)batch * sh * sw * 4 * co, nd = (size_t)batch * 2 * h * 2 * w * ps;
  __half *src = (__half *)dalloc(ns * 2), *dst = (__half *)dalloc(nd * 2);
  fill(src, ns);
  memset(dst, 0, nd * 2);
  const hf_cuk_view v = make_view(dst, 2 * h, 2 * w, ps, ch_off, co, 2 * h, 2 * w, 0, 0, 1);
  const int a = unit_for_view(v), b = unit_for(4 * co, co, 0, 0, src), u = a < b ? a : b;
  run_grid(shape((long long)v.w * (co / u), v.h, batch), [&](int uu, int y, int n) {
    switch (u) {
    case 8: d2s_unit<8>(v, src, offset, uu, y, n); break;
    case 4: d2s_unit<4>(v, src, offset, uu, y, n); break;
    case 2: d2s_unit<2>(v, src, offset, uu, y, n); break;
    default: d2s_unit<1>(v, src, offset, uu, y, n); break;
    }
  });
  int bad = 0;
  for (int n = 0; n < batch; n++)
    for (int Y = 0; Y < 2 * h; Y++)
      for (int X = 0; X < 2 * w; X++)
        for (int k = 0; k < ps; k++) {
          const int dy = Y % 2, dx = X % 2;
          const uint16_t got = *(const uint16_t *)((dst + (((size_t)n * 2 * h + Y) * 2 * w + X) * ps + k));
          uint16_t want = 0;
          if (k >= ch_off && k < ch_off + co)
            want = *(const uint16_t *)(src + (((size_t)n * sh + Y / 2 + dy * offset) * sw + X / 2 +
                                              dx * offset) * 4 * co + (2 * dy + dx) * co + k - ch_off);
          bad += got != want;
        }
  CHECK(!bad, "depth-to-space offset %d co %d: %d wrong", offset, co, bad);
  printf("  d2s        offset %d, %2d channels into %2d (from %2d): %d-element accesses: %s\n",
         offset, co, ps, ch_off, u, bad ? "WRONG" : "exact");
  free(src);
  free(dst);
}

// ---- output stages -----------------------------------------------------------

static double rel_diff(double a, double b) { return fabs(a - b) / (fabs(b) > 1 ? fabs(b) : 1); }

// Random raw output of batch frames of ph x pw: dec0's OUT buffer (co
// channels), or a D2S dec0 scratch ((ph/2+1) x (pw/2+1) pixels of 4 phases
// x co channels). *buf is the data (free it).
static hf_cuk_raw random_raw(int d2s, int co, int batch, int pw, int ph, __half **buf) {
  hf_cuk_raw raw;
  memset(&raw, 0, sizeof raw);
  raw.at.buf = d2s ? HF_CL_BUF_SCRATCH : HF_CL_BUF_OUT;
  raw.at.pix_stride = d2s ? 4 * co : co;
  raw.at.rows = d2s ? ph / 2 + 1 : ph;
  raw.at.cols = d2s ? pw / 2 + 1 : pw;
  raw.at.div = d2s ? 2 : 1;
  raw.at.offset = d2s ? 1 : 0;
  raw.at.co = co;
  const size_t nraw = (size_t)batch * raw.at.rows * raw.at.cols * raw.at.pix_stride;
  *buf = (__half *)dalloc(nraw * 2);
  fill(*buf, nraw);
  raw.data = *buf;
  return raw;
}

// The FP16 network input of batch frames of ph x pw (cpad channels, spp
// samples): samples covered (alpha > 0) or not (all zero), none covered in
// the left empty_cols columns of frame 0. *in32 is the same in FP32.
// With estimate, each pixel also gets an alpha-corrected estimate after its
// samples (alpha 0 in a fifth of the pixels and in the empty columns).
static __half *random_input(int batch, int pw, int ph, int spp, int cpad, int empty_cols,
                            float **in32, int estimate = 0) {
  const size_t nin = (size_t)batch * ph * pw * cpad;
  __half *in = (__half *)dalloc(nin * 2);
  *in32 = (float *)malloc(nin * 4);
  for (size_t i = 0; i < nin; i++) in[i] = __float2half_rn(0.0f);
  for (size_t p = 0; p < (size_t)batch * ph * pw; p++) {
    const int hair = p >= (size_t)ph * pw || (int)(p % pw) >= empty_cols;
    for (int s = 0; s < spp; s++) {
      const int covered = frand() < 0.6f && hair;
      for (int f = 0; f < 6; f++) {
        const float v = covered ? (f == 2 ? 0.05f + 0.95f * frand() : frand()) : 0.0f;
        in[p * cpad + s * 6 + f] = __float2half_rn(v);
      }
    }
    if (estimate && hair && frand() < 0.8f)
      for (int f = 0; f < 3; f++) in[p * cpad + spp * 6 + f] = __float2half_rn(frand());
  }
  for (size_t i = 0; i < nin; i++) (*in32)[i] = h2f(in[i]);
  return in;
}

static void test_output(int residual, int d2s, int dst_f16) {
  const int batch = 2, w = 37, h = 23, pw = 40, ph = 24, spp = 4, cpad = 24;
  // Raw output: the OUT buffer's 8 channels, or D2S phases of 3.
  __half *rbuf;
  const hf_cuk_raw raw = random_raw(d2s, d2s ? 3 : 8, batch, pw, ph, &rbuf);
  float *in32;
  __half *in = random_input(batch, pw, ph, spp, cpad, 0, &in32);
  const size_t nout = (size_t)batch * h * w * 3;
  void *out = dalloc(nout * 4);
  memset(out, 0xff, nout * 4);
  if (!residual) {
    run_grid(shape(w, h, batch),
             [&](int x, int y, int n) { output_unet_px(raw, w, h, out, dst_f16, x, y, n); });
  } else {
    // One block per tile: the three phases, each by every thread, in order.
    static float3 px[kHaloH][kHaloW], rows[kHaloH][kTileX];
    for (int n = 0; n < batch; n++)
      for (int by = 0; by < (h + kTileY - 1) / kTileY; by++)
        for (int bx = 0; bx < (w + kTileX - 1) / kTileX; bx++) {
          for (int t = 0; t < kTileX * kTileY; t++)
            residual_load(px, in, cpad, pw, ph, spp, w, h, bx, by, n, t, kTileX * kTileY);
          for (int t = 0; t < kTileX * kTileY; t++) residual_rows(px, rows, t, kTileX * kTileY);
          for (int ty = 0; ty < kTileY; ty++)
            for (int tx = 0; tx < kTileX; tx++)
              residual_finish(rows, raw, spp, w, h, out, dst_f16, bx, by, n, tx, ty);
        }
  }
  hf_net_config cfg;
  hf_variant_preset(residual ? "Residual" : "Base", &cfg);
  double worst = 0;
  for (int n = 0; n < batch; n++) {
    hf_input_view view = {in32 + (size_t)n * ph * pw * cpad, w, h, pw, cpad};
    for (int y = 0; y < h; y++)
      for (int x = 0; x < w; x++) {
        const __half *r = raw_pixel(raw, n, y, x);
        // Where the raw output is, spelled out: the phase's pixel and block.
        const __half *r2 = d2s ? rbuf + (((size_t)n * raw.at.rows + y / 2 + y % 2) * raw.at.cols +
                                         x / 2 + x % 2) * 12 + (2 * (y % 2) + x % 2) * 3
                               : rbuf + (((size_t)n * ph + y) * pw + x) * 8;
        CHECK(r == r2, "raw pixel (%d, %d) of frame %d at the wrong place", x, y, n);
        float v[3] = {h2f(r2[0]), h2f(r2[1]), h2f(r2[2])};
        hf_output_finish(&cfg, &view, x, y, v);
        for (int k = 0; k < 3; k++) {
          const size_t i = (((size_t)n * h + y) * w + x) * 3 + k;
          const float got = dst_f16 ? h2f(((__half *)out)[i]) : ((float *)out)[i];
          const float want = dst_f16 ? h2f(__float2half_rn(v[k])) : v[k];
          const double d = rel_diff(got, want);
          if (d > worst) worst = d;
        }
      }
  }
  // FP32 sums in another order (the window) and FP16 rounding of the result.
  const double tol = dst_f16 ? 1e-3 : 1e-5;
  CHECK(worst <= tol, "output %s%s %s: worst relative difference %.2e", residual ? "residual" : "unet",
        d2s ? " (D2S phases)" : "", dst_f16 ? "f16" : "f32", worst);
  printf("  output     %-8s raw %-10s -> %s: worst relative difference %.1e\n",
         residual ? "residual" : "unet", d2s ? "D2S phases" : "OUT buffer", dst_f16 ? "f16" : "f32",
         worst);
  free(rbuf);
  free(in);
  free(in32);
  free(out);
}

// HF_ARCH_KERNEL: the raw output in dec0's OUT buffer or D2S phases (the
// taps + 3 channels, or the hidden ones a head reads with the input),
// against hf_output_finish of the same values (the head's dot products
// summed in the same order on the CPU). ksums: what the kernel weighs
// (HF_KSUMS_*: Kernel, KernelAC, KernelMix).
static void test_output_kernel(int radius, int hidden, int d2s, int dst_f16,
                               int ksums = HF_KSUMS_SAMPLES) {
  const int batch = 2, w = 37, h = 23, pw = 40, ph = 24, spp = 4, estimate = ksums != 0;
  const int cin = estimate ? 27 : 24, cpad = estimate ? 32 : 24;
  hf_net_config cfg;
  hf_variant_preset(ksums == HF_KSUMS_MIXED ? "KernelMix" : estimate ? "KernelAC" : "Kernel", &cfg);
  cfg.kernel_radius = radius;
  cfg.kernel_hidden = hidden;
  cfg.out_channels = hf_kernel_taps(radius) + 3 + cfg.kernel_mix;
  const int oc = hidden ? hidden : cfg.out_channels, co = (oc + 7) / 8 * 8;
  __half *rbuf;
  const hf_cuk_raw raw = random_raw(d2s, co, batch, pw, ph, &rbuf);
  const size_t nraw = (size_t)batch * raw.at.rows * raw.at.cols * raw.at.pix_stride;
  if (hidden)  // after dec0's ReLU
    for (size_t i = 0; i < nraw; i++) rbuf[i] = __float2half_rn(fabsf(h2f(rbuf[i])));
  const int nfeat = hidden + cin;
  float *hw = (float *)malloc((size_t)cfg.out_channels * nfeat * 4),
        *hb = (float *)malloc(HF_MAX_RAW_CHANNELS * 4);
  for (int i = 0; i < cfg.out_channels * nfeat; i++) hw[i] = (2 * frand() - 1) / 4;
  for (int i = 0; i < cfg.out_channels; i++) hb[i] = 2 * frand() - 1;
  hf_cuk_head head = {hidden ? hw : NULL, hidden ? hb : NULL, hidden, cin};
  // The left 5 columns of frame 0 empty: pixels with no covered sample in
  // reach, for radius <= 4.
  float *in32;
  __half *in = random_input(batch, pw, ph, spp, cpad, 5, &in32, estimate);
  const size_t nout = (size_t)batch * h * w * 3;
  void *out = dalloc(nout * 4);
  memset(out, 0xff, nout * 4);
  // One block per tile: the sums by every thread, then each thread's pixel.
  static float3 px[kKHaloH][kKHaloW], pe_mem[kKHaloH][kKHaloW];
  float3 (*pe)[kKHaloW] = ksums == HF_KSUMS_MIXED ? pe_mem : nullptr;
  for (int n = 0; n < batch; n++)
    for (int by = 0; by < (h + kTileY - 1) / kTileY; by++)
      for (int bx = 0; bx < (w + kTileX - 1) / kTileX; bx++) {
        for (int t = 0; t < kTileX * kTileY; t++)
          sums_load<kKR>(px, pe, in, cpad, pw, ph, spp, ksums, w, h, bx, by, n, t,
                         kTileX * kTileY);
        for (int ty = 0; ty < kTileY; ty++)
          for (int tx = 0; tx < kTileX; tx++)
            kernel_finish(px, pe, raw, head, in, cpad, pw, ph, spp, radius, w, h, out, dst_f16, bx,
                          by, n, tx, ty);
      }
  double worst = 0;
  int colour_one = 0;
  for (int n = 0; n < batch; n++) {
    hf_input_view view = {in32 + (size_t)n * ph * pw * cpad, w, h, pw, cpad};
    for (int y = 0; y < h; y++)
      for (int x = 0; x < w; x++) {
        const __half *r = raw_pixel(raw, n, y, x);
        const float *ip = in32 + (((size_t)n * ph + y) * pw + x) * cpad;
        float v[HF_MAX_RAW_CHANNELS];
        for (int o = 0; o < cfg.out_channels; o++) {
          if (!hidden) {
            v[o] = h2f(r[o]);
            continue;
          }
          v[o] = hb[o];
          for (int j = 0; j < nfeat; j++)
            v[o] += hw[(size_t)o * nfeat + j] * (j < hidden ? h2f(r[j]) : ip[j - hidden]);
        }
        hf_output_finish(&cfg, &view, x, y, v);
        if (n == 0 && x + radius < 5) colour_one++;
        for (int k = 0; k < 3; k++) {
          const size_t i = (((size_t)n * h + y) * w + x) * 3 + k;
          const float got = dst_f16 ? h2f(((__half *)out)[i]) : ((float *)out)[i];
          const float want = dst_f16 ? h2f(__float2half_rn(v[k])) : v[k];
          const double d = rel_diff(got, want);
          if (!(d <= worst)) worst = d;  // NaN too
        }
      }
  }
  // An online softmax against the two-pass one: FP32 sums in another
  // order, and FP16 rounding of the result.
  const double tol = dst_f16 ? 1e-3 : 2e-5;
  CHECK(colour_one > 0, "no pixel without a covered sample in reach");
  const char *kind = ksums == HF_KSUMS_MIXED ? " (mixed)" : estimate ? " (estimate)" : "";
  CHECK(worst <= tol, "output kernel%s r%d h%d%s %s: worst relative difference %.2e", kind, radius, hidden, d2s ? " (D2S phases)" : "",
        dst_f16 ? "f16" : "f32", worst);
  printf("  output     kernel%s r%d h%-2d raw %-10s -> %s: worst relative difference %.1e\n",
         kind, radius, hidden, d2s ? "D2S phases" : "OUT buffer",
         dst_f16 ? "f16" : "f32", worst);
  free(rbuf);
  free(in);
  free(in32);
  free(out);
  free(hw);
  free(hb);
}

// ---- input check -------------------------------------------------------------

// One random feature value of a sample, in contract or (rarely) not: every
// kind the rule knows (non-finite, alpha <= 0 beside other values, each
// feature out of range on either side), and the edge cases it must let
// through (-0 in an uncovered sample, bounds exactly).
static void random_sample(float *s) {
  const float r = frand();
  if (r < 0.35f) {  // uncovered
    for (int f = 0; f < 6; f++) s[f] = frand() < 0.1f ? -0.0f : 0.0f;
    return;
  }
  s[0] = 2 * frand(), s[1] = frand() < 0.5f ? 0 : 3 * frand(), s[2] = 1 - frand();
  s[3] = frand(), s[4] = 2 * frand() - 1, s[5] = 2 * frand() - 1;
  if (frand() < 0.05f) s[2] = 1.0f, s[3] = frand() < 0.5f ? 0.0f : 1.0f, s[4] = -1.0f;
  if (frand() >= 0.03f) return;
  const int f = (int)(frand() * 6);
  switch ((int)(frand() * 7)) {
  case 0: s[f] = NAN; break;
  case 1: s[f] = frand() < 0.5f ? INFINITY : -INFINITY; break;
  case 2: s[2] = 0.0f; break;                                // uncovered, features left
  case 3: s[2] = -0.25f; break;
  case 4: s[f] = 100.0f; break;                              // above every range
  case 5: s[f] = -1.5f; break;                               // below every range
  default: s[f] = f < 2 ? 64.0f : f == 2 ? 1.0f : -1.0f;     // a bound itself: in contract
  }
}

// The device's input check (scan_pixel over the kernel's pixels, its counts
// summed as the kernel's atomics sum them) against the host passes:
// hf_features_scan's report and statistics of the frame as it came, and
// hf_features_sanitise's fixed frame, bit for bit. clean: every sample
// in contract.
static void test_scan(int f16, int spp, int batch, int w, int h, int clean) {
  const size_t pixels = (size_t)w * h, values = pixels * spp * 6;
  const size_t es = f16 ? 2 : 4;
  uint8_t *in = (uint8_t *)malloc(values * es * batch);
  uint8_t *dev = (uint8_t *)dalloc(values * es * batch);
  uint8_t *want = (uint8_t *)malloc(values * es * batch);
  if (!in || !want) abort();
  for (size_t i = 0; i < values * batch; i += 6) {
    float smp[6];
    do random_sample(smp);
    while (clean && !hf_rule_ok_f32(smp));
    for (int f = 0; f < 6; f++) {
      if (f16) ((uint16_t *)in)[i + f] = hf_f32_to_f16(smp[f]);
      else ((float *)in)[i + f] = smp[f];
    }
    if (f16 && !clean && frand() < 0.01f)  // halves the floats above do not make
      ((uint16_t *)in)[i + 2] = frand() < 0.5f ? 0x0001u : 0x7c00u;  // subnormal, +inf alpha
  }
  memcpy(dev, in, values * es * batch);
  memcpy(want, in, values * es * batch);
  hf_cuk_scan_counts *counts = (hf_cuk_scan_counts *)calloc(batch, sizeof *counts);
  if (!counts) abort();
  for (int n = 0; n < batch; n++) {
    void *frame = dev + values * es * n;
    hf_cuk_scan_counts *c = &counts[n];
    for (size_t p = 0; p < pixels; p++) {
      const ScanPixel r = f16 ? scan_pixel<true>(frame, spp, (long long)p)
                              : scan_pixel<false>(frame, spp, (long long)p);
      if (r.covered) c->hist[r.bin]++, c->hair++, c->full += r.covered == spp;
      if (r.bad) {
        c->bad += r.bad;
        const unsigned long long inv = ~(unsigned long long)(p * spp + r.first_bad);
        if (inv > c->first_bad_inv) c->first_bad_inv = inv;
      }
    }
  }
  uint64_t total_bad = 0;
  for (int n = 0; n < batch; n++) {
    const hf_dtype dt = f16 ? HF_F16 : HF_F32;
    const uint8_t *frame = in + values * es * n;
    hf_input_report want_rep, got_rep;
    hf_input_stats want_st, got_st;
    if (hf_features_scan(frame, dt, w, h, spp, &want_rep, &want_st) != HF_OK) abort();
    hf_features_sanitise(want + values * es * n, dt, w, h, spp, &want_rep);
    hf_input_stats_acc acc;
    memcpy(&acc, &counts[n], sizeof acc);
    hf_input_stats_finish(&acc, w, h, spp, &got_st);
    hf_features_report_counted(frame, dt, w, spp, counts[n].bad, ~counts[n].first_bad_inv,
                               &got_rep);
    total_bad += got_rep.samples;
    CHECK(got_rep.samples == want_rep.samples && got_rep.x == want_rep.x &&
              got_rep.y == want_rep.y && got_rep.sample == want_rep.sample &&
              got_rep.feature == want_rep.feature && got_rep.kind == want_rep.kind &&
              !memcmp(&got_rep.value, &want_rep.value, sizeof got_rep.value),
          "scan f16=%d spp=%d frame %d: report %llu at (%d,%d) s%d f%d kind %d, want %llu at "
          "(%d,%d) s%d f%d kind %d", f16, spp, n, (unsigned long long)got_rep.samples, got_rep.x,
          got_rep.y, got_rep.sample, got_rep.feature, got_rep.kind,
          (unsigned long long)want_rep.samples, want_rep.x, want_rep.y, want_rep.sample,
          want_rep.feature, want_rep.kind);
    CHECK(!memcmp(&got_st, &want_st, sizeof got_st),
          "scan f16=%d spp=%d frame %d: statistics differ (hair %llu/%llu, p50 %g/%g)", f16, spp,
          n, (unsigned long long)got_st.hair_pixels, (unsigned long long)want_st.hair_pixels,
          got_st.value[HF_STAT_STRAND_ALPHA_P50], want_st.value[HF_STAT_STRAND_ALPHA_P50]);
  }
  CHECK(!memcmp(dev, want, values * es * batch), "scan f16=%d spp=%d: fixed frames differ from "
        "hf_features_sanitise's", f16, spp);
  CHECK(clean ? total_bad == 0 : total_bad > 0, "scan f16=%d spp=%d: %llu bad samples in a %s "
        "frame", f16, spp, (unsigned long long)total_bad, clean ? "clean" : "dirty");
  printf("  input check %s spp %2d, %d frame(s) %dx%d: %llu out-of-contract samples\n",
         f16 ? "f16" : "f32", spp, batch, w, h, (unsigned long long)total_bad);
  free(in);
  free(dev);
  free(want);
  free(counts);
}

// The device's output guard (guard_pixel over the kernel's pixels) against
// hf_output_guard_serial: the same values and the same count, bit for bit.
static void test_guard(int f16) {
  const size_t pixels = 5000, n = pixels * 3;
  const size_t es = f16 ? 2 : 4;
  uint8_t *dev = (uint8_t *)dalloc(n * es), *want = (uint8_t *)malloc(n * es);
  if (!want) abort();
  static const float odd[] = {NAN, INFINITY, -INFINITY, -0.0f, 1e30f, -1e30f, 70000.0f,
                              -2.0f, 1.0f, 1.5f, 65504.0f, -65504.0f};
  for (size_t i = 0; i < n; i++) {
    const float v = frand() < 0.05f ? odd[(int)(frand() * 12)] : 3 * frand() - 1;
    if (f16) ((uint16_t *)dev)[i] = hf_f32_to_f16(v);
    else ((float *)dev)[i] = v;
  }
  memcpy(want, dev, n * es);
  const uint64_t want_fixed = hf_output_guard_serial(want, f16 ? HF_F16 : HF_F32, pixels);
  uint64_t fixed = 0;
  for (size_t p = 0; p < pixels; p++)
    fixed += f16 ? guard_pixel<true>(dev, (long long)p) : guard_pixel<false>(dev, (long long)p);
  CHECK(fixed == want_fixed && fixed > 0, "guard %s: %llu pixels changed, want %llu",
        f16 ? "f16" : "f32", (unsigned long long)fixed, (unsigned long long)want_fixed);
  CHECK(!memcmp(dev, want, n * es), "guard %s: values differ from hf_output_guard's",
        f16 ? "f16" : "f32");
  printf("  output guard %s, %zu pixels: %llu changed\n", f16 ? "f16" : "f32", pixels,
         (unsigned long long)fixed);
  free(dev);
  free(want);
}

int main(void) {
  printf("element-wise kernels of the cudnn backend, run on the CPU\n");
  for (int f16 = 0; f16 <= 1; f16++) {
    test_input(24, f16);
    test_input(6, f16);
    test_input(5, f16);  // odd: the element-by-element path
  }
  // Half of a skip buffer; a PHASE dec0 view (4 channels, step 2, odd
  // column offset: 8-byte aligned); a dense 12-channel tensor.
  test_bias_act("skip half (32 of 64)", 12, 17, 64, 32, 32, 0, 0, 1, 8);
  test_bias_act("phase view (4, step 2, x0 1)", 12, 18, 4, 0, 4, 0, 1, 2, 4);
  test_bias_act("dense 12 channels", 9, 7, 12, 0, 12, 0, 0, 1, 4);
  test_copy();
  test_d2s(1, 32, 64, 0);   // D2S into the first half of a skip buffer
  test_d2s(0, 32, 64, 0);   // SHUFFLE
  test_d2s(1, 3, 3, 0);     // 3 channels: single-element accesses
  test_d2s(0, 8, 8, 0);
  for (int residual = 0; residual <= 1; residual++)
    for (int d2s = 0; d2s <= 1; d2s++)
      for (int f16 = 0; f16 <= 1; f16++) test_output(residual, d2s, f16);
  test_output_kernel(3, 16, 0, 0);
  test_output_kernel(3, 16, 1, 1);
  test_output_kernel(2, 0, 1, 0);
  test_output_kernel(2, 0, 0, 1);
  test_output_kernel(1, 5, 1, 0);
  test_output_kernel(4, 64, 0, 0);
  test_output_kernel(3, 32, 0, 0, 1);
  test_output_kernel(3, 32, 1, 1, 1);
  test_output_kernel(2, 0, 0, 0, 1);
  test_output_kernel(3, 32, 0, 0, HF_KSUMS_MIXED);
  test_output_kernel(3, 32, 1, 1, HF_KSUMS_MIXED);
  test_output_kernel(2, 0, 0, 0, HF_KSUMS_MIXED);
  for (int f16 = 0; f16 <= 1; f16++) {
    test_scan(f16, 4, 2, 67, 45, 0);
    test_scan(f16, 4, 1, 64, 64, 1);
    test_scan(f16, 1, 1, 33, 17, 0);
    test_scan(f16, 16, 1, 19, 23, 0);
    test_guard(f16);
  }
  if (failures) {
    printf("%d check(s) failed\n", failures);
    return 1;
  }
  printf("PASSED\n");
  return 0;
}
