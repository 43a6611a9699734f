/* The lattice in a filter's error: period folding of the error image
 * (eval_lattice.h). Written here because it is a few loops over the phases,
 * not a spectrum: one pass per period, no FFT library needed. */
#include "eval_lattice.h"

#include <math.h>
#include <stdlib.h>

#include "hfcore.h"

double eval_lattice_energy(const float *a, const float *b, int w, int h, int c, int period) {
  int p = period;
  if (p < 2 || p > EVAL_LATTICE_MAX_PERIOD + 1 || c < 1 || w < 2 * p || h < 2 * p) return NAN;
  int hh = h / p * p, ww = w / p * p;
  double n = (double)(hh / p) * (ww / p);   /* pixels per phase */
  double *sum = calloc((size_t)p * p * c, sizeof *sum);
  if (!sum) return HF_ENOMEM;
  for (int y = 0; y < hh; y++) {
    double *row = sum + (size_t)(y % p) * p * c;
    const float *pa = a + (size_t)y * w * c, *pb = b + (size_t)y * w * c;
    for (int x = 0; x < ww; x++) {
      double *cell = row + (size_t)(x % p) * c;
      for (int k = 0; k < c; k++) cell[k] += (double)pa[x * c + k] - pb[x * c + k];
    }
  }
  double energy = 0;
  for (int k = 0; k < c; k++) {
    double mean = 0, spread = 0;
    for (int i = 0; i < p * p; i++) mean += sum[(size_t)i * c + k] / n;
    mean /= (double)p * p;
    for (int i = 0; i < p * p; i++) {
      double d = sum[(size_t)i * c + k] / n - mean;
      spread += d * d;
    }
    energy += n * spread / ((double)p * p - 1);
  }
  free(sum);
  return energy / c;
}

double eval_lattice_peak(const float *a, const float *b, int w, int h, int c, int period) {
  if (period < 3 || period > EVAL_LATTICE_MAX_PERIOD) return NAN;
  double e[3];
  for (int i = 0; i < 3; i++) {
    e[i] = eval_lattice_energy(a, b, w, h, c, period - 1 + i);
    if (isnan(e[i]) || e[i] < 0) return e[i];
  }
  double around = 0.5 * (e[0] + e[2]);
  if (around > 0) return e[1] / around;
  return e[1] > 0 ? INFINITY : 0;
}
