/* Internals shared by the renderer's files. */
#ifndef HR_INTERNAL_H
#define HR_INTERNAL_H

#include "hfrender.h"
#include "hr_context.h"
#include "hr_gl.h"

typedef struct hr_program {
  GLuint id;
} hr_program;

/* Compiles and links vs (+ gs when not NULL) + fs. */
int hr_program_build(hr_program *p, const char *vs, const char *gs, const char *fs, char *err,
                     size_t errlen);
void hr_program_free(hr_program *p);
/* Uniform setters by name; a uniform the compiler removed is ignored. */
void hr_set_i(const hr_program *p, const char *name, int v);
void hr_set_u(const hr_program *p, const char *name, unsigned v);
void hr_set_f(const hr_program *p, const char *name, float v);
void hr_set_2f(const hr_program *p, const char *name, float x, float y);
void hr_set_2i(const hr_program *p, const char *name, int x, int y);
void hr_set_3f(const hr_program *p, const char *name, const float v[3]);
void hr_set_m4(const hr_program *p, const char *name, const float m[16]);

/* Matrices and ranges of one render, derived from the view and the model. */
typedef struct hr_camera {
  float view[16], proj[16];
  float eye[3];
  float depth_near, depth_far;  /* depth feature 0..1 over this range */
  float px_per_unit;            /* at eye distance 1 (perspective) */
  int ortho;
  /* The whole frame (pixels) and the window drawn (GL origin: bottom left). */
  int frame_w, frame_h, win_x, win_y, win_w, win_h;
} hr_camera;

/* Floats of the camera and thickness scale the segments' bounds depend on. */
#define HR_BOUNDS_KEY 37

/* Instances [first, first + count) of the hair's draw. */
typedef struct hr_run {
  uint32_t first, count;
} hr_run;

/* The whole frame's attachments of each pass (hr_passes.c frame_tex). */
enum {
  HR_TEX_FEATURE_0, HR_TEX_FEATURE_1, HR_TEX_FEATURE_DEPTH, /* hr_pass_ms */
  HR_TEX_AC_COLOR, HR_TEX_AC_DEPTH,                         /* its alpha-corrected pass */
  HR_TEX_BG_COLOR, HR_TEX_BG_DEPTH,                         /* hr_pass_background */
  HR_TEX_GT_DEPTH,                                          /* hr_pass_gt, supersampled */
  HR_TEX_SLOTS
};
typedef struct hr_frame_tex {
  GLuint id;
  GLenum fmt;
  int w, h, samples;
} hr_frame_tex;

struct hfr_renderer {
  hr_context *ctx;
  hr_gl_table gl;               /* entry points of ctx */
  char gl_renderer[128];        /* GL_RENDERER and GL_VERSION */
  int gl_loaded;
  hr_program st, stac, shadow, abuf, head, occluder, resolve_ms, resolve_stac, resolve_abuf;
  hr_program gt_near, gt_depths, gt_cut; /* hr_gt_cull.c */
  GLuint hair_vao, hair_vbo, head_vao, head_vbo, empty_vao;
  /* The ground truth's pool of A-buffer nodes, grown as windows need and
   * kept for the next (hr_pass_gt): up to HFR_MAX_FRAGMENTS nodes. */
  GLuint abuf_nodes;
  uint32_t abuf_nodes_cap;
  /* Attachments the size of the whole (supersampled) frame, kept while the
   * next pass asks for the same size: llvmpipe zero-fills a new texture
   * (256 MiB for the depth of a 1024x1024 frame at 8x8) and a banded ground
   * truth or a frame of many passes asked for one per band or pass.
   * hfr_render releases them after each stage (hr_frame_tex_release). */
  hr_frame_tex frame_tex[HR_TEX_SLOTS];
  uint32_t points;              /* instances drawn: points - 1 */
  /* The model's points as drawn ([points][4]: x, y, z, diameter) and the
   * first point of each strand ([strands + 1]), for hr_hair_window_runs;
   * runs is its output, reused from window to window. */
  float *cull_pts;
  uint32_t *strand_first, strands;
  hr_run *runs;
  size_t runs_cap;
  /* Each segment's pixel bounds ([points - 1][4]) for the camera in
   * bounds_key (hr_cull.c), kept for the next window of that camera (the
   * bands of a ground truth, the passes of a crop); bounds_valid 0 when
   * stale. */
  float *seg_bounds;
  float *seg_area;              /* each segment's quad in pixels ([points - 1]) */
  float bounds_key[HR_BOUNDS_KEY];
  int bounds_valid;
  uint32_t max_fragments;       /* hfr_outputs.max_fragments of the frame drawn */
  int gt_cull;                  /* hfr_outputs.gt_cull of the frame drawn */
  GLsizei head_vertices;
  int has_hair, has_head;       /* has_head: an occluder is set */
  uint64_t segments;
  float centre[3], radius;      /* bounding sphere of hair (and an enclosed occluder) */
  float hair_centre[3], hair_radius; /* of the hair alone */
  /* Position and diameter of up to HR_STAT_POINTS points of the model, evenly
   * picked, for the strand widths of hfr_frame_stats. */
  float *stat_pts;              /* [n_stat][4] */
  uint32_t n_stat;
  uint32_t n_model_pts;         /* the model's points, of which stat_pts are picked */
  GLuint shadow_tex, shadow_fbo;
  int shadow_size;
  int ms_samples;               /* samples the MS framebuffer really has */
  /* hfr_msaa_positions once read: a property of the context, asked by
   * every frame that has a ground truth. */
  float msaa_pos[8];
  int msaa_pos_known;
};

