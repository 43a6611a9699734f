/* The hairfilter CLI on files from other tools and out-of-contract input,
 * as a user runs it: hairfilter infer on the field cases (tests/data/field)
 * and on generated files of the same kinds, hairfilter eval on a frame
 * with a NaN sample. Checks the exit status, the one-line messages and what
 * the result EXR holds. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <errno.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <cmocka.h>
#include <png.h>

#include "exr_parts.h"
#include "test_paths.h"
#include "hfcore.h"

static char text[16384];  /* what the last command printed */

/* Runs the CLI with args (a shell fragment); returns its exit status and
 * leaves stdout and stderr in text. */
static int cli(const char *fmt, ...) {
  char args[3000], cmd[4000];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(args, sizeof args, fmt, ap);
  va_end(ap);
  snprintf(cmd, sizeof cmd, "'%s' %s > '%s' 2>&1", HAIRFILTER_CLI_PATH, args, test_tmp("out.txt"));
  int rc = system(cmd);
  FILE *f = fopen(test_tmp("out.txt"), "r");
  size_t n = f ? fread(text, 1, sizeof text - 1, f) : 0;
  if (f) fclose(f);
  text[n] = 0;
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

#define BASE HF_SOURCE_DIR "/weights/base.safetensors"

static void expect_text(const char *needle) {
  if (!strstr(text, needle)) fail_msg("output lacks '%s':\n%s", needle, text);
}

static void read_result(const char *path, hf_image *img) {
  char err[512];
  assert_int_equal(hf_exr_read(path, img, err, sizeof err), HF_OK);
  assert_int_equal(img->channels, 3);
  for (size_t i = 0; i < (size_t)img->width * img->height * 3; i++)
    assert_true(isfinite(img->data[i]));
}

static void test_inf_sample(void **state) {
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("features-one-inf-sample.exr"), test_tmp("inf.exr")), 0);
  expect_text("warning: ");
  expect_text("features-one-inf-sample.exr: 1 sample sanitised");
  expect_text("the first at pixel (40, 40): S1.highlight = inf is not finite");
  hf_image img;
  read_result(test_tmp("inf.exr"), &img);
  hf_image_free(&img);
  /* A clean frame: nothing sanitised (a 64x64 frame is still outside the
   * resolutions Base was trained on, which is another warning). */
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("frame-64x64.exr"), test_tmp("clean.exr")), 0);
  assert_null(strstr(text, "sanitised"));
  assert_null(strstr(text, "lossy"));
  /* Features compressed with B44: filtered, with a warning naming it. */
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_data("exr-b44-half.exr"), test_tmp("b44.exr")), 0);
  expect_text("exr-b44-half.exr is compressed with B44, which is lossy");
  expect_text("--compression zip");
}

/* A negative alpha in a sample otherwise all zero: rule 2 makes it
 * uncovered (protocol/FEATURES.md), and the warning says why in those
 * terms, not that other features are non-zero. */
static void test_negative_alpha_sample(void **state) {
  hf_image f;
  char err[512];
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &f, err, sizeof err), HF_OK);
  int alpha = hf_image_channel(&f, "S1.alpha"), found = -1;
  assert_true(alpha >= 0);
  /* The first pixel whose sample 1 is all zero. */
  for (int p = 0; p < f.width * f.height && found < 0; p++) {
    int zero = 1;
    for (int c = 0; c < f.channels; c++)
      if (!strncmp(f.names[c], "S1.", 3) && f.data[(size_t)p * f.channels + c] != 0.0f) zero = 0;
    if (zero) found = p;
  }
  assert_true(found >= 0);
  f.data[(size_t)found * f.channels + alpha] = -0.5f;
  assert_int_equal(hf_exr_write(test_tmp("negalpha.exr"), &f, 0), HF_OK);
  char want[160];
  snprintf(want, sizeof want, "the first at pixel (%d, %d): S1.alpha = -0.5 is not above 0 in a "
           "sample that is not all zero: the sample counts as uncovered", found % f.width,
           found / f.width);
  hf_image_free(&f);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("negalpha.exr"), test_tmp("negalpha_out.exr")), 0);
  expect_text("negalpha.exr: 1 sample sanitised");
  expect_text(want);
  hf_image img;
  read_result(test_tmp("negalpha_out.exr"), &img);
  hf_image_free(&img);
}

/* An estimate out of contract: the warning names its channel and the
 * estimate's own rule (the pixel's estimate becomes 0), not a sample's. */
static void test_estimate_sanitised(void **state) {
  hf_image f, e;
  char err[512];
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &f, err, sizeof err), HF_OK);
  assert_int_equal(hf_image_alloc(&e, f.width, f.height, f.channels + 3), HF_OK);
  for (int c = 0; c < f.channels; c++) memcpy(e.names[c], f.names[c], sizeof e.names[c]);
  static const char *const est[3] = {"acst4.color", "acst4.highlight", "acst4.alpha"};
  for (int c = 0; c < 3; c++) snprintf(e.names[f.channels + c], sizeof e.names[0], "%s", est[c]);
  const int n = f.channels + 3;
  for (int p = 0; p < f.width * f.height; p++) {
    memcpy(e.data + (size_t)p * n, f.data + (size_t)p * f.channels, f.channels * sizeof(float));
    memset(e.data + (size_t)p * n + f.channels, 0, 3 * sizeof(float));
  }
  /* (3, 7): colour without alpha; (10, 5), first in memory: a NaN. */
  e.data[(size_t)(7 * f.width + 3) * n + f.channels] = 0.5f;
  e.data[(size_t)(5 * f.width + 10) * n + f.channels] = NAN;
  assert_int_equal(hf_exr_write(test_tmp("est_nan.exr"), &e, 0), HF_OK);
  hf_image_free(&f);
  hf_image_free(&e);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s/weights/kernel_ac.safetensors "
                       "--in %s --out %s", HF_SOURCE_DIR, test_tmp("est_nan.exr"),
                       test_tmp("est_out.exr")), 0);
  expect_text("est_nan.exr: 2 samples sanitised");
  expect_text("the first at pixel (10, 5): acst4.color = nan is not finite: the pixel's "
              "estimate becomes 0 (no hair)");
  hf_image img;
  read_result(test_tmp("est_out.exr"), &img);
  hf_image_free(&img);
}

static void test_tall_frame(void **state) {
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("exr-1x1024.exr"), test_tmp("tall.exr")), 0);
  hf_image img;
  read_result(test_tmp("tall.exr"), &img);
  assert_int_equal(img.width, 1);
  assert_int_equal(img.height, 1024);
  int a = hf_image_channel(&img, "alpha");
  for (int p = 0; p < 1024; p++) assert_true(img.data[p * 3 + a] >= 0 && img.data[p * 3 + a] <= 1);
  hf_image_free(&img);
}

static void test_crop_windows(void **state) {
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --png %s", BASE,
                       test_field("exr-crop-datawindow.exr"), test_tmp("crop.exr"), test_tmp("crop.png")), 0);
  hf_image img;
  read_result(test_tmp("crop.exr"), &img);
  assert_int_equal(img.width, 64);
  assert_int_equal(img.origin_x, 30);
  assert_int_equal(img.origin_y, 40);
  assert_int_equal(img.display_x, 0);
  assert_int_equal(img.display_y, 0);
  assert_int_equal(img.display_width, 501);
  assert_int_equal(img.display_height, 401);
  hf_image_free(&img);
}

