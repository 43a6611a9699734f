/* EXR files written and read: every file hf_exr_write makes reads back bit
 * for bit (OpenEXRCore 3.1.5's ZIP writer corrupts chunks that do not
 * shrink, upstream issue 2306), and files from other tools (tiled,
 * multi-part, cropped, cut short, DWAA, many samples) are read or refused
 * with a message that names the problem. The odd files are made here with
 * OpenEXRCore, beside the field cases in tests/data/field. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include <openexr.h>

#include "exr_parts.h"
#include "test_paths.h"
#include "hfcore.h"

static uint64_t rng = 0x9e3779b97f4a7c15ull;
static uint32_t next(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (uint32_t)(rng >> 16);
}

/* Values of kind k: 0 random bits (finite), 1 uniform [0, 1), 2 feature-like
 * (mostly 0, some alpha), 3 a repeating ramp. */
static float value(int kind, size_t i, int nch) {
  uint32_t r = next();
  float v;
  switch (kind) {
  case 0:
    r = r << 16 ^ next();
    memcpy(&v, &r, 4);
    return isfinite(v) ? v : 1.0f;
  case 1: return (float)(r >> 8) * (1.0f / 16777216.0f);
  case 2: return (int)(i % (size_t)nch) == 2 ? ((r & 3) ? 0.0f : (float)(r >> 8) / 16777216.0f)
                                             : (float)(r >> 9) * (2.0f / 8388608.0f);
  default: return (float)(i % 97) * 0.01f;
  }
}

static int same_bits(float a, float b) { return memcmp(&a, &b, 4) == 0; }

/* Writes and reads back one image; every value must come back bit for bit
 * (rounded to half first with half). */
static int roundtrip(int w, int h, int nch, int kind, int half) {
  hf_image img;
  assert_int_equal(hf_image_alloc(&img, w, h, nch), HF_OK);
  for (int c = 0; c < nch; c++) snprintf(img.names[c], 32, "c%02d", c);
  size_t n = (size_t)w * h * nch;
  for (size_t i = 0; i < n; i++) img.data[i] = value(kind, i, nch);
  const char *path = test_tmp("rt.exr");
  int ok = hf_exr_write(path, &img, half) == HF_OK;
  hf_image back;
  char err[512];
  if (ok && hf_exr_read(path, &back, err, sizeof err) == HF_OK) {
    ok = back.width == w && back.height == h && back.channels == nch;
    for (int c = 0; ok && c < nch; c++) {
      int bc = hf_image_channel(&back, img.names[c]);
      ok = bc >= 0;
      for (size_t p = 0; ok && p < (size_t)w * h; p++) {
        float want = img.data[p * nch + c];
        if (half) want = hf_f16_to_f32(hf_f32_to_f16(want));
        ok = same_bits(want, back.data[p * nch + bc]);
      }
    }
    hf_image_free(&back);
  } else {
    ok = 0;
  }
  if (!ok) fprintf(stderr, "round trip failed: %dx%d, %d channels, data %d, %s\n", w, h, nch,
                   kind, half ? "half" : "float");
  hf_image_free(&img);
  return ok;
}

/* The sizes where OpenEXRCore 3.1.5's own ZIP writer stored zlib bytes as
 * raw ones (1x15 ... 3x333 among them), and the usual shapes. */
static void test_write_reads_back_exactly(void **state) {
  static const int sizes[][2] = {{1, 1},   {1, 2},    {1, 15},   {1, 16},  {1, 17},
                                 {1, 100}, {1, 1024}, {1024, 1}, {2, 1024}, {3, 333},
                                 {7, 65},  {17, 17},  {31, 47},  {64, 64}, {63, 65},
                                 {128, 3}, {100, 100}, {37, 150}, {16, 1000}};
  static const int channels[] = {1, 3, 6, 12, 24};
  int bad = 0, total = 0;
  for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++)
    for (size_t c = 0; c < sizeof channels / sizeof channels[0]; c++)
      for (int kind = 0; kind < 4; kind++)
        for (int half = 0; half < 2; half++) {
          total++;
          bad += !roundtrip(sizes[s][0], sizes[s][1], channels[c], kind, half);
        }
  assert_int_equal(total, 760);
  assert_int_equal(bad, 0);
}

static void test_result_of_tall_frame(void **state) {
  /* What hairfilter infer writes for the field case: a 1x1024 result. */
  hf_image feat;
  char err[512];
  assert_int_equal(hf_exr_read(test_field("exr-1x1024.exr"), &feat, err, sizeof err), HF_OK);
  assert_int_equal(feat.width, 1);
  assert_int_equal(feat.height, 1024);
  assert_int_equal(hf_features_spp(&feat), 4);
  float *in = malloc(sizeof(float) * 1024 * 24), out[1024 * 3];
  assert_int_equal(hf_features_from_image(&feat, 4, in), 4);
  for (int p = 0; p < 1024; p++) hf_st_estimate(in + p * 24, 4, out + p * 3);
  hf_image res;
  assert_int_equal(hf_result_to_image(out, 1, 1024, &res), HF_OK);
  const char *path = test_tmp("tall.exr");
  assert_int_equal(hf_exr_write(path, &res, 0), HF_OK);
  hf_image back;
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  for (int p = 0; p < 1024; p++)
    for (int k = 0; k < 3; k++)
      assert_true(same_bits(back.data[p * 3 + hf_image_channel(&back, HF_OUTPUT_NAMES[k])],
                            out[p * 3 + k]));
  hf_image_free(&back);
  hf_image_free(&res);
  hf_image_free(&feat);
  free(in);
}

/* ---- windows ----------------------------------------------------------------- */

static void test_windows(void **state) {
  hf_image img, back;
  char err[512];
  assert_int_equal(hf_image_alloc(&img, 5, 3, 2), HF_OK);
  strcpy(img.names[0], "a");
  strcpy(img.names[1], "b");
  for (int i = 0; i < 30; i++) img.data[i] = (float)i;
  img.origin_x = -7;
  img.origin_y = 40;
  img.display_x = -10;
  img.display_y = 0;
  img.display_width = 501;
  img.display_height = 401;
  const char *path = test_tmp("win.exr");
  assert_int_equal(hf_exr_write(path, &img, 1), HF_OK);
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  assert_int_equal(back.origin_x, -7);
  assert_int_equal(back.origin_y, 40);
  assert_int_equal(back.display_x, -10);
  assert_int_equal(back.display_width, 501);
  assert_int_equal(back.display_height, 401);
  assert_memory_equal(back.data, img.data, 30 * sizeof(float));
  hf_image_free(&back);
  /* No display window of its own: written as the data window, read as none. */
  img.display_width = img.display_height = 0;
  assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  assert_int_equal(back.origin_y, 40);
  assert_int_equal(back.display_width, 0);
  hf_image_free(&back);
  hf_image_free(&img);
  /* The field case: a half PIZ crop of a 501x401 frame. */
  assert_int_equal(hf_exr_read(test_field("exr-crop-datawindow.exr"), &img, err, sizeof err), HF_OK);
  assert_int_equal(img.width, 64);
  assert_int_equal(img.height, 64);
  assert_int_equal(img.origin_x, 30);
  assert_int_equal(img.origin_y, 40);
  assert_int_equal(img.display_x, 0);
  assert_int_equal(img.display_y, 0);
  assert_int_equal(img.display_width, 501);
  assert_int_equal(img.display_height, 401);
  hf_image res;
  float out[64 * 64 * 3] = {0};
  assert_int_equal(hf_result_to_image(out, 64, 64, &res), HF_OK);
  hf_image_copy_windows(&res, &img);
  assert_int_equal(hf_exr_write(path, &res, 0), HF_OK);
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  assert_int_equal(back.origin_x, 30);
  assert_int_equal(back.origin_y, 40);
  assert_int_equal(back.display_width, 501);
  assert_int_equal(back.display_height, 401);
  hf_image_free(&back);
  hf_image_free(&res);
  hf_image_free(&img);
}

