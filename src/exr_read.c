/* EXR reading on OpenEXR's C API (OpenEXRCore): scanline and tiled parts of
 * single- and multi-part files, with their data and display windows.
 * Channels are addressed by name: the library keeps them sorted, so callers
 * never rely on file order.
 *
 * Files come from other tools, so every failure says what is wrong in the
 * user's terms and what to do: a compression this build's OpenEXR cannot
 * decode (DWAA/DWAB before OpenEXR 3.2) is named with a conversion command,
 * a file cut short is called truncated, a multi-part file without an
 * obvious part lists its parts. */
#define _XOPEN_SOURCE 700
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "hfcore.h"
#include "errors.h"
#include "exr_internal.h"

/* Refuse images over this many samples before allocating (2^31 bytes). */
#define EXR_MAX_FLOATS ((size_t)1 << 29)

#define fail hf_fail_msg

void hf_exr_on_error(exr_const_context_t ctx, exr_result_t code, const char *msg) {
  void *ud = NULL;
  (void)code;
  if (exr_get_user_data(ctx, &ud) == EXR_ERR_SUCCESS && ud && msg)
    snprintf(((hf_exr_msg *)ud)->text, sizeof ((hf_exr_msg *)ud)->text, "%s", msg);
}

static const char *compression_name(exr_compression_t c) {
  static const char *const names[] = {"no", "RLE", "ZIPS", "ZIP", "PIZ",
                                      "PXR24", "B44", "B44A", "DWAA", "DWAB"};
  return (unsigned)c < sizeof names / sizeof names[0] ? names[c] : "an unknown";
}

/* The name of a lossy compression that changed the part's values, or NULL:
 * B44 and B44A quantise half channels (float ones are stored as they are),
 * PXR24 rounds float channels to 24 bits (half ones are exact), DWAA and
 * DWAB are lossy for both (OpenEXR's documentation of the compressions). */
static const char *lossy_compression(exr_const_context_t ctx, int part,
                                     const exr_attr_chlist_t *chl) {
  exr_compression_t c = EXR_COMPRESSION_NONE;
  if (exr_get_compression(ctx, part, &c) != EXR_ERR_SUCCESS) return NULL;
  int half = 0, flt = 0;
  for (int i = 0; i < chl->num_channels; i++) {
    half |= chl->entries[i].pixel_type == EXR_PIXEL_HALF;
    flt |= chl->entries[i].pixel_type == EXR_PIXEL_FLOAT;
  }
  if (((c == EXR_COMPRESSION_B44 || c == EXR_COMPRESSION_B44A) && half) ||
      (c == EXR_COMPRESSION_PXR24 && flt) || c == EXR_COMPRESSION_DWAA ||
      c == EXR_COMPRESSION_DWAB)
    return compression_name(c);
  return NULL;
}

/* " (library: ...)" when the library said something, for the end of a message. */
static const char *detail(const hf_exr_msg *m, char *buf, size_t len) {
  if (!m || !m->text[0]) return "";
  snprintf(buf, len, " (OpenEXR: %s)", m->text);
  return buf;
}

/* ---- decoding a part ------------------------------------------------------- */

typedef struct chunk_pos {
  int x, y, w, h;     /* pixels it covers, in image space */
  int tiled, tx, ty;  /* tile indices when tiled */
} chunk_pos;

static void chunk_name(const chunk_pos *p, char *buf, size_t len) {
  if (p->tiled)
    snprintf(buf, len, "tile (%d, %d) at pixel (%d, %d)", p->tx, p->ty, p->x, p->y);
  else
    snprintf(buf, len, "scanlines %d-%d", p->y, p->y + p->h - 1);
}

/* ---- files cut short ---------------------------------------------------------- */

/* A second reader of the same file that does not know its size, so the
 * library reads on where the first one stopped at the end of the file; the
 * reads it asks for say whether the file was cut short. (OpenEXR has no
 * "truncated" error: it reports a chunk table, a chunk leader or a chunk
 * that does not fit the file like any other corruption.) */
typedef struct probe {
  hf_exr_msg msg;   /* first: hf_exr_on_error writes here */
  int fd;
  uint64_t size;
  int past_end;     /* the library asked for bytes past the end of the file */
} probe;

static int64_t probe_read(exr_const_context_t ctx, void *ud, void *buf, uint64_t sz,
                          uint64_t off, exr_stream_error_func_ptr_t error_cb) {
  probe *p = ud;
  (void)ctx;
  (void)error_cb;
  if (off + sz > p->size) p->past_end = 1;
  ssize_t n = pread(p->fd, buf, (size_t)sz, (off_t)off);
  return n < 0 ? -1 : (int64_t)n;
}

/* 1 when the header (c NULL) or chunk c of part needs bytes past the end of
 * a file of size bytes. */
static int cut_short(const char *path, int part, const chunk_pos *c, uint64_t size) {
  probe p = {{""}, open(path, O_RDONLY), size, 0};
  if (p.fd < 0) return 0;
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = hf_exr_on_error;
  init.user_data = &p;
  init.read_fn = probe_read;
  exr_context_t ctx = NULL;
  if (exr_start_read(&ctx, path, &init) == EXR_ERR_SUCCESS && c) {
    /* The header is read in blocks, past the end of a file smaller than
     * one: only the chunk's own reads say whether it was cut short (a
     * complete small file with a damaged chunk leader was called
     * truncated). */
    p.past_end = 0;
    exr_chunk_info_t ci;
    memset(&ci, 0, sizeof ci);
    exr_result_t r = c->tiled ? exr_read_tile_chunk_info(ctx, part, c->tx, c->ty, 0, 0, &ci)
                              : exr_read_scanline_chunk_info(ctx, part, c->y, &ci);
    if (r == EXR_ERR_SUCCESS && ci.data_offset + ci.packed_size > size) p.past_end = 1;
  }
  exr_finish(&ctx);
  close(p.fd);
  return p.past_end;
}

/* ---- the chunk offset table ------------------------------------------------- */

/* Our own walk over the headers to the chunk offset tables, because
 * OpenEXRCore 3.1 says neither where a part's table lies nor what it
 * holds, and it "repairs" a table whose offsets point past the end of the
 * file by scanning the chunks, failing then with a chunk-leader error (or,
 * before decoding, a data window too large for the file) that does not say
 * the file is cut short. The layout is the format's (openexr.com, "OpenEXR
 * File Layout"): magic and version (8 bytes), then each part's header,
 * attributes of name\0 type\0 int32 size and value, ended by a 0 byte;
 * a multi-part file (version bit 12) ends its headers with one more 0
 * byte; then the parts' tables in part order, one little-endian uint64
 * file offset per chunk. */
