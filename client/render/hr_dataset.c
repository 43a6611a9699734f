/* Dataset mode: many randomised frames, one EXR each, and a manifest. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <sys/stat.h>

#include <cjson/cJSON.h>

#include "hr_dataset.h"
#include "hr_internal.h"
#include "hr_math.h"
#include "hr_style.h"

void hfr_dataset_defaults(hfr_dataset_opts *o) {
  memset(o, 0, sizeof *o);
  o->styles[0] = HFR_STYLE_STRAIGHT;
  o->styles[1] = HFR_STYLE_WAVY;
  o->n_styles = 2;
  o->count = 8;
  o->width = o->height = 256;
  o->spp_list[0] = 1, o->spp_list[1] = 2, o->spp_list[2] = 4;
  o->n_spp = 3;
  o->gt_supersample = HFR_GT_SUPERSAMPLE;
  o->strands = 20000;
  o->shadow_size = 1024;
  o->seed = 1;
  o->progress = 1;
  hfr_asset_defaults(&o->asset);
}

/* done of total frames, reused of them taken up from an earlier run (no
 * time spent: the ETA is the rate of the others). */
static void progress(int done, int reused, int total, double start_ms) {
  double el = (hr_now_ms() - start_ms) / 1000;
  int rendered = done - reused;
  double eta = rendered > 0 ? el / rendered * (total - done) : 0;
  int bar = 30, fill = total ? done * bar / total : bar;
  char b[64];
  for (int i = 0; i < bar; i++) b[i] = i < fill ? '#' : '.';
  b[bar] = 0;
  /* Rewritten in place on a terminal; a line per frame in a log. */
  int tty = isatty(2);
  fprintf(stderr, "%s[%s] %d/%d  %.0fs elapsed  ETA %.0fs%s", tty ? "\r" : "", b, done, total, el,
          eta, tty ? " " : "\n");
  fflush(stderr);
}

static cJSON *vec3(const float v[3]) {
  double d[3] = {v[0], v[1], v[2]};
  return cJSON_CreateDoubleArray(d, 3);
}

static cJSON *int_list(const int *v, int n) { return cJSON_CreateIntArray(v, n); }

static void add_stats(cJSON *e, const hfr_frame_stats *f) {
  cJSON *s = cJSON_AddObjectToObject(e, "stats");
  if (f->valid) {
    double a[3] = {f->alpha_p10, f->alpha_p50, f->alpha_p90};
    cJSON_AddItemToObject(s, "covered_alpha_p10_p50_p90", cJSON_CreateDoubleArray(a, 3));
    cJSON_AddNumberToObject(s, "sample_coverage", f->sample_coverage);
    cJSON_AddNumberToObject(s, "hair_pixels", f->hair_pixels);
    cJSON_AddNumberToObject(s, "full_pixels", f->full_pixels);
  }
  if (f->gt_opaque >= 0) cJSON_AddNumberToObject(s, "gt_opaque", f->gt_opaque);
  double w[3] = {f->width_px_p10, f->width_px_p50, f->width_px_p90};
  cJSON_AddItemToObject(s, "width_px_p10_p50_p90", cJSON_CreateDoubleArray(w, 3));
  cJSON_AddNumberToObject(s, "points_in_view", (double)f->points_in_view);
  cJSON_AddNumberToObject(s, "points_picked", (double)f->points_picked);
  cJSON_AddNumberToObject(s, "points_model", (double)f->points_model);
}

