/* Renderer lifetime: context, programs, the uploaded model, cameras. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hr_internal.h"
#include "hr_math.h"
#include "hr_shaders.h"

#define VERTEX_FLOATS 9 /* pos 3, tangent 3, thickness, opacity, strand id */

const char *hfr_renderer_platform(const hfr_renderer *r) {
  return r ? hr_context_platform(r->ctx) : "none";
}

const char *hfr_renderer_gl_name(const hfr_renderer *r) {
  return r ? r->gl_renderer : "none";
}

int hr_renderer_bind(hfr_renderer *r) {
  if (!r->gl_loaded) return HF_EINVAL;
  int rc = hr_context_make_current(r->ctx);
  if (rc == HF_OK) hrgl = r->gl;
  return rc;
}

void hfr_renderer_destroy(hfr_renderer *r) {
  if (!r) return;
  if (r->ctx && hr_renderer_bind(r) == HF_OK) {
    hr_program *progs[] = {&r->st,       &r->stac,     &r->shadow,     &r->abuf,
                           &r->head,     &r->occluder, &r->resolve_ms, &r->resolve_stac,
                           &r->resolve_abuf, &r->gt_near,   &r->gt_depths,   &r->gt_cut};
    for (size_t i = 0; i < sizeof progs / sizeof progs[0]; i++) hr_program_free(progs[i]);
    GLuint vaos[] = {r->hair_vao, r->head_vao, r->empty_vao};
    GLuint bufs[] = {r->hair_vbo, r->head_vbo};
    hrgl.DeleteVertexArrays(3, vaos);
    hrgl.DeleteBuffers(2, bufs);
    if (r->shadow_tex) hrgl.DeleteTextures(1, &r->shadow_tex);
    if (r->shadow_fbo) hrgl.DeleteFramebuffers(1, &r->shadow_fbo);
    if (r->abuf_nodes) hrgl.DeleteBuffers(1, &r->abuf_nodes);
    hr_frame_tex_release(r);
  }
  hr_context_destroy(r->ctx);
  free(r->stat_pts);
  free(r->cull_pts);
  free(r->strand_first);
  free(r->runs);
  free(r->seg_bounds);
  free(r->seg_area);
  free(r);
}

/* Uploads the occluder's triangles (position, normal), or none. */
static int upload_occluder(hfr_renderer *r, const hfr_mesh *m) {
  r->has_head = 0;
  r->head_vertices = 0;
  if (!m || !m->vertices) return HF_OK;
  if (m->vertices > 3 * HFR_MESH_MAX_TRIANGLES || !m->v) return HF_ERANGE;
  if (!r->head_vao) {
    hrgl.GenVertexArrays(1, &r->head_vao);
    hrgl.GenBuffers(1, &r->head_vbo);
  }
  hrgl.BindVertexArray(r->head_vao);
  hrgl.BindBuffer(GL_ARRAY_BUFFER, r->head_vbo);
  hrgl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)((size_t)m->vertices * 6 * sizeof(float)), m->v,
                  GL_STATIC_DRAW);
  hrgl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)0);
  hrgl.EnableVertexAttribArray(0);
  hrgl.VertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float),
                           (void *)(3 * sizeof(float)));
  hrgl.EnableVertexAttribArray(1);
  hrgl.BindVertexArray(0);
  r->head_vertices = (GLsizei)m->vertices;
  r->has_head = 1;
  return HF_OK;
}

/* Grows the sphere (centre, *radius) just enough to contain q. */
static void grow_sphere(float centre[3], float *radius, const float q[3]) {
  float d[3] = {q[0] - centre[0], q[1] - centre[1], q[2] - centre[2]};
  float l = hr_len(d);
  if (l <= *radius) return;
  float nr = 0.5f * (*radius + l);
  for (int c = 0; c < 3; c++) centre[c] += d[c] / l * (nr - *radius);
  *radius = nr;
}

