/* Where the 4x MSAA samples sit in a pixel, and whether they sit on the
 * ground truth's sub-pixel grid. A 4x4 supersampled truth shares all 4
 * standard MSAA positions, which biases every score of the first pass's
 * samples upward on opaque strands; the renderer reports how many a frame's
 * truth shares (hfr_stats.gt_shared_positions) so that no figure is made
 * against such a truth unknowingly, and writes it into the frame's EXR
 * header, where it stays with the frame wherever the file goes. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "hr_gl.h"
#include "hr_internal.h"

int hfr_msaa_positions(hfr_renderer *r, float pos[8], char *err, size_t errlen) {
  if (!r || !pos) return HF_EINVAL;
  if (r->msaa_pos_known) {
    memcpy(pos, r->msaa_pos, sizeof r->msaa_pos);
    return HF_OK;
  }
  int rc = hr_renderer_bind(r);
  if (rc != HF_OK) return rc;
  /* Errors left by earlier calls are not this query's (a bounded drain: a
   * lost context may keep reporting one). */
  for (int i = 0; i < 16 && hrgl.GetError() != GL_NO_ERROR; i++) {
  }
  /* A 1x1 target of the samples' count and format is enough: positions are
   * a property of the sample count and the implementation. */
  GLuint tex = 0, fbo = 0;
  hrgl.GenTextures(1, &tex);
  hrgl.BindTexture(GL_TEXTURE_2D_MULTISAMPLE, tex);
  hrgl.TexStorage2DMultisample(GL_TEXTURE_2D_MULTISAMPLE, 4, GL_RGBA32F, 1, 1, GL_TRUE);
  hrgl.GenFramebuffers(1, &fbo);
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, fbo);
  hrgl.FramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D_MULTISAMPLE, tex,
                            0);
  GLint samples = 0;
  if (hrgl.CheckFramebufferStatus(GL_FRAMEBUFFER) == GL_FRAMEBUFFER_COMPLETE)
    hrgl.GetIntegerv(GL_SAMPLES, &samples);
  if (samples != 4) {
    if (err) snprintf(err, errlen, "no 4-sample framebuffer (GL_SAMPLES %d)", (int)samples);
    rc = HF_EUNSUPPORTED;
  }
  for (GLuint k = 0; rc == HF_OK && k < 4; k++)
    hrgl.GetMultisamplefv(GL_SAMPLE_POSITION, k, pos + 2 * k);
  GLenum e = hrgl.GetError();
  if (rc == HF_OK && e != GL_NO_ERROR) {
    if (err) snprintf(err, errlen, "glGetMultisamplefv failed (0x%04x)", (unsigned)e);
    rc = HF_EBACKEND;
  }
  for (int k = 0; rc == HF_OK && k < 8; k++)
    if (!(pos[k] >= 0 && pos[k] < 1)) {
      if (err) snprintf(err, errlen, "sample position %g outside the pixel", (double)pos[k]);
      rc = HF_EBACKEND;
    }
  hrgl.BindFramebuffer(GL_FRAMEBUFFER, 0);
  hrgl.DeleteFramebuffers(1, &fbo);
  hrgl.DeleteTextures(1, &tex);
  if (rc == HF_OK) {
    memcpy(r->msaa_pos, pos, sizeof r->msaa_pos);
    r->msaa_pos_known = 1;
  }
  return rc;
}

/* Whether x is (i + 0.5) / ss for an integer i in [0, ss). */
static int on_centre(float x, int ss) {
  double i = x * ss - 0.5;
  return i > -0.5 && i < ss - 0.5 && fabs(i - floor(i + 0.5)) * (1.0 / ss) < 1e-4;
}

int hfr_gt_shared_positions(const float pos[8], int ss) {
  if (!pos || ss < 1) return 0;
  int n = 0;
  for (int k = 0; k < 4; k++) n += on_centre(pos[2 * k], ss) && on_centre(pos[2 * k + 1], ss);
  return n;
}

int hfr_frame_write(const char *path, const hf_image *img, int half, const hfr_outputs *out,
                    const hfr_stats *stats) {
  if (!out || !stats) return HF_EINVAL;
  hf_exr_int_attr attrs[2] = {{HFR_EXR_ATTR_GT_SUPERSAMPLE, out->gt_supersample},
                              {HFR_EXR_ATTR_GT_SHARED, stats->gt_shared_positions}};
  return hf_exr_write_attrs(path, img, half, attrs, out->gt_supersample > 0 ? 2 : 1);
}
