/* Test helper: see exr_parts.h. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "exr_parts.h"

float part_value(const part_spec *p, int c, int x, int y) {
  if (p->data) return p->data[((size_t)(y - p->y0) * p->w + (size_t)(x - p->x0)) * p->nch + c];
  return p->base + (float)c * 1000.0f + (float)y * 100.0f + (float)x;
}

/* Writes the full-resolution level (and for mipmaps the others, zeroed) of
 * every part; float channels. */
void write_parts(const char *path, const part_spec *parts, int nparts) {
  write_parts_uint(path, parts, nparts, NULL);
}

void write_parts_uint(const char *path, const part_spec *parts, int nparts,
                      const char *uint_channel) {
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  exr_context_t ctx;
  assert_int_equal(exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init), 0);
  for (int i = 0; i < nparts; i++) {
    const part_spec *p = &parts[i];
    int idx;
    assert_int_equal(exr_add_part(ctx, p->name, p->tiled ? EXR_STORAGE_TILED : EXR_STORAGE_SCANLINE,
                                  &idx), 0);
    exr_attr_box2i_t dw, disp;
    dw.min.x = p->x0, dw.min.y = p->y0, dw.max.x = p->x0 + p->w - 1, dw.max.y = p->y0 + p->h - 1;
    disp = dw;
    exr_attr_v2f_t center;
    center.x = center.y = 0;
    assert_int_equal(exr_initialize_required_attr(ctx, idx, &disp, &dw, 1.0f, &center, 1.0f,
                                                  EXR_LINEORDER_INCREASING_Y, p->compression), 0);
    if (p->tiled)
      assert_int_equal(exr_set_tile_descriptor(ctx, idx, (uint32_t)p->tile_w, (uint32_t)p->tile_h,
                                               p->mipmap ? EXR_TILE_MIPMAP_LEVELS
                                                         : EXR_TILE_ONE_LEVEL,
                                               EXR_TILE_ROUND_DOWN), 0);
    for (int c = 0; c < p->nch; c++)
      assert_int_equal(exr_add_channel(ctx, idx, p->channels[c],
                                       uint_channel && !strcmp(uint_channel, p->channels[c])
                                           ? EXR_PIXEL_UINT
                                           : EXR_PIXEL_FLOAT,
                                       EXR_PERCEPTUALLY_LINEAR, 1, 1), 0);
  }
  assert_int_equal(exr_write_header(ctx), 0);
  for (int i = 0; i < nparts; i++) {
    const part_spec *p = &parts[i];
    const exr_attr_chlist_t *chl;
    assert_int_equal(exr_get_channels(ctx, i, &chl), 0);
    int levels = 1;
    if (p->tiled && p->mipmap) {
      int32_t lx, ly;
      assert_int_equal(exr_get_tile_levels(ctx, i, &lx, &ly), 0);
      levels = lx;
    }
    for (int lv = 0; lv < levels; lv++) {
      int lw = p->w, lh = p->h, cw, chh;
      if (p->tiled) assert_int_equal(exr_get_level_sizes(ctx, i, lv, lv, &lw, &lh), 0);
      cw = p->tiled ? p->tile_w : lw;
      int32_t spc = 1;
      if (!p->tiled) assert_int_equal(exr_get_scanlines_per_chunk(ctx, i, &spc), 0);
      chh = p->tiled ? p->tile_h : spc;
      for (int ty = 0; ty * chh < lh; ty++)
        for (int tx = 0; tx * cw < lw; tx++) {
          int bw = lw - tx * cw < cw ? lw - tx * cw : cw, bh = lh - ty * chh < chh ? lh - ty * chh : chh;
          float *buf = calloc((size_t)bw * bh * p->nch, sizeof(float));
          for (int c = 0; c < p->nch; c++)
            for (int y = 0; y < bh; y++)
              for (int x = 0; x < bw; x++)
                buf[((size_t)c * bh + y) * bw + x] =
                    lv ? 0.0f : part_value(p, c, p->x0 + tx * cw + x, p->y0 + ty * chh + y);
          exr_chunk_info_t ci;
          if (p->tiled)
            assert_int_equal(exr_write_tile_chunk_info(ctx, i, tx, ty, lv, lv, &ci), 0);
          else
            assert_int_equal(exr_write_scanline_chunk_info(ctx, i, p->y0 + ty * chh, &ci), 0);
          exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
          assert_int_equal(exr_encoding_initialize(ctx, i, &ci, &enc), 0);
          for (int c = 0; c < enc.channel_count; c++) {
            int src = -1;
            for (int k = 0; k < p->nch; k++)
              if (!strcmp(p->channels[k], enc.channels[c].channel_name)) src = k;
            assert_true(src >= 0);
            float *from = buf + (size_t)src * bh * bw;
            enc.channels[c].encode_from_ptr = (const uint8_t *)from;
            enc.channels[c].user_pixel_stride = 4;
            enc.channels[c].user_line_stride = 4 * bw;
            enc.channels[c].user_data_type = EXR_PIXEL_FLOAT;
            enc.channels[c].user_bytes_per_element = 4;
            if (enc.channels[c].data_type == EXR_PIXEL_UINT) {
              /* In place: a uint32 holds each float's value, rounded. */
              for (size_t k = 0; k < (size_t)bh * bw; k++) {
                uint32_t u = from[k] > 0 ? (uint32_t)(from[k] + 0.5f) : 0;
                memcpy(from + k, &u, 4);
              }
              enc.channels[c].user_data_type = EXR_PIXEL_UINT;
            }
          }
          assert_int_equal(exr_encoding_choose_default_routines(ctx, i, &enc), 0);
          assert_int_equal(exr_encoding_run(ctx, i, &enc), 0);
          exr_encoding_destroy(ctx, &enc);
          free(buf);
        }
    }
  }
  assert_int_equal(exr_finish(&ctx), 0);
}
