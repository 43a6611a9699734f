/* Procedural hairstyles on the ellipsoid head of hfrender.h.
 *
 * Every style is built in four steps, each strand from its own seeded
 * stream so that its root and base curve do not depend on how many others
 * there are (its clump guide does):
 *   1. a root on the scalp (the part of the ellipsoid above a hairline that
 *      is high at the forehead and low at the nape);
 *   2. a base curve grown segment by segment: the direction starts along
 *      the scalp normal and bends under a style-specific gravity; points
 *      that enter the head (grown by a per-strand layer offset, which gives
 *      the hair volume) are pushed back out radially;
 *   3. a style offset in the strand's moving frame: a planar wave (wavy), a
 *      helix (curly, coily), ramped in from the root so roots stay put;
 *   4. clumping towards the nearest of a few guide strands, growing towards
 *      the tip, then frizz (a smoothed random walk growing to the tip) and a
 *      last push out of the head.
 * The ponytail's base curve runs over the scalp to a tie point at the back
 * of the head and hangs from there; the braided style's is combed flat into
 * a three-strand plait (hr_hair_braid.c), and a strand clumps only towards
 * guides of its own section of the scalp (its bundle of the plait). Spiky
 * and fur are grown from guides (hr_hair_guides.c), then frizzed the same
 * way.
 *
 * width_spread gives each clump (the strands that follow one guide) its own
 * diameter factor, so that a frame holds strand groups of different widths
 * as real grooms do. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "hfrender.h"
#include "hr_math.h"
#include "hr_style.h"

static const char *const style_names[HFR_STYLE_COUNT] = {
    "straight", "wavy", "curly", "coily", "ponytail", "spiky", "fur", "braided"};

const char *hfr_style_name(hfr_style s) {
  return (unsigned)s < HFR_STYLE_COUNT ? style_names[s] : "unknown";
}

int hfr_style_from_name(const char *name, hfr_style *out) {
  if (!name || !out) return HF_EINVAL;
  for (int i = 0; i < HFR_STYLE_COUNT; i++)
    if (!strcasecmp(name, style_names[i])) {
      *out = (hfr_style)i;
      return HF_OK;
    }
  if (!strcasecmp(name, "afro")) {
    *out = HFR_STYLE_COILY;
    return HF_OK;
  }
  if (!strcasecmp(name, "long-tied")) {
    *out = HFR_STYLE_PONYTAIL;
    return HF_OK;
  }
  if (!strcasecmp(name, "braids") || !strcasecmp(name, "plaits")) {
    *out = HFR_STYLE_BRAIDED;
    return HF_OK;
  }
  return HF_ENOTFOUND;
}

void hfr_style_list(char *out, size_t n) {
  if (!out || !n) return;
  *out = 0;
  for (int k = 0; k < HFR_STYLE_COUNT; k++) {
    size_t used = strlen(out);
    if (used + 1 >= n) return;
    snprintf(out + used, n - used, "%s%s", k ? ", " : "", style_names[k]);
  }
}

int hfr_style_has_tie(hfr_style s) { return s == HFR_STYLE_PONYTAIL || s == HFR_STYLE_BRAIDED; }

int hfr_style_defaults(hfr_style s, hfr_style_params *p) {
  if (!p || (unsigned)s >= HFR_STYLE_COUNT) return HF_EINVAL;
  memset(p, 0, sizeof *p);
  p->style = s;
  p->seed = 1;
  p->strands = 50000;
  p->thickness = 0.0008f;   /* ~80 um on a 10 cm head radius */
  p->opacity = 0.8f;
  p->clumping = 0.25f;
  p->frizz = 0.01f;
  switch (s) {
  case HFR_STYLE_STRAIGHT:
    p->segments = 24, p->length = 2.2f;
    break;
  case HFR_STYLE_WAVY:
    p->segments = 40, p->length = 2.4f, p->curl_radius = 0.07f, p->curl_period = 0.55f;
    break;
  case HFR_STYLE_CURLY:
    p->segments = 64, p->length = 2.0f, p->curl_radius = 0.08f, p->curl_period = 0.28f;
    p->clumping = 0.4f, p->frizz = 0.02f;
    break;
  case HFR_STYLE_COILY:
    p->segments = 64, p->length = 1.0f, p->curl_radius = 0.035f, p->curl_period = 0.09f;
    p->clumping = 0.15f, p->frizz = 0.04f;
    break;
  case HFR_STYLE_PONYTAIL:
    p->segments = 40, p->length = 3.2f, p->curl_radius = 0.03f, p->curl_period = 0.8f;
    p->clumping = 0.2f;
    break;
  case HFR_STYLE_SPIKY:
    /* Guides 4-5 cm long; gelled: children meet their guide at the tip. */
    p->segments = 12, p->length = 0.45f, p->clumping = 0.8f, p->frizz = 0.004f;
    p->children = 15;
    p->thickness = 0.0009f;
    break;
  case HFR_STYLE_FUR:
    /* 2 cm fur, dense: 60 000 strands cover a torso. */
    p->strands = 60000;
    p->segments = 8, p->length = 0.2f, p->clumping = 0.3f, p->frizz = 0.003f;
    p->children = 15;
    p->thickness = 0.0018f;   /* artist fur: thick enough to cover the body */
    p->opacity = 0.85f;
    break;
  case HFR_STYLE_BRAIDED:
    /* curl_radius: how far a bundle swings to each side of the plait's
     * centre; curl_period: the plait's length over which each bundle
     * crosses the other two (about 13 segments of it here). */
    p->segments = 96, p->length = 3.0f, p->curl_radius = 0.11f, p->curl_period = 0.45f;
    p->clumping = 0.3f, p->frizz = 0.004f;
    break;
  default:
    return HF_EINVAL;
  }
  return HF_OK;
}