typedef enum table_state {
  TABLE_INSIDE,
  TABLE_OFFSET_PAST_END,   /* an offset points past the end of the file (a file cut
                              short, or a damaged table) or before the chunks (a
                              damaged table) */
  TABLE_CHUNK_CUT,         /* the chunk that starts last in the file ends past it: cut
                              short, whatever the table says */
  TABLE_PAST_END           /* the table itself does not fit in the file */
} table_state;

/* Reads a NUL-terminated string of at most max - 1 bytes into buf: its
 * length, -1 at the end of the file, -2 when max bytes hold no NUL.
 * *printable is cleared when a byte is not printable ASCII, which no
 * attribute's name or type holds. */
static int read_cstring(FILE *f, char *buf, int max, int *printable) {
  for (int i = 0; i < max; i++) {
    int c = fgetc(f);
    if (c == EOF) return -1;
    buf[i] = (char)c;
    if (c == 0) return i;
    if (c < 0x20 || c > 0x7e) *printable = 0;
  }
  return -2;
}

/* The offset just past the headers, or 0 when they cannot be walked (a
 * damaged header, which the library reports in its own words). *cut (NULL:
 * not wanted) is 1 when the walk ran into the end of the file while every
 * attribute so far looked like one (a name and a type of printable
 * characters, a size that is not negative), else 0: a header the library
 * refused for a value it holds (a channel's sampling, say) is damaged, not
 * cut short, although the library's parse, once off the rails, may read
 * on to the end of the file (and it reads ahead past the end of a small
 * one). */
static uint64_t headers_end(FILE *f, uint64_t size, int *cut) {
  int whole = 1, dummy;
  if (!cut) cut = &dummy;
  *cut = 0;
  unsigned char head[8];
  if (fread(head, 1, 8, f) != 8) {
    *cut = 1;
    return 0;
  }
  int multipart = (head[5] & 0x10) != 0;   /* version bit 12 */
  char name[256], type[256];
  for (int part = 0;; part++) {
    if (part > 0 && !multipart) break;
    for (int attr = 0;; attr++) {
      int n = read_cstring(f, name, (int)sizeof name, &whole);
      if (n == -1) *cut = whole;
      if (n < 0 || attr > 100000) return 0;
      if (n == 0) {
        if (attr == 0) {   /* the empty header that ends a multi-part file's */
          off_t end = ftello(f);
          return part > 0 && end > 0 ? (uint64_t)end : 0;
        }
        break;
      }
      unsigned char len[4];
      int t = read_cstring(f, type, (int)sizeof type, &whole);
      if (t == -1 || (t >= 0 && fread(len, 1, 4, f) != 4)) {
        *cut = whole;   /* the end of the file inside the type or its size */
        return 0;
      }
      if (t < 0) return 0;
      uint32_t vlen = (uint32_t)len[0] | (uint32_t)len[1] << 8 | (uint32_t)len[2] << 16 |
                      (uint32_t)len[3] << 24;
      off_t at = ftello(f);
      if (at < 0 || vlen > 0x7fffffffu) return 0;
      if ((uint64_t)at + vlen > size || fseeko(f, (off_t)vlen, SEEK_CUR) != 0) {
        *cut = whole;
        return 0;
      }
    }
  }
  off_t at = ftello(f);
  return at < 0 ? 0 : (uint64_t)at;
}

/* headers_end's *cut for the file at path, of size bytes; 0 when it
 * cannot be opened. */
static int header_cut_short(const char *path, uint64_t size) {
  FILE *f = fopen(path, "rb");
  if (!f) return 0;
  int cut;
  headers_end(f, size, &cut);
  fclose(f);
  return cut;
}

/* Whether the file's chunk offset tables, or a chunk they point to (or the
 * data of the one that starts last), lie past the end of a file of size
 * bytes: the file was cut short (or its header claims far more chunks than
 * the file holds). Every part's table is judged, not only part's: a
 * multi-part file cut in its last part is cut short whichever part is
 * read, as a mipmapped one cut in its smaller levels is (check_complete).
 * TABLE_INSIDE also when the tables cannot be found. */
static table_state chunk_table(exr_const_context_t ctx, int part, const char *path,
                               uint64_t size) {
  int nparts = 0;
  if (exr_get_count(ctx, &nparts) || part < 0 || part >= nparts) return TABLE_INSIDE;
  FILE *f = fopen(path, "rb");
  if (!f) return TABLE_INSIDE;
  table_state st = TABLE_INSIDE;
  /* The file the caller measured: one replaced or grown since is not
   * judged by another's size. */
  struct stat fs;
  if (fstat(fileno(f), &fs) != 0 || (uint64_t)fs.st_size != size) {
    fclose(f);
    return TABLE_INSIDE;
  }
  uint64_t at = headers_end(f, size, NULL), tables_end = at, count = 0;
  for (int q = 0; at && q < nparts; q++) {
    int32_t n = 0;
    if (exr_get_chunk_count(ctx, q, &n) || n < 0) at = 0;
    else count += (uint64_t)n;
  }
  if (!at) goto out;
  tables_end = at + count * 8;
  if (tables_end > size) {
    st = TABLE_PAST_END;
    goto out;
  }
  if (fseeko(f, (off_t)at, SEEK_SET) != 0) goto out;
  unsigned char buf[8 * 512];
  uint64_t last = 0;   /* the chunk that starts last inside the file */
  for (uint64_t i = 0; i < count;) {
    size_t k = count - i < 512 ? (size_t)(count - i) : 512;
    if (fread(buf, 8, k, f) != k) goto out;
    for (size_t j = 0; j < k; j++) {
      uint64_t off = 0;
      for (int b = 7; b >= 0; b--) off = off << 8 | buf[8 * j + (size_t)b];
      if (off >= size || off < tables_end)
        st = TABLE_OFFSET_PAST_END;
      else if (off > last)
        last = off;
    }
    i += k;
  }
  /* The last chunk's leader: [part number (multi-part)], the scanline's y
   * or the tile's 4 coordinates, then its data's size; a deep chunk's,
   * three 64-bit sizes (its sample count table, its data packed and
   * unpacked), the first two of which follow. */
  if (!last) goto out;
  int owner = part;
  unsigned char num[4];
  if (nparts > 1) {
    if (last + 4 > size) {
      st = TABLE_CHUNK_CUT;
      goto out;
    }
    if (fseeko(f, (off_t)last, SEEK_SET) != 0 || fread(num, 1, 4, f) != 4) goto out;
    owner = (int)((uint32_t)num[0] | (uint32_t)num[1] << 8 | (uint32_t)num[2] << 16 |
                  (uint32_t)num[3] << 24);
    if (owner < 0 || owner >= nparts) goto out;   /* a damaged leader: the decoder's to say */
  }
  exr_storage_t storage;
  if (exr_get_storage(ctx, owner, &storage)) goto out;
  int tiled = storage == EXR_STORAGE_TILED || storage == EXR_STORAGE_DEEP_TILED;
  int deep = storage == EXR_STORAGE_DEEP_SCANLINE || storage == EXR_STORAGE_DEEP_TILED;
  uint64_t lead = (nparts > 1 ? 4 : 0) + (tiled ? 16 : 4), sizes = deep ? 24 : 4;
  unsigned char len[24];
  if (last + lead + sizes > size) {
    st = TABLE_CHUNK_CUT;
  } else if (fseeko(f, (off_t)(last + lead), SEEK_SET) == 0 && fread(len, 1, sizes, f) == sizes) {
    uint64_t data = 0;
    for (int v = 0; v < (deep ? 2 : 1); v++) {
      uint64_t x = 0;
      for (int b = (deep ? 7 : 3); b >= 0; b--) x = x << 8 | len[8 * v + b];
      data = x > size - data ? size + 1 : data + x;   /* no wrap past 2^64 */
    }
    if (last + lead + sizes + data > size) st = TABLE_CHUNK_CUT;
  }
out:
  fclose(f);
  return st;
}

