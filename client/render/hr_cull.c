/* Which of the hair's segment instances can reach a window of the frame.
 *
 * A crop or a band of rows is drawn with the whole frame's viewport and a
 * scissor to the window (hr_set_viewport), so that every sample sees the
 * whole frame's coordinates. llvmpipe runs the vertex shader and sets up
 * every instance of a draw, in one thread, before the scissor throws it
 * away: a dense ground truth drawn in 53 bands of rows spent most of its
 * time there (docs/RENDERING.md, "Dense ground truths"). Drawing only the
 * runs of instances whose quads can touch the window leaves the window's
 * fragments, and their order, as they were: the instances left out have
 * none there, the others keep their order (one draw per run, in order). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hr_internal.h"

/* Instances between two runs that are drawn anyway (the vertex shader
 * places them outside the window) rather than costing one more draw. */
#define RUN_GAP 32u

/* Pixels added around a quad's bounds: a pass's jitter (at most half a
 * pixel) and rounding between this float arithmetic and the shader's.
 * Only the window's own pixels matter: the scissor's growth to whole
 * 16-pixel blocks (hr_set_viewport) rasterises pixels no pass reads, and
 * the A-buffer keeps only the window's fragments. */
#define WINDOW_MARGIN 2.0f

static void clip_of(const hr_camera *cam, const float p[3], float e[4], float c[4]) {
  for (int i = 0; i < 4; i++)
    e[i] = cam->view[i] * p[0] + cam->view[4 + i] * p[1] + cam->view[8 + i] * p[2] +
           cam->view[12 + i];
  for (int i = 0; i < 4; i++)
    c[i] = cam->proj[i] * e[0] + cam->proj[4 + i] * e[1] + cam->proj[8 + i] * e[2] +
           cam->proj[12 + i] * e[3];
}

/* The pixels the quad of the segment from point a to point b (x, y, z,
 * diameter each) can cover, as hr_glsl_hair_vs builds it: out = x0, y0,
 * x1, y1 in GL window coordinates, the quad reaching half its width either
 * side of the projected segment, plus WINDOW_MARGIN. A segment this
 * arithmetic cannot place (a point at or behind the eye, infinite or NaN
 * coordinates) gets the whole plane. */
static void segment_bounds(const hr_camera *cam, float thick_scale, const float *a,
                           const float *b, float out[4], float *area) {
  float lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY}, half = 0, wsum = 0;
  float sp[2][2];
  *area = 0;
  const float *pt[2] = {a, b};
  for (int k = 0; k < 2; k++) {
    float e[4], c[4];
    clip_of(cam, pt[k], e, c);
    const float dist = -e[2] > 1e-6f ? -e[2] : 1e-6f;
    const float px = pt[k][3] * thick_scale * cam->px_per_unit / (cam->ortho ? 1.0f : dist);
    const float m = px > 1 ? px : 1;
    const float s[2] = {(c[0] / c[3] * 0.5f + 0.5f) * cam->frame_w,
                        (c[1] / c[3] * 0.5f + 0.5f) * cam->frame_h};
    if (!(c[3] > 1e-6f) || !isfinite(s[0]) || !isfinite(s[1]) || !isfinite(m)) {
      out[0] = out[1] = -INFINITY, out[2] = out[3] = INFINITY;
      return;
    }
    half = m > half ? m : half;
    wsum += m, sp[k][0] = s[0], sp[k][1] = s[1];
    for (int i = 0; i < 2; i++) {
      lo[i] = s[i] < lo[i] ? s[i] : lo[i];
      hi[i] = s[i] > hi[i] ? s[i] : hi[i];
    }
  }
  const float r = 0.5f * half + WINDOW_MARGIN;
  out[0] = lo[0] - r, out[1] = lo[1] - r, out[2] = hi[0] + r, out[3] = hi[1] + r;
  /* The quad: the projected length times the mean of its end widths. */
  *area = hypotf(sp[1][0] - sp[0][0], sp[1][1] - sp[0][1]) * 0.5f * wsum;
}

/* What the segments' bounds depend on: the camera without its window,
 * and the thickness scale. */
static void bounds_key(const hr_camera *cam, float thick_scale, float key[HR_BOUNDS_KEY]) {
  memcpy(key, cam->view, sizeof cam->view);
  memcpy(key + 16, cam->proj, sizeof cam->proj);
  key[32] = (float)cam->frame_w, key[33] = (float)cam->frame_h;
  key[34] = cam->px_per_unit, key[35] = (float)cam->ortho, key[36] = thick_scale;
}

typedef struct {
  const hfr_renderer *r;
  const hr_camera *cam;
  float thick_scale;
} bounds_job;