static void test_tiled_and_parts(void **state) {
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("exr-tiled.exr"), test_tmp("tiled.exr")), 0);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("frame-64x64.exr"), test_tmp("plain.exr")), 0);
  hf_image a, b;
  read_result(test_tmp("tiled.exr"), &a);
  read_result(test_tmp("plain.exr"), &b);
  assert_memory_equal(a.data, b.data, 64 * 64 * 3 * sizeof(float));
  hf_image_free(&b);

  /* A two-part file: a beauty part, then the features (tiled, offset);
   * the automatic choice and --part agree with the plain file. */
  hf_image feat;
  char err[512];
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &feat, err, sizeof err), HF_OK);
  const char *names[64];
  for (int c = 0; c < feat.channels; c++) names[c] = feat.names[c];
  static const char *const rgb[] = {"R", "G", "B"};
  part_spec parts[2] = {
    {"beauty", 0, 0, 0, 0, 0, 0, 64, 64, 3, rgb, EXR_COMPRESSION_ZIP, 0.0f, NULL},
    {"features", 1, 16, 16, 0, 100, 200, 64, 64, feat.channels, names, EXR_COMPRESSION_PIZ,
     0.0f, feat.data},
  };
  write_parts(test_tmp("two.exr"), parts, 2);
  static const char *const choose[] = {"", "--part 1", "--part features"};
  for (int k = 0; k < 3; k++) {
    assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s %s", BASE,
                         test_tmp("two.exr"), test_tmp("part.exr"), choose[k]), 0);
    read_result(test_tmp("part.exr"), &b);
    assert_memory_equal(a.data, b.data, 64 * 64 * 3 * sizeof(float));
    assert_int_equal(b.origin_x, 100);
    assert_int_equal(b.origin_y, 200);
    hf_image_free(&b);
  }
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --part beauty",
                       BASE, test_tmp("two.exr"), test_tmp("x.exr")), 1);
  expect_text("no channel S0.color: not a feature file");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --part 2", BASE,
                       test_tmp("two.exr"), test_tmp("x.exr")), 1);
  expect_text("has no part \"2\"; its 2 parts are: 0 \"beauty\" (3 channels), 1 \"features\" "
              "(24 channels, tiled)");
  hf_image_free(&feat);
  hf_image_free(&a);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --part 1", BASE,
                       test_field("frame-64x64.exr"), test_tmp("x.exr")), 1);
  expect_text("has no part \"1\"; its 1 part is: 0");
}

static void test_refusals(void **state) {
  /* A missing option is named before the usage, with the weights to give. */
  assert_int_equal(cli("infer --in %s --out %s", test_field("frame-64x64.exr"), test_tmp("x.exr")),
                   2);
  expect_text("hairfilter infer: give --weights FILE (");
  expect_text("weights/kernel_mix.safetensors");
  assert_int_equal(cli("infer --weights %s --in %s --out %s stray", BASE,
                       test_field("frame-64x64.exr"), test_tmp("x.exr")), 2);
  expect_text("unexpected argument 'stray'");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("exr-dwaa.exr"), test_tmp("x.exr")), 1);
  expect_text("exr-dwaa.exr: DWAA compression cannot be decoded");
  expect_text("oiiotool");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("exr-truncated.exr"), test_tmp("x.exr")), 1);
  expect_text("exr-truncated.exr: truncated / incomplete file");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s",
                       test_field("weights-duplicate-metadata.safetensors"), test_field("frame-64x64.exr"),
                       test_tmp("x.exr")), 1);
  expect_text("duplicate key '__metadata__'");
  /* Features under a layer (as compositing tools write them) are said to
   * be, with the layer's name. */
  static const char *const layered[] = {"beauty.S0.color", "beauty.S0.highlight",
                                         "beauty.S0.alpha", "beauty.S0.depth",
                                         "beauty.S0.tangent.x", "beauty.S0.tangent.y"};
  part_spec lp = {"main", 0, 0, 0, 0, 0, 0, 8, 8, 6, layered, EXR_COMPRESSION_ZIP, 0.0f, NULL};
  write_parts(test_tmp("layered.exr"), &lp, 1);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("layered.exr"), test_tmp("x.exr")), 1);
  expect_text("layered.exr: no channel S0.color, but beauty.S0.color: the features are under "
              "layer \"beauty\"");
  /* A result file is not a feature file. */
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("plain.exr"), test_tmp("x.exr")), 1);
  expect_text("no channel S0.color: not a feature file");
  /* A feature stored as UINT is refused, naming it; a UINT channel outside
   * the contract (an object id) is left alone. */
  hf_image feat;
  char err[512];
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &feat, err, sizeof err), HF_OK);
  const char *names[64];
  for (int c = 0; c < feat.channels; c++) names[c] = feat.names[c];
  part_spec up = {"f", 0, 0, 0, 0, 0, 0, 64, 64, feat.channels, names, EXR_COMPRESSION_ZIP,
                  0.0f, feat.data};
  write_parts_uint(test_tmp("uint.exr"), &up, 1, "S2.alpha");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("uint.exr"), test_tmp("x.exr")), 1);
  expect_text("uint.exr: channel S2.alpha is stored as UINT");
  expect_text("write them as float");
  hf_image id;
  assert_int_equal(hf_image_alloc(&id, 64, 64, feat.channels + 1), HF_OK);
  for (int c = 0; c < feat.channels; c++) names[c] = feat.names[c];
  names[feat.channels] = "id";
  for (size_t p = 0; p < 64 * 64; p++) {
    memcpy(id.data + p * (size_t)id.channels, feat.data + p * (size_t)feat.channels,
           (size_t)feat.channels * sizeof(float));
    id.data[p * (size_t)id.channels + (size_t)feat.channels] = (float)(p % 7);
  }
  part_spec ip = {"f", 0, 0, 0, 0, 0, 0, 64, 64, id.channels, names, EXR_COMPRESSION_ZIP, 0.0f,
                  id.data};
  write_parts_uint(test_tmp("uint_id.exr"), &ip, 1, "id");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("uint_id.exr"), test_tmp("x.exr")), 0);
  assert_null(strstr(text, "UINT"));
  hf_image_free(&id);
  hf_image_free(&feat);
}

/* An output in a directory that does not exist is refused before any
 * work, naming the directory and the command that makes it; nothing is
 * written. */
static void test_output_directory(void **state) {
  (void)state;
  char missing[1024];
  snprintf(missing, sizeof missing, "%s", test_tmp("no-such-dir/x.exr"));
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("frame-64x64.exr"), missing), 1);
  expect_text("no-such-dir/x.exr: the directory ");
  expect_text("does not exist; create it first (mkdir -p ");
  assert_null(strstr(text, "Base 64x64"));   /* refused before inference */
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --png %s", BASE,
                       test_field("frame-64x64.exr"), test_tmp("x.exr"),
                       test_tmp("no-such-dir/p.png")), 1);
  expect_text("no-such-dir/p.png: the directory ");
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s/", BASE,
                       test_field("frame-64x64.exr"), test_tmp("")), 1);
  expect_text("names a directory; give a file name");
  char under_file[1100];   /* a "directory" that is a file */
  snprintf(under_file, sizeof under_file, "%s/x.exr", test_field("frame-64x64.exr"));
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_field("frame-64x64.exr"), under_file), 1);
  expect_text("frame-64x64.exr is a file, not a directory");
#ifdef HF_TEST_EVAL
  assert_int_equal(cli("eval --json %s %s", test_tmp("no-such-dir/e.json"),
                       test_field("frame-64x64.exr")), 1);
  expect_text("no-such-dir/e.json: the directory ");
  assert_int_equal(cli("eval --grid %s %s", test_tmp("no-such-dir/g.png"),
                       test_field("frame-64x64.exr")), 1);
  expect_text("no-such-dir/g.png: the directory ");
#endif
#ifdef HF_TEST_RENDERER
  assert_int_equal(cli("render frame --style straight --strands 50 --size 16x16 --out %s",
                       test_tmp("no-such-dir/r.exr")), 1);
  expect_text("no-such-dir/r.exr: the directory ");
  assert_null(strstr(text, "regime:"));   /* refused before rendering */
  assert_int_equal(cli("render dataset --styles straight --count 1 --size 16x16 --out %s/",
                       test_tmp("no-such-dir/set")), 1);
  expect_text("render dataset: ");
  expect_text("no-such-dir/set: the directory ");
  assert_int_equal(cli("demo --size 16x16 --out %s", test_tmp("no-such-dir/d.png")), 1);
  expect_text("hairfilter demo: ");
  expect_text("no-such-dir/d.png: the directory ");
  assert_null(strstr(text, "PSNR"));   /* refused before rendering and filtering */
#endif
}

/* A file with fewer samples than the variant reads, and one with a feature
 * channel missing: the message names the channel. */