/* ---- files made with OpenEXRCore ------------------------------------------------ */

static void check_part(const hf_image *img, const part_spec *p) {
  assert_int_equal(img->width, p->w);
  assert_int_equal(img->height, p->h);
  assert_int_equal(img->channels, p->nch);
  assert_int_equal(img->origin_x, p->x0);
  assert_int_equal(img->origin_y, p->y0);
  for (int c = 0; c < p->nch; c++) {
    int ic = hf_image_channel(img, p->channels[c]);
    assert_true(ic >= 0);
    for (int y = 0; y < p->h; y++)
      for (int x = 0; x < p->w; x++)
        assert_true(img->data[((size_t)y * p->w + x) * p->nch + ic] ==
                    part_value(p, c, p->x0 + x, p->y0 + y));
  }
}

static const char *const FEAT6[] = {"S0.color", "S0.highlight", "S0.alpha",
                                    "S0.depth", "S0.tangent.x", "S0.tangent.y"};
static const char *const RGB[] = {"R", "G", "B"};
static const char *const Z[] = {"Z"};

static void test_tiled(void **state) {
  static const struct { int w, h, tw, th, mip; exr_compression_t comp; } cases[] = {
    {64, 64, 32, 32, 0, EXR_COMPRESSION_ZIP}, {37, 23, 16, 16, 0, EXR_COMPRESSION_ZIP},
    {37, 23, 8, 5, 0, EXR_COMPRESSION_PIZ},   {50, 31, 16, 8, 1, EXR_COMPRESSION_ZIPS},
    {1, 70, 4, 4, 0, EXR_COMPRESSION_NONE},   {64, 48, 64, 64, 1, EXR_COMPRESSION_RLE},
  };
  char err[512];
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    part_spec p = {"tiles", 1, cases[i].tw, cases[i].th, cases[i].mip, (int)i * 3 - 4, 7,
                   cases[i].w, cases[i].h, 6, FEAT6, cases[i].comp, 0.5f, NULL};
    const char *path = test_tmp("tiled.exr");
    write_parts(path, &p, 1);
    hf_image img;
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_OK);
    check_part(&img, &p);
    hf_image_free(&img);
  }
  /* The field case holds frame-64x64.exr as 32x32 tiles. */
  hf_image tiled, plain;
  assert_int_equal(hf_exr_read(test_field("exr-tiled.exr"), &tiled, err, sizeof err), HF_OK);
  assert_int_equal(hf_exr_read(test_field("frame-64x64.exr"), &plain, err, sizeof err), HF_OK);
  assert_int_equal(tiled.channels, plain.channels);
  assert_int_equal(hf_features_spp(&tiled), 4);
  float *a = malloc(64 * 64 * 24 * sizeof(float)), *b = malloc(64 * 64 * 24 * sizeof(float));
  assert_int_equal(hf_features_from_image(&tiled, 4, a), 4);
  assert_int_equal(hf_features_from_image(&plain, 4, b), 4);
  assert_memory_equal(a, b, 64 * 64 * 24 * sizeof(float));
  free(a), free(b);
  hf_image_free(&tiled);
  hf_image_free(&plain);
}

static void test_multipart(void **state) {
  part_spec parts[3] = {
    {"beauty", 0, 0, 0, 0, 0, 0, 20, 10, 3, RGB, EXR_COMPRESSION_ZIP, 1.0f, NULL},
    {"features", 1, 8, 8, 0, 5, -3, 19, 11, 6, FEAT6, EXR_COMPRESSION_PIZ, 2.0f, NULL},
    {"depth", 0, 0, 0, 0, 0, 0, 20, 10, 1, Z, EXR_COMPRESSION_NONE, 3.0f, NULL},
  };
  const char *path = test_tmp("multi.exr");
  char err[1024];
  write_parts(path, parts, 3);
  hf_image img;
  /* Automatic: the one part with the channel asked for. */
  assert_int_equal(hf_exr_read_part(path, NULL, "S0.color", &img, err, sizeof err), HF_OK);
  check_part(&img, &parts[1]);
  hf_image_free(&img);
  /* By index and by name. */
  assert_int_equal(hf_exr_read_part(path, "2", NULL, &img, err, sizeof err), HF_OK);
  check_part(&img, &parts[2]);
  hf_image_free(&img);
  assert_int_equal(hf_exr_read_part(path, "beauty", "S0.color", &img, err, sizeof err), HF_OK);
  check_part(&img, &parts[0]);
  hf_image_free(&img);
  /* Nothing to choose by: the error lists the parts. */
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_ENOTFOUND);
  assert_null(img.data);
  assert_non_null(strstr(err, path));
  assert_non_null(strstr(err, "3 parts"));
  assert_non_null(strstr(err, "0 \"beauty\" (3 channels)"));
  assert_non_null(strstr(err, "1 \"features\" (6 channels, tiled)"));
  assert_non_null(strstr(err, "--part"));
  assert_int_equal(hf_exr_read_part(path, NULL, "S9.color", &img, err, sizeof err), HF_ENOTFOUND);
  assert_non_null(strstr(err, "none with channel S9.color"));
  assert_int_equal(hf_exr_read_part(path, "3", NULL, &img, err, sizeof err), HF_ENOTFOUND);
  assert_non_null(strstr(err, "has no part \"3\""));
  assert_int_equal(hf_exr_read_part(path, "nope", NULL, &img, err, sizeof err), HF_ENOTFOUND);
  assert_non_null(strstr(err, "2 \"depth\" (1 channels)"));
  /* Two parts with features: ambiguous. */
  part_spec two[2] = {parts[1], parts[1]};
  two[1].name = "features2";
  two[1].tiled = 0;
  write_parts(path, two, 2);
  assert_int_equal(hf_exr_read_part(path, NULL, "S0.color", &img, err, sizeof err), HF_ENOTFOUND);
  assert_non_null(strstr(err, "several with channel S0.color"));
  assert_int_equal(hf_exr_read_part(path, "features2", "S0.color", &img, err, sizeof err), HF_OK);
  check_part(&img, &two[1]);
  hf_image_free(&img);
}

/* ---- files that cannot be read ------------------------------------------------------ */

static long file_size(const char *path) {
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fclose(f);
  return n;
}

static void copy_prefix(const char *from, const char *to, long n) {
  FILE *a = fopen(from, "rb"), *b = fopen(to, "wb");
  assert_non_null(a);
  assert_non_null(b);
  char *buf = malloc((size_t)n + 1);
  assert_int_equal(fread(buf, 1, (size_t)n, a), (size_t)n);
  assert_int_equal(fwrite(buf, 1, (size_t)n, b), (size_t)n);
  free(buf);
  fclose(a);
  fclose(b);
}

static void patch_header(const char *path, const char *key, size_t keylen, const void *value,
                         size_t n, void *old);

