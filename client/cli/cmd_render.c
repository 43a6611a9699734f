/* hairfilter render: the reference renderer (client/render, hfrender.h).
 *
 *   render frame   [model] [view] [outputs] --out F.exr [--png PREFIX]
 *   render fig6    [model] [view] --out F.png      (the paper's Fig. 6)
 *   render dataset --styles a,b --count N --size WxH --spp 1,2,4 --seed S --out DIR
 *   render hair    [model] --out F.hair            (export a procedural style) */
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "cli_common.h"
#include "commands.h"
#include "hfrender.h"

static void usage(FILE *f) {
  fprintf(f,
    "usage: hairfilter render <frame|fig6|dataset|hair> [options]\n"
    "\n"
    "model:   --style straight|wavy|curly|coily|ponytail|spiky|fur|braided (default straight)\n"
    "         --hair FILE.hair (instead of a style)   --hair-seed N\n"
    "         --strands N --segments N --length L --clumping C --frizz F\n"
    "         --curl-radius R --curl-period P --thickness T --opacity O\n"
    "         --width-spread S (per clump width x S^u, u in [-1,1]) --children N (spiky, fur)\n"
    "         --gather G (ponytail, braided: 0..1, 1 ties every strand through one point)\n"
    ".hair:   --up y|z|x|-y|-z|-x (the file's up axis; or --up-axis)\n"
    "         --units m|dm|cm|mm|in|ft or --scale S\n"
    "         --thickness T (diameter in the file's units, replaces the file's widths)\n"
    "         --opacity O (in (0, 1], replaces the file's transparencies)\n"
    "         --children N (grow N children per guide) --child-spread F --child-clumping C\n"
    "         --occluder fit|none|MESH (fit: ellipsoid under the roots; MESH: OBJ, PLY, ...)\n"
    "view:    --size WxH (256x256)  --cam-distance D --cam-yaw DEG --cam-pitch DEG --fov DEG\n"
    "         --crop X,Y,W,H (render only this window of the WxH frame, at its cost)\n"
    "         --light-yaw DEG --light-pitch DEG --light-distance D --directional\n"
    "         --alpha-r DEG --alpha-trt DEG --ambient A --spec-half\n"
    "         --shadow-size N (0: off) --shadow-bias B --thickness-scale S\n"
    "         --random-view SEED (camera, light, lobes, colours from a seed)\n"
    "         --hair-color R,G,B --light-color R,G,B --background R,G,B (composites)\n"
    "outputs: --spp N (4) --gt-ss S (0..8, default 8; 0: none; at 4 its sub-pixel centres\n"
    "         include the 4 MSAA positions) --opaque N (multiple of 4)\n"
    "         --st 1,2,4,... (stochastic-transparency baselines at these spp, what eval compares\n"
    "           the filters with, e.g. --st 4,16,64; default none)\n"
    "         --seed N (hash seed of the stochastic samples)\n"
    "         --half (float16 EXR)  --png PREFIX (frame: PREFIX_<name>.png composites; _input: the\n"
    "           samples' own estimate, what a filter reads)\n"
    "         --no-background (leave out the occluder layer background.R/G/B/A)\n"
    "         --no-alpha-corrected (leave out acst4.*, the first 4 samples' alpha-corrected\n"
    "           estimate, Enderton et al. 2010, that KernelMix reads: one more draw of the hair;\n"
    "           written by default with --spp 4 or more) --alpha-corrected (also below 4)\n"
    "dataset: --styles a,b --count N (per style) --spp 1,2,4 --seed S --out DIR\n"
    "         --size WxH --strands N --gt-ss S --st LIST --opaque N --no-alpha-corrected --quiet\n"
    "         --resume (take up a run stopped in --out: keep the frames its manifest lists,\n"
    "           render the rest; the same options, --count may grow)\n"
    "         --extended (style parameters, density and distance over wide ranges)\n"
    "         --regimes (widths, density, zoom, crops, camera, light, shadows per frame and\n"
    "           clump) --frame-sizes MIN,MAX (regimes: virtual frames, default 256,1024)\n"
    "           --width-px MIN,MAX (regimes: strand width in pixels, default 0.004,4)\n"
    "         --opacity-range MIN,MAX (each style frame's strand opacity drawn in it; 1,1:\n"
    "           opaque; default: with --regimes 0.2,1, else the style's own)\n"
    "         --gather-range MIN,MAX (ponytail, braided: each frame's --gather drawn in it;\n"
    "           default none, 0)\n"
    "         --smooth-share P (this share of the style frames drawn as smooth grooms: no frizz,\n"
    "           no clumping but spiky's and fur's; default 0)\n"
    "         --hair-files A.hair,B.hair|DIR (these models as styles; --up, --units, --children,\n"
    "           --thickness, --opacity, --occluder apply to them)\n"
    "         a ground truth too dense for one A-buffer is drawn in bands of rows; a frame\n"
    "         whose single rows do not fit is left out (manifest \"skipped\") and the run\n"
    "         goes on; --max-fragments N lowers that limit (default and most 67108864)\n"
    "         --gt-cull auto|off|on: keep out of the truth's A-buffer the fragments behind an\n"
    "           optical depth of 30 (each, and all together, weigh under 1e-13); auto: windows\n"
    "           whose lists will be deep (about 64 fragments a subsample, or 8 once drawn);\n"
    "           off: every fragment\n"
    "other:   --platform osmesa|egl|auto   --out PATH\n"
    "An option the mode does not read (render frame --resume, render dataset --cam-yaw) is\n"
    "refused, naming the modes that read it.\n");
}

typedef struct {
  const char *cmd, *out, *hair_path, *png, *platform;
  hfr_style_params style;
  int style_set;
  hfr_view view;
  hfr_outputs outputs;
  int half, quiet;
  hfr_dataset_opts ds;
  int st_set;
  /* Overrides applied after a --style resets the parameters. */
  struct { int strands, segments; float length, clumping, frizz, cr, cp, thick, opac, wspread, gather;
           int children; uint64_t seed; } ov;
  hfr_asset_opts asset;
  int no_background, styles_set;
  char *hair_files[256];
  int n_hair_files;
  int random_view;
  uint64_t random_seed;
  int random_keep_size;
  /* The options given, by name (argv's strings), for given(). */
  const char *given[128];
  int n_given;
} opts;

/* 1 when option name (or, for --up, its alias) was given. */
static int given(const opts *o, const char *name) {
  for (int i = 0; i < o->n_given; i++)
    if (!strcmp(o->given[i], name) || (!strcmp(name, "--up") && !strcmp(o->given[i], "--up-axis")))
      return 1;
  return 0;
}

static int parse_int_list(const char *s, int *out, int max, int *n) {
  *n = 0;
  char *end;
  while (*s) {
    if (*n == max) return -1;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (end == s || errno || v < 1 || v > 1000000) return -1;
    out[(*n)++] = (int)v;
    s = end;
    if (*s == ',') s++;
    else if (*s) return -1;
  }
  return *n > 0 ? 0 : -1;
}

/* The whole argument: anything after the numbers ("64x64x") is refused,
 * not dropped. */
static int parse_size(const char *s, int *w, int *h) {
  char tail;
  return sscanf(s, "%dx%d%c", w, h, &tail) == 2 && *w > 0 && *h > 0 ? 0 : -1;
}

