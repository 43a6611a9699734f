/* The GL passes: stochastic shadow map, 4x MSAA feature pass with its
 * resolve, and the supersampled A-buffer with its resolve. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hr_internal.h"
#include "hr_math.h"
#include "hr_shaders.h"

#define ABUF_MIN_NODES (1u << 20)
#define NODE_WORDS 5
/* Mean fragments per supersampled pixel from which a window drawn again
 * (its A-buffer too small) is drawn behind the transmittance cull
 * (hr_gt_cull.c): its three passes cost about one more draw of the hair. */
#define GT_CULL_DEPTH 8
/* Mean fragments per supersampled pixel, estimated before the first draw
 * (hr_hair_window_fragments), from which a window is drawn behind the cull
 * from the start: far above GT_CULL_DEPTH, since the estimate leaves out
 * the occluder and a frame of ordinary density loses the cull's passes. */
#define GT_CULL_PRIOR 64

GLuint hr_make_tex(GLenum target, GLenum fmt, int w, int h, int samples) {
  GLuint t = 0;
  hrgl.GenTextures(1, &t);
  hrgl.BindTexture(target, t);
  if (target == GL_TEXTURE_2D_MULTISAMPLE) {
    hrgl.TexStorage2DMultisample(target, samples, fmt, w, h, GL_TRUE);
  } else {
    hrgl.TexStorage2D(target, 1, fmt, w, h);
    hrgl.TexParameteri(target, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    hrgl.TexParameteri(target, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  }
  return t;
}

/* r's texture of slot (HR_TEX_*): the one kept from the pass before when
 * it has this format, size and sample count, else a new one (the old one
 * deleted). Its contents are those of the pass before: each pass clears
 * the window it draws (the scissor of hr_set_viewport) and reads nothing
 * else. */
static GLuint frame_tex(hfr_renderer *r, int slot, GLenum fmt, int w, int h, int samples) {
  hr_frame_tex *t = &r->frame_tex[slot];
  if (t->id && t->fmt == fmt && t->w == w && t->h == h && t->samples == samples) return t->id;
  if (t->id) hrgl.DeleteTextures(1, &t->id);
  t->id = hr_make_tex(samples ? GL_TEXTURE_2D_MULTISAMPLE : GL_TEXTURE_2D, fmt, w, h, samples);
  t->fmt = fmt, t->w = w, t->h = h, t->samples = samples;
  return t->id;
}

void hr_frame_tex_release(hfr_renderer *r) {
  for (int k = 0; k < HR_TEX_SLOTS; k++)
    if (r->frame_tex[k].id) hrgl.DeleteTextures(1, &r->frame_tex[k].id);
  memset(r->frame_tex, 0, sizeof r->frame_tex);
}

int hr_fbo_complete(const char *what, char *err, size_t errlen) {
  GLenum st = hrgl.CheckFramebufferStatus(GL_FRAMEBUFFER);
  if (st == GL_FRAMEBUFFER_COMPLETE) return HF_OK;
  if (err) snprintf(err, errlen, "%s framebuffer incomplete (0x%04x)", what, (unsigned)st);
  return HF_EBACKEND;
}

/* Draws the full-viewport triangle over a w x h target: a 2w x 2h viewport
 * when the implementation allows it (see hr_glsl_fullscreen_vs), else a
 * w x h viewport with the usual clipped triangle. */
void hr_draw_fullscreen(hfr_renderer *r, const hr_program *p, int w, int h) {
  GLint maxvp[2] = {0, 0};
  hrgl.GetIntegerv(GL_MAX_VIEWPORT_DIMS, maxvp);
  int grow = !(2 * w <= maxvp[0] && 2 * h <= maxvp[1]);
  hr_set_i(p, "u_grow", grow);
  if (grow) hrgl.Viewport(0, 0, w, h);
  else hrgl.Viewport(0, 0, 2 * w, 2 * h);
  hrgl.BindVertexArray(r->empty_vao);
  hrgl.DrawArrays(GL_TRIANGLES, 0, 3);
}

/* jx, jy: the pass's sub-pixel offset in pixels. */
void hr_set_geometry(const hr_program *p, const hr_camera *cam, const hfr_view *v,
                         float jx, float jy) {
  hr_set_m4(p, "u_view", cam->view);
  hr_set_m4(p, "u_proj", cam->proj);
  hr_set_2f(p, "u_viewport", (float)cam->frame_w, (float)cam->frame_h);
  hr_set_2f(p, "u_jitter", 2 * jx / cam->frame_w, 2 * jy / cam->frame_h);
  hr_set_f(p, "u_px_per_unit", cam->px_per_unit);
  hr_set_i(p, "u_ortho", cam->ortho);
  hr_set_f(p, "u_thick_scale", v->thickness_scale);
  hr_set_f(p, "u_depth_near", cam->depth_near);
  hr_set_f(p, "u_depth_far", cam->depth_far);
}

static void draw_head(hfr_renderer *r, const hr_camera *cam, const hfr_view *v, float jx,
                      float jy, int linear_depth) {
  if (!r->has_head) return;
  hrgl.UseProgram(r->head.id);
  hr_set_geometry(&r->head, cam, v, jx, jy);
  hr_set_i(&r->head, "u_linear_depth", linear_depth);
  hrgl.BindVertexArray(r->head_vao);
  hrgl.DrawArrays(GL_TRIANGLES, 0, r->head_vertices);
}

/* One instance per pair of consecutive points; the vertex shader expands
 * each into a quad max(1, strand width) pixels wide and culls pairs that
 * span two strands. */
static void draw_hair(hfr_renderer *r) {
  hrgl.BindVertexArray(r->hair_vao);
  hrgl.DrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, (GLsizei)(r->points - 1));
}

/* draw_hair for cam's window: when it is smaller than the frame, only the
 * instances that can reach it, in order (hr_hair_window_runs), which gives
 * the window the same fragments in the same order. */
void hr_draw_hair_window(hfr_renderer *r, const hr_camera *cam, const hfr_view *v) {
  size_t n = 0;
  if ((cam->win_w == cam->frame_w && cam->win_h == cam->frame_h) ||
      hr_hair_window_runs(r, cam, v->thickness_scale, &n) != HF_OK) {
    draw_hair(r);
    return;
  }
  hrgl.BindVertexArray(r->hair_vao);
  for (size_t k = 0; k < n; k++)
    hrgl.DrawArraysInstancedBaseInstance(GL_TRIANGLE_STRIP, 0, 4, (GLsizei)r->runs[k].count,
                                         r->runs[k].first);
}

void hr_bind_shading(hfr_renderer *r, const hr_program *p, const hfr_view *v,
                     const hr_camera *cam, const hr_camera *light, uint32_t seed) {
  float l[3];
  if (v->light_directional) {
    hr_dir_from_angles(v->light_yaw_deg, v->light_pitch_deg, l);
  } else {
    memcpy(l, light->eye, sizeof l);
  }
  hr_set_3f(p, "u_light", l);
  hr_set_i(p, "u_light_directional", v->light_directional);
  hr_set_3f(p, "u_eye", cam->eye);
  hr_set_f(p, "u_alpha_r", hr_deg(v->alpha_r_deg));
  hr_set_f(p, "u_alpha_trt", hr_deg(v->alpha_trt_deg));
  hr_set_f(p, "u_ambient", v->ambient);
  hr_set_i(p, "u_spec_half", v->spec_half_vector);
  hr_set_u(p, "u_seed", seed);
  hr_set_f(p, "u_hash_scale", 1.0f);
  int shadows = v->shadow_size > 0 && r->shadow_tex;
  hr_set_i(p, "u_shadow_on", shadows);
  hr_set_i(p, "u_shadow", 0);
  hrgl.ActiveTexture(GL_TEXTURE0);
  hrgl.BindTexture(GL_TEXTURE_2D, shadows ? r->shadow_tex : 0);
  float vp[16];
  hr_mat_mul(light->proj, light->view, vp);
  hr_set_m4(p, "u_light_view", light->view);
  hr_set_m4(p, "u_light_vp", vp);
  hr_set_f(p, "u_shadow_near", light->depth_near);
  hr_set_f(p, "u_shadow_far", light->depth_far);
  hr_set_f(p, "u_shadow_bias", v->shadow_bias);
  hr_set_f(p, "u_shadow_texel", shadows ? 1.0f / r->shadow_size : 0.0f);
}

int hr_pass_shadow(hfr_renderer *r, const hfr_view *v, const hr_camera *light, uint32_t seed,
                   char *err, size_t errlen) {
  if (v->shadow_size <= 0) return HF_OK;
  if (r->shadow_size != v->shadow_size) {
    if (r->shadow_tex) hrgl.DeleteTextures(1, &r->shadow_tex);
    if (r->shadow_fbo) hrgl.DeleteFramebuffers(1, &r->shadow_fbo);
    r->shadow_tex = hr_make_tex(GL_TEXTURE_2D, GL_DEPTH_COMPONENT32F, v->shadow_size,
                             v->shadow_size, 0);
    /* Hardware comparison with bilinear PCF. */
    hrgl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    hrgl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    hrgl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    hrgl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    hrgl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_MODE, GL_COMPARE_REF_TO_TEXTURE);
    hrgl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_FUNC, GL_LEQUAL);
    hrgl.GenFramebuffers(1, &r->shadow_fbo);
    hrgl.BindFramebuffer(GL_FRAMEBUFFER, r->shadow_fbo);
    hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D,
                              r->shadow_tex, 0);
    GLenum none = GL_NONE;
    hrgl.DrawBuffers(1, &none);
    int rc = hr_fbo_complete("shadow", err, errlen);
    if (rc != HF_OK) return rc;
    r->shadow_size = v->shadow_size;
  }
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, r->shadow_fbo);
  hr_set_viewport(light);
  const float one = 1.0f;
  hrgl.ClearBufferfv(GL_DEPTH, 0, &one);
  hrgl.Enable(GL_DEPTH_TEST);
  hrgl.DepthFunc(GL_LESS);
  hrgl.DepthMask(GL_TRUE);
  draw_head(r, light, v, 0, 0, 1);
  hrgl.UseProgram(r->shadow.id);
  hr_set_geometry(&r->shadow, light, v, 0, 0);
  hr_set_u(&r->shadow, "u_seed", seed);
  hr_set_f(&r->shadow, "u_hash_scale", 1.0f);
  draw_hair(r);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, 0);
  return hr_gl_check("shadow pass", err, errlen);
}

