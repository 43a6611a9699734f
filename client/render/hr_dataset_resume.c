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
#include <sys/stat.h>

#include <cjson/cJSON.h>

#include "hr_dataset.h"
#include "hr_internal.h"

/* A manifest of tens of thousands of frames is a few tens of MB. */
#define HR_MANIFEST_MAX_BYTES (256u << 20)

static void add_range(cJSON *o, const char *name, double lo, double hi) {
  double v[2] = {lo, hi};
  cJSON_AddItemToObject(o, name, cJSON_CreateDoubleArray(v, 2));
}

cJSON *hr_dataset_options(const hfr_dataset_opts *o) {
  cJSON *j = cJSON_CreateObject();
  if (!j) return NULL;
  cJSON *styles = cJSON_AddArrayToObject(j, "styles");
  for (int i = 0; i < o->n_styles; i++)
    cJSON_AddItemToArray(styles, cJSON_CreateString(hfr_style_name(o->styles[i])));
  cJSON *files = cJSON_AddArrayToObject(j, "hair_files");
  for (int i = 0; i < o->n_hair_files; i++)
    cJSON_AddItemToArray(files, cJSON_CreateString(o->hair_files[i]));
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
  cJSON_AddBoolToObject(j, "regimes", o->regimes != 0);
  if (o->regimes) {
    add_range(j, "frame_sizes", o->frame_min > 0 ? o->frame_min : 256,
              o->frame_max > 0 ? o->frame_max : 1024);
    add_range(j, "width_px_range", o->width_px_min > 0 ? o->width_px_min : HR_REGIME_WIDTH_PX_MIN,
              o->width_px_max > 0 ? o->width_px_max : HR_REGIME_WIDTH_PX_MAX);
    float op[2];
    hr_regime_opacity_range(o, op);
    add_range(j, "opacity_range", op[0], op[1]);
  }
  cJSON_AddNumberToObject(j, "width_spread", o->width_spread);
  cJSON_AddBoolToObject(j, "background_layer", o->background_layer != 0);
  if (o->n_hair_files) {
    const hfr_asset_opts *a = &o->asset;
    cJSON *aj = cJSON_AddObjectToObject(j, "asset");
    cJSON_AddStringToObject(aj, "up", hfr_axis_name(a->up));
    cJSON_AddNumberToObject(aj, "scale", a->scale > 0 ? a->scale : 1);
    cJSON_AddNumberToObject(aj, "thickness", a->thickness);
    cJSON_AddStringToObject(aj, "occluder", hfr_asset_fitted(a) ? "fit" : a->occluder);
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

/* The first member of want whose value differs in have (or is missing). */
static const char *first_difference(const cJSON *want, const cJSON *have) {
  const cJSON *w;
  cJSON_ArrayForEach(w, want) {
    const cJSON *h = cJSON_GetObjectItemCaseSensitive(have, w->string);
    if (!h || !cJSON_Compare(w, h, 1)) return w->string;
  }
  cJSON_ArrayForEach(w, have)
    if (!cJSON_GetObjectItemCaseSensitive(want, w->string)) return w->string;
  return NULL;
}

int hr_dataset_resume_open(const char *dir, const cJSON *options, const char *gl_renderer,
                           cJSON **old, char *err, size_t errlen) {
  *old = NULL;
  char path[4200];
  snprintf(path, sizeof path, "%s/manifest.json", dir);
  struct stat st;
  if (stat(path, &st) != 0) return HF_OK; /* nothing to take up: a fresh run */
  char *text = read_text(path, err, errlen);
  if (!text) return HF_EIO;
  cJSON *doc = cJSON_Parse(text);
  free(text);
  const cJSON *fmt = doc ? cJSON_GetObjectItemCaseSensitive(doc, "format") : NULL;
  if (!cJSON_IsString(fmt) || strcmp(fmt->valuestring, "hairfilter-dataset") != 0 ||
      !cJSON_IsArray(cJSON_GetObjectItemCaseSensitive(doc, "frames"))) {
    snprintf(err, errlen, "%s is not a hairfilter dataset manifest: --out another directory, "
             "or leave out --resume to start again", path);
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
  const char *diff = first_difference(options, had);
  if (diff) {
    snprintf(err, errlen, "%s was made with other options (\"%s\" differs; only --count may "
             "change): resume with the options it was made with, or --out another directory",
             path, diff);
    cJSON_Delete(doc);
    return HF_EINVAL;
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
    if (stat(path, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) return e;
    cJSON_Delete(e); /* listed but gone: render it again */
    return NULL;
  }
  e = take_entry(cJSON_GetObjectItemCaseSensitive(old, "skipped"), file);
  if (e) *was_skipped = 1;
  return e;
}