static int parse_float(const char *s, float *f) {
  char *end;
  errno = 0;
  *f = strtof(s, &end);
  return end != s && !*end && !errno && isfinite(*f) ? 0 : -1;
}

/* --hair-files: a comma-separated list, or a directory's *.hair files in
 * name order (so that a dataset is the same on every machine). */
static int name_cmp(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

static int add_hair_file(opts *o, const char *path) {
  int max = (int)(sizeof o->hair_files / sizeof o->hair_files[0]);
  if (o->n_hair_files == max) {
    fprintf(stderr, "hairfilter render: more than %d --hair-files\n", max);
    return -1;
  }
  o->hair_files[o->n_hair_files] = strdup(path);
  if (!o->hair_files[o->n_hair_files]) return -1;
  o->n_hair_files++;
  return 0;
}

static int collect_hair_files(const char *v, opts *o) {
  struct stat st;
  if (stat(v, &st) == 0 && S_ISDIR(st.st_mode)) {
    DIR *d = opendir(v);
    if (!d) {
      fprintf(stderr, "hairfilter render: %s: %s\n", v, strerror(errno));
      return -1;
    }
    int first = o->n_hair_files;
    struct dirent *e;
    while ((e = readdir(d))) {
      size_t l = strlen(e->d_name);
      if (l < 6 || strcmp(e->d_name + l - 5, ".hair")) continue;
      char path[4096];
      snprintf(path, sizeof path, "%s/%s", v, e->d_name);
      if (add_hair_file(o, path)) {
        closedir(d);
        return -1;
      }
    }
    closedir(d);
    qsort(o->hair_files + first, (size_t)(o->n_hair_files - first), sizeof(char *), name_cmp);
    if (o->n_hair_files == first) {
      fprintf(stderr, "hairfilter render: no .hair files in %s\n", v);
      return -1;
    }
    return 0;
  }
  char buf[8192];
  snprintf(buf, sizeof buf, "%s", v);
  for (char *t = strtok(buf, ","); t; t = strtok(NULL, ","))
    if (add_hair_file(o, t)) return -1;
  return 0;
}

/* Which modes read an option. Each mode reads only some of the options,
 * and one it does not read would be dropped without a word (render frame
 * --resume rendering a frame afresh), so parse_args refuses it by name.
 * Options not listed here are read by every mode. */
enum { M_FRAME = 1, M_FIG6 = 2, M_DATASET = 4, M_HAIR = 8 };
static const struct { const char *name; int modes; } option_modes[] = {
  /* the procedural model, which a dataset varies itself */
  {"--style", M_FRAME | M_FIG6 | M_HAIR},        {"--hair", M_FRAME | M_FIG6 | M_HAIR},
  {"--length", M_FRAME | M_FIG6 | M_HAIR},       {"--clumping", M_FRAME | M_FIG6 | M_HAIR},
  {"--frizz", M_FRAME | M_FIG6 | M_HAIR},        {"--curl-radius", M_FRAME | M_FIG6 | M_HAIR},
  {"--curl-period", M_FRAME | M_FIG6 | M_HAIR},  {"--opacity", M_FRAME | M_FIG6 | M_DATASET | M_HAIR},
  {"--gather", M_FRAME | M_FIG6 | M_HAIR},
  {"--hair-seed", M_FRAME | M_FIG6 | M_HAIR},    /* a dataset draws a seed per frame */
  /* the view, which a dataset draws per frame */
  {"--cam-distance", M_FRAME | M_FIG6},  {"--cam-yaw", M_FRAME | M_FIG6},
  {"--cam-pitch", M_FRAME | M_FIG6},     {"--fov", M_FRAME | M_FIG6},
  {"--light-yaw", M_FRAME | M_FIG6},     {"--light-pitch", M_FRAME | M_FIG6},
  {"--light-distance", M_FRAME | M_FIG6}, {"--directional", M_FRAME | M_FIG6},
  {"--alpha-r", M_FRAME | M_FIG6},       {"--alpha-trt", M_FRAME | M_FIG6},
  {"--ambient", M_FRAME | M_FIG6},       {"--spec-half", M_FRAME | M_FIG6},
  {"--shadow-bias", M_FRAME | M_FIG6},   {"--thickness-scale", M_FRAME | M_FIG6},
  {"--crop", M_FRAME | M_FIG6},          {"--random-view", M_FRAME | M_FIG6},
  {"--hair-color", M_FRAME | M_FIG6},    {"--light-color", M_FRAME | M_FIG6},
  {"--background", M_FRAME | M_FIG6},
  /* what is rendered: nothing of it in a .hair file */
  {"--size", M_FRAME | M_FIG6 | M_DATASET},        {"--shadow-size", M_FRAME | M_FIG6 | M_DATASET},
  {"--gt-ss", M_FRAME | M_FIG6 | M_DATASET},       {"--st", M_FRAME | M_FIG6 | M_DATASET},
  {"--opaque", M_FRAME | M_FIG6 | M_DATASET},      {"--seed", M_FRAME | M_FIG6 | M_DATASET},
  {"--max-fragments", M_FRAME | M_FIG6 | M_DATASET},
  {"--gt-cull", M_FRAME | M_FIG6 | M_DATASET},
  {"--no-background", M_FRAME | M_FIG6 | M_DATASET},
  {"--alpha-corrected", M_FRAME | M_DATASET},      {"--no-alpha-corrected", M_FRAME | M_DATASET},
  {"--spp", M_FRAME | M_DATASET},                  {"--half", M_FRAME | M_DATASET},
  {"--png", M_FRAME},
  {"--platform", M_FRAME | M_FIG6 | M_DATASET}, /* render hair draws nothing */
  /* the set of frames */
  {"--styles", M_DATASET},       {"--count", M_DATASET},     {"--resume", M_DATASET},
  {"--extended", M_DATASET},     {"--regimes", M_DATASET},   {"--frame-sizes", M_DATASET},
  {"--width-px", M_DATASET},     {"--opacity-range", M_DATASET},
  {"--gather-range", M_DATASET}, {"--smooth-share", M_DATASET},
  {"--hair-files", M_DATASET},
};

/* 0 when mode reads option a (or a or mode is not known here); otherwise
 * prints which modes do and returns -1. */
static int check_option_mode(const char *mode, const char *a) {
  static const char *const names[] = {"frame", "fig6", "dataset", "hair"};
  int m = 0;
  for (int k = 0; k < 4; k++)
    if (!strcmp(mode, names[k])) m = 1 << k;
  if (!m) return 0;
  for (size_t i = 0; i < sizeof option_modes / sizeof option_modes[0]; i++) {
    if (strcmp(a, option_modes[i].name) || (option_modes[i].modes & m)) continue;
    char which[64] = "";
    for (int k = 0; k < 4; k++)
      if (option_modes[i].modes & (1 << k))
        snprintf(which + strlen(which), sizeof which - strlen(which), "%s%s",
                 *which ? ", " : "", names[k]);
    /* The option of this mode a user most likely meant. */
    static const char *const siblings[][3] = {
        {"dataset", "--hair", "--hair-files"}, {"dataset", "--style", "--styles"},
        {"frame", "--hair-files", "--hair"},   {"fig6", "--hair-files", "--hair"},
        {"hair", "--hair-files", "--hair"},    {"frame", "--styles", "--style"},
        {"fig6", "--styles", "--style"},       {"hair", "--styles", "--style"},
        {"hair", "--seed", "--hair-seed"},     {"dataset", "--gather", "--gather-range"}};
    const char *instead = NULL;
    for (size_t k = 0; k < sizeof siblings / sizeof siblings[0]; k++)
      if (!strcmp(mode, siblings[k][0]) && !strcmp(a, siblings[k][1])) instead = siblings[k][2];
    if (instead)
      fprintf(stderr, "hairfilter render %s: %s is an option of render %s only; here it is "
              "%s\n", mode, a, which, instead);
    else
      fprintf(stderr, "hairfilter render %s: %s is an option of render %s only; leave it out "
              "here\n", mode, a, which);
    return -1;
  }
  return 0;
}

/* Options that one kind of model reads and the other drops: refused by
 * name rather than dropped. A procedural style reads its shape; a .hair
 * model (--hair, or a dataset's --hair-files) reads its conventions. */
static int check_model_options(const opts *o) {
  static const char *const style_only[] = {"--style", "--strands", "--segments", "--length",
                                           "--clumping", "--frizz", "--curl-radius",
                                           "--curl-period", "--width-spread", "--gather",
                                           "--gather-range", "--smooth-share"};
  static const char *const asset_only[] = {"--up", "--units", "--scale", "--occluder",
                                           "--child-spread", "--child-clumping"};
  const int dataset = !strcmp(o->cmd, "dataset");
  const int files = dataset ? o->n_hair_files > 0 : o->hair_path != NULL;
  /* A dataset of --hair-files alone has no procedural style. */
  const int styles = dataset ? !files || o->styles_set : !files;
  for (size_t k = 0; k < sizeof style_only / sizeof style_only[0]; k++)
    if (!styles && given(o, style_only[k])) {
      fprintf(stderr, "hairfilter render %s: %s shapes a procedural style, and a .hair model "
              "keeps its own; it takes --thickness, --opacity, --children, --up, --units and "
              "--occluder\n", o->cmd, style_only[k]);
      return -1;
    }
  for (size_t k = 0; k < sizeof asset_only / sizeof asset_only[0]; k++)
    if (!files && given(o, asset_only[k])) {
      fprintf(stderr, "hairfilter render %s: %s applies to a .hair model: give %s\n", o->cmd,
              asset_only[k], dataset ? "--hair-files" : "--hair FILE");
      return -1;
    }
  /* 0 would mean "the file's" to a .hair model: said, not taken. */
  if (given(o, "--opacity") && !(o->ov.opac > 0 && o->ov.opac <= 1)) {
    fprintf(stderr, "hairfilter render %s: --opacity %g is outside (0, 1]\n", o->cmd, o->ov.opac);
    return -1;
  }
  if (given(o, "--thickness") && !(o->ov.thick > 0)) {
    fprintf(stderr, "hairfilter render %s: --thickness %g: a diameter above 0\n", o->cmd,
            o->ov.thick);
    return -1;
  }
  /* A .hair model's children, in hfr_hair_interpolate's ranges. */
  const hfr_children_params *c = &o->asset.children;
  if (files && given(o, "--children") && (c->children < 0 || c->children > 10000)) {
    fprintf(stderr, "hairfilter render %s: --children %d is outside 0..10000\n", o->cmd,
            c->children);
    return -1;
  }
  /* Children are grown only where --children asks for them. */
  static const char *const child_shape[] = {"--child-spread", "--child-clumping"};
  for (size_t k = 0; files && k < 2; k++)
    if (given(o, child_shape[k]) && c->children <= 0) {
      fprintf(stderr, "hairfilter render %s: %s shapes the children --children N grows, and "
              "none are grown: give --children N above 0, or leave %s out\n", o->cmd,
              child_shape[k], child_shape[k]);
      return -1;
    }
  if (files && given(o, "--child-spread") && !(c->spread >= 0)) {
    fprintf(stderr, "hairfilter render %s: --child-spread %g is below 0\n", o->cmd, c->spread);
    return -1;
  }
  if (files && given(o, "--child-clumping") && !(c->clumping >= 0 && c->clumping <= 1)) {
    fprintf(stderr, "hairfilter render %s: --child-clumping %g is outside [0, 1]\n", o->cmd,
            c->clumping);
    return -1;
  }
  /* Both set the one factor, the later silently over the earlier: --units cm
   * --scale 2 drew the model at 2 renderer units per centimetre. */
  if (given(o, "--units") && given(o, "--scale")) {
    fprintf(stderr, "hairfilter render %s: --units and --scale both say the file's unit "
            "(--scale S: S renderer units per file unit; --units cm is --scale 0.1): give "
            "one\n", o->cmd);
    return -1;
  }
  if (given(o, "--scale") && !(o->asset.scale > 0)) {
    fprintf(stderr, "hairfilter render %s: --scale %g: renderer units per file unit, above 0\n",
            o->cmd, o->asset.scale);
    return -1;
  }
  if (dataset) {
    /* What only --regimes reads, and what it draws itself. */
    static const char *const regimes_only[] = {"--frame-sizes", "--width-px"};
    for (size_t k = 0; k < 2; k++)
      if (!o->ds.regimes && given(o, regimes_only[k])) {
        fprintf(stderr, "hairfilter render dataset: %s applies to --regimes\n", regimes_only[k]);
        return -1;
      }
    if (o->ds.regimes && given(o, "--width-spread")) {
      fprintf(stderr, "hairfilter render dataset: --regimes draws each frame's clump width "
              "spread itself: leave out --width-spread\n");
      return -1;
    }
    int tied = 0;
    for (int k = 0; k < o->ds.n_styles; k++)
      tied |= hfr_style_has_tie(o->ds.styles[k]);
    /* The ranges' bounds, checked here so that a bad one is a usage error
     * (exit 2) that echoes it; hfr_dataset_run checks them again for
     * library callers. */
    const int f0 = o->ds.frame_min, f1 = o->ds.frame_max;
    if (given(o, "--frame-sizes") && !(f0 > 0 && f0 <= f1 && f1 <= 8192)) {
      fprintf(stderr, "hairfilter render dataset: --frame-sizes %d,%d: frame sizes must be 0 < "
              "MIN <= MAX <= 8192 pixels\n", f0, f1);
      return -1;
    }
    const float w0 = o->ds.width_px_min, w1 = o->ds.width_px_max;
    if (given(o, "--width-px") && !(w0 > 0 && w0 <= w1 && w1 <= 64)) {
      fprintf(stderr, "hairfilter render dataset: --width-px %g,%g: strand widths must be 0 < "
              "MIN <= MAX <= 64 pixels\n", w0, w1);
      return -1;
    }
    const float op0 = o->ds.opacity_min, op1 = o->ds.opacity_max;
    if (given(o, "--opacity-range") && !(op0 > 0 && op0 <= op1 && op1 <= 1)) {
      fprintf(stderr, "hairfilter render dataset: --opacity-range %g,%g: strand opacities must "
              "be 0 < MIN <= MAX <= 1\n", op0, op1);
      return -1;
    }
    const float g0 = o->ds.gather_min, g1 = o->ds.gather_max;
    if (given(o, "--gather-range") && !(g0 >= 0 && g0 <= g1 && g1 <= 1)) {
      fprintf(stderr, "hairfilter render dataset: --gather-range %g,%g: gathers must be 0 <= MIN "
              "<= MAX <= 1\n", g0, g1);
      return -1;
    }
    if (given(o, "--smooth-share") && !(o->ds.smooth_share >= 0 && o->ds.smooth_share <= 1)) {
      fprintf(stderr, "hairfilter render dataset: --smooth-share %g: a share of the frames, in "
              "[0, 1]\n", o->ds.smooth_share);
      return -1;
    }
    if (styles && given(o, "--gather-range") && !tied) {
      fprintf(stderr, "hairfilter render dataset: --gather-range draws the tie of ponytail and "
              "braided frames, and --styles has neither: add one of them, or leave it out\n");
      return -1;
    }
    if (!styles && given(o, "--opacity-range")) {
      fprintf(stderr, "hairfilter render dataset: --opacity-range draws the procedural --styles' "
              "opacity; for --hair-files give --opacity\n");
      return -1;
    }
  }
  /* A style's parameters, checked here so that a bad value is a usage
   * error (exit 2) like every other, before anything is opened. */
  char err[512] = "";
  hfr_style_params p = o->style;
  if (dataset) {
    hfr_style_defaults(HFR_STYLE_STRAIGHT, &p);
    if (given(o, "--strands")) p.strands = o->ov.strands;
    if (given(o, "--segments")) p.segments = o->ov.segments;
    if (given(o, "--width-spread")) p.width_spread = o->ov.wspread;
  }
  if (styles && hfr_style_check(&p, err, sizeof err) != HF_OK) {
    fprintf(stderr, "hairfilter render %s: %s\n", o->cmd, err);
    return -1;
  }
  /* A dataset draws its styles' widths, opacities and children itself. */
  static const char *const dataset_asset[] = {"--thickness", "--opacity", "--children"};
  for (size_t k = 0; dataset && !files && k < 3; k++)
    if (given(o, dataset_asset[k])) {
      fprintf(stderr, "hairfilter render dataset: %s applies to --hair-files; the styles' "
              "are drawn per frame%s\n", dataset_asset[k],
              k == 1 ? " (--opacity-range MIN,MAX draws them in a range; 1,1: opaque)" : "");
      return -1;
    }
  return 0;
}

static int parse_args(int argc, char **argv, opts *o) {
  /* Help first, whatever else the line holds. */
  for (int i = 2; i < argc; i++)
    if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
      usage(stdout);
      exit(0);
    }
  for (int i = 2; i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
#define NEED_VALUE                                                   \
  if (!v) {                                                          \
    fprintf(stderr, "hairfilter render: %s needs a value\n", a);     \
    return -1;                                                       \
  }                                                                  \
  i++;
#define FLOAT_OPT(name, dst)                                                    \
  if (!strcmp(a, name)) {                                                       \
    NEED_VALUE;                                                                 \
    if (parse_float(v, &(dst))) {                                               \
      fprintf(stderr, "hairfilter render: %s: not a number: %s\n", a, v);       \
      return -1;                                                                \
    }                                                                           \
    continue;                                                                   \
  }
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      usage(stdout);
      exit(0);
    }
    if (check_option_mode(o->cmd, a)) return -1;
    if (o->n_given < (int)(sizeof o->given / sizeof o->given[0])) o->given[o->n_given++] = a;
    FLOAT_OPT("--length", o->ov.length)
    FLOAT_OPT("--clumping", o->ov.clumping)
    FLOAT_OPT("--frizz", o->ov.frizz)
    FLOAT_OPT("--curl-radius", o->ov.cr)
    FLOAT_OPT("--curl-period", o->ov.cp)
    FLOAT_OPT("--thickness", o->ov.thick)
    FLOAT_OPT("--opacity", o->ov.opac)
    FLOAT_OPT("--cam-distance", o->view.cam_distance)
    FLOAT_OPT("--cam-yaw", o->view.cam_yaw_deg)
    FLOAT_OPT("--cam-pitch", o->view.cam_pitch_deg)
    FLOAT_OPT("--fov", o->view.cam_fov_deg)
    FLOAT_OPT("--light-yaw", o->view.light_yaw_deg)
    FLOAT_OPT("--light-pitch", o->view.light_pitch_deg)
    FLOAT_OPT("--light-distance", o->view.light_distance)
    FLOAT_OPT("--alpha-r", o->view.alpha_r_deg)
    FLOAT_OPT("--alpha-trt", o->view.alpha_trt_deg)
    FLOAT_OPT("--ambient", o->view.ambient)
    FLOAT_OPT("--shadow-bias", o->view.shadow_bias)
    FLOAT_OPT("--thickness-scale", o->view.thickness_scale)
    FLOAT_OPT("--width-spread", o->ov.wspread)
    FLOAT_OPT("--gather", o->ov.gather)
    FLOAT_OPT("--smooth-share", o->ds.smooth_share)
    FLOAT_OPT("--scale", o->asset.scale)
    FLOAT_OPT("--child-spread", o->asset.children.spread)
    FLOAT_OPT("--child-clumping", o->asset.children.clumping)
    if (!strcmp(a, "--directional")) { o->view.light_directional = 1; continue; }
    if (!strcmp(a, "--spec-half")) { o->view.spec_half_vector = 1; continue; }
    if (!strcmp(a, "--half")) { o->half = 1; continue; }
    if (!strcmp(a, "--quiet")) { o->quiet = 1; continue; }
    if (!strcmp(a, "--extended")) { o->ds.extended = 1; continue; }
    if (!strcmp(a, "--regimes")) { o->ds.regimes = 1; continue; }
    if (!strcmp(a, "--resume")) { o->ds.resume = 1; continue; }
    if (!strcmp(a, "--no-background")) { o->no_background = 1; continue; }
    if (!strcmp(a, "--alpha-corrected")) { o->outputs.alpha_corrected = 1; continue; }
    if (!strcmp(a, "--no-alpha-corrected")) { o->outputs.alpha_corrected = 0; continue; }
    NEED_VALUE;
    int end = 0; /* a range's two numbers must be all of its value: 0.5,0.7,0.9 is refused */
    if (!strcmp(a, "--out")) o->out = v;
    else if (!strcmp(a, "--hair")) o->hair_path = v;
    else if (!strcmp(a, "--png")) o->png = v;
    else if (!strcmp(a, "--platform")) o->platform = v;
    else if (!strcmp(a, "--occluder")) o->asset.occluder = v;
    else if (!strcmp(a, "--up") || !strcmp(a, "--up-axis")) {
      if (hfr_axis_from_name(v, &o->asset.up)) {
        fprintf(stderr, "hairfilter render: %s wants y, z, x, -y, -z or -x, not '%s'\n", a, v);
        return -1;
      }
    } else if (!strcmp(a, "--units")) {
      if (hfr_units_scale(v, &o->asset.scale)) {
        fprintf(stderr, "hairfilter render: --units wants m, dm, cm, mm, in or ft, not '%s'\n", v);
        return -1;
      }
    } else if (!strcmp(a, "--crop")) {
      if (sscanf(v, "%d,%d,%d,%d", &o->view.crop_x, &o->view.crop_y, &o->view.crop_w,
                 &o->view.crop_h) != 4 || o->view.crop_w < 1 || o->view.crop_h < 1) {
        fprintf(stderr, "hairfilter render: --crop wants X,Y,W,H in pixels of the --size frame\n");
        return -1;
      }
    } else if (!strcmp(a, "--gt-cull")) {
      static const char *const modes[] = {"auto", "off", "on"}; /* HFR_GT_CULL_* */
      int m = -1;
      for (int k = 0; k < 3; k++)
        if (!strcmp(v, modes[k])) m = k;
      if (m < 0) {
        fprintf(stderr, "hairfilter render: --gt-cull takes auto, off or on, not '%s'\n", v);
        return -1;
      }
      o->outputs.gt_cull = m, o->ds.gt_cull = m;
    } else if (!strcmp(a, "--frame-sizes")) {
      if (sscanf(v, "%d,%d%n", &o->ds.frame_min, &o->ds.frame_max, &end) != 2 || v[end]) {
        fprintf(stderr, "hairfilter render: --frame-sizes wants MIN,MAX\n");
        return -1;
      }
    } else if (!strcmp(a, "--width-px")) {
      if (sscanf(v, "%f,%f%n", &o->ds.width_px_min, &o->ds.width_px_max, &end) != 2 || v[end]) {
        fprintf(stderr, "hairfilter render: --width-px wants MIN,MAX (strand width in pixels)\n");
        return -1;
      }
    } else if (!strcmp(a, "--opacity-range")) {
      if (sscanf(v, "%f,%f%n", &o->ds.opacity_min, &o->ds.opacity_max, &end) != 2 || v[end]) {
        fprintf(stderr, "hairfilter render: --opacity-range wants MIN,MAX (strand opacity in (0, 1])\n");
        return -1;
      }
    } else if (!strcmp(a, "--gather-range")) {
      if (sscanf(v, "%f,%f%n", &o->ds.gather_min, &o->ds.gather_max, &end) != 2 || v[end]) {
        fprintf(stderr, "hairfilter render: --gather-range wants MIN,MAX (ponytail and braided "
                "frames' gather, in [0, 1])\n");
        return -1;
      }
    } else if (!strcmp(a, "--hair-files")) {
      if (collect_hair_files(v, o)) return -1;
    }
    else if (!strcmp(a, "--style")) {
      hfr_style s;
      if (hfr_style_from_name(v, &s)) {
        char known[256];
        hfr_style_list(known, sizeof known);
        fprintf(stderr, "hairfilter render: --style '%s': no such style (the styles: %s; a model "
                "of your own: --hair FILE.hair)\n", v, known);
        return -1;
      }
      hfr_style_defaults(s, &o->style);
      o->style_set = 1;
    } else if (!strcmp(a, "--styles")) {
      char buf[256];
      snprintf(buf, sizeof buf, "%s", v);
      o->ds.n_styles = 0;
      o->styles_set = 1;
      for (char *t = strtok(buf, ","); t; t = strtok(NULL, ",")) {
        if (o->ds.n_styles == HFR_STYLE_COUNT) {
          fprintf(stderr, "hairfilter render: --styles '%s': more than %d styles (name each "
                  "once)\n", v, HFR_STYLE_COUNT);
          return -1;
        }
        if (hfr_style_from_name(t, &o->ds.styles[o->ds.n_styles])) {
          /* The one not known, and those that are. */
          char known[256];
          hfr_style_list(known, sizeof known);
          fprintf(stderr, "hairfilter render: --styles '%s': no style '%s' (the styles: %s; "
                  "your own models: --hair-files)\n", v, t, known);
          return -1;
        }
        o->ds.n_styles++;
      }
    } else if (!strcmp(a, "--size")) {
      if (parse_size(v, &o->view.width, &o->view.height)) {
        fprintf(stderr, "hairfilter render: --size wants WxH\n");
        return -1;
      }
    } else if (!strcmp(a, "--hair-color") || !strcmp(a, "--light-color") ||
               !strcmp(a, "--background")) {
      float *dst = a[2] == 'h' ? o->view.hair_color : a[2] == 'l' ? o->view.light_color
                                                                  : o->view.background;
      if (cli_parse_rgb("hairfilter render", a, v, dst)) return -1;
    } else if (!strcmp(a, "--st")) {
      if (parse_int_list(v, o->outputs.st_spp, HFR_MAX_BASELINES, &o->outputs.n_st)) {
        fprintf(stderr, "hairfilter render: --st wants a list like 1,2,4,8,16,64\n");
        return -1;
      }
      o->st_set = 1;
    } else if (!strcmp(a, "--spp")) {
      int n = 0;
      if (parse_int_list(v, o->ds.spp_list, 4, &n)) {
        fprintf(stderr, "hairfilter render: --spp wants N or a list like 1,2,4\n");
        return -1;
      }
      o->ds.n_spp = n;
      o->outputs.spp = 0;
      for (int k = 0; k < n; k++)
        if (o->ds.spp_list[k] > o->outputs.spp) o->outputs.spp = o->ds.spp_list[k];
    } else {
      char *end;
      errno = 0;
      long long n = strtoll(v, &end, 10);
      static const char *const ints[] = {"--strands", "--segments", "--hair-seed", "--children",
                                         "--shadow-size", "--gt-ss", "--opaque", "--seed",
                                         "--count", "--max-fragments", "--random-view"};
      int known = 0;
      for (size_t k = 0; k < sizeof ints / sizeof ints[0]; k++) known |= !strcmp(a, ints[k]);
      /* An option not known is said as such, whatever its value (past
       * int, it was "too large"). */
      if (!known) {
        fprintf(stderr, "hairfilter render: unknown option %s\n", a);
        return -1;
      }
      if (end == v || *end || errno || n < 0) {
        fprintf(stderr, "hairfilter render: %s wants a whole number of at least 0, not '%s'\n",
                a, v);
        return -1;
      }
      /* Past int, (int)n would wrap: --count 4294967297 rendered 1 frame a
       * style, --strands 4294967296 was "strands 0". The seeds (--random-view
       * takes one too) keep 64 bits. */
      if (n > INT_MAX && strcmp(a, "--seed") && strcmp(a, "--hair-seed") &&
          strcmp(a, "--random-view")) {
        fprintf(stderr, "hairfilter render: %s %s is too large (at most %d)\n", a, v, INT_MAX);
        return -1;
      }
      if (!strcmp(a, "--strands")) o->ov.strands = (int)n;
      else if (!strcmp(a, "--segments")) o->ov.segments = (int)n;
      else if (!strcmp(a, "--hair-seed")) o->ov.seed = (uint64_t)n;
      else if (!strcmp(a, "--children")) o->ov.children = (int)n;
      else if (!strcmp(a, "--shadow-size")) o->view.shadow_size = (int)n;
      else if (!strcmp(a, "--gt-ss")) {
        if (n > 8) {
          fprintf(stderr, "hairfilter render: --gt-ss takes 0..8 (0: no ground truth; default "
                  "%d), not %lld\n", HFR_GT_SUPERSAMPLE, n);
          return -1;
        }
        o->outputs.gt_supersample = (int)n;
      }
      else if (!strcmp(a, "--opaque")) o->outputs.opaque_samples = (int)n;
      else if (!strcmp(a, "--seed")) o->outputs.seed = (uint32_t)n, o->ds.seed = (uint64_t)n;
      else if (!strcmp(a, "--count")) o->ds.count = (int)n;
      else if (!strcmp(a, "--max-fragments")) {
        if (n > HFR_MAX_FRAGMENTS) {
          fprintf(stderr, "hairfilter render: --max-fragments is at most %u\n", HFR_MAX_FRAGMENTS);
          return -1;
        }
        o->outputs.max_fragments = (uint32_t)n, o->ds.max_fragments = (uint32_t)n;
      }
      else if (!strcmp(a, "--random-view")) o->random_view = 1, o->random_seed = (uint64_t)n;
      else {
        fprintf(stderr, "hairfilter render: unknown option %s\n", a);
        return -1;
      }
    }
  }
  hfr_style_params *s = &o->style;
  /* Overrides on top of the style's defaults, 0 included where given. */
  if (given(o, "--strands")) s->strands = o->ov.strands;
  if (given(o, "--segments")) s->segments = o->ov.segments;
  if (given(o, "--length")) s->length = o->ov.length;
  if (given(o, "--clumping")) s->clumping = o->ov.clumping;
  if (given(o, "--frizz")) s->frizz = o->ov.frizz;
  if (given(o, "--curl-radius")) s->curl_radius = o->ov.cr;
  if (given(o, "--curl-period")) s->curl_period = o->ov.cp;
  if (given(o, "--thickness")) s->thickness = o->ov.thick, o->asset.thickness = o->ov.thick;
  if (given(o, "--opacity")) s->opacity = o->ov.opac, o->asset.opacity = o->ov.opac;
  if (given(o, "--hair-seed")) s->seed = o->ov.seed, o->asset.children.seed = o->ov.seed;
  if (given(o, "--width-spread")) s->width_spread = o->ov.wspread;
  if (given(o, "--gather")) s->gather = o->ov.gather;
  if (given(o, "--children")) s->children = o->ov.children, o->asset.children.children = o->ov.children;
  if (o->random_view) hfr_view_randomize(&o->view, o->random_seed);
  return check_model_options(o);
}

