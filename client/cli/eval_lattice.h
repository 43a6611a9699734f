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
 * divides P, lifts only P's. Images are interleaved [h][w][c] float. */
#ifndef HF_EVAL_LATTICE_H
#define HF_EVAL_LATTICE_H

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

#endif
