/* hairfilter eval: filtering quality against ground truth over dataset EXRs.
 *
 * For every frame (an EXR with S{k}.* features, gt.* and optionally st{N}.*,
 * acst4.* and opaque.* baselines, as `hairfilter render dataset` writes them) and
 * every method (the input's own sample average, each weights file run
 * in-process, each baseline present), the result is composited with one
 * fixed hair colour, light and background, and compared with the composited
 * ground truth on the hair pixels (gt.alpha > 0). docs/QUALITY.md defines the
 * metrics. The same scores are also grouped by regime (eval_strata.h): hair
 * pixels by strand width in pixels and by coverage, frames by their median
 * of those and by resolution. A last table measures, per method, the lattice
 * a decoder's transposed convolutions print into the error, over whole
 * frames and in windows (eval_lattice.h). */
#define _POSIX_C_SOURCE 200809L
#include <cjson/cJSON.h>
#include <ctype.h>
#include <dirent.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>
#include <sys/stat.h>

#include "cli_args.h"
#include "cli_common.h"
#include "commands.h"
#include "eval_lattice.h"
#include "eval_metrics.h"
#include "eval_strata.h"
#include "hfrender.h"

#define MAX_MODELS 16
#define MAX_METHODS (MAX_MODELS + 16)

static const int ST_SPP[] = {1, 2, 4, 8, 16, 64};
#define N_ST ((int)(sizeof ST_SPP / sizeof ST_SPP[0]))

static void usage(FILE *f) {
  fprintf(f,
          "usage: hairfilter eval [--weights A.safetensors,B.safetensors,...]\n"
          "                       [--backend auto|cpu|cpu-ref|cudnn] [--styles curly,coily]\n"
          "                       [--hair r,g,b] [--light r,g,b] [--background r,g,b]\n"
          "                       [--input-spp N] [--max-frames N]\n"
          "                       [--grid OUT.png] [--grid-rows N] [--grid-crop N]\n"
          "                       [--temporal] [--temporal-png OUT.png] [--json OUT.json]\n"
          "                       DIR|FRAME.exr ...\n"
          "Compares, on hair pixels (gt.alpha > 0) of the composited image, the networks,\n"
          "the input's sample average and its 3x3 and 5x5 pools, stochastic transparency\n"
          "st{1,2,4,8,16,64}, its alpha-corrected estimate acst4 and opaque MSAA (those the\n"
          "frames hold) with the ground truth. A DIR is the frames its manifest.json lists\n"
          "(as weights/train.py reads it), or every *.exr in it when it has none;\n"
          "prints a Markdown table (docs/QUALITY.md), then one per regime grouping: hair\n"
          "pixels by strand width in pixels and by coverage, frames by those and by\n"
          "resolution. --json writes every number, per bucket and per frame. Frames\n"
          "outside the input range a weights file was trained on (its input_range\n"
          "metadata) are named on stderr, and counted there are frames whose manifest (or\n"
          "EXR header) says their truth's sub-pixel centres include the MSAA positions\n"
          "(gt_supersample 4, docs/RENDERING.md). A table then counts, per network, the frames\n"
          "where it is below its own input (the estimate of the samples it reads) and\n"
          "below ST 16 spp in PSNR or SSIM; stderr names the frames below the input. A\n"
          "last table measures the lattice in each method's error: the pattern of period\n"
          "2^levels a network's transposed convolutions print, over whole frames and in\n"
          "windows of 8 periods, where its amplitude in display levels says whether it\n"
          "can be seen (docs/QUALITY.md, \"Lattice in the error\").\n"
          "The grid has one row per frame: input average, each network, ST 16 spp, truth.\n"
          "--temporal: the frames (in file-name order) are one camera sequence; also prints\n"
          "each method's mean frame-to-frame change beside the ground truth's (flicker);\n"
          "--temporal-png draws |frame t+1 - frame t| of the middle pair, x4, per method.\n");
}

/* ---- frame list -------------------------------------------------------- */

typedef struct frame_ref {
  char *path;
  char style[32];
  int full_w, full_h;           /* manifest full_width/full_height; 0: none */
  int gt_shared;                /* MSAA positions on the truth's grid; -1: not said */
} frame_ref;

typedef struct frame_list {
  frame_ref *v;
  int n, cap;
  /* Frames a set's manifest lists that are not there (left out, said on
   * stderr): the --json document names them, so that scores of a partial
   * set are not taken for the whole set's. NULL until one is. */
  cJSON *missing;
} frame_list;

/* What the frame's own EXR header says of its truth (hfr_frame_write), for
 * a frame whose manifest does not: the MSAA positions its truth shares, 4
 * for a 4x4 truth of a file without the count, else -1 (not said). */
static int gt_shared_of_file(const char *path) {
  int shared = -1, ss = 0;
  if (hf_exr_read_int_attr(path, HFR_EXR_ATTR_GT_SHARED, &shared) == HF_OK && shared >= 0 &&
      shared <= 4)
    return shared;
  /* Not counted (-1: GL did not say where its samples are): a 4x4 truth
   * is taken to share the standard pattern's 4, as every GPU's does. The
   * header is opened a second time only here. */
  if (hf_exr_read_int_attr(path, HFR_EXR_ATTR_GT_SUPERSAMPLE, &ss) == HF_OK)
    return ss == 4 ? 4 : 0;
  return -1;
}

static int list_push(frame_list *l, const char *path, const char *style, int full_w,
                     int full_h, int gt_shared) {
  if (gt_shared < 0) gt_shared = gt_shared_of_file(path);
  if (l->n == l->cap) {
    int cap = l->cap ? 2 * l->cap : 64;
    frame_ref *v = realloc(l->v, cap * sizeof *v);
    if (!v) return HF_ENOMEM;
    l->v = v;
    l->cap = cap;
  }
  frame_ref *f = &l->v[l->n];
  if (!(f->path = strdup(path))) return HF_ENOMEM;
  snprintf(f->style, sizeof f->style, "%s", style);
  f->full_w = full_w;
  f->full_h = full_h;
  f->gt_shared = gt_shared;
  l->n++;
  return 0;
}

static void list_free(frame_list *l) {
  for (int i = 0; i < l->n; i++) free(l->v[i].path);
  free(l->v);
  cJSON_Delete(l->missing);
}

/* A file's style when no manifest says: its name up to the first '_'. */
static void style_from_name(const char *path, char *out, size_t len) {
  const char *base = strrchr(path, '/');
  base = base ? base + 1 : path;
  size_t n = strcspn(base, "_.");
  if (n >= len) n = len - 1;
  for (size_t i = 0; i < n; i++) out[i] = (char)(base[i] >= 'A' && base[i] <= 'Z' ? base[i] + 32 : base[i]);
  out[n] = 0;
}

static char *read_text(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f) return NULL;
  char *buf = NULL;
  if (fseek(f, 0, SEEK_END) == 0) {
    long n = ftell(f);
    if (n >= 0 && n < (64l << 20) && fseek(f, 0, SEEK_SET) == 0 && (buf = malloc(n + 1))) {
      if (fread(buf, 1, n, f) != (size_t)n) {
        free(buf);
        buf = NULL;
      } else {
        buf[n] = 0;
      }
    }
  }
  fclose(f);
  return buf;
}

/* Style of base name `name` according to DIR/manifest.json, if any, the
 * frame's full size when it is a crop ("full_width", "full_height"; left
 * alone when absent) and how many MSAA sample positions its ground truth
 * shares ("gt_shared_positions"; manifests older than it that say
 * "gt_supersample": 4 share all 4 of the standard pattern's, the only
 * supersampling up to 8 that does, docs/RENDERING.md; left alone when
 * neither says). The manifest lists frames under "frames" (or
 * "images", "renders", "items"), each an object with "file" (or "path",
 * "exr", "name") and "style". */
static const cJSON *manifest_frames(const cJSON *doc) {
  static const char *lists[] = {"frames", "images", "renders", "items", "files"};
  const cJSON *arr = cJSON_IsArray(doc) ? doc : NULL;
  for (size_t i = 0; doc && !arr && i < sizeof lists / sizeof *lists; i++) {
    const cJSON *a = cJSON_GetObjectItemCaseSensitive(doc, lists[i]);
    if (cJSON_IsArray(a)) arr = a;
  }
  return arr;
}

/* File of manifest frame entry it, as written (a string, or an object's
 * "file", "path", "exr" or "name": relative to the manifest's directory,
 * or absolute), NULL when it has none. */
static const char *manifest_file(const cJSON *it) {
  static const char *files[] = {"file", "path", "exr", "name"};
  const char *fname = cJSON_IsString(it) ? it->valuestring : NULL;
  for (size_t i = 0; !fname && i < sizeof files / sizeof *files; i++) {
    const cJSON *s = cJSON_GetObjectItemCaseSensitive(it, files[i]);
    if (cJSON_IsString(s)) fname = s->valuestring;
  }
  return fname;
}

/* What manifest frame entry it says of its frame: its style (lower case;
 * HF_ENOTFOUND when it gives none), its full size when it is a crop
 * ("full_width", "full_height"; left alone when absent) and how many MSAA
 * sample positions its ground truth shares ("gt_shared_positions";
 * manifests older than it that say "gt_supersample": 4 share all 4 of the
 * standard pattern's, the only supersampling up to 8 that does,
 * docs/RENDERING.md; left alone when neither says). */
static int entry_fields(const cJSON *it, char *out, size_t len, int *full_w, int *full_h,
                        int *gt_shared) {
  const cJSON *fw = cJSON_GetObjectItemCaseSensitive(it, "full_width");
  const cJSON *fh = cJSON_GetObjectItemCaseSensitive(it, "full_height");
  if (cJSON_IsNumber(fw) && cJSON_IsNumber(fh) && fw->valuedouble >= 1 &&
      fh->valuedouble >= 1 && fw->valuedouble <= 1 << 20 && fh->valuedouble <= 1 << 20) {
    *full_w = (int)fw->valuedouble;
    *full_h = (int)fh->valuedouble;
  }
  const cJSON *sh = cJSON_GetObjectItemCaseSensitive(it, "gt_shared_positions");
  const cJSON *ss = cJSON_GetObjectItemCaseSensitive(it, "gt_supersample");
  if (cJSON_IsNumber(sh) && sh->valuedouble >= 0 && sh->valuedouble <= 4)
    *gt_shared = (int)sh->valuedouble;
  else if (cJSON_IsNumber(ss)) /* older, or -1: GL did not say (as gt_shared_of_file) */
    *gt_shared = ss->valuedouble == 4 ? 4 : 0;
  const cJSON *st = cJSON_GetObjectItemCaseSensitive(it, "style");
  if (!cJSON_IsString(st)) return HF_ENOTFOUND;
  snprintf(out, len, "%s", st->valuestring);
  for (char *p = out; *p; p++)
    if (*p >= 'A' && *p <= 'Z') *p += 32;
  return 0;
}