static const float head_r[3] = HFR_HEAD_RADII;

/* A uniformly distributed point of the scalp and its outward normal. */
void hr_scalp_root(hr_rng *g, float p[3], float n[3]) {
  for (;;) {
    float d[3] = {hr_rng_normal(g), hr_rng_normal(g), hr_rng_normal(g)};
    if (hr_len(d) < 1e-6f) continue;
    hr_normalize(d);
    /* Hairline: 0.55 above the equator at the forehead, 0 at the ears,
     * -0.55 at the nape. */
    if (d[1] < 0.55f * d[2]) continue;
    for (int k = 0; k < 3; k++) {
      p[k] = head_r[k] * d[k];
      n[k] = d[k] / head_r[k];
    }
    hr_normalize(n);
    return;
  }
}

void hr_push_out_of(const float radii[3], float p[3], float shell) {
  float q = 0;
  for (int k = 0; k < 3; k++) {
    float t = p[k] / (radii[k] * (1 + shell));
    q += t * t;
  }
  if (q < 1 && q > 1e-12f) {
    float s = 1 / sqrtf(q);
    for (int k = 0; k < 3; k++) p[k] *= s;
  }
}

/* Pushes p radially out of the head grown by (1 + shell). */
static void push_out(float p[3], float shell) { hr_push_out_of(head_r, p, shell); }

/* Step 2: the base curve of one strand, n + 1 points into c; for the tied
 * styles, its tie into tie: the point's index, then the point. */
