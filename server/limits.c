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
 *
 * Likewise --max-connections, against the open-file limit: a connection
 * the kernel will not give a descriptor for is accepted and dropped by
 * libuv unseen, with no ERROR and no log line, so the documented refusal
 * (a fatal BUSY naming the limit) must come first.
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <sys/resource.h>

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
  if (w_before != (int)w || h_before != (int)h) {
    hfd_log("max size lowered from %ux%u to %ux%u: %s", w0, h0, w, h, why);
    /* --warm is checked against --max-size as given; a shape above the
     * lowered size had its plans built (seconds each on a GPU, and device
     * memory) for frames that will all get TOO_LARGE. */
    for (int k = 0; k < s->cfg->num_warm; k++)
      if ((uint32_t)s->cfg->warm[k].width > w || (uint32_t)s->cfg->warm[k].height > h)
        hfd_warn("--warm %dx%d is over the largest frame served, %ux%u (lowered: the line "
                 "above says why): its frames get TOO_LARGE and its plans serve none; warm "
                 "shapes within %ux%u, or raise the limit that lowered it",
                 s->cfg->warm[k].width, s->cfg->warm[k].height, w, h, w, h);
  }
  return 0;
}

/* Descriptors each connection may hold: its socket, and one shared-memory
 * segment's memfd while its SHM_CREATED waits to be written (conn.c passes
 * one at a time). */
#define FDS_PER_CONN 2
/* The daemon's own, besides its listeners and connections: stdio, the
 * loop (epoll, signals, async, timers), the worker and its backend, a
 * weights file being read on reload, the ready file, TLS files. */
#define FDS_RESERVE 64

int hfd_limits_fds(hfd_server *s) {
  const hfd_config *cfg = s->cfg;
  uint64_t reserve = FDS_RESERVE + (uint64_t)cfg->num_listen + (cfg->http ? HFD_HTTP_CONN_LIMIT : 0);
  uint64_t need = (uint64_t)cfg->max_connections * FDS_PER_CONN + reserve;
  s->max_connections = cfg->max_connections;
  struct rlimit rl;
  if (getrlimit(RLIMIT_NOFILE, &rl) != 0) {
    hfd_warn("getrlimit(RLIMIT_NOFILE): %s; --max-connections %d not checked against it",
             strerror(errno), cfg->max_connections);
    return 0;
  }
  if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < need) {
    /* The soft limit is ours to raise, up to the hard one. */
    rlim_t was = rl.rlim_cur;
    rl.rlim_cur = rl.rlim_max == RLIM_INFINITY || rl.rlim_max >= need ? (rlim_t)need : rl.rlim_max;
    if (rl.rlim_cur > was) {
      if (setrlimit(RLIMIT_NOFILE, &rl) == 0) {
        hfd_log("open-file limit raised from %llu to %llu for --max-connections %d",
                (unsigned long long)was, (unsigned long long)rl.rlim_cur, cfg->max_connections);
      } else {
        hfd_warn("setrlimit(RLIMIT_NOFILE, %llu): %s", (unsigned long long)rl.rlim_cur,
                 strerror(errno));
        rl.rlim_cur = was;
      }
    }
  }
  if (rl.rlim_cur == RLIM_INFINITY || rl.rlim_cur >= need) return 0;
  uint64_t fit = rl.rlim_cur > reserve ? (rl.rlim_cur - reserve) / FDS_PER_CONN : 0;
  if (fit < 1) {
    hfd_err("the open-file limit (%llu) leaves no descriptor for a connection: the daemon keeps "
            "%llu for itself; raise it (ulimit -n, or LimitNOFILE= in the systemd unit)",
            (unsigned long long)rl.rlim_cur, (unsigned long long)reserve);
    return -1;
  }
  s->max_connections = (int)fit;
  hfd_warn("--max-connections lowered from %d to %d: the open-file limit is %llu (hard limit "
           "%llu) and each connection may hold %d descriptors besides the %llu the daemon keeps; "
           "raise it with ulimit -n or LimitNOFILE= in the systemd unit",
           cfg->max_connections, s->max_connections, (unsigned long long)rl.rlim_cur,
           (unsigned long long)rl.rlim_max, FDS_PER_CONN, (unsigned long long)reserve);
  return 0;
}