/* The model and what it grows on: a .hair file as --up, --units, --children
 * and --occluder say (warnings about its widths printed), or a style and
 * its body. */
static int load_model(const opts *o, hfr_hair *hair, hfr_mesh *occ) {
  char err[512] = "", warn[2048] = "";
  int rc;
  memset(occ, 0, sizeof *occ);
  if (o->hair_path) {
    rc = hfr_asset_load(o->hair_path, &o->asset, hair, occ, warn, sizeof warn, err, sizeof err);
    if (*warn) fprintf(stderr, "hairfilter render: warning: %s: %s\n", o->hair_path, warn);
  } else {
    rc = hfr_hair_generate(&o->style, hair);  /* parameters checked in parse_args */
    hfr_ellipsoid body;
    hfr_style_body(o->style.style, &body);
    if (rc == HF_OK && (rc = hfr_mesh_ellipsoid(&body, 48, 24, occ)) != HF_OK)
      hfr_hair_free(hair);
  }
  if (rc != HF_OK) {
    /* Some reasons name the file already ("groom.hair: No such file or
     * directory"): not twice. */
    const char *what = o->hair_path ? o->hair_path : "style";
    size_t n = strlen(what);
    if (*err && !strncmp(err, what, n) && err[n] == ':')
      fprintf(stderr, "hairfilter render %s: %s\n", o->cmd, err);
    else
      fprintf(stderr, "hairfilter render %s: %s: %s\n", o->cmd, what, *err ? err : hf_strerror(rc));
  }
  return rc;
}

