/* GLSL program building and uniform setters. */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "hr_internal.h"

double hr_now_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static GLuint compile(GLenum type, const char *src, char *err, size_t errlen) {
  GLuint s = hrgl.CreateShader(type);
  if (!s) {
    if (err) snprintf(err, errlen, "glCreateShader failed");
    return 0;
  }
  hrgl.ShaderSource(s, 1, &src, NULL);
  hrgl.CompileShader(s);
  GLint ok = 0;
  hrgl.GetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[1024] = "";
    hrgl.GetShaderInfoLog(s, sizeof log, NULL, log);
    if (err) snprintf(err, errlen, "shader compile: %s", log);
    hrgl.DeleteShader(s);
    return 0;
  }
  return s;
}

int hr_program_build(hr_program *p, const char *vs, const char *gs, const char *fs, char *err,
                     size_t errlen) {
  p->id = 0;
  GLuint v = compile(GL_VERTEX_SHADER, vs, err, errlen);
  GLuint g = gs ? compile(GL_GEOMETRY_SHADER, gs, err, errlen) : 0;
  GLuint f = compile(GL_FRAGMENT_SHADER, fs, err, errlen);
  int rc = HF_EBACKEND;
  if (v && f && (!gs || g)) {
    GLuint prog = hrgl.CreateProgram();
    hrgl.AttachShader(prog, v);
    if (g) hrgl.AttachShader(prog, g);
    hrgl.AttachShader(prog, f);
    hrgl.LinkProgram(prog);
    GLint ok = 0;
    hrgl.GetProgramiv(prog, GL_LINK_STATUS, &ok);
    if (ok) {
      p->id = prog;
      rc = HF_OK;
    } else {
      char log[1024] = "";
      hrgl.GetProgramInfoLog(prog, sizeof log, NULL, log);
      if (err) snprintf(err, errlen, "program link: %s", log);
      hrgl.DeleteProgram(prog);
    }
  }
  if (v) hrgl.DeleteShader(v);
  if (g) hrgl.DeleteShader(g);
  if (f) hrgl.DeleteShader(f);
  return rc;
}

void hr_program_free(hr_program *p) {
  if (p->id) hrgl.DeleteProgram(p->id);
  p->id = 0;
}

/* The setters assume p is the bound program. */
void hr_set_i(const hr_program *p, const char *name, int v) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.Uniform1i(l, v);
}
void hr_set_u(const hr_program *p, const char *name, unsigned v) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.Uniform1ui(l, v);
}
void hr_set_f(const hr_program *p, const char *name, float v) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.Uniform1f(l, v);
}
void hr_set_2f(const hr_program *p, const char *name, float x, float y) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.Uniform2f(l, x, y);
}
void hr_set_2i(const hr_program *p, const char *name, int x, int y) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.Uniform2i(l, x, y);
}
void hr_set_3f(const hr_program *p, const char *name, const float v[3]) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.Uniform3fv(l, 1, v);
}
void hr_set_m4(const hr_program *p, const char *name, const float m[16]) {
  GLint l = hrgl.GetUniformLocation(p->id, name);
  if (l >= 0) hrgl.UniformMatrix4fv(l, 1, GL_FALSE, m);
}
