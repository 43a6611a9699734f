/* hfr_render: the passes of one frame and the channels they fill; views;
 * the one-call hfr_render_frame; composites. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hr_internal.h"
#include "hr_math.h"

void hfr_view_defaults(hfr_view *v) {
  memset(v, 0, sizeof *v);
  v->width = v->height = 256;
  v->cam_distance = 3.0f;
  v->cam_yaw_deg = 35;
  v->cam_pitch_deg = 10;
  v->cam_fov_deg = 40;
  v->light_yaw_deg = -60;
  v->light_pitch_deg = 45;
  v->light_distance = 4;
  v->alpha_r_deg = -7.5f;
  v->alpha_trt_deg = 11.25f;
  v->ambient = 0.08f;
  v->shadow_size = 1024;
  v->shadow_bias = 0.01f;
  v->thickness_scale = 1;
  const float hair[3] = {0.32f, 0.17f, 0.08f}, light[3] = {1, 1, 1}, bg[3] = {0.55f, 0.6f, 0.65f};
  const float skin[3] = {0.56f, 0.36f, 0.27f};
  memcpy(v->hair_color, hair, sizeof hair);
  memcpy(v->light_color, light, sizeof light);
  memcpy(v->background, bg, sizeof bg);
  memcpy(v->occluder_color, skin, sizeof skin);
}

void hfr_view_randomize(hfr_view *v, uint64_t seed) {
  hr_rng g = {seed ^ 0x6a09e667f3bcc908ull};
  v->cam_distance = hr_rng_range(&g, 2.4f, 4.0f);
  v->cam_yaw_deg = hr_rng_range(&g, 0, 360);
  v->cam_pitch_deg = hr_rng_range(&g, -15, 35);
  v->light_yaw_deg = hr_rng_range(&g, 0, 360);
  v->light_pitch_deg = hr_rng_range(&g, -10, 70);
  v->light_distance = hr_rng_range(&g, 2.5f, 6.0f);
  v->alpha_r_deg = hr_rng_range(&g, -10, -5);
  v->alpha_trt_deg = -1.5f * v->alpha_r_deg;
  /* Natural hair albedos, black to blond and red, jittered. */
  static const float palette[][3] = {{0.02f, 0.015f, 0.01f}, {0.09f, 0.05f, 0.025f},
                                     {0.32f, 0.17f, 0.08f},  {0.65f, 0.5f, 0.3f},
                                     {0.45f, 0.15f, 0.05f},  {0.6f, 0.6f, 0.6f}};
  const float *c = palette[hr_rng_next(&g) % (sizeof palette / sizeof palette[0])];
  float j = hr_rng_range(&g, 0.8f, 1.2f);
  for (int k = 0; k < 3; k++) v->hair_color[k] = fminf(1.0f, c[k] * j);
  float warm = hr_rng_range(&g, -0.1f, 0.1f);
  v->light_color[0] = 1 + warm, v->light_color[1] = 1, v->light_color[2] = 1 - warm;
  float b = hr_rng_range(&g, 0.1f, 0.8f);
  for (int k = 0; k < 3; k++) v->background[k] = b * hr_rng_range(&g, 0.85f, 1.15f);
  /* Skin, light to dark (linear albedo), from its own stream so that the
   * draws above stay those of earlier versions. */
  hr_rng gs = {seed ^ 0x3c6ef372fe94f82bull};
  static const float skins[][3] = {{0.61f, 0.42f, 0.33f}, {0.56f, 0.36f, 0.27f},
                                   {0.39f, 0.24f, 0.16f}, {0.2f, 0.12f, 0.08f}};
  const float *sk = skins[hr_rng_next(&gs) % (sizeof skins / sizeof skins[0])];
  for (int k = 0; k < 3; k++) v->occluder_color[k] = sk[k];
}

int hfr_outputs_channels(const hfr_outputs *o) {
  return o->spp * HF_FEATURES_PER_SAMPLE + (o->gt_supersample > 0 ? 3 : 0) + 3 * o->n_st +
         (o->opaque_samples > 0 ? 3 : 0) + (o->alpha_corrected ? 3 : 0) +
         (o->background_layer ? 4 : 0);
}

static int bad(char *err, size_t errlen, const char *msg) {
  if (err) snprintf(err, errlen, "%s", msg);
  return HF_EINVAL;
}