static void test_truncated(void **state) {
  char err[512];
  hf_image img;
  assert_int_equal(hf_exr_read(test_field("exr-truncated.exr"), &img, err, sizeof err), HF_EIO);
  assert_non_null(strstr(err, "exr-truncated.exr"));
  assert_non_null(strstr(err, "truncated / incomplete file"));
  assert_null(img.data);
  /* Files of every layout cut anywhere: in the header, the offset table, a
   * chunk's leader or its data. */
  part_spec scan = {"s", 0, 0, 0, 0, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_ZIP, 0.25f, NULL};
  part_spec tile = {"t", 1, 16, 16, 0, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_ZIP, 0.25f, NULL};
  /* Mipmapped: a cut in the smaller levels leaves the full-resolution one
   * whole, and the file is still refused as cut short. */
  part_spec mip = {"m", 1, 16, 16, 1, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_ZIP, 0.25f, NULL};
  part_spec *specs[3] = {&scan, &tile, &mip};
  for (int s = 0; s < 3; s++) {
    const char *full = test_tmp("full.exr"), *cut = test_tmp("cut.exr");
    write_parts(full, specs[s], 1);
    long n = file_size(full);
    for (int pct = 1; pct < 100; pct += 7) {
      copy_prefix(full, cut, n * pct / 100);
      int rc = hf_exr_read(cut, &img, err, sizeof err);
      if (rc != HF_EIO || !strstr(err, "truncated / incomplete"))
        fprintf(stderr, "cut at %d%% of %ld: %d %s\n", pct, n, rc, err);
      assert_int_equal(rc, HF_EIO);
      assert_non_null(strstr(err, "truncated / incomplete"));
    }
    copy_prefix(full, cut, n - 1);
    assert_int_equal(hf_exr_read(cut, &img, err, sizeof err), HF_EIO);
    assert_non_null(strstr(err, "truncated / incomplete"));
    /* Complete but damaged: said so, not called truncated. */
    copy_prefix(full, cut, n);
    FILE *f = fopen(cut, "r+b");
    fseek(f, n / 2, SEEK_SET);
    for (int i = 0; i < 64; i++) fputc(0x55, f);
    fclose(f);
    assert_int_equal(hf_exr_read(cut, &img, err, sizeof err), HF_EFORMAT);
    assert_non_null(strstr(err, "damaged"));
    assert_null(strstr(err, "truncated"));
  }
  /* Multi-part: a cut in the last part's chunks leaves the others whole,
   * and the file is still refused as cut short whichever part is read (as
   * a mipmapped file cut in its smaller levels is). */
  {
    part_spec mp[3] = {
      {"beauty", 0, 0, 0, 0, 0, 0, 20, 10, 3, RGB, EXR_COMPRESSION_ZIP, 1.0f, NULL},
      {"features", 1, 8, 8, 0, 5, -3, 19, 11, 6, FEAT6, EXR_COMPRESSION_PIZ, 2.0f, NULL},
      {"depth", 0, 0, 0, 0, 0, 0, 20, 10, 1, Z, EXR_COMPRESSION_NONE, 3.0f, NULL},
    };
    const char *full = test_tmp("full.exr"), *cut = test_tmp("cut.exr");
    write_parts(full, mp, 3);
    long n = file_size(full);
    const long at[] = {n - 1, n - 8, n - 100};
    for (int k = 0; k < 3; k++) {
      copy_prefix(full, cut, at[k]);
      for (int part = 0; part < 3; part++) {
        char which[4];
        snprintf(which, sizeof which, "%d", part);
        int rc = hf_exr_read_part(cut, which, NULL, &img, err, sizeof err);
        if (rc == HF_OK) hf_image_free(&img);
        if (rc != HF_EIO || !strstr(err, "truncated / incomplete"))
          fail_msg("3 parts cut at %ld of %ld, part %d: %d %s", at[k], n, part, rc,
                   rc ? err : "read");
      }
    }
  }
  /* Uncompressed and RLE, whose claimed-size check fails first on a cut
   * file: still called truncated. */
  static const exr_compression_t raw[] = {EXR_COMPRESSION_NONE, EXR_COMPRESSION_RLE};
  for (int k = 0; k < 2; k++) {
    part_spec p = {"r", 0, 0, 0, 0, 0, 0, 40, 70, 6, FEAT6, raw[k], 0.25f, NULL};
    const char *full = test_tmp("full.exr"), *cut = test_tmp("cut.exr");
    write_parts(full, &p, 1);
    long n = file_size(full);
    for (int pct = 50; pct < 100; pct += 7) {
      copy_prefix(full, cut, n * pct / 100);
      assert_int_equal(hf_exr_read(cut, &img, err, sizeof err), HF_EIO);
      assert_non_null(strstr(err, "truncated / incomplete"));
    }
  }
}

/* A chunk offset table with an offset outside the file's chunks is
 * refused: OpenEXR 3.1.5 "repairs" it by scanning the chunks and then
 * reads another chunk's pixels for a scanline, with no error. A complete
 * file whose header holds an invalid value is damaged, not truncated,
 * however small (the library reads ahead past the end of a small file). */
static void test_damaged_chunk_table(void **state) {
  char err[512];
  hf_image img;
  part_spec p = {"d", 0, 0, 0, 0, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_ZIP, 0.25f, NULL};
  const char *path = test_tmp("table.exr");
  /* ZIP holds 16 scanlines a chunk: 5 chunks; the first offset is the
   * table's own end. The second chunk's offset past the end, then into
   * the header. */
  const unsigned char bad[2][8] = {{0xff, 0xff, 0xff, 0x7f, 0, 0, 0, 0}, {100, 0, 0, 0, 0, 0, 0, 0}};
  for (int k = 0; k < 2; k++) {
    write_parts(path, &p, 1);
    FILE *f = fopen(path, "r+b");
    assert_non_null(f);
    unsigned char buf[4096];
    size_t got = fread(buf, 1, sizeof buf, f);
    long at = -1;
    for (size_t i = 8; i + 8 <= got && at < 0; i++) {
      uint64_t v = 0;
      for (int b = 7; b >= 0; b--) v = v << 8 | buf[i + (size_t)b];
      if (v == i + 5 * 8) at = (long)i;
    }
    assert_true(at > 0);
    fseek(f, at + 8, SEEK_SET);
    assert_int_equal(fwrite(bad[k], 1, 8, f), 8);
    fclose(f);
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EIO);
    assert_non_null(strstr(err, "damaged chunk table"));
    assert_null(img.data);
  }

  static const char disp[] = "displayWindow\0box2i\0\x10\0\0\0";
  const int32_t inverted[4] = {5, 5, 0, 0};
  part_spec one = {"o", 0, 0, 0, 0, 0, 0, 1, 1, 6, FEAT6, EXR_COMPRESSION_ZIP, 0.25f, NULL};
  path = test_tmp("inverted.exr");
  write_parts(path, &one, 1);
  patch_header(path, disp, sizeof disp - 1, inverted, sizeof inverted, NULL);
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "display window"));
  assert_non_null(strstr(err, "damaged"));
  assert_null(strstr(err, "truncated"));
}

/* An uncompressed chunk holds exactly its pixels: one whose leader claims
 * fewer bytes is damaged. OpenEXRCore 3.1.5 decodes it with no error, the
 * pixels after the claimed size shifted or left at what the buffer held
 * (the pixels read back differed, the leader one byte short). */
