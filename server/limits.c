/*
 * What a frame costs, and the largest frame the limits let through.
 *
 * HELLO_OK announces a largest frame (max_width x max_height, max_spp), and
 * PROTOCOL.md promises that a frame within it is refused only for reasons
 * that pass (BUSY). So the announced size must satisfy every limit that
 * applies to a single frame on an idle server: the payload limit
 * (--max-frame-mb), the memory one frame may be charged (--max-memory-mb
 * less what the worker may keep between runs), and the backend's own range.
 * --max-size is the operator's wish; this file lowers it to what those
 * limits allow, for the most demanding loaded variant.
 */
#include <stdio.h>
#include <string.h>

#include "server.h"

uint64_t hfd_frame_bytes(const hfd_server *s, int variant, const hfp_filter *f) {
  uint64_t out = 0, rgba = 0;
  if (hfp_output_bytes(f->width, f->height, HFP_OUTPUTS, f->out_dtype, &out) ||
      ((f->flags & HFP_FILTER_COMPOSITE) &&
       hfp_output_bytes(f->width, f->height, 4, f->out_dtype, &rgba)))
    return UINT64_MAX;
  uint64_t run = hfd_worker_run_bytes(&s->worker, &s->variants[variant].model->cfg, f->width,
                                      f->height, 1, f->data_len);
  if (run == UINT64_MAX) return UINT64_MAX;
  /* A frame by reference reads and writes the client's segment. */
  if (f->flags & HFP_FILTER_SHM) return run;
  /* Through the socket its tensor and results sit in receive-pool buffers,
   * which a new mapping rounds up to 2 MiB steps: that rest is resident too
   * and is counted here, so that the announced size is admitted on an idle
   * server whatever plans the worker keeps within its quarter. */
  return hfd_rpool_footprint(f->data_len) + hfd_rpool_footprint(out) + hfd_rpool_footprint(rgba) +
         run;
}

/* The most demanding frame of w x h any loaded variant can be sent: f32
 * both ways, with a composite. *why says which limit it breaks. */
static int frame_fits(const hfd_server *s, uint32_t w, uint32_t h, char *why, size_t whylen) {
  for (int v = 0; v < s->num_variants; v++) {
    const hfd_model *var = s->variants[v].model;
    if (!var) continue;  /* removed */
    hfp_filter f = {.flags = HFP_FILTER_COMPOSITE | (var->cfg.estimate ? HFP_FILTER_ESTIMATE : 0),
                    .width = w, .height = h, .spp = (uint16_t)var->cfg.spp,
                    .in_dtype = HFP_F32, .out_dtype = HFP_F32};
    if (hfp_filter_input_bytes(w, h, f.spp, HFP_F32, f.flags, &f.data_len)) return 0;
    uint64_t payload = HFP_FILTER_FIXED + strlen(var->name) + f.data_len;
    if (payload > s->cfg->max_frame_bytes) {
      snprintf(why, whylen, "a %s frame of %ux%u is %.1f MiB, over --max-frame-mb %llu",
               var->name, w, h, payload / 1048576.0,
               (unsigned long long)(s->cfg->max_frame_bytes >> 20));
      return 0;
    }
    uint64_t need = hfd_frame_bytes(s, v, &f);
    if (need == UINT64_MAX) {
      snprintf(why, whylen, "the %s backend does not run %ux%u frames",
               hf_backend_name(s->worker.backend), w, h);
      return 0;
    }
    if (need > s->frame_budget) {
      snprintf(why, whylen,
               "a %s frame of %ux%u needs %.1f MiB (buffers and inference), over the "
               "%.1f MiB one frame may use (--max-memory-mb %llu less a quarter kept for plans)",
               var->name, w, h, need / 1048576.0, s->frame_budget / 1048576.0,
               (unsigned long long)(s->cfg->max_memory_bytes >> 20));
      return 0;
    }
  }
  return 1;
}

/* Side lengths at step k of m along the line from 1x1 to w0 x h0. */
static void scaled(uint32_t w0, uint32_t h0, uint32_t k, uint32_t m, uint32_t *w, uint32_t *h) {
  *w = (uint32_t)((uint64_t)w0 * k / m);
  *h = (uint32_t)((uint64_t)h0 * k / m);
  if (*w < 1) *w = 1;
  if (*h < 1) *h = 1;
}

int hfd_limits_derive(hfd_server *s) {
  uint32_t w0 = (uint32_t)s->cfg->max_width, h0 = (uint32_t)s->cfg->max_height;
  /* A reload derives the size again; the log speaks when it changes. */
  const int w_before = s->max_width, h_before = s->max_height;
  char why[400] = "";
  if (frame_fits(s, w0, h0, why, sizeof why)) {
    s->max_width = (int)w0;
    s->max_height = (int)h0;
    if (w_before && (w_before != (int)w0 || h_before != (int)h0))
      hfd_log("max size back to %ux%u (was %dx%d)", w0, h0, w_before, h_before);
    return 0;
  }
  /* Shrink both sides by the same factor: the largest step k of m (the
   * longer side) that fits. Every limit grows with the frame, so fitting is
   * monotone in k and a bisection finds the edge. */
  uint32_t m = w0 > h0 ? w0 : h0, lo = 0, hi = m, w, h;   /* lo fits (0: none), hi not */
  char hi_why[400];
  while (hi - lo > 1) {
    uint32_t mid = lo + (hi - lo) / 2;
    scaled(w0, h0, mid, m, &w, &h);
    if (frame_fits(s, w, h, hi_why, sizeof hi_why)) {
      lo = mid;
    } else {
      hi = mid;
      /* The limit that stops the size just above the one announced. */
      memcpy(why, hi_why, sizeof why);
    }
  }
  if (lo == 0) {
    hfd_err("no frame can be served: %s", why);
    return -1;
  }
  scaled(w0, h0, lo, m, &w, &h);
  s->max_width = (int)w;
  s->max_height = (int)h;
  if (w_before != (int)w || h_before != (int)h)
    hfd_log("max size lowered from %ux%u to %ux%u: %s", w0, h0, w, h, why);
  return 0;
}