static int validate(const hfr_view *v, const hfr_outputs *o, char *err, size_t errlen) {
  if (v->width < 1 || v->height < 1 || v->width > 8192 || v->height > 8192)
    return bad(err, errlen, "size must be 1..8192 on each side");
  if (!(v->cam_distance > 1.05f) || !(v->cam_fov_deg > 1 && v->cam_fov_deg < 170))
    return bad(err, errlen, "camera must be outside the hair (distance > 1.05) with fov 1..170");
  if (!v->light_directional && !(v->light_distance > 1.1f))
    return bad(err, errlen, "point light must be outside the hair (distance > 1.1)");
  if (v->shadow_size < 0 || v->shadow_size > 8192 || !(v->thickness_scale > 0))
    return bad(err, errlen, "shadow size 0..8192 and a positive thickness scale");
  if (v->crop_w != 0 &&
      (v->crop_w < 1 || v->crop_h < 1 || v->crop_x < 0 || v->crop_y < 0 ||
       v->crop_x > v->width - v->crop_w || v->crop_y > v->height - v->crop_h))
    return bad(err, errlen, "the crop window must lie inside the frame (x, y >= 0, "
                            "x + w <= width, y + h <= height)");
  if (o->spp < 0 || o->spp > HF_MAX_SPP) return bad(err, errlen, "spp must be 0..16");
  if (o->gt_supersample < 0 || o->gt_supersample > 8)
    return bad(err, errlen, "ground-truth supersampling must be 0..8");
  if (o->n_st < 0 || o->n_st > HFR_MAX_BASELINES) return bad(err, errlen, "too many baselines");
  for (int i = 0; i < o->n_st; i++)
    if (o->st_spp[i] < 1 || o->st_spp[i] > HFR_MAX_ST_SPP)
      return bad(err, errlen, "stochastic baselines take 1..256 spp");
  if (o->opaque_samples < 0 || o->opaque_samples % 4 || o->opaque_samples > 64)
    return bad(err, errlen, "opaque samples must be a multiple of 4 up to 64");
  if (o->gt_cull < HFR_GT_CULL_AUTO || o->gt_cull > HFR_GT_CULL_ON)
    return bad(err, errlen, "the ground truth's cull must be HFR_GT_CULL_AUTO, _OFF or _ON");
  if (hfr_outputs_channels(o) == 0) return bad(err, errlen, "nothing to render");
  return HF_OK;
}

/* Sub-pixel offset of pass p in pixels (none for the first): the R2
 * sequence. */
static void pass_jitter(int p, float *jx, float *jy) {
  if (p == 0) {
    *jx = *jy = 0;
    return;
  }
  *jx = (float)(fmod(0.5 + p * 0.7548776662466927, 1.0) - 0.5);
  *jy = (float)(fmod(0.5 + p * 0.5698402909980532, 1.0) - 0.5);
}

/* Pass p's hash seed. */
static uint32_t pass_seed(uint32_t seed, int p) { return seed * 0x9E3779B1u + (uint32_t)p * 7919u; }

static void set_name(hf_image *img, int c, const char *prefix, const char *name) {
  snprintf(img->names[c], sizeof img->names[c], "%s%s%s", prefix, *prefix ? "." : "", name);
}

/* Adds the covered samples [first, first + n) of a pass to a running
 * stochastic estimate acc [px][3] = (sum colour, sum highlight, covered). */
static void accumulate(const float *pass, size_t px, int S, int first, int n, float *acc) {
  for (size_t i = 0; i < px; i++)
    for (int s = first; s < first + n; s++) {
      const float *f = pass + (i * S + s) * 6;
      if (f[2] > 0) {
        acc[3 * i] += f[0];
        acc[3 * i + 1] += f[1];
        acc[3 * i + 2] += 1;
      }
    }
}

/* Estimate -> (colour, highlight, alpha) channels starting at c. */
static void write_estimate(hf_image *img, int c, const float *acc, int samples) {
  size_t px = (size_t)img->width * img->height;
  for (size_t i = 0; i < px; i++) {
    float *o = img->data + i * img->channels + c;
    float k = acc[3 * i + 2];
    o[0] = k > 0 ? acc[3 * i] / k : 0;
    o[1] = k > 0 ? acc[3 * i + 1] / k : 0;
    o[2] = k / samples;
  }
}

