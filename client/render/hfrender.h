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
  uint32_t dropped;             /* strands of a single point (0 segments) left out */
  /* What the loader accepted as other .hair readers do (cyHairFile and the
   * renderers built on it read what the header announces and no more),
   * each said as a warning by hfr_asset_load: */
  uint32_t dropped_nonfinite;   /* strands left out for a NaN/Inf point, width or transparency */
  uint64_t clamped;             /* per-point values clamped: width < 0 to 0, transparency to [0, 1] */
  uint64_t trailing_bytes;      /* bytes after the arrays, not read */
  uint32_t unknown_flags;       /* header flag bits above the five the format defines, ignored */
  /* 1: default_thickness is the caller's choice (--thickness), drawn as
   * given instead of judged against the model's size. */
  uint8_t thickness_given;
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
 * limits above and each other before anything is allocated; a file shorter
 * than its arrays is refused. Read as the reference reader (cyHairFile)
 * reads it, and counted in the fields above so callers can warn: bytes after
 * the arrays and flag bits above 16 are ignored; a strand of 0 segments (one
 * point, which the format allows and nothing draws) is left out (`dropped`),
 * and so is a strand with a non-finite position, thickness or transparency
 * (`dropped_nonfinite`); a negative thickness is taken as 0 and a
 * transparency outside [0, 1] clamped to it (`clamped`). A file with no
 * strand left is refused (HF_EFORMAT, err says why). */
int hfr_hair_load(const char *path, hfr_hair *out, char *err, size_t errlen);
int hfr_hair_load_mem(const void *buf, size_t len, hfr_hair *out, char *err, size_t errlen);
/* Writes every array the model has (and the segments array always). */
int hfr_hair_save(const char *path, const hfr_hair *hair);
void hfr_hair_free(hfr_hair *hair);
/* Segments of strand i, and the model's total segment count. */
uint32_t hfr_hair_strand_segments(const hfr_hair *hair, uint32_t i);
uint64_t hfr_hair_total_segments(const hfr_hair *hair);
/* Centre and radius of a sphere enclosing every point, computed in double
 * (a float model's extent can overflow or underflow float); radius 0 when
 * every point coincides. */
void hfr_hair_extent(const hfr_hair *hair, double centre[3], double *radius);
/* hfr_hair_extent in float: radius 1 where the extent is 0, inf where it
 * overflows float. */
void hfr_hair_bounds(const hfr_hair *hair, float centre[3], float *radius);
/* Bounding radii (renderer units, about 10 cm) the renderer draws: its
 * cameras, widths and coverage are float, and their squares and products
 * lose the model outside this range. */
#define HFR_RADIUS_MIN 1e-5
#define HFR_RADIUS_MAX 1e15
/* The coarsest float spacing at a model's coordinates, relative to its
 * bounding radius, that keeps its shape: a fifth of the default strand
 * width (1/2000 of the radius). */
#define HFR_SPACING_MAX_REL 1e-4
/* HF_OK when the model's bounding radius times scale (renderer units per
 * model unit) is within [HFR_RADIUS_MIN, HFR_RADIUS_MAX] and float's
 * spacing at its coordinates within HFR_SPACING_MAX_REL of the radius;
 * else HF_ERANGE with err naming the radius (or, where every point
 * coincides, the point; or the spacing and the way out, nearer the
 * origin) and the --units/--scale way out. Also HF_ERANGE when a tenth of
 * the strands or fewer reach over 1000 times as far from the origin as
 * the others' median (a damaged file: the radius would be theirs), err
 * naming how many and the first. */
int hfr_hair_check_extent(const hfr_hair *hair, double scale, char *err, size_t errlen);

/* ---- strand widths (hr_hair_width.c) ------------------------------------- */

/* What Cem Yuksel's reference writer (cyHairFile) stores as the header
 * thickness when the author set none. */
#define HFR_HAIR_UNSET_THICKNESS 1.0f
/* Plausible strand diameters, relative to the model's bounding radius R
 * (human hair on a 10-30 cm head is 1e-4 to 2e-3 R; artist assets go a few
 * times thicker), and the diameter used when the header's is not. */
#define HFR_WIDTH_MIN_REL 1e-6f
#define HFR_WIDTH_MAX_REL 0.02f
#define HFR_WIDTH_FALLBACK_REL 5e-4f

