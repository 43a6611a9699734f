/* hr_context on OSMesa: a core 4.5 context bound to a 1x1 colour buffer that
 * is never drawn to (everything renders into FBOs). */
#include <stdio.h>
#include <stdlib.h>

#include <GL/osmesa.h>

#include "hfcore.h"
#include "hr_context.h"

typedef struct {
  OSMesaContext ctx;
  unsigned char buffer[4 * 4];
} osmesa_impl;

static int osmesa_make_current(hr_context *c) {
  osmesa_impl *m = c->impl;
  return OSMesaMakeCurrent(m->ctx, m->buffer, GL_UNSIGNED_BYTE, 1, 1) ? HF_OK : HF_EBACKEND;
}

static hr_proc osmesa_proc(hr_context *c, const char *name) {
  (void)c;
  return (hr_proc)OSMesaGetProcAddress(name);
}

static void osmesa_destroy(hr_context *c) {
  osmesa_impl *m = c->impl;
  OSMesaMakeCurrent(NULL, NULL, 0, 0, 0);
  OSMesaDestroyContext(m->ctx);
  free(m);
  free(c);
}

int hr_context_create_osmesa(hr_context **out, char *why, size_t whylen) {
  *out = NULL;
  const int attribs[] = {
    OSMESA_FORMAT, OSMESA_RGBA,
    OSMESA_DEPTH_BITS, 0,
    OSMESA_PROFILE, OSMESA_CORE_PROFILE,
    OSMESA_CONTEXT_MAJOR_VERSION, 4,
    OSMESA_CONTEXT_MINOR_VERSION, 5,
    0,
  };
  hr_context *c = calloc(1, sizeof *c);
  osmesa_impl *m = calloc(1, sizeof *m);
  if (!c || !m) {
    free(c);
    free(m);
    return HF_ENOMEM;
  }
  m->ctx = OSMesaCreateContextAttribs(attribs, NULL);
  if (!m->ctx) {
    if (why) snprintf(why, whylen, "OSMesaCreateContextAttribs(core 4.5) failed");
    free(c);
    free(m);
    return HF_EUNAVAILABLE;
  }
  c->platform = "osmesa";
  c->impl = m;
  c->make_current = osmesa_make_current;
  c->proc = osmesa_proc;
  c->destroy = osmesa_destroy;
  if (osmesa_make_current(c) != HF_OK) {
    if (why) snprintf(why, whylen, "OSMesaMakeCurrent failed");
    osmesa_destroy(c);
    return HF_EUNAVAILABLE;
  }
  *out = c;
  return HF_OK;
}
