/* Writes a small dataset frame and random weights for the end-to-end test
 * of `hairfilter eval`: make_eval_frame DIR. The frame's st4.* channels
 * equal the ground truth (that row must score PSNR inf, SSIM 1) and st16.*
 * is the truth with alpha scaled by 0.5 on every hair pixel; acst4.* (the
 * alpha-corrected baseline) is the truth in every frame.
 *
 * DIR/seq/ holds a two-frame sequence for --temporal: the same frame, then
 * that frame with the colour factor of the truth and of every baseline
 * 0.8 -> 0.6 on the hair pixels. With the default look (hair colour mean
 * 0.27333, light 1) the composite moves by alpha * 0.2 * 0.27333 per
 * channel: 0.03280 for the truth and st4 (alpha 0.6), 0.01640 for st16
 * (alpha 0.3).
 *
 * DIR/strata/ holds three 56x8 frames for the regime tables, built of 8-pixel
 * column regions whose bucket membership is known exactly:
 *
 *   region  gt alpha           input samples               strand width
 *   R0      0 (no hair)        none                        -
 *   R1      0.2 (sparse)       1 of 4 covered, alpha 0.02  <0.03
 *   R2      0.6 (medium)       2 of 4, alpha 0.05          0.03-0.1
 *   R3      0.6 (medium)       4 of 4, alpha 0.2           0.1-0.3
 *   R4      1   (dense)        4 of 4, alpha 0.5           0.3-0.7
 *   R5      1   (dense)        4 of 4, alpha 0.9           >=0.7
 *   R6      0.2 (sparse)       none                        none
 *
 * a.exr holds R0-R6 (256 bucket: 56 pixels wide, no full size given),
 * b.exr only R4 and R5 (the manifest says it was cut from 512x512), c.exr
 * only R1 and R6 (its EXR display window is 1024x768). Colour 0.8 and
 * highlight 0.1 everywhere; st4.* is the truth, st16.* the truth with half
 * its alpha: with the default look its composite is off by (a/2) (0.28,
 * 0.10, -0.044) per pixel, so its MSE is (a/2)^2 0.090336 / 3.
 * DIR/lattice/dots.exr (64x64, hair everywhere) is for the lattice table:
 * st4.* is the truth and st16.* the truth with colour factor 0.8 -> 1.0 on
 * the pixels where x mod 8 = 3 and y mod 8 = 5, a dot lattice of period 8
 * and nothing else.
 * small_narrow.safetensors is small.safetensors with an input range whose
 * strand_alpha_p50 is [0.015, 0.025]: only c.exr (median 0.02) is inside. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "hfcore.h"

#define W 48
#define H 40

/* A w x h frame of 4 feature samples, then gt.*, st4.*, st16.* and
 * acst4.*, zeroed. */
static int alloc_frame(hf_image *img, int w, int h) {
  static const char *groups[] = {"gt", "st4", "st16", "acst4"};
  const int spp = 4, nfeat = spp * HF_FEATURES_PER_SAMPLE;
  if (hf_image_alloc(img, w, h, nfeat + 12)) return 1;
  for (int k = 0; k < spp; k++)
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++)
      snprintf(img->names[k * 6 + f], 32, "S%d.%s", k, HF_FEATURE_NAMES[f]);
  for (int g = 0; g < 4; g++)
    for (int f = 0; f < 3; f++)
      snprintf(img->names[nfeat + 3 * g + f], 32, "%s.%s", groups[g], HF_OUTPUT_NAMES[f]);
  memset(img->data, 0, (size_t)w * h * img->channels * sizeof(float));
  return 0;
}

/* The frame of straight_0000.exr (w x h, dots 0) or of lattice/dots.exr
 * (dots 1: hair everywhere, st16 the truth plus the dot lattice). */
static int write_frame_wh(const char *path, float gt_color, int w, int h, int dots) {
  const int spp = 4, nfeat = spp * HF_FEATURES_PER_SAMPLE;
  hf_image img = {0};
  if (alloc_frame(&img, w, h)) return 1;
  uint32_t s = 12345;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      float *px = img.data + ((size_t)y * w + x) * img.channels;
      int hair = dots || (x + 2 * y) % 7 < 3;   /* diagonal strands */
      for (int k = 0; k < spp; k++) {
        s = s * 1664525u + 1013904223u;
        int cov = hair && (s >> 30) != 0;
        float *f = px + 6 * k;
        f[0] = cov ? 0.8f : 0;
        f[1] = cov ? 0.1f : 0;
        f[2] = cov ? 0.3f : 0;
        f[3] = cov ? 0.5f : 0;
        f[4] = cov ? 0.447f : 0;
        f[5] = cov ? -0.894f : 0;
      }
      float gt[3] = {hair ? gt_color : 0, hair ? 0.1f : 0, hair ? 0.6f : 0};
      memcpy(px + nfeat, gt, sizeof gt);
      memcpy(px + nfeat + 3, gt, sizeof gt);
      memcpy(px + nfeat + 6, gt, sizeof gt);
      memcpy(px + nfeat + 9, gt, sizeof gt);
      if (!dots) px[nfeat + 8] *= 0.5f;
      else if (x % 8 == 3 && y % 8 == 5) px[nfeat + 6] = 1.0f;
    }
  int rc = hf_exr_write(path, &img, 0);
  hf_image_free(&img);
  if (rc) fprintf(stderr, "make_eval_frame: %s: %s\n", path, hf_strerror(rc));
  return rc;
}