static int open_renderer(const opts *o, const hfr_hair *hair, const hfr_mesh *occ,
                         hfr_renderer **r) {
  char err[512] = "";
  int rc = hfr_renderer_create(o->platform, r, err, sizeof err);
  int head = o->hair_path == NULL && o->style.style != HFR_STYLE_FUR;
  if (rc == HF_OK) rc = hfr_renderer_set_hair(*r, hair, head, err, sizeof err);
  if (rc == HF_OK && !head)
    rc = hfr_renderer_set_occluder(*r, occ, o->hair_path ? hfr_asset_fitted(&o->asset) : 1, err,
                                   sizeof err);
  if (rc != HF_OK) {
    fprintf(stderr, "hairfilter render: %s (%s)\n", err, hf_strerror(rc));
    hfr_renderer_destroy(*r);
    *r = NULL;
  }
  return rc;
}

/* load_model then open_renderer: on failure nothing is left to free, and
 * the reason is printed. */
static int open_scene(const opts *o, hfr_hair *hair, hfr_mesh *occ, hfr_renderer **r) {
  *r = NULL;
  int rc = load_model(o, hair, occ);
  if (rc != HF_OK) return rc;
  if ((rc = open_renderer(o, hair, occ, r)) != HF_OK) {
    hfr_hair_free(hair);
    hfr_mesh_free(occ);
  }
  return rc;
}

