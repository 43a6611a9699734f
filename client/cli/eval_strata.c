/* Stratified quality of `hairfilter eval` (eval_strata.h). Pixel tables pool
 * the bucket's hair pixels: PSNR from their mean squared error, SSIM the
 * mean of the SSIM map over them. Frame tables average the per-frame values
 * of the bucket's frames, as the main table does over all frames. */
#include "eval_strata.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "eval_metrics.h"

typedef struct table_def {
  const char *key, *title;
  int nb;
  const char *names[EVAL_MAX_BUCKETS];
  double edges[EVAL_MAX_BUCKETS];   /* lower edges of buckets 1.. (width: 2..) */
  int none_bucket;                  /* bucket 0 holds values that are not > 0 */
} table_def;

#define WIDTH_BUCKETS {"none", "<0.03", "0.03-0.1", "0.1-0.3", "0.3-0.7", ">=0.7"}
/* The strand-width edges 0.03, 0.1, 0.3 and 0.7 rounded down to the bins of
 * hf_input_stats (128 per octave), so that a frame's strand_alpha_p50 (a
 * bin's lower edge) falls in the bucket of the exact median: bucketing a
 * value and bucketing its bin are then the same. */
#define WIDTH_EDGES {245.0 / 8192, 51.0 / 512, 153.0 / 512, 179.0 / 256}
#define COVER_BUCKETS {"sparse <0.3", "medium 0.3-0.9", "dense >=0.9"}

static const table_def TABLES[EVAL_TABLES] = {
  [EVAL_T_WIDTH_PX] = {"strand_width_pixels",
                       "Strand width in pixels, per hair pixel (mean alpha of its covered "
                       "input samples; none: no sample covered)",
                       6, WIDTH_BUCKETS, WIDTH_EDGES, 1},
  [EVAL_T_COVER_PX] = {"coverage_pixels", "Local coverage, per hair pixel (ground-truth alpha)",
                       3, COVER_BUCKETS, {0.3, 0.9}, 0},
  [EVAL_T_WIDTH_FR] = {"strand_width_frames",
                       "Strand width in pixels, per frame (strand_alpha_p50 of its input)", 6,
                       WIDTH_BUCKETS, WIDTH_EDGES, 1},
  [EVAL_T_COVER_FR] = {"coverage_frames",
                       "Local coverage, per frame (median ground-truth alpha of its hair "
                       "pixels)",
                       3, COVER_BUCKETS, {0.3, 0.9}, 0},
  [EVAL_T_RES_FR] = {"resolution_frames",
                     "Resolution, per frame (long side of the full frame; a crop counts at "
                     "the size it was cut from)",
                     3, {"256 (<384)", "512 (384-767)", "1024+ (>=768)"}, {384, 768}, 0},
};

int eval_bucket_count(int table) { return TABLES[table].nb; }
const char *eval_bucket_name(int table, int b) { return TABLES[table].names[b]; }
const char *eval_table_key(int table) { return TABLES[table].key; }
const char *eval_table_title(int table) { return TABLES[table].title; }

int eval_bucket(int table, double v) {
  const table_def *t = &TABLES[table];
  if (t->none_bucket && !(v > 0)) return 0;
  int b = t->none_bucket;
  for (int e = 0; b + 1 < t->nb && v >= t->edges[e]; e++) b++;
  return b;
}

/* ---- a frame's regime ----------------------------------------------------- */