static void test_missing_samples(void **state) {
  float in[4 * 4 * 12] = {0};
  hf_image img;
  assert_int_equal(hf_features_to_image(in, 4, 4, 2, &img), HF_OK);
  assert_int_equal(hf_exr_write(test_tmp("two.exr"), &img, 0), HF_OK);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("two.exr"), test_tmp("x.exr")), 1);
  expect_text("has 2 samples per pixel (S0.color..S1.color), variant Base needs 4: render the "
              "frame with --spp 4 (or more), or filter it with Base@2spp");
  hf_image_free(&img);
  float in4[4 * 4 * 24] = {0};
  assert_int_equal(hf_features_to_image(in4, 4, 4, 4, &img), HF_OK);
  strcpy(img.names[3 * 6 + 3], "S3.dpeth");
  assert_int_equal(hf_exr_write(test_tmp("typo.exr"), &img, 0), HF_OK);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("typo.exr"), test_tmp("x.exr")), 1);
  expect_text("no channel S3.depth: sample 3 lacks its depth feature");
  /* Sample 1's colour missing, its other features there: said as such,
   * not as a frame of one sample. */
  strcpy(img.names[3 * 6 + 3], "S3.depth");
  strcpy(img.names[1 * 6 + 0], "S1.colour");
  assert_int_equal(hf_exr_write(test_tmp("nocolor.exr"), &img, 0), HF_OK);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s", BASE,
                       test_tmp("nocolor.exr"), test_tmp("x.exr")), 1);
  expect_text("no channel S1.color, though it has S1.");
  expect_text("sample 1 lacks its color feature");
  hf_image_free(&img);
#ifdef HF_TEST_RENDERER
  /* eval skips such a frame for that network, and says what would score it. */
  assert_int_equal(cli("render frame --style wavy --strands 200 --size 16x16 --spp 2 --gt-ss 2 "
                       "--quiet --out %s", test_tmp("two_gt.exr")), 0);
  assert_int_equal(cli("eval --backend cpu-ref --weights %s %s", BASE, test_tmp("two_gt.exr")),
                   1);   /* the network scored no frame */
  expect_text("has 2 spp, ours Base (base.safetensors) needs 4: skipped for it (render the "
              "frames with --spp 4 or more to score it there)");
#endif
}

/* hairfilter eval on a frame with a NaN sample: one warning for the frame,
 * whichever methods see it, and finite scores. */
static void test_eval_warning(void **state) {
#ifndef HF_TEST_EVAL
  skip();  /* built without the renderer: no eval command */
#endif
  hf_image feat, frame;
  char err[512];
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &feat, err, sizeof err), HF_OK);
  assert_int_equal(hf_image_alloc(&frame, 64, 64, feat.channels + 3), HF_OK);
  for (int c = 0; c < feat.channels; c++) strcpy(frame.names[c], feat.names[c]);
  strcpy(frame.names[feat.channels], "gt.color");
  strcpy(frame.names[feat.channels + 1], "gt.highlight");
  strcpy(frame.names[feat.channels + 2], "gt.alpha");
  float *in = malloc(64 * 64 * 24 * sizeof(float));
  assert_int_equal(hf_features_from_image(&feat, 4, in), 4);
  for (int p = 0; p < 64 * 64; p++) {
    memcpy(frame.data + (size_t)p * frame.channels, feat.data + (size_t)p * feat.channels,
           feat.channels * sizeof(float));
    hf_st_estimate(in + p * 24, 4, frame.data + (size_t)p * frame.channels + feat.channels);
  }
  int ch = hf_image_channel(&frame, "S2.depth");
  frame.data[((size_t)9 * 64 + 33) * frame.channels + ch] = NAN;
  assert_int_equal(hf_exr_write(test_tmp("evalnan.exr"), &frame, 0), HF_OK);
  assert_int_equal(cli("eval --backend cpu-ref --weights %s %s", BASE, test_tmp("evalnan.exr")), 0);
  expect_text("evalnan.exr: 1 sample sanitised");
  expect_text("the first at pixel (33, 9): S2.depth = nan is not finite");
  /* One sanitising warning, whichever methods see the frame. */
  int warnings = 0;
  for (const char *t = text; (t = strstr(t, "sanitised")) != NULL; t++) warnings++;
  assert_int_equal(warnings, 1);
  assert_null(strstr(text, "| nan"));
  expect_text("| ours Base");

  /* A stored baseline (acst4.*) with a non-finite value is left out for
   * the frame, said with its pixel, and no score is NaN or Inf. */
  hf_image more;
  assert_int_equal(hf_image_alloc(&more, 64, 64, frame.channels + 3), HF_OK);
  for (int c = 0; c < frame.channels; c++) strcpy(more.names[c], frame.names[c]);
  for (int c = 0; c < 3; c++)
    snprintf(more.names[frame.channels + c], 32, "acst4.%s", HF_OUTPUT_NAMES[c]);
  for (int p = 0; p < 64 * 64; p++) {
    memcpy(more.data + (size_t)p * more.channels, frame.data + (size_t)p * frame.channels,
           frame.channels * sizeof(float));
    memcpy(more.data + (size_t)p * more.channels + frame.channels,
           frame.data + (size_t)p * frame.channels + feat.channels, 3 * sizeof(float));
  }
  more.data[((size_t)20 * 64 + 40) * more.channels + hf_image_channel(&more, "acst4.color")] =
      INFINITY;
  assert_int_equal(hf_exr_write(test_tmp("evalbase.exr"), &more, 0), HF_OK);
  assert_int_equal(cli("eval --backend cpu-ref --weights %s %s", BASE, test_tmp("evalbase.exr")),
                   0);
  expect_text("evalbase.exr: acst4.color = inf at pixel (40, 20) is not finite");
  /* (The input's own rows may score inf dB: this frame's truth is its
   * input's estimate.) */
  assert_null(strstr(text, "| nan"));
  assert_null(strstr(text, " nan |"));
  for (const char *r = text; (r = strstr(r, "| stochastic transparency 4 spp, alpha")); r++) {
    const char *end = strchr(r, '\n');
    const char *inf = strstr(r, "inf");
    if (inf && (!end || inf < end)) fail_msg("a damaged baseline scored: %.120s", r);
  }

  /* A ground truth with a non-finite value cannot score the frame:
   * refused, naming the value and its pixel. */
  more.data[((size_t)20 * 64 + 40) * more.channels + hf_image_channel(&more, "acst4.color")] = 0;
  more.data[((size_t)7 * 64 + 12) * more.channels + hf_image_channel(&more, "gt.highlight")] =
      NAN;
  assert_int_equal(hf_exr_write(test_tmp("evalgt.exr"), &more, 0), HF_OK);
  assert_int_equal(cli("eval --backend cpu-ref --weights %s %s", BASE, test_tmp("evalgt.exr")),
                   1);
  expect_text("evalgt.exr: its ground truth gt.highlight = nan at pixel (12, 7) is not finite");
  hf_image_free(&more);
  free(in);
  hf_image_free(&frame);
  hf_image_free(&feat);
}

/* Paths that hold no frames to score are named for what they are: a
 * directory without .exr files (a run directory, a mistyped set), and
 * --styles that match none of the frames given (with the styles they
 * have), not "no frames with hair". */