/* The diameter (model units) drawn where hair has no per-point thickness:
 * the header thickness when finite, positive and within [HFR_WIDTH_MIN_REL,
 * HFR_WIDTH_MAX_REL] * radius, except HFR_HAIR_UNSET_THICKNESS when that is
 * above radius / 1000 (the writer's unset value, taken as unset unless the
 * model is in units so small that 1.0 is plausible); otherwise
 * HFR_WIDTH_FALLBACK_REL * radius. radius: hfr_hair_bounds' radius. *why is
 * set to NULL, or to a static reason when the fallback was taken. */
float hfr_hair_default_thickness(const hfr_hair *hair, float radius, const char **why);
/* Checks a loaded model's widths against its size. Without per-point
 * thickness the header thickness is replaced in place by
 * hfr_hair_default_thickness; per-point widths are kept. Writes a one-line
 * warning into warn (empty when none) and returns 1 when it has one, else 0. */
int hfr_hair_check_widths(hfr_hair *hair, char *warn, size_t warnlen);
/* 1 when the model has a per-point thickness and every value is 0: no width
 * at all, which hfr_hair_check_widths and the renderer take as no per-point
 * thickness (the header rule above applies). */
int hfr_hair_thickness_all_zero(const hfr_hair *hair);

/* ---- strand transparency (hr_hair_width.c) -------------------------------- */

/* The header transparency drawn for a model without per-point transparency
 * when the header's is not usable (not finite, or outside [0, 1]): opaque,
 * what the reference writer stores when its author set none. */
#define HFR_HAIR_FALLBACK_TRANSPARENCY 0.0f
/* The transparency drawn where a model has no per-point transparency: the
 * header's when finite and in [0, 1] (1 is kept: fully transparent, as a
 * per-point 1 is), otherwise HFR_HAIR_FALLBACK_TRANSPARENCY. The renderer
 * and hfr_hair_interpolate use this same rule. *why is set to NULL, or to
 * a static reason when the fallback was taken. */
float hfr_hair_default_transparency(const hfr_hair *hair, const char **why);
/* Without per-point transparency, replaces an unusable header value in
 * place by hfr_hair_default_transparency's; says so, and says when nothing
 * will be drawn (header 1, or every per-point value 1). Writes a one-line
 * warning into warn (empty when none) and returns 1 when it has one. */
int hfr_hair_check_transparency(hfr_hair *hair, char *warn, size_t warnlen);

/* ---- conventions of loaded models (hr_hair_orient.c) ---------------------- */

/* The axis of a model that points up. The renderer's frame is y up, the face
 * (or front) towards +z, one unit about 10 cm (the procedural head). */
typedef enum hfr_axis {
  HFR_AXIS_Y = 0, HFR_AXIS_Z, HFR_AXIS_X, HFR_AXIS_NEG_Y, HFR_AXIS_NEG_Z, HFR_AXIS_NEG_X,
  HFR_AXIS_COUNT
} hfr_axis;

/* "y", "+y", "z", "-z", ... (case-insensitive); HF_ENOTFOUND otherwise. */
int hfr_axis_from_name(const char *name, hfr_axis *out);
const char *hfr_axis_name(hfr_axis a);
/* Renderer units per model unit for a unit name: m 10, dm 1, cm 0.1,
 * mm 0.01, in 0.254, ft 3.048 ("units" or "" 1: the model's own).
 * HF_ENOTFOUND for an unknown name. */
int hfr_units_scale(const char *name, float *scale);
/* Rotates the model so that its up axis becomes +y, by the rotation that
 * takes a z-up model's -y (its front, as in Blender) to +z
 * ((x, y, z) -> (x, z, -y)); the others: x up (x, y, z) -> (-y, x, z), -y up
 * (x, -y, -z), -z up (x, -z, y), -x up (y, -x, z). Then multiplies positions
 * and thickness (per-point and header) by scale (> 0, finite). */
int hfr_hair_orient(hfr_hair *hair, hfr_axis up, float scale);

/* ---- guide interpolation (hr_hair_children.c) ----------------------------- */

/* Children grown around guide strands, as DCC tools do with the guides a
 * groom ships: each child takes a root at a random offset from its guide
 * within the local guide spacing (the distance to the nearest other guide
 * root), in the plane of the guide's and its two nearest neighbours' roots
 * (across the guide's first segment where those are in a line), and its shape is
 * the guides around it (the guide and its two nearest neighbours, weighted
 * by inverse root distance, each resampled at the same fraction of its
 * length), pulled towards the guide's own shape by clumping towards the tip,
 * with some length variation and frizz. */