/* Everything that went into a frame, for the manifest. */
static cJSON *frame_entry(const char *file, const char *source, const hfr_style_params *sp,
                          const hfr_view *v, const hfr_outputs *out, const hfr_dataset_opts *o,
                          uint64_t seed, const hfr_hair *hair, const hfr_stats *st, double ms,
                          const char *hair_file, const hfr_children_params *cp,
                          const hr_regime *rg, const hfr_mesh *occ) {
  int W, H;
  hr_view_target(v, &W, &H);
  cJSON *e = cJSON_CreateObject();
  cJSON_AddStringToObject(e, "file", file);
  cJSON_AddStringToObject(e, "style", source);
  cJSON_AddNumberToObject(e, "seed", (double)seed);
  cJSON_AddNumberToObject(e, "width", W);
  cJSON_AddNumberToObject(e, "height", H);
  /* A crop of a larger frame: EXR's data window inside its display window. */
  cJSON *fr = cJSON_AddObjectToObject(e, "frame");
  cJSON_AddNumberToObject(fr, "width", v->width);
  cJSON_AddNumberToObject(fr, "height", v->height);
  int crop[4] = {v->crop_w > 0 ? v->crop_x : 0, v->crop_w > 0 ? v->crop_y : 0, W, H};
  cJSON_AddItemToObject(fr, "crop_x_y_w_h", int_list(crop, 4));
  /* The names hairfilter eval reads a crop's whole frame by. */
  cJSON_AddNumberToObject(e, "full_width", v->width);
  cJSON_AddNumberToObject(e, "full_height", v->height);
  cJSON_AddNumberToObject(e, "spp", out->spp);
  cJSON_AddItemToObject(e, "spp_list", int_list(o->spp_list, o->n_spp));
  cJSON_AddNumberToObject(e, "gt_supersample", out->gt_supersample);
  cJSON_AddNumberToObject(e, "sample_seed", out->seed);
  cJSON *cam = cJSON_AddObjectToObject(e, "camera");
  cJSON_AddNumberToObject(cam, "distance", v->cam_distance);
  cJSON_AddNumberToObject(cam, "yaw_deg", v->cam_yaw_deg);
  cJSON_AddNumberToObject(cam, "pitch_deg", v->cam_pitch_deg);
  cJSON_AddNumberToObject(cam, "fov_deg", v->cam_fov_deg);
  cJSON *li = cJSON_AddObjectToObject(e, "light");
  cJSON_AddStringToObject(li, "type", v->light_directional ? "directional" : "point");
  cJSON_AddNumberToObject(li, "yaw_deg", v->light_yaw_deg);
  cJSON_AddNumberToObject(li, "pitch_deg", v->light_pitch_deg);
  cJSON_AddNumberToObject(li, "distance", v->light_distance);
  cJSON_AddNumberToObject(li, "shadow_size", v->shadow_size);
  cJSON_AddNumberToObject(li, "shadow_bias", v->shadow_bias);
  cJSON *sh = cJSON_AddObjectToObject(e, "shading");
  cJSON_AddNumberToObject(sh, "alpha_r_deg", v->alpha_r_deg);
  cJSON_AddNumberToObject(sh, "alpha_trt_deg", v->alpha_trt_deg);
  cJSON_AddNumberToObject(sh, "ambient", v->ambient);
  cJSON_AddNumberToObject(sh, "thickness_scale", v->thickness_scale);
  cJSON_AddItemToObject(sh, "hair_color", vec3(v->hair_color));
  cJSON_AddItemToObject(sh, "light_color", vec3(v->light_color));
  cJSON_AddItemToObject(sh, "background", vec3(v->background));
  cJSON_AddItemToObject(sh, "occluder_color", vec3(v->occluder_color));
  cJSON *h = cJSON_AddObjectToObject(e, "hair");
  if (hair_file) {
    cJSON_AddStringToObject(h, "file", hair_file);
    cJSON_AddStringToObject(h, "up", hfr_axis_name(o->asset.up));
    cJSON_AddNumberToObject(h, "scale", o->asset.scale > 0 ? o->asset.scale : 1);
    cJSON_AddNumberToObject(h, "children", cp->children);
    cJSON_AddNumberToObject(h, "children_seed", (double)cp->seed);
    cJSON_AddNumberToObject(h, "child_spread", cp->spread);
    cJSON_AddNumberToObject(h, "child_clumping", cp->clumping);
    if (o->asset.thickness > 0) cJSON_AddNumberToObject(h, "thickness", o->asset.thickness);
    if (o->asset.opacity > 0) cJSON_AddNumberToObject(h, "opacity", o->asset.opacity);
  } else {
    cJSON_AddNumberToObject(h, "seed", (double)sp->seed);
    cJSON_AddNumberToObject(h, "strands", sp->strands);
    cJSON_AddNumberToObject(h, "segments", sp->segments);
    cJSON_AddNumberToObject(h, "length", sp->length);
    cJSON_AddNumberToObject(h, "clumping", sp->clumping);
    cJSON_AddNumberToObject(h, "frizz", sp->frizz);
    cJSON_AddNumberToObject(h, "curl_radius", sp->curl_radius);
    cJSON_AddNumberToObject(h, "curl_period", sp->curl_period);
    cJSON_AddNumberToObject(h, "thickness", sp->thickness);
    cJSON_AddNumberToObject(h, "opacity", sp->opacity);
    cJSON_AddNumberToObject(h, "width_spread", sp->width_spread);
    cJSON_AddNumberToObject(h, "children", sp->children);
    if (sp->style == HFR_STYLE_BRAIDED) cJSON_AddNumberToObject(h, "plaits", hr_braid_plaits(sp));
    /* Only where drawn, so that other runs' manifests read as before. */
    if (o->gather_max > 0 && hfr_style_has_tie(sp->style))
      cJSON_AddNumberToObject(h, "gather", sp->gather);
    if (o->smooth_share > 0) cJSON_AddBoolToObject(h, "smooth", hr_smooth_picked(o, sp->seed));
  }
  cJSON_AddStringToObject(e, "occluder", !occ || !occ->vertices ? "none"
                                         : hair_file ? (hfr_asset_fitted(&o->asset) ? "fit"
                                                                                   : o->asset.occluder)
                                                     : (sp->style == HFR_STYLE_FUR ? "fur body"
                                                                                   : "head"));
  if (o->regimes) {
    cJSON *rj = cJSON_AddObjectToObject(e, "regime");
    cJSON_AddNumberToObject(rj, "frame_size", rg->frame_size);
    cJSON_AddNumberToObject(rj, "target_width_px", rg->target_width_px);
    cJSON_AddNumberToObject(rj, "typical_thickness", rg->typical_thickness);
    cJSON_AddNumberToObject(rj, "clump_width_spread", rg->clump_width_spread);
  }
  add_stats(e, &st->frame);
  cJSON_AddNumberToObject(e, "strand_count", hair->strands);
  cJSON_AddNumberToObject(e, "segment_count", (double)hfr_hair_total_segments(hair));
  cJSON_AddNumberToObject(e, "gt_fragments", (double)st->gt_fragments);
  if (st->gt_culled) cJSON_AddNumberToObject(e, "gt_culled", (double)st->gt_culled);
  cJSON_AddNumberToObject(e, "gt_shared_positions", st->gt_shared_positions);
  cJSON_AddNumberToObject(e, "render_ms", ms);
  return e;
}