static void test_eval_no_frames(void **state) {
  (void)state;
#ifndef HF_TEST_EVAL
  skip();  /* built without the renderer: no eval command */
#endif
  mkdir(test_tmp("evalempty"), 0755);
  assert_int_equal(cli("eval --backend cpu-ref --weights %s %s", BASE, test_tmp("evalempty")), 1);
  expect_text("evalempty: no .exr frames in it (give a directory that `hairfilter render "
              "dataset` wrote, or FRAME.exr files)");
  assert_null(strstr(text, "no frames with hair"));
  /* The parent of sets: the sets named, to give instead. */
  char sub[1200];
  mkdir(test_tmp("evalsets"), 0755);
  const char *names[] = {"b", "a", "c", "e", "d"};
  for (int i = 0; i < 5; i++) {
    snprintf(sub, sizeof sub, "%s/%s", test_tmp("evalsets"), names[i]);
    mkdir(sub, 0755);
    strcat(sub, "/manifest.json");
    FILE *f = fopen(sub, "w");
    assert_non_null(f);
    assert_true(fputs("{\"frames\": []}", f) >= 0);
    assert_int_equal(fclose(f), 0);
  }
  assert_int_equal(cli("eval --backend cpu-ref --weights %s %s/", BASE, test_tmp("evalsets")), 1);
  snprintf(sub, sizeof sub, "evalsets/: no .exr frames of its own; it holds 5 set(s) "
           "(directories with a manifest.json): give them (%s/a %s/b %s/c %s/d ...)",
           test_tmp("evalsets"), test_tmp("evalsets"), test_tmp("evalsets"),
           test_tmp("evalsets"));
  expect_text(sub);
  assert_int_equal(cli("eval --backend cpu-ref --styles curly,coily %s",
                       test_field("frame-64x64.exr")), 1);
  expect_text("no frame of styles curly,coily among the 1 frames given (their styles: "
              "frame-64x64); name some of those with --styles");
  /* As train.py takes --styles: spaces around a name dropped, in any case
   * (MyBob.hair's frames are style mybob). The frame is then chosen, and
   * refused for what it lacks. */
  assert_int_equal(cli("eval --backend cpu-ref --weights %s --styles 'coily, Frame-64x64' %s",
                       BASE, test_field("frame-64x64.exr")), 1);
  assert_null(strstr(text, "no frame of styles"));
  expect_text("frame-64x64.exr: no gt.color/gt.highlight/gt.alpha");
  /* A backend that does not exist is a bad option, --weights or not. */
  assert_int_equal(cli("eval --backend foo %s", test_field("frame-64x64.exr")), 2);
  expect_text("hairfilter eval: --backend wants auto, cudnn, cpu or cpu-ref, not 'foo'");
}

/* An 8-bit RGB PNG read back (libpng's simplified API), [h][w][3]. */
static unsigned char *read_png(const char *path, int *w, int *h) {
  png_image im;
  memset(&im, 0, sizeof im);
  im.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&im, path)) fail_msg("%s: %s", path, im.message);
  im.format = PNG_FORMAT_RGB;
  unsigned char *px = malloc(PNG_IMAGE_SIZE(im));
  assert_non_null(px);
  if (!png_image_finish_read(&im, NULL, px, 0, NULL)) fail_msg("%s: %s", path, im.message);
  *w = (int)im.width;
  *h = (int)im.height;
  return px;
}

/* render frame --png PREFIX writes PREFIX_input.png, the estimate of the
 * frame's own samples: the 4-sample stochastic-transparency baseline of the
 * same pass, to the byte. */
static void test_render_input_preview(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  char prefix[1024];
  snprintf(prefix, sizeof prefix, "%s", test_tmp("prev"));
  assert_int_equal(cli("render frame --style wavy --strands 1500 --size 48x40 --spp 4 --st 4 "
                       "--gt-ss 0 --out %s --png %s", test_tmp("prev.exr"), prefix), 0);
  int w, h, w2, h2;
  char a[1100], b[1100];
  snprintf(a, sizeof a, "%s_input.png", prefix);
  snprintf(b, sizeof b, "%s_st4.png", prefix);
  unsigned char *in = read_png(a, &w, &h);
  unsigned char *st = read_png(b, &w2, &h2);
  assert_true(w == 48 && h == 40 && w2 == w && h2 == h);
  assert_memory_equal(in, st, (size_t)w * h * 3);
  int varied = 0;   /* hair over the background, not a flat image */
  for (int p = 1; p < w * h; p++) varied |= memcmp(in + 3 * p, in, 3) != 0;
  assert_true(varied);
  free(in);
  free(st);
#endif
}

/* render frame --crop writes the window where it lies in the whole frame
 * (data window inside the frame's display window), and infer keeps both. */
static void test_render_crop_windows(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  assert_int_equal(cli("render frame --style wavy --strands 1500 --size 64x48 --crop 8,4,24,20 "
                       "--gt-ss 0 --out %s --quiet", test_tmp("crop.exr")), 0);
  hf_image img;
  char err[512];
  assert_int_equal(hf_exr_read(test_tmp("crop.exr"), &img, err, sizeof err), HF_OK);
  assert_true(img.width == 24 && img.height == 20 && img.origin_x == 8 && img.origin_y == 4);
  assert_true(img.display_x == 0 && img.display_y == 0 && img.display_width == 64 &&
              img.display_height == 48);
  hf_image_free(&img);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s/weights/kernel_ac.safetensors --in %s "
                       "--out %s", HF_SOURCE_DIR, test_tmp("crop.exr"), test_tmp("crop_out.exr")),
                   0);
  read_result(test_tmp("crop_out.exr"), &img);
  assert_true(img.origin_x == 8 && img.origin_y == 4 && img.display_width == 64 &&
              img.display_height == 48);
  hf_image_free(&img);
#endif
}

/* The bytes of a file (at most 64 MB), NUL-terminated; *n its length. */
static char *slurp(const char *path, size_t *n) {
  FILE *f = fopen(path, "rb");
  if (!f) fail_msg("cannot open %s", path);
  char *b = malloc(64u << 20);
  assert_non_null(b);
  *n = fread(b, 1, (64u << 20) - 1, f);
  b[*n] = 0;
  fclose(f);
  return b;
}

static void write_text(const char *path, const char *t) {
  FILE *f = fopen(path, "w");
  assert_non_null(f);
  assert_int_equal(fputs(t, f) >= 0, 1);
  assert_int_equal(fclose(f), 0);
}

/* render says when the ground truth's sub-pixel centres include the MSAA
 * sample positions (--gt-ss 4 here), and not at the default. */
static void test_render_gt_grid_note(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  const char *note = "MSAA sample positions are sub-pixel centres of this ground truth";
  assert_int_equal(cli("render frame --style wavy --strands 500 --size 24x24 --gt-ss 4 "
                       "--no-alpha-corrected --out %s", test_tmp("grid4.exr")), 0);
  expect_text("4 of the 4 ");
  expect_text(note);
  assert_int_equal(cli("render frame --style wavy --strands 500 --size 24x24 "
                       "--no-alpha-corrected --out %s", test_tmp("grid8.exr")), 0);
  if (strstr(text, note)) fail_msg("a note at the default ground truth:\n%s", text);

  /* eval warns of such frames by their manifest, and of no others. */
  const char *warn = "frames have a ground truth whose sub-pixel centres include the MSAA";
  const char *sizes[2] = {"--gt-ss 4", ""};
  for (int i = 0; i < 2; i++) {
    char dir[1100];
    snprintf(dir, sizeof dir, "%s", test_tmp(i ? "grid_ds8" : "grid_ds4"));
    assert_int_equal(mkdir(dir, 0755) == 0 || errno == EEXIST, 1);
    assert_int_equal(cli("render dataset --styles wavy --count 1 --size 24x24 --strands 500 "
                         "--spp 4 %s --quiet --out %s", sizes[i], dir), 0);
    /* --quiet leaves out the progress, not the note. */
    if (!i) expect_text(note);
    else if (strstr(text, note)) fail_msg("a note at the default ground truth:\n%s", text);
    assert_int_equal(cli("eval %s", dir), 0);
    if (!i) expect_text("1 of 1 frames have a ground truth whose sub-pixel centres");
    else if (strstr(text, warn)) fail_msg("eval warned of an 8x8 truth:\n%s", text);
    /* A frame named alone is taken with what its directory's manifest says. */
    assert_int_equal(cli("eval %s/wavy_0000.exr", dir), 0);
    if (!i) expect_text("1 of 1 frames have a ground truth whose sub-pixel centres");
    else if (strstr(text, warn)) fail_msg("eval warned of an 8x8 truth:\n%s", text);
  }
  /* A frame without its manifest: its EXR header says what its truth is. */
  char lone[1100];
  snprintf(lone, sizeof lone, "%s", test_tmp("grid_lone"));
  assert_int_equal(mkdir(lone, 0755) == 0 || errno == EEXIST, 1);
  for (int i = 0; i < 2; i++) {
    assert_int_equal(cli("render frame --style wavy --strands 500 --size 24x24 %s --quiet "
                         "--no-alpha-corrected --out %s/f.exr", sizes[i], lone), 0);
    if (!i) expect_text(note);  /* --quiet leaves out the statistics, not the note */
    assert_int_equal(cli("eval --json %s %s", test_tmp("grid_lone.json"), lone), 0);
    if (!i) expect_text("1 of 1 frames have a ground truth whose sub-pixel centres");
    else if (strstr(text, warn)) fail_msg("eval warned of an 8x8 truth:\n%s", text);
    /* --json gives it per frame. */
    size_t n;
    char *j = slurp(test_tmp("grid_lone.json"), &n);
    const char *k = strstr(j, "\"gt_shared_positions\"");
    if (!k) fail_msg("eval --json lacks gt_shared_positions");
    k += strlen("\"gt_shared_positions\"");
    while (*k == ':' || *k == ' ' || *k == '\t') k++;
    assert_int_equal(atoi(k), i ? 0 : 4);
    free(j);
  }
  assert_int_equal(cli("render frame --gt-ss 9 --out %s", test_tmp("grid9.exr")), 2);
  expect_text("--gt-ss takes 0..8");
#endif
}