/* entry_fields of the entry of doc's frame list whose file has base name
 * name; HF_ENOTFOUND when none has (or it gives no style). */
static int manifest_entry(const cJSON *doc, const char *name, char *out, size_t len,
                          int *full_w, int *full_h, int *gt_shared) {
  const cJSON *arr = manifest_frames(doc), *it;
  if (!arr) return HF_ENOTFOUND;
  cJSON_ArrayForEach(it, arr) {
    const char *fname = manifest_file(it), *b = fname ? strrchr(fname, '/') : NULL;
    if (fname && !strcmp(b ? b + 1 : fname, name))
      return entry_fields(it, out, len, full_w, full_h, gt_shared);
  }
  return HF_ENOTFOUND;
}

/* Path of manifest entry file fname of directory dir, as weights/train.py
 * joins them (os.path.join: no second '/' after a dir given as "data/bob/"):
 * fname itself when absolute. 0, or HF_ERANGE when too long. */
static int entry_path(const char *dir, const char *fname, char *out, size_t len) {
  size_t dl = strlen(dir);
  const char *sep = dl && dir[dl - 1] == '/' ? "" : "/";
  int n = fname[0] == '/' ? snprintf(out, len, "%s", fname)
                          : snprintf(out, len, "%s%s%s", dir, sep, fname);
  return n < 0 || (size_t)n >= len ? HF_ERANGE : 0;
}

static int cmp_ref(const void *a, const void *b) {
  return strcmp(((const frame_ref *)a)->path, ((const frame_ref *)b)->path);
}

static int ends_with(const char *s, const char *suf) {
  size_t n = strlen(s), m = strlen(suf);
  return n >= m && !strcmp(s + n - m, suf);
}

/* Whether one of manifest frame list frames of dir is dir/name. */
static int in_manifest(const cJSON *frames, const char *dir, const char *name) {
  char full[4096], mine[4096];
  if (entry_path(dir, name, mine, sizeof mine)) return 0;
  const cJSON *it;
  cJSON_ArrayForEach(it, frames) {
    const char *f = manifest_file(it);
    if (f && !entry_path(dir, f, full, sizeof full) && !strcmp(full, mine)) return 1;
  }
  return 0;
}

/* Adds the frames manifest list frames of dir lists, in its order (sorted
 * later), naming (the first, and a count) those that are not there: a set
 * copied in part, or rendered elsewhere. */
static int add_listed(frame_list *l, const char *dir, const cJSON *frames) {
  int missing = 0, rc = 0;
  char first[256] = "", style[32];
  const cJSON *it;
  cJSON_ArrayForEach(it, frames) {
    const char *f = manifest_file(it);
    char full[4096];
    struct stat st;
    if (!f) continue;
    if (entry_path(dir, f, full, sizeof full) || stat(full, &st) || !S_ISREG(st.st_mode)) {
      if (!missing++) snprintf(first, sizeof first, "%s", f);
      if (!l->missing && !(l->missing = cJSON_CreateArray())) return HF_ENOMEM;
      char named[4400];
      snprintf(named, sizeof named, "%s/%s", dir, f);
      if (!cJSON_AddItemToArray(l->missing, cJSON_CreateString(f[0] == '/' ? f : named)))
        return HF_ENOMEM;
      continue;
    }
    int fw = 0, fh = 0, shared = -1;
    if (entry_fields(it, style, sizeof style, &fw, &fh, &shared))
      style_from_name(full, style, sizeof style);
    if ((rc = list_push(l, full, style, fw, fh, shared))) return rc;
  }
  if (missing)
    fprintf(stderr, "hairfilter eval: %s: %d frame(s) its manifest.json lists are not there "
                    "(%s%s); left out\n", dir, missing, first, missing > 1 ? ", ..." : "");
  return 0;
}

/* DIR/manifest.json parsed, or NULL when there is none (or it is not JSON). */
static cJSON *read_manifest(const char *dir, int dir_len) {
  char mpath[4096];
  snprintf(mpath, sizeof mpath, "%.*s/manifest.json", dir_len, dir);
  char *text = read_text(mpath);
  cJSON *doc = text ? cJSON_Parse(text) : NULL;
  free(text);
  return doc;
}

static int cmp_str(const void *a, const void *b) {
  return strcmp(*(const char *const *)a, *(const char *const *)b);
}

/* How many directories right under dir hold a manifest.json (the sets of a
 * directory that is their parent, as weights/dataset.py sets_below finds
 * them), and the first four in name order, dir joined to each and
 * space-separated, into out ("..." after them when there are more). */
static int sets_below(const char *dir, char *out, size_t len) {
  *out = 0;
  DIR *d = opendir(dir);
  if (!d) return 0;
  char **names = NULL;
  int n = 0, cap = 0;
  struct dirent *e;
  while ((e = readdir(d))) {
    if (e->d_name[0] == '.') continue;
    char m[4096];
    struct stat st;
    int k = snprintf(m, sizeof m, "%s/%s/manifest.json", dir, e->d_name);
    if (k < 0 || (size_t)k >= sizeof m || stat(m, &st) || !S_ISREG(st.st_mode)) continue;
    if (n == cap) {
      int nc = cap ? 2 * cap : 16;
      char **v = realloc(names, nc * sizeof *v);
      if (!v) break;   /* out of memory: the sets found so far */
      names = v;
      cap = nc;
    }
    if (!(names[n] = strdup(e->d_name))) break;
    n++;
  }
  closedir(d);
  if (n) qsort(names, n, sizeof *names, cmp_str);
  size_t used = 0;
  const char *sep = dir[0] && dir[strlen(dir) - 1] == '/' ? "" : "/";   /* data/ or data */
  for (int i = 0; i < n && i < 4 && used < len; i++) {
    int k = snprintf(out + used, len - used, "%s%s%s%s", i ? " " : "", dir, sep, names[i]);
    if (k < 0) break;
    used += (size_t)k;
  }
  if (n > 4 && used < len) snprintf(out + used, len - used, " ...");
  for (int i = 0; i < n; i++) free(names[i]);
  free(names);
  return n;
}

typedef struct file_key {
  dev_t dev;
  ino_t ino;
  int at;   /* index in the frame list */
} file_key;

static int cmp_key(const void *a, const void *b) {
  const file_key *x = a, *y = b;
  if (x->dev != y->dev) return x->dev < y->dev ? -1 : 1;
  if (x->ino != y->ino) return x->ino < y->ino ? -1 : 1;
  return x->at - y->at;
}

/* HF_EINVAL, naming it, when one file is in l twice (a set given twice, a set
 * and a frame of it, a manifest that lists a file twice): its scores would
 * count twice in every mean, as weights/dataset.py read_sets refuses such a
 * frame for training. The file itself (device and inode) is compared, not
 * the spelling of its path. */
static int check_frames_once(const frame_list *l) {
  if (l->n < 2) return 0;
  file_key *k = malloc((size_t)l->n * sizeof *k);
  if (!k) return HF_ENOMEM;
  int n = 0;
  for (int i = 0; i < l->n; i++) {
    struct stat st;
    if (stat(l->v[i].path, &st)) continue;   /* missing: said when it is read */
    k[n].dev = st.st_dev;
    k[n].ino = st.st_ino;
    k[n++].at = i;
  }
  qsort(k, n, sizeof *k, cmp_key);
  /* The first repeat in the order given (equal keys are sorted by index). */
  int best = -1;
  for (int i = 1; i < n; i++)
    if (k[i].dev == k[i - 1].dev && k[i].ino == k[i - 1].ino && (best < 0 || k[i].at < k[best].at))
      best = i;
  if (best >= 0) {
    const char *a = l->v[k[best - 1].at].path, *b = l->v[k[best].at].path;
    if (!strcmp(a, b))
      fprintf(stderr, "hairfilter eval: %s is given twice", a);
    else
      fprintf(stderr, "hairfilter eval: %s and %s are one frame, given twice", a, b);
    fprintf(stderr, " (a set given twice, a set and a frame of it, or a manifest that lists "
                    "the frame twice): give each frame once; its scores would count twice\n");
  }
  free(k);
  return best >= 0 ? HF_EINVAL : 0;
}

/* Adds FILE.exr (with what the manifest beside it says of it), or every
 * *.exr of DIR in name order. */
