/* The lattice in a filter's error: period folding of the error image
 * (eval_lattice.h). Written here because it is a few loops over the phases,
 * not a spectrum: one pass per period, no FFT library needed. */
#include "eval_lattice.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "hfcore.h"

/* eval_lattice_energy of a w x h part of images whose rows are stride
 * floats apart. */
static double energy_strided(const float *a, const float *b, size_t stride, int w, int h, int c,
                             int period) {
  int p = period;
  if (p < 2 || p > EVAL_LATTICE_MAX_PERIOD + 1 || c < 1 || w < 2 * p || h < 2 * p) return NAN;
  int hh = h / p * p, ww = w / p * p;
  double n = (double)(hh / p) * (ww / p);   /* pixels per phase */
  double *sum = calloc((size_t)p * p * c, sizeof *sum);
  if (!sum) return HF_ENOMEM;
  for (int y = 0; y < hh; y++) {
    double *row = sum + (size_t)(y % p) * p * c;
    const float *pa = a + (size_t)y * stride, *pb = b + (size_t)y * stride;
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

double eval_lattice_energy(const float *a, const float *b, int w, int h, int c, int period) {
  return energy_strided(a, b, (size_t)w * c, w, h, c, period);
}

/* eval_lattice_peak of a w x h part of images whose rows are stride floats
 * apart; *amplitude (when not NULL): the RMS of the pattern of period P
 * the peak finds, net of what noise puts into the phase means (the energy
 * the neighbours see), 0 where there is none. */
static double peak_strided(const float *a, const float *b, size_t stride, int w, int h, int c,
                           int period, double *amplitude) {
  if (amplitude) *amplitude = 0;
  if (period < 3 || period > EVAL_LATTICE_MAX_PERIOD) return NAN;
  double e[3];
  for (int i = 0; i < 3; i++) {
    e[i] = energy_strided(a, b, stride, w, h, c, period - 1 + i);
    if (isnan(e[i]) || e[i] < 0) return e[i];
  }
  double around = 0.5 * (e[0] + e[2]);
  if (amplitude && e[1] > around) {
    /* energy = n spread / (P^2 - 1); the phase means' variance is spread /
     * P^2, of which noise accounts for around / n. */
    double p2 = (double)period * period, n = (double)(h / period) * (w / period);
    *amplitude = sqrt((e[1] - around) / n * (p2 - 1) / p2);
  }
  if (around > 0) return e[1] / around;
  return e[1] > 0 ? INFINITY : 0;
}

double eval_lattice_peak(const float *a, const float *b, int w, int h, int c, int period) {
  return peak_strided(a, b, (size_t)w * c, w, h, c, period, NULL);
}

/* The origins of windows of side s over n pixels, half a window apart, the
 * last flush with the far edge: every pixel lies in a window. */
static int window_origin(int i, int n, int s) {
  int o = i * (s / 2);
  return o + s > n ? n - s : o;
}

static int window_count(int n, int s) {
  return n <= s ? 1 : (n - s + s / 2 - 1) / (s / 2) + 1;
}

int eval_lattice_windows(const float *a, const float *b, const uint8_t *mask, int w, int h,
                         int c, int period, eval_lattice_window *out) {
  *out = (eval_lattice_window){.peak = NAN};
  if (period < 3 || period > EVAL_LATTICE_MAX_PERIOD || c < 1 || w < 1 || h < 1) return 0;
  int side = EVAL_LATTICE_WINDOW_PERIODS * period;
  if (side > w) side = w;
  if (side > h) side = h;
  if (side < 2 * (period + 1)) return 0;
  size_t stride = (size_t)w * c;
  int nx = window_count(w, side), ny = window_count(h, side);
  for (int j = 0; j < ny; j++) {
    int y0 = window_origin(j, h, side);
    for (int i = 0; i < nx; i++) {
      int x0 = window_origin(i, w, side);
      if (mask) {
        size_t hair = 0;
        for (int y = y0; y < y0 + side; y++)
          for (int x = x0; x < x0 + side; x++) hair += mask[(size_t)y * w + x] != 0;
        if (hair < EVAL_LATTICE_WINDOW_HAIR * side * side) continue;
      }
      size_t off = (size_t)y0 * stride + (size_t)x0 * c;
      double amp, peak = peak_strided(a + off, b + off, stride, side, side, c, period, &amp);
      if (peak < 0) return (int)peak;
      if (isnan(peak)) continue;
      out->windows++;
      if (!(peak <= out->peak)) {   /* also the first: out->peak is NAN */
        out->peak = peak;
        out->peak_x = x0;
        out->peak_y = y0;
      }
      if (peak >= EVAL_LATTICE_WINDOW_PEAK && amp > out->amplitude) {
        out->amplitude = amp;
        out->x = x0;
        out->y = y0;
      }
    }
  }
  return out->windows > 0;
}
