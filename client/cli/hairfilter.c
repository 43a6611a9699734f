/* hairfilter: the command-line front end. Each subcommand lives in its own
 * cmd_<name>.c; this file only dispatches. */
#include <stdio.h>
#include <string.h>

#include <hairfilter/hairfilter.h>

#include "commands.h"

#ifndef HF_HAVE_RENDERER
/* render and demo draw hair with client/render, and eval composites through
 * it, which this build leaves out (cmake -DHF_RENDERER=OFF, the build that
 * travels to GPU machines). */
static int cmd_no_renderer(int argc, char **argv) {
  (void)argc;
  fprintf(stderr,
          "hairfilter %s: this hairfilter was built without the renderer "
          "(-DHF_RENDERER=OFF); use a build with it\n",
          argv[0]);
  return 2;
}
#define cmd_demo cmd_no_renderer
#define cmd_render cmd_no_renderer
#define cmd_eval cmd_no_renderer
#endif

static const struct {
  const char *name;
  int (*fn)(int, char **);
  const char *help;
} commands[] = {
  {"demo",   cmd_demo,   "render or load the bundled example, filter it, write a PNG"},
  {"infer",  cmd_infer,  "filter a feature EXR in-process: --weights W --in F.exr --out R.exr"},
  {"filter", cmd_filter, "filter a feature EXR through hairfilterd: --server URL"},
  {"render", cmd_render, "render hair with OSMesa: features, ground truth, baselines, datasets"},
  {"bench",  cmd_bench,  "benchmark backends and variants"},
  {"eval",   cmd_eval,   "evaluate filtering quality against ground truth"},
  {"conformance", cmd_conformance, "check a server (or libhairfilter) against PROTOCOL.md: --server URL"},
  {"load",   cmd_load,   "load a server: latency and throughput sweeps, open or closed loop"},
};

static void usage(FILE *f) {
  fprintf(f, "usage: hairfilter <command> [options]   (hairfilter <command> --help)\n"
             "       hairfilter --version\n\n");
  for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
    fprintf(f, "  %-12s %s\n", commands[i].name, commands[i].help);
}

int main(int argc, char **argv) {
  if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  if (!strcmp(argv[1], "--version")) {
    /* The library's own version too: it is linked statically here, but an
     * engine may load another. */
    printf("hairfilter %s (libhairfilter %s)\n", HAIRFILTER_VERSION_STRING, hfc_version());
    return 0;
  }
  for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
    if (!strcmp(argv[1], commands[i].name))
      return commands[i].fn(argc - 1, argv + 1);
  fprintf(stderr, "hairfilter: unknown command '%s'\n", argv[1]);
  usage(stderr);
  return 2;
}