/* render dataset --resume takes up a stopped run: the frames its manifest
 * lists are kept as they are (not rendered again), a file it does not list
 * (the frame in flight when it stopped) is rendered again, --count may
 * grow, and the result is the run made in one go, frame for frame. Other
 * options, or a manifest without their record, are refused by name. */
static void test_render_dataset_resume(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  const char *opt = "--styles straight,wavy --size 16x16 --strands 300 --spp 4 --st 4 --seed 7 "
                    "--quiet";
  char whole[1100], part[1100], p1[1200], p2[1200];
  snprintf(whole, sizeof whole, "%s", test_tmp("resume_whole"));
  snprintf(part, sizeof part, "%s", test_tmp("resume_part"));
  assert_int_equal(cli("render dataset %s --count 2 --out %s", opt, whole), 0);
  assert_int_equal(cli("render dataset %s --count 1 --out %s", opt, part), 0);
  /* A listed frame whose bytes say whether it was rendered again (another
   * frame's, a whole EXR: kept as it is), a listed frame cut short (it was
   * kept, to be refused by train.py and eval later: rendered again), and
   * the half-written frame of a stopped run. */
  size_t nk;
  snprintf(p1, sizeof p1, "%s/straight_0000.exr", whole);
  char *other = slurp(p1, &nk);
  snprintf(p2, sizeof p2, "%s/wavy_0000.exr", part);
  FILE *f = fopen(p2, "wb");
  assert_non_null(f);
  assert_int_equal(fwrite(other, 1, nk, f), nk);
  assert_int_equal(fclose(f), 0);
  snprintf(p2, sizeof p2, "%s/straight_0000.exr", part);
  assert_int_equal(truncate(p2, (off_t)(nk / 2)), 0);
  snprintf(p2, sizeof p2, "%s/straight_0001.exr", part);
  write_text(p2, "half written");
  assert_int_equal(cli("render dataset %s --count 2 --resume --out %s", opt, part), 0);
  expect_text("/straight_0000.exr is listed but does not read whole (");
  const char *files[4] = {"straight_0000.exr", "wavy_0000.exr", "straight_0001.exr",
                          "wavy_0001.exr"};
  for (int k = 0; k < 4; k++) {
    size_t na, nb;
    snprintf(p1, sizeof p1, "%s/%s", whole, files[k]);
    snprintf(p2, sizeof p2, "%s/%s", part, files[k]);
    char *a = slurp(p1, &na), *b = slurp(p2, &nb);
    if (k == 1) {
      if (nb != nk || memcmp(b, other, nk)) fail_msg("%s, whole, was not kept as it was", p2);
    } else if (na != nb || memcmp(a, b, na)) {
      fail_msg("%s differs from the run in one go", p2);
    }
    free(a);
    free(b);
  }
  free(other);
  /* The manifest lists the 4 frames in the order of the run in one go. */
  size_t n;
  snprintf(p1, sizeof p1, "%s/manifest.json", part);
  char *m = slurp(p1, &n);
  const char *at = m;
  for (int k = 0; k < 4; k++) {
    char key[64];
    snprintf(key, sizeof key, "\"%s\"", files[k]);
    const char *hit = strstr(at, key);
    if (!hit) fail_msg("manifest lacks %s after the one before:\n%s", files[k], m);
    at = hit + 1;
  }
  free(m);

  assert_int_equal(cli("render dataset %s --count 2 --seed 8 --resume --out %s", opt, part), 1);
  expect_text("--seed (\"seed\") is \"7\" there, \"8\" here");
  assert_int_equal(cli("render dataset %s --count 2 --gt-ss 4 --resume --out %s", opt, part), 1);
  expect_text("--gt-ss (\"gt_supersample\") is 8 there, 4 here");
  /* Whole numbers as they were typed, not as %g's shortest form (2e+01). */
  assert_int_equal(cli("render dataset %s --count 2 --size 20x16 --resume --out %s", opt, part),
                   1);
  expect_text("--size (\"width\") is 16 there, 20 here");
  assert_int_equal(cli("render dataset %s --count 2 --strands 1000 --resume --out %s", opt,
                       part), 1);
  expect_text("--strands (\"strands\") is 300 there, 1000 here");
  /* A float option is named as given, not as its float widened to double
   * (0.699999988...). */
  assert_int_equal(cli("render dataset %s --count 2 --width-spread 0.7 --resume --out %s", opt,
                       part), 1);
  expect_text("--width-spread (\"width_spread\") is 0 there, 0.7 here");
  /* A smaller count would leave listed frames on disk outside the set. */
  assert_int_equal(cli("render dataset %s --count 1 --resume --out %s", opt, part), 1);
  expect_text("lists straight_0001.exr, beyond --count 1: resume with --count 2 or more");
  write_text(p1, "{\"format\": \"hairfilter-dataset\", \"frames\": []}");
  assert_int_equal(cli("render dataset %s --count 2 --resume --out %s", opt, part), 1);
  expect_text("no record of the options");
  write_text(p1, "{\"frames\"");
  assert_int_equal(cli("render dataset %s --count 2 --resume --out %s", opt, part), 1);
  expect_text("is not a hairfilter dataset manifest");
  /* The set's command run again without --resume starts over: said, with
   * how many frames it renders over and how to keep them. */
  assert_int_equal(cli("render dataset %s --count 1 --out %s", opt, whole), 0);
  expect_text("/manifest.json lists 4 frames of an earlier run: this run starts the set again "
              "and renders over them; to keep them, stop it and run the set's command with "
              "--resume");
#endif
}

/* An occluder mesh is the file, not the spelling of its path, as the .hair
 * files are: a set made with DIR/./head.obj resumes with DIR/head.obj (or
 * from another directory), and a manifest that kept the path as it was
 * typed still resumes with its own command. */
static void test_render_dataset_resume_occluder(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  char dir[1100], hair[1200], obj[1200], dotted[1200], set[1200], man[1300];
  snprintf(dir, sizeof dir, "%s", test_tmp("resume_occ"));
  mkdir(dir, 0755);
  snprintf(hair, sizeof hair, "%s/bob.hair", dir);
  snprintf(obj, sizeof obj, "%s/head.obj", dir);
  snprintf(dotted, sizeof dotted, "%s/./head.obj", dir);
  snprintf(set, sizeof set, "%s/set", dir);
  snprintf(man, sizeof man, "%s/manifest.json", set);
  assert_int_equal(cli("render hair --style straight --strands 40 --hair-seed 3 --out %s", hair),
                   0);
  write_text(obj, "v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv 0 0.5 -0.5\nv 0 0 0.5\n"
                  "f 1 2 3\nf 1 2 4\nf 2 3 4\nf 3 1 4\n");
  const char *opt = "--size 16x16 --spp 4 --seed 5 --quiet";
  assert_int_equal(cli("render dataset --hair-files %s --occluder %s --count 1 %s --out %s", hair,
                       dotted, opt, set), 0);
  size_t n;
  char *m = slurp(man, &n), *real = realpath(obj, NULL);
  assert_non_null(real);
  char want[1300];
  snprintf(want, sizeof want, "\"occluder\":\t\"%s\"", real);
  free(real);
  if (!strstr(m, want)) fail_msg("the options record lacks %s:\n%s", want, m);
  free(m);
  assert_int_equal(cli("render dataset --hair-files %s --occluder %s --count 2 --resume %s --out %s",
                       hair, obj, opt, set), 0);
  /* A manifest of before, with the path as it was typed. */
  m = slurp(man, &n);
  char *at = strstr(m, want);
  assert_non_null(at);
  char *old = malloc(n + 64);
  assert_non_null(old);
  snprintf(old, n + 64, "%.*s\"occluder\":\t\"%s\"%s", (int)(at - m), m, dotted,
           at + strlen(want));
  write_text(man, old);
  free(old);
  free(m);
  assert_int_equal(cli("render dataset --hair-files %s --occluder %s --count 3 --resume %s --out %s",
                       hair, dotted, opt, set), 0);
  /* Another mesh is still another option. */
  snprintf(dotted, sizeof dotted, "%s/other.obj", dir);
  write_text(dotted, "v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv 0 0.5 -0.5\nf 1 2 3\n");
  assert_int_equal(cli("render dataset --hair-files %s --occluder %s --count 3 --resume %s --out %s",
                       hair, dotted, opt, set), 1);
  expect_text("--occluder (\"asset.occluder\") is");
#endif
}

