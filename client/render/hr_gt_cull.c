/* The ground truth's transmittance cull.
 *
 * In a dense frame most of a supersampled pixel's A-buffer list lies behind
 * so many strands that its weight in the blend is nil (a 128x128 window of
 * a dense ponytail at 8x8: 575 M of its 680 M fragments left out, docs/
 * RENDERING.md, "The transmittance cull"), yet every one was shaded,
 * stored, sorted and blended, and
 * their count drew such frames in dozens of bands. Three cheap passes find,
 * per supersampled pixel, a depth behind which every hair fragment has an
 * optical depth of at least HR_GT_CULL_TAU in front of it, and write it
 * into the A-buffer's depth, whose early depth test then keeps those
 * fragments out:
 *   1. the view distance of the pixel's nearest hair fragment (atomicMin);
 *   2. the sum of -ln(1 - alpha) over its fragments in each of 16 bins of
 *      view distance past that one, bounded by edge x 2^(k/2), k = 0..15
 *      (edge = 1/2048 of the depth feature's range; integer atomics on a
 *      fixed point that rounds every term down);
 *   3. the first bound in front of which the bins sum to the threshold,
 *      plus a margin of edge / 8, as a window depth (a full-frame pass,
 *      LESS against the occluder's depth already there).
 * A fragment behind the written depth lies behind every fragment the sum
 * counted, since the margin is far above the rounding between window depth
 * and view distance (the A-buffer orders by view distance, depth01), so the
 * fragments in front of it leave it a transmittance under e^-tau; the
 * weights of all of them together are under that too, so the subsample's
 * colour, highlight and alpha move by less.
 *
 * Step 1 also counts each pixel's fragments and step 2 those of each bin,
 * so that step 3 leaves, per pixel, a bound on what the A-buffer will hold
 * there: the window's A-buffer is then made the right size at once, or its
 * bands planned, without drawing it to count.
 *
 * The steps keep their values in storage buffers of the window's pixels
 * and draw with the A-buffer's own viewport, scissor and depth test (the
 * occluder), so that they see exactly its fragments; the window is taken
 * in strips of rows of at most CULL_STRIP_BYTES of them (136 bytes a
 * pixel), so a 1024x1024 window at 8x8 needs 256 MiB, not 8.5 GiB. */
#include <stdio.h>

#include "hr_internal.h"

#define CULL_STRIP_BYTES ((size_t)256 << 20)
#define CULL_BINS 16
#define CULL_COUNT_WORDS 17 /* hr_glsl_gt_near_fs */
#define CULL_FIXED 4096.0f /* optical depth's fixed point (hr_glsl_gt_depths_fs) */

/* The uniforms every step reads: the strip's pixels and the bounds. */
static void set_strip(const hr_program *p, const hr_camera *s) {
  const float edge = (s->depth_far - s->depth_near) / 2048;
  hr_set_2i(p, "u_win_lo", s->win_x, s->win_y);
  hr_set_2i(p, "u_win_hi", s->win_x + s->win_w, s->win_y + s->win_h);
  hr_set_i(p, "u_width", s->win_w);
  hr_set_f(p, "u_edge", edge);
  hr_set_f(p, "u_margin", edge / 8);
}

