/* Fuzz target: the safetensors weights loader (hf_weights_load_mem,
 * src/weights_load.c), which reads files a user hands the server. The
 * contract: any input is refused with an error code and a message, or
 * loads into weights whose configuration validates and whose every tensor
 * is inside the buffer it was read from; nothing is read out of bounds,
 * nothing leaks (ASan, UBSan, LeakSanitizer). */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hfcore.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  hf_weights *w = NULL;
  char err[512];
  err[0] = 0;
  int rc = hf_weights_load_mem(data, size, &w, err, sizeof err);
  if (rc) {
    if (rc > 0 || w || !err[0]) {
      fprintf(stderr, "fuzz_weights: failure %d without a message or with weights\n", rc);
      abort();
    }
    return 0;
  }
  if (!w || hf_net_config_validate(&w->cfg)) {
    fprintf(stderr, "fuzz_weights: loaded weights whose configuration does not validate\n");
    abort();
  }
  hf_weights_free(w);
  return 0;
}
