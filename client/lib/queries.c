/*
 * queries.c: the control requests LIST_VARIANTS and STATS of the server in
 * use, decoded into the public structs.
 */
#include <stdlib.h>
#include <string.h>

#include "client_internal.h"

int hfci_list(hfc_client *c, hfc_variant *out, int max, int *count) {
  uint8_t frame[HFP_HEADER_SIZE];
  int n = hfp_encode_empty(frame, sizeof frame, HFP_LIST_VARIANTS, 0);
  if (n < 0) return HFC_E_ARG;
  hfp_variant *v = malloc(sizeof *v * HFP_MAX_VARIANTS);
  if (!v) return HFC_E_NOMEM;
  int rc = hfci_control(c, frame, (size_t)n, HFP_VARIANTS);
  if (rc) {
    free(v);
    return rc;
  }
  int got = 0;
  rc = hfp_decode_variants(c->ctl, c->ctl_len, v, HFP_MAX_VARIANTS, &got);
  free(c->ctl);
  c->ctl = NULL;
  if (rc) {
    free(v);
    hfci_msg(c, "a malformed VARIANTS reply (%s)", hfp_strerror(rc));
    return HFC_E_PROTOCOL;
  }
  *count = got;
  for (int i = 0; i < got && i < max; i++) {
    memset(&out[i], 0, sizeof out[i]);
    memcpy(out[i].name, v[i].name, sizeof out[i].name);
    memcpy(out[i].backend, v[i].backend, sizeof out[i].backend);
    memcpy(out[i].precision, v[i].precision, sizeof out[i].precision);
    out[i].spp = v[i].spp;
    out[i].num_levels = v[i].num_levels;
    for (int l = 0; l < v[i].num_levels; l++) out[i].levels[l] = (int)v[i].levels[l];
    for (int k = 0; k < v[i].num_ranges; k++) {
      int stat = v[i].ranges[k].stat;
      if (stat >= HFC_MAX_STATS) continue;   /* one this library does not know */
      out[i].range_mask |= 1u << stat;
      out[i].range_lo[stat] = v[i].ranges[k].lo;
      out[i].range_hi[stat] = v[i].ranges[k].hi;
    }
    out[i].estimate = v[i].estimate == HFP_ESTIMATE_ALPHA_CORRECTED;
  }
  free(v);
  return 0;
}

int hfc_list_variants(hfc_client *c, hfc_variant *out, int max, int *count) {
  hfci_begin(c);
  if (!c || (!out && max > 0) || max < 0 || !count)
    return hfci_arg(c, "hfc_list_variants: %s", !c ? "the client is NULL"
                                                 : max < 0 ? "max is negative"
                                                 : !count ? "count is NULL"
                                                          : "out is NULL with max > 0");
  return hfci_list(c, out, max, count);
}

int hfc_get_stats(hfc_client *c, hfc_stats *out) {
  hfci_begin(c);
  if (!c || !out) return hfci_arg(c, "hfc_get_stats: %s is NULL", c ? "out" : "the client");
  uint8_t frame[HFP_HEADER_SIZE];
  int n = hfp_encode_empty(frame, sizeof frame, HFP_STATS, 0);
  if (n < 0) return HFC_E_ARG;
  hfp_stats *st = malloc(sizeof *st);
  if (!st) return HFC_E_NOMEM;
  int rc = hfci_control(c, frame, (size_t)n, HFP_STATS_REPLY);
  if (rc) {
    free(st);
    return rc;
  }
  rc = hfp_decode_stats(c->ctl, c->ctl_len, st);
  free(c->ctl);
  c->ctl = NULL;
  if (rc) {
    free(st);
    hfci_msg(c, "a malformed STATS_REPLY (%s)", hfp_strerror(rc));
    return HFC_E_PROTOCOL;
  }
  memset(out, 0, sizeof *out);
  out->uptime_us = st->uptime_us;
  out->connections_total = st->connections_total;
  out->protocol_errors = st->protocol_errors;
  out->connections_open = (int)st->connections_open;
  out->queue_depth = (int)st->queue_depth;
  out->queue_capacity = (int)st->queue_capacity;
  out->num_variants = st->num_variants;
  for (int i = 0; i < st->num_variants; i++) {
    const hfp_variant_stats *s = &st->variants[i];
    hfc_variant_stats *d = &out->variants[i];
    memcpy(d->name, s->name, sizeof d->name);
    d->requests_ok = s->requests_ok;
    d->requests_failed = s->requests_failed;
    d->rejected = s->rejected;
    d->batches = s->batches;
    d->sum_queue_us = s->sum_queue_us;
    d->sum_infer_us = s->sum_infer_us;
    d->sum_total_us = s->sum_total_us;
    memcpy(d->hist_total, s->hist_total, sizeof d->hist_total);
    memcpy(d->hist_infer, s->hist_infer, sizeof d->hist_infer);
    d->out_of_range = s->out_of_range;
    d->expired = s->expired;
    d->cancelled = s->cancelled;
    d->frames_sanitised = s->frames_sanitised;
    d->cache_bytes = s->cache_bytes;
  }
  free(st);
  return 0;
}