int hfr_render(hfr_renderer *r, const hfr_view *v, const hfr_outputs *o, hf_image *out,
               hfr_stats *stats, char *err, size_t errlen) {
  if (!r || !v || !o || !out) return HF_EINVAL;
  memset(out, 0, sizeof *out);
  hfr_stats local;
  if (!stats) stats = &local;
  memset(stats, 0, sizeof *stats);
  int rc = validate(v, o, err, errlen);
  if (rc != HF_OK) return rc;
  if (!r->has_hair) return bad(err, errlen, "no hair model set");
  if ((rc = hr_renderer_bind(r)) != HF_OK) return rc;
  r->max_fragments = o->max_fragments;
  r->gt_cull = o->gt_cull;
  int W, H;
  hr_view_target(v, &W, &H);
  const int S = 4;
  const size_t px = (size_t)W * H;
  if ((rc = hf_image_alloc(out, W, H, hfr_outputs_channels(o))) != HF_OK) return rc;
  if (v->crop_w > 0) {
    /* A crop lies where it was in the whole frame: its data window inside
     * the frame's display window (EXR's convention, which hairfilter filter
     * and infer keep in their results). */
    out->origin_x = v->crop_x;
    out->origin_y = v->crop_y;
    out->display_width = v->width;
    out->display_height = v->height;
  }
  stats->segments = r->segments;
  if (o->gt_supersample > 0) {
    float pos[8];
    stats->gt_shared_positions =
        hfr_msaa_positions(r, pos, NULL, 0) == HF_OK ? hfr_gt_shared_positions(pos, o->gt_supersample)
                                                     : -1;
  }

  /* Channel layout (hfrender.h). */
  int c = 0;
  for (int k = 0; k < o->spp; k++)
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++) {
      char pre[16];
      snprintf(pre, sizeof pre, "S%d", k);
      set_name(out, c++, pre, HF_FEATURE_NAMES[f]);
    }
  int c_gt = c, c_st = c + (o->gt_supersample > 0 ? 3 : 0);
  int c_opaque = c_st + 3 * o->n_st;
  if (o->gt_supersample > 0)
    for (int f = 0; f < 3; f++) set_name(out, c_gt + f, "gt", HF_OUTPUT_NAMES[f]);
  for (int i = 0; i < o->n_st; i++) {
    char pre[16];
    snprintf(pre, sizeof pre, "st%d", o->st_spp[i]);
    for (int f = 0; f < 3; f++) set_name(out, c_st + 3 * i + f, pre, HF_OUTPUT_NAMES[f]);
  }
  if (o->opaque_samples > 0)
    for (int f = 0; f < 3; f++) set_name(out, c_opaque + f, "opaque", HF_OUTPUT_NAMES[f]);
  int c_ac = c_opaque + (o->opaque_samples > 0 ? 3 : 0);
  if (o->alpha_corrected)
    for (int f = 0; f < 3; f++) set_name(out, c_ac + f, "acst4", HF_OUTPUT_NAMES[f]);
  int c_bg = c_ac + (o->alpha_corrected ? 3 : 0);
  if (o->background_layer)
    for (int f = 0; f < 4; f++) set_name(out, c_bg + f, "background", (const char *[]){"R", "G", "B", "A"}[f]);

  hr_camera cam, light;
  hr_camera_from_view(r, v, &cam);
  hr_camera_light(r, v, &light);
  double t0 = hr_now_ms();
  rc = hr_pass_shadow(r, v, &light, o->seed ^ 0x5bd1e995u, err, errlen);
  hrgl.Finish();
  stats->shadow_ms = hr_now_ms() - t0;

  /* Stochastic passes shared by the features and the ST baselines: sample
   * g of the frame is sample g % 4 of pass g / 4. */
  int max_st = 0;
  for (int i = 0; i < o->n_st; i++) max_st = o->st_spp[i] > max_st ? o->st_spp[i] : max_st;
  int need = o->spp > max_st ? o->spp : max_st;
  int passes = (need + S - 1) / S;
  if (o->alpha_corrected && passes == 0) passes = 1;
  float *pass = malloc(sizeof(float) * 6 * S * px);
  float *ac = o->alpha_corrected ? malloc(sizeof(float) * 3 * px) : NULL;
  float *acc = calloc((size_t)3 * px * (o->n_st + 1), sizeof(float));
  unsigned char *hairpx = NULL; /* pixels with a covered sample in the first pass */
  if (!pass || !acc || (o->alpha_corrected && !ac)) rc = HF_ENOMEM;
  if (rc == HF_OK && passes == 0) hr_frame_stats(r, v, &cam, NULL, W, H, &stats->frame);
  stats->frame.gt_opaque = -1;
  for (int p = 0; rc == HF_OK && p < passes; p++) {
    float jx, jy;
    pass_jitter(p, &jx, &jy);
    t0 = hr_now_ms();
    rc = hr_pass_ms(r, v, &cam, &light, pass_seed(o->seed, p), jx, jy, 0, pass,
                    p == 0 ? ac : NULL, err, errlen);
    double dt = hr_now_ms() - t0;
    if (rc != HF_OK) break;
    if (p * S < o->spp) stats->features_ms += dt;
    else stats->baselines_ms += dt;
    if (p == 0) {
      hr_frame_stats(r, v, &cam, pass, W, H, &stats->frame);
      hairpx = malloc(px);
      for (size_t i = 0; hairpx && i < px; i++) {
        int any = 0;
        for (int s = 0; s < S; s++) any |= pass[(i * S + s) * 6 + 2] > 0;
        hairpx[i] = (unsigned char)any;
      }
    }
    for (int s = 0; s < S && p * S + s < o->spp; s++) {
      int k = p * S + s;
      for (size_t i = 0; i < px; i++)
        memcpy(out->data + i * out->channels + k * 6, pass + (i * S + s) * 6, 6 * sizeof(float));
    }
    for (int b = 0; b < o->n_st; b++) {
      int n = o->st_spp[b] - p * S;
      if (n > 0) accumulate(pass, px, S, 0, n < S ? n : S, acc + (size_t)3 * px * b);
    }
  }
  for (int b = 0; rc == HF_OK && b < o->n_st; b++)
    write_estimate(out, c_st + 3 * b, acc + (size_t)3 * px * b, o->st_spp[b]);
  for (size_t i = 0; rc == HF_OK && ac && i < px; i++)
    memcpy(out->data + i * out->channels + c_ac, ac + 3 * i, 3 * sizeof(float));

  if (rc == HF_OK && o->opaque_samples > 0) {
    float *oacc = acc + (size_t)3 * px * o->n_st;
    t0 = hr_now_ms();
    for (int p = 0; rc == HF_OK && p < o->opaque_samples / S; p++) {
      float jx, jy;
      pass_jitter(p, &jx, &jy);
      rc = hr_pass_ms(r, v, &cam, &light, 0, jx, jy, 1, pass, NULL, err, errlen);
      if (rc == HF_OK) accumulate(pass, px, S, 0, S, oacc);
    }
    stats->baselines_ms += hr_now_ms() - t0;
    if (rc == HF_OK) write_estimate(out, c_opaque, oacc, o->opaque_samples);
  }

  /* Each stage's attachments, kept from pass to pass and band to band,
   * are given back before the next stage makes its own. */
  hr_frame_tex_release(r);
  if (rc == HF_OK && o->gt_supersample > 0) {
    float *gt = malloc(sizeof(float) * 3 * px);
    if (!gt) rc = HF_ENOMEM;
    if (rc == HF_OK) rc = hr_pass_gt(r, v, &light, o->gt_supersample, gt, NULL, stats, err,
                                     errlen);
    if (rc == HF_OK)
      for (size_t i = 0; i < px; i++) memcpy(out->data + i * out->channels + c_gt, gt + 3 * i,
                                             3 * sizeof(float));
    if (rc == HF_OK && hairpx) {
      /* Of the hair pixels, those the ground truth makes opaque. */
      size_t hair = 0, opaque = 0;
      for (size_t i = 0; i < px; i++) {
        hair += hairpx[i];
        opaque += hairpx[i] && gt[3 * i + 2] >= 0.99f;
      }
      stats->frame.gt_opaque = hair ? (double)opaque / hair : 0;
    }
    free(gt);
  }
  hr_frame_tex_release(r);
  if (rc == HF_OK && o->background_layer) {
    float *bg = malloc(sizeof(float) * 2 * px);
    if (!bg) rc = HF_ENOMEM;
    if (rc == HF_OK) rc = hr_pass_background(r, v, &cam, &light, bg, err, errlen);
    for (size_t i = 0; rc == HF_OK && i < px; i++) {
      float *d = out->data + i * out->channels + c_bg;
      for (int k = 0; k < 3; k++) d[k] = bg[2 * i] * v->occluder_color[k] * v->light_color[k];
      d[3] = bg[2 * i + 1];
    }
    free(bg);
  }
  hr_frame_tex_release(r);
  free(pass);
  free(ac);
  free(acc);
  free(hairpx);
  if (rc != HF_OK) hf_image_free(out);
  return rc;
}