typedef struct hfr_children_params {
  int children;                 /* children per guide, 0..10000 */
  int keep_guides;              /* the guides are strands of the result too */
  float spread;                 /* root offset radius in local guide spacings (0.5) */
  float clumping;               /* 0..1: tips pulled to the guide's shape (0.3) */
  float frizz;                  /* random walk at the tip, in guide spacings (0.3) */
  float length_jitter;          /* child length x [1 - j, 1] (0.15) */
  float width_spread;           /* per guide group: width x s^u, u uniform in [-1, 1]; 0/1 none */
  uint64_t seed;
} hfr_children_params;

void hfr_children_defaults(hfr_children_params *p);
/* out = (keep_guides ? guides : none) + children per guide, strands in guide
 * order (guide g's children follow it). Thickness and transparency follow
 * the guide's profile (or its defaults). Limits: HFR_MAX_STRANDS,
 * HFR_MAX_POINTS (HF_ERANGE); HF_EINVAL for bad parameters. */
int hfr_hair_interpolate(const hfr_hair *guides, const hfr_children_params *p, hfr_hair *out);

/* ---- procedural hairstyles --------------------------------------------- */

typedef enum hfr_style {
  HFR_STYLE_STRAIGHT = 0,
  HFR_STYLE_WAVY,
  HFR_STYLE_CURLY,
  HFR_STYLE_COILY,              /* tight coils grown outwards: an afro */
  HFR_STYLE_PONYTAIL,            /* long hair tied at the back */
  HFR_STYLE_SPIKY,              /* a short spiky cut: stiff strands standing out, gelled clumps */
  HFR_STYLE_FUR,                /* an animal's fur: short dense strands lying along the body */
  HFR_STYLE_BRAIDED,            /* combed flat over the scalp into one or two three-strand plaits */
  HFR_STYLE_COUNT
} hfr_style;

/* The procedural head: an ellipsoid at the origin with these semi-axes. */
#define HFR_HEAD_RADII {0.78f, 1.0f, 0.95f}

/* The body a fur style grows on: an ellipsoid at the origin (a torso along z). */
#define HFR_FUR_BODY_RADII {0.75f, 0.65f, 1.5f}

/* Styles grow on a head of radius ~1 (an ellipsoid, y up, face towards +z),
 * fur on HFR_FUR_BODY_RADII; lengths are in those units (1 ~ 10 cm). Spiky
 * and fur are grown as real grooms are: guides, then children interpolated
 * around them (hfr_hair_interpolate), strands / (children + 1) guides. */
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
  float width_spread;           /* per clump: diameter x s^u, u uniform in [-1, 1]; 0/1 none */
  int children;                 /* spiky, fur: children per guide (>= 0); others 0 */
  float gather;                 /* ponytail, braided: 0..1, how tightly the strands are gathered
                                   at the tie (0: through a disc 2 cm across, or each at its place
                                   in its bundle; 1: every strand through one point, as a tight
                                   elastic or a model whose strands are aimed at one point); others 0 */
} hfr_style_params;

const char *hfr_style_name(hfr_style s);
/* Case-insensitive; HF_ENOTFOUND for an unknown name. */
int hfr_style_from_name(const char *name, hfr_style *out);
/* The styles' names, ", " between them, into out (n bytes, always
 * terminated; cut short if n is too small): for a message that names the
 * styles there are. */
void hfr_style_list(char *out, size_t n);
/* 1 for the styles whose strands are tied (ponytail, braided): those that
 * read hfr_style_params.gather; 0 for the others. */
int hfr_style_has_tie(hfr_style s);
/* The style's defaults (strands 50000, its segments, length, curl, ...). */
int hfr_style_defaults(hfr_style s, hfr_style_params *p);
/* Checks p against the ranges hfr_hair_generate takes: strands 1 to
 * HFR_MAX_STRANDS, segments 8 to 1024, strands x (segments + 1) at most
 * HFR_MAX_POINTS, length and thickness above 0, opacity in (0, 1], clumping
 * in [0, 1], frizz and the curl's radius and period at least 0, width_spread
 * in [0, 100], children 0 to 10000 (above 0 on spiky and fur only, the
 * styles grown from guides), gather in [0, 1] (above 0 on ponytail and
 * braided only, the styles with a tie). HF_OK; HF_EINVAL or HF_ERANGE (too many
 * strands or points) with err naming the parameter, its value and its range
 * (err may be NULL). */
