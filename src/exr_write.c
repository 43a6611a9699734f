/* EXR writing on OpenEXR's C API (OpenEXRCore), and the proof that what was
 * written reads back.
 *
 * OpenEXR's file layout stores a chunk uncompressed when compressing does
 * not make it smaller, and readers take a chunk whose stored size equals its
 * raw size for an uncompressed one. OpenEXRCore 3.1 (Debian 12 ships 3.1.5)
 * keeps the zlib output of a ZIP chunk when it is exactly as long as the raw
 * data, so that chunk reads back as garbage (upstream issue 2306). Such
 * chunks are common in tall narrow frames (16 scanlines of 1 pixel do not
 * compress) and occur in ordinary ones. store_raw_unless_smaller applies the
 * layout's rule around the library's compressor, which fixes the cause; the
 * read-back comparison after every write makes sure no other path like it
 * goes unnoticed. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "hfcore.h"
#include "errors.h"
#include "exr_internal.h"

/* The library's compressor of the part, kept per pipeline. */
typedef struct compressor {
  exr_result_t (*fn)(exr_encode_pipeline_t *);
} compressor;

static exr_result_t store_raw_unless_smaller(exr_encode_pipeline_t *enc) {
  const compressor *lib = enc->encoding_user_data;
  exr_result_t r = lib->fn(enc);
  if (r != EXR_ERR_SUCCESS) return r;
  if (enc->compressed_bytes >= enc->packed_bytes && enc->compressed_buffer != enc->packed_buffer) {
    /* The compressed buffer holds at least compressed_bytes >= packed_bytes. */
    memcpy(enc->compressed_buffer, enc->packed_buffer, enc->packed_bytes);
    enc->compressed_bytes = enc->packed_bytes;
  }
  return EXR_ERR_SUCCESS;
}

/* Reads path back and compares every value bit for bit with what was meant
 * to be written: src is [h][w][nch] of float32, or of half when half. */
static int verify(const char *path, const hf_image *img, const void *src, int half) {
  struct stat st;
  if (stat(path, &st) != 0) return HF_EIO;
  hf_exr_msg msg = {""};
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = hf_exr_on_error;
  init.user_data = &msg;
  exr_context_t ctx = NULL;
  if (exr_start_read(&ctx, path, &init) != EXR_ERR_SUCCESS) {
    exr_finish(&ctx);
    return HF_EIO;
  }
  int nch = img->channels, rc = HF_EIO;
  size_t esz = half ? 2 : 4, n = (size_t)img->width * img->height * nch;
  int *slot = malloc(sizeof *slot * (size_t)nch);
  void *back = malloc(n * esz);
  const exr_attr_chlist_t *chl;
  if (!slot || !back) {
    rc = HF_ENOMEM;
    goto out;
  }
  if (exr_get_channels(ctx, 0, &chl) || chl->num_channels != nch) goto out;
  for (int c = 0; c < nch; c++)
    if ((slot[c] = hf_image_channel(img, chl->entries[c].name.str)) < 0) goto out;
  if (hf_exr_decode_part(ctx, 0, path, "", (uint64_t)st.st_size, slot, nch,
                         half ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT, back, NULL, 0) == HF_OK &&
      memcmp(back, src, n * esz) == 0)
    rc = HF_OK;
out:
  free(slot);
  free(back);
  exr_finish(&ctx);
  return rc;
}

static exr_attr_box2i_t box(int x, int y, int w, int h) {
  exr_attr_box2i_t b;
  b.min.x = x;
  b.min.y = y;
  b.max.x = x + w - 1;
  b.max.y = y + h - 1;
  return b;
}

int hf_exr_write(const char *path, const hf_image *img, int half) {
  return hf_exr_write_attrs(path, img, half, NULL, 0);
}

int hf_exr_write_attrs(const char *path, const hf_image *img, int half,
                       const hf_exr_int_attr *attrs, int n_attrs) {
  if (n_attrs < 0 || (n_attrs > 0 && !attrs)) return HF_EINVAL;
  for (int a = 0; a < n_attrs; a++)
    if (!attrs[a].name || !strchr(attrs[a].name, ':')) return HF_EINVAL;
  if (!path || !img || !img->data || !img->names || img->width < 1 || img->height < 1 ||
      img->channels < 1 || img->display_width < 0 || img->display_height < 0 ||
      (int64_t)img->origin_x + img->width - 1 > INT32_MAX ||
      (int64_t)img->origin_y + img->height - 1 > INT32_MAX ||
      (int64_t)img->display_x + img->display_width - 1 > INT32_MAX ||
      (int64_t)img->display_y + img->display_height - 1 > INT32_MAX)
    return HF_EINVAL;
  int w = img->width, h = img->height, nch = img->channels;
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  hf_exr_msg msg = {""};
  init.error_handler_fn = hf_exr_on_error;
  init.user_data = &msg;
  exr_context_t ctx = NULL;
  int part, rc = HF_EIO;
  uint16_t *tmp = NULL;
  exr_attr_box2i_t data = box(img->origin_x, img->origin_y, w, h);
  exr_attr_box2i_t disp = img->display_width > 0 && img->display_height > 0
                              ? box(img->display_x, img->display_y, img->display_width,
                                    img->display_height)
                              : data;
  exr_attr_v2f_t center;
  center.x = center.y = 0.0f;
  /* Into a temporary file renamed over path once complete: a reader, or a
   * run stopped and taken up again, never sees half a file at path (a file
   * there is whole), and an earlier file there survives a failed write. */
  if (exr_start_write(&ctx, path, EXR_INTERMEDIATE_TEMP_FILE, &init)) return HF_EIO;
  if (exr_add_part(ctx, "main", EXR_STORAGE_SCANLINE, &part) ||
      exr_initialize_required_attr(ctx, part, &disp, &data, 1.0f, &center, 1.0f,
                                   EXR_LINEORDER_INCREASING_Y, EXR_COMPRESSION_ZIP))
    goto out;
  for (int a = 0; a < n_attrs; a++)
    if (exr_attr_set_int(ctx, part, attrs[a].name, attrs[a].value)) {
      rc = HF_EINVAL; /* a name the library refuses (empty, too long, a standard one's) */
      goto out;
    }
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
    hf_f32_to_f16_array(img->data, tmp, n);
  }
  for (int y = 0; y < h; y += spc) {
    exr_chunk_info_t ci;
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    if (exr_write_scanline_chunk_info(ctx, part, img->origin_y + y, &ci) ||
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
    compressor lib = {NULL};
    if (ok && !exr_encoding_choose_default_routines(ctx, part, &enc) && enc.compress_fn) {
      lib.fn = enc.compress_fn;
      enc.compress_fn = store_raw_unless_smaller;
      enc.encoding_user_data = &lib;
    } else {
      ok = 0;
    }
    if (!ok || exr_encoding_run(ctx, part, &enc)) {
      exr_encoding_destroy(ctx, &enc);
      goto out;
    }
    exr_encoding_destroy(ctx, &enc);
  }
  rc = HF_OK;
out:
  if (exr_finish(&ctx) && rc == HF_OK) rc = HF_EIO;
  if (rc == HF_OK) rc = verify(path, img, half ? (const void *)tmp : (const void *)img->data, half);
  free(tmp);
  return rc;
}