/* Makes r's context current and its entry points the ones hrgl calls. */
int hr_renderer_bind(hfr_renderer *r);

#define HR_STAT_POINTS (1u << 20)

/* Camera of the view (jitter excluded) at width x height, drawing the
 * view's crop window. */
void hr_camera_from_view(const hfr_renderer *r, const hfr_view *v, hr_camera *cam);
/* The viewport of cam's whole frame, and a scissor to its window: a crop
 * is drawn into a target of the whole frame's size where only the window is
 * rasterised, cleared and read, so that every sample sees exactly the window
 * coordinates and interpolants of the whole frame (bit-exact crops) while
 * the fragment work is the window's. Resolves and reads take the window's
 * origin (win_x, win_y); hr_scissor_off ends it. */
void hr_set_viewport(const hr_camera *cam);
void hr_scissor_off(void);
/* Size of what v renders: its crop, or the whole frame. */
void hr_view_target(const hfr_view *v, int *w, int *h);
/* Light camera for the shadow map. */
void hr_camera_light(const hfr_renderer *r, const hfr_view *v, hr_camera *cam);

/* The runs of r's hair instances, in order, whose quads (hr_glsl_hair_vs,
 * with thick_scale and a pass jitter under a pixel) can cover a pixel of
 * cam's window: r->runs[0 .. *n_runs), ascending and disjoint. Instances
 * joining two strands, which the vertex shader culls, are left out; runs
 * less than 32 instances apart are joined. Drawing these runs in order
 * gives the window the fragments, in the order, that drawing every
 * instance gives it (hr_cull.c). HF_OK, HF_EINVAL (no hair set) or
 * HF_ENOMEM (r->runs kept as it was, *n_runs 0). */
int hr_hair_window_runs(hfr_renderer *r, const hr_camera *cam, float thick_scale,
                        size_t *n_runs);
/* An estimate of the fragments r's hair draws into cam's window, pixels of
 * its quads (projected length times width, at least a pixel wide) where
 * their bounds overlap the window, the occluder not counted: what a
 * window's depth complexity will be before it is drawn. HF_OK, HF_EINVAL
 * (no hair set) or HF_ENOMEM. */
int hr_hair_window_fragments(hfr_renderer *r, const hr_camera *cam, float thick_scale,
                             double *frags);

/* Passes (hr_passes.c). */
/* A texture of one level (GL_TEXTURE_2D, nearest filtering) or a
 * multisampled one of samples samples, fmt storage, w x h texels. */
GLuint hr_make_tex(GLenum target, GLenum fmt, int w, int h, int samples);
/* HF_OK when the bound framebuffer is complete, else HF_EBACKEND with
 * "<what> framebuffer incomplete" in err. */
int hr_fbo_complete(const char *what, char *err, size_t errlen);
/* Draws p's full-viewport triangle (hr_glsl_fullscreen_vs) over a w x h
 * target; sets the viewport. */
void hr_draw_fullscreen(hfr_renderer *r, const hr_program *p, int w, int h);
/* The hair vertex shader's uniforms of p for cam and v, with a sub-pixel
 * offset of (jx, jy) pixels. */
void hr_set_geometry(const hr_program *p, const hr_camera *cam, const hfr_view *v, float jx,
                     float jy);
/* Draws the hair instances that can reach cam's window (all of them for a
 * whole frame), in order, with the bound program. */
void hr_draw_hair_window(hfr_renderer *r, const hr_camera *cam, const hfr_view *v);