int hfr_style_check(const hfr_style_params *p, char *err, size_t errlen);
/* Builds the hairstyle; same parameters give the same model. Errors as
 * hfr_style_check. */
int hfr_hair_generate(const hfr_style_params *p, hfr_hair *out);

/* ---- occluders (hr_occluder.c, hr_mesh_io.c) ------------------------------ */

/* What the hair grows on: drawn opaque, it hides the hair behind it in the
 * view and in the shadow map, and shows (diffusely shaded) in the background
 * layer, never in the features. A triangle soup: 3 vertices per triangle,
 * each [6] floats (position, unit normal). */
typedef struct hfr_mesh {
  uint32_t vertices;
  float *v;                     /* [vertices][6] */
} hfr_mesh;

#define HFR_MESH_MAX_TRIANGLES 4000000u

/* An ellipsoid: centre, orthonormal axes (rows) and semi-axes along them. */
typedef struct hfr_ellipsoid {
  float centre[3], axes[3][3], radii[3];
} hfr_ellipsoid;

void hfr_mesh_free(hfr_mesh *m);
/* A lat-long tessellation of e (slices around, stacks pole to pole). */
int hfr_mesh_ellipsoid(const hfr_ellipsoid *e, int slices, int stacks, hfr_mesh *out);
/* The body a style grows on (head or fur body), slightly inside it so that
 * it never hides a root. */
void hfr_style_body(hfr_style s, hfr_ellipsoid *e);
/* An ellipsoid under the roots (first points) of a model: an algebraic
 * least-squares fit in the frame of the roots' principal axes (a scalp), or,
 * where that fails or does not lie under the hair (a flat patch of fur), a
 * flat ellipsoid below the roots' mean plane on the side away from the hair
 * (roots along a line: the plane of the line and the strands' growth, the
 * body a quarter as wide as the line is long); then shrunk about its centre
 * until 98% of the roots are on or outside it. HF_EINVAL for a model with
 * fewer than 4 strands, HF_ERANGE when the roots are all at one point. */
int hfr_ellipsoid_fit_roots(const hfr_hair *hair, hfr_ellipsoid *out);
/* Reads a triangle mesh (Wavefront OBJ, PLY, glTF, FBX, STL, ... through
 * the Open Asset Import Library); polygons are triangulated, smooth normals
 * made where the file has none. HF_EUNSUPPORTED when this build has no
 * Assimp; HF_ERANGE above HFR_MESH_MAX_TRIANGLES; err says why. */
int hfr_mesh_load(const char *path, hfr_mesh *out, char *err, size_t errlen);
/* hfr_hair_orient for a mesh (normals are rotated only). */
int hfr_mesh_orient(hfr_mesh *m, hfr_axis up, float scale);

/* ---- view: camera, light, shading --------------------------------------- */

typedef struct hfr_view {
  int width, height;
  /* Camera orbiting the hair's bounding-sphere centre: distance in bounding
   * radii, yaw about +y (0 = looking at the face, from +z), pitch up; the
   * field of view spans the frame's shorter side (the vertical one of a
   * square or landscape frame). */
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
   * background, linear RGB; the occluder's diffuse albedo in the background
   * layer. */
  float hair_color[3], light_color[3], background[3], occluder_color[3];
  /* A window of the width x height frame (x, y from the top left, w, h in
   * pixels; w = 0: the whole frame). It costs a w x h render and gives the
   * same pixels as that window of the whole frame (hr_glsl_hair_vs). */
  int crop_x, crop_y, crop_w, crop_h;
} hfr_view;

void hfr_view_defaults(hfr_view *v);
/* Randomises camera and light (distance, orientation), lobe shifts and the
 * composite colours from seed, keeping size and switches (paper 3.3.3). */
void hfr_view_randomize(hfr_view *v, uint64_t seed);

/* ---- rendering ----------------------------------------------------------- */

#define HFR_MAX_BASELINES 8
#define HFR_MAX_ST_SPP 256