void hfr_renderer_bounds(const hfr_renderer *r, float centre[3], float *radius) {
  memcpy(centre, r->centre, 3 * sizeof(float));
  *radius = r->radius;
}

int hfr_renderer_set_occluder(hfr_renderer *r, const hfr_mesh *m, int enclose, char *err,
                              size_t errlen) {
  if (!r || !r->has_hair) return HF_EINVAL;
  int rc = hr_renderer_bind(r);
  if (rc != HF_OK) return rc;
  memcpy(r->centre, r->hair_centre, sizeof r->centre);
  r->radius = r->hair_radius;
  if ((rc = upload_occluder(r, m)) != HF_OK) {
    if (err) snprintf(err, errlen, "occluder of %u vertices: too large", m->vertices);
    return rc;
  }
  if (m && enclose)
    for (uint32_t i = 0; i < m->vertices; i++) grow_sphere(r->centre, &r->radius, m->v + 6 * (size_t)i);
  return hr_gl_check("occluder upload", err, errlen);
}

int hfr_renderer_create(const char *platform, hfr_renderer **out, char *err, size_t errlen) {
  if (!out) return HF_EINVAL;
  *out = NULL;
  hfr_renderer *r = calloc(1, sizeof *r);
  if (!r) return HF_ENOMEM;
  int rc = hr_context_create(platform, &r->ctx, err, errlen);
  if (rc == HF_OK) rc = hr_gl_load(r->ctx, &r->gl, err, errlen);
  if (rc == HF_OK) {
    r->gl_loaded = 1;
    const char *name = (const char *)hrgl.GetString(GL_RENDERER);
    const char *ver = (const char *)hrgl.GetString(GL_VERSION);
    snprintf(r->gl_renderer, sizeof r->gl_renderer, "%s, %s", name ? name : "?",
             ver ? ver : "?");
  }
  if (rc != HF_OK) {
    hfr_renderer_destroy(r);
    return rc;
  }
  struct {
    hr_program *p;
    const char *vs, *gs, *fs;
  } progs[] = {
    {&r->st, hr_glsl_hair_vs, NULL, hr_glsl_st_fs},
    {&r->stac, hr_glsl_hair_vs, NULL, hr_glsl_stac_fs},
    {&r->shadow, hr_glsl_hair_vs, NULL, hr_glsl_shadow_fs},
    {&r->abuf, hr_glsl_hair_vs, NULL, hr_glsl_abuf_fs},
    {&r->gt_near, hr_glsl_hair_vs, NULL, hr_glsl_gt_near_fs},
    {&r->gt_depths, hr_glsl_hair_vs, NULL, hr_glsl_gt_depths_fs},
    {&r->gt_cut, hr_glsl_fullscreen_vs, NULL, hr_glsl_gt_cut_fs},
    {&r->head, hr_glsl_head_vs, NULL, hr_glsl_head_fs},
    {&r->occluder, hr_glsl_head_vs, NULL, hr_glsl_occluder_fs},
    {&r->resolve_ms, hr_glsl_fullscreen_vs, NULL, hr_glsl_resolve_ms_fs},
    {&r->resolve_stac, hr_glsl_fullscreen_vs, NULL, hr_glsl_resolve_stac_fs},
    {&r->resolve_abuf, hr_glsl_fullscreen_vs, NULL, hr_glsl_resolve_abuf_fs},
  };
  for (size_t i = 0; i < sizeof progs / sizeof progs[0]; i++) {
    rc = hr_program_build(progs[i].p, progs[i].vs, progs[i].gs, progs[i].fs, err, errlen);
    if (rc != HF_OK) {
      hfr_renderer_destroy(r);
      return rc;
    }
  }
  hrgl.GenVertexArrays(1, &r->empty_vao);
  if ((rc = hr_gl_check("renderer setup", err, errlen))) {
    hfr_renderer_destroy(r);
    return rc;
  }
  r->radius = 1;
  *out = r;
  return HF_OK;
}