/* Starts a depth-tested 4x MSAA draw into the bound framebuffer over cam's
 * window: colour attachment 0 cleared to clear, depth to 1, LESS with
 * depth writes. */
static void begin_ms_draw(const hr_camera *cam, const float clear[4]) {
  const float one = 1.0f;
  hr_set_viewport(cam);
  hrgl.ClearBufferfv(GL_COLOR, 0, clear);
  hrgl.ClearBufferfv(GL_DEPTH, 0, &one);
  hrgl.Enable(GL_MULTISAMPLE);
  hrgl.Enable(GL_DEPTH_TEST);
  hrgl.DepthFunc(GL_LESS);
  hrgl.DepthMask(GL_TRUE);
}

/* Colour attachment 0 of the bound read framebuffer, w x h RGBA32F from
 * its origin, into a new buffer *out (the caller frees it); what names the
 * pass in an error. */
static int read_rgba(int w, int h, const char *what, float **out, char *err, size_t errlen) {
  float *buf = malloc(sizeof(float) * 4 * (size_t)w * h);
  if (!buf) return HF_ENOMEM;
  hrgl.ReadBuffer(GL_COLOR_ATTACHMENT0);
  hrgl.PixelStorei(GL_PACK_ALIGNMENT, 4);
  hrgl.ReadPixels(0, 0, w, h, GL_RGBA, GL_FLOAT, buf);
  int rc = hr_gl_check(what, err, errlen);
  if (rc != HF_OK) {
    free(buf);
    return rc;
  }
  *out = buf;
  return HF_OK;
}

/* A samples-sample MSAA target of the whole frame (fw x fh) bound as fbo:
 * RGBA32F colour tex[0] as attachment 0 (the one drawn) and depth tex[1].
 * what names it in an error. */
static int ms_rgba_target(hfr_renderer *r, int slot_color, int slot_depth, int fw, int fh,
                          int samples, GLuint tex[2], GLuint fbo, const char *what, char *err,
                          size_t errlen) {
  tex[0] = frame_tex(r, slot_color, GL_RGBA32F, fw, fh, samples);
  tex[1] = frame_tex(r, slot_depth, GL_DEPTH_COMPONENT32F, fw, fh, samples);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D_MULTISAMPLE,
                            tex[0], 0);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D_MULTISAMPLE,
                            tex[1], 0);
  const GLenum b0 = GL_COLOR_ATTACHMENT0;
  hrgl.DrawBuffers(1, &b0);
  return hr_fbo_complete(what, err, errlen);
}

/* Alpha-corrected stochastic transparency over the depth samples depth_ms
 * of a feature pass (hr_glsl_stac_fs), S-sample MSAA: ac [h][w][3] colour
 * factor, highlight, alpha, rows top first. The occluder hides hair through
 * its own depth samples here; hair hides hair only through depth_ms. Per
 * pixel (hr_glsl_resolve_stac_fs): alpha = 1 - the mean transmittance of
 * its samples (the exact coverage of every fragment, at S samples);
 * colour and highlight = the alpha-weighted means of each sample's
 * weighted sums over its summed weight. */
