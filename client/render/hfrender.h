/*
 * hfrender: the reference hair renderer (headless OpenGL 4.5 core through
 * OSMesa or EGL).
 *
 * It draws strands as 1-pixel-wide quads into a 4x multisampled framebuffer
 * with stochastic transparency: each sample's coverage bit is set with
 * probability alpha = opacity * (strand width / pixel footprint), decided by
 * a hashed alpha value of the model-space position and strand (stable from
 * frame to frame). Per
 * sample it keeps the nearest surviving fragment's features, in the order and
 * under the names hfcore uses (S{k}.color, .highlight, .alpha, .depth,
 * .tangent.x, .tangent.y; protocol/FEATURES.md). Shading is the paper's
 * Fig. 3 (colour factor F_d + F_TRT + ambient, highlight F_R), lit by one
 * point or directional light behind a 1-sample stochastic shadow map.
 *
 * Ground truth is a supersampled per-pixel linked-list A-buffer, sorted and
 * blended exactly; baselines are stochastic transparency averaged over N
 * samples and opaque MSAA. Everything is returned as one hf_image with named
 * channels, ready for hf_exr_write.
 *
 * Errors are negative HF_E* codes (hfcore.h); functions that take err fill it
 * with a one-line reason.
 */
#ifndef HFRENDER_H
#define HFRENDER_H

#include <stddef.h>
#include <stdint.h>

#include "hfcore.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- hair models ------------------------------------------------------- */

/* A hair model in the layout of Cem Yuksel's .hair format: strands are
 * polylines of segments[i] segments (segments[i] + 1 points), points stored
 * strand after strand. Optional arrays are NULL when the model has none; the
 * defaults apply then. Thickness is a diameter in model units; transparency
 * is 1 - opacity. */
typedef struct hfr_hair {
  uint32_t strands, points;
  uint16_t *segments;           /* [strands] or NULL: default_segments each */
  float *pos;                   /* [points][3] */
  float *thickness;             /* [points] or NULL */
  float *transparency;          /* [points] or NULL */
  float *color;                 /* [points][3] or NULL (kept, not rendered) */
  uint32_t default_segments;
  float default_thickness, default_transparency, default_color[3];
  char info[89];                /* NUL-terminated file info */
} hfr_hair;

/* .hair header flag bits. */
enum {
  HFR_HAIR_SEGMENTS = 1, HFR_HAIR_POINTS = 2, HFR_HAIR_THICKNESS = 4,
  HFR_HAIR_TRANSPARENCY = 8, HFR_HAIR_COLORS = 16
};

/* Limits a loaded or generated model must respect. */
#define HFR_MAX_STRANDS 4000000u
#define HFR_MAX_POINTS  (1u << 27)

/* Reads a .hair file. Every count is checked against the file size, the
 * limits above and each other before anything is allocated; positions and
 * thickness must be finite, transparency in [0, 1]. */
int hfr_hair_load(const char *path, hfr_hair *out, char *err, size_t errlen);
int hfr_hair_load_mem(const void *buf, size_t len, hfr_hair *out, char *err, size_t errlen);
/* Writes every array the model has (and the segments array always). */
int hfr_hair_save(const char *path, const hfr_hair *hair);
void hfr_hair_free(hfr_hair *hair);
/* Segments of strand i, and the model's total segment count. */
uint32_t hfr_hair_strand_segments(const hfr_hair *hair, uint32_t i);
uint64_t hfr_hair_total_segments(const hfr_hair *hair);
/* Centre and radius of a sphere enclosing every point. */
void hfr_hair_bounds(const hfr_hair *hair, float centre[3], float *radius);

/* ---- procedural hairstyles --------------------------------------------- */

typedef enum hfr_style {
  HFR_STYLE_STRAIGHT = 0,
  HFR_STYLE_WAVY,
  HFR_STYLE_CURLY,
  HFR_STYLE_COILY,              /* tight coils grown outwards: an afro */
  HFR_STYLE_PONYTAIL,
  HFR_STYLE_COUNT
} hfr_style;