int hr_gt_cull(hfr_renderer *r, const hfr_view *v, const hr_camera *cam, GLuint depth_fbo,
               uint64_t *row_frags, uint64_t *uncut, char *err, size_t errlen) {
  *uncut = 0;
  const int W = cam->win_w, H = cam->win_h;
  const size_t px_bytes = sizeof(uint32_t) * (1 + CULL_BINS + CULL_COUNT_WORDS);
  size_t rows = CULL_STRIP_BYTES / ((size_t)W * px_bytes);
  if (rows < 1) rows = 1;
  if (rows > (size_t)H) rows = (size_t)H;
  const int SH = (int)rows;
  GLuint buf[3] = {0, 0, 0};
  hrgl.GenBuffers(3, buf);
  hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, buf[0]);
  hrgl.BufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)(sizeof(uint32_t) * (size_t)W * SH),
                  NULL, GL_DYNAMIC_COPY);
  hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, buf[1]);
  hrgl.BufferData(GL_SHADER_STORAGE_BUFFER,
                  (GLsizeiptr)(sizeof(uint32_t) * CULL_BINS * (size_t)W * SH), NULL,
                  GL_DYNAMIC_COPY);
  hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, buf[2]);
  hrgl.BufferData(GL_SHADER_STORAGE_BUFFER,
                  (GLsizeiptr)(sizeof(uint32_t) * CULL_COUNT_WORDS * (size_t)W * SH), NULL,
                  GL_DYNAMIC_COPY);
  for (GLuint k = 0; k < 3; k++) hrgl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 4 + k, buf[k]);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, depth_fbo);
  int rc = hr_gl_check("ground-truth cull buffers", err, errlen);
  const uint32_t far_bits = 0xFFFFFFFFu, zero = 0;
  for (int y0 = 0; rc == HF_OK && y0 < H; y0 += SH) {
    hr_camera strip = *cam;
    strip.win_y = cam->win_y + y0;
    strip.win_h = H - y0 < SH ? H - y0 : SH;
    hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, buf[0]);
    hrgl.ClearBufferData(GL_SHADER_STORAGE_BUFFER, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT,
                         &far_bits);
    for (int k = 1; k < 3; k++) {
      hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, buf[k]);
      hrgl.ClearBufferData(GL_SHADER_STORAGE_BUFFER, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT,
                           &zero);
    }
    hr_set_viewport(&strip);
    hrgl.Enable(GL_DEPTH_TEST);
    hrgl.DepthFunc(GL_LESS);
    hrgl.DepthMask(GL_FALSE);
    /* 1. Nearest hair fragment. */
    hrgl.UseProgram(r->gt_near.id);
    hr_set_geometry(&r->gt_near, &strip, v, 0, 0);
    set_strip(&r->gt_near, &strip);
    hr_draw_hair_window(r, &strip, v);
    hrgl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    /* 2. Optical depth in each bin. */
    hrgl.UseProgram(r->gt_depths.id);
    hr_set_geometry(&r->gt_depths, &strip, v, 0, 0);
    set_strip(&r->gt_depths, &strip);
    hr_draw_hair_window(r, &strip, v);
    hrgl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    /* 3. The cut, into the A-buffer's depth. */
    hrgl.DepthMask(GL_TRUE);
    hrgl.UseProgram(r->gt_cut.id);
    set_strip(&r->gt_cut, &strip);
    hr_set_u(&r->gt_cut, "u_tau", (unsigned)(HR_GT_CULL_TAU * CULL_FIXED));
    hr_set_f(&r->gt_cut, "u_p10", strip.proj[10]);
    hr_set_f(&r->gt_cut, "u_p14", strip.proj[14]);
    hr_set_f(&r->gt_cut, "u_near_lim", strip.depth_near);
    hr_set_f(&r->gt_cut, "u_far_lim", strip.depth_far);
    hr_draw_fullscreen(r, &r->gt_cut, strip.frame_w, strip.frame_h);
    hrgl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    rc = hr_gl_check("ground-truth cull", err, errlen);
    /* Each row's bound on what the A-buffer will hold. */
    const uint32_t *cnt = NULL;
    if (rc == HF_OK) {
      hrgl.BindBuffer(GL_SHADER_STORAGE_BUFFER, buf[2]);
      cnt = hrgl.MapBufferRange(
          GL_SHADER_STORAGE_BUFFER, 0,
          (GLsizeiptr)(sizeof(uint32_t) * CULL_COUNT_WORDS * (size_t)W * strip.win_h),
          GL_MAP_READ_BIT);
      rc = hr_gl_check("ground-truth cull counts", err, errlen);
      if (rc == HF_OK && !cnt) {
        if (err) snprintf(err, errlen, "ground-truth cull counts: the GL gave no pointer");
        rc = HF_EBACKEND;
      }
    }
    if (cnt) {
      for (int y = 0; y < strip.win_h; y++) {
        uint64_t n = 0;
        for (int x = 0; x < W; x++) {
          const uint32_t *w = cnt + ((size_t)y * W + x) * CULL_COUNT_WORDS;
          n += w[0], *uncut += w[16];
        }
        row_frags[y0 + y] = n;
      }
      hrgl.UnmapBuffer(GL_SHADER_STORAGE_BUFFER);
    }
  }
  hrgl.Disable(GL_DEPTH_TEST);
  hr_scissor_off();
  hrgl.DeleteBuffers(3, buf);
  return rc;
}
