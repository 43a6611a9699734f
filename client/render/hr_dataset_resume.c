/* Resuming a dataset run: the record of the options that decide a dataset's
 * frames, and taking the frames an earlier, interrupted run of the same
 * options finished.
 *
 * A frame's draws depend only on the options and its (source, index), never
 * on the frames before it (hr_dataset.c), so a run stopped after any frame
 * can be taken up again: the frames its manifest lists are kept as they are
 * and only the others are rendered. The manifest is written after each
 * frame's EXR is complete, so a file it lists is whole; a file it does not
 * list (the frame in flight when the run stopped) is rendered again. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#include <cjson/cJSON.h>

#include "hfcore.h"
#include "hr_dataset.h"
#include "hr_internal.h"

/* A manifest of tens of thousands of frames is a few tens of MB. */
#define HR_MANIFEST_MAX_BYTES (256u << 20)

static void add_range(cJSON *o, const char *name, double lo, double hi) {
  double v[2] = {lo, hi};
  cJSON_AddItemToObject(o, name, cJSON_CreateDoubleArray(v, 2));
}

/* A mesh file by its real path, as the .hair files are: the record is
 * compared on --resume, which may run from another directory or spell the
 * path another way (./head.obj, /abs/head.obj). "fit" and "none" as they
 * were recorded before: they name no file. */
static cJSON *occluder_record(const hfr_asset_opts *a) {
  if (hfr_asset_fitted(a)) return cJSON_CreateString("fit");
  if (!strcasecmp(a->occluder, "none")) return cJSON_CreateString(a->occluder);
  char *real = realpath(a->occluder, NULL);
  cJSON *s = cJSON_CreateString(real ? real : a->occluder);
  free(real);
  return s;
}

cJSON *hr_dataset_options(const hfr_dataset_opts *o) {
  cJSON *j = cJSON_CreateObject();
  if (!j) return NULL;
  cJSON *styles = cJSON_AddArrayToObject(j, "styles");
  for (int i = 0; i < o->n_styles; i++)
    cJSON_AddItemToArray(styles, cJSON_CreateString(hfr_style_name(o->styles[i])));
  cJSON *files = cJSON_AddArrayToObject(j, "hair_files");
  for (int i = 0; i < o->n_hair_files; i++) {
    /* The file, not the spelling of its path: ./a.hair and /abs/a.hair match. */
    char *real = realpath(o->hair_files[i], NULL);
    cJSON_AddItemToArray(files, cJSON_CreateString(real ? real : o->hair_files[i]));
    free(real);
  }
  cJSON_AddNumberToObject(j, "width", o->width);
  cJSON_AddNumberToObject(j, "height", o->height);
  cJSON_AddItemToObject(j, "spp_list", cJSON_CreateIntArray(o->spp_list, o->n_spp));
  cJSON_AddNumberToObject(j, "gt_supersample", o->gt_supersample);
  cJSON_AddItemToObject(j, "st", cJSON_CreateIntArray(o->st_spp, o->n_st));
  cJSON_AddNumberToObject(j, "opaque_samples", o->opaque_samples);
  cJSON_AddBoolToObject(j, "alpha_corrected", o->alpha_corrected != 0);
  cJSON_AddNumberToObject(j, "strands", o->strands);
  cJSON_AddNumberToObject(j, "segments", o->segments);
  cJSON_AddNumberToObject(j, "shadow_size", o->shadow_size);
  /* As a string: a 64-bit seed does not survive a JSON double. */
  char seed[32];
  snprintf(seed, sizeof seed, "%llu", (unsigned long long)o->seed);
  cJSON_AddStringToObject(j, "seed", seed);
  cJSON_AddBoolToObject(j, "half", o->half != 0);
  cJSON_AddBoolToObject(j, "extended", o->extended != 0);
  cJSON_AddNumberToObject(j, "max_fragments", o->max_fragments);
  if (o->gt_cull) cJSON_AddNumberToObject(j, "gt_cull", o->gt_cull); /* auto: as before */
  cJSON_AddBoolToObject(j, "regimes", o->regimes != 0);
  if (o->regimes) {
    add_range(j, "frame_sizes", o->frame_min > 0 ? o->frame_min : 256,
              o->frame_max > 0 ? o->frame_max : 1024);
    add_range(j, "width_px_range", o->width_px_min > 0 ? o->width_px_min : HR_REGIME_WIDTH_PX_MIN,
              o->width_px_max > 0 ? o->width_px_max : HR_REGIME_WIDTH_PX_MAX);
    float op[2];
    hr_regime_opacity_range(o, op);
    add_range(j, "opacity_range", op[0], op[1]);
  } else if (o->opacity_max > 0) {
    /* Only when drawn, so that a manifest from before still matches. */
    add_range(j, "opacity_range", o->opacity_min, o->opacity_max);
  }
  /* Only when drawn, so that a manifest from before --gather-range still
   * matches. */
  if (o->gather_max > 0) add_range(j, "gather_range", o->gather_min, o->gather_max);
  if (o->smooth_share > 0) cJSON_AddNumberToObject(j, "smooth_share", o->smooth_share);
  cJSON_AddNumberToObject(j, "width_spread", o->width_spread);
  cJSON_AddBoolToObject(j, "background_layer", o->background_layer != 0);
  if (o->n_hair_files) {
    const hfr_asset_opts *a = &o->asset;
    cJSON *aj = cJSON_AddObjectToObject(j, "asset");
    cJSON_AddStringToObject(aj, "up", hfr_axis_name(a->up));
    cJSON_AddNumberToObject(aj, "scale", a->scale > 0 ? a->scale : 1);
    cJSON_AddNumberToObject(aj, "thickness", a->thickness);
    /* Only when given, so that a manifest from before --opacity took .hair
     * files still matches. */
    if (a->opacity > 0) cJSON_AddNumberToObject(aj, "opacity", a->opacity);
    cJSON_AddItemToObject(aj, "occluder", occluder_record(a));
    const hfr_children_params *c = &a->children;
    cJSON_AddNumberToObject(aj, "children", c->children);
    cJSON_AddBoolToObject(aj, "keep_guides", c->keep_guides != 0);
    cJSON_AddNumberToObject(aj, "child_spread", c->spread);
    cJSON_AddNumberToObject(aj, "child_clumping", c->clumping);
    cJSON_AddNumberToObject(aj, "child_frizz", c->frizz);
    cJSON_AddNumberToObject(aj, "child_length_jitter", c->length_jitter);
    cJSON_AddNumberToObject(aj, "child_width_spread", c->width_spread);
  }
  return j;
}