static int pass_alpha_corrected(hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
                                const hr_camera *light, float jx, float jy, GLuint depth_ms,
                                int S, float *ac, char *err, size_t errlen) {
  const int W = cam->win_w, H = cam->win_h, FW = cam->frame_w, FH = cam->frame_h;
  const int RW = (W + 15) & ~15, RH = (H + 15) & ~15; /* whole blocks: draw_fullscreen */
  GLuint tex[3], fbo[2] = {0, 0};
  tex[2] = hr_make_tex(GL_TEXTURE_2D, GL_RGBA32F, RW, RH, 0);
  hrgl.GenFramebuffers(2, fbo);
  const GLenum b0 = GL_COLOR_ATTACHMENT0;
  float *tmp = NULL;
  int rc = ms_rgba_target(r, HR_TEX_AC_COLOR, HR_TEX_AC_DEPTH, FW, FH, S, tex, fbo[0],
                          "alpha-corrected", err, errlen);
  GLint samples = 0;
  if (rc == HF_OK) {
    /* Sample s here must lie where depth_ms's sample s does. */
    hrgl.GetIntegerv(GL_SAMPLES, &samples);
    if (samples != S) {
      if (err) snprintf(err, errlen, "alpha-corrected pass: asked for %d MSAA samples, got %d", S,
                        (int)samples);
      rc = HF_EUNSUPPORTED;
    }
  }
  if (rc == HF_OK) {
    /* RGB: sums from 0; A: transmittance from 1. */
    const float clear[4] = {0, 0, 0, 1};
    begin_ms_draw(cam, clear);
    hrgl.ColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    draw_head(r, cam, v, jx, jy, 0);
    hrgl.ColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    hrgl.DepthMask(GL_FALSE);
    hrgl.UseProgram(r->stac.id);
    hr_set_geometry(&r->stac, cam, v, jx, jy);
    hr_bind_shading(r, &r->stac, v, cam, light, 0);
    hrgl.ActiveTexture(GL_TEXTURE3);
    hrgl.BindTexture(GL_TEXTURE_2D_MULTISAMPLE, depth_ms);
    hr_set_i(&r->stac, "u_depth", 3);
    hr_set_i(&r->stac, "u_samples", S);
    hrgl.Enable(GL_BLEND);
    hrgl.BlendFuncSeparate(GL_ONE, GL_ONE, GL_ZERO, GL_ONE_MINUS_SRC_ALPHA);
    hr_draw_hair_window(r, cam, v);
    hrgl.Disable(GL_BLEND);
    hrgl.DepthMask(GL_TRUE);
    hrgl.Disable(GL_DEPTH_TEST);
    hr_scissor_off();

    hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[1]);
    hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, tex[2], 0);
    hrgl.DrawBuffers(1, &b0);
    rc = hr_fbo_complete("alpha-corrected resolve", err, errlen);
  }
  if (rc == HF_OK) {
    hrgl.UseProgram(r->resolve_stac.id);
    hrgl.ActiveTexture(GL_TEXTURE1);
    hrgl.BindTexture(GL_TEXTURE_2D_MULTISAMPLE, tex[0]);
    hr_set_i(&r->resolve_stac, "u_src", 1);
    hr_set_i(&r->resolve_stac, "u_samples", S);
    hr_set_2i(&r->resolve_stac, "u_origin", cam->win_x, cam->win_y);
    hr_draw_fullscreen(r, &r->resolve_stac, RW, RH);
    hrgl.ActiveTexture(GL_TEXTURE0);
    rc = read_rgba(W, H, "alpha-corrected pass", &tmp, err, errlen);
  }
  if (rc == HF_OK)
    for (int y = 0; y < H; y++)
      for (int x = 0; x < W; x++) {
        const float *q = tmp + 4 * ((size_t)y * W + x);
        float *o = ac + 3 * ((size_t)(H - 1 - y) * W + x);
        int some = q[2] > 0;
        o[0] = some ? q[0] / q[2] : 0;
        o[1] = some ? q[1] / q[2] : 0;
        o[2] = some ? (q[3] < 1 ? q[3] : 1) : 0;
      }
  free(tmp);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, 0);
  hrgl.DeleteFramebuffers(2, fbo);
  hrgl.DeleteTextures(1, &tex[2]); /* tex[0], tex[1]: r's (frame_tex) */
  return rc;
}

int hr_pass_ms(hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
               const hr_camera *light, uint32_t seed, float jx, float jy, int opaque,
               float *out, float *ac, char *err, size_t errlen) {
  const int W = cam->win_w, H = cam->win_h, S = 4, FW = cam->frame_w, FH = cam->frame_h;
  GLuint tex[3], fbo[2] = {0, 0}, rtex = 0;
  tex[0] = frame_tex(r, HR_TEX_FEATURE_0, GL_RGBA32F, FW, FH, S);
  tex[1] = frame_tex(r, HR_TEX_FEATURE_1, GL_RG32F, FW, FH, S);
  tex[2] = frame_tex(r, HR_TEX_FEATURE_DEPTH, GL_DEPTH_COMPONENT32F, FW, FH, S);
  hrgl.GenFramebuffers(2, fbo);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[0]);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D_MULTISAMPLE,
                            tex[0], 0);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_TEXTURE_2D_MULTISAMPLE,
                            tex[1], 0);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D_MULTISAMPLE,
                            tex[2], 0);
  const GLenum bufs[2] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
  hrgl.DrawBuffers(2, bufs);
  float *tmp = NULL;
  int rc = hr_fbo_complete("feature", err, errlen);
  GLint samples = 0;
  if (rc == HF_OK) {
    hrgl.GetIntegerv(GL_SAMPLES, &samples);
    if (samples != S) {
      if (err) snprintf(err, errlen, "asked for %d MSAA samples, got %d", S, (int)samples);
      rc = HF_EUNSUPPORTED;
    }
  }
  if (rc == HF_OK) {
    r->ms_samples = samples;
    /* Samples no fragment covers keep all six features 0
     * (protocol/FEATURES.md); the depth test uses its own attachment. */
    const float zero[4] = {0, 0, 0, 0};
    begin_ms_draw(cam, zero);
    hrgl.ClearBufferfv(GL_COLOR, 1, zero);
    hrgl.ColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    draw_head(r, cam, v, jx, jy, 0);
    hrgl.ColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    hrgl.UseProgram(r->st.id);
    hr_set_geometry(&r->st, cam, v, jx, jy);
    hr_bind_shading(r, &r->st, v, cam, light, seed);
    hr_set_i(&r->st, "u_opaque", opaque);
    hr_set_i(&r->st, "u_samples", S);
    hr_draw_hair_window(r, cam, v);
    hrgl.Disable(GL_DEPTH_TEST);
    hr_scissor_off();

    /* Resolve: a (3W) x (H * S) RG32F target, texel (3x + j, S y + s). */
    rtex = hr_make_tex(GL_TEXTURE_2D, GL_RG32F, 3 * W, H * S, 0);
    hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[1]);
    hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, rtex, 0);
    hrgl.DrawBuffers(1, bufs);
    rc = hr_fbo_complete("resolve", err, errlen);
  }
  if (rc == HF_OK) {
    hrgl.UseProgram(r->resolve_ms.id);
    hrgl.ActiveTexture(GL_TEXTURE1);
    hrgl.BindTexture(GL_TEXTURE_2D_MULTISAMPLE, tex[0]);
    hrgl.ActiveTexture(GL_TEXTURE2);
    hrgl.BindTexture(GL_TEXTURE_2D_MULTISAMPLE, tex[1]);
    hr_set_i(&r->resolve_ms, "u_f0", 1);
    hr_set_i(&r->resolve_ms, "u_f1", 2);
    hr_set_i(&r->resolve_ms, "u_samples", S);
    hr_set_2i(&r->resolve_ms, "u_origin", cam->win_x, cam->win_y);
    hr_draw_fullscreen(r, &r->resolve_ms, 3 * W, H * S);
    tmp = malloc(sizeof(float) * 6 * (size_t)W * H * S);
    if (!tmp) rc = HF_ENOMEM;
  }
  if (rc == HF_OK) {
    hrgl.ReadBuffer(GL_COLOR_ATTACHMENT0);
    hrgl.PixelStorei(GL_PACK_ALIGNMENT, 4);
    hrgl.ReadPixels(0, 0, 3 * W, H * S, GL_RG, GL_FLOAT, tmp);
    rc = hr_gl_check("feature pass", err, errlen);
  }
  if (rc == HF_OK) {
    /* GL rows are bottom first; hf_image rows top first. */
    for (int y = 0; y < H; y++)
      for (int s = 0; s < S; s++) {
        const float *src = tmp + (size_t)(y * S + s) * 6 * W;
        float *dst = out + (size_t)(H - 1 - y) * W * S * 6;
        for (int x = 0; x < W; x++) memcpy(dst + ((size_t)x * S + s) * 6, src + 6 * x,
                                           6 * sizeof(float));
      }
  }
  free(tmp);
  if (rc == HF_OK && ac)
    rc = pass_alpha_corrected(r, v, cam, light, jx, jy, tex[2], S, ac, err, errlen);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, 0);
  hrgl.DeleteFramebuffers(2, fbo);
  /* tex: r's (frame_tex) */
  if (rtex) hrgl.DeleteTextures(1, &rtex);
  return rc;
}

