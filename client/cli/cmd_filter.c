/* Placeholder until the filter command lands. */
#include <stdio.h>
#include "commands.h"
int cmd_filter(int argc, char **argv) {
  (void)argc; (void)argv;
  fprintf(stderr, "hairfilter filter: not available in this build\n");
  return 2;
}
