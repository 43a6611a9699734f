/* EXR reading and writing on OpenEXR's C API (OpenEXRCore). Channels are
 * addressed by name: the library keeps them sorted, so callers never rely on
 * file order. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <openexr.h>

#include "hfcore.h"
#include "errors.h"

/* Refuse images over this many samples before allocating (2^31 bytes). */
#define EXR_MAX_FLOATS ((size_t)1 << 29)

#define fail hf_fail_msg

/* Silence the library's own stderr messages: errors are reported to the
 * caller through err instead. */
static void quiet_handler(exr_const_context_t ctxt, exr_result_t code, const char *msg) {}

int hf_exr_read(const char *path, hf_image *img, char *err, size_t errlen) {
  if (!path || !img) return fail(err, errlen, HF_EINVAL, "null argument");
  memset(img, 0, sizeof *img);
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = quiet_handler;
  exr_context_t ctx = NULL;
  exr_result_t r = exr_start_read(&ctx, path, &init);
  if (r != EXR_ERR_SUCCESS)
    return fail(err, errlen, HF_EIO, "%s: %s", path, exr_get_error_code_as_string(r));
  int rc = HF_EFORMAT;
  exr_storage_t storage;
  exr_attr_box2i_t dw;
  const exr_attr_chlist_t *chl;
  int32_t spc;
  if ((r = exr_get_storage(ctx, 0, &storage)) || (r = exr_get_data_window(ctx, 0, &dw)) ||
      (r = exr_get_channels(ctx, 0, &chl)) || (r = exr_get_scanlines_per_chunk(ctx, 0, &spc))) {
    fail(err, errlen, rc, "%s: %s", path, exr_get_error_code_as_string(r));
    goto out;
  }
  if (storage != EXR_STORAGE_SCANLINE) {
    rc = fail(err, errlen, HF_EUNSUPPORTED, "%s: only scanline EXR files are supported", path);
    goto out;
  }
  int64_t w = (int64_t)dw.max.x - dw.min.x + 1, h = (int64_t)dw.max.y - dw.min.y + 1;
  int nch = chl->num_channels;
  if (w < 1 || h < 1 || nch < 1 || (size_t)(w * h) > EXR_MAX_FLOATS / (size_t)nch) {
    rc = fail(err, errlen, HF_ERANGE, "%s: %lldx%lld with %d channels is out of range", path,
              (long long)w, (long long)h, nch);
    goto out;
  }
  for (int c = 0; c < nch; c++)
    if (chl->entries[c].x_sampling != 1 || chl->entries[c].y_sampling != 1) {
      rc = fail(err, errlen, HF_EUNSUPPORTED, "%s: subsampled channel %s", path,
                chl->entries[c].name.str);
      goto out;
    }
  if ((rc = hf_image_alloc(img, (int)w, (int)h, nch)) != 0) {
    fail(err, errlen, rc, "%s: %s", path, hf_strerror(rc));
    goto out;
  }
  for (int c = 0; c < nch; c++)
    snprintf(img->names[c], sizeof img->names[c], "%s", chl->entries[c].name.str);
  for (int64_t y = dw.min.y; y <= dw.max.y; y += spc) {
    exr_chunk_info_t ci;
    exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
    if ((r = exr_read_scanline_chunk_info(ctx, 0, (int)y, &ci)) ||
        (r = exr_decoding_initialize(ctx, 0, &ci, &dec))) {
      rc = fail(err, errlen, HF_EFORMAT, "%s: %s", path, exr_get_error_code_as_string(r));
      goto fail_img;
    }
    for (int c = 0; c < dec.channel_count; c++) {
      exr_coding_channel_info_t *ch = &dec.channels[c];
      ch->decode_to_ptr = (uint8_t *)(img->data + ((size_t)(ci.start_y - dw.min.y) * w) * nch + c);
      ch->user_pixel_stride = (int32_t)(sizeof(float) * nch);
      ch->user_line_stride = (int32_t)(sizeof(float) * nch * w);
      ch->user_data_type = EXR_PIXEL_FLOAT;
      ch->user_bytes_per_element = 4;
    }
    if ((r = exr_decoding_choose_default_routines(ctx, 0, &dec)) ||
        (r = exr_decoding_run(ctx, 0, &dec))) {
      exr_decoding_destroy(ctx, &dec);
      rc = fail(err, errlen, HF_EFORMAT, "%s: %s", path, exr_get_error_code_as_string(r));
      goto fail_img;
    }
    exr_decoding_destroy(ctx, &dec);
  }
  rc = HF_OK;
  goto out;
fail_img:
  hf_image_free(img);
out:
  exr_finish(&ctx);
  return rc;
}