/* The refusal of a part whose compression this build's OpenEXR cannot
 * decode, with a conversion command. */
static int undecodable(exr_const_context_t ctx, int part, const char *path, const char *label,
                       char *err, size_t errlen) {
  exr_compression_t c = EXR_COMPRESSION_NONE;
  exr_get_compression(ctx, part, &c);
  int maj = 0, min = 0, pat = 0;
  exr_get_library_version(&maj, &min, &pat, NULL);
  return fail(err, errlen, HF_EUNSUPPORTED,
              "%s%s: %s compression cannot be decoded by this build's OpenEXR %d.%d.%d; "
              "convert the file to ZIP first, e.g. oiiotool %s --compression zip -o "
              "converted.exr (Debian package openimageio-tools)",
              path, label, compression_name(c), maj, min, pat, path);
}

static int chunk_failed(exr_const_context_t ctx, int part, const char *path, const char *label,
                        const chunk_pos *p, exr_result_t r, const exr_chunk_info_t *ci,
                        uint64_t file_size, char *err, size_t errlen) {
  void *ud = NULL;
  exr_get_user_data(ctx, &ud);
  char what[96], more[300];
  chunk_name(p, what, sizeof what);
  const char *d = detail(ud, more, sizeof more);
  if (r == EXR_ERR_FEATURE_NOT_IMPLEMENTED) return undecodable(ctx, part, path, label, err, errlen);
  if (r == EXR_ERR_READ_IO || (ci->data_offset && ci->data_offset + ci->packed_size > file_size) ||
      cut_short(path, part, p, file_size))
    return fail(err, errlen, HF_EIO,
                "%s%s: truncated / incomplete file: the data of %s is missing (the file ends "
                "at byte %llu); write or copy the file again",
                path, label, what, (unsigned long long)file_size);
  return fail(err, errlen, HF_EFORMAT, "%s%s: %s cannot be read: %s%s; the file is damaged, "
              "write it again", path, label, what, exr_get_error_code_as_string(r), d);
}

/* HF_OK, or the refusal of an uncompressed chunk whose leader claims a
 * size other than its pixels': OpenEXRCore 3.1.5 decodes one that claims
 * fewer bytes with no error, the pixels past the claimed size read from
 * the wrong bytes or left as they were. (A compressed chunk's size is its
 * compressor's to check.) */
static int check_raw_size(const exr_chunk_info_t *ci, const chunk_pos *p, const char *path,
                          const char *label, char *err, size_t errlen) {
  if (ci->compression != EXR_COMPRESSION_NONE || ci->packed_size == ci->unpacked_size)
    return HF_OK;
  char what[96];
  chunk_name(p, what, sizeof what);
  return fail(err, errlen, HF_EFORMAT, "%s%s: %s is uncompressed and holds %llu bytes, but its "
              "pixels are %llu bytes; the file is damaged, write it again", path, label, what,
              (unsigned long long)ci->packed_size, (unsigned long long)ci->unpacked_size);
}

/* 1 when the chunk's channels are four HALF ones, each decoded: OpenEXRCore
 * 3.1.5 (Debian 12's) widens those to interleaved floats in reverse order
 * (its fast path for A, B, G, R into R, G, B, A), with no error; halves
 * come out in order. */
static int four_halves(const exr_decode_pipeline_t *dec, const int *slot) {
  if (dec->channel_count != 4) return 0;
  for (int c = 0; c < 4; c++)
    if (dec->channels[c].data_type != EXR_PIXEL_HALF || slot[c] < 0) return 0;
  return 1;
}

/* The library's decompressor of a chunk, run after hf_exr_check_packed. */
typedef struct checked_fn {
  exr_result_t (*decompress)(exr_decode_pipeline_t *dec);
} checked_fn;

static exr_result_t checked_decompress(exr_decode_pipeline_t *dec) {
  const checked_fn *next = dec->decoding_user_data;
  exr_result_t r = hf_exr_check_packed(dec);
  return r ? r : next->decompress(dec);
}

