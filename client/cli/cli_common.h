/* Small helpers shared by the CLI subcommands. */
#ifndef HF_CLI_COMMON_H
#define HF_CLI_COMMON_H

#include "hfcore.h"

/* Parses "r,g,b" (three finite numbers, nothing else) into rgb; 0 on
 * success, else -1 after printing "hairfilter <cmd>: <opt>: ..." naming
 * the value and the form it takes. */
int cli_parse_rgb(const char *cmd, const char *opt, const char *s, float rgb[3]);
/* Prints why hfc_connect failed with rc: the library's message (which
 * names each endpoint and what to check), then, for a refused token, where
 * the CLI takes it from. prog: "hairfilter filter", ... */
void cli_connect_failed(const char *prog, int rc);
/* Checks, before any work, that a file can be created at path: its
 * directory exists and is writable. 0 when so; else prints
 * "<prog>: <path>: ..." naming the directory and what to do, and returns
 * HF_EIO, so that a command does not render or filter for minutes and
 * then lose the result. NULL path: 0. */
int cli_check_output(const char *prog, const char *path);
/* cli_check_output for a directory the command creates (trailing '/'s
 * allowed): the directory it goes in must exist and be writable. */
int cli_check_output_dir(const char *prog, const char *dir);
/* Parses "WxH"; 0 on success. */
int cli_parse_size(const char *s, int *w, int *h);
/* Where bundled data (weights/, bench/) lives: $HAIRFILTER_DATA; else the
 * first directory holding weights/hfnet.py among the executable's own
 * directory and its parents (a checkout's build/, a carried or installed
 * bin/, with share/hairfilter looked at too); else the source tree this
 * binary was built from. */
const char *cli_data_dir(void);
/* Creates the backend by name and prints one line saying which and why. */
int cli_open_backend(const char *name, hf_backend **out);
/* Composites a [h][w][3] result with the given colors and writes a PNG:
 * over layer (a frame's background layer, cli_read_features) when it is not
 * NULL and of this size, as the renderer's composites (hfr_composite_result;
 * protocol/FEATURES.md), else over bg alone. */
int cli_write_preview(const char *path, const float *result, int w, int h,
                      const hf_image *layer, const float hair[3], const float light[3],
                      const float bg[3]);

/* The frame's input statistics (hf_input_stats_compute of in, [h][w][spp*6]
 * of dtype) into *st, checked against a trained range: the mask of the
 * statistics outside it (bit HF_STAT_*; 0 inside or when r has no range), or
 * a negative HF_E* code. */
int cli_input_range_check(const hf_input_range *r, const void *in, hf_dtype dtype, int w, int h,
                          int spp, hf_input_stats *st);
/* "PROG: warning: PATH is compressed with B44, which is lossy: ..." on
 * stderr when img was read from a lossily compressed file (img->lossy). */
void cli_warn_lossy(const char *prog, const char *path, const hf_image *img);
/* 1, with a message naming the channel, when img (read from path) holds a
 * channel of protocol/FEATURES.md's contract (S<k>.*, acst4.*, gt.*,
 * st<n>.*) stored as UINT: its integers would be read as feature values. */
int cli_refuse_uint(const char *prog, const char *path, const hf_image *img);
/* "PROG: warning: FRAME is outside the input range VARIANT was trained on:
 * STAT VALUE (trained LOW..HIGH), ..." on stderr (hf_input_range_describe). */
void cli_warn_input_range(const char *prog, const char *frame, const char *variant,
                          const hf_input_range *r, const hf_input_stats *st, unsigned mask);
/* Reads a feature EXR for a network of spp samples per pixel: the part
 * (NULL: the one with S0.color, else --part's N or NAME), and its first spp
 * samples as network input (*in, malloc'd, [h][w][spp*6] of dtype, NHWC; a
 * HALF file read as HF_F16 is never converted: hf_exr_read_part_as), with
 * estimate (hf_net_config.estimate) followed by the frame's alpha-corrected
 * estimate ([h][w][3], the acst4.* channels: the planar frame hf_io
 * takes; a file without them is refused, naming the render option). img
 * gets the size, channel names and windows, img->data stays NULL. layer
 * (may be NULL) gets the file's background layer, background.R/G/B/A as
 * float32 [h][w][4] (the renderer draws the head and anything else under the
 * hair there: docs/RENDERING.md), or stays zeroed (width 0) without one.
 * Files with more samples are read on their first spp (protocol/FEATURES.md).
 * variant names the network in messages. On failure prints one line naming
 * the file, the part or channel and what to do, and returns a negative HF_E*
 * code with img and *in released. */
int cli_read_features(const char *path, const char *part, int spp, int estimate,
                      const char *variant, hf_dtype dtype, hf_image *img, void **in,
                      hf_image *layer);
/* Prints one warning when hf_model_run_report sanitised a frame's input or
 * repaired its output: how many samples, and the first one by pixel (in the
 * file's coordinates: img's data window origin added), sample and channel.
 * Nothing when r changed nothing. */
void cli_warn_sanitised(const char *path, const hf_image *img, const hf_input_report *r);

/* Default colours of previews: brown hair, white light, grey-blue background. */
extern const float CLI_HAIR_DEFAULT[3], CLI_LIGHT_DEFAULT[3], CLI_BG_DEFAULT[3];

#endif