static void bounds_chunk(void *arg, int worker, size_t i0, size_t i1) {
  (void)worker;
  const bounds_job *j = arg;
  for (size_t i = i0; i < i1; i++)
    segment_bounds(j->cam, j->thick_scale, j->r->cull_pts + 4 * i, j->r->cull_pts + 4 * (i + 1),
                   j->r->seg_bounds + 4 * i, j->r->seg_area + i);
}

/* r->seg_bounds for cam and thick_scale: computed once, on every core,
 * for all the windows (bands, passes) of one camera. */
static int ensure_bounds(hfr_renderer *r, const hr_camera *cam, float thick_scale) {
  float key[HR_BOUNDS_KEY];
  bounds_key(cam, thick_scale, key);
  if (r->bounds_valid && !memcmp(key, r->bounds_key, sizeof key)) return HF_OK;
  r->bounds_valid = 0;
  const size_t segs = r->points - 1;
  if (!r->seg_bounds) {
    r->seg_bounds = malloc(sizeof(float) * 4 * (r->points ? r->points : 1));
    if (!r->seg_bounds) return HF_ENOMEM;
  }
  if (!r->seg_area) {
    r->seg_area = malloc(sizeof(float) * (r->points ? r->points : 1));
    if (!r->seg_area) return HF_ENOMEM;
  }
  bounds_job j = {r, cam, thick_scale};
  hf_parallel_chunks(segs, 1 << 14, 1 << 16, bounds_chunk, &j);
  memcpy(r->bounds_key, key, sizeof key);
  r->bounds_valid = 1;
  return HF_OK;
}

/* Appends the run [first, end) to r->runs[*n]. */
static int push_run(hfr_renderer *r, size_t *n, uint32_t first, uint32_t end) {
  if (*n == r->runs_cap) {
    size_t cap = r->runs_cap ? 2 * r->runs_cap : 1024;
    hr_run *g = realloc(r->runs, cap * sizeof *g);
    if (!g) return HF_ENOMEM;
    r->runs = g, r->runs_cap = cap;
  }
  r->runs[(*n)++] = (hr_run){first, end - first};
  return HF_OK;
}

int hr_hair_window_runs(hfr_renderer *r, const hr_camera *cam, float thick_scale,
                        size_t *n_runs) {
  *n_runs = 0;
  if (!r->cull_pts || !r->strand_first || r->points < 2) return HF_EINVAL;
  if (ensure_bounds(r, cam, thick_scale) != HF_OK) return HF_ENOMEM;
  const float x0 = (float)cam->win_x, y0 = (float)cam->win_y;
  const float x1 = (float)(cam->win_x + cam->win_w), y1 = (float)(cam->win_y + cam->win_h);
  size_t n = 0;
  uint32_t first = 0, end = 0; /* the open run, [first, end) */
  int open = 0;
  for (uint32_t s = 0; s < r->strands; s++) {
    /* Instance i is the segment from point i to i + 1; the strand's last
     * point starts the instance that would join two strands. */
    for (uint32_t i = r->strand_first[s]; i + 1 < r->strand_first[s + 1]; i++) {
      const float *b = r->seg_bounds + 4 * (size_t)i;
      if (b[2] < x0 || b[0] > x1 || b[3] < y0 || b[1] > y1) continue;
      if (open && i - end <= RUN_GAP) {
        end = i + 1;
        continue;
      }
      if (open && push_run(r, &n, first, end) != HF_OK) return HF_ENOMEM;
      first = i, end = i + 1, open = 1;
    }
  }
  if (open && push_run(r, &n, first, end) != HF_OK) return HF_ENOMEM;
  *n_runs = n;
  return HF_OK;
}

int hr_hair_window_fragments(hfr_renderer *r, const hr_camera *cam, float thick_scale,
                             double *frags) {
  *frags = 0;
  if (!r->cull_pts || !r->strand_first || r->points < 2) return HF_EINVAL;
  if (ensure_bounds(r, cam, thick_scale) != HF_OK) return HF_ENOMEM;
  const double x0 = cam->win_x, y0 = cam->win_y;
  const double x1 = cam->win_x + cam->win_w, y1 = cam->win_y + cam->win_h;
  double sum = 0;
  for (uint32_t s = 0; s < r->strands; s++)
    for (uint32_t i = r->strand_first[s]; i + 1 < r->strand_first[s + 1]; i++) {
      const float *b = r->seg_bounds + 4 * (size_t)i;
      if (!(r->seg_area[i] > 0) || b[2] < x0 || b[0] > x1 || b[3] < y0 || b[1] > y1) continue;
      /* The share of its bounds inside the window. */
      const double w = (double)b[2] - b[0], h = (double)b[3] - b[1];
      const double iw = fmin(b[2], x1) - fmax(b[0], x0), ih = fmin(b[3], y1) - fmax(b[1], y0);
      if (w > 0 && h > 0 && iw > 0 && ih > 0) sum += r->seg_area[i] * (iw / w) * (ih / h);
    }
  *frags = sum;
  return HF_OK;
}
