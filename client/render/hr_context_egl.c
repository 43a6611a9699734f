/* hr_context on EGL without a surface: the device platform when the driver
 * enumerates devices (a GPU machine), else Mesa's surfaceless platform. Built
 * only when EGL is found (HR_HAVE_EGL); otherwise the constructor reports
 * that EGL is not part of this build. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"
#include "hr_context.h"

#ifdef HR_HAVE_EGL
#include <EGL/egl.h>
#include <EGL/eglext.h>

typedef struct {
  EGLDisplay dpy;
  EGLContext ctx;
} egl_impl;

static int egl_make_current(hr_context *c) {
  egl_impl *e = c->impl;
  return eglMakeCurrent(e->dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, e->ctx) ? HF_OK : HF_EBACKEND;
}

static hr_proc egl_proc(hr_context *c, const char *name) {
  (void)c;
  return (hr_proc)eglGetProcAddress(name);
}

static void egl_destroy(hr_context *c) {
  egl_impl *e = c->impl;
  if (e->dpy != EGL_NO_DISPLAY) {
    eglMakeCurrent(e->dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    if (e->ctx != EGL_NO_CONTEXT) eglDestroyContext(e->dpy, e->ctx);
    /* No eglTerminate: the platform hands every renderer the same display,
     * and terminating it would pull the contexts of the others. */
  }
  free(e);
  free(c);
}

/* The first display that initialises: an enumerated device, then the
 * surfaceless platform. */
static EGLDisplay egl_open_display(char *why, size_t whylen) {
  PFNEGLGETPLATFORMDISPLAYEXTPROC get_display =
      (PFNEGLGETPLATFORMDISPLAYEXTPROC)eglGetProcAddress("eglGetPlatformDisplayEXT");
  PFNEGLQUERYDEVICESEXTPROC query_devices =
      (PFNEGLQUERYDEVICESEXTPROC)eglGetProcAddress("eglQueryDevicesEXT");
  if (!get_display) {
    if (why) snprintf(why, whylen, "eglGetPlatformDisplayEXT missing");
    return EGL_NO_DISPLAY;
  }
  if (query_devices) {
    EGLDeviceEXT devices[8];
    EGLint n = 0;
    if (query_devices(8, devices, &n)) {
      for (EGLint i = 0; i < n; i++) {
        EGLDisplay d = get_display(EGL_PLATFORM_DEVICE_EXT, devices[i], NULL);
        if (d != EGL_NO_DISPLAY && eglInitialize(d, NULL, NULL)) return d;
      }
    }
  }
  EGLDisplay d = get_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, NULL);
  if (d != EGL_NO_DISPLAY && eglInitialize(d, NULL, NULL)) return d;
  if (why) snprintf(why, whylen, "no EGL device or surfaceless display initialised (0x%x)",
                    (unsigned)eglGetError());
  return EGL_NO_DISPLAY;
}

int hr_context_create_egl(hr_context **out, char *why, size_t whylen) {
  *out = NULL;
  hr_context *c = calloc(1, sizeof *c);
  egl_impl *e = calloc(1, sizeof *e);
  if (!c || !e) {
    free(c);
    free(e);
    return HF_ENOMEM;
  }
  e->dpy = EGL_NO_DISPLAY;
  e->ctx = EGL_NO_CONTEXT;
  c->platform = "egl";
  c->impl = e;
  c->make_current = egl_make_current;
  c->proc = egl_proc;
  c->destroy = egl_destroy;

  e->dpy = egl_open_display(why, whylen);
  if (e->dpy == EGL_NO_DISPLAY) {
    egl_destroy(c);
    return HF_EUNAVAILABLE;
  }
  const char *ext = eglQueryString(e->dpy, EGL_EXTENSIONS);
  if (!ext || !strstr(ext, "EGL_KHR_surfaceless_context")) {
    if (why) snprintf(why, whylen, "EGL_KHR_surfaceless_context missing");
    egl_destroy(c);
    return HF_EUNAVAILABLE;
  }
  if (!eglBindAPI(EGL_OPENGL_API)) {
    if (why) snprintf(why, whylen, "eglBindAPI(EGL_OPENGL_API) failed");
    egl_destroy(c);
    return HF_EUNAVAILABLE;
  }
  const EGLint cfg_attr[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE,
                             EGL_OPENGL_BIT, EGL_NONE};
  EGLConfig cfg = NULL;
  EGLint ncfg = 0;
  /* No config is needed with EGL_KHR_no_config_context; ask for one anyway
   * and fall back to none. */
  if (!eglChooseConfig(e->dpy, cfg_attr, &cfg, 1, &ncfg) || ncfg < 1) cfg = NULL;
  const EGLint ctx_attr[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 5,
                             EGL_CONTEXT_OPENGL_PROFILE_MASK,
                             EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
  e->ctx = eglCreateContext(e->dpy, cfg, EGL_NO_CONTEXT, ctx_attr);
  if (e->ctx == EGL_NO_CONTEXT) {
    if (why) snprintf(why, whylen, "eglCreateContext(core 4.5) failed (0x%x)",
                      (unsigned)eglGetError());
    egl_destroy(c);
    return HF_EUNAVAILABLE;
  }
  if (egl_make_current(c) != HF_OK) {
    if (why) snprintf(why, whylen, "eglMakeCurrent without surface failed");
    egl_destroy(c);
    return HF_EUNAVAILABLE;
  }
  *out = c;
  return HF_OK;
}

#else /* !HR_HAVE_EGL */

int hr_context_create_egl(hr_context **out, char *why, size_t whylen) {
  *out = NULL;
  if (why) snprintf(why, whylen, "EGL was not found when this build was configured");
  return HF_EUNSUPPORTED;
}

#endif