/* The ground truth's default supersampling: s x s sub-pixel centres at
 * ((i + 0.5) / s, (j + 0.5) / s) of the pixel. 8, not 4: the 4x MSAA
 * positions every GL implementation here reports (the standard pattern,
 * (0.375, 0.125), (0.875, 0.375), (0.125, 0.625), (0.625, 0.875)) are 4 of
 * the 16 centres of a 4x4 truth, so where strands are opaque 4 samples see
 * exactly what a quarter of that truth sees and score better against it
 * than they are (docs/RENDERING.md, "The ground truth's sub-pixel grid"). No
 * centre of 8x8 is one of them (hfr_gt_shared_positions). */
#define HFR_GT_SUPERSAMPLE 8

/* What to render. Channels of the output image, in this order:
 *   S{k}.color .highlight .alpha .depth .tangent.x .tangent.y, k < spp
 *   gt.color gt.highlight gt.alpha                    when gt_supersample
 *   st{N}.color .highlight .alpha for each N in st_spp
 *   opaque.color .highlight .alpha                    when opaque_samples
 *   acst4.color .highlight .alpha                     when alpha_corrected:
 *     stochastic transparency's alpha-corrected estimate over the 4 samples
 *     of the first pass (Enderton et al. 2010, section 3.3; one more draw of
 *     every hair fragment)
 *   background.R .G .B .A                             when background_layer:
 *     the occluder, diffusely lit, premultiplied by its coverage A (0 where
 *     there is none); composites put the hair over it (hfr_composite_result) */
typedef struct hfr_outputs {
  int spp;                      /* feature samples per pixel, 0..HF_MAX_SPP */
  int gt_supersample;           /* ground truth s x s per pixel, 1..8; 0 = none */
  int st_spp[HFR_MAX_BASELINES];/* stochastic-transparency baselines */
  int n_st;
  int opaque_samples;           /* opaque MSAA baseline (multiple of 4); 0 = none */
  int alpha_corrected;          /* the alpha-corrected baseline (acst4.*) */
  int background_layer;         /* the occluder layer (background.*) */
  uint32_t seed;                /* hash seed of the stochastic samples */
  /* Most A-buffer fragments the ground truth may store at once (each 20
   * bytes of GL memory): 0 or anything above HFR_MAX_FRAGMENTS means that
   * limit. A frame that needs more is drawn in bands of rows, each within
   * it (the same result); one whose single rows need more fails with
   * HF_ERANGE. */
  uint32_t max_fragments;
  /* The ground truth's transmittance cull (HFR_GT_CULL_*): fragments behind
   * an optical depth of 30 (weight under e^-30 in their subsample, all of
   * them together too) are kept out of the A-buffer. */
  int gt_cull;
} hfr_outputs;

enum {
  HFR_GT_CULL_AUTO = 0, /* windows whose quads promise 64 or more fragments a subsample,
                         * and windows drawn again with 8 or more */
  HFR_GT_CULL_OFF = 1,  /* every fragment stored: the exact blend */
  HFR_GT_CULL_ON = 2    /* every window, from its first draw */
};

#define HFR_MAX_FRAGMENTS (1u << 26)

/* What the network will see in a frame, measured on the first 4x pass
 * (samples 0-3 of the features, or of the ST baselines when spp is 0) and
 * on the model: the regime a frame belongs to. */
typedef struct hfr_frame_stats {
  int valid;                    /* 0 when no stochastic pass was rendered */
  double alpha_p10, alpha_p50, alpha_p90; /* alpha of covered samples */
  double sample_coverage;       /* covered samples / all samples */
  double hair_pixels;           /* pixels with a covered sample / all pixels */
  double full_pixels;           /* of the hair pixels: all 4 samples covered */
  double gt_opaque;             /* of the hair pixels: gt.alpha >= 0.99 (-1: no gt) */
  /* Strand diameter in pixels (thickness x scale x pixels per unit at the
   * point's depth) over the model's points inside the (cropped) view. */
  double width_px_p10, width_px_p50, width_px_p90;
  uint64_t points_in_view;       /* of the points picked, those inside the window */
  uint64_t points_picked;        /* evenly picked points measured (at most 2^20) */
  uint64_t points_model;         /* the model's points they are picked from */
} hfr_frame_stats;

