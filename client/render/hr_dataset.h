/* Internals of dataset mode (hr_dataset.c, hr_dataset_regimes.c). */
#ifndef HR_DATASET_H
#define HR_DATASET_H

#include "hfrender.h"
#include "hr_math.h"

/* The strand widths in pixels regimes draw from unless asked otherwise:
 * covered-sample alpha from about 0.005 (far sub-pixel) to opacity (wider
 * than a pixel). */
#define HR_REGIME_WIDTH_PX_MIN 0.004f
#define HR_REGIME_OPACITY_MIN 0.2f
#define HR_REGIME_OPACITY_MAX 1.0f
#define HR_REGIME_WIDTH_PX_MAX 4.0f

/* What a regimes frame drew beyond its style parameters and view. */
typedef struct hr_regime {
  int frame_size;               /* the virtual square frame the output is a crop of */
  float target_width_px;        /* strand width drawn, at the bounding sphere's centre */
  float typical_thickness;      /* the model's median diameter it was scaled from */
  float clump_width_spread;     /* per clump width x s^u, u in [-1, 1] */
} hr_regime;

/* Draws a frame's style parameters (before the model is generated). */
void hr_regime_style(hr_rng *g, const hfr_dataset_opts *o, hfr_style_params *sp,
                     hr_regime *rg);
/* Draws the view: frame size, camera, light, shadows, the thickness scale
 * that gives the drawn width in pixels, and the crop (o->width x o->height)
 * centred on the hair. r holds h (hfr_renderer_set_hair) already. */
void hr_regime_view(hr_rng *g, const hfr_dataset_opts *o, hfr_renderer *r, const hfr_hair *h,
                    hfr_view *v, hr_regime *rg);
/* Median strand diameter of a model (model units): of its points with a
 * positive width, or the header rule's width (hfr_hair_default_thickness)
 * where it has no per-point widths or only zeros, as the renderer draws
 * it. */
float hr_typical_thickness(const hfr_hair *h);
/* The braided style's plait drawn for a set (--regimes, --extended): length
 * 2.2-4.5, period 0.15-0.6, a bundle's swing 0.15-0.35 of it, about 8
 * segments a period (48-160) unless the set fixes --segments. Other styles'
 * length and curl ranges would leave no plait (the comb takes 1-2 of the
 * length; a 0.07 period caps a strand at 1.5). */
void hr_braid_draw(hr_rng *g, const hfr_dataset_opts *o, hfr_style_params *sp);
/* A ponytail or braided frame's gather, drawn uniformly from o's
 * gather_min..gather_max by a stream of sp->seed's own (the frame's other
 * draws unchanged); nothing for other styles or where o draws none. */
void hr_gather_draw(const hfr_dataset_opts *o, hfr_style_params *sp);
/* Whether the frame of model seed seed is drawn as a smooth groom: with
 * probability o->smooth_share, from a stream of the seed's own. */
int hr_smooth_picked(const hfr_dataset_opts *o, uint64_t seed);
/* With probability o->smooth_share, from a stream of sp->seed's own, makes
 * sp a smooth groom (frizz 0; clumping 0 but on the guide-grown styles). */
void hr_smooth_draw(const hfr_dataset_opts *o, hfr_style_params *sp);
/* Out of regimes, where o gives an opacity range: sp->opacity drawn
 * uniformly from it by a stream of sp->seed's own (the frame's other draws
 * unchanged); nothing where o gives none. */
void hr_opacity_draw(const hfr_dataset_opts *o, hfr_style_params *sp);
/* The regimes' strand opacity range of o: o->opacity_min..max, or the
 * default 0.2..1 where o leaves it 0, 0. */
void hr_regime_opacity_range(const hfr_dataset_opts *o, float range[2]);

/* ---- resuming (hr_dataset_resume.c) ---- */
struct cJSON;
/* The manifest's "options": every option that decides the frames (all of o
 * but count, out_dir, progress, platform and resume). NULL when out of
 * memory. */
struct cJSON *hr_dataset_options(const hfr_dataset_opts *o);
/* Reads dir/manifest.json for a resumed run: *old is NULL when there is
 * none (a fresh run, said on stderr), else the parsed manifest. HF_EFORMAT
 * when it is not a dataset manifest, HF_EINVAL when it has no "options"
 * record, when its options differ from options (err names the first that
 * differs, by its command-line option, with both values) or when it lists
 * a frame of index count or more; HF_EIO when it cannot be read. Warns on
 * stderr when gl_renderer differs. */
int hr_dataset_resume_open(const char *dir, const struct cJSON *options, int count,
                           const char *gl_renderer, struct cJSON **old, char *err, size_t errlen);
/* For a run without --resume: says on stderr, before anything is
 * rendered, when dir/manifest.json lists frames of an earlier run, how
 * many, that they are rendered again over and that --resume keeps them
 * (a command run again without it started over in silence). */
void hr_dataset_note_earlier_run(const char *dir);
/* Records in doc's "earlier_gl_renderers" the renderers of old's frames
 * (its "gl_renderer" and its own list) that differ from doc's. */
void hr_dataset_resume_history(struct cJSON *doc, const struct cJSON *old);
/* The manifest entry of frame file that old lists as finished (its file is
 * still in dir) or as left out (*was_skipped 1), detached from old for the
 * new manifest; NULL when the frame is to be rendered. old may be NULL. */
struct cJSON *hr_dataset_resume_take(struct cJSON *old, const char *dir, const char *file,
                                     int *was_skipped);

#endif
