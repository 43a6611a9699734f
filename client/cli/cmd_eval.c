/* Placeholder until the eval command lands. */
#include <stdio.h>
#include "commands.h"
int cmd_eval(int argc, char **argv) {
  (void)argc; (void)argv;
  fprintf(stderr, "hairfilter eval: not available in this build\n");
  return 2;
}
