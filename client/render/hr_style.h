/* Internals shared by the style generators (hr_hair_gen.c, hr_hair_guides.c). */
#ifndef HR_STYLE_H
#define HR_STYLE_H

#include "hfrender.h"
#include "hr_math.h"

/* A uniformly distributed point of the scalp (HFR_HEAD_RADII above the
 * hairline) and its outward normal. */
void hr_scalp_root(hr_rng *g, float p[3], float n[3]);
/* Pushes p radially out of the ellipsoid of these semi-axes at the origin
 * grown by (1 + shell). */
void hr_push_out_of(const float radii[3], float p[3], float shell);
/* Diameter factor of clump (guide) number clump: sp->width_spread^u. */
float hr_clump_width(const hfr_style_params *sp, uint64_t clump);
/* A strand's opacity: the style's times its own factor jitter (drawn in
 * [0.9, 1] by the caller, whatever the opacity, so the stream is the same),
 * except that a style opacity of 1 gives opaque strands, as assets without
 * transparency have. */
float hr_strand_opacity(float style_opacity, float jitter);
/* Frizz of every strand of h, then a push out of the body (semi-axes). */
void hr_frizz(const hfr_style_params *sp, const float body[3], hfr_hair *h);
/* Where a strand of a tied style (ponytail, braided) is tied: the index of
 * its point there, and where that point is before clumping and frizz. */
typedef struct hr_tie {
  int index;
  float point[3];
} hr_tie;
/* Braided (hr_hair_braid.c): how many plaits the model has (1 or 2, from
 * its seed), and which section of the scalp a root belongs to in a model
 * of that many plaits (the plait and bundle its strand is plaited into;
 * 0..2 for one plait, 0..5 for two). */
int hr_braid_plaits(const hfr_style_params *sp);
int hr_braid_section(int plaits, const float root[3]);
/* Braided: the n + 1 points of one strand into c (n = sp->segments),
 * combed from root over the scalp at layer offset shell into its plait,
 * then plaited; length len. Where it joins the plait into tie (may be
 * NULL). */
void hr_grow_braided(const hfr_style_params *sp, hr_rng *g, const float root[3], float len,
                     float shell, float *c, hr_tie *tie);
/* Spiky and fur: guides, then hfr_hair_interpolate (no frizz yet). */
int hr_generate_from_guides(const hfr_style_params *sp, hfr_hair *out);

#endif