static void test_short_uncompressed_chunk(void **state) {
  (void)state;
  char err[512];
  hf_image img;
  /* 70 chunks of one scanline; 3 x 5 tiles of 16 x 16. */
  part_spec scan = {"n", 0, 0, 0, 0, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_NONE, 0.25f, NULL};
  part_spec tile = {"n", 1, 16, 16, 0, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_NONE, 0.25f, NULL};
  const part_spec *specs[2] = {&scan, &tile};
  const int chunks[2] = {70, 15}, lead[2] = {4, 16};
  const char *path = test_tmp("short-chunk.exr");
  for (int s = 0; s < 2; s++)
    for (int which = 0; which < 3; which++)
      for (int by = 1; by <= 4; by *= 2) {
        write_parts(path, specs[s], 1);
        FILE *f = fopen(path, "r+b");
        assert_non_null(f);
        static unsigned char buf[1 << 17];
        size_t got = fread(buf, 1, sizeof buf, f);
        long table = -1;
        for (size_t i = 8; i + 8 <= got && table < 0; i++) {
          uint64_t v = 0;
          for (int b = 7; b >= 0; b--) v = v << 8 | buf[i + (size_t)b];
          if (v == i + (uint64_t)chunks[s] * 8) table = (long)i;
        }
        assert_true(table > 0);
        /* The first, a middle and the last chunk: its data size one, two
         * or four bytes short. */
        int c = which == 0 ? 0 : which == 1 ? chunks[s] / 2 : chunks[s] - 1;
        uint64_t off = 0;
        for (int b = 7; b >= 0; b--) off = off << 8 | buf[table + 8 * c + b];
        size_t at = (size_t)off + (size_t)lead[s];
        assert_true(at + 4 <= got);
        uint32_t size = (uint32_t)buf[at] | (uint32_t)buf[at + 1] << 8 |
                        (uint32_t)buf[at + 2] << 16 | (uint32_t)buf[at + 3] << 24;
        size -= (uint32_t)by;
        unsigned char le[4] = {(unsigned char)size, (unsigned char)(size >> 8),
                               (unsigned char)(size >> 16), (unsigned char)(size >> 24)};
        fseek(f, (long)at, SEEK_SET);
        assert_int_equal(fwrite(le, 1, 4, f), 4);
        fclose(f);
        int rc = hf_exr_read(path, &img, err, sizeof err);
        if (rc == HF_OK) hf_image_free(&img);
        if (rc != HF_EFORMAT || !strstr(err, "damaged") || !strstr(err, "short-chunk.exr"))
          fail_msg("%s, chunk %d, %d byte(s) short: %d %s", s ? "tiled" : "scanline", c, by, rc,
                   rc ? err : "read");
        assert_non_null(strstr(err, "uncompressed"));
      }
}

/* A complete file smaller than the block the library reads its header in,
 * with a chunk leader that claims more bytes than the chunk holds (but not
 * past the end of the file), is damaged, not truncated: the header's
 * read-ahead past the end of the file is no sign of a cut. */
static void test_small_file_bad_leader(void **state) {
  (void)state;
  char err[512];
  hf_image img;
  part_spec p = {"s", 0, 0, 0, 0, 0, 0, 1, 7, 6, FEAT6, EXR_COMPRESSION_NONE, 0.25f, NULL};
  const char *path = test_tmp("small-leader.exr");
  for (int c = 0; c < 6; c += 3) {
    write_parts(path, &p, 1);
    long n = file_size(path);
    assert_true(n < 4096);
    FILE *f = fopen(path, "r+b");
    assert_non_null(f);
    unsigned char buf[4096];
    assert_int_equal(fread(buf, 1, (size_t)n, f), (size_t)n);
    long table = -1;
    for (long i = 8; i + 8 <= n && table < 0; i++) {
      uint64_t v = 0;
      for (int b = 7; b >= 0; b--) v = v << 8 | buf[i + b];
      if (v == (uint64_t)i + 7 * 8) table = i;
    }
    assert_true(table > 0);
    uint64_t off = 0;
    for (int b = 7; b >= 0; b--) off = off << 8 | buf[table + 8 * c + b];
    buf[off + 4] += 1;   /* 24 bytes of pixels, said to be 25 */
    fseek(f, 0, SEEK_SET);
    assert_int_equal(fwrite(buf, 1, (size_t)n, f), (size_t)n);
    fclose(f);
    assert_int_not_equal(hf_exr_read(path, &img, err, sizeof err), HF_OK);
    if (!strstr(err, "damaged") || strstr(err, "truncated"))
      fail_msg("chunk %d's leader 1 byte long: %s", c, err);
  }
}

/* A complete file whose header holds a value the library refuses (a
 * channel's sampling, an attribute's size) is damaged, not truncated: it
 * does not end inside its header. Small files too, whose header the
 * library reads ahead past the end of. */
static void test_damaged_header_not_cut(void **state) {
  (void)state;
  char err[512];
  hf_image img;
  part_spec big = {"h", 0, 0, 0, 0, 0, 0, 40, 70, 6, FEAT6, EXR_COMPRESSION_NONE, 0.25f, NULL};
  part_spec small = {"h", 0, 0, 0, 0, 0, 0, 1, 3, 6, FEAT6, EXR_COMPRESSION_NONE, 0.25f, NULL};
  const part_spec *specs[2] = {&big, &small};
  const char *path = test_tmp("damaged-header.exr");
  for (int s = 0; s < 2; s++)
    for (int how = 0; how < 2; how++) {
      write_parts(path, specs[s], 1);
      long n = file_size(path);
      FILE *f = fopen(path, "r+b");
      assert_non_null(f);
      static unsigned char buf[1 << 17];
      assert_int_equal(fread(buf, 1, (size_t)n, f), (size_t)n);
      /* The header's end: the 0 after the last attribute, which the
       * chunk table follows (its first offset is the table's end). */
      long end = -1;
      int chunks = s ? 3 : 70;
      for (long i = 9; i + 8 <= n && end < 0; i++) {
        uint64_t v = 0;
        for (int b = 7; b >= 0; b--) v = v << 8 | buf[i + b];
        if (v == (uint64_t)i + (uint64_t)chunks * 8 && buf[i - 1] == 0) end = i - 1;
      }
      assert_true(end > 0);
      if (how == 0) {
        /* The first channel's y sampling (after its name, pixel type,
         * pLinear, 3 reserved bytes and x sampling) made negative: the
         * library drops the channel list, and reports it missing. */
        static const char key[] = "chlist\0";
        long at = -1;
        for (long i = 8; i + 16 < end && at < 0; i++)
          if (!memcmp(buf + i, key, sizeof key - 1)) at = i + (long)sizeof key - 1 + 4;
        assert_true(at > 0 && buf[at] == 'S');
        at += (long)strlen((const char *)buf + at) + 1 + 4 + 4 + 4;
        buf[at + 3] = 0xdb;
      } else {
        /* The last attribute's size (4 bytes before its value) negative:
         * the "type" attribute's string, "scanlineimage", is last. */
        static const char key[] = "type\0string\0";
        long at = -1;
        for (long i = 8; i + 16 < end && at < 0; i++)
          if (!memcmp(buf + i, key, sizeof key - 1)) at = i + (long)sizeof key - 1;
        assert_true(at > 0);
        buf[at + 3] = 0xf0;
      }
      fseek(f, 0, SEEK_SET);
      assert_int_equal(fwrite(buf, 1, (size_t)n, f), (size_t)n);
      fclose(f);
      assert_int_not_equal(hf_exr_read(path, &img, err, sizeof err), HF_OK);
      if (strstr(err, "truncated") || !strstr(err, "damaged"))
        fail_msg("%s file, %s: %s", s ? "small" : "large",
                 how ? "negative attribute size" : "negative channel sampling", err);
    }
}

