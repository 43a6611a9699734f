/* Fuzz target: the feature EXR reader, as the CLI and the load tool use
 * it (hf_exr_read_part choosing the part with S0.color, then
 * hf_features_spp and hf_features_from_image; src/exr_read.c,
 * src/features.c). OpenEXR's C API reads from a file, so each input is put
 * in a memory file (memfd) and read through /proc/self/fd. The contract:
 * any input is refused with a message, or gives an image whose size and
 * channels agree with what was allocated; its features are read without
 * leaving the image, or named missing. */
#define _GNU_SOURCE
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "hfcore.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static int fd = -1;
  static char path[64];
  if (fd < 0) {
    fd = memfd_create("fuzz-exr", MFD_CLOEXEC);
    if (fd < 0) abort();
    snprintf(path, sizeof path, "/proc/self/fd/%d", fd);
  }
  if (ftruncate(fd, 0) || pwrite(fd, data, size, 0) != (ssize_t)size) abort();
  hf_image img;
  char err[512];
  err[0] = 0;
  memset(&img, 0, sizeof img);
  int rc = hf_exr_read_part(path, NULL, "S0.color", &img, err, sizeof err);
  if (rc) {
    if (!err[0] || img.data) {
      fprintf(stderr, "fuzz_exr: failure %d without a message, or with pixels\n", rc);
      abort();
    }
    return 0;
  }
  if (img.width < 1 || img.height < 1 || img.channels < 1 || !img.data) {
    fprintf(stderr, "fuzz_exr: read an image of %dx%d x %d channels\n", img.width, img.height,
            img.channels);
    abort();
  }
  int spp = hf_features_spp(&img);
  if (spp > 0 && spp <= HF_MAX_SPP && (size_t)img.width * img.height <= (1u << 20)) {
    float *in = malloc((size_t)img.width * img.height * (size_t)spp * 6 * sizeof *in);
    /* All spp samples read, or one of their features is missing. */
    int rc2 = in ? hf_features_from_image(&img, spp, in) : spp;
    if (rc2 != spp && rc2 != HF_ENOTFOUND) {
      fprintf(stderr, "fuzz_exr: %d samples counted, reading them gave %d\n", spp, rc2);
      abort();
    }
    free(in);
  }
  hf_image_free(&img);
  return 0;
}
