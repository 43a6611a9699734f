/* Writes a small dataset frame and random weights for the end-to-end test
 * of `hairfilter eval`: make_eval_frame DIR. The frame's st4.* channels
 * equal the ground truth (that row must score PSNR inf, SSIM 1) and st16.*
 * is the truth with alpha scaled by 0.5 on every hair pixel.
 *
 * DIR/seq/ holds a two-frame sequence for --temporal: the same frame, then
 * that frame with the colour factor of the truth and of every baseline
 * 0.8 -> 0.6 on the hair pixels. With the default look (hair colour mean
 * 0.27333, light 1) the composite moves by alpha * 0.2 * 0.27333 per
 * channel: 0.03280 for the truth and st4 (alpha 0.6), 0.01640 for st16
 * (alpha 0.3). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "hfcore.h"

#define W 48
#define H 40

static int write_frame(const char *path, float gt_color) {
  static const char *groups[] = {"gt", "st4", "st16"};
  const int spp = 4, nfeat = spp * HF_FEATURES_PER_SAMPLE;
  hf_image img = {0};
  if (hf_image_alloc(&img, W, H, nfeat + 9)) return 1;
  for (int k = 0; k < spp; k++)
    for (int f = 0; f < HF_FEATURES_PER_SAMPLE; f++)
      snprintf(img.names[k * 6 + f], 32, "S%d.%s", k, HF_FEATURE_NAMES[f]);
  for (int g = 0; g < 3; g++)
    for (int f = 0; f < 3; f++) snprintf(img.names[nfeat + 3 * g + f], 32, "%s.%s", groups[g], HF_OUTPUT_NAMES[f]);
  uint32_t s = 12345;
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      float *px = img.data + ((size_t)y * W + x) * img.channels;
      int hair = (x + 2 * y) % 7 < 3;   /* diagonal strands */
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
      px[nfeat + 8] *= 0.5f;
    }
  int rc = hf_exr_write(path, &img, 0);
  hf_image_free(&img);
  if (rc) fprintf(stderr, "make_eval_frame: %s: %s\n", path, hf_strerror(rc));
  return rc;
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
  int rc;
  hf_net_config cfg;
  hf_weights *w = NULL;
  if (hf_variant_preset("Small", &cfg) || hf_weights_init_random(&cfg, 7, &w)) return 1;
  snprintf(path, sizeof path, "%s/small.safetensors", argv[1]);
  rc = hf_weights_save(path, w);
  hf_weights_free(w);
  return rc ? 1 : 0;
}
