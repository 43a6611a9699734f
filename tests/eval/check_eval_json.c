/* Checks the --json output of `hairfilter eval` on the regime frames of
 * make_eval_frame (DIR/strata, see there for the regions):
 *
 *   check_eval_json OUT.json
 *   check_eval_json --lattice OUT.json
 *
 * Bucket membership (pixels and frames), the full sizes from the manifest
 * and from the EXR display window, the input statistics of every frame,
 * stochastic transparency at 4 spp (the truth: infinite PSNR, SSIM 1 in
 * every bucket), at 16 spp (half the alpha: PSNR known in closed form in
 * every bucket), the frames flagged outside the narrow trained range, and
 * the network's frames below its own input and below ST 16 spp; their
 * frames are too small for the lattice measure, so no method has one.
 *
 * --lattice: the run on DIR/lattice/dots.exr, where st16 is the truth plus
 * a dot lattice of period 8 and st4 the truth: st16's peak stands out,
 * st4's is 0, the windowed measure finds st16's dots in the frame's one
 * window with an amplitude over a level, and every method's summaries
 * (whole-frame and windowed) are those of its frame values. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

static int failures;

#define CHECK(cond, ...)                        \
  do {                                          \
    if (!(cond)) {                              \
      fprintf(stderr, "check_eval_json: ");     \
      fprintf(stderr, __VA_ARGS__);             \
      fprintf(stderr, "\n");                    \
      failures++;                               \
    }                                           \
  } while (0)

static const cJSON *at(const cJSON *o, const char *key) {
  return cJSON_GetObjectItemCaseSensitive(o, key);
}

static double num(const cJSON *o, const char *key) {
  const cJSON *v = at(o, key);
  return cJSON_IsNumber(v) ? v->valuedouble : NAN;
}

static const cJSON *find(const cJSON *arr, const char *key, const char *value) {
  const cJSON *it;
  cJSON_ArrayForEach(it, arr) {
    const cJSON *v = at(it, key);
    if (cJSON_IsString(v) && strstr(v->valuestring, value)) return it;
  }
  return NULL;
}

/* Composite MSE of st16 on a pixel of ground-truth alpha a (default look,
 * colour 0.8, highlight 0.1): the alpha is halved, so each channel is off
 * by (a/2)(L (H c + h) - B) = (a/2)(0.28, 0.10, -0.044). */
static double st16_mse(double a) { return a * a / 4 * (0.28 * 0.28 + 0.01 + 0.044 * 0.044) / 3; }

static double psnr(double mse) { return 10 * log10(1 / mse); }

/* A frame's value of a lattice measure from its per-method item: the
 * whole frame's lattice_peak, or the windowed amplitude in levels
 * (lattice_window.amplitude); NULL when the item has none. */
static const cJSON *lattice_value(const cJSON *item, int windowed) {
  return windowed ? at(at(item, "lattice_window"), "amplitude") : at(item, "lattice_peak");
}

/* Each method's summary `name` ("lattice" or, windowed, "lattice_window")
 * against the values of its per-frame scores (null or absent: not
 * measured): frames, mean, largest and its file, frames at or above
 * visible_at. Returns how many methods have one. */