int hf_exr_write(const char *path, const hf_image *img, int half) {
  if (!path || !img || !img->data || img->width < 1 || img->height < 1 || img->channels < 1)
    return HF_EINVAL;
  int w = img->width, h = img->height, nch = img->channels;
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = quiet_handler;
  exr_context_t ctx = NULL;
  int part, rc = HF_EIO;
  uint16_t *tmp = NULL;
  if (exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init)) return HF_EIO;
  if (exr_add_part(ctx, "main", EXR_STORAGE_SCANLINE, &part) ||
      exr_initialize_required_attr_simple(ctx, part, w, h, EXR_COMPRESSION_ZIP))
    goto out;
  for (int c = 0; c < nch; c++)
    if (exr_add_channel(ctx, part, img->names[c], half ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT,
                        EXR_PERCEPTUALLY_LINEAR, 1, 1)) {
      rc = HF_EINVAL; /* duplicate or empty channel name */
      goto out;
    }
  if (exr_write_header(ctx)) goto out;
  int32_t spc;
  if (exr_get_scanlines_per_chunk(ctx, part, &spc)) goto out;
  if (half) {
    /* Convert once up front: the encoder packs, it does not convert. */
    size_t n = (size_t)w * h * nch;
    if (!(tmp = malloc(n * sizeof *tmp))) {
      rc = HF_ENOMEM;
      goto out;
    }
    for (size_t i = 0; i < n; i++) tmp[i] = hf_f32_to_f16(img->data[i]);
  }
  const exr_attr_chlist_t *chl;
  if (exr_get_channels(ctx, part, &chl)) goto out;
  for (int y = 0; y < h; y += spc) {
    exr_chunk_info_t ci;
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    if (exr_write_scanline_chunk_info(ctx, part, y, &ci) ||
        exr_encoding_initialize(ctx, part, &ci, &enc))
      goto out;
    int ok = 1;
    for (int c = 0; c < enc.channel_count; c++) {
      exr_coding_channel_info_t *ch = &enc.channels[c];
      int src = hf_image_channel(img, ch->channel_name);
      if (src < 0) ok = 0;
      size_t off = ((size_t)y * w) * nch + (src < 0 ? 0 : src);
      int esz = half ? 2 : 4;
      ch->encode_from_ptr = half ? (const uint8_t *)(tmp + off) : (const uint8_t *)(img->data + off);
      ch->user_pixel_stride = esz * nch;
      ch->user_line_stride = esz * nch * w;
      ch->user_data_type = half ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT;
      ch->user_bytes_per_element = (int16_t)esz;
    }
    if (!ok || exr_encoding_choose_default_routines(ctx, part, &enc) ||
        exr_encoding_run(ctx, part, &enc)) {
      exr_encoding_destroy(ctx, &enc);
      goto out;
    }
    exr_encoding_destroy(ctx, &enc);
  }
  rc = HF_OK;
out:
  free(tmp);
  if (exr_finish(&ctx) && rc == HF_OK) rc = HF_EIO;
  return rc;
}

int hf_exr_display_size(const char *path, int *width, int *height, char *err, size_t errlen) {
  if (!path || !width || !height) return fail(err, errlen, HF_EINVAL, "null argument");
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = quiet_handler;
  init.flags |= EXR_CONTEXT_FLAG_SILENT_HEADER_PARSE;
  exr_context_t ctx = NULL;
  exr_result_t r = exr_start_read(&ctx, path, &init);
  if (r != EXR_ERR_SUCCESS)
    return fail(err, errlen, HF_EIO, "%s: %s", path, exr_get_error_code_as_string(r));
  exr_attr_box2i_t dw;
  int rc = HF_OK;
  if ((r = exr_get_display_window(ctx, 0, &dw)) != EXR_ERR_SUCCESS) {
    rc = fail(err, errlen, HF_EFORMAT, "%s: %s", path, exr_get_error_code_as_string(r));
  } else {
    int64_t w = (int64_t)dw.max.x - dw.min.x + 1, h = (int64_t)dw.max.y - dw.min.y + 1;
    if (w < 1 || h < 1 || w > INT32_MAX || h > INT32_MAX) {
      rc = fail(err, errlen, HF_ERANGE, "%s: display window %lldx%lld", path, (long long)w,
                (long long)h);
    } else {
      *width = (int)w;
      *height = (int)h;
    }
  }
  exr_finish(&ctx);
  return rc;
}