static void grow_base(const hfr_style_params *sp, hr_rng *g, const float root[3],
                      const float nrm[3], float len, float shell, float *c,
                      hr_tie *tie_record) {
  int n = sp->segments;
  float seg = len / n;
  float dir[3] = {nrm[0], nrm[1], nrm[2]};
  float gravity = 1.6f, comb = 0.0f;
  switch (sp->style) {
  case HFR_STYLE_COILY: gravity = 0.15f; break;
  case HFR_STYLE_CURLY: gravity = 1.0f, comb = 0.2f; break;
  default: comb = 0.3f; break;
  }
  /* Combing: start slightly backwards/down rather than straight out. */
  dir[1] -= comb * 0.5f;
  dir[2] -= comb;
  hr_normalize(dir);
  memcpy(c, root, 3 * sizeof(float));

  if (sp->style == HFR_STYLE_BRAIDED) {
    hr_grow_braided(sp, g, root, len, shell, c, tie_record);
    return;
  }
  if (sp->style == HFR_STYLE_PONYTAIL) {
    /* Over the scalp to the tie, then down. The tie, at the back, is a disc
     * the strands pass through at random points, 2 cm across at gather 0
     * and shrinking to one point at gather 1 (every strand through one
     * pixel: a tight elastic seen from afar, the deepest fragment lists
     * hair gives). */
    const float loose = 1 - sp->gather;
    float tr = 0.1f * loose * sqrtf(hr_rng_uniform(g)), ta = 2 * HR_PI * hr_rng_uniform(g);
    const float tie[3] = {tr * cosf(ta), 0.35f + tr * sinf(ta), -1.0f};
    float dt[3] = {tie[0] - root[0], tie[1] - root[1], tie[2] - root[2]};
    float dist = hr_len(dt) * 1.15f;
    int n1 = (int)(n * dist / len);
    if (n1 < 2) n1 = 2;
    if (n1 > n - 4) n1 = n - 4;
    for (int i = 1; i <= n1; i++) {
      float t = (float)i / n1;
      float *p = c + 3 * i;
      for (int k = 0; k < 3; k++) p[k] = root[k] + (tie[k] - root[k]) * t;
      /* Bulge over the scalp, tightening into the tie. */
      push_out(p, shell * (1 - t) + 0.01f);
    }
    if (tie_record) {
      tie_record->index = n1;
      memcpy(tie_record->point, c + 3 * n1, sizeof tie_record->point);
    }
    /* Tail: strands keep an offset from the tie that shrinks near it. */
    float off[3] = {hr_rng_normal(g) * 0.08f, hr_rng_normal(g) * 0.08f,
                    hr_rng_normal(g) * 0.05f};
    float tdir[3] = {0, -0.35f, -1};
    hr_normalize(tdir);
    float tseg = (len - dist) / (n - n1);
    if (tseg < seg * 0.5f) tseg = seg * 0.5f;
    float p[3] = {tie[0], tie[1], tie[2]};
    for (int i = n1 + 1; i <= n; i++) {
      float t = (float)(i - n1) / (n - n1);
      tdir[1] -= 1.2f * tseg;
      hr_normalize(tdir);
      for (int k = 0; k < 3; k++) p[k] += tdir[k] * tseg;
      float spread = 0.3f * loose + (1.7f + 0.3f * sp->gather) * t;
      for (int k = 0; k < 3; k++) c[3 * i + k] = p[k] + off[k] * spread;
      push_out(c + 3 * i, 0.02f);
    }
    return;
  }

  float p[3] = {root[0], root[1], root[2]};
  for (int i = 1; i <= n; i++) {
    dir[1] -= gravity * seg;
    hr_normalize(dir);
    float prev[3] = {p[0], p[1], p[2]};
    for (int k = 0; k < 3; k++) p[k] += dir[k] * seg;
    push_out(p, shell * fminf(1.0f, 4.0f * i / n));
    for (int k = 0; k < 3; k++) dir[k] = p[k] - prev[k];
    hr_normalize(dir);
    memcpy(c + 3 * i, p, sizeof p);
  }
}

/* Step 3: wave or helix around the base curve. */
static void add_curl(const hfr_style_params *sp, hr_rng *g, const float nrm[3], float *c) {
  int n = sp->segments;
  int helix = sp->style == HFR_STYLE_CURLY || sp->style == HFR_STYLE_COILY;
  int wave = sp->style == HFR_STYLE_WAVY || sp->style == HFR_STYLE_PONYTAIL;
  if ((!helix && !wave) || sp->curl_radius <= 0 || sp->curl_period <= 0) return;
  float amp = sp->curl_radius * hr_rng_range(g, 0.8f, 1.2f);
  float period = sp->curl_period * hr_rng_range(g, 0.85f, 1.15f);
  float phase = hr_rng_range(g, 0, 2 * HR_PI);
  float *base = malloc(sizeof(float) * 3 * (n + 1));
  if (!base) return; /* the strand stays straight */
  memcpy(base, c, sizeof(float) * 3 * (n + 1));
  float u[3] = {nrm[0], nrm[1], nrm[2]}, s = 0;
  for (int i = 1; i <= n; i++) {
    float t[3] = {base[3 * i] - base[3 * i - 3], base[3 * i + 1] - base[3 * i - 2],
                  base[3 * i + 2] - base[3 * i - 1]};
    s += hr_len(t);
    hr_normalize(t);
    /* Transport u: keep it perpendicular to the tangent. */
    float d = hr_dot(u, t);
    for (int k = 0; k < 3; k++) u[k] -= d * t[k];
    if (hr_len(u) < 1e-4f) {
      float alt[3] = {1, 0, 0};
      hr_cross(t, alt, u);
    }
    hr_normalize(u);
    float b[3];
    hr_cross(t, u, b);
    float ramp = fminf(1.0f, s / (2.0f * period + 0.05f));
    float th = 2 * HR_PI * s / period + phase;
    for (int k = 0; k < 3; k++) {
      float o = helix ? u[k] * cosf(th) + b[k] * sinf(th) : b[k] * sinf(th);
      c[3 * i + k] = base[3 * i + k] + ramp * amp * o;
    }
  }
  free(base);
}