static void close_scene(hfr_hair *hair, hfr_mesh *occ, hfr_renderer *r) {
  hfr_renderer_destroy(r);
  hfr_hair_free(hair);
  hfr_mesh_free(occ);
}

/* Says when the truth's sub-pixel centres include MSAA sample positions:
 * scores of the first pass's samples against it are then biased upward. */
static void gt_grid_note(int shared) {
  if (shared > 0)
    fprintf(stderr, "hairfilter render: note: %d of the 4 MSAA sample positions are sub-pixel "
            "centres of this ground truth, so on opaque strands the 4 samples, and what reads "
            "them, score better against it than they are; use --gt-ss %d "
            "(docs/RENDERING.md)\n", shared, HFR_GT_SUPERSAMPLE);
}

static void print_stats(const hfr_renderer *r, const hfr_hair *hair, const hfr_view *v,
                        const hfr_stats *st) {
  char culled[96] = "";
  if (st->gt_culled)
    snprintf(culled, sizeof culled, ", %llu behind an optical depth of 30 left out",
             (unsigned long long)st->gt_culled);
  fprintf(stderr,
          "%s (%s), %u strands, %llu segments, %dx%d: shadow %.0f ms, features %.0f ms, "
          "baselines %.0f ms, ground truth %.0f ms (%llu fragments%s, deepest list %u, "
          "%llu lists sorted in several rounds%s)\n",
          hfr_renderer_platform(r), hfr_renderer_gl_name(r), hair->strands,
          (unsigned long long)hfr_hair_total_segments(hair), v->width, v->height, st->shadow_ms,
          st->features_ms, st->baselines_ms, st->gt_ms, (unsigned long long)st->gt_fragments,
          culled, st->gt_max_depth, (unsigned long long)st->gt_truncated,
          st->gt_host_resolve ? ", blended on the host" : "");
  char line[512];
  hfr_frame_stats_format(&st->frame, line, sizeof line);
  fprintf(stderr, "regime: %s\n", line);
}

