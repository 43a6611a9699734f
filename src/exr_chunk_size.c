/* Whether a compressed chunk's bytes are exactly what its compression makes
 * of its pixels.
 *
 * Why this file exists: OpenEXRCore 3.1.5 (Debian 12's) decodes a PXR24,
 * B44 or B44A chunk that holds more bytes than its pixels need with no
 * error: a chunk another compression wrote and whose header names one of
 * these (a damaged or mislabelled file) comes out as plausible garbage.
 * OpenEXR's C++ library refuses such chunks ("input data are longer than
 * expected"); these checks are the same rules, applied before the
 * library's own decompressor runs. The inflating is zlib's. */
#include <stdlib.h>

#include <zlib.h>

#include "exr_internal.h"

/* The bytes PXR24 stores a sample of the type in before deflating
 * (OpenEXR's Pxr24Compressor: FLOAT in 24 bits). */
static uint64_t pxr24_bytes(uint16_t type) {
  return type == EXR_PIXEL_HALF ? 2 : type == EXR_PIXEL_FLOAT ? 3 : 4;
}

/* PXR24: the chunk must inflate to exactly the channels' samples. */
static exr_result_t check_pxr24(const exr_decode_pipeline_t *dec) {
  uint64_t want = 0;
  for (int c = 0; c < dec->channel_count; c++) {
    const exr_coding_channel_info_t *ch = &dec->channels[c];
    want += (uint64_t)ch->width * (uint64_t)ch->height * pxr24_bytes(ch->data_type);
  }
  if (want == 0 || want > dec->chunk.unpacked_size) return EXR_ERR_CORRUPT_CHUNK;
  /* One byte more than wanted: a stream longer than the pixels fills it. */
  uLongf got = (uLongf)want + 1;
  Bytef *tmp = malloc(got);
  if (!tmp) return EXR_ERR_OUT_OF_MEMORY;
  int z = uncompress(tmp, &got, dec->packed_buffer, (uLong)dec->chunk.packed_size);
  free(tmp);
  return z == Z_OK && got == want ? EXR_ERR_SUCCESS : EXR_ERR_CORRUPT_CHUNK;
}

/* B44 and B44A: each HALF channel is 4x4 blocks of 14 bytes, or of 3 where
 * the block is flat (its third byte 13 << 2 or more, the rule of OpenEXR's
 * B44Compressor::uncompress); other channels are stored as they are. The
 * blocks and raw channels must end exactly at the chunk's end. */
static exr_result_t check_b44(const exr_decode_pipeline_t *dec) {
  const uint8_t *p = dec->packed_buffer;
  uint64_t left = dec->chunk.packed_size;
  for (int c = 0; c < dec->channel_count; c++) {
    const exr_coding_channel_info_t *ch = &dec->channels[c];
    uint64_t w = (uint64_t)ch->width, h = (uint64_t)ch->height;
    if (ch->data_type != EXR_PIXEL_HALF) {
      uint64_t n = w * h * 4;
      if (n > left) return EXR_ERR_CORRUPT_CHUNK;
      p += n;
      left -= n;
      continue;
    }
    for (uint64_t b = ((w + 3) / 4) * ((h + 3) / 4); b > 0; b--) {
      if (left < 3) return EXR_ERR_CORRUPT_CHUNK;
      uint64_t n = p[2] >= (13 << 2) ? 3 : 14;
      if (n > left) return EXR_ERR_CORRUPT_CHUNK;
      p += n;
      left -= n;
    }
  }
  return left == 0 ? EXR_ERR_SUCCESS : EXR_ERR_CORRUPT_CHUNK;
}

exr_result_t hf_exr_check_packed(const exr_decode_pipeline_t *dec) {
  /* A chunk compression would not make smaller is stored raw, at its
   * pixels' size: nothing to decompress, nothing to check. */
  if (dec->chunk.packed_size == dec->chunk.unpacked_size) return EXR_ERR_SUCCESS;
  if (!dec->packed_buffer) return EXR_ERR_CORRUPT_CHUNK;
  switch (dec->chunk.compression) {
    case EXR_COMPRESSION_PXR24: return check_pxr24(dec);
    case EXR_COMPRESSION_B44:
    case EXR_COMPRESSION_B44A: return check_b44(dec);
    default: return EXR_ERR_SUCCESS;
  }
}