typedef struct hfr_stats {
  double shadow_ms, features_ms, gt_ms, baselines_ms;
  uint64_t segments;            /* per geometry pass */
  uint64_t gt_fragments;        /* fragments stored in the A-buffer */
  uint32_t gt_max_depth;        /* longest per-subsample fragment list */
  uint64_t gt_truncated;        /* subsamples sorted in more than one round */
  int gt_host_resolve;          /* lists too deep for the GPU resolve: blended on the host */
  /* Fragments the transmittance cull kept out of the A-buffer (each behind
   * an optical depth of at least 30: weight under e^-30 in its subsample,
   * all of them together too); 0 when it was not used. */
  uint64_t gt_culled;
  /* How many of the 4 MSAA sample positions are sub-pixel centres of the
   * ground truth (hfr_gt_shared_positions): 0 when there is no truth, -1
   * when the implementation did not say where its samples are. */
  int gt_shared_positions;
  hfr_frame_stats frame;        /* the frame's regime */
} hfr_stats;

typedef struct hfr_renderer hfr_renderer;

/* platform: "osmesa", "egl", "auto" or NULL (see HF_GL_PLATFORM). */
int hfr_renderer_create(const char *platform, hfr_renderer **out, char *err, size_t errlen);
/* Frees r and its GL context, with the ground truth's pool of A-buffer
 * nodes, which r keeps from frame to frame once a truth has grown it (20
 * bytes a fragment, up to hfr_outputs.max_fragments: 1.3 GB at most), so a
 * long-lived renderer holds that much between frames. */
void hfr_renderer_destroy(hfr_renderer *r);
const char *hfr_renderer_platform(const hfr_renderer *r);
/* GL_RENDERER and GL_VERSION of its context ("llvmpipe (LLVM ...), 4.5 ..."). */
const char *hfr_renderer_gl_name(const hfr_renderer *r);
/* Uploads a model (replacing the previous one). head: the model grows on
 * the procedural head (HFR_HEAD_RADII at the origin), which is then drawn as
 * an opaque occluder (hair behind it hidden and shadowed) that itself never
 * shows in the features. r keeps, besides the GL's copy, every point's
 * position and diameter (16 bytes a point) to draw a crop's segments only.
 * HF_EINVAL, HF_ERANGE (more strands or points than HFR_MAX_STRANDS,
 * HFR_MAX_POINTS), HF_ENOMEM (r then has no model: set one again). */
int hfr_renderer_set_hair(hfr_renderer *r, const hfr_hair *hair, int head, char *err,
                          size_t errlen);
/* Replaces the occluder (after hfr_renderer_set_hair; NULL or an empty mesh
 * for none). enclose: grow the bounding sphere the camera frames to
 * contain it (a head sticking out of short hair); otherwise only the hair
 * is framed (a whole body under a groom). */
int hfr_renderer_set_occluder(hfr_renderer *r, const hfr_mesh *m, int enclose, char *err,
                              size_t errlen);
/* The sub-pixel positions of the 4 samples of the renderer's 4x MSAA
 * passes, as its GL implementation reports them (glGetMultisamplefv,
 * GL_SAMPLE_POSITION): pos[2k], pos[2k + 1] = x, y of sample k in pixels
 * from the pixel's lower-left corner, each in [0, 1). HF_EUNSUPPORTED
 * when the implementation has no 4-sample target, HF_EBACKEND when GL
 * fails (err says why). */
int hfr_msaa_positions(hfr_renderer *r, float pos[8], char *err, size_t errlen);
/* How many of the 4 positions pos (as hfr_msaa_positions gives them) lie,
 * within 1e-4 pixel, on a sub-pixel centre ((i + 0.5) / ss, (j + 0.5) / ss)
 * of an ss x ss ground truth: 0..4; 0 for ss < 1. With the standard
 * pattern: 4 at ss 4, 0 at every other ss from 1 to 8 (the range
 * hfr_outputs.gt_supersample takes). */
int hfr_gt_shared_positions(const float pos[8], int ss);
/* The EXR header attributes that record a frame's ground truth, so that a
 * frame read without its manifest still says what its truth is: an int
 * "hairfilter:gtSupersample" (hfr_outputs.gt_supersample; 0: no truth) and,
 * with a truth, "hairfilter:gtSharedPositions" (hfr_stats.gt_shared_positions;
 * -1: not known). hairfilter eval reads them where a manifest does not say. */