/* Frames are named after their source, so two sources of one name (a style
 * twice, two files of one base name, a file named after a style) would
 * write over each other's frames: refused, naming both, before a frame. */
static void test_render_dataset_source_names(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  char a[1100], b[1100], fa[1200], fb[1200], fw[1200], set[1100];
  snprintf(a, sizeof a, "%s", test_tmp("names_a"));
  snprintf(b, sizeof b, "%s", test_tmp("names_b"));
  mkdir(a, 0755);
  mkdir(b, 0755);
  snprintf(fa, sizeof fa, "%s/bob.hair", a);
  snprintf(fb, sizeof fb, "%s/bob.hair", b);
  snprintf(fw, sizeof fw, "%s/wavy.hair", b);
  snprintf(set, sizeof set, "%s", test_tmp("names_set"));
  assert_int_equal(cli("render hair --style wavy --strands 30 --out %s", fa), 0);
  assert_int_equal(cli("render hair --style curly --strands 30 --out %s", fb), 0);
  assert_int_equal(cli("render hair --style curly --strands 30 --out %s", fw), 0);
  const char *opt = "--count 1 --size 16x16 --spp 4 --gt-ss 2 --quiet";
  assert_int_equal(cli("render dataset --styles wavy,straight,afro,coily %s --out %s", opt, set),
                   1);
  expect_text("style coily and style coily would both write coily_NNNN.exr");
  expect_text("give each style once");
  assert_int_equal(cli("render dataset --hair-files %s,%s %s --out %s", fa, fb, opt, set), 1);
  char said[2600];
  snprintf(said, sizeof said, "%s and %s would both write bob_NNNN.exr", fa, fb);
  expect_text(said);
  assert_int_equal(cli("render dataset --styles wavy --hair-files %s %s --out %s", fw, opt, set),
                   1);
  snprintf(said, sizeof said, "style wavy and %s would both write wavy_NNNN.exr", fw);
  expect_text(said);
  expect_text("link the file under another name");
  struct stat st;
  assert_int_not_equal(stat(set, &st), 0);   /* refused before anything was written */
#endif
}

/* A .hair file that does not load is named once, in every mode: render
 * frame did not repeat it, render dataset (several files) did not name it. */
static void test_render_bad_hair_named(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  char missing[1100], bad[1100], twice[2300];
  snprintf(missing, sizeof missing, "%s", test_tmp("missing.hair"));
  snprintf(bad, sizeof bad, "%s", test_tmp("short.hair"));
  write_text(bad, "HAIR");
  assert_int_equal(cli("render frame --hair %s --size 16x16 --out %s", missing,
                       test_tmp("bad_hair.exr")), 1);
  expect_text(missing);
  expect_text("No such file or directory");
  snprintf(twice, sizeof twice, "%s: %s", missing, missing);
  if (strstr(text, twice)) fail_msg("the file is named twice:\n%s", text);
  assert_int_equal(cli("render dataset --hair-files %s --count 1 --size 16x16 --quiet --out %s",
                       bad, test_tmp("bad_hair_set")), 1);
  char said[1200];
  snprintf(said, sizeof said, "%s: ", bad);
  expect_text(said);
  assert_int_equal(cli("render dataset --hair-files %s --count 1 --size 16x16 --quiet --out %s",
                       missing, test_tmp("bad_hair_set")), 1);
  expect_text(missing);
  if (strstr(text, twice)) fail_msg("the file is named twice:\n%s", text);
#endif
}

/* A loaded model's warnings (here the width fallback of the reference
 * writer's header 1.0) say how it is drawn: render dataset prints them with
 * --quiet too, which silences only the progress bar. */
static void test_render_dataset_quiet_warns(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  const char *hair = HF_SOURCE_DIR "/tests/data/hair-default-header.hair";
  assert_int_equal(cli("render dataset --hair-files %s --units cm --count 1 --size 16x16 --quiet "
                       "--out %s", hair, test_tmp("quiet_set")), 0);
  expect_text("render dataset: warning: ");
  expect_text("header thickness 1.0 is what the reference .hair writer stores");
#endif
}

/* Numbers are read whole: a value with a unit or a tail is refused naming
 * the option (filter --timeout-ms 10s was 10 ms, eval --max-frames 5x 5). */
static void test_strict_numbers(void **state) {
  (void)state;
  assert_int_equal(cli("filter --server unix:/nonexistent.sock --timeout-ms 10s --list"), 2);
  expect_text("--timeout-ms: '10s' is not an integer");
  assert_int_equal(cli("eval --weights %s --max-frames 5x %s", BASE, test_tmp("none")), 2);
  expect_text("--max-frames: '5x' is not an integer");
  assert_int_equal(cli("eval --weights %s --grid-rows 0 %s", BASE, test_tmp("none")), 2);
  expect_text("--grid-rows: 0 is outside 1..64");
  /* A colour that is not three numbers is named, not answered with the
   * whole usage and no word of what is wrong. */
  assert_int_equal(cli("eval --weights %s --hair 1,2 %s", BASE, test_tmp("none")), 2);
  expect_text("hairfilter eval: --hair: '1,2' is not R,G,B (three finite numbers");
  assert_int_equal(cli("infer --weights %s --background 0,0,nan --in x.exr --out %s", BASE,
                       test_tmp("x.exr")), 2);
  expect_text("hairfilter infer: --background: '0,0,nan' is not R,G,B");
  assert_int_equal(cli("filter --server unix:/nonexistent.sock --light 1,1,1x --list"), 2);
  expect_text("hairfilter filter: --light: '1,1,1x' is not R,G,B");
#ifdef HF_TEST_RENDERER
  assert_int_equal(cli("render frame --size 64x64x --out %s", test_tmp("tail.exr")), 2);
  expect_text("--size wants WxH");
  assert_int_equal(cli("render frame --size 16x16 --hair-color 1,2,3x --out %s",
                       test_tmp("tail.exr")), 2);
  /* Past int a count wrapped (4294967297 frames was 1) and 0 was "need an
   * output directory, styles or .hair files, a count and spp". */
  assert_int_equal(cli("render dataset --styles straight --count 4294967297 --size 16x16 "
                       "--out %s", test_tmp("wrap_set")), 2);
  expect_text("--count 4294967297 is too large (at most 2147483647)");
  assert_int_equal(cli("render frame --strands 4294967296 --size 16x16 --out %s",
                       test_tmp("tail.exr")), 2);
  expect_text("--strands 4294967296 is too large");
  /* An option not known is said to be one, not a number too large. */
  assert_int_equal(cli("render frame --strandz 4294967296 --size 16x16 --out %s",
                       test_tmp("tail.exr")), 2);
  expect_text("hairfilter render: unknown option --strandz");
  assert_null(strstr(text, "too large"));
  /* A seed is not a count: --random-view takes 64 bits, as --seed does. */
  assert_int_equal(cli("render frame --random-view 4294967296 --size 16x16 --spp 1 --out %s",
                       test_tmp("seed.exr")), 0);
  assert_int_equal(cli("render dataset --styles straight --count 0 --size 16x16 --out %s",
                       test_tmp("wrap_set")), 2);
  expect_text("--count 0: a set needs at least 1 frame of each style");
  /* A style not known is named, with those that are. */
  assert_int_equal(cli("render dataset --styles straight,bogus --count 1 --size 16x16 --out %s",
                       test_tmp("wrap_set")), 2);
  expect_text("--styles 'straight,bogus': no style 'bogus' (the styles: straight, wavy, curly, "
              "coily, ponytail, spiky, fur, braided;");
  /* --style too names the styles there are. */
  assert_int_equal(cli("render frame --style plait --size 16x16 --out %s", test_tmp("s.exr")), 2);
  expect_text("--style 'plait': no such style (the styles: straight, wavy, curly, coily, "
              "ponytail, spiky, fur, braided; a model of your own: --hair FILE.hair)");
  /* An alias given twice with its style: both named as the style, the alias explained. */
  assert_int_equal(cli("render dataset --styles braided,braids --count 1 --size 16x16 --out %s",
                       test_tmp("alias_set")), 1);
  expect_text("braids and plaits braided");
#endif
}