int hfr_renderer_set_hair(hfr_renderer *r, const hfr_hair *h, int head, char *err,
                          size_t errlen) {
  if (!r || !h || !h->pos || !h->strands || h->points <= h->strands) return HF_EINVAL;
  if (h->strands > HFR_MAX_STRANDS || h->points > HFR_MAX_POINTS) return HF_ERANGE;
  int rc = hr_renderer_bind(r);
  if (rc != HF_OK) return rc;
  /* Check the strand layout before trusting any offset computed from it. */
  uint64_t total = 0;
  for (uint32_t s = 0; s < h->strands; s++) total += hfr_hair_strand_segments(h, s) + 1u;
  if (total != h->points) {
    if (err) snprintf(err, errlen, "segment counts do not add up to the point count");
    return HF_EINVAL;
  }
  size_t bytes = (size_t)h->points * VERTEX_FLOATS * sizeof(float);
  if (bytes > ((size_t)1 << 31)) {
    if (err) snprintf(err, errlen, "model too large for one vertex buffer");
    return HF_ERANGE;
  }
  /* A radius float cannot hold, or one whose squares it cannot, frames
   * nothing: an empty frame would pass for a rendering. */
  if ((rc = hfr_hair_check_extent(h, 1, err, errlen)) != HF_OK) return rc;
  float *v = malloc(bytes);
  if (!v) return HF_ENOMEM;
  float centre[3], radius;
  hfr_hair_bounds(h, centre, &radius);
  /* The same rules the loader documents and warns about. */
  float def_thick = hfr_hair_default_thickness(h, radius, NULL);
  float def_opac = 1 - hfr_hair_default_transparency(h, NULL);
  const float *thick = hfr_hair_thickness_all_zero(h) ? NULL : h->thickness;

  size_t base = 0;
  for (uint32_t s = 0; s < h->strands; s++) {
    uint32_t n = hfr_hair_strand_segments(h, s) + 1;
    for (uint32_t i = 0; i < n; i++) {
      size_t a = base + (i ? i - 1 : 0), b = base + (i + 1 < n ? i + 1 : i);
      float *o = v + (base + i) * VERTEX_FLOATS;
      const float *p = h->pos + 3 * (base + i);
      float t[3] = {h->pos[3 * b] - h->pos[3 * a], h->pos[3 * b + 1] - h->pos[3 * a + 1],
                    h->pos[3 * b + 2] - h->pos[3 * a + 2]};
      if (hr_len(t) < 1e-20f) t[0] = 0, t[1] = -1, t[2] = 0;
      hr_normalize(t);
      o[0] = p[0], o[1] = p[1], o[2] = p[2];
      o[3] = t[0], o[4] = t[1], o[5] = t[2];
      o[6] = thick ? thick[base + i] : def_thick;
      o[7] = h->transparency ? 1 - h->transparency[base + i] : def_opac;
      o[8] = (float)s;
    }
    base += n;
  }
  if (!r->hair_vao) {
    hrgl.GenVertexArrays(1, &r->hair_vao);
    hrgl.GenBuffers(1, &r->hair_vbo);
  }
  hrgl.BindVertexArray(r->hair_vao);
  hrgl.BindBuffer(GL_ARRAY_BUFFER, r->hair_vbo);
  hrgl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)bytes, v, GL_STATIC_DRAW);
  /* Instance i is the segment from point i to point i + 1: attributes 0-4
   * read point i, 5-9 the next one. */
  const GLsizei stride = VERTEX_FLOATS * sizeof(float);
  const GLint sizes[5] = {3, 3, 1, 1, 1}, offs[5] = {0, 3, 6, 7, 8};
  for (GLuint end = 0; end < 2; end++)
    for (GLuint a = 0; a < 5; a++) {
      GLuint loc = 5 * end + a;
      hrgl.VertexAttribPointer(loc, sizes[a], GL_FLOAT, GL_FALSE, stride,
                               (void *)((offs[a] + end * VERTEX_FLOATS) * sizeof(float)));
      hrgl.VertexAttribDivisor(loc, 1);
      hrgl.EnableVertexAttribArray(loc);
    }
  hrgl.BindVertexArray(0);
  /* Evenly picked points for the strand-width statistics. */
  uint32_t pick = h->points / HR_STAT_POINTS + 1, n_stat = (h->points + pick - 1) / pick;
  float *sp = realloc(r->stat_pts, sizeof(float) * 4 * n_stat);
  if (!sp) {
    free(v);
    r->strands = 0, r->has_hair = 0; /* the buffer above holds the new model */
    return HF_ENOMEM;
  }
  r->stat_pts = sp;
  r->n_stat = n_stat;
  r->n_model_pts = h->points;
  for (uint32_t k = 0; k < n_stat; k++)
    memcpy(sp + 4 * k, v + (size_t)k * pick * VERTEX_FLOATS, 3 * sizeof(float)),
        sp[4 * k + 3] = v[(size_t)k * pick * VERTEX_FLOATS + 6];
  /* Every point's position and diameter, and where each strand starts, for
   * drawing a window's instances only (hr_hair_window_runs). */
  free(r->seg_bounds); /* sized for the model before: made again when needed */
  free(r->seg_area);
  r->seg_bounds = NULL, r->seg_area = NULL, r->bounds_valid = 0;
  float *cp = realloc(r->cull_pts, sizeof(float) * 4 * (size_t)h->points);
  if (cp) r->cull_pts = cp;
  uint32_t *sf = cp ? realloc(r->strand_first, sizeof(uint32_t) * ((size_t)h->strands + 1)) : NULL;
  if (sf) r->strand_first = sf;
  if (!cp || !sf) {
    free(v);
    r->strands = 0, r->has_hair = 0; /* the buffer above holds the new model */
    return HF_ENOMEM;
  }
  for (size_t k = 0; k < h->points; k++)
    memcpy(cp + 4 * k, v + k * VERTEX_FLOATS, 3 * sizeof(float)),
        cp[4 * k + 3] = v[k * VERTEX_FLOATS + 6];
  sf[0] = 0;
  for (uint32_t s = 0; s < h->strands; s++) sf[s + 1] = sf[s] + hfr_hair_strand_segments(h, s) + 1;
  r->strands = h->strands;
  free(v);
  r->points = h->points;
  r->segments = hfr_hair_total_segments(h);
  r->has_hair = 1;
  memcpy(r->hair_centre, centre, sizeof centre);
  r->hair_radius = radius;
  hfr_mesh head_mesh = {0};
  if (head) {
    hfr_ellipsoid e;
    hfr_style_body(HFR_STYLE_STRAIGHT, &e);
    if ((rc = hfr_mesh_ellipsoid(&e, 48, 24, &head_mesh)) != HF_OK) return rc;
    /* Enclose the head too: it can stick out of short hair. */
    const float hr_[3] = HFR_HEAD_RADII;
    for (int k = 0; k < 3; k++)
      for (int sgn = -1; sgn <= 1; sgn += 2) {
        float q[3] = {0, 0, 0};
        q[k] = sgn * hr_[k];
        grow_sphere(centre, &radius, q);
      }
  }
  rc = upload_occluder(r, head ? &head_mesh : NULL);
  hfr_mesh_free(&head_mesh);
  if (rc != HF_OK) return rc;
  memcpy(r->centre, centre, sizeof centre);
  r->radius = radius;
  return hr_gl_check("hair upload", err, errlen);
}