#define HFR_EXR_ATTR_GT_SUPERSAMPLE "hairfilter:gtSupersample"
#define HFR_EXR_ATTR_GT_SHARED "hairfilter:gtSharedPositions"
/* hf_exr_write of a rendered frame img (of hfr_render(r, v, out, ...), which
 * gave stats) with those attributes. Errors: those of hf_exr_write. */
int hfr_frame_write(const char *path, const hf_image *img, int half, const hfr_outputs *out,
                    const hfr_stats *stats);
/* Bounding sphere the camera and light orbit (hair, and an enclosed occluder). */
void hfr_renderer_bounds(const hfr_renderer *r, float centre[3], float *radius);
/* Renders what o asks for into *out (allocated here; hf_image_free it).
 * stats may be NULL. */
int hfr_render(hfr_renderer *r, const hfr_view *v, const hfr_outputs *o, hf_image *out,
               hfr_stats *stats, char *err, size_t errlen);

/* The number of channels hfr_render produces for o. */
int hfr_outputs_channels(const hfr_outputs *o);
/* One line of a frame's statistics (for logs): "covered-sample alpha p10 ...". */
void hfr_frame_stats_format(const hfr_frame_stats *s, char *buf, size_t len);

/* ---- loaded models as they come (hr_asset.c) ----------------------------- */

/* How to take a .hair file: its conventions, widths, children, occluder. */
typedef struct hfr_asset_opts {
  hfr_axis up;                  /* the file's up axis */
  float scale;                  /* renderer units per file unit (hfr_units_scale); 0 = 1 */
  float thickness;              /* > 0: every strand this diameter, in the file's units,
                                   at any width (hfr_hair.thickness_given) */
  float opacity;                /* in (0, 1]: every strand this opacity (1 - transparency);
                                   0: the file's */
  hfr_children_params children; /* children.children = 0: the strands as they are */
  /* "fit" (NULL, "", "auto": the default) an ellipsoid under the roots,
   * "none", or a mesh file (hfr_mesh_load) in the file's conventions. */
  const char *occluder;
} hfr_asset_opts;

void hfr_asset_defaults(hfr_asset_opts *o);
/* 1 when o's occluder is fitted (framed with the hair), 0 for a mesh file or
 * none (the camera frames the hair alone). */
int hfr_asset_fitted(const hfr_asset_opts *o);
/* Loads a .hair file as o says: its extent checked at o's scale
 * (hfr_hair_check_extent: HF_ERANGE, err set), transparency and widths
 * checked (hfr_hair_check_transparency, hfr_hair_check_widths; the
 * warnings into warn, "; " between them), --thickness (drawn as given,
 * warned about when implausible) and --opacity applied (HF_EINVAL, err
 * set, for an opacity outside [0, 1]), oriented and scaled, the
 * occluder made (fitted on the guides' roots, or loaded and oriented the
 * same way; *occ empty for none), then children grown. */
int hfr_asset_load(const char *path, const hfr_asset_opts *o, hfr_hair *hair, hfr_mesh *occ,
                   char *warn, size_t warnlen, char *err, size_t errlen);

/* ---- one call ------------------------------------------------------------- */

/* One frame, start to finish: a model (hair_path, else the procedural style),
 * a view and the outputs. For callers that render a single image (the demo
 * command); loops should keep an hfr_renderer instead. */
typedef struct hfr_frame {
  const char *hair_path;        /* a .hair file, or NULL for style */
  hfr_asset_opts asset;         /* how to take hair_path */
  hfr_style_params style;
  hfr_view view;
  hfr_outputs outputs;
  const char *platform;         /* as hfr_renderer_create */
} hfr_frame;

/* Fills f with: straight style defaults (seed 1), default view at
 * width x height, 4 spp features, the default ground truth
 * (HFR_GT_SUPERSAMPLE: 8x8), no baselines, no
 * background layer, default asset options. */
void hfr_frame_defaults(hfr_frame *f, int width, int height);
int hfr_render_frame(const hfr_frame *f, hf_image *out, hfr_stats *stats, char *err,
                     size_t errlen);

/* ---- datasets ------------------------------------------------------------- */