/* The whole of a file, NUL-terminated, or NULL with err set. */
static char *read_text(const char *path, char *err, size_t errlen) {
  FILE *f = fopen(path, "rb");
  if (!f) {
    snprintf(err, errlen, "%s: cannot open", path);
    return NULL;
  }
  char *text = NULL;
  long n = -1;
  if (fseek(f, 0, SEEK_END) == 0) n = ftell(f);
  if (n < 0 || (unsigned long)n > HR_MANIFEST_MAX_BYTES || fseek(f, 0, SEEK_SET) != 0)
    snprintf(err, errlen, "%s: unreadable or larger than %u MB", path,
             HR_MANIFEST_MAX_BYTES >> 20);
  else if (!(text = malloc((size_t)n + 1)))
    snprintf(err, errlen, "%s: out of memory", path);
  else if (fread(text, 1, (size_t)n, f) != (size_t)n) {
    snprintf(err, errlen, "%s: read error", path);
    free(text);
    text = NULL;
  } else
    text[n] = 0;
  fclose(f);
  return text;
}

/* The command-line option that sets each member of the options record
 * (hr_dataset_options), for messages; members without one are named as
 * they are. */
static const char *const option_names[][2] = {
    {"styles", "--styles"}, {"hair_files", "--hair-files"}, {"width", "--size"},
    {"height", "--size"}, {"spp_list", "--spp"}, {"gt_supersample", "--gt-ss"}, {"st", "--st"},
    {"opaque_samples", "--opaque"}, {"alpha_corrected", "--alpha-corrected/--no-alpha-corrected"},
    {"strands", "--strands"}, {"segments", "--segments"}, {"shadow_size", "--shadow-size"},
    {"seed", "--seed"}, {"half", "--half"}, {"extended", "--extended"},
    {"max_fragments", "--max-fragments"}, {"gt_cull", "--gt-cull"}, {"regimes", "--regimes"},
    {"frame_sizes", "--frame-sizes"}, {"width_px_range", "--width-px"},
    {"opacity_range", "--opacity-range"}, {"gather_range", "--gather-range"},
    {"smooth_share", "--smooth-share"},
    {"width_spread", "--width-spread"},
    {"background_layer", "--no-background"}, {"asset.up", "--up"},
    {"asset.scale", "--units/--scale"}, {"asset.thickness", "--thickness"}, {"asset.opacity", "--opacity"},
    {"asset.occluder", "--occluder"}, {"asset.children", "--children"},
    {"asset.child_spread", "--child-spread"}, {"asset.child_clumping", "--child-clumping"},
};