/* n bytes of an attribute's value in the header of the file at path: the
 * bytes after the first occurrence of key (keylen bytes: name, type and
 * size). Their old bytes into old when old is not NULL, then value written
 * over them when value is not NULL. */
static void patch_header(const char *path, const char *key, size_t keylen, const void *value,
                         size_t n, void *old) {
  FILE *f = fopen(path, "r+b");
  assert_non_null(f);
  char buf[4096];
  size_t got = fread(buf, 1, sizeof buf, f);
  long at = -1;
  for (size_t i = 0; i + keylen + n <= got && at < 0; i++)
    if (!memcmp(buf + i, key, keylen)) at = (long)(i + keylen);
  assert_true(at >= 0);
  if (old) memcpy(old, buf + at, n);
  if (value) {
    fseek(f, at, SEEK_SET);
    assert_int_equal(fwrite(value, 1, n, f), n);
  }
  fclose(f);
}

/* Replaces the value byte of the header's compression attribute. */
static void set_compression(const char *path, int value) {
  static const char key[] = "compression\0compression\0\1\0\0\0";
  unsigned char v = (unsigned char)value;
  patch_header(path, key, sizeof key - 1, &v, 1, NULL);
}

static void test_undecodable_compression(void **state) {
  char err[512];
  hf_image img;
  int rc = hf_exr_read(test_field("exr-dwaa.exr"), &img, err, sizeof err);
  if (rc == HF_OK) {  /* an OpenEXR that decodes DWAA: nothing to refuse */
    hf_image_free(&img);
    return;
  }
  assert_int_equal(rc, HF_EUNSUPPORTED);
  assert_non_null(strstr(err, "exr-dwaa.exr"));
  assert_non_null(strstr(err, "DWAA compression"));
  assert_non_null(strstr(err, "--compression zip"));
  /* DWAB as well (a file that says so: the library stops at the name). */
  part_spec p = {"d", 0, 0, 0, 0, 0, 0, 12, 40, 6, FEAT6, EXR_COMPRESSION_ZIP, 0.5f, NULL};
  const char *path = test_tmp("dwab.exr");
  write_parts(path, &p, 1);
  set_compression(path, EXR_COMPRESSION_DWAB);
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EUNSUPPORTED);
  assert_non_null(strstr(err, "DWAB compression"));
  /* A compression code no OpenEXR defines, which the library reports and
   * replaces with ZIP: refused in its words, before any decoding. */
  write_parts(path, &p, 1);
  set_compression(path, 42);
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "'compression'"));
  assert_non_null(strstr(err, "Invalid value 42"));
  assert_non_null(strstr(err, "damaged"));
}

/* B44 stores 32-bit channels as they are; OpenEXRCore before 3.2 decodes
 * those of files written by OpenEXR's C++ library wrongly, so they are
 * refused there (tests/data/exr-b44-float.exr: 8x8, 24 FLOAT channels,
 * channel c of pixel (x, y) = 0.25 + 0.01 c + 0.001 y + 0.0001 x in the
 * order of FEATURES.md, written by OpenImageIO 2.4.7); a later OpenEXR
 * must read every value exactly. */
static void test_b44_float(void **state) {
  char err[512];
  hf_image img;
  int maj = 0, min = 0, pat = 0;
  exr_get_library_version(&maj, &min, &pat, NULL);
  int rc = hf_exr_read(test_data("exr-b44-float.exr"), &img, err, sizeof err);
  if (maj < 3 || (maj == 3 && min < 2)) {
    assert_int_equal(rc, HF_EUNSUPPORTED);
    assert_non_null(strstr(err, "is 32-bit in a B44-compressed part"));
    assert_non_null(strstr(err, "--compression zip"));
    return;
  }
  assert_int_equal(rc, HF_OK);
  static const char *const feats[] = {"color", "highlight", "alpha", "depth", "tangent.x",
                                      "tangent.y"};
  for (int c = 0; c < img.channels; c++) {
    int k = -1, fi = -1;
    for (int kk = 0; kk < 4; kk++)
      for (int ff = 0; ff < 6; ff++) {
        char name[32];
        snprintf(name, sizeof name, "S%d.%s", kk, feats[ff]);
        if (!strcmp(name, img.names[c])) k = kk, fi = ff;
      }
    assert_true(k >= 0);
    for (int y = 0; y < 8; y++)
      for (int x = 0; x < 8; x++)
        assert_true(same_bits(img.data[((size_t)y * 8 + (size_t)x) * (size_t)img.channels +
                                       (size_t)c],
                              (float)(0.25f + (k * 6 + fi) * 0.01f + y * 0.001f + x * 0.0001f)));
  }
  hf_image_free(&img);
}

/* B44 and B44A chunks that compression would not make smaller are stored
 * raw by OpenEXR's C++ writer (a chunk of 1 row, a 2x2 edge tile): they
 * read exactly. tests/data/exr-b44-raw-scanlines.exr (6x33, B44, the
 * last chunk one row) and exr-b44a-raw-tiles.exr (6x6 in 4x4 tiles,
 * B44A, tile (1, 1) 2x2), half channels c0..c4: channel c of pixel
 * (x, y) = c + 0.5 x + 0.25 y, written by OpenImageIO 2.4.7; the blocks
 * B44 compressed are within its error (0.25 here) of it. */
static void test_b44_raw_chunks(void **state) {
  static const struct {
    const char *file;
    int w, h, exact_x, exact_y;   /* pixels from (exact_x, exact_y) on are stored raw */
  } files[] = {{"exr-b44-raw-scanlines.exr", 6, 33, 0, 32}, {"exr-b44a-raw-tiles.exr", 6, 6, 4, 4}};
  for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
    char err[512];
    hf_image img;
    assert_int_equal(hf_exr_read(test_data(files[i].file), &img, err, sizeof err), HF_OK);
    assert_true(img.width == files[i].w && img.height == files[i].h && img.channels == 5);
    for (int y = 0; y < img.height; y++)
      for (int x = 0; x < img.width; x++)
        for (int c = 0; c < 5; c++) {
          float v = img.data[((size_t)y * (size_t)img.width + (size_t)x) * 5 + (size_t)c];
          float want = (float)c + 0.5f * (float)x + 0.25f * (float)y;
          if (x >= files[i].exact_x && y >= files[i].exact_y) assert_true(same_bits(v, want));
          else assert_true(fabsf(v - want) <= 0.25f);
        }
    hf_image_free(&img);
  }
}

/* A part of exactly four HALF channels (tests/data/exr-half-4ch.exr: 5x3,
 * ZIP, c0..c3, channel c of pixel (x, y) = c + 0.5 x + 0.25 y, written by
 * OpenImageIO 2.4.7) reads with each channel under its own name, as
 * float32 (which OpenEXRCore 3.1.5 widens in reverse channel order) and as
 * halves. */
