/* IEEE 754 binary16 <-> binary32, round to nearest even. The scalar
 * functions are the reference: portable C, so the wire codec, EXR helpers
 * and every backend agree bit for bit. The array functions are what frames
 * go through (daemon, backends, EXR I/O, CLI): 8 values per instruction
 * with F16C where the processor has it (chosen at run time, so one binary
 * runs everywhere), the scalar loop elsewhere, and a large frame split
 * between threads, since one core converts about 2-4 GB/s and a 1024x1024
 * frame of 4 spp is 25 M values. */
#include <stdatomic.h>
#include <string.h>

#include "hfcore.h"

uint16_t hf_f32_to_f16(float f) {
  uint32_t x;
  memcpy(&x, &f, 4);
  uint32_t sign = (x >> 16) & 0x8000u;
  uint32_t exp = (x >> 23) & 0xffu;
  uint32_t man = x & 0x7fffffu;
  if (exp == 0xff) /* inf or nan (keep nan quiet) */
    return (uint16_t)(sign | 0x7c00u | (man ? 0x200u | (man >> 13) : 0));
  int e = (int)exp - 127 + 15;
  if (e >= 31) return (uint16_t)(sign | 0x7c00u); /* overflow to inf */
  if (e <= 0) {                                     /* subnormal or zero */
    if (e < -10) return (uint16_t)sign;
    man |= 0x800000u;
    int shift = 14 - e;
    uint32_t half = man >> shift;
    uint32_t rem = man & ((1u << shift) - 1);
    uint32_t mid = 1u << (shift - 1);
    if (rem > mid || (rem == mid && (half & 1))) half++;
    return (uint16_t)(sign | half);
  }
  uint32_t half = sign | ((uint32_t)e << 10) | (man >> 13);
  uint32_t rem = man & 0x1fffu;
  if (rem > 0x1000u || (rem == 0x1000u && (half & 1))) half++; /* may carry into exp: correct */
  return (uint16_t)half;
}

float hf_f16_to_f32(uint16_t h) {
  uint32_t sign = (uint32_t)(h & 0x8000u) << 16;
  uint32_t exp = (h >> 10) & 0x1fu;
  uint32_t man = h & 0x3ffu;
  uint32_t x;
  if (exp == 0) {
    if (man == 0) {
      x = sign;
    } else { /* subnormal: normalise */
      int e = -1;
      do { man <<= 1; e++; } while (!(man & 0x400u));
      x = sign | ((uint32_t)(127 - 15 - e) << 23) | ((man & 0x3ffu) << 13);
    }
  } else if (exp == 31) {
    /* Infinity, or a NaN with its sign and payload kept and made quiet, as
     * IEEE 754 (5.4.2) converts a signalling NaN, as F16C does, and as
     * hf_f32_to_f16 does the other way. */
    x = sign | 0x7f800000u | (man << 13) | (man ? 0x400000u : 0);
  } else {
    x = sign | ((exp - 15 + 127) << 23) | (man << 13);
  }
  float f;
  memcpy(&f, &x, 4);
  return f;
}

static void f32_to_f16_scalar(const float *src, uint16_t *dst, size_t n) {
  for (size_t i = 0; i < n; i++) dst[i] = hf_f32_to_f16(src[i]);
}

static void f16_to_f32_scalar(const uint16_t *src, float *dst, size_t n) {
  for (size_t i = 0; i < n; i++) dst[i] = hf_f16_to_f32(src[i]);
}

/* Frames far larger than the caches are written with non-temporal stores:
 * no read of the destination's lines before they are overwritten (a third
 * less memory traffic for f16 -> f32, whose destination is twice the
 * source). */
#define HALF_STREAM_MIN ((size_t)1 << 18)

/* x86-64 processors with F16C (Ivy Bridge and later, every AMD Zen)
 * convert 8 values per instruction, rounding to nearest even like the
 * scalar code (for NaN too: both keep the sign and the payload's top bits
 * and set the quiet bit). */
#if defined(__x86_64__) && defined(__GNUC__)
#include <cpuid.h>
#include <immintrin.h>
#define HF_HALF_X86 1

