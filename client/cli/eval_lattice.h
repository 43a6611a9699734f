/* The lattice in a filter's error, for `hairfilter eval`'s "Lattice in the
 * error" table (docs/QUALITY.md says how to read it).
 *
 * A U-Net whose decoder upsamples with stride-2 transposed convolutions can
 * print a fixed pattern that repeats every 2^levels pixels (Odena, Dumoulin
 * & Olah, "Deconvolution and Checkerboard Artifacts", Distill 2016): the
 * dots a viewer sees in dark, dense hair. The measure folds the error
 * e = a - b onto the P x P pixel phases (y mod P, x mod P) of the largest
 * part of the frame that is whole periods, and takes the spread of the
 * phase means, scaled so that error without structure gives its own
 * variance at any P. The peak is that at P over the mean at P - 1 and
 * P + 1: noise, blur and smooth gradients spread evenly over neighbouring
 * periods (a peak near 1); a pattern of period P, or of any period that
 * divides P, lifts only P's. The windowed measure takes the same peak in
 * windows of 8 periods, and where it finds a pattern, the pattern's
 * amplitude in display levels: whether a viewer can see it. Images are
 * interleaved [h][w][c] float. */
#ifndef HF_EVAL_LATTICE_H
#define HF_EVAL_LATTICE_H

#include <stdint.h>

/* A peak at or above this stands out of the error (the table's "frames
 * >= 3" column). Error with no pattern stays below it with a margin: on
 * the 35 frames of docs/QUALITY.md the peaks of the input, its 3x3 and 5x5
 * pools and stochastic transparency at 4 to 64 spp range from 0.23 to 2.23
 * (the pools' blurred error spreads widest). */
#define EVAL_LATTICE_VISIBLE 3.0

/* The largest period measured (the peak also folds at period + 1). */
#define EVAL_LATTICE_MAX_PERIOD 64

/* Energy of the error a - b at period P: with m[k][i][j] the mean of
 * channel k's error over the pixels of phase (i, j) and n the pixels per
 * phase, n / (P^2 - 1) times the sum over phases of (m - mean over phases
 * of m)^2, averaged over the c channels; for independent noise of variance
 * s^2 its expectation is s^2. 0 for identical images. NAN when P is
 * outside [2, EVAL_LATTICE_MAX_PERIOD + 1] or the image is not 2 periods
 * wide and high; HF_ENOMEM (negative) when scratch cannot be had. */
double eval_lattice_energy(const float *a, const float *b, int w, int h, int c, int period);

/* eval_lattice_energy at period over the mean of it at period - 1 and
 * period + 1: about 1 without a lattice. 0 for identical images, INFINITY
 * for a pure pattern of period P with nothing at the neighbours, NAN when
 * period is outside [3, EVAL_LATTICE_MAX_PERIOD] or the image is not
 * 2 (period + 1) pixels wide and high, HF_ENOMEM (negative) on failure. */
double eval_lattice_peak(const float *a, const float *b, int w, int h, int c, int period);

/* A lattice confined to part of a frame (the dots of a network in its
 * dark, dense hair) is diluted in the whole frame's peak; the windowed
 * measure looks for it in windows of this many periods on a side. Eight
 * periods leave 64 pixels per phase. */
#define EVAL_LATTICE_WINDOW_PERIODS 8

/* The share of a window's pixels that must be hair (mask != 0) for the
 * windowed measure to look at it: a pattern over background (or one
 * strand over it) is not what a viewer sees in the hair. */
#define EVAL_LATTICE_WINDOW_HAIR 0.5

/* A window's pattern of period P is one when its peak is at least this.
 * The peak of one window rests on few pixels: where a window's error is a
 * handful of outliers over near-zero error (the input on dark, dense hair)
 * it reaches 5 without any pattern; such a window's amplitude is a small
 * fraction of a level, hence the amplitude floor below. */
#define EVAL_LATTICE_WINDOW_PEAK 6.0

/* A pattern stands out when its amplitude (RMS, display units of the
 * composite in [0, 1]) is at least this: one level of an 8-bit display. */
#define EVAL_LATTICE_VISIBLE_AMPLITUDE (1.0 / 255)

/* The windowed measure of one frame (eval_lattice_windows). */
typedef struct eval_lattice_window {
  int windows;          /* windows measured (enough hair, large enough) */
  double peak;          /* the largest eval_lattice_peak of a window; NAN if none */
  int peak_x, peak_y;   /* that window's top-left pixel */
  double amplitude;     /* the largest pattern amplitude (RMS, [0, 1] units) among
                           windows whose peak is >= EVAL_LATTICE_WINDOW_PEAK; 0: none */
  int x, y;             /* that window's top-left pixel */
} eval_lattice_window;

/* Measures the lattice of period P in square windows of side
 * EVAL_LATTICE_WINDOW_PERIODS x P pixels (the frame's smaller side where
 * that is less), half a window apart and covering the frame, among those
 * at least EVAL_LATTICE_WINDOW_HAIR hair by mask ([h][w], nonzero = hair;
 * NULL: every window): each window's peak (eval_lattice_peak) and, where
 * the peak says there is a pattern, its amplitude: the RMS over the P x P
 * phases of the error's periodic part, less what noise contributes. A frame
 * shows a lattice where out->amplitude >= EVAL_LATTICE_VISIBLE_AMPLITUDE.
 * Returns 1 when some window was measured, 0 when none qualifies (too
 * little hair, the frame is less than 2 (P + 1) pixels on a side, or P is
 * outside [3, EVAL_LATTICE_MAX_PERIOD]), HF_ENOMEM (negative) on failure. */
int eval_lattice_windows(const float *a, const float *b, const uint8_t *mask, int w, int h,
                         int c, int period, eval_lattice_window *out);

#endif
