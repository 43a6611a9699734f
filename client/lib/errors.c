/*
 * errors.c: libhairfilter's error names, its messages and its version.
 *
 * Each call clears the message first and sets it when it fails, in the
 * client and in a thread-local copy: hfc_connect has no client to keep a
 * message in when it fails, and an engine that logs from the thread that
 * made the call can read it there with hfc_last_message(NULL).
 */
#include <stdio.h>
#include <string.h>

#include "client_internal.h"

const char *hfc_version(void) { return HAIRFILTER_VERSION_STRING; }

static const struct {
  int code;
  const char *msg;
} local_errors[] = {
  {HFC_E_ARG, "bad argument"},
  {HFC_E_URL, "bad server URL (want unix:PATH, tcp:HOST:PORT, tcp:PORT or tls:HOST:PORT)"},
  {HFC_E_CONNECT, "cannot connect to the server"},
  {HFC_E_IO, "connection failed"},
  {HFC_E_TIMEOUT, "timed out waiting for the server"},
  {HFC_E_CLOSED, "server closed the connection"},
  {HFC_E_NOMEM, "out of memory"},
  {HFC_E_INFLIGHT, "too many requests in flight, or shared segments held, on this connection"},
  {HFC_E_NOPENDING, "no request in flight"},
  {HFC_E_TLS, "TLS handshake or certificate refused"},
};

const char *hfc_strerror(int err) {
  if (err == 0) return "ok";
  if (err < 0 && err > -HFP_E_COUNT) return hfp_strerror(err);
  for (size_t i = 0; i < sizeof local_errors / sizeof local_errors[0]; i++)
    if (local_errors[i].code == err) return local_errors[i].msg;
  return "unknown error";
}

static _Thread_local char thread_msg[MSG_MAX];

void hfci_begin(hfc_client *c) {
  thread_msg[0] = 0;
  if (c) c->msg[0] = 0;
}

static void set_msg(hfc_client *c, const char *fmt, va_list ap) {
  vsnprintf(thread_msg, sizeof thread_msg, fmt, ap);
  if (c) memcpy(c->msg, thread_msg, sizeof c->msg);
}

void hfci_msg(hfc_client *c, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  set_msg(c, fmt, ap);
  va_end(ap);
}

int hfci_arg(hfc_client *c, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  set_msg(c, fmt, ap);
  va_end(ap);
  return HFC_E_ARG;
}

int hfci_take_struct(hfc_client *c, const char *type, const void *given, void *full,
                     size_t full_size, const size_t *sizes, int nsizes, const char *init) {
  size_t size;
  memcpy(&size, given, sizeof size);   /* struct_size, the first field of each */
  if (size == 0)
    return hfci_arg(c, "%s.struct_size is 0: initialise it with %s()", type, init);
  if (size > full_size) {
    /* A newer header's struct: its fields past ours are honoured only
     * when unset (all zero, what its init leaves), the rule of the
     * kernel's extensible structs (copy_struct_from_user); a set one
     * would be ignored silently. */
    const unsigned char *tail = (const unsigned char *)given + full_size;
    for (size_t i = 0; i < size - full_size; i++)
      if (tail[i])
        return hfci_arg(c, "%s.struct_size is %zu, from a newer hairfilter.h than this "
                           "library's (%s, %zu bytes), and byte %zu past its fields is set: "
                           "run with the library of the header you built with",
                        type, size, HAIRFILTER_VERSION_STRING, full_size, full_size + i);
  } else {
    /* Only the sizes the header has had: any other ends inside a field
     * (half a pointer copied) or is not a struct of ours at all. */
    int known = size == full_size;
    for (int i = 0; i < nsizes && !known; i++) known = size == sizes[i];
    if (!known)
      return hfci_arg(c, "%s.struct_size is %zu, not the size of any version of it (%zu in "
                         "0.1.0, %zu in %s): initialise it with %s()",
                      type, size, sizes[0], full_size, HAIRFILTER_VERSION_STRING, init);
  }
  memcpy(full, given, size < full_size ? size : full_size);
  memcpy(full, &full_size, sizeof full_size);
  return 0;
}

const char *hfc_last_message(const hfc_client *c) { return c ? c->msg : thread_msg; }
