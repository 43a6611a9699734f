/* Children interpolated from guide strands (hfrender.h, hfr_hair_interpolate).
 *
 * Grooms ship guides: a few thousand strands an artist shaped, which a DCC
 * tool (XGen, Houdini's hair generate, Blender's interpolated children)
 * grows into tens of thousands at render time. The same is done here:
 *   1. each guide's nearest other guide roots (a hashed uniform grid over
 *      the roots, searched in growing shells) give its local spacing and the
 *      neighbours it blends with;
 *   2. a child's root is offset from its guide's within spread x spacing, in
 *      the plane through its guide's and the two nearest roots (the surface
 *      they grow from), or across the guide's first segment where those
 *      are in a line;
 *   3. its shape (points minus root) is the inverse-distance blend of the
 *      guide's and its neighbours' shapes, each resampled at the same
 *      fraction of its arc length, pulled towards the guide's own shape
 *      (clumping, growing to the tip), cut a little shorter at random and
 *      given a smoothed random walk (frizz) growing to the tip.
 * Every child draws from its own stream (seed, guide, child), so a model is
 * the same for the same parameters. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hfrender.h"
#include "hr_math.h"

#define NEIGHBOURS 2

void hfr_children_defaults(hfr_children_params *p) {
  memset(p, 0, sizeof *p);
  p->keep_guides = 1;
  p->spread = 0.5f;
  p->clumping = 0.3f;
  p->frizz = 0.3f;
  p->length_jitter = 0.15f;
  p->seed = 1;
}

/* ---- nearest roots ------------------------------------------------------- */

typedef struct root_grid {
  float lo[3], cell;
  int64_t dims[3];
  uint32_t nbuckets;
  uint32_t *start;              /* [nbuckets + 1] */
  uint32_t *items;              /* root indices, bucketed */
} root_grid;

static uint32_t cell_hash(const root_grid *g, int64_t x, int64_t y, int64_t z) {
  uint64_t h = (uint64_t)x * 0x9e3779b97f4a7c15ull ^ (uint64_t)y * 0xc2b2ae3d27d4eb4full ^
               (uint64_t)z * 0x165667b19e3779f9ull;
  return (uint32_t)((h ^ (h >> 29)) % g->nbuckets);
}

static void cell_of(const root_grid *g, const float p[3], int64_t c[3]) {
  for (int k = 0; k < 3; k++) c[k] = (int64_t)floorf((p[k] - g->lo[k]) / g->cell);
}

static int grid_build(root_grid *g, const float *roots, uint32_t n) {
  float hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (int k = 0; k < 3; k++) g->lo[k] = INFINITY;
  for (uint32_t i = 0; i < n; i++)
    for (int k = 0; k < 3; k++) {
      g->lo[k] = fminf(g->lo[k], roots[3 * i + k]);
      hi[k] = fmaxf(hi[k], roots[3 * i + k]);
    }
  float diag = sqrtf((hi[0] - g->lo[0]) * (hi[0] - g->lo[0]) +
                     (hi[1] - g->lo[1]) * (hi[1] - g->lo[1]) +
                     (hi[2] - g->lo[2]) * (hi[2] - g->lo[2]));
  /* Roots lie on a surface: n of them on an area about diag^2 are about
   * diag / sqrt(n) apart; cells of twice that hold a few each. */
  g->cell = diag > 0 ? 2 * diag / sqrtf((float)n) : 1;
  for (int k = 0; k < 3; k++) g->dims[k] = (int64_t)((hi[k] - g->lo[k]) / g->cell) + 1;
  g->nbuckets = 2 * n + 1;
  g->start = calloc((size_t)g->nbuckets + 1, sizeof *g->start);
  g->items = malloc(sizeof *g->items * (size_t)n);
  uint32_t *key = malloc(sizeof *key * (size_t)n);
  if (!g->start || !g->items || !key) {
    free(key);
    return HF_ENOMEM;
  }
  for (uint32_t i = 0; i < n; i++) {
    int64_t c[3];
    cell_of(g, roots + 3 * i, c);
    key[i] = cell_hash(g, c[0], c[1], c[2]);
    g->start[key[i] + 1]++;
  }
  for (uint32_t b = 0; b < g->nbuckets; b++) g->start[b + 1] += g->start[b];
  uint32_t *fill = malloc(sizeof *fill * (size_t)g->nbuckets);
  if (!fill) {
    free(key);
    return HF_ENOMEM;
  }
  memcpy(fill, g->start, sizeof *fill * (size_t)g->nbuckets);
  for (uint32_t i = 0; i < n; i++) g->items[fill[key[i]]++] = i;
  free(fill);
  free(key);
  return HF_OK;
}

