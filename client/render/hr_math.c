/* Matrix helpers of hr_math.h. */
#include <string.h>

#include "hr_math.h"

void hr_mat_identity(float m[16]) {
  memset(m, 0, 16 * sizeof *m);
  m[0] = m[5] = m[10] = m[15] = 1;
}

void hr_mat_mul(const float a[16], const float b[16], float o[16]) {
  float t[16];
  for (int c = 0; c < 4; c++)
    for (int r = 0; r < 4; r++) {
      float s = 0;
      for (int k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      t[c * 4 + r] = s;
    }
  memcpy(o, t, sizeof t);
}

void hr_mat_look_at(const float eye[3], const float at[3], const float up[3], float m[16]) {
  float f[3] = {at[0] - eye[0], at[1] - eye[1], at[2] - eye[2]};
  hr_normalize(f);
  float s[3], u[3];
  hr_cross(f, up, s);
  if (hr_len(s) < 1e-6f) { /* looking along up: pick another up */
    float alt[3] = {0, 0, 1};
    hr_cross(f, alt, s);
  }
  hr_normalize(s);
  hr_cross(s, f, u);
  hr_mat_identity(m);
  m[0] = s[0], m[4] = s[1], m[8] = s[2];
  m[1] = u[0], m[5] = u[1], m[9] = u[2];
  m[2] = -f[0], m[6] = -f[1], m[10] = -f[2];
  m[12] = -hr_dot(s, eye);
  m[13] = -hr_dot(u, eye);
  m[14] = hr_dot(f, eye);
}

void hr_mat_perspective(float fovy, float aspect, float n, float f, float m[16]) {
  float t = 1.0f / tanf(fovy / 2);
  memset(m, 0, 16 * sizeof *m);
  m[0] = t / aspect;
  m[5] = t;
  m[10] = (f + n) / (n - f);
  m[11] = -1;
  m[14] = 2 * f * n / (n - f);
}

void hr_mat_ortho(float l, float r, float b, float t, float n, float f, float m[16]) {
  hr_mat_identity(m);
  m[0] = 2 / (r - l);
  m[5] = 2 / (t - b);
  m[10] = -2 / (f - n);
  m[12] = -(r + l) / (r - l);
  m[13] = -(t + b) / (t - b);
  m[14] = -(f + n) / (f - n);
}

void hr_dir_from_angles(float yaw_deg, float pitch_deg, float d[3]) {
  float y = hr_deg(yaw_deg), p = hr_deg(pitch_deg);
  d[0] = sinf(y) * cosf(p);
  d[1] = sinf(p);
  d[2] = cosf(y) * cosf(p);
}