/* Training pairs (paper 3.3.3): for each style (and .hair file), count
 * frames with their own hair seed, jittered style parameters and a
 * randomised view; each frame is one EXR ({style}_{i:04d}.exr: features at
 * the largest spp, gt.*, any baselines) and an entry in DIR/manifest.json
 * recording everything used and the frame's statistics (hfr_frame_stats). */
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
  int alpha_corrected;          /* hfr_outputs.alpha_corrected of every frame */
  int strands;                  /* 0: style default */
  int segments;                 /* 0: style default */
  int shadow_size;
  uint64_t seed;
  int half;                     /* EXR in float16 */
  int extended;                 /* style parameters over wide ranges (hr_dataset.c) */
  uint32_t max_fragments;       /* hfr_outputs.max_fragments of every frame */
  int gt_cull;                  /* hfr_outputs.gt_cull of every frame */
  /* Regimes (hr_dataset_regimes.c): per frame and per clump, strand width in
   * pixels, density, virtual frame size (the output is a width x height
   * crop of a frame_min..frame_max square frame), camera, light, shadows,
   * curl and frizz, drawn over what engines render. */
  int regimes;
  int frame_min, frame_max;
  /* Regimes: the strand width in pixels at the hair's centre is drawn
   * log-uniformly from width_px_min..width_px_max (0, 0: 0.004..4, far
   * sub-pixel to several pixels); a narrower range renders more frames of
   * one regime (wide strands, say) without changing the others' draws. */
  float width_px_min, width_px_max;
  /* Each procedural-style frame's strand opacity is drawn uniformly from
   * opacity_min..opacity_max. 1, 1 draws opaque strands, as many assets
   * have, so that covered-sample alpha reaches 1 where strands are wider
   * than a pixel. Regimes: 0, 0 is 0.2..1, and the draw is made either
   * way, so the other parameters' draws do not change. Out of regimes: 0,
   * 0 keeps the style's opacity; a range is drawn from a stream of the
   * frame's own, so its other draws are those of a run without it. */
  float opacity_min, opacity_max;
  /* Each ponytail and braided frame's gather (hfr_style_params) is drawn
   * uniformly from gather_min..gather_max, from a stream of its own, so
   * that the frame's other draws are those of a run without it (0, 0: the
   * style's 0, not drawn). Any mode, not only regimes. */
  float gather_min, gather_max;
  /* The share of procedural-style frames drawn as smooth grooms, 0..1:
   * frizz 0, and clumping 0 on the styles drawn strand by strand (spiky's
   * and fur's clumps are their children's, kept), so that every strand
   * lies in its bundle as hand-made assets' often do (docs/QUALITY.md,
   * "What makes the braids hard"). Which frames, from a stream of their
   * own: the frames' other draws are those of a run without it. */
  float smooth_share;
  /* .hair files drawn as styles (frames {basename}_{i:04d}.exr), each taken
   * as asset says; children.seed is varied per frame. */
  const char *const *hair_files;
  int n_hair_files;
  hfr_asset_opts asset;
  float width_spread;           /* per-clump width spread of every style frame (0: none) */
  int background_layer;         /* background.* channels in every frame */
  int progress;                 /* progress bar with ETA on stderr */
  const char *platform;
  /* Take up an interrupted run in out_dir: the frames its manifest lists
   * are kept and the others rendered. Its manifest must record the same
   * options ("options"; count may differ), else HF_EINVAL naming the first
   * that differs. Without a manifest in out_dir, a fresh run. */
  int resume;
} hfr_dataset_opts;

void hfr_dataset_defaults(hfr_dataset_opts *o);
int hfr_dataset_run(const hfr_dataset_opts *o, char *err, size_t errlen);

/* Composite of a result res [h][w][3] (colour factor, highlight, alpha)
 * into rgb [h][w][3], linear: hf_composite's formula, over frame's
 * background layer (background.R/G/B/A: rgb += (1 - alpha) * (layer.RGB +
 * (1 - layer.A) * bg)) when frame is not NULL, of this size and has one,
 * else over bg alone. */
int hfr_composite_result(const float *res, int width, int height, const hf_image *frame,
                         const float hair[3], const float light[3], const float bg[3],
                         float *rgb);

/* Composite of three channels named prefix.color/.highlight/.alpha of img
 * ("gt", "st4", "opaque"; "" for a result image with bare names) with the
 * view's colours into rgb [h][w][3], over img's background layer where it
 * has one (hfr_composite_result). */
int hfr_composite_channels(const hf_image *img, const char *prefix, const hfr_view *v,
                           float *rgb);

#ifdef __cplusplus
}
#endif
#endif
