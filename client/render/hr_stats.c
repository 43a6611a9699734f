/* The regime of a frame (hfr_frame_stats): how wide its strands are in
 * pixels and how dense it is, read off the first 4x pass the way the
 * network sees it, and off the model's points and the camera. Quantiles are
 * exact (libc's qsort on a copy): a frame has at most a few million covered
 * samples and points, sorted in well under the time one pass takes. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hr_internal.h"
#include "hr_math.h"

static int cmp_float(const void *a, const void *b) {
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

/* Quantile q of sorted v[n] (nearest rank). */
static double quantile(const float *v, size_t n, double q) {
  if (!n) return 0;
  size_t i = (size_t)floor(q * (double)(n - 1) + 0.5);
  return v[i < n ? i : n - 1];
}

void hr_frame_stats(const hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
                    const float *pass, int w, int h, hfr_frame_stats *fs) {
  memset(fs, 0, sizeof *fs);
  fs->gt_opaque = -1;
  const size_t px = (size_t)w * h;
  if (pass) {
    float *a = malloc(sizeof(float) * 4 * px);
    size_t n = 0, hair = 0, full = 0;
    for (size_t i = 0; a && i < px; i++) {
      int k = 0;
      for (int s = 0; s < 4; s++) {
        float al = pass[(i * 4 + s) * 6 + 2];
        if (al > 0) a[n++] = al, k++;
      }
      hair += k > 0;
      full += k == 4;
    }
    if (a) {
      qsort(a, n, sizeof *a, cmp_float);
      fs->valid = 1;
      fs->alpha_p10 = quantile(a, n, 0.1);
      fs->alpha_p50 = quantile(a, n, 0.5);
      fs->alpha_p90 = quantile(a, n, 0.9);
      fs->sample_coverage = px ? (double)n / (4.0 * px) : 0;
      fs->hair_pixels = px ? (double)hair / px : 0;
      fs->full_pixels = hair ? (double)full / hair : 0;
    }
    free(a);
  }
  /* Strand widths in pixels at the model's points inside the window. */
  float *wd = malloc(sizeof(float) * (r->n_stat ? r->n_stat : 1));
  if (!wd) return;
  size_t n = 0;
  for (uint32_t i = 0; i < r->n_stat; i++) {
    const float *p = r->stat_pts + 4 * (size_t)i;
    float e[4], c[4];
    for (int k = 0; k < 4; k++) {
      e[k] = cam->view[k] * p[0] + cam->view[4 + k] * p[1] + cam->view[8 + k] * p[2] +
             cam->view[12 + k];
    }
    for (int k = 0; k < 4; k++)
      c[k] = cam->proj[k] * e[0] + cam->proj[4 + k] * e[1] + cam->proj[8 + k] * e[2] +
             cam->proj[12 + k] * e[3];
    float dist = -e[2];
    if (!(dist > 0) || !(c[3] > 0)) continue;
    /* Window position in the whole frame (GL origin), then the window. */
    float x = (c[0] / c[3] * 0.5f + 0.5f) * cam->frame_w - cam->win_x;
    float y = (c[1] / c[3] * 0.5f + 0.5f) * cam->frame_h - cam->win_y;
    if (x < 0 || y < 0 || x >= cam->win_w || y >= cam->win_h) continue;
    wd[n++] = p[3] * v->thickness_scale * cam->px_per_unit / dist;
  }
  qsort(wd, n, sizeof *wd, cmp_float);
  fs->width_px_p10 = quantile(wd, n, 0.1);
  fs->width_px_p50 = quantile(wd, n, 0.5);
  fs->width_px_p90 = quantile(wd, n, 0.9);
  fs->points_in_view = n;
  fs->points_picked = r->n_stat;
  fs->points_model = r->n_model_pts;
  free(wd);
}

/* Significant digits, not decimals: strands far below a pixel (1e-5 px
 * wide, a hair fraction of 4e-4) are a regime of their own, and printed as
 * 0.0000 they read as no hair at all. */
void hfr_frame_stats_format(const hfr_frame_stats *s, char *buf, size_t len) {
  int k = 0;
  if (s->valid)
    k = snprintf(buf, len,
                 "covered-sample alpha p10/p50/p90 %.3g/%.3g/%.3g, samples covered %.3g, hair "
                 "pixels %.3g, of them fully covered %.3g",
                 s->alpha_p10, s->alpha_p50, s->alpha_p90, s->sample_coverage, s->hair_pixels,
                 s->full_pixels);
  else
    k = snprintf(buf, len, "no stochastic pass");
  if (k < 0 || (size_t)k >= len) return;
  if (s->gt_opaque >= 0)
    k += snprintf(buf + k, len - k, ", opaque in the ground truth %.3g", s->gt_opaque);
  if (k < 0 || (size_t)k >= len) return;
  /* Picked points are counted apart from the model's: a model of more than
   * 2^20 points is measured at every k-th, and "in view" is of those. */
  if (s->points_picked && s->points_picked < s->points_model)
    snprintf(buf + k, len - k,
             "; strand width p10/p50/p90 %.3g/%.3g/%.3g px (at %llu points in view, of %llu "
             "picked evenly from the model's %llu)",
             s->width_px_p10, s->width_px_p50, s->width_px_p90,
             (unsigned long long)s->points_in_view, (unsigned long long)s->points_picked,
             (unsigned long long)s->points_model);
  else
    snprintf(buf + k, len - k,
             "; strand width p10/p50/p90 %.3g/%.3g/%.3g px (at %llu points in view, of the "
             "model's %llu)",
             s->width_px_p10, s->width_px_p50, s->width_px_p90,
             (unsigned long long)s->points_in_view, (unsigned long long)s->points_model);
}