/* The extended set: each frame's style parameters drawn over wide ranges
 * instead of around the style's defaults, so that a network trained on a
 * few generators sees the curl radii and periods, densities, strand widths,
 * lengths, clumping and opacities of styles it is never trained on (a wavy
 * strand with a 0.09 period and 0.035 radius is as tight as a coil). The
 * ranges cover every style default in hr_hair_gen.c with room to spare. */
static void extend_style(hfr_style_params *sp, hr_rng *g, const hfr_dataset_opts *o) {
  sp->length = hr_rng_range(g, 0.7f, 3.0f);
  if (sp->style == HFR_STYLE_BRAIDED) {
    hr_braid_draw(g, o, sp);
  } else if (sp->style != HFR_STYLE_STRAIGHT) {
    sp->curl_period = hr_rng_range(g, 0.07f, 0.9f);
    /* Radius relative to period: tight coils have small radii. */
    sp->curl_radius = sp->curl_period * hr_rng_range(g, 0.1f, 0.45f);
    /* A wave is drawn with about 6 segments per period, at most 128 per
     * strand: tight waves get the short lengths of coily hair. */
    sp->length = fminf(sp->length, 128.0f * sp->curl_period / 6.0f);
    if (o->segments <= 0)
      sp->segments = (int)fminf(128.0f, fmaxf(24.0f, ceilf(6.0f * sp->length / sp->curl_period)));
  }
  sp->clumping = hr_rng_range(g, 0.0f, 0.7f);
  sp->frizz = hr_rng_range(g, 0.0f, 0.05f);
  sp->thickness = 0.0008f * hr_rng_range(g, 0.5f, 2.0f);
  sp->opacity = hr_rng_range(g, 0.3f, 1.0f);
  if (o->strands <= 0) sp->strands = (int)hr_rng_range(g, 8000.0f, 40000.0f);
}

