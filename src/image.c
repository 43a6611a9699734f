/* Named-channel float images and compositing. */
#include <float.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"

int hf_image_alloc(hf_image *img, int width, int height, int channels) {
  if (!img) return HF_EINVAL;
  memset(img, 0, sizeof *img);
  if (width < 1 || height < 1 || channels < 1 || channels > 4096) return HF_ERANGE;
  if ((size_t)width * height > ((size_t)1 << 31) / sizeof(float) / (size_t)channels)
    return HF_ERANGE;
  img->names = calloc((size_t)channels, sizeof *img->names);
  img->data = calloc((size_t)width * height * channels, sizeof(float));
  if (!img->names || !img->data) {
    hf_image_free(img);
    return HF_ENOMEM;
  }
  img->width = width;
  img->height = height;
  img->channels = channels;
  return HF_OK;
}

void hf_image_free(hf_image *img) {
  if (!img) return;
  free(img->names);
  free(img->data);
  free(img->uint_stored);
  memset(img, 0, sizeof *img);
}

int hf_image_channel(const hf_image *img, const char *name) {
  if (!img || !name) return HF_EINVAL;
  for (int c = 0; c < img->channels; c++)
    if (!strcmp(img->names[c], name)) return c;
  return HF_ENOTFOUND;
}

void hf_image_copy_windows(hf_image *dst, const hf_image *src) {
  if (!dst || !src) return;
  dst->origin_x = src->origin_x;
  dst->origin_y = src->origin_y;
  dst->display_x = src->display_x;
  dst->display_y = src->display_y;
  dst->display_width = src->display_width;
  dst->display_height = src->display_height;
}

void hf_composite(const float *res, int width, int height, const float hair[3],
                  const float light[3], const float bg[3], float *rgb) {
  size_t n = (size_t)width * height;
  for (size_t p = 0; p < n; p++) {
    double col = res[3 * p + HF_OUT_COLOR], hl = res[3 * p + HF_OUT_HIGHLIGHT];
    double a = res[3 * p + HF_OUT_ALPHA];
    for (int c = 0; c < 3; c++) {
      /* In double, finite float colours up to FLT_MAX times result values
       * in their documented ranges cannot overflow (three factors of at
       * most ~3.4e38 and a result factor stay far under DBL_MAX); the
       * float result saturates. */
      double v = a * light[c] * (hair[c] * col + hl) + (1.0 - a) * bg[c];
      rgb[3 * p + c] = v != v ? 0.0f : v > FLT_MAX ? FLT_MAX : v < -FLT_MAX ? -FLT_MAX : (float)v;
    }
  }
}