__attribute__((target("avx,f16c"))) static void f32_to_f16_f16c(const float *src, uint16_t *dst,
                                                                size_t n, int stream) {
  size_t i = 0;
  if (stream) {
    for (; i < n && ((uintptr_t)(dst + i) & 15); i++) dst[i] = hf_f32_to_f16(src[i]);
    for (; i + 16 <= n; i += 16) {
      __m256 a = _mm256_loadu_ps(src + i), b = _mm256_loadu_ps(src + i + 8);
      _mm_stream_si128((__m128i *)(dst + i),
                       _mm256_cvtps_ph(a, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
      _mm_stream_si128((__m128i *)(dst + i + 8),
                       _mm256_cvtps_ph(b, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
    }
    _mm_sfence();
  }
  for (; i + 16 <= n; i += 16) {
    __m256 a = _mm256_loadu_ps(src + i), b = _mm256_loadu_ps(src + i + 8);
    _mm_storeu_si128((__m128i *)(dst + i),
                     _mm256_cvtps_ph(a, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
    _mm_storeu_si128((__m128i *)(dst + i + 8),
                     _mm256_cvtps_ph(b, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
  }
  for (; i + 8 <= n; i += 8)
    _mm_storeu_si128((__m128i *)(dst + i),
                     _mm256_cvtps_ph(_mm256_loadu_ps(src + i),
                                     _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
  f32_to_f16_scalar(src + i, dst + i, n - i);
}

__attribute__((target("avx,f16c"))) static void f16_to_f32_f16c(const uint16_t *src, float *dst,
                                                                size_t n, int stream) {
  size_t i = 0;
  if (stream) {
    for (; i < n && ((uintptr_t)(dst + i) & 31); i++) dst[i] = hf_f16_to_f32(src[i]);
    for (; i + 16 <= n; i += 16) {
      __m128i a = _mm_loadu_si128((const __m128i *)(src + i));
      __m128i b = _mm_loadu_si128((const __m128i *)(src + i + 8));
      _mm256_stream_ps(dst + i, _mm256_cvtph_ps(a));
      _mm256_stream_ps(dst + i + 8, _mm256_cvtph_ps(b));
    }
    _mm_sfence();
  }
  for (; i + 16 <= n; i += 16) {
    __m128i a = _mm_loadu_si128((const __m128i *)(src + i));
    __m128i b = _mm_loadu_si128((const __m128i *)(src + i + 8));
    _mm256_storeu_ps(dst + i, _mm256_cvtph_ps(a));
    _mm256_storeu_ps(dst + i + 8, _mm256_cvtph_ps(b));
  }
  for (; i + 8 <= n; i += 8)
    _mm256_storeu_ps(dst + i, _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(src + i))));
  f16_to_f32_scalar(src + i, dst + i, n - i);
}

/* F16C from CPUID (leaf 1, ECX) rather than __builtin_cpu_supports("f16c"),
 * which clang 14 (the fuzz targets' compiler) does not know; it needs AVX,
 * whose check covers the OS saving the YMM registers. */
static int cpu_has_f16c(void) {
  unsigned a, b, c, d;
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx") && __get_cpuid(1, &a, &b, &c, &d) && (c & bit_F16C);
}
#endif

/* -1: not yet chosen; 0: scalar; 1: F16C. */
static _Atomic int use_simd = -1;

static int simd(void) {
  int s = atomic_load_explicit(&use_simd, memory_order_relaxed);
  if (s < 0) {
#ifdef HF_HALF_X86
    s = cpu_has_f16c();
#else
    s = 0;
#endif
    atomic_store(&use_simd, s);
  }
  return s;
}

int hf_half_use_simd(int on) {
  int had = simd();
#ifdef HF_HALF_X86
  if (on >= 0) atomic_store(&use_simd, on ? cpu_has_f16c() : 0);
#else
  (void)on;
#endif
  return had;
}

const char *hf_half_impl(void) { return simd() ? "f16c" : "scalar"; }

/* stream: the frame is larger than the caches (HALF_STREAM_MIN values or
 * more in all, whatever part of it this call converts). */
static void run_f32_to_f16(const float *src, uint16_t *dst, size_t n, int stream) {
#ifdef HF_HALF_X86
  if (simd()) {
    f32_to_f16_f16c(src, dst, n, stream);
    return;
  }
#endif
  (void)stream;
  f32_to_f16_scalar(src, dst, n);
}

static void run_f16_to_f32(const uint16_t *src, float *dst, size_t n, int stream) {
#ifdef HF_HALF_X86
  if (simd()) {
    f16_to_f32_f16c(src, dst, n, stream);
    return;
  }
#endif
  (void)stream;
  f16_to_f32_scalar(src, dst, n);
}

/* ---- threads for large frames -------------------------------------------- */

/* Below this many values per thread a thread's start (tens of
 * microseconds) costs more than its share saves. */
#define HALF_PER_THREAD ((size_t)1 << 19)
/* Values per chunk taken by a thread (hf_parallel_chunks): a multiple of 16
 * (whole vectors, and chunks that start 64-byte aligned where the frame
 * does), small enough that a thread descheduled on a shared machine holds
 * up little of the frame. */
#define HALF_CHUNK ((size_t)1 << 16)

typedef struct half_job {
  const void *src;
  void *dst;
  int to_f16, stream;
} half_job;

static void half_chunk(void *arg, int worker, size_t b, size_t e) {
  const half_job *j = arg;
  (void)worker;
  if (j->to_f16)
    run_f32_to_f16((const float *)j->src + b, (uint16_t *)j->dst + b, e - b, j->stream);
  else
    run_f16_to_f32((const uint16_t *)j->src + b, (float *)j->dst + b, e - b, j->stream);
}

static void half_split(const void *src, void *dst, size_t n, int to_f16) {
  half_job j = {src, dst, to_f16, n >= HALF_STREAM_MIN};
  hf_parallel_chunks(n, HALF_CHUNK, HALF_PER_THREAD, half_chunk, &j);
}

void hf_f32_to_f16_serial(const float *src, uint16_t *dst, size_t n) {
  run_f32_to_f16(src, dst, n, n >= HALF_STREAM_MIN);
}

void hf_f16_to_f32_serial(const uint16_t *src, float *dst, size_t n) {
  run_f16_to_f32(src, dst, n, n >= HALF_STREAM_MIN);
}

void hf_f16_to_f32_stream(const uint16_t *src, float *dst, size_t n) {
  run_f16_to_f32(src, dst, n, 1);
}

void hf_f32_to_f16_array(const float *src, uint16_t *dst, size_t n) {
  if (n >= 2 * HALF_PER_THREAD) half_split(src, dst, n, 1);
  else run_f32_to_f16(src, dst, n, n >= HALF_STREAM_MIN);
}

void hf_f16_to_f32_array(const uint16_t *src, float *dst, size_t n) {
  if (n >= 2 * HALF_PER_THREAD) half_split(src, dst, n, 0);
  else run_f16_to_f32(src, dst, n, n >= HALF_STREAM_MIN);
}
