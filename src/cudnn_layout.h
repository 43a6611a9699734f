/*
 * Device memory layout of one forward pass for the cudnn backend (internal
 * to src/). Pure arithmetic, no CUDA: it is unit-tested on machines without
 * a GPU.
 *
 * Activations are FP16 NHWC with every channel count rounded up to a
 * multiple of 8, which tensor-core kernels need. The skip concatenation is
 * never copied: the input of dec{i} (i < L-1) is one buffer of 2*c_i
 * channels per pixel; dec{i+1} writes its first c_i channels and enc{i}
 * its last c_i, each through a strided view (channel stride 1, pixel stride
 * 2*c_i). enc{i+1} reads enc{i}'s output through the same strided view.
 *
 * Buffers (all [batch][h][w][channels]):
 *   HF_CL_BUF_IN       network input, ph x pw, cin_pad channels
 *   HF_CL_BUF_SKIP0+i  i = 0..L-2: [dec{i+1} out | enc{i} out],
 *                      ph/2^(i+1) x pw/2^(i+1), 2*pad8(c_i)
 *   HF_CL_BUF_DEEP     enc{L-1} out, ph/2^L x pw/2^L, pad8(c_{L-1})
 *   HF_CL_BUF_OUT      dec0 out, ph x pw, 8 (3 used)
 *
 * Filters are FP16 in cuDNN's NHWC filter order [K][R][S][C]. For enc{i}
 * (forward conv) K is the output and C the input. dec{i} is a transposed
 * conv computed as the data gradient of the forward conv it transposes, so
 * K is its *input* (cuDNN's dy) and C its *output* (dx); PyTorch's
 * ConvTranspose2d weight [in][out][4][4] is exactly that forward conv's
 * [K][C][R][S], with no flip.
 *
 * With HF_CL_DECONV_SHUFFLE a decoder is instead a 3x3 stride-1 forward
 * conv to 4*C channels at the input resolution followed by a depth-to-space
 * of 2: output pixel (2y+dy, 2x+dx), channel c, is channel (2dy+dx)*C + c
 * of conv pixel (y, x). A 4x4 stride-2 pad-1 transposed conv reaches output
 * row 2y+dy from input rows y-1, y (dy = 0, taps 3, 1) or y, y+1 (dy = 1,
 * taps 2, 0), which is what the 3x3 filter holds.
 */
#ifndef HF_CUDNN_LAYOUT_H
#define HF_CUDNN_LAYOUT_H

#include <stddef.h>
#include <stdint.h>

#include "hfcore.h"

#define HF_CL_ALIGN_CH 8
#define HF_CL_OUT_CH   8          /* dec0's 3 outputs, padded */
#define HF_CL_MAX_LAYERS (2 * HF_MAX_LEVELS)

enum {
  HF_CL_BUF_IN = 0,
  HF_CL_BUF_DEEP = 1,
  HF_CL_BUF_OUT = 2,
  HF_CL_BUF_SKIP0 = 3,
  HF_CL_MAX_BUFS = HF_CL_BUF_SKIP0 + HF_MAX_LEVELS - 1
};

enum { HF_CL_CONV_FWD = 0, HF_CL_CONV_BWD_DATA = 1, HF_CL_CONV_SHUFFLE = 2 };

/* How decoders (transposed convs) are computed. */
enum { HF_CL_DECONV_BWD_DATA = 0, HF_CL_DECONV_SHUFFLE = 1 };

/* A 4-D NHWC tensor inside a buffer: elements of pixel p, channel k live at
 * buffer + ch_off + p * pix_stride + k. */
typedef struct hf_cl_view {
  int buf;
  int ch_off;
  int pix_stride;
  int c, h, w;
} hf_cl_view;

typedef struct hf_cl_layer {
  char name[16];               /* "enc0", "dec2" */
  int kind;                    /* HF_CL_CONV_* */
  int level;
  int relu;                    /* ReLU after the bias (all but dec0) */
  int k, c, r, s;              /* filter [K][R][S][C], padded; for
                                  SHUFFLE K = 4 * out.c */
  int stride, pad;
  /* What the layer reads and writes. For BWD_DATA, in is cuDNN's dy
   * (K channels) and out is dx (C channels). */
  hf_cl_view in, out;
  /* Real (unpadded) channel counts and how real input channels map to
   * padded ones: real input j < in_split goes to j, j >= in_split goes to
   * in_split_pad + (j - in_split). in_split == in_real means no split. */
  int in_real, out_real, in_split, in_split_pad;
  size_t w_off, w_elems;       /* into the packed FP16 filter array */
  size_t b_off;                /* into the packed bias arrays (the conv's
                                  output channels) */
  int b_elems;
} hf_cl_layer;

typedef struct hf_cl_layout {
  int batch, pw, ph;
  int cin_pad;
  int nlayers;                 /* 2L: enc0..enc{L-1}, dec{L-1}..dec0 */
  hf_cl_layer layers[HF_CL_MAX_LAYERS];
  int nbufs;
  size_t buf_elems[HF_CL_MAX_BUFS];   /* FP16 elements, 0 = unused */
  size_t w_elems, b_elems;            /* packed filter / bias totals */
} hf_cl_layout;

static inline int hf_cl_pad8(int c) { return (c + HF_CL_ALIGN_CH - 1) & ~(HF_CL_ALIGN_CH - 1); }

/* Lays out cfg for batch frames of pw x ph (multiples of 2^L). Returns
 * HF_EINVAL for sizes that are not, HF_ERANGE when a buffer would overflow
 * size_t or a dimension would not fit cuDNN's int64 arithmetic. */
int hf_cl_layout_init(const hf_net_config *cfg, int batch, int pw, int ph, int deconv,
                      hf_cl_layout *lo);

/* Whether the layer's cuDNN operation is a forward convolution (x -> y)
 * rather than a data gradient (dy -> dx). */
static inline int hf_cl_is_fwd(const hf_cl_layer *ly) { return ly->kind != HF_CL_CONV_BWD_DATA; }

/* Repacks PyTorch-layout float weights into FP16 filters ([K][R][S][C],
 * zeros in padded channels) and biases (FP16 for fused cuDNN graphs, FP32
 * for the stand-alone bias kernel). w16 has lo->w_elems, b16 and b32
 * lo->b_elems elements. */
int hf_cl_pack_weights(const hf_cl_layout *lo, const hf_weights *w, uint16_t *w16,
                       uint16_t *b16, float *b32);

#endif /* HF_CUDNN_LAYOUT_H */