static int check_lattice_summary(const cJSON *methods, const cJSON *rows, const char *name,
                                 int windowed) {
  const cJSON *m;
  int with = 0;
  cJSON_ArrayForEach(m, methods) {
    const char *label = at(m, "method")->valuestring;
    const cJSON *l = at(m, name), *row;
    int frames = 0, visible = 0;
    double sum = 0, max = -1;
    const char *max_file = NULL;
    cJSON_ArrayForEach(row, rows) {
      const cJSON *item = find(at(row, "methods"), "method", label);
      if (!item) continue;
      const cJSON *v = lattice_value(item, windowed);
      CHECK(v || windowed, "%s: %s has no lattice_peak", at(row, "file")->valuestring, label);
      if (!cJSON_IsNumber(v)) continue;
      frames++;
      sum += v->valuedouble;
      visible += v->valuedouble >= num(l, "visible_at");
      if (v->valuedouble > max) {
        max = v->valuedouble;
        max_file = at(row, "file")->valuestring;
      }
    }
    CHECK(!frames == !l, "%s: %d frames measured, %s summary %s", label, frames, name,
          l ? "present" : "absent");
    if (!l || !frames) continue;
    with++;
    /* Windowed, a maximum of 0 (no pattern anywhere) names no frame. */
    const cJSON *mf = at(l, "max_file");
    int file_ok = windowed && max == 0 ? cJSON_IsNull(mf) && cJSON_IsNull(at(l, "max_at"))
                                       : cJSON_IsString(mf) && !strcmp(mf->valuestring, max_file);
    CHECK(num(l, "frames") == frames && fabs(num(l, "mean") - sum / frames) < 1e-9 &&
              num(l, "max") == max && file_ok && num(l, "frames_visible") == visible,
          "%s: %s %g frames, mean %g, max %g, %g visible; from the rows %d %g %g %d",
          label, name, num(l, "frames"), num(l, "mean"), num(l, "max"),
          num(l, "frames_visible"), frames, sum / frames, max, visible);
  }
  return with;
}

/* Both lattice summaries of every method; returns how many methods have
 * the whole-frame one, after checking that the same methods have the
 * windowed one. */
static int check_lattice(const cJSON *methods, const cJSON *rows) {
  int whole = check_lattice_summary(methods, rows, "lattice", 0);
  int windowed = check_lattice_summary(methods, rows, "lattice_window", 1);
  CHECK(whole == windowed, "%d methods with a lattice summary, %d with a windowed one", whole,
        windowed);
  return whole;
}

/* The --lattice run (one frame, lattice/dots.exr). */
static void check_dots(const cJSON *doc) {
  const cJSON *methods = at(doc, "methods");
  CHECK(num(doc, "frames") == 1, "frames %g", num(doc, "frames"));
  CHECK(check_lattice(methods, at(doc, "frame_rows")) >= 4, "fewer than 4 methods measured");
  const cJSON *st4 = at(find(methods, "method", "stochastic transparency 4 spp"), "lattice");
  const cJSON *st16 = at(find(methods, "method", "stochastic transparency 16 spp"), "lattice");
  const cJSON *net = at(find(methods, "kind", "network"), "lattice");
  CHECK(num(st4, "period") == 8 && num(st4, "max") == 0 && num(st4, "frames_visible") == 0,
        "st4 (the truth): period %g, peak %g", num(st4, "period"), num(st4, "max"));
  CHECK(num(st16, "max") >= 10 * num(st16, "visible_at") && num(st16, "frames_visible") == 1 &&
            strstr(at(st16, "max_file")->valuestring, "dots.exr"),
        "st16 (the dots): peak %g, %g visible", num(st16, "max"), num(st16, "frames_visible"));
  CHECK(num(net, "period") == 8, "the network (3 levels): period %g", num(net, "period"));
  /* Windowed: the frame is one window (64 = 8 periods) of hair; st16's
   * dots are one dot per period of 0.2 in colour factor, well over a
   * level, and the truth has none. */
  const cJSON *w4 = at(find(methods, "method", "stochastic transparency 4 spp"), "lattice_window");
  const cJSON *w16 = at(find(methods, "method", "stochastic transparency 16 spp"), "lattice_window");
  CHECK(num(w4, "frames") == 1 && num(w4, "max") == 0 && num(w4, "frames_visible") == 0,
        "st4 (the truth), windowed: %g frames, amplitude %g", num(w4, "frames"), num(w4, "max"));
  CHECK(num(w16, "frames") == 1 && num(w16, "max") >= num(w16, "visible_at") &&
            num(w16, "frames_visible") == 1 && num(w16, "visible_at") == 1 &&
            num(w16, "window_periods") == 8,
        "st16 (the dots), windowed: amplitude %g levels, %g visible", num(w16, "max"),
        num(w16, "frames_visible"));
  const cJSON *row = cJSON_GetArrayItem(at(doc, "frame_rows"), 0);
  const cJSON *r16 = at(find(at(row, "methods"), "method", "stochastic transparency 16 spp"),
                        "lattice_window");
  const cJSON *r4 = at(find(at(row, "methods"), "method", "stochastic transparency 4 spp"),
                       "lattice_window");
  CHECK(num(r4, "amplitude") == 0 && cJSON_IsNull(at(r4, "at")),
        "st4's frame row: amplitude %g, at not null", num(r4, "amplitude"));
  CHECK(num(r16, "windows") == 1 && num(r16, "peak") >= 10 * num(w16, "window_peak") &&
            cJSON_GetArraySize(at(r16, "at")) == 2,
        "st16's frame row: %g windows, peak %g", num(r16, "windows"), num(r16, "peak"));
}