static int write_png(const hf_image *img, const char *prefix, const hfr_view *v,
                     const char *path) {
  float *rgb = malloc(sizeof(float) * 3 * (size_t)img->width * img->height);
  if (!rgb) return HF_ENOMEM;
  int rc = hfr_composite_channels(img, prefix, v, rgb);
  if (rc == HF_OK) rc = hf_png_write_rgb(path, rgb, img->width, img->height);
  free(rgb);
  if (rc != HF_OK) fprintf(stderr, "hairfilter render: %s: %s\n", path, hf_strerror(rc));
  return rc;
}

/* PNG of the stochastic-transparency estimate of the frame's own spp
 * feature samples (what a filter reads; hf_st_estimate per pixel),
 * composited as the baselines are. */
static int write_input_png(const hf_image *img, int spp, const hfr_view *v, const char *path) {
  size_t px = (size_t)img->width * img->height;
  float *in = malloc(sizeof(float) * px * (size_t)spp * 6);
  float *res = malloc(sizeof(float) * 3 * px);
  float *rgb = malloc(sizeof(float) * 3 * px);
  int rc = in && res && rgb ? hf_features_from_image(img, spp, in) : HF_ENOMEM;
  if (rc == spp) rc = HF_OK;   /* it returns the samples read */
  for (size_t i = 0; rc == HF_OK && i < px; i++)
    hf_st_estimate(in + i * (size_t)spp * 6, spp, res + 3 * i);
  if (rc == HF_OK)
    rc = hfr_composite_result(res, img->width, img->height, img, v->hair_color, v->light_color,
                              v->background, rgb);
  if (rc == HF_OK) rc = hf_png_write_rgb(path, rgb, img->width, img->height);
  if (rc != HF_OK) fprintf(stderr, "hairfilter render: %s: %s\n", path, hf_strerror(rc));
  free(in);
  free(res);
  free(rgb);
  return rc;
}