static exr_result_t decode_chunk(exr_const_context_t ctx, int part, const exr_chunk_info_t *ci,
                                 const chunk_pos *p, const exr_attr_box2i_t *dw,
                                 const int *slot, int nch, exr_pixel_type_t type, void *dst) {
  size_t w = (size_t)((int64_t)dw->max.x - dw->min.x + 1);
  size_t px = (size_t)(p->y - dw->min.y) * w + (size_t)(p->x - dw->min.x);
  exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
  exr_result_t r = exr_decoding_initialize(ctx, part, ci, &dec);
  if (r) return r;
  /* Four halves asked for as floats: decoded as halves into tmp, a tight
   * p->w x p->h x 4 block, and widened here. */
  uint16_t *tmp = NULL;
  if (type == EXR_PIXEL_FLOAT && four_halves(&dec, slot)) {
    if (!(tmp = malloc((size_t)p->w * (size_t)p->h * 4 * sizeof *tmp))) {
      exr_decoding_destroy(ctx, &dec);
      return EXR_ERR_OUT_OF_MEMORY;
    }
  }
  exr_pixel_type_t as = tmp ? EXR_PIXEL_HALF : type;
  size_t esz = as == EXR_PIXEL_HALF ? 2 : 4;
  for (int c = 0; c < dec.channel_count; c++) {
    exr_coding_channel_info_t *ch = &dec.channels[c];
    if (slot[c] < 0) {
      ch->decode_to_ptr = NULL; /* skipped */
      continue;
    }
    if (tmp) {
      ch->decode_to_ptr = (uint8_t *)(tmp + c);
      ch->user_pixel_stride = (int32_t)(4 * esz);
      ch->user_line_stride = (int32_t)(4 * esz * (size_t)p->w);
    } else {
      ch->decode_to_ptr = (uint8_t *)dst + (px * (size_t)nch + (size_t)slot[c]) * esz;
      ch->user_pixel_stride = (int32_t)(esz * (size_t)nch);
      ch->user_line_stride = (int32_t)(esz * (size_t)nch * w);
    }
    ch->user_data_type = (uint16_t)as;
    ch->user_bytes_per_element = (int16_t)esz;
  }
  r = exr_decoding_choose_default_routines(ctx, part, &dec);
  /* The file layout stores a chunk that compression would not make smaller
   * as it is, its size then the raw size (OpenEXR's C++ writer does so for
   * B44 blocks of chunks under 4x4 pixels). OpenEXRCore 3.1 skips
   * decompression of such chunks for every compression but B44 and B44A,
   * whose decoder then refuses the raw bytes: the pipeline reads them as
   * they are, as OpenEXR's C++ reader does. */
  if (r == EXR_ERR_SUCCESS && ci->packed_size == ci->unpacked_size &&
      (ci->compression == EXR_COMPRESSION_B44 || ci->compression == EXR_COMPRESSION_B44A))
    dec.decompress_fn = NULL;
  checked_fn next = {dec.decompress_fn};
  if (r == EXR_ERR_SUCCESS && next.decompress) {
    dec.decoding_user_data = &next;
    dec.decompress_fn = checked_decompress;
  }
  if (r == EXR_ERR_SUCCESS) r = exr_decoding_run(ctx, part, &dec);
  exr_decoding_destroy(ctx, &dec);
  if (tmp && r == EXR_ERR_SUCCESS)
    for (int y = 0; y < p->h; y++)
      for (int x = 0; x < p->w; x++)
        for (int c = 0; c < 4; c++)
          ((float *)dst)[(px + (size_t)y * w + (size_t)x) * (size_t)nch + (size_t)slot[c]] =
              hf_f16_to_f32(tmp[((size_t)y * (size_t)p->w + (size_t)x) * 4 + (size_t)c]);
  free(tmp);
  return r;
}

int hf_exr_decode_part(exr_const_context_t ctx, int part, const char *path, const char *label,
                       uint64_t file_size, const int *slot, int nch, exr_pixel_type_t type,
                       void *dst, char *err, size_t errlen) {
  exr_storage_t storage;
  exr_attr_box2i_t dw;
  exr_result_t r;
  if ((r = exr_get_storage(ctx, part, &storage)) || (r = exr_get_data_window(ctx, part, &dw)))
    return fail(err, errlen, HF_EFORMAT, "%s%s: %s", path, label,
                exr_get_error_code_as_string(r));
  int w = (int)((int64_t)dw.max.x - dw.min.x + 1), h = (int)((int64_t)dw.max.y - dw.min.y + 1);
  if (storage == EXR_STORAGE_SCANLINE) {
    int32_t spc;
    if ((r = exr_get_scanlines_per_chunk(ctx, part, &spc)) || spc < 1)
      return fail(err, errlen, HF_EFORMAT, "%s%s: %s", path, label,
                  exr_get_error_code_as_string(r ? r : EXR_ERR_INVALID_ATTR));
    /* Chunks start at multiples of spc from the data window's top. */
    for (int64_t y = dw.min.y; y <= dw.max.y; y += spc) {
      exr_chunk_info_t ci;
      memset(&ci, 0, sizeof ci);
      chunk_pos p = {dw.min.x, (int)y, w, (int)(dw.max.y - y + 1 < spc ? dw.max.y - y + 1 : spc),
                     0, 0, 0};
      r = exr_read_scanline_chunk_info(ctx, part, (int)y, &ci);
      if (!r && ci.data_offset + ci.packed_size > file_size) r = EXR_ERR_READ_IO;
      if (!r && check_raw_size(&ci, &p, path, label, err, errlen)) return HF_EFORMAT;
      if (!r) r = decode_chunk(ctx, part, &ci, &p, &dw, slot, nch, type, dst);
      if (r)
        return chunk_failed(ctx, part, path, label, &p, r, &ci, file_size, err, errlen);
    }
    return HF_OK;
  }
  if (storage != EXR_STORAGE_TILED)
    return fail(err, errlen, HF_EUNSUPPORTED, "%s%s: deep data cannot be read", path, label);
  /* Tiled: the full-resolution level (0, 0) of any level mode, tile by tile. */
  uint32_t tw, th;
  exr_tile_level_mode_t lm;
  exr_tile_round_mode_t rm;
  if ((r = exr_get_tile_descriptor(ctx, part, &tw, &th, &lm, &rm)) || tw < 1 || th < 1)
    return fail(err, errlen, HF_EFORMAT, "%s%s: tile description: %s", path, label,
                exr_get_error_code_as_string(r ? r : EXR_ERR_INVALID_ATTR));
  int ntx = (int)(((int64_t)w + tw - 1) / tw), nty = (int)(((int64_t)h + th - 1) / th);
  for (int ty = 0; ty < nty; ty++)
    for (int tx = 0; tx < ntx; tx++) {
      exr_chunk_info_t ci;
      memset(&ci, 0, sizeof ci);
      chunk_pos p = {dw.min.x + tx * (int)tw, dw.min.y + ty * (int)th, 0, 0, 1, tx, ty};
      p.w = w - tx * (int)tw < (int)tw ? w - tx * (int)tw : (int)tw;
      p.h = h - ty * (int)th < (int)th ? h - ty * (int)th : (int)th;
      r = exr_read_tile_chunk_info(ctx, part, tx, ty, 0, 0, &ci);
      if (!r && ci.data_offset + ci.packed_size > file_size) r = EXR_ERR_READ_IO;
      if (!r && (ci.width != p.w || ci.height != p.h)) r = EXR_ERR_CORRUPT_CHUNK;
      if (!r && check_raw_size(&ci, &p, path, label, err, errlen)) return HF_EFORMAT;
      if (!r) r = decode_chunk(ctx, part, &ci, &p, &dw, slot, nch, type, dst);
      if (r)
        return chunk_failed(ctx, part, path, label, &p, r, &ci, file_size, err, errlen);
    }
  return HF_OK;
}