static int cmp_float(const void *a, const void *b) {
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

int eval_regime_compute(eval_regime *r, const float *in, int spp, const float *gt,
                        const uint8_t *mask, int w, int h, int full_w, int full_h) {
  memset(r, 0, sizeof *r);
  size_t npx = (size_t)w * h;
  r->width = w;
  r->height = h;
  r->full_width = full_w > 0 ? full_w : w;
  r->full_height = full_h > 0 ? full_h : h;
  int rc = hf_input_stats_compute(in, HF_F32, w, h, spp, &r->stats);
  if (rc) return rc;
  float *alphas = malloc((npx ? npx : 1) * sizeof(float));
  for (int t = 0; t < EVAL_PIXEL_TABLES; t++) r->pixel[t] = malloc(npx ? npx : 1);
  if (!alphas || !r->pixel[0] || !r->pixel[1]) {
    free(alphas);
    eval_regime_free(r);
    return HF_ENOMEM;
  }
  size_t nhair = 0;
  const size_t stride = (size_t)spp * HF_FEATURES_PER_SAMPLE;
  for (size_t p = 0; p < npx; p++) {
    if (!mask[p]) {
      r->pixel[EVAL_T_WIDTH_PX][p] = r->pixel[EVAL_T_COVER_PX][p] = EVAL_NO_BUCKET;
      continue;
    }
    int bw = eval_bucket(EVAL_T_WIDTH_PX, hf_pixel_strand_alpha(in + p * stride, spp));
    int bc = eval_bucket(EVAL_T_COVER_PX, gt[3 * p + 2]);
    r->pixel[EVAL_T_WIDTH_PX][p] = (uint8_t)bw;
    r->pixel[EVAL_T_COVER_PX][p] = (uint8_t)bc;
    r->bucket_pixels[EVAL_T_WIDTH_PX][bw]++;
    r->bucket_pixels[EVAL_T_COVER_PX][bc]++;
    alphas[nhair++] = gt[3 * p + 2];
  }
  r->hair_pixels = nhair;
  /* Median, nearest rank as for the input statistics: the ceil(n/2)-th. */
  qsort(alphas, nhair, sizeof *alphas, cmp_float);
  r->gt_alpha_p50 = nhair ? alphas[(nhair + 1) / 2 - 1] : NAN;
  free(alphas);
  int long_side = r->full_width > r->full_height ? r->full_width : r->full_height;
  for (int t = 0; t < EVAL_TABLES; t++) r->frame[t] = -1;
  r->frame[EVAL_T_WIDTH_FR] = eval_bucket(EVAL_T_WIDTH_FR,
                                          r->stats.value[HF_STAT_STRAND_ALPHA_P50]);
  r->frame[EVAL_T_COVER_FR] = eval_bucket(EVAL_T_COVER_FR, r->gt_alpha_p50);
  r->frame[EVAL_T_RES_FR] = eval_bucket(EVAL_T_RES_FR, long_side);
  for (int t = EVAL_PIXEL_TABLES; t < EVAL_TABLES; t++) r->bucket_pixels[t][r->frame[t]] = nhair;
  return 0;
}

void eval_regime_free(eval_regime *r) {
  for (int t = 0; t < EVAL_PIXEL_TABLES; t++) {
    free(r->pixel[t]);
    r->pixel[t] = NULL;
  }
}

/* ---- sums ------------------------------------------------------------------ */

typedef struct sums {
  uint64_t pixels;
  int frames;
  /* over pixels */
  double se, ssim, col, hl, alpha;
  /* over frames */
  double f_psnr, f_ssim, f_mse, f_col, f_hl, f_alpha;
  int f_inf;
} sums;

/* Slot 0 of a method: every hair pixel / frame; then the tables. */
#define SLOTS (1 + EVAL_TABLES * EVAL_MAX_BUCKETS)

struct eval_strata {
  int methods;
  sums *s;                                   /* [methods][SLOTS] */
  int frames[EVAL_TABLES][EVAL_MAX_BUCKETS]; /* frames holding the bucket */
  uint64_t pixels[EVAL_TABLES][EVAL_MAX_BUCKETS];
  int total_frames;
  uint64_t total_pixels;
};

static sums *slot(const eval_strata *s, int m, int table, int b) {
  return &s->s[(size_t)m * SLOTS + (table < 0 ? 0 : 1 + table * EVAL_MAX_BUCKETS + b)];
}

int eval_strata_create(int methods, eval_strata **out) {
  eval_strata *s = calloc(1, sizeof *s);
  if (!s || !(s->s = calloc((size_t)methods * SLOTS, sizeof(sums)))) {
    free(s);
    return HF_ENOMEM;
  }
  s->methods = methods;
  *out = s;
  return 0;
}

void eval_strata_free(eval_strata *s) {
  if (!s) return;
  free(s->s);
  free(s);
}

static void add_frame_values(sums *d, const eval_frame_score *fs, const sums *px) {
  d->frames++;
  d->pixels += px->pixels;
  d->se += px->se;
  d->ssim += px->ssim;
  d->col += px->col;
  d->hl += px->hl;
  d->alpha += px->alpha;
  if (isinf(fs->psnr)) d->f_inf++;
  else d->f_psnr += fs->psnr;
  d->f_ssim += fs->ssim;
  d->f_mse += fs->mse;
  d->f_col += fs->col;
  d->f_hl += fs->hl;
  d->f_alpha += fs->alpha;
}

void eval_strata_add(eval_strata *s, int m, const eval_regime *r, const float *rgb,
                     const float *gt_rgb, const float *res, const float *gt,
                     const double *ssim_map, const eval_frame_score *fs) {
  sums frame = {0};
  int seen[EVAL_PIXEL_TABLES][EVAL_MAX_BUCKETS] = {{0}};
  size_t npx = (size_t)r->width * r->height;
  for (size_t p = 0; p < npx; p++) {
    if (r->pixel[0][p] == EVAL_NO_BUCKET) continue;
    double se = 0;
    for (int c = 0; c < 3; c++) {
      double d = (double)rgb[3 * p + c] - gt_rgb[3 * p + c];
      se += d * d;
    }
    /* Colour and highlight premultiplied by alpha, as eval_channel_mse. */
    const float *a = res + 3 * p, *b = gt + 3 * p;
    double col = a[0] * (double)a[2] - b[0] * (double)b[2];
    double hl = a[1] * (double)a[2] - b[1] * (double)b[2];
    double al = (double)a[2] - b[2];
    sums px = {.pixels = 1, .se = se, .ssim = ssim_map[p], .col = col * col, .hl = hl * hl,
               .alpha = al * al};
    for (int t = 0; t < EVAL_PIXEL_TABLES; t++) {
      int bk = r->pixel[t][p];
      sums *d = slot(s, m, t, bk);
      d->pixels++;
      d->se += px.se;
      d->ssim += px.ssim;
      d->col += px.col;
      d->hl += px.hl;
      d->alpha += px.alpha;
      if (!seen[t][bk]) d->frames++;
      seen[t][bk] = 1;
    }
    frame.pixels++;
    frame.se += px.se;
    frame.ssim += px.ssim;
    frame.col += px.col;
    frame.hl += px.hl;
    frame.alpha += px.alpha;
  }
  add_frame_values(slot(s, m, -1, 0), fs, &frame);
  for (int t = EVAL_PIXEL_TABLES; t < EVAL_TABLES; t++)
    add_frame_values(slot(s, m, t, r->frame[t]), fs, &frame);
}

void eval_strata_frame_done(eval_strata *s, const eval_regime *r) {
  for (int t = 0; t < EVAL_TABLES; t++)
    for (int b = 0; b < TABLES[t].nb; b++) {
      s->pixels[t][b] += r->bucket_pixels[t][b];
      s->frames[t][b] += r->bucket_pixels[t][b] > 0;
    }
  s->total_frames++;
  s->total_pixels += r->hair_pixels;
}

/* ---- reports ---------------------------------------------------------------- */

typedef eval_frame_score metrics;

/* Pooled over pixels (pixel tables), or the mean over frames. */
static int metrics_of(const sums *d, int over_frames, metrics *out) {
  if (over_frames) {
    if (!d->frames) return 0;
    double n = d->frames;
    out->psnr = d->f_inf ? INFINITY : d->f_psnr / n;
    out->ssim = d->f_ssim / n;
    out->mse = d->f_mse / n;
    out->col = d->f_col / n;
    out->hl = d->f_hl / n;
    out->alpha = d->f_alpha / n;
    return 1;
  }
  if (!d->pixels) return 0;
  double n = (double)d->pixels;
  out->mse = d->se / (3 * n);
  out->psnr = eval_psnr(out->mse, 1.0);
  out->ssim = d->ssim / n;
  out->col = d->col / n;
  out->hl = d->hl / n;
  out->alpha = d->alpha / n;
  return 1;
}

void eval_strata_print(const eval_strata *s, const char *const *labels, FILE *f) {
  for (int t = 0; t < EVAL_TABLES; t++) {
    const table_def *td = &TABLES[t];
    int px = t < EVAL_PIXEL_TABLES;
    fprintf(f, "\n%s: PSNR (dB) / SSIM %s\n\n| method |", td->title,
            px ? "over the bucket's hair pixels" : "averaged over the bucket's frames");
    for (int b = 0; b < td->nb; b++) fprintf(f, " %s |", td->names[b]);
    fprintf(f, "\n|---|");
    for (int b = 0; b < td->nb; b++) fprintf(f, "---:|");
    fprintf(f, "\n| hair pixels (frames) |");
    for (int b = 0; b < td->nb; b++)
      fprintf(f, " %llu (%d) |", (unsigned long long)s->pixels[t][b], s->frames[t][b]);
    fprintf(f, "\n");
    for (int m = 0; m < s->methods; m++) {
      if (!slot(s, m, -1, 0)->frames) continue;
      fprintf(f, "| %s |", labels[m]);
      for (int b = 0; b < td->nb; b++) {
        metrics v;
        const sums *d = slot(s, m, t, b);
        if (!metrics_of(d, !px, &v)) {
          fprintf(f, " - |");
          continue;
        }
        if (isinf(v.psnr)) fprintf(f, " inf / %.4f", v.ssim);
        else fprintf(f, " %.2f / %.4f", v.psnr, v.ssim);
        /* A method some of the bucket's frames lack (a baseline not
         * rendered for them) is scored on other pixels than the rows
         * beside it: said in its cell, not left to pass for a comparison. */
        if (d->frames != s->frames[t][b]) fprintf(f, " (%d of %d frames)", d->frames, s->frames[t][b]);
        fprintf(f, " |");
      }
      fprintf(f, "\n");
    }
  }
}

int eval_strata_mean(const eval_strata *s, int m, eval_frame_score *mean) {
  const sums *d = slot(s, m, -1, 0);
  return metrics_of(d, 1, mean) ? d->frames : 0;
}

cJSON *eval_json_number(double v) {
  return isfinite(v) ? cJSON_CreateNumber(v) : cJSON_CreateNull();
}

void eval_json_scores(cJSON *o, const eval_frame_score *v) {
  cJSON_AddItemToObject(o, "psnr", eval_json_number(v->psnr));
  cJSON_AddItemToObject(o, "ssim", eval_json_number(v->ssim));
  cJSON_AddItemToObject(o, "mse", eval_json_number(v->mse));
  cJSON_AddItemToObject(o, "color_alpha_mse", eval_json_number(v->col));
  cJSON_AddItemToObject(o, "highlight_alpha_mse", eval_json_number(v->hl));
  cJSON_AddItemToObject(o, "alpha_mse", eval_json_number(v->alpha));
}

static cJSON *sums_json(const sums *d, int over_frames, const char *bucket) {
  cJSON *o = cJSON_CreateObject();
  if (!o) return NULL;
  if (bucket) cJSON_AddStringToObject(o, "bucket", bucket);
  cJSON_AddNumberToObject(o, "pixels", (double)d->pixels);
  cJSON_AddNumberToObject(o, "frames", d->frames);
  /* An empty bucket: every value null. */
  metrics v = {NAN, NAN, NAN, NAN, NAN, NAN};
  metrics_of(d, over_frames, &v);
  eval_json_scores(o, &v);
  return o;
}

cJSON *eval_strata_method_json(const eval_strata *s, int m) {
  cJSON *o = cJSON_CreateObject();
  if (!o) return NULL;
  cJSON_AddItemToObject(o, "overall", sums_json(slot(s, m, -1, 0), 1, NULL));
  cJSON_AddItemToObject(o, "overall_pixels", sums_json(slot(s, m, -1, 0), 0, NULL));
  for (int t = 0; t < EVAL_TABLES; t++) {
    cJSON *arr = cJSON_AddArrayToObject(o, TABLES[t].key);
    for (int b = 0; arr && b < TABLES[t].nb; b++)
      cJSON_AddItemToArray(arr, sums_json(slot(s, m, t, b), t >= EVAL_PIXEL_TABLES,
                                          TABLES[t].names[b]));
  }
  return o;
}

cJSON *eval_strata_groupings_json(const eval_strata *s) {
  cJSON *arr = cJSON_CreateArray();
  for (int t = 0; arr && t < EVAL_TABLES; t++) {
    const table_def *td = &TABLES[t];
    cJSON *g = cJSON_CreateObject();
    cJSON_AddItemToArray(arr, g);
    cJSON_AddStringToObject(g, "key", td->key);
    cJSON_AddStringToObject(g, "title", td->title);
    cJSON_AddStringToObject(g, "unit", t < EVAL_PIXEL_TABLES ? "pixels" : "frames");
    cJSON *bs = cJSON_AddArrayToObject(g, "buckets");
    for (int b = 0; bs && b < td->nb; b++) {
      cJSON *o = cJSON_CreateObject();
      cJSON_AddItemToArray(bs, o);
      cJSON_AddStringToObject(o, "bucket", td->names[b]);
      /* [low, high) of the measure; none: not > 0 */
      int first = td->none_bucket;
      if (b >= first) {
        cJSON_AddNumberToObject(o, "low", b == first ? 0 : td->edges[b - first - 1]);
        if (b + 1 < td->nb) cJSON_AddNumberToObject(o, "high", td->edges[b - first]);
        else cJSON_AddNullToObject(o, "high");
      }
      cJSON_AddNumberToObject(o, "pixels", (double)s->pixels[t][b]);
      cJSON_AddNumberToObject(o, "frames", s->frames[t][b]);
    }
  }
  return arr;
}

cJSON *eval_regime_json(const eval_regime *r) {
  cJSON *o = cJSON_CreateObject();
  if (!o) return NULL;
  cJSON_AddNumberToObject(o, "width", r->width);
  cJSON_AddNumberToObject(o, "height", r->height);
  cJSON_AddNumberToObject(o, "full_width", r->full_width);
  cJSON_AddNumberToObject(o, "full_height", r->full_height);
  cJSON_AddNumberToObject(o, "hair_pixels", (double)r->hair_pixels);
  cJSON *st = cJSON_AddObjectToObject(o, "input_stats");
  for (int k = 0; st && k < HF_STAT_COUNT; k++)
    cJSON_AddItemToObject(st, hf_input_stat_name(k), eval_json_number(r->stats.value[k]));
  cJSON_AddItemToObject(o, "gt_alpha_p50", eval_json_number(r->gt_alpha_p50));
  cJSON *bk = cJSON_AddObjectToObject(o, "buckets");
  for (int t = EVAL_PIXEL_TABLES; bk && t < EVAL_TABLES; t++)
    cJSON_AddStringToObject(bk, TABLES[t].key, TABLES[t].names[r->frame[t]]);
  for (int t = 0; bk && t < EVAL_PIXEL_TABLES; t++) {
    cJSON *px = cJSON_AddObjectToObject(bk, TABLES[t].key);
    for (int b = 0; px && b < TABLES[t].nb; b++)
      cJSON_AddNumberToObject(px, TABLES[t].names[b], (double)r->bucket_pixels[t][b]);
  }
  return o;
}