int hr_pass_background(hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
                       const hr_camera *light, float *out, char *err, size_t errlen) {
  const int W = cam->win_w, H = cam->win_h, FW = cam->frame_w, FH = cam->frame_h;
  GLuint tex[3], fbo[2] = {0, 0};
  tex[2] = hr_make_tex(GL_TEXTURE_2D, GL_RGBA32F, W, H, 0);
  hrgl.GenFramebuffers(2, fbo);
  const GLenum b0 = GL_COLOR_ATTACHMENT0;
  int rc = ms_rgba_target(r, HR_TEX_BG_COLOR, HR_TEX_BG_DEPTH, FW, FH, 4, tex, fbo[0],
                          "background", err, errlen);
  float *tmp = NULL;
  if (rc == HF_OK) {
    const float zero[4] = {0, 0, 0, 0};
    begin_ms_draw(cam, zero);
    if (r->has_head) {
      hrgl.UseProgram(r->occluder.id);
      hr_set_geometry(&r->occluder, cam, v, 0, 0);
      hr_bind_shading(r, &r->occluder, v, cam, light, 0);
      hr_set_f(&r->occluder, "u_normal_offset", 0.02f * r->radius);
      hrgl.BindVertexArray(r->head_vao);
      hrgl.DrawArrays(GL_TRIANGLES, 0, r->head_vertices);
    }
    hrgl.Disable(GL_DEPTH_TEST);
    hr_scissor_off();
    /* Resolve: the average of the 4 samples, premultiplied by coverage. */
    hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[1]);
    hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, tex[2], 0);
    hrgl.DrawBuffers(1, &b0);
    rc = hr_fbo_complete("background resolve", err, errlen);
  }
  if (rc == HF_OK) {
    hrgl.BindFramebuffer(GL_READ_FRAMEBUFFER, fbo[0]);
    hrgl.BindFramebuffer(GL_DRAW_FRAMEBUFFER, fbo[1]);
    hrgl.BlitFramebuffer(cam->win_x, cam->win_y, cam->win_x + W, cam->win_y + H, 0, 0, W, H,
                         GL_COLOR_BUFFER_BIT, GL_NEAREST);
    hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[1]);
    rc = read_rgba(W, H, "background pass", &tmp, err, errlen);
  }
  if (rc == HF_OK)
    for (int y = 0; y < H; y++)
      for (int x = 0; x < W; x++) {
        const float *s = tmp + 4 * ((size_t)y * W + x);
        float *o = out + 2 * ((size_t)(H - 1 - y) * W + x);
        o[0] = s[0], o[1] = s[3];
      }
  free(tmp);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, 0);
  hrgl.DeleteFramebuffers(2, fbo);
  hrgl.DeleteTextures(1, &tex[2]); /* tex[0], tex[1]: r's (frame_tex) */
  return rc;
}

/* ---- ground truth ---------------------------------------------------------- */

/* A fragment's place in its list's blend order as one integer: depth, then
 * node index (the shader's order). Depths are in [0, 1] (depth01), whose
 * binary32 bits order as the values do once -0 is made +0, so comparing
 * keys is comparing (depth, index) as the shader does. */
typedef uint64_t sort_key;

static inline sort_key key_of(float d, uint32_t i) {
  uint32_t bits;
  if (d == 0.0f) d = 0.0f; /* -0 sorts as +0: equal depths fall to the index */
  memcpy(&bits, &d, sizeof bits);
  return (uint64_t)bits << 32 | i;
}

/* Sorts keys ascending. Our own rather than qsort: the host blend sorts
 * millions of lists, up to thousands deep, and qsort's call through a
 * comparison function per step was a third of a dense frame's time.
 * Quicksort on the median of three, the smaller part first (depth log n),
 * insertion sort below 16 keys. Keys are distinct (the indices are). */
static void sort_keys(sort_key *k, size_t n) {
  while (n > 16) {
    size_t mid = n / 2;
    if (k[mid] < k[0]) { sort_key t = k[mid]; k[mid] = k[0]; k[0] = t; }
    if (k[n - 1] < k[0]) { sort_key t = k[n - 1]; k[n - 1] = k[0]; k[0] = t; }
    if (k[n - 1] < k[mid]) { sort_key t = k[n - 1]; k[n - 1] = k[mid]; k[mid] = t; }
    const sort_key pivot = k[mid];
    size_t i = 0, j = n - 1;
    for (;;) {
      while (k[i] < pivot) i++;
      while (pivot < k[j]) j--;
      if (i >= j) break;
      sort_key t = k[i]; k[i] = k[j]; k[j] = t;
      i++, j--;
    }
    /* [0, j] <= pivot <= [j + 1, n) */
    size_t left = j + 1, right = n - left;
    if (left < right) {
      sort_keys(k, left);
      k += left, n = right;
    } else {
      sort_keys(k + left, right);
      n = left;
    }
  }
  for (size_t a = 1; a < n; a++) {
    sort_key x = k[a];
    size_t b = a;
    for (; b > 0 && x < k[b - 1]; b--) k[b] = k[b - 1];
    k[b] = x;
  }
}

/* The host blend's work, split by rows of pixels between threads
 * (hf_parallel_chunks): each worker sorts with its own keys and keeps its
 * own deepest list and count of long lists. */
