/* Dataset regimes (render dataset --regimes): frames drawn over what
 * engines render, not around one look. Per frame: the strand width in
 * pixels (so that covered-sample alpha runs from far sub-pixel, 0.005, to
 * wider than a pixel, opacity), a further width factor per clump, density
 * (strand count, opacity, length, clumping), the virtual frame size (256 to
 * 1024: the output is a crop of it, placed on the hair, so a 256x256 frame
 * can show a close-up of a 1024x1024 one), the camera (full head to
 * close-up), the light (direction, point or directional, ambient, shadows on
 * or off, their bias and resolution), curl and frizz. Every draw comes from
 * the frame's seed and is written to the manifest. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hr_dataset.h"
#include "hr_internal.h"

/* Log-uniform in [lo, hi]. */
static float log_range(hr_rng *g, float lo, float hi) {
  return expf(hr_rng_range(g, logf(lo), logf(hi)));
}

void hr_braid_draw(hr_rng *g, const hfr_dataset_opts *o, hfr_style_params *sp) {
  /* The comb to the gathering point takes 1 to 2 of a strand's length: 2.2
   * or more leaves a plait. */
  sp->length = hr_rng_range(g, 2.2f, 4.5f);
  sp->curl_period = hr_rng_range(g, 0.15f, 0.6f);
  sp->curl_radius = sp->curl_period * hr_rng_range(g, 0.15f, 0.35f);
  /* About 8 segments per period over the whole strand (the combed part
   * takes its share), 48 to 160. */
  if (o->segments <= 0)
    sp->segments = (int)fminf(160.0f, fmaxf(48.0f, ceilf(8.0f * sp->length / sp->curl_period)));
}

/* A stream of its own for one optional draw of a frame (salt tells the
 * draws apart), from the model's seed: the frame's other draws stay those
 * of a run without the option. */
static hr_rng own_stream(uint64_t seed, uint64_t mul, uint64_t salt) {
  hr_rng g = {seed * mul + salt};
  return g;
}

void hr_gather_draw(const hfr_dataset_opts *o, hfr_style_params *sp) {
  if (!(o->gather_max > 0) || !hfr_style_has_tie(sp->style)) return;
  hr_rng g = own_stream(sp->seed, 0xd1342543de82ef95ull, 0x2545f4914f6cdd1dull);
  sp->gather = hr_rng_range(&g, o->gather_min, o->gather_max);
}

void hr_opacity_draw(const hfr_dataset_opts *o, hfr_style_params *sp) {
  if (o->regimes || !(o->opacity_max > 0)) return;
  hr_rng g = own_stream(sp->seed, 0xbf58476d1ce4e5b9ull, 0x94d049bb133111ebull);
  sp->opacity = hr_rng_range(&g, o->opacity_min, o->opacity_max);
}

int hr_smooth_picked(const hfr_dataset_opts *o, uint64_t seed) {
  if (!(o->smooth_share > 0)) return 0;
  hr_rng g = own_stream(seed, 0x9fb21c651e98df25ull, 0x3c6ef372fe94f82bull);
  return hr_rng_uniform(&g) < o->smooth_share;
}

void hr_smooth_draw(const hfr_dataset_opts *o, hfr_style_params *sp) {
  if (!hr_smooth_picked(o, sp->seed)) return;
  sp->frizz = 0;
  if (!sp->children) sp->clumping = 0;
}

void hr_regime_style(hr_rng *g, const hfr_dataset_opts *o, hfr_style_params *sp,
                     hr_regime *rg) {
  memset(rg, 0, sizeof *rg);
  hfr_style_params def;
  hfr_style_defaults(sp->style, &def);
  /* Density: sparse flyaways to masses that cover everything. */
  if (o->strands <= 0) sp->strands = (int)log_range(g, 400.0f, 40000.0f);
  if (sp->style == HFR_STYLE_FUR && o->strands <= 0) sp->strands *= 2;
  float opacity[2];
  hr_regime_opacity_range(o, opacity);
  sp->opacity = hr_rng_range(g, opacity[0], opacity[1]);
  sp->length = def.length * hr_rng_range(g, 0.5f, 1.6f);
  sp->clumping = hr_rng_range(g, 0.0f, 0.9f);
  sp->frizz = fminf(0.08f, def.frizz * log_range(g, 0.2f, 5.0f));
  if (sp->style == HFR_STYLE_WAVY || sp->style == HFR_STYLE_CURLY ||
      sp->style == HFR_STYLE_COILY || sp->style == HFR_STYLE_PONYTAIL) {
    sp->curl_period = hr_rng_range(g, 0.07f, 0.9f);
    sp->curl_radius = sp->curl_period * hr_rng_range(g, 0.1f, 0.45f);
    /* About 6 segments per period, at most 128 per strand. */
    sp->length = fminf(sp->length, 128.0f * sp->curl_period / 6.0f);
    if (o->segments <= 0)
      sp->segments = (int)fminf(128.0f, fmaxf(24.0f, ceilf(6.0f * sp->length / sp->curl_period)));
  }
  if (sp->style == HFR_STYLE_BRAIDED) hr_braid_draw(g, o, sp);
  if (def.children) sp->children = (int)hr_rng_range(g, 7.0f, 32.0f);
  /* Per clump: diameter x s^u, u in [-1, 1]. */
  sp->width_spread = log_range(g, 1.0f, 4.0f);
  rg->clump_width_spread = sp->width_spread;
}

void hr_regime_opacity_range(const hfr_dataset_opts *o, float range[2]) {
  int set = o->opacity_max > 0;
  range[0] = set ? o->opacity_min : HR_REGIME_OPACITY_MIN;
  range[1] = set ? o->opacity_max : HR_REGIME_OPACITY_MAX;
}

