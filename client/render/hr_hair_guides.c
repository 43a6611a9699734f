/* Styles grown as real grooms are: a few guide strands shaped here, then
 * children interpolated around them (hfr_hair_interpolate), the way the
 * assets a studio ships are made.
 *
 *   spiky: a short cut, 4-5 cm guides standing out from the scalp (along
 *          the normal, brushed up and back, little gravity, a slight bend);
 *          the children are strongly clumped to their guide's tip: gelled
 *          spikes.
 *   fur:   1-2 cm guides on an animal's torso (HFR_FUR_BODY_RADII, its
 *          upper three quarters), leaving the skin at a low angle and lying
 *          down along the body's flow (head to tail, and down the flanks),
 *          dense enough to cover it. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hr_style.h"

static const float fur_r[3] = HFR_FUR_BODY_RADII;
static const float head_radii[3] = HFR_HEAD_RADII;

void hfr_style_body(hfr_style s, hfr_ellipsoid *e) {
  memset(e, 0, sizeof *e);
  const float *r = s == HFR_STYLE_FUR ? fur_r : head_radii;
  for (int k = 0; k < 3; k++) {
    e->axes[k][k] = 1;
    e->radii[k] = 0.99f * r[k];
  }
}

/* A root on the fur's body: uniform in direction over its upper three
 * quarters, and the outward normal there. */
static void body_root(hr_rng *g, float p[3], float n[3]) {
  for (;;) {
    float d[3] = {hr_rng_normal(g), hr_rng_normal(g), hr_rng_normal(g)};
    if (hr_len(d) < 1e-6f) continue;
    hr_normalize(d);
    if (d[1] < -0.5f) continue;
    for (int k = 0; k < 3; k++) p[k] = fur_r[k] * d[k], n[k] = d[k] / fur_r[k];
    hr_normalize(n);
    return;
  }
}

static void spiky_guide(const hfr_style_params *sp, hr_rng *g, float *c, int n) {
  float root[3], nrm[3];
  hr_scalp_root(g, root, nrm);
  float len = sp->length * hr_rng_range(g, 0.7f, 1.2f), seg = len / n;
  /* Standing out: the normal, brushed up and back, a random tilt. */
  float dir[3] = {nrm[0] + 0.3f * hr_rng_normal(g), nrm[1] + 0.35f + 0.3f * hr_rng_normal(g),
                  nrm[2] - 0.25f + 0.3f * hr_rng_normal(g)};
  hr_normalize(dir);
  float bend[3] = {hr_rng_normal(g), hr_rng_normal(g), hr_rng_normal(g)};
  float p[3] = {root[0], root[1], root[2]};
  memcpy(c, p, sizeof p);
  for (int i = 1; i <= n; i++) {
    for (int k = 0; k < 3; k++) dir[k] += 0.6f * bend[k] * seg;
    dir[1] -= 0.3f * seg;
    hr_normalize(dir);
    for (int k = 0; k < 3; k++) p[k] += dir[k] * seg;
    hr_push_out_of(head_radii, p, 0.01f);
    memcpy(c + 3 * i, p, sizeof p);
  }
}

static void fur_guide(const hfr_style_params *sp, hr_rng *g, float *c, int n) {
  float root[3], nrm[3];
  body_root(g, root, nrm);
  /* Flow: towards the tail (-z) and down the flanks, in the tangent plane. */
  float f[3] = {0.15f * hr_rng_normal(g), -0.6f, -1.0f};
  float d = hr_dot(f, nrm);
  for (int k = 0; k < 3; k++) f[k] -= d * nrm[k];
  if (hr_len(f) < 1e-4f) f[0] = 0, f[1] = -1, f[2] = 0;
  hr_normalize(f);
  float len = sp->length * hr_rng_range(g, 0.75f, 1.25f), seg = len / n;
  float lift = hr_rng_range(g, 0.35f, 0.8f);
  float dir[3] = {lift * nrm[0] + f[0], lift * nrm[1] + f[1], lift * nrm[2] + f[2]};
  hr_normalize(dir);
  float p[3] = {root[0], root[1], root[2]};
  memcpy(c, p, sizeof p);
  for (int i = 1; i <= n; i++) {
    /* Lies down along the flow as it grows. */
    for (int k = 0; k < 3; k++) dir[k] += (0.8f * f[k] - 0.5f * nrm[k]) * seg / len * 2;
    hr_normalize(dir);
    for (int k = 0; k < 3; k++) p[k] += dir[k] * seg;
    hr_push_out_of(fur_r, p, 0.004f * i);
    memcpy(c + 3 * i, p, sizeof p);
  }
}