/* The procedural head: an ellipsoid at the origin with these semi-axes. */
#define HFR_HEAD_RADII {0.78f, 1.0f, 0.95f}

/* Styles grow on a head of radius ~1 (an ellipsoid, y up, face towards +z);
 * lengths are in those units (1 ~ 10 cm). */
typedef struct hfr_style_params {
  hfr_style style;
  uint64_t seed;
  int strands;                  /* number of strands */
  int segments;                 /* segments per strand */
  float length;                 /* mean strand length */
  float clumping;               /* 0..1: how far tips pull towards clump guides */
  float frizz;                  /* random displacement growing to the tip */
  float curl_radius;            /* wave amplitude / curl or coil radius */
  float curl_period;            /* wave length / curl or coil pitch */
  float thickness;              /* strand diameter */
  float opacity;                /* strand opacity (1 - transparency) */
} hfr_style_params;

const char *hfr_style_name(hfr_style s);
/* Case-insensitive; HF_ENOTFOUND for an unknown name. */
int hfr_style_from_name(const char *name, hfr_style *out);
/* The style's defaults (strands 50000, its segments, length, curl, ...). */
int hfr_style_defaults(hfr_style s, hfr_style_params *p);
/* Builds the hairstyle; same parameters give the same model. */
int hfr_hair_generate(const hfr_style_params *p, hfr_hair *out);

/* ---- view: camera, light, shading --------------------------------------- */

typedef struct hfr_view {
  int width, height;
  /* Camera orbiting the hair's bounding-sphere centre: distance in bounding
   * radii, yaw about +y (0 = looking at the face, from +z), pitch up. */
  float cam_distance, cam_yaw_deg, cam_pitch_deg, cam_fov_deg;
  /* Light: a point light at light_distance bounding radii from the centre,
   * or a directional light from that direction (light_directional). */
  float light_yaw_deg, light_pitch_deg, light_distance;
  int light_directional;
  /* Shading (Fig. 3): lobe shifts alpha_R, alpha_TRT (Marschner's ranges:
   * alpha_R in [-10, -5] deg, alpha_TRT = -1.5 alpha_R), ambient term added
   * to the colour factor. spec_half_vector measures the specular angles
   * against the half vector instead of the light direction. */
  float alpha_r_deg, alpha_trt_deg, ambient;
  int spec_half_vector;
  /* Stochastic shadow map: side in texels (0 = no shadows), depth bias as a
   * fraction of the light's depth range. */
  int shadow_size;
  float shadow_bias;
  float thickness_scale;        /* multiplies every strand's thickness */
  /* Composite only (not in the features): hair albedo, light colour and
   * background, linear RGB. */
  float hair_color[3], light_color[3], background[3];
} hfr_view;

void hfr_view_defaults(hfr_view *v);
/* Randomises camera and light (distance, orientation), lobe shifts and the
 * composite colours from seed, keeping size and switches (paper 3.3.3). */
void hfr_view_randomize(hfr_view *v, uint64_t seed);

/* ---- rendering ----------------------------------------------------------- */

#define HFR_MAX_BASELINES 8
#define HFR_MAX_ST_SPP 256

/* What to render. Channels of the output image, in this order:
 *   S{k}.color .highlight .alpha .depth .tangent.x .tangent.y, k < spp
 *   gt.color gt.highlight gt.alpha                    when gt_supersample
 *   st{N}.color .highlight .alpha for each N in st_spp
 *   opaque.color .highlight .alpha                    when opaque_samples */
typedef struct hfr_outputs {
  int spp;                      /* feature samples per pixel, 0..HF_MAX_SPP */
  int gt_supersample;           /* ground truth s x s per pixel; 0 = none */
  int st_spp[HFR_MAX_BASELINES];/* stochastic-transparency baselines */
  int n_st;
  int opaque_samples;           /* opaque MSAA baseline (multiple of 4); 0 = none */
  uint32_t seed;                /* hash seed of the stochastic samples */
} hfr_outputs;