void hr_view_target(const hfr_view *v, int *w, int *h) {
  *w = v->crop_w > 0 ? v->crop_w : v->width;
  *h = v->crop_w > 0 ? v->crop_h : v->height;
}

void hr_set_viewport(const hr_camera *cam) {
  hrgl.Viewport(0, 0, cam->frame_w, cam->frame_h);
  if (cam->win_w == cam->frame_w && cam->win_h == cam->frame_h) {
    hrgl.Disable(GL_SCISSOR_TEST);
  } else {
    /* Grown to whole 16x16-pixel blocks: llvmpipe shades 4x4 blocks, and
     * those the scissor cuts lose some of their A-buffer insertions (the
     * same fault as a clipped full-screen triangle, see draw_fullscreen);
     * whole blocks are shaded as in the whole frame. Only the window is
     * read back. */
    int x0 = cam->win_x & ~15, y0 = cam->win_y & ~15;
    int x1 = (cam->win_x + cam->win_w + 15) & ~15, y1 = (cam->win_y + cam->win_h + 15) & ~15;
    if (x1 > cam->frame_w) x1 = cam->frame_w;
    if (y1 > cam->frame_h) y1 = cam->frame_h;
    hrgl.Enable(GL_SCISSOR_TEST);
    hrgl.Scissor(x0, y0, x1 - x0, y1 - y0);
  }
}