float hr_strand_opacity(float style_opacity, float jitter) {
  return style_opacity >= 1 ? 1 : style_opacity * jitter;
}

/* A clump's diameter factor: spread^u, u uniform in [-1, 1], from the clump's
 * own stream. */
float hr_clump_width(const hfr_style_params *sp, uint64_t clump) {
  if (!(sp->width_spread > 1)) return 1;
  hr_rng g = {sp->seed * 0x94d049bb133111ebull + clump * 0x9e3779b97f4a7c15ull + 13};
  return powf(sp->width_spread, hr_rng_range(&g, -1, 1));
}

/* Frizz (a smoothed random walk growing to the tip) of every strand, each
 * from its own stream, then a last push out of the body. */
void hr_frizz(const hfr_style_params *sp, const float body[3], hfr_hair *h) {
  size_t base = 0;
  for (uint32_t s = 0; s < h->strands; s++) {
    uint32_t n = hfr_hair_strand_segments(h, s);
    hr_rng g = {sp->seed * 0x2545f4914f6cdd1dull + (uint64_t)s * 0x9e3779b97f4a7c15ull + 7};
    float *c = h->pos + 3 * base;
    float walk[3] = {0, 0, 0};
    for (uint32_t i = 1; i <= n; i++) {
      float t = (float)i / n;
      for (int k = 0; k < 3; k++) {
        walk[k] = 0.75f * walk[k] + 0.25f * hr_rng_normal(&g);
        c[3 * i + k] += sp->frizz * t * sqrtf(t) * walk[k] * 2.0f;
      }
      hr_push_out_of(body, c + 3 * i, 0.005f);
    }
    base += n + 1;
  }
}

/* The gather of the tied styles, last: curl, clumping and frizz moved each
 * strand off its tie, and an elastic holds the strands wherever they would
 * go. Each strand is drawn back to its tie point by gather at the tie,
 * less over a few segments on either side (a smooth bump), so that at
 * gather 1 every strand passes through its tie point exactly. */
static void gather_ties(const hfr_style_params *sp, const hr_tie *ties, hfr_hair *h) {
  const int n = sp->segments;
  const float reach = fmaxf(3.0f, n / 12.0f);
  for (uint32_t s = 0; s < h->strands; s++) {
    float *c = h->pos + 3 * (size_t)s * (n + 1);
    const hr_tie *t = ties + s;
    for (int i = 0; i <= n; i++) {
      float d = fabsf((float)(i - t->index)) / reach;
      if (d >= 1) continue;
      float w = sp->gather * (1 - d * d * (3 - 2 * d));
      for (int k = 0; k < 3; k++) c[3 * i + k] += w * (t->point[k] - c[3 * i + k]);
    }
  }
}

/* One failed range for hfr_style_check's message. */
static int style_range(char *err, size_t errlen, const char *name, double v, const char *range) {
  if (err && errlen) snprintf(err, errlen, "%s %g is outside %s", name, v, range);
  return HF_EINVAL;
}