/* An option the mode does not read is refused by name, before anything is
 * rendered or written, instead of being dropped. */
static void test_render_option_modes(void **state) {
  (void)state;
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer */
#else
  assert_int_equal(cli("render frame --size 16x16 --strands 50 --resume --out %s",
                       test_tmp("mode_frame.exr")), 2);
  expect_text("render frame: --resume is an option of render dataset only");
  struct stat st;
  assert_int_not_equal(stat(test_tmp("mode_frame.exr"), &st), 0);
  assert_int_equal(cli("render dataset --styles straight --count 1 --size 16x16 --cam-yaw 30 "
                       "--out %s", test_tmp("mode_set")), 2);
  expect_text("render dataset: --cam-yaw is an option of render frame, fig6 only");
  assert_int_equal(cli("render hair --style wavy --strands 20 --size 64x64 --out %s",
                       test_tmp("mode.hair")), 2);
  expect_text("render hair: --size is an option of render frame, fig6, dataset only");
  assert_int_equal(cli("render fig6 --png x --out %s", test_tmp("mode.png")), 2);
  expect_text("--png is an option of render frame only");
  assert_int_equal(cli("render fig6 --gt-ss 0 --out %s", test_tmp("mode.png")), 2);
  expect_text("--opaque and --gt-ss take 1 or more here");
  /* A style's shape with a .hair model, a .hair model's conventions with a
   * style, and a dataset's per-frame widths. */
  assert_int_equal(cli("render frame --hair %s --length 0.3 --out %s",
                       HF_SOURCE_DIR "/tests/data/hair-default-header.hair",
                       test_tmp("mode_frame.exr")), 2);
  expect_text("render frame: --length shapes a procedural style");
  assert_int_equal(cli("render frame --style wavy --up z --out %s", test_tmp("mode_frame.exr")),
                   2);
  expect_text("--up applies to a .hair model: give --hair FILE");
  assert_int_equal(cli("render dataset --styles wavy --count 1 --children 3 --out %s",
                       test_tmp("mode_set")), 2);
  expect_text("--children applies to --hair-files");
  assert_int_equal(cli("render dataset --styles wavy --count 1 --segments 4 --out %s",
                       test_tmp("mode_set")), 2);
  expect_text("render dataset: segments 4 is outside 8..1024");
  /* 0 is a value, not "unset"; a negative count is named. */
  assert_int_equal(cli("render hair --strands 0 --out %s", test_tmp("mode.hair")), 2);
  expect_text("strands 0 is outside 1..");
  assert_int_equal(cli("render hair --strands -5 --out %s", test_tmp("mode.hair")), 2);
  expect_text("--strands wants a whole number of at least 0, not '-5'");
  assert_int_equal(cli("render hair --opacity 0 --out %s", test_tmp("mode.hair")), 2);
  expect_text("--opacity 0 is outside (0, 1]");
  /* --opacity reaches a .hair model: its truth's coverage falls. */
  const char *hair = HF_SOURCE_DIR "/tests/data/hair-default-header.hair";
  double cover[2] = {0, 0};
  for (int k = 0; k < 2; k++) {
    assert_int_equal(cli("render frame --hair %s --units cm --thickness 0.05 %s --size 32x32 "
                         "--gt-ss 2 --spp 4 --no-alpha-corrected --quiet --out %s", hair,
                         k ? "--opacity 0.2" : "", test_tmp("mode_op.exr")), 0);
    char err[512];
    hf_image img;
    assert_int_equal(hf_exr_read(test_tmp("mode_op.exr"), &img, err, sizeof err), HF_OK);
    int a = hf_image_channel(&img, "gt.alpha");
    assert_true(a >= 0);
    for (size_t p = 0; p < (size_t)img.width * img.height; p++)
      cover[k] += img.data[p * img.channels + a];
    hf_image_free(&img);
  }
  assert_true(cover[0] > 1);
  assert_true(cover[1] < 0.8 * cover[0]);
  /* What --regimes draws itself, what only it reads, and the option of this
   * mode a user most likely meant. */
  assert_int_equal(cli("render dataset --styles wavy --count 1 --regimes --width-spread 2 "
                       "--out %s", test_tmp("mode_set")), 2);
  expect_text("--regimes draws each frame's clump width spread itself");
  assert_int_equal(cli("render dataset --styles wavy --count 1 --width-px 0.2,0.5 --out %s",
                       test_tmp("mode_set")), 2);
  expect_text("--width-px applies to --regimes");
  assert_int_equal(cli("render dataset --hair-files %s --opacity-range 0.2,0.5 "
                       "--count 1 --out %s", hair, test_tmp("mode_set")), 2);
  expect_text("for --hair-files give --opacity");
  assert_int_equal(cli("render dataset --hair %s --count 1 --out %s", hair, test_tmp("mode_set")),
                   2);
  expect_text("here it is --hair-files");
  /* The tie: the styles that have one, in [0, 1], and a range for a set
   * with a tied style. */
  assert_int_equal(cli("render hair --style wavy --gather 0.5 --out %s", test_tmp("g.hair")), 2);
  expect_text("the wavy style has no tie; gather applies to ponytail and braided only");
  assert_int_equal(cli("render hair --style ponytail --gather 2 --out %s", test_tmp("g.hair")), 2);
  expect_text("gather 2 is outside [0, 1]");
  assert_int_equal(cli("render frame --hair %s --gather 1 --out %s", hair,
                       test_tmp("mode_frame.exr")), 2);
  expect_text("--gather shapes a procedural style");
  /* A dataset's gather range: for a set with a tied style, in [0, 1], two
   * numbers and nothing after them; --gather is render frame's; a smooth
   * share in [0, 1]; the other ranges' bounds, a usage error that echoes
   * them, with or without --regimes; --opacity for styles points to
   * --opacity-range. */
  static const char *const gather_sets[][2] = {
      {"--styles wavy,fur --gather-range 0,1", "--styles has neither"},
      {"--styles braided --gather-range 1,0.5",
       "--gather-range 1,0.5: gathers must be 0 <= MIN <= MAX <= 1"},
      {"--styles braided --gather-range 1", "--gather-range wants MIN,MAX"},
      {"--styles braided --gather-range 0.5,0.7,0.9", "--gather-range wants MIN,MAX"},
      {"--styles braided --gather 1", "here it is --gather-range"},
      {"--styles braided --smooth-share 1.5", "--smooth-share 1.5: a share of the frames, in [0, 1]"},
      {"--styles wavy --opacity-range 0.8,0.5",
       "--opacity-range 0.8,0.5: strand opacities must be 0 < MIN <= MAX <= 1"},
      {"--styles wavy --regimes --opacity-range 0,1", "--opacity-range 0,1: strand opacities must"},
      {"--styles wavy --regimes --width-px 4,1", "--width-px 4,1: strand widths must be 0 < MIN"},
      {"--styles wavy --regimes --frame-sizes 1024,256",
       "--frame-sizes 1024,256: frame sizes must be 0 < MIN <= MAX <= 8192"},
      {"--styles wavy --opacity 0.5", "--opacity-range MIN,MAX draws them in a range"}};
  for (size_t k = 0; k < sizeof gather_sets / sizeof gather_sets[0]; k++) {
    assert_int_equal(cli("render dataset %s --count 1 --out %s", gather_sets[k][0],
                         test_tmp("mode_set")), 2);
    expect_text(gather_sets[k][1]);
  }
  assert_int_equal(cli("render frame --hair %s --scale 0 --out %s", hair,
                       test_tmp("mode_frame.exr")), 2);
  expect_text("--scale 0: renderer units per file unit, above 0");
  /* Two options of one factor: the later one silently won. */
  assert_int_equal(cli("render frame --hair %s --units cm --scale 2 --out %s", hair,
                       test_tmp("mode_frame.exr")), 2);
  expect_text("render frame: --units and --scale both say the file's unit");
  assert_int_equal(cli("render dataset --hair-files %s --scale 2 --units mm --count 1 --out %s",
                       hair, test_tmp("mode_set")), 2);
  expect_text("render dataset: --units and --scale both say the file's unit");
  assert_int_equal(cli("render frame --hair %s --children 2 --child-clumping 2 --out %s", hair,
                       test_tmp("mode_frame.exr")), 2);
  expect_text("--child-clumping 2 is outside [0, 1]");
  /* Children where none are grown: a style drawn strand by strand, and a
   * .hair model without --children. */
  assert_int_equal(cli("render frame --style straight --children 8 --out %s",
                       test_tmp("mode_frame.exr")), 2);
  expect_text("children 8: the straight style draws every strand itself");
  assert_int_equal(cli("render frame --style fur --strands 160 --children 7 --size 16x16 --quiet "
                       "--gt-ss 1 --st 4 --out %s", test_tmp("mode_frame.exr")), 0);
  assert_int_equal(cli("render frame --hair %s --child-spread 0.5 --out %s", hair,
                       test_tmp("mode_frame.exr")), 2);
  expect_text("--child-spread shapes the children --children N grows, and none are grown");
  assert_int_equal(cli("render dataset --hair-files %s --children 0 --child-clumping 0.5 "
                       "--count 1 --out %s", hair, test_tmp("mode_set")), 2);
  expect_text("--child-clumping shapes the children");
  /* --help wins over a refusal. */
  assert_int_equal(cli("render dataset --cam-yaw 3 --help"), 0);
  expect_text("usage: hairfilter render");
  /* Every spelling the parser takes is in the help, --up's other one too. */
  expect_text("--up-axis");
  /* What every mode reads, and a negative value after an option. */
  assert_int_equal(cli("render hair --style wavy --strands 20 --segments 8 --quiet --out %s",
                       test_tmp("mode.hair")), 0);
  /* A style parameter out of range is named with its range. */
  assert_int_equal(cli("render hair --style wavy --strands 20 --segments 4 --out %s",
                       test_tmp("mode.hair")), 2);
  expect_text("segments 4 is outside 8..1024");
  assert_int_equal(cli("render frame --size 16x16 --strands 50 --gt-ss 0 --st 4 --quiet "
                       "--cam-pitch -20 --out %s", test_tmp("mode_frame.exr")), 0);
#endif
}