void hr_scissor_off(void) { hrgl.Disable(GL_SCISSOR_TEST); }

void hr_camera_from_view(const hfr_renderer *r, const hfr_view *v, hr_camera *cam) {
  float d[3];
  hr_dir_from_angles(v->cam_yaw_deg, v->cam_pitch_deg, d);
  float dist = v->cam_distance * r->radius;
  for (int k = 0; k < 3; k++) cam->eye[k] = r->centre[k] + d[k] * dist;
  float up[3] = {0, 1, 0};
  hr_mat_look_at(cam->eye, r->centre, up, cam->view);
  float n = fmaxf(dist - 1.2f * r->radius, 0.02f * r->radius), f = dist + 1.2f * r->radius;
  /* --fov spans the frame's shorter side: the vertical one of a square or
   * landscape frame, the horizontal one of a portrait frame, so that at the
   * default distance the bounding sphere is in view at any aspect (a
   * vertical fov cut the sides of a portrait frame's model off). */
  float aspect = (float)v->width / v->height, fovy = hr_deg(v->cam_fov_deg);
  if (aspect < 1) fovy = 2 * atanf(tanf(0.5f * fovy) / aspect);
  hr_mat_perspective(fovy, aspect, n, f, cam->proj);
  cam->depth_near = dist - r->radius;
  cam->depth_far = dist + r->radius;
  cam->px_per_unit = cam->proj[5] * v->height * 0.5f;
  cam->ortho = 0;
  cam->frame_w = v->width, cam->frame_h = v->height;
  hr_view_target(v, &cam->win_w, &cam->win_h);
  cam->win_x = v->crop_w > 0 ? v->crop_x : 0;
  cam->win_y = v->crop_w > 0 ? v->height - v->crop_y - v->crop_h : 0;
}

void hr_camera_light(const hfr_renderer *r, const hfr_view *v, hr_camera *cam) {
  float d[3];
  hr_dir_from_angles(v->light_yaw_deg, v->light_pitch_deg, d);
  float R = r->radius;
  float dist = v->light_directional ? 3 * R : v->light_distance * R;
  for (int k = 0; k < 3; k++) cam->eye[k] = r->centre[k] + d[k] * dist;
  float up[3] = {0, 1, 0};
  hr_mat_look_at(cam->eye, r->centre, up, cam->view);
  float n = fmaxf(dist - 1.05f * R, 0.02f * R), f = dist + 1.05f * R;
  int size = v->shadow_size > 0 ? v->shadow_size : 1;
  if (v->light_directional) {
    hr_mat_ortho(-1.05f * R, 1.05f * R, -1.05f * R, 1.05f * R, n, f, cam->proj);
    cam->ortho = 1;
  } else {
    float half = asinf(fminf(1.05f / v->light_distance, 0.999f));
    hr_mat_perspective(2 * half, 1, n, f, cam->proj);
    cam->ortho = 0;
  }
  cam->depth_near = n;
  cam->depth_far = f;
  cam->px_per_unit = cam->proj[5] * size * 0.5f;
  cam->frame_w = cam->frame_h = cam->win_w = cam->win_h = size;
  cam->win_x = cam->win_y = 0;
}