/* ---- sizes a file can hold ----------------------------------------------------- */

/* The most bytes of pixels one byte of a chunk's compressed data can decode
 * to: a file whose data window claims more than its size allows is damaged,
 * and is refused before the image is allocated (a 50 KB file must not make
 * the reader allocate gigabytes). From the formats: RLE's longest run is 127
 * bytes from 2; deflate (ZIPS, ZIP) expands at most 1032:1 (zlib's
 * documented limit); PIZ's Huffman codes a run of up to 255 16-bit symbols
 * in 10 bits or more (about 400:1), bounded here by deflate's; PXR24 is
 * deflate over floats cut to 3 bytes; B44A stores a flat 4x4 block of halves
 * (32 bytes) in 3; DWAA and DWAB nest RLE and deflate. Measured on 2048x2048
 * images of zeros, 8 channels, one file per compression written by
 * python3-openimageio 2.4.7 (2026-12-05), the larger of HALF and FLOAT:
 * RLE 63:1, ZIP 991:1, PIZ 405:1, PXR24 1303:1, B44A 10.7:1, DWAB 1947:1. */
static double max_expansion(exr_compression_t c) {
  switch (c) {
    case EXR_COMPRESSION_NONE: return 1;
    case EXR_COMPRESSION_RLE: return 64;
    case EXR_COMPRESSION_ZIPS:
    case EXR_COMPRESSION_ZIP:
    case EXR_COMPRESSION_PIZ: return 1032;
    case EXR_COMPRESSION_PXR24: return 1032.0 * 4 / 3;
    case EXR_COMPRESSION_B44:
    case EXR_COMPRESSION_B44A: return 32.0 / 3;
    default: return 64.0 * 1032;
  }
}

/* HF_OK, or HF_EIO when the part's chunk table shows the file cut short
 * (chunk_table): its last chunk ends past the end of the file, or the
 * table does not fit in it. Also when the full-resolution level is whole
 * (a mipmapped file cut in its smaller levels): a file cut short was
 * copied or written wrong. Also an offset outside the chunks: OpenEXR 3.1.5
 * "repairs" such a table by scanning the chunks and then reads the wrong
 * chunk for a scanline, with no error (test_exr, a table with one offset
 * past the end). */
static int check_complete(table_state t, const char *path, const char *label, int64_t w,
                          int64_t h, uint64_t file_size, char *err, size_t errlen) {
  if (t == TABLE_CHUNK_CUT)
    return fail(err, errlen, HF_EIO, "%s%s: truncated / incomplete file: it ends (at %llu "
                "bytes) inside the data of a chunk its table points to; write or copy the file "
                "again", path, label, (unsigned long long)file_size);
  if (t == TABLE_OFFSET_PAST_END)
    return fail(err, errlen, HF_EIO, "%s%s: truncated / incomplete file, or a damaged chunk "
                "table: an offset of its table points outside the file's chunks (%llu bytes); "
                "write or copy the file again", path, label, (unsigned long long)file_size);
  if (t == TABLE_PAST_END)
    return fail(err, errlen, HF_EIO, "%s%s: truncated / incomplete file, or a damaged header: "
                "the chunk table of its %lldx%lld data window does not fit in its %llu bytes; "
                "write or copy the file again", path, label, (long long)w, (long long)h,
                (unsigned long long)file_size);
  return HF_OK;
}

/* HF_OK, or HF_EFORMAT when w x h pixels of the part's channels cannot come
 * out of a file of file_size bytes (max_expansion). */
static int check_claimed_size(exr_const_context_t ctx, int part, const char *path,
                              const char *label, const exr_attr_chlist_t *chl, int64_t w,
                              int64_t h, uint64_t file_size, table_state table, char *err,
                              size_t errlen) {
  exr_compression_t c = EXR_COMPRESSION_NONE;
  exr_get_compression(ctx, part, &c);
  double bytes = 0;
  for (int i = 0; i < chl->num_channels; i++)
    bytes += chl->entries[i].pixel_type == EXR_PIXEL_HALF ? 2 : 4;
  bytes *= (double)w * (double)h;
  const double most = (double)file_size * max_expansion(c);
  if (bytes <= most) return HF_OK;
  /* A file cut inside its chunk table fails here too: said as both. */
  int cut = table == TABLE_PAST_END;
  return fail(err, errlen, cut ? HF_EIO : HF_EFORMAT, "%s%s: %sits data window claims "
              "%lldx%lld pixels of %d channels (%.1f MB of pixels), more than %llu bytes of "
              "%s-compressed data can hold (%.1f MB)%s; %s", path, label,
              cut ? "truncated / incomplete file, or a damaged header: " : "", (long long)w,
              (long long)h, chl->num_channels, bytes / 1e6, (unsigned long long)file_size,
              compression_name(c), most / 1e6,
              cut ? ", and its chunk table does not fit in the file" : "",
              cut ? "write or copy the file again" : "the file is damaged, write it again");
}

/* HF_OK, or the refusal of a part whose compression this build's OpenEXR
 * cannot decode (DWAA and DWAB, which OpenEXRCore decodes from 3.2 on;
 * B44 and B44A with 32-bit channels, below; a code the library does not
 * know is refused when the header is read, read_part),
 * before the image is allocated: the file is not read further, so a
 * damaged one cannot make the reader allocate what its header claims. */
static int check_decodable(exr_const_context_t ctx, int part, const char *path,
                           const char *label, const exr_attr_chlist_t *chl, char *err,
                           size_t errlen) {
  exr_compression_t c = EXR_COMPRESSION_NONE;
  if (exr_get_compression(ctx, part, &c)) return HF_OK;
  int maj = 0, min = 0, pat = 0;
  exr_get_library_version(&maj, &min, &pat, NULL);
  /* B44 stores FLOAT and UINT channels uncompressed beside its half
   * blocks; OpenEXRCore 3.1.5 (Debian 12's) decodes them to wrong values
   * with no error, where OpenEXR's C++ reader gets them right (measured on
   * files written by OpenImageIO 2.4). Refused rather than read wrong
   * before 3.2, whose rewritten decoder test_b44_float holds to exact
   * values. */
  int before_3_2 = maj < 3 || (maj == 3 && min < 2);
  if ((c == EXR_COMPRESSION_B44 || c == EXR_COMPRESSION_B44A) && before_3_2)
    for (int i = 0; i < chl->num_channels; i++)
      if (chl->entries[i].pixel_type != EXR_PIXEL_HALF)
        return fail(err, errlen, HF_EUNSUPPORTED,
                    "%s%s: channel %s is 32-bit in a %s-compressed part, which this build's "
                    "OpenEXR %d.%d.%d decodes wrongly; convert the file to ZIP first, e.g. "
                    "oiiotool %s --compression zip -o converted.exr (Debian package "
                    "openimageio-tools)", path, label, chl->entries[i].name.str,
                    compression_name(c), maj, min, pat, path);
  if ((c != EXR_COMPRESSION_DWAA && c != EXR_COMPRESSION_DWAB) || !before_3_2) return HF_OK;
  return undecodable(ctx, part, path, label, err, errlen);
}