int hfr_style_check(const hfr_style_params *sp, char *err, size_t errlen) {
  if (err && errlen) *err = 0;
  if (!sp) return HF_EINVAL;
  if ((unsigned)sp->style >= HFR_STYLE_COUNT) return style_range(err, errlen, "style", sp->style, "the styles");
  if (sp->segments < 8 || sp->segments > 1024)
    return style_range(err, errlen, "segments", sp->segments, "8..1024");
  if (!(sp->length > 0)) return style_range(err, errlen, "length", sp->length, "(0, inf)");
  if (!(sp->thickness > 0)) return style_range(err, errlen, "thickness", sp->thickness, "(0, inf)");
  if (!(sp->opacity > 0 && sp->opacity <= 1))
    return style_range(err, errlen, "opacity", sp->opacity, "(0, 1]");
  if (!(sp->clumping >= 0 && sp->clumping <= 1))
    return style_range(err, errlen, "clumping", sp->clumping, "[0, 1]");
  if (!(sp->frizz >= 0)) return style_range(err, errlen, "frizz", sp->frizz, "[0, inf)");
  if (!(sp->curl_radius >= 0))
    return style_range(err, errlen, "curl-radius", sp->curl_radius, "[0, inf)");
  if (!(sp->curl_period >= 0))
    return style_range(err, errlen, "curl-period", sp->curl_period, "[0, inf)");
  if (!(sp->width_spread >= 0 && sp->width_spread <= 100))
    return style_range(err, errlen, "width-spread", sp->width_spread, "[0, 100]");
  if (sp->children < 0 || sp->children > 10000)
    return style_range(err, errlen, "children", sp->children, "0..10000");
  /* Only the styles grown from guides have children to grow; elsewhere the
   * count would be dropped without a word. */
  if (sp->children > 0 && sp->style != HFR_STYLE_SPIKY && sp->style != HFR_STYLE_FUR) {
    if (err && errlen)
      snprintf(err, errlen, "children %d: the %s style draws every strand itself; children "
               "grow on the guides of spiky and fur only", sp->children, hfr_style_name(sp->style));
    return HF_EINVAL;
  }
  if (!(sp->gather >= 0 && sp->gather <= 1))
    return style_range(err, errlen, "gather", sp->gather, "[0, 1]");
  /* Only the styles with a tie gather their strands; elsewhere the value
   * would be dropped without a word. */
  if (sp->gather > 0 && !hfr_style_has_tie(sp->style)) {
    if (err && errlen)
      snprintf(err, errlen, "gather %g: the %s style has no tie; gather applies to ponytail "
               "and braided only", sp->gather, hfr_style_name(sp->style));
    return HF_EINVAL;
  }
  if (sp->strands < 1 || (uint64_t)sp->strands > HFR_MAX_STRANDS) {
    if (err && errlen)
      snprintf(err, errlen, "strands %d is outside 1..%u", sp->strands, HFR_MAX_STRANDS);
    return sp->strands < 1 ? HF_EINVAL : HF_ERANGE;
  }
  uint64_t points = (uint64_t)sp->strands * (sp->segments + 1);
  if (points > HFR_MAX_POINTS) {
    if (err && errlen)
      snprintf(err, errlen, "%d strands of %d segments are %llu points, more than %u: fewer "
               "strands or segments", sp->strands, sp->segments, (unsigned long long)points,
               HFR_MAX_POINTS);
    return HF_ERANGE;
  }
  return HF_OK;
}

