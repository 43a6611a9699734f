/* Conventions of loaded models: which axis is up and what a unit is.
 * Assets come z-up (Blender, 3ds Max, Unreal) or y-up (Maya, Houdini, USD
 * by default), in metres or centimetres; the renderer wants y up, the front
 * towards +z and about 10 cm per unit, the frame its procedural styles and
 * view randomisation are made for. */
#include <math.h>
#include <string.h>
#include <strings.h>

#include "hfrender.h"

static const char *const axis_names[HFR_AXIS_COUNT] = {"y", "z", "x", "-y", "-z", "-x"};

const char *hfr_axis_name(hfr_axis a) {
  return (unsigned)a < HFR_AXIS_COUNT ? axis_names[a] : "unknown";
}

int hfr_axis_from_name(const char *name, hfr_axis *out) {
  if (!name || !out) return HF_EINVAL;
  if (name[0] == '+') name++;
  for (int i = 0; i < HFR_AXIS_COUNT; i++)
    if (!strcasecmp(name, axis_names[i])) {
      *out = (hfr_axis)i;
      return HF_OK;
    }
  return HF_ENOTFOUND;
}

int hfr_units_scale(const char *name, float *scale) {
  static const struct { const char *name; float scale; } units[] = {
    {"", 1}, {"units", 1}, {"dm", 1}, {"m", 10}, {"cm", 0.1f}, {"mm", 0.01f},
    {"in", 0.254f}, {"inch", 0.254f}, {"ft", 3.048f}, {"foot", 3.048f},
  };
  if (!name || !scale) return HF_EINVAL;
  for (size_t i = 0; i < sizeof units / sizeof units[0]; i++)
    if (!strcasecmp(name, units[i].name)) {
      *scale = units[i].scale;
      return HF_OK;
    }
  return HF_ENOTFOUND;
}

/* p in place: the rotation of hfr_hair_orient's docstring, then scale. */
static void orient_point(float *p, hfr_axis up, float scale) {
  float x = p[0], y = p[1], z = p[2];
  switch (up) {
  case HFR_AXIS_Z: p[0] = x, p[1] = z, p[2] = -y; break;
  case HFR_AXIS_X: p[0] = -y, p[1] = x, p[2] = z; break;
  case HFR_AXIS_NEG_Y: p[0] = x, p[1] = -y, p[2] = -z; break;
  case HFR_AXIS_NEG_Z: p[0] = x, p[1] = -z, p[2] = y; break;
  case HFR_AXIS_NEG_X: p[0] = y, p[1] = -x, p[2] = z; break;
  default: break;
  }
  for (int k = 0; k < 3; k++) p[k] *= scale;
}

int hfr_hair_orient(hfr_hair *h, hfr_axis up, float scale) {
  if (!h || !h->pos || (unsigned)up >= HFR_AXIS_COUNT || !isfinite(scale) || !(scale > 0))
    return HF_EINVAL;
  for (uint32_t i = 0; i < h->points; i++) orient_point(h->pos + 3 * (size_t)i, up, scale);
  if (h->thickness)
    for (uint32_t i = 0; i < h->points; i++) h->thickness[i] *= scale;
  h->default_thickness *= scale;
  return HF_OK;
}

void hr_orient_points(float *p, size_t n, size_t stride, hfr_axis up, float scale) {
  for (size_t i = 0; i < n; i++) orient_point(p + i * stride, up, scale);
}
