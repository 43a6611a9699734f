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
 *   HF_CL_BUF_OUT      dec0 out, ph x pw, out_ch channels: up to 8 (3 used),
 *                      or dec0's channels padded to 8 for HF_ARCH_KERNEL
 * A form may add a dense scratch tensor of its own (HF_CL_BUF_SCRATCH).
 *
 * Encoders are forward convolutions. A decoder, a 4x4 stride-2 pad-1
 * transposed conv, can be computed in several exact forms (hf_cl_form),
 * all from the same weights; the backend times them and keeps the fastest:
 *
 *   BWD_DATA  cuDNN's data gradient of the forward conv it transposes.
 *             Filter [K=in][4][4][C=out]: PyTorch's ConvTranspose2d weight
 *             [in][out][4][4] is that forward conv's [K][C][R][S], no flip.
 *   D2S       one 2x2 stride-1 forward conv, padded by one pixel on every
 *             side, to 4*co channels at (h+1) x (w+1), then a depth-to-space
 *             with a one-pixel offset: output pixel (2m+dy, 2n+dx), channel
 *             o, is channel (2dy+dx)*co + o of conv pixel (m+dy, n+dx).
 *   PHASE     four 2x2 stride-1 forward convs, one per output phase
 *             (dy, dx), padded (1-dy, 1-dx) before and (dy, dx) after, each
 *             writing a stride-2 view of the output directly.
 *   SHUFFLE   one 3x3 stride-1 pad-1 conv to 4*co channels at h x w, then a
 *             depth-to-space without offset; 2.25x the multiply-adds (9 taps
 *             per phase, of which 4 are not zero).
 *
 * Why the 2x2 forms are exact: the transposed conv reaches output row
 * 2m+dy from input rows m-1 and m (dy = 0, kernel rows 3 and 1) or m and
 * m+1 (dy = 1, kernel rows 2 and 0), and likewise for columns. A 2x2
 * filter per phase holds exactly those four taps (hf_cl_tap2), so D2S and
 * PHASE do the transposed conv's multiply-adds and no more (D2S computes
 * one extra row and column of conv pixels, of which each phase uses all
 * but one).
 *
 * dec0 writes the 3 output channels, padded to 8 for BWD_DATA and SHUFFLE,
 * to 4 per phase for PHASE (a 4-channel OUT buffer), and to 3 per phase for
 * D2S, whose conv output the output stage reads directly (no depth-to-space
 * pass, hf_cl_raw). The Kernel architecture's dec0 has more channels (the
 * kernel's taps + 3, or kernel_hidden before the head): they are padded to
 * 8 in every form, like the other decoders', and D2S's output is read from
 * the scratch too; its ReLU, when a head follows, is the layer's. The head
 * itself is not a layer here: the output stage computes it per pixel
 * (cudnn_kernels.h).
 */
#ifndef HF_CUDNN_LAYOUT_H
#define HF_CUDNN_LAYOUT_H

#include <stddef.h>
#include <stdint.h>

#include "hfcore.h"

#define HF_CL_ALIGN_CH 8
#define HF_CL_OUT_CH   8          /* the OUT buffer's channels per pixel for 3 outputs */
#define HF_CL_MAX_LAYERS (2 * HF_MAX_LEVELS)
#define HF_CL_MAX_CONVS 4         /* cuDNN convolutions in one layer form */

enum {
  HF_CL_BUF_IN = 0,
  HF_CL_BUF_DEEP = 1,
  HF_CL_BUF_OUT = 2,
  HF_CL_BUF_SKIP0 = 3,
  HF_CL_MAX_BUFS = HF_CL_BUF_SKIP0 + HF_MAX_LEVELS - 1,
  HF_CL_BUF_SCRATCH = HF_CL_MAX_BUFS   /* a form's own dense tensor */
};

/* How a layer is computed. Encoders have FWD only; decoders any other. */
enum {
  HF_CL_FORM_FWD = 0,
  HF_CL_FORM_BWD_DATA = 1,
  HF_CL_FORM_D2S = 2,
  HF_CL_FORM_PHASE = 3,
  HF_CL_FORM_SHUFFLE = 4,
  HF_CL_NFORMS = 5
};

/* Depth-to-space after a form's convolution. */
enum { HF_CL_D2S_NONE = 0, HF_CL_D2S_SHUFFLE = 1, HF_CL_D2S_OFFSET = 2 };

/* The form's name ("fwd", "bwd-data", "d2s", "phase", "shuffle"), and back
 * (HF_ENOTFOUND for other names). */
const char *hf_cl_form_name(int form);
int hf_cl_form_from_name(const char *name);

/* A 4-D NHWC tensor inside a buffer. Its pixel (n, y, x), channel k, is
 * element ch_off + ((n*bh + y0 + step*y) * bw + x0 + step*x) * pix_stride + k
 * of buffer buf: a whole-frame view has y0 = x0 = 0, step = 1 and
 * (bh, bw) = (h, w); a PHASE conv writes a step-2 view. */
typedef struct hf_cl_view {
  int buf;
  int ch_off;
  int pix_stride;
  int c, h, w;                  /* the view's shape per frame */
  int bh, bw;                   /* the buffer's frame: rows, pixels per row */
  int y0, x0, step;
} hf_cl_view;

/* Element offset of the view's first element (n = y = x = k = 0). */
size_t hf_cl_view_offset(const hf_cl_view *v);
/* Element strides in cuDNN's dimension order (n, c, h, w). */
void hf_cl_view_strides(const hf_cl_view *v, int64_t strides[4]);
/* Whether the view is a whole, packed tensor (channels == pixel stride,
 * whole frame). */