int hfr_hair_generate(const hfr_style_params *sp, hfr_hair *out) {
  if (!sp || !out) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  int rc = hfr_style_check(sp, NULL, 0);
  if (rc != HF_OK) return rc;
  uint64_t points = (uint64_t)sp->strands * (sp->segments + 1);
  if (sp->style == HFR_STYLE_SPIKY || sp->style == HFR_STYLE_FUR) {
    rc = hr_generate_from_guides(sp, out);
    if (rc != HF_OK) return rc;
    hfr_ellipsoid body;
    hfr_style_body(sp->style, &body);
    const float r[3] = {body.radii[0] / 0.99f, body.radii[1] / 0.99f, body.radii[2] / 0.99f};
    hr_frizz(sp, r, out);
    return HF_OK;
  }
  int n = sp->segments;
  out->strands = (uint32_t)sp->strands;
  out->points = (uint32_t)points;
  out->default_segments = (uint32_t)n;
  out->default_thickness = sp->thickness;
  out->default_transparency = 1 - sp->opacity;
  out->pos = malloc(sizeof(float) * 3 * points);
  out->thickness = malloc(sizeof(float) * points);
  out->transparency = malloc(sizeof(float) * points);
  float *roots = malloc(sizeof(float) * 3 * (size_t)sp->strands);
  /* Where each strand is tied, for the gather after clumping and frizz. */
  const int tied = sp->gather > 0 && hfr_style_has_tie(sp->style);
  hr_tie *ties = tied ? malloc(sizeof *ties * (size_t)sp->strands) : NULL;
  if (!out->pos || !out->thickness || !out->transparency || !roots || (tied && !ties)) {
    free(roots);
    free(ties);
    hfr_hair_free(out);
    return HF_ENOMEM;
  }
  snprintf(out->info, sizeof out->info, "hairfilter %s seed %llu", hfr_style_name(sp->style),
           (unsigned long long)sp->seed);

  for (int s = 0; s < sp->strands; s++) {
    hr_rng g = {sp->seed * 0x9e3779b97f4a7c15ull + (uint64_t)s * 0xd1b54a32d192ed03ull + 1};
    float nrm[3];
    float *c = out->pos + 3 * (size_t)s * (n + 1);
    hr_scalp_root(&g, roots + 3 * s, nrm);
    float len = sp->length * hr_rng_range(&g, 0.85f, 1.1f);
    /* The layer offset that gives the hair its volume; combed flat for a
     * plait. */
    float shell = sp->style == HFR_STYLE_BRAIDED
                      ? hr_rng_range(&g, 0.003f, 0.02f)
                      : hr_rng_range(&g, 0.01f, sp->style == HFR_STYLE_COILY ? 0.05f : 0.12f);
    grow_base(sp, &g, roots + 3 * s, nrm, len, shell, c, ties ? ties + s : NULL);
    add_curl(sp, &g, nrm, c);
    float opac = hr_strand_opacity(sp->opacity, hr_rng_range(&g, 0.9f, 1.0f));
    for (int i = 0; i <= n; i++) {
      float t = (float)i / n;
      /* Strands taper towards the tip. */
      out->thickness[(size_t)s * (n + 1) + i] = sp->thickness * (1 - 0.5f * t * t);
      out->transparency[(size_t)s * (n + 1) + i] = 1 - opac;
    }
  }

  /* Step 4: clumps. Guides are the first strands (their roots are random
   * anyway); each strand follows the guide whose root is nearest. */
  int guides = sp->strands / 80;
  if (guides < 1) guides = 1;
  if (guides > 2000) guides = 2000;
  int widths = sp->width_spread > 1;
  if ((sp->clumping > 0 || widths) && sp->strands > guides) {
    size_t one = sizeof(float) * 3 * (n + 1);
    float *gcopy = malloc(one * guides);
    if (!gcopy) {
      free(roots);
      free(ties);
      hfr_hair_free(out);
      return HF_ENOMEM;
    }
    memcpy(gcopy, out->pos, one * guides);
    /* A plait's strand stays in its bundle: the guides' sections, once. */
    const int braided = sp->style == HFR_STYLE_BRAIDED;
    const int plaits = braided ? hr_braid_plaits(sp) : 0;
    unsigned char gsec[2000]; /* guides <= 2000 above */
    for (int q = 0; q < guides && braided; q++)
      gsec[q] = (unsigned char)hr_braid_section(plaits, roots + 3 * q);
    for (int s = 0; s < sp->strands; s++) {
      const float *r = roots + 3 * s;
      int best = s;
      const int sec = braided ? hr_braid_section(plaits, r) : 0;
      if (s >= guides) {
        float bd = INFINITY;
        for (int q = 0; q < guides; q++) {
          const float *rq = roots + 3 * q;
          if (braided && gsec[q] != sec) continue;
          float d[3] = {r[0] - rq[0], r[1] - rq[1], r[2] - rq[2]};
          float dd = hr_dot(d, d);
          if (dd < bd) bd = dd, best = q;
        }
      }
      if (widths) {
        float f = hr_clump_width(sp, (uint64_t)best);
        for (int i = 0; i <= n; i++) out->thickness[(size_t)s * (n + 1) + i] *= f;
      }
      /* best == s past the guides: no guide of its section (a plait's strand
       * then follows none). */
      if (s < guides || best == s || !(sp->clumping > 0)) continue;
      const float *gp = gcopy + 3 * (size_t)best * (n + 1);
      float *c = out->pos + 3 * (size_t)s * (n + 1);
      for (int i = 1; i <= n; i++) {
        float t = (float)i / n, w = sp->clumping * powf(t, 0.7f);
        for (int k = 0; k < 3; k++) {
          float target = gp[3 * i + k] + (r[k] - roots[3 * best + k]) * (1 - t);
          c[3 * i + k] += w * (target - c[3 * i + k]);
        }
      }
    }
    free(gcopy);
  }
  free(roots);
  hr_frizz(sp, head_r, out);
  if (ties) gather_ties(sp, ties, out);
  free(ties);
  return HF_OK;
}
