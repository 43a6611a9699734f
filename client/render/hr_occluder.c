/* Occluders: triangle meshes, ellipsoids and the ellipsoid fitted under a
 * loaded model's roots.
 *
 * A .hair file has strands only; what they grow on (a scalp, a body) is
 * missing, so without an occluder the hair behind the head shows through
 * it. Roots are the first point of each strand and lie on that surface, so
 * an ellipsoid fitted to them stands in for it. The fit is a 9x9 linear
 * least-squares solve (Gaussian elimination) for the quadric through the
 * roots and 3x3 symmetric eigenproblems (its axes, the roots' principal
 * axes; cyclic Jacobi): a few lines each, part of the
 * renderer's geometry like hr_math.c, and no linear-algebra library is a
 * dependency of the project. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hfrender.h"
#include "hr_internal.h"
#include "hr_math.h"

void hfr_mesh_free(hfr_mesh *m) {
  if (!m) return;
  free(m->v);
  memset(m, 0, sizeof *m);
}

/* Point and normal of e at polar angle th (from axis 1) and azimuth ph. */
static void ellipsoid_at(const hfr_ellipsoid *e, float th, float ph, float *o) {
  float s[3] = {sinf(th) * sinf(ph), cosf(th), sinf(th) * cosf(ph)};
  float n[3] = {0, 0, 0};
  for (int k = 0; k < 3; k++) o[k] = e->centre[k];
  for (int a = 0; a < 3; a++)
    for (int k = 0; k < 3; k++) {
      o[k] += e->radii[a] * s[a] * e->axes[a][k];
      n[k] += s[a] / fmaxf(e->radii[a], 1e-30f) * e->axes[a][k];
    }
  hr_normalize(n);
  memcpy(o + 3, n, sizeof n);
}

int hfr_mesh_ellipsoid(const hfr_ellipsoid *e, int slices, int stacks, hfr_mesh *out) {
  if (!e || !out || slices < 3 || stacks < 2 || slices > 4096 || stacks > 4096) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  size_t n = (size_t)slices * stacks * 6;
  out->v = malloc(n * 6 * sizeof(float));
  if (!out->v) return HF_ENOMEM;
  size_t k = 0;
  for (int i = 0; i < stacks; i++)
    for (int j = 0; j < slices; j++) {
      float th[2] = {HR_PI * i / stacks, HR_PI * (i + 1) / stacks};
      float ph[2] = {2 * HR_PI * j / slices, 2 * HR_PI * (j + 1) / slices};
      static const int quad[6][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 0}, {1, 1}, {0, 1}};
      for (int q = 0; q < 6; q++) ellipsoid_at(e, th[quad[q][0]], ph[quad[q][1]], out->v + 6 * k++);
    }
  out->vertices = (uint32_t)n;
  return HF_OK;
}

int hfr_mesh_orient(hfr_mesh *m, hfr_axis up, float scale) {
  if (!m || (unsigned)up >= HFR_AXIS_COUNT || !isfinite(scale) || !(scale > 0)) return HF_EINVAL;
  hr_orient_points(m->v, m->vertices, 6, up, scale);
  hr_orient_points(m->v + 3, m->vertices, 6, up, 1);
  return HF_OK;
}

/* ---- the fit -------------------------------------------------------------- */

/* Eigenvectors (columns of v) and eigenvalues (d) of the symmetric a, by
 * cyclic Jacobi rotations; sorted by decreasing eigenvalue. */