static int write_frame(const char *path, float gt_color) {
  return write_frame_wh(path, gt_color, W, H, 0);
}

/* ---- regime frames ---------------------------------------------------------- */

#define SW 56
#define SH 8

static const struct { float gt_alpha; int covered; float alpha; } REGION[7] = {
  {0, 0, 0}, {0.2f, 1, 0.02f}, {0.6f, 2, 0.05f}, {0.6f, 4, 0.2f},
  {1, 4, 0.5f}, {1, 4, 0.9f}, {0.2f, 0, 0}};

/* Writes a regime frame holding the regions whose bit is set in `regions`. */
static int write_strata_frame(const char *path, unsigned regions) {
  const int nfeat = 4 * HF_FEATURES_PER_SAMPLE;
  hf_image img = {0};
  if (alloc_frame(&img, SW, SH)) return 1;
  for (int y = 0; y < SH; y++)
    for (int x = 0; x < SW; x++) {
      int r = x / 8;
      if (!(regions & (1u << r))) continue;
      float *px = img.data + ((size_t)y * SW + x) * img.channels;
      for (int k = 0; k < REGION[r].covered; k++) {
        float *f = px + 6 * k;
        f[0] = 0.8f, f[1] = 0.1f, f[2] = REGION[r].alpha, f[3] = 0.5f, f[4] = 0.6f, f[5] = -0.8f;
      }
      float gt[3] = {REGION[r].gt_alpha > 0 ? 0.8f : 0, REGION[r].gt_alpha > 0 ? 0.1f : 0,
                     REGION[r].gt_alpha};
      for (int g = 0; g < 4; g++) memcpy(px + nfeat + 3 * g, gt, sizeof gt);
      px[nfeat + 8] *= 0.5f;
    }
  int rc = hf_exr_write(path, &img, 0);
  hf_image_free(&img);
  if (rc) fprintf(stderr, "make_eval_frame: %s: %s\n", path, hf_strerror(rc));
  return rc;
}

/* Makes the file a crop of a w x h image: rewrites its displayWindow
 * attribute (a box2i: four little-endian int32 after the name, the type
 * "box2i" and the size 16) in place. hf_exr_write always writes the data
 * window as the display window; the header is not compressed and keeps
 * its length, so nothing else moves. */
static int set_display_window(const char *path, int w, int h) {
  FILE *f = fopen(path, "r+b");
  if (!f) return 1;
  unsigned char head[4096];
  size_t n = fread(head, 1, sizeof head, f);
  static const char key[] = "displayWindow\0box2i\0\x10\0\0\0";
  size_t klen = sizeof key - 1;
  int rc = 1;
  for (size_t i = 0; i + klen + 16 <= n; i++) {
    if (memcmp(head + i, key, klen)) continue;
    int32_t box[4] = {0, 0, w - 1, h - 1};
    unsigned char le[16];
    for (int k = 0; k < 16; k++) le[k] = (unsigned char)((uint32_t)box[k / 4] >> (8 * (k % 4)));
    rc = fseek(f, (long)(i + klen), SEEK_SET) || fwrite(le, 1, 16, f) != 16;
    break;
  }
  if (fclose(f)) rc = 1;
  if (rc) fprintf(stderr, "make_eval_frame: %s: no displayWindow to rewrite\n", path);
  return rc;
}

static int write_strata(const char *dir) {
  char path[4096];
  snprintf(path, sizeof path, "%s/strata", dir);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/strata/a.exr", dir);
  if (write_strata_frame(path, 0x7f)) return 1;
  snprintf(path, sizeof path, "%s/strata/b.exr", dir);
  if (write_strata_frame(path, (1u << 4) | (1u << 5))) return 1;
  snprintf(path, sizeof path, "%s/strata/c.exr", dir);
  if (write_strata_frame(path, (1u << 1) | (1u << 6)) || set_display_window(path, 1024, 768))
    return 1;
  snprintf(path, sizeof path, "%s/strata/manifest.json", dir);
  FILE *f = fopen(path, "w");
  if (!f) return 1;
  fprintf(f, "{\"format\": \"hairfilter-dataset\", \"version\": 1, \"frames\": [\n"
             "  {\"file\": \"a.exr\", \"style\": \"strata\"},\n"
             "  {\"file\": \"b.exr\", \"style\": \"strata\", \"full_width\": 512, "
             "\"full_height\": 512},\n"
             "  {\"file\": \"c.exr\", \"style\": \"strata\"}]}\n");
  return fclose(f) ? 1 : 0;
}

