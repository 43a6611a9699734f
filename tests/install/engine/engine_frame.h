/* The frame every test engine filters: 32x24 pixels of 4 samples, features
 * from a fixed generator (plausible values: colour, highlight, alpha, depth
 * in [0, 1), tangents in [-1, 1)), and the FNV-1a hash the engines print of
 * their results, so that their outputs can be compared. C99 and C++11. */
#ifndef ENGINE_FRAME_H
#define ENGINE_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define ENGINE_W 32
#define ENGINE_H 24
#define ENGINE_SPP 4

static void engine_features(float *f) {
  uint32_t x = 12345u;
  size_t n = (size_t)ENGINE_W * ENGINE_H * ENGINE_SPP * 6, i;
  for (i = 0; i < n; i++) {
    float u;
    x = x * 1664525u + 1013904223u;
    u = (float)(x >> 8) / 16777216.0f;
    f[i] = i % 6 >= 4 ? 2.0f * u - 1.0f : u;
  }
}

static uint64_t engine_hash(const void *p, size_t n) {
  const unsigned char *b = (const unsigned char *)p;
  uint64_t h = 1469598103934665603ull;
  size_t i;
  for (i = 0; i < n; i++) h = (h ^ b[i]) * 1099511628211ull;
  return h;
}

#endif
