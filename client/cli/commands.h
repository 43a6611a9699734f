/* Subcommands of the hairfilter CLI: one file each (cmd_<name>.c). */
#ifndef HF_CLI_COMMANDS_H
#define HF_CLI_COMMANDS_H

int cmd_infer(int argc, char **argv);   /* in-process inference on an EXR */
int cmd_demo(int argc, char **argv);    /* the README's main job */
int cmd_bench(int argc, char **argv);   /* backend benchmark table */
int cmd_filter(int argc, char **argv);  /* filter through hairfilterd */
int cmd_render(int argc, char **argv);  /* OSMesa hair renderer */
int cmd_eval(int argc, char **argv);    /* quality evaluation */
int cmd_conformance(int argc, char **argv); /* protocol conformance suite */
int cmd_load(int argc, char **argv);    /* load sweeps (hairfilter load) */

#endif