float hr_typical_thickness(const hfr_hair *h) {
  /* Median of evenly picked points that have a width: tips written 0 (half
   * the points of one-segment strands) would otherwise make it 0, and the
   * drawn width then misses its target. An array of zeros is ignored, as
   * the renderer ignores it (hfr_renderer_set_hair). */
  enum { N = 4096 };
  float v[N];
  uint32_t n = 0;
  if (h->thickness && !hfr_hair_thickness_all_zero(h)) {
    uint32_t picks = h->points < N ? h->points : N;
    for (uint32_t i = 0; i < picks; i++) {
      float t = h->thickness[(uint64_t)i * h->points / picks];
      if (t > 0) v[n++] = t;
    }
    /* Every picked point 0 but not every point: the positive ones. */
    for (uint64_t i = 0; !n && i < h->points; i++)
      if (h->thickness[i] > 0) v[n++] = h->thickness[i];
  }
  if (!n) {
    float c[3], r;
    hfr_hair_bounds(h, c, &r);
    return hfr_hair_default_thickness(h, r, NULL);
  }
  for (uint32_t i = 1; i < n; i++) { /* insertion sort: n is small */
    float x = v[i];
    uint32_t j = i;
    while (j > 0 && v[j - 1] > x) v[j] = v[j - 1], j--;
    v[j] = x;
  }
  return n ? v[n / 2] : 0;
}

void hr_regime_view(hr_rng *g, const hfr_dataset_opts *o, hfr_renderer *r, const hfr_hair *h,
                    hfr_view *v, hr_regime *rg) {
  /* The virtual frame: the output is a crop of it. */
  int lo = o->frame_min > 0 ? o->frame_min : 256, hi = o->frame_max > 0 ? o->frame_max : 1024;
  int crop = o->width > o->height ? o->width : o->height;
  if (lo < crop) lo = crop;
  if (hi < lo) hi = lo;
  int F = (int)lroundf(log_range(g, (float)lo, (float)hi));
  if (F < lo) F = lo;
  if (F > hi) F = hi;
  rg->frame_size = F;
  v->width = v->height = F;
  /* Camera: full head to close-up. */
  v->cam_fov_deg = hr_rng_range(g, 25.0f, 50.0f);
  v->cam_distance = log_range(g, 1.5f, 5.0f);
  v->cam_yaw_deg = hr_rng_range(g, 0, 360);
  v->cam_pitch_deg = hr_rng_range(g, -20, 50);
  /* Light and shadows. */
  v->light_yaw_deg = hr_rng_range(g, 0, 360);
  v->light_pitch_deg = hr_rng_range(g, -30, 80);
  v->light_distance = hr_rng_range(g, 2.5f, 8.0f);
  v->light_directional = hr_rng_uniform(g) < 0.3f;
  v->ambient = hr_rng_range(g, 0.0f, 0.3f);
  static const int sizes[] = {512, 1024, 2048};
  v->shadow_size = hr_rng_uniform(g) < 0.2f ? 0 : sizes[hr_rng_next(g) % 3];
  if (o->shadow_size == 0) v->shadow_size = 0;
  v->shadow_bias = log_range(g, 0.002f, 0.05f);
  /* Strand width in pixels at the bounding sphere's centre: the model's
   * typical diameter scaled to a width drawn log-uniformly from far
   * sub-pixel to several pixels (or the range asked for). */
  rg->target_width_px = log_range(g, o->width_px_min > 0 ? o->width_px_min : HR_REGIME_WIDTH_PX_MIN,
                                  o->width_px_max > 0 ? o->width_px_max : HR_REGIME_WIDTH_PX_MAX);
  float centre[3], radius;
  hfr_renderer_bounds(r, centre, &radius);
  hr_camera cam;
  v->crop_w = 0;
  v->thickness_scale = 1;
  hr_camera_from_view(r, v, &cam);
  rg->typical_thickness = hr_typical_thickness(h);
  float px = rg->typical_thickness * cam.px_per_unit / (v->cam_distance * radius);
  v->thickness_scale = px > 0 ? rg->target_width_px / px : 1;
  /* The crop, centred on a random point of the hair in view. */
  int cw = o->width < F ? o->width : F, ch = o->height < F ? o->height : F;
  float cx = F * 0.5f, cy = F * 0.5f;
  for (int tries = 0; tries < 32 && h->points; tries++) {
    const float *p = h->pos + 3 * (size_t)(hr_rng_next(g) % h->points);
    float e[4], c[4];
    for (int k = 0; k < 4; k++)
      e[k] = cam.view[k] * p[0] + cam.view[4 + k] * p[1] + cam.view[8 + k] * p[2] + cam.view[12 + k];
    for (int k = 0; k < 4; k++)
      c[k] = cam.proj[k] * e[0] + cam.proj[4 + k] * e[1] + cam.proj[8 + k] * e[2] + cam.proj[12 + k] * e[3];
    if (!(c[3] > 0)) continue;
    float x = (c[0] / c[3] * 0.5f + 0.5f) * F, y = (0.5f - c[1] / c[3] * 0.5f) * F;
    if (x < 0 || y < 0 || x >= F || y >= F) continue;
    cx = x, cy = y;
    break;
  }
  int x0 = (int)lroundf(cx - cw * 0.5f), y0 = (int)lroundf(cy - ch * 0.5f);
  x0 = x0 < 0 ? 0 : x0 > F - cw ? F - cw : x0;
  y0 = y0 < 0 ? 0 : y0 > F - ch ? F - ch : y0;
  v->crop_x = x0, v->crop_y = y0, v->crop_w = cw, v->crop_h = ch;
}