/* DIR/listed: the set its manifest lists, as weights/train.py joins its
 * entries: a.exr, sub/b.exr (a subdirectory), DIR/outside/elsewhere.exr by
 * its absolute path, and gone.exr (not there); beside them results.exr, which
 * is no EXR at all. `hairfilter eval DIR/listed` must score the three
 * frames alone and say what it left out. */
static int write_listed(const char *dir) {
  char path[4096 + 32], abs_dir[4096];
  if (!realpath(dir, abs_dir)) return 1;
  snprintf(path, sizeof path, "%s/listed", dir);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/listed/sub", dir);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/listed/a.exr", dir);
  if (write_strata_frame(path, 0x7f)) return 1;
  snprintf(path, sizeof path, "%s/listed/sub/b.exr", dir);
  if (write_strata_frame(path, 0x7f)) return 1;
  snprintf(path, sizeof path, "%s/outside", dir);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/outside/elsewhere.exr", abs_dir);
  if (write_strata_frame(path, 0x7f)) return 1;
  snprintf(path, sizeof path, "%s/listed/results.exr", dir);
  FILE *f = fopen(path, "w");
  if (!f || fputs("not a frame\n", f) < 0 || fclose(f)) return 1;
  snprintf(path, sizeof path, "%s/listed/manifest.json", dir);
  f = fopen(path, "w");
  if (!f) return 1;
  fprintf(f, "{\"frames\": [{\"file\": \"a.exr\", \"style\": \"listed\"},\n"
             "            {\"file\": \"sub/b.exr\", \"style\": \"listed\"},\n"
             "            {\"file\": \"%s/outside/elsewhere.exr\", \"style\": \"listed\"},\n"
             "            {\"file\": \"gone.exr\", \"style\": \"listed\"}]}\n", abs_dir);
  return fclose(f) ? 1 : 0;
}

/* DIR/damaged: a.exr beside a manifest.json cut short, which lists no set
 * that can be read: `hairfilter eval DIR` must refuse it, not score every
 * .exr there. */
static int write_damaged(const char *dir) {
  char path[4096];
  snprintf(path, sizeof path, "%s/damaged", dir);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/damaged/a.exr", dir);
  if (write_strata_frame(path, 0x7f)) return 1;
  snprintf(path, sizeof path, "%s/damaged/manifest.json", dir);
  FILE *f = fopen(path, "w");
  if (!f) return 1;
  fprintf(f, "{\"frames\": [{\"file\": \"a.exr\", \"sty");
  return fclose(f) ? 1 : 0;
}

int main(int argc, char **argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: make_eval_frame DIR\n");
    return 2;
  }
  char path[4096];
  mkdir(argv[1], 0777);   /* may exist; writing the frame says if unusable */
  snprintf(path, sizeof path, "%s/seq", argv[1]);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/straight_0000.exr", argv[1]);
  if (write_frame(path, 0.8f)) return 1;
  snprintf(path, sizeof path, "%s/seq/straight_0000.exr", argv[1]);
  if (write_frame(path, 0.8f)) return 1;
  snprintf(path, sizeof path, "%s/seq/straight_0001.exr", argv[1]);
  if (write_frame(path, 0.6f)) return 1;
  snprintf(path, sizeof path, "%s/lattice", argv[1]);
  mkdir(path, 0777);
  snprintf(path, sizeof path, "%s/lattice/dots.exr", argv[1]);
  if (write_frame_wh(path, 0.8f, 64, 64, 1)) return 1;
  int rc;
  hf_net_config cfg;
  hf_weights *w = NULL;
  if (hf_variant_preset("Small", &cfg) || hf_weights_init_random(&cfg, 7, &w)) return 1;
  snprintf(path, sizeof path, "%s/small.safetensors", argv[1]);
  rc = hf_weights_save(path, w);
  if (!rc) {
    static const char narrow[] =
      "{\"definition\": 1, \"spp\": 4, \"frames\": 3, \"strand_alpha_p50\": [0.015, 0.025]}";
    snprintf(path, sizeof path, "%s/small_narrow.safetensors", argv[1]);
    rc = hf_input_range_parse(narrow, 4, &w->input_range, NULL, 0) || hf_weights_save(path, w);
  }
  hf_weights_free(w);
  /* A variant of 8 spp, more samples than the frames hold: a network eval
   * scores on no frame. */
  w = NULL;
  cfg.spp = 8;
  cfg.in_channels = 8 * HF_FEATURES_PER_SAMPLE;
  snprintf(path, sizeof path, "%s/small_8spp.safetensors", argv[1]);
  if (!rc) rc = hf_weights_init_random(&cfg, 7, &w) || hf_weights_save(path, w);
  hf_weights_free(w);
  return rc || write_strata(argv[1]) || write_listed(argv[1]) ||
         write_damaged(argv[1]) ? 1 : 0;
}