static void grid_free(root_grid *g) {
  free(g->start);
  free(g->items);
}

/* The NEIGHBOURS roots nearest to root self (other than itself, and apart
 * from it): nb[] and
 * their squared distances d2[] (INFINITY where there are fewer). Shells of
 * cells at growing Chebyshev distance r are searched until the last
 * neighbour found is nearer than any unsearched cell. */
static void grid_nearest(const root_grid *g, const float *roots, uint32_t self, uint32_t nb[],
                         float d2[]) {
  for (int k = 0; k < NEIGHBOURS; k++) nb[k] = self, d2[k] = INFINITY;
  int64_t c[3];
  const float *p = roots + 3 * (size_t)self;
  cell_of(g, p, c);
  int64_t rmax = g->dims[0];
  if (g->dims[1] > rmax) rmax = g->dims[1];
  if (g->dims[2] > rmax) rmax = g->dims[2];
  for (int64_t r = 0; r <= rmax; r++) {
    for (int64_t dx = -r; dx <= r; dx++)
      for (int64_t dy = -r; dy <= r; dy++)
        for (int64_t dz = -r; dz <= r; dz++) {
          if (llabs(dx) != r && llabs(dy) != r && llabs(dz) != r) continue; /* inside the shell */
          int64_t x = c[0] + dx, y = c[1] + dy, z = c[2] + dz;
          if (x < 0 || y < 0 || z < 0 || x >= g->dims[0] || y >= g->dims[1] || z >= g->dims[2])
            continue;
          uint32_t b = cell_hash(g, x, y, z);
          for (uint32_t i = g->start[b]; i < g->start[b + 1]; i++) {
            uint32_t q = g->items[i];
            if (q == self) continue;
            const float *o = roots + 3 * (size_t)q;
            /* Other cells share the bucket: check the cell. */
            int64_t oc[3];
            cell_of(g, o, oc);
            if (oc[0] != x || oc[1] != y || oc[2] != z) continue;
            float d[3] = {o[0] - p[0], o[1] - p[1], o[2] - p[2]}, dd = hr_dot(d, d);
            /* A root at the same point (a guide written twice) is no
             * neighbour: it spans no spacing (every child would sit on
             * its guide's root) and no surface. */
            if (dd == 0 || dd >= d2[NEIGHBOURS - 1]) continue;
            int k = NEIGHBOURS - 1;
            while (k > 0 && dd < d2[k - 1]) {
              d2[k] = d2[k - 1], nb[k] = nb[k - 1];
              k--;
            }
            d2[k] = dd, nb[k] = q;
          }
        }
    /* Every unsearched point is at least r * cell away. */
    float reach = (float)r * g->cell;
    if (d2[NEIGHBOURS - 1] <= reach * reach) break;
  }
}

/* ---- guides -------------------------------------------------------------- */

typedef struct guide {
  const float *p;               /* points, n + 1 */
  uint32_t n, first;            /* segments, index of its first point */
  float *cum;                   /* arc length at each point, cum[n] = length */
} guide;

/* Point at fraction t of g's length, relative to its root, into o; *seg
 * walks forward (t increases along a child). */
static void guide_at(const guide *g, float t, uint32_t *seg, float o[3]) {
  float L = g->cum[g->n], s = t * L;
  uint32_t i = *seg;
  while (i + 1 < g->n && g->cum[i + 1] < s) i++;
  *seg = i;
  float len = g->cum[i + 1] - g->cum[i];
  float f = len > 0 ? (s - g->cum[i]) / len : 0;
  f = fminf(fmaxf(f, 0), 1);
  for (int k = 0; k < 3; k++)
    o[k] = g->p[3 * i + k] + f * (g->p[3 * (i + 1) + k] - g->p[3 * i + k]) - g->p[k];
}

/* Per-point value of a guide's profile (thickness or transparency) at
 * fraction t, or def where the model has no array. */
static float profile_at(const float *arr, const guide *g, float t, float def) {
  if (!arr) return def;
  float x = t * g->n;
  uint32_t i = (uint32_t)x;
  if (i >= g->n) return arr[g->first + g->n];
  float f = x - i;
  return arr[g->first + i] * (1 - f) + arr[g->first + i + 1] * f;
}

