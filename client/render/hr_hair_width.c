/* Strand widths of a model: the diameter drawn where a model has no
 * per-point thickness, and whether the widths it carries are plausible for
 * its size.
 *
 * A .hair header always holds a thickness, and Cem Yuksel's reference
 * writer (cyHairFile) stores 1.0 there when its author set none. Taken at
 * its word, 1.0 is a centimetre-wide strand on a centimetre-scale head: every
 * sample gets alpha 1. So the header value is judged against the model's
 * bounding radius R, which says what scale the model is in, before it is
 * used. Human hair is 17-180 um on heads of 10-30 cm (1e-4 to 2e-3 R);
 * artist-made game and film assets use strands up to a few times thicker,
 * so widths up to HFR_WIDTH_MAX_REL R are accepted. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfrender.h"

/* The rule in double: the radius of a model near float's limits (and its
 * products with the limits below) does not fit a float. */
static double default_thickness(const hfr_hair *h, double radius, const char **why) {
  double t = h->default_thickness;
  const char *reason = NULL;
  if (!isfinite(t) || !(t > 0))
    reason = "no usable header thickness";
  else if (t == HFR_HAIR_UNSET_THICKNESS && t > radius * 1e-3)
    reason = "header thickness 1.0 is what the reference .hair writer stores when none was set";
  else if (t > radius * HFR_WIDTH_MAX_REL)
    reason = "header thickness wider than any plausible strand for the model's size";
  else if (t < radius * HFR_WIDTH_MIN_REL)
    reason = "header thickness narrower than any plausible strand for the model's size";
  if (why) *why = reason;
  return reason ? radius * HFR_WIDTH_FALLBACK_REL : t;
}

float hfr_hair_default_thickness(const hfr_hair *h, float radius, const char **why) {
  /* The user's diameter (--thickness) is drawn as given: judging it would
   * silently replace an explicit choice. */
  if (h->thickness_given) {
    if (why) *why = NULL;
    return h->default_thickness;
  }
  return (float)default_thickness(h, radius, why);
}

int hfr_hair_thickness_all_zero(const hfr_hair *h) {
  if (!h->thickness) return 0;
  for (uint32_t i = 0; i < h->points; i++)
    if (h->thickness[i] != 0) return 0;
  return 1;
}

int hfr_hair_check_widths(hfr_hair *h, char *warn, size_t warnlen) {
  if (warn && warnlen) warn[0] = 0;
  if (!h || !h->pos || !h->points) return 0;
  double centre[3], radius;
  hfr_hair_extent(h, centre, &radius);
  const double lo = radius * HFR_WIDTH_MIN_REL, hi = radius * HFR_WIDTH_MAX_REL;
  const char *zero = "";
  if (hfr_hair_thickness_all_zero(h)) {
    /* Zero everywhere is no width at all (a tool that wrote the array
     * without filling it), not a taper: nothing would be drawn. The header
     * rule below applies, as to a file without the array. */
    free(h->thickness);
    h->thickness = NULL;
    zero = "every point's thickness is 0 (nothing would be drawn), so the per-point "
           "thickness is ignored and the header's used: ";
  }
  if (h->thickness) {
    /* Per-point widths are the author's: kept, but said when implausible.
     * Zero is a legitimate tip taper, not a width. */
    uint64_t bad = 0;
    float wmin = INFINITY, wmax = 0;
    for (uint32_t i = 0; i < h->points; i++) {
      float t = h->thickness[i];
      if (t > 0 && t < wmin) wmin = t;
      if (t > wmax) wmax = t;
      if (t > hi || (t > 0 && t < lo)) bad++;
    }
    if (!bad) return 0;
    if (warn)
      snprintf(warn, warnlen,
               "%llu of %u points have a strand width outside %.3g..%.3g (%g..%g of the "
               "model's bounding radius %.4g); widths in the file: %.4g..%.4g. They are drawn "
               "as given: set --thickness (a diameter in the file's units) or "
               "--thickness-scale if that is wrong",
               (unsigned long long)bad, h->points, lo, hi, (double)HFR_WIDTH_MIN_REL,
               (double)HFR_WIDTH_MAX_REL, radius, isfinite(wmin) ? wmin : 0, wmax);
    return 1;
  }
  const char *why = NULL;
  float header = h->default_thickness;
  float t = h->thickness_given ? header : (float)default_thickness(h, radius, &why);
  if (!why) {
    if (!*zero) return 0;
    if (warn)
      snprintf(warn, warnlen, "%sstrands are drawn %.4g wide (the header thickness); set "
               "--thickness (a diameter in the file's units) to choose", zero, t);
    return 1;
  }
  h->default_thickness = t;
  if (warn)
    snprintf(warn, warnlen,
             "%s%s (%g, bounding radius %.4g): strands are drawn %.4g wide, 1/%d of the "
             "bounding radius; set --thickness (a diameter in the file's units) to choose",
             zero, why, header, radius, t, (int)lroundf(1.0f / HFR_WIDTH_FALLBACK_REL));
  return 1;
}

float hfr_hair_default_transparency(const hfr_hair *h, const char **why) {
  float t = h->default_transparency;
  const char *reason = NULL;
  if (!isfinite(t))
    reason = "header transparency not finite";
  else if (t < 0 || t > 1)
    reason = "header transparency outside [0, 1]";
  if (why) *why = reason;
  return reason ? HFR_HAIR_FALLBACK_TRANSPARENCY : t;
}

int hfr_hair_check_transparency(hfr_hair *h, char *warn, size_t warnlen) {
  if (warn && warnlen) warn[0] = 0;
  if (!h || !h->points) return 0;
  if (h->transparency) {
    /* The loader keeps per-point values in [0, 1]; all of them 1 is a
     * model nothing draws, which a user would otherwise see as a bug. */
    for (uint32_t i = 0; i < h->points; i++)
      if (h->transparency[i] < 1) return 0;
    if (warn)
      snprintf(warn, warnlen, "every point's transparency is 1 (fully transparent): nothing "
               "is drawn; set --opacity to draw the strands");
    return 1;
  }
  const char *why = NULL;
  float header = h->default_transparency;
  float t = hfr_hair_default_transparency(h, &why);
  if (why) {
    h->default_transparency = t;
    if (warn)
      snprintf(warn, warnlen, "%s (%g) and no per-point transparency: strands are drawn with "
               "transparency %g (opaque, what the reference .hair writer stores when none is "
               "set); set --opacity to choose", why, header, t);
    return 1;
  }
  if (t == 1) {
    if (warn)
      snprintf(warn, warnlen, "header transparency 1 (fully transparent) and no per-point "
               "transparency: nothing is drawn; set --opacity to draw the strands");
    return 1;
  }
  return 0;
}