/* Adds composite.<prefix>.R/G/B for every result triple in img (the
 * ground truth and each baseline), with the view's colours. */
static int add_composites(hf_image *img, const hfr_outputs *out, const hfr_view *v) {
  char prefixes[3 + HFR_MAX_BASELINES][24];
  int n = 0;
  if (out->gt_supersample) snprintf(prefixes[n++], 24, "gt");
  for (int i = 0; i < out->n_st; i++) snprintf(prefixes[n++], 24, "st%d", out->st_spp[i]);
  if (out->opaque_samples) snprintf(prefixes[n++], 24, "opaque");
  if (out->alpha_corrected) snprintf(prefixes[n++], 24, "acst4");
  if (!n) return HF_OK;
  hf_image big;
  size_t px = (size_t)img->width * img->height;
  int rc = hf_image_alloc(&big, img->width, img->height, img->channels + 3 * n);
  if (rc != HF_OK) return rc;
  float *rgb = malloc(sizeof(float) * 3 * px);
  if (!rgb) {
    hf_image_free(&big);
    return HF_ENOMEM;
  }
  hf_image_copy_windows(&big, img);   /* a crop stays where it lies in the frame */
  for (int c = 0; c < img->channels; c++) memcpy(big.names[c], img->names[c], sizeof big.names[c]);
  for (size_t i = 0; i < px; i++)
    memcpy(big.data + i * big.channels, img->data + i * img->channels,
           sizeof(float) * img->channels);
  for (int t = 0; rc == HF_OK && t < n; t++) {
    rc = hfr_composite_channels(img, prefixes[t], v, rgb);
    int c0 = img->channels + 3 * t;
    for (int k = 0; k < 3; k++)
      snprintf(big.names[c0 + k], sizeof big.names[c0 + k], "composite.%.16s.%c", prefixes[t],
               "RGB"[k]);
    for (size_t i = 0; rc == HF_OK && i < px; i++)
      memcpy(big.data + i * big.channels + c0, rgb + 3 * i, 3 * sizeof(float));
  }
  free(rgb);
  if (rc != HF_OK) {
    hf_image_free(&big);
    return rc;
  }
  hf_image_free(img);
  *img = big;
  return HF_OK;
}

static int run_frame(opts *o) {
  if (!o->out && !o->png) {
    fprintf(stderr, "hairfilter render frame: --out F.exr and/or --png PREFIX\n");
    return 2;
  }
  if (cli_check_output("hairfilter render", o->out) || cli_check_output("hairfilter render", o->png))
    return 1;
  hfr_hair hair;
  hfr_mesh occ;
  hfr_renderer *r;
  if (open_scene(o, &hair, &occ, &r) != HF_OK) return 1;
  hf_image img;
  hfr_stats st;
  char err[512] = "";
  o->outputs.background_layer = !o->no_background;
  int rc = hfr_render(r, &o->view, &o->outputs, &img, &st, err, sizeof err);
  if (rc == HF_OK) {
    if (o->view.crop_w > 0 && !o->quiet)
      fprintf(stderr, "crop: window (%d,%d) %dx%d of a %dx%d frame (rows from the top)\n",
              o->view.crop_x, o->view.crop_y, o->view.crop_w, o->view.crop_h, o->view.width,
              o->view.height);
    if (!o->quiet) print_stats(r, &hair, &o->view, &st);
    gt_grid_note(st.gt_shared_positions); /* --quiet or not: it biases every score */
    if (o->out && (rc = add_composites(&img, &o->outputs, &o->view)) != HF_OK)
      fprintf(stderr, "hairfilter render: composites: %s\n", hf_strerror(rc));
    if (rc == HF_OK && o->out &&
        (rc = hfr_frame_write(o->out, &img, o->half, &o->outputs, &st)) != HF_OK)
      fprintf(stderr, "hairfilter render: %s: %s\n", o->out, hf_strerror(rc));
    if (rc == HF_OK && o->png) {
      const char *prefixes[3 + HFR_MAX_BASELINES];
      char names[HFR_MAX_BASELINES][16];
      int n = 0;
      if (o->outputs.gt_supersample) prefixes[n++] = "gt";
      for (int i = 0; i < o->outputs.n_st; i++) {
        snprintf(names[i], sizeof names[i], "st%d", o->outputs.st_spp[i]);
        prefixes[n++] = names[i];
      }
      if (o->outputs.opaque_samples) prefixes[n++] = "opaque";
      if (o->outputs.alpha_corrected) prefixes[n++] = "acst4";
      for (int i = 0; rc == HF_OK && i < n; i++) {
        char path[4096];
        snprintf(path, sizeof path, "%s_%s.png", o->png, prefixes[i]);
        rc = write_png(&img, prefixes[i], &o->view, path);
      }
      if (rc == HF_OK && o->outputs.spp > 0) {
        char path[4096];
        snprintf(path, sizeof path, "%s_input.png", o->png);
        rc = write_input_png(&img, o->outputs.spp, &o->view, path);
      }
    }
    hf_image_free(&img);
  } else {
    fprintf(stderr, "hairfilter render: %s (%s)\n", err, hf_strerror(rc));
  }
  close_scene(&hair, &occ, r);
  return rc == HF_OK ? 0 : 1;
}