/* ---- choosing a part --------------------------------------------------------- */

static int part_has_channel(exr_const_context_t ctx, int part, const char *channel) {
  const exr_attr_chlist_t *chl;
  if (!channel || exr_get_channels(ctx, part, &chl)) return 0;
  for (int c = 0; c < chl->num_channels; c++)
    if (!strcmp(chl->entries[c].name.str, channel)) return 1;
  return 0;
}

/* ", part 2 \"beauty\"" for messages about a part of a multi-part file. */
static void part_label(exr_const_context_t ctx, int part, int nparts, char *buf, size_t len) {
  const char *name = NULL;
  buf[0] = 0;
  if (nparts <= 1) return;
  if (exr_get_name(ctx, part, &name) == EXR_ERR_SUCCESS && name && name[0])
    snprintf(buf, len, ", part %d \"%s\"", part, name);
  else
    snprintf(buf, len, ", part %d", part);
}

/* "0 \"rgba\" (4 channels), 1 \"features\" (24 channels, tiled)" into buf. */
static void list_parts(exr_const_context_t ctx, int nparts, char *buf, size_t len) {
  size_t used = 0;
  buf[0] = 0;
  for (int i = 0; i < nparts && used + 1 < len; i++) {
    const char *name = NULL;
    const exr_attr_chlist_t *chl = NULL;
    exr_storage_t st = EXR_STORAGE_SCANLINE;
    exr_get_name(ctx, i, &name);
    exr_get_channels(ctx, i, &chl);
    exr_get_storage(ctx, i, &st);
    int n = snprintf(buf + used, len - used, "%s%d%s%s%s (%d channels%s)", i ? ", " : "", i,
                     name ? " \"" : "", name ? name : "", name ? "\"" : "",
                     chl ? chl->num_channels : 0,
                     st == EXR_STORAGE_TILED ? ", tiled"
                     : st == EXR_STORAGE_DEEP_SCANLINE || st == EXR_STORAGE_DEEP_TILED ? ", deep"
                                                                                      : "");
    if (n < 0) break;
    used += (size_t)n;
  }
}

static int choose_part(exr_const_context_t ctx, const char *path, int nparts, const char *part,
                       const char *channel, int *out, char *err, size_t errlen) {
  char parts[700];
  if (part) {
    char *end;
    errno = 0;
    long idx = strtol(part, &end, 10);
    if (part[0] >= '0' && part[0] <= '9' && !*end && !errno) {
      if (idx < nparts) {
        *out = (int)idx;
        return HF_OK;
      }
    } else {
      for (int i = 0; i < nparts; i++) {
        const char *name = NULL;
        if (exr_get_name(ctx, i, &name) == EXR_ERR_SUCCESS && name && !strcmp(name, part)) {
          *out = i;
          return HF_OK;
        }
      }
    }
    list_parts(ctx, nparts, parts, sizeof parts);
    return fail(err, errlen, HF_ENOTFOUND, "%s has no part \"%s\"; its %d part%s: %s", path,
                part, nparts, nparts == 1 ? " is" : "s are", parts);
  }
  if (nparts == 1) {
    *out = 0;
    return HF_OK;
  }
  int found = -1, count = 0;
  for (int i = 0; i < nparts; i++)
    if (part_has_channel(ctx, i, channel)) found = i, count++;
  if (count == 1) {
    *out = found;
    return HF_OK;
  }
  list_parts(ctx, nparts, parts, sizeof parts);
  if (!channel)
    return fail(err, errlen, HF_ENOTFOUND, "%s has %d parts: %s; choose one with --part N|NAME",
                path, nparts, parts);
  return fail(err, errlen, HF_ENOTFOUND, "%s has %d parts, %s with channel %s: %s; choose one "
              "with --part N|NAME", path, nparts, count ? "several" : "none", channel, parts);
}

/* ---- reading ------------------------------------------------------------------ */

/* Why exr_start_read refused a file, in the user's terms. */
static int open_failed(const char *path, uint64_t size, exr_result_t r, const hf_exr_msg *msg,
                       char *err, size_t errlen) {
  char more[300];
  const char *d = detail(msg, more, sizeof more);
  unsigned char magic[4] = {0};
  FILE *f = fopen(path, "rb");
  size_t got = f ? fread(magic, 1, 4, f) : 0;
  if (f) fclose(f);
  if (r == EXR_ERR_FILE_ACCESS || !f)
    return fail(err, errlen, HF_EIO, "%s: cannot open%s", path, d);
  /* An empty file, or one that ends inside the magic number, is a copy or
   * a write that stopped, not a file of another kind. */
  static const unsigned char want[4] = {0x76, 0x2f, 0x31, 0x01};
  if (size == 0)
    return fail(err, errlen, HF_EIO, "%s: empty file (0 bytes): write or copy the file again",
                path);
  if (got < 4 && got == size && !memcmp(magic, want, got))
    return fail(err, errlen, HF_EIO, "%s: truncated / incomplete file: it ends inside the "
                "OpenEXR magic number (%llu bytes); write or copy the file again", path,
                (unsigned long long)size);
  if (got < 4 || magic[0] != 0x76 || magic[1] != 0x2f || magic[2] != 0x31 || magic[3] != 0x01)
    return fail(err, errlen, HF_EFORMAT, "%s: not an OpenEXR file", path);
  /* A header cut short fails to parse (bad header, a required attribute
   * missing, a short read); an invalid value (EXR_ERR_INVALID_ATTR) is
   * found in a header read whole, even when the library read ahead past
   * the end of a small file. The library also reads past the end of a
   * damaged header it has given up on (and ahead past the end of a small
   * file): the headers must run into the end looking whole up to it. */
  if ((r == EXR_ERR_FILE_BAD_HEADER || r == EXR_ERR_MISSING_REQ_ATTR || r == EXR_ERR_READ_IO) &&
      cut_short(path, 0, NULL, size) && header_cut_short(path, size))
    return fail(err, errlen, HF_EIO, "%s: truncated / incomplete file: it ends inside its "
                "header (%llu bytes); write or copy the file again", path,
                (unsigned long long)size);
  char why[400];
  if (hf_exr_chlist_fault(path, why, sizeof why))
    return fail(err, errlen, HF_EFORMAT, "%s: %s", path, why);
  return fail(err, errlen, HF_EFORMAT, "%s: the EXR header cannot be read: %s%s; the file is "
              "damaged, write it again", path, exr_get_error_code_as_string(r), d);
}