static int add_path(frame_list *l, const char *path) {
  struct stat st;
  if (stat(path, &st)) {
    fprintf(stderr, "hairfilter eval: %s: no such file or directory\n", path);
    return HF_EIO;
  }
  char style[32];
  if (!S_ISDIR(st.st_mode)) {
    const char *slash = strrchr(path, '/');
    cJSON *doc = slash ? read_manifest(path, (int)(slash - path)) : read_manifest(".", 1);
    int fw = 0, fh = 0, shared = -1;
    if (!doc || manifest_entry(doc, slash ? slash + 1 : path, style, sizeof style, &fw, &fh,
                               &shared))
      style_from_name(path, style, sizeof style);
    cJSON_Delete(doc);
    return list_push(l, path, style, fw, fh, shared);
  }
  cJSON *doc = read_manifest(path, (int)strlen(path));
  /* A manifest that is there but lists nothing readable (cut short, not
   * JSON, no frame list) is refused, as weights/train.py refuses it: taken
   * for no manifest, the set would silently become every .exr beside it. */
  char mpath[4096];
  struct stat ms;
  snprintf(mpath, sizeof mpath, "%s/manifest.json", path);
  if (!manifest_frames(doc) && !stat(mpath, &ms)) {
    fprintf(stderr, "hairfilter eval: %s: %s, so the set it lists is unknown (weights/train.py "
            "refuses it too); render the set again, or remove it to score every .exr of %s\n",
            mpath, doc ? "no frame list (frames, images, renders, items or files)"
                       : "not JSON, or not readable",
            path);
    cJSON_Delete(doc);
    return HF_EFORMAT;
  }
  DIR *d = opendir(path);
  if (!d) {
    cJSON_Delete(doc);
    return HF_EIO;
  }
  /* A directory whose manifest lists its frames is the set the manifest
   * lists, as weights/train.py reads it (entries relative to the directory
   * or absolute): other .exr files there (results written beside the
   * frames, a frame a stopped render left half written) are left out and
   * counted; frames it lists that are not there are named. */
  const cJSON *listed = manifest_frames(doc);
  int first = l->n, rc = listed ? add_listed(l, path, listed) : 0, unlisted = 0;
  char first_unlisted[256] = "";
  struct dirent *e;
  while (!rc && (e = readdir(d))) {
    if (!ends_with(e->d_name, ".exr")) continue;
    if (listed) {
      if (!in_manifest(listed, path, e->d_name) && !unlisted++)
        snprintf(first_unlisted, sizeof first_unlisted, "%s", e->d_name);
      continue;
    }
    char full[4096];
    if (entry_path(path, e->d_name, full, sizeof full)) continue;   /* too long to open */
    style_from_name(e->d_name, style, sizeof style);
    rc = list_push(l, full, style, 0, 0, -1);
  }
  closedir(d);
  if (unlisted)
    fprintf(stderr, "hairfilter eval: %s: %d .exr file(s) not in its manifest.json left out "
                    "(%s%s); name them as FILE.exr to score them\n",
            path, unlisted, first_unlisted, unlisted > 1 ? ", ..." : "");
  cJSON_Delete(doc);
  if (!rc && l->n == first) {
    /* Said here, not later as "no frames with hair": a run directory or a
     * mistyped path is not a set of frames whose hair was all empty. */
    char sets[1024];
    int n_sets = sets_below(path, sets, sizeof sets);
    if (n_sets > 0)
      fprintf(stderr, "hairfilter eval: %s: no .exr frames of its own; it holds %d set(s) "
                      "(directories with a manifest.json): give them (%s)\n", path, n_sets,
              sets);
    else
      fprintf(stderr, "hairfilter eval: %s: no .exr frames in it (give a directory that "
                      "`hairfilter render dataset` wrote, or FRAME.exr files)\n", path);
    return HF_ENOTFOUND;
  }
  qsort(l->v + first, l->n - first, sizeof *l->v, cmp_ref);
  return rc;
}

/* How many entries of the comma-separated list all have base name base (n
 * bytes), and how many are the whole path tok. */
static void count_names(const char *all, const char *tok, const char *base, size_t n,
                        int *same_base, int *same_path) {
  *same_base = *same_path = 0;
  for (const char *p = all; *p;) {
    size_t m = strcspn(p, ",");
    const char *b = p;
    for (size_t i = 0; i < m; i++)
      if (p[i] == '/') b = p + i + 1;
    size_t bn = m - (size_t)(b - p);
    *same_base += bn == n && !strncmp(b, base, n);
    *same_path += m == strlen(tok) && !strncmp(p, tok, m);
    p += m;
    if (*p == ',') p++;
  }
}

/* 1 when style is one of the comma-separated styles (all when none), each
 * taken as train.py's --styles takes it (dataset.parse_styles): spaces
 * around it dropped, in any case (a frame's style is lower case, a .hair
 * file's name need not be: MyBob.hair's frames are style mybob). */
static int style_wanted(const char *styles, const char *style) {
  if (!styles) return 1;
  size_t n = strlen(style);
  int named = 0;   /* no style named (",", " "): every style, as parse_styles */
  for (const char *p = styles; *p;) {
    size_t m = strcspn(p, ",");
    const char *t = p;
    size_t k = m;
    while (k && isspace((unsigned char)*t)) t++, k--;
    while (k && isspace((unsigned char)t[k - 1])) k--;
    named += k > 0;
    if (k && k == n && !strncasecmp(t, style, n)) return 1;
    p += m;
    if (*p == ',') p++;
  }
  return !named;
}

/* ---- methods ------------------------------------------------------------- */

enum { M_INPUT, M_INPUT_POOL, M_MODEL, M_CHANNELS };

/* One lattice measure of a method over the frames (eval_lattice.h): the
 * frames it was measured on, the sum and largest of their peaks, the frame
 * with the largest (and, windowed, the window's top-left pixel), and the
 * frames at or above the measure's threshold. */
typedef struct lattice_summary {
  int frames, visible, max_frame, max_x, max_y;
  double sum, max;
} lattice_summary;

typedef struct method {
  int kind;
  char label[320];
  char prefix[16];              /* M_CHANNELS: "st4", "opaque" */
  int radius;                   /* M_INPUT_POOL: half side of the window */
  int model;                    /* M_MODEL: index into models */
  /* --temporal: the previous frame's composite and the summed change. */
  float *prev;
  int has_prev, pairs;
  double change;
  /* M_MODEL: frames compared with a reference and, of them, those where
   * the method is lower in PSNR, in SSIM, in either (below[k][0..2]).
   * k = REF_OWN_INPUT: the stochastic-transparency estimate of the samples
   * the network reads (its own input); REF_ST16: 16 spp. */
  int compared[2], below[2][3];
  cJSON *below_files;           /* names of the frames below its own input */
  /* The lattice in its error (eval_lattice.h) at this period (a network's
   * 2^levels, LATTICE_REF_PERIOD for the rest): over whole frames and the
   * largest over a frame's windows. */
  int lattice_period;
  lattice_summary lattice, lattice_window;
} method;

/* The period the input and the baselines are measured at: that of Base
 * and Kernel (three levels). */
#define LATTICE_REF_PERIOD 8

enum { REF_OWN_INPUT, REF_ST16 };

/* ---- temporal stability ------------------------------------------------------ */

/* Mean over pixels that are hair in either frame (ground-truth alpha > 0)
 * and the 3 channels of |b - a|: how much the image moves from one frame to
 * the next. The ground truth's own value is the motion of the scene; what a
 * method adds on top of it is flicker. */
static double frame_change(const float *a, const float *b, const uint8_t *ma,
                           const uint8_t *mb, size_t npx) {
  double sum = 0;
  size_t n = 0;
  for (size_t p = 0; p < npx; p++) {
    if (!ma[p] && !mb[p]) continue;
    for (int c = 0; c < 3; c++) sum += fabsf(b[3 * p + c] - a[3 * p + c]);
    n++;
  }
  return n ? sum / (3.0 * n) : 0;
}

/* Records this frame's composite for method m: adds the change from its
 * previous frame, keeps the frame for the next one, and fills diff (when
 * not NULL) with |now - previous| x gain for the figure. */
static int temporal_step(method *m, const float *rgb, const uint8_t *mask, const uint8_t *pmask,
                         size_t npx, float *diff, float gain) {
  if (m->has_prev) {
    m->change += frame_change(m->prev, rgb, pmask, mask, npx);
    m->pairs++;
    if (diff)
      for (size_t i = 0; i < npx * 3; i++) diff[i] = fminf(1.f, gain * fabsf(rgb[i] - m->prev[i]));
  } else if (!m->prev && !(m->prev = malloc(npx * 3 * sizeof(float)))) {
    return HF_ENOMEM;
  }
  memcpy(m->prev, rgb, npx * 3 * sizeof(float));
  m->has_prev = 1;
  return 0;
}

/* The frame's first spp samples into in, sanitised as hf_model_run does
 * (protocol/FEATURES.md), so the baselines see what the networks see. */
static void input_features(const hf_image *img, int spp, float *in, hf_input_report *rep) {
  hf_features_from_image(img, spp, in);
  hf_features_sanitise(in, HF_F32, img->width, img->height, spp, rep);
}

/* The stochastic-transparency estimate of the input's first spp samples
 * (hf_st_estimate): alpha = covered fraction, color/highlight = mean over
 * covered samples. in receives the frame's features. */
static void input_average(const hf_image *img, int spp, float *in, float *res,
                          hf_input_report *rep) {
  input_features(img, spp, in, rep);
  size_t n = (size_t)img->width * img->height;
  for (size_t p = 0; p < n; p++)
    hf_st_estimate(in + p * spp * HF_FEATURES_PER_SAMPLE, spp, res + 3 * p);
}

/* The same estimate pooled over the (2 radius + 1)^2 window of each pixel
 * (hf_pooled_estimate_frame): the best fixed filter of the samples without
 * a network; radius 2 is the base the Residual architecture corrects. tmp:
 * scratch of the size of res. */
static void input_pooled(const hf_image *img, int spp, int radius, float *in, float *res,
                         float *tmp, hf_input_report *rep) {
  input_features(img, spp, in, rep);
  hf_input_view v = {in, img->width, img->height, img->width, spp * HF_FEATURES_PER_SAMPLE};
  hf_pooled_estimate_frame(&v, spp, radius, res, tmp);
}

/* Copies channels prefix.color/.highlight/.alpha into res; HF_ENOTFOUND when
 * the frame lacks them. */
static int gather(const hf_image *img, const char *prefix, float *res) {
  int idx[3];
  for (int f = 0; f < 3; f++) {
    char name[48];
    snprintf(name, sizeof name, "%s.%s", prefix, HF_OUTPUT_NAMES[f]);
    if ((idx[f] = hf_image_channel(img, name)) < 0) return HF_ENOTFOUND;
  }
  size_t n = (size_t)img->width * img->height;
  for (size_t p = 0; p < n; p++)
    for (int f = 0; f < 3; f++) res[3 * p + f] = img->data[p * img->channels + idx[f]];
  return 0;
}

/* The first non-finite value of res ([n][3] of prefix.color/highlight/
 * alpha, as gather makes it), said in what: "gt.color = nan at pixel (x,
 * y)". 0 when every value is finite. Scores of a NaN or an infinity are NaN
 * or infinite themselves, and one such pixel would turn a whole table's
 * mean into one. */
static int nonfinite(const hf_image *img, const char *prefix, const float *res, char *what,
                     size_t len) {
  size_t n = (size_t)img->width * img->height;
  for (size_t i = 0; i < 3 * n; i++)
    if (!isfinite(res[i])) {
      size_t p = i / 3;
      snprintf(what, len, "%s.%s = %g at pixel (%lld, %lld)", prefix, HF_OUTPUT_NAMES[i % 3],
               (double)res[i], (long long)img->origin_x + (long long)(p % (size_t)img->width),
               (long long)img->origin_y + (long long)(p / (size_t)img->width));
      return 1;
    }
  return 0;
}

typedef struct look {
  float hair[3], light[3], bg[3];
} look;

/* Composite, clamped to [0, 1] as a display shows it; over the frame's
 * background layer (the head or body the hair grows on, background.*) where
 * the frame has one, as hfr_composite_result. */
