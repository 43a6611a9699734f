/* A tiny engine in C99, built against an installed hairfilter alone: the
 * integration client/lib/README.md describes. engine URL VARIANT prints the
 * versions and a hash of the filtered frame. */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <hairfilter/hairfilter.h>

#include "engine_frame.h"

int main(int argc, char **argv) {
  static float features[ENGINE_W * ENGINE_H * ENGINE_SPP * 6];
  static float filtered[ENGINE_W * ENGINE_H * 3];
  hfc_options opt;
  hfc_client *hf;
  hfc_request r;
  hfc_timing t;
  int rc;
  if (argc != 3) return 2;
  if (strcmp(hfc_version(), HAIRFILTER_VERSION_STRING) != 0) {
    fprintf(stderr, "engine: headers %s, library %s\n", HAIRFILTER_VERSION_STRING, hfc_version());
    return 1;
  }
  hfc_options_init(&opt);
  opt.client_name = "engine-c";
  if (hfc_connect(argv[1], &opt, &hf) != HFC_OK) {
    fprintf(stderr, "engine: %s\n", hfc_last_message(NULL));
    return 1;
  }
  engine_features(features);
  hfc_request_init(&r);
  r.variant = argv[2];
  r.width = ENGINE_W;
  r.height = ENGINE_H;
  r.spp = ENGINE_SPP;
  r.features = features;
  r.features_bytes = sizeof features;
  r.result = filtered;
  r.result_bytes = sizeof filtered;
  rc = hfc_filter(hf, &r, &t);
  if (rc != HFC_OK) {
    fprintf(stderr, "engine: %s (%s)\n", hfc_strerror(rc), hfc_last_message(hf));
    hfc_close(hf);
    return 1;
  }
  printf("library %s server %s result %016" PRIx64 "\n", hfc_version(),
         hfc_info(hf)->software_version, engine_hash(filtered, sizeof filtered));
  hfc_close(hf);
  return 0;
}