/* The channels' image (names, windows) and their values: into img->data as
 * float32 when data is NULL, else into a buffer of dtype given back in
 * *data, img->data staying NULL. */
static int read_part(const char *path, const char *part, const char *channel, hf_image *img,
                     hf_dtype dtype, void **data, char *err, size_t errlen) {
  if (data) *data = NULL;
  if (img) memset(img, 0, sizeof *img);
  if (!path || !img || (data && dtype != HF_F32 && dtype != HF_F16))
    return fail(err, errlen, HF_EINVAL, "null argument or unknown dtype");
  struct stat st;
  if (stat(path, &st) != 0) return fail(err, errlen, HF_EIO, "%s: %s", path, strerror(errno));
  if (!S_ISREG(st.st_mode)) return fail(err, errlen, HF_EIO, "%s: not a regular file", path);
  hf_exr_msg msg = {""};
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = hf_exr_on_error;
  init.user_data = &msg;
  exr_context_t ctx = NULL;
  exr_result_t r = exr_start_read(&ctx, path, &init);
  if (r != EXR_ERR_SUCCESS) {
    exr_finish(&ctx);
    return open_failed(path, (uint64_t)st.st_size, r, &msg, err, errlen);
  }
  /* The library reports some invalid values and reads on with a default in
   * their place (a compression code it does not know becomes ZIP, whose
   * decoder then fails or reads garbage): what it said is why the file is
   * refused. */
  if (msg.text[0]) {
    exr_finish(&ctx);
    return fail(err, errlen, HF_EFORMAT, "%s: the EXR header holds an invalid value (OpenEXR: "
                "%s); the file is damaged, write it again", path, msg.text);
  }
  int rc, nparts = 0, pi = 0;
  char label[128];
  if ((r = exr_get_count(ctx, &nparts)) || nparts < 1) {
    rc = fail(err, errlen, HF_EFORMAT, "%s: no image part", path);
    goto out;
  }
  if ((rc = choose_part(ctx, path, nparts, part, channel, &pi, err, errlen)) != HF_OK) goto out;
  part_label(ctx, pi, nparts, label, sizeof label);
  exr_storage_t storage;
  exr_attr_box2i_t dw, disp;
  const exr_attr_chlist_t *chl;
  if ((r = exr_get_storage(ctx, pi, &storage)) || (r = exr_get_data_window(ctx, pi, &dw)) ||
      (r = exr_get_display_window(ctx, pi, &disp)) || (r = exr_get_channels(ctx, pi, &chl))) {
    rc = fail(err, errlen, HF_EFORMAT, "%s%s: %s", path, label, exr_get_error_code_as_string(r));
    goto out;
  }
  if (storage == EXR_STORAGE_DEEP_SCANLINE || storage == EXR_STORAGE_DEEP_TILED) {
    rc = fail(err, errlen, HF_EUNSUPPORTED, "%s%s: deep data (several samples per pixel of "
              "varying count) is not read; flatten it first, e.g. oiiotool %s --flatten -o "
              "flat.exr", path, label, path);
    goto out;
  }
  int64_t w = (int64_t)dw.max.x - dw.min.x + 1, h = (int64_t)dw.max.y - dw.min.y + 1;
  int nch = chl->num_channels;
  if (w < 1 || h < 1 || nch < 1 || nch > HF_MAX_CHANNELS ||
      (size_t)(w * h) > EXR_MAX_FLOATS / (size_t)nch) {
    rc = fail(err, errlen, HF_ERANGE, "%s%s: %lldx%lld pixels with %d channels is more than "
              "this reader takes (%zu values, %d channels); split the file", path, label,
              (long long)w, (long long)h, nch, EXR_MAX_FLOATS, HF_MAX_CHANNELS);
    goto out;
  }
  for (int c = 0; c < nch; c++)
    if (chl->entries[c].x_sampling != 1 || chl->entries[c].y_sampling != 1) {
      rc = fail(err, errlen, HF_EUNSUPPORTED, "%s%s: channel %s is subsampled (%dx%d); "
                "only full-resolution channels are read", path, label,
                chl->entries[c].name.str, chl->entries[c].x_sampling,
                chl->entries[c].y_sampling);
      goto out;
    }
  /* The claimed-size check speaks first, its words (pixels claimed against
   * bytes held) saying most about a header that claims far more than the
   * file holds, whose table is then garbage; but a file that ends inside
   * its last chunk is called cut short, also when (uncompressed) it holds
   * fewer bytes than its pixels. */
  table_state table = chunk_table(ctx, pi, path, (uint64_t)st.st_size);
  if ((rc = check_decodable(ctx, pi, path, label, chl, err, errlen)) != HF_OK ||
      (table == TABLE_CHUNK_CUT &&
       (rc = check_complete(table, path, label, w, h, (uint64_t)st.st_size, err, errlen)) !=
           HF_OK) ||
      (rc = check_claimed_size(ctx, pi, path, label, chl, w, h, (uint64_t)st.st_size, table,
                               err, errlen)) != HF_OK ||
      (rc = check_complete(table, path, label, w, h, (uint64_t)st.st_size, err, errlen)) !=
          HF_OK)
    goto out;
  /* HALF channels go straight into halves when halves are asked for: the
   * library widens them to float otherwise, and narrowing back would cost a
   * second pass over the frame for the same bits. Any other channel type
   * (FLOAT, UINT) is decoded as float and, for halves, converted once. */
  int all_half = 1;
  for (int c = 0; c < nch; c++)
    if (chl->entries[c].pixel_type != EXR_PIXEL_HALF) all_half = 0;
  exr_pixel_type_t type = data && dtype == HF_F16 && all_half ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT;
  size_t nval = (size_t)(w * h) * (size_t)nch;
  void *dst = NULL;
  if (!data) {
    if ((rc = hf_image_alloc(img, (int)w, (int)h, nch)) != 0) {
      fail(err, errlen, rc, "%s%s: %s", path, label, hf_strerror(rc));
      goto out;
    }
    dst = img->data;
  } else {
    img->names = calloc((size_t)nch, sizeof *img->names);
    dst = malloc(nval * (type == EXR_PIXEL_HALF ? sizeof(uint16_t) : sizeof(float)));
    if (!img->names || !dst) {
      free(dst);
      rc = fail(err, errlen, HF_ENOMEM, "%s%s: out of memory for %lldx%lld pixels with %d "
                "channels", path, label, (long long)w, (long long)h, nch);
      goto fail_img;
    }
    img->width = (int)w;
    img->height = (int)h;
    img->channels = nch;
  }
  int *slot = malloc(sizeof *slot * (size_t)nch);
  if (!slot) {
    rc = fail(err, errlen, HF_ENOMEM, "%s: out of memory", path);
    goto fail_dst;
  }
  for (int c = 0; c < nch; c++) {
    snprintf(img->names[c], sizeof img->names[c], "%s", chl->entries[c].name.str);
    slot[c] = c;
  }
  img->origin_x = dw.min.x;
  img->origin_y = dw.min.y;
  img->lossy = lossy_compression(ctx, pi, chl);
  for (int c = 0; c < nch; c++)
    if (chl->entries[c].pixel_type == EXR_PIXEL_UINT) {
      if (!img->uint_stored && !(img->uint_stored = calloc((size_t)nch, 1))) {
        free(slot);
        rc = fail(err, errlen, HF_ENOMEM, "%s: out of memory", path);
        goto fail_dst;
      }
      img->uint_stored[c] = 1;
    }
  int64_t dispw = (int64_t)disp.max.x - disp.min.x + 1, disph = (int64_t)disp.max.y - disp.min.y + 1;
  if ((disp.min.x != dw.min.x || disp.min.y != dw.min.y || dispw != w || disph != h) &&
      dispw >= 1 && disph >= 1 && dispw <= INT32_MAX && disph <= INT32_MAX) {
    img->display_x = disp.min.x;
    img->display_y = disp.min.y;
    img->display_width = (int)dispw;
    img->display_height = (int)disph;
  }
  rc = hf_exr_decode_part(ctx, pi, path, label, (uint64_t)st.st_size, slot, nch, type, dst,
                          err, errlen);
  free(slot);
  if (rc != HF_OK) goto fail_dst;
  if (data && dtype == HF_F16 && type == EXR_PIXEL_FLOAT) {
    uint16_t *half = malloc(nval * sizeof *half);
    if (!half) {
      rc = fail(err, errlen, HF_ENOMEM, "%s%s: out of memory for %lldx%lld pixels with %d "
                "channels", path, label, (long long)w, (long long)h, nch);
      goto fail_dst;
    }
    hf_f32_to_f16_array(dst, half, nval);
    /* A finite value beyond binary16's range rounds to an infinity the
     * file does not hold, and a non-finite feature makes its whole sample
     * uncovered where float32 would clamp it (protocol/FEATURES.md, "Out-of-
     * contract values"): it becomes the largest half of its sign instead,
     * which every rule clamps as it clamps the file's value (every bound is
     * at most 64). */
    const float *f = dst;
    for (size_t i = 0; i < nval; i++)
      if ((half[i] & 0x7fffu) == 0x7c00u && isfinite(f[i])) half[i] = (uint16_t)(half[i] - 1u);
    free(dst);
    dst = half;
  }
  if (data) *data = dst;
  goto out;
fail_dst:
  if (data) free(dst);
fail_img:
  hf_image_free(img);
out:
  exr_finish(&ctx);
  return rc;
}

