/* hr_context: a current OpenGL 4.5 core context with no window.
 *
 * The renderer draws only into its own framebuffer objects, so all it needs
 * from the platform is a current context and a way to look up entry points.
 * Two implementations: OSMesa (software, llvmpipe; always built) and EGL
 * (surfaceless or device platform, which is how the same code runs on a GPU
 * machine; built when EGL is found). */
#ifndef HR_CONTEXT_H
#define HR_CONTEXT_H

#include <stddef.h>

typedef struct hr_context hr_context;
typedef void (*hr_proc)(void);

/* platform: "osmesa", "egl" or "auto" (EGL when built and working, else
 * OSMesa) or NULL (= "auto", or $HF_GL_PLATFORM when set). On failure
 * returns a negative HF_E* code and a one-line reason in why. */
int hr_context_create(const char *platform, hr_context **out, char *why, size_t whylen);
void hr_context_destroy(hr_context *ctx);
/* Makes the context current on the calling thread. */
int hr_context_make_current(hr_context *ctx);
/* Entry point by name, NULL when absent. */
hr_proc hr_context_proc(hr_context *ctx, const char *name);
/* "osmesa" or "egl". */
const char *hr_context_platform(const hr_context *ctx);

/* Per-platform constructors behind hr_context_create. */
int hr_context_create_osmesa(hr_context **out, char *why, size_t whylen);
int hr_context_create_egl(hr_context **out, char *why, size_t whylen);

/* The shared shape of both implementations. */
struct hr_context {
  const char *platform;
  void *impl;
  int (*make_current)(hr_context *ctx);
  hr_proc (*proc)(hr_context *ctx, const char *name);
  void (*destroy)(hr_context *ctx);
};

#endif