static void test_four_half_channels(void **state) {
  for (int as_half = 0; as_half < 2; as_half++) {
    char err[512];
    hf_image img;
    void *data = NULL;
    assert_int_equal(hf_exr_read_part_as(test_data("exr-half-4ch.exr"), NULL, NULL,
                                         as_half ? HF_F16 : HF_F32, &img, &data, err, sizeof err),
                     HF_OK);
    assert_true(img.width == 5 && img.height == 3 && img.channels == 4);
    for (int c = 0; c < 4; c++) {
      char name[8];
      snprintf(name, sizeof name, "c%d", c);
      int k = hf_image_channel(&img, name);
      assert_true(k >= 0);
      for (int y = 0; y < 3; y++)
        for (int x = 0; x < 5; x++) {
          size_t i = ((size_t)y * 5 + (size_t)x) * 4 + (size_t)k;
          float v = as_half ? hf_f16_to_f32(((const uint16_t *)data)[i]) : ((const float *)data)[i];
          assert_true(same_bits(v, (float)c + 0.5f * (float)x + 0.25f * (float)y));
        }
    }
    free(data);
    hf_image_free(&img);
  }
  /* And into the image's own floats. */
  char err[512];
  hf_image img;
  assert_int_equal(hf_exr_read(test_data("exr-half-4ch.exr"), &img, err, sizeof err), HF_OK);
  int k = hf_image_channel(&img, "c3");
  assert_true(k >= 0 && same_bits(img.data[k], 3.0f));
  hf_image_free(&img);
}

/* Sets the header's data window to w x h pixels from its origin. */
static void set_data_window(const char *path, int w, int h) {
  static const char key[] = "dataWindow\0box2i\0\x10\0\0\0";
  int32_t box[4];
  patch_header(path, key, sizeof key - 1, NULL, sizeof box, box);
  box[2] = box[0] + w - 1;
  box[3] = box[1] + h - 1;
  patch_header(path, key, sizeof key - 1, box, sizeof box, NULL);
}

/* A header that claims more pixels than the file's data can decode to (a
 * few KB claiming 1.9 GB) is refused as damaged before the image is
 * allocated, for each compression's bound; a real file at the bound of its
 * compression reads (tests/fuzz/regressions/exr: what the fuzzer found). */
static void test_claimed_size(void **state) {
  char err[512];
  hf_image img;
  static const exr_compression_t comps[] = {EXR_COMPRESSION_NONE, EXR_COMPRESSION_RLE,
                                            EXR_COMPRESSION_ZIP, EXR_COMPRESSION_PIZ};
  for (size_t k = 0; k < sizeof comps / sizeof comps[0]; k++) {
    part_spec p = {"c", 0, 0, 0, 0, 0, 0, 40, 70, 6, FEAT6, comps[k], 0.25f, NULL};
    const char *path = test_tmp("claims.exr");
    write_parts(path, &p, 1);
    set_data_window(path, 9000, 9000);
    /* Damaged, or, where the chunk table 9000 rows need does not fit in
     * the file either, as a file cut short would be: truncated or damaged. */
    int rc = hf_exr_read(path, &img, err, sizeof err);
    assert_true(rc == HF_EFORMAT || (rc == HF_EIO && strstr(err, "chunk table does not fit") &&
                                     strstr(err, "truncated / incomplete")));
    assert_non_null(strstr(err, "claims 9000x9000 pixels of 6 channels (1944.0 MB of pixels)"));
    assert_non_null(strstr(err, "damaged"));
    assert_null(img.data);
  }
  /* Zeros compress best: 1024x1024 of 4 channels in ZIP reads. */
  float *zeros = calloc((size_t)1024 * 1024 * 4, sizeof(float));
  assert_non_null(zeros);
  static const char *const four[] = {"A", "B", "G", "R"};
  part_spec z = {"z", 0, 0, 0, 0, 0, 0, 1024, 1024, 4, four, EXR_COMPRESSION_ZIP, 0, zeros};
  write_parts(test_tmp("zeros.exr"), &z, 1);
  assert_int_equal(hf_exr_read(test_tmp("zeros.exr"), &img, err, sizeof err), HF_OK);
  assert_true(img.width == 1024 && img.height == 1024 && img.data[4 * 1024 * 1024 - 1] == 0);
  hf_image_free(&img);
  free(zeros);
}

/* Lossy compressions are named on the image: B44 of half channels (the
 * file tests/data/exr-b44-half.exr, 8x8, 4 samples, written by
 * OpenImageIO), PXR24 of float ones; PXR24 of half ones (the base frame
 * as written) and ZIP keep every value (B44 of float ones:
 * test_b44_float). */
static void test_lossy_compression(void **state) {
  char err[512];
  hf_image img;
  assert_int_equal(hf_exr_read(test_data("exr-b44-half.exr"), &img, err, sizeof err), HF_OK);
  assert_string_equal(img.lossy, "B44");
  hf_image_free(&img);
  const struct {
    exr_compression_t c;
    const char *lossy;
  } cases[] = {{EXR_COMPRESSION_PXR24, "PXR24"}, {EXR_COMPRESSION_ZIP, NULL}};
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    part_spec p = {"l", 0, 0, 0, 0, 0, 0, 8, 8, 6, FEAT6, cases[i].c, 0.5f, NULL};
    const char *path = test_tmp("lossy.exr");
    write_parts(path, &p, 1);
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_OK);
    if (cases[i].lossy) assert_string_equal(img.lossy, cases[i].lossy);
    else assert_null(img.lossy);
    hf_image_free(&img);
  }
}

/* A chunk written by one compression in a file whose header names PXR24,
 * B44 or B44A (a damaged or mislabelled file) is refused as damaged, not
 * decoded into plausible garbage (src/exr_chunk_size.c): a ZIP file of
 * FLOAT channels relabelled PXR24, and of HALF ones relabelled B44 and
 * B44A. The files as written, and the real PXR24 and B44 files of
 * test_lossy_compression and test_b44_raw_chunks, read. */
static void test_mislabelled_compression(void **state) {
  static const struct {
    int half;
    exr_compression_t as;
  } cases[] = {{0, EXR_COMPRESSION_PXR24}, {1, EXR_COMPRESSION_B44}, {1, EXR_COMPRESSION_B44A}};
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    hf_image img, back;
    assert_int_equal(hf_image_alloc(&img, 32, 32, 6), HF_OK);
    for (int c = 0; c < 6; c++) snprintf(img.names[c], 32, "c%d", c);
    for (size_t k = 0; k < (size_t)32 * 32 * 6; k++) img.data[k] = value(3, k, 6);
    const char *path = test_tmp("relabelled.exr");
    assert_int_equal(hf_exr_write(path, &img, cases[i].half), HF_OK);
    hf_image_free(&img);
    char err[512];
    assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
    hf_image_free(&back);
    set_compression(path, cases[i].as);
    int rc = hf_exr_read(path, &back, err, sizeof err);
    if (rc == HF_OK) {
      hf_image_free(&back);
      fail_msg("case %zu: a ZIP file labelled compression %d read", i, (int)cases[i].as);
    }
    assert_int_equal(rc, HF_EFORMAT);
    assert_non_null(strstr(err, "relabelled.exr"));
    assert_non_null(strstr(err, "damaged"));
  }
}

static void test_subsampled_refused(void **state) {
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  exr_context_t ctx;
  const char *path = test_tmp("sub.exr");
  char err[512];
  int idx;
  assert_int_equal(exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init), 0);
  assert_int_equal(exr_add_part(ctx, "main", EXR_STORAGE_SCANLINE, &idx), 0);
  assert_int_equal(exr_initialize_required_attr_simple(ctx, idx, 8, 8, EXR_COMPRESSION_NONE), 0);
  assert_int_equal(exr_add_channel(ctx, idx, "Y", EXR_PIXEL_HALF, EXR_PERCEPTUALLY_LINEAR, 1, 1), 0);
  assert_int_equal(exr_add_channel(ctx, idx, "RY", EXR_PIXEL_HALF, EXR_PERCEPTUALLY_LINEAR, 2, 2), 0);
  assert_int_equal(exr_write_header(ctx), 0);
  /* Uncompressed lines: RY (4 samples, even lines only), then Y (8). */
  uint16_t line[12] = {0};
  for (int y = 0; y < 8; y++)
    assert_int_equal(exr_write_scanline_chunk(ctx, idx, y, y % 2 ? line + 4 : line,
                                              y % 2 ? 16 : 24), 0);
  assert_int_equal(exr_finish(&ctx), 0);
  hf_image img;
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EUNSUPPORTED);
  assert_non_null(strstr(err, "channel RY is subsampled"));
}