static int write_manifest(const char *dir, cJSON *doc) {
  char path[4096], tmp[4200];
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  snprintf(tmp, sizeof tmp, "%s.tmp", path);
  char *text = cJSON_Print(doc);
  if (!text) return HF_ENOMEM;
  FILE *f = fopen(tmp, "w");
  int rc = f ? HF_OK : HF_EIO;
  if (f) {
    if (fputs(text, f) < 0) rc = HF_EIO;
    if (fclose(f) != 0) rc = HF_EIO;
  }
  free(text);
  /* Rename: a reader never sees half a manifest. */
  if (rc == HF_OK && rename(tmp, path) != 0) rc = HF_EIO;
  return rc;
}

/* A .hair file drawn as a style: its guides (as loaded: widths checked,
 * oriented) and its occluder, loaded once. */
typedef struct ds_model {
  hfr_hair guides;
  hfr_mesh occ;
  char name[64];
} ds_model;

/* "dir/Long Tied.hair" -> "Long_Tied". */
static void base_name(const char *path, char *out, size_t n) {
  const char *b = strrchr(path, '/');
  b = b ? b + 1 : path;
  size_t k = 0;
  for (; *b && k + 1 < n; b++) {
    if (!strcmp(b, ".hair")) break;
    char c = *b;
    out[k++] = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                       c == '-' || c == '.'
                   ? c : '_';
  }
  out[k] = 0;
}

/* Source k's name, the stem of its frames' files: the k-th style, then the
 * .hair files. */
static void source_name(const hfr_dataset_opts *o, int k, char *out, size_t n) {
  if (k < o->n_styles) snprintf(out, n, "%s", hfr_style_name(o->styles[k]));
  else base_name(o->hair_files[k - o->n_styles], out, n);
}

/* Source k as the command line gave it, for messages. */
static void source_said(const hfr_dataset_opts *o, int k, char *out, size_t n) {
  if (k < o->n_styles) snprintf(out, n, "style %s", hfr_style_name(o->styles[k]));
  else snprintf(out, n, "%s", o->hair_files[k - o->n_styles]);
}

/* A frame's file is named after its source ("{source}_{i:04d}.exr"), so two
 * sources of one name (a style given twice, a/bob.hair and b/bob.hair,
 * wavy.hair beside --styles wavy) would write over each other's frames and
 * the manifest would list one file twice. HF_EINVAL, naming both. */
static int check_source_names(const hfr_dataset_opts *o, char *err, size_t errlen) {
  const int n = o->n_styles + o->n_hair_files;
  for (int a = 0; a < n; a++)
    for (int b = a + 1; b < n; b++) {
      char na[64], nb[64];
      source_name(o, a, na, sizeof na);
      source_name(o, b, nb, sizeof nb);
      if (strcmp(na, nb)) continue;
      char sa[512], sb[512];
      source_said(o, a, sa, sizeof sa);
      source_said(o, b, sb, sizeof sb);
      if (err)
        snprintf(err, errlen, "%s and %s would both write %s_NNNN.exr (a frame is named "
                 "after its style or .hair file): %s", sa, sb, na,
                 b < o->n_styles   ? "give each style once (afro names coily, long-tied "
                                     "ponytail, braids and plaits braided)"
                 : a < o->n_styles ? "link the file under another name (ln -s "
                                     "DIR/NAME.hair OTHER.hair)"
                                   : "give each file once, or link one under another name "
                                     "(ln -s DIR/NAME.hair OTHER.hair)");
      return HF_EINVAL;
    }
  return HF_OK;
}

