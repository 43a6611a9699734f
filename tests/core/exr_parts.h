/* Test helper: EXR files of any layout written with OpenEXRCore itself
 * (tiled, mipmapped, multi-part, any data window and compression), the
 * kinds other tools write and hf_exr_write does not. */
#ifndef HF_TEST_EXR_PARTS_H
#define HF_TEST_EXR_PARTS_H

#include <openexr.h>

typedef struct part_spec {
  const char *name;
  int tiled, tile_w, tile_h, mipmap;
  int x0, y0, w, h, nch;               /* data window origin and size */
  const char *const *channels;         /* nch names */
  exr_compression_t compression;
  float base;  /* without data: channel c of pixel (x, y) holds base + c*1000 + y*100 + x */
  const float *data;                   /* or [h][w][nch] in channels' order */
} part_spec;

/* The value write_parts stores for channel c of image-space pixel (x, y). */
float part_value(const part_spec *p, int c, int x, int y);
/* Writes every part (float channels; mipmap levels below the first are 0);
 * fails the test on any library error. */
void write_parts(const char *path, const part_spec *parts, int nparts);
/* write_parts with the channel named uint_channel, in every part that has
 * one, stored as UINT (its values rounded). */
void write_parts_uint(const char *path, const part_spec *parts, int nparts,
                      const char *uint_channel);

#endif
