/* Stratified quality of `hairfilter eval`: hair pixels and frames grouped by
 * regime (strand width in pixels, local coverage, resolution), PSNR / SSIM
 * and the per-channel errors of every method in every bucket, as Markdown
 * tables and as JSON. docs/QUALITY.md ("Regimes") defines the buckets. */
#ifndef HF_EVAL_STRATA_H
#define HF_EVAL_STRATA_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include <cjson/cJSON.h>

#include "hfcore.h"

/* The tables: two group hair pixels, three group whole frames. */
enum {
  EVAL_T_WIDTH_PX,   /* hair pixels by their strand width (hf_pixel_strand_alpha) */
  EVAL_T_COVER_PX,   /* hair pixels by their ground-truth alpha */
  EVAL_T_WIDTH_FR,   /* frames by strand_alpha_p50 of their input (hf_input_stats) */
  EVAL_T_COVER_FR,   /* frames by the median ground-truth alpha of their hair pixels */
  EVAL_T_RES_FR,     /* frames by the long side of their full (uncropped) size */
  EVAL_TABLES
};
#define EVAL_PIXEL_TABLES 2     /* tables 0 and 1 group pixels */
#define EVAL_MAX_BUCKETS 6
#define EVAL_NO_BUCKET 255

/* Bucket of a value for a table, and the table's bucket names. */
int eval_bucket(int table, double value);
int eval_bucket_count(int table);
const char *eval_bucket_name(int table, int bucket);
/* JSON key of a table ("strand_width_pixels", ...) and its Markdown title. */
const char *eval_table_key(int table);
const char *eval_table_title(int table);

/* The regime of one frame, computed once and shared by every method. */
typedef struct eval_regime {
  int width, height;
  int full_width, full_height;    /* the frame's full size (a crop's is larger) */
  hf_input_stats stats;           /* of the input's first spp samples */
  double gt_alpha_p50;            /* median ground-truth alpha of the hair pixels */
  uint8_t *pixel[EVAL_PIXEL_TABLES];  /* [h][w] bucket, EVAL_NO_BUCKET off the hair */
  int frame[EVAL_TABLES];         /* bucket of the frame (frame tables only) */
  uint64_t hair_pixels;
  uint64_t bucket_pixels[EVAL_TABLES][EVAL_MAX_BUCKETS];
} eval_regime;

/* in: the input's [h][w][spp*6] features; gt: [h][w][3] ground truth; mask:
 * the hair pixels (gt alpha > 0). full_width/height 0: the frame's own. */
int eval_regime_compute(eval_regime *r, const float *in, int spp, const float *gt,
                        const uint8_t *mask, int width, int height, int full_width,
                        int full_height);
void eval_regime_free(eval_regime *r);

/* One method's values on one frame (what the main table averages). */
typedef struct eval_frame_score {
  double mse, psnr, ssim, col, hl, alpha;
} eval_frame_score;

typedef struct eval_strata eval_strata;

int eval_strata_create(int methods, eval_strata **out);
void eval_strata_free(eval_strata *s);
/* Adds method m's result on a frame: rgb / gt_rgb the composites, res / gt
 * the [h][w][3] results, ssim_map the channel-mean SSIM at every pixel. */
void eval_strata_add(eval_strata *s, int m, const eval_regime *r, const float *rgb,
                     const float *gt_rgb, const float *res, const float *gt,
                     const double *ssim_map, const eval_frame_score *fs);
/* Method m's per-frame values averaged over the frames it was scored on
 * (the main table's row; psnr is INFINITY when a frame's is), and the
 * number of those frames (0: none, *mean untouched). */
int eval_strata_mean(const eval_strata *s, int m, eval_frame_score *mean);
/* Adds psnr (null when infinite), ssim, mse, color_alpha_mse,
 * highlight_alpha_mse and alpha_mse to a JSON object. */
void eval_json_scores(cJSON *o, const eval_frame_score *v);
/* Counts the frame in its buckets (once per frame, after its methods). */
void eval_strata_frame_done(eval_strata *s, const eval_regime *r);

/* Markdown: one table per grouping, a row per method (labels[m]) with
 * "PSNR / SSIM" per bucket. */
void eval_strata_print(const eval_strata *s, const char *const *labels, FILE *f);
/* JSON of method m: {"overall": ..., "overall_pixels": ..., "<table key>":
 * [bucket, ...], ...}, each with pixels, frames, psnr (null: infinite), ssim,
 * mse and the per-channel errors. NULL on allocation failure. */
cJSON *eval_strata_method_json(const eval_strata *s, int m);
/* The groupings: names, buckets, how many frames and pixels each holds. */
cJSON *eval_strata_groupings_json(const eval_strata *s);
/* JSON of one frame's regime (sizes, input statistics, buckets). */
cJSON *eval_regime_json(const eval_regime *r);
/* A JSON number, or null for a non-finite value. */
cJSON *eval_json_number(double v);

#endif
