/* Internal to src/: what the EXR reader and writer share. */
#ifndef HF_EXR_INTERNAL_H
#define HF_EXR_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include <openexr.h>

/* The library's last error message of a context, kept by hf_exr_on_error
 * (install it as error_handler_fn with user_data pointing here): the
 * library's own words ("found corrupt leader: packed size 20658, file size
 * 31774") are the detail our one-line errors end with. */
typedef struct hf_exr_msg {
  char text[256];
} hf_exr_msg;
void hf_exr_on_error(exr_const_context_t ctx, exr_result_t code, const char *msg);

/* Decodes the full-resolution pixels of a flat part (scanline or tiled) of
 * an open file into dst, [h][w][nch] elements of type (EXR_PIXEL_FLOAT or
 * EXR_PIXEL_HALF) where w x h is the data window: the file's channel c goes
 * to element slot[c] of a pixel, or nowhere when slot[c] < 0. file_size
 * lets a chunk that ends past the end of the file be named for what it is.
 * On failure err says what (naming path and label, the part). */
int hf_exr_decode_part(exr_const_context_t ctx, int part, const char *path, const char *label,
                       uint64_t file_size, const int *slot, int nch, exr_pixel_type_t type,
                       void *dst, char *err, size_t errlen);

/* EXR_ERR_SUCCESS when the packed (compressed) chunk dec has read holds
 * exactly what its compression makes of the chunk's pixels, else
 * EXR_ERR_CORRUPT_CHUNK (EXR_ERR_OUT_OF_MEMORY when a PXR24 check cannot
 * allocate). Checks PXR24, B44 and B44A chunks, whose decoders in
 * OpenEXRCore 3.1.5 accept trailing bytes; others pass. Call it after the
 * pipeline's read_fn, before its decompress_fn (exr_chunk_size.c). */
exr_result_t hf_exr_check_packed(const exr_decode_pipeline_t *dec);

/* 1 when a channel list of the file at path has an entry OpenEXRCore
 * refuses (a channel named twice, a pixel type other than UINT, HALF or
 * FLOAT, a sampling below 1), the refusal's words (naming the channel and
 * its part, and what to do) in why; 0 otherwise, also when the headers
 * cannot be walked. For the refusal of a header OpenEXRCore would not
 * read, which it words as a list "not found". */
int hf_exr_chlist_fault(const char *path, char *why, size_t len);

#endif