typedef struct hfr_stats {
  double shadow_ms, features_ms, gt_ms, baselines_ms;
  uint64_t segments;            /* per geometry pass */
  uint64_t gt_fragments;        /* fragments stored in the A-buffer */
  uint32_t gt_max_depth;        /* longest per-subsample fragment list */
  uint64_t gt_truncated;        /* subsamples sorted in more than one round */
  int gt_host_resolve;          /* lists too deep for the GPU resolve: blended on the host */
} hfr_stats;

typedef struct hfr_renderer hfr_renderer;

/* platform: "osmesa", "egl", "auto" or NULL (see HF_GL_PLATFORM). */
int hfr_renderer_create(const char *platform, hfr_renderer **out, char *err, size_t errlen);
void hfr_renderer_destroy(hfr_renderer *r);
const char *hfr_renderer_platform(const hfr_renderer *r);
/* GL_RENDERER and GL_VERSION of its context ("llvmpipe (LLVM ...), 4.5 ..."). */
const char *hfr_renderer_gl_name(const hfr_renderer *r);
/* Uploads a model (replacing the previous one). head: the model grows on
 * the procedural head (HFR_HEAD_RADII at the origin), which is then drawn as
 * an opaque occluder (hair behind it hidden and shadowed) that itself never
 * shows in the features. */
int hfr_renderer_set_hair(hfr_renderer *r, const hfr_hair *hair, int head, char *err,
                          size_t errlen);
/* Renders what o asks for into *out (allocated here; hf_image_free it).
 * stats may be NULL. */
int hfr_render(hfr_renderer *r, const hfr_view *v, const hfr_outputs *o, hf_image *out,
               hfr_stats *stats, char *err, size_t errlen);

/* The number of channels hfr_render produces for o. */
int hfr_outputs_channels(const hfr_outputs *o);

/* ---- one call ------------------------------------------------------------- */

/* One frame, start to finish: a model (hair_path, else the procedural style),
 * a view and the outputs. For callers that render a single image (the demo
 * command); loops should keep an hfr_renderer instead. */
typedef struct hfr_frame {
  const char *hair_path;        /* a .hair file, or NULL for style */
  hfr_style_params style;
  hfr_view view;
  hfr_outputs outputs;
  const char *platform;         /* as hfr_renderer_create */
} hfr_frame;

/* Fills f with: straight style defaults (seed 1), default view at
 * width x height, 4 spp features, 4x4 ground truth, no baselines. */
void hfr_frame_defaults(hfr_frame *f, int width, int height);
int hfr_render_frame(const hfr_frame *f, hf_image *out, hfr_stats *stats, char *err,
                     size_t errlen);

/* ---- datasets ------------------------------------------------------------- */

/* Training pairs (paper 3.3.3): for each style, count frames with their own
 * hair seed, jittered style parameters and a randomised view; each frame is
 * one EXR ({style}_{i:04d}.exr: features at the largest spp, gt.*, any
 * baselines) and an entry in DIR/manifest.json recording everything used. */
typedef struct hfr_dataset_opts {
  const char *out_dir;
  hfr_style styles[HFR_STYLE_COUNT];
  int n_styles;
  int count;                    /* frames per style */
  int width, height;
  int spp_list[4];              /* e.g. 1, 2, 4; features at the largest */
  int n_spp;
  int gt_supersample;
  int st_spp[HFR_MAX_BASELINES];
  int n_st;
  int opaque_samples;
  int strands;                  /* 0: style default */
  int segments;                 /* 0: style default */
  int shadow_size;
  uint64_t seed;
  int half;                     /* EXR in float16 */
  int extended;                 /* style parameters over wide ranges (hr_dataset.c) */
  int progress;                 /* progress bar with ETA on stderr */
  const char *platform;
} hfr_dataset_opts;

void hfr_dataset_defaults(hfr_dataset_opts *o);
int hfr_dataset_run(const hfr_dataset_opts *o, char *err, size_t errlen);

/* Composite of three channels named prefix.color/.highlight/.alpha of img
 * ("gt", "st4", "opaque"; "" for a result image with bare names) with the
 * view's colours into rgb [h][w][3]. */
int hfr_composite_channels(const hf_image *img, const char *prefix, const hfr_view *v,
                           float *rgb);

#ifdef __cplusplus
}
#endif
#endif