/* A channel listed twice, of a pixel type OpenEXRCore does not know, or
 * of a sampling below 1: OpenEXRCore refuses the list and calls it "not
 * found"; the refusal names the channel and what is wrong with it
 * (OpenEXR's C++ library, and weights/dataset.py through it, kept one of
 * two channels of a name). */
static void test_channel_list_faults(void **state) {
  (void)state;
  static const struct {
    const char *to;           /* S0.color's name becomes */
    int at, value;            /* and the int32 this many bytes past its NUL this */
    const char *want;
  } cases[] = {
      {"S0.alpha", 0, 2, "channel \"S0.alpha\" is listed twice in the channel list of part 0"},
      {"S0.color", 0, 7, "channel \"S0.color\" of part 0 has pixel type 7, not UINT (0), HALF (1) "
                         "or FLOAT (2)"},
      {"S0.color", 8, 0, "channel \"S0.color\" of part 0 has sampling 0x1, below 1"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    hf_image img;
    assert_int_equal(hf_image_alloc(&img, 4, 3, 2), HF_OK);
    snprintf(img.names[0], 32, "S0.alpha");
    snprintf(img.names[1], 32, "S0.color");
    for (size_t k = 0; k < 24; k++) img.data[k] = 0.5f;
    const char *path = test_tmp("chlist.exr");
    assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
    hf_image_free(&img);
    FILE *f = fopen(path, "r+b");
    assert_non_null(f);
    unsigned char buf[4096];
    size_t n = fread(buf, 1, sizeof buf, f);
    size_t at = 0;
    while (at + 9 <= n && memcmp(buf + at, "S0.color", 9)) at++;
    assert_true(at + 9 + 16 <= n);
    memcpy(buf + at, cases[i].to, 8);
    unsigned char *v = buf + at + 9 + cases[i].at;
    v[0] = (unsigned char)cases[i].value;
    v[1] = v[2] = v[3] = 0;
    assert_int_equal(fseek(f, 0, SEEK_SET), 0);
    assert_int_equal(fwrite(buf, 1, n, f), n);
    assert_int_equal(fclose(f), 0);
    char err[512];
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EFORMAT);
    if (!strstr(err, cases[i].want) || !strstr(err, "chlist.exr")) fail_msg("%s", err);
  }
}

static void test_not_exr(void **state) {
  char err[512];
  const char *path = test_tmp("junk.exr");
  FILE *f = fopen(path, "wb");
  fputs("P6\n1 1\n255\n...", f);
  fclose(f);
  hf_image img;
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "not an OpenEXR file"));
  assert_int_equal(hf_exr_read(test_tmp("missing.exr"), &img, err, sizeof err), HF_EIO);
  assert_non_null(strstr(err, "No such file"));
  /* An empty file, and one cut inside the 4-byte magic number, are not
   * files of another kind: said as empty or cut short. */
  f = fopen(path, "wb");
  fclose(f);
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EIO);
  if (!strstr(err, "empty") || !strstr(err, "junk.exr")) fail_msg("0 bytes: %s", err);
  static const unsigned char magic[4] = {0x76, 0x2f, 0x31, 0x01};
  for (size_t n = 1; n < 4; n++) {
    f = fopen(path, "wb");
    fwrite(magic, 1, n, f);
    fclose(f);
    assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EIO);
    if (!strstr(err, "truncated / incomplete")) fail_msg("%zu bytes: %s", n, err);
  }
  f = fopen(path, "wb");
  fputs("P6", f);
  fclose(f);
  assert_int_equal(hf_exr_read(path, &img, err, sizeof err), HF_EFORMAT);
  assert_non_null(strstr(err, "not an OpenEXR file"));
}

/* More samples than any network reads (HF_MAX_SPP): counted, and the first
 * spp of them read, as protocol/FEATURES.md says. */
static void test_many_samples(void **state) {
  int spp = HF_MAX_SPP + 4, w = 3, h = 2;
  size_t n = (size_t)w * h * spp * 6;
  float *in = malloc(n * sizeof(float)), got[3 * 2 * 4 * 6];
  for (size_t i = 0; i < n; i++) in[i] = (float)i;
  hf_image img, back;
  char err[512];
  const char *path = test_tmp("many.exr");
  assert_int_equal(hf_image_alloc(&img, w, h, spp * 6), HF_OK);
  for (int k = 0; k < spp; k++)
    for (int f = 0; f < 6; f++) snprintf(img.names[k * 6 + f], 32, "S%d.%s", k, HF_FEATURE_NAMES[f]);
  memcpy(img.data, in, n * sizeof(float));
  assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  assert_int_equal(hf_features_spp(&back), spp);
  assert_int_equal(hf_features_from_image(&back, 4, got), 4);
  for (int p = 0; p < w * h; p++)
    assert_memory_equal(got + p * 24, in + (size_t)p * spp * 6, 24 * sizeof(float));
  hf_image_free(&back);
  hf_image_free(&img);
  free(in);
}

static int setup(void **state) { return test_tmp_create("hf_test_exr"); }
static int teardown(void **state) { return test_tmp_remove(); }


/* Read as halves, a HALF file gives its stored bits and a FLOAT file
 * hf_f32_to_f16 of its values (finite ones beyond half's range the largest
 * half of their sign); read as float32, the halves widened. Every
 * finite half pattern is stored once (65,536 less the infinities and NaNs,
 * padded with zeros to 128 x 128 pixels of one sample's 6 features). The
 * library sorts channels by name, so values are compared after the
 * features are gathered back into the network's order. */