static void composite(const look *lk, const hf_image *frame, const float *res, int w, int h,
                      float *rgb) {
  hfr_composite_result(res, w, h, frame, lk->hair, lk->light, lk->bg, rgb);
  for (size_t i = 0; i < (size_t)w * h * 3; i++) rgb[i] = fminf(1.f, fmaxf(0.f, rgb[i]));
}

/* A result's values on the hair pixels of a frame (the main table's
 * per-frame values): the composite's MSE, PSNR and SSIM, the channels'
 * errors. res / gt: [h][w][3] results; smap receives the SSIM map. */
static int frame_score(const float *res, const float *gt, const float *rgb,
                       const float *gt_rgb, int w, int h, const uint8_t *mask, double *smap,
                       eval_frame_score *fs) {
  if (eval_ssim_mean_map(rgb, gt_rgb, w, h, 3, smap)) return HF_ENOMEM;
  fs->mse = eval_mse(rgb, gt_rgb, w, h, 3, mask, NULL);
  fs->ssim = eval_masked_mean(smap, (size_t)w * h, mask, 1.0);
  fs->psnr = eval_psnr(fs->mse, 1.0);
  fs->col = eval_channel_mse(res, 3, 0, 2, gt, 3, 0, 2, w, h, mask);
  fs->hl = eval_channel_mse(res, 3, 1, 2, gt, 3, 1, 2, w, h, mask);
  fs->alpha = eval_channel_mse(res, 3, 2, -1, gt, 3, 2, -1, w, h, mask);
  return 0;
}

/* Scores method mi's result on a frame: the frame's values into fs, and
 * they and every hair pixel into the sums behind the main table and the
 * regime tables. smap: scratch [h][w] for the SSIM map. */
static int score(int mi, eval_strata *strata, const eval_regime *rg,
                 const float *res, const float *gt, const float *rgb, const float *gt_rgb,
                 int w, int h, const uint8_t *mask, double *smap, eval_frame_score *fs) {
  if (frame_score(res, gt, rgb, gt_rgb, w, h, mask, smap, fs)) return HF_ENOMEM;
  eval_strata_add(strata, mi, rg, rgb, gt_rgb, res, gt, smap, fs);
  return 0;
}

/* Compares network m's score on a frame with a reference's (k: REF_OWN_INPUT
 * or REF_ST16) and counts the frame as below it in PSNR, in SSIM, in either.
 * A lower value by any margin counts: the bar is "never below". Marks the
 * frame's JSON item (when not NULL) with below_own_input / below_st16.
 * Returns 1 when below in either. */
static int compare_ref(method *m, int k, const eval_frame_score *net,
                       const eval_frame_score *ref, cJSON *item) {
  int p = net->psnr < ref->psnr, s = net->ssim < ref->ssim;
  m->compared[k]++;
  m->below[k][0] += p;
  m->below[k][1] += s;
  m->below[k][2] += p || s;
  if (item)
    cJSON_AddBoolToObject(item, k == REF_OWN_INPUT ? "below_own_input" : "below_st16", p || s);
  return p || s;
}

static cJSON *below_json(const method *m, int k) {
  cJSON *o = cJSON_CreateObject();
  if (!o) return NULL;
  cJSON_AddNumberToObject(o, "frames", m->compared[k]);
  cJSON_AddNumberToObject(o, "psnr", m->below[k][0]);
  cJSON_AddNumberToObject(o, "ssim", m->below[k][1]);
  cJSON_AddNumberToObject(o, "either", m->below[k][2]);
  if (k == REF_OWN_INPUT && m->below_files)
    cJSON_AddItemReferenceToObject(o, "files", m->below_files);
  return o;
}

static cJSON *score_json(const method *m, const eval_frame_score *fs) {
  cJSON *o = cJSON_CreateObject();
  if (!o) return NULL;
  cJSON_AddStringToObject(o, "method", m->label);
  eval_json_scores(o, fs);
  return o;
}

/* Warns when the frame's input statistics are outside the range a model
 * was trained on (the weights' input_range metadata): 1 when they are, 0
 * when not or when the weights record no range, a negative HF_E* code on
 * failure. Adds the details to flags (a JSON array) when not NULL. */
static int check_range(const hf_input_range *r, const char *label, const char *path,
                       const float *in, int w, int h, int spp, cJSON *flags) {
  hf_input_stats st;
  int bad = cli_input_range_check(r, in, HF_F32, w, h, spp, &st);
  if (bad <= 0) return bad;
  /* Over the progress line on a terminal; a log has none to end, so no
   * blank line before each warning there. */
  if (isatty(2)) fprintf(stderr, "\r\x1b[K");
  cli_warn_input_range("hairfilter eval", path, label, r, &st, (unsigned)bad);
  if (flags) {
    cJSON *o = cJSON_CreateObject();
    cJSON_AddItemToArray(flags, o);
    cJSON_AddStringToObject(o, "method", label);
    cJSON *stats = cJSON_AddObjectToObject(o, "statistics");
    for (int k = 0; stats && k < HF_STAT_COUNT; k++) {
      if (!(bad & (1 << k))) continue;
      cJSON *v = cJSON_AddObjectToObject(stats, hf_input_stat_name(k));
      cJSON_AddItemToObject(v, "value", eval_json_number(st.value[k]));
      double tr[2] = {r->lo[k], r->hi[k]};
      cJSON_AddItemToObject(v, "trained", cJSON_CreateDoubleArray(tr, 2));
    }
  }
  return 1;
}

static const char *kind_name(int kind) {
  switch (kind) {
  case M_INPUT: return "input";
  case M_INPUT_POOL: return "pool";
  case M_MODEL: return "network";
  default: return "baseline";
  }
}

/* Adds a frame's windowed lattice measure to o as "lattice_window":
 * windows, peak and peak_at (the largest peak and its window's top-left
 * pixel), amplitude (in levels of an 8-bit display) and at (its window;
 * null where no window's peak found a pattern). */
static void lattice_window_json(cJSON *o, const eval_lattice_window *lw) {
  cJSON *l = cJSON_AddObjectToObject(o, "lattice_window");
  if (!l) return;
  int pat[2] = {lw->peak_x, lw->peak_y}, at[2] = {lw->x, lw->y};
  cJSON_AddNumberToObject(l, "windows", lw->windows);
  cJSON_AddItemToObject(l, "peak", eval_json_number(lw->peak));
  cJSON_AddItemToObject(l, "peak_at", cJSON_CreateIntArray(pat, 2));
  cJSON_AddItemToObject(l, "amplitude", eval_json_number(255 * lw->amplitude));
  cJSON_AddItemToObject(l, "at", lw->amplitude > 0 ? cJSON_CreateIntArray(at, 2) : cJSON_CreateNull());
}

/* A path's file name (after the last '/'). */
static const char *file_base(const char *path) {
  const char *b = strrchr(path, '/');
  return b ? b + 1 : path;
}

/* Frame i's name in a table: its file name, or its path as given when
 * another frame of the list has the same file name (eval256/a.exr and
 * eval512/a.exr are told apart). */
static const char *frame_label(const frame_list *frames, int i) {
  const char *b = file_base(frames->v[i].path);
  for (int j = 0; j < frames->n; j++)
    if (j != i && !strcmp(file_base(frames->v[j].path), b)) return frames->v[i].path;
  return b;
}

/* Adds lattice summary ls as object `name` of o (nothing when no frame was
 * measured): period, frames, mean, max, max_file (and, windowed, max_at:
 * the window's top-left pixel; both null where the windowed maximum is 0,
 * no pattern on any frame), visible_at, frames_visible. */
static void lattice_json(cJSON *o, const char *name, int period, const lattice_summary *ls,
                         double visible, int windowed, const frame_list *frames) {
  if (!ls->frames) return;
  cJSON *l = cJSON_AddObjectToObject(o, name);
  if (!l) return;
  cJSON_AddNumberToObject(l, "period", period);
  cJSON_AddNumberToObject(l, "frames", ls->frames);
  cJSON_AddItemToObject(l, "mean", eval_json_number(ls->sum / ls->frames));
  cJSON_AddItemToObject(l, "max", eval_json_number(ls->max));
  int none = windowed && !(ls->max > 0);
  cJSON_AddItemToObject(l, "max_file", none ? cJSON_CreateNull()
                                            : cJSON_CreateString(frames->v[ls->max_frame].path));
  if (windowed) {
    int at[2] = {ls->max_x, ls->max_y};
    cJSON_AddItemToObject(l, "max_at", none ? cJSON_CreateNull() : cJSON_CreateIntArray(at, 2));
    cJSON_AddNumberToObject(l, "window_periods", EVAL_LATTICE_WINDOW_PERIODS);
    cJSON_AddNumberToObject(l, "window_hair", EVAL_LATTICE_WINDOW_HAIR);
    cJSON_AddNumberToObject(l, "window_peak", EVAL_LATTICE_WINDOW_PEAK);
  }
  cJSON_AddNumberToObject(l, "visible_at", visible);
  cJSON_AddNumberToObject(l, "frames_visible", ls->visible);
}

/* The --json document: every number of the tables, per bucket, plus the
 * per-frame rows collected while scoring. */