/* Deletes r's whole-frame attachments (r->frame_tex): a stage of
 * hfr_render that no longer needs them gives their memory back. */
void hr_frame_tex_release(hfr_renderer *r);
int hr_pass_shadow(hfr_renderer *r, const hfr_view *v, const hr_camera *light, uint32_t seed,
                   char *err, size_t errlen);
/* Sets every shading uniform of p (light, lobes, shadow map) for one pass. */
void hr_bind_shading(hfr_renderer *r, const hr_program *p, const hfr_view *v,
                     const hr_camera *cam, const hr_camera *light, uint32_t seed);
/* One 4x MSAA pass: samples [pass_samples][h][w] features into out as
 * [h][w][ms_samples][6] floats, rows top first. opaque: geometric coverage
 * and alpha 1 instead of stochastic transparency. ac, when not NULL: the
 * pass's alpha-corrected estimate [h][w][3] (colour factor, highlight,
 * alpha; hr_glsl_stac_fs), one more draw of the hair. */
int hr_pass_ms(hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
               const hr_camera *light, uint32_t seed, float jx, float jy, int opaque,
               float *out, float *ac, char *err, size_t errlen);
/* The supersampled A-buffer and its GPU resolve into gt [h][w][3] (rows top
 * first). When cpu_gt is not NULL the same lists are also read back and
 * blended on the host into cpu_gt (tests). */
int hr_pass_gt(hfr_renderer *r, const hfr_view *v, const hr_camera *light, int ss,
               float *gt, float *cpu_gt, hfr_stats *stats, char *err, size_t errlen);

/* The ground truth's transmittance cull (hr_gt_cull.c): into the depth
 * attachment of depth_fbo, which holds the occluder's depth of cam's
 * supersampled frame (LESS), writes at each pixel of cam's window the
 * depth behind which the hair's fragments are hidden by an optical depth
 * of at least HR_GT_CULL_TAU in front of them, where such a depth exists,
 * so that the A-buffer's early depth test keeps them out. v: the view
 * drawn (thickness scale). row_frags [cam->win_h], rows bottom first: at
 * least the fragments the A-buffer will then hold in each supersampled
 * row; *uncut: the window's fragments before the cut. Leaves depth_fbo
 * bound, the depth test and the scissor off; uses storage buffer bindings
 * 4 to 6. HF_OK, or HF_EBACKEND with err set. */
int hr_gt_cull(hfr_renderer *r, const hfr_view *v, const hr_camera *cam, GLuint depth_fbo,
               uint64_t *row_frags, uint64_t *uncut, char *err, size_t errlen);
/* ln(1 / transmittance) in front of a fragment the cull keeps out: each
 * such fragment, and all of them together, weigh less than e^-30 (1e-13)
 * in their subsample's blend. */
#define HR_GT_CULL_TAU 30.0f
/* The occluder, diffusely lit, at the camera's window with 4x MSAA:
 * out [h][w][2] (diffuse factor premultiplied by coverage, coverage), rows
 * top first. */
int hr_pass_background(hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
                       const hr_camera *light, float *out, char *err, size_t errlen);

/* The frame statistics of one 4x pass ([h][w][4][6]) and of the model's
 * points in cam's window. */
void hr_frame_stats(const hfr_renderer *r, const hfr_view *v, const hr_camera *cam,
                    const float *pass, int w, int h, hfr_frame_stats *fs);

/* Rotation and scale of hfr_hair_orient on n points of stride floats. */
void hr_orient_points(float *p, size_t n, size_t stride, hfr_axis up, float scale);

/* Host sort-and-blend of A-buffer lists into out [h][w][3] (colour factor,
 * highlight, alpha; rows bottom first): heads holds the window's h * ss
 * rows of w * ss list heads, row r at heads + r * heads_stride; nodes are
 * 5 32-bit words each (c, h, a, d, next), indices at or above capacity
 * ending a list. Each subsample's list is sorted by depth, then node index
 * (as the shader's resolve), and blended front to back in double. Rows of
 * pixels are split between threads (hf_parallel_chunks). max_depth and
 * long_lists, when not NULL, get the longest list's length and the number
 * of lists longer than HR_ABUF_SORT (those the shader sorts in several
 * rounds). HF_OK or HF_ENOMEM. */
int hr_abuf_blend_cpu(const uint32_t *heads, size_t heads_stride, const uint32_t *nodes,
                      uint32_t capacity, int w, int h, int ss, float *out, uint32_t *max_depth,
                      uint64_t *long_lists);

double hr_now_ms(void);

#endif