static void test_read_as_halves(void **state) {
  (void)state;
  const int w = 128, h = 128, nch = HF_FEATURES_PER_SAMPLE;
  const size_t n = (size_t)w * h * nch;
  hf_image img;
  assert_int_equal(hf_image_alloc(&img, w, h, nch), HF_OK);
  for (int c = 0; c < nch; c++) snprintf(img.names[c], 32, "S0.%s", HF_FEATURE_NAMES[c]);
  uint16_t *bits = calloc(n, sizeof *bits), *in16 = malloc(n * sizeof *in16);
  float *in32 = malloc(n * sizeof *in32);
  assert_true(bits && in16 && in32);
  size_t k = 0;
  for (uint32_t b = 0; b < 65536; b++)
    if ((b & 0x7c00u) != 0x7c00u) bits[k++] = (uint16_t)b;
  for (size_t i = 0; i < n; i++) img.data[i] = hf_f16_to_f32(bits[i]);
  img.origin_x = -3;
  img.origin_y = 5;
  const char *path = test_tmp("halves.exr");
  assert_int_equal(hf_exr_write(path, &img, 1), HF_OK);

  char err[512];
  hf_image got;
  void *data = NULL;
  assert_int_equal(hf_exr_read_part_as(path, NULL, NULL, HF_F16, &got, &data, err, sizeof err),
                   HF_OK);
  assert_null(got.data);
  assert_int_equal(got.width, w);
  assert_int_equal(got.height, h);
  assert_int_equal(got.channels, nch);
  assert_int_equal(got.origin_x, -3);
  assert_int_equal(got.origin_y, 5);
  assert_int_equal(hf_features_from_data(&got, data, HF_F16, 1, in16), 1);
  assert_memory_equal(in16, bits, n * sizeof *bits);
  free(data);
  hf_image_free(&got);

  assert_int_equal(hf_exr_read_part_as(path, NULL, NULL, HF_F32, &got, &data, err, sizeof err),
                   HF_OK);
  assert_int_equal(hf_features_from_data(&got, data, HF_F32, 1, in32), 1);
  for (size_t i = 0; i < n; i++)
    if (!same_bits(in32[i], hf_f16_to_f32(bits[i]))) fail_msg("value %zu: %a", i, (double)in32[i]);
  free(data);
  hf_image_free(&got);

  /* FLOAT channels holding values between halves: one rounding, ours. */
  for (size_t i = 0; i < n; i++) img.data[i] = value(i % 2 ? 0 : 2, i, nch);
  assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
  assert_int_equal(hf_exr_read_part_as(path, NULL, NULL, HF_F16, &got, &data, err, sizeof err),
                   HF_OK);
  assert_int_equal(hf_features_from_data(&got, data, HF_F16, 1, in16), 1);
  for (size_t i = 0; i < n; i++) {
    uint16_t want = hf_f32_to_f16(img.data[i]);
    if ((want & 0x7fffu) == 0x7c00u) want--; /* finite beyond half's range: below */
    if (in16[i] != want) fail_msg("value %zu: 0x%04x for %a", i, in16[i], (double)img.data[i]);
  }
  assert_int_equal(hf_features_from_data(&got, data, HF_F16, 2, in16), HF_ENOTFOUND);
  free(data);
  hf_image_free(&got);

  /* A finite FLOAT value beyond binary16's range is read as the largest
   * half of its sign, not rounded to an infinity the file does not hold:
   * the sanitising rule then clamps it as it does in float32, instead of
   * making the whole sample uncovered (protocol/FEATURES.md). Infinities
   * and NaNs stay what they are. */
  {
    const float big[] = {1e9f, -70000.0f, 65520.0f, 65504.0f, 3.4e38f, INFINITY, -INFINITY, NAN};
    const uint16_t want[] = {0x7bff, 0xfbff, 0x7bff, 0x7bff, 0x7bff, 0x7c00, 0xfc00, 0};
    const size_t nb = sizeof big / sizeof big[0];
    for (size_t i = 0; i < n; i++) img.data[i] = i < nb ? big[i] : 0.5f;
    assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
    assert_int_equal(hf_exr_read_part_as(path, NULL, NULL, HF_F16, &got, &data, err, sizeof err),
                     HF_OK);
    assert_int_equal(hf_features_from_data(&got, data, HF_F16, 1, in16), 1);
    for (size_t i = 0; i < nb; i++) {
      if (isnan(big[i])) {
        if ((in16[i] & 0x7c00u) != 0x7c00u || !(in16[i] & 0x3ffu))
          fail_msg("value %zu: 0x%04x for NaN", i, in16[i]);
      } else if (in16[i] != want[i]) {
        fail_msg("value %zu: 0x%04x for %g, want 0x%04x", i, in16[i], (double)big[i], want[i]);
      }
    }
    free(data);
    hf_image_free(&got);
  }

  /* Errors release everything and name the file. */
  data = (void *)1;
  assert_int_equal(hf_exr_read_part_as(test_tmp("no-such.exr"), NULL, NULL, HF_F16, &got, &data,
                                       err, sizeof err), HF_EIO);
  assert_null(data);
  assert_non_null(strstr(err, "no-such.exr"));
  data = (void *)1;
  assert_int_equal(hf_exr_read_part_as(path, NULL, NULL, (hf_dtype)7, &got, &data, err,
                                       sizeof err), HF_EINVAL);
  assert_null(data);
  hf_image_free(&img);
  free(bits);
  free(in16);
  free(in32);
}

/* Int attributes written into the header read back by name, with the
 * pixels unchanged; absent ones, a name without a tool's prefix and a file
 * that is not an EXR are told apart. */
static void test_int_attrs(void **state) {
  (void)state;
  hf_image img;
  assert_int_equal(hf_image_alloc(&img, 5, 3, 2), HF_OK);
  snprintf(img.names[0], 32, "a");
  snprintf(img.names[1], 32, "b");
  for (int i = 0; i < 30; i++) img.data[i] = (float)i * 0.25f;
  const char *path = test_tmp("attrs.exr");
  hf_exr_int_attr attrs[2] = {{"hairfilter:gtSupersample", 8}, {"hairfilter:gtSharedPositions", -1}};
  assert_int_equal(hf_exr_write_attrs(path, &img, 1, attrs, 2), HF_OK);
  int v = 99;
  assert_int_equal(hf_exr_read_int_attr(path, "hairfilter:gtSupersample", &v), HF_OK);
  assert_int_equal(v, 8);
  assert_int_equal(hf_exr_read_int_attr(path, "hairfilter:gtSharedPositions", &v), HF_OK);
  assert_int_equal(v, -1);
  assert_int_equal(hf_exr_read_int_attr(path, "hairfilter:other", &v), HF_ENOTFOUND);
  /* A standard attribute of another type. */
  assert_int_equal(hf_exr_read_int_attr(path, "pixelAspectRatio", &v), HF_EFORMAT);
  char err[256];
  hf_image back;
  assert_int_equal(hf_exr_read(path, &back, err, sizeof err), HF_OK);
  for (int i = 0; i < 30; i++) assert_true(back.data[i] == img.data[i]);
  hf_image_free(&back);
  /* A file hf_exr_write makes has none. */
  assert_int_equal(hf_exr_write(path, &img, 0), HF_OK);
  assert_int_equal(hf_exr_read_int_attr(path, "hairfilter:gtSupersample", &v), HF_ENOTFOUND);
  hf_exr_int_attr bare = {"gtSupersample", 8};
  assert_int_equal(hf_exr_write_attrs(path, &img, 0, &bare, 1), HF_EINVAL);
  assert_int_equal(hf_exr_write_attrs(path, &img, 0, NULL, 1), HF_EINVAL);
  assert_int_equal(hf_exr_read_int_attr(test_tmp("no-such.exr"), "hairfilter:x", &v), HF_EIO);
  hf_image_free(&img);
}

int main(void) {
  const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_int_attrs),
    cmocka_unit_test(test_write_reads_back_exactly), cmocka_unit_test(test_result_of_tall_frame),
    cmocka_unit_test(test_windows),                  cmocka_unit_test(test_tiled),
    cmocka_unit_test(test_multipart),                cmocka_unit_test(test_truncated),
    cmocka_unit_test(test_undecodable_compression),  cmocka_unit_test(test_subsampled_refused),
    cmocka_unit_test(test_channel_list_faults),
    cmocka_unit_test(test_lossy_compression),        cmocka_unit_test(test_claimed_size),
    cmocka_unit_test(test_mislabelled_compression),
    cmocka_unit_test(test_not_exr),                  cmocka_unit_test(test_many_samples),
    cmocka_unit_test(test_read_as_halves),           cmocka_unit_test(test_damaged_chunk_table),
    cmocka_unit_test(test_b44_float),                cmocka_unit_test(test_short_uncompressed_chunk),
    cmocka_unit_test(test_b44_raw_chunks),             cmocka_unit_test(test_four_half_channels),
    cmocka_unit_test(test_small_file_bad_leader), cmocka_unit_test(test_damaged_header_not_cut),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
