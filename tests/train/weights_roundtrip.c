/* Loads a weights file through the C loader and writes it back with
 * hf_weights_save, so the training test can check that an export survives
 * the C side bit-exactly: weights_roundtrip IN.safetensors OUT.safetensors */
#include <stdio.h>

#include "hfcore.h"

int main(int argc, char **argv) {
  if (argc != 3) {
    fprintf(stderr, "usage: weights_roundtrip IN.safetensors OUT.safetensors\n");
    return 2;
  }
  char err[512];
  hf_weights *w = NULL;
  int rc = hf_weights_load(argv[1], &w, err, sizeof err);
  if (rc) {
    fprintf(stderr, "weights_roundtrip: %s\n", err);
    return 1;
  }
  printf("%s: %s, %d spp, %d levels, %zu parameters\n", argv[1], w->cfg.name, w->cfg.spp,
         w->cfg.num_levels, w->num_params);
  rc = hf_weights_save(argv[2], w);
  hf_weights_free(w);
  if (rc) {
    fprintf(stderr, "weights_roundtrip: writing %s: %s\n", argv[2], hf_strerror(rc));
    return 1;
  }
  return 0;
}
