/* Fuzz target: the .hair reader (hfr_hair_load_mem, client/render/
 * hr_hair_io.c). The contract: any input is refused with a message, or
 * loads into a model whose counts agree (the segments of the strands add
 * up to the points, within HFR_MAX_*) and whose positions are finite;
 * nothing is read out of bounds, nothing leaks. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfrender.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  hfr_hair h;
  char err[512];
  err[0] = 0;
  memset(&h, 0, sizeof h);
  int rc = hfr_hair_load_mem(data, size, &h, err, sizeof err);
  if (rc) {
    if (!err[0]) {
      fprintf(stderr, "fuzz_hair: failure %d without a message\n", rc);
      abort();
    }
    return 0;
  }
  uint64_t points = 0;
  for (uint32_t i = 0; i < h.strands; i++) points += hfr_hair_strand_segments(&h, i) + 1;
  if (h.strands > HFR_MAX_STRANDS || h.points > HFR_MAX_POINTS || points != h.points) {
    fprintf(stderr, "fuzz_hair: %u strands of %llu points, the header says %u\n", h.strands,
            (unsigned long long)points, h.points);
    abort();
  }
  for (uint64_t i = 0; i < 3ull * h.points; i++)
    if (!isfinite(h.pos[i])) {
      fprintf(stderr, "fuzz_hair: a loaded position is not finite\n");
      abort();
    }
  hfr_hair_free(&h);
  return 0;
}
