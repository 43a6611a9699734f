/* Entry point loading for hr_gl.h. */
#include <stdio.h>
#include <string.h>

#include "hfcore.h"
#include "hr_gl.h"

hr_gl_table hrgl;

int hr_gl_load(hr_context *ctx, hr_gl_table *out, char *why, size_t whylen) {
  hr_gl_table t;
  memset(&t, 0, sizeof t);
#define HR_GL_LOAD(type, name)                                                 \
  t.name = (type)hr_context_proc(ctx, "gl" #name);                             \
  if (!t.name) {                                                               \
    if (why) snprintf(why, whylen, "GL entry point gl%s missing", #name);      \
    return HF_EUNAVAILABLE;                                                    \
  }
  HR_GL_FUNCS(HR_GL_LOAD)
#undef HR_GL_LOAD
  GLint major = 0, minor = 0;
  t.GetIntegerv(GL_MAJOR_VERSION, &major);
  t.GetIntegerv(GL_MINOR_VERSION, &minor);
  if (major * 10 + minor < 45) {
    if (why) snprintf(why, whylen, "OpenGL %d.%d, need 4.5 core", major, minor);
    return HF_EUNAVAILABLE;
  }
  *out = t;
  hrgl = t;
  return HF_OK;
}

int hr_gl_check(const char *where, char *why, size_t whylen) {
  GLenum first = GL_NO_ERROR, e;
  while ((e = hrgl.GetError()) != GL_NO_ERROR)
    if (first == GL_NO_ERROR) first = e;
  if (first == GL_NO_ERROR) return HF_OK;
  if (why) snprintf(why, whylen, "GL error 0x%04x in %s", (unsigned)first, where);
  return HF_EBACKEND;
}