static int write_json(const char *path, const method *ms, int nm, const eval_strata *strata,
                      cJSON *rows, const hf_input_range *ranges, const int *flagged, int frames,
                      size_t hair_px, const look *lk, const char *styles, int input_spp,
                      const frame_list *frame_refs) {
  cJSON *doc = cJSON_CreateObject();
  if (!doc) return HF_ENOMEM;
  cJSON_AddStringToObject(doc, "format", "hairfilter-eval");
  cJSON_AddNumberToObject(doc, "version", 1);
  cJSON_AddNumberToObject(doc, "frames", frames);
  /* Listed by a set's manifest and not there: always present, empty for
   * a whole set. */
  cJSON_AddItemToObject(doc, "frames_missing", frame_refs->missing
                                                   ? cJSON_Duplicate(frame_refs->missing, 1)
                                                   : cJSON_CreateArray());
  cJSON_AddNumberToObject(doc, "hair_pixels", (double)hair_px);
  cJSON_AddNumberToObject(doc, "input_spp", input_spp);
  if (styles && *styles) cJSON_AddStringToObject(doc, "styles", styles);
  cJSON *look_o = cJSON_AddObjectToObject(doc, "look");
  if (look_o) {
    cJSON_AddItemToObject(look_o, "hair", cJSON_CreateFloatArray(lk->hair, 3));
    cJSON_AddItemToObject(look_o, "light", cJSON_CreateFloatArray(lk->light, 3));
    cJSON_AddItemToObject(look_o, "background", cJSON_CreateFloatArray(lk->bg, 3));
  }
  cJSON_AddItemToObject(doc, "groupings", eval_strata_groupings_json(strata));
  cJSON *arr = cJSON_AddArrayToObject(doc, "methods");
  /* The methods written: those no frame had (a baseline its channels lack)
   * are left out, so the count said is the document's, not nm. */
  int written = 0;
  for (int i = 0; arr && i < nm; i++) {
    eval_frame_score mean;
    if (!eval_strata_mean(strata, i, &mean)) continue;
    cJSON *o = eval_strata_method_json(strata, i);
    if (!o) break;
    cJSON_AddItemToArray(arr, o);
    written++;
    cJSON_AddStringToObject(o, "method", ms[i].label);
    cJSON_AddStringToObject(o, "kind", kind_name(ms[i].kind));
    if (ms[i].kind == M_CHANNELS) cJSON_AddStringToObject(o, "channels", ms[i].prefix);
    if (ms[i].kind == M_INPUT_POOL) cJSON_AddNumberToObject(o, "window", 2 * ms[i].radius + 1);
    lattice_json(o, "lattice", ms[i].lattice_period, &ms[i].lattice, EVAL_LATTICE_VISIBLE, 0,
                 frame_refs);
    lattice_json(o, "lattice_window", ms[i].lattice_period, &ms[i].lattice_window,
                 255 * EVAL_LATTICE_VISIBLE_AMPLITUDE, 1, frame_refs);
    if (ms[i].kind == M_MODEL) {
      char *text = hf_input_range_to_json(&ranges[ms[i].model]);
      cJSON *r = text ? cJSON_Parse(text) : cJSON_CreateNull();
      free(text);
      cJSON_AddItemToObject(o, "input_range", r);
      cJSON_AddNumberToObject(o, "frames_out_of_range", flagged[ms[i].model]);
      cJSON_AddItemToObject(o, "below_own_input", below_json(&ms[i], REF_OWN_INPUT));
      cJSON_AddItemToObject(o, "below_st16", below_json(&ms[i], REF_ST16));
    }
  }
  /* A reference: rows stay the caller's. */
  cJSON_AddItemReferenceToObject(doc, "frame_rows", rows);
  char *text = cJSON_Print(doc);
  cJSON_Delete(doc);
  if (!text) return HF_ENOMEM;
  FILE *f = fopen(path, "w");
  int ok = f && fputs(text, f) >= 0 && fputc('\n', f) != EOF;
  if (f && fclose(f)) ok = 0;
  free(text);
  if (!ok) {
    fprintf(stderr, "hairfilter eval: writing %s failed\n", path);
    return HF_EIO;
  }
  fprintf(stderr, "eval: %s: %d frames, %d methods\n", path, frames, written);
  return 0;
}

/* ---- grid ----------------------------------------------------------------- */

typedef struct grid {
  int rows, cols, tile, gap;
  int filled;
  float *rgb;                   /* [rows*(tile+gap)+gap][cols*(tile+gap)+gap][3] */
} grid;

static int grid_width(const grid *g) { return g->cols * (g->tile + g->gap) + g->gap; }
static int grid_height(const grid *g) { return g->rows * (g->tile + g->gap) + g->gap; }

/* Puts the centre tile x tile crop of a w x h image at (row, col). */
static void grid_put(grid *g, int row, int col, const float *rgb, int w, int h) {
  int gw = grid_width(g);
  int cw = w < g->tile ? w : g->tile, ch = h < g->tile ? h : g->tile;
  int x0 = (w - cw) / 2, y0 = (h - ch) / 2;
  int ox = g->gap + col * (g->tile + g->gap), oy = g->gap + row * (g->tile + g->gap);
  for (int y = 0; y < ch; y++)
    memcpy(g->rgb + ((size_t)(oy + y) * gw + ox) * 3, rgb + ((size_t)(y0 + y) * w + x0) * 3,
           (size_t)cw * 3 * sizeof(float));
}

/* ---- command ----------------------------------------------------------------- */

static void print_table(const method *ms, int nm, const eval_strata *strata, int frames,
                        size_t hair_px, const look *lk, const char *styles) {
  printf("Frames: %d%s%s%s, hair pixels: %zu; composite: hair %.3g,%.3g,%.3g, light "
         "%.3g,%.3g,%.3g, background %.3g,%.3g,%.3g\n\n",
         frames, styles && *styles ? " (styles " : "", styles && *styles ? styles : "",
         styles && *styles ? ")" : "", hair_px, lk->hair[0], lk->hair[1], lk->hair[2],
         lk->light[0], lk->light[1], lk->light[2], lk->bg[0], lk->bg[1], lk->bg[2]);
  printf("| method | frames | PSNR (dB) | SSIM | MSE | color·α MSE | highlight·α MSE | "
         "alpha MSE |\n");
  printf("|---|---:|---:|---:|---:|---:|---:|---:|\n");
  for (int i = 0; i < nm; i++) {
    eval_frame_score v;
    int n = eval_strata_mean(strata, i, &v);
    if (!n) continue;
    char psnr[32];
    if (isinf(v.psnr)) snprintf(psnr, sizeof psnr, "inf");
    else snprintf(psnr, sizeof psnr, "%.2f", v.psnr);
    printf("| %s | %d | %s | %.4f | %.5f | %.2e | %.2e | %.2e |\n", ms[i].label, n, psnr,
           v.ssim, v.mse, v.col, v.hl, v.alpha);
  }
  for (int i = 0; i < nm; i++) {
    int n = eval_strata_mean(strata, i, &(eval_frame_score){0});
    if (n && n < frames) {
      printf("\nA row over fewer frames than %d (a baseline, or the estimate a network reads, "
             "that some frames lack: render every frame with the same --st, --opaque and "
             "estimate) is scored on those frames' "
             "pixels only and does not compare with the rows over all of them; the regime "
             "tables mark such cells (k of n frames).\n", frames);
      break;
    }
  }
}

/* The networks' frames below their own input and below ST 16 spp: the
 * per-frame bars of docs/QUALITY.md ("never below its own input"). */
static void print_below(const method *ms, int nm) {
  int any = 0;
  for (int i = 0; i < nm; i++) any |= ms[i].kind == M_MODEL && ms[i].compared[REF_OWN_INPUT];
  if (!any) return;
  printf("\nFrames where a network is below a reference (lower PSNR or SSIM on the frame's "
         "hair pixels; its own input: the stochastic-transparency estimate of the samples "
         "it reads)\n\n");
  printf("| method | frames | below its own input: PSNR / SSIM / either | frames with ST 16 "
         "spp | below ST 16 spp: PSNR / SSIM / either |\n|---|---:|---:|---:|---:|\n");
  for (int i = 0; i < nm; i++) {
    const method *m = &ms[i];
    if (m->kind != M_MODEL || !m->compared[REF_OWN_INPUT]) continue;
    printf("| %s | %d | %d / %d / %d | %d | %d / %d / %d |\n", m->label,
           m->compared[REF_OWN_INPUT], m->below[REF_OWN_INPUT][0], m->below[REF_OWN_INPUT][1],
           m->below[REF_OWN_INPUT][2], m->compared[REF_ST16], m->below[REF_ST16][0],
           m->below[REF_ST16][1], m->below[REF_ST16][2]);
  }
}

/* Counts frame fi's lattice peak (found in the window at x, y) into the
 * summary ls, a frame at or above visible as one where it stands out; NaN
 * (the frame is too small for the period, or has no window with enough
 * hair) is left out. */
static void lattice_add(lattice_summary *ls, double peak, double visible, int fi, int x, int y) {
  if (isnan(peak)) return;
  if (!ls->frames || peak > ls->max) {
    ls->max = peak;
    ls->max_frame = fi;
    ls->max_x = x;
    ls->max_y = y;
  }
  ls->sum += peak;
  ls->frames++;
  ls->visible += peak >= visible;
}

/* Each method's lattice peak (eval_lattice.h): mean and largest over the
 * frames, the frame of the largest, and the frames where it stands out. */
static void print_lattice(const method *ms, int nm, const frame_list *frames) {
  printf("\nLattice in the error: the composited error folded onto P x P pixel phases, "
         "its energy at period P over the mean at P - 1 and P + 1 (about 1: no pattern; "
         ">= %.0f: a pattern of period P, the dots of a decoder's transposed "
         "convolutions, stands out), per frame. Windowed, for a lattice in part of a "
         "frame: in windows of %d P x %d P pixels at least %.0f%% hair, the amplitude "
         "(RMS, in levels of an 8-bit display) of a pattern whose peak there is >= %.0f; "
         "a frame shows a lattice where it is >= %.0f level\n\n",
         EVAL_LATTICE_VISIBLE, EVAL_LATTICE_WINDOW_PERIODS, EVAL_LATTICE_WINDOW_PERIODS,
         100 * EVAL_LATTICE_WINDOW_HAIR, EVAL_LATTICE_WINDOW_PEAK,
         255 * EVAL_LATTICE_VISIBLE_AMPLITUDE);
  printf("| method | P | frames | mean | largest | frame of the largest | frames >= %.0f "
         "| windowed: frames | mean amplitude | largest | where (x, y) | frames >= %.0f |\n"
         "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---|---:|\n",
         EVAL_LATTICE_VISIBLE, 255 * EVAL_LATTICE_VISIBLE_AMPLITUDE);
  for (int i = 0; i < nm; i++) {
    const method *m = &ms[i];
    const lattice_summary *l = &m->lattice, *lw = &m->lattice_window;
    if (!l->frames) continue;
    printf("| %s | %d | %d | %.2f | %.2f | %s | %d ", m->label, m->lattice_period, l->frames,
           l->sum / l->frames, l->max, frame_label(frames, l->max_frame), l->visible);
    if (lw->frames && lw->max > 0)
      printf("| %d | %.2f | %.2f | %s (%d, %d) | %d |\n", lw->frames, lw->sum / lw->frames,
             lw->max, frame_label(frames, lw->max_frame), lw->max_x, lw->max_y,
             lw->visible);
    else if (lw->frames)
      printf("| %d | 0 | 0 | - | 0 |\n", lw->frames);
    else
      printf("| 0 | - | - | - | 0 |\n");
  }
}