void hfr_frame_defaults(hfr_frame *f, int width, int height) {
  memset(f, 0, sizeof *f);
  hfr_style_defaults(HFR_STYLE_STRAIGHT, &f->style);
  hfr_view_defaults(&f->view);
  hfr_asset_defaults(&f->asset);
  f->view.width = width;
  f->view.height = height;
  f->outputs.spp = 4;
  f->outputs.gt_supersample = HFR_GT_SUPERSAMPLE;
  f->outputs.seed = 1;
}

int hfr_render_frame(const hfr_frame *f, hf_image *out, hfr_stats *stats, char *err,
                     size_t errlen) {
  if (!f || !out) return HF_EINVAL;
  hfr_hair hair;
  hfr_mesh occ = {0};
  int rc;
  if (f->hair_path) {
    rc = hfr_asset_load(f->hair_path, &f->asset, &hair, &occ, NULL, 0, err, errlen);
  } else {
    rc = hfr_style_check(&f->style, err, errlen);
    if (rc == HF_OK) rc = hfr_hair_generate(&f->style, &hair);
    hfr_ellipsoid body;
    hfr_style_body(f->style.style, &body);
    if (rc == HF_OK && (rc = hfr_mesh_ellipsoid(&body, 48, 24, &occ)) != HF_OK)
      hfr_hair_free(&hair);
  }
  if (rc != HF_OK) return rc;
  hfr_renderer *r = NULL;
  rc = hfr_renderer_create(f->platform, &r, err, errlen);
  if (rc == HF_OK) rc = hfr_renderer_set_hair(r, &hair, f->hair_path == NULL, err, errlen);
  /* A style's body other than the head (fur) replaces it. */
  if (rc == HF_OK && !f->hair_path && f->style.style == HFR_STYLE_FUR)
    rc = hfr_renderer_set_occluder(r, &occ, 1, err, errlen);
  if (rc == HF_OK && f->hair_path)
    rc = hfr_renderer_set_occluder(r, &occ, hfr_asset_fitted(&f->asset), err, errlen);
  if (rc == HF_OK) rc = hfr_render(r, &f->view, &f->outputs, out, stats, err, errlen);
  hfr_renderer_destroy(r);
  hfr_hair_free(&hair);
  hfr_mesh_free(&occ);
  return rc;
}