typedef struct blend_run {
  const uint32_t *heads, *nodes;
  size_t heads_stride;
  uint32_t capacity;
  int w, ss;
  float *out;
  struct {
    sort_key *keys;
    size_t cap;
    uint32_t max_depth;
    uint64_t long_lists;
    int rc;
  } part[HF_PARALLEL_MAX];
} blend_run;

static void blend_rows(void *arg, int worker, size_t y0, size_t y1) {
  blend_run *b = arg;
  const int ss = b->ss, w = b->w;
  __typeof__(b->part[0]) *pt = &b->part[worker];
  if (pt->rc) return;
  for (size_t y = y0; y < y1; y++)
    for (int x = 0; x < w; x++) {
      double acc[3] = {0, 0, 0};
      for (int sy = 0; sy < ss; sy++)
        for (int sx = 0; sx < ss; sx++) {
          size_t n = 0;
          for (uint32_t i = b->heads[(y * ss + sy) * b->heads_stride + (size_t)x * ss + sx];
               i != 0xFFFFFFFFu && i < b->capacity; i = b->nodes[(size_t)i * NODE_WORDS + 4]) {
            if (n == pt->cap) {
              size_t cap = pt->cap ? pt->cap * 2 : 256;
              sort_key *k2 = realloc(pt->keys, sizeof *k2 * cap);
              if (!k2) {
                pt->rc = HF_ENOMEM;
                return;
              }
              pt->keys = k2;
              pt->cap = cap;
            }
            float d;
            memcpy(&d, &b->nodes[(size_t)i * NODE_WORDS + 3], 4);
            pt->keys[n++] = key_of(d, i);
          }
          if (n > pt->max_depth) pt->max_depth = (uint32_t)n;
          pt->long_lists += n > HR_ABUF_SORT;
          sort_keys(pt->keys, n);
          double T = 1, c = 0, hl = 0;
          for (size_t k = 0; k < n; k++) {
            float q[3];
            memcpy(q, &b->nodes[(size_t)(uint32_t)pt->keys[k] * NODE_WORDS], sizeof q);
            c += T * q[2] * q[0];
            hl += T * q[2] * q[1];
            T *= 1 - q[2];
          }
          acc[0] += c, acc[1] += hl, acc[2] += 1 - T;
        }
      float *o = b->out + 3 * (y * (size_t)w + x);
      double a = acc[2] / (ss * ss);
      o[0] = a > 0 ? (float)(acc[0] / acc[2]) : 0;
      o[1] = a > 0 ? (float)(acc[1] / acc[2]) : 0;
      o[2] = (float)a;
    }
}

int hr_abuf_blend_cpu(const uint32_t *heads, size_t heads_stride, const uint32_t *nodes,
                      uint32_t capacity, int w, int h, int ss, float *out, uint32_t *max_depth,
                      uint64_t *long_lists) {
  blend_run *b = calloc(1, sizeof *b);
  if (!b) return HF_ENOMEM;
  b->heads = heads, b->heads_stride = heads_stride, b->nodes = nodes, b->capacity = capacity;
  b->w = w, b->ss = ss, b->out = out;
  /* Rows of at least 64 lists' worth per thread: a few rows of a small
   * window are not worth a thread. */
  const size_t min_rows = (size_t)(4096 / ((size_t)w * ss * ss) + 1);
  int nw = hf_parallel_chunks((size_t)h, 1, min_rows, blend_rows, b);
  int rc = HF_OK;
  uint32_t depth = 0;
  uint64_t longs = 0;
  for (int k = 0; k < nw; k++) {
    if (b->part[k].rc) rc = b->part[k].rc;
    depth = b->part[k].max_depth > depth ? b->part[k].max_depth : depth;
    longs += b->part[k].long_lists;
  }
  for (int k = 0; k < HF_PARALLEL_MAX; k++) free(b->part[k].keys);
  free(b);
  if (max_depth) *max_depth = depth;
  if (long_lists) *long_lists = longs;
  return rc;
}

static void flip_rows(const float *src, float *dst, int w, int h, int ch) {
  for (int y = 0; y < h; y++)
    memcpy(dst + (size_t)(h - 1 - y) * w * ch, src + (size_t)y * w * ch,
           sizeof(float) * w * ch);
}

/* Most fragments one A-buffer of r holds. */
static uint32_t abuf_max_nodes(const hfr_renderer *r) {
  return r->max_fragments > 0 && r->max_fragments < HFR_MAX_FRAGMENTS ? r->max_fragments
                                                                      : HFR_MAX_FRAGMENTS;
}

/* Grows r's pool of A-buffer nodes to capacity nodes (no smaller). */
static int abuf_reserve(hfr_renderer *r, uint32_t capacity, char *err, size_t errlen) {
  if (capacity <= r->abuf_nodes_cap) return HF_OK;
  if (!r->abuf_nodes) hrgl.GenBuffers(1, &r->abuf_nodes);
  hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, r->abuf_nodes);
  hrgl.BufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)capacity * NODE_WORDS * 4, NULL,
                  GL_DYNAMIC_COPY);
  int rc = hr_gl_check("A-buffer nodes", err, errlen);
  r->abuf_nodes_cap = rc == HF_OK ? capacity : 0;
  return rc;
}

/* How a window of the ground truth is drawn, and what its first draw
 * learnt for its bands. */
typedef struct gt_plan {
  int cull;          /* behind the transmittance cull (hr_gt_cull) */
  int depth_ready;   /* a band: the window it belongs to made the A-buffer's
                      * depth over it (occluder and cut) */
  uint64_t *rows;    /* [h], rows top first: a bound on each row's A-buffer
                      * fragments behind the cut, once known; else NULL */
  uint64_t uncut;    /* fragments counted before the cut (0: none) */
} gt_plan;

/* The ground truth of v's window in one A-buffer. *overflow is set to the
 * window's fragment count when that is more than one A-buffer holds
 * (HF_ERANGE). plan says how to draw it and gets what the draw learnt: a
 * window first drawn without the cull turns it on (plan->cull, uncut) when
 * it must be drawn again (HFR_GT_CULL_AUTO) with lists GT_CULL_DEPTH deep;
 * the cull then sets plan->rows (the caller frees it). */