int main(int argc, char **argv) {
  int dots = argc == 3 && !strcmp(argv[1], "--lattice");
  if (argc != 2 && !dots) {
    fprintf(stderr, "usage: check_eval_json [--lattice] OUT.json\n");
    return 2;
  }
  const char *path = argv[argc - 1];
  FILE *f = fopen(path, "rb");
  if (!f) {
    perror(path);
    return 1;
  }
  static char text[1 << 20];
  size_t n = fread(text, 1, sizeof text - 1, f);
  fclose(f);
  text[n] = 0;
  cJSON *doc = cJSON_Parse(text);
  if (!doc) {
    fprintf(stderr, "check_eval_json: %s is not JSON\n", path);
    return 1;
  }
  if (dots) {
    check_dots(doc);
    cJSON_Delete(doc);
    if (!failures) printf("check_eval_json: all checks passed\n");
    return failures ? 1 : 0;
  }
  CHECK(num(doc, "frames") == 3, "frames %g", num(doc, "frames"));
  CHECK(num(doc, "hair_pixels") == 640, "hair pixels %g", num(doc, "hair_pixels"));

  /* Bucket membership: pixels (frames holding them). */
  static const struct { const char *key; int n; double px[6], fr[6]; } want[] = {
    {"strand_width_pixels", 6, {128, 128, 64, 64, 128, 128}, {2, 2, 1, 1, 2, 2}},
    {"coverage_pixels", 3, {256, 128, 256}, {2, 1, 2}},
    {"strand_width_frames", 6, {0, 128, 0, 384, 128, 0}, {0, 1, 0, 1, 1, 0}},
    {"coverage_frames", 3, {128, 384, 128}, {1, 1, 1}},
    {"resolution_frames", 3, {384, 128, 128}, {1, 1, 1}},
  };
  const cJSON *groupings = at(doc, "groupings");
  for (size_t t = 0; t < sizeof want / sizeof want[0]; t++) {
    const cJSON *g = find(groupings, "key", want[t].key);
    CHECK(g, "no grouping %s", want[t].key);
    if (!g) continue;
    const cJSON *bs = at(g, "buckets");
    CHECK(cJSON_GetArraySize(bs) == want[t].n, "%s: %d buckets", want[t].key,
          cJSON_GetArraySize(bs));
    for (int b = 0; b < want[t].n; b++) {
      const cJSON *o = cJSON_GetArrayItem(bs, b);
      CHECK(num(o, "pixels") == want[t].px[b] && num(o, "frames") == want[t].fr[b],
            "%s bucket %d: %g pixels, %g frames", want[t].key, b, num(o, "pixels"),
            num(o, "frames"));
    }
  }

  const cJSON *methods = at(doc, "methods");
  /* The rows the frames have: the input and its two pools, the two
   * networks, st4, st16 and the alpha-corrected estimate (eval.json_methods
   * checks the count eval reports is this one). */
  CHECK(cJSON_GetArraySize(methods) == 8, "%d methods, not 8", cJSON_GetArraySize(methods));
  /* st4 is the truth everywhere. */
  const cJSON *st4 = find(methods, "method", "stochastic transparency 4 spp");
  CHECK(st4, "no st4 row");
  for (size_t t = 0; st4 && t < sizeof want / sizeof want[0]; t++) {
    const cJSON *o;
    cJSON_ArrayForEach(o, at(st4, want[t].key)) {
      if (num(o, "pixels") == 0) continue;
      CHECK(cJSON_IsNull(at(o, "psnr")) && num(o, "ssim") == 1.0 && num(o, "mse") == 0,
            "st4 %s %s: not the truth", want[t].key, at(o, "bucket")->valuestring);
    }
  }
  /* st16: by ground-truth alpha of the bucket's pixels. Width buckets: none
   * and <0.03 are sparse (0.2) regions, 0.03-0.1 and 0.1-0.3 medium (0.6),
   * 0.3-0.7 and >=0.7 dense (1). Frames: a holds 128 pixels of each alpha,
   * b only dense, c only sparse. */
  double sp = st16_mse(0.2), md = st16_mse(0.6), dn = st16_mse(1.0), fa = (sp + md + dn) / 3;
  static const struct { const char *key; int b; int frames; double which; } w16[] = {
    {"strand_width_pixels", 0, 0, 0.2}, {"strand_width_pixels", 1, 0, 0.2},
    {"strand_width_pixels", 2, 0, 0.6}, {"strand_width_pixels", 3, 0, 0.6},
    {"strand_width_pixels", 4, 0, 1.0}, {"strand_width_pixels", 5, 0, 1.0},
    {"coverage_pixels", 0, 0, 0.2},     {"coverage_pixels", 1, 0, 0.6},
    {"coverage_pixels", 2, 0, 1.0},     {"resolution_frames", 0, 1, -1},
    {"resolution_frames", 1, 1, 1.0},   {"resolution_frames", 2, 1, 0.2},
    {"strand_width_frames", 1, 1, 0.2}, {"strand_width_frames", 3, 1, -1},
    {"strand_width_frames", 4, 1, 1.0}, {"coverage_frames", 0, 1, 0.2},
    {"coverage_frames", 1, 1, -1},      {"coverage_frames", 2, 1, 1.0},
  };
  const cJSON *st16 = find(methods, "method", "stochastic transparency 16 spp");
  CHECK(st16, "no st16 row");
  for (size_t i = 0; st16 && i < sizeof w16 / sizeof w16[0]; i++) {
    double mse = w16[i].which < 0 ? fa : st16_mse(w16[i].which);
    const cJSON *o = cJSON_GetArrayItem(at(st16, w16[i].key), w16[i].b);
    CHECK(fabs(num(o, "mse") - mse) < 1e-4 * mse && fabs(num(o, "psnr") - psnr(mse)) < 1e-3,
          "st16 %s bucket %d: mse %.9g psnr %.6f, want %.9g %.6f", w16[i].key, w16[i].b,
          num(o, "mse"), num(o, "psnr"), mse, psnr(mse));
  }
  (void)sp, (void)md, (void)dn;
  /* The 3x3 and 5x5 pools are there, with their windows. */
  CHECK(num(find(methods, "method", "pooled over 3x3"), "window") == 3, "no 3x3 pool");
  CHECK(num(find(methods, "method", "pooled over 5x5"), "window") == 5, "no 5x5 pool");

  /* The network stamped with a narrow range: a and b are outside it. */
  const cJSON *net = find(methods, "kind", "network");
  CHECK(net && num(net, "frames_out_of_range") == 2, "network: frames out of range %g",
        net ? num(net, "frames_out_of_range") : NAN);
  CHECK(net && num(at(net, "input_range"), "frames") == 3, "network: input_range missing");

  /* Frame rows: sizes, statistics, buckets, flags. */
  const cJSON *rows = at(doc, "frame_rows");
  CHECK(cJSON_GetArraySize(rows) == 3, "%d frame rows", cJSON_GetArraySize(rows));
  static const struct {
    const char *file;
    double full_w, full_h, p50, p90, full, hair, flags;
    const char *width, *cover, *res;
  } fr[] = {
    /* a: widths 64 x (.02 .05 .2 .5 .9): median .2, p90 (288th) .9 (bin edges
     * .19921875, .8984375); R3-R5 fully covered: 192 of 320; 320 of 448 pixels */
    {"a.exr", 56, 8, 0.19921875, 0.8984375, 0.6, 320.0 / 448, 1, "0.1-0.3", "medium 0.3-0.9",
     "256 (<384)"},
    {"b.exr", 512, 512, 0.5, 0.8984375, 1.0, 128.0 / 448, 1, "0.3-0.7", "dense >=0.9",
     "512 (384-767)"},
    {"c.exr", 1024, 768, 0.0198974609375, 0.0198974609375, 0.0, 64.0 / 448, 0, "<0.03",
     "sparse <0.3", "1024+ (>=768)"},
  };
  for (size_t i = 0; i < 3; i++) {
    const cJSON *row = find(rows, "file", fr[i].file);
    CHECK(row, "no row for %s", fr[i].file);
    if (!row) continue;
    const cJSON *st = at(row, "input_stats"), *bk = at(row, "buckets");
    CHECK(num(row, "full_width") == fr[i].full_w && num(row, "full_height") == fr[i].full_h,
          "%s: full size %gx%g", fr[i].file, num(row, "full_width"), num(row, "full_height"));
    CHECK(num(st, "strand_alpha_p50") == fr[i].p50 && num(st, "strand_alpha_p90") == fr[i].p90 &&
              num(st, "full_coverage") == fr[i].full && num(st, "hair_fraction") == fr[i].hair &&
              num(st, "long_side") == 56,
          "%s: input statistics %.10g %.10g %.10g %.10g", fr[i].file, num(st, "strand_alpha_p50"),
          num(st, "strand_alpha_p90"), num(st, "full_coverage"), num(st, "hair_fraction"));
    CHECK(!strcmp(at(bk, "strand_width_frames")->valuestring, fr[i].width) &&
              !strcmp(at(bk, "coverage_frames")->valuestring, fr[i].cover) &&
              !strcmp(at(bk, "resolution_frames")->valuestring, fr[i].res),
          "%s: buckets", fr[i].file);
    /* Small's flags (Base@1spp has its own range) */
    const cJSON *flags = at(row, "out_of_range"), *fl, *small = NULL;
    int nflags = 0;
    cJSON_ArrayForEach(fl, flags) {
      if (!strstr(at(fl, "method")->valuestring, "small_narrow")) continue;
      small = fl;
      nflags++;
    }
    CHECK(nflags == fr[i].flags, "%s: %d flags", fr[i].file, nflags);
    if (fr[i].flags && small) {
      const cJSON *v = at(at(small, "statistics"), "strand_alpha_p50");
      const cJSON *tr = at(v, "trained");
      CHECK(num(v, "value") == fr[i].p50 && cJSON_GetArrayItem(tr, 0)->valuedouble == 0.015 &&
                cJSON_GetArrayItem(tr, 1)->valuedouble == 0.025,
            "%s: flag details", fr[i].file);
    }
    /* input, two pools, two networks, st4, st16, acst4 */
    CHECK(cJSON_GetArraySize(at(row, "methods")) == 8, "%s: %d method rows", fr[i].file,
          cJSON_GetArraySize(at(row, "methods")));
  }
  /* Below its own input and below ST 16 spp, for each network (Small reads
   * 4 samples, Base@1spp its first): the summary counts are those of its
   * per-frame scores, each frame row says which, and a 4-sample network's
   * own input is the input row. */
  const cJSON *m;
  int networks = 0;
  cJSON_ArrayForEach(m, methods) {
    const cJSON *label = at(m, "method");
    if (!cJSON_IsString(at(m, "kind")) || strcmp(at(m, "kind")->valuestring, "network")) continue;
    networks++;
    int below[2][3] = {{0}}, compared[2] = {0}, listed = 0;
    const cJSON *row;
    cJSON_ArrayForEach(row, rows) {
      const char *file = at(row, "file")->valuestring;
      const cJSON *ms = at(row, "methods");
      const cJSON *n = find(ms, "method", label->valuestring);
      const cJSON *in = find(ms, "method", "input (mean of 4");
      const cJSON *s16 = find(ms, "method", "stochastic transparency 16 spp");
      const cJSON *own = n ? at(n, "own_input") : NULL;
      CHECK(n && in && s16 && own, "%s: no %s, input, st16 or own input score", file,
            label->valuestring);
      if (!n || !in || !s16 || !own) continue;
      if (strstr(label->valuestring, "Small"))
        CHECK(num(own, "ssim") == num(in, "ssim") && num(own, "mse") == num(in, "mse"),
              "%s: Small's own input is not the input row", file);
      else if (num(in, "mse") > 0)   /* b: every sample is the truth */
        CHECK(num(own, "mse") != num(in, "mse"), "%s: Base@1spp's own input is the 4-sample row",
              file);
      const cJSON *ref[2] = {own, s16};
      const char *key[2] = {"below_own_input", "below_st16"};
      for (int k = 0; k < 2; k++) {
        /* psnr null: infinite (no error) */
        double np = cJSON_IsNull(at(n, "psnr")) ? INFINITY : num(n, "psnr");
        double rp = cJSON_IsNull(at(ref[k], "psnr")) ? INFINITY : num(ref[k], "psnr");
        int p = np < rp, sl = num(n, "ssim") < num(ref[k], "ssim");
        compared[k]++;
        below[k][0] += p;
        below[k][1] += sl;
        below[k][2] += p || sl;
        CHECK(cJSON_IsBool(at(n, key[k])) && cJSON_IsTrue(at(n, key[k])) == (p || sl),
              "%s: %s of %s not %d", file, key[k], label->valuestring, p || sl);
        if (k == 0 && (p || sl)) {
          const cJSON *f, *files = at(at(m, "below_own_input"), "files");
          int found = 0;
          cJSON_ArrayForEach(f, files) found |= !strcmp(f->valuestring, file);
          CHECK(found, "%s below the own input of %s but not listed", file, label->valuestring);
          listed++;
        }
      }
    }
    for (int k = 0; k < 2; k++) {
      const cJSON *o = at(m, k ? "below_st16" : "below_own_input");
      CHECK(num(o, "frames") == compared[k] && num(o, "psnr") == below[k][0] &&
                num(o, "ssim") == below[k][1] && num(o, "either") == below[k][2],
            "%s %s: %g %g %g %g, from the rows %d %d %d %d", label->valuestring,
            k ? "below_st16" : "below_own_input", num(o, "frames"), num(o, "psnr"),
            num(o, "ssim"), num(o, "either"), compared[k], below[k][0], below[k][1],
            below[k][2]);
    }
    CHECK(compared[0] == 3, "%s: %d frames compared", label->valuestring, compared[0]);
    CHECK(cJSON_GetArraySize(at(at(m, "below_own_input"), "files")) == listed,
          "%s: files listed %d, below %d", label->valuestring,
          cJSON_GetArraySize(at(at(m, "below_own_input"), "files")), listed);
  }
  CHECK(networks == 2, "%d networks", networks);
  CHECK(check_lattice(methods, rows) == 0, "a lattice measured on frames too small for it");
  cJSON_Delete(doc);
  if (!failures) printf("check_eval_json: all checks passed\n");
  return failures ? 1 : 0;
}