int hfr_composite_result(const float *res, int width, int height, const hf_image *frame,
                         const float hair[3], const float light[3], const float bg[3],
                         float *rgb) {
  if (!res || !hair || !light || !bg || !rgb || width < 1 || height < 1) return HF_EINVAL;
  int ch[4] = {-1, -1, -1, -1};
  if (frame && frame->width == width && frame->height == height)
    for (int k = 0; k < 4; k++) {
      char name[32];
      snprintf(name, sizeof name, "background.%c", "RGBA"[k]);
      ch[k] = hf_image_channel(frame, name);
    }
  if (ch[0] < 0 || ch[1] < 0 || ch[2] < 0 || ch[3] < 0) {
    hf_composite(res, width, height, hair, light, bg, rgb);
    return HF_OK;
  }
  /* The hair over the layer, the layer over the background. */
  const float black[3] = {0, 0, 0};
  hf_composite(res, width, height, hair, light, black, rgb);
  size_t px = (size_t)width * height;
  for (size_t i = 0; i < px; i++) {
    const float *l = frame->data + i * frame->channels;
    float a = res[3 * i + 2], la = l[ch[3]];
    for (int k = 0; k < 3; k++) rgb[3 * i + k] += (1 - a) * (l[ch[k]] + (1 - la) * bg[k]);
  }
  return HF_OK;
}

int hfr_composite_channels(const hf_image *img, const char *prefix, const hfr_view *v,
                           float *rgb) {
  if (!img || !prefix || !v || !rgb) return HF_EINVAL;
  int ch[3];
  for (int f = 0; f < 3; f++) {
    char name[48];
    snprintf(name, sizeof name, "%s%s%s", prefix, *prefix ? "." : "", HF_OUTPUT_NAMES[f]);
    ch[f] = hf_image_channel(img, name);
    if (ch[f] < 0) return HF_ENOTFOUND;
  }
  size_t px = (size_t)img->width * img->height;
  float *res = malloc(sizeof(float) * 3 * px);
  if (!res) return HF_ENOMEM;
  for (size_t i = 0; i < px; i++)
    for (int f = 0; f < 3; f++) res[3 * i + f] = img->data[i * img->channels + ch[f]];
  int rc = hfr_composite_result(res, img->width, img->height, img, v->hair_color,
                                v->light_color, v->background, rgb);
  free(res);
  return rc;
}