int hr_generate_from_guides(const hfr_style_params *sp, hfr_hair *out) {
  memset(out, 0, sizeof *out);
  int n = sp->segments;
  int per = sp->children + 1, guides = sp->strands / per;
  if (guides < 1) guides = 1;
  hfr_hair g = {0};
  g.strands = (uint32_t)guides;
  g.points = (uint32_t)((uint64_t)guides * (n + 1));
  g.default_segments = (uint32_t)n;
  g.default_thickness = sp->thickness;
  g.default_transparency = 1 - sp->opacity;
  g.pos = malloc(sizeof(float) * 3 * g.points);
  g.thickness = malloc(sizeof(float) * g.points);
  g.transparency = malloc(sizeof(float) * g.points);
  if (!g.pos || !g.thickness || !g.transparency) {
    hfr_hair_free(&g);
    return HF_ENOMEM;
  }
  for (int s = 0; s < guides; s++) {
    hr_rng r = {sp->seed * 0x9e3779b97f4a7c15ull + (uint64_t)s * 0xd1b54a32d192ed03ull + 1};
    float *c = g.pos + 3 * (size_t)s * (n + 1);
    if (sp->style == HFR_STYLE_FUR) fur_guide(sp, &r, c, n);
    else spiky_guide(sp, &r, c, n);
    float opac = hr_strand_opacity(sp->opacity, hr_rng_range(&r, 0.9f, 1.0f));
    float w = hr_clump_width(sp, (uint64_t)s);
    for (int i = 0; i <= n; i++) {
      float t = (float)i / n;
      /* Spikes and fur taper to a fine tip. */
      g.thickness[(size_t)s * (n + 1) + i] = w * sp->thickness * (1 - 0.7f * t * t);
      g.transparency[(size_t)s * (n + 1) + i] = 1 - opac;
    }
  }
  hfr_children_params cp;
  hfr_children_defaults(&cp);
  cp.children = sp->children;
  cp.clumping = sp->clumping;
  cp.frizz = 0;                 /* hr_frizz, in model units, as every style */
  cp.length_jitter = 0.2f;
  cp.seed = sp->seed;
  int rc = hfr_hair_interpolate(&g, &cp, out);
  hfr_hair_free(&g);
  /* Children's roots are offset in the plane of nearby roots, a chord of
   * the curved skin: move each child radially, whole, so that its root is on
   * the skin. */
  const float *body = sp->style == HFR_STYLE_FUR ? fur_r : head_radii;
  size_t base = 0;
  for (uint32_t s = 0; rc == HF_OK && s < out->strands; s++) {
    uint32_t n1 = hfr_hair_strand_segments(out, s) + 1;
    float *c = out->pos + 3 * base, q = 0;
    for (int k = 0; k < 3; k++) q += (c[k] / body[k]) * (c[k] / body[k]);
    if (q > 1e-12f) {
      float f = 1 / sqrtf(q), delta[3] = {c[0] * (f - 1), c[1] * (f - 1), c[2] * (f - 1)};
      for (uint32_t i = 0; i < n1; i++)
        for (int k = 0; k < 3; k++) c[3 * i + k] += delta[k];
    }
    base += n1;
  }
  if (rc == HF_OK)
    snprintf(out->info, sizeof out->info, "hairfilter %s seed %llu", hfr_style_name(sp->style),
             (unsigned long long)sp->seed);
  return rc;
}