static int gt_window(hfr_renderer *r, const hfr_view *v, const hr_camera *light, int ss,
                     float *gt, float *cpu_gt, hfr_stats *stats, uint64_t *overflow,
                     gt_plan *plan, char *err, size_t errlen) {
  int W, H;
  hr_view_target(v, &W, &H);
  const int SW = W * ss, SH = H * ss, FSW = v->width * ss, FSH = v->height * ss;
  GLint maxtex = 0, maxvp[2] = {0, 0};
  hrgl.GetIntegerv(GL_MAX_TEXTURE_SIZE, &maxtex);
  hrgl.GetIntegerv(GL_MAX_VIEWPORT_DIMS, maxvp);
  if (ss < 1 || FSW > maxtex || FSH > maxtex || FSW > maxvp[0] || FSH > maxvp[1]) {
    if (err) snprintf(err, errlen, "supersampled size %dx%d (frame %dx%d) above the GL limits "
                      "(texture %d, viewport %dx%d)", SW, SH, v->width * ss, v->height * ss,
                      (int)maxtex, (int)maxvp[0], (int)maxvp[1]);
    return HF_ERANGE;
  }
  /* The same frame and window, ss times finer. */
  hfr_view sv = *v;
  sv.width = v->width * ss;
  sv.height = v->height * ss;
  sv.crop_x *= ss, sv.crop_y *= ss, sv.crop_w *= ss, sv.crop_h *= ss;
  hr_camera cam;
  hr_camera_from_view(r, &sv, &cam);

  /* heads, nodes (the renderer's: r->abuf_nodes, set below), counter,
   * stats */
  GLuint bufs[4] = {0, 0, 0, 0};
  GLuint depth = 0, rtex = 0, fbo[2] = {0, 0};
  hrgl.GenBuffers(1, &bufs[0]);
  hrgl.GenBuffers(2, &bufs[2]);
  hrgl.GenFramebuffers(2, fbo);
  depth = frame_tex(r, HR_TEX_GT_DEPTH, GL_DEPTH_COMPONENT32F, FSW, FSH, 0);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[0]);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D, depth, 0);
  GLenum none = GL_NONE;
  hrgl.DrawBuffers(1, &none);
  int rc = hr_fbo_complete("A-buffer", err, errlen);

  /* List heads of the window's supersampled pixels only (a 256x256 crop of
   * a 1024x1024 frame at 8x8 needs 16 MiB of them, not 256). */
  hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[0]);
  hrgl.BufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)sizeof(uint32_t) * SW * SH, NULL,
                  GL_DYNAMIC_COPY);
  /* HFR_MAX_FRAGMENTS: 1.3 GB of nodes at most. */
  const uint32_t max_nodes = abuf_max_nodes(r);
  uint64_t want = (uint64_t)SW * SH * 2;
  uint32_t capacity = want < ABUF_MIN_NODES ? ABUF_MIN_NODES
                      : want > max_nodes ? max_nodes : (uint32_t)want;
  /* The pool of nodes is kept from window to window (bands, frames): a
   * new buffer is zero-filled by llvmpipe (docs/RENDERING.md, step 3: 4.5
   * s for 1.2 GB), so a window takes the pool the one before it grew. */
  if (r->abuf_nodes_cap > capacity) capacity = r->abuf_nodes_cap < max_nodes ? r->abuf_nodes_cap
                                                                             : max_nodes;
  if (plan->rows) {
    /* A band of a cut window: its bound, which the pool holds at once. */
    uint64_t n = 0;
    for (int y = 0; y < H; y++) n += plan->rows[y];
    capacity = n < ABUF_MIN_NODES ? ABUF_MIN_NODES : n > max_nodes ? max_nodes : (uint32_t)n;
  }
  uint64_t count = 0;
  double t0 = hr_now_ms();
  /* A window whose hair promises lists GT_CULL_PRIOR deep on average is
   * drawn behind the cull from the start: its first, uncut count would be
   * a large part of its time (a 128x128 window of a dense ponytail at 8x8:
   * 67.6 s of truth with that count, 34.1 s without). The estimate counts
   * quads without the occluder: high. */
  if (!plan->cull && !plan->depth_ready && r->gt_cull == HFR_GT_CULL_AUTO) {
    double est = 0;
    if (hr_hair_window_fragments(r, &cam, sv.thickness_scale, &est) == HF_OK &&
        est >= GT_CULL_PRIOR * (double)SW * SH)
      plan->cull = 1;
  }
  int depth_made = plan->depth_ready, cut = plan->depth_ready && plan->cull;
  for (int attempt = 0; rc == HF_OK && attempt < 3; attempt++) {
    if ((rc = abuf_reserve(r, capacity, err, errlen)) != HF_OK) break;
    bufs[1] = r->abuf_nodes;
    const uint32_t empty = 0xFFFFFFFFu;
    hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[0]);
    hrgl.ClearBufferData(GL_SHADER_STORAGE_BUFFER, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT,
                         &empty);
    const uint32_t zero2[2] = {0, 0};
    hrgl.BindBuffer(GL_ATOMIC_COUNTER_BUFFER, bufs[2]);
    hrgl.BufferData(GL_ATOMIC_COUNTER_BUFFER, sizeof zero2, zero2, GL_DYNAMIC_COPY);
    hrgl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, bufs[0]);
    hrgl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, bufs[1]);
    hrgl.BindBufferBase(GL_ATOMIC_COUNTER_BUFFER, 0, bufs[2]);

    /* The depth the hair is tested against (the occluder's, then the
     * cull's) is made once: the hair's draws leave it as it is. */
    hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[0]);
    hr_set_viewport(&cam);
    if (!depth_made) {
      const float one = 1.0f;
      hrgl.ClearBufferfv(GL_DEPTH, 0, &one);
      hrgl.Enable(GL_DEPTH_TEST);
      hrgl.DepthFunc(GL_LESS);
      hrgl.DepthMask(GL_TRUE);
      draw_head(r, &cam, &sv, 0, 0, 0);
      depth_made = 1;
    }
    if (plan->cull && !cut) {
      uint64_t *fine = calloc((size_t)SH, sizeof *fine);
      plan->rows = calloc((size_t)H, sizeof *plan->rows);
      if (!fine || !plan->rows) {
        free(fine);
        rc = HF_ENOMEM;
        break;
      }
      uint64_t uncut = 0;
      rc = hr_gt_cull(r, &sv, &cam, fbo[0], fine, &uncut, err, errlen);
      plan->uncut = uncut;
      cut = 1;
      /* Supersampled rows, bottom first, into the window's rows, top first. */
      uint64_t total = 0;
      for (int y = 0; y < SH; y++) plan->rows[H - 1 - y / ss] += fine[y], total += fine[y];
      free(fine);
      if (rc != HF_OK) break;
      if (total > max_nodes) {
        if (err) snprintf(err, errlen, "%llu A-buffer fragments in %d row%s of %d pixels, "
                          "more than the %u one A-buffer holds: lower the supersampling or "
                          "the strand count", (unsigned long long)total, H, H == 1 ? "" : "s",
                          W, max_nodes);
        *overflow = max_nodes; /* the caller bands by plan->rows */
        rc = HF_ERANGE;
        break;
      }
      if (total > capacity) {
        capacity = (uint32_t)total;
        if ((rc = abuf_reserve(r, capacity, err, errlen)) != HF_OK) break;
        bufs[1] = r->abuf_nodes;
        hrgl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, bufs[1]);
      }
      hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[0]);
      hr_set_viewport(&cam);
    }
    hrgl.Enable(GL_DEPTH_TEST);
    hrgl.DepthFunc(GL_LESS);
    hrgl.DepthMask(GL_FALSE); /* every hair fragment is kept, none hides another */
    hrgl.UseProgram(r->abuf.id);
    hr_set_geometry(&r->abuf, &cam, &sv, 0, 0);
    hr_bind_shading(r, &r->abuf, &sv, &cam, light, 0);
    hr_set_u(&r->abuf, "u_capacity", capacity);
    hr_set_i(&r->abuf, "u_width", SW);
    hr_set_2i(&r->abuf, "u_win_lo", cam.win_x, cam.win_y);
    hr_set_2i(&r->abuf, "u_win_hi", cam.win_x + SW, cam.win_y + SH);
    hr_draw_hair_window(r, &cam, &sv);
    hrgl.DepthMask(GL_TRUE);
    hrgl.Disable(GL_DEPTH_TEST);
    hr_scissor_off();
    hrgl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_ATOMIC_COUNTER_BARRIER_BIT |
                       GL_BUFFER_UPDATE_BARRIER_BIT);
    /* Fragments counted, and how often the 32-bit counter went round: a
     * dense 512x512 window at 8x8 draws more than 2^32. */
    uint32_t cw[2] = {0, 0};
    hrgl.BindBuffer(GL_ATOMIC_COUNTER_BUFFER, bufs[2]);
    hrgl.GetBufferSubData(GL_ATOMIC_COUNTER_BUFFER, 0, sizeof cw, cw);
    count = (uint64_t)cw[1] << 32 | cw[0];
    rc = hr_gl_check("A-buffer pass", err, errlen);
    if (rc != HF_OK) break;
    /* Lists deep enough to be drawn again: again behind the cull. */
    if (!plan->cull && r->gt_cull == HFR_GT_CULL_AUTO && count > capacity &&
        count / ((double)SW * SH) >= GT_CULL_DEPTH) {
      plan->cull = 1;
      continue;
    }
    if (count > max_nodes) {
      if (err) snprintf(err, errlen, "%llu A-buffer fragments in %d row%s of %d pixels, more "
                        "than the %u one A-buffer holds: lower the supersampling or the "
                        "strand count", (unsigned long long)count, H, H == 1 ? "" : "s", W,
                        max_nodes);
      *overflow = count;
      rc = HF_ERANGE;
      break;
    }
    if (count <= capacity) break;
    /* Too small: grow to what was counted and draw again. */
    capacity = count + count / 16 > max_nodes ? max_nodes : (uint32_t)(count + count / 16);
  }

  if (rc == HF_OK) {
    const uint32_t zero3[3] = {0, 0, 0};
    hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[3]);
    hrgl.BufferData(GL_SHADER_STORAGE_BUFFER, sizeof zero3, zero3, GL_DYNAMIC_COPY);
    hrgl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, bufs[3]);
    /* Whole 16x16 blocks: llvmpipe blends the lists of partially covered
     * 4x4 blocks wrongly (draw_fullscreen), so the target is grown to whole
     * blocks and only W x H is read back. */
    rtex = hr_make_tex(GL_TEXTURE_2D, GL_RGBA32F, (W + 15) & ~15, (H + 15) & ~15, 0);
    hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo[1]);
    hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, rtex, 0);
    GLenum b0 = GL_COLOR_ATTACHMENT0;
    hrgl.DrawBuffers(1, &b0);
    rc = hr_fbo_complete("A-buffer resolve", err, errlen);
  }
  float *tmp = NULL;
  int host = 0; /* lists too deep for the shader: blend on the host */
  int deep = 0; /* that known before the shader's resolve */
  if (rc == HF_OK) {
    const float zero4[4] = {0, 0, 0, 0};
    hrgl.ClearBufferfv(GL_COLOR, 0, zero4);
    hrgl.UseProgram(r->resolve_abuf.id);
    hr_set_i(&r->resolve_abuf, "u_ss", ss);
    hr_set_i(&r->resolve_abuf, "u_width", SW);
    hr_set_2i(&r->resolve_abuf, "u_size", W, H);
    hr_set_u(&r->resolve_abuf, "u_capacity", capacity);
    /* One draw per subsample, summed (see hr_glsl_resolve_abuf_fs). Lists
     * longer than one round of its sort on average go to the host at once:
     * the shader would sort most of them in several rounds, walking each
     * list again per round, often up to its loop budget, then hand the
     * window to the host all the same. */
    deep = count > (uint64_t)HR_ABUF_SORT * SW * SH;
    hrgl.Enable(GL_BLEND);
    hrgl.BlendFunc(GL_ONE, GL_ONE);
    for (int sub = 0; sub < (deep ? 0 : ss * ss); sub++) {
      hr_set_i(&r->resolve_abuf, "u_sub", sub);
      hr_draw_fullscreen(r, &r->resolve_abuf, (W + 15) & ~15, (H + 15) & ~15);
      if (sub == 0) {
        /* A list too deep for the shader in the first subsample means the
         * host blends the window: the other subsamples' draws would only
         * walk deep lists up to the loop budget, then be thrown away (on
         * dense close-ups that was most of a frame's time). */
        uint32_t st0[3] = {0, 0, 0};
        hrgl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[3]);
        hrgl.GetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, sizeof st0, st0);
        if (st0[2] > 0) break;
      }
    }
    hrgl.Disable(GL_BLEND);
    hrgl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    tmp = malloc(sizeof(float) * 4 * (size_t)W * H);
    if (!tmp) rc = HF_ENOMEM;
  }
  if (rc == HF_OK) {
    hrgl.ReadBuffer(GL_COLOR_ATTACHMENT0);
    hrgl.ReadPixels(0, 0, W, H, GL_RGBA, GL_FLOAT, tmp);
    uint32_t st[3] = {0, 0, 0};
    hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[3]);
    hrgl.GetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, sizeof st, st);
    rc = hr_gl_check("A-buffer resolve", err, errlen);
    host = deep || st[2] > 0;
    if (stats) {
      stats->gt_host_resolve = host;
      stats->gt_fragments = count;
      stats->gt_max_depth = st[0];
      stats->gt_truncated = st[1];
    }
  }
  /* Lists too deep for the shader's loop budget: the host blends them all
   * (same sort, same result, slower). */
  if (rc == HF_OK && !host) {
    /* Premultiplied sums -> colour factor, highlight, alpha. */
    for (size_t i = 0; i < (size_t)W * H; i++) {
      float a = tmp[4 * i + 2];
      float c = a > 0 ? tmp[4 * i] / a : 0, h = a > 0 ? tmp[4 * i + 1] / a : 0;
      tmp[3 * i] = c, tmp[3 * i + 1] = h, tmp[3 * i + 2] = a;
    }
    flip_rows(tmp, gt, W, H, 3);
  }
  if (rc == HF_OK && (cpu_gt || host)) {
    /* The lists where they are: the window's rows of the whole frame's
     * heads and the pool of nodes, mapped for reading (llvmpipe's buffers
     * are host memory: no copy of up to HFR_MAX_FRAGMENTS nodes). */
    float *cpu = malloc(sizeof(float) * 3 * (size_t)W * H);
    const uint32_t *heads = NULL, *nodes = NULL;
    if (!cpu) rc = HF_ENOMEM;
    if (rc == HF_OK) {
      hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[0]);
      heads = hrgl.MapBufferRange(GL_SHADER_STORAGE_BUFFER, 0,
                                  (GLsizeiptr)(sizeof(uint32_t) * (size_t)SW * SH),
                                  GL_MAP_READ_BIT);
      hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[1]);
      if (count)
        nodes = hrgl.MapBufferRange(GL_SHADER_STORAGE_BUFFER, 0,
                                    (GLsizeiptr)(sizeof(uint32_t) * NODE_WORDS * (size_t)count),
                                    GL_MAP_READ_BIT);
      rc = hr_gl_check("A-buffer map", err, errlen);
      if (rc == HF_OK && (!heads || (count && !nodes))) {
        if (err) snprintf(err, errlen, "A-buffer map: the GL gave no pointer");
        rc = HF_EBACKEND;
      }
    }
    uint32_t depth = 0;
    uint64_t longs = 0;
    if (rc == HF_OK)
      rc = hr_abuf_blend_cpu(heads, (size_t)SW, nodes, (uint32_t)count, W, H, ss, cpu, &depth,
                             &longs);
    if (heads) {
      hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[0]);
      hrgl.UnmapBuffer(GL_SHADER_STORAGE_BUFFER);
    }
    if (nodes) {
      hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, bufs[1]);
      hrgl.UnmapBuffer(GL_SHADER_STORAGE_BUFFER);
    }
    /* Blended here: the statistics of every list, not of the shader's
     * first subsample. */
    if (rc == HF_OK && host && stats) stats->gt_max_depth = depth, stats->gt_truncated = longs;
    if (rc == HF_OK) flip_rows(cpu, cpu_gt ? cpu_gt : gt, W, H, 3);
    if (rc == HF_OK && host && cpu_gt) memcpy(gt, cpu_gt, sizeof(float) * 3 * (size_t)W * H);
    free(cpu);
  }
  if (stats) stats->gt_ms += hr_now_ms() - t0;
  free(tmp);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, 0);
  hrgl.DeleteFramebuffers(2, fbo);
  /* depth: r's (frame_tex) */
  if (rtex) hrgl.DeleteTextures(1, &rtex);
  hrgl.DeleteBuffers(1, &bufs[0]);
  hrgl.DeleteBuffers(2, &bufs[2]);
  return rc;
}

