/* hairfilter demo: the README's main job on the bundled defaults. */
#include <getopt.h>
#include <stdio.h>
#include <string.h>

#include "cli_common.h"
#include "commands.h"

int cli_infer_file(const char *weights, const char *in_path, const char *backend,
                   hf_image *result_img, int verbose);

int cmd_demo(int argc, char **argv) {
  const char *out = "hairfilter-demo.png", *backend = "auto";
  static const struct option opts[] = {{"out", required_argument, 0, 'o'},
                                       {"backend", required_argument, 0, 'b'},
                                       {"help", no_argument, 0, 'h'},
                                       {0, 0, 0, 0}};
  int c;
  optind = 1;
  while ((c = getopt_long(argc, argv, "o:b:h", opts, NULL)) != -1) {
    if (c == 'o') out = optarg;
    else if (c == 'b') backend = optarg;
    else {
      fprintf(c == 'h' ? stdout : stderr, "usage: hairfilter demo [--out PNG] [--backend NAME]\n");
      return c == 'h' ? 0 : 2;
    }
  }
  char weights[1024], example[1024];
  snprintf(weights, sizeof weights, "%s/weights/base.safetensors", cli_data_dir());
  snprintf(example, sizeof example, "%s/weights/examples/example.exr", cli_data_dir());
  hf_image res = {0};
  if (cli_infer_file(weights, example, backend, &res, 1)) return 1;
  int rc = cli_write_preview(out, res.data, res.width, res.height, CLI_HAIR_DEFAULT,
                             CLI_LIGHT_DEFAULT, CLI_BG_DEFAULT);
  hf_image_free(&res);
  if (rc) {
    fprintf(stderr, "hairfilter: writing %s: %s\n", out, hf_strerror(rc));
    return 1;
  }
  printf("wrote %s\n", out);
  return 0;
}
