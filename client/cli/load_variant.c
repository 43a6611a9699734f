#include "load_variant.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

enum { MAX_LISTED = 64 };

int load_find_variant(hfc_client *c, const char *prog, const char *name, hfc_variant *found) {
  /* On the heap: 64 variants with their input ranges are about 20 KB. */
  hfc_variant *vs = calloc(MAX_LISTED, sizeof *vs);
  int nv = 0, rc = vs ? hfc_list_variants(c, vs, MAX_LISTED, &nv) : HFC_E_NOMEM;
  if (rc) {
    fprintf(stderr, "%s: listing variants: %s\n", prog, hfc_strerror(rc));
    free(vs);
    return 1;
  }
  char names[MAX_LISTED * 66] = "";
  int hit = -1;
  for (int i = 0; i < nv && i < MAX_LISTED; i++) {
    size_t used = strlen(names);
    snprintf(names + used, sizeof names - used, "%s%.64s", i ? ", " : "", vs[i].name);
    if (hit < 0 && !strcasecmp(vs[i].name, name)) hit = i;
  }
  if (hit >= 0) *found = vs[hit];
  else
    fprintf(stderr, "%s: the server has no variant '%s': it has %s\n", prog, name,
            names[0] ? names : "none");
  free(vs);
  return hit < 0;
}