/* infer --png composites over the frame's background layer (the head the
 * renderer draws under the hair) where it has one, as the renderer's own
 * composites do, and over --background without one. */
static void test_preview_over_background_layer(void **state) {
#ifndef HF_TEST_RENDERER
  skip();  /* built without the renderer: previews are over --background alone */
#endif
  char err[512];
  hf_image frame, layered;
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &frame, err, sizeof err), HF_OK);
  assert_int_equal(hf_image_alloc(&layered, frame.width, frame.height, frame.channels + 4), HF_OK);
  for (int c = 0; c < frame.channels; c++) memcpy(layered.names[c], frame.names[c], 32);
  for (int k = 0; k < 4; k++)
    snprintf(layered.names[frame.channels + k], 32, "background.%c", "RGBA"[k]);
  const float red[4] = {1, 0, 0, 1};   /* an opaque red layer */
  for (size_t p = 0; p < (size_t)frame.width * frame.height; p++) {
    memcpy(layered.data + p * layered.channels, frame.data + p * frame.channels,
           (size_t)frame.channels * sizeof(float));
    memcpy(layered.data + p * layered.channels + frame.channels, red, sizeof red);
  }
  assert_int_equal(hf_exr_write(test_tmp("layered.exr"), &layered, 0), HF_OK);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --png %s "
                       "--background 0,0,1", BASE, test_tmp("layered.exr"),
                       test_tmp("layered_res.exr"), test_tmp("layered.png")), 0);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --png %s "
                       "--background 0,0,1", BASE, test_field("frame-64x64.exr"),
                       test_tmp("plain_res.exr"), test_tmp("plain.png")), 0);
  hf_image res;
  read_result(test_tmp("layered_res.exr"), &res);
  int a = hf_image_channel(&res, "alpha"), w, h, w2, h2, empty = 0;
  unsigned char *over = read_png(test_tmp("layered.png"), &w, &h);
  unsigned char *flat = read_png(test_tmp("plain.png"), &w2, &h2);
  assert_true(w == frame.width && h == frame.height && w2 == w && h2 == h);
  for (int p = 0; p < w * h; p++) {
    if (res.data[p * 3 + a] != 0) continue;   /* no hair: the layer alone */
    empty++;
    assert_true(over[p * 3] == 255 && over[p * 3 + 1] == 0 && over[p * 3 + 2] == 0);
    assert_true(flat[p * 3] == 0 && flat[p * 3 + 1] == 0 && flat[p * 3 + 2] == 255);
  }
  assert_true(empty > 0);

  /* A layer pixel with a NaN (a damaged layer) is left out, with a warning
   * naming it: the preview shows --background there, not black. */
  int bare = -1;
  for (int p = 0; p < w * h && bare < 0; p++)
    if (res.data[p * 3 + a] == 0) bare = p;
  layered.data[(size_t)bare * layered.channels + frame.channels + 1] = NAN;
  assert_int_equal(hf_exr_write(test_tmp("layered_nan.exr"), &layered, 0), HF_OK);
  assert_int_equal(cli("infer --backend cpu-ref --weights %s --in %s --out %s --png %s "
                       "--background 0,0,1", BASE, test_tmp("layered_nan.exr"),
                       test_tmp("layered_res.exr"), test_tmp("layered_nan.png")), 0);
  char want[160];
  snprintf(want, sizeof want, "layered_nan.exr: its background layer has 1 pixel with a value "
           "that is not finite, the first at pixel (%d, %d): background.G = nan", bare % w,
           bare / w);
  expect_text(want);
  unsigned char *fixed = read_png(test_tmp("layered_nan.png"), &w2, &h2);
  assert_true(fixed[bare * 3] == 0 && fixed[bare * 3 + 1] == 0 && fixed[bare * 3 + 2] == 255);
  free(fixed);
  free(over);
  free(flat);
  hf_image_free(&res);
  hf_image_free(&layered);
  hf_image_free(&frame);
}

static int setup(void **state) { return test_tmp_create("hf_test_cli"); }
static int teardown(void **state) { return test_tmp_remove(); }

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_inf_sample),      cmocka_unit_test(test_estimate_sanitised),
    cmocka_unit_test(test_negative_alpha_sample),
    cmocka_unit_test(test_tall_frame),
    cmocka_unit_test(test_crop_windows),    cmocka_unit_test(test_tiled_and_parts),
    cmocka_unit_test(test_refusals),        cmocka_unit_test(test_missing_samples),
    cmocka_unit_test(test_output_directory), cmocka_unit_test(test_render_input_preview),
    cmocka_unit_test(test_render_gt_grid_note), cmocka_unit_test(test_render_dataset_resume),
    cmocka_unit_test(test_render_dataset_resume_occluder),
    cmocka_unit_test(test_render_bad_hair_named),
    cmocka_unit_test(test_render_dataset_quiet_warns),
    cmocka_unit_test(test_render_dataset_source_names),
    cmocka_unit_test(test_strict_numbers),
    cmocka_unit_test(test_render_option_modes), cmocka_unit_test(test_eval_warning),
    cmocka_unit_test(test_eval_no_frames),
    cmocka_unit_test(test_preview_over_background_layer),
    cmocka_unit_test(test_render_crop_windows),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