int hf_cl_view_dense(const hf_cl_view *v);
/* The packed tensor of the view's shape in buffer buf. */
hf_cl_view hf_cl_view_packed(int buf, int c, int h, int w);

/* One cuDNN convolution: a forward cross-correlation x -> y with filter
 * [K][R][S][C] (K = y's channels), or, when bwd_data, the data gradient of
 * such a conv: x is cuDNN's dy (K channels), y its dx (C channels). Bias is
 * per channel of y; ReLU after it when relu. */
typedef struct hf_cl_conv {
  int bwd_data;
  int k, c, r, s;
  int stride;
  int pad_pre[2], pad_post[2];  /* rows, columns */
  int relu;
  hf_cl_view x, y;
  size_t w_off;                 /* into the packed FP16 filters */
  size_t b_off;                 /* into the packed biases: y's channels */
} hf_cl_conv;

/* Layer as the network defines it. */
typedef struct hf_cl_layer {
  char name[16];                /* "enc0", "dec2" */
  int dec;                      /* 0 encoder, 1 decoder */
  int level;
  int relu;                     /* ReLU after the bias (all but dec0) */
  hf_cl_view in, out;           /* out: for dec0 the OUT view (out_ch channels) */
  /* Real (unpadded) channel counts and how real input channels map to
   * padded ones: real input j < in_split goes to j, j >= in_split goes to
   * in_split_pad + (j - in_split). in_split == in_real means no split. */
  int in_real, out_real, in_split, in_split_pad;
  /* Packed filters and biases of each form (0 elements: form unused). */
  size_t w_off[HF_CL_NFORMS], w_elems[HF_CL_NFORMS];
  size_t b_off[HF_CL_NFORMS], b_elems[HF_CL_NFORMS];
} hf_cl_layer;

/* A layer in one form: its convolutions, then optionally a depth-to-space
 * from the dense scratch the convs wrote into the layer's output view. */
typedef struct hf_cl_form {
  int form;
  int nconv;
  hf_cl_conv conv[HF_CL_MAX_CONVS];
  int d2s;                      /* HF_CL_D2S_* */
  int co;                       /* output channels per phase */
  hf_cl_view scratch;           /* d2s: what the conv writes (buf SCRATCH) */
  hf_cl_view out;               /* the layer's output in this form */
  int out_in_scratch;           /* dec0 D2S: the output stage reads the
                                   scratch; no depth-to-space pass */
} hf_cl_form;

typedef struct hf_cl_layout {
  int batch, pw, ph;
  int cin_pad;
  int out_ch;                   /* the OUT buffer's channels per pixel */
  int nlayers;                  /* 2L: enc0..enc{L-1}, dec{L-1}..dec0 */
  hf_cl_layer layers[HF_CL_MAX_LAYERS];
  int nbufs;
  size_t buf_elems[HF_CL_MAX_BUFS];   /* FP16 elements, 0 = unused */
  size_t w_elems, b_elems;            /* packed filter / bias totals */
} hf_cl_layout;

static inline int hf_cl_pad8(int c) { return (c + HF_CL_ALIGN_CH - 1) & ~(HF_CL_ALIGN_CH - 1); }

/* Lays out cfg for batch frames of pw x ph (multiples of 2^L). Returns
 * HF_EINVAL for sizes that are not, HF_ERANGE when a buffer would overflow
 * size_t or a dimension would not fit cuDNN's int64 arithmetic. */
int hf_cl_layout_init(const hf_net_config *cfg, int batch, int pw, int ph, hf_cl_layout *lo);

/* Layer ly of lo in the given form. HF_EINVAL when the form does not apply
 * (an encoder in a decoder form or the reverse). */
int hf_cl_layer_form(const hf_cl_layout *lo, const hf_cl_layer *ly, int form, hf_cl_form *f);

/* Kernel row (or column) of the 4x4 transposed conv that tap t (0: the
 * earlier input row) of phase d uses in the 2x2 forms: {3, 1} for d = 0,
 * {2, 0} for d = 1. */
static inline int hf_cl_tap2(int d, int t) { return d ? 2 - 2 * t : 3 - 2 * t; }

/* Where the output stage finds the raw network output (color, highlight,
 * alpha) of frame pixel (x, y) of frame n: element
 *   ch_off(y, x) + ((n*rows + y / div + dy*offset) * cols + x / div + dx*offset) * pix_stride
 * of the tensor, with (dy, dx) = (y % div, x % div) and ch_off = (2dy+dx)*co
 * when div == 2, and ch_off 0 when div == 1. */
typedef struct hf_cl_raw {
  int buf;                      /* HF_CL_BUF_OUT or HF_CL_BUF_SCRATCH */
  int pix_stride, rows, cols;
  int div;                      /* 1: plain; 2: phases of a D2S conv */
  int offset;                   /* 1 for D2S (one-pixel offset) */
  int co;
} hf_cl_raw;

/* The raw output of dec0 in form f (hf_cl_layer_form of dec0). */
hf_cl_raw hf_cl_raw_output(const hf_cl_form *f);

/* Repacks PyTorch-layout float weights into FP16 filters ([K][R][S][C],
 * zeros in padded channels) and biases (FP16 for fused cuDNN graphs, FP32
 * for the stand-alone bias kernel), every form of every layer. w16 has
 * lo->w_elems, b16 and b32 lo->b_elems elements. */
int hf_cl_pack_weights(const hf_cl_layout *lo, const hf_weights *w, uint16_t *w16,
                       uint16_t *b16, float *b32);

#endif /* HF_CUDNN_LAYOUT_H */