static void print_temporal(method *ms, int nm, const method *truth) {
  printf("\nTemporal stability: mean |frame t+1 - frame t| of the composite over hair "
         "pixels (either frame), %d frame pairs\n\n", truth->pairs);
  printf("| method | mean frame-to-frame change | x ground truth |\n|---|---:|---:|\n");
  double t = truth->pairs ? truth->change / truth->pairs : 0;
  for (int i = 0; i < nm; i++) {
    if (!ms[i].pairs) continue;
    double v = ms[i].change / ms[i].pairs;
    printf("| %s | %.5f | %.2f |\n", ms[i].label, v, t > 0 ? v / t : 0);
  }
  printf("| ground truth | %.5f | 1.00 |\n", t);
}

int cmd_eval(int argc, char **argv) {
  const char *weights_arg = NULL, *backend_name = "auto", *styles = NULL, *grid_path = NULL;
  const char *temporal_png = NULL, *json_path = NULL;
  int input_spp = 4, max_frames = 0, grid_rows = 4, grid_crop = 192, temporal = 0;
  look lk;
  memcpy(lk.hair, CLI_HAIR_DEFAULT, sizeof lk.hair);
  memcpy(lk.light, CLI_LIGHT_DEFAULT, sizeof lk.light);
  memcpy(lk.bg, CLI_BG_DEFAULT, sizeof lk.bg);
  static const struct option opts[] = {
    {"weights", required_argument, 0, 'w'},   {"backend", required_argument, 0, 'b'},
    {"styles", required_argument, 0, 's'},    {"hair", required_argument, 0, 'H'},
    {"light", required_argument, 0, 'L'},     {"background", required_argument, 0, 'B'},
    {"input-spp", required_argument, 0, 'n'}, {"max-frames", required_argument, 0, 'm'},
    {"grid", required_argument, 0, 'g'},      {"grid-rows", required_argument, 0, 'r'},
    {"grid-crop", required_argument, 0, 'c'}, {"help", no_argument, 0, 'h'},
    {"temporal", no_argument, 0, 't'},        {"temporal-png", required_argument, 0, 'T'},
    {"json", required_argument, 0, 'J'},      {0, 0, 0, 0}};
  int c;
  optind = 1;
  while ((c = getopt_long(argc, argv, "w:b:h", opts, NULL)) != -1) {
    switch (c) {
    case 'w': weights_arg = optarg; break;
    case 'b': backend_name = optarg; break;
    case 's': styles = optarg; break;
    case 'H': if (cli_parse_rgb("hairfilter eval", "--hair", optarg, lk.hair)) return 2; break;
    case 'L': if (cli_parse_rgb("hairfilter eval", "--light", optarg, lk.light)) return 2; break;
    case 'B': if (cli_parse_rgb("hairfilter eval", "--background", optarg, lk.bg)) return 2; break;
    case 'n': case 'm': case 'r': case 'c': {
      /* The whole argument, in range, or said what is wrong with it. */
      long v;
      const char *name = c == 'n'   ? "--input-spp"
                         : c == 'm' ? "--max-frames"
                         : c == 'r' ? "--grid-rows"
                                    : "--grid-crop";
      long lo = c == 'n' ? 1 : c == 'm' ? 0 : c == 'r' ? 1 : 8;
      long hi = c == 'n' ? HF_MAX_SPP : c == 'm' ? 1000000000L : c == 'r' ? 64 : 4096;
      if (cli_arg_long("hairfilter eval", name, optarg, lo, hi, &v)) return 2;
      if (c == 'n') input_spp = (int)v;
      else if (c == 'm') max_frames = (int)v;
      else if (c == 'r') grid_rows = (int)v;
      else grid_crop = (int)v;
      break;
    }
    case 'g': grid_path = optarg; break;
    case 't': temporal = 1; break;
    case 'T': temporal = 1; temporal_png = optarg; break;
    case 'J': json_path = optarg; break;
    case 'h': usage(stdout); return 0;
    default: goto bad;
    }
  }
  if (optind >= argc) goto bad;
  if (strcmp(backend_name, "auto") && strcmp(backend_name, "cudnn") &&
      strcmp(backend_name, "cpu") && strcmp(backend_name, "cpu-ref")) {
    /* Said at once, with or without --weights (without, no backend is
     * opened, and a misspelt name would pass unseen). */
    fprintf(stderr, "hairfilter eval: --backend wants auto, cudnn, cpu or cpu-ref, not '%s'\n",
            backend_name);
    return 2;
  }
  if (cli_check_output("hairfilter eval", json_path) || cli_check_output("hairfilter eval", grid_path) ||
      cli_check_output("hairfilter eval", temporal_png))
    return 1;

  int rc = 0, nmodels = 0, nm = 0;
  frame_list frames = {0};
  hf_backend *backend = NULL;
  hf_model *models[MAX_MODELS] = {0};
  hf_input_range ranges[MAX_MODELS];        /* each model's trained input range */
  int flagged[MAX_MODELS] = {0};            /* frames outside it */
  method ms[MAX_METHODS];
  memset(ms, 0, sizeof ms);
  grid g = {0}, tg = {0};
  method truth = {0};
  hf_image img = {0};
  float *res = NULL, *gt = NULL, *rgb = NULL, *gt_rgb = NULL, *in = NULL, *diff = NULL;
  uint8_t *mask = NULL, *pmask = NULL;
  double *smap = NULL;
  int seq_w = 0, seq_h = 0, diff_pair = -1;
  char err[512];
  eval_strata *strata = NULL;
  eval_regime rg = {0};
  eval_frame_score fs;
  /* One frame's scores per method, and each network's own input's where
   * it reads fewer samples than the input row (Base@1spp, Base@2spp). */
  eval_frame_score frame_fs[MAX_METHODS], own_fs[MAX_METHODS];
  int frame_has[MAX_METHODS];
  int frames_by[MAX_METHODS] = {0};         /* frames each method scored */
  int ispp_min = 0, ispp_max = 0;           /* samples the input rows read, over the frames */
  cJSON *row_item[MAX_METHODS];
  int st16 = -1;
  cJSON *rows = cJSON_CreateArray(), *row = NULL;   /* per-frame JSON rows */
  if (!rows) return 1;

  for (int i = optind; i < argc; i++)
    if ((rc = add_path(&frames, argv[i])) != 0) goto out;
  if ((rc = check_frames_once(&frames)) != 0) goto out;
  if (styles && *styles) {
    /* --styles that match none of the frames: name the styles they have,
     * before any weights are loaded or frames read. */
    int any = 0;
    for (int fi = 0; fi < frames.n && !any; fi++) any = style_wanted(styles, frames.v[fi].style);
    if (!any) {
      char have[512] = "";
      for (int fi = 0; fi < frames.n; fi++) {
        const char *st = frames.v[fi].style;
        int seen = 0;
        for (int fj = 0; fj < fi && !seen; fj++) seen = !strcmp(frames.v[fj].style, st);
        size_t used = strlen(have);
        if (!seen && used < sizeof have - 1)
          snprintf(have + used, sizeof have - used, "%s%s", used ? ", " : "", st);
      }
      fprintf(stderr, "hairfilter eval: no frame of styles %s among the %d frames given "
                      "(their styles: %s); name some of those with --styles\n",
              styles, frames.n, have);
      rc = HF_ENOTFOUND;
      goto out;
    }
  }

  /* Methods: the input average, each network, each baseline. */
  ms[nm].kind = M_INPUT;
  snprintf(ms[nm++].label, sizeof ms[0].label, "input (mean of %d samples)", input_spp);
  ms[nm].kind = M_INPUT_POOL;
  ms[nm].radius = 1;
  snprintf(ms[nm++].label, sizeof ms[0].label, "input pooled over 3x3 pixels");
  ms[nm].kind = M_INPUT_POOL;
  ms[nm].radius = HF_RESIDUAL_RADIUS;
  snprintf(ms[nm++].label, sizeof ms[0].label, "input pooled over 5x5 pixels (Residual's base)");
  if (!weights_arg)
    fprintf(stderr, "hairfilter eval: no --weights: scoring the baselines only (add e.g. "
                    "--weights weights/kernel_mix.safetensors to score the default variant)\n");
  if (weights_arg) {
    if ((rc = cli_open_backend(backend_name, &backend)) != 0) goto out;
    char *list = strdup(weights_arg);
    if (!list) { rc = HF_ENOMEM; goto out; }
    for (char *tok = strtok(list, ","); tok; tok = strtok(NULL, ",")) {
      if (nmodels == MAX_MODELS) {
        fprintf(stderr, "hairfilter eval: at most %d weights files\n", MAX_MODELS);
        rc = HF_ERANGE;
        break;
      }
      const char *base = strrchr(tok, '/');
      base = base ? base + 1 : tok;
      /* Two runs' files of one name (runs/a/final.safetensors and
       * runs/b/final.safetensors) would be two rows of one label, in the
       * tables and the JSON alike: such files are labelled by their path.
       * Checked before anything is loaded for the file. */
      int same_base, same_path;
      count_names(weights_arg, tok, base, strlen(base), &same_base, &same_path);
      if (same_path > 1) {
        fprintf(stderr, "hairfilter eval: --weights names %s %d times: give each file once\n",
                tok, same_path);
        rc = HF_EINVAL;
        break;
      }
      hf_weights *w = NULL;
      if ((rc = hf_weights_load(tok, &w, err, sizeof err)) != 0) {
        fprintf(stderr, "hairfilter eval: %s\n", err);
        break;
      }
      rc = hf_model_create(backend, w, &models[nmodels]);
      if (rc) {
        fprintf(stderr, "hairfilter eval: preparing %s on %s: %s\n", tok,
                hf_backend_name(backend), hf_strerror(rc));
        hf_weights_free(w);
        break;
      }
      ranges[nmodels] = w->input_range;
      ms[nm].kind = M_MODEL;
      ms[nm].lattice_period = 1 << w->cfg.num_levels;
      ms[nm].model = nmodels++;
      snprintf(ms[nm++].label, sizeof ms[0].label, "ours %s (%s)", w->cfg.name,
               same_base > 1 ? tok : base);
      hf_weights_free(w);
    }
    free(list);
    if (rc) goto out;
  }
  for (int i = 0; i < N_ST; i++) {
    ms[nm].kind = M_CHANNELS;
    snprintf(ms[nm].prefix, sizeof ms[0].prefix, "st%d", ST_SPP[i]);
    if (ST_SPP[i] == 16) st16 = nm;
    snprintf(ms[nm++].label, sizeof ms[0].label, "stochastic transparency %d spp", ST_SPP[i]);
  }
  ms[nm].kind = M_CHANNELS;
  snprintf(ms[nm].prefix, sizeof ms[0].prefix, "acst4");
  snprintf(ms[nm++].label, sizeof ms[0].label, "stochastic transparency 4 spp, alpha-corrected");
  ms[nm].kind = M_CHANNELS;
  snprintf(ms[nm].prefix, sizeof ms[0].prefix, "opaque");
  snprintf(ms[nm++].label, sizeof ms[0].label, "opaque MSAA (no transparency)");
  for (int i = 0; i < nm; i++)
    if (!ms[i].lattice_period) ms[i].lattice_period = LATTICE_REF_PERIOD;
  if ((rc = eval_strata_create(nm, &strata)) != 0) goto out;

  if (grid_path) {
    g.rows = grid_rows;
    g.cols = 3 + nmodels;
    g.tile = grid_crop;
    g.gap = 4;
  }
  if (temporal_png) {
    /* The change between the middle two frames of the sequence. */
    int wanted = 0;
    for (int fi = 0; fi < frames.n; fi++) wanted += style_wanted(styles, frames.v[fi].style);
    if (max_frames && wanted > max_frames) wanted = max_frames;
    diff_pair = wanted / 2;
    tg.rows = 1;
    tg.cols = 3 + nmodels;
    tg.tile = grid_crop;
    tg.gap = 4;
  }

  int scored = 0, on_sample_grid = 0;
  char grid_names[512] = "";
  size_t hair_px = 0;
  for (int fi = 0; fi < frames.n && (!max_frames || scored < max_frames); fi++) {
    frame_ref *fr = &frames.v[fi];
    if (!style_wanted(styles, fr->style)) continue;
    hf_image_free(&img);
    if ((rc = hf_exr_read_part(fr->path, NULL, "S0.color", &img, err, sizeof err)) != 0) {
      fprintf(stderr, "hairfilter eval: %s\n", err);
      goto out;
    }
    cli_warn_lossy("hairfilter eval", fr->path, &img);
    if (cli_refuse_uint("hairfilter eval", fr->path, &img)) {
      rc = HF_EFORMAT;
      goto out;
    }
    int w = img.width, h = img.height, spp = hf_features_spp(&img);
    size_t npx = (size_t)w * h;
    if (temporal && scored && (w != seq_w || h != seq_h)) {
      fprintf(stderr, "hairfilter eval: --temporal: %s is %dx%d, the sequence %dx%d\n",
              fr->path, w, h, seq_w, seq_h);
      rc = HF_EINVAL;
      goto out;
    }
    seq_w = w, seq_h = h;
    uint8_t *keep = pmask;
    pmask = mask;   /* the previous frame's hair pixels, for --temporal */
    mask = keep;
    free(res); free(gt); free(rgb); free(gt_rgb); free(mask); free(in); free(diff); free(smap);
    smap = malloc(npx * sizeof(double));
    res = malloc(npx * 3 * sizeof(float));
    gt = malloc(npx * 3 * sizeof(float));
    rgb = malloc(npx * 3 * sizeof(float));
    gt_rgb = malloc(npx * 3 * sizeof(float));
    in = malloc(npx * (HF_MAX_SPP * HF_FEATURES_PER_SAMPLE + HF_ESTIMATE_CHANNELS) * sizeof(float));
    diff = malloc(npx * 3 * sizeof(float));
    mask = malloc(npx);
    if (!res || !gt || !rgb || !gt_rgb || !in || !diff || !mask || !smap) {
      rc = HF_ENOMEM;
      goto out;
    }
    if (gather(&img, "gt", gt)) {
      fprintf(stderr, "hairfilter eval: %s: no gt.color/gt.highlight/gt.alpha: eval scores "
              "against the frame's ground truth; render it without --gt-ss 0 (docs/RENDERING.md)\n",
              fr->path);
      rc = HF_EFORMAT;
      goto out;
    }
    char bad[160];
    if (nonfinite(&img, "gt", gt, bad, sizeof bad)) {
      fprintf(stderr, "hairfilter eval: %s: its ground truth %s is not finite: nothing can be "
              "scored against it; render the frame again\n", fr->path, bad);
      rc = HF_EFORMAT;
      goto out;
    }
    size_t nhair = 0;
    for (size_t p = 0; p < npx; p++) nhair += (mask[p] = gt[3 * p + 2] > 0);
    if (!nhair) {
      fprintf(stderr, "hairfilter eval: %s: no hair pixels, skipped\n", fr->path);
      continue;
    }
    if (spp < 1) {
      fprintf(stderr, "hairfilter eval: %s: no S0.color: not a feature file\n", fr->path);
      rc = HF_EFORMAT;
      goto out;
    }
    composite(&lk, &img, gt, w, h, gt_rgb);
    /* The frame's regime, from the samples the input rows read. */
    int full_w = fr->full_w, full_h = fr->full_h;
    if (!full_w && hf_exr_display_size(fr->path, &full_w, &full_h, NULL, 0)) full_w = full_h = 0;
    int ispp = input_spp < spp ? input_spp : spp;
    eval_regime_free(&rg);
    hf_features_from_image(&img, ispp, in);
    if ((rc = eval_regime_compute(&rg, in, ispp, gt, mask, w, h, full_w, full_h)) != 0) goto out;
    if (json_path) {
      if (!(row = eval_regime_json(&rg))) { rc = HF_ENOMEM; goto out; }
      cJSON_AddItemToArray(rows, row);
      cJSON_AddStringToObject(row, "file", fr->path);
      cJSON_AddStringToObject(row, "style", fr->style);
      /* MSAA positions its truth shares (manifest or EXR header; -1 not said). */
      cJSON_AddNumberToObject(row, "gt_shared_positions", fr->gt_shared);
    }
    cJSON *row_scores = json_path ? cJSON_AddArrayToObject(row, "methods") : NULL;
    cJSON *row_flags = json_path ? cJSON_AddArrayToObject(row, "out_of_range") : NULL;
    int grow = g.rows && scored < g.rows ? scored : -1;
    if (grow >= 0 && !g.rgb) {
      /* Tiles are the first frame's size, up to the crop: no wasted space. */
      int side = w > h ? w : h;
      if (side < g.tile) g.tile = side;
      g.rgb = malloc((size_t)grid_width(&g) * grid_height(&g) * 3 * sizeof(float));
      if (!g.rgb) { rc = HF_ENOMEM; goto out; }
      for (size_t i = 0; i < (size_t)grid_width(&g) * grid_height(&g) * 3; i++) g.rgb[i] = 1.f;
    }
    int col = 0, tcol = 0;
    int tfig = temporal_png && scored == diff_pair && scored > 0;
    if (tfig && !tg.rgb) {
      /* Columns as the grid's, less ST 16 spp where the sequence lacks it. */
      tg.cols = 2 + nmodels + (hf_image_channel(&img, "st16.color") >= 0);
      int side = w > h ? w : h;
      if (side < tg.tile) tg.tile = side;
      tg.rgb = malloc((size_t)grid_width(&tg) * grid_height(&tg) * 3 * sizeof(float));
      if (!tg.rgb) { rc = HF_ENOMEM; goto out; }
      for (size_t i = 0; i < (size_t)grid_width(&tg) * grid_height(&tg) * 3; i++) tg.rgb[i] = 1.f;
    }
    int warned = 0;   /* one warning per frame about out-of-contract input */
    memset(frame_has, 0, sizeof frame_has);
    for (int mi = 0; mi < nm; mi++) {
      method *m = &ms[mi];
      hf_input_report rep = {0};
      if (m->kind == M_INPUT) {
        input_average(&img, input_spp < spp ? input_spp : spp, in, res, &rep);
      } else if (m->kind == M_INPUT_POOL) {
        /* rgb is free until this method's composite below: the scratch. */
        input_pooled(&img, input_spp < spp ? input_spp : spp, m->radius, in, res, rgb, &rep);
      } else if (m->kind == M_MODEL) {
        const hf_net_config *cfg = hf_model_config(models[m->model]);
        if (spp < cfg->spp) {
          fprintf(stderr, "hairfilter eval: %s has %d spp, %s needs %d: skipped for it "
                  "(render the frames with --spp %d or more to score it there)\n",
                  fr->path, spp, m->label, cfg->spp, cfg->spp);
          continue;
        }
        if (cfg->spp != ispp) {
          /* Its own input: the estimate of the cfg->spp samples it reads. */
          hf_input_report own_rep = {0};
          input_average(&img, cfg->spp, in, res, &own_rep);
          composite(&lk, &img, res, w, h, rgb);
          if ((rc = frame_score(res, gt, rgb, gt_rgb, w, h, mask, smap, &own_fs[mi])) != 0)
            goto out;
        }
        if ((rc = hf_features_from_image(&img, cfg->spp, in)) < 0) goto out;
        /* A network that reads the estimate gets it after the samples. */
        if (cfg->estimate &&
            hf_estimate_from_data(&img, img.data, HF_F32,
                                  in + npx * cfg->spp * HF_FEATURES_PER_SAMPLE) != HF_OK) {
          fprintf(stderr, "hairfilter eval: %s has no %s.* channels, %s reads the "
                  "alpha-corrected estimate: skipped for it (rendered with --no-alpha-corrected?)\n",
                  fr->path, HF_ESTIMATE_PREFIX, m->label);
          continue;
        }
        int out_of_range = check_range(&ranges[m->model], m->label, fr->path, in, w, h,
                                       cfg->spp, row_flags);
        if (out_of_range < 0) {
          rc = out_of_range;
          goto out;
        }
        flagged[m->model] += out_of_range;
        hf_io io = {.batch = 1, .width = w, .height = h, .in = in, .in_dtype = HF_F32,
                    .out = res, .out_dtype = HF_F32};
        if ((rc = hf_model_run_report(models[m->model], &io, NULL, &rep)) != 0) {
          fprintf(stderr, "hairfilter eval: %s on %s: %s\n", cfg->name, fr->path,
                  hf_strerror(rc));
          goto out;
        }
      } else if (gather(&img, m->prefix, res)) {
        continue;   /* this frame has no such baseline */
      } else if (nonfinite(&img, m->prefix, res, bad, sizeof bad)) {
        fprintf(stderr, "hairfilter eval: warning: %s: %s is not finite: %s skipped for this "
                "frame (its stored result is damaged)\n", fr->path, bad, m->label);
        continue;
      }
      if (!warned && (rep.samples || rep.outputs)) {
        cli_warn_sanitised(fr->path, &img, &rep);
        warned = 1;
      }
      composite(&lk, &img, res, w, h, rgb);
      if ((rc = score(mi, strata, &rg, res, gt, rgb, gt_rgb, w, h, mask, smap, &fs)) != 0)
        goto out;
      row_item[mi] = row_scores ? score_json(m, &fs) : NULL;
      if (row_item[mi]) cJSON_AddItemToArray(row_scores, row_item[mi]);
      double peak = eval_lattice_peak(rgb, gt_rgb, w, h, 3, m->lattice_period);
      eval_lattice_window lw;
      int measured = peak < 0 ? (int)peak
                              : eval_lattice_windows(rgb, gt_rgb, mask, w, h, 3,
                                                     m->lattice_period, &lw);
      if (measured < 0) {
        rc = measured;
        goto out;
      }
      lattice_add(&m->lattice, peak, EVAL_LATTICE_VISIBLE, fi, 0, 0);
      /* Windowed: the amplitude in levels of an 8-bit display. */
      lattice_add(&m->lattice_window, measured ? 255 * lw.amplitude : NAN,
                  255 * EVAL_LATTICE_VISIBLE_AMPLITUDE, fi, lw.x, lw.y);
      if (row_item[mi]) {
        cJSON_AddItemToObject(row_item[mi], "lattice_peak", eval_json_number(peak));
        if (measured) lattice_window_json(row_item[mi], &lw);
      }
      frame_fs[mi] = fs;
      frame_has[mi] = 1;
      frames_by[mi]++;
      int in_grid = m->kind == M_INPUT || m->kind == M_MODEL || !strcmp(m->prefix, "st16");
      if (grow >= 0 && in_grid) grid_put(&g, grow, col++, rgb, w, h);
      if (temporal) {
        if ((rc = temporal_step(m, rgb, mask, pmask, npx, tfig && in_grid ? diff : NULL, 4.f)))
          goto out;
        if (tfig && in_grid) grid_put(&tg, 0, tcol++, diff, w, h);
      }
    }
    for (int mi = 0; mi < nm; mi++) {
      method *m = &ms[mi];
      if (m->kind != M_MODEL || !frame_has[mi]) continue;
      int own_spp = hf_model_config(models[m->model])->spp;
      /* ms[0] is the input row: the estimate of the first ispp samples. */
      const eval_frame_score *own = own_spp == ispp ? &frame_fs[0] : &own_fs[mi];
      if (row_item[mi]) {
        cJSON *o = cJSON_AddObjectToObject(row_item[mi], "own_input");
        if (o) eval_json_scores(o, own);
      }
      if (compare_ref(m, REF_OWN_INPUT, &frame_fs[mi], own, row_item[mi])) {
        if (!m->below_files && !(m->below_files = cJSON_CreateArray())) {
          rc = HF_ENOMEM;
          goto out;
        }
        cJSON_AddItemToArray(m->below_files, cJSON_CreateString(fr->path));
      }
      if (st16 >= 0 && frame_has[st16])
        compare_ref(m, REF_ST16, &frame_fs[mi], &frame_fs[st16], row_item[mi]);
    }
    if (grow >= 0) {
      grid_put(&g, grow, g.cols - 1, gt_rgb, w, h);
      g.filled = grow + 1;
    }
    if (temporal) {
      if ((rc = temporal_step(&truth, gt_rgb, mask, pmask, npx, tfig ? diff : NULL, 4.f)))
        goto out;
      if (tfig) {
        grid_put(&tg, 0, tg.cols - 1, diff, w, h);
        tg.filled = 1;
      }
    }
    eval_strata_frame_done(strata, &rg);
    hair_px += nhair;
    if (!ispp_min || ispp < ispp_min) ispp_min = ispp;
    if (ispp > ispp_max) ispp_max = ispp;
    if (fr->gt_shared > 0 && on_sample_grid++ < 5) {
      /* The first few named in the warning; base names keep it short. */
      const char *b = strrchr(fr->path, '/');
      size_t used = strlen(grid_names);
      snprintf(grid_names + used, sizeof grid_names - used, " %s", b ? b + 1 : fr->path);
    }
    scored++;
    /* One line rewritten in place on a terminal; in a log, no control codes. */
    if (isatty(2)) fprintf(stderr, "\reval: %d frames (%s)\x1b[K", scored, fr->path);
  }
  if (isatty(2)) fprintf(stderr, "\n");
  fprintf(stderr, "eval: %d frames scored\n", scored);
  if (!scored) {
    fprintf(stderr, "hairfilter eval: no frames with hair%s%s\n", styles ? " of styles " : "",
            styles ? styles : "");
    rc = HF_ENOTFOUND;
    goto out;
  }
  /* The input rows read what the frames hold: fewer samples than
   * --input-spp on frames rendered with fewer. */
  if (ispp_min != input_spp || ispp_max != input_spp) {
    char what[48];
    if (ispp_min == ispp_max)
      snprintf(what, sizeof what, "mean of %d samples", ispp_min);
    else
      snprintf(what, sizeof what, "mean of %d to %d samples", ispp_min, ispp_max);
    snprintf(ms[0].label, sizeof ms[0].label, "input (%s)", what);
    fprintf(stderr, "hairfilter eval: warning: frames hold fewer samples than --input-spp %d: "
            "the input rows are the %s (render with --spp ...,%d, or give --input-spp %d)\n",
            input_spp, what, input_spp, ispp_min);
  }
  print_table(ms, nm, strata, scored, hair_px, &lk, styles);
  {
    const char *labels[MAX_METHODS];
    for (int i = 0; i < nm; i++) labels[i] = ms[i].label;
    eval_strata_print(strata, labels, stdout);
  }
  print_below(ms, nm);
  print_lattice(ms, nm, &frames);
  fflush(stdout);   /* the tables first, then what stderr says about them */
  if (on_sample_grid)
    fprintf(stderr, "hairfilter eval: warning: %d of %d frames have a ground truth whose "
            "sub-pixel centres include the MSAA sample positions (as their manifest or EXR "
            "header says), so "
            "on opaque strands their 4 samples, and what reads them, score better than they "
            "are; render them again with the default --gt-ss 8 (docs/RENDERING.md, "
            "\"The ground truth's sub-pixel grid\"):%s%s\n", on_sample_grid, scored, grid_names,
            on_sample_grid > 5 ? " ..." : "");
  for (int i = 0; i < nm; i++)
    if (ms[i].kind == M_MODEL && flagged[ms[i].model])
      fprintf(stderr, "hairfilter eval: warning: %d of %d frames are outside the input range %s "
              "was trained on (its scores there may not hold)\n", flagged[ms[i].model], scored,
              ms[i].label);
  for (int i = 0; i < nm; i++) {
    const cJSON *f;
    if (ms[i].kind != M_MODEL || !ms[i].below_files) continue;
    fprintf(stderr, "eval: %s is below its own input (PSNR or SSIM) on %d of %d frames:",
            ms[i].label, ms[i].below[REF_OWN_INPUT][2], ms[i].compared[REF_OWN_INPUT]);
    cJSON_ArrayForEach(f, ms[i].below_files) fprintf(stderr, " %s", f->valuestring);
    fprintf(stderr, "\n");
  }
  /* Without a pair of frames the table would be a truth that moves by
   * 0.00000 and no method at all: said instead, as --temporal-png says it. */
  if (temporal && truth.pairs) print_temporal(ms, nm, &truth);
  if (json_path &&
      (rc = write_json(json_path, ms, nm, strata, rows, ranges, flagged, scored, hair_px, &lk,
                       styles, ispp_min, &frames)) != 0)
    goto out;
  if (temporal && !truth.pairs) {
    fprintf(stderr, "hairfilter eval: --temporal needs at least two frames (one camera "
            "sequence, in file-name order); %d scored\n", scored);
    rc = HF_EINVAL;
    goto out;
  }
  if (temporal_png) {
    if (!tg.filled) {
      fprintf(stderr, "hairfilter eval: --temporal-png needs at least two frames\n");
      rc = HF_EINVAL;
      goto out;
    }
    if ((rc = hf_png_write_rgb(temporal_png, tg.rgb, grid_width(&tg), grid_height(&tg))) != 0) {
      fprintf(stderr, "hairfilter eval: writing %s: %s\n", temporal_png, hf_strerror(rc));
      goto out;
    }
    fprintf(stderr, "eval: %s: |frame %d - frame %d| x4; columns as the grid's\n", temporal_png,
            diff_pair, diff_pair - 1);
  }
  if (g.rgb) {
    g.rows = g.filled;   /* fewer frames than rows: drop the empty rows */
    if ((rc = hf_png_write_rgb(grid_path, g.rgb, grid_width(&g), grid_height(&g))) != 0) {
      fprintf(stderr, "hairfilter eval: writing %s: %s\n", grid_path, hf_strerror(rc));
      goto out;
    }
    fprintf(stderr, "eval: grid %s: %d rows; columns: input mean,", grid_path, g.rows);
    for (int mi = 0; mi < nm; mi++)
      if (ms[mi].kind == M_MODEL) fprintf(stderr, " %s,", ms[mi].label);
    fprintf(stderr, " ST 16 spp, ground truth\n");
  }
  /* A network asked for that scored nothing: its row is empty, which a
   * script reading only the exit status would miss. */
  for (int mi = 0; mi < nm; mi++)
    if (ms[mi].kind == M_MODEL && !frames_by[mi]) {
      fprintf(stderr, "hairfilter eval: %s scored none of the %d frames (the lines above say "
              "why each was skipped)\n", ms[mi].label, scored);
      rc = HF_ENOTFOUND;
    }
out:
  for (int i = 0; i < nmodels; i++) hf_model_destroy(models[i]);
  hf_backend_destroy(backend);
  hf_image_free(&img);
  list_free(&frames);
  free(res); free(gt); free(rgb); free(gt_rgb); free(in); free(mask); free(g.rgb);
  free(pmask); free(diff); free(tg.rgb); free(truth.prev); free(smap);
  eval_regime_free(&rg);
  eval_strata_free(strata);
  cJSON_Delete(rows);
  for (int i = 0; i < nm; i++) {
    free(ms[i].prev);
    cJSON_Delete(ms[i].below_files);
  }
  return rc ? 1 : 0;
bad:
  usage(stderr);
  return 2;
}