/* The window as bands of rows when its fragments do not fit one A-buffer,
 * each drawn again with the A-buffer shader keeping only its own rows'
 * fragments: behind a cut the window made (gt_plan), bands as large as the
 * bounds of its rows allow, drawn against its depth; otherwise as many
 * bands as the count it measured needs at three quarters of an A-buffer
 * each. A band that still overflows is split again, down to single rows.
 * Every pixel's list is the same whichever band draws it, so the result is
 * the one a large enough A-buffer gives; each band costs one more draw of
 * the hair. */
static int gt_rows(hfr_renderer *r, const hfr_view *v, const hr_camera *light, int ss,
                   float *gt, float *cpu_gt, hfr_stats *stats, gt_plan plan, char *err,
                   size_t errlen) {
  int W, H;
  uint64_t overflow = 0;
  hr_view_target(v, &W, &H);
  hfr_stats own = {0};
  uint64_t *const given = plan.rows; /* a band's: its window's, not freed here */
  int rc = gt_window(r, v, light, ss, gt, cpu_gt, &own, &overflow, &plan, err, errlen);
  if (rc == HF_ERANGE && overflow && H > 1) {
    const uint32_t max_nodes = abuf_max_nodes(r);
    hfr_view band = *v;
    if (band.crop_w <= 0) band.crop_x = 0, band.crop_y = 0, band.crop_w = W, band.crop_h = H;
    const int y0 = band.crop_y;
    /* Every band's nodes fit the largest pool, which is made once here:
     * growing it band by band would zero-fill it again and redraw each
     * band that outgrew it. */
    const double t_pool = hr_now_ms();
    rc = abuf_reserve(r, max_nodes, err, errlen);
    if (rc != HF_OK) {
      if (!given) free(plan.rows);
      return rc;
    }
    const double tried = own.gt_ms + (hr_now_ms() - t_pool);
    own = (hfr_stats){0};
    own.gt_ms = tried;
    /* Behind a cut made here, bands as full as each row's bound allows,
     * drawn against that depth; else (or a band that still overflows) as
     * many even bands as the count needs at three quarters of the pool. */
    const int by_rows = plan.cull && plan.rows && !given;
    const uint64_t per_band = (uint64_t)max_nodes * 3 / 4 + 1;
    uint64_t want = (overflow + per_band - 1) / per_band;
    const int n = want < 2 ? 2 : want > (uint64_t)H ? H : (int)want;
    for (int b = 0, top = 0; rc == HF_OK && top < H; b++) {
      int end;
      if (by_rows) {
        uint64_t sum = plan.rows[top];
        for (end = top + 1; end < H && sum + plan.rows[end] <= max_nodes; end++)
          sum += plan.rows[end];
      } else {
        end = (int)((int64_t)H * (b + 1) / n);
      }
      /* Rows top first: gt and cpu_gt are [h][w][3]. */
      const size_t off = (size_t)3 * W * top;
      band.crop_y = y0 + top, band.crop_h = end - top;
      /* A band keeps its window's depth (and cut) however deep it is split. */
      gt_plan sub = {plan.cull, plan.depth_ready || (plan.cull && plan.rows),
                     by_rows ? plan.rows + top : NULL, 0};
      hfr_stats part = {0};
      rc = gt_rows(r, &band, light, ss, gt + off, cpu_gt ? cpu_gt + off : NULL, &part, sub,
                   err, errlen);
      own.gt_ms += part.gt_ms;
      own.gt_fragments += part.gt_fragments;
      own.gt_max_depth = part.gt_max_depth > own.gt_max_depth ? part.gt_max_depth
                                                              : own.gt_max_depth;
      own.gt_truncated += part.gt_truncated;
      own.gt_host_resolve |= part.gt_host_resolve;
      own.gt_culled += part.gt_culled;
      top = end;
    }
  }
  if (!given) free(plan.rows);
  /* Counted whole before the cull: what it kept out is the difference. */
  if (rc == HF_OK && plan.uncut)
    own.gt_culled = plan.uncut > own.gt_fragments ? plan.uncut - own.gt_fragments : 0;
  if (stats) {
    stats->gt_ms += own.gt_ms;
    stats->gt_fragments = own.gt_fragments;
    stats->gt_max_depth = own.gt_max_depth;
    stats->gt_truncated = own.gt_truncated;
    stats->gt_host_resolve = own.gt_host_resolve;
    stats->gt_culled = own.gt_culled;
  }
  return rc;
}

int hr_pass_gt(hfr_renderer *r, const hfr_view *v, const hr_camera *light, int ss, float *gt,
               float *cpu_gt, hfr_stats *stats, char *err, size_t errlen) {
  const gt_plan plan = {r->gt_cull == HFR_GT_CULL_ON, 0, NULL, 0};
  return gt_rows(r, v, light, ss, gt, cpu_gt, stats, plan, err, errlen);
}