static void eigen_sym3(const double a_in[3][3], double d[3], double v[3][3]) {
  double a[3][3];
  memcpy(a, a_in, sizeof a);
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++) v[i][j] = i == j;
  for (int sweep = 0; sweep < 50; sweep++) {
    double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
    if (off < 1e-300) break;
    for (int p = 0; p < 2; p++)
      for (int q = p + 1; q < 3; q++) {
        if (fabs(a[p][q]) < 1e-300) continue;
        double th = 0.5 * (a[q][q] - a[p][p]) / a[p][q];
        double t = (th >= 0 ? 1 : -1) / (fabs(th) + sqrt(th * th + 1));
        double c = 1 / sqrt(t * t + 1), s = t * c;
        for (int k = 0; k < 3; k++) { /* a <- a J */
          double akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (int k = 0; k < 3; k++) { /* a <- J^T a */
          double apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (int k = 0; k < 3; k++) {
          double vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
  }
  for (int i = 0; i < 3; i++) d[i] = a[i][i];
  for (int i = 0; i < 2; i++)
    for (int j = i + 1; j < 3; j++)
      if (d[j] > d[i]) {
        double t = d[i];
        d[i] = d[j], d[j] = t;
        for (int k = 0; k < 3; k++) t = v[k][i], v[k][i] = v[k][j], v[k][j] = t;
      }
}

/* Solves m x = b (n x n, n <= 9) by Gaussian elimination with partial
 * pivoting; 0 when singular. */
static int solve(double m[9][9], double b[9], int n, double x[9]) {
  for (int c = 0; c < n; c++) {
    int p = c;
    for (int r = c + 1; r < n; r++)
      if (fabs(m[r][c]) > fabs(m[p][c])) p = r;
    if (fabs(m[p][c]) < 1e-12 * (fabs(m[0][0]) + 1e-300)) return 0;
    for (int k = 0; k < n; k++) {
      double t = m[c][k];
      m[c][k] = m[p][k], m[p][k] = t;
    }
    double t = b[c];
    b[c] = b[p], b[p] = t;
    for (int r = c + 1; r < n; r++) {
      double f = m[r][c] / m[c][c];
      for (int k = c; k < n; k++) m[r][k] -= f * m[c][k];
      b[r] -= f * b[c];
    }
  }
  for (int r = n - 1; r >= 0; r--) {
    double s = b[r];
    for (int k = r + 1; k < n; k++) s -= m[r][k] * x[k];
    x[r] = s / m[r][r];
  }
  return 1;
}

static int cmp_float(const void *a, const void *b) {
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

/* The direction a strand of n points at p leaves its root in: to its
 * first point apart from the root (exporters often write the root twice,
 * and a zero first segment says nothing of the way out); 0, 0, 0 when
 * every point is the root. */
static void strand_out(const float *p, uint32_t n, double d[3]) {
  d[0] = d[1] = d[2] = 0;
  for (uint32_t i = 1; i < n; i++) {
    const float *q = p + 3 * (size_t)i;
    if (q[0] != p[0] || q[1] != p[1] || q[2] != p[2]) {
      for (int k = 0; k < 3; k++) d[k] = (double)q[k] - p[k];
      return;
    }
  }
}

int hfr_ellipsoid_fit_roots(const hfr_hair *h, hfr_ellipsoid *out) {
  if (!h || !out || !h->pos || h->strands < 4) return HF_EINVAL;
  const uint32_t N = h->strands;
  float *u = malloc(sizeof(float) * 3 * N), *q = malloc(sizeof(float) * N);
  if (!u || !q) {
    free(u), free(q);
    return HF_ENOMEM;
  }
  /* Roots, their mean, and the mean direction strands leave them in. */
  double mean[3] = {0, 0, 0}, grow[3] = {0, 0, 0};
  size_t base = 0;
  for (uint32_t s = 0; s < N; s++) {
    uint32_t n = hfr_hair_strand_segments(h, s);
    const float *p = h->pos + 3 * base;
    double d[3];
    strand_out(p, n + 1, d);
    for (int k = 0; k < 3; k++) {
      u[3 * s + k] = p[k];
      mean[k] += p[k];
      grow[k] += d[k];
    }
    base += n + 1;
  }
  for (int k = 0; k < 3; k++) mean[k] /= N;
  /* Roots relative to their mean, in units of their extent. */
  double ext = 0;
  for (uint32_t s = 0; s < N; s++)
    for (int k = 0; k < 3; k++) {
      u[3 * s + k] = (float)(u[3 * s + k] - mean[k]);
      ext = fmax(ext, fabs(u[3 * s + k]));
    }
  if (!(ext > 0)) ext = 1;
  /* The quadric x^T A x + b^T x = 1 through the roots, least squares:
   * a xx + b yy + c zz + d xy + e xz + f yz + g x + h y + i z = 1. */
  double M[9][9] = {{0}}, B[9] = {0}, X[9];
  for (uint32_t s = 0; s < N; s++) {
    double x = u[3 * s] / ext, y = u[3 * s + 1] / ext, z = u[3 * s + 2] / ext;
    double phi[9] = {x * x, y * y, z * z, x * y, x * z, y * z, x, y, z};
    for (int i = 0; i < 9; i++) {
      B[i] += phi[i];
      for (int j = 0; j < 9; j++) M[i][j] += phi[i] * phi[j];
    }
  }
  double c[3] = {0, 0, 0}, rad[3] = {0, 0, 0}, E[3][3];
  int ok = solve(M, B, 9, X);
  if (ok) {
    double A[3][3] = {{X[0], X[3] / 2, X[4] / 2}, {X[3] / 2, X[1], X[5] / 2},
                      {X[4] / 2, X[5] / 2, X[2]}};
    double lamA[3];
    eigen_sym3(A, lamA, E);
    ok = lamA[2] > 0;
    if (ok) {
      /* Centre: A c = -b / 2, through the eigenbasis. */
      double G = 1;
      for (int a = 0; a < 3; a++) {
        double bd = X[6] * E[0][a] + X[7] * E[1][a] + X[8] * E[2][a];
        double ca = -bd / (2 * lamA[a]);
        for (int k = 0; k < 3; k++) c[k] += ca * E[k][a];
        G += lamA[a] * ca * ca;
      }
      for (int a = 0; a < 3; a++) {
        rad[a] = sqrt(G / lamA[a]) * ext;
        /* An ellipsoid far larger than the roots, or centred far from them,
         * is the fit of a nearly flat patch: not a body. */
        if (!isfinite(rad[a]) || rad[a] > 3 * ext) ok = 0;
      }
      for (int k = 0; k < 3; k++) {
        c[k] *= ext;
        if (!(fabs(c[k]) < 2 * ext)) ok = 0;
      }
    }
  }
  /* Under the hair: strands grow away from the centre. */
  if (ok) {
    double out_dot = 0, counted = 0;
    base = 0;
    for (uint32_t s = 0; s < N; s++) {
      uint32_t n = hfr_hair_strand_segments(h, s);
      const float *p = h->pos + 3 * base;
      double d = 0, dir[3];
      /* The way out of the root: strands leave the skin outwards, then may
       * fall. A strand that never leaves its root has no say. */
      strand_out(p, n + 1, dir);
      for (int k = 0; k < 3; k++) d += (u[3 * s + k] - c[k]) * dir[k];
      if (dir[0] != 0 || dir[1] != 0 || dir[2] != 0) out_dot += d > 0 ? 1 : -1, counted++;
      base += n + 1;
    }
    if (out_dot < 0.5 * counted) ok = 0;
  }
  if (!ok) {
    /* A flat ellipsoid under the roots' mean plane, on the side away from
     * the hair, as wide as the roots spread: the principal axes. */
    double cov[3][3] = {{0}}, lam[3];
    for (uint32_t s = 0; s < N; s++)
      for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) cov[i][j] += (double)u[3 * s + i] * u[3 * s + j] / N;
    eigen_sym3(cov, lam, E);
    if (lam[0] > 0 && !(lam[1] > 1e-6 * lam[0])) {
      /* Roots along a line (a row of strands): every plane through it fits
       * them, so the patch's plane is the one the strands grow out of, the
       * line and their mean growth across it. */
      double g[3], gl = 0, along = 0;
      for (int k = 0; k < 3; k++) along += grow[k] * E[k][0];
      for (int k = 0; k < 3; k++) g[k] = grow[k] - along * E[k][0], gl += g[k] * g[k];
      if (gl > 0) {
        gl = sqrt(gl);
        for (int k = 0; k < 3; k++) E[k][2] = g[k] / gl;
        E[0][1] = E[1][2] * E[2][0] - E[2][2] * E[1][0];
        E[1][1] = E[2][2] * E[0][0] - E[0][2] * E[2][0];
        E[2][1] = E[0][2] * E[1][0] - E[1][2] * E[0][0];
      }
    }
    double nrm_dot = grow[0] * E[0][2] + grow[1] * E[1][2] + grow[2] * E[2][2];
    double sgn = nrm_dot >= 0 ? 1 : -1;
    rad[0] = 2 * sqrt(fmax(lam[0], 0));
    /* A line of roots gets a body a quarter as wide as it is long. */
    rad[1] = fmax(2 * sqrt(fmax(lam[1], 0)), 0.25 * rad[0]);
    rad[2] = fmax(2 * sqrt(fmax(lam[2], 0)), 0.1 * 0.5 * (rad[0] + rad[1]));
    for (int k = 0; k < 3; k++) c[k] = -sgn * rad[2] * E[k][2];
  }
  /* Roots in the ellipsoid's frame. */
  for (uint32_t s = 0; s < N; s++) {
    double r[3] = {u[3 * s] - c[0], u[3 * s + 1] - c[1], u[3 * s + 2] - c[2]};
    for (int a = 0; a < 3; a++) u[3 * s + a] = (float)(r[0] * E[0][a] + r[1] * E[1][a] + r[2] * E[2][a]);
  }
  /* Shrink about the centre until 98% of the roots are on or outside. */
  for (uint32_t s = 0; s < N; s++) {
    double d2 = 0;
    for (int a = 0; a < 3; a++) {
      double t = u[3 * s + a] / fmax(rad[a], 1e-30);
      d2 += t * t;
    }
    q[s] = (float)sqrt(d2);
  }
  qsort(q, N, sizeof *q, cmp_float);
  double p2 = q[(size_t)(0.02 * (N - 1))];
  double shrink = 0.99 * fmin(1.0, p2);
  for (int a = 0; a < 3; a++) {
    out->radii[a] = (float)(rad[a] * shrink);
    for (int k = 0; k < 3; k++) out->axes[a][k] = (float)E[k][a];
  }
  for (int k = 0; k < 3; k++) out->centre[k] = (float)(mean[k] + c[k]);
  free(u), free(q);
  for (int a = 0; a < 3; a++)
    if (!isfinite(out->radii[a]) || !(out->radii[a] > 0)) return HF_ERANGE;
  return HF_OK;
}
