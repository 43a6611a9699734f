/* 8-bit sRGB PNG previews through libpng's simplified API. */
#include <math.h>
#include <stdlib.h>

#include <png.h>

#include "hfcore.h"

static unsigned char to_srgb8(float v) {
  if (!(v > 0.0f)) return 0; /* also maps NaN to black */
  if (v >= 1.0f) return 255;
  float s = v <= 0.0031308f ? 12.92f * v : 1.055f * powf(v, 1.0f / 2.4f) - 0.055f;
  return (unsigned char)lrintf(s * 255.0f);
}

int hf_png_write_rgb(const char *path, const float *rgb, int width, int height) {
  if (!path || !rgb || width < 1 || height < 1) return HF_EINVAL;
  if ((size_t)width * height > ((size_t)1 << 28)) return HF_ERANGE;
  size_t n = (size_t)width * height * 3;
  unsigned char *buf = malloc(n);
  if (!buf) return HF_ENOMEM;
  for (size_t i = 0; i < n; i++) buf[i] = to_srgb8(rgb[i]);
  png_image img = {0};
  img.version = PNG_IMAGE_VERSION;
  img.width = (png_uint_32)width;
  img.height = (png_uint_32)height;
  img.format = PNG_FORMAT_RGB;
  int ok = png_image_write_to_file(&img, path, 0, buf, 0, NULL);
  free(buf);
  png_image_free(&img);
  return ok ? HF_OK : HF_EIO;
}