static const char *option_of(const char *key) {
  for (size_t i = 0; i < sizeof option_names / sizeof option_names[0]; i++)
    if (!strcmp(option_names[i][0], key)) return option_names[i][1];
  return key;
}

/* The first member of want whose value differs in have, or that one of the
 * two lacks, descending into objects: its path ("asset.up") into key and
 * the two values into w and h (JSON, "(none)" where absent). 0 when none. */
static int first_difference(const cJSON *want, const cJSON *have, const char *prefix, char *key,
                            size_t keylen, const cJSON **w, const cJSON **h) {
  for (int pass = 0; pass < 2; pass++) {
    const cJSON *a = pass ? have : want, *b = pass ? want : have, *it;
    cJSON_ArrayForEach(it, a) {
      const cJSON *other = cJSON_GetObjectItemCaseSensitive(b, it->string);
      if (other && cJSON_Compare(it, other, 1)) continue;
      if (other && cJSON_IsObject(it) && cJSON_IsObject(other)) {
        char sub[128];
        snprintf(sub, sizeof sub, "%s%s.", prefix, it->string);
        if (first_difference(pass ? other : it, pass ? it : other, sub, key, keylen, w, h))
          return 1;
      }
      snprintf(key, keylen, "%s%s", prefix, it->string);
      *w = pass ? other : it;
      *h = pass ? it : other;
      return 1;
    }
  }
  return 0;
}

/* A number as it was given: the options record holds floats widened to
 * double (0.7f is 0.699999988079071), so a value a float holds exactly is
 * printed with the fewest digits that give the same float back ("0.7"),
 * any other with the fewest that give the same double back. */
static void number_text(double v, char *out, size_t len) {
  const int as_float = (double)(float)v == v;
  /* A whole number in full ("20", "1000"): %g with few digits would write
   * 20 as "2e+01", which reads back the same but not as it was typed. */
  if (v == (double)(long long)v && v > -1e15 && v < 1e15) {
    snprintf(out, len, "%lld", (long long)v);
    return;
  }
  for (int p = 1; p <= 17; p++) {
    snprintf(out, len, "%.*g", p, v);
    double back = strtod(out, NULL);
    if (as_float ? (float)back == (float)v : back == v) return;
  }
}

/* v as one line of JSON with its numbers as number_text writes them,
 * appended at out + *used (never past len - 1). */
static void append_json(const cJSON *v, char *out, size_t len, size_t *used) {
  char num[32];
  const char *t = NULL;
  char *owned = NULL;
  if (cJSON_IsNumber(v)) {
    number_text(v->valuedouble, num, sizeof num);
    t = num;
  } else if (cJSON_IsArray(v) || cJSON_IsObject(v)) {
    const int obj = cJSON_IsObject(v);
    if (*used + 1 < len) out[(*used)++] = obj ? '{' : '[';
    const cJSON *it;
    cJSON_ArrayForEach(it, v) {
      if (it != v->child && *used + 1 < len) out[(*used)++] = ',';
      if (obj && it->string && *used + 1 < len)
        *used += (size_t)snprintf(out + *used, len - *used, "\"%s\":", it->string);
      if (*used >= len) *used = len - 1;
      append_json(it, out, len, used);
    }
    if (*used + 1 < len) out[(*used)++] = obj ? '}' : ']';
    out[*used] = 0;
    return;
  } else if (v) {
    t = owned = cJSON_PrintUnformatted(v);
  }
  if (t && *used + 1 < len) {
    *used += (size_t)snprintf(out + *used, len - *used, "%s", t);
    if (*used >= len) *used = len - 1;
  }
  free(owned);
}

/* A value for a message: JSON on one line, cut to fit. */
static void value_text(const cJSON *v, char *out, size_t len) {
  if (len < 8) {
    if (len) *out = 0;
    return;
  }
  size_t used = 0;
  *out = 0;
  if (!v) {
    snprintf(out, len, "(none)");
    return;
  }
  append_json(v, out, len, &used);
  if (used >= len - 1) memcpy(out + len - 4, "...", 4);
}