int hf_exr_read_part(const char *path, const char *part, const char *channel, hf_image *img,
                     char *err, size_t errlen) {
  return read_part(path, part, channel, img, HF_F32, NULL, err, errlen);
}

int hf_exr_read_part_as(const char *path, const char *part, const char *channel, hf_dtype dtype,
                        hf_image *img, void **data, char *err, size_t errlen) {
  if (!data) return fail(err, errlen, HF_EINVAL, "null argument");
  return read_part(path, part, channel, img, dtype, data, err, errlen);
}

int hf_exr_read(const char *path, hf_image *img, char *err, size_t errlen) {
  return hf_exr_read_part(path, NULL, NULL, img, err, errlen);
}

/* Opens path's headers alone (no chunk is read), errors into msg: what the
 * header-only queries below share. */
static exr_result_t start_headers(const char *path, hf_exr_msg *msg, exr_context_t *ctx) {
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = hf_exr_on_error;
  init.user_data = msg;
  init.flags |= EXR_CONTEXT_FLAG_SILENT_HEADER_PARSE;
  *ctx = NULL;
  return exr_start_read(ctx, path, &init);
}

int hf_exr_display_size(const char *path, int *width, int *height, char *err, size_t errlen) {
  if (!path || !width || !height) return fail(err, errlen, HF_EINVAL, "null argument");
  hf_exr_msg msg = {""};
  exr_context_t ctx;
  exr_result_t r = start_headers(path, &msg, &ctx);
  if (r != EXR_ERR_SUCCESS) {
    exr_finish(&ctx);
    return fail(err, errlen, HF_EIO, "%s: %s", path, exr_get_error_code_as_string(r));
  }
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

int hf_exr_has_channel(const char *path, const char *channel) {
  if (!path || !channel) return HF_EINVAL;
  hf_exr_msg msg = {""};
  exr_context_t ctx;
  int parts = 0, found = 0;
  if (start_headers(path, &msg, &ctx) != EXR_ERR_SUCCESS ||
      exr_get_count(ctx, &parts) != EXR_ERR_SUCCESS) {
    exr_finish(&ctx);
    return HF_EIO;
  }
  for (int p = 0; p < parts && !found; p++) {
    const exr_attr_chlist_t *ch = NULL;
    if (exr_get_channels(ctx, p, &ch) != EXR_ERR_SUCCESS || !ch) continue;
    for (int c = 0; c < ch->num_channels && !found; c++)
      found = ch->entries[c].name.str && !strcmp(ch->entries[c].name.str, channel);
  }
  exr_finish(&ctx);
  return found;
}

int hf_exr_read_int_attr(const char *path, const char *name, int *value) {
  if (!path || !name || !value) return HF_EINVAL;
  hf_exr_msg msg = {""};
  exr_context_t ctx;
  if (start_headers(path, &msg, &ctx) != EXR_ERR_SUCCESS) {
    exr_finish(&ctx);
    return HF_EIO;
  }
  int32_t v = 0;
  exr_result_t r = exr_attr_get_int(ctx, 0, name, &v);
  exr_finish(&ctx);
  if (r == EXR_ERR_NO_ATTR_BY_NAME) return HF_ENOTFOUND;
  if (r != EXR_ERR_SUCCESS) return HF_EFORMAT; /* there, but not an int */
  *value = v;
  return HF_OK;
}