/* Fig. 6: ST at several spp, opaque MSAA, ground truth, left to right. */
static int run_fig6(opts *o) {
  if (!o->out) {
    fprintf(stderr, "hairfilter render fig6: --out F.png\n");
    return 2;
  }
  if (cli_check_output("hairfilter render", o->out)) return 1;
  if (!o->st_set) {
    const int def[] = {1, 4, 16, 64};
    memcpy(o->outputs.st_spp, def, sizeof def);
    o->outputs.n_st = 4;
  }
  o->outputs.spp = 0;
  /* Its last two tiles are opaque MSAA and the ground truth. */
  if ((given(o, "--gt-ss") && !o->outputs.gt_supersample) ||
      (given(o, "--opaque") && !o->outputs.opaque_samples)) {
    fprintf(stderr, "hairfilter render fig6: its tiles include opaque MSAA and the ground "
            "truth: --opaque and --gt-ss take 1 or more here\n");
    return 2;
  }
  if (!o->outputs.opaque_samples) o->outputs.opaque_samples = 16;
  o->outputs.background_layer = !o->no_background;
  hfr_hair hair;
  hfr_mesh occ;
  hfr_renderer *r;
  if (open_scene(o, &hair, &occ, &r) != HF_OK) return 1;
  hf_image img;
  hfr_stats st;
  char err[512] = "";
  int rc = hfr_render(r, &o->view, &o->outputs, &img, &st, err, sizeof err);
  if (rc != HF_OK) {
    fprintf(stderr, "hairfilter render: %s (%s)\n", err, hf_strerror(rc));
  } else {
    if (!o->quiet) print_stats(r, &hair, &o->view, &st);
    gt_grid_note(st.gt_shared_positions); /* --quiet or not: it biases every score */
    const int W = img.width, H = img.height, tiles = o->outputs.n_st + 2, gap = 2;
    const int FW = tiles * W + (tiles - 1) * gap;
    float *fig = malloc(sizeof(float) * 3 * (size_t)FW * H);
    float *rgb = malloc(sizeof(float) * 3 * (size_t)W * H);
    if (!fig || !rgb) rc = HF_ENOMEM;
    for (size_t i = 0; rc == HF_OK && i < 3 * (size_t)FW * H; i++) fig[i] = 1; /* white gaps */
    for (int t = 0; rc == HF_OK && t < tiles; t++) {
      char prefix[16];
      if (t < o->outputs.n_st) snprintf(prefix, sizeof prefix, "st%d", o->outputs.st_spp[t]);
      else snprintf(prefix, sizeof prefix, "%s", t == tiles - 2 ? "opaque" : "gt");
      rc = hfr_composite_channels(&img, prefix, &o->view, rgb);
      for (int y = 0; rc == HF_OK && y < H; y++)
        memcpy(fig + 3 * ((size_t)y * FW + t * (W + gap)), rgb + 3 * (size_t)y * W,
               sizeof(float) * 3 * W);
      if (!o->quiet) fprintf(stderr, "tile %d: %s\n", t + 1, prefix);
    }
    if (rc == HF_OK) rc = hf_png_write_rgb(o->out, fig, FW, H);
    if (rc != HF_OK) fprintf(stderr, "hairfilter render: %s: %s\n", o->out, hf_strerror(rc));
    free(fig);
    free(rgb);
    hf_image_free(&img);
  }
  close_scene(&hair, &occ, r);
  return rc == HF_OK ? 0 : 1;
}

static int run_dataset(opts *o) {
  if (!o->out) {
    fprintf(stderr, "hairfilter render dataset: --out DIR\n");
    return 2;
  }
  if (o->ds.count < 1) {
    fprintf(stderr, "hairfilter render dataset: --count %d: a set needs at least 1 frame of "
            "each style\n", o->ds.count);
    return 2;
  }
  if (cli_check_output_dir("hairfilter render dataset", o->out)) return 1;
  char err[512] = "";
  hfr_dataset_opts *d = &o->ds;
  d->out_dir = o->out;
  d->width = o->view.width;
  d->height = o->view.height;
  d->gt_supersample = o->outputs.gt_supersample;
  d->n_st = o->outputs.n_st;
  memcpy(d->st_spp, o->outputs.st_spp, sizeof d->st_spp);
  d->opaque_samples = o->outputs.opaque_samples;
  d->alpha_corrected = o->outputs.alpha_corrected;
  if (given(o, "--strands")) d->strands = o->ov.strands;
  else if (d->extended || d->regimes) d->strands = 0; /* density is one of the varied parameters */
  if (given(o, "--segments")) d->segments = o->ov.segments;
  d->shadow_size = o->view.shadow_size;
  d->half = o->half;
  d->background_layer = !o->no_background;
  d->asset = o->asset;
  d->hair_files = (const char *const *)o->hair_files;
  d->n_hair_files = o->n_hair_files;
  if (o->n_hair_files && !o->styles_set) d->n_styles = 0; /* the files alone */
  if (given(o, "--width-spread")) d->width_spread = o->ov.wspread;
  d->progress = !o->quiet;
  d->platform = o->platform;
  int rc = hfr_dataset_run(d, err, sizeof err);
  /* err says what and what to do; the code's name only when it is empty. */
  if (rc != HF_OK)
    fprintf(stderr, "hairfilter render dataset: %s\n", *err ? err : hf_strerror(rc));
  return rc == HF_OK ? 0 : 1;
}

static int run_hair(opts *o) {
  if (!o->out) {
    fprintf(stderr, "hairfilter render hair: --out F.hair\n");
    return 2;
  }
  if (cli_check_output("hairfilter render", o->out)) return 1;
  hfr_hair hair;
  hfr_mesh occ;
  if (load_model(o, &hair, &occ) != HF_OK) return 1;
  hfr_mesh_free(&occ);
  int rc = hfr_hair_save(o->out, &hair);
  if (rc != HF_OK) fprintf(stderr, "hairfilter render: %s: %s\n", o->out, hf_strerror(rc));
  else if (!o->quiet)
    fprintf(stderr, "%s: %u strands, %u points\n", o->out, hair.strands, hair.points);
  hfr_hair_free(&hair);
  return rc == HF_OK ? 0 : 1;
}

int cmd_render(int argc, char **argv) {
  if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  opts o;
  memset(&o, 0, sizeof o);
  o.cmd = argv[1];
  hfr_style_defaults(HFR_STYLE_STRAIGHT, &o.style);
  hfr_view_defaults(&o.view);
  o.outputs.spp = 4;
  o.outputs.gt_supersample = HFR_GT_SUPERSAMPLE;
  o.outputs.seed = 1;
  /* The default variant (KernelMix, 4 spp) reads it: on for frames of at
   * least 4 spp unless --no-alpha-corrected (-1: not said). */
  o.outputs.alpha_corrected = -1;
  hfr_dataset_defaults(&o.ds);
  hfr_asset_defaults(&o.asset);
  int rc = 2;
  if (parse_args(argc, argv, &o)) goto done;
  /* fig6's panels are the paper's unless asked. */
  if (o.outputs.alpha_corrected < 0)
    o.outputs.alpha_corrected = strcmp(o.cmd, "fig6") != 0 && o.outputs.spp >= 4;
  if (!strcmp(o.cmd, "frame")) rc = run_frame(&o);
  else if (!strcmp(o.cmd, "fig6")) rc = run_fig6(&o);
  else if (!strcmp(o.cmd, "dataset")) rc = run_dataset(&o);
  else if (!strcmp(o.cmd, "hair")) rc = run_hair(&o);
  else {
    fprintf(stderr, "hairfilter render: unknown mode '%s'\n", o.cmd);
    usage(stderr);
  }
done:
  for (int i = 0; i < o.n_hair_files; i++) free(o.hair_files[i]);
  return rc;
}