/* The index of a frame file "{source}_{i:04d}.exr", or -1. */
static long frame_index(const char *file) {
  const char *u = strrchr(file, '_');
  if (!u) return -1;
  char *end;
  long i = strtol(u + 1, &end, 10);
  return end != u + 1 && !strcmp(end, ".exr") && i >= 0 ? i : -1;
}

/* HF_EINVAL, err naming it, when list holds a frame beyond count. */
static int check_count(const cJSON *list, int count, const char *path, char *err,
                       size_t errlen) {
  const cJSON *e;
  cJSON_ArrayForEach(e, list) {
    const cJSON *f = cJSON_GetObjectItemCaseSensitive(e, "file");
    long i = cJSON_IsString(f) ? frame_index(f->valuestring) : -1;
    if (i >= count) {
      snprintf(err, errlen, "%s lists %s, beyond --count %d: resume with --count %ld or more "
               "(a smaller set would leave frames on disk that its manifest does not list)",
               path, f->valuestring, count, i + 1);
      return HF_EINVAL;
    }
  }
  return HF_OK;
}

void hr_dataset_note_earlier_run(const char *dir) {
  char path[4200], err[256];
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  struct stat st;
  if (stat(path, &st) != 0) return;
  char *text = read_text(path, err, sizeof err);
  cJSON *doc = text ? cJSON_Parse(text) : NULL;
  free(text);
  int n = cJSON_GetArraySize(doc ? cJSON_GetObjectItemCaseSensitive(doc, "frames") : NULL);
  if (n > 0)
    fprintf(stderr, "hairfilter render dataset: %s lists %d frame%s of an earlier run: this "
            "run starts the set again and renders over them; to keep them, stop it and run "
            "the set's command with --resume\n", path, n, n == 1 ? "" : "s");
  cJSON_Delete(doc);
}

/* A manifest written before occluder_record kept the mesh's path as it was
 * typed: taken as a path from here (where the set's command is run again),
 * so that its own command still resumes it. */
static void occluder_to_real_path(cJSON *asset) {
  cJSON *occ = cJSON_GetObjectItemCaseSensitive(asset, "occluder");
  if (!cJSON_IsString(occ) || !strcasecmp(occ->valuestring, "fit") ||
      !strcasecmp(occ->valuestring, "none"))
    return;
  char *real = realpath(occ->valuestring, NULL);
  /* Out of memory leaves the path as it was, which the comparison names. */
  if (real && !cJSON_SetValuestring(occ, real))
    fprintf(stderr, "hairfilter render dataset: out of memory reading the occluder's path\n");
  free(real);
}

int hr_dataset_resume_open(const char *dir, const cJSON *options, int count,
                           const char *gl_renderer, cJSON **old, char *err, size_t errlen) {
  *old = NULL;
  char path[4200];
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  struct stat st;
  if (stat(path, &st) != 0) {
    /* Said, so that a mistyped --out does not silently start over. */
    fprintf(stderr, "hairfilter render dataset: --resume: no %s to take up: a fresh run\n", path);
    return HF_OK;
  }
  char *text = read_text(path, err, errlen);
  if (!text) return HF_EIO;
  cJSON *doc = cJSON_Parse(text);
  free(text);
  const cJSON *fmt = doc ? cJSON_GetObjectItemCaseSensitive(doc, "format") : NULL;
  if (!cJSON_IsString(fmt) || strcmp(fmt->valuestring, "hairfilter-dataset") != 0 ||
      !cJSON_IsArray(cJSON_GetObjectItemCaseSensitive(doc, "frames"))) {
    snprintf(err, errlen, "%s is not a hairfilter dataset manifest (a run would overwrite "
             "it): --out another directory", path);
    cJSON_Delete(doc);
    return HF_EFORMAT;
  }
  const cJSON *had = cJSON_GetObjectItemCaseSensitive(doc, "options");
  if (!cJSON_IsObject(had)) {
    snprintf(err, errlen, "%s has no record of the options its frames were made with (it was "
             "written before --resume): --out another directory, or leave out --resume to "
             "start again", path);
    cJSON_Delete(doc);
    return HF_EINVAL;
  }
  occluder_to_real_path(cJSON_GetObjectItemCaseSensitive(had, "asset"));
  char key[160], now[96], then[96];
  const cJSON *w = NULL, *h = NULL;
  if (first_difference(options, had, "", key, sizeof key, &w, &h)) {
    value_text(w, now, sizeof now);
    value_text(h, then, sizeof then);
    snprintf(err, errlen, "%s was made with other options: %s (\"%s\") is %s there, %s here; "
             "only --count may grow: resume with the options it was made with, or --out "
             "another directory", path, option_of(key), key, then, now);
    cJSON_Delete(doc);
    return HF_EINVAL;
  }
  int rc = check_count(cJSON_GetObjectItemCaseSensitive(doc, "frames"), count, path, err, errlen);
  if (rc == HF_OK)
    rc = check_count(cJSON_GetObjectItemCaseSensitive(doc, "skipped"), count, path, err, errlen);
  if (rc != HF_OK) {
    cJSON_Delete(doc);
    return rc;
  }
  const cJSON *gl = cJSON_GetObjectItemCaseSensitive(doc, "gl_renderer");
  if (cJSON_IsString(gl) && gl_renderer && strcmp(gl->valuestring, gl_renderer) != 0)
    fprintf(stderr, "hairfilter render dataset: warning: %s was rendered by %s, this run by %s: "
            "the frames may differ in rasterisation\n", path, gl->valuestring, gl_renderer);
  *old = doc;
  return HF_OK;
}

