/* Placeholder until the bench command lands. */
#include <stdio.h>
#include "commands.h"
int cmd_bench(int argc, char **argv) {
  (void)argc; (void)argv;
  fprintf(stderr, "hairfilter bench: not available in this build\n");
  return 2;
}
