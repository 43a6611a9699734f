/* Platform choice for hr_context; the implementations live in
 * hr_context_osmesa.c and hr_context_egl.c. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"
#include "hr_context.h"

int hr_context_create(const char *platform, hr_context **out, char *why, size_t whylen) {
  if (!out) return HF_EINVAL;
  *out = NULL;
  if (!platform || !*platform) platform = getenv("HF_GL_PLATFORM");
  if (!platform || !*platform) platform = "auto";
  if (!strcmp(platform, "osmesa")) return hr_context_create_osmesa(out, why, whylen);
  if (!strcmp(platform, "egl")) return hr_context_create_egl(out, why, whylen);
  if (strcmp(platform, "auto")) {
    if (why) snprintf(why, whylen, "unknown GL platform '%s' (osmesa, egl, auto)", platform);
    return HF_EINVAL;
  }
  /* auto: OSMesa first. It always gives the same software rasteriser, so
   * renders (and the datasets built from them) are reproducible; EGL is the
   * fallback for builds or machines without OSMesa. Ask for "egl" to use a
   * GPU. */
  char why_osmesa[256] = "";
  int rc = hr_context_create_osmesa(out, why_osmesa, sizeof why_osmesa);
  if (rc == HF_OK) return rc;
  rc = hr_context_create_egl(out, why, whylen);
  if (rc != HF_OK && why) {
    char tmp[256];
    snprintf(tmp, sizeof tmp, "%s", why);
    snprintf(why, whylen, "osmesa: %s; egl: %s", why_osmesa, tmp);
  }
  return rc;
}

void hr_context_destroy(hr_context *ctx) {
  if (ctx) ctx->destroy(ctx);
}

int hr_context_make_current(hr_context *ctx) {
  return ctx ? ctx->make_current(ctx) : HF_EINVAL;
}

hr_proc hr_context_proc(hr_context *ctx, const char *name) {
  return ctx && name ? ctx->proc(ctx, name) : NULL;
}

const char *hr_context_platform(const hr_context *ctx) {
  return ctx ? ctx->platform : "none";
}
