/* Internal to the weights loader and writer: the tensor list of a network. */
#ifndef HF_WEIGHTS_H
#define HF_WEIGHTS_H

#include "hfcore.h"

#define HF_TENSORS_MAX (4 * HF_MAX_LEVELS + 2)

typedef struct hf_tensor_spec {
  char name[24];          /* "enc0.weight" ... */
  int ndim;
  int64_t shape[4];
  size_t numel;
  float **slot;           /* where the array lives in hf_weights */
} hf_tensor_spec;

/* Fills specs for w->cfg (which must be valid) in file order: enc0.weight,
 * enc0.bias, dec0.weight, dec0.bias, enc1..., then head.weight, head.bias
 * when the network has a head, and returns their count. */
int hf_weights_specs(hf_weights *w, hf_tensor_spec *specs);

#endif