int hfr_hair_interpolate(const hfr_hair *in, const hfr_children_params *p, hfr_hair *out) {
  if (!in || !p || !out || !in->pos || !in->strands) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  if (p->children < 0 || p->children > 10000 || (!p->children && !p->keep_guides) ||
      !(p->spread >= 0) || !(p->clumping >= 0 && p->clumping <= 1) || !(p->frizz >= 0) ||
      !(p->length_jitter >= 0 && p->length_jitter < 1) || !(p->width_spread >= 0) ||
      !isfinite(p->spread + p->frizz + p->width_spread))
    return HF_EINVAL;
  const uint32_t G = in->strands;
  const uint64_t per = (uint64_t)p->children + (p->keep_guides ? 1 : 0);
  uint64_t strands = (uint64_t)G * per, points = (uint64_t)in->points * per;
  if (strands > HFR_MAX_STRANDS || points > HFR_MAX_POINTS) return HF_ERANGE;

  guide *gd = calloc(G, sizeof *gd);
  float *roots = malloc(sizeof(float) * 3 * G);
  float *cum = malloc(sizeof(float) * in->points);
  if (!gd || !roots || !cum) {
    free(gd), free(roots), free(cum);
    return HF_ENOMEM;
  }
  uint64_t base = 0;
  for (uint32_t s = 0; s < G; s++) {
    guide *g = &gd[s];
    g->n = hfr_hair_strand_segments(in, s);
    g->first = (uint32_t)base;
    g->p = in->pos + 3 * base;
    g->cum = cum + base;
    g->cum[0] = 0;
    for (uint32_t i = 1; i <= g->n; i++) {
      float d[3] = {g->p[3 * i] - g->p[3 * i - 3], g->p[3 * i + 1] - g->p[3 * i - 2],
                    g->p[3 * i + 2] - g->p[3 * i - 1]};
      g->cum[i] = g->cum[i - 1] + hr_len(d);
    }
    memcpy(roots + 3 * s, g->p, 3 * sizeof(float));
    base += g->n + 1;
  }
  float centre[3], radius;
  hfr_hair_bounds(in, centre, &radius);
  const float def_thick = hfr_hair_default_thickness(in, radius, NULL);
  const float def_transp = hfr_hair_default_transparency(in, NULL);
  /* An all-zero thickness is no width (as in the renderer): the default's. */
  const float *in_thick = hfr_hair_thickness_all_zero(in) ? NULL : in->thickness;

  root_grid grid = {0};
  int rc = grid_build(&grid, roots, G);
  out->strands = (uint32_t)strands;
  out->points = (uint32_t)points;
  out->default_segments = in->default_segments;
  out->default_thickness = def_thick;
  out->thickness_given = in->thickness_given;
  out->default_transparency = def_transp;
  memcpy(out->default_color, in->default_color, sizeof out->default_color);
  memcpy(out->info, in->info, sizeof out->info);
  if (rc == HF_OK) {
    out->segments = malloc(sizeof(uint16_t) * (size_t)strands);
    out->pos = malloc(sizeof(float) * 3 * (size_t)points);
    out->thickness = malloc(sizeof(float) * (size_t)points);
    out->transparency = malloc(sizeof(float) * (size_t)points);
    if (!out->segments || !out->pos || !out->thickness || !out->transparency) rc = HF_ENOMEM;
  }
  uint64_t so = 0, po = 0;
  for (uint32_t s = 0; rc == HF_OK && s < G; s++) {
    const guide *g = &gd[s];
    uint32_t nb[NEIGHBOURS];
    float d2[NEIGHBOURS];
    grid_nearest(&grid, roots, s, nb, d2);
    /* Local spacing: the nearest other root; a lone guide takes a
     * fiftieth of its length. */
    float spacing = isfinite(d2[0]) ? sqrtf(d2[0]) : 0.02f * g->cum[g->n];
    hr_rng gr = {p->seed * 0x9e3779b97f4a7c15ull + (uint64_t)s * 0xbf58476d1ce4e5b9ull + 11};
    float width = 1;
    if (p->width_spread > 1) width = powf(p->width_spread, hr_rng_range(&gr, -1, 1));
    /* A basis of the surface the roots lie on: the plane through the
     * guide's and its two neighbours' roots, or, where they are (nearly) in
     * a line, the plane across the guide's first segment. */
    float d[3] = {g->p[3] - g->p[0], g->p[4] - g->p[1], g->p[5] - g->p[2]};
    if (hr_len(d) < 1e-20f) d[0] = 0, d[1] = 1, d[2] = 0;
    hr_normalize(d);
    if (isfinite(d2[1])) {
      const float *ra = roots + 3 * (size_t)nb[0], *rb = roots + 3 * (size_t)nb[1];
      float a[3] = {ra[0] - g->p[0], ra[1] - g->p[1], ra[2] - g->p[2]};
      float b[3] = {rb[0] - g->p[0], rb[1] - g->p[1], rb[2] - g->p[2]}, nrm[3];
      hr_cross(a, b, nrm);
      if (hr_len(nrm) > 0.2f * hr_len(a) * hr_len(b)) {
        hr_normalize(nrm);
        float sg = hr_dot(nrm, d) < 0 ? -1.0f : 1.0f;
        for (int k = 0; k < 3; k++) d[k] = sg * nrm[k];
      }
    }
    float e1[3], e2[3], ax[3] = {1, 0, 0};
    if (fabsf(d[0]) > 0.9f) ax[0] = 0, ax[1] = 1;
    hr_cross(d, ax, e1);
    hr_normalize(e1);
    hr_cross(d, e1, e2);
    for (uint64_t c = 0; c < per; c++) {
      int is_guide = p->keep_guides && c == 0;
      hr_rng r = {p->seed * 0xd1b54a32d192ed03ull + (uint64_t)s * 0x94d049bb133111ebull +
                  c * 0x2545f4914f6cdd1dull + 5};
      float off[3] = {0, 0, 0}, lambda = 1;
      if (!is_guide) {
        float rr = p->spread * spacing * sqrtf(hr_rng_uniform(&r));
        float th = 2 * HR_PI * hr_rng_uniform(&r);
        for (int k = 0; k < 3; k++) off[k] = rr * (cosf(th) * e1[k] + sinf(th) * e2[k]);
        lambda = 1 - p->length_jitter * hr_rng_uniform(&r);
      }
      float croot[3] = {g->p[0] + off[0], g->p[1] + off[1], g->p[2] + off[2]};
      /* Inverse-distance weights of the guide and its neighbours. */
      uint32_t ids[1 + NEIGHBOURS] = {s};
      float w[1 + NEIGHBOURS];
      int nw = 1;
      for (int k = 0; k < NEIGHBOURS; k++)
        if (isfinite(d2[k]) && !is_guide) ids[nw++] = nb[k];
      float wsum = 0;
      for (int k = 0; k < nw; k++) {
        const float *rk = roots + 3 * (size_t)ids[k];
        float dd[3] = {croot[0] - rk[0], croot[1] - rk[1], croot[2] - rk[2]};
        w[k] = 1 / (hr_len(dd) + 0.05f * spacing + 1e-30f);
        wsum += w[k];
      }
      uint32_t seg[1 + NEIGHBOURS] = {0};
      float walk[3] = {0, 0, 0};
      out->segments[so] = (uint16_t)g->n;
      for (uint32_t i = 0; i <= g->n; i++) {
        float t = lambda * (float)i / g->n, tn = (float)i / g->n;
        float *o = out->pos + 3 * (po + i);
        if (is_guide) {
          memcpy(o, g->p + 3 * i, 3 * sizeof(float));
        } else {
          float blend[3] = {0, 0, 0}, own[3];
          for (int k = 0; k < nw; k++) {
            float q[3];
            guide_at(&gd[ids[k]], t, &seg[k], q);
            if (k == 0) memcpy(own, q, sizeof own);
            for (int a = 0; a < 3; a++) blend[a] += w[k] / wsum * q[a];
          }
          /* Clumping: at the tip the child meets its guide's shape. */
          float kc = p->clumping * powf(tn, 0.7f);
          for (int a = 0; a < 3; a++) {
            walk[a] = 0.75f * walk[a] + 0.25f * hr_rng_normal(&r);
            float clumped = own[a] - off[a];
            o[a] = croot[a] + (1 - kc) * blend[a] + kc * clumped +
                   p->frizz * spacing * tn * sqrtf(tn) * walk[a] * 2;
          }
        }
        out->thickness[po + i] = width * profile_at(in_thick, g, t, def_thick);
        out->transparency[po + i] = profile_at(in->transparency, g, t, def_transp);
      }
      so++;
      po += g->n + 1;
    }
  }
  grid_free(&grid);
  free(gd), free(roots), free(cum);
  if (rc != HF_OK) hfr_hair_free(out);
  return rc;
}
