// hairfilter.hpp's ownership: a SharedBuffer follows the connection, not
// the Client object. It stays usable when its Client is moved, and one
// destroyed after the connection was closed (members declared before the
// Client, a Client moved into a shorter-lived owner) must not hand the
// closed client to hfc_shm_free, which would read freed memory.
//
// Linked with -Wl,--wrap=hfc_connect,--wrap=hfc_close,--wrap=hfc_shm_free
// (a client's address recorded between its hfc_close and a new
// hfc_connect that is given the same memory) so that a call
// with a closed client is caught in any build, not only under
// AddressSanitizer. Exit status 0, or 1 with the failures on stderr.
#include <cstdio>
#include <cstring>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <hairfilter/hairfilter.hpp>

extern "C" {
#include "harness.h"

int __real_hfc_connect(const char *url, const hfc_options *opt, hfc_client **out);
void __real_hfc_close(hfc_client *c);
int __real_hfc_shm_free(hfc_client *c, void *mem);
}

namespace {

std::set<const void *> g_closed;
int g_failures = 0, g_shm_frees = 0;

void fail(const char *what) {
  std::fprintf(stderr, "FAIL: %s\n", what);
  g_failures++;
}

}  // namespace

// A new client may be allocated where a closed one was.
extern "C" int __wrap_hfc_connect(const char *url, const hfc_options *opt, hfc_client **out) {
  int rc = __real_hfc_connect(url, opt, out);
  if (rc == 0) g_closed.erase(*out);
  return rc;
}

extern "C" void __wrap_hfc_close(hfc_client *c) {
  if (c) g_closed.insert(c);
  __real_hfc_close(c);
}

extern "C" int __wrap_hfc_shm_free(hfc_client *c, void *mem) {
  if (g_closed.count(c)) {
    fail("hfc_shm_free was given a client that hfc_close had freed");
    return HFC_E_ARG;   // not into freed memory
  }
  g_shm_frees++;
  return __real_hfc_shm_free(c, mem);
}

namespace {

harness H;
server S;

const int W = 8, HT = 8;

// One Tiny frame through shared memory in buf on c: 0 when filtered by
// reference.
int shm_frame(hairfilter::Client &c, hairfilter::SharedBuffer &buf) {
  const std::size_t in = hfc_features_bytes(W, HT, 2, HFC_F32);
  float *f = make_features(W, HT, 2, 3);
  if (!f) return -1;
  std::memcpy(buf.data(), f, in);
  std::free(f);
  hairfilter::Request r;
  r.variant = "Tiny";
  r.width = W;
  r.height = HT;
  r.spp = 2;
  r.set_features(buf.data(), in);
  r.set_result(buf.as<unsigned char>(in), hfc_output_bytes(W, HT, 3, HFC_F32));
  hfc_timing t;
  hairfilter::Status s = c.filter(r, &t);
  if (!s) std::fprintf(stderr, "filter: %s\n", s.what().c_str());
  return s && t.via_shm ? 0 : -1;
}

const std::size_t kBytes = 64 * 1024;

// A buffer declared before its Client: destroyed after it.
void buffer_outlives_client() {
  hairfilter::SharedBuffer buf;
  hairfilter::Client c(S.unix_url);
  buf = hairfilter::SharedBuffer(c, kBytes);
  if (shm_frame(c, buf)) fail("a frame through the buffer");
}

// A Client moved into another that goes first; the buffer made with the
// first one works through the second.
void client_moved() {
  hairfilter::Client a(S.unix_url);
  hairfilter::SharedBuffer buf(a, kBytes);
  {
    hairfilter::Client b(std::move(a));
    if (a) fail("a moved-from Client still says it is connected");
    if (a.pending() != HFC_E_ARG) fail("pending() of a moved-from Client");
    if (shm_frame(b, buf)) fail("a frame through the buffer on the moved-to Client");
  }
  if (buf.data() == nullptr) fail("the buffer forgot its segment before its own end");
}

// With the connection open, reset() frees the segment on it.
void reset_frees() {
  hairfilter::Client c(S.unix_url);
  hairfilter::SharedBuffer buf(c, kBytes);
  int before = g_shm_frees;
  buf.reset();
  if (g_shm_frees != before + 1) fail("reset() with the connection open did not free the segment");
  hairfilter::SharedBuffer again(c, kBytes);
  if (shm_frame(c, again)) fail("a frame through a buffer made after a reset");
}

// A completion that failed: wait() is OK, completion() gives the frame's
// code and the server's words (they were out of reach of the wrapper).
void failed_completion() {
  hairfilter::Client c(S.unix_url);
  std::vector<float> in(static_cast<std::size_t>(W) * HT * 2 * 6, 0.5f), out(W * HT * 3);
  hairfilter::Request r;
  r.variant = "NoSuchVariant";
  r.width = W;
  r.height = HT;
  r.spp = 2;
  r.set_features(in.data(), in.size() * sizeof(float));
  r.set_result(out.data(), out.size() * sizeof(float));
  if (!c.submit(r)) fail("submit of a frame naming no variant");
  hfc_completion done;
  hairfilter::Status s = c.wait(done, 10000);
  hairfilter::Status frame = c.completion(done);
  if (!s) fail("wait() for a completion that failed");
  if (frame.code != HFC_E_UNKNOWN_VARIANT || frame.message.find("NoSuchVariant") == std::string::npos)
    fail("completion() of a frame naming no variant: want HFC_E_UNKNOWN_VARIANT and its name");
  if (c.last_message() != frame.message) fail("last_message() is not the completion's");
}

// A frame whose budget passed in the queue is routine in a frame loop, as
// BUSY is: Status says which, and a Request has no budget unless given one.
void status_kinds() {
  hairfilter::Status expired(HFC_E_EXPIRED, ""), busy(HFC_E_BUSY, "");
  if (!expired.expired() || expired.busy() || expired) fail("Status::expired() of HFC_E_EXPIRED");
  if (busy.expired() || !busy.busy()) fail("Status::expired() of HFC_E_BUSY");
  if (expired.what().find("deadline") == std::string::npos) fail("what() of HFC_E_EXPIRED");
  hairfilter::Status cancelled(HFC_E_CANCELLED, "");
  if (!cancelled.cancelled() || cancelled.expired()) fail("Status::cancelled() of HFC_E_CANCELLED");
  hairfilter::Request r;
  if (r.deadline_us != 0) fail("a Request's deadline_us is not 0 by default");
}

}  // namespace

int main() {
  if (harness_init(&H) || server_start(&H, &S, nullptr)) return 1;
  try {
    buffer_outlives_client();
    client_moved();
    reset_frees();
    failed_completion();
    status_kinds();
  } catch (const hairfilter::Error &e) {
    std::fprintf(stderr, "hairfilter::Error: %s\n", e.what());
    g_failures++;
  }
  if (harness_stop(&H, &S)) g_failures++;
  if (!g_failures) std::printf("test_hpp: ok\n");
  return g_failures ? 1 : 0;
}