/* The entry of list whose "file" is file, detached from it, or NULL. */
static cJSON *take_entry(cJSON *list, const char *file) {
  cJSON *e;
  int i = 0;
  cJSON_ArrayForEach(e, list) {
    const cJSON *f = cJSON_GetObjectItemCaseSensitive(e, "file");
    if (cJSON_IsString(f) && !strcmp(f->valuestring, file))
      return cJSON_DetachItemFromArray(list, i);
    i++;
  }
  return NULL;
}

cJSON *hr_dataset_resume_take(cJSON *old, const char *dir, const char *file, int *was_skipped) {
  *was_skipped = 0;
  if (!old) return NULL;
  cJSON *e = take_entry(cJSON_GetObjectItemCaseSensitive(old, "frames"), file);
  if (e) {
    char path[4200];
    struct stat st;
    snprintf(path, sizeof path, "%s/%s", dir, file);
    if (stat(path, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
      /* Listed and there, but kept only if it reads whole: a file cut short
       * or damaged since (a full disk, a copy stopped half way) would be
       * kept as it is and refused later by train.py and eval, frame by
       * frame. */
      hf_image img;
      char why[512];
      memset(&img, 0, sizeof img);
      int rc = hf_exr_read_part(path, NULL, "S0.color", &img, why, sizeof why);
      hf_image_free(&img);
      if (rc == HF_OK) return e;
      fprintf(stderr, "hairfilter render dataset: --resume: %s is listed but does not read "
              "whole (%s): rendered again\n", path, why);
    }
    cJSON_Delete(e); /* listed but gone or damaged: render it again */
    return NULL;
  }
  e = take_entry(cJSON_GetObjectItemCaseSensitive(old, "skipped"), file);
  if (e) *was_skipped = 1;
  return e;
}

/* Adds name to doc's "earlier_gl_renderers" unless it is doc's own
 * "gl_renderer" or listed already. */
static void add_earlier(cJSON *doc, const char *name) {
  const cJSON *now = cJSON_GetObjectItemCaseSensitive(doc, "gl_renderer");
  if (!name || (cJSON_IsString(now) && !strcmp(now->valuestring, name))) return;
  cJSON *list = cJSON_GetObjectItemCaseSensitive(doc, "earlier_gl_renderers");
  if (!list && !(list = cJSON_AddArrayToObject(doc, "earlier_gl_renderers"))) return;
  const cJSON *e;
  cJSON_ArrayForEach(e, list)
    if (cJSON_IsString(e) && !strcmp(e->valuestring, name)) return;
  cJSON_AddItemToArray(list, cJSON_CreateString(name));
}

void hr_dataset_resume_history(cJSON *doc, const cJSON *old) {
  if (!old) return;
  const cJSON *gl = cJSON_GetObjectItemCaseSensitive(old, "gl_renderer"), *e;
  if (cJSON_IsString(gl)) add_earlier(doc, gl->valuestring);
  cJSON_ArrayForEach(e, cJSON_GetObjectItemCaseSensitive(old, "earlier_gl_renderers"))
    if (cJSON_IsString(e)) add_earlier(doc, e->valuestring);
}
