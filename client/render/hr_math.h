/* Small vector/matrix helpers and a seeded generator for the renderer.
 * Matrices are column-major float[16], as GL takes them. */
#ifndef HR_MATH_H
#define HR_MATH_H

#include <math.h>
#include <stdint.h>

#define HR_PI 3.14159265358979323846f

static inline float hr_deg(float d) { return d * HR_PI / 180.0f; }
static inline float hr_dot(const float a[3], const float b[3]) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static inline void hr_cross(const float a[3], const float b[3], float o[3]) {
  float t[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  o[0] = t[0], o[1] = t[1], o[2] = t[2];
}
static inline float hr_len(const float a[3]) { return sqrtf(hr_dot(a, a)); }
static inline void hr_normalize(float a[3]) {
  float l = hr_len(a);
  if (l > 0) a[0] /= l, a[1] /= l, a[2] /= l;
}

/* splitmix64: tiny, seedable, good enough for geometry and views. */
typedef struct hr_rng { uint64_t s; } hr_rng;
static inline uint64_t hr_rng_next(hr_rng *r) {
  uint64_t z = (r->s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}
/* Uniform in [0, 1). */
static inline float hr_rng_uniform(hr_rng *r) {
  return (float)(hr_rng_next(r) >> 40) * (1.0f / 16777216.0f);
}
static inline float hr_rng_range(hr_rng *r, float lo, float hi) {
  return lo + (hi - lo) * hr_rng_uniform(r);
}
static inline float hr_rng_normal(hr_rng *r) {
  float u = hr_rng_uniform(r) + 1e-7f, v = hr_rng_uniform(r);
  return sqrtf(-2.0f * logf(u)) * cosf(2.0f * HR_PI * v);
}

void hr_mat_identity(float m[16]);
void hr_mat_mul(const float a[16], const float b[16], float o[16]);
void hr_mat_look_at(const float eye[3], const float at[3], const float up[3], float m[16]);
void hr_mat_perspective(float fovy_rad, float aspect, float n, float f, float m[16]);
void hr_mat_ortho(float l, float r, float b, float t, float n, float f, float m[16]);
/* Direction from spherical angles: yaw about +y from +z, pitch up. */
void hr_dir_from_angles(float yaw_deg, float pitch_deg, float d[3]);

#endif