int hfr_dataset_run(const hfr_dataset_opts *o, char *err, size_t errlen) {
  if (!o || !o->out_dir || (o->n_styles < 1 && o->n_hair_files < 1) || o->count < 1 ||
      o->n_spp < 1 || o->n_styles < 0 || o->n_hair_files < 0) {
    if (err) snprintf(err, errlen, "need an output directory, styles or .hair files, a count and spp");
    return HF_EINVAL;
  }
  int spp = 0;
  for (int i = 0; i < o->n_spp; i++) {
    if (o->spp_list[i] < 1 || o->spp_list[i] > HF_MAX_SPP) {
      if (err) snprintf(err, errlen, "spp must be 1..%d", HF_MAX_SPP);
      return HF_EINVAL;
    }
    if (o->spp_list[i] > spp) spp = o->spp_list[i];
  }
  if (o->regimes && (o->frame_min < 0 || o->frame_max < 0 || o->frame_max > 8192 ||
                     (o->frame_min && o->frame_max && o->frame_min > o->frame_max))) {
    if (err) snprintf(err, errlen, "frame sizes must be MIN <= MAX <= 8192");
    return HF_EINVAL;
  }
  if (o->regimes && (o->width_px_min || o->width_px_max) &&
      !(o->width_px_min > 0 && o->width_px_min <= o->width_px_max && o->width_px_max <= 64)) {
    if (err)
      snprintf(err, errlen, "strand widths must be 0 < MIN <= MAX <= 64 pixels (--width-px)");
    return HF_EINVAL;
  }
  if ((o->opacity_min || o->opacity_max) &&
      !(o->opacity_min > 0 && o->opacity_min <= o->opacity_max && o->opacity_max <= 1)) {
    if (err) snprintf(err, errlen, "strand opacities must be 0 < MIN <= MAX <= 1 (--opacity-range)");
    return HF_EINVAL;
  }
  if ((o->gather_min || o->gather_max) &&
      !(o->gather_min >= 0 && o->gather_min <= o->gather_max && o->gather_max <= 1)) {
    if (err) snprintf(err, errlen, "gathers must be 0 <= MIN <= MAX <= 1 (--gather-range)");
    return HF_EINVAL;
  }
  if (!(o->smooth_share >= 0 && o->smooth_share <= 1)) {
    if (err) snprintf(err, errlen, "the smooth share must be in [0, 1] (--smooth-share)");
    return HF_EINVAL;
  }
  if (check_source_names(o, err, errlen) != HF_OK) return HF_EINVAL;
  if (mkdir(o->out_dir, 0777) != 0 && errno != EEXIST) {
    if (err) snprintf(err, errlen, "%s: %s", o->out_dir, strerror(errno));
    return HF_EIO;
  }
  ds_model *models = calloc(o->n_hair_files ? (size_t)o->n_hair_files : 1, sizeof *models);
  if (!models) return HF_ENOMEM;
  int rc = HF_OK;
  hfr_asset_opts guides_only = o->asset;
  guides_only.children.children = 0;
  for (int f = 0; rc == HF_OK && f < o->n_hair_files; f++) {
    char warn[2048] = "";
    rc = hfr_asset_load(o->hair_files[f], &guides_only, &models[f].guides, &models[f].occ, warn,
                        sizeof warn, err, errlen);
    /* Which of the files it was, when the reason does not say. */
    size_t n = strlen(o->hair_files[f]);
    if (rc != HF_OK && err && errlen && (strncmp(err, o->hair_files[f], n) || err[n] != ':')) {
      char why[1024];
      snprintf(why, sizeof why, "%s", err);
      snprintf(err, errlen, "%s: %s", o->hair_files[f], why);
    }
    /* --quiet or not: --quiet silences the progress bar, and these say how
     * the model is drawn (a width fallback, strands left out). */
    if (*warn)
      fprintf(stderr, "hairfilter render dataset: warning: %s: %s\n", o->hair_files[f], warn);
    base_name(o->hair_files[f], models[f].name, sizeof models[f].name);
  }
  hfr_renderer *r = NULL;
  if (rc == HF_OK) rc = hfr_renderer_create(o->platform, &r, err, errlen);
  if (rc != HF_OK) {
    for (int f = 0; f < o->n_hair_files; f++)
      hfr_hair_free(&models[f].guides), hfr_mesh_free(&models[f].occ);
    free(models);
    return rc;
  }

  cJSON *doc = cJSON_CreateObject();
  cJSON_AddStringToObject(doc, "format", "hairfilter-dataset");
  cJSON_AddNumberToObject(doc, "version", 1);
  cJSON_AddStringToObject(doc, "generator", "hairfilter render dataset");
  cJSON_AddStringToObject(doc, "gl_platform", hfr_renderer_platform(r));
  cJSON_AddStringToObject(doc, "gl_renderer", hfr_renderer_gl_name(r));
  cJSON_AddNumberToObject(doc, "spp", spp);
  cJSON_AddItemToObject(doc, "spp_list", int_list(o->spp_list, o->n_spp));
  cJSON_AddItemToObject(doc, "st", int_list(o->st_spp, o->n_st));
  cJSON_AddBoolToObject(doc, "alpha_corrected", o->alpha_corrected != 0);
  cJSON_AddNumberToObject(doc, "seed", (double)o->seed);
  cJSON_AddBoolToObject(doc, "extended", o->extended != 0);
  cJSON_AddBoolToObject(doc, "regimes", o->regimes != 0);
  /* The ranges as they were drawn from (the regimes' with defaults filled
   * in; an opacity range given out of regimes): the options record's, at
   * the top level where readers look for them. */
  cJSON *options = hr_dataset_options(o);
  static const char *const ranges[] = {"frame_sizes", "width_px_range", "opacity_range"};
  for (int k = 0; options && k < 3; k++) {
    const cJSON *range = cJSON_GetObjectItemCaseSensitive(options, ranges[k]);
    if (range) cJSON_AddItemToObject(doc, ranges[k], cJSON_Duplicate(range, 1));
  }
  if (options && o->smooth_share > 0) cJSON_AddNumberToObject(doc, "smooth_share", o->smooth_share);
  if (options && o->gather_max > 0)
    cJSON_AddItemToObject(doc, "gather_range",
                          cJSON_Duplicate(cJSON_GetObjectItemCaseSensitive(options, "gather_range"), 1));
  if (options) cJSON_AddItemToObject(doc, "options", options);
  cJSON *frames = cJSON_AddArrayToObject(doc, "frames");
  cJSON *skipped = cJSON_AddArrayToObject(doc, "skipped");
  int n_skipped = 0, grid_noted = 0, reused = 0, n_reused_skipped = 0;
  cJSON *old = NULL;
  if (!options || !frames || !skipped) rc = HF_ENOMEM;
  else if (o->resume)
    rc = hr_dataset_resume_open(o->out_dir, options, o->count, hfr_renderer_gl_name(r), &old,
                                err, errlen);
  else
    hr_dataset_note_earlier_run(o->out_dir);
  hr_dataset_resume_history(doc, old);

  const int sources = o->n_styles + o->n_hair_files, total = sources * o->count;
  double start = hr_now_ms();
  int done = 0;
  /* Round robin over the sources (frame i of every style, then frame i + 1):
   * a run stopped early still holds every style in equal measure. A frame's
   * seed depends only on (si, i), never on the order. */
  for (int i = 0; rc == HF_OK && i < o->count; i++)
    for (int si = 0; rc == HF_OK && si < sources; si++) {
      const int fi = si - o->n_styles; /* >= 0: a .hair file */
      uint64_t seed = o->seed * 1000003ull + (uint64_t)si * 10007ull + (uint64_t)i;
      char file[128], path[4200];
      snprintf(file, sizeof file, "%s_%04d.exr",
               fi < 0 ? hfr_style_name(o->styles[si]) : models[fi].name, i);
      snprintf(path, sizeof path, "%s/%s", o->out_dir, file);
      int was_skipped = 0;
      cJSON *kept = hr_dataset_resume_take(old, o->out_dir, file, &was_skipped);
      if (kept) {
        /* Finished (or left out) by the run taken up: as it was. */
        cJSON_AddItemToArray(was_skipped ? skipped : frames, kept);
        n_skipped += was_skipped;
        n_reused_skipped += was_skipped;
        /* The manifest on disk lists it already; the next frame rendered,
         * or the end of the run, writes the new one. */
        reused++;
        done++;
        if (o->progress) progress(done, reused, total, start);
        continue;
      }
      hr_rng g = {seed * 0x9e3779b97f4a7c15ull + 3};
      hfr_style_params sp;
      hfr_style_defaults(fi < 0 ? o->styles[si] : HFR_STYLE_STRAIGHT, &sp);
      sp.seed = seed;
      hr_regime rg;
      memset(&rg, 0, sizeof rg);
      if (fi < 0) {
        if (o->strands > 0) sp.strands = o->strands;
        if (o->segments > 0) sp.segments = o->segments;
        /* Some variety within a style. */
        sp.length *= hr_rng_range(&g, 0.8f, 1.2f);
        sp.clumping = fminf(1.0f, sp.clumping * hr_rng_range(&g, 0.5f, 1.5f));
        sp.frizz *= hr_rng_range(&g, 0.5f, 1.5f);
        sp.curl_radius *= hr_rng_range(&g, 0.8f, 1.2f);
        sp.thickness *= hr_rng_range(&g, 0.8f, 1.25f);
        sp.opacity = fminf(1.0f, sp.opacity * hr_rng_range(&g, 0.85f, 1.2f));
        if (o->extended) extend_style(&sp, &g, o);
        if (o->width_spread > 0) sp.width_spread = o->width_spread;
        if (o->regimes) hr_regime_style(&g, o, &sp, &rg);
        hr_opacity_draw(o, &sp);
        hr_gather_draw(o, &sp);
        hr_smooth_draw(o, &sp);
      }
      hfr_view v;
      hfr_view_defaults(&v);
      v.width = o->width;
      v.height = o->height;
      v.shadow_size = o->shadow_size;
      hfr_view_randomize(&v, seed);
      /* Closer and farther than the standard views: strand width on screen
       * and pixel coverage vary with distance as much as with thickness. */
      if (o->extended) v.cam_distance = hr_rng_range(&g, 1.8f, 6.0f);
      hfr_outputs out = {0};
      out.spp = spp;
      out.gt_supersample = o->gt_supersample;
      out.n_st = o->n_st;
      memcpy(out.st_spp, o->st_spp, sizeof out.st_spp);
      out.opaque_samples = o->opaque_samples;
      out.alpha_corrected = o->alpha_corrected;
      out.background_layer = o->background_layer;
      out.seed = (uint32_t)(seed * 2654435761u);
      out.max_fragments = o->max_fragments;
      out.gt_cull = o->gt_cull;

      double t0 = hr_now_ms();
      hfr_hair hair;
      hf_image img = {0};
      hfr_stats st;
      hfr_mesh body = {0};
      const hfr_mesh *occ = &body;
      hfr_children_params cp = o->asset.children;
      cp.seed = seed;
      if (fi < 0) {
        rc = hfr_style_check(&sp, err, errlen);
        if (rc == HF_OK) rc = hfr_hair_generate(&sp, &hair);
        hfr_ellipsoid e;
        hfr_style_body(sp.style, &e);
        if (rc == HF_OK) rc = hfr_mesh_ellipsoid(&e, 48, 24, &body);
      } else if (cp.children > 0) {
        rc = hfr_hair_interpolate(&models[fi].guides, &cp, &hair);
        if (rc != HF_OK && err) snprintf(err, errlen, "%s: children: %s", o->hair_files[fi],
                                         hf_strerror(rc));
        occ = &models[fi].occ;
      } else {
        /* The guides as they are: a copy the loop can free. */
        hfr_children_params keep;
        hfr_children_defaults(&keep);
        keep.children = 0;
        rc = hfr_hair_interpolate(&models[fi].guides, &keep, &hair);
        occ = &models[fi].occ;
      }
      if (rc != HF_OK) {
        hfr_mesh_free(&body);
        break;
      }
      int head = fi < 0 && sp.style != HFR_STYLE_FUR;
      rc = hfr_renderer_set_hair(r, &hair, head, err, errlen);
      if (rc == HF_OK && !head)
        rc = hfr_renderer_set_occluder(r, occ, fi < 0 || hfr_asset_fitted(&o->asset), err, errlen);
      if (rc == HF_OK && o->regimes) hr_regime_view(&g, o, r, &hair, &v, &rg);
      if (rc == HF_OK) rc = hfr_render(r, &v, &out, &img, &st, err, errlen);
      int left_out = rc == HF_ERANGE;
      if (left_out) {
        /* A draw too dense for the ground truth's A-buffer: the frame is
         * left out (named in the manifest's "skipped" list) and the run goes
         * on, rather than losing every frame after it. */
        fprintf(stderr, "%shairfilter render dataset: %s left out: %s\n",
                o->progress && isatty(2) ? "\n" : "", file, err ? err : "too many fragments");
        cJSON *sk = cJSON_CreateObject();
        cJSON_AddStringToObject(sk, "file", file);
        cJSON_AddStringToObject(sk, "reason", err ? err : "too many fragments");
        cJSON_AddItemToArray(skipped, sk);
        rc = write_manifest(o->out_dir, doc);
        if (rc != HF_OK && err) snprintf(err, errlen, "cannot write %s/manifest.json", o->out_dir);
        n_skipped++;
      }
      if (rc == HF_OK && !left_out) {
        rc = hfr_frame_write(path, &img, o->half, &out, &st);
        if (rc != HF_OK && err) snprintf(err, errlen, "%s: %s", path, hf_strerror(rc));
      }
      if (rc == HF_OK && !left_out && st.gt_shared_positions > 0 && !grid_noted) {
        /* Once per run, --quiet or not: every frame shares the same
         * positions, and the scores of every frame are biased by them. */
        fprintf(stderr, "%shairfilter render dataset: note: %d of the 4 MSAA sample positions "
                "are sub-pixel centres of this ground truth (--gt-ss %d): on opaque strands the "
                "4 samples, and what reads them, score better against it than they are; use "
                "--gt-ss %d\n",
                o->progress && isatty(2) ? "\n" : "", st.gt_shared_positions, out.gt_supersample,
                HFR_GT_SUPERSAMPLE);
        grid_noted = 1;
      }
      if (rc == HF_OK && !left_out) {
        cJSON_AddItemToArray(
            frames, frame_entry(file, fi < 0 ? hfr_style_name(sp.style) : models[fi].name, &sp,
                                &v, &out, o, seed, &hair, &st, hr_now_ms() - t0,
                                fi < 0 ? NULL : o->hair_files[fi], &cp, &rg, occ));
        /* Rewritten after every frame: an interrupted run keeps a valid
         * manifest of the frames it finished. */
        rc = write_manifest(o->out_dir, doc);
        if (rc != HF_OK && err) snprintf(err, errlen, "cannot write %s/manifest.json", o->out_dir);
      }
      hf_image_free(&img);
      hfr_hair_free(&hair);
      hfr_mesh_free(&body);
      done++;
      if (o->progress) progress(done, reused, total, start);
    }
  if (o->progress && isatty(2)) fprintf(stderr, "\n");
  if (rc == HF_OK && reused) {
    rc = write_manifest(o->out_dir, doc);
    if (rc != HF_OK && err) snprintf(err, errlen, "cannot write %s/manifest.json", o->out_dir);
  }
  if (o->progress && reused)
    fprintf(stderr, "hairfilter render dataset: took up %d frames of the run before (%d of "
            "them left out as too dense), rendered %d\n", reused, n_reused_skipped,
            done - reused);
  cJSON_Delete(old);
  if (rc == HF_OK && n_skipped == total) {
    if (err) snprintf(err, errlen, "every frame was left out (too dense for the A-buffer): "
                      "lower --strands, --size or --gt-ss");
    rc = HF_ERANGE;
  }
  cJSON_Delete(doc);
  hfr_renderer_destroy(r);
  for (int f = 0; f < o->n_hair_files; f++)
    hfr_hair_free(&models[f].guides), hfr_mesh_free(&models[f].occ);
  free(models);
  return rc;
}
