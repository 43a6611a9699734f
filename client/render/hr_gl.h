/* hr_gl: the OpenGL 4.5 core entry points the renderer uses, loaded through
 * the context's GetProcAddress (OSMesa and EGL both need that for some of
 * them). Call them as hrgl.Name(...). */
#ifndef HR_GL_H
#define HR_GL_H

#include <GL/glcorearb.h>

#include "hr_context.h"

#define HR_GL_FUNCS(X)                                                        \
  X(PFNGLGETERRORPROC, GetError)                                              \
  X(PFNGLGETSTRINGPROC, GetString)                                            \
  X(PFNGLGETINTEGERVPROC, GetIntegerv)                                        \
  X(PFNGLGETMULTISAMPLEFVPROC, GetMultisamplefv)                              \
  X(PFNGLENABLEPROC, Enable)                                                  \
  X(PFNGLDISABLEPROC, Disable)                                                \
  X(PFNGLBLENDFUNCPROC, BlendFunc)                                            \
  X(PFNGLBLENDFUNCSEPARATEPROC, BlendFuncSeparate)                            \
  X(PFNGLVIEWPORTPROC, Viewport)                                              \
  X(PFNGLSCISSORPROC, Scissor)                                                \
  X(PFNGLDEPTHFUNCPROC, DepthFunc)                                            \
  X(PFNGLDEPTHMASKPROC, DepthMask)                                            \
  X(PFNGLCOLORMASKPROC, ColorMask)                                            \
  X(PFNGLFINISHPROC, Finish)                                                  \
  X(PFNGLREADPIXELSPROC, ReadPixels)                                          \
  X(PFNGLBLITFRAMEBUFFERPROC, BlitFramebuffer)                                \
  X(PFNGLREADBUFFERPROC, ReadBuffer)                                          \
  X(PFNGLPIXELSTOREIPROC, PixelStorei)                                        \
  X(PFNGLDRAWBUFFERSPROC, DrawBuffers)                                        \
  X(PFNGLCLEARBUFFERFVPROC, ClearBufferfv)                                    \
  X(PFNGLGENTEXTURESPROC, GenTextures)                                        \
  X(PFNGLDELETETEXTURESPROC, DeleteTextures)                                  \
  X(PFNGLBINDTEXTUREPROC, BindTexture)                                        \
  X(PFNGLACTIVETEXTUREPROC, ActiveTexture)                                    \
  X(PFNGLTEXPARAMETERIPROC, TexParameteri)                                    \
  X(PFNGLTEXSTORAGE2DPROC, TexStorage2D)                                      \
  X(PFNGLTEXSTORAGE2DMULTISAMPLEPROC, TexStorage2DMultisample)                \
  X(PFNGLGENFRAMEBUFFERSPROC, GenFramebuffers)                                \
  X(PFNGLDELETEFRAMEBUFFERSPROC, DeleteFramebuffers)                          \
  X(PFNGLBINDFRAMEBUFFERPROC, BindFramebuffer)                                \
  X(PFNGLFRAMEBUFFERTEXTURE2DPROC, FramebufferTexture2D)                      \
  X(PFNGLCHECKFRAMEBUFFERSTATUSPROC, CheckFramebufferStatus)                  \
  X(PFNGLGENBUFFERSPROC, GenBuffers)                                          \
  X(PFNGLDELETEBUFFERSPROC, DeleteBuffers)                                    \
  X(PFNGLBINDBUFFERPROC, BindBuffer)                                          \
  X(PFNGLBINDBUFFERBASEPROC, BindBufferBase)                                  \
  X(PFNGLBUFFERDATAPROC, BufferData)                                          \
  X(PFNGLGETBUFFERSUBDATAPROC, GetBufferSubData)                              \
  X(PFNGLMAPBUFFERRANGEPROC, MapBufferRange)                                  \
  X(PFNGLUNMAPBUFFERPROC, UnmapBuffer)                                        \
  X(PFNGLCLEARBUFFERDATAPROC, ClearBufferData)                                \
  X(PFNGLGENVERTEXARRAYSPROC, GenVertexArrays)                                \
  X(PFNGLDELETEVERTEXARRAYSPROC, DeleteVertexArrays)                          \
  X(PFNGLBINDVERTEXARRAYPROC, BindVertexArray)                                \
  X(PFNGLVERTEXATTRIBPOINTERPROC, VertexAttribPointer)                        \
  X(PFNGLENABLEVERTEXATTRIBARRAYPROC, EnableVertexAttribArray)                \
  X(PFNGLDRAWARRAYSPROC, DrawArrays)                                          \
  X(PFNGLDRAWARRAYSINSTANCEDPROC, DrawArraysInstanced)                        \
  X(PFNGLDRAWARRAYSINSTANCEDBASEINSTANCEPROC, DrawArraysInstancedBaseInstance) \
  X(PFNGLVERTEXATTRIBDIVISORPROC, VertexAttribDivisor)                        \
  X(PFNGLMEMORYBARRIERPROC, MemoryBarrier)                                    \
  X(PFNGLCREATESHADERPROC, CreateShader)                                      \
  X(PFNGLSHADERSOURCEPROC, ShaderSource)                                      \
  X(PFNGLCOMPILESHADERPROC, CompileShader)                                    \
  X(PFNGLGETSHADERIVPROC, GetShaderiv)                                        \
  X(PFNGLGETSHADERINFOLOGPROC, GetShaderInfoLog)                              \
  X(PFNGLDELETESHADERPROC, DeleteShader)                                      \
  X(PFNGLCREATEPROGRAMPROC, CreateProgram)                                    \
  X(PFNGLATTACHSHADERPROC, AttachShader)                                      \
  X(PFNGLLINKPROGRAMPROC, LinkProgram)                                        \
  X(PFNGLGETPROGRAMIVPROC, GetProgramiv)                                      \
  X(PFNGLGETPROGRAMINFOLOGPROC, GetProgramInfoLog)                            \
  X(PFNGLDELETEPROGRAMPROC, DeleteProgram)                                    \
  X(PFNGLUSEPROGRAMPROC, UseProgram)                                          \
  X(PFNGLGETUNIFORMLOCATIONPROC, GetUniformLocation)                          \
  X(PFNGLUNIFORM1IPROC, Uniform1i)                                            \
  X(PFNGLUNIFORM1UIPROC, Uniform1ui)                                          \
  X(PFNGLUNIFORM1FPROC, Uniform1f)                                            \
  X(PFNGLUNIFORM2FPROC, Uniform2f)                                            \
  X(PFNGLUNIFORM2IPROC, Uniform2i)                                            \
  X(PFNGLUNIFORM3FVPROC, Uniform3fv)                                          \
  X(PFNGLUNIFORMMATRIX4FVPROC, UniformMatrix4fv)

typedef struct hr_gl_table {
#define HR_GL_FIELD(type, name) type name;
  HR_GL_FUNCS(HR_GL_FIELD)
#undef HR_GL_FIELD
} hr_gl_table;

/* The table of the current context: each renderer keeps its own (OSMesa
 * and EGL hand out different pointers) and installs it here when it makes
 * its context current (hr_renderer_bind). */
extern hr_gl_table hrgl;

/* Loads every entry point of the current context ctx into *out and hrgl;
 * on a missing one returns HF_EUNAVAILABLE and its name in why. Also checks
 * the context is at least 4.5 core. */
int hr_gl_load(hr_context *ctx, hr_gl_table *out, char *why, size_t whylen);

/* Drains the GL error queue; returns HF_EBACKEND (and the first error and
 * where in why, when given) if there was one. */
int hr_gl_check(const char *where, char *why, size_t whylen);

#endif
