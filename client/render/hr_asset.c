/* Loaded models as they come (hfrender.h, hfr_asset_load): a .hair file in
 * its own conventions, with guides rather than every strand, and nothing
 * for the hair to grow on. The order matters: widths are judged in the
 * file's units (the reference writer's unset 1.0 must be seen before any
 * scaling), the occluder is fitted on the guides' roots (children are
 * offset from them), and children are grown last, in the renderer's
 * frame. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "hfrender.h"

void hfr_asset_defaults(hfr_asset_opts *o) {
  memset(o, 0, sizeof *o);
  o->up = HFR_AXIS_Y;
  o->scale = 1;
  hfr_children_defaults(&o->children);
  o->children.children = 0;
}

int hfr_asset_fitted(const hfr_asset_opts *o) {
  return !o->occluder || !*o->occluder || !strcasecmp(o->occluder, "fit") ||
         !strcasecmp(o->occluder, "auto");
}

/* Appends one warning to warn, "; " between warnings. */
static void add_warning(char *warn, size_t warnlen, const char *msg) {
  if (!warn || !warnlen) return;
  size_t used = strlen(warn);
  if (used + 1 < warnlen) snprintf(warn + used, warnlen - used, "%s%s", used ? "; " : "", msg);
}

int hfr_asset_load(const char *path, const hfr_asset_opts *o, hfr_hair *hair, hfr_mesh *occ,
                   char *warn, size_t warnlen, char *err, size_t errlen) {
  if (!path || !o || !hair || !occ) return HF_EINVAL;
  memset(occ, 0, sizeof *occ);
  if (warn && warnlen) warn[0] = 0;
  float scale = o->scale > 0 ? o->scale : 1;
  if (!(o->opacity >= 0 && o->opacity <= 1)) {
    if (err) snprintf(err, errlen, "opacity %g is outside (0, 1]", o->opacity);
    return HF_EINVAL;
  }
  int rc = hfr_hair_load(path, hair, err, errlen);
  if (rc != HF_OK) return rc;
  /* Before anything is judged against the model's size: a size float
   * cannot draw has no plausible widths either. */
  if ((rc = hfr_hair_check_extent(hair, scale, err, errlen)) != HF_OK) goto fail;
  char msg[512];
  if (o->opacity > 0) {
    /* The user's opacity, for every strand. */
    free(hair->transparency);
    hair->transparency = NULL;
    hair->default_transparency = 1 - o->opacity;
  } else if (hfr_hair_check_transparency(hair, msg, sizeof msg)) {
    add_warning(warn, warnlen, msg);
  }
  if (o->thickness > 0) {
    /* The user's diameter, for every strand, drawn as given (not judged
     * against the model's size like the file's): said when implausible. */
    free(hair->thickness);
    hair->thickness = NULL;
    hair->default_thickness = o->thickness;
    hair->thickness_given = 1;
    double c[3], r;
    hfr_hair_extent(hair, c, &r);
    if (o->thickness > r * HFR_WIDTH_MAX_REL || o->thickness < r * HFR_WIDTH_MIN_REL) {
      snprintf(msg, sizeof msg, "--thickness %g is %s than any plausible strand for the "
               "model's size (bounding radius %.4g, plausible %.3g..%.3g in the file's "
               "units); drawn as given", o->thickness,
               o->thickness > r * HFR_WIDTH_MAX_REL ? "wider" : "narrower", r,
               r * HFR_WIDTH_MIN_REL, r * HFR_WIDTH_MAX_REL);
      add_warning(warn, warnlen, msg);
    }
  } else if (hfr_hair_check_widths(hair, msg, sizeof msg)) {
    add_warning(warn, warnlen, msg);
  }
  if (hair->dropped) {
    snprintf(msg, sizeof msg, "%u strand(s) of a single point (0 segments) left out: nothing "
             "draws them", hair->dropped);
    add_warning(warn, warnlen, msg);
  }
  if (hair->dropped_nonfinite) {
    snprintf(msg, sizeof msg, "%u strand(s) with a NaN or Inf point coordinate, thickness or "
             "transparency left out (the file is damaged or its writer has a fault)",
             hair->dropped_nonfinite);
    add_warning(warn, warnlen, msg);
  }
  if (hair->clamped) {
    snprintf(msg, sizeof msg, "%llu per-point value(s) out of range clamped: a thickness "
             "below 0 taken as 0, a transparency outside [0, 1] to it",
             (unsigned long long)hair->clamped);
    add_warning(warn, warnlen, msg);
  }
  if (hair->unknown_flags) {
    snprintf(msg, sizeof msg, "header flag bits 0x%x are not the format's (segments, points, "
             "thickness, transparency, colours: 0x1f) and are ignored, as other .hair readers "
             "do", hair->unknown_flags);
    add_warning(warn, warnlen, msg);
  }
  if (hair->trailing_bytes) {
    snprintf(msg, sizeof msg, "%llu byte(s) after the arrays the header announces are "
             "ignored, as other .hair readers do (if the model looks incomplete, the header's "
             "strand and point counts are wrong)", (unsigned long long)hair->trailing_bytes);
    add_warning(warn, warnlen, msg);
  }
  if ((rc = hfr_hair_orient(hair, o->up, scale)) != HF_OK) {
    if (err) snprintf(err, errlen, "bad up axis or scale");
    goto fail;
  }
  const char *kind = o->occluder;
  if (hfr_asset_fitted(o)) {
    hfr_ellipsoid e;
    int fit = hair->strands >= 4 ? hfr_ellipsoid_fit_roots(hair, &e) : HF_EINVAL;
    if (fit == HF_OK) {
      rc = hfr_mesh_ellipsoid(&e, 64, 32, occ);
    } else if (fit == HF_ENOMEM) {
      rc = fit;
    } else {
      /* Nothing to fit: said, since the background layer stays empty and
       * strands behind the model show through where a body would be. */
      snprintf(msg, sizeof msg, "no occluder fitted under the roots (%s): the hair is drawn "
               "with nothing under it; give --occluder MESH, or --occluder none to say so",
               hair->strands < 4 ? "fewer than 4 strands" : "the roots are all at one point");
      add_warning(warn, warnlen, msg);
    }
  } else if (strcasecmp(kind, "none")) {
    rc = hfr_mesh_load(kind, occ, err, errlen);
    if (rc == HF_OK) rc = hfr_mesh_orient(occ, o->up, scale);
  }
  if (rc != HF_OK) {
    if (err && !*err) snprintf(err, errlen, "occluder: %s", hf_strerror(rc));
    goto fail;
  }
  if (o->children.children > 0) {
    hfr_hair grown;
    rc = hfr_hair_interpolate(hair, &o->children, &grown);
    if (rc != HF_OK) {
      if (err)
        snprintf(err, errlen, "children: %s (%u guides x %d children)", hf_strerror(rc),
                 hair->strands, o->children.children);
      goto fail;
    }
    hfr_hair_free(hair);
    *hair = grown;
  }
  return HF_OK;
fail:
  hfr_hair_free(hair);
  hfr_mesh_free(occ);
  return rc;
}
